//! The memory plan of a solve: which levels live in memory as whole arrays and which in
//! scratch files, and how many blocks are in flight, under the budget (`--mem`).

use super::level::{coarse_level_bytes, worker_bytes};
use super::multigrid::{pass_halo, CycleOptions};
use crate::grid::{GridError, GridSpec, MemBudget};

/// Which levels (0 = finest; arrays: mask, generations, and with `cuts` the packed
/// arms) live in memory, and how many blocks are in flight, under `mem`. `held(k)`:
/// the share of level `k`'s voxels this process holds, at most 1 (on MPI ranks its
/// slab and the planes it receives, the largest over the ranks; 1 in one process).
pub fn plan_memory(
    fine: &GridSpec,
    coarse: &[GridSpec],
    cycle: &CycleOptions,
    mem: MemBudget,
    cuts: bool,
    held: impl Fn(usize) -> f64,
) -> Result<(Vec<bool>, usize), GridError> {
    let share = |k: usize, bytes: u64| (bytes as f64 * held(k).clamp(0.0, 1.0)).ceil() as u64;
    let halo = pass_halo(cycle);
    // With cuts a box also holds its arms, 8 bytes a voxel (as many as u).
    let arms = |b: u64| if cuts { b } else { 0 };
    let boxed = crate::math::volume(fine.chunk.map(|c| c + 2 * halo + 3));
    let per_worker = worker_bytes(fine.chunk, halo) + arms(8 * boxed);
    let threads = rayon::current_num_threads();
    // At least one worker must fit; keep room for as many as there are threads.
    let workers = mem.workers(
        "the solve (one block with its halo)",
        0,
        per_worker,
        threads,
    )?;
    let mut avail = mem.work_bytes().saturating_sub(workers as u64 * per_worker);
    let mut in_memory = vec![false; coarse.len() + 1];
    for (k, s) in coarse.iter().enumerate().rev() {
        let b =
            share(k + 1, coarse_level_bytes(s, cuts)) + super::flat::pass_bytes(s, threads, cuts);
        if b <= avail {
            avail -= b;
            in_memory[k + 1] = true;
        } else {
            break;
        }
    }
    // The finest level: labels and two generations of f64.
    let fine_bytes = share(0, fine.num_voxels() * 17 + arms(8 * fine.num_voxels()))
        + super::flat::pass_bytes(fine, threads, cuts);
    if in_memory.iter().skip(1).all(|&m| m) && fine_bytes <= avail {
        in_memory[0] = true;
    }
    Ok((in_memory, workers))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::coarsen::coarse_specs;

    /// A budget that holds half of the finest level but not all of it: in one process
    /// the finest level goes to scratch files, on a rank holding half of it (its slab)
    /// it stays in memory; the coarse levels fit either way.
    #[test]
    fn a_rank_plans_for_its_share_of_each_level() {
        let fine = GridSpec {
            shape: [256; 3],
            origin: [0.0; 3],
            spacing: 1.0,
            chunk: [64; 3],
            unit: None,
        };
        let cycle = CycleOptions::default();
        let coarse = coarse_specs(&fine, cycle.coarsest);
        let mem = MemBudget(fine.num_voxels() * 17 * 3 / 4 + (128 << 20));
        let (whole, _) = plan_memory(&fine, &coarse, &cycle, mem, false, |_| 1.0).unwrap();
        let (half, _) = plan_memory(&fine, &coarse, &cycle, mem, false, |_| 0.5).unwrap();
        assert!(!whole[0] && whole[1..].iter().all(|&m| m), "{whole:?}");
        assert!(half.iter().all(|&m| m), "{half:?}");
    }
}
