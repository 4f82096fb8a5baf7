//! `harmap solve`: phi on a voxelized run, out of core, with checkpoints.
//!
//! The solver's stores live in `RUN/solve/`: scratch files of the levels that do not fit
//! the budget ([`super::plan`]), and the checkpoints ([`super::checkpoint`]). The state
//! is u = 1 - phi (see [`super::dirichlet`]). When the solve finishes, phi and u are
//! written to `RUN/phi.partial/` and `RUN/u.partial/` and renamed into place, the stage
//! is recorded, and `RUN/solve/` is removed.

use std::fs;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::blocks::BlockLoop;
use super::checkpoint::{identity, Checkpoints};
use super::coarsen::coarse_specs;
use super::cuts::fine_mask;
use super::deepen::DeepenReport;
use super::dirichlet::initialize;
use super::driver::{Decision, History, Iteration, Method, StopReason};
use super::error::SolveError;
use super::level::Level;
use super::multigrid::{held_share, pass_halo, Hierarchy, Scratch};
use super::options::SolveOptions;
use super::plan::plan_memory;
use super::polish::{PolishOptions, PolishReport};
use super::report::SolveReport;
use crate::grid::{human, BlockStore, Compression, Decomposition, GridError, GridSpec, Reach};
use crate::progress::Progress;
use crate::run::RunDir;
use crate::voxelize::cuts::NAME as CUTS;

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
    solve_with(run, opts, crate::grid::world(), stop, progress)
}

/// [`solve`] as one part of a decomposition: this process relaxes the blocks
/// `decomp` gives it and exchanges halos through it (see the module docs of
/// [`crate::solve`]). With [`Whole`](crate::grid::Whole) it is [`solve`].
pub fn solve_with(
    run: &RunDir,
    opts: &SolveOptions,
    decomp: &dyn Decomposition,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<SolveReport, crate::Error> {
    let t0 = Instant::now();
    check_options(opts)?;
    let _lock = run.lock()?;
    let _staged = run.staged_images(&["phi", "u"]);
    run.require_stage("voxelize")?;
    let spec = run.grid()?;
    let dir = run.checkpoint_dir();
    let mut setup = build(run, &spec, opts, decomp, &dir, progress)?;
    let h = &setup.h;
    let it = Iteration::new(h, opts.method, opts.omega);
    let t_setup = t0.elapsed().as_secs_f64();

    let mut ck = Checkpoints {
        files: run.checkpoint_files(),
        identity: identity(run, opts)?,
        written: 0,
    };
    let (mut hist, resumed_at) = start(h, opts, &ck, progress)?;
    let why = iterate(&it, opts, &mut hist, &mut ck, stop, progress)?;
    let t_iter = t0.elapsed().as_secs_f64();
    if why == StopReason::Interrupted {
        return Err(SolveError::Interrupted {
            iterations: hist.iterations,
            path: dir,
            run: run.root().to_owned(),
        }
        .into());
    }
    let (work, cycle_work) = (it.work(&hist), it.sweeps_per_iteration());
    let checkpointed = ck.written > 0 || resumed_at.is_some();
    let deep = deepen_tiny(
        run,
        &mut setup.h,
        opts,
        &hist,
        cycle_work,
        checkpointed,
        stop,
        progress,
    )?;
    let h = &setup.h;
    let t_deepen = t0.elapsed().as_secs_f64();
    // Without stages, all of the tiny values from 0; after them, what is below the
    // last stage's reach, from the values it left, down to far smaller values (the
    // stages no longer carry the deep pockets' values down to the floor's neighbours).
    let polish_opts = match deep.stages.last() {
        None => opts.polish,
        Some(s) => PolishOptions {
            threshold: s.threshold * opts.deepen.factor,
            floor: DEEP_FLOOR,
            from_values: true,
            ..opts.polish
        },
    };
    let polish = polish_tiny(
        run,
        h,
        opts,
        &polish_opts,
        &hist,
        checkpointed,
        stop,
        progress,
    )?;
    let t_polish = t0.elapsed().as_secs_f64();
    write_phi(run, &spec, &*h.levels[0].u[hist.cur], &h.blocks, progress)?;
    let report = SolveReport {
        method: opts.method,
        iterations: hist.iterations,
        stopped_by: why,
        relative_residual: *hist.residual.last().unwrap_or(&0.0),
        max_change: hist.max_change.last().copied().unwrap_or(0.0),
        residual_history: hist.residual.clone(),
        max_change_history: hist.max_change.clone(),
        unknowns: hist.unknowns,
        levels: setup.levels,
        sweep_equivalents: work + deep.sweep_equivalents,
        resumed_at,
        checkpoints: ck.written,
        workers: h.blocks.workers,
        in_memory: setup.in_memory,
        deepen: deep,
        polish,
    };
    // The scratch stores go before phi and u are renamed into place.
    drop(setup.h);
    run.commit_image("u")?;
    run.commit_image("phi")?;
    let seconds = t0.elapsed().as_secs_f64();
    progress.info(&format!(
        "solve: seconds: setup {t_setup:.2}, {} {:.2}, deepen {:.2}, polish {:.2}, writing {:.2}",
        opts.method.name(),
        t_iter - t_setup,
        t_deepen - t_iter,
        t_polish - t_deepen,
        seconds - t_polish
    ));
    run.record_stage("solve", seconds, opts, &report)?;
    if decomp.is_root() {
        let _ = fs::remove_dir_all(&dir);
    }
    Ok(report)
}

fn options(msg: String) -> crate::Error {
    SolveError::Options(msg).into()
}

/// Refuse options that cannot work, before anything is touched.
fn check_options(opts: &SolveOptions) -> Result<(), crate::Error> {
    if !(opts.eps > 0.0 && opts.eps < 0.01) {
        return Err(options(format!(
            "--eps {} must be positive and below 0.01 (the paper uses 1e-4)",
            opts.eps
        )));
    }
    let rtol = opts.rtol;
    if !(rtol >= 0.0 && opts.tol >= 0.0)
        || (rtol == 0.0 && opts.tol == 0.0 && !opts.stops_at_discretization())
    {
        return Err(options(
            "give a positive --rtol or --tol (both 0 would never stop)".into(),
        ));
    }
    if opts.omega.is_some_and(|w| !(w > 0.0 && w < 2.0)) {
        return Err(options("--omega must lie in (0, 2)".into()));
    }
    Ok(())
}

/// The levels of a solve and where they live.
struct Setup<'d> {
    h: Hierarchy<'d>,
    /// The shapes of the levels the method uses (the finest alone for SOR and Jacobi).
    levels: Vec<[u64; 3]>,
    in_memory: Vec<bool>,
}

/// A fresh scratch directory `dir/scratch` (`dir/scratch.K` on MPI rank K of several).
fn scratch_dir(dir: &Path, decomp: &dyn Decomposition) -> Result<Scratch, GridError> {
    let scratch = if decomp.parts() > 1 {
        dir.join(format!("scratch.{}", decomp.part()))
    } else {
        dir.join("scratch")
    };
    let io = |source| GridError::Io {
        path: scratch.clone(),
        source,
    };
    if scratch.exists() {
        fs::remove_dir_all(&scratch).map_err(io)?;
    }
    fs::create_dir_all(&scratch).map_err(io)?;
    Ok(Scratch { dir: scratch })
}

/// Plan the memory and build the levels: the finest from the run's labels, the coarse
/// ones (multigrid) from it.
fn build<'d>(
    run: &RunDir,
    spec: &GridSpec,
    opts: &SolveOptions,
    decomp: &'d dyn Decomposition,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<Setup<'d>, crate::Error> {
    crate::grid::release_freed_memory();
    let labels = run.open_image::<u8>("labels")?;
    // Mesh runs carry the arms of the sub-voxel boundary; others solve on the staircase.
    let cuts = if run.root().join(CUTS).join("0").join("zarr.json").exists() {
        Some(run.open_image::<u64>(CUTS)?)
    } else {
        None
    };
    let maker = scratch_dir(dir, decomp)?;
    let coarse = if opts.method == Method::Multigrid {
        coarse_specs(spec, opts.cycle.coarsest)
    } else {
        Vec::new()
    };
    let halo = pass_halo(&opts.cycle);
    let levels: Vec<GridSpec> = std::iter::once(spec.clone())
        .chain(coarse.iter().cloned())
        .collect();
    // On ranks each holds its slab of a level and the planes it receives: the budget
    // is per rank, so it counts the largest such share.
    let held = |k: usize| held_share(&levels, k, halo, decomp);
    let (in_memory, workers) =
        plan_memory(spec, &coarse, &opts.cycle, opts.mem, cuts.is_some(), held)?;
    progress.info(&format!(
        "solve: {} levels, in memory {:?}, {workers} blocks in flight, budget {}",
        coarse.len() + 1,
        in_memory,
        human(opts.mem.0)
    ));
    let blocks = BlockLoop { workers, decomp };

    // The finest level: a scratch copy of the labels (cheap halo reads), with the
    // unknowns of the sub-voxel boundary marked where there are cuts, their arms, and
    // two generations of phi.
    let mem0 = in_memory[0];
    let mask = maker.make::<u8>("labels", spec, mem0, 0)?;
    let arms = if let Some(c) = &cuts {
        let arms = maker.make::<u64>("cuts", spec, mem0, 0)?;
        blocks.each(spec, |b| {
            let (l, p) = (labels.read_block(b)?, c.read_block(b)?);
            arms.write_block(b, &p)?;
            let m: Vec<u8> = l.iter().zip(&p).map(|(&l, &p)| fine_mask(l, p)).collect();
            mask.write_block(b, &m)
        })?;
        blocks.exchange("cuts@0", &*arms, &Reach::Halo(halo))?;
        Some(arms)
    } else {
        blocks.each(spec, |b| mask.write_block(b, &labels.read_block(b)?))?;
        None
    };
    let fine = Level {
        spec: spec.clone(),
        mask,
        u: [
            maker.make::<f64>("phi_a", spec, mem0, 0.0)?,
            maker.make::<f64>("phi_b", spec, mem0, 0.0)?,
        ],
        f: None,
        cuts: arms,
        flat: super::flat::Cache::default(),
        depth: 0,
        halo,
        reach: Reach::Halo(halo),
        // On ranks a level in memory runs its whole-array passes on the rank's slab.
        slab: (mem0 && !blocks.owns_all())
            .then(|| super::multigrid::slab_of(spec, &Reach::Halo(halo), decomp)),
    };
    blocks.exchange(&fine.field("mask"), &*fine.mask, &fine.reach)?;
    let h = Hierarchy::build(
        fine,
        opts.cycle,
        &maker,
        |k, _| in_memory.get(k).copied().unwrap_or(false),
        blocks,
    )?;
    let levels = std::iter::once(spec.shape)
        .chain(coarse.iter().map(|s| s.shape))
        .collect();
    Ok(Setup {
        h,
        levels,
        in_memory,
    })
}

/// The starting state: the last checkpoint with `--resume`, else the initial values.
/// Returns the history to continue and the iterations done before a resume.
fn start(
    h: &Hierarchy<'_>,
    opts: &SolveOptions,
    ck: &Checkpoints,
    progress: &dyn Progress,
) -> Result<(History, Option<u64>), crate::Error> {
    let fine = &h.levels[0];
    let out = if opts.resume {
        let m = ck.latest(progress).map_err(crate::Error::from)?;
        ck.read(&*fine.u[0], &m)?;
        // On MPI ranks each read its own blocks: the halos come from the others.
        h.blocks
            .exchange(&fine.field("u0"), &*fine.u[0], &fine.reach)?;
        let hist = m.history;
        progress.info(&format!("resuming after {} iterations", hist.iterations));
        let at = Some(hist.iterations);
        (hist, at)
    } else {
        ck.files.clear();
        initialize(fine, opts.eps, &h.blocks)?;
        (History::default(), None)
    };
    fine.flat.state_replaced();
    Ok(out)
}

/// Whether to stop after the measurement `hs`: the criteria, the iteration limit, a
/// request to stop (`interrupted`).
fn decide(opts: &SolveOptions, hs: &History, stop: &AtomicBool) -> Decision {
    let rel = *hs.residual.last().unwrap_or(&1.0);
    let rtol = opts.rtol;
    if rtol > 0.0 && rel < rtol {
        Decision::Stop(StopReason::Residual)
    } else if opts.stops_at_discretization() && discretization_reached(hs) {
        Decision::Stop(StopReason::Discretization)
    } else if opts.tol > 0.0 && hs.max_change.last().is_some_and(|&c| c < opts.tol) {
        Decision::Stop(StopReason::MaxChange)
    } else if hs.iterations >= opts.max_iter {
        Decision::Stop(StopReason::IterationLimit)
    } else if stop.load(Ordering::SeqCst) {
        Decision::Stop(StopReason::Interrupted)
    } else {
        Decision::Continue
    }
}

/// Full multigrid's stop: the algebraic error is small against the discretization
/// error.
///
/// The first V-cycle on the finest level (`max_change[1]`; `max_change[0]` is the
/// coarse phase) moves the interpolated solution of the level below to this level's:
/// its largest change `d1` is the difference of the two finest levels' solutions, about
/// three times the finest level's discretization error for a second-order scheme. Later
/// cycles change the iterate by `d` at a rate `rho = d / d_prev`, which leaves an
/// algebraic error of about `d rho / (1 - rho)`; the solve stops when that is below a
/// tenth of the discretization error, `d1 / 30`.
///
/// The trace needs more where u is tiny: the polish ([`super::polish`]) gives the
/// values below its threshold relative accuracy only when the values around them are
/// right to well within it, which the default residual target (1e-6) gives and this
/// criterion does not.
#[must_use]
pub fn discretization_reached(hs: &History) -> bool {
    match algebraic_error(hs) {
        Some(e) => e <= hs.max_change[1] / 30.0,
        None => false,
    }
}

/// The algebraic error (largest, over the unknowns) that full multigrid's V-cycles
/// leave, `d rho / (1 - rho)` from the last two cycles' largest changes; `None` before
/// two V-cycles on the finest level, or when they do not converge.
#[must_use]
pub fn algebraic_error(hs: &History) -> Option<f64> {
    let c = &hs.max_change;
    if !hs.fmg || c.len() < 3 {
        return None;
    }
    let (prev, d) = (c[c.len() - 2], c[c.len() - 1]);
    let rho = d / prev;
    (rho < 1.0).then(|| d * rho / (1.0 - rho))
}

/// Show the residual, its rate of decrease, and the iterations still needed at that
/// rate.
fn show(progress: &dyn Progress, label: &str, rtol: f64, hs: &History) {
    let rel = *hs.residual.last().unwrap_or(&1.0);
    let k = hs.iterations;
    let n = hs.residual.len();
    let rate = if n >= 3 {
        (hs.residual[n - 1] / hs.residual[n - 3]).sqrt()
    } else if n == 2 {
        hs.residual[1]
    } else {
        f64::NAN
    };
    if rtol > 0.0 && rate > 0.0 && rate < 1.0 && rel > rtol {
        let left = ((rtol / rel).ln() / rate.ln()).ceil().max(1.0) as u64;
        progress.set_total(k + left);
    }
    progress.set_position(k);
    progress.message(&format!(
        "{label}  residual {rel:.2e}  x{rate:.3}/iteration"
    ));
}

/// Iterate until a criterion, the limit or `stop`; checkpoint every
/// `opts.checkpoint_every` seconds and when stopped.
fn iterate(
    it: &Iteration<'_>,
    opts: &SolveOptions,
    hist: &mut History,
    ck: &mut Checkpoints,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<StopReason, crate::Error> {
    let label = format!("solve: {}", opts.method.name());
    progress.start(&label, 0);
    let mut last_ck = Instant::now();
    let mut ck_err: Option<crate::Error> = None;
    let why = it.run(hist, |hs| {
        show(progress, &label, opts.rtol, hs);
        let d = decide(opts, hs, stop);
        let interrupted = matches!(d, Decision::Stop(StopReason::Interrupted));
        let periodic = opts.checkpoint_every > 0.0
            && last_ck.elapsed().as_secs_f64() >= opts.checkpoint_every
            && matches!(d, Decision::Continue);
        // MPI ranks agree: a stop request on any rank stops all, and rank 0's clock
        // says when to checkpoint.
        let (d, interrupted, periodic) = agree(it.h.blocks.decomp, d, interrupted, periodic)?;
        if periodic || interrupted {
            // The state is whole in generation `cur` at this point.
            if let Err(e) = ck.write(&*it.h.levels[0].u[hs.cur], hs) {
                ck_err = Some(e);
                return Ok(Decision::Stop(StopReason::Interrupted));
            }
            last_ck = Instant::now();
        }
        Ok(d)
    })?;
    progress.finish();
    match ck_err {
        Some(e) => Err(e),
        None => Ok(why),
    }
}

/// The decision of every MPI rank after an iteration: stopped when any rank was asked
/// to stop, checkpointed when rank 0's clock says so. One process: as given.
fn agree(
    decomp: &dyn Decomposition,
    d: Decision,
    interrupted: bool,
    periodic: bool,
) -> Result<(Decision, bool, bool), GridError> {
    if decomp.parts() == 1 {
        return Ok((d, interrupted, periodic));
    }
    let all = decomp.all_gather_bytes(vec![u8::from(interrupted), u8::from(periodic)])?;
    let any_stop = all.iter().any(|v| v[0] == 1);
    let periodic = all[0][1] == 1;
    if any_stop && matches!(d, Decision::Continue) {
        return Ok((Decision::Stop(StopReason::Interrupted), true, false));
    }
    Ok((d, interrupted, periodic && !any_stop))
}

/// Relative accuracy where u is tiny (thin parts of the shape), after the iterations.
/// `checkpointed`: whether a checkpoint exists to resume from if stopped now.
#[allow(clippy::too_many_arguments)] // the run, the levels, the options, the threshold and the callbacks
fn polish_tiny(
    run: &RunDir,
    h: &Hierarchy<'_>,
    opts: &SolveOptions,
    polish_opts: &PolishOptions,
    hist: &History,
    checkpointed: bool,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<PolishReport, crate::Error> {
    progress.start("solve: polishing tiny values", 0);
    let fine = &h.levels[0];
    let polish = super::polish::polish(
        &*fine.u[hist.cur],
        &*fine.mask,
        fine.cuts.as_deref(),
        polish_opts,
        opts.mem.work_bytes() / 2,
        &h.blocks,
        &|| stop.load(Ordering::SeqCst),
        progress,
    )?;
    progress.finish();
    if polish.interrupted {
        return Err(interrupted_after(run, hist, checkpointed));
    }
    if polish.voxels > 0 {
        progress.info(&format!(
            "solve: polished {} tiny values in {} sweeps (last relative change {:.1e}); u < 0 at {} unknowns before, {} after",
            polish.voxels, polish.sweeps, polish.last_change, polish.negative[0], polish.negative[1]
        ));
    }
    Ok(polish)
}

/// The polish's floor after deepening: values below it count as converged (above the
/// subnormal numbers, whose relative precision is coarse).
const DEEP_FLOOR: f64 = 1e-290;

/// The error of a solve stopped after its iterations (deepening or polishing).
fn interrupted_after(run: &RunDir, hist: &History, checkpointed: bool) -> crate::Error {
    let then = if checkpointed {
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
    SolveError::InterruptedPolish {
        iterations: hist.iterations,
        then,
    }
    .into()
}

/// Relative accuracy where u is tiny, by multigrid on the regions below falling
/// thresholds ([`super::deepen`]), after the iterations (multigrid only).
#[allow(clippy::too_many_arguments)] // the run, the levels, the options and the callbacks
fn deepen_tiny(
    run: &RunDir,
    h: &mut Hierarchy<'_>,
    opts: &SolveOptions,
    hist: &History,
    cycle_work: f64,
    checkpointed: bool,
    stop: &AtomicBool,
    progress: &dyn Progress,
) -> Result<DeepenReport, crate::Error> {
    if opts.method != Method::Multigrid {
        return Ok(DeepenReport::default());
    }
    progress.start("solve: deepening tiny values", 0);
    let deep = super::deepen::deepen(
        h,
        &opts.deepen,
        cycle_work,
        &|| stop.load(Ordering::SeqCst),
        progress,
    )?;
    progress.finish();
    if deep.interrupted {
        return Err(interrupted_after(run, hist, checkpointed));
    }
    for s in &deep.stages {
        progress.info(&format!(
            "solve: {} values below {:.0e} in {} cycles (last change {:.1e})",
            s.voxels, s.threshold, s.cycles, s.last_change
        ));
    }
    Ok(deep)
}

/// Write phi = 1 - u for users and u itself (the precise one, for the stages after),
/// NaN outside the problem, to staged images (committed by the caller).
fn write_phi(
    run: &RunDir,
    spec: &GridSpec,
    cur: &dyn BlockStore<f64>,
    blocks: &BlockLoop<'_>,
    progress: &dyn Progress,
) -> Result<(), crate::Error> {
    let out_phi = run.create_image_staged::<f64>("phi", spec, f64::NAN, Compression::Zstd(1))?;
    let out_u = run.create_image_staged::<f64>("u", spec, f64::NAN, Compression::None)?;
    progress.start("solve: writing phi and u", spec.num_blocks());
    blocks.each(spec, |b| {
        let u = cur.read_block(b)?;
        out_u.write_block(b, &u)?;
        let phi: Vec<f64> = u.iter().map(|&v| 1.0 - v).collect();
        out_phi.write_block(b, &phi)?;
        progress.advance(1);
        Ok(())
    })?;
    progress.finish();
    Ok(())
}
