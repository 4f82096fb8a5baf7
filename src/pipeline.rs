//! Stages chained over a run directory. `harmap run` and the stage subcommands call
//! these, so a stage run alone and a stage run by the pipeline write the same run.

use std::path::Path;
use std::time::Instant;

use serde_json::{json, Value};

use crate::input::{self, InputOptions, Shape};
use crate::progress::Progress;
use crate::run::{RunDir, Staging};
use crate::voxelize::{self, VoxelizeOptions, VoxelizeReport};

/// Where the shape comes from.
#[derive(Clone, Debug)]
pub enum Source<'a> {
    /// A file (or a Zarr directory) to read.
    File(&'a Path, &'a InputOptions),
    /// The built-in five-armed starfish.
    Starfish,
    /// A surface already in memory, with a name for messages.
    Mesh(&'a crate::input::TriMesh, &'a str),
}

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
    let t0 = Instant::now();
    let (shape, input_meta, name) = match source {
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
            let mut meta = json!({"path": name, "sha256": sha, "format": format});
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
    };
    let staging = Staging::begin(out, force)?;
    let report = voxelize::voxelize(&shape, &name, opts, staging.run(), progress)?;
    for w in &report.warnings {
        progress.warn(w);
    }
    let seconds = t0.elapsed().as_secs_f64();
    record_voxelize(
        &staging,
        &report,
        input_meta,
        &serde_json::to_value(opts).expect("options"),
        seconds,
    )?;
    let run = staging.commit()?;
    Ok((run, report))
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
    })?;
    Ok(())
}
