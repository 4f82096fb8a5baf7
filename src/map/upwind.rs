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
//! Blocks are visited with a halo (see [`transport`]): first the blocks the stop ball
//! touches, together, then every other block once its neighbours ranked before it
//! (nearer the center) are done; later rounds visit, in eight colour groups (no two
//! blocks of a group touch), the blocks whose neighbours gained values, until nothing
//! changes. Voxels with no upwind neighbour (flat sheets of boundary voxels, where u = 0
//! on every side) then take the mean direction of their neighbours that have one, in
//! that fixed order of blocks.

use glam::DVec3;
use rayon::prelude::*;

use crate::grid::{Block, BlockStore, GridError, MemStore, MmapStore};
use crate::math::{floor, volume, Idx3};
use crate::parallel::map_bounded;
use crate::progress::Progress;
use crate::trace::field::Tile;
use crate::trace::integrate::StopBall;
use crate::trace::nearest::SurfaceIndex;
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

    /// Block `b` with a halo of [`HALO`], one [x, y, z] per voxel (a visit reads all
    /// three components of a voxel together).
    fn read_halo(&self, b: Idx3) -> Result<Vec<[f32; 3]>, GridError> {
        let r = |i: usize| -> Result<Vec<f32>, GridError> {
            Ok(self.c[i].read_block_halo(b, HALO as usize, 0.0)?.data)
        };
        let [x, y, z] = [r(0)?, r(1)?, r(2)?];
        Ok((0..x.len()).map(|i| [x[i], y[i], z[i]]).collect())
    }

    /// The x, y and z components of block `b` (all three zero where there is no value).
    pub fn read(&self, b: Idx3) -> Result<[Vec<f32>; 3], GridError> {
        Ok([
            self.c[0].read_block(b)?,
            self.c[1].read_block(b)?,
            self.c[2].read_block(b)?,
        ])
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
    // u (f64), labels (u8), the three f32 components as read and interleaved, the
    // visiting order (a 16 B key, a chunk and an index per voxel of the block and its
    // first layer of halo) and the output; the direction tile and what building it
    // holds (u with the tile's margin, read once for both).
    h * (8 + 1 + 24)
        + volume(chunk.map(|c| c + 2 * REACH as u64)) * 24
        + volume(chunk) * 12
        + Tile::bytes(tile)
        + Tile::build_bytes(tile)
}

/// The blocks the stop ball touches: they hold the seeds every other voxel depends on.
#[must_use]
pub fn central_blocks(spec: &crate::grid::GridSpec, ball: &StopBall) -> Vec<Idx3> {
    let c = [ball.center.z, ball.center.y, ball.center.x];
    spec.block_indices()
        .into_iter()
        .filter(|b| {
            let st = spec.block_start(*b);
            let sh = spec.block_shape(*b);
            (0..3).all(|a| {
                (st[a] as f64) <= c[a] + ball.radius
                    && ((st[a] + sh[a]) as f64) > c[a] - ball.radius
            })
        })
        .collect()
}

/// Bytes the transport holds beyond its workers: the results of the central blocks,
/// which are visited together and written when all are done.
#[must_use]
pub fn held_bytes(spec: &crate::grid::GridSpec, ball: &StopBall) -> u64 {
    central_blocks(spec, ball).len() as u64 * volume(spec.chunk) * 12
}

/// Takes each block whose target voxels all have their direction, once, when they do:
/// the block, its labels and its directions as [x, y, z] component blocks (all three
/// zero where there is none), as [`Directions::read`] gives them.
pub type Sink<'a> = &'a (dyn Fn(Idx3, &[u8], &[Vec<f32>; 3]) -> Result<(), GridError> + Sync);

/// What the transport knows about each block, updated after every visit.
struct Book<'a> {
    spec: &'a crate::grid::GridSpec,
    /// Target voxels of the block's core still without a direction (MAX: not visited).
    pending: Vec<u64>,
    /// Whether a neighbour gained directions since the block's last visit.
    stale: Vec<bool>,
    stats: TransportStats,
    /// Voxels done, for the progress bar.
    done: u64,
}

impl Book<'_> {
    fn lin(&self, b: Idx3) -> usize {
        self.spec.block_linear(b) as usize
    }

    /// Whether block `b` is to be visited in a round.
    fn due(&self, b: Idx3) -> bool {
        let i = self.lin(b);
        self.stale[i] && self.pending[i] > 0
    }

    /// Record visit `v` of block `b`; whether it set any voxel.
    fn record(&mut self, b: Idx3, v: Visit) -> bool {
        self.stats.visits += 1;
        let i = self.lin(b);
        let first = self.pending[i] == u64::MAX;
        self.pending[i] = v.pending;
        self.stale[i] = false;
        if first {
            // Voxels that are not targets count as done for the bar.
            let vol = volume(self.spec.block_shape(b));
            self.done += vol - v.ball - v.computed - v.filled - v.pending;
        }
        self.done += v.ball + v.computed + v.filled;
        self.stats.from_ball += v.ball;
        self.stats.upwind += v.computed;
        self.stats.filled += v.filled;
        let changed = v.ball + v.computed + v.filled > 0;
        if changed {
            for n in neighbours(b, self.spec.blocks()) {
                let j = self.lin(n);
                self.stale[j] = true;
            }
        }
        changed
    }
}

/// Transport the arrival direction into `dirs` for every target voxel.
///
/// The first round visits every block once, in an order that meets the dependencies
/// between neighbouring blocks: first the central blocks (together: each reads the
/// state before any of them and their results are written when all are done), then
/// the others as soon as their neighbours ranked before them (by distance from the
/// center, then colour) are done, on `workers` threads. Two blocks that touch are never visited at the same time
/// (one of them waits for the other). Later rounds go over the blocks with voxels left
/// in eight colour groups (no two blocks of a group touch) until nothing changes,
/// first by the upwind rule and then allowed to fill.
#[allow(clippy::too_many_arguments)]
pub fn transport(
    u: &dyn BlockStore<f64>,
    boundary: Option<&SurfaceIndex>,
    labels: &dyn BlockStore<u8>,
    dirs: &Directions,
    ball: &StopBall,
    workers: usize,
    progress: &dyn Progress,
    sink: Option<Sink>,
) -> Result<TransportStats, GridError> {
    let spec = u.spec();
    let blocks = spec.block_indices();
    let central = central_blocks(spec, ball);
    let c = [ball.center.z, ball.center.y, ball.center.x];
    // Squared distance from the center to the block's nearest voxel.
    let dist2 = |b: &Idx3| -> f64 {
        let st = spec.block_start(*b);
        let sh = spec.block_shape(*b);
        (0..3)
            .map(|a| {
                let lo = st[a] as f64;
                let hi = (st[a] + sh[a] - 1) as f64;
                let e = (lo - c[a]).max(c[a] - hi).max(0.0);
                e * e
            })
            .sum()
    };
    let mut order: Vec<Idx3> = blocks
        .iter()
        .copied()
        .filter(|b| !central.contains(b))
        .collect();
    // By distance in quarters of a block edge, then by colour: blocks about as far
    // out hardly depend on each other, and those of one colour never touch, so they can
    // run side by side (by distance alone, ties went in index order, and each waited
    // for the touching one before it).
    let colour = |b: &Idx3| (b[0] % 2) * 4 + (b[1] % 2) * 2 + b[2] % 2;
    let quarter = spec.chunk.iter().copied().min().unwrap_or(4).max(4) as f64 / 4.0;
    let rank = |b: &Idx3| {
        (
            (dist2(b).sqrt() / quarter).floor() as u64,
            colour(b),
            spec.block_linear(*b),
        )
    };
    order.sort_by_key(rank);
    // Later rounds: by distance from the center (in block edges), then by colour (no
    // two blocks of a group touch), so that what a round finds moves outwards within it.
    let key = |b: &Idx3| {
        let ring = (dist2(b).sqrt() / spec.chunk[0] as f64).floor() as u64;
        (ring, colour(b))
    };
    let mut by_key = blocks.clone();
    by_key.sort_by_key(|b| (key(b), spec.block_linear(*b)));
    let mut colours: Vec<Vec<Idx3>> = Vec::new();
    for (i, b) in by_key.iter().enumerate() {
        if i == 0 || key(b) != key(&by_key[i - 1]) {
            colours.push(Vec::new());
        }
        colours.last_mut().expect("a group").push(*b);
    }
    let ctx = Ctx {
        u,
        boundary,
        labels,
        dirs,
        ball,
        workers,
        progress,
        sink,
    };
    let mut book = Book {
        spec,
        pending: vec![u64::MAX; blocks.len()],
        stale: vec![true; blocks.len()],
        stats: TransportStats::default(),
        done: 0,
    };
    progress.start("map (upwind)", spec.num_voxels());
    for (slot, rule) in [Rule::Upwind, Rule::Fill].into_iter().enumerate() {
        if rule == Rule::Fill {
            // Every block with voxels left looks again, now allowed to fill.
            for i in 0..book.pending.len() {
                book.stale[i] = book.pending[i] > 0;
            }
        }
        loop {
            crate::progress::check_interrupt(progress)?;
            let first = book.stats.rounds[slot] == 0 && rule == Rule::Upwind;
            book.stats.rounds[slot] += 1;
            let mut changed = false;
            if first {
                changed |= ctx.group(&mut book, &central, rule, true)?;
                // They did not see each other's results: those with voxels left go
                // again, one at a time, until none of them changes.
                loop {
                    let mut again = false;
                    for b in &central {
                        again |= ctx.group(&mut book, std::slice::from_ref(b), rule, false)?;
                    }
                    changed |= again;
                    if !again {
                        break;
                    }
                }
                changed |= ctx.ordered(&mut book, &order)?;
            } else {
                for g in &colours {
                    crate::progress::check_interrupt(progress)?;
                    changed |= ctx.group(&mut book, g, rule, false)?;
                }
            }
            if !changed {
                break;
            }
        }
    }
    progress.finish();
    let mut stats = book.stats;
    stats.unreached = book.pending.iter().filter(|&&p| p != u64::MAX).sum();
    Ok(stats)
}

/// What the workers of [`Ctx::ordered`] share.
struct OrderState<'b, 'c> {
    /// Blocks whose earlier neighbours are all done, by rank.
    ready: std::collections::BinaryHeap<std::cmp::Reverse<usize>>,
    /// Earlier neighbours not done yet, by rank.
    waits: Vec<u32>,
    /// Blocks not done yet.
    left: usize,
    error: Option<GridError>,
    panic: Option<Box<dyn std::any::Any + Send>>,
    changed: bool,
    book: &'b mut Book<'c>,
}

/// What a visit did, and the block's directions (x, y, z) when they are to be written
/// by the caller.
type Visited = (Visit, Option<[Vec<f32>; 3]>);

/// What every visit of a transport reads.
struct Ctx<'a> {
    u: &'a dyn BlockStore<f64>,
    boundary: Option<&'a SurfaceIndex>,
    labels: &'a dyn BlockStore<u8>,
    dirs: &'a Directions,
    ball: &'a StopBall,
    workers: usize,
    progress: &'a dyn Progress,
    sink: Option<Sink<'a>>,
}

impl Ctx<'_> {
    /// Visit the due blocks of `group` at the same time: blocks that do not touch, or,
    /// `together`, blocks that may, each visited against the state before the group and
    /// written when all are done. A group of fewer blocks than workers spreads each
    /// visit over the threads instead.
    fn group(
        &self,
        book: &mut Book,
        group: &[Idx3],
        rule: Rule,
        together: bool,
    ) -> Result<bool, GridError> {
        let todo: Vec<Idx3> = group.iter().copied().filter(|b| book.due(*b)).collect();
        if todo.is_empty() {
            return Ok(false);
        }
        let inside = todo.len() < self.workers;
        let visits = map_bounded(&todo, self.workers, |&b| {
            self.visit(b, rule, inside, !together)
        })?;
        let mut changed = Vec::with_capacity(todo.len());
        for (b, (v, out)) in todo.iter().zip(visits) {
            if let Some(out) = out {
                for (store, comp) in self.dirs.c.iter().zip(out) {
                    store.write_block(*b, &comp)?;
                }
            }
            changed.push(book.record(*b, v));
        }
        if together {
            // A block of the group did not see what the others (it may touch) found.
            for (i, b) in todo.iter().enumerate() {
                if changed.iter().enumerate().any(|(j, &c)| c && j != i) {
                    let k = book.lin(*b);
                    book.stale[k] = true;
                }
            }
        }
        self.progress.set_position(book.done);
        Ok(changed.iter().any(|&c| c))
    }

    /// Visit the blocks of `order` (the first round: all of them are due) on the
    /// workers, each once all its neighbours earlier in `order` are done.
    fn ordered(&self, book: &mut Book, order: &[Idx3]) -> Result<bool, GridError> {
        use std::cmp::Reverse;
        let spec = book.spec;
        let nb = spec.blocks();
        let mut rank = vec![usize::MAX; spec.num_blocks() as usize];
        for (r, b) in order.iter().enumerate() {
            rank[book.lin(*b)] = r;
        }
        let later = |r: usize| {
            neighbours(order[r], nb)
                .map(|n| rank[spec.block_linear(n) as usize])
                .filter(move |&q| q != usize::MAX && q > r)
        };
        let mut waits = vec![0u32; order.len()];
        for r in 0..order.len() {
            for q in later(r) {
                waits[q] += 1;
            }
        }
        let state = std::sync::Mutex::new(OrderState {
            ready: (0..order.len())
                .filter(|&r| waits[r] == 0)
                .map(Reverse)
                .collect(),
            waits,
            left: order.len(),
            error: None,
            panic: None,
            changed: false,
            book,
        });
        let wake = std::sync::Condvar::new();
        let lock = || {
            state
                .lock()
                .expect("nothing panics while it holds the lock")
        };
        let work = || loop {
            let r = {
                let mut st = lock();
                loop {
                    if st.error.is_some() || st.panic.is_some() || st.left == 0 {
                        return;
                    }
                    if let Some(Reverse(r)) = st.ready.pop() {
                        break r;
                    }
                    st = wake
                        .wait(st)
                        .expect("nothing panics while it holds the lock");
                }
            };
            let b = order[r];
            // A panic stops the others too (they would wait for this block forever)
            // and is raised again once they have.
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                crate::progress::check_interrupt(self.progress)?;
                self.visit(b, Rule::Upwind, false, true)
            }));
            let mut st = lock();
            match result {
                Err(p) => {
                    st.panic.get_or_insert(p);
                }
                Ok(Err(e)) => {
                    st.error.get_or_insert(e);
                }
                Ok(Ok((v, _))) => {
                    st.changed |= st.book.record(b, v);
                    self.progress.set_position(st.book.done);
                    st.left -= 1;
                    for q in later(r) {
                        st.waits[q] -= 1;
                        if st.waits[q] == 0 {
                            st.ready.push(Reverse(q));
                        }
                    }
                }
            }
            drop(st);
            wake.notify_all();
        };
        std::thread::scope(|s| {
            for _ in 1..self.workers.max(1) {
                s.spawn(work);
            }
            work();
        });
        let st = state
            .into_inner()
            .expect("nothing panics while it holds the lock");
        if let Some(p) = st.panic {
            std::panic::resume_unwind(p);
        }
        match st.error {
            Some(e) => Err(e),
            None => Ok(st.changed),
        }
    }
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

impl Ctx<'_> {
    /// Visit block `b`: compute every target voxel without a direction whose upwind
    /// neighbours have theirs (in decreasing u, so neighbours inside the block come first).
    #[allow(clippy::too_many_lines)]
    fn visit(
        &self,
        b: Idx3,
        rule: Rule,
        parallel: bool,
        write: bool,
    ) -> Result<Visited, GridError> {
        let (u, dirs, ball) = (self.u, self.dirs, self.ball);
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
        let lb = self.labels.read_block_halo(b, h, 0)?;
        let mut d = dirs.read_halo(b)?;
        let strides = [hs[1] * hs[2], hs[2], 1];
        let at = |z: usize, y: usize, x: usize| (z * hs[1] + y) * hs[2] + x;
        // Upwind voxels are computed in the halo too (all but its outer layer, whose
        // neighbours are not read), so chains of dependencies that zig-zag across the face
        // of the block resolve in one visit; only the core is written.
        let reach = if rule == Rule::Upwind { REACH } else { 0 };
        let in_core = |l: [usize; 3]| (0..3).all(|a| l[a] >= h && l[a] < h + shape[a] as usize);
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
            // No target voxel in the core (a block is due only with voxels left).
            if let Some(sink) = self.sink {
                let none = || vec![0.0; volume(shape) as usize];
                sink(b, &core(&lb.data, hs, h, shape), &[none(), none(), none()])?;
            }
            return Ok((v, None));
        }
        // The tile covers the block's halo but its last node; the boundary nodes' values
        // need SURFACE_REACH more nodes of u around that.
        let tile = Tile::from_u(
            &wide,
            ub.origin.map(|o| o + 1),
            [hs[0] - 2, hs[1] - 2, hs[2] - 2],
            self.boundary,
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
        // (32-bit divisions: a visit's block with its halo holds far fewer than 2^32
        // voxels, and they are much faster than 64-bit ones.)
        let (plane, row) = ((hs[1] * hs[2]) as u32, hs[2] as u32);
        let local = |i: usize| {
            let i = i as u32;
            [i / plane, i / row % hs[1] as u32, i % row].map(|c| c as usize)
        };
        // What voxel `i` gets from the directions known so far, and whether it is in the
        // block's core.
        let eval = |d: &[[f32; 3]], i: usize, fill: bool| -> (Upwind, bool) {
            let (ux, local) = (ub.data[i], local(i));
            let own = in_core(local);
            let g: [f64; 3] =
                std::array::from_fn(|a| start[2 - a] as f64 + local[2 - a] as f64 - h as f64);
            let p = DVec3::from_array(g);
            let r = p - ball.center;
            let n = r.length();
            if n <= ball.radius {
                return (Upwind::Ball(if n > 1e-12 { r / n } else { DVec3::Z }), own);
            }
            let step = match region.follow(d, p, ux) {
                Upwind::Flat => upwind(&ub.data, &lb.data, d, i, ux, strides),
                other => other,
            };
            let value = match step {
                Upwind::Wait | Upwind::Flat if fill && own => {
                    mean_of_neighbours(&lb.data, d, i, strides).map_or(Upwind::Flat, Upwind::Filled)
                }
                other => other,
            };
            (value, own)
        };
        let mut changed = false;
        let mut apply = |d: &mut [[f32; 3]], i: usize, (value, own): (Upwind, bool)| {
            let (dir, count) = match value {
                Upwind::Value(dir) => (dir, &mut v.computed),
                Upwind::Ball(dir) => (dir, &mut v.ball),
                Upwind::Filled(dir) => (dir, &mut v.filled),
                _ => {
                    v.pending += u64::from(own);
                    return;
                }
            };
            d[i] = dir.as_vec3().to_array();
            if own {
                changed = true;
                *count += 1;
            }
        };
        // In chunks of decreasing u, each visited in memory order: the chunk's voxels are
        // a thin shell, and memory order keeps u, the tile and the directions in cache where
        // the order of u would jump across the block. A voxel that waits for one of its own
        // chunk is retried after the chunk, in the order of u, when all those above it are
        // done. Every value is the unique one of the dependency graph, so the result is the
        // same as one voxel after the other in the order of u.
        let (starts, members) = chunks_of(&todo);
        let mut retry: Vec<u128> = Vec::new();
        let fill = rule == Rule::Fill;
        for w in starts.windows(2) {
            let chunk = &members[w[0]..w[1]];
            retry.clear();
            if parallel && !fill {
                // Against the directions known before the chunk, spread over the threads.
                let first: Vec<(Upwind, bool)> = chunk
                    .par_iter()
                    .map(|&i| eval(&d, i as usize, false))
                    .collect();
                for (&i, value) in chunk.iter().zip(first) {
                    match value {
                        (Upwind::Wait, _) => retry.push(pack(ub.data[i as usize], i as usize)),
                        value => apply(&mut d, i as usize, value),
                    }
                }
            } else {
                // When filling, only upwind values are final out of order: what a voxel
                // fills from its neighbours depends on which of them are done.
                for (j, &i) in chunk.iter().enumerate() {
                    if let Some(&n) = chunk.get(j + PREFETCH) {
                        prefetch(&ub.data, n as usize);
                        prefetch(&d, n as usize);
                        prefetch(&lb.data, n as usize);
                    }
                    let i = i as usize;
                    match eval(&d, i, false) {
                        (Upwind::Wait, _) => retry.push(pack(ub.data[i], i)),
                        value @ (Upwind::Value(_) | Upwind::Ball(_), _) => apply(&mut d, i, value),
                        _ if fill => retry.push(pack(ub.data[i], i)),
                        value => apply(&mut d, i, value),
                    }
                }
            }
            retry.sort_unstable();
            for &t in &retry {
                let value = eval(&d, index(t), fill);
                apply(&mut d, index(t), value);
            }
        }
        let sink = self.sink.filter(|_| v.pending == 0);
        if !changed && sink.is_none() {
            return Ok((v, None));
        }
        let out = components(&d, hs, h, shape);
        if let Some(sink) = sink {
            sink(b, &core(&lb.data, hs, h, shape), &out)?;
        }
        if !changed {
            return Ok((v, None));
        }
        if !write {
            return Ok((v, Some(out)));
        }
        for (store, comp) in dirs.c.iter().zip(&out) {
            store.write_block(b, comp)?;
        }
        Ok((v, None))
    }
}

/// The x, y and z components of the core of a visit's directions `d` (a block of
/// `shape` with a halo of `h`, `hs` in all), in one pass.
fn components(d: &[[f32; 3]], hs: [usize; 3], h: usize, shape: Idx3) -> [Vec<f32>; 3] {
    let n = volume(shape) as usize;
    let mut out = [
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    ];
    for z in h..h + shape[0] as usize {
        for y in h..h + shape[1] as usize {
            let row = (z * hs[1] + y) * hs[2] + h;
            for c in &d[row..row + shape[2] as usize] {
                for (o, &v) in out.iter_mut().zip(c) {
                    o.push(v);
                }
            }
        }
    }
    out
}

/// The core of a visit's array `data` (a block of `shape` with a halo of `h`, `hs` in
/// all).
fn core<T: Copy>(data: &[T], hs: [usize; 3], h: usize, shape: Idx3) -> Vec<T> {
    let mut out = Vec::with_capacity(volume(shape) as usize);
    for z in h..h + shape[0] as usize {
        for y in h..h + shape[1] as usize {
            let row = (z * hs[1] + y) * hs[2] + h;
            out.extend_from_slice(&data[row..row + shape[2] as usize]);
        }
    }
    out
}

enum Upwind {
    /// From the upwind neighbours.
    Value(DVec3),
    /// Inside the stop ball: the direction from the center.
    Ball(DVec3),
    /// Set from the neighbours (no upwind neighbour).
    Filled(DVec3),
    /// An upwind neighbour has no direction yet.
    Wait,
    /// No neighbour has a higher u.
    Flat,
    /// The voxel needs data beyond what this visit read (a voxel of the halo).
    Skip,
}

/// Voxels of a visit taken together, in memory order, about (see [`Ctx::visit`]).
const CHUNK: usize = 4096;

/// One key in this many, in memory order, chooses where the chunks split.
const SAMPLE: usize = 16;

/// Split the [`pack`]ed keys `todo` (in memory order) into chunks of consecutive keys,
/// about [`CHUNK`] each: every key of a chunk sorts before every key of the next (higher
/// u), and a chunk keeps memory order. Returns the voxel indices, chunk after chunk, and
/// the bounds of the chunks in them (chunk k is `starts[k]..starts[k + 1]`).
fn chunks_of(todo: &[u128]) -> (Vec<usize>, Vec<u32>) {
    // Splitting keys from a sorted sample: far cheaper than sorting all the keys, and the
    // chunks need not be equal.
    let mut sample: Vec<u128> = todo.iter().step_by(SAMPLE).copied().collect();
    sample.sort_unstable();
    let mut splits: Vec<u128> = sample
        .iter()
        .skip(CHUNK / SAMPLE)
        .step_by(CHUNK / SAMPLE)
        .copied()
        .collect();
    splits.dedup();
    let chunk: Vec<u32> = todo
        .iter()
        .map(|t| splits.partition_point(|s| s <= t) as u32)
        .collect();
    // Chunk k (of splits.len() + 1) is counted at k + 2, so that after the prefix sums
    // starts[k + 1] is where it begins.
    let mut starts = vec![0usize; splits.len() + 3];
    for &k in &chunk {
        starts[k as usize + 2] += 1;
    }
    for k in 2..starts.len() {
        starts[k] += starts[k - 1];
    }
    // Filling moves starts[k + 1] to chunk k's end: chunk k is starts[k]..starts[k + 1]
    // (the last window is empty).
    let mut members = vec![0u32; todo.len()];
    for (t, &k) in todo.iter().zip(&chunk) {
        let k = k as usize;
        members[starts[k + 1]] = index(*t) as u32;
        starts[k + 1] += 1;
    }
    (starts, members)
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
        let c = [floor(q.z), floor(q.y), floor(q.x)];
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
    fn follow(&self, d: &[[f32; 3]], p: DVec3, ux: f64) -> Upwind {
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
        let f = [floor(q.z) as f64, floor(q.y) as f64, floor(q.x) as f64];
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
                return Upwind::Wait;
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
fn known(d: &[[f32; 3]], i: usize) -> bool {
    is_set(d[i])
}

/// Whether a direction (x, y, z) is set: (0, 0, 0) means "no value".
#[must_use]
pub fn is_set(v: [f32; 3]) -> bool {
    v.iter().any(|&c| c != 0.0)
}

fn get(d: &[[f32; 3]], i: usize) -> DVec3 {
    DVec3::from_array(d[i].map(f64::from))
}

fn upwind(u: &[f64], lab: &[u8], d: &[[f32; 3]], i: usize, ux: f64, strides: [usize; 3]) -> Upwind {
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
                return Upwind::Wait;
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

fn mean_of_neighbours(lab: &[u8], d: &[[f32; 3]], i: usize, strides: [usize; 3]) -> Option<DVec3> {
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

/// How many voxels ahead the voxel loop asks for a voxel's u, label and direction.
const PREFETCH: usize = 8;

/// Ask the processor to bring `data[i]` into its caches (a hint; nothing on other
/// targets). The voxels of a chunk lie scattered over the block (a thin shell of u), so
/// each misses the caches; asked for ahead, their loads overlap the work on the voxels
/// before them.
#[inline]
fn prefetch<T>(data: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < data.len() {
        // SAFETY: a prefetch reads nothing and cannot fault; the pointer lies in `data`.
        unsafe {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            _mm_prefetch::<_MM_HINT_T0>(data.as_ptr().add(i).cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keys as a visit makes them: u in memory order, with runs of equal u (flat sheets)
    /// and a spread of magnitudes.
    fn keys(n: usize) -> Vec<u128> {
        let mut x = 0x2545_f491_4f6c_dd1d_u64;
        (0..n)
            .map(|i| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let u = if i % 7 == 0 {
                    0.0
                } else {
                    (x >> 11) as f64 / (1u64 << 53) as f64 * 10f64.powi(-((x % 5) as i32))
                };
                pack(u, i)
            })
            .collect()
    }

    #[test]
    fn chunks_split_by_u_and_keep_memory_order() {
        for n in [0, 1, 100, CHUNK - 1, CHUNK, 10 * CHUNK + 17, 50_000] {
            let todo = keys(n);
            let (starts, members) = chunks_of(&todo);
            assert_eq!(members.len(), n);
            assert_eq!(starts.first(), Some(&0));
            assert_eq!(starts.last(), Some(&n));
            // Every voxel once.
            let mut seen = members.clone();
            seen.sort_unstable();
            assert!(seen.iter().enumerate().all(|(i, &m)| m as usize == i));
            let key = |m: u32| todo[m as usize];
            let mut before: Option<u128> = None;
            for w in starts.windows(2) {
                let chunk = &members[w[0]..w[1]];
                // Memory order within a chunk.
                assert!(chunk.windows(2).all(|p| p[0] < p[1]));
                // Every key of a chunk after every key of the chunks before it.
                if let (Some(b), Some(lo)) = (before, chunk.iter().map(|&m| key(m)).min()) {
                    assert!(lo > b, "n = {n}: chunks overlap in u");
                }
                if let Some(hi) = chunk.iter().map(|&m| key(m)).max() {
                    before = Some(hi);
                }
                assert!(
                    chunk.len() <= 4 * CHUNK,
                    "n = {n}: a chunk of {}",
                    chunk.len()
                );
            }
            if n >= 10 * CHUNK {
                let chunks = starts.windows(2).filter(|w| w[1] > w[0]).count();
                assert!(chunks >= n / CHUNK / 2, "n = {n}: only {chunks} chunks");
            }
        }
    }

    #[test]
    fn packed_keys_go_by_decreasing_u_then_index() {
        let us = [1.0, 0.5, 0.5, 1e-300, 0.0, -0.0, -1e-3, f64::NAN];
        let mut k: Vec<(u128, usize)> = us
            .iter()
            .enumerate()
            .map(|(i, &u)| (pack(u, i), i))
            .collect();
        k.sort_unstable();
        let order: Vec<usize> = k.iter().map(|&(_, i)| i).collect();
        assert_eq!(order, [7, 0, 1, 2, 3, 4, 5, 6]);
        assert!(k.iter().all(|&(key, i)| index(key) == i));
    }
}
