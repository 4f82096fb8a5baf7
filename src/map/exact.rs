//! The exact map: a streamline from the center of every voxel of the solid, with the
//! tracer of `trace`, in batches of whole blocks.
//!
//! Across processes each part maps the blocks its [`Decomposition`] owns; a streamline
//! crosses into the other parts' blocks only through the tracer's tiles, which read u
//! (written by the solve, complete everywhere).

use std::collections::BTreeMap;

use glam::DVec3;

use super::angles::Angles;
use super::upwind::is_target;
use super::MapOptions;
use crate::grid::{BlockStore, Decomposition};
use crate::math::Idx3;
use crate::progress::Progress;
use crate::run::RunDir;
use crate::trace::integrate::StopBall;
use crate::trace::stage::{Tracer, LINE_BYTES};
use crate::trace::surface::Boundary;
use crate::trace::{Rk45, SeedKind, Stop, TraceOptions};

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
#[allow(clippy::too_many_arguments)]
#[allow(clippy::many_single_char_names)] // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
pub(super) fn exact(
    run: &RunDir,
    opts: &MapOptions,
    labels: &dyn BlockStore<u8>,
    angles: &Angles<f64>,
    ball: &StopBall,
    boundary: &Boundary,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<BTreeMap<&'static str, u64>, crate::Error> {
    let spec = labels.spec().clone();
    let batch_lines = ((opts.mem.work_bytes() / 4) / (LINE_BYTES + 40)).clamp(10_000, 4_000_000);
    let topts = TraceOptions {
        stop_radius: Some(ball.radius),
        mem: opts.mem,
        rk: exact_integrator(),
        ..TraceOptions::default()
    };
    let tracer = Tracer::with_boundary(run, &topts, batch_lines, boundary.clone())?;
    let mut stops: BTreeMap<&'static str, u64> = Stop::ALL.iter().map(|s| (s.name(), 0)).collect();
    let blocks = decomp.owned(&spec);
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
