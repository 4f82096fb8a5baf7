//! The extension module `harmap._harmap`: the harmap stages for Python.
//!
//! Each function calls the same library entry the command line calls (so a run made
//! from Python has the same bytes as one made by `harmap`), with the command line's
//! options and defaults. The work runs on a thread of its own while the calling thread
//! waits with the GIL released; every tenth of a second it hands the progress to the
//! Python callback and checks for signals. A Ctrl-C sets the library's interrupt token
//! ([`harmap::progress::Interrupt`]), which the stages poll per block, tile or
//! iteration, as the command line's SIGINT handler does: the solve writes its
//! checkpoint, the other stages stop within about a second, and the call raises
//! KeyboardInterrupt. Library errors become `harmap.HarmapError` (a `ValueError`) with
//! the message the command line prints.

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use harmap::grid::MemBudget;
use harmap::input::{InputOptions, RawDtype, RawSpec};
use harmap::run::RunDir;
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;

create_exception!(
    _harmap,
    HarmapError,
    PyValueError,
    "A harmap stage failed: bad input, bad options, or a run it cannot use. The message \
     is the one the harmap command prints; `bad_input` says whether the command would \
     exit with code 2 (bad input) rather than 1."
);

/// A library error as a `HarmapError` with the command line's message.
fn harmap_err(py: Python<'_>, e: &harmap::Error) -> PyErr {
    let mut msg = e.to_string();
    let mut src = std::error::Error::source(e);
    while let Some(c) = src {
        let s = c.to_string();
        if !msg.contains(&s) {
            msg.push_str("\n  caused by: ");
            msg.push_str(&s);
        }
        src = c.source();
    }
    let err = HarmapError::new_err(msg);
    let _ = err.value(py).setattr("bad_input", e.is_bad_input());
    err
}

fn usage(msg: impl Into<String>) -> PyErr {
    HarmapError::new_err(msg.into())
}

fn mem_budget(s: &str) -> PyResult<MemBudget> {
    MemBudget::from_str(s).map_err(|e| usage(format!("mem: {e}")))
}

/// Progress of the running stage, written by the library's threads (no GIL, no lock
/// on the hot path) and read by the waiting thread.
#[derive(Default)]
struct Shared {
    phase: Mutex<(u64, String)>,
    total: AtomicU64,
    position: AtomicU64,
    message: Mutex<String>,
    warnings: Mutex<Vec<String>>,
    /// Set on Ctrl-C; the stages poll it.
    interrupt: harmap::progress::Interrupt,
}

impl harmap::progress::Progress for Shared {
    fn start(&self, name: &str, total: u64) {
        let mut p = self.phase.lock().expect("progress lock");
        p.0 += 1;
        p.1 = name.to_owned();
        self.total.store(total, Ordering::Relaxed);
        self.position.store(0, Ordering::Relaxed);
    }
    fn advance(&self, n: u64) {
        self.position.fetch_add(n, Ordering::Relaxed);
    }
    fn set_total(&self, total: u64) {
        self.total.store(total, Ordering::Relaxed);
    }
    fn set_position(&self, pos: u64) {
        self.position.store(pos, Ordering::Relaxed);
    }
    fn message(&self, message: &str) {
        message.clone_into(&mut self.message.lock().expect("progress lock"));
    }
    fn finish(&self) {
        let t = self.total.load(Ordering::Relaxed);
        self.position.store(t, Ordering::Relaxed);
    }
    fn warn(&self, message: &str) {
        self.warnings
            .lock()
            .expect("progress lock")
            .push(message.to_owned());
    }
    fn interrupt(&self) -> Option<&harmap::progress::Interrupt> {
        Some(&self.interrupt)
    }
}

/// SIGINT's number, recorded in the interrupt token as the command line does.
const SIGINT: usize = 2;

/// Hand the state of `s` to `cb(phase_id, name, position, total, message)`.
fn report(py: Python<'_>, s: &Shared, cb: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    for w in std::mem::take(&mut *s.warnings.lock().expect("progress lock")) {
        let warnings = py.import("warnings")?;
        warnings.call_method1(
            "warn",
            (w, py.get_type::<pyo3::exceptions::PyUserWarning>(), 3),
        )?;
    }
    if let Some(cb) = cb {
        let (id, name) = s.phase.lock().expect("progress lock").clone();
        if id > 0 {
            let msg = s.message.lock().expect("progress lock").clone();
            cb.call1((
                id,
                name,
                s.position.load(Ordering::Relaxed),
                s.total.load(Ordering::Relaxed),
                msg,
            ))?;
        }
    }
    Ok(())
}

/// Run `work` on a thread of its own with the GIL released, reporting progress to
/// `cb` and polling for signals. On a signal, the interrupt token the stages poll is
/// set and the signal's exception (KeyboardInterrupt for Ctrl-C) is raised once the
/// work has returned (within about a second: the stages check the token per block,
/// tile or iteration).
fn detached<T: Send>(
    py: Python<'_>,
    cb: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&Shared) -> T + Send,
) -> PyResult<T> {
    match detached_raw(py, cb, work) {
        (_, Some(e)) => Err(e),
        (v, None) => Ok(v),
    }
}

/// [`detached`], returning the work's result together with the signal's exception.
fn detached_raw<T: Send>(
    py: Python<'_>,
    cb: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&Shared) -> T + Send,
) -> (T, Option<PyErr>) {
    let shared = Shared::default();
    let mut raised: Option<PyErr> = None;
    let out = std::thread::scope(|scope| {
        let h = scope.spawn(|| work(&shared));
        loop {
            let finished = py.detach(|| {
                for _ in 0..10 {
                    if h.is_finished() {
                        return true;
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
                h.is_finished()
            });
            if raised.is_none() {
                if let Err(e) = py.check_signals() {
                    shared.interrupt.set(SIGINT);
                    raised = Some(e);
                }
            }
            if raised.is_none() {
                if let Err(e) = report(py, &shared, cb) {
                    // A failing callback stops the progress, not the stage.
                    e.print(py);
                }
            }
            if finished {
                break;
            }
        }
        h.join()
    });
    let out = match out {
        Ok(v) => v,
        Err(p) => std::panic::resume_unwind(p),
    };
    let _ = report(py, &shared, cb);
    (out, raised)
}

fn json_str(v: &impl serde::Serialize) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "null".into())
}

/// The voxelization's options and the input's, from the keyword arguments of
/// `harmap.voxelize` and `harmap.run` (the command line's flags, same defaults).
#[allow(clippy::too_many_arguments, clippy::fn_params_excessive_bools)]
fn voxelize_options(
    starfish: bool,
    resolution: Option<u64>,
    spacing: Option<f64>,
    padding: u64,
    center: Option<[f64; 3]>,
    center_radius: f64,
    topology: &str,
    allow_genus: bool,
    keep_largest: bool,
    close: u32,
    unit: Option<String>,
    chunk: u64,
    mem: MemBudget,
    scratch: &str,
    raw_shape: Option<[u64; 3]>,
    raw_dtype: Option<&str>,
    surface: &str,
    probe: &[f64],
    model: Option<u32>,
    keep_hetatm: bool,
    radius: Option<f64>,
) -> PyResult<(harmap::voxelize::VoxelizeOptions, InputOptions)> {
    use harmap::voxelize::spheres::MolSurface;
    use harmap::voxelize::{Scratch, TopologyMode, VoxelizeOptions};
    if resolution.is_some() && spacing.is_some() {
        return Err(usage(
            "the argument '--resolution <N>' cannot be used with '--spacing <H>'",
        ));
    }
    let raw = match (raw_shape, raw_dtype) {
        (Some(shape), Some(d)) => Some(RawSpec {
            shape,
            dtype: RawDtype::from_str(d).map_err(|e| usage(format!("raw_dtype: {e}")))?,
        }),
        (None, None) => None,
        _ => return Err(usage("--raw-shape and --raw-dtype go together")),
    };
    if probe.is_empty() {
        return Err(usage("probe: give at least one radius"));
    }
    let opts = VoxelizeOptions {
        resolution,
        spacing,
        padding,
        // As `harmap run` does for the starfish: its middle is the center.
        center: center.or(starfish.then_some([0.0, 0.0, 0.0])),
        center_radius,
        allow_genus,
        keep_largest,
        chunk,
        mem,
        unit,
        scratch: match scratch {
            "auto" => Scratch::Auto,
            "memory" => Scratch::Memory,
            "disk" => Scratch::Disk,
            s => return Err(usage(format!("scratch '{s}': use auto, memory or disk"))),
        },
        surface: match surface {
            "vdw" => MolSurface::Vdw,
            "sas" => MolSurface::Sas,
            "ses" => MolSurface::Ses,
            s => return Err(usage(format!("surface '{s}': use vdw, sas or ses"))),
        },
        probe: probe[0],
        close,
        probe_ladder: probe[1..].to_vec(),
        topology: match topology {
            "auto" => TopologyMode::Auto,
            "repair" => TopologyMode::Repair,
            "strict" => TopologyMode::Strict,
            t => return Err(usage(format!("topology '{t}': use auto, repair or strict"))),
        },
        skip_handle_search: false,
    };
    let iopts = InputOptions {
        raw,
        mem: Some(opts.mem),
        molecule: harmap::input::molecule::MoleculeOptions {
            model,
            keep_hetatm,
            radius,
        },
    };
    Ok((opts, iopts))
}

/// Voxelize `path` (None: the built-in starfish) into a new run at `out`. Options as
/// `harmap voxelize`'s flags; returns the voxelize report as JSON text.
#[pyfunction]
#[pyo3(signature = (path, out, *, force=false, resolution=None, spacing=None, padding=6,
    center=None, center_radius=2.0, topology="auto", allow_genus=false, keep_largest=false,
    close=0, unit=None, chunk=64, mem="1GiB", scratch="auto", raw_shape=None,
    raw_dtype=None, surface="ses", probe=vec![1.4], model=None, keep_hetatm=false,
    radius=None, progress=None))]
#[allow(clippy::too_many_arguments, clippy::fn_params_excessive_bools)]
fn voxelize(
    py: Python<'_>,
    path: Option<PathBuf>,
    out: PathBuf,
    force: bool,
    resolution: Option<u64>,
    spacing: Option<f64>,
    padding: u64,
    center: Option<[f64; 3]>,
    center_radius: f64,
    topology: &str,
    allow_genus: bool,
    keep_largest: bool,
    close: u32,
    unit: Option<String>,
    chunk: u64,
    mem: &str,
    scratch: &str,
    raw_shape: Option<[u64; 3]>,
    raw_dtype: Option<&str>,
    surface: &str,
    probe: Vec<f64>,
    model: Option<u32>,
    keep_hetatm: bool,
    radius: Option<f64>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let (opts, iopts) = voxelize_options(
        path.is_none(),
        resolution,
        spacing,
        padding,
        center,
        center_radius,
        topology,
        allow_genus,
        keep_largest,
        close,
        unit,
        chunk,
        mem_budget(mem)?,
        scratch,
        raw_shape,
        raw_dtype,
        surface,
        &probe,
        model,
        keep_hetatm,
        radius,
    )?;
    let r = detached(py, progress.as_ref(), |p| {
        harmap::pipeline::voxelize_new_run(
            &source_of(path.as_deref(), &iopts),
            &opts,
            &out,
            force,
            p,
        )
    })?;
    let (_, report) = r.map_err(|e| harmap_err(py, &e))?;
    Ok(json_str(&report))
}

/// The shape `path` names (None: the built-in starfish).
fn source_of<'a>(path: Option<&'a Path>, iopts: &'a InputOptions) -> harmap::pipeline::Source<'a> {
    path.map_or(harmap::pipeline::Source::Starfish, |f| {
        harmap::pipeline::Source::File(f, iopts)
    })
}

/// Move the file `file` into the run (as `input.<ext>`) and point the run's input at
/// it: for shapes handed over in memory, written to a file first so that the stages
/// read them exactly as `harmap` reads a file.
#[pyfunction]
fn adopt_input(py: Python<'_>, run: PathBuf, file: PathBuf, name: String) -> PyResult<String> {
    let r = RunDir::open(&run).map_err(|e| harmap_err(py, &e.into()))?;
    let ext = file
        .extension()
        .map_or_else(String::new, |e| e.to_string_lossy().into_owned());
    let dest = r.root().join(format!("input.{ext}"));
    std::fs::rename(&file, &dest)
        .or_else(|_| std::fs::copy(&file, &dest).map(|_| ()))
        .map_err(|e| usage(format!("{}: cannot move into the run: {e}", file.display())))?;
    let _ = std::fs::remove_file(&file);
    let abs = std::path::absolute(&dest).unwrap_or(dest);
    r.update_attrs(|a| {
        if let Some(i) = a.get_mut("input").and_then(|i| i.as_object_mut()) {
            i.insert("path".into(), abs.display().to_string().into());
            i.insert("handed_over".into(), name.into());
        }
    })
    .map_err(|e| harmap_err(py, &e.into()))?;
    Ok(abs.display().to_string())
}

/// The solve's options from the keyword arguments of `harmap.solve` and `harmap.run`.
#[allow(clippy::too_many_arguments)]
fn solve_options(
    method: &str,
    cycle: &str,
    rtol: f64,
    tol: f64,
    eps: f64,
    max_iter: u64,
    omega: Option<f64>,
    checkpoint_every: f64,
    mem: MemBudget,
    resume: bool,
) -> PyResult<harmap::solve::SolveOptions> {
    use harmap::solve::driver::Method;
    Ok(harmap::solve::SolveOptions {
        method: match method {
            "multigrid" => Method::Multigrid,
            "sor" => Method::Sor,
            "jacobi" => Method::Jacobi,
            m => return Err(usage(format!("method '{m}': use multigrid, sor or jacobi"))),
        },
        cycle: harmap::solve::CycleOptions {
            kind: match cycle {
                "fmg" => harmap::solve::Cycle::Fmg,
                "v" => harmap::solve::Cycle::V,
                c => return Err(usage(format!("cycle '{c}': use fmg or v"))),
            },
            ..harmap::solve::CycleOptions::default()
        },
        tol,
        rtol,
        eps,
        max_iter,
        omega,
        mem,
        checkpoint_every,
        resume,
        ..harmap::solve::SolveOptions::default()
    })
}

/// Solve for phi, as `harmap solve`. Ctrl-C writes a checkpoint and raises
/// KeyboardInterrupt; `resume=True` continues from it.
#[pyfunction]
#[pyo3(signature = (run, *, method="multigrid", cycle="fmg", rtol=1e-6, tol=0.0, eps=1e-4, max_iter=1000,
    omega=None, checkpoint_every=300.0, mem="1GiB", resume=false, progress=None))]
#[allow(clippy::too_many_arguments)]
fn solve(
    py: Python<'_>,
    run: PathBuf,
    method: &str,
    cycle: &str,
    rtol: f64,
    tol: f64,
    eps: f64,
    max_iter: u64,
    omega: Option<f64>,
    checkpoint_every: f64,
    mem: &str,
    resume: bool,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let opts = solve_options(
        method,
        cycle,
        rtol,
        tol,
        eps,
        max_iter,
        omega,
        checkpoint_every,
        mem_budget(mem)?,
        resume,
    )?;
    let r = open(py, &run)?;
    let (res, raised) = detached_raw(py, progress.as_ref(), |p| {
        harmap::solve::solve(&r, &opts, p.interrupt.flag(), p)
    });
    match (res, raised) {
        // The library's message (it names the checkpoint), as KeyboardInterrupt.
        (
            Err(
                e @ harmap::Error::Solve(
                    harmap::solve::SolveError::Interrupted { .. }
                    | harmap::solve::SolveError::InterruptedPolish { .. },
                ),
            ),
            Some(k),
        ) if k.is_instance_of::<PyKeyboardInterrupt>(py) => Err(PyKeyboardInterrupt::new_err(
            format!("{e} (from Python: solve(..., resume=True))"),
        )),
        (_, Some(k)) => Err(k),
        (Ok(rep), None) => Ok(json_str(&rep)),
        (Err(e), None) => Err(harmap_err(py, &e)),
    }
}

fn open(py: Python<'_>, run: &Path) -> PyResult<RunDir> {
    RunDir::open(run).map_err(|e| harmap_err(py, &e.into()))
}

/// The trace's options from the keyword arguments of `harmap.trace` and `harmap.run`,
/// built as the command line builds them (src/cli/trace.rs): `atol` and `level_step`
/// default by the seeds.
#[allow(clippy::too_many_arguments)]
fn trace_options(
    seeds: &str,
    sample: Option<u64>,
    stop_radius: Option<f64>,
    tile: Option<u64>,
    mem: MemBudget,
    atol: Option<f64>,
    rtol: f64,
    h_min: f64,
    h_max: f64,
    max_steps: u32,
    level_step: Option<f64>,
    untangle: bool,
    no_untangle: bool,
) -> PyResult<harmap::trace::TraceOptions> {
    use harmap::trace::{Rk45, SeedKind, TraceOptions};
    let seeds = match seeds {
        "boundary" => SeedKind::Boundary,
        "surface" => SeedKind::Surface,
        s => return Err(usage(format!("seeds '{s}': use surface or boundary"))),
    };
    let default = Rk45::for_seeds(seeds);
    // As the command: untangled by default where the seeds are a whole surface.
    if untangle && no_untangle {
        return Err(usage("untangle and no_untangle: give one"));
    }
    if untangle && (seeds != SeedKind::Surface || sample.is_some()) {
        return Err(usage(
            "untangle works on the whole surface's sphere map: use it with surface seeds \
             (the default) and without sample",
        ));
    }
    Ok(TraceOptions {
        seeds,
        sample,
        stop_radius,
        tile,
        untangle: !no_untangle && seeds == SeedKind::Surface && sample.is_none(),
        mem,
        rk: Rk45 {
            atol: atol.unwrap_or(default.atol),
            rtol,
            h_min,
            h_max,
            max_steps,
            level_step: level_step.unwrap_or(default.level_step),
            level_after: default.level_after,
        },
    })
}

/// Trace streamlines, as `harmap trace` (whose default seeds are the surface's
/// vertices, as `harmap run`'s).
#[pyfunction]
#[pyo3(signature = (run, *, seeds="surface", sample=None, stop_radius=None, tile=None,
    mem="1GiB", atol=None, rtol=0.0, h_min=1e-6, h_max=2.0, max_steps=20_000,
    level_step=None, untangle=false, no_untangle=false, progress=None))]
#[allow(clippy::too_many_arguments)]
fn trace(
    py: Python<'_>,
    run: PathBuf,
    seeds: &str,
    sample: Option<u64>,
    stop_radius: Option<f64>,
    tile: Option<u64>,
    mem: &str,
    atol: Option<f64>,
    rtol: f64,
    h_min: f64,
    h_max: f64,
    max_steps: u32,
    level_step: Option<f64>,
    untangle: bool,
    no_untangle: bool,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let opts = trace_options(
        seeds,
        sample,
        stop_radius,
        tile,
        mem_budget(mem)?,
        atol,
        rtol,
        h_min,
        h_max,
        max_steps,
        level_step,
        untangle,
        no_untangle,
    )?;
    let r = open(py, &run)?;
    // Stop radii that cannot work are refused before anything is traced, as the
    // command line does.
    let attrs = r.attrs().map_err(|e| harmap_err(py, &e.into()))?;
    harmap::pipeline::check_stop_radius(&attrs, opts.stop_radius)
        .map_err(|e| harmap_err(py, &e))?;
    let rep = detached(py, progress.as_ref(), |p| {
        harmap::trace::trace(&r, &opts, p)
    })?;
    rep.map(|x| json_str(&x)).map_err(|e| harmap_err(py, &e))
}

/// The map's options: the method, the trace's stop ball, the budget.
fn map_options(exact: bool, stop_radius: Option<f64>, mem: MemBudget) -> harmap::map::MapOptions {
    harmap::map::MapOptions {
        method: if exact {
            harmap::map::MapMethod::Exact
        } else {
            harmap::map::MapMethod::Upwind
        },
        stop_radius,
        mem,
    }
}

/// Map every voxel, as `harmap map` (the stop ball of the trace).
#[pyfunction]
#[pyo3(signature = (run, *, exact=false, mem="1GiB", progress=None))]
fn map(
    py: Python<'_>,
    run: PathBuf,
    exact: bool,
    mem: &str,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let r = open(py, &run)?;
    let attrs = r.attrs().map_err(|e| harmap_err(py, &e.into()))?;
    let stop_radius = harmap::run::options_in::<harmap::trace::TraceOptions>(&attrs, "trace")
        .and_then(|t| t.stop_radius);
    let opts = map_options(exact, stop_radius, mem_budget(mem)?);
    let rep = detached(py, progress.as_ref(), |p| harmap::map::map(&r, &opts, p))?;
    rep.map(|x| json_str(&x)).map_err(|e| harmap_err(py, &e))
}

/// The whole pipeline, as `harmap run`, through the library's
/// [`harmap::pipeline::run`]: stages done alike are skipped, stale ones run again, an
/// interrupted solve is continued, a run of another input or other voxelization
/// options is refused unless `force`, and the atlas and the report page are written
/// beside the run (`atlas`, `report`). Returns the stages and what was done with each,
/// as JSON text.
#[pyfunction]
#[pyo3(signature = (path, out, *, force=false, resolution=None, spacing=None, padding=6,
    center=None, center_radius=2.0, topology="auto", allow_genus=false, keep_largest=false,
    close=0, unit=None, chunk=64, mem="1GiB", scratch="auto", raw_shape=None,
    raw_dtype=None, surface="ses", probe=vec![1.4], model=None, keep_hetatm=false,
    radius=None, method="multigrid", cycle="fmg", rtol=1e-6, tol=0.0, eps=1e-4, max_iter=1000,
    omega=None, checkpoint_every=300.0, seeds="surface", sample=None, stop_radius=None,
    tile=None, atol=None, h_min=1e-6, h_max=2.0, max_steps=20_000, level_step=None,
    untangle=false, no_untangle=false, trace_rtol=0.0, exact=false, atlas=None, report=None, progress=None))]
#[allow(clippy::too_many_arguments, clippy::fn_params_excessive_bools)]
fn run(
    py: Python<'_>,
    path: Option<PathBuf>,
    out: PathBuf,
    force: bool,
    resolution: Option<u64>,
    spacing: Option<f64>,
    padding: u64,
    center: Option<[f64; 3]>,
    center_radius: f64,
    topology: &str,
    allow_genus: bool,
    keep_largest: bool,
    close: u32,
    unit: Option<String>,
    chunk: u64,
    mem: &str,
    scratch: &str,
    raw_shape: Option<[u64; 3]>,
    raw_dtype: Option<&str>,
    surface: &str,
    probe: Vec<f64>,
    model: Option<u32>,
    keep_hetatm: bool,
    radius: Option<f64>,
    method: &str,
    cycle: &str,
    rtol: f64,
    tol: f64,
    eps: f64,
    max_iter: u64,
    omega: Option<f64>,
    checkpoint_every: f64,
    seeds: &str,
    sample: Option<u64>,
    stop_radius: Option<f64>,
    tile: Option<u64>,
    atol: Option<f64>,
    h_min: f64,
    h_max: f64,
    max_steps: u32,
    level_step: Option<f64>,
    untangle: bool,
    no_untangle: bool,
    trace_rtol: f64,
    exact: bool,
    atlas: Option<PathBuf>,
    report: Option<PathBuf>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    use harmap::pipeline::{PipelineError, PipelineOptions, StageRun};
    let mem = mem_budget(mem)?;
    let (voxelize, iopts) = voxelize_options(
        path.is_none(),
        resolution,
        spacing,
        padding,
        center,
        center_radius,
        topology,
        allow_genus,
        keep_largest,
        close,
        unit,
        chunk,
        mem,
        scratch,
        raw_shape,
        raw_dtype,
        surface,
        &probe,
        model,
        keep_hetatm,
        radius,
    )?;
    let opts = PipelineOptions {
        out: out.clone(),
        force,
        voxelize,
        solve: solve_options(
            method,
            cycle,
            rtol,
            tol,
            eps,
            max_iter,
            omega,
            checkpoint_every,
            mem,
            false,
        )?,
        trace: trace_options(
            seeds,
            sample,
            stop_radius,
            tile,
            mem,
            atol,
            trace_rtol,
            h_min,
            h_max,
            max_steps,
            level_step,
            untangle,
            no_untangle,
        )?,
        map: map_options(exact, None, mem),
        atlas,
        report,
    };
    let (res, raised) = detached_raw(py, progress.as_ref(), |p| {
        harmap::pipeline::run(&source_of(path.as_deref(), &iopts), &opts, p)
    });
    let rep = match (res, raised) {
        (Err(PipelineError::Interrupted { run, stage, .. }), Some(k))
            if k.is_instance_of::<PyKeyboardInterrupt>(py) =>
        {
            return Err(PyKeyboardInterrupt::new_err(format!(
                "{}: stopped during the {stage} stage; the finished stages are kept. \
                 Call harmap.run again with the same arguments to continue",
                run.display()
            )))
        }
        (_, Some(k)) => return Err(k),
        (Ok(r), None) => r,
        (Err(PipelineError::Stage(e)), None) => return Err(harmap_err(py, &e)),
        (Err(e), None) => {
            let err = HarmapError::new_err(e.to_string());
            let _ = err.value(py).setattr("bad_input", e.is_bad_input());
            return Err(err);
        }
    };
    let stages: serde_json::Map<String, serde_json::Value> = rep
        .stages
        .iter()
        .map(|(name, how)| {
            let v = match how {
                StageRun::Skipped => serde_json::json!({"skipped": true}),
                StageRun::Ran { again, resumed } => {
                    serde_json::json!({"skipped": false, "again": again, "resumed": resumed})
                }
            };
            ((*name).to_owned(), v)
        })
        .collect();
    Ok(json_str(&serde_json::json!({
        "run": rep.run,
        "stages": stages,
        "atlas": rep.atlas,
        "atlas_fallback": rep.atlas_fallback,
        "report": rep.report,
    })))
}

/// Draw the atlas (or with `sphere` the sphere view) of a traced run to `dest`.
#[pyfunction]
#[pyo3(signature = (run, dest, *, sphere=false, color=None))]
fn atlas(
    py: Python<'_>,
    run: PathBuf,
    dest: PathBuf,
    sphere: bool,
    color: Option<&str>,
) -> PyResult<usize> {
    use harmap::report::ColorBy;
    let r = open(py, &run)?;
    let attrs = r.attrs().map_err(|e| harmap_err(py, &e.into()))?;
    let by = match color {
        None => harmap::report::default_coloring(&attrs),
        Some("axis") => ColorBy::Axis,
        Some("z") => ColorBy::Z,
        Some("distance") => ColorBy::Distance,
        Some("chain") => ColorBy::Chain,
        Some("residue") => ColorBy::Residue,
        Some(c) => {
            return Err(usage(format!(
                "color '{c}': use axis, z, distance, chain or residue"
            )))
        }
    };
    let n = detached(py, None, |_| {
        match harmap::report::atlas(&r, &dest, sphere, &by) {
            // As `harmap run`: the main axis when a molecule's residues cannot be had.
            Err(e) if color.is_none() && by != ColorBy::Axis && e.is_bad_input() => {
                harmap::report::atlas(&r, &dest, sphere, &ColorBy::Axis)
            }
            x => x,
        }
    })?;
    n.map_err(|e| harmap_err(py, &e))
}

/// Write the report page of a run to `dest`.
#[pyfunction]
fn report_page(py: Python<'_>, run: PathBuf, dest: PathBuf) -> PyResult<()> {
    let r = open(py, &run)?;
    detached(py, None, |_| harmap::report::html::write_report(&r, &dest))?
        .map_err(|e| harmap_err(py, &e))
}

/// Export, as `harmap export`: format csv, obj-sphere, vtk-streamlines, nifti, vti, dx
/// or ome-zarr; `field` for the image formats.
#[pyfunction]
#[pyo3(signature = (run, dest, format, *, field=None, sample=None, mem="1GiB", force=false, progress=None))]
#[allow(clippy::too_many_arguments)]
fn export(
    py: Python<'_>,
    run: PathBuf,
    dest: PathBuf,
    format: &str,
    field: Option<&str>,
    sample: Option<u64>,
    mem: &str,
    force: bool,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<u64> {
    use harmap::export::image::{export_image, export_ome_zarr, Field, ImageFormat};
    use harmap::export::{check_target, ExportKind};
    let r = open(py, &run)?;
    let mem = mem_budget(mem)?;
    let image = matches!(format, "nifti" | "vti" | "dx" | "ome-zarr");
    if sample.is_some() && format != "vtk-streamlines" {
        return Err(usage("--sample applies to --format vtk-streamlines only"));
    }
    if field.is_some() && !image {
        return Err(usage(
            "--field applies to the image formats (nifti, vti, dx, ome-zarr)",
        ));
    }
    let one = match field {
        None | Some("phi") => Field::Phi,
        Some("theta") => Field::Theta,
        Some("psi") => Field::Psi,
        Some("labels") => Field::Labels,
        Some(f) => return Err(usage(format!("field '{f}': use phi, theta, psi or labels"))),
    };
    let some: Vec<Field> = match field {
        Some(_) => vec![one],
        None => Field::ALL
            .into_iter()
            .filter(|f| r.root().join(f.name()).join("0").exists())
            .collect(),
    };
    let fmt = match format {
        "csv" | "obj-sphere" | "vtk-streamlines" | "ome-zarr" => None,
        "nifti" => Some(ImageFormat::Nifti),
        "vti" => Some(ImageFormat::Vti),
        "dx" => Some(ImageFormat::Dx),
        f => {
            return Err(usage(format!(
                "format '{f}': use csv, obj-sphere, vtk-streamlines, nifti, vti, dx or ome-zarr"
            )))
        }
    };
    // The command's rule: never destroy what this export did not create (an existing
    // path that is not its own earlier output, anything inside a run) unless `force`.
    let kind = match (format, fmt) {
        ("csv", _) => ExportKind::Csv,
        ("obj-sphere", _) => ExportKind::ObjSphere,
        ("vtk-streamlines", _) => ExportKind::VtkStreamlines,
        (_, Some(f)) => ExportKind::Image(f),
        (_, None) => ExportKind::OmeZarr,
    };
    check_target(&dest, kind, force).map_err(|e| harmap_err(py, &harmap::Error::from(e)))?;
    let res = detached(py, progress.as_ref(), |p| match (format, fmt) {
        ("csv", _) => harmap::export::seeds_csv(&r, &dest),
        ("obj-sphere", _) => harmap::export::obj_sphere(&r, &dest),
        ("vtk-streamlines", _) => harmap::export::vtk_streamlines(&r, &dest, sample, mem, p),
        ("ome-zarr", _) => export_ome_zarr(&r, &some, &dest),
        (_, Some(ImageFormat::Vti)) => export_image(&r, ImageFormat::Vti, &some, &dest, mem, p),
        (_, Some(f)) => export_image(&r, f, &[one], &dest, mem, p),
        (_, None) => unreachable!("formats checked above"),
    })?;
    res.map_err(|e| harmap_err(py, &e))
}

/// Points of the solid for coordinates (phi, theta, psi), as `harmap inverse`: an
/// (N, 3) float64 array of x, y, z (NaN where there is no point) and the reason for
/// each row without a point ("" for rows with one).
#[pyfunction]
#[pyo3(signature = (run, phi, theta, psi, *, mem="1GiB", progress=None))]
#[allow(clippy::type_complexity)]
fn inverse<'py>(
    py: Python<'py>,
    run: PathBuf,
    phi: PyReadonlyArray1<'py, f64>,
    theta: PyReadonlyArray1<'py, f64>,
    psi: PyReadonlyArray1<'py, f64>,
    mem: &str,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Vec<String>)> {
    use rayon::prelude::*;
    let (phi, theta, psi) = (phi.as_array(), theta.as_array(), psi.as_array());
    let n = phi.len();
    if theta.len() != n || psi.len() != n {
        return Err(usage(format!(
            "phi, theta and psi differ in length ({n}, {}, {})",
            theta.len(),
            psi.len()
        )));
    }
    let rows: Vec<[f64; 3]> = (0..n).map(|i| [phi[i], theta[i], psi[i]]).collect();
    if let Some(i) = rows.iter().position(|r| r.iter().any(|x| x.is_nan())) {
        return Err(usage(format!("row {i}: NaN is not a coordinate")));
    }
    let mem = mem_budget(mem)?;
    let r = open(py, &run)?;
    let res = detached(py, progress.as_ref(), |p| {
        // The map's stop ball, as inverse_csv takes it.
        let attrs = r.attrs()?;
        let stop_radius = attrs
            .pointer("/stages/map/result/stop_radius")
            .or_else(|| attrs.pointer("/stages/trace/options/stop_radius"))
            .and_then(serde_json::Value::as_f64);
        let inv = harmap::map::inverse::Inverse::new(&r, stop_radius, mem)?;
        if let Some(problem) = &inv.boundary().problem {
            harmap::progress::Progress::warn(p, problem);
        }
        harmap::progress::Progress::start(p, "inverse", n as u64);
        let pts: Vec<Result<glam::DVec3, String>> = rows
            .par_iter()
            .with_min_len(64)
            .map(|q| {
                let x = inv.point(q[0], q[1], q[2]);
                harmap::progress::Progress::advance(p, 1);
                x
            })
            .collect();
        harmap::progress::Progress::finish(p);
        Ok::<_, harmap::Error>(pts)
    })?;
    let pts = res.map_err(|e| harmap_err(py, &e))?;
    let mut xyz = Vec::with_capacity(3 * n);
    let mut why = Vec::with_capacity(n);
    for p in pts {
        match p {
            Ok(v) => {
                xyz.extend_from_slice(&[v.x, v.y, v.z]);
                why.push(String::new());
            }
            Err(e) => {
                xyz.extend_from_slice(&[f64::NAN; 3]);
                why.push(e);
            }
        }
    }
    let arr = PyArray1::from_vec(py, xyz).reshape([n, 3])?;
    Ok((arr, why))
}

/// The harmap library version.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _harmap(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("HarmapError", m.py().get_type::<HarmapError>())?;
    m.add_function(wrap_pyfunction!(voxelize, m)?)?;
    m.add_function(wrap_pyfunction!(adopt_input, m)?)?;
    m.add_function(wrap_pyfunction!(solve, m)?)?;
    m.add_function(wrap_pyfunction!(trace, m)?)?;
    m.add_function(wrap_pyfunction!(map, m)?)?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(atlas, m)?)?;
    m.add_function(wrap_pyfunction!(report_page, m)?)?;
    m.add_function(wrap_pyfunction!(export, m)?)?;
    m.add_function(wrap_pyfunction!(inverse, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
