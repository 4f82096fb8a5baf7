//! Which blocks of a grid this process owns, and the hook that makes the blocks other
//! processes wrote readable here.
//!
//! Every block loop of the stages (voxelize passes, the solve and its polish, the
//! trace's tile builds, the map) iterates over [`Decomposition::owned`] instead of all
//! blocks, and calls [`Decomposition::exchange`] after writing its blocks of a field
//! and before it reads a neighbour's. In one process ([`Whole`]) every block is owned
//! and the exchange does nothing, so the loops behave exactly as before.
//!
//! A decomposition over several processes (MPI ranks) gives each a slab of whole block
//! layers along z ([`Slabs`]): slabs keep a block's neighbours in x and y on the same
//! process, so only the two faces of a slab cross processes. Its `exchange` is where
//! halo messages (or a barrier over a shared filesystem) go.
//!
//! Invariants:
//! - the owned sets of all parts are disjoint and cover the grid's blocks;
//! - `owned` lists blocks in the grid's block order (z, then y, then x), so per-block
//!   partial sums gathered from every part and added in that order give the same bytes
//!   for any number of parts ([`Decomposition::reduce_in_block_order`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

use crate::grid::{BlockStore, GridError, GridSpec, Scalar};
use crate::math::Idx3;

/// A field's blocks as bytes, whatever its element type: what a halo exchange sends
/// and receives ([`Decomposition::exchange`]).
pub trait HaloData {
    /// The field's grid.
    fn spec(&self) -> &GridSpec;
    /// Bytes of one element.
    fn elem_bytes(&self) -> usize;
    /// Append block `b`'s values, as bytes, to `out`.
    fn block_bytes(&self, b: Idx3, out: &mut Vec<u8>) -> Result<(), GridError>;
    /// Write block `b` from its bytes.
    fn put_block_bytes(&self, b: Idx3, bytes: &[u8]) -> Result<(), GridError>;
    /// Append the planes `z` (along z, counted within the block) of block `b`, as
    /// bytes, to `out`.
    fn planes_bytes(
        &self,
        b: Idx3,
        z: std::ops::Range<u64>,
        out: &mut Vec<u8>,
    ) -> Result<(), GridError>;
    /// Write the planes `z` of block `b` from their bytes, the rest of the block as it
    /// was.
    fn put_planes_bytes(
        &self,
        b: Idx3,
        z: std::ops::Range<u64>,
        bytes: &[u8],
    ) -> Result<(), GridError>;
}

/// A [`BlockStore`] seen as [`HaloData`].
pub struct Field<'a, T: Scalar>(pub &'a dyn BlockStore<T>);

impl<T: Scalar> HaloData for Field<'_, T> {
    fn spec(&self) -> &GridSpec {
        self.0.spec()
    }

    fn elem_bytes(&self) -> usize {
        std::mem::size_of::<T>()
    }

    fn block_bytes(&self, b: Idx3, out: &mut Vec<u8>) -> Result<(), GridError> {
        out.extend_from_slice(bytemuck::cast_slice(&self.0.read_block(b)?));
        Ok(())
    }

    fn put_block_bytes(&self, b: Idx3, bytes: &[u8]) -> Result<(), GridError> {
        self.0
            .write_block(b, &bytemuck::pod_collect_to_vec::<u8, T>(bytes))
    }

    fn planes_bytes(
        &self,
        b: Idx3,
        z: std::ops::Range<u64>,
        out: &mut Vec<u8>,
    ) -> Result<(), GridError> {
        // Only those planes: a store copies (or reads) the rows of the region alone.
        let (st, sh) = (self.0.spec().block_start(b), self.0.spec().block_shape(b));
        let planes = self.0.read_region(
            [(st[0] + z.start) as i64, st[1] as i64, st[2] as i64],
            [(z.end - z.start) as usize, sh[1] as usize, sh[2] as usize],
            bytemuck::Zeroable::zeroed(),
        )?;
        out.extend_from_slice(bytemuck::cast_slice(&planes.data));
        Ok(())
    }

    fn put_planes_bytes(
        &self,
        b: Idx3,
        z: std::ops::Range<u64>,
        bytes: &[u8],
    ) -> Result<(), GridError> {
        self.0
            .write_planes(b, z, &bytemuck::pod_collect_to_vec::<u8, T>(bytes))
    }
}

/// Which planes along z of a field each part reads besides its own blocks: what a
/// halo exchange ([`Decomposition::exchange`]) must make readable there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Reach {
    /// `halo` planes either side of the part's slab: a pass over its own blocks that
    /// reads that far past them.
    Halo(u64),
    /// Per part (indexed by part), the ranges of planes it reads, in the grid's plane
    /// indices; they may overlap each other and the part's own planes. A level of the
    /// multigrid hierarchy reads so: its slab's halo, and the planes under (or over)
    /// the part's slabs of the levels next to it, which need not line up with its own.
    Planes(Vec<Vec<std::ops::Range<u64>>>),
}

impl Reach {
    /// The ranges of planes of `spec`'s grid that `part`, owning the block layers
    /// `own`, reads: sorted, disjoint, within the grid.
    #[must_use]
    pub fn wanted(
        &self,
        spec: &GridSpec,
        part: usize,
        own: &std::ops::Range<u64>,
    ) -> Vec<std::ops::Range<u64>> {
        let n = spec.shape[0];
        let mut w: Vec<std::ops::Range<u64>> = Vec::new();
        match self {
            Self::Halo(halo) => {
                if let Some(r) = layer_planes(spec, own) {
                    w.push(r.start.saturating_sub(*halo)..(r.end + halo).min(n));
                }
            }
            Self::Planes(parts) => w.extend(
                parts
                    .get(part)
                    .into_iter()
                    .flatten()
                    .map(|r| r.start.min(n)..r.end.min(n)),
            ),
        }
        w.retain(|r| !r.is_empty());
        w.sort_by_key(|r| r.start);
        let mut merged: Vec<std::ops::Range<u64>> = Vec::with_capacity(w.len());
        for r in w {
            match merged.last_mut() {
                Some(m) if r.start <= m.end => m.end = m.end.max(r.end),
                _ => merged.push(r),
            }
        }
        merged
    }
}

/// The planes along z of the block layers `layers` of `spec`'s grid (`None` when
/// there are none).
#[must_use]
pub fn layer_planes(
    spec: &GridSpec,
    layers: &std::ops::Range<u64>,
) -> Option<std::ops::Range<u64>> {
    if layers.is_empty() {
        return None;
    }
    let last = [layers.end - 1, 0, 0];
    Some(
        spec.block_start([layers.start, 0, 0])[0]
            ..spec.block_start(last)[0] + spec.block_shape(last)[0],
    )
}

/// The planes of the block layers `from` (another part's) that a part owning the
/// layers `own` reads, when it reads the planes `wanted` (sorted, disjoint; see
/// [`Reach::wanted`]): per block layer, in layer order, the ranges of its planes
/// counted within the layer's blocks. Every block of such a layer is read at those
/// planes. Layers the part owns itself are never listed.
#[must_use]
pub fn planes_read(
    spec: &GridSpec,
    own: &std::ops::Range<u64>,
    from: &std::ops::Range<u64>,
    wanted: &[std::ops::Range<u64>],
) -> Vec<(u64, std::ops::Range<u64>)> {
    let mut out = Vec::new();
    for l in from.clone().filter(|l| !own.contains(l)) {
        let Some(r) = layer_planes(spec, &(l..l + 1)) else {
            continue;
        };
        for w in wanted {
            let (lo, hi) = (w.start.max(r.start), w.end.min(r.end));
            if lo < hi {
                out.push((l, lo - r.start..hi - r.start));
            }
        }
    }
    out
}

/// The planes of the block layers `from` (another part's) that a part owning the
/// layers `own` reads within `halo` voxels along z ([`planes_read`] of
/// [`Reach::Halo`]).
#[must_use]
pub fn halo_planes(
    spec: &GridSpec,
    own: &std::ops::Range<u64>,
    from: &std::ops::Range<u64>,
    halo: u64,
) -> Vec<(u64, std::ops::Range<u64>)> {
    planes_read(spec, own, from, &Reach::Halo(halo).wanted(spec, 0, own))
}

static WORLD: OnceLock<Box<dyn Decomposition>> = OnceLock::new();
static WHOLE: Whole = Whole;
static SOLO: AtomicBool = AtomicBool::new(false);

/// The decomposition of this process's run: [`Whole`] unless the binary started on
/// MPI ranks set another ([`set_world`]), or inside [`solo`]. The run directory asks
/// it who writes the metadata (part 0) and waits at its barriers.
#[must_use]
pub fn world() -> &'static dyn Decomposition {
    if SOLO.load(Ordering::Acquire) {
        return &WHOLE;
    }
    WORLD.get().map_or(&WHOLE, |w| &**w)
}

/// Run `f` as if this process were alone ([`world`] is [`Whole`]): what rank 0 does
/// while the other ranks wait (the voxelization, the atlas, the report page).
pub fn solo<R>(f: impl FnOnce() -> R) -> R {
    struct Back(bool);
    impl Drop for Back {
        fn drop(&mut self) {
            SOLO.store(self.0, Ordering::Release);
        }
    }
    let _back = Back(SOLO.swap(true, Ordering::AcqRel));
    f()
}

/// Set the decomposition [`world`] returns, once, before any stage runs. Returns
/// false when one was set already.
pub fn set_world(d: Box<dyn Decomposition>) -> bool {
    WORLD.set(d).is_ok()
}

/// Which blocks this process computes and writes, and how it sees the others' blocks.
pub trait Decomposition: Send + Sync + std::fmt::Debug {
    /// This process's index among [`parts`](Self::parts), from 0.
    fn part(&self) -> usize;

    /// How many processes share the grid.
    fn parts(&self) -> usize;

    /// The range of block layers along z (block index `b[0]`) that `part` owns in a grid
    /// of `blocks` blocks a side.
    fn z_layers(&self, part: usize, blocks: Idx3) -> std::ops::Range<u64>;

    /// Whether this process owns block `b` of `spec`'s grid.
    fn owns(&self, spec: &GridSpec, b: Idx3) -> bool {
        self.z_layers(self.part(), spec.blocks()).contains(&b[0])
    }

    /// Whether this process is the only one to play its part, so that what it
    /// records about the blocks it owns (which hold unknowns, which it visited) holds
    /// for the whole run: true in one process and on MPI ranks, false for parts played
    /// one after another in one process (the tests' [`Slabs`]).
    fn one_part_per_process(&self) -> bool {
        self.parts() == 1
    }

    /// The blocks of `spec` this process owns, in block order.
    fn owned(&self, spec: &GridSpec) -> Vec<Idx3> {
        let nb = spec.blocks();
        let layers = self.z_layers(self.part(), nb);
        spec.block_indices()
            .into_iter()
            .filter(|b| layers.contains(&b[0]))
            .collect()
    }

    /// Make the blocks that other processes wrote of the field named `field` (held
    /// here in `data`) readable by this one, at least at the planes `reach` says this
    /// process reads. Called by every process at the same point of a pass. One
    /// process: nothing to do.
    fn exchange(&self, field: &str, data: &dyn HaloData, reach: &Reach) -> Result<(), GridError>;

    /// Wait until every process has come here. One process: nothing to do.
    fn barrier(&self) -> Result<(), GridError> {
        Ok(())
    }

    /// Every process's `mine`, in part order, on every process.
    fn all_gather_bytes(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, GridError> {
        Ok(vec![mine])
    }

    /// Every process's `mine` added entry by entry, on every process: counts each
    /// process made over its own blocks, as totals. (Integers: the order of the
    /// additions does not change the bytes.) Every process passes as many entries.
    fn sum_u64(&self, mine: &[u64]) -> Result<Vec<u64>, GridError> {
        let all = self.all_gather_bytes(mine.iter().flat_map(|v| v.to_le_bytes()).collect())?;
        let mut total = vec![0u64; mine.len()];
        for (part, bytes) in all.iter().enumerate() {
            if bytes.len() != 8 * mine.len() {
                return Err(GridError::Ranks(format!(
                    "part {part} sent {} bytes of counts where {} were expected",
                    bytes.len(),
                    8 * mine.len()
                )));
            }
            for (t, c) in total.iter_mut().zip(bytes.chunks_exact(8)) {
                *t += u64::from_le_bytes(c.try_into().expect("8 bytes"));
            }
        }
        Ok(total)
    }

    /// Bytes this process has sent to others so far (halos, gathers).
    fn bytes_sent(&self) -> u64 {
        0
    }

    /// Whether this process writes the run's metadata, holds its lock and commits
    /// checkpoints (part 0).
    fn is_root(&self) -> bool {
        self.part() == 0
    }

    /// Complete per-block partial sums: `partials[i]` belongs to the `i`-th block of
    /// `spec` in block order; each process filled the entries of the blocks it owns and
    /// left the others 0. Afterwards every process holds every entry, and the caller
    /// adds them in block order, so the total does not depend on the number of parts.
    fn reduce_in_block_order(&self, spec: &GridSpec, partials: &mut [f64])
        -> Result<(), GridError>;
}

/// One process owns every block.
#[derive(Clone, Copy, Debug, Default)]
pub struct Whole;

impl Decomposition for Whole {
    fn part(&self) -> usize {
        0
    }

    fn parts(&self) -> usize {
        1
    }

    fn z_layers(&self, _part: usize, blocks: Idx3) -> std::ops::Range<u64> {
        0..blocks[0]
    }

    fn owned(&self, spec: &GridSpec) -> Vec<Idx3> {
        spec.block_indices()
    }

    fn exchange(
        &self,
        _field: &str,
        _data: &dyn HaloData,
        _reach: &Reach,
    ) -> Result<(), GridError> {
        Ok(())
    }

    fn reduce_in_block_order(
        &self,
        _spec: &GridSpec,
        _partials: &mut [f64],
    ) -> Result<(), GridError> {
        Ok(())
    }
}

/// Slabs of whole block layers along z, as even as the layer count allows: part `p` of
/// `n` owns layers `[p * L / n, (p + 1) * L / n)` of `L`. With more parts than layers
/// some parts own none.
///
/// This type only says who owns what; its `exchange` and `reduce_in_block_order` do
/// nothing, which is right only when the parts share one address space or one
/// filesystem and run one after another (the tests do). A message-passing
/// decomposition wraps it and supplies both.
#[derive(Clone, Copy, Debug)]
pub struct Slabs {
    /// This process's part.
    pub part: usize,
    /// The number of parts.
    pub parts: usize,
}

impl Decomposition for Slabs {
    fn part(&self) -> usize {
        self.part
    }

    fn parts(&self) -> usize {
        self.parts
    }

    fn z_layers(&self, part: usize, blocks: Idx3) -> std::ops::Range<u64> {
        let n = self.parts.max(1) as u64;
        let p = part as u64;
        (p * blocks[0] / n)..((p + 1) * blocks[0] / n)
    }

    fn exchange(
        &self,
        _field: &str,
        _data: &dyn HaloData,
        _reach: &Reach,
    ) -> Result<(), GridError> {
        Ok(())
    }

    fn reduce_in_block_order(
        &self,
        _spec: &GridSpec,
        _partials: &mut [f64],
    ) -> Result<(), GridError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(shape: Idx3, chunk: Idx3) -> GridSpec {
        GridSpec {
            shape,
            origin: [0.0; 3],
            spacing: 1.0,
            chunk,
            unit: None,
        }
    }

    #[test]
    fn whole_owns_every_block_in_block_order() {
        let s = spec([10, 7, 9], [4, 4, 4]);
        assert_eq!(Whole.owned(&s), s.block_indices());
        assert!(s.block_indices().iter().all(|&b| Whole.owns(&s, b)));
    }

    /// For any number of parts, the slabs are disjoint, cover the grid, keep block
    /// order, and are as even as the layers allow.
    #[test]
    fn slabs_partition_the_blocks() {
        for (shape, chunk) in [
            ([10, 7, 9], [4, 4, 4]),
            ([64, 8, 8], [8, 8, 8]),
            ([3, 3, 3], [1, 3, 3]),
        ] {
            let s = spec(shape, chunk);
            let all = s.block_indices();
            let layers = s.blocks()[0];
            for parts in 1..=7 {
                let mut seen = Vec::new();
                for part in 0..parts {
                    let d = Slabs { part, parts };
                    let own = d.owned(&s);
                    assert!(own.iter().all(|&b| d.owns(&s, b)));
                    let n = d.z_layers(part, s.blocks()).count() as u64;
                    assert!(n == layers / parts as u64 || n == layers / parts as u64 + 1);
                    seen.extend(own);
                }
                assert_eq!(seen, all, "{parts} parts of {shape:?}");
            }
        }
    }

    /// A part's wanted planes are clamped to the grid, sorted and merged; with no
    /// slab a halo reaches nothing, while explicit planes still do.
    #[test]
    fn reach_wanted_merges_and_clamps() {
        let s = spec([40, 4, 4], [8, 4, 4]);
        let planes = Reach::Planes(vec![vec![30..50, 2..5, 4..9, 12..12], vec![]]);
        assert_eq!(planes.wanted(&s, 0, &(0..0)), vec![2..9, 30..40]);
        assert!(planes.wanted(&s, 1, &(1..2)).is_empty());
        assert!(planes.wanted(&s, 2, &(1..2)).is_empty());
        assert_eq!(Reach::Halo(3).wanted(&s, 0, &(1..3)), vec![5..27]);
        assert_eq!(Reach::Halo(3).wanted(&s, 0, &(4..5)), vec![29..40]);
        assert!(Reach::Halo(3).wanted(&s, 0, &(2..2)).is_empty());
        // Planes of layer 1 (8..16) and 3 (24..32) that part 0, owning layer 2, reads.
        let got = planes_read(&s, &(2..3), &(0..5), &[2..9, 14..26, 30..40]);
        assert_eq!(
            got,
            vec![
                (0, 2..8),
                (1, 0..1),
                (1, 6..8),
                (3, 0..2),
                (3, 6..8),
                (4, 0..8)
            ]
        );
    }

    /// The planes a part reads of the others are exactly the grid's planes within the
    /// halo of its slab and outside it, each from the part that owns it, once.
    #[test]
    fn halo_planes_are_the_planes_within_the_halo() {
        for (shape, chunk) in [
            ([100, 8, 8], [16, 8, 8]),
            ([33, 4, 4], [8, 4, 4]),
            ([7, 2, 2], [2, 2, 2]),
        ] {
            let s = spec(shape, chunk);
            let nb = s.blocks();
            for parts in 1..=5 {
                for halo in [1, 3, 6, 20] {
                    for part in 0..parts {
                        let d = Slabs { part, parts };
                        let own = d.z_layers(part, nb);
                        if own.is_empty() {
                            continue;
                        }
                        let mut got = Vec::new();
                        for from in (0..parts).filter(|&p| p != part) {
                            let theirs = d.z_layers(from, nb);
                            for (l, z) in halo_planes(&s, &own, &theirs, halo) {
                                assert!(theirs.contains(&l));
                                let z0 = s.block_start([l, 0, 0])[0];
                                got.extend(z.map(|p| z0 + p));
                            }
                        }
                        got.sort_unstable();
                        let (lo, hi) = (own.start * chunk[0], (own.end * chunk[0]).min(shape[0]));
                        let want: Vec<u64> = (lo.saturating_sub(halo)..lo)
                            .chain(hi..(hi + halo).min(shape[0]))
                            .collect();
                        assert_eq!(
                            got, want,
                            "{shape:?} in {parts} parts, part {part}, halo {halo}"
                        );
                    }
                }
            }
        }
    }
}
