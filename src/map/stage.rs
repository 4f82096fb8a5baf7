//! The map stage: checks the run, picks the method, holds the budget, and records what
//! it did.

use std::path::Path;
use std::time::Instant;

use super::angles::Angles;
use super::exact::exact;
use super::folds::{folded, Folded, HaloDirections};
use super::squeeze::SQUEEZE_BELOW;
use super::unfold::{unfold, Unfold};
use super::upwind::is_set;
use super::upwind::{self, Directions, TransportStats};
use super::{exact::exact_integrator, Hybrid, MapError, MapMethod, MapOptions, MapReport};
use crate::grid::{
    BlockStore, Decomposition, GridError, GridSpec, MappedStore, MemStore, ZarrStore,
};
use crate::math::Idx3;
use crate::progress::Progress;
use crate::run::RunDir;
use crate::solve::driver::copy_blocks;
use crate::trace::integrate::StopBall;
use crate::trace::surface::Boundary;
use glam::DVec3;
use std::collections::{BTreeMap, HashMap};

/// Compute the map of `run` and write `RUN/theta/0` and `RUN/psi/0`.
pub fn map(
    run: &RunDir,
    opts: &MapOptions,
    progress: &dyn Progress,
) -> Result<MapReport, crate::Error> {
    map_with(run, opts, progress, crate::grid::world())
}

/// [`map`] over the blocks `decomp` owns: each part computes and writes the directions
/// and angles of its blocks (see [`upwind::transport_with`] for what crosses between
/// parts). The counts of the report are this part's.
pub fn map_with(
    run: &RunDir,
    opts: &MapOptions,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<MapReport, crate::Error> {
    let t0 = Instant::now();
    let _lock = run.lock()?;
    let mut staged = run.staged_images(&["theta", "psi"]);
    let attrs = run.require_stage("solve")?;
    if !run.has_image("u") {
        return Err(MapError::NoU {
            run: run.root().to_path_buf(),
        }
        .into());
    }
    // A map killed half-way must not look done: forget the old record first.
    forget_map(run)?;
    let spec = run.grid()?;
    let labels = run.open_image::<u8>("labels")?;
    let ball = stop_ball(run, &attrs, &spec, opts)?;
    let scratch = scratch_of(run, decomp);
    staged.and_scratch(&scratch);
    fresh_dir(&scratch)?;
    let boundary = Boundary::for_run(&attrs, &spec, opts.mem);
    if let Some(problem) = &boundary.problem {
        progress.warn(problem);
    }
    let t = Instant::now();
    let (upwind_stats, stops, hybrid, seconds_directions, (voxels, mapped), folded) =
        match opts.method {
            MapMethod::Upwind => {
                let angles = Angles::<f64>::create(run, &spec)?;
                let dirs = Directions::create(&scratch, &spec, in_memory(&spec, opts))?;
                let s = upwind_map(
                    run, opts, &spec, &labels, &dirs, &ball, &boundary, progress, decomp,
                )?;
                // Where the upwind map squeezes, a streamline from the voxel.
                let traced = exact(
                    run,
                    opts,
                    &labels,
                    &angles,
                    &ball,
                    &boundary,
                    progress,
                    decomp,
                    Some(&dirs),
                )?;
                let seconds = t.elapsed().as_secs_f64();
                let counts = angles.finish(&labels, None, opts.mem, progress, decomp)?;
                let folded = upwind_folds(
                    run,
                    &spec,
                    decomp,
                    &ball,
                    opts,
                    progress,
                    &dirs,
                    traced.dirs.as_ref(),
                )?;
                let hybrid = Hybrid::of(traced.voxels, counts.0);
                (
                    Some(s),
                    Some(traced.stops),
                    Some(hybrid),
                    seconds,
                    counts,
                    folded,
                )
            }
            MapMethod::Exact => {
                let angles = Angles::<f64>::create(run, &spec)?;
                let traced = exact(
                    run, opts, &labels, &angles, &ball, &boundary, progress, decomp, None,
                )?;
                let seconds = t.elapsed().as_secs_f64();
                let counts = angles.finish(&labels, None, opts.mem, progress, decomp)?;
                decomp.barrier()?;
                let folded = exact_folds(run, &spec, decomp, &ball, opts, progress)?;
                (None, Some(traced.stops), None, seconds, counts, folded)
            }
        };
    let (folded, unfold) = unfold_and_count(run, &spec, decomp, &ball, opts, progress, folded)?;
    // theta and psi are whole (unfolded too): publish them.
    run.commit_image("theta")?;
    run.commit_image("psi")?;
    let _ = std::fs::remove_dir_all(&scratch);
    let (upwind_stats, stops, hybrid, (voxels, mapped)) =
        totals(decomp, upwind_stats, stops, hybrid, (voxels, mapped))?;
    let report = MapReport {
        method: opts.method,
        voxels,
        mapped,
        stop_radius: ball.radius,
        upwind: upwind_stats,
        hybrid,
        boundary: boundary.name(),
        integrator: stops.is_some().then(exact_integrator),
        stops,
        seconds_directions,
        folded,
        unfold,
    };
    run.record_stage("map", t0.elapsed().as_secs_f64(), opts, &report)?;
    Ok(report)
}

impl Hybrid {
    /// `traced` voxels of `voxels`, where the upwind map squeezes.
    fn of(traced: u64, voxels: u64) -> Self {
        Self {
            squeeze_below: SQUEEZE_BELOW,
            traced,
            traced_fraction: traced as f64 / voxels.max(1) as f64,
        }
    }
}

/// The stop ball of the run's map. The stop radius is the map's option here: its
/// problems are the map's.
fn stop_ball(
    run: &RunDir,
    attrs: &serde_json::Value,
    spec: &GridSpec,
    opts: &MapOptions,
) -> Result<StopBall, crate::Error> {
    crate::trace::stage::stop_ball(attrs, spec, opts.stop_radius, run.root()).map_err(|e| match e {
        crate::Error::Trace(crate::trace::TraceError::Options(m)) => MapError::Options(m).into(),
        e => e,
    })
}

/// Remove the run's record of a map.
fn forget_map(run: &RunDir) -> Result<(), crate::Error> {
    run.update_attrs(|a| {
        if let Some(s) = a.get_mut("stages").and_then(|s| s.as_object_mut()) {
            s.remove("map");
        }
    })?;
    Ok(())
}

/// The map's scratch folder: `map.scratch` in one process, `map.scratch.K` on MPI rank
/// K of several (each rank has its own).
fn scratch_of(run: &RunDir, decomp: &dyn Decomposition) -> std::path::PathBuf {
    match decomp.parts() {
        1 => run.root().join("map.scratch"),
        _ => run.root().join(format!("map.scratch.{}", decomp.part())),
    }
}

/// The report's counts over every part: each part counted its own blocks (in one
/// process, the counts unchanged). The rounds of the transport are the same on every
/// part (they agree when to stop) and stay.
fn totals(
    decomp: &dyn Decomposition,
    mut upwind: Option<TransportStats>,
    mut stops: Option<BTreeMap<&'static str, u64>>,
    mut hybrid: Option<Hybrid>,
    (voxels, mapped): (u64, u64),
) -> Result<Totals, GridError> {
    if decomp.parts() == 1 {
        return Ok((upwind, stops, hybrid, (voxels, mapped)));
    }
    let mut mine = vec![voxels, mapped];
    if let Some(s) = &upwind {
        mine.extend([s.from_ball, s.upwind, s.filled, s.unreached, s.visits]);
    }
    if let Some(h) = &hybrid {
        mine.push(h.traced);
    }
    if let Some(s) = &stops {
        mine.extend(s.values());
    }
    let total = decomp.sum_u64(&mine)?;
    let mut t = total.into_iter();
    let mut next = || t.next().expect("one total per count");
    let (voxels, mapped) = (next(), next());
    if let Some(s) = &mut upwind {
        s.from_ball = next();
        s.upwind = next();
        s.filled = next();
        s.unreached = next();
        s.visits = next();
    }
    if let Some(h) = &mut hybrid {
        h.traced = next();
        h.traced_fraction = h.traced as f64 / voxels.max(1) as f64;
    }
    if let Some(s) = &mut stops {
        for v in s.values_mut() {
            *v = next();
        }
    }
    Ok((upwind, stops, hybrid, (voxels, mapped)))
}

/// What [`totals`] adds up: the transport's counters, the stop reasons, the traced
/// voxels, and (target voxels, voxels with a direction).
type Totals = (
    Option<TransportStats>,
    Option<BTreeMap<&'static str, u64>>,
    Option<Hybrid>,
    (u64, u64),
);

/// `kept` (this part's traced directions by linear voxel index) with the other parts'
/// traced directions of the voxels next to this part's slab, which the folded voxels'
/// one-voxel halos read. One process: `kept` itself.
fn with_neighbours_traced<'a>(
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    kept: &'a HashMap<u64, DVec3>,
) -> Result<std::borrow::Cow<'a, HashMap<u64, DVec3>>, GridError> {
    if decomp.parts() == 1 {
        return Ok(std::borrow::Cow::Borrowed(kept));
    }
    let plane = spec.shape[1] * spec.shape[2];
    let layers = decomp.z_layers(decomp.part(), spec.blocks());
    // This part's voxel planes [lo, hi) along z (empty when it owns no layer).
    let (lo, hi) = if layers.is_empty() {
        (0, 0)
    } else {
        let end = layers.end - 1;
        (
            spec.block_start([layers.start, 0, 0])[0],
            spec.block_start([end, 0, 0])[0] + spec.block_shape([end, 0, 0])[0],
        )
    };
    // Send the directions of this slab's first and last plane.
    let mut mine = Vec::new();
    for (&k, d) in kept {
        let z = k / plane;
        if hi > lo && (z == lo || z + 1 == hi) {
            mine.extend(k.to_le_bytes());
            for c in d.to_array() {
                mine.extend(c.to_le_bytes());
            }
        }
    }
    let mut all = kept.clone();
    for (part, bytes) in decomp.all_gather_bytes(mine)?.iter().enumerate() {
        if part == decomp.part() || hi == lo {
            continue;
        }
        for e in bytes.chunks_exact(32) {
            let w = |i: usize| e[8 * i..8 * i + 8].try_into().expect("8 bytes");
            let k = u64::from_le_bytes(w(0));
            let z = k / plane;
            if z + 1 == lo || z == hi {
                let d = DVec3::new(
                    f64::from_le_bytes(w(1)),
                    f64::from_le_bytes(w(2)),
                    f64::from_le_bytes(w(3)),
                );
                all.insert(k, d);
            }
        }
    }
    Ok(std::borrow::Cow::Owned(all))
}

/// The default map's folded voxels: from the traced directions `kept` and the upwind
/// field ([`hybrid_folds`]), unless a part could not keep its traced directions (then
/// from the stored angles, [`exact_folds`]). Every part takes the same path.
#[allow(clippy::too_many_arguments)]
fn upwind_folds(
    run: &RunDir,
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    ball: &StopBall,
    opts: &MapOptions,
    progress: &dyn Progress,
    dirs: &Directions,
    kept: Option<&HashMap<u64, DVec3>>,
) -> Result<FoldsFound, crate::Error> {
    let kept_everywhere = decomp.sum_u64(&[u64::from(kept.is_none())])?.first() == Some(&0);
    match kept {
        Some(kept) if kept_everywhere => {
            let kept = with_neighbours_traced(spec, decomp, kept)?;
            hybrid_folds(run, spec, decomp, ball, opts, progress, dirs, &kept)
        }
        _ => {
            decomp.barrier()?;
            exact_folds(run, spec, decomp, ball, opts, progress)
        }
    }
}

/// Where the map folds, move the directions around the folds ([`unfold`]) and count
/// the folded voxels again from the stored angles. Nothing folded: the count as it is.
#[allow(clippy::too_many_arguments)]
fn unfold_and_count(
    run: &RunDir,
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    ball: &StopBall,
    opts: &MapOptions,
    progress: &dyn Progress,
    folded: FoldsFound,
) -> Result<(Option<Folded>, Option<Unfold>), crate::Error> {
    let Some((f, positions)) = folded else {
        return Ok((None, None));
    };
    if f.voxels == 0 {
        return Ok((Some(f), None));
    }
    // The staged angles are read whole: every part has written its blocks.
    decomp.barrier()?;
    let (theta, psi) = (
        run.open_staged_image::<f64>("theta")?,
        run.open_staged_image::<f64>("psi")?,
    );
    let u = run.open_image::<f64>("u")?;
    let labels = run.open_image::<u8>("labels")?;
    let mut report = unfold(
        &u, &labels, &theta, &psi, ball, &positions, decomp, progress,
    )?;
    report.folded_before = f.voxels;
    decomp.barrier()?;
    let t = Instant::now();
    let after = exact_folds(run, spec, decomp, ball, opts, progress)?.map(|(f, _)| f);
    report.seconds_recount = t.elapsed().as_secs_f64();
    Ok((after, Some(report)))
}

/// The default map's folded voxels: from the upwind direction field (raw f32, read
/// with its halo without decoding the angles' chunks; the stored f64 angles are those of
/// its directions) and the traced voxels' directions.
#[allow(clippy::too_many_arguments)]
fn hybrid_folds(
    run: &RunDir,
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    ball: &StopBall,
    opts: &MapOptions,
    progress: &dyn Progress,
    dirs: &Directions,
    traced: &HashMap<u64, DVec3>,
) -> Result<FoldsFound, crate::Error> {
    let halo = |b: Idx3| -> Result<Vec<Option<DVec3>>, GridError> {
        let d = dirs.read_halo_of(b, 1)?;
        let st = spec.block_start(b).map(|c| c as i64 - 1);
        let sh = spec.block_shape(b).map(|c| c as usize + 2);
        let n = spec.shape.map(|c| c as i64);
        Ok(d.iter()
            .enumerate()
            .map(|(i, v)| {
                if !traced.is_empty() {
                    let g = [
                        st[0] + (i / (sh[1] * sh[2])) as i64,
                        st[1] + ((i / sh[2]) % sh[1]) as i64,
                        st[2] + (i % sh[2]) as i64,
                    ];
                    if (0..3).all(|a| g[a] >= 0 && g[a] < n[a]) {
                        let k = ((g[0] * n[1] + g[1]) * n[2] + g[2]) as u64;
                        if let Some(t) = traced.get(&k) {
                            return Some(*t);
                        }
                    }
                }
                is_set(*v).then(|| DVec3::from_array(v.map(f64::from)).normalize())
            })
            .collect())
    };
    folds_with(run, spec, decomp, ball, opts, progress, 12, &halo)
}

/// The folded voxels from the stored f64 angles (staged, not yet published; every
/// part has written its blocks).
fn exact_folds(
    run: &RunDir,
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    ball: &StopBall,
    opts: &MapOptions,
    progress: &dyn Progress,
) -> Result<FoldsFound, crate::Error> {
    let (theta, psi) = (
        run.open_staged_image::<f64>("theta")?,
        run.open_staged_image::<f64>("psi")?,
    );
    let halo = |b: Idx3| -> Result<Vec<Option<DVec3>>, GridError> {
        let th = theta.read_block_halo(b, 1, f64::NAN)?.data;
        let ps = psi.read_block_halo(b, 1, f64::NAN)?.data;
        Ok(th
            .iter()
            .zip(&ps)
            .map(|(&t, &p)| (t.is_finite() && p.is_finite()).then(|| crate::trace::unit(t, p)))
            .collect())
    };
    folds_with(run, spec, decomp, ball, opts, progress, 16, &halo)
}

/// The folded voxels ([`folded`]) of the whole map, counted over the blocks `decomp`
/// owns and gathered (a block's halo reads its neighbours' directions: the upwind
/// field's halos crossed between parts after its last round, the stored angles were
/// committed by every part).
#[allow(clippy::too_many_arguments)]
fn folds_with(
    run: &RunDir,
    spec: &GridSpec,
    decomp: &dyn Decomposition,
    ball: &StopBall,
    opts: &MapOptions,
    progress: &dyn Progress,
    bytes_per_voxel: u64,
    dirs: HaloDirections<'_>,
) -> Result<FoldsFound, crate::Error> {
    let u = run.open_image::<f64>("u")?;
    let labels = run.open_image::<u8>("labels")?;
    let halo = crate::math::volume(spec.chunk.map(|c| c + 2));
    Ok(Some(folded(
        &u,
        &labels,
        dirs,
        halo * (bytes_per_voxel + 24),
        ball,
        decomp,
        opts.mem,
        progress,
    )?))
}

/// The folded voxels counted ([`folded`]) and the first of their positions.
type FoldsFound = Option<(Folded, Vec<[u32; 3]>)>;

/// `dir`, emptied of what an earlier map left or created.
fn fresh_dir(dir: &Path) -> Result<(), GridError> {
    let io = |e| GridError::Io {
        path: dir.to_path_buf(),
        source: e,
    };
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(io)?;
    }
    std::fs::create_dir_all(dir).map_err(io)
}

/// Whether the upwind map's direction field stays in memory: when it takes at most
/// half the budget.
fn in_memory(spec: &GridSpec, opts: &MapOptions) -> bool {
    Directions::bytes(spec) <= opts.mem.work_bytes() / 2
}

/// The upwind map's transport within the budget, with u and the labels copied into
/// memory when they fit, and each block's angles written as soon as its directions are
/// all known.
#[allow(clippy::too_many_arguments)]
fn upwind_map(
    run: &RunDir,
    opts: &MapOptions,
    spec: &GridSpec,
    labels: &ZarrStore<u8>,
    dirs: &Directions,
    ball: &StopBall,
    boundary: &Boundary,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<TransportStats, crate::Error> {
    let u = run.open_image::<f64>("u")?;
    let in_memory = in_memory(spec, opts);
    let held = upwind::held_bytes(spec, ball)
        + boundary.bytes()
        + if in_memory {
            Directions::bytes(spec)
        } else {
            0
        };
    // Blocks are visited more than once, each read with a halo from the
    // neighbouring chunks: when the direction field is in memory and u and the
    // labels fit beside it within half the budget, they are read from the
    // run once, into memory.
    let copies = spec.num_voxels() * (8 + 1);
    let cached = in_memory && held + copies <= opts.mem.work_bytes() / 2;
    let workers = opts.mem.workers(
        "the upwind map (a block of u, labels and directions per worker)",
        held + if cached { copies } else { 0 },
        upwind::worker_bytes(spec.chunk),
        rayon::current_num_threads(),
    )?;
    let transport = |u: &dyn BlockStore<f64>, labels: &dyn BlockStore<u8>| {
        upwind::transport_with(
            u,
            boundary.index(),
            labels,
            dirs,
            ball,
            workers,
            progress,
            None,
            decomp,
        )
    };
    if !cached {
        return Ok(transport(&u, labels)?);
    }
    // u stored raw is read in place, through maps of its chunks kept for the
    // map; otherwise, like the labels, it is copied into memory.
    let mapped = MappedStore::new(&u);
    let held = MemStore::new(spec.clone(), f64::NAN);
    let mu: &dyn BlockStore<f64> = if let Some(m) = &mapped {
        m
    } else {
        copy_blocks(&u, &held, workers)?;
        &held
    };
    let ml = MemStore::new(spec.clone(), 0u8);
    copy_blocks(labels, &ml, workers)?;
    Ok(transport(mu, &ml)?)
}
