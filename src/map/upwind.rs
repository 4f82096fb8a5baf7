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
//!
//! Files: [`directions`] (the field's store), `schedule` (the order of the visits and
//! the scheduler of the first round), `visit` (one visit of a block), `rule` (the
//! rules for one voxel).
//!
//! Across processes ([`transport_with`]): each part visits the blocks its
//! [`Decomposition`] owns. A voxel's direction crosses to another part when a visit
//! there reads it in its halo, after the [`Decomposition::exchange`] that ends every
//! round; whether any part still changes is agreed through
//! [`Decomposition::reduce_in_block_order`].

pub mod directions;
mod rule;
mod schedule;
mod visit;

pub use directions::{is_set, is_target, Directions};
pub use schedule::{central_blocks, held_bytes};

use crate::grid::{BlockStore, Decomposition, GridError, Whole};
use crate::math::{volume, Idx3};
use crate::progress::Progress;
use crate::trace::field::Tile;
use crate::trace::integrate::StopBall;
use crate::trace::nearest::SurfaceIndex;
use schedule::{Book, Plan};

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

/// What a visit did, and the block's directions (x, y, z) when they are to be written
/// by the caller.
type Visited = (Visit, Option<[Vec<f32>; 3]>);

/// What every visit of a transport reads.
pub(super) struct Ctx<'a> {
    pub(super) u: &'a dyn BlockStore<f64>,
    pub(super) boundary: Option<&'a SurfaceIndex>,
    pub(super) labels: &'a dyn BlockStore<u8>,
    pub(super) dirs: &'a Directions,
    pub(super) ball: &'a StopBall,
    pub(super) workers: usize,
    pub(super) progress: &'a dyn Progress,
    pub(super) sink: Option<Sink<'a>>,
}

/// Takes each block whose target voxels all have their direction, once, when they do:
/// the block, its labels and its directions as [x, y, z] component blocks (all three
/// zero where there is none), as [`Directions::read`] gives them.
pub type Sink<'a> = &'a (dyn Fn(Idx3, &[u8], &[Vec<f32>; 3]) -> Result<(), GridError> + Sync);

/// Transport the arrival direction into `dirs` for every target voxel.
///
/// The first round visits every block once, in an order that meets the dependencies
/// between neighbouring blocks: first the central blocks (together: each reads the
/// state before any of them and their results are written when all are done), then
/// the others as soon as their neighbours ranked before them (by distance from the
/// center, then colour) are done, on `workers` threads. Two blocks that touch are
/// never visited at the same time (one of them waits for the other). Later rounds go over the blocks with voxels left
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
    transport_with(
        u, boundary, labels, dirs, ball, workers, progress, sink, &Whole,
    )
}

/// [`transport`] over the blocks `decomp` owns (see the module's docs).
#[allow(clippy::too_many_arguments)]
pub fn transport_with(
    u: &dyn BlockStore<f64>,
    boundary: Option<&SurfaceIndex>,
    labels: &dyn BlockStore<u8>,
    dirs: &Directions,
    ball: &StopBall,
    workers: usize,
    progress: &dyn Progress,
    sink: Option<Sink>,
    decomp: &dyn Decomposition,
) -> Result<TransportStats, GridError> {
    let spec = u.spec();
    let n = spec.num_blocks() as usize;
    let plan = Plan::new(spec, ball, decomp);
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
        pending: vec![u64::MAX; n],
        stale: vec![true; n],
        stats: TransportStats::default(),
        done: 0,
        gained: vec![false; n],
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
            if first {
                ctx.group(&mut book, &plan.central, rule, true)?;
                // They did not see each other's results: those with voxels left go
                // again, one at a time, until none of them changes.
                loop {
                    let mut again = false;
                    for b in &plan.central {
                        again |= ctx.group(&mut book, std::slice::from_ref(b), rule, false)?;
                    }
                    if !again {
                        break;
                    }
                }
                ctx.ordered(&mut book, &plan.order)?;
            } else {
                for g in &plan.colours {
                    crate::progress::check_interrupt(progress)?;
                    ctx.group(&mut book, g, rule, false)?;
                }
            }
            // (One process: whether any block of the round gained directions.)
            if !book.end_round(decomp, dirs)? {
                break;
            }
        }
    }
    progress.finish();
    let mut stats = book.stats;
    stats.unreached = book.pending.iter().filter(|&&p| p != u64::MAX).sum();
    Ok(stats)
}
