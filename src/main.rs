//! The `harmap` command. All the work is in the library and `src/cli/`.

mod cli;

fn main() -> std::process::ExitCode {
    tune_malloc();
    // Under mpiexec (the `mpi` feature), MPI runs until the command is done.
    #[cfg(feature = "mpi")]
    let _mpi = launched_by_mpi().then(harmap::grid::mpi::init).flatten();
    cli::main()
}

/// Whether a process manager started this process as an MPI rank (MPICH's and Slurm's
/// PMI, PMIx, Open MPI), or `HARMAP_MPI=1` asks for MPI.
#[cfg(feature = "mpi")]
fn launched_by_mpi() -> bool {
    [
        "PMI_RANK",
        "PMI_SIZE",
        "PMIX_RANK",
        "OMPI_COMM_WORLD_SIZE",
        "HARMAP_MPI",
    ]
    .iter()
    .any(|v| std::env::var_os(v).is_some())
}

/// Block visits (the map's, the trace's tiles) allocate buffers of several MiB and free
/// them at the end. By default glibc maps such buffers afresh, or gives freed memory back
/// to the system, so every visit faults its pages in again: on the starfish of `harmap
/// run` the map spent a third of its time there. Fixed thresholds keep freed memory for
/// the next visit; the peak stays what the visits themselves hold.
///
/// One arena for all threads: by default each worker thread gets its own, and a buffer
/// freed in one arena cannot hold the next buffer another thread asks for, so freed
/// memory piles up beside the budget. With `--mem 256MiB` on the 512^3 ball the trace
/// peaked at 313 MiB, the inverse at 285 MiB and the map at 147 MiB; with one arena at
/// 247, 227 and 96 MiB. The hot loops do not allocate, so the shared arena's lock costs
/// no measurable time.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn tune_malloc() {
    // Buffers above 16 MiB are still mapped (and unmapped) on their own; at most
    // 32 MiB of free memory stays at the top of a heap (larger values raised the peak
    // of the 512^3 map by 70 MiB).
    const MMAP_THRESHOLD: libc::c_int = 16 << 20;
    const TRIM_THRESHOLD: libc::c_int = 32 << 20;
    // SAFETY: mallopt only sets the allocator's parameters, and runs before any other
    // thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn tune_malloc() {}
