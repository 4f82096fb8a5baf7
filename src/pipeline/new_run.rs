//! A new run: the voxelization (with the probe ladder of molecules) written under a
//! staging name and renamed into place when whole, and its record in the attributes.

use std::path::Path;
use std::time::Instant;

use serde_json::{json, Value};

use crate::grid::{Decomposition, Whole};
use crate::input::{self, Shape};
use crate::progress::Progress;
use crate::run::{RunDir, Staging};
use crate::voxelize::{self, VoxelizeOptions, VoxelizeReport};

use super::Source;

/// Voxelize `source` into a new run directory at `out` (replacing an existing one only
/// when `force`). The run is built under a staging name and renamed into place when
/// whole; on error nothing is left at `out` that was not there before.
pub fn voxelize_new_run(
    source: &Source<'_>,
    opts: &VoxelizeOptions,
    out: &Path,
    force: bool,
    progress: &dyn Progress,
) -> Result<(RunDir, VoxelizeReport), crate::Error> {
    voxelize_new_run_on(source, opts, out, force, progress, &Whole)
}

/// [`voxelize_new_run`] on rank 0 of the MPI ranks `decomp`, while every other rank
/// runs [`serve_voxelize`]: they compute their slabs of the solid, rank 0 the rest.
pub fn voxelize_new_run_on(
    source: &Source<'_>,
    opts: &VoxelizeOptions,
    out: &Path,
    force: bool,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(RunDir, VoxelizeReport), crate::Error> {
    let t0 = Instant::now();
    let (shape, input_meta, name) = load(source)?;
    let (staging, report, used) =
        voxelize_probes(&shape, &name, opts, out, force, progress, decomp)?;
    voxelize::ranks_done(decomp)?;
    for w in &report.warnings {
        progress.warn(w);
    }
    let seconds = t0.elapsed().as_secs_f64();
    record_voxelize(
        &staging,
        &report,
        input_meta,
        &serde_json::to_value(&used).expect("options"),
        seconds,
    )?;
    let run = staging.commit()?;
    Ok((run, report))
}

/// On an MPI rank other than 0 while rank 0 runs [`voxelize_new_run_on`]: read the
/// input and compute this rank's slab of each solid pass rank 0 asks for.
pub fn serve_voxelize(
    source: &Source<'_>,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(), crate::Error> {
    let (shape, _, _) = load(source)?;
    voxelize::serve_ranks(&shape, progress, decomp)
}

/// The shape of `source`, what the run records of it, and its name in messages.
fn load(source: &Source<'_>) -> Result<(Shape, Value, String), crate::Error> {
    Ok(match source {
        Source::File(path, iopts) => {
            let shape = input::load(path, iopts)?;
            let sha = if path.is_file() {
                Value::String(input::sha256_file(path)?)
            } else {
                Value::Null
            };
            let format = match &shape {
                Shape::Mesh(_) | Shape::Molecule(_) => input::extension(path).0,
                Shape::Volume(_) => "label-volume".into(),
            };
            let name = path.display().to_string();
            // The later stages read a mesh input again (surface seeds, the field's
            // boundary values): from wherever they run.
            let absolute = std::path::absolute(path)
                .map_or_else(|_| name.clone(), |p| p.display().to_string());
            let mut meta = json!({"path": absolute, "sha256": sha, "format": format});
            if let Shape::Molecule(_) = &shape {
                // How the atoms were read, so that pictures can read them again alike.
                meta["molecule"] = serde_json::to_value(&iopts.molecule).expect("options");
            }
            (shape, meta, name)
        }
        Source::Starfish => (
            Shape::Mesh(input::starfish::starfish(64, 240)),
            json!({"path": null, "builtin": "starfish", "sha256": null, "format": "builtin"}),
            "built-in starfish".to_owned(),
        ),
        Source::Mesh(m, name) => (
            Shape::Mesh((*m).clone()),
            json!({"path": name, "sha256": null, "format": "memory"}),
            (*name).to_owned(),
        ),
    })
}

/// Voxelize into a new staging run. For a molecule with a probe ladder (`--probe
/// 1.4,2,3`), each probe is tried in turn until the solid is one genus-0 piece (the
/// last is kept whatever it gives, and `allow_genus` decides then); the report lists
/// the trials, and the options returned are those of the probe kept.
fn voxelize_probes(
    shape: &Shape,
    name: &str,
    opts: &VoxelizeOptions,
    out: &Path,
    force: bool,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<(Staging, VoxelizeReport, VoxelizeOptions), crate::Error> {
    let probes: Vec<f64> = std::iter::once(opts.probe)
        .chain(opts.probe_ladder.iter().copied())
        .collect();
    if probes.len() > 1 {
        let why = match shape {
            Shape::Molecule(_) if opts.surface == voxelize::spheres::MolSurface::Vdw => {
                Some("--surface vdw does not use the probe")
            }
            Shape::Molecule(_) => None,
            _ => Some("only molecules and point sets have a probe"),
        };
        if let Some(why) = why {
            return Err(voxelize::VoxelizeError::Options(format!(
                "--probe with several radii: {why}"
            ))
            .into());
        }
    }
    let mut trials = Vec::new();
    for (i, &probe) in probes.iter().enumerate() {
        let last = i + 1 == probes.len();
        let mut o = opts.clone();
        o.probe = probe;
        if !last {
            o.allow_genus = true;
            o.skip_handle_search = true;
        }
        let staging = Staging::begin(out, force)?;
        let mut report = voxelize::voxelize_on(shape, name, &o, staging.run(), progress, decomp)?;
        let whole = report.genus == 0 && report.components == 1;
        if probes.len() > 1 {
            trials.push(voxelize::ProbeTrial {
                probe,
                genus: report.genus,
                components: report.components,
            });
        }
        if whole || last {
            report.probe_trials = trials;
            o.allow_genus = opts.allow_genus;
            o.skip_handle_search = false;
            return Ok((staging, report, o));
        }
        progress.info(&format!(
            "probe {probe} Angstrom: {} piece(s), genus {}; trying probe {} Angstrom",
            report.components,
            report.genus,
            probes[i + 1]
        ));
        drop(staging);
    }
    unreachable!("the last probe always returns")
}

/// Write the standard problem (see [`voxelize::StandardBall`]) as a new run at `out`.
pub fn standard_ball_run(
    p: &voxelize::StandardBall,
    out: &Path,
    force: bool,
    progress: &dyn Progress,
) -> Result<(RunDir, VoxelizeReport), crate::Error> {
    let t0 = Instant::now();
    let staging = Staging::begin(out, force)?;
    let report = voxelize::standard_ball(p, staging.run(), progress)?;
    let input =
        json!({"path": null, "builtin": "standard-ball", "sha256": null, "format": "builtin"});
    record_voxelize(
        &staging,
        &report,
        input,
        &serde_json::to_value(p).expect("options"),
        t0.elapsed().as_secs_f64(),
    )?;
    Ok((staging.commit()?, report))
}

/// Record a finished voxelization in the run's attributes: the grid (once, at
/// `harmap.grid`), the center, the input, and the stage with its options and result.
fn record_voxelize(
    staging: &Staging,
    report: &VoxelizeReport,
    input: Value,
    options: &Value,
    seconds: f64,
) -> Result<(), crate::Error> {
    let mut result = serde_json::to_value(report).expect("report");
    if let Some(o) = result.as_object_mut() {
        o.remove("grid");
    }
    staging.run().update_attrs(|a| {
        a.insert(
            "grid".into(),
            serde_json::to_value(&report.grid).expect("grid"),
        );
        a.insert("center".into(), json!(report.center));
        a.insert("center_voxel".into(), json!(report.center_voxel));
        a.insert("input".into(), input);
        let stages = a.entry("stages").or_insert_with(|| json!({}));
        stages["voxelize"] =
            json!({"status": "done", "seconds": seconds, "options": options, "result": result});
        if let Some(peak) = crate::run::peak_rss() {
            stages["voxelize"]["peak_rss_bytes"] = json!(peak);
        }
    })?;
    Ok(())
}
