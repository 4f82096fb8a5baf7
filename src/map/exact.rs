//! Exact tracing: a streamline from the center of voxels of the solid, with the tracer
//! of `trace`, in batches of whole blocks. The exact map traces every voxel outside the
//! stop ball; the default (hybrid) map only those where the upwind map squeezes
//! ([`super::squeeze`]), and keeps the upwind direction elsewhere.
//!
//! Across processes each part maps the blocks its [`Decomposition`] owns; a streamline
//! crosses into the other parts' blocks only through the tracer's tiles, which read u
//! (written by the solve, complete everywhere).

use std::collections::{BTreeMap, HashMap};

use glam::DVec3;

use super::angles::Angles;
use super::squeeze::{turns_at_least, SQUEEZE_BELOW};
use super::upwind::{is_target, Directions};
use super::MapOptions;
use crate::grid::{BlockStore, Decomposition, GridError};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::run::RunDir;
use crate::trace::integrate::StopBall;
use crate::trace::stage::{Tracer, LINE_BYTES};
use crate::trace::surface::Boundary;
use crate::trace::{Rk45, SeedKind, Stop, TraceOptions};

/// A block of an exact batch: its index, labels, directions, and (voxel, seed) pairs.
type BatchBlock = (Idx3, Vec<u8>, Vec<Option<DVec3>>, Vec<(usize, usize)>);

/// A block prepared: its labels, the directions known without tracing, the voxels
/// (index in the block, point) to trace, and how many lie in the stop ball.
type Prepared = (Vec<u8>, Vec<Option<DVec3>>, Vec<(usize, DVec3)>, u64);

/// The integrator of the exact map, which the inverse map undoes: the surface seeds'
/// ([`Rk45::for_seeds`]), on levels of ln u from the voxel on.
#[must_use]
pub fn exact_integrator() -> Rk45 {
    Rk45 {
        level_after: 0.0,
        ..Rk45::for_seeds(SeedKind::Surface)
    }
}

/// What the tracing did.
pub(super) struct Traced {
    /// Streamlines per stop reason (voxels inside the stop ball count as reached).
    pub(super) stops: BTreeMap<&'static str, u64>,
    /// Voxels traced (outside the stop ball).
    pub(super) voxels: u64,
    /// With the upwind directions: the traced voxels' directions by linear voxel index,
    /// unless they took more than the budget's share (then None).
    pub(super) dirs: Option<HashMap<u64, DVec3>>,
}

/// Bytes a kept traced direction takes (key, value and the table's slack).
const KEPT_BYTES: u64 = 64;

/// Trace a streamline from the center of every voxel of the solid outside the stop
/// ball (with `upwind`: only those where it squeezes, [`SQUEEZE_BELOW`], or has no
/// direction; the others keep it), in batches of whole blocks that fit the budget, and
/// write the angles of every block `decomp` owns.
#[allow(clippy::too_many_arguments)]
#[allow(clippy::many_single_char_names)]
// the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
#[allow(clippy::too_many_lines)] // the batch loop: prepare, trace, keep and write share the batch's blocks
pub(super) fn exact(
    run: &RunDir,
    opts: &MapOptions,
    labels: &dyn BlockStore<u8>,
    angles: &Angles<f64>,
    ball: &StopBall,
    boundary: &Boundary,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
    upwind: Option<&Directions>,
) -> Result<Traced, crate::Error> {
    let spec = labels.spec().clone();
    let batch_lines = ((opts.mem.work_bytes() / 4) / (LINE_BYTES + 40)).clamp(10_000, 4_000_000);
    let topts = TraceOptions {
        stop_radius: Some(ball.radius),
        mem: opts.mem,
        rk: exact_integrator(),
        ..TraceOptions::default()
    };
    let mut tracer = None;
    let mut stops: BTreeMap<&'static str, u64> = Stop::ALL.iter().map(|s| (s.name(), 0)).collect();
    let kept_cap = opts.mem.work_bytes() / 8 / KEPT_BYTES;
    let mut kept = upwind.map(|_| HashMap::new());
    let mut traced = 0u64;
    let blocks = decomp.owned(&spec);
    // Blocks are prepared a group at a time, in parallel: labels, the directions from
    // the ball and the upwind map, and the voxels to trace. A block with none to trace
    // is written at once.
    let halo = volume(spec.chunk.map(|c| c + 2));
    let per_block = volume(spec.chunk) * (1 + 32 + 32) + upwind.map_or(0, |_| halo * 24);
    let workers = opts.mem.workers(
        "the exact tracing's blocks (labels, directions, upwind field)",
        batch_lines * (LINE_BYTES + 40),
        per_block,
        rayon::current_num_threads(),
    )?;
    let group = (2 * workers).max(1);
    let prepare = |b: &Idx3| -> Result<(u64, Option<BatchBlock>, Vec<DVec3>), GridError> {
        let (lab, d, todo, in_ball) = prepare_block(labels, ball, upwind, *b)?;
        if todo.is_empty() {
            angles.write_with(*b, &lab, |i| d[i])?;
            return Ok((in_ball, None, Vec::new()));
        }
        let owners = todo.iter().enumerate().map(|(s, &(k, _))| (k, s)).collect();
        let points = todo.into_iter().map(|(_, p)| p).collect();
        Ok((in_ball, Some((*b, lab, d, owners)), points))
    };
    let mut i = 0;
    while i < blocks.len() {
        crate::progress::check_interrupt(progress)?;
        // Whole blocks until the batch is full: its streamlines, or the blocks it holds
        // (labels and directions) a quarter of the budget, as when a few voxels of many
        // blocks are traced.
        let mut batch: Vec<BatchBlock> = Vec::new();
        let mut seeds: Vec<DVec3> = Vec::new();
        let held = |n: usize| n as u64 * volume(spec.chunk) * (1 + 32);
        while i < blocks.len()
            && (batch.is_empty()
                || ((seeds.len() as u64) < batch_lines
                    && held(batch.len() + group) <= opts.mem.work_bytes() / 4))
        {
            let end = (i + group).min(blocks.len());
            let prepared = map_bounded(&blocks[i..end], workers, prepare)?;
            i = end;
            for (in_ball, block, points) in prepared {
                *stops.get_mut("reached").expect("reason") += in_ball;
                if let Some((b, lab, d, mut owners)) = block {
                    for o in &mut owners {
                        o.1 += seeds.len();
                    }
                    seeds.extend(points);
                    batch.push((b, lab, d, owners));
                }
            }
        }
        if !seeds.is_empty() {
            if tracer.is_none() {
                tracer = Some(Tracer::with_boundary(
                    run,
                    &topts,
                    batch_lines,
                    boundary.clone(),
                )?);
            }
            let t = tracer.as_ref().expect("created");
            let (outcomes, _, _) = t.trace(&seeds, false, progress)?;
            traced += seeds.len() as u64;
            for (b, _, d, owners) in &mut batch {
                let st = spec.block_start(*b);
                let sh = spec.block_shape(*b);
                for &(k, s) in owners.iter() {
                    let o = &outcomes[s];
                    *stops.get_mut(o.stop.name()).expect("reason") += 1;
                    d[k] = None;
                    if o.stop == Stop::Reached {
                        let r = o.end - ball.center;
                        d[k] = (r.length() > 0.0).then(|| r.normalize());
                    }
                    if let (Some(m), Some(v)) = (kept.as_mut(), d[k]) {
                        let k = k as u64;
                        let g = [
                            st[0] + k / (sh[1] * sh[2]),
                            st[1] + (k / sh[2]) % sh[1],
                            st[2] + k % sh[2],
                        ];
                        m.insert((g[0] * spec.shape[1] + g[1]) * spec.shape[2] + g[2], v);
                    }
                }
            }
            if kept.as_ref().is_some_and(|m| m.len() as u64 > kept_cap) {
                kept = None;
            }
        }
        for (b, lab, d, _) in &batch {
            angles.write_with(*b, lab, |i| d[i])?;
        }
    }
    // With the upwind map, the kept map is dropped when too large: then None.
    let dirs = if upwind.is_some() { kept } else { None };
    Ok(Traced {
        stops,
        voxels: traced,
        dirs,
    })
}

/// Block `b`'s labels, directions known without tracing (inside the stop ball; with
/// `upwind`, where it does not squeeze) and the voxels to trace.
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
fn prepare_block(
    labels: &dyn BlockStore<u8>,
    ball: &StopBall,
    upwind: Option<&Directions>,
    b: Idx3,
) -> Result<Prepared, GridError> {
    let spec = labels.spec();
    let lab = labels.read_block(b)?;
    let st = spec.block_start(b);
    let sh = spec.block_shape(b);
    let halo = upwind.map(|dirs| dirs.read_halo_of(b, 1)).transpose()?;
    let (hy, hx) = ((sh[1] + 2) as usize, (sh[2] + 2) as usize);
    let mut d = vec![None; lab.len()];
    let mut todo = Vec::new();
    let mut in_ball = 0;
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
            in_ball += 1;
            continue;
        }
        if let Some(h) = &halo {
            let z = (v[0] - st[0]) as usize + 1;
            let y = (v[1] - st[1]) as usize + 1;
            let x = (v[2] - st[2]) as usize + 1;
            let i = (z * hy + y) * hx + x;
            if turns_at_least(h, i, [hy * hx, hx, 1], SQUEEZE_BELOW) {
                d[k] = Some(DVec3::from_array(h[i].map(f64::from)).normalize());
                continue;
            }
        }
        todo.push((k, p));
    }
    Ok((lab, d, todo, in_ball))
}
