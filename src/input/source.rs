//! Opening input files, transparently gunzipping `.gz`.

use std::io::Read;
use std::path::Path;

use super::InputError;

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

/// Read a whole input file into memory, decompressing it if its name ends in `.gz`.
///
/// Shapes are small next to grids (a 100k-triangle mesh is a few MB), so whole-file reads
/// are fine here; grids are what must never be whole in memory.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, InputError> {
    let raw = std::fs::read(path).map_err(|e| InputError::io(path, e))?;
    if !extension(path).1 {
        return Ok(raw);
    }
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(&raw[..])
        .read_to_end(&mut out)
        .map_err(|e| InputError::invalid(path, format!("cannot gunzip: {e}")))?;
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
