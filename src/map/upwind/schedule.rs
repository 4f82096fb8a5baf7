//! The order of the visits: which blocks go first, which may run side by side, and
//! the hand-written scheduler of the first round, which starts a block as soon as its
//! neighbours ranked before it are done.
//!
//! A block's visit reads its neighbours' directions within [`HALO`] voxels, so two
//! blocks that touch are never visited at the same time. Across parts of a
//! [`Decomposition`] the blocks of the other parts are not visited here: their
//! directions arrive through [`Decomposition::exchange`] after each round, and a block
//! next to another part's is visited again in the next round when they did.

use super::Directions;
use super::{Ctx, Rule, TransportStats, Visit, HALO};
use crate::grid::{Decomposition, Field, GridError, GridSpec, Reach};
use crate::math::{volume, Idx3};
use crate::parallel::map_bounded;
use crate::trace::integrate::StopBall;

/// The blocks the stop ball touches: they hold the seeds every other voxel depends on.
#[must_use]
pub fn central_blocks(spec: &GridSpec, ball: &StopBall) -> Vec<Idx3> {
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
pub fn held_bytes(spec: &GridSpec, ball: &StopBall) -> u64 {
    central_blocks(spec, ball).len() as u64 * volume(spec.chunk) * 12
}

/// The order of a transport's visits over the blocks this process owns.
pub(super) struct Plan {
    /// The blocks the stop ball touches, visited together first.
    pub(super) central: Vec<Idx3>,
    /// The others, in the first round's order: by distance from the center in quarters
    /// of a block edge, then by colour.
    pub(super) order: Vec<Idx3>,
    /// Later rounds' groups, in turn: by distance in block edges, then by colour (no
    /// two blocks of a group touch).
    pub(super) colours: Vec<Vec<Idx3>>,
}

impl Plan {
    /// The plan for the blocks of `spec` that `decomp` owns, around `ball`.
    pub(super) fn new(spec: &GridSpec, ball: &StopBall, decomp: &dyn Decomposition) -> Self {
        let blocks = decomp.owned(spec);
        let central: Vec<Idx3> = central_blocks(spec, ball)
            .into_iter()
            .filter(|b| decomp.owns(spec, *b))
            .collect();
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
        // out hardly depend on each other, and those of one colour never touch, so they
        // can run side by side (by distance alone, ties went in index order, and each
        // waited for the touching one before it).
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
        // Later rounds: by distance from the center (in block edges), then by colour,
        // so that what a round finds moves outwards within it.
        let key = |b: &Idx3| {
            let ring = (dist2(b).sqrt() / spec.chunk[0] as f64).floor() as u64;
            (ring, colour(b))
        };
        let mut by_key = blocks;
        by_key.sort_by_key(|b| (key(b), spec.block_linear(*b)));
        let mut colours: Vec<Vec<Idx3>> = Vec::new();
        for (i, b) in by_key.iter().enumerate() {
            if i == 0 || key(b) != key(&by_key[i - 1]) {
                colours.push(Vec::new());
            }
            colours.last_mut().expect("a group").push(*b);
        }
        Self {
            central,
            order,
            colours,
        }
    }
}
/// What the transport knows about each block, updated after every visit.
pub(super) struct Book<'a> {
    pub(super) spec: &'a GridSpec,
    /// Target voxels of the block's core still without a direction (MAX: not visited).
    pub(super) pending: Vec<u64>,
    /// Whether a neighbour gained directions since the block's last visit.
    pub(super) stale: Vec<bool>,
    /// The counters so far.
    pub(super) stats: TransportStats,
    /// Voxels done, for the progress bar.
    pub(super) done: u64,
    /// Whether the block gained directions in this round.
    pub(super) gained: Vec<bool>,
}

impl Book<'_> {
    /// The end of a round: the other parts' directions made readable here, and whether
    /// any part's block gained directions in it (the same answer in every part). A block
    /// next to another part's block that gained is visited again.
    pub(super) fn end_round(
        &mut self,
        decomp: &dyn Decomposition,
        dirs: &Directions,
    ) -> Result<bool, GridError> {
        for (c, name) in dirs.c.iter().zip(["x", "y", "z"]) {
            decomp.exchange(
                &format!("map.directions.{name}"),
                &Field(&**c),
                &Reach::Halo(HALO),
            )?;
        }
        let mut partials: Vec<f64> = self
            .gained
            .iter()
            .map(|&g| f64::from(u8::from(g)))
            .collect();
        decomp.reduce_in_block_order(self.spec, &mut partials)?;
        let nb = self.spec.blocks();
        let mut any = false;
        for (b, p) in self.spec.block_indices().into_iter().zip(&partials) {
            if *p > 0.0 {
                any = true;
                if !decomp.owns(self.spec, b) {
                    for n in neighbours(b, nb) {
                        let j = self.lin(n);
                        self.stale[j] = true;
                    }
                }
            }
        }
        self.gained.fill(false);
        Ok(any)
    }

    pub(super) fn lin(&self, b: Idx3) -> usize {
        self.spec.block_linear(b) as usize
    }

    /// Whether block `b` is to be visited in a round.
    pub(super) fn due(&self, b: Idx3) -> bool {
        let i = self.lin(b);
        self.stale[i] && self.pending[i] > 0
    }

    /// Record visit `v` of block `b`; whether it set any voxel.
    pub(super) fn record(&mut self, b: Idx3, v: Visit) -> bool {
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
            self.gained[i] = true;
            for n in neighbours(b, self.spec.blocks()) {
                let j = self.lin(n);
                self.stale[j] = true;
            }
        }
        changed
    }
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

impl Ctx<'_> {
    /// Visit the due blocks of `group` at the same time: blocks that do not touch, or,
    /// `together`, blocks that may, each visited against the state before the group and
    /// written when all are done. A group of fewer blocks than workers spreads each
    /// visit over the threads instead.
    pub(super) fn group(
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
    pub(super) fn ordered(&self, book: &mut Book, order: &[Idx3]) -> Result<bool, GridError> {
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
