//! The files of the solve's checkpoints in `RUN/solve/`, as bytes: the generations
//! `g0.bin` and `g1.bin`, `manifest.json` and `manifest.prev.json`. Their format (what
//! the bytes mean, the checksums) is [`crate::solve::checkpoint`]'s; this is the only
//! place that touches the filesystem for them.

use std::fs;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::{io, write_atomic, RunError};

/// The manifest naming the newest checkpoint.
const MANIFEST: &str = "manifest.json";
/// The manifest before it.
const MANIFEST_PREV: &str = "manifest.prev.json";

/// The checkpoint files of a run (see [`super::RunDir::checkpoint_files`]).
#[derive(Clone, Debug)]
pub struct CheckpointFiles {
    dir: PathBuf,
}

impl CheckpointFiles {
    pub(super) fn new(dir: PathBuf) -> Self {
        Self { dir }
    }

    /// The directory (`RUN/solve/`).
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// The path of generation `g` (for messages).
    #[must_use]
    pub fn generation_path(&self, g: usize) -> PathBuf {
        self.dir.join(format!("g{g}.bin"))
    }

    /// Whether the newest manifest exists.
    #[must_use]
    pub fn has_manifest(&self) -> bool {
        self.dir.join(MANIFEST).exists()
    }

    /// The bytes of the manifest `name` (`manifest.json` or `manifest.prev.json`), if
    /// readable.
    #[must_use]
    pub fn read_manifest(&self, name: &str) -> Option<Vec<u8>> {
        fs::read(self.dir.join(name)).ok()
    }

    /// Make `bytes` the newest manifest, keeping the one before as
    /// `manifest.prev.json`; the new one is written atomically ([`write_atomic`]).
    pub fn commit_manifest(&self, bytes: &[u8]) -> Result<(), RunError> {
        let manifest = self.dir.join(MANIFEST);
        if manifest.exists() {
            let prev = self.dir.join(MANIFEST_PREV);
            fs::copy(&manifest, &prev).map_err(io(&prev))?;
        }
        write_atomic(&manifest, bytes)
    }

    /// Remove every checkpoint file (a fresh start). Best effort.
    pub fn clear(&self) {
        // On MPI ranks rank 0 removes them, and every rank waits until it has.
        let w = crate::grid::world();
        if w.is_root() {
            for name in [MANIFEST, MANIFEST_PREV, "g0.bin", "g1.bin"] {
                let _ = fs::remove_file(self.dir.join(name));
            }
        }
        let _ = w.barrier();
    }

    /// Start writing generation `g` anew (see [`GenerationWriter::finish`]).
    pub fn create_generation(&self, g: usize) -> std::io::Result<GenerationWriter> {
        let file = fs::File::create(self.generation_path(g))?;
        Ok(GenerationWriter {
            out: BufWriter::with_capacity(1 << 20, file),
        })
    }

    /// The length in bytes of generation `g`.
    pub fn generation_len(&self, g: usize) -> std::io::Result<u64> {
        Ok(fs::metadata(self.generation_path(g))?.len())
    }

    /// Read generation `g` from its start.
    pub fn open_generation(&self, g: usize) -> std::io::Result<impl Read> {
        let file = fs::File::open(self.generation_path(g))?;
        Ok(BufReader::with_capacity(1 << 20, file))
    }
}

/// A generation being written (buffered); [`GenerationWriter::finish`] makes it durable.
pub struct GenerationWriter {
    out: BufWriter<fs::File>,
}

impl Write for GenerationWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.out.write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.out.write_all(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

impl GenerationWriter {
    /// Flush and fsync the generation.
    pub fn finish(self) -> std::io::Result<()> {
        let file = self
            .out
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)?;
        file.sync_all()
    }
}
