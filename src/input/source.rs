//! Opening input files, transparently gunzipping `.gz`, within a bound on the bytes
//! held: a stream that never ends (`/dev/zero`) or a gzip bomb is refused when it
//! passes the bound, with the size read so far and the position in the file.

use std::cell::Cell;
use std::io::Read;
use std::path::Path;
use std::rc::Rc;

use super::InputError;
use crate::grid::{human, MemBudget};

/// The share of `--mem` the decoded bytes of an input may take: the readers hold the
/// bytes and what they parse from them (vertices, triangles, atoms), about as much
/// again, next to the reader's own tables.
const INPUT_SHARE: u64 = 3;

/// The least the readers may hold, whatever the budget: small inputs are read under any
/// `--mem`, so that a budget too small for the grid is refused by the stage that knows
/// what it needs; this much is part of the fixed allowance beyond `--mem`.
const INPUT_FLOOR: u64 = 16 << 20;

/// The most decoded bytes an input file may have under the budget `mem`: a third of
/// it, at least 16 MiB.
#[must_use]
pub fn input_limit(mem: MemBudget) -> u64 {
    (mem.work_bytes() / INPUT_SHARE).max(INPUT_FLOOR)
}

/// Counts the bytes read from the file itself (before decompression).
struct Counting<R> {
    inner: R,
    read: Rc<Cell<u64>>,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read.set(self.read.get() + n as u64);
        Ok(n)
    }
}

/// The format-bearing extension of `path`, lower case, with a trailing `.gz` removed
/// (`armadillo.obj.gz` -> `obj`), and whether it was gzipped.
#[must_use]
pub fn extension(path: &Path) -> (String, bool) {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let (stem, gz) = match name.strip_suffix(".gz") {
        Some(s) => (s.to_owned(), true),
        None => (name, false),
    };
    let ext = Path::new(&stem)
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_default();
    (ext, gz)
}

/// Read a whole input file into memory, decompressing it if its name ends in `.gz`,
/// within the default `--mem` ([`read_bytes_within`]).
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, InputError> {
    read_bytes_within(path, input_limit(MemBudget::default()))
}

/// Read a whole input file into memory, decompressing it if its name ends in `.gz`;
/// refused ([`InputError::TooLarge`]) once more than `limit` decoded bytes come out.
///
/// Shapes are small next to grids (a 100k-triangle mesh is a few MB), so whole-file reads
/// are fine here; grids are what must never be whole in memory.
pub fn read_bytes_within(path: &Path, limit: u64) -> Result<Vec<u8>, InputError> {
    let file = std::fs::File::open(path).map_err(|e| InputError::io(path, e))?;
    // A regular file's size is known: reserve it (within the limit) instead of growing.
    let size = file.metadata().map_or(0, |m| m.len());
    let read = Rc::new(Cell::new(0u64));
    let counted = Counting {
        inner: std::io::BufReader::with_capacity(1 << 16, file),
        read: read.clone(),
    };
    let gz = extension(path).1;
    let mut out = Vec::with_capacity(if gz { 0 } else { size.min(limit) as usize });
    // One byte past the limit tells a file of exactly `limit` bytes from a longer one.
    let res = if gz {
        flate2::read::MultiGzDecoder::new(counted)
            .take(limit.saturating_add(1))
            .read_to_end(&mut out)
    } else {
        counted.take(limit.saturating_add(1)).read_to_end(&mut out)
    };
    res.map_err(|e| {
        if gz {
            InputError::invalid(
                path,
                format!("cannot gunzip at byte {} of the file: {e}", read.get()),
            )
        } else {
            InputError::io(path, e)
        }
    })?;
    if out.len() as u64 > limit {
        // Pieces between line ends: the number of the line reached.
        let line = out.split(|&b| b == b'\n').count() as u64;
        return Err(InputError::TooLarge {
            path: path.to_owned(),
            seen: human(out.len() as u64),
            position: read.get(),
            line,
            limit: human(limit),
        });
    }
    Ok(out)
}

/// SHA-256 of the file's bytes as stored (before any decompression), lower-case hex.
pub fn sha256_file(path: &Path) -> Result<String, InputError> {
    use sha2::Digest;
    let mut f = std::fs::File::open(path).map_err(|e| InputError::io(path, e))?;
    let mut h = sha2::Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(|e| InputError::io(path, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize()
        .iter()
        .fold(String::with_capacity(64), |mut s, b| {
            use std::fmt::Write;
            let _ = write!(s, "{b:02x}");
            s
        }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An endless stream and a gzip bomb stop at the limit, with the size and position.
    #[test]
    fn reads_stop_at_the_limit() {
        let d = tempfile::tempdir().unwrap();
        let plain = d.path().join("big.obj");
        std::fs::write(&plain, vec![b'v'; 5000]).unwrap();
        assert_eq!(read_bytes_within(&plain, 5000).unwrap().len(), 5000);
        let e = read_bytes_within(&plain, 4999).unwrap_err();
        assert!(
            matches!(e, InputError::TooLarge { position: 5000, .. }),
            "{e}"
        );
        let bomb = d.path().join("bomb.obj.gz");
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        std::io::Write::write_all(&mut enc, &vec![0u8; 4 << 20]).unwrap();
        let gz = enc.finish().unwrap();
        std::fs::write(&bomb, &gz).unwrap();
        let e = read_bytes_within(&bomb, 1 << 20).unwrap_err();
        let InputError::TooLarge { position, .. } = e else {
            panic!("{e}")
        };
        assert!(position <= gz.len() as u64, "{position}");
        assert_eq!(read_bytes_within(&bomb, 4 << 20).unwrap().len(), 4 << 20);
    }

    #[test]
    fn extension_strips_gz() {
        assert_eq!(
            extension(Path::new("a/b/Armadillo.OBJ.gz")),
            ("obj".into(), true)
        );
        assert_eq!(extension(Path::new("x.stl")), ("stl".into(), false));
        assert_eq!(extension(Path::new("noext")), (String::new(), false));
    }
}
