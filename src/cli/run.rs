//! `harmap run`: the whole pipeline in one command, as far as it is built.

use std::path::PathBuf;

use anyhow::Context;
use harmap::input::InputOptions;
use harmap::pipeline::{voxelize_new_run, Source};
use harmap::run::RunDir;

use super::progress::Bars;
use super::solve::{MethodArg, SolveArgs};
use super::trace::SeedArg;
use super::voxelize::VoxelizeArgs;
use super::{Global, UsageError};

/// Run the pipeline on a shape: voxelization (labels and center), the solve (phi,
/// multigrid; an interrupted solve resumes from its checkpoint), the trace (streamlines
/// from the vertices of the input mesh, or for other inputs of the labels' surface nets,
/// so that the summary has the bijectivity numbers; --seeds boundary traces from every
/// boundary voxel instead), the full-volume map (theta and psi for every voxel, upwind)
/// and the atlas picture (RUN's name with .atlas.png), then a summary.
///
/// With no INPUT, runs on the built-in five-armed starfish, centered at its middle.
/// Stages already done in RUN are skipped, so a run that was stopped is finished by
/// giving the same command again; --force starts over.
///
/// Examples:
///   harmap run                                 # the built-in starfish -> starfish.harmap
///   harmap run spot.obj -o spot.harmap --resolution 96
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The shape (default: the built-in starfish).
    pub input: Option<PathBuf>,
    /// The run directory [default: INPUT's name with .harmap, or starfish.harmap].
    #[arg(short, long, value_name = "RUN")]
    pub output: Option<PathBuf>,
    /// Redo every stage, replacing RUN.
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub opts: VoxelizeArgs,
    /// Solve: multigrid, sor or jacobi.
    #[arg(long, value_enum, default_value_t = MethodArg::Multigrid, help_heading = "Solve")]
    pub method: MethodArg,
    /// Solve: stop at this relative residual.
    #[arg(long, value_name = "R", default_value_t = 1e-6, help_heading = "Solve")]
    pub rtol: f64,
    /// Solve: iteration limit.
    #[arg(long, value_name = "N", default_value_t = 1000, help_heading = "Solve")]
    pub max_iter: u64,
    /// Solve: time between checkpoints (90s, 10m; 0: only when interrupted).
    #[arg(long, value_name = "DURATION", default_value = "5m", value_parser = super::solve::parse_duration, help_heading = "Solve")]
    pub checkpoint_every: f64,
    /// Trace and map: radius of the stop ball, voxels [default: as `harmap trace`].
    #[arg(long, value_name = "VOXELS", help_heading = "Trace and map")]
    pub stop_radius: Option<f64>,
    /// Trace: seeds. Surface: the vertices of the input mesh, or for other inputs of the
    /// labels' surface nets (the summary then has the bijectivity numbers); boundary:
    /// every boundary voxel (fewer steps a line: faster on large grids).
    #[arg(long, value_enum, default_value_t = SeedArg::Surface, help_heading = "Trace and map")]
    pub seeds: SeedArg,
    /// Map: trace from every voxel instead of the upwind transport.
    #[arg(long, help_heading = "Trace and map")]
    pub exact: bool,
}

/// Run `harmap run`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let out = a.output.clone().unwrap_or_else(|| {
        let stem =
            a.input
                .as_ref()
                .and_then(|p| p.file_name())
                .map_or("starfish".to_owned(), |n| {
                    let n = n.to_string_lossy();
                    n.split('.').next().unwrap_or("shape").to_owned()
                });
        PathBuf::from(format!("{stem}.harmap"))
    });
    let (mut opts, iopts): (_, InputOptions) = a.opts.options()?;
    if a.input.is_none() && opts.center.is_none() {
        // The starfish is symmetric about the origin: its middle is the natural center
        // (the deepest voxel lies off-middle, toward an arm's root).
        opts.center = Some([0.0, 0.0, 0.0]);
    }
    let bars = Bars::new(g);
    let done = !a.force && voxelize_done(&out, a.input.as_deref(), &opts)?;
    if done {
        g.say(&format!(
            "voxelize: already done in {} (skipped; --force redoes it)",
            out.display()
        ));
    } else {
        let source = a
            .input
            .as_ref()
            .map_or(Source::Starfish, |p| Source::File(p, &iopts));
        let (_, r) = voxelize_new_run(&source, &opts, &out, a.force, &bars)
            .with_context(|| format!("voxelizing into {}", out.display()))?;
        let s = r.grid.shape;
        g.say(&format!(
            "voxelize: {} x {} x {} voxels, {} solid, genus {}, center ({:.3}, {:.3}, {:.3}), {:.2}s",
            s[2],
            s[1],
            s[0],
            r.counts[1] + r.counts[2] + r.counts[3],
            r.genus,
            r.center[0],
            r.center[1],
            r.center[2],
            r.timings.iter().map(|t| t.1).sum::<f64>()
        ));
        if let Some(p) = r.probe_summary() {
            g.say(&format!("voxelize: {p}"));
        }
    }
    let run = harmap::run::RunDir::open(&out).map_err(harmap::Error::from)?;
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    if harmap::run::stage_done(&attrs, "solve") {
        g.say("solve: already done (skipped; --force redoes every stage)");
    } else {
        // Continue an interrupted solve from its checkpoint when there is one.
        let resume = out.join("solve/manifest.json").exists();
        let opts = SolveArgs {
            method: a.method,
            rtol: a.rtol,
            tol: 0.0,
            eps: 1e-4,
            max_iter: a.max_iter,
            omega: None,
            checkpoint_every: a.checkpoint_every,
            mem: a.opts.mem,
        }
        .options(resume);
        let stop = super::solve::stop_flag()?;
        let t = std::time::Instant::now();
        let r = harmap::solve::solve(&run, &opts, &stop, &Bars::new(g))?;
        g.say(&format!(
            "solve: {}",
            super::solve::summary(&r, t.elapsed().as_secs_f64())
        ));
    }
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    if harmap::run::stage_done(&attrs, "trace") && out.join("seeds").exists() {
        g.say("trace: already done (skipped; --force redoes every stage)");
    } else {
        let seeds = a.seeds.kind();
        let opts = harmap::trace::TraceOptions {
            stop_radius: a.stop_radius,
            mem: a.opts.mem,
            ..harmap::trace::TraceOptions::for_seeds(seeds)
        };
        let t = std::time::Instant::now();
        let r = harmap::trace::trace(&run, &opts, &Bars::new(g))?;
        g.say(&format!(
            "trace: {}",
            super::trace::summary(&r, t.elapsed().as_secs_f64())
        ));
    }
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    if harmap::run::stage_done(&attrs, "map") && out.join("theta").exists() {
        g.say("map: already done (skipped; --force redoes every stage)");
    } else {
        let stop_radius = attrs
            .pointer("/stages/trace/options/stop_radius")
            .and_then(serde_json::Value::as_f64);
        let opts = super::map::MapArgs {
            exact: a.exact,
            mem: a.opts.mem,
        }
        .options(stop_radius);
        let t = std::time::Instant::now();
        let r = harmap::map::map(&run, &opts, &Bars::new(g))?;
        g.say(&format!(
            "map: {}",
            super::map::summary(&r, t.elapsed().as_secs_f64())
        ));
    }
    let atlas = out.with_extension("atlas.png");
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    let by = harmap::report::default_coloring(&attrs);
    if let Err(e) = harmap::report::atlas(&run, &atlas, false, &by) {
        // A molecule's residues color its atlas when they can be had; the axis does
        // otherwise (a file without residue numbers, or moved since the voxelization).
        if by == harmap::report::ColorBy::Axis || !e.is_bad_input() {
            return Err(e.into());
        }
        eprintln!("warning: atlas colored by the main axis: {e}");
        harmap::report::atlas(&run, &atlas, false, &harmap::report::ColorBy::Axis)?;
    }
    // The report page beside the atlas. (When `harmap run` moves into
    // harmap::pipeline::run, this call goes with it.)
    let page = super::report::default_path(&out);
    harmap::report::html::write_report(&run, &page)?;
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    let secs = |s: &str| {
        attrs
            .pointer(&format!("/stages/{s}/seconds"))
            .and_then(serde_json::Value::as_f64)
            .unwrap_or(f64::NAN)
    };
    let trace = attrs.pointer("/stages/trace/result");
    let num = |p: &str| {
        trace
            .and_then(|t| t.pointer(p))
            .cloned()
            .unwrap_or_default()
    };
    let bijectivity = match trace
        .and_then(|t| t.get("surface"))
        .filter(|s| !s.is_null())
    {
        Some(_) => format!(
            "{} of {} surface triangles flipped on the sphere, {} colliding seeds",
            num("/surface/flipped"),
            num("/surface/measured"),
            num("/collisions/seeds")
        ),
        None => format!("{} colliding seeds", num("/collisions/seeds")),
    };
    let mapped = attrs
        .pointer("/stages/map/result")
        .map(|m| format!("{} of {} voxels", m["mapped"], m["voxels"]))
        .unwrap_or_default();
    g.say(&format!(
        "{}: done. Seconds per stage: voxelize {:.2}, solve {:.2}, trace {:.2}, map {:.2}.\n  \
         {:.3}% of the streamlines reached the center; {bijectivity}; {mapped} mapped.\n  \
         fields: {0}/phi, {0}/theta, {0}/psi (Zarr); seed table: {0}/seeds; atlas: {}; report: {}\n  \
         `harmap info {0}` shows the numbers; `harmap export {0} --format nifti|vti|csv|...` exports.",
        out.display(),
        secs("voxelize"),
        secs("solve"),
        secs("trace"),
        secs("map"),
        100.0 * num("/reached_fraction").as_f64().unwrap_or(f64::NAN),
        atlas.display(),
        page.display(),
    ));
    Ok(())
}

fn voxelize_done(
    out: &std::path::Path,
    input: Option<&std::path::Path>,
    opts: &harmap::voxelize::VoxelizeOptions,
) -> anyhow::Result<bool> {
    let Some(attrs) = RunDir::open(out).ok().and_then(|r| r.attrs().ok()) else {
        return Ok(false);
    };
    if !harmap::run::stage_done(&attrs, "voxelize") {
        return Ok(false);
    }
    let same_input = match input {
        None => attrs.pointer("/input/builtin").is_some(),
        Some(p) => {
            harmap::input::sha256_file(p).ok().as_deref()
                == attrs.pointer("/input/sha256").and_then(|s| s.as_str())
        }
    };
    let same_opts =
        attrs.pointer("/stages/voxelize/options") == serde_json::to_value(opts).ok().as_ref();
    if same_input && same_opts {
        return Ok(true);
    }
    Err(UsageError(format!(
        "{} holds a run of another {}; pass --force to redo it, or choose another -o",
        out.display(),
        if same_input {
            "set of options"
        } else {
            "input"
        }
    ))
    .into())
}
