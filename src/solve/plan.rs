//! The memory plan of a solve: which levels live in memory as whole arrays and which in
//! scratch files, and how many blocks are in flight, under the budget (`--mem`).

use super::level::{coarse_level_bytes, worker_bytes};
use super::multigrid::{pass_halo, CycleOptions};
use crate::grid::{GridError, GridSpec, MemBudget};

/// Which levels (0 = finest; arrays: mask, generations, and with `cuts` the packed
/// arms) live in memory, and how many blocks are in flight, under `mem`.
pub fn plan_memory(
    fine: &GridSpec,
    coarse: &[GridSpec],
    cycle: &CycleOptions,
    mem: MemBudget,
    cuts: bool,
) -> Result<(Vec<bool>, usize), GridError> {
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
        let b = coarse_level_bytes(s) + super::flat::pass_bytes(s, threads);
        if b <= avail {
            avail -= b;
            in_memory[k + 1] = true;
        } else {
            break;
        }
    }
    // The finest level: labels and two generations of f64.
    let fine_bytes = fine.num_voxels() * 17
        + arms(8 * fine.num_voxels())
        + super::flat::pass_bytes(fine, threads);
    if in_memory.iter().skip(1).all(|&m| m) && fine_bytes <= avail {
        in_memory[0] = true;
    }
    Ok((in_memory, workers))
}
