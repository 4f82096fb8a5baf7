//! Tiled tracing: streamlines wait in the queue of the tile that owns their point; in
//! rounds, the waiting tiles farthest from the center (a wave of a few per thread) are
//! built (node directions with a halo) if they are not cached and their streamlines
//! advanced, in one parallel pass; a streamline that leaves its tile joins the queue of
//! the next one. The cache is bounded by the memory budget and by what is worth keeping
//! ([`Tiling::keep_for`]); an evicted tile's node buffer goes to the next tile built.
//! u is read by chunks, mapped where they are stored raw.
//!
//! Across processes ([`trace_tiled_with`]): a part builds and advances only the tiles
//! whose first cell lies in a block its [`Decomposition`] owns. A streamline crosses to
//! another part when it leaves its tile for one that part owns: it is handed back to
//! the caller, with its state, to be traced on there. The tiles read only u, which the
//! solve completed before, so the trace needs no halo exchange.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use glam::DVec3;
use rayon::prelude::*;

use super::field::Tile;
use super::integrate::{advance_all, Advance, Line, Rk45, Stop, StopBall, ESCAPE_RADIUS};
use super::nearest::SurfaceIndex;
use crate::grid::{
    copy_overlap, to_usize, Block, BlockStore, Decomposition, GridError, GridSpec, MappedBlock,
    Whole,
};
use crate::math::{volume, Idx3};
use crate::progress::Progress;

/// How a finished streamline ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// Why it stopped.
    pub stop: Stop,
    /// Where (voxel coordinates x, y, z).
    pub end: DVec3,
    /// Accepted steps.
    pub steps: u32,
    /// Arc length (voxels).
    pub length: f64,
}

/// The tiling of a grid and the memory it may use.
#[derive(Clone, Copy, Debug)]
pub struct Tiling {
    /// Grid shape `[z, y, x]`.
    pub grid: Idx3,
    /// Tile edge (nodes).
    pub edge: u64,
    /// Halo (nodes) a tile holds around its core.
    pub halo: i64,
    /// Tiles the cache may hold.
    pub cache_tiles: usize,
    /// Tiles one round builds and advances at most ([`Tiling::wave_for`]).
    pub wave: usize,
    /// u chunks (decoded or mapped) the cache may hold.
    pub cache_chunks: usize,
}

impl Tiling {
    /// Tiles per round for `threads` workers: four each, enough to keep them busy while
    /// tiles of very different loads are advanced (one is built while another's
    /// streamlines are traced, [`trace_tiled`]).
    #[must_use]
    pub fn wave_for(threads: usize) -> usize {
        4 * threads.max(1)
    }

    /// Tiles worth keeping for `threads` workers when memory allows more: two rounds'
    /// worth. Streamlines flow inward, so a tile is rarely visited again once the rounds
    /// have moved past it, and a tile kept costs fresh memory that the kernel must fault
    /// in and zero (4 KiB at a time: 3-4 ms for a tile of 74^3 nodes here, half of what
    /// building it takes), where an evicted tile hands its faulted-in buffer to the next
    /// build. (The 256^3 ball: the trace's peak resident set fell from 590 MB to 280 MB,
    /// its system time from 0.35 s to 0.13 s, and no tile was built twice.)
    #[must_use]
    pub fn keep_for(threads: usize) -> usize {
        2 * Self::wave_for(threads)
    }

    /// Halo needed by the integrator `rk`: its reach rounded up, plus two nodes (a point
    /// q reads the nodes from round(q) - 1 to round(q) + 1, which on the high side is
    /// ceil(reach) + 1 beyond the last owned cell; the trilinear fallback needs one), and
    /// at least the nodes an escape from a flat sheet looks at. Exact on the high side:
    /// `the_halo_holds_the_spline_of_every_stage_point` checks it.
    #[must_use]
    pub fn halo_for(rk: &Rk45) -> i64 {
        (rk.reach().ceil() as i64 + 2).max(ESCAPE_RADIUS + 2)
    }

    fn tiles(&self) -> Idx3 {
        self.grid.map(|n| n.div_ceil(self.edge))
    }

    /// The tile that owns `p` (points off the grid belong to the nearest edge tile).
    #[allow(clippy::many_single_char_names)]
    // the names of the formulas and index arithmetic (p, q points; h step; k stages; b block; i, j voxels; u, d fields)
    #[must_use]
    pub fn tile_of(&self, p: DVec3) -> u64 {
        let t = self.tiles();
        let c = [p.z, p.y, p.x];
        let idx: [u64; 3] = std::array::from_fn(|a| {
            let f = c[a].floor();
            let i = if f < 0.0 { 0 } else { (f as u64) / self.edge };
            i.min(t[a] - 1)
        });
        (idx[0] * t[1] + idx[1]) * t[2] + idx[2]
    }

    /// Cells owned by tile `k`, `[lo, hi)`; edge tiles own everything beyond the grid.
    fn core(&self, k: u64) -> ([i64; 3], [i64; 3]) {
        let t = self.tiles();
        let idx = [k / (t[1] * t[2]), (k / t[2]) % t[1], k % t[2]];
        let mut lo = [0i64; 3];
        let mut hi = [0i64; 3];
        for a in 0..3 {
            lo[a] = (idx[a] * self.edge) as i64;
            hi[a] = ((idx[a] + 1) * self.edge).min(self.grid[a]) as i64;
            if idx[a] == 0 {
                lo[a] = i64::MIN / 4;
            }
            if idx[a] + 1 == t[a] {
                hi[a] = i64::MAX / 4;
            }
        }
        (lo, hi)
    }

    /// Distance from `c` (voxel coordinates x, y, z) to the middle of tile `k`.
    fn distance(&self, k: u64, c: DVec3) -> f64 {
        let t = self.tiles();
        let idx = [k / (t[1] * t[2]), (k / t[2]) % t[1], k % t[2]];
        let mid = idx.map(|i| (i as f64 + 0.5) * self.edge as f64);
        (DVec3::new(mid[2], mid[1], mid[0]) - c).length()
    }

    /// Whether `decomp` owns tile `k`: the block of its first cell is its.
    #[must_use]
    pub fn owned_by(&self, k: u64, spec: &GridSpec, decomp: &dyn Decomposition) -> bool {
        let t = self.tiles();
        let idx = [k / (t[1] * t[2]), (k / t[2]) % t[1], k % t[2]];
        let b: Idx3 =
            std::array::from_fn(|a| (idx[a] * self.edge).min(self.grid[a] - 1) / spec.chunk[a]);
        decomp.owns(spec, b)
    }

    /// The node box a tile holds: its cells within the grid, plus the halo.
    fn node_box(&self, k: u64) -> ([i64; 3], [usize; 3]) {
        let t = self.tiles();
        let idx = [k / (t[1] * t[2]), (k / t[2]) % t[1], k % t[2]];
        let mut origin = [0i64; 3];
        let mut shape = [0usize; 3];
        for a in 0..3 {
            let lo = (idx[a] * self.edge) as i64;
            let hi = ((idx[a] + 1) * self.edge).min(self.grid[a]) as i64;
            origin[a] = lo - self.halo;
            shape[a] = (hi - lo + 2 * self.halo) as usize;
        }
        (origin, shape)
    }
}

/// A small least-recently-used cache.
pub(crate) struct Lru<V> {
    cap: usize,
    clock: u64,
    map: HashMap<u64, (Arc<V>, u64)>,
}

impl<V> Lru<V> {
    pub(crate) fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(1),
            clock: 0,
            map: HashMap::new(),
        }
    }

    pub(crate) fn get(&mut self, k: u64) -> Option<Arc<V>> {
        self.clock += 1;
        let c = self.clock;
        self.map.get_mut(&k).map(|e| {
            e.1 = c;
            e.0.clone()
        })
    }

    /// Drop the least recently used entries until `room` more fit.
    fn make_room(&mut self, room: usize) {
        drop(self.evict(room));
    }

    /// Remove the least recently used entries until `room` more fit, and return them.
    fn evict(&mut self, room: usize) -> Vec<Arc<V>> {
        let mut out = Vec::new();
        while !self.map.is_empty() && self.map.len() + room > self.cap {
            let old = self
                .map
                .iter()
                .min_by_key(|(key, (_, t))| (*t, **key))
                .map(|(key, _)| *key)
                .expect("not empty");
            out.extend(self.map.remove(&old).map(|e| e.0));
        }
        out
    }

    pub(crate) fn put(&mut self, k: u64, v: Arc<V>) {
        self.clock += 1;
        if !self.map.contains_key(&k) {
            self.make_room(1);
        }
        self.map.insert(k, (v, self.clock));
    }
}

/// A chunk of u: decoded, or its stored bytes mapped.
enum Chunk {
    Decoded(Vec<f64>),
    Mapped(Arc<MappedBlock<f64>>),
}

impl std::ops::Deref for Chunk {
    type Target = [f64];

    fn deref(&self) -> &[f64] {
        match self {
            Self::Decoded(v) => v,
            Self::Mapped(m) => m,
        }
    }
}

/// Chunks of u = 1 - phi, shared by the tile builders: mapped where the store keeps them
/// raw, decoded otherwise.
struct Chunks<'a> {
    phi: &'a dyn BlockStore<f64>,
    cache: Mutex<Lru<Chunk>>,
    decoded: std::sync::atomic::AtomicU64,
}

impl Chunks<'_> {
    fn block(&self, b: Idx3) -> Result<Arc<Chunk>, GridError> {
        let key = self.phi.spec().block_linear(b);
        if let Some(v) = self.cache.lock().expect("lock").get(key) {
            return Ok(v);
        }
        let v = Arc::new(match self.phi.map_block(b) {
            Some(m) => Chunk::Mapped(m?),
            None => Chunk::Decoded(self.phi.read_block(b)?),
        });
        self.decoded
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.cache.lock().expect("lock").put(key, v.clone());
        Ok(v)
    }

    /// phi over `[origin, origin + shape)`, NaN off the grid.
    fn region(&self, origin: [i64; 3], shape: [usize; 3]) -> Result<Block<f64>, GridError> {
        let spec: &GridSpec = self.phi.spec();
        let mut out = Block::filled(origin, shape, f64::NAN);
        for b in spec.blocks_overlapping(origin, shape) {
            let data = self.block(b)?;
            let s = spec.block_start(b).map(|c| c as i64);
            copy_overlap(&data, s, to_usize(spec.block_shape(b)), &mut out);
        }
        Ok(out)
    }
}

/// Counters of a tiled trace.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct TileStats {
    /// Rounds of the scheduler.
    pub rounds: u64,
    /// Tiles built (a tile evicted and needed again is built again).
    pub tiles_built: u64,
    /// Different tiles built: `tiles_built` less this is how many builds were repeats.
    pub tiles_distinct: u64,
    /// u chunks read (decoded, or mapped where stored raw).
    pub chunks_decoded: u64,
    /// Hand-offs of a streamline from one tile to another.
    pub handoffs: u64,
}

/// The outcome of every line (by id), the points of every line when recorded, and the
/// scheduler's counters.
pub type Traced = (Vec<Outcome>, Option<Vec<Vec<DVec3>>>, TileStats);

/// A streamline that finished in a tile: its id, outcome and the points it added.
type Done = (u32, Outcome, Vec<DVec3>);
/// A streamline that left its tile, with the points it added.
type Moved = (Line, Vec<DVec3>);

/// A tile's visit in a round: the tile when it was built for it, and what became of its
/// streamlines, slice by slice.
type Visit = (Option<(u64, Arc<Tile>)>, Vec<(Vec<Done>, Vec<Moved>)>);

/// Lines advanced between two looks at the stop token (see the trace loop).
const STOP_CHECK_LINES: usize = 8;

/// Advance the streamlines of `slice` in `tile` (owning the cells `[lo, hi)`) until each
/// ends or leaves, pushing each onto the pair of lists given: those that ended, and
/// those that left.
#[allow(clippy::too_many_arguments)]
fn advance_slice(
    slice: &[Line],
    tile: &Tile,
    lo: [i64; 3],
    hi: [i64; 3],
    rk: &Rk45,
    ball: &StopBall,
    record_paths: bool,
    (done, moved): (&mut Vec<Done>, &mut Vec<Moved>),
) {
    advance_all(
        slice.iter().copied(),
        tile,
        lo,
        hi,
        rk,
        ball,
        record_paths,
        |l, r, path| match r {
            Advance::Done(stop, end) => done.push((
                l.id,
                Outcome {
                    stop,
                    end,
                    steps: l.steps,
                    length: l.length,
                },
                path,
            )),
            Advance::Moved => moved.push((l, path)),
        },
    );
}

/// Trace every line of `lines` to its end. `phi` is read through a chunk cache; tiles are
/// built as needed, their boundary nodes' values from `mesh` where it is given (the
/// run's input surface, [`super::surface`]). Results are indexed by `Line::id`. `paths`,
/// when given, collects the points of every streamline (for exports).
#[allow(clippy::too_many_arguments)]
pub fn trace_tiled(
    phi: &dyn BlockStore<f64>,
    mesh: Option<&SurfaceIndex>,
    tiling: &Tiling,
    rk: &Rk45,
    ball: &StopBall,
    lines: Vec<Line>,
    record_paths: bool,
    progress: &dyn Progress,
) -> Result<Traced, GridError> {
    let n = lines.len();
    let part = trace_tiled_with(
        phi,
        mesh,
        tiling,
        rk,
        ball,
        lines,
        n,
        record_paths,
        progress,
        &Whole,
    )?;
    debug_assert!(part.away.is_empty(), "one process owns every tile");
    let out = part
        .outcomes
        .into_iter()
        .map(|o| o.expect("every line finishes"))
        .collect();
    Ok((out, part.paths, part.stats))
}

/// What one part of a [`Decomposition`] traced ([`trace_tiled_with`]).
#[derive(Debug)]
pub struct TracedPart {
    /// The outcome of every line that ended here, by id (None: elsewhere or not yet).
    pub outcomes: Vec<Option<Outcome>>,
    /// The points each line took here, by id, when recorded: the seed first where it
    /// was advanced first, then every accepted point.
    pub paths: Option<Vec<Vec<DVec3>>>,
    /// The scheduler's counters for this part.
    pub stats: TileStats,
    /// Lines that left this part's tiles for another part's, as they were when they
    /// left: to be traced on by the part that owns them.
    pub away: Vec<Line>,
}

/// [`trace_tiled`] for the tiles `decomp` owns (see the module's docs): `lines` may be
/// seeds or lines handed over by another part, with ids below `ids`. A line's outcome
/// and points do not depend on which part or tile advanced it.
#[allow(clippy::too_many_arguments)]
#[allow(clippy::too_many_lines)] // one round of the scheduler reads as one loop; its steps share the queues and caches
pub fn trace_tiled_with(
    phi: &dyn BlockStore<f64>,
    mesh: Option<&SurfaceIndex>,
    tiling: &Tiling,
    rk: &Rk45,
    ball: &StopBall,
    lines: Vec<Line>,
    ids: usize,
    record_paths: bool,
    progress: &dyn Progress,
    decomp: &dyn Decomposition,
) -> Result<TracedPart, GridError> {
    let n = lines.len();
    let spec = phi.spec();
    let all = decomp.parts() == 1;
    let mine = |k: u64| all || tiling.owned_by(k, spec, decomp);
    let mut away = Vec::new();
    let chunks = Chunks {
        phi,
        cache: Mutex::new(Lru::new(tiling.cache_chunks)),
        decoded: std::sync::atomic::AtomicU64::new(0),
    };
    let mut tiles: Lru<Tile> = Lru::new(tiling.cache_tiles);
    let mut out: Vec<Option<Outcome>> = vec![None; ids];
    let mut paths: Option<Vec<Vec<DVec3>>> = record_paths.then(|| vec![Vec::new(); ids]);
    let mut pending: BTreeMap<u64, Vec<Line>> = BTreeMap::new();
    for l in lines {
        let k = tiling.tile_of(l.p);
        if !mine(k) {
            away.push(l);
            continue;
        }
        // A seed's path starts where it is advanced first.
        if let (Some(p), 0) = (paths.as_mut(), l.steps) {
            p[l.id as usize].push(l.p);
        }
        pending.entry(k).or_default().push(l);
    }
    let mut stats = TileStats::default();
    let mut seen = std::collections::HashSet::new();
    progress.start("trace", n as u64);
    while !pending.is_empty() {
        // A stop request ends the trace between rounds (a round is a fraction of a
        // second of work).
        crate::progress::check_interrupt(progress)?;
        stats.rounds += 1;
        // This round: the waiting tiles farthest from the center, at most a wave of
        // them. Streamlines flow inward, so a tile is mostly visited once, after the
        // tiles outside it have handed it their streamlines.
        let mut order: Vec<(f64, u64)> = pending
            .keys()
            .map(|&k| (tiling.distance(k, ball.center), k))
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        order.truncate(tiling.cache_tiles.min(tiling.wave).max(1));
        // Built in index order: neighbouring tiles share the phi chunks they read.
        let mut batch: Vec<u64> = order.iter().map(|o| o.1).collect();
        batch.sort_unstable();
        // Touch the cached ones first, so making room evicts tiles of no use this round
        // (the batch never exceeds the cache).
        let jobs: Vec<(u64, Option<Arc<Tile>>, Vec<Line>)> = batch
            .iter()
            .map(|&k| {
                let mut v = pending.remove(&k).expect("pending");
                // Neighbours one after another: they visit the same nodes, which then
                // stay in cache. (No line's result depends on the order.)
                v.sort_by_key(|l| {
                    let c = [l.p.z, l.p.y, l.p.x].map(|x| (x.max(0.0) as u64) >> 2);
                    ((c[0] * 4096 + c[1]) * 4096 + c[2], l.id)
                });
                (k, tiles.get(k), v)
            })
            .collect();
        let missing = jobs.iter().filter(|j| j.1.is_none()).count();
        // Room first, so old and new tiles never exceed the cache together; the evicted
        // tiles' node buffers are reused (already faulted in).
        let pool: Mutex<Vec<Vec<glam::Vec4>>> = Mutex::new(
            tiles
                .evict(missing)
                .into_iter()
                .filter_map(|t| Arc::try_unwrap(t).ok().map(Tile::into_nodes))
                .collect(),
        );
        // One pass: each tile is built if it is not cached, then its streamlines are
        // advanced in slices spread over the threads, so no thread waits for the last
        // build of the round before tracing.
        let visits: Vec<Visit> = jobs
            .into_par_iter()
            .with_max_len(1)
            .map(|(k, cached, v)| {
                let (tile, new) = if let Some(t) = cached {
                    (t, false)
                } else {
                    let (origin, shape) = tiling.node_box(k);
                    let (u_origin, u_shape) = Tile::u_box(origin, shape);
                    let u = chunks.region(u_origin, u_shape)?;
                    let buf = pool.lock().expect("lock").pop().unwrap_or_default();
                    (
                        Arc::new(Tile::from_u_in(&u, origin, shape, mesh, buf)),
                        true,
                    )
                };
                let (lo, hi) = tiling.core(k);
                let results = v
                    .par_chunks(512)
                    .with_max_len(1)
                    .map(|slice| {
                        // Stopping: the lines not yet advanced go back to wait unchanged,
                        // and the next round's check ends the trace. The token is looked
                        // at every few lines: with small steps a whole slice can take
                        // seconds, a few lines a small fraction of one.
                        let (mut done, mut moved) = (Vec::new(), Vec::new());
                        for few in slice.chunks(STOP_CHECK_LINES) {
                            if progress.interrupted() {
                                moved.extend(few.iter().map(|l| (*l, Vec::new())));
                            } else {
                                let out = (&mut done, &mut moved);
                                advance_slice(few, &tile, lo, hi, rk, ball, record_paths, out);
                            }
                        }
                        (done, moved)
                    })
                    .collect();
                Ok((new.then_some((k, tile)), results))
            })
            .collect::<Result<_, GridError>>()?;
        let mut results = Vec::new();
        for (built, r) in visits {
            if let Some((k, t)) = built {
                stats.tiles_built += 1;
                stats.tiles_distinct += u64::from(seen.insert(k));
                tiles.put(k, t);
            }
            results.extend(r);
        }
        let mut finished = 0u64;
        for (done, moved) in results {
            finished += done.len() as u64;
            for (id, o, path) in done {
                if let Some(p) = paths.as_mut() {
                    p[id as usize].extend(path);
                }
                out[id as usize] = Some(o);
            }
            stats.handoffs += moved.len() as u64;
            for (l, path) in moved {
                if let Some(p) = paths.as_mut() {
                    p[l.id as usize].extend(path);
                }
                let k = tiling.tile_of(l.p);
                if mine(k) {
                    pending.entry(k).or_default().push(l);
                } else {
                    away.push(l);
                }
            }
        }
        // Lines within a tile are in the order they arrived, which depends on the batch
        // order; no line's result depends on it.
        progress.advance(finished);
    }
    progress.finish();
    stats.chunks_decoded = chunks.decoded.load(std::sync::atomic::Ordering::Relaxed);
    Ok(TracedPart {
        outcomes: out,
        paths,
        stats,
        away,
    })
}

/// Bytes one tile of edge `edge` with `halo` takes in the cache, the most building one
/// holds besides (the u it is read from and the boundary's corrections), and one decoded
/// chunk of `spec`.
#[must_use]
pub fn footprint(edge: u64, halo: i64, spec: &GridSpec) -> (u64, u64, u64) {
    let s = [(edge as i64 + 2 * halo) as usize; 3];
    (Tile::bytes(s), Tile::build_bytes(s), volume(spec.chunk) * 8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parts of a decomposition, each tracing the lines in its tiles and handing the
    /// others on, give every line the outcome and the points one process gives it.
    #[test]
    fn parts_handing_lines_on_trace_what_one_process_traces() {
        use crate::grid::{MemStore, Slabs};
        use crate::progress::Silent;
        let n = 40u64;
        let spec = GridSpec {
            shape: [n; 3],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [8; 3],
            unit: None,
        };
        let c = DVec3::new(20.3, 19.9, 20.2);
        let u = MemStore::new(spec.clone(), 0.0f64);
        for b in spec.block_indices() {
            let (st, sh) = (spec.block_start(b), spec.block_shape(b));
            let mut data = Vec::new();
            for z in 0..sh[0] {
                for y in 0..sh[1] {
                    for x in 0..sh[2] {
                        let p =
                            DVec3::new((st[2] + x) as f64, (st[1] + y) as f64, (st[0] + z) as f64);
                        data.push(1000.0 - (p - c).length());
                    }
                }
            }
            u.write_block(b, &data).unwrap();
        }
        let rk = Rk45::default();
        let tiling = Tiling {
            grid: spec.shape,
            edge: 12,
            halo: Tiling::halo_for(&rk),
            cache_tiles: 8,
            cache_chunks: 64,
            wave: 4,
        };
        let ball = StopBall {
            center: c,
            radius: 2.0,
        };
        let seeds: Vec<Line> = (0..300u32)
            .map(|i| {
                let f = |k: u32| f64::from((i * k + 7) % 97) / 97.0 * 37.0 + 1.0;
                Line::new(i, DVec3::new(f(31), f(17), f(53)), &rk)
            })
            .collect();
        let (one, one_paths, _) =
            trace_tiled(&u, None, &tiling, &rk, &ball, seeds.clone(), true, &Silent).unwrap();
        let one_paths = one_paths.unwrap();
        let parts = 3;
        let mut inbox: Vec<Vec<Line>> = vec![seeds.clone(), Vec::new(), Vec::new()];
        let mut got: Vec<Option<Outcome>> = vec![None; seeds.len()];
        let mut paths: Vec<Vec<DVec3>> = vec![Vec::new(); seeds.len()];
        let mut handed = 0;
        for p in (0..parts).cycle().take(1000) {
            if inbox.iter().all(Vec::is_empty) {
                break;
            }
            let lines = std::mem::take(&mut inbox[p]);
            let part = trace_tiled_with(
                &u,
                None,
                &tiling,
                &rk,
                &ball,
                lines,
                seeds.len(),
                true,
                &Silent,
                &Slabs { part: p, parts },
            )
            .unwrap();
            for (i, o) in part.outcomes.into_iter().enumerate() {
                if let Some(o) = o {
                    assert!(got[i].is_none(), "line {i} ended twice");
                    got[i] = Some(o);
                }
            }
            for (i, piece) in part.paths.unwrap().into_iter().enumerate() {
                paths[i].extend(piece);
            }
            handed += part.away.len();
            inbox[(p + 1) % parts].extend(part.away);
        }
        assert!(inbox.iter().all(Vec::is_empty));
        assert!(handed > 0, "the lines should cross between parts");
        for (i, o) in one.iter().enumerate() {
            let g = got[i].expect("every line ends in some part");
            assert_eq!(o.stop, g.stop);
            assert_eq!(o.steps, g.steps);
            assert_eq!(
                o.end.to_array().map(f64::to_bits),
                g.end.to_array().map(f64::to_bits)
            );
            assert_eq!(o.length.to_bits(), g.length.to_bits());
            assert_eq!(one_paths[i], paths[i], "line {i}");
        }
        assert!(one.iter().filter(|o| o.stop == Stop::Reached).count() > 250);
    }

    /// The middle tile of a 3 x 3 x 3 tiling with `halo`, built from a linear, positive u
    /// (every node has a value).
    fn middle_tile(edge: u64, halo: i64) -> Tile {
        let tiling = Tiling {
            grid: [3 * edge; 3],
            edge,
            halo,
            cache_tiles: 1,
            cache_chunks: 1,
            wave: 1,
        };
        let (origin, shape) = tiling.node_box(13);
        let (uo, us) = Tile::u_box(origin, shape);
        let mut u = Block::filled(uo, us, 0.0f64);
        for z in 0..us[0] {
            for y in 0..us[1] {
                for x in 0..us[2] {
                    let o = u.offset(z, y, x);
                    let g = [z, y, x].map(|c| c as f64);
                    u.data[o] = 1000.0 + 0.5 * g[2] - 0.25 * g[1] + 0.125 * g[0];
                }
            }
        }
        Tile::from_u(&u, origin, shape, None)
    }

    /// Every stage point of a step started in a tile's own cells lies within `reach` of
    /// the step's start per axis; the tile must hold the 27 nodes the spline reads there,
    /// or the field would fall back to the trilinear interpolant in one tiling and not in
    /// another. The extreme points are the corners of the core moved out by the reach.
    /// One node less of halo fails on the high side: the halo is exact.
    #[test]
    fn the_halo_holds_the_spline_of_every_stage_point() {
        for h_max in [2.0, 4.0, 16.0] {
            let rk = Rk45 {
                h_max,
                ..Rk45::default()
            };
            let r = rk.reach();
            let halo = Tiling::halo_for(&rk);
            let edge = 8;
            let (lo, hi) = (edge as f64, (2 * edge) as f64);
            let below = lo - r;
            let above = f64::from_bits(hi.to_bits() - 1) + r;
            let tile = middle_tile(edge, halo);
            for k in 0..8 {
                let pick = |b: usize| if k >> b & 1 == 1 { above } else { below };
                let q = DVec3::new(pick(0), pick(1), pick(2));
                assert!(tile.spline(q).is_some(), "h_max {h_max}: {q}");
            }
            let short = middle_tile(edge, halo - 1);
            assert!(
                short.spline(DVec3::splat(above)).is_none(),
                "h_max {h_max}: one node less of halo should not hold the spline"
            );
        }
    }
}
