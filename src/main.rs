//! The `harmap` command. All the work is in the library and `src/cli/`.

mod cli;

fn main() -> std::process::ExitCode {
    tune_malloc();
    cli::main()
}

/// Block visits (the map's, the trace's tiles) allocate buffers of several MiB and free
/// them at the end. By default glibc maps such buffers afresh, or gives freed memory back
/// to the system, so every visit faults its pages in again: on the starfish of `harmap
/// run` the map spent a third of its time there. Fixed thresholds keep freed memory for
/// the next visit; the peak stays what the visits themselves hold.
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
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn tune_malloc() {}
