//! MPI ranks (the `mpi` feature): [`MpiSlabs`], the [`Slabs`] decomposition whose
//! exchange and reductions are messages between ranks. The only file that knows the
//! `mpi` crate.
//!
//! - A halo exchange sends, to every other rank, the planes of its blocks that rank
//!   reads ([`Reach`], [`planes_read`]: the halo's planes of each block of the layers
//!   next to the slab, not whole blocks; on a coarse level of the solve also the planes
//!   under or over the rank's slabs of the levels next to it), in block order, with one
//!   `MPI_Alltoallv` of bytes; each rank writes what it receives into its own store of
//!   the field (those planes of its copies of the blocks). Fields whose other blocks
//!   are never read are not sent.
//! - Per-block partial sums are completed with one `MPI_Allgatherv` of the owned
//!   entries (a slab's blocks are one run in block order), never with a floating-point
//!   reduction: the caller adds every entry in block order, so the sum is the same bytes
//!   for any number of ranks.
//! - Every call is collective: every rank makes it at the same point of the same pass.
//!   MPI's default error handler aborts the job on a communication failure, and a rank
//!   that dies takes the job down (see docs/scale-out.md).

use std::sync::atomic::{AtomicU64, Ordering};

use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::{Threading, Universe};
use mpi::topology::SimpleCommunicator;
use mpi::traits::{Communicator, CommunicatorCollectives};
use mpi::Count;

use super::decomposition::planes_read;
use super::{Decomposition, GridError, GridSpec, HaloData, Reach, Slabs};
use crate::math::Idx3;

/// Started MPI; finalized when dropped (keep it alive until the process ends).
pub struct Mpi {
    _universe: Universe,
    /// This rank.
    pub rank: usize,
    /// The number of ranks.
    pub size: usize,
}

/// Initialize MPI when the process was started by `mpiexec` (or as a singleton). With
/// more than one rank the [`super::world`] decomposition becomes [`MpiSlabs`]; with one
/// it stays [`super::Whole`], the one-process path. `None` when MPI cannot start.
#[must_use]
pub fn init() -> Option<Mpi> {
    let (universe, _) = mpi::initialize_with_threading(Threading::Serialized)?;
    let world = universe.world();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    if size > 1 {
        super::set_world(Box::new(MpiSlabs::new(world)));
    }
    Some(Mpi {
        _universe: universe,
        rank,
        size,
    })
}

/// End the job on every rank with `code` (MPI_Abort): what a rank that failed does, so
/// that no other rank waits for it forever.
pub fn abort(code: i32) -> ! {
    mpi::topology::SimpleCommunicator::world().abort(code)
}

/// Slabs of block layers, one per rank, with messages for halos and reductions.
pub struct MpiSlabs {
    comm: SimpleCommunicator,
    slabs: Slabs,
    sent: AtomicU64,
}

impl std::fmt::Debug for MpiSlabs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MpiSlabs")
            .field("slabs", &self.slabs)
            .finish_non_exhaustive()
    }
}

/// Planes `z` of block `b`.
type Piece = (Idx3, std::ops::Range<u64>);

/// The bytes of piece `(b, z)` of `data`.
fn piece_bytes(data: &dyn HaloData, b: Idx3, z: &std::ops::Range<u64>) -> usize {
    let sh = data.spec().block_shape(b);
    ((z.end - z.start) * sh[1] * sh[2]) as usize * data.elem_bytes()
}

impl MpiSlabs {
    /// One all-to-all of halo pieces: `send[q]` of this rank's blocks to rank `q`,
    /// `recv[p]` of rank `p`'s blocks into `data`.
    fn exchange_pieces(
        &self,
        data: &dyn HaloData,
        send: &[Vec<Piece>],
        recv: &[Vec<Piece>],
    ) -> Result<(), GridError> {
        let whole = |b: Idx3, z: &std::ops::Range<u64>| {
            z.start == 0 && z.end == data.spec().block_shape(b)[0]
        };
        let bytes =
            |ps: &[Piece]| -> usize { ps.iter().map(|(b, z)| piece_bytes(data, *b, z)).sum() };
        // Sized once: a buffer grown by doubling leaves the smaller ones it outgrew
        // resident in the heap.
        let mut out = Vec::with_capacity(send.iter().map(|ps| bytes(ps)).sum());
        let mut send_counts = Vec::with_capacity(send.len());
        for ps in send {
            let before = out.len();
            for (b, z) in ps {
                if whole(*b, z) {
                    data.block_bytes(*b, &mut out)?;
                } else {
                    data.planes_bytes(*b, z.clone(), &mut out)?;
                }
            }
            send_counts.push(count(out.len() - before)?);
        }
        let recv_counts: Vec<Count> = recv
            .iter()
            .map(|ps| count(bytes(ps)))
            .collect::<Result<_, _>>()?;
        let mut into = vec![0u8; recv_counts.iter().map(|&c| c as usize).sum()];
        {
            let sd = displs(&send_counts);
            let rd = displs(&recv_counts);
            let sp = Partition::new(&out[..], &send_counts[..], &sd[..]);
            let mut rp = PartitionMut::new(&mut into[..], &recv_counts[..], &rd[..]);
            self.comm.all_to_all_varcount_into(&sp, &mut rp);
        }
        self.sent.fetch_add(out.len() as u64, Ordering::Relaxed);
        drop(out);
        let mut at = 0;
        for (b, z) in recv.iter().flatten() {
            let len = piece_bytes(data, *b, z);
            if whole(*b, z) {
                data.put_block_bytes(*b, &into[at..at + len])?;
            } else {
                data.put_planes_bytes(*b, z.clone(), &into[at..at + len])?;
            }
            at += len;
        }
        Ok(())
    }
}

// SAFETY: an MPI communicator handle is a plain integer (MPICH) or pointer (Open MPI)
// naming a library object; the library is initialized with MPI_THREAD_SERIALIZED and
// harmap calls it from one thread at a time (the stage's driver, between its parallel
// block loops).
unsafe impl Send for MpiSlabs {}
// SAFETY: as above.
unsafe impl Sync for MpiSlabs {}

/// Bytes a halo exchange sends from one rank to another in one round (more when one
/// block's planes are more): 2 MiB, or `HARMAP_EXCHANGE_ROUND` bytes (for the tests,
/// whose halos are smaller than one round).
fn exchange_round() -> usize {
    static ROUND: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *ROUND.get_or_init(|| {
        std::env::var("HARMAP_EXCHANGE_ROUND")
            .ok()
            .and_then(|v| v.parse().ok())
            .filter(|&r| r > 0)
            .unwrap_or(2 << 20)
    })
}

fn count(n: usize) -> Result<Count, GridError> {
    Count::try_from(n).map_err(|_| {
        GridError::RankLayout(format!(
            "{n} bytes in one message exceed MPI's count limit (2 GiB); use smaller blocks (--chunk) or more ranks"
        ))
    })
}

fn displs(counts: &[Count]) -> Vec<Count> {
    counts
        .iter()
        .scan(0, |acc, &c| {
            let d = *acc;
            *acc += c;
            Some(d)
        })
        .collect()
}

impl MpiSlabs {
    /// The slabs of `comm`'s ranks.
    #[must_use]
    pub fn new(comm: SimpleCommunicator) -> Self {
        let slabs = Slabs {
            part: comm.rank() as usize,
            parts: comm.size() as usize,
        };
        Self {
            comm,
            slabs,
            sent: AtomicU64::new(0),
        }
    }

    /// The blocks of layers `layers` of `spec` in block order.
    fn blocks_of(spec: &GridSpec, layers: &[u64]) -> Vec<Idx3> {
        let nb = spec.blocks();
        let mut out = Vec::new();
        for &l in layers {
            for y in 0..nb[1] {
                for x in 0..nb[2] {
                    out.push([l, y, x]);
                }
            }
        }
        out
    }
}

impl Decomposition for MpiSlabs {
    fn part(&self) -> usize {
        self.slabs.part
    }

    fn parts(&self) -> usize {
        self.slabs.parts
    }

    fn z_layers(&self, part: usize, blocks: Idx3) -> std::ops::Range<u64> {
        self.slabs.z_layers(part, blocks)
    }

    fn exchange(&self, _field: &str, data: &dyn HaloData, reach: &Reach) -> Result<(), GridError> {
        let spec = data.spec();
        let nb = spec.blocks();
        let (me, n) = (self.part(), self.parts());
        // What rank `to` reads of rank `from`'s blocks: the planes of `reach` (its
        // slab's halo, and on a coarse level of the solve the planes under or over its
        // slabs of the levels next to it), every block of the layers they cross.
        let pieces = |to: usize, from: usize| -> Vec<Piece> {
            if to == from {
                return Vec::new();
            }
            let own = self.z_layers(to, nb);
            let wanted = reach.wanted(spec, to, &own);
            planes_read(spec, &own, &self.z_layers(from, nb), &wanted)
                .into_iter()
                .flat_map(|(l, z)| {
                    Self::blocks_of(spec, &[l])
                        .into_iter()
                        .map(move |b| (b, z.clone()))
                })
                .collect()
        };
        // In rounds of about exchange_round() bytes between each pair of ranks, so
        // that a halo of many planes (the finest level's) never sits whole in a send
        // and a receive buffer at once. Every rank knows every pair's pieces, so all
        // take part in as many rounds.
        let per_round = exchange_round();
        let by_round = |ps: &[Piece]| -> Vec<Vec<Piece>> {
            let mut rounds: Vec<Vec<Piece>> = Vec::new();
            let mut at = 0;
            for (b, z) in ps {
                let r = at / per_round;
                at += piece_bytes(data, *b, z);
                if rounds.len() <= r {
                    rounds.resize_with(r + 1, Vec::new);
                }
                rounds[r].push((*b, z.clone()));
            }
            rounds
        };
        let all: Vec<Vec<Vec<Piece>>> = (0..n)
            .map(|to| (0..n).map(|from| pieces(to, from)).collect())
            .collect();
        let rounds = all
            .iter()
            .flatten()
            .map(|ps| by_round(ps).len())
            .max()
            .unwrap_or(0);
        let send: Vec<_> = (0..n).map(|q| by_round(&all[q][me])).collect();
        let recv: Vec<_> = (0..n).map(|p| by_round(&all[me][p])).collect();
        for round in 0..rounds {
            let of = |lists: &[Vec<Vec<Piece>>]| -> Vec<Vec<Piece>> {
                lists
                    .iter()
                    .map(|l| l.get(round).cloned().unwrap_or_default())
                    .collect()
            };
            let (send, recv) = (of(&send), of(&recv));
            self.exchange_pieces(data, &send, &recv)?;
        }
        Ok(())
    }

    fn reduce_in_block_order(
        &self,
        spec: &GridSpec,
        partials: &mut [f64],
    ) -> Result<(), GridError> {
        let nb = spec.blocks();
        let per_layer = (nb[1] * nb[2]) as usize;
        let ranges: Vec<std::ops::Range<usize>> = (0..self.parts())
            .map(|p| {
                let l = self.z_layers(p, nb);
                l.start as usize * per_layer..l.end as usize * per_layer
            })
            .collect();
        let counts: Vec<Count> = ranges
            .iter()
            .map(|r| count(r.len()))
            .collect::<Result<_, _>>()?;
        let d = displs(&counts);
        let mine = partials[ranges[self.part()].clone()].to_vec();
        let mut all = vec![0.0f64; partials.len()];
        {
            let mut rp = PartitionMut::new(&mut all[..], &counts[..], &d[..]);
            self.comm.all_gather_varcount_into(&mine[..], &mut rp);
        }
        self.sent.fetch_add(
            (mine.len() * 8 * (self.parts() - 1)) as u64,
            Ordering::Relaxed,
        );
        partials.copy_from_slice(&all);
        Ok(())
    }

    fn barrier(&self) -> Result<(), GridError> {
        self.comm.barrier();
        Ok(())
    }

    fn all_gather_bytes(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, GridError> {
        let n = self.parts();
        let my_count = count(mine.len())?;
        let mut counts: Vec<Count> = vec![0; n];
        self.comm.all_gather_into(&my_count, &mut counts[..]);
        let total: usize = counts.iter().map(|&c| c as usize).sum();
        count(total)?;
        let d = displs(&counts);
        let mut all = vec![0u8; total];
        {
            let mut rp = PartitionMut::new(&mut all[..], &counts[..], &d[..]);
            self.comm.all_gather_varcount_into(&mine[..], &mut rp);
        }
        self.sent
            .fetch_add((mine.len() * (n - 1)) as u64, Ordering::Relaxed);
        Ok((0..n)
            .map(|p| all[d[p] as usize..(d[p] + counts[p]) as usize].to_vec())
            .collect())
    }

    fn one_part_per_process(&self) -> bool {
        true
    }

    fn bytes_sent(&self) -> u64 {
        self.sent.load(Ordering::Relaxed)
    }
}
