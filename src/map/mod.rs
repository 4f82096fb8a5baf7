//! `map`: (theta, psi) for every voxel of the solid (the paper's steps 8-9).
//!
//! - [`upwind`] (default): the arrival direction transported up u = 1 - phi from the
//!   stop ball, block by block; one visit per block and a few rounds.
//! - `exact`: a streamline from every voxel with the tracer of `trace` (the reference).
//!
//! Both write `RUN/theta/0` and `RUN/psi/0` (radians, NaN outside the solid and where no
//! direction was found) and record `harmap.stages.map`. The upwind map writes f32. The
//! exact map writes f64: its streamlines step on levels of ln u from the voxel on, so
//! [`inverse`] can undo them step by step, and down a thin arm neighbouring voxels
//! differ in direction by less than f32 resolves (1e-10 radians and below).

pub mod inverse;
pub mod upwind;

use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::grid::{
    BlockStore, Compression, GridError, MappedStore, MemBudget, MemStore, Scalar, ZarrStore,
};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::run::RunDir;
use crate::solve::driver::copy_blocks;
use crate::trace::integrate::StopBall;
use crate::trace::stage::{Tracer, LINE_BYTES};
use crate::trace::surface::Boundary;
use crate::trace::{Rk45, SeedKind, Stop, TraceOptions};
use upwind::{is_target, Directions, TransportStats};

/// How the full-volume map is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MapMethod {
    /// Upwind transport of the arrival direction (fast).
    #[default]
    Upwind,
    /// A streamline from every voxel (the reference).
    Exact,
}

/// Options of `harmap map`.
#[derive(Clone, Debug, Serialize, Deserialize, Default)]
pub struct MapOptions {
    /// Upwind transport or exact tracing.
    pub method: MapMethod,
    /// Radius of the stop ball (voxels; default as in `trace`). Inside it the direction
    /// is the one from the center.
    pub stop_radius: Option<f64>,
    /// Memory budget.
    #[serde(skip)]
    pub mem: MemBudget,
}

/// What a map did.
#[derive(Clone, Debug, Serialize)]
pub struct MapReport {
    /// The method.
    pub method: MapMethod,
    /// Voxels of the solid (boundary, interior, center).
    pub voxels: u64,
    /// Voxels that have (theta, psi).
    pub mapped: u64,
    /// The stop ball's radius (voxels).
    pub stop_radius: f64,
    /// Upwind counters (upwind method).
    pub upwind: Option<TransportStats>,
    /// Streamlines per stop reason (exact method; voxels inside the stop ball count as
    /// reached without a streamline).
    pub stops: Option<std::collections::BTreeMap<&'static str, u64>>,
    /// Seconds spent computing directions (upwind: with the theta and psi of the blocks
    /// written as they are done, that is nearly all of them).
    pub seconds_directions: f64,
    /// Where the direction field's boundary values came from
    /// ([`crate::trace::surface::Boundary::name`]).
    pub boundary: &'static str,
    /// The integrator of the exact map's streamlines, which `harmap inverse` undoes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub integrator: Option<Rk45>,
}

/// Compute the map of `run` and write `RUN/theta/0` and `RUN/psi/0`.
pub fn map(
    run: &RunDir,
    opts: &MapOptions,
    progress: &dyn Progress,
) -> Result<MapReport, crate::Error> {
    let t0 = Instant::now();
    let _lock = run.lock()?;
    let attrs = run.require_stage("solve")?;
    if !run.root().join("u/0").exists() {
        return Err(crate::trace::TraceError::Options(format!(
            "{}: solved by an older harmap that did not store u = 1 - phi; run `harmap solve` again",
            run.root().display()
        ))
        .into());
    }
    // A map killed half-way must not look done: forget the old record first.
    run.update_attrs(|a| {
        if let Some(s) = a.get_mut("stages").and_then(|s| s.as_object_mut()) {
            s.remove("map");
        }
    })?;
    let spec = run.grid()?;
    let u = run.open_image::<f64>("u")?;
    let labels = run.open_image::<u8>("labels")?;
    let ball = crate::trace::stage::stop_ball(&attrs, &spec, opts.stop_radius, run.root())?;
    let scratch = run.root().join("map.scratch");
    if scratch.exists() {
        std::fs::remove_dir_all(&scratch).map_err(|e| GridError::Io {
            path: scratch.clone(),
            source: e,
        })?;
    }
    std::fs::create_dir_all(&scratch).map_err(|e| GridError::Io {
        path: scratch.clone(),
        source: e,
    })?;
    let boundary = Boundary::for_run(&attrs, &spec, opts.mem);
    if let Some(problem) = &boundary.problem {
        progress.warn(problem);
    }
    let threads = rayon::current_num_threads();
    let t = Instant::now();
    let (upwind_stats, stops, seconds_directions, (voxels, mapped)) = match opts.method {
        MapMethod::Upwind => {
            // The field stays in memory when it takes at most half the budget.
            let in_memory = Directions::bytes(&spec) <= opts.mem.work_bytes() / 2;
            let dirs = Directions::create(&scratch, &spec, in_memory)?;
            let angles = Angles::<f32>::create(run, &spec)?;
            let held = upwind::held_bytes(&spec, &ball)
                + boundary.bytes()
                + if in_memory {
                    Directions::bytes(&spec)
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
                upwind::worker_bytes(spec.chunk) + Angles::<f32>::block_bytes(&spec),
                threads,
            )?;
            // A block's angles are written as soon as all its voxels have a direction,
            // while its data is at hand.
            let sink = |b: Idx3, lab: &[u8], d: &[Vec<f32>; 3]| angles.write(b, lab, d);
            let s = if cached {
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
                copy_blocks(&labels, &ml, workers)?;
                upwind::transport(
                    mu,
                    boundary.index(),
                    &ml,
                    &dirs,
                    &ball,
                    workers,
                    progress,
                    Some(&sink),
                )?
            } else {
                upwind::transport(
                    &u,
                    boundary.index(),
                    &labels,
                    &dirs,
                    &ball,
                    workers,
                    progress,
                    Some(&sink),
                )?
            };
            let seconds = t.elapsed().as_secs_f64();
            let counts = angles.finish(run, &labels, Some(&dirs), opts.mem, progress)?;
            (Some(s), None, seconds, counts)
        }
        MapMethod::Exact => {
            let angles = Angles::<f64>::create(run, &spec)?;
            let stops = exact(run, opts, &labels, &angles, &ball, &boundary, progress)?;
            let seconds = t.elapsed().as_secs_f64();
            let counts = angles.finish(run, &labels, None, opts.mem, progress)?;
            (None, Some(stops), seconds, counts)
        }
    };
    let _ = std::fs::remove_dir_all(&scratch);
    let report = MapReport {
        method: opts.method,
        voxels,
        mapped,
        stop_radius: ball.radius,
        upwind: upwind_stats,
        boundary: boundary.name(),
        integrator: stops.is_some().then(exact_integrator),
        stops,
        seconds_directions,
    };
    run.record_stage("map", t0.elapsed().as_secs_f64(), opts, &report)?;
    Ok(report)
}

/// theta and psi, written block by block: during the transport as blocks are done,
/// then the rest.
struct Angles<T: Scalar> {
    theta: ZarrStore<T>,
    psi: ZarrStore<T>,
    /// Which blocks are written.
    written: Vec<std::sync::atomic::AtomicBool>,
    /// Target voxels and those with a direction, over the written blocks.
    counts: std::sync::Mutex<(u64, u64)>,
}

impl<T: Scalar> Angles<T> {
    fn create(run: &RunDir, spec: &crate::grid::GridSpec) -> Result<Self, crate::Error> {
        let nan = T::from_f64(f64::NAN);
        Ok(Self {
            theta: run.create_image_staged("theta", spec, nan, Compression::Zstd(1))?,
            psi: run.create_image_staged("psi", spec, nan, Compression::Zstd(1))?,
            written: (0..spec.num_blocks())
                .map(|_| std::sync::atomic::AtomicBool::new(false))
                .collect(),
            counts: std::sync::Mutex::new((0, 0)),
        })
    }

    /// Bytes [`Angles::write`] holds for a block: theta, psi, and the labels and
    /// directions it is given.
    fn block_bytes(spec: &crate::grid::GridSpec) -> u64 {
        volume(spec.chunk) * (2 * T::SIZE as u64 + 1 + 12)
    }

    /// Write block `b` from its labels and its [x, y, z] direction components (all three
    /// zero where a voxel has none).
    fn write(&self, b: Idx3, lab: &[u8], d: &[Vec<f32>; 3]) -> Result<(), GridError> {
        // In f32, the precision of the directions and of the stored angles.
        self.write_angles(b, lab, |i| {
            let v = [d[0][i], d[1][i], d[2][i]];
            upwind::is_set(v).then(|| {
                let (t, p) = crate::trace::angles_f32(v);
                (f64::from(t), f64::from(p))
            })
        })
    }

    /// Write block `b` from its labels and the direction of each voxel, if it has one.
    fn write_with(
        &self,
        b: Idx3,
        lab: &[u8],
        dir: impl Fn(usize) -> Option<DVec3>,
    ) -> Result<(), GridError> {
        self.write_angles(b, lab, |i| dir(i).map(crate::trace::angles))
    }

    /// Write block `b` from its labels and the (theta, psi) of each voxel, if it has
    /// them.
    fn write_angles(
        &self,
        b: Idx3,
        lab: &[u8],
        angles: impl Fn(usize) -> Option<(f64, f64)>,
    ) -> Result<(), GridError> {
        let nan = T::from_f64(f64::NAN);
        let mut th = vec![nan; lab.len()];
        let mut ps = vec![nan; lab.len()];
        let (mut n, mut m) = (0, 0);
        for i in 0..lab.len() {
            if !is_target(lab[i]) {
                continue;
            }
            n += 1;
            if let Some((t, p)) = angles(i) {
                th[i] = T::from_f64(t);
                ps[i] = T::from_f64(p);
                m += 1;
            }
        }
        self.theta.write_block(b, &th)?;
        self.psi.write_block(b, &ps)?;
        let i = self.theta.spec().block_linear(b) as usize;
        self.written[i].store(true, std::sync::atomic::Ordering::Relaxed);
        let mut c = self
            .counts
            .lock()
            .expect("no writer panics holding the counts");
        c.0 += n;
        c.1 += m;
        Ok(())
    }

    /// Write the blocks not written yet from `dirs` (without directions where there are
    /// none), publish theta and psi, and return the counts (target voxels, voxels with a
    /// direction).
    fn finish(
        self,
        run: &RunDir,
        labels: &dyn BlockStore<u8>,
        dirs: Option<&Directions>,
        mem: MemBudget,
        progress: &dyn Progress,
    ) -> Result<(u64, u64), crate::Error> {
        let spec = labels.spec().clone();
        let rest: Vec<Idx3> = spec
            .block_indices()
            .into_iter()
            .filter(|b| {
                !self.written[spec.block_linear(*b) as usize]
                    .load(std::sync::atomic::Ordering::Relaxed)
            })
            .collect();
        let workers = mem.workers(
            "writing theta and psi",
            0,
            Self::block_bytes(&spec),
            rayon::current_num_threads(),
        )?;
        progress.start("map (writing theta, psi)", rest.len() as u64);
        map_bounded(&rest, workers, |&b| -> Result<(), GridError> {
            let lab = labels.read_block(b)?;
            match dirs {
                Some(d) => self.write(b, &lab, &d.read(b)?)?,
                None => self.write_with(b, &lab, |_| None)?,
            }
            progress.advance(1);
            Ok(())
        })?;
        progress.finish();
        run.commit_image("theta")?;
        run.commit_image("psi")?;
        Ok(self
            .counts
            .into_inner()
            .expect("no writer panics holding the counts"))
    }
}

/// A block of an exact batch: its index, labels, directions, and (voxel, seed) pairs.
type BatchBlock = (Idx3, Vec<u8>, Vec<Option<DVec3>>, Vec<(usize, usize)>);

/// The integrator of the exact map, which the inverse map undoes: the surface seeds'
/// ([`Rk45::for_seeds`]), on levels of ln u from the voxel on.
#[must_use]
pub fn exact_integrator() -> Rk45 {
    Rk45 {
        level_after: 0.0,
        ..Rk45::for_seeds(SeedKind::Surface)
    }
}

/// The exact map: a streamline from the center of every voxel of the solid outside the
/// stop ball, in batches of whole blocks that fit the budget.
fn exact(
    run: &RunDir,
    opts: &MapOptions,
    labels: &dyn BlockStore<u8>,
    angles: &Angles<f64>,
    ball: &StopBall,
    boundary: &Boundary,
    progress: &dyn Progress,
) -> Result<std::collections::BTreeMap<&'static str, u64>, crate::Error> {
    let spec = labels.spec().clone();
    let batch_lines = ((opts.mem.work_bytes() / 4) / (LINE_BYTES + 40)).clamp(10_000, 4_000_000);
    let topts = TraceOptions {
        stop_radius: Some(ball.radius),
        mem: opts.mem,
        rk: exact_integrator(),
        ..TraceOptions::default()
    };
    let tracer = Tracer::with_boundary(run, &topts, batch_lines, boundary.clone())?;
    let mut stops: std::collections::BTreeMap<&'static str, u64> =
        Stop::ALL.iter().map(|s| (s.name(), 0)).collect();
    let blocks = spec.block_indices();
    let mut i = 0;
    while i < blocks.len() {
        crate::progress::check_interrupt(progress)?;
        // Whole blocks until the batch is full.
        let mut batch: Vec<BatchBlock> = Vec::new();
        let mut seeds: Vec<DVec3> = Vec::new();
        while i < blocks.len() && (batch.is_empty() || (seeds.len() as u64) < batch_lines) {
            let b = blocks[i];
            i += 1;
            let lab = labels.read_block(b)?;
            let st = spec.block_start(b);
            let sh = spec.block_shape(b);
            let mut d = vec![None; lab.len()];
            let mut owners = Vec::new();
            for (k, &l) in lab.iter().enumerate() {
                if !is_target(l) {
                    continue;
                }
                let v = [
                    st[0] + k as u64 / (sh[1] * sh[2]),
                    st[1] + (k as u64 / sh[2]) % sh[1],
                    st[2] + k as u64 % sh[2],
                ];
                let p = DVec3::new(v[2] as f64, v[1] as f64, v[0] as f64);
                let r = p - ball.center;
                if r.length() <= ball.radius {
                    let n = r.length();
                    d[k] = Some(if n > 1e-12 { r / n } else { DVec3::Z });
                    *stops.get_mut("reached").expect("reason") += 1;
                } else {
                    owners.push((k, seeds.len()));
                    seeds.push(p);
                }
            }
            batch.push((b, lab, d, owners));
        }
        if !seeds.is_empty() {
            let (outcomes, _, _) = tracer.trace(&seeds, false, progress)?;
            for (_, _, d, owners) in &mut batch {
                for &(k, s) in owners.iter() {
                    let o = &outcomes[s];
                    *stops.get_mut(o.stop.name()).expect("reason") += 1;
                    if o.stop == Stop::Reached {
                        let r = o.end - ball.center;
                        d[k] = (r.length() > 0.0).then(|| r.normalize());
                    }
                }
            }
        }
        for (b, lab, d, _) in &batch {
            angles.write_with(*b, lab, |i| d[i])?;
        }
    }
    Ok(stops)
}
