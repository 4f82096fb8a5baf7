//! Polishing the tiny values: relative accuracy where u = 1 - phi is far below the
//! solve's absolute error.
//!
//! Multigrid (and any solve stopped on the global residual) leaves an absolute error
//! of about rtol times the scale of u everywhere, 1e-10 or so. Down the thin arms of a
//! real shape u falls to 1e-20 and below, so there the iterate is mostly error: on
//! cactus10k at resolution 128 with rtol 1e-6, 40% of the interior came out negative, and
//! half the streamlines stalled in the false minima. Coarse-grid corrections re-inject
//! that absolute error at every cycle, so more cycles do not help much.
//!
//! Plain Gauss-Seidel does: it only averages neighbours, so in a region whose border
//! values are right it converges to relative accuracy, however small the values. And in
//! a thin arm with Dirichlet walls it converges fast (the walls make the local problem
//! well conditioned). So after the solve, the unknowns with u below `threshold` (negatives too; the
//! region, fixed when the polish starts) are relaxed by red-black SOR with the rest held
//! fixed, until no value changes by more than `rel_change` of itself in a sweep.
//!
//! The solve's values in the region are mostly error (of either sign, and up to 1e10
//! times the true value), so the polish starts them from 0 instead: Gauss-Seidel then
//! fills them in from the region's border, and the relative error to remove is at most
//! 1 rather than 1e10 or more. Values below `FLOOR` (1e-24) count as converged.
//!
//! Out of core, block by block: a pass visits the blocks that hold region voxels in
//! eight colour phases (the parity of the block index along each axis); the blocks of a
//! phase are relaxed in parallel, each read with a one-voxel halo and swept a few times,
//! or until it is converged against that halo. Blocks of one phase never touch each other's voxels or
//! halos, so the result is the same for any thread count and budget. A block is
//! visited again while it has not converged, or when a neighbour whose face values it
//! reads has changed. Memory: one bit per voxel of the blocks that hold the region,
//! plus a haloed block per worker.

use super::blocks::BlockLoop;
use super::cuts::{is_unknown, Coef, CUT};
use crate::grid::{BlockStore, GridError, GridSpec, Reach};
use crate::math::Idx3;
use crate::progress::Progress;

/// What polishing did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PolishReport {
    /// Unknowns relaxed.
    pub voxels: u64,
    /// Red-black sweeps, the most any block had in all.
    pub sweeps: u64,
    /// Passes over the blocks (a block is swept to convergence against its halo in each
    /// pass it is visited).
    #[serde(default)]
    pub passes: u64,
    /// Blocks that hold region voxels.
    #[serde(default)]
    pub blocks: u64,
    /// Largest relative change in the last sweep of any block.
    pub last_change: f64,
    /// Unknowns with u < 0 before and after (the maximum principle says none).
    pub negative: [u64; 2],
    /// Stopped between passes because `stop` said so; `u` is then half polished.
    #[serde(skip)]
    pub interrupted: bool,
}

/// Settings of [`polish`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PolishOptions {
    /// Relax unknowns with u below this (negative ones too: the maximum principle rules them out).
    pub threshold: f64,
    /// Stop when no value changes by more than this fraction of itself in a sweep.
    pub rel_change: f64,
    /// Sweeps allowed for any one block (over all passes).
    pub max_sweeps: u64,
    /// Over-relaxation factor. 1.9, near the optimum of a region 60 voxels across,
    /// stalled down thin arms (cactus10k, the test tube); 1.6 converges on both.
    pub omega: f64,
    /// Values below this count as converged whatever their relative change
    /// ([`FLOOR`] by default; at least about 1e-300, above the subnormal numbers).
    #[serde(default = "floor")]
    pub floor: f64,
    /// Start the region from the values it holds (clamped at 0) instead of 0: after
    /// [`super::deepen`], which leaves them right to a small part of its last
    /// threshold.
    #[serde(default)]
    pub from_values: bool,
}

fn floor() -> f64 {
    FLOOR
}

impl Default for PolishOptions {
    fn default() -> Self {
        Self {
            threshold: 1e-6,
            rel_change: 1e-9,
            max_sweeps: 20_000,
            omega: 1.6,
            floor: FLOOR,
            from_values: false,
        }
    }
}

/// Sweeps of a block per visit. Few: a block swept to convergence against a halo
/// that is still moving wastes the sweeps (non-overlapping blocks have no coarse
/// space to carry news), so the blocks take turns, as one global red-black SOR would.
const SWEEPS_PER_VISIT: u64 = 8;

/// Values below this count as converged whatever their relative change. The tracer's
/// directions hold down to gradients of about 1e-22 (docs/trace.md), so relative
/// accuracy below it buys nothing; and far below it, in the deepest pockets of a large
/// molecule, u underflows into subnormal numbers, whose relative precision is coarse
/// enough (5e-4 at 1e-320) to keep the relative change above any tolerance forever.
const FLOOR: f64 = 1e-24;

/// The region of one block: a bit per voxel of the block, C order.
struct Region {
    bits: Vec<u64>,
    negative: u64,
}

impl Region {
    fn contains(&self, o: usize) -> bool {
        self.bits[o / 64] >> (o % 64) & 1 == 1
    }
}

/// What one visit of a block did.
struct Visit {
    sweeps: u64,
    converged: bool,
    /// Relative change in the last sweep.
    last: f64,
    /// Whether region values on each face (-z, +z, -y, +y, -x, +x) moved by more than
    /// `rel_change` of themselves during the visit.
    face_moved: [bool; 6],
    /// Region values below 0 after the visit.
    negative: u64,
}

/// The finest level's mask and packed arms, in a run with cuts ([`super::cuts`]): the
/// polish relaxes cut unknowns with their Shortley-Weller equation.
pub type Arms<'a> = Option<&'a dyn BlockStore<u64>>;

/// Relax the small values of `u` (unknowns of `mask`) in place, block by
/// block. `bytes` is the memory the polish may hold at once (it decides how many blocks
/// are relaxed at a time, not the result). `stop` is polled between passes.
///
/// This process relaxes the blocks `blocks` owns, exchanges `u` (halo 1) after each
/// colour phase, and learns which of its blocks to visit next from the faces that
/// moved in its neighbours' visits, gathered over all processes.
#[allow(clippy::too_many_arguments)] // the level's fields, the budget, the loop and the two callbacks
pub fn polish(
    u: &dyn BlockStore<f64>,
    mask: &dyn BlockStore<u8>,
    arms: Arms<'_>,
    opts: &PolishOptions,
    bytes: u64,
    blocks: &BlockLoop<'_>,
    stop: &(dyn Fn() -> bool + Sync),
    progress: &dyn Progress,
) -> Result<PolishReport, GridError> {
    let spec = u.spec().clone();
    let lin = |b: Idx3| spec.block_linear(b) as usize;
    let (mut regions, found) = find_regions(u, mask, opts, blocks)?;
    let mut report = PolishReport {
        voxels: found.voxels,
        negative: [found.negative, found.negative],
        blocks: found.has_region.iter().filter(|&&r| r).count() as u64,
        ..PolishReport::default()
    };
    if found.voxels == 0 {
        return Ok(report);
    }
    // A worker holds a haloed block and the lists of its region voxels.
    let held: u64 = regions
        .iter()
        .flatten()
        .map(|r| r.bits.len() as u64 * 8)
        .sum();
    let per_worker =
        (crate::math::volume(spec.chunk.map(|c| c + 2)) * 8) + crate::math::volume(spec.chunk) * 12;
    let workers = blocks
        .workers
        .min((bytes.saturating_sub(held) / per_worker.max(1)) as usize)
        .max(1);
    let owned = blocks.decomp.owned(&spec);
    let region_negative = |regions: &[Option<Region>]| -> Result<u64, GridError> {
        let own = owned
            .iter()
            .filter_map(|&b| Some((b, regions[lin(b)].as_ref()?.negative as f64)));
        Ok(blocks.gather(&spec, own)?.iter().map(|&v| v as u64).sum())
    };
    let region_negative_before = region_negative(&regions)?;
    let mut active = found.has_region.clone();
    let mut sweeps = vec![0u64; regions.len()];
    loop {
        let flags = owned
            .iter()
            .map(|&b| (b, f64::from(u8::from(active[lin(b)]))));
        let to_visit = blocks
            .gather(&spec, flags)?
            .iter()
            .filter(|&&a| a > 0.0)
            .count();
        if to_visit == 0 {
            break;
        }
        if stop() {
            report.interrupted = true;
            break;
        }
        progress.message(&format!(
            "solve: polishing {} tiny values  pass {}, {to_visit} of {} blocks to visit, largest change {:.1e}",
            found.voxels,
            report.passes + 1,
            report.blocks,
            report.last_change
        ));
        report.passes += 1;
        let before = sweeps.clone();
        let first = report.passes == 1;
        let mut state = State {
            regions: &mut regions,
            sweeps: &mut sweeps,
            active: &active,
            arms: arms.map(|a| (mask, a)),
        };
        let pass = state.visit(u, opts, &owned, workers, first, blocks)?;
        report.last_change = blocks
            .gather(&spec, pass.last.iter().copied())?
            .into_iter()
            .fold(0.0f64, f64::max);
        let moved = owned.iter().map(|&b| (b, f64::from(pass.moved[lin(b)])));
        let moved = blocks.gather(&spec, moved)?;
        for &b in &owned {
            let k = lin(b);
            active[k] = pass.unconverged[k] && sweeps[k] < opts.max_sweeps
                || found.has_region[k]
                    && woken(&spec, b, &moved, &before, &sweeps, opts.max_sweeps);
        }
    }
    report.sweeps = blocks
        .gather(&spec, owned.iter().map(|&b| (b, sweeps[lin(b)] as f64)))?
        .into_iter()
        .map(|s| s as u64)
        .max()
        .unwrap_or(0);
    let region_negative_after = region_negative(&regions)?;
    report.negative[1] = found.negative - region_negative_before + region_negative_after;
    Ok(report)
}

/// The colour phase of block `b`: the parity of its index along each axis. Blocks of
/// one phase share no face.
fn phase_of(b: Idx3) -> u64 {
    (b[0] % 2) * 4 + (b[1] % 2) * 2 + b[2] % 2
}

/// The blocks of this process between passes.
struct State<'a> {
    /// Per block: its region (None where there is none, or another process owns it).
    regions: &'a mut [Option<Region>],
    /// Per block: sweeps done.
    sweeps: &'a mut [u64],
    /// Per block: to visit in this pass.
    active: &'a [bool],
    /// The mask and the arms, in a run with cuts.
    arms: Option<(&'a dyn BlockStore<u8>, &'a dyn BlockStore<u64>)>,
}

impl State<'_> {
    /// One pass: the active blocks of `owned` that have sweeps left, in eight colour
    /// phases (blocks of a phase in parallel), exchanging `u` after each phase.
    fn visit(
        &mut self,
        u: &dyn BlockStore<f64>,
        opts: &PolishOptions,
        owned: &[Idx3],
        workers: usize,
        first: bool,
        blocks: &BlockLoop<'_>,
    ) -> Result<Pass, GridError> {
        let spec = u.spec();
        let lin = |b: Idx3| spec.block_linear(b) as usize;
        let n = self.regions.len();
        let mut pass = Pass {
            unconverged: vec![false; n],
            moved: vec![0; n],
            last: Vec::new(),
        };
        for phase in 0..8u64 {
            let todo: Vec<Idx3> = owned
                .iter()
                .copied()
                .filter(|&b| {
                    self.active[lin(b)]
                        && self.sweeps[lin(b)] < opts.max_sweeps
                        && phase_of(b) == phase
                })
                .collect();
            let (regions, sweeps, arms) = (&*self.regions, &*self.sweeps, self.arms);
            let visits = crate::parallel::map_bounded(&todo, workers, |&b| {
                let region = regions[lin(b)].as_ref().expect("active blocks hold region");
                let limit = SWEEPS_PER_VISIT.min(opts.max_sweeps - sweeps[lin(b)]);
                relax_block(u, arms, b, region, opts, limit, first)
            })?;
            for (&b, v) in todo.iter().zip(visits) {
                let k = lin(b);
                self.sweeps[k] += v.sweeps;
                pass.last.push((b, v.last));
                pass.unconverged[k] = !v.converged;
                if let Some(r) = self.regions[k].as_mut() {
                    r.negative = v.negative;
                }
                pass.moved[k] = v
                    .face_moved
                    .iter()
                    .enumerate()
                    .fold(0u8, |m, (f, &moved)| m | u8::from(moved) << f);
            }
            blocks.exchange("u", u, &Reach::Halo(1))?;
        }
        Ok(pass)
    }
}

/// What the visits of one pass left, per block of this process.
struct Pass {
    /// Visited and not converged.
    unconverged: Vec<bool>,
    /// Faces whose values moved, a bit per face (-z, +z, -y, +y, -x, +x).
    moved: Vec<u8>,
    /// The last relative change of each visit.
    last: Vec<(Idx3, f64)>,
}

/// Whether block `b` must be visited again because a neighbour's face toward it moved
/// in this pass (`moved`: the face bits of every block), and `b` then still had sweeps
/// left: a neighbour visited in a phase before `b`'s saw `b` before its own visit of
/// this pass (`before`), one visited after saw it after (`now`).
fn woken(spec: &GridSpec, b: Idx3, moved: &[f64], before: &[u64], now: &[u64], max: u64) -> bool {
    let nb = spec.blocks();
    let k = spec.block_linear(b) as usize;
    (0..3).any(|a| {
        [false, true].into_iter().any(|up| {
            // The neighbour on the `up` side of b along a, and its face toward b.
            if (up && b[a] + 1 == nb[a]) || (!up && b[a] == 0) {
                return false;
            }
            let mut n = b;
            n[a] = if up { b[a] + 1 } else { b[a] - 1 };
            let face = 2 * a + usize::from(!up);
            let bits = moved[spec.block_linear(n) as usize] as u8;
            if bits >> face & 1 == 0 {
                return false;
            }
            let seen = if phase_of(b) < phase_of(n) {
                now[k]
            } else {
                before[k]
            };
            seen < max
        })
    })
}

/// What the scan before the passes found, over all blocks.
struct Found {
    /// Unknowns in the region.
    voxels: u64,
    /// Unknowns with u < 0.
    negative: u64,
    /// Per block: whether it holds region voxels.
    has_region: Vec<bool>,
}

/// The region of each block this process owns (None elsewhere), and what the scan
/// found over all blocks.
fn find_regions(
    u: &dyn BlockStore<f64>,
    mask: &dyn BlockStore<u8>,
    opts: &PolishOptions,
    blocks: &BlockLoop<'_>,
) -> Result<(Vec<Option<Region>>, Found), GridError> {
    let spec = u.spec();
    let scan = blocks.map(spec, |b| {
        let (uv, mv) = (u.read_block(b)?, mask.read_block(b)?);
        let mut bits = vec![0u64; uv.len().div_ceil(64)];
        let (mut count, mut negative, mut region_negative) = (0u64, 0u64, 0u64);
        for (o, (&x, &m)) in uv.iter().zip(&mv).enumerate() {
            if is_unknown(m) {
                negative += u64::from(x < 0.0);
                if x < opts.threshold {
                    bits[o / 64] |= 1 << (o % 64);
                    count += 1;
                    region_negative += u64::from(x < 0.0);
                }
            }
        }
        let region = (count > 0).then_some(Region {
            bits,
            negative: region_negative,
        });
        Ok((region, count, negative))
    })?;
    let counts = blocks.gather(spec, scan.iter().map(|(b, s)| (*b, s.1 as f64)))?;
    let negatives = blocks.gather(spec, scan.iter().map(|(b, s)| (*b, s.2 as f64)))?;
    let mut regions: Vec<Option<Region>> = counts.iter().map(|_| None).collect();
    for (b, s) in scan {
        regions[spec.block_linear(b) as usize] = s.0;
    }
    let found = Found {
        voxels: counts.iter().map(|&c| c as u64).sum(),
        negative: negatives.iter().map(|&c| c as u64).sum(),
        has_region: counts.iter().map(|&c| c > 0.0).collect(),
    };
    Ok((regions, found))
}

/// Relax the region voxels of block `b` against its one-voxel halo until a sweep moves
/// no value by more than `rel_change` of itself (or `limit` sweeps), and write the
/// block back. On the `first` visit, the region's values start from 0.
#[allow(clippy::many_single_char_names)] // grid axes (z, y, x) and stencil terms named as in the formulas
#[allow(clippy::too_many_lines)] // the lists by colour, the sweeps and the faces that moved
fn relax_block(
    u: &dyn BlockStore<f64>,
    arms: Option<(&dyn BlockStore<u8>, &dyn BlockStore<u64>)>,
    b: Idx3,
    region: &Region,
    opts: &PolishOptions,
    limit: u64,
    first: bool,
) -> Result<Visit, GridError> {
    let spec = u.spec();
    let st = spec.block_start(b);
    let sh = crate::grid::to_usize(spec.block_shape(b));
    let mut blk = u.read_block_halo(b, 1, f64::NAN)?;
    let (hx, hxy) = (sh[2] + 2, (sh[1] + 2) * (sh[2] + 2));
    // Haloed offsets of the region voxels by colour (the grid parity, as the solver's
    // sweeps), and the faces each lies on.
    let mut lists: [Vec<u32>; 2] = [Vec::new(), Vec::new()];
    // Cut unknowns of the region, by colour, with their equations.
    let mut cut_lists: [Vec<(u32, Coef)>; 2] = [Vec::new(), Vec::new()];
    let arms = match arms {
        Some((mask, cuts)) => Some((mask.read_block_halo(b, 1, 0)?, cuts.read_block(b)?)),
        None => None,
    };
    let mut on_face: Vec<(u32, u8)> = Vec::new();
    let mut o = 0;
    for z in 0..sh[0] {
        for y in 0..sh[1] {
            for x in 0..sh[2] {
                if region.contains(o) {
                    let h = ((z + 1) * hxy + (y + 1) * hx + x + 1) as u32;
                    let colour = (st[0] as usize + z + st[1] as usize + y + st[2] as usize + x) % 2;
                    match &arms {
                        Some((m, p)) if m.data[h as usize] == CUT => {
                            cut_lists[colour]
                                .push((h, Coef::at_haloed(&p[o], &m.data, h as usize, hx, hxy)));
                        }
                        _ => lists[colour].push(h),
                    }
                    let faces = u8::from(z == 0)
                        | u8::from(z + 1 == sh[0]) << 1
                        | u8::from(y == 0) << 2
                        | u8::from(y + 1 == sh[1]) << 3
                        | u8::from(x == 0) << 4
                        | u8::from(x + 1 == sh[2]) << 5;
                    if faces != 0 {
                        on_face.push((h, faces));
                    }
                }
                o += 1;
            }
        }
    }
    if first {
        for &h in lists
            .iter()
            .flatten()
            .chain(cut_lists.iter().flatten().map(|(h, _)| h))
        {
            let v = &mut blk.data[h as usize];
            *v = if opts.from_values { v.max(0.0) } else { 0.0 };
        }
    }
    let start: Vec<f64> = on_face.iter().map(|&(h, _)| blk.data[h as usize]).collect();
    let w = opts.omega;
    let d = &mut blk.data;
    let mut visit = Visit {
        sweeps: 0,
        converged: false,
        last: 0.0,
        face_moved: [false; 6],
        negative: 0,
    };
    while visit.sweeps < limit {
        let mut change = 0.0f64;
        for (list, cut_list) in lists.iter().zip(&cut_lists) {
            for &(h, k) in cut_list {
                let h = h as usize;
                let nb = [h - 1, h + 1, h - hx, h + hx, h - hxy, h + hxy].map(|j| d[j]);
                let old = d[h];
                let v = (1.0 - w) * old + w * ((k.defect(nb, 0.0)) / k.diag);
                d[h] = v;
                let scale = v.abs().max(old.abs());
                if scale > opts.floor {
                    change = change.max((v - old).abs() / scale);
                }
            }
            for &h in list {
                let h = h as usize;
                let s = d[h - 1] + d[h + 1] + d[h - hx] + d[h + hx] + d[h - hxy] + d[h + hxy];
                let old = d[h];
                let v = (1.0 - w) * old + w * (s / 6.0);
                d[h] = v;
                let scale = v.abs().max(old.abs());
                if scale > opts.floor {
                    change = change.max((v - old).abs() / scale);
                }
            }
        }
        visit.sweeps += 1;
        visit.last = change;
        if change < opts.rel_change {
            visit.converged = true;
            break;
        }
    }
    for (&(h, faces), &old) in on_face.iter().zip(&start) {
        let v = d[h as usize];
        let scale = v.abs().max(old.abs());
        if scale > opts.floor && (v - old).abs() > opts.rel_change * scale {
            for (f, moved) in visit.face_moved.iter_mut().enumerate() {
                *moved |= faces >> f & 1 == 1;
            }
        }
    }
    visit.negative = lists
        .iter()
        .flatten()
        .chain(cut_lists.iter().flatten().map(|(h, _)| h))
        .filter(|&&h| d[h as usize] < 0.0)
        .count() as u64;
    u.write_block(b, &blk.crop([1, 1, 1], sh))?;
    Ok(visit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{fill_with, to_usize, GridSpec, MemStore};
    use crate::voxelize::labels::INTERIOR;
    use crate::voxelize::labels::{BOUNDARY, CENTER};

    /// The tube of the test below in a grid of `chunk`-long blocks, started from the
    /// wrong profile with noise.
    fn tube(chunk: u64) -> (GridSpec, MemStore<f64>, MemStore<u8>) {
        let spec = GridSpec {
            shape: [5, 5, 42],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [5, 5, chunk],
            unit: None,
        };
        let inside = |v: Idx3| (1..4).contains(&v[0]) && (1..4).contains(&v[1]);
        let mask = MemStore::new(spec.clone(), 0u8);
        fill_with(&mask, 1, |v| {
            if inside(v) && v[2] == 0 {
                CENTER
            } else if inside(v) && (1..41).contains(&v[2]) {
                INTERIOR
            } else {
                BOUNDARY
            }
        })
        .unwrap();
        let u = MemStore::new(spec.clone(), 0.0f64);
        fill_with(&u, 1, |v| {
            if inside(v) && v[2] == 0 {
                1.0
            } else if inside(v) && v[2] < 41 {
                let noise = if (v[0] + v[1] + v[2]) % 2 == 0 {
                    1e-12
                } else {
                    -1e-12
                };
                (-0.8 * v[2] as f64).exp() + noise
            } else {
                0.0
            }
        })
        .unwrap();
        (spec, u, mask)
    }

    /// The polish with default options, never stopped, silent.
    fn run(u: &MemStore<f64>, mask: &MemStore<u8>, bytes: u64, workers: usize) -> PolishReport {
        let opts = PolishOptions::default();
        polish(
            u,
            mask,
            None,
            &opts,
            bytes,
            &BlockLoop::whole(workers),
            &|| false,
            &crate::progress::Silent,
        )
        .unwrap()
    }

    fn all_values(spec: &GridSpec, u: &MemStore<f64>) -> Vec<f64> {
        let b = u
            .read_region([0; 3], to_usize(spec.shape), f64::NAN)
            .unwrap();
        b.data
    }

    /// The block decomposition changes the path to the answer, not the answer: blocks
    /// of 4, 16 and 64 voxels along the tube agree to well within the stopping
    /// criterion's 1e-9 per sweep (relative, even where u is 1e-17), and the worker count
    /// and budget change nothing at all.
    #[test]
    fn blocks_threads_and_budget_do_not_change_the_answer() {
        let opts = PolishOptions::default();
        let mut results = Vec::new();
        for chunk in [4, 16, 64] {
            let (spec, u, mask) = tube(chunk);
            let rep = run(&u, &mask, 1 << 30, 2);
            assert!(
                rep.negative[1] == 0 && rep.last_change < opts.rel_change,
                "{rep:?}"
            );
            results.push(all_values(&spec, &u));
        }
        for r in &results[..2] {
            for (a, b) in r.iter().zip(&results[2]) {
                if a.is_finite() && *b != 0.0 {
                    assert!(((a - b) / b).abs() < 1e-6, "{a:e} vs {b:e}");
                }
            }
        }
        let (spec, u, mask) = tube(4);
        let rep = run(&u, &mask, 1, 1);
        assert!(rep.blocks >= 6 && rep.passes > 1, "{rep:?}");
        assert_eq!(all_values(&spec, &u), results[0]);
    }

    /// A square tube 3 voxels wide and 40 long, u = 1 at its mouth and 0 on its walls:
    /// u falls by a factor 0.39 per voxel down the tube, to ~1e-17 at the end. Started from
    /// a wrong profile plus an absolute error of 1e-12 (with negatives), as a solve
    /// stopped on the global residual leaves the tiny values.
    #[test]
    fn tiny_values_get_relative_accuracy() {
        let (spec, u, mask) = tube(16);
        let opts = PolishOptions::default();
        let rep = run(&u, &mask, 1 << 30, 2);
        assert!(rep.negative[0] > 0 && rep.negative[1] == 0, "{rep:?}");
        assert!(rep.last_change < opts.rel_change, "{rep:?}");
        // Down the tube's axis the values fall by the same factor per voxel (the tube's
        // decay rate), even where they are 1e-30.
        let axis: Vec<f64> = (0..42)
            .map(|x| {
                let b = [0, 0, x / 16];
                let w = spec.block_shape(b)[2] as usize;
                let d = u.read_block(b).unwrap();
                d[(2 * 5 + 2) * w + (x % 16) as usize]
            })
            .collect();
        // (The region polished starts where u < 1e-6, x >= 18; its first voxels still
        // carry the higher modes of the start values.)
        let ratios: Vec<f64> = (22..36).map(|x| axis[x + 1] / axis[x]).collect();
        let (lo, hi) = ratios
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), &r| (a.min(r), b.max(r)));
        // Below the 1e-12 error it started with.
        assert!(axis[35] > 0.0 && axis[35] < 1e-13, "{:e}", axis[35]);
        assert!(hi / lo < 1.01, "decay ratios {lo} .. {hi}");
        // The discrete decay rate of the lowest mode of a 3 x 3 tube: r + 1/r = 2 + 4 (1 -
        // cos(pi / 4)).
        let a = 2.0 + 4.0 * (1.0 - std::f64::consts::FRAC_PI_4.cos());
        let r = (a - (a * a - 4.0).sqrt()) / 2.0;
        assert!((ratios[10] / r - 1.0).abs() < 1e-3, "{} vs {r}", ratios[10]);
    }
}
