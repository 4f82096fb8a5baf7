//! `trace`: seeds -> streamlines -> the seed table `RUN/seeds/` and `stages.trace`.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::integrate::{Line, Rk45, Stop, StopBall};
use super::metrics::{self, Collisions, SurfaceMetrics};
use super::seeds::{self, SeedKind};
use super::surface::Boundary;
use super::table::write_seeds;
pub use super::table::{read_seeds, SeedTable};
use super::tiles::{footprint, trace_tiled, TileStats, Tiling};
use super::untangle;
use crate::grid::{BlockStore, GridError, GridSpec, MemBudget};
use crate::progress::Progress;
use crate::run::RunDir;

/// Options of `harmap trace`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TraceOptions {
    /// Boundary voxels or surface vertices.
    pub seeds: SeedKind,
    /// Trace a deterministic subset of this many seeds.
    pub sample: Option<u64>,
    /// Radius of the stop ball around the center, voxels (default: 4 center radii, at
    /// most half the center's depth, at least the center radius plus one).
    pub stop_radius: Option<f64>,
    /// The integrator.
    pub rk: Rk45,
    /// Tile edge in voxels (default: the chunk edge of phi). Results do not depend on it.
    pub tile: Option<u64>,
    /// Untangle the sphere map ([`untangle`]) when the seeds are a whole surface (surface
    /// seeds without a sample; no effect otherwise), keeping the arrivals beside it. On
    /// in [`TraceOptions::for_seeds`] of surface seeds, the commands' default. Recorded
    /// only when on, so runs traced before it keep their options.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub untangle: bool,
    /// Memory budget.
    #[serde(skip)]
    pub mem: MemBudget,
}

/// The seeds `harmap trace` and `harmap run` use by default: the vertices of the input
/// surface (or of the labels' surface nets), whose triangles give the bijectivity
/// numbers (flipped triangles). `TraceOptions::for_seeds(DEFAULT_SEEDS)` are those
/// commands' default options.
pub const DEFAULT_SEEDS: SeedKind = SeedKind::Surface;

/// Boundary seeds with [`Rk45::default`] (the library's plain integrator, which tests
/// and benchmarks build on); the commands' defaults are
/// `TraceOptions::for_seeds(DEFAULT_SEEDS)`, which also picks the seeds' tolerance.
impl Default for TraceOptions {
    fn default() -> Self {
        Self {
            seeds: SeedKind::Boundary,
            sample: None,
            stop_radius: None,
            rk: Rk45::default(),
            tile: None,
            untangle: false,
            mem: MemBudget::default(),
        }
    }
}

impl TraceOptions {
    /// The default options for `seeds` (the integrator of [`Rk45::for_seeds`], and
    /// untangling for surface seeds).
    #[must_use]
    pub fn for_seeds(seeds: SeedKind) -> Self {
        Self {
            seeds,
            rk: Rk45::for_seeds(seeds),
            untangle: seeds == SeedKind::Surface,
            ..Self::default()
        }
    }
}

/// Errors of the trace stage.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// Options or inputs that cannot work.
    #[error("{0}")]
    Options(String),
}

/// What a trace did.
#[derive(Clone, Debug, Serialize)]
pub struct TraceReport {
    /// Seeds traced.
    pub seeds: u64,
    /// Seeds of this kind in the run (before sampling).
    pub seeds_available: u64,
    /// Streamlines per stop reason.
    pub stops: BTreeMap<&'static str, u64>,
    /// Share of seeds that reached the center.
    pub reached_fraction: f64,
    /// Mean accepted steps per streamline.
    pub mean_steps: f64,
    /// Mean arc length per streamline (voxels).
    pub mean_length: f64,
    /// The stop ball's radius (voxels).
    pub stop_radius: f64,
    /// Tile edge (voxels).
    pub tile: u64,
    /// Tiles and chunks the cache held.
    pub cache: [usize; 2],
    /// Scheduler counters.
    pub tiles: TileStats,
    /// Seeds landing within a tiny angle of seeds from elsewhere.
    pub collisions: Collisions,
    /// Seeds whose stored arrival directions equal those of a seed from elsewhere.
    pub indistinguishable: metrics::Indistinguishable,
    /// Flips and distortion of the stored sphere map, for surface seeds (after
    /// [`untangle`] when it ran).
    pub surface: Option<SurfaceMetrics>,
    /// With `untangle`: what untangling the surface's sphere map changed (the flips of
    /// the streamlines' arrivals, the seeds moved).
    pub untangle: Option<untangle::UntangleReport>,
    /// Streamlines per second (tracing only).
    pub lines_per_second: f64,
    /// The direction field the streamlines followed ([`crate::trace::field::FIELD`]).
    pub field: &'static str,
    /// Where its boundary nodes' sub-voxel values came from ([`Boundary::name`]).
    pub boundary: &'static str,
    /// For surface seeds, whose vertices they are: "input mesh" or "surface nets of the
    /// labels".
    pub seed_surface: Option<&'static str>,
}

fn options(msg: String) -> crate::Error {
    TraceError::Options(msg).into()
}

/// Everything a trace needs from the run, and the tracing itself, without writing:
/// seeds in voxel coordinates, the outcome of each, and the streamline points when
/// `record_paths`. Used by `trace` and by the streamline export.
pub struct Traced {
    /// Seeds (voxel coordinates x, y, z).
    pub seeds: Vec<DVec3>,
    /// Surface vertex per seed (surface seeds only).
    pub vertex: Vec<u32>,
    /// The surface, for surface seeds.
    pub surface: Option<crate::input::TriMesh>,
    /// How each streamline ended.
    pub outcomes: Vec<super::tiles::Outcome>,
    /// phi at each seed.
    pub phi: Vec<f64>,
    /// Points per streamline (voxel coordinates), when asked for.
    pub paths: Option<Vec<Vec<DVec3>>>,
    /// Seeds of this kind before sampling.
    pub available: u64,
    /// The stop ball.
    pub ball: StopBall,
    /// Tile edge and cache sizes.
    pub tiling: Tiling,
    /// Scheduler counters.
    pub stats: TileStats,
    /// Seconds spent tracing.
    pub seconds: f64,
    /// For surface seeds, whether their surface is the input mesh.
    pub input_mesh: bool,
    /// Where the field's boundary values came from ([`Boundary::name`]).
    pub boundary: &'static str,
}

/// The stop ball of a solved run: radius `stop_radius` voxels, or by default 4 center
/// radii, within half the center's depth for thin shapes, never inside the sink.
pub fn stop_ball(
    attrs: &Value,
    spec: &GridSpec,
    stop_radius: Option<f64>,
    root: &Path,
) -> Result<StopBall, crate::Error> {
    /// The voxelization's center radius (an option) and the center's depth (its
    /// report; an infinite depth is stored as null).
    #[derive(Deserialize)]
    struct Center {
        center_radius: Option<f64>,
        center_depth: Option<f64>,
    }
    let read = |v: Option<Center>| {
        v.unwrap_or(Center {
            center_radius: None,
            center_depth: None,
        })
    };
    let center_radius = read(crate::run::options_in(attrs, "voxelize"))
        .center_radius
        .unwrap_or(2.0);
    let depth = read(crate::run::report_in(attrs, "voxelize"))
        .center_depth
        .unwrap_or(f64::INFINITY);
    let radius = stop_radius.unwrap_or_else(|| {
        let least = center_radius + 1.0;
        (4.0 * center_radius.max(1.0)).min(0.5 * depth).max(least)
    });
    if !(radius.is_finite() && radius > 0.0) {
        return Err(options(format!(
            "--stop-radius {radius}: give a positive number of voxels"
        )));
    }
    let center: [f64; 3] = attrs
        .get("center")
        .and_then(|v| serde_json::from_value(v.clone()).ok())
        .ok_or_else(|| options(format!("{}: the run has no center", root.display())))?;
    Ok(StopBall {
        center: spec.world_to_voxel(DVec3::from_array(center)),
        radius,
    })
}

/// Everything needed to trace streamlines on a solved run: the stored u = 1 - phi, the
/// integrator, the stop ball and the tiling within the budget.
pub struct Tracer {
    /// u = 1 - phi (the solve stores it because it keeps its precision where phi is
    /// within 1e-16 of 1).
    pub u: crate::grid::ZarrStore<f64>,
    /// The integrator.
    pub rk: Rk45,
    /// The stop ball.
    pub ball: StopBall,
    /// Tile edge and cache sizes.
    pub tiling: Tiling,
    /// Where the boundary nodes' sub-voxel values come from.
    pub boundary: Boundary,
}

impl Tracer {
    /// Set up tracing of up to `lines` streamlines at once on `run` within `opts.mem`,
    /// with the boundary of the run's input ([`Boundary::for_run`]).
    pub fn new(run: &RunDir, opts: &TraceOptions, lines: u64) -> Result<Self, crate::Error> {
        let attrs = run.require_stage("solve")?;
        let boundary = Boundary::for_run(&attrs, &run.grid()?, opts.mem);
        Self::with_boundary(run, opts, lines, boundary)
    }

    /// [`Tracer::new`] with a boundary at hand.
    pub fn with_boundary(
        run: &RunDir,
        opts: &TraceOptions,
        lines: u64,
        boundary: Boundary,
    ) -> Result<Self, crate::Error> {
        Self::holding(run, opts, lines, 0, boundary)
    }

    /// [`Tracer::with_boundary`] next to `held` bytes that the caller keeps for the
    /// whole trace (the seeds and their surface, [`held_bytes`]): the tiles get what
    /// is left of the budget.
    pub fn holding(
        run: &RunDir,
        opts: &TraceOptions,
        lines: u64,
        held: u64,
        boundary: Boundary,
    ) -> Result<Self, crate::Error> {
        let attrs = run.require_stage("solve")?;
        if !run.has_image("u") {
            return Err(options(format!(
                "{}: solved by an older harmap that did not store u = 1 - phi; run `harmap solve` again",
                run.root().display()
            )));
        }
        let spec = run.grid()?;
        let u = run.open_image::<f64>("u")?;
        let rk = opts.rk;
        if let Some(why) = rk.problem() {
            return Err(options(why));
        }
        let ball = stop_ball(&attrs, &spec, opts.stop_radius, run.root())?;
        let edge = opts
            .tile
            .unwrap_or(u.spec().chunk.iter().copied().max().unwrap_or(64));
        if edge == 0 {
            return Err(options(
                "--tile 0: give a tile edge of at least 1 voxel".into(),
            ));
        }
        let halo = Tiling::halo_for(&rk);
        let (tile_bytes, build_bytes, chunk_bytes) = footprint(edge, halo, u.spec());
        // The lines in flight, the boundary's mesh index and what the caller holds stay
        // for the whole trace.
        let line_bytes = lines * LINE_BYTES + boundary.bytes() + held;
        let threads = rayon::current_num_threads() as u64;
        // Every thread may be building a tile at once.
        let work = opts
            .mem
            .work_bytes()
            .saturating_sub(line_bytes + threads * build_bytes);
        // At least one tile per thread plus a chunk per tile's neighbourhood.
        let need = threads * tile_bytes + 8 * chunk_bytes;
        if work < need {
            let total = need + crate::grid::BASE_BYTES + line_bytes + threads * build_bytes;
            return Err(crate::grid::GridError::Budget {
                budget: opts.mem.to_string(),
                what: "tracing (tiles of node gradients and phi chunks)".into(),
                needed: crate::grid::human(total),
                suggest: crate::grid::human(total.next_power_of_two()),
            }
            .into());
        }
        let tiles_total = spec.shape.iter().map(|n| n.div_ceil(edge)).product::<u64>();
        let cache_chunks = ((work / 3) / chunk_bytes).clamp(8, spec.num_blocks().max(8)) as usize;
        let cache_tiles = (((work - cache_chunks as u64 * chunk_bytes) / tile_bytes).max(threads))
            .min(tiles_total)
            .min(Tiling::keep_for(threads as usize) as u64) as usize;
        let tiling = Tiling {
            grid: spec.shape,
            edge,
            halo,
            cache_tiles,
            cache_chunks,
            wave: Tiling::wave_for(threads as usize),
        };
        Ok(Self {
            u,
            rk,
            ball,
            tiling,
            boundary,
        })
    }

    /// Trace a streamline from each of `seeds` (voxel coordinates x, y, z): how each
    /// ended, the points of each when `record_paths`, and the scheduler counters.
    pub fn trace(
        &self,
        seeds: &[DVec3],
        record_paths: bool,
        progress: &dyn Progress,
    ) -> Result<super::tiles::Traced, GridError> {
        let lines: Vec<Line> = seeds
            .iter()
            .enumerate()
            .map(|(i, &p)| Line::new(i as u32, p, &self.rk))
            .collect();
        trace_tiled(
            &self.u,
            self.boundary.index(),
            &self.tiling,
            &self.rk,
            &self.ball,
            lines,
            record_paths,
            progress,
        )
    }

    /// phi at each point (voxel coordinates), trilinear.
    pub fn phi_at(&self, pts: &[DVec3]) -> Result<Vec<f64>, GridError> {
        seed_phi(&self.u, pts)
    }
}

/// Bytes a streamline in flight holds (queues, outcome, ordering).
pub const LINE_BYTES: u64 = 176;

/// Bytes a seed holds beside its line while tracing: its point (24), surface vertex
/// (4) and phi (8).
pub const SEED_BYTES: u64 = 36;

/// Bytes a seed holds at most after tracing, while [`trace`] measures and writes: its
/// point (24), its row of the seed table (89, and 16 for the arrival angles of surface
/// seeds), its sphere point (32) and the scratch of one measure at a time (the
/// collision search's 16 or the indistinguishable search's 24). The tiles are gone by
/// then, so this is within what the seed and its line held while tracing (checked at
/// compile time).
pub const END_SEED_BYTES: u64 = 24 + 89 + 16 + 32 + 24;
const _: () = assert!(END_SEED_BYTES <= LINE_BYTES + SEED_BYTES);

/// Bytes of the seeds and their surface that [`trace_seeds`] and [`trace`] hold for the
/// whole trace, counted against `--mem` beside the lines: [`SEED_BYTES`] a seed, and for
/// surface seeds the surface (a vertex 24, a triangle 12) and the most the end phase
/// holds beside it: the surface measures' [`metrics::SURFACE_TRIANGLE_BYTES`], or with
/// `untangle` the untangling's index if larger ([`untangle::UNTANGLE_TRIANGLE_BYTES`]
/// and [`untangle::UNTANGLE_VERTEX_BYTES`]).
#[must_use]
pub fn held_bytes(seeds: u64, surface: Option<&crate::input::TriMesh>, untangle: bool) -> u64 {
    let mesh = surface.map_or(0, |m| {
        let (t, v) = (m.triangles.len() as u64, m.vertices.len() as u64);
        let measures = t * metrics::SURFACE_TRIANGLE_BYTES;
        let end = if untangle {
            measures
                .max(t * untangle::UNTANGLE_TRIANGLE_BYTES + v * untangle::UNTANGLE_VERTEX_BYTES)
        } else {
            measures
        };
        v * 24 + t * 12 + end
    });
    seeds * SEED_BYTES + mesh
}

/// Trace the seeds of `run` (see [`trace`]) and return them without writing anything.
pub fn trace_seeds(
    run: &RunDir,
    opts: &TraceOptions,
    record_paths: bool,
    progress: &dyn Progress,
) -> Result<Traced, crate::Error> {
    let attrs = run.require_stage("solve")?;
    let spec = run.grid()?;

    // Seeds. (Whether the surface seeds' mesh is the input's own, which then also
    // gives the field its boundary values.)
    let mut input_mesh = false;
    let (mut seed_pts, mut vertex, surface) = match opts.seeds {
        SeedKind::Boundary => {
            let labels = run.open_image::<u8>("labels")?;
            let workers = rayon::current_num_threads();
            (seeds::boundary(&labels, workers)?, Vec::new(), None)
        }
        SeedKind::Surface => {
            let (mesh, own) = match seeds::seed_surface(run) {
                Err(crate::Error::Trace(TraceError::Options(e))) => {
                    return Err(options(format!(
                        "{e}; surface seeds need it (or use --seeds boundary)"
                    )));
                }
                other => other?,
            };
            input_mesh = own;
            let pts: Vec<DVec3> = mesh
                .vertices
                .iter()
                .map(|&v| spec.world_to_voxel(v))
                .collect();
            let idx: Vec<u32> = (0..pts.len() as u32).collect();
            (pts, idx, Some(mesh))
        }
    };
    let available = seed_pts.len() as u64;
    if let Some(n) = opts.sample {
        let keep = seeds::sample(seed_pts.len(), n as usize);
        seed_pts = keep.iter().map(|&i| seed_pts[i]).collect();
        if !vertex.is_empty() {
            vertex = keep.iter().map(|&i| vertex[i]).collect();
        }
    }
    if seed_pts.is_empty() {
        return Err(options(format!(
            "{}: no seeds to trace",
            run.root().display()
        )));
    }
    let boundary = match &surface {
        Some(mesh) if input_mesh => Boundary::with_mesh(&attrs, &spec, opts.mem, Some(mesh)),
        _ => Boundary::for_run(&attrs, &spec, opts.mem),
    };
    if let Some(problem) = &boundary.problem {
        progress.warn(problem);
    }
    let boundary_name = boundary.name();
    let held = held_bytes(seed_pts.len() as u64, surface.as_ref(), opts.untangle);
    let tracer = Tracer::holding(run, opts, seed_pts.len() as u64, held, boundary)?;
    let tiling = tracer.tiling;
    progress.info(&format!(
        "trace: {} seeds, tiles of {} (+{} halo), cache {} tiles and {} chunks",
        seed_pts.len(),
        tiling.edge,
        tiling.halo,
        tiling.cache_tiles,
        tiling.cache_chunks
    ));
    let t = Instant::now();
    let phi_at = tracer.phi_at(&seed_pts)?;
    // On MPI ranks (without recorded paths) the seeds are traced across the ranks.
    let (outcomes, paths, stats) = if crate::grid::world().parts() > 1 && !record_paths {
        tracer.trace_across(&seed_pts, progress, crate::grid::world())?
    } else {
        tracer.trace(&seed_pts, record_paths, progress)?
    };
    Ok(Traced {
        seeds: seed_pts,
        vertex,
        surface,
        outcomes,
        phi: phi_at,
        paths,
        available,
        ball: tracer.ball,
        tiling,
        stats,
        seconds: t.elapsed().as_secs_f64(),
        input_mesh,
        boundary: boundary_name,
    })
}

/// phi at each seed (voxel coordinates) from the trilinear u. Seeds are grouped by the
/// block of their cell, and the blocks done in parallel; a block is read alone unless
/// one of its seeds weighs a node of the next block (a seed off the nodes in the block's
/// last layer), when the block is read with one more layer.
fn seed_phi(phi: &dyn BlockStore<f64>, pts: &[DVec3]) -> Result<Vec<f64>, GridError> {
    let spec = phi.spec();
    let mut by_block: BTreeMap<u64, Vec<usize>> = BTreeMap::new();
    for (i, p) in pts.iter().enumerate() {
        let v = [p.z.floor(), p.y.floor(), p.x.floor()];
        let b: [u64; 3] =
            std::array::from_fn(|a| (v[a].max(0.0) as u64).min(spec.shape[a] - 1) / spec.chunk[a]);
        by_block.entry(spec.block_linear(b)).or_default().push(i);
    }
    let nb = spec.blocks();
    let groups: Vec<(u64, Vec<usize>)> = by_block.into_iter().collect();
    let workers = rayon::current_num_threads();
    let values = crate::parallel::map_bounded(&groups, workers, |(k, idx)| {
        let b = [k / (nb[1] * nb[2]), (k / nb[2]) % nb[1], k % nb[2]];
        let st = spec.block_start(b).map(|c| c as i64);
        let sh = spec.block_shape(b).map(|c| c as usize);
        let reaches_next = idx.iter().any(|&i| {
            let q = [pts[i].z, pts[i].y, pts[i].x];
            (0..3).any(|a| q[a].floor() as i64 + 1 >= st[a] + sh[a] as i64 && q[a] > q[a].floor())
        });
        let phi_of = |data: &[f64], shape: [usize; 3]| -> Vec<f64> {
            idx.iter()
                .map(|&i| 1.0 - trilinear(data, st, shape, pts[i]))
                .collect()
        };
        Ok::<_, GridError>(if reaches_next {
            let region = phi.read_region(st, sh.map(|c| c + 1), f64::NAN)?;
            phi_of(&region.data, region.shape)
        } else if let Some(mapped) = phi.map_block(b) {
            // Stored raw: read in place, only the pages the seeds touch.
            phi_of(&mapped?, sh)
        } else {
            phi_of(&phi.read_block(b)?, sh)
        })
    })?;
    let mut out = vec![f64::NAN; pts.len()];
    for ((_, idx), v) in groups.iter().zip(values) {
        for (&i, v) in idx.iter().zip(v) {
            out[i] = v;
        }
    }
    Ok(out)
}

/// The trilinear interpolant at `p` of the box `data` (C order, `shape` from grid index
/// `origin`), over the corners that lie in the box and have a value.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn trilinear(data: &[f64], origin: [i64; 3], shape: [usize; 3], p: DVec3) -> f64 {
    let f = [p.z.floor(), p.y.floor(), p.x.floor()];
    let t = [p.z - f[0], p.y - f[1], p.x - f[2]];
    let mut acc = 0.0;
    let mut wsum = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let g = [f[0] as i64 + dz, f[1] as i64 + dy, f[2] as i64 + dx];
                let inside =
                    (0..3).all(|a| g[a] >= origin[a] && g[a] < origin[a] + shape[a] as i64);
                if !inside {
                    continue;
                }
                let l = [0, 1, 2].map(|a| (g[a] - origin[a]) as usize);
                let v = data[(l[0] * shape[1] + l[1]) * shape[2] + l[2]];
                if v.is_nan() {
                    continue;
                }
                let w = crate::math::corner_weight(t, [dz, dy, dx].map(|d| d as usize));
                acc += w * v;
                wsum += w;
            }
        }
    }
    if wsum > 0.0 {
        acc / wsum
    } else {
        f64::NAN
    }
}

/// Trace the run's seeds to the center and write `RUN/seeds/` (staged, renamed when
/// whole) and `harmap.stages.trace`.
pub fn trace(
    run: &RunDir,
    opts: &TraceOptions,
    progress: &dyn Progress,
) -> Result<TraceReport, crate::Error> {
    let t0 = Instant::now();
    // Recorded as it applies: untangling needs a whole surface's seeds.
    let opts = &TraceOptions {
        untangle: opts.untangle && opts.seeds == SeedKind::Surface && opts.sample.is_none(),
        ..opts.clone()
    };
    let _lock = run.lock()?;
    let _staged = run.staged_images(&["seeds"]);
    let spec: GridSpec = run.grid()?;
    let mut tr = trace_seeds(run, opts, false, progress)?;
    let n = tr.seeds.len();
    let c = tr.ball.center;
    // The end phase holds the seed table, the sphere points and one metric's scratch at
    // a time, within what the lines in flight held while tracing (see
    // [`END_SEED_BYTES`]): the outcomes are consumed into the table, and nothing is
    // copied that can be moved.
    let mut table = SeedTable {
        position: tr.seeds.iter().map(|&p| to_world(&spec, p)).collect(),
        phi: std::mem::take(&mut tr.phi),
        vertex: std::mem::take(&mut tr.vertex),
        theta: Vec::with_capacity(n),
        psi: Vec::with_capacity(n),
        arrival_theta: Vec::new(),
        arrival_psi: Vec::new(),
        stop: Vec::with_capacity(n),
        steps: Vec::with_capacity(n),
        length: Vec::with_capacity(n),
        end: Vec::with_capacity(n),
    };
    let mut stops: BTreeMap<&'static str, u64> = Stop::ALL.iter().map(|s| (s.name(), 0)).collect();
    let (mut steps, mut length) = (0u64, 0.0);
    for o in std::mem::take(&mut tr.outcomes) {
        *stops.get_mut(o.stop.name()).expect("every reason") += 1;
        let (theta, psi) = if o.stop == Stop::Reached {
            super::angles(o.end - c)
        } else {
            (f64::NAN, f64::NAN)
        };
        table.theta.push(theta);
        table.psi.push(psi);
        table.stop.push(o.stop as u8);
        table.steps.push(o.steps);
        table.length.push(o.length * spec.spacing);
        table.end.push(to_world(&spec, o.end));
        steps += u64::from(o.steps);
        length += o.length;
    }
    let mut sphere: Vec<Option<DVec3>> = (0..n).map(|i| table.sphere(i)).collect();
    // The collisions measure the squeeze of the streamlines' own arrivals.
    let collisions = metrics::collisions(&tr.seeds, &sphere, 0.05, 5.0);
    // A whole surface's sphere map is untangled where its flat triangles turn over
    // (unless --no-untangle); the arrivals are kept beside it.
    let whole_surface = tr.surface.as_ref().filter(|_| opts.sample.is_none());
    let untangled = whole_surface.filter(|_| opts.untangle).map(|m| {
        let mut r = untangle::untangle(&m.triangles, &mut sphere);
        table.arrival_theta.clone_from(&table.theta);
        table.arrival_psi.clone_from(&table.psi);
        for i in std::mem::take(&mut r.moved) {
            let p = sphere[i as usize].expect("moved seeds reached");
            (table.theta[i as usize], table.psi[i as usize]) = super::angles(p);
        }
        r
    });
    let indistinguishable = metrics::indistinguishable(&tr.seeds, &table.theta, &table.psi);
    let surface = whole_surface.map(|m| metrics::surface(&m.vertices, &m.triangles, &sphere));
    drop(sphere);
    let reached = stops["reached"];
    let report = TraceReport {
        seeds: n as u64,
        seeds_available: tr.available,
        stops,
        reached_fraction: reached as f64 / n as f64,
        mean_steps: steps as f64 / n as f64,
        mean_length: length / n as f64,
        stop_radius: tr.ball.radius,
        tile: tr.tiling.edge,
        cache: [tr.tiling.cache_tiles, tr.tiling.cache_chunks],
        tiles: tr.stats,
        collisions,
        indistinguishable,
        surface,
        untangle: untangled,
        lines_per_second: n as f64 / tr.seconds.max(1e-9),
        field: super::field::FIELD,
        boundary: tr.boundary,
        seed_surface: tr.surface.as_ref().map(|_| {
            if tr.input_mesh {
                "input mesh"
            } else {
                "surface nets of the labels"
            }
        }),
    };
    // On MPI ranks every rank holds the whole table; rank 0 writes it.
    if crate::grid::world().is_root() {
        write_seeds(run.root(), "seeds.partial", &table, opts.seeds)?;
    }
    run.commit_image("seeds")?;
    let seconds = t0.elapsed().as_secs_f64();
    run.record_stage("trace", seconds, opts, &report)?;
    Ok(report)
}

fn to_world(spec: &GridSpec, p: DVec3) -> DVec3 {
    DVec3::from_array(spec.origin) + spec.spacing * p
}
