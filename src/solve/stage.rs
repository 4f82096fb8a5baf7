//! `harmap solve`: phi on a voxelized run, out of core, with checkpoints.
//!
//! The solver's stores live in `RUN/solve/`: scratch files of the levels that do not fit
//! the budget, and the checkpoints — two generation files `g0.bin`, `g1.bin` and
//! `manifest.json` (the previous one kept as `manifest.prev.json`). A checkpoint writes
//! the state to the generation the current manifest does not name, fsyncs it, then
//! commits a new manifest atomically; a torn or damaged generation fails its checksum and
//! the previous manifest is used. The state is u = 1 - phi (see [`super::dirichlet`]).
//! When the solve finishes, phi and u are written to `RUN/phi.partial/` and
//! `RUN/u.partial/` and renamed into place, the stage is recorded, and `RUN/solve/` is
//! removed.

use std::fs;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use serde_json::json;
use sha2::{Digest, Sha256};

use super::driver::{initialize, Decision, History, Iteration, Method, StopReason};
use super::multigrid::{
    coarse_level_bytes, coarse_specs, worker_bytes, CycleOptions, Hierarchy, Level, Scratch,
    StoreMaker,
};
use crate::grid::{human, BlockStore, Compression, GridError, GridSpec, MemBudget};
use crate::progress::Progress;
use crate::run::{write_atomic, RunDir};

/// Options of `harmap solve`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveOptions {
    /// The iteration.
    pub method: Method,
    /// The paper's zeta: stop when the largest change of an iteration is below it (0:
    /// off).
    pub tol: f64,
    /// Stop when `||r||_2 / ||r_0||_2` is below it (0: off).
    pub rtol: f64,
    /// Spacing of the exterior layers' values `1 + k eps`.
    pub eps: f64,
    /// Iteration limit (cycles for multigrid, sweeps otherwise).
    pub max_iter: u64,
    /// SOR factor (`None`: the optimum for the grid).
    pub omega: Option<f64>,
    /// Multigrid cycle.
    pub cycle: CycleOptions,
    /// Relaxing the tiny values after the solve.
    pub polish: super::polish::PolishOptions,
    /// Memory budget.
    #[serde(skip)]
    pub mem: MemBudget,
    /// Seconds between checkpoints (0: only on interruption).
    #[serde(skip)]
    pub checkpoint_every: f64,
    /// Continue from the last checkpoint.
    #[serde(skip)]
    pub resume: bool,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            method: Method::Multigrid,
            tol: 0.0,
            rtol: 1e-6,
            eps: 1e-4,
            max_iter: 1000,
            omega: None,
            cycle: CycleOptions::default(),
            polish: super::polish::PolishOptions::default(),
            mem: MemBudget::default(),
            checkpoint_every: 300.0,
            resume: false,
        }
    }
}

/// Errors of the solve stage.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// Options that cannot work.
    #[error("{0}")]
    Options(String),
    /// `--resume` with no usable checkpoint, or one made for other inputs or options.
    #[error("{}: {reason}", path.display())]
    Checkpoint {
        /// The checkpoint directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Stopped by a signal while polishing the tiny values, after the iterations; the
    /// state checkpointed last (if any) is kept.
    #[error("interrupted while polishing the tiny values after {iterations} iterations; {then}")]
    InterruptedPolish {
        /// Iterations done.
        iterations: u64,
        /// What to do now.
        then: String,
    },
    /// Stopped by a signal after writing a checkpoint.
    #[error("interrupted after {iterations} iterations; the state is checkpointed in {}; continue with `harmap solve {} --resume`", path.display(), run.display())]
    Interrupted {
        /// Iterations done.
        iterations: u64,
        /// The checkpoint directory.
        path: PathBuf,
        /// The run.
        run: PathBuf,
    },
}

impl SolveError {
    /// Whether the user's options or files are at fault (exit code 2).
    #[must_use]
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SolveError::Options(_) | SolveError::Checkpoint { .. })
    }
}

/// What the solve did, as recorded in the run's attributes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveReport {
    /// The method.
    pub method: Method,
    /// Iterations (cycles or sweeps).
    pub iterations: u64,
    /// Why it stopped.
    pub stopped_by: StopReason,
    /// Final `||r||_2 / ||r_0||_2`.
    pub relative_residual: f64,
    /// Largest change of the last iteration.
    pub max_change: f64,
    /// `||r||_2 / ||r_0||_2` per iterate.
    pub residual_history: Vec<f64>,
    /// Largest change per iteration.
    pub max_change_history: Vec<f64>,
    /// Unknowns (interior voxels).
    pub unknowns: u64,
    /// Level shapes (multigrid).
    pub levels: Vec<[u64; 3]>,
    /// Work in fine-grid sweep equivalents.
    pub sweep_equivalents: f64,
    /// Iterations done before a resume, if resumed.
    pub resumed_at: Option<u64>,
    /// Checkpoints written.
    pub checkpoints: u64,
    /// Blocks in flight.
    pub workers: usize,
    /// Levels held in memory (the rest in scratch files).
    pub in_memory: Vec<bool>,
    /// The relaxation of tiny values after the solve.
    pub polish: super::polish::PolishReport,
}

/// Version of the checkpoint files (2: the state is u = 1 - phi).
const CHECKPOINT_FORMAT: u32 = 2;

#[derive(Debug, Serialize, Deserialize)]
struct Manifest {
    format: u32,
    identity: String,
    generation: usize,
    sha256: String,
    bytes: u64,
    history: History,
}

/// The identity a checkpoint must match: the labels' provenance and the options that
/// change the iterates.
fn identity(run: &RunDir, opts: &SolveOptions) -> Result<String, crate::Error> {
    let a = run.attrs()?;
    let v = json!({
        "grid": a.get("grid"),
        "input": a.get("input"),
        "center": a.get("center"),
        "voxelize": a.pointer("/stages/voxelize/options"),
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

/// Write every block of `u` (block order, true extents, f64 little-endian) to `path`,
/// fsync it, and return its sha256 and length.
fn write_generation(u: &dyn BlockStore<f64>, path: &Path) -> Result<(String, u64), GridError> {
    let f = fs::File::create(path).map_err(io_err(path))?;
    let mut w = BufWriter::with_capacity(1 << 20, f);
    let mut h = Sha256::new();
    let mut n = 0u64;
    let mut buf = Vec::new();
    for b in u.spec().block_indices() {
        buf.clear();
        for v in u.read_block(b)? {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        h.update(&buf);
        w.write_all(&buf).map_err(io_err(path))?;
        n += buf.len() as u64;
    }
    let f = w.into_inner().map_err(|e| io_err(path)(e.into_error()))?;
    f.sync_all().map_err(io_err(path))?;
    Ok((hex(&h.finalize()), n))
}

/// Check a generation file against its manifest (length and sha256).
fn verify_generation(path: &Path, m: &Manifest) -> Result<(), String> {
    let meta = fs::metadata(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if meta.len() != m.bytes {
        return Err(format!(
            "{}: {} bytes, the manifest says {} (torn write)",
            path.display(),
            meta.len(),
            m.bytes
        ));
    }
    let mut r = BufReader::new(fs::File::open(path).map_err(|e| e.to_string())?);
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

fn read_generation(u: &dyn BlockStore<f64>, path: &Path) -> Result<(), GridError> {
    let mut r = BufReader::with_capacity(1 << 20, fs::File::open(path).map_err(io_err(path))?);
    for b in u.spec().block_indices() {
        let n = crate::math::volume(u.spec().block_shape(b)) as usize;
        let mut bytes = vec![0u8; n * 8];
        r.read_exact(&mut bytes).map_err(io_err(path))?;
        let v: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        u.write_block(b, &v)?;
    }
    Ok(())
}

/// Checkpoints in a directory.
struct Checkpoints {
    dir: PathBuf,
    identity: String,
    written: u64,
}

impl Checkpoints {
    fn manifest(&self) -> PathBuf {
        self.dir.join("manifest.json")
    }

    fn load(path: &Path) -> Option<Manifest> {
        serde_json::from_slice(&fs::read(path).ok()?).ok()
    }

    /// The newest whole checkpoint: the manifest, or the previous one when the newest
    /// generation is damaged. Errors when none matches this run and options.
    fn latest(&self, progress: &dyn Progress) -> Result<Manifest, SolveError> {
        let bad = |reason: String| SolveError::Checkpoint {
            path: self.dir.clone(),
            reason,
        };
        let mut why = Vec::new();
        for name in ["manifest.json", "manifest.prev.json"] {
            let p = self.dir.join(name);
            let Some(m) = Self::load(&p) else {
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
            match verify_generation(&self.dir.join(format!("g{}.bin", m.generation)), &m) {
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

    /// Write the state `u` with `hist` as a new checkpoint.
    fn write(&mut self, u: &dyn BlockStore<f64>, hist: &History) -> Result<(), crate::Error> {
        let current = Self::load(&self.manifest()).map(|m| m.generation);
        let generation = match current {
            Some(0) => 1,
            _ => 0,
        };
        let g = self.dir.join(format!("g{generation}.bin"));
        let (sha256, bytes) = write_generation(u, &g)?;
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
        if self.manifest().exists() {
            let prev = self.dir.join("manifest.prev.json");
            fs::copy(self.manifest(), &prev)
                .map_err(io_err(&prev))
                .map_err(crate::Error::from)?;
        }
        write_atomic(
            &self.manifest(),
            serde_json::to_string_pretty(&m).expect("json").as_bytes(),
        )?;
        self.written += 1;
        Ok(())
    }
}

/// Which levels (0 = finest; arrays: mask, generations) live in memory, and how many
/// blocks are in flight, under `mem`.
fn plan_memory(
    fine: &GridSpec,
    coarse: &[GridSpec],
    cycle: &CycleOptions,
    mem: MemBudget,
) -> Result<(Vec<bool>, usize), GridError> {
    let halo = 2 * cycle.pre.max(cycle.post).max(1) as u64 + 2;
    let per_worker = worker_bytes(fine.chunk, halo);
    let threads = rayon::current_num_threads();
    // At least one worker must fit; keep room for as many as there are threads.
    let workers = mem.workers(
        "the solve (one block with its halo)",
        0,
        per_worker,
        threads,
    )?;
    let mut avail = mem.work_bytes().saturating_sub(workers as u64 * per_worker);
    let mut in_memory = vec![false; coarse.len() + 1];
    for (k, s) in coarse.iter().enumerate().rev() {
        let b = coarse_level_bytes(s) + super::flat::pass_bytes(s, threads);
        if b <= avail {
            avail -= b;
            in_memory[k + 1] = true;
        } else {
            break;
        }
    }
    // The finest level: labels and two generations of f64.
    let fine_bytes = fine.num_voxels() * 17 + super::flat::pass_bytes(fine, threads);
    if in_memory.iter().skip(1).all(|&m| m) && fine_bytes <= avail {
        in_memory[0] = true;
    }
    Ok((in_memory, workers))
}

/// Solve for phi on the voxelized run `run` and store it in `RUN/phi/0`.
///
/// `stop` is polled between iterations (the CLI sets it on SIGINT/SIGTERM): the state
/// is checkpointed and [`SolveError::Interrupted`] returned.
pub fn solve(
    run: &RunDir,
    opts: &SolveOptions,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<SolveReport, crate::Error> {
    let t0 = Instant::now();
    if !(opts.eps > 0.0 && opts.eps < 0.01) {
        return Err(options(format!(
            "--eps {} must be positive and below 0.01 (the paper uses 1e-4)",
            opts.eps
        )));
    }
    if !(opts.rtol >= 0.0 && opts.tol >= 0.0) || (opts.rtol == 0.0 && opts.tol == 0.0) {
        return Err(options(
            "give a positive --rtol or --tol (both 0 would never stop)".into(),
        ));
    }
    if opts.omega.is_some_and(|w| !(w > 0.0 && w < 2.0)) {
        return Err(options("--omega must lie in (0, 2)".into()));
    }
    let _lock = run.lock()?;
    run.require_stage("voxelize")?;
    let spec = run.grid()?;
    let labels = run.open_image::<u8>("labels")?;
    let dir = run.root().join("solve");
    let scratch_dir = dir.join("scratch");
    if scratch_dir.exists() {
        fs::remove_dir_all(&scratch_dir).map_err(io_err(&scratch_dir))?;
    }
    fs::create_dir_all(&scratch_dir).map_err(io_err(&scratch_dir))?;
    let maker = Scratch {
        dir: scratch_dir.clone(),
    };
    let coarse = if opts.method == Method::Multigrid {
        coarse_specs(&spec, opts.cycle.coarsest)
    } else {
        Vec::new()
    };
    let (in_memory, workers) = plan_memory(&spec, &coarse, &opts.cycle, opts.mem)?;
    progress.info(&format!(
        "solve: {} levels, in memory {:?}, {workers} blocks in flight, budget {}",
        coarse.len() + 1,
        in_memory,
        human(opts.mem.0)
    ));

    // The finest level: a scratch copy of the labels (cheap halo reads) and two
    // generations of phi.
    let mem0 = in_memory[0];
    let mask = maker.make::<u8>("labels", &spec, mem0, 0)?;
    super::driver::copy_blocks(&labels, &*mask, workers)?;
    let fine = Level {
        spec: spec.clone(),
        mask,
        u: [
            maker.make::<f64>("phi_a", &spec, mem0, 0.0)?,
            maker.make::<f64>("phi_b", &spec, mem0, 0.0)?,
        ],
        f: None,
        flat: super::flat::Cache::default(),
    };
    let h = Hierarchy::build(
        fine,
        opts.cycle,
        &maker,
        |k, _| in_memory.get(k).copied().unwrap_or(false),
        workers,
    )?;
    let it = Iteration::new(&h, opts.method, opts.omega);
    let t_setup = t0.elapsed().as_secs_f64();

    let mut ck = Checkpoints {
        dir: dir.clone(),
        identity: identity(run, opts)?,
        written: 0,
    };
    let mut hist = History::default();
    let mut resumed_at = None;
    if opts.resume {
        let m = ck.latest(progress).map_err(crate::Error::from)?;
        read_generation(
            &*h.levels[0].u[0],
            &dir.join(format!("g{}.bin", m.generation)),
        )?;
        h.levels[0].flat.state_replaced();
        hist = m.history;
        resumed_at = Some(hist.iterations);
        progress.info(&format!("resuming after {} iterations", hist.iterations));
    } else {
        for name in ["manifest.json", "manifest.prev.json", "g0.bin", "g1.bin"] {
            let _ = fs::remove_file(dir.join(name));
        }
        initialize(&h.levels[0], opts.eps, workers)?;
        h.levels[0].flat.state_replaced();
    }

    let label = format!("solve: {}", opts.method.name());
    progress.start(&label, 0);
    let mut last_ck = Instant::now();
    let mut ck_err: Option<crate::Error> = None;
    let mut interrupted = false;
    let why = it.run(&mut hist, |hs| {
        let rel = *hs.residual.last().unwrap_or(&1.0);
        let k = hs.iterations;
        // Residual, its rate of decrease, and the iterations still needed at that rate.
        let n = hs.residual.len();
        let rate = if n >= 3 {
            (hs.residual[n - 1] / hs.residual[n - 3]).sqrt()
        } else if n == 2 {
            hs.residual[1]
        } else {
            f64::NAN
        };
        if opts.rtol > 0.0 && rate > 0.0 && rate < 1.0 && rel > opts.rtol {
            let left = ((opts.rtol / rel).ln() / rate.ln()).ceil().max(1.0) as u64;
            progress.set_total(k + left);
        }
        progress.set_position(k);
        progress.message(&format!(
            "{label}  residual {rel:.2e}  x{rate:.3}/iteration"
        ));
        let d = if opts.rtol > 0.0 && rel < opts.rtol {
            Decision::Stop(StopReason::Residual)
        } else if opts.tol > 0.0 && hs.max_change.last().is_some_and(|&c| c < opts.tol) {
            Decision::Stop(StopReason::MaxChange)
        } else if k >= opts.max_iter {
            Decision::Stop(StopReason::IterationLimit)
        } else if stop.load(Ordering::SeqCst) {
            interrupted = true;
            Decision::Stop(StopReason::Interrupted)
        } else {
            Decision::Continue
        };
        let periodic = opts.checkpoint_every > 0.0
            && last_ck.elapsed().as_secs_f64() >= opts.checkpoint_every
            && matches!(d, Decision::Continue);
        if periodic || interrupted {
            // The state is whole in generation `cur` at this point.
            if let Err(e) = ck.write(&*h.levels[0].u[hs.cur], hs) {
                ck_err = Some(e);
                return Ok(Decision::Stop(StopReason::Interrupted));
            }
            last_ck = Instant::now();
        }
        Ok(d)
    })?;
    progress.finish();
    let t_iter = t0.elapsed().as_secs_f64();
    if let Some(e) = ck_err {
        return Err(e);
    }
    if why == StopReason::Interrupted {
        return Err(SolveError::Interrupted {
            iterations: hist.iterations,
            path: dir,
            run: run.root().to_owned(),
        }
        .into());
    }

    // Relative accuracy where u is tiny (thin parts of the shape).
    progress.start("solve: polishing tiny values", 0);
    let polish = super::polish::polish(
        &*h.levels[0].u[hist.cur],
        &*h.levels[0].mask,
        &opts.polish,
        opts.mem.work_bytes() / 2,
        workers,
        &|| stop.load(Ordering::SeqCst),
        progress,
    )?;
    progress.finish();
    if polish.interrupted {
        let then = if ck.written > 0 || resumed_at.is_some() {
            format!(
                "continue from the last checkpoint with `harmap solve {} --resume`",
                run.root().display()
            )
        } else {
            format!(
                "no checkpoint was written yet; start again with `harmap solve {}`",
                run.root().display()
            )
        };
        return Err(SolveError::InterruptedPolish {
            iterations: hist.iterations,
            then,
        }
        .into());
    }
    if polish.voxels > 0 {
        progress.info(&format!(
            "solve: polished {} tiny values in {} sweeps (last relative change {:.1e}); u < 0 at {} unknowns before, {} after",
            polish.voxels, polish.sweeps, polish.last_change, polish.negative[0], polish.negative[1]
        ));
    }

    let t_polish = t0.elapsed().as_secs_f64();
    // phi = 1 - u for users, and u itself (the precise one, for the stages after);
    // NaN outside the problem; staged then renamed into place.
    let out_phi = run.create_image_staged::<f64>("phi", &spec, f64::NAN, Compression::Zstd(1))?;
    let out_u = run.create_image_staged::<f64>("u", &spec, f64::NAN, Compression::None)?;
    let cur = &*h.levels[0].u[hist.cur];
    progress.start("solve: writing phi and u", spec.num_blocks());
    crate::parallel::map_bounded(&spec.block_indices(), workers, |&b| {
        let u = cur.read_block(b)?;
        out_u.write_block(b, &u)?;
        let phi: Vec<f64> = u.iter().map(|&v| 1.0 - v).collect();
        out_phi.write_block(b, &phi)?;
        progress.advance(1);
        Ok::<_, GridError>(())
    })?;
    progress.finish();
    let sweep_equivalents = it.sweeps_per_iteration() * hist.iterations as f64;
    drop(h);
    run.commit_image("u")?;
    run.commit_image("phi")?;
    let report = SolveReport {
        method: opts.method,
        iterations: hist.iterations,
        stopped_by: why,
        relative_residual: *hist.residual.last().unwrap_or(&0.0),
        max_change: hist.max_change.last().copied().unwrap_or(0.0),
        residual_history: hist.residual.clone(),
        max_change_history: hist.max_change.clone(),
        unknowns: hist.unknowns,
        levels: std::iter::once(spec.shape)
            .chain(coarse.iter().map(|s| s.shape))
            .collect(),
        sweep_equivalents,
        resumed_at,
        checkpoints: ck.written,
        workers,
        in_memory,
        polish,
    };
    let seconds = t0.elapsed().as_secs_f64();
    progress.info(&format!(
        "solve: seconds: setup {t_setup:.2}, {} {:.2}, polish {:.2}, writing {:.2}",
        opts.method.name(),
        t_iter - t_setup,
        t_polish - t_iter,
        seconds - t_polish
    ));
    run.record_stage("solve", seconds, opts, &report)?;
    let _ = fs::remove_dir_all(&dir);
    Ok(report)
}

fn options(msg: String) -> crate::Error {
    SolveError::Options(msg).into()
}
