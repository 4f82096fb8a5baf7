//! [`run`]: every stage in turn over one run directory, skipping what is done and
//! fresh, running again what changed, and stopping when asked.

use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{
    check_solve, check_stop_radius, serve_voxelize, voxelize_new_run_on, PipelineError,
    PipelineOptions, PipelineReport, Source, StageRun, Summary,
};
use crate::grid::{solo, world};
use crate::progress::Progress;
use crate::run::stages::{freshness, options_in, report_in, stage_record, Freshness};
use crate::run::RunDir;
use crate::solve::SolveError;
use crate::trace::TraceOptions;

/// Run the pipeline on `source` into `opts.out`: voxelize (unless the run there was
/// voxelized alike), solve, trace, map and the atlas, each skipped when it is done
/// with the same options and its inputs have not changed since, else run (again). An
/// interrupted solve continues from its checkpoint when that was made for the same
/// options. When `progress`'s interrupt is set, the stage running stops at its next
/// block, tile or iteration and [`PipelineError::Interrupted`] is returned: running
/// the same pipeline again continues.
#[allow(clippy::too_many_lines)] // the stages in their order, each with its skip, re-run and interrupt checks
pub fn run(
    source: &Source<'_>,
    opts: &PipelineOptions,
    progress: &dyn Progress,
) -> Result<PipelineReport, PipelineError> {
    let out = &opts.out;
    let never = AtomicBool::new(false);
    let stop = progress.interrupt().map_or(&never, |i| i.flag().as_ref());
    let stopped = |stage: &'static str| PipelineError::Interrupted {
        run: out.clone(),
        stage,
        signal: progress
            .interrupt()
            .map_or(0, crate::progress::Interrupt::signal),
    };
    // A stage's error when the interrupt is set is the interruption, whatever the
    // stage made of it.
    let fail = |stage: &'static str, e: crate::Error| {
        if progress.interrupted() {
            stopped(stage)
        } else {
            PipelineError::Stage(e)
        }
    };
    // Options that mean nothing are refused before anything is written.
    check_solve(&opts.solve)?;
    let mut report = PipelineReport {
        run: out.clone(),
        stages: Vec::new(),
        voxelize: None,
        solve: None,
        trace: None,
        map: None,
        atlas: None,
        atlas_fallback: None,
        report: None,
        summary: Summary::default(),
    };

    // Voxelize: a new run, unless the one at `out` was made alike.
    if !opts.force && same_voxelization(source, opts)? {
        report.stages.push(("voxelize", StageRun::Skipped));
    } else {
        if progress.interrupted() {
            return Err(stopped("voxelize"));
        }
        // On MPI ranks every rank computes its slab of the solid, and rank 0 the
        // passes after it alone while the others wait (docs/scale-out.md).
        let w = world();
        if w.is_root() {
            let (_, r) =
                solo(|| voxelize_new_run_on(source, &opts.voxelize, out, opts.force, progress, w))
                    .map_err(|e| fail("voxelize", e))?;
            report.voxelize = Some(r);
        } else {
            serve_voxelize(source, progress, w).map_err(|e| fail("voxelize", e))?;
        }
        w.barrier().map_err(|e| PipelineError::Stage(e.into()))?;
        report.stages.push(("voxelize", ran(None)));
    }
    let run = RunDir::open(out).map_err(|e| PipelineError::Stage(e.into()))?;
    let attrs = |run: &RunDir| run.attrs().map_err(|e| PipelineError::Stage(e.into()));

    // Solve.
    let a = attrs(&run)?;
    match decide(&a, "solve", &opts.solve, run.has_image("phi")) {
        Decision::Skip => report.stages.push(("solve", StageRun::Skipped)),
        Decision::Run(again) => {
            if progress.interrupted() {
                return Err(stopped("solve"));
            }
            let mut o = opts.solve.clone();
            o.resume = run.has_checkpoint();
            let t = Instant::now();
            let mut r = crate::solve::solve(&run, &o, stop, progress);
            if let Err(crate::Error::Solve(SolveError::Checkpoint { reason, .. })) = &r {
                // A checkpoint of other options (or a damaged one) is of no use to
                // these options: start over, and say so.
                progress.warn(&format!(
                    "solve: the checkpoint in {} is of no use here ({reason}); solving from the start",
                    run.checkpoint_dir().display()
                ));
                o.resume = false;
                r = crate::solve::solve(&run, &o, stop, progress);
            }
            let r = r.map_err(|e| fail("solve", e))?;
            let resumed = r.resumed_at.is_some();
            report.solve = Some((r, t.elapsed().as_secs_f64()));
            report
                .stages
                .push(("solve", StageRun::Ran { again, resumed }));
        }
    }

    // Trace.
    let a = attrs(&run)?;
    match decide(&a, "trace", &opts.trace, run.has_seed_table()) {
        Decision::Skip => report.stages.push(("trace", StageRun::Skipped)),
        Decision::Run(again) => {
            if progress.interrupted() {
                return Err(stopped("trace"));
            }
            check_stop_radius(&a, opts.trace.stop_radius)?;
            let t = Instant::now();
            let r =
                crate::trace::trace(&run, &opts.trace, progress).map_err(|e| fail("trace", e))?;
            report.trace = Some((r, t.elapsed().as_secs_f64()));
            report.stages.push(("trace", ran(again)));
        }
    }

    // Map, with the trace's stop ball unless told otherwise.
    let a = attrs(&run)?;
    let mut map_opts = opts.map.clone();
    if map_opts.stop_radius.is_none() {
        map_opts.stop_radius = options_in::<TraceOptions>(&a, "trace").and_then(|t| t.stop_radius);
    }
    match decide(&a, "map", &map_opts, run.has_image("theta")) {
        Decision::Skip => report.stages.push(("map", StageRun::Skipped)),
        Decision::Run(again) => {
            if progress.interrupted() {
                return Err(stopped("map"));
            }
            let t = Instant::now();
            let r = crate::map::map(&run, &map_opts, progress).map_err(|e| fail("map", e))?;
            report.map = Some((r, t.elapsed().as_secs_f64()));
            report.stages.push(("map", ran(again)));
        }
    }

    // The atlas: by the molecule's residues when they can be had, else by the axis
    // (a file without residue numbers, or moved since the voxelization).
    // On MPI ranks rank 0 alone draws the atlas and writes the page.
    let w = world();
    if let Some(dest) = opts.atlas.as_ref().filter(|_| w.is_root()) {
        if progress.interrupted() {
            return Err(stopped("atlas"));
        }
        let a = attrs(&run)?;
        let by = crate::report::default_coloring(&a);
        if let Err(e) = solo(|| crate::report::atlas(&run, dest, false, &by)) {
            if by == crate::report::ColorBy::Axis || !e.is_bad_input() {
                return Err(fail("atlas", e));
            }
            report.atlas_fallback = Some(e.to_string());
            solo(|| crate::report::atlas(&run, dest, false, &crate::report::ColorBy::Axis))
                .map_err(|e| fail("atlas", e))?;
        }
        report.atlas = Some(dest.clone());
    }
    // The report page, after the atlas, whose picture it shows too.
    if let Some(dest) = opts.report.as_ref().filter(|_| w.is_root()) {
        if progress.interrupted() {
            return Err(stopped("report"));
        }
        solo(|| crate::report::html::write_report(&run, dest)).map_err(|e| fail("report", e))?;
        report.report = Some(dest.clone());
    }
    w.barrier().map_err(|e| PipelineError::Stage(e.into()))?;
    report.summary = summary(&attrs(&run)?);
    Ok(report)
}

fn ran(again: Option<String>) -> StageRun {
    StageRun::Ran {
        again,
        resumed: false,
    }
}

/// Whether the run at `opts.out` was voxelized from the same input with the same
/// options (then the stage is skipped); an error when it holds a run of something
/// else; `false` when there is no run there.
fn same_voxelization(source: &Source<'_>, opts: &PipelineOptions) -> Result<bool, PipelineError> {
    let Some(attrs) = RunDir::open(&opts.out).ok().and_then(|r| r.attrs().ok()) else {
        return Ok(false);
    };
    if freshness(&attrs, "voxelize") == Freshness::Missing {
        return Ok(false);
    }
    let input: InputRecord = attrs
        .get("input")
        .and_then(|i| serde_json::from_value(i.clone()).ok())
        .unwrap_or_default();
    let same_input = match source {
        Source::Starfish => input.builtin.is_some(),
        // A directory (a Zarr label volume) has no digest: taken as the same input.
        Source::File(p, _) => crate::input::sha256_file(p).ok() == input.sha256,
        Source::Mesh(..) => false,
    };
    let recorded = stage_record(&attrs, "voxelize").map_or(Value::Null, |r| r.options);
    let changed = changes(&recorded, &as_recorded(&opts.voxelize));
    if same_input && changed.is_empty() {
        return Ok(true);
    }
    Err(PipelineError::OtherRun {
        run: opts.out.clone(),
        what: if same_input {
            format!("the same input with other voxelization options ({changed})")
        } else {
            "another input".into()
        },
    })
}

/// The run's record of its input (`harmap.input`), the fields compared.
#[derive(Default, Deserialize)]
struct InputRecord {
    /// The input file's SHA-256 (none for built-in shapes and directories).
    sha256: Option<String>,
    /// The built-in shape's name.
    builtin: Option<String>,
}

/// What to do with a stage.
enum Decision {
    /// Done with these options, fresh, its outputs there.
    Skip,
    /// Run it: `None` when it was not done, else why it must run again.
    Run(Option<String>),
}

/// Whether `stage`, wanted with options `want`, is skipped or run (see [`Decision`]);
/// `outputs`: its outputs are in the run.
fn decide(attrs: &Value, stage: &str, want: &impl Serialize, outputs: bool) -> Decision {
    match freshness(attrs, stage) {
        Freshness::Missing => Decision::Run(None),
        Freshness::Stale(why) => Decision::Run(Some(format!("out of date: {why}"))),
        Freshness::Done => {
            let recorded = stage_record(attrs, stage).map_or(Value::Null, |r| r.options);
            let changed = changes(&recorded, &as_recorded(want));
            if !changed.is_empty() {
                Decision::Run(Some(format!("its options changed: {changed}")))
            } else if !outputs {
                Decision::Run(Some("its outputs are missing".into()))
            } else {
                Decision::Skip
            }
        }
    }
}

/// `opts` as a stage record holds them: serialized and read back, so that numbers
/// compare as they will be read from the run.
fn as_recorded(opts: &impl Serialize) -> Value {
    serde_json::to_string(opts)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or(Value::Null)
}

/// The options that differ between `old` and `new`, as `name old -> new`, joined.
fn changes(old: &Value, new: &Value) -> String {
    let mut out = Vec::new();
    diff("", old, new, &mut out);
    out.join(", ")
}

fn diff(path: &str, old: &Value, new: &Value, out: &mut Vec<String>) {
    match (old, new) {
        (Value::Object(a), Value::Object(b)) => {
            let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            for k in keys {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                diff(
                    &p,
                    a.get(k).unwrap_or(&Value::Null),
                    b.get(k).unwrap_or(&Value::Null),
                    out,
                );
            }
        }
        _ if old != new => out.push(format!("{path} {old} -> {new}")),
        _ => {}
    }
}

/// The trace's result fields of the summary.
#[derive(Deserialize)]
struct TraceNumbers {
    reached_fraction: f64,
    surface: Option<SurfaceNumbers>,
    collisions: CollisionNumbers,
}

#[derive(Deserialize)]
struct SurfaceNumbers {
    flipped: u64,
    measured: u64,
}

#[derive(Deserialize)]
struct CollisionNumbers {
    seeds: u64,
}

/// The map's result fields of the summary.
#[derive(Deserialize)]
struct MapNumbers {
    mapped: u64,
    voxels: u64,
}

/// The numbers of the run, from its records.
fn summary(attrs: &Value) -> Summary {
    let secs = |s: &str| stage_record(attrs, s).map_or(f64::NAN, |r| r.seconds);
    let mut s = Summary {
        seconds: [secs("voxelize"), secs("solve"), secs("trace"), secs("map")],
        reached_fraction: f64::NAN,
        ..Summary::default()
    };
    if let Some(t) = report_in::<TraceNumbers>(attrs, "trace") {
        s.reached_fraction = t.reached_fraction;
        s.flipped = t.surface.map(|m| (m.flipped, m.measured));
        s.colliding_seeds = t.collisions.seeds;
    }
    if let Some(m) = report_in::<MapNumbers>(attrs, "map") {
        s.mapped = (m.mapped, m.voxels);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn changed_options_are_named_with_old_and_new_values() {
        let old = json!({"method": "multigrid", "rtol": 1e-6, "rk": {"atol": 1e-8}});
        let new = json!({"method": "sor", "rtol": 1e-6, "rk": {"atol": 1e-5}});
        assert_eq!(
            changes(&old, &new),
            "method \"multigrid\" -> \"sor\", rk.atol 1e-8 -> 0.00001"
        );
        assert_eq!(changes(&old, &old), "");
    }
}
