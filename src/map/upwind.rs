//! Upwind transport of the arrival direction, block by block.
//!
//! The arrival direction is constant along a streamline, and streamlines run up u = 1 -
//! phi (down phi). So a voxel takes its direction from its neighbours of higher u: on
//! each axis the neighbour with the larger u, if that is above the voxel's own, weighted
//! by the difference (the one-sided, upwind discretization of grad(u) . grad(d) = 0).
//! The dependencies form a directed acyclic graph (u strictly increases along every
//! edge) rooted in the stop ball, where the direction is the one from the center. A
//! voxel is computed once, when all its upwind neighbours have their values; so the
//! result is the graph's unique solution, whatever the order of the blocks or the
//! number of threads.
//!
//! Blocks are processed with a one-voxel halo, from the center's block outwards, in
//! eight colour phases (no two blocks of a phase touch); a block whose neighbours gained
//! values is visited again until nothing changes. Voxels with no upwind neighbour (flat
//! sheets of boundary voxels, where u = 0 on every side) then take the mean direction of
//! their neighbours that have one.

use glam::DVec3;
use rayon::prelude::*;

use crate::grid::{Block, BlockStore, GridError, MemStore, MmapStore};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::trace::field::Tile;
use crate::trace::integrate::StopBall;
use crate::trace::surface::REACH as SURFACE_REACH;

/// Whether a label takes part in the map (boundary, interior, center).
#[must_use]
pub fn is_target(label: u8) -> bool {
    matches!(label, 1..=3)
}

/// The direction field: one f32 store per component, in memory or in scratch files.
/// (0, 0, 0) means "no value yet" (both start zero-filled).
pub struct Directions {
    /// x, y and z components.
    pub c: [Box<dyn BlockStore<f32>>; 3],
}

impl Directions {
    /// Bytes the field takes for `spec`.
    #[must_use]
    pub fn bytes(spec: &crate::grid::GridSpec) -> u64 {
        12 * spec.num_blocks() * volume(spec.chunk)
    }

    /// In memory when `in_memory`, else scratch files `dir/{x,y,z}.f32`.
    pub fn create(
        dir: &std::path::Path,
        spec: &crate::grid::GridSpec,
        in_memory: bool,
    ) -> Result<Self, GridError> {
        let mk = |n: &str| -> Result<Box<dyn BlockStore<f32>>, GridError> {
            Ok(if in_memory {
                Box::new(MemStore::<f32>::new(spec.clone(), 0.0))
            } else {
                Box::new(MmapStore::<f32>::create(
                    &dir.join(format!("{n}.f32")),
                    spec.clone(),
                )?)
            })
        };
        Ok(Self {
            c: [mk("x")?, mk("y")?, mk("z")?],
        })
    }

    /// Block `b` with a halo of [`HALO`], as [x, y, z] component blocks.
    fn read_halo(&self, b: Idx3) -> Result<[Vec<f32>; 3], GridError> {
        let r = |i: usize| -> Result<Vec<f32>, GridError> {
            Ok(self.c[i].read_block_halo(b, HALO as usize, 0.0)?.data)
        };
        Ok([r(0)?, r(1)?, r(2)?])
    }

    /// The unit direction of each voxel of block `b` (None where there is none).
    pub fn read(&self, b: Idx3) -> Result<Vec<Option<DVec3>>, GridError> {
        let [x, y, z] = [
            self.c[0].read_block(b)?,
            self.c[1].read_block(b)?,
            self.c[2].read_block(b)?,
        ];
        Ok((0..x.len())
            .map(|i| {
                let v = DVec3::new(f64::from(x[i]), f64::from(y[i]), f64::from(z[i]));
                (v != DVec3::ZERO).then_some(v)
            })
            .collect())
    }

    /// Write the directions of block `b` (None: no value).
    pub fn write(&self, b: Idx3, d: &[Option<DVec3>]) -> Result<(), GridError> {
        for (a, store) in self.c.iter().enumerate() {
            let comp: Vec<f32> = d.iter().map(|v| v.map_or(0.0, |v| v[a] as f32)).collect();
            store.write_block(b, &comp)?;
        }
        Ok(())
    }
}

/// Halo (voxels) a visit reads around its block.
pub const HALO: u64 = 6;

/// Layers of the halo in which a visit computes voxels too (never written).
const REACH: usize = 1;

/// Which rule a visit applies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Rule {
    /// Upwind neighbours only.
    Upwind,
    /// Upwind where possible, else the mean of neighbours that have a value.
    Fill,
}

/// What a visit to a block did.
#[derive(Clone, Copy, Debug, Default)]
struct Visit {
    ball: u64,
    computed: u64,
    filled: u64,
    pending: u64,
}

/// Counters of a transport.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct TransportStats {
    /// Voxels set from the direction to the center (inside the stop ball).
    pub from_ball: u64,
    /// Voxels set by the upwind rule.
    pub upwind: u64,
    /// Voxels without an upwind neighbour, set from their neighbours.
    pub filled: u64,
    /// Voxels left without a direction (cut off from the center).
    pub unreached: u64,
    /// Rounds over the blocks (upwind, then fill).
    pub rounds: [u32; 2],
    /// Block visits.
    pub visits: u64,
}

/// Bytes one worker holds while visiting a block of edge `chunk`.
#[must_use]
pub fn worker_bytes(chunk: Idx3) -> u64 {
    let h = volume(chunk.map(|c| c + 2 * HALO));
    let tile = chunk.map(|c| (c + 2 * HALO - 2) as usize);
    // u (f64), labels (u8), three f32 components, the visiting order (16 B per voxel
    // of the block and its first layer of halo) and the output; the direction tile and
    // what building it holds (u with the tile's margin, read once for both).
    h * (8 + 1 + 12)
        + volume(chunk.map(|c| c + 2 * REACH as u64)) * 16
        + volume(chunk) * 12
        + Tile::bytes(tile)
        + Tile::build_bytes(tile)
}

/// Transport the arrival direction into `dirs` for every target voxel.
pub fn transport(
    u: &dyn BlockStore<f64>,
    labels: &dyn BlockStore<u8>,
    dirs: &Directions,
    ball: &StopBall,
    workers: usize,
    progress: &dyn Progress,
) -> Result<TransportStats, GridError> {
    let spec = u.spec();
    let nb = spec.blocks();
    let blocks = spec.block_indices();
    // Groups of blocks: by distance from the center to the block (in block edges),
    // then by colour, so that dependencies (which run outwards) are mostly met in order.
    let c = [ball.center.z, ball.center.y, ball.center.x];
    let key = |b: &Idx3| {
        let st = spec.block_start(*b);
        let sh = spec.block_shape(*b);
        let d2: f64 = (0..3)
            .map(|a| {
                let lo = st[a] as f64;
                let hi = (st[a] + sh[a] - 1) as f64;
                let e = (lo - c[a]).max(c[a] - hi).max(0.0);
                e * e
            })
            .sum();
        let ring = (d2.sqrt() / spec.chunk[0] as f64).floor() as u64;
        let colour = (b[0] % 2) * 4 + (b[1] % 2) * 2 + (b[2] % 2);
        (ring, colour)
    };
    let mut order = blocks.clone();
    order.sort_by_key(|b| (key(b), spec.block_linear(*b)));
    let mut groups: Vec<Vec<Idx3>> = Vec::new();
    let mut last = None;
    for b in order {
        if last != Some(key(&b)) {
            groups.push(Vec::new());
            last = Some(key(&b));
        }
        groups.last_mut().expect("a group").push(b);
    }
    let lin = |b: &Idx3| spec.block_linear(*b) as usize;
    let mut pending = vec![u64::MAX; blocks.len()];
    let mut stale = vec![true; blocks.len()];
    let mut stats = TransportStats::default();
    let mut done = 0u64;
    progress.start("map (upwind)", spec.num_voxels());
    for (round_slot, rule) in [Rule::Upwind, Rule::Fill].into_iter().enumerate() {
        if rule == Rule::Fill {
            // Every block with voxels left looks again, now allowed to fill.
            for (i, p) in pending.iter().enumerate() {
                stale[i] = *p > 0;
            }
        }
        loop {
            stats.rounds[round_slot] += 1;
            let mut changed = false;
            for g in &groups {
                let todo: Vec<Idx3> = g
                    .iter()
                    .copied()
                    .filter(|b| stale[lin(b)] && pending[lin(b)] > 0)
                    .collect();
                if todo.is_empty() {
                    continue;
                }
                // A group of fewer blocks than workers (the blocks around the center)
                // spreads each visit over the threads instead.
                let inside = todo.len() < workers;
                let visits = map_bounded(&todo, workers, |&b| {
                    visit(b, u, labels, dirs, ball, rule, inside)
                })?;
                for (b, v) in todo.iter().zip(visits) {
                    stats.visits += 1;
                    let i = lin(b);
                    let first = pending[i] == u64::MAX;
                    pending[i] = v.pending;
                    stale[i] = false;
                    if first {
                        // Voxels that are not targets count as done for the bar.
                        let vol = volume(spec.block_shape(*b));
                        done += vol - v.ball - v.computed - v.filled - v.pending;
                    }
                    done += v.ball + v.computed + v.filled;
                    stats.from_ball += v.ball;
                    stats.upwind += v.computed;
                    stats.filled += v.filled;
                    if v.ball + v.computed + v.filled > 0 {
                        changed = true;
                        for nbr in neighbours(*b, nb) {
                            stale[lin(&nbr)] = true;
                        }
                    }
                }
                progress.set_position(done);
            }
            if !changed {
                break;
            }
        }
    }
    progress.finish();
    stats.unreached = pending.iter().filter(|&&p| p != u64::MAX).sum();
    Ok(stats)
}

/// The 26 blocks around `b` (those inside the grid).
fn neighbours(b: Idx3, nb: Idx3) -> impl Iterator<Item = Idx3> {
    (0..27).filter_map(move |k| {
        let d = [k / 9, (k / 3) % 3, k % 3].map(|v: i64| v - 1);
        if d == [0, 0, 0] {
            return None;
        }
        let n: [i64; 3] = std::array::from_fn(|a| b[a] as i64 + d[a]);
        (0..3)
            .all(|a| n[a] >= 0 && (n[a] as u64) < nb[a])
            .then(|| n.map(|v| v as u64))
    })
}

/// Visit block `b`: compute every target voxel without a direction whose upwind
/// neighbours have theirs (in decreasing u, so neighbours inside the block come first).
fn visit(
    b: Idx3,
    u: &dyn BlockStore<f64>,
    labels: &dyn BlockStore<u8>,
    dirs: &Directions,
    ball: &StopBall,
    rule: Rule,
    parallel: bool,
) -> Result<Visit, GridError> {
    let spec = u.spec();
    let start = spec.block_start(b);
    let shape = spec.block_shape(b);
    let h = HALO as usize;
    // u is read once, with the margin the tile's boundary values need; the visit's
    // own arrays keep the halo of HALO.
    let wide = u.read_block_halo(b, h + SURFACE_REACH, f64::NAN)?;
    let hs = shape.map(|c| c as usize + 2 * h);
    let ub = Block {
        origin: wide.origin.map(|o| o + SURFACE_REACH as i64),
        shape: hs,
        data: wide.crop([SURFACE_REACH; 3], hs),
    };
    let lb = labels.read_block_halo(b, h, 0)?;
    let mut d = dirs.read_halo(b)?;
    let strides = [hs[1] * hs[2], hs[2], 1];
    let at = |z: usize, y: usize, x: usize| (z * hs[1] + y) * hs[2] + x;
    // Upwind voxels are computed in the halo too (all but its outer layer, whose
    // neighbours are not read), so chains of dependencies that zig-zag across the face
    // of the block resolve in one visit; only the core is written.
    let reach = if rule == Rule::Upwind { REACH } else { 0 };
    let core = |l: [usize; 3]| (0..3).all(|a| l[a] >= h && l[a] < h + shape[a] as usize);
    // The voxels to compute, each as one u128: decreasing u, then increasing index
    // (sorting packed keys moves a third of the bytes a tuple would).
    let mut todo: Vec<u128> = Vec::new();
    let mut v = Visit::default();
    for z in h - reach..h + shape[0] as usize + reach {
        for y in h - reach..h + shape[1] as usize + reach {
            for x in h - reach..h + shape[2] as usize + reach {
                let i = at(z, y, x);
                if is_target(lb.data[i]) && !known(&d, i) {
                    todo.push(pack(ub.data[i], i));
                }
            }
        }
    }
    if todo.is_empty() {
        return Ok(v);
    }
    // The tile covers the block's halo but its last node; the boundary nodes' values
    // need SURFACE_REACH more nodes of u around that.
    let tile = Tile::from_u(
        &wide,
        ub.origin.map(|o| o + 1),
        [hs[0] - 2, hs[1] - 2, hs[2] - 2],
    );
    drop(wide);
    let region = Region {
        u: &ub.data,
        lab: &lb.data,
        hs,
        origin: ub.origin,
        tile: &tile,
        ball,
    };
    // Decreasing u; ties in index order (the keys are distinct, so the order is
    // deterministic).
    todo.sort_unstable();
    let local = |i: usize| [i / (hs[1] * hs[2]), i / hs[2] % hs[1], i % hs[2]];
    // What voxel `t` gets from the directions known so far.
    let eval = |d: &[Vec<f32>; 3], t: &u128, fill: bool| -> Upwind {
        let i = index(*t);
        let (ux, local) = (ub.data[i], local(i));
        let g: [f64; 3] =
            std::array::from_fn(|a| start[2 - a] as f64 + local[2 - a] as f64 - h as f64);
        let p = DVec3::from_array(g);
        let r = p - ball.center;
        if r.length() <= ball.radius {
            let n = r.length();
            return Upwind::Value(if n > 1e-12 { r / n } else { DVec3::Z });
        }
        let step = match region.follow(d, p, ux) {
            Upwind::Flat => upwind(&ub.data, &lb.data, d, i, ux, strides),
            other => other,
        };
        match step {
            Upwind::Wait(_) | Upwind::Flat if fill && core(local) => {
                mean_of_neighbours(&lb.data, d, i, strides).map_or(Upwind::Flat, Upwind::Filled)
            }
            other => other,
        }
    };
    let mut changed = false;
    let mut apply = |d: &mut [Vec<f32>; 3], t: &u128, value: Upwind| {
        let i = index(*t);
        let local = local(i);
        let own = core(local);
        let (dir, filled) = match value {
            Upwind::Value(dir) => (dir, false),
            Upwind::Filled(dir) => (dir, true),
            _ => {
                v.pending += u64::from(own);
                return;
            }
        };
        for a in 0..3 {
            d[a][i] = dir[a] as f32;
        }
        if !own {
            return;
        }
        changed = true;
        let g: [f64; 3] =
            std::array::from_fn(|a| start[2 - a] as f64 + local[2 - a] as f64 - h as f64);
        if filled {
            v.filled += 1;
        } else if (DVec3::from_array(g) - ball.center).length() <= ball.radius {
            v.ball += 1;
        } else {
            v.computed += 1;
        }
    };
    if rule == Rule::Upwind && parallel {
        // In slices of decreasing u, in parallel against the directions known before
        // the slice; a voxel that waited for one in its own slice is redone in order.
        // Every value is the unique one of the dependency graph, so the result is the
        // same as one voxel after the other.
        for slice in todo.chunks(4096) {
            let first: Vec<Upwind> = slice.par_iter().map(|t| eval(&d, t, false)).collect();
            for (t, value) in slice.iter().zip(first) {
                let value = match value {
                    Upwind::Wait(n) if known(&d, n) => eval(&d, t, false),
                    other => other,
                };
                apply(&mut d, t, value);
            }
        }
    } else {
        for t in &todo {
            let value = eval(&d, t, rule == Rule::Fill);
            apply(&mut d, t, value);
        }
    }
    if changed {
        for (a, store) in dirs.c.iter().enumerate() {
            store.write_block(b, &crop(&d[a], hs, shape, h))?;
        }
    }
    Ok(v)
}

fn crop(data: &[f32], hs: [usize; 3], shape: Idx3, h: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(volume(shape) as usize);
    for z in h..h + shape[0] as usize {
        for y in h..h + shape[1] as usize {
            let row = (z * hs[1] + y) * hs[2];
            out.extend_from_slice(&data[row + h..row + h + shape[2] as usize]);
        }
    }
    out
}

enum Upwind {
    Value(DVec3),
    /// Set from the neighbours (no upwind neighbour).
    Filled(DVec3),
    /// An upwind neighbour (this local index) has no direction yet.
    Wait(usize),
    /// No neighbour has a higher u.
    Flat,
    /// The voxel needs data beyond what this visit read (a voxel of the halo).
    Skip,
}

/// Length (voxels) of each midpoint step of the short streamline a voxel follows before
/// it interpolates the direction, and the number of steps.
const STEP: f64 = 2.0;
const STEPS: usize = 1;

/// What a visit holds: u and labels with the halo, and the tracer's direction field.
struct Region<'a> {
    u: &'a [f64],
    lab: &'a [u8],
    hs: [usize; 3],
    /// Grid index [z, y, x] of local voxel 0.
    origin: [i64; 3],
    tile: &'a Tile,
    ball: &'a StopBall,
}

impl Region<'_> {
    /// Whether the cells within `m` voxels of the cell of `q` all lie in the tile.
    fn safe(&self, q: DVec3, m: i64) -> bool {
        let c = [q.z.floor() as i64, q.y.floor() as i64, q.x.floor() as i64];
        (0..3).all(|a| {
            c[a] - m >= self.tile.origin[a]
                && c[a] + m + 1 < self.tile.origin[a] + self.tile.shape[a] as i64
        })
    }

    /// The semi-Lagrangian step: follow the streamline through `p` (u = `ux`) uphill
    /// in u for `STEPS` midpoint steps with the tracer's field, then interpolate the
    /// direction trilinearly at the foot from the corners of its cell, which all lie
    /// higher in u (else Flat, and the caller takes the one-cell upwind rule). A path
    /// that enters the stop ball takes the direction of its entry point.
    fn follow(&self, d: &[Vec<f32>; 3], p: DVec3, ux: f64) -> Upwind {
        let reach = STEP.ceil() as i64;
        let mut q = p;
        for _ in 0..STEPS {
            if !self.safe(q, reach) {
                return Upwind::Skip;
            }
            // At the voxel itself the node's own direction; later the interpolant.
            let first = if q == p {
                self.tile
                    .node([q.z as i64, q.y as i64, q.x as i64])
                    .map_or_else(|| self.tile.direction(q), Ok)
            } else {
                self.tile.direction(q)
            };
            let Ok(k1) = first else { break };
            let Ok(k2) = self.tile.direction(q + 0.5 * STEP * k1) else {
                break;
            };
            let next = q + STEP * k2;
            if let Some(e) = self.ball.entry(q, next) {
                let r = e - self.ball.center;
                return if r.length() > 0.0 {
                    Upwind::Value(r.normalize())
                } else {
                    Upwind::Flat
                };
            }
            q = next;
        }
        if q == p || !self.safe(q, 0) {
            return Upwind::Flat;
        }
        let f = [q.z.floor(), q.y.floor(), q.x.floor()];
        let t = [q.z - f[0], q.y - f[1], q.x - f[2]];
        let l: [usize; 3] = std::array::from_fn(|a| (f[a] as i64 - self.origin[a]) as usize);
        let mut acc = DVec3::ZERO;
        let mut wsum = 0.0;
        for k in 0..8 {
            let o = [k >> 2, (k >> 1) & 1, k & 1];
            let w = crate::math::corner_weight(t, o);
            let n = ((l[0] + o[0]) * self.hs[1] + l[1] + o[1]) * self.hs[2] + l[2] + o[2];
            if w == 0.0 || !is_target(self.lab[n]) {
                continue;
            }
            if self.u[n] <= ux {
                return Upwind::Flat;
            }
            if !known(d, n) {
                return Upwind::Wait(n);
            }
            acc += w * get(d, n);
            wsum += w;
        }
        let len = acc.length();
        if wsum == 0.0 || len < 1e-3 * wsum {
            return Upwind::Flat;
        }
        Upwind::Value(acc / len)
    }
}

/// The sort key of voxel `i` with u = `u`: ascending keys go by decreasing u, ties by
/// increasing index; the low 64 bits are `i`.
fn pack(u: f64, i: usize) -> u128 {
    (u128::from(!ordered(u)) << 64) | i as u128
}

/// The voxel index a [`pack`]ed key holds.
fn index(key: u128) -> usize {
    key as u64 as usize
}

/// A u64 whose order is the order of the f64 `x` (total order, as `f64::total_cmp`).
fn ordered(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 {
        !b
    } else {
        b | (1 << 63)
    }
}

/// Whether voxel `i` of a halo block has a direction.
fn known(d: &[Vec<f32>; 3], i: usize) -> bool {
    d[0][i] != 0.0 || d[1][i] != 0.0 || d[2][i] != 0.0
}

fn get(d: &[Vec<f32>; 3], i: usize) -> DVec3 {
    DVec3::new(f64::from(d[0][i]), f64::from(d[1][i]), f64::from(d[2][i]))
}

fn upwind(
    u: &[f64],
    lab: &[u8],
    d: &[Vec<f32>; 3],
    i: usize,
    ux: f64,
    strides: [usize; 3],
) -> Upwind {
    let mut acc = DVec3::ZERO;
    let mut any = false;
    let mut strongest = (0.0, DVec3::ZERO);
    for s in strides {
        let (lo, hi) = (i - s, i + s);
        let pick = match (
            is_target(lab[lo]) && u[lo] > ux,
            is_target(lab[hi]) && u[hi] > ux,
        ) {
            (true, true) => Some(if u[hi] > u[lo] { hi } else { lo }),
            (true, false) => Some(lo),
            (false, true) => Some(hi),
            (false, false) => None,
        };
        if let Some(n) = pick {
            if !known(d, n) {
                return Upwind::Wait(n);
            }
            let w = u[n] - ux;
            let dn = get(d, n);
            acc += w * dn;
            any = true;
            if w > strongest.0 {
                strongest = (w, dn);
            }
        }
    }
    if !any {
        return Upwind::Flat;
    }
    let len = acc.length();
    // Opposite neighbours can cancel (a ridge between two arrival regions): take the
    // steepest one rather than an arbitrary direction.
    Upwind::Value(if len > 1e-3 * strongest.0 {
        acc / len
    } else {
        strongest.1.normalize()
    })
}

fn mean_of_neighbours(
    lab: &[u8],
    d: &[Vec<f32>; 3],
    i: usize,
    strides: [usize; 3],
) -> Option<DVec3> {
    let mut acc = DVec3::ZERO;
    let mut any = None;
    for dz in -1i64..=1 {
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                if (dz, dy, dx) == (0, 0, 0) {
                    continue;
                }
                let off = dz * strides[0] as i64 + dy * strides[1] as i64 + dx;
                let n = (i as i64 + off) as usize;
                if is_target(lab[n]) && known(d, n) {
                    let g = get(d, n);
                    acc += g;
                    any.get_or_insert(g);
                }
            }
        }
    }
    let first = any?;
    let len = acc.length();
    Some(if len > 1e-6 {
        acc / len
    } else {
        first.normalize()
    })
}
