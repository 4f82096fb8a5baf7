//! Checkpoints of the iteration: the state u and the loop's history, written so that a
//! resumed solve gives the same bytes as an uninterrupted one.
//!
//! Format (version [`CHECKPOINT_FORMAT`]), in `RUN/solve/`: two generation files
//! `g0.bin`, `g1.bin` — every block of u in block order, true extents, f64
//! little-endian — and `manifest.json` naming the generation that holds the newest
//! state, with its length and sha256, the identity of the labels and options it was
//! made for, and the [`History`]; the manifest before it is kept as
//! `manifest.prev.json`.
//!
//! A checkpoint writes the generation the current manifest does not name, fsyncs it,
//! then commits a new manifest atomically (temporary file, fsync, rename). A torn or
//! damaged generation fails its checksum on resume, and the previous manifest is used.
//!
//! The files are read and written through the run directory
//! ([`RunDir::checkpoint_files`]), the only place that touches the filesystem for
//! checkpoints; this module holds their format.

use std::io::{Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::json;
use sha2::{Digest, Sha256};

use super::driver::History;
use super::error::SolveError;
use super::options::SolveOptions;
use crate::grid::{world, BlockStore, Decomposition, GridError};
use crate::progress::Progress;
use crate::run::{CheckpointFiles, RunDir};

/// Version of the checkpoint files (2: the state is u = 1 - phi).
pub const CHECKPOINT_FORMAT: u32 = 2;

/// What `manifest.json` records.
#[derive(Debug, Serialize, Deserialize)]
pub struct Manifest {
    format: u32,
    identity: String,
    /// The generation file (0 or 1) that holds the state.
    pub generation: usize,
    sha256: String,
    bytes: u64,
    /// The iteration's history at the state.
    pub history: History,
}

/// The identity a checkpoint must match: the labels' provenance and the options that
/// change the iterates.
pub fn identity(run: &RunDir, opts: &SolveOptions) -> Result<String, crate::Error> {
    let a = run.attrs()?;
    let v = json!({
        "grid": a.get("grid"),
        "input": a.get("input"),
        "center": a.get("center"),
        // The options as recorded (not read back by type: the identity must change
        // with any recorded field, known to this version or not).
        "voxelize": crate::run::stage_record(&a, "voxelize").map(|r| r.options),
        "solve": opts,
    });
    Ok(hex(&Sha256::digest(v.to_string().as_bytes())))
}

fn hex(b: &[u8]) -> String {
    use std::fmt::Write as _;
    b.iter().fold(String::new(), |mut s, x| {
        let _ = write!(s, "{x:02x}");
        s
    })
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> GridError + '_ {
    move |source| GridError::Io {
        path: path.to_owned(),
        source,
    }
}

/// The manifest `name` (`manifest.json` or `manifest.prev.json`), if readable.
fn load(files: &CheckpointFiles, name: &str) -> Option<Manifest> {
    serde_json::from_slice(&files.read_manifest(name)?).ok()
}

/// Write every block of `u` to generation `g`, fsync it, and return its sha256 and
/// length.
fn write_generation(
    files: &CheckpointFiles,
    u: &dyn BlockStore<f64>,
    g: usize,
) -> Result<(String, u64), GridError> {
    let path = &files.generation_path(g);
    let w = world();
    if w.parts() > 1 {
        return write_generation_ranks(files, u, g, w);
    }
    let mut out = files.create_generation(g).map_err(io_err(path))?;
    let mut sha = Sha256::new();
    let mut len = 0u64;
    let mut buf = Vec::new();
    for block in u.spec().block_indices() {
        buf.clear();
        for v in u.read_block(block)? {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        sha.update(&buf);
        out.write_all(&buf).map_err(io_err(path))?;
        len += buf.len() as u64;
    }
    out.finish().map_err(io_err(path))?;
    Ok((hex(&sha.finalize()), len))
}

/// [`write_generation`] on MPI ranks: each rank's blocks (one run in block order) are
/// gathered, and rank 0 writes them in rank order, which is block order.
fn write_generation_ranks(
    files: &CheckpointFiles,
    u: &dyn BlockStore<f64>,
    g: usize,
    w: &dyn Decomposition,
) -> Result<(String, u64), GridError> {
    let mut mine = Vec::new();
    for block in w.owned(u.spec()) {
        for v in u.read_block(block)? {
            mine.extend_from_slice(&v.to_le_bytes());
        }
    }
    let parts = w.all_gather_bytes(mine)?;
    let mut sha = Sha256::new();
    let mut len = 0u64;
    for p in &parts {
        sha.update(p);
        len += p.len() as u64;
    }
    if w.is_root() {
        let path = &files.generation_path(g);
        let mut out = files.create_generation(g).map_err(io_err(path))?;
        for p in &parts {
            out.write_all(p).map_err(io_err(path))?;
        }
        out.finish().map_err(io_err(path))?;
    }
    Ok((hex(&sha.finalize()), len))
}

/// Check the generation `m` names against it (length and sha256).
fn verify(files: &CheckpointFiles, m: &Manifest) -> Result<(), String> {
    let path = files.generation_path(m.generation);
    let len = files
        .generation_len(m.generation)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    if len != m.bytes {
        return Err(format!(
            "{}: {} bytes, the manifest says {} (torn write)",
            path.display(),
            len,
            m.bytes
        ));
    }
    let mut r = files
        .open_generation(m.generation)
        .map_err(|e| e.to_string())?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let k = r.read(&mut buf).map_err(|e| e.to_string())?;
        if k == 0 {
            break;
        }
        h.update(&buf[..k]);
    }
    if hex(&h.finalize()) != m.sha256 {
        return Err(format!("{}: checksum mismatch (damaged)", path.display()));
    }
    Ok(())
}

/// Read the generation `m` names into `u`.
fn read_generation(
    files: &CheckpointFiles,
    u: &dyn BlockStore<f64>,
    m: &Manifest,
) -> Result<(), GridError> {
    let path = &files.generation_path(m.generation);
    let mut input = files.open_generation(m.generation).map_err(io_err(path))?;
    // On MPI ranks each keeps the blocks it owns (the caller exchanges the halos).
    let w = world();
    for block in u.spec().block_indices() {
        let len = crate::math::volume(u.spec().block_shape(block)) as usize;
        let mut bytes = vec![0u8; len * 8];
        input.read_exact(&mut bytes).map_err(io_err(path))?;
        if !w.owns(u.spec(), block) {
            continue;
        }
        let values: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        u.write_block(block, &values)?;
    }
    Ok(())
}

/// The checkpoints of one solve.
pub struct Checkpoints {
    /// Their files ([`RunDir::checkpoint_files`]).
    pub files: CheckpointFiles,
    /// What they must match ([`identity`]).
    pub identity: String,
    /// Checkpoints written by this solve.
    pub written: u64,
}

impl Checkpoints {
    /// The newest whole checkpoint: the manifest, or the previous one when the newest
    /// generation is damaged. Errors when none matches this run and options.
    pub fn latest(&self, progress: &dyn Progress) -> Result<Manifest, SolveError> {
        let bad = |reason: String| SolveError::Checkpoint {
            path: self.files.path().to_owned(),
            reason,
        };
        let mut why = Vec::new();
        for name in ["manifest.json", "manifest.prev.json"] {
            let Some(m) = load(&self.files, name) else {
                why.push(format!("{name}: missing or unreadable"));
                continue;
            };
            if m.format != CHECKPOINT_FORMAT {
                return Err(bad(format!(
                    "{name} is checkpoint format {}, this harmap writes {CHECKPOINT_FORMAT}; run without --resume to start over",
                    m.format
                )));
            }
            if m.identity != self.identity {
                return Err(bad(format!(
                    "{name} was made for other labels or other solve options; run without --resume to start over"
                )));
            }
            match verify(&self.files, &m) {
                Ok(()) => {
                    if name != "manifest.json" {
                        progress.warn(&format!(
                            "the newest checkpoint is damaged ({}); resuming from the previous one",
                            why.join("; ")
                        ));
                    }
                    return Ok(m);
                }
                Err(e) => why.push(e),
            }
        }
        Err(bad(format!("no usable checkpoint: {}", why.join("; "))))
    }

    /// Read the state of checkpoint `m` (from [`Checkpoints::latest`]) into `u`.
    pub fn read(&self, u: &dyn BlockStore<f64>, m: &Manifest) -> Result<(), GridError> {
        read_generation(&self.files, u, m)
    }

    /// Write the state `u` with `hist` as a new checkpoint.
    pub fn write(&mut self, u: &dyn BlockStore<f64>, hist: &History) -> Result<(), crate::Error> {
        let current = load(&self.files, "manifest.json").map(|m| m.generation);
        let generation = match current {
            Some(0) => 1,
            _ => 0,
        };
        let (sha256, bytes) = write_generation(&self.files, u, generation)?;
        // Resuming loads the state into generation 0 and measures its residual again.
        let mut h = hist.clone();
        h.cur = 0;
        h.residual.pop();
        let m = Manifest {
            format: CHECKPOINT_FORMAT,
            identity: self.identity.clone(),
            generation,
            sha256,
            bytes,
            history: h,
        };
        let w = world();
        if w.is_root() {
            self.files
                .commit_manifest(serde_json::to_string_pretty(&m).expect("json").as_bytes())?;
        }
        w.barrier()?;
        self.written += 1;
        Ok(())
    }
}
