//! `harmap map`.

use std::fmt::Write as _;
use std::path::PathBuf;

use harmap::grid::MemBudget;
use harmap::map::{map, MapMethod, MapOptions, MapReport};
use harmap::run::RunDir;

use super::progress::Bars;
use super::Global;

/// Give every voxel of the solid its (theta, psi): the direction at which the
/// streamline through it arrives at the center (the paper's steps 8-9). With phi, they
/// place every voxel in the ball: the boundary on the unit sphere, the center at 0.
///
/// Default: upwind transport. The arrival direction is constant along a streamline, so
/// each voxel takes it from its neighbours nearer the center (those of lower phi),
/// starting in the stop ball with the direction from the center; the grid is swept
/// block by block within --mem. Where the upwind direction turns by less than 0.003
/// radians per voxel across the flow (thin arms that squeeze the map, where its small
/// angular error would move a point by voxels), a streamline is traced from the voxel
/// instead; the summary says how many. With --exact, a streamline is traced from every
/// voxel (the reference; much slower).
///
/// Writes RUN/theta/0 and RUN/psi/0 (f64 radians; NaN outside the solid), which
/// `harmap export` turns into NIfTI, VTK image data or OpenDX.
///
/// Examples:
///   harmap map spot.harmap
///   harmap map spot.harmap --exact
///   harmap map big.harmap --mem 256MiB
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The run directory (voxelized and solved).
    pub run: PathBuf,
    #[command(flatten)]
    pub opts: MapArgs,
    /// Memory budget: peak resident memory (e.g. 256MiB, 2GiB).
    #[arg(long, value_name = "SIZE", default_value_t = MemBudget::default())]
    pub mem: MemBudget,
}

/// Map flags, shared with `harmap run` (which flattens them under "Map").
#[derive(clap::Args, Debug, Clone)]
#[command(next_help_heading = "Map")]
pub struct MapArgs {
    /// Trace a streamline from every voxel instead of the upwind transport.
    #[arg(long)]
    pub exact: bool,
}

impl MapArgs {
    /// The library options; the stop ball is the trace's, the budget `mem`.
    #[must_use]
    pub fn options(&self, stop_radius: Option<f64>, mem: MemBudget) -> MapOptions {
        MapOptions {
            method: if self.exact {
                MapMethod::Exact
            } else {
                MapMethod::Upwind
            },
            stop_radius,
            mem,
        }
    }
}

/// One line about a finished map.
#[must_use]
pub fn summary(r: &MapReport, seconds: f64) -> String {
    let mut s = format!(
        "{} of {} voxels mapped in {seconds:.2} s ({:?})",
        r.mapped, r.voxels, r.method
    );
    if let Some(u) = &r.upwind {
        let _ = write!(
            s,
            ", {} from the stop ball, {} upwind, {} filled from neighbours, {} rounds",
            u.from_ball,
            u.upwind,
            u.filled,
            u.rounds[0] + u.rounds[1]
        );
    }
    if let Some(h) = &r.hybrid {
        let _ = write!(
            s,
            "; {} voxels ({:.2}%) traced exactly where the upwind map squeezes (turns by less than {} rad per voxel)",
            h.traced,
            100.0 * h.traced_fraction,
            h.squeeze_below
        );
    }
    if let Some(f) = &r.folded {
        let _ = write!(s, "; {}", folded_line(f));
    }
    if let Some(u) = &r.unfold {
        let _ = write!(s, "; {}", unfold_line(u));
    }
    s
}

/// What unfolding moved.
#[must_use]
pub fn unfold_line(u: &harmap::map::Unfold) -> String {
    format!(
        "unfolded {} folded voxels by moving {} directions (median {:.3}, at most {:.2} degrees)",
        u.folded_before, u.moved, u.median_move_degrees, u.max_move_degrees
    )
}

/// The folded voxels and where the largest clusters of them are.
#[must_use]
pub fn folded_line(f: &harmap::map::Folded) -> String {
    let mut s = format!(
        "{} of {} voxels outside the stop ball folded (negative Jacobian), {} degenerate",
        f.voxels, f.measured, f.degenerate
    );
    if !f.clusters.is_empty() {
        let c: Vec<String> = f
            .clusters
            .iter()
            .map(|c| {
                format!(
                    "{} at ({:.4}, {:.4}, {:.4})",
                    c.voxels, c.center[0], c.center[1], c.center[2]
                )
            })
            .collect();
        let _ = write!(
            s,
            "; largest clusters{}: {}",
            if f.clusters_partial {
                " (of the first voxels)"
            } else {
                ""
            },
            c.join(", ")
        );
    }
    s
}

/// Run `harmap map`.
pub fn run(a: &Args, g: &Global) -> anyhow::Result<()> {
    let run = RunDir::open(&a.run).map_err(harmap::Error::from)?;
    // The trace's stop ball, when the run was traced with one.
    let stop_radius = run.attrs().ok().and_then(|v| {
        harmap::run::stages::options_in::<harmap::trace::TraceOptions>(&v, "trace")
            .and_then(|t| t.stop_radius)
    });
    let t = std::time::Instant::now();
    let r = map(&run, &a.opts.options(stop_radius, a.mem), &Bars::new(g))?;
    // Beside the folded voxels, the sphere map's flipped triangles when traced.
    let flips = run
        .attrs()
        .ok()
        .and_then(|v| harmap::run::report_in::<TracedSurface>(&v, "trace"))
        .and_then(|t| t.surface)
        .map(|m| {
            format!(
                "; the sphere map: {} of {} triangles flipped",
                m.flipped, m.measured
            )
        })
        .unwrap_or_default();
    g.say(&format!(
        "{}: {}{flips}; fields in {} and {}",
        a.run.display(),
        summary(&r, t.elapsed().as_secs_f64()),
        run.root().join("theta").display(),
        run.root().join("psi").display()
    ));
    Ok(())
}

/// The fields of the trace's report that the map's summary shows.
#[derive(serde::Deserialize)]
struct TracedSurface {
    surface: Option<SurfaceFlips>,
}

/// Of the trace report's `surface`.
#[derive(serde::Deserialize)]
struct SurfaceFlips {
    measured: u64,
    flipped: u64,
}
