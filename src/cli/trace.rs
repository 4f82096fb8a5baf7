//! `harmap trace`.

use std::fmt::Write as _;
use std::path::PathBuf;

use harmap::grid::MemBudget;
use harmap::run::RunDir;
use harmap::trace::{trace, Rk45, SeedKind, TraceOptions, TraceReport, DEFAULT_SEEDS};

use super::progress::Bars;
use super::Global;

/// Trace streamlines from the boundary down -grad(phi) to the center (the paper's steps
/// 6-8) and record where each arrives.
///
/// The direction field is the quadratic B-spline of phi's unit node directions of
/// descent; the integrator is Dormand-Prince RK45 with error control. Surface seeds
/// then step on levels of ln(1 - phi) (--level-step), which keeps neighbouring
/// streamlines in order where they converge. A streamline stops in the stop
/// ball around the center (reached), or else says why: it left the domain, stalled on a
/// vanishing gradient, or used its steps. The arrival direction from the center gives
/// theta (polar) and psi (azimuth): the seed's place on the unit sphere.
///
/// Seeds (as in `harmap run`): by default the vertices of a surface: the input mesh's
/// own, or for label volumes and molecules a surface extracted from the labels (surface
/// nets, on the boundary between the solid's voxels and the outside). Its triangles
/// give the bijectivity numbers: triangles flipped on the sphere, seeds landing on seeds
/// from elsewhere, and area and angle distortion. --seeds boundary traces from every
/// boundary voxel instead (no triangles, so no flip count).
///
/// The grid is cut into tiles; tiles with streamlines waiting are built into a cache
/// that stays within --mem and processed in parallel. Results do not depend on the tile
/// size or the number of threads.
///
/// The table goes to RUN/seeds/ (Zarr arrays position, theta, psi, phi, stop, steps,
/// length, end); `harmap info RUN` shows the counts, `harmap atlas RUN -o atlas.png`
/// draws it, `harmap export RUN --format csv|obj-sphere|vtk-streamlines` exports it.
///
/// Examples:
///   harmap trace spot.harmap
///   harmap trace spot.harmap --seeds boundary
///   harmap trace big.harmap --sample 50000 --mem 256MiB
///   harmap trace spot.harmap --atol 1e-5       # faster, a noisier sphere map
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (voxelized and solved).
    pub run: PathBuf,
    #[command(flatten)]
    pub opts: TraceArgs,
    /// Error allowed per voxel of step, on top of --atol: a step of h voxels may err by
    /// atol + rtol * h.
    #[arg(long, value_name = "FRACTION", default_value_t = Rk45::default().rtol, help_heading = "Integrator")]
    pub rtol: f64,
    /// Memory budget: peak resident memory (e.g. 256MiB, 2GiB).
    #[arg(long, value_name = "SIZE", default_value_t = MemBudget::default())]
    pub mem: MemBudget,
}

/// Trace flags, shared with `harmap run` (which flattens them under "Trace"; the
/// integrator's --rtol is `--trace-rtol` there, --rtol being the solve's). The
/// defaults are [`TraceOptions`]' and [`Rk45`]'s.
#[derive(clap::Args, Debug, Clone)]
#[command(next_help_heading = "Trace")]
pub struct TraceArgs {
    /// Seeds: the vertices of the input surface (of the labels' surface nets for inputs
    /// that are not meshes), whose triangles give the bijectivity numbers, or every
    /// boundary voxel.
    #[arg(long, value_enum, default_value_t = SeedArg::from(DEFAULT_SEEDS))]
    pub seeds: SeedArg,
    /// Trace a deterministic subset of N seeds (the same N gives the same seeds).
    #[arg(long, value_name = "N")]
    pub sample: Option<u64>,
    /// Radius of the stop ball around the center, voxels [default: 4 times the
    /// voxelization's center radius, at most half the center's depth].
    #[arg(long, value_name = "VOXELS")]
    pub stop_radius: Option<f64>,
    /// Tile edge, voxels [default: phi's chunk edge]. Results do not depend on it.
    #[arg(long, value_name = "VOXELS", hide_short_help = true)]
    pub tile: Option<u64>,
    /// Error allowed per RK45 step, voxels [default: 1e-6 for boundary seeds, 1e-8 for
    /// surface seeds]. The arrival angles on the ball are the same from 1e-6 to 1e-8;
    /// a mesh's sphere map is not: its smallest triangles flip where neighbouring
    /// streamlines differ by the step control's noise (spot: 60 flipped at 1e-6, 14 at
    /// 1e-8; docs/trace.md).
    #[arg(long, value_name = "VOXELS", help_heading = "Integrator")]
    pub atol: Option<f64>,
    /// Smallest step, voxels; a streamline that needs a smaller one stops (stalled or
    /// left the domain).
    #[arg(long, value_name = "VOXELS", default_value_t = Rk45::default().h_min, help_heading = "Integrator")]
    pub h_min: f64,
    /// Largest step, voxels (at most 16; tiles hold 1.5 h-max + 2 nodes of halo).
    #[arg(long, value_name = "VOXELS", default_value_t = Rk45::default().h_max, help_heading = "Integrator")]
    pub h_max: f64,
    /// Steps allowed per streamline (then it stops with step_limit).
    #[arg(long, value_name = "N", default_value_t = Rk45::default().max_steps, help_heading = "Integrator")]
    pub max_steps: u32,
    /// Step on levels of ln u (u = 1 - phi), this much ln u per step (1e-4 to 1), after
    /// the first 2 voxels; 0 for off [default: 0.05 for surface seeds, off for boundary
    /// seeds]. Neighbouring streamlines then land on the same level after every step
    /// (split where one would be longer than --h-max), which keeps their order where
    /// they converge to 1e-6 voxel apart (cactus10k at resolution 128: no flipped
    /// triangles, against 1,779 on RK45's own steps; docs/trace.md). It takes 2-4 times
    /// the steps.
    #[arg(long, value_name = "LN_U", help_heading = "Integrator")]
    pub level_step: Option<f64>,
    /// Keep the streamlines' arrivals as the sphere map, flips and all. By default the
    /// sphere map of surface seeds (without --sample) is untangled where its flat
    /// triangles turn over: the vertices of flipped triangles move toward the point
    /// that maximizes the smallest area of their triangles, and where that is not
    /// enough a region around them is re-embedded inside its fixed boundary (mean value
    /// weights, so vertices whose rings are laid down well stay), then every moved
    /// vertex goes back toward its arrival as far as no triangle turns over. theta and
    /// psi are then the untangled map, the arrivals are kept as arrival_theta and
    /// arrival_psi, and the report says how many seeds moved and how far (blub at 128:
    /// 445 flips to 0, 469 of 7,106 seeds moved, median 0.006 degrees; docs/trace.md,
    /// Untangling).
    #[arg(long, conflicts_with = "untangle")]
    pub no_untangle: bool,
    /// Untangle the sphere map (the default for surface seeds without --sample); an
    /// error with boundary seeds or --sample, which give no whole surface.
    #[arg(long)]
    pub untangle: bool,
}

impl From<SeedKind> for SeedArg {
    fn from(k: SeedKind) -> Self {
        match k {
            SeedKind::Boundary => SeedArg::Boundary,
            SeedKind::Surface => SeedArg::Surface,
        }
    }
}

impl SeedArg {
    /// The library's seed kind.
    #[must_use]
    pub fn kind(self) -> SeedKind {
        match self {
            SeedArg::Boundary => SeedKind::Boundary,
            SeedArg::Surface => SeedKind::Surface,
        }
    }
}

/// `--seeds` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum SeedArg {
    /// Every boundary voxel.
    Boundary,
    /// The vertices of the input mesh (or the built-in starfish); for other inputs, of
    /// the surface nets of the labels.
    Surface,
}

impl TraceArgs {
    /// Refuse `--untangle` where there is no whole surface to untangle.
    ///
    /// # Errors
    /// [`harmap::trace::TraceError::Options`] with boundary seeds or `--sample`.
    pub fn check(&self) -> Result<(), harmap::Error> {
        if self.untangle && (self.seeds.kind() != SeedKind::Surface || self.sample.is_some()) {
            return Err(harmap::trace::TraceError::Options(
                "--untangle works on the whole surface's sphere map: use it with surface seeds \
                 (the default) and without --sample"
                    .into(),
            )
            .into());
        }
        Ok(())
    }

    /// The library options, with the integrator's relative tolerance `rtol` and the
    /// memory budget `mem`.
    #[must_use]
    pub fn options(&self, rtol: f64, mem: MemBudget) -> TraceOptions {
        let seeds = self.seeds.kind();
        let default = Rk45::for_seeds(seeds);
        TraceOptions {
            seeds,
            sample: self.sample,
            stop_radius: self.stop_radius,
            tile: self.tile,
            untangle: !self.no_untangle && seeds == SeedKind::Surface && self.sample.is_none(),
            mem,
            rk: Rk45 {
                atol: self.atol.unwrap_or(default.atol),
                rtol,
                h_min: self.h_min,
                h_max: self.h_max,
                max_steps: self.max_steps,
                level_step: self.level_step.unwrap_or(default.level_step),
                level_after: default.level_after,
            },
        }
    }
}

/// One line about a finished trace.
#[must_use]
pub fn summary(r: &TraceReport, seconds: f64) -> String {
    let mut s = format!(
        "{} streamlines in {seconds:.2} s ({:.0}/s), {:.2}% reached the center",
        r.seeds,
        r.lines_per_second,
        100.0 * r.reached_fraction
    );
    let others: Vec<String> = r
        .stops
        .iter()
        .filter(|(k, v)| **k != "reached" && **v > 0)
        .map(|(k, v)| format!("{v} {k}"))
        .collect();
    if !others.is_empty() {
        let _ = write!(s, " ({})", others.join(", "));
    }
    let _ = write!(s, ", {:.0} steps per line", r.mean_steps);
    if let Some(m) = &r.surface {
        let _ = write!(
            s,
            "; {} of {} triangles flipped, median conformal distortion {:.2}",
            m.flipped, m.measured, m.conformal.p50
        );
    }
    if let Some(u) = &r.untangle {
        let _ = write!(s, " ({})", untangled(u));
    }
    let _ = write!(s, "; {} colliding seeds", r.collisions.seeds);
    s
}

/// What untangling changed, in words.
#[must_use]
pub fn untangled(u: &harmap::trace::untangle::UntangleReport) -> String {
    format!(
        "untangled from {} flipped and {} degenerate as the streamlines arrived: {} seeds moved, median {:.3} and at most {:.2} degrees{}",
        u.flipped_arrivals,
        u.degenerate_arrivals,
        u.seeds_moved,
        u.median_move_deg,
        u.max_move_deg,
        if u.out_of_work {
            "; stopped at its work bound"
        } else {
            ""
        }
    )
}

/// Run `harmap trace`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    a.opts.check()?;
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    let opts = a.opts.options(a.rtol, a.mem);
    let attrs = run.attrs().map_err(harmap::Error::from)?;
    harmap::pipeline::check_stop_radius(&attrs, opts.stop_radius)?;
    let t = std::time::Instant::now();
    let r = trace(&run, &opts, &Bars::new(g))?;
    g.say(&format!(
        "{}: {}; table in {}",
        a.run.display(),
        summary(&r, t.elapsed().as_secs_f64()),
        run.root().join("seeds").display()
    ));
    Ok(())
}
