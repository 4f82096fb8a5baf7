//! `harmap::pipeline::run` called directly: a complete run, skipping what is done,
//! running again what changed (and what reads it), staleness, and a stop request in
//! the middle of the trace that the same call then finishes.

use std::path::Path;

use harmap::input::InputOptions;
use harmap::map::MapOptions;
use harmap::math::Vec3;
use harmap::pipeline::{self, PipelineError, PipelineOptions, Source, StageRun};
use harmap::progress::{Interrupt, Progress, Silent};
use harmap::run::stages::{freshness, Freshness};
use harmap::run::RunDir;
use harmap::solve::SolveOptions;
use harmap::trace::{SeedKind, TraceOptions};
use harmap::voxelize::VoxelizeOptions;

use crate::common::{sphere, write_obj};

fn options(out: &Path) -> PipelineOptions {
    PipelineOptions {
        out: out.to_owned(),
        force: false,
        voxelize: VoxelizeOptions {
            resolution: Some(20),
            ..VoxelizeOptions::default()
        },
        solve: SolveOptions::default(),
        trace: TraceOptions::for_seeds(SeedKind::Surface),
        map: MapOptions::default(),
        atlas: Some(out.with_extension("atlas.png")),
        report: None,
    }
}

fn stage<'a>(r: &'a pipeline::PipelineReport, name: &str) -> &'a StageRun {
    &r.stages
        .iter()
        .find(|s| s.0 == name)
        .expect("stage listed")
        .1
}

/// A sphere run end to end through the library: every stage done and fresh, every
/// solid voxel mapped, the streamlines reach the center; the same call again skips
/// every stage; another rtol runs the solve again and, as they read phi, the trace and
/// the map, and says why.
#[test]
fn the_pipeline_runs_skips_and_reruns_what_changed() {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 12, 24));
    let out = d.path().join("s.harmap");
    let iopts = InputOptions::default();
    let source = Source::File(&shape, &iopts);
    let mut opts = options(&out);
    let r = pipeline::run(&source, &opts, &Silent).unwrap();
    for s in ["voxelize", "solve", "trace", "map"] {
        assert!(
            matches!(stage(&r, s), StageRun::Ran { again: None, .. }),
            "{s}"
        );
    }
    let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
    for s in ["voxelize", "solve", "trace", "map"] {
        assert_eq!(freshness(&attrs, s), Freshness::Done, "{s}");
    }
    let (mapped, voxels) = r.summary.mapped;
    assert!(voxels > 1000 && mapped == voxels, "{mapped} of {voxels}");
    assert!(
        r.summary.reached_fraction > 0.99,
        "{}",
        r.summary.reached_fraction
    );
    assert!(r.summary.flipped.is_some(), "surface seeds give the flips");
    assert!(out.with_extension("atlas.png").exists());

    let again = pipeline::run(&source, &opts, &Silent).unwrap();
    for s in ["voxelize", "solve", "trace", "map"] {
        assert_eq!(stage(&again, s), &StageRun::Skipped, "{s}");
    }

    opts.solve.rtol = 1e-4;
    let changed = pipeline::run(&source, &opts, &Silent).unwrap();
    assert_eq!(stage(&changed, "voxelize"), &StageRun::Skipped);
    let StageRun::Ran {
        again: Some(why), ..
    } = stage(&changed, "solve")
    else {
        panic!("the solve did not run again");
    };
    assert!(why.contains("rtol"), "{why}");
    for s in ["trace", "map"] {
        let StageRun::Ran {
            again: Some(why), ..
        } = stage(&changed, s)
        else {
            panic!("{s} did not run again");
        };
        assert!(why.contains("solve"), "{s}: {why}");
    }
    let solved = changed.solve.as_ref().unwrap().0.relative_residual;
    assert!(solved < 1e-4, "{solved}");

    // Only the trace's options changed: the solve is kept, the map (which does not
    // read the seeds) too.
    opts.trace.rk.atol = 1e-6;
    let t = pipeline::run(&source, &opts, &Silent).unwrap();
    assert_eq!(stage(&t, "solve"), &StageRun::Skipped);
    assert!(
        matches!(stage(&t, "trace"), StageRun::Ran { again: Some(w), .. } if w.contains("atol"))
    );
    assert_eq!(stage(&t, "map"), &StageRun::Skipped);

    // Other voxelization options are another run: refused, nothing touched.
    opts.voxelize.resolution = Some(24);
    let e = pipeline::run(&source, &opts, &Silent).unwrap_err();
    assert!(
        matches!(e, PipelineError::OtherRun { .. }) && e.is_bad_input(),
        "{e}"
    );
    assert!(e.to_string().contains("resolution"), "{e}");
}

/// Sets its token when the trace starts, as a signal in the middle of it would.
struct StopAtTrace(Interrupt);

impl Progress for StopAtTrace {
    fn start(&self, name: &str, _: u64) {
        if name == "trace" {
            self.0.set(2);
        }
    }
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
    fn warn(&self, _: &str) {}
    fn interrupt(&self) -> Option<&Interrupt> {
        Some(&self.0)
    }
}

/// A stop request during the trace ends the call with `Interrupted` naming the trace
/// and the signal; the trace is not recorded; the same call again keeps the solve and
/// finishes the run.
#[test]
fn a_stop_during_the_trace_is_reported_and_the_same_call_finishes() {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 12, 24));
    let out = d.path().join("s.harmap");
    let iopts = InputOptions::default();
    let source = Source::File(&shape, &iopts);
    let opts = options(&out);
    let e = pipeline::run(&source, &opts, &StopAtTrace(Interrupt::new())).unwrap_err();
    let PipelineError::Interrupted { stage, signal, .. } = e else {
        panic!("not an interruption: {e}");
    };
    assert_eq!((stage, signal), ("trace", 2));
    let attrs = RunDir::open(&out).unwrap().attrs().unwrap();
    assert_eq!(freshness(&attrs, "solve"), Freshness::Done);
    assert_eq!(freshness(&attrs, "trace"), Freshness::Missing);
    let r = pipeline::run(&source, &opts, &Silent).unwrap();
    assert_eq!(stage_of(&r, "solve"), &StageRun::Skipped);
    assert!(matches!(stage_of(&r, "trace"), StageRun::Ran { .. }));
    assert!(matches!(stage_of(&r, "map"), StageRun::Ran { .. }));
}

fn stage_of<'a>(r: &'a pipeline::PipelineReport, name: &str) -> &'a StageRun {
    stage(r, name)
}

/// Running the solve again with other options makes the trace and the map stale; a
/// stage that reads the seeds refuses them, naming the stage to run.
#[test]
fn a_new_solve_makes_the_trace_stale_and_its_readers_refuse() {
    let d = tempfile::tempdir().unwrap();
    let shape = d.path().join("s.obj");
    write_obj(&shape, &sphere(Vec3::ZERO, 1.0, 12, 24));
    let out = d.path().join("s.harmap");
    let iopts = InputOptions::default();
    pipeline::run(&Source::File(&shape, &iopts), &options(&out), &Silent).unwrap();
    let run = RunDir::open(&out).unwrap();
    let never = std::sync::atomic::AtomicBool::new(false);
    let o = SolveOptions {
        rtol: 1e-3,
        ..SolveOptions::default()
    };
    harmap::solve::solve(&run, &o, &never, &Silent).unwrap();
    assert!(matches!(run.freshness("trace").unwrap(), Freshness::Stale(w) if w.contains("solve")));
    assert!(matches!(run.freshness("map").unwrap(), Freshness::Stale(_)));
    let e = harmap::trace::read_seeds(&run).unwrap_err();
    assert!(e.is_bad_input(), "{e}");
    assert!(
        e.to_string().contains("out of date") && e.to_string().contains("harmap trace"),
        "{e}"
    );
    // The same solve options as the trace saw: fresh again.
    harmap::solve::solve(&run, &SolveOptions::default(), &never, &Silent).unwrap();
    assert_eq!(run.freshness("trace").unwrap(), Freshness::Done);
}
