//! The cap on `--threads`.

/// `--threads` beyond this many times the cores only costs: each worker holds its own
/// buffers within `--mem`, and ten thousand threads spent minutes starting and
/// contending on a 64^3 grid that takes 0.08 s.
const THREADS_PER_CORE: usize = 4;

/// The thread count to use for `--threads n` on a machine of `cores`: at most
/// [`THREADS_PER_CORE`] per core, with the warning to print when capped.
pub(super) fn cap_threads(n: usize, cores: usize) -> (usize, Option<String>) {
    let cap = THREADS_PER_CORE * cores.max(1);
    if n > cap {
        (
            cap,
            Some(format!(
                "--threads {n} is more than {THREADS_PER_CORE} per core on this machine of {cores} cores: using {cap} (results are the same for any count)"
            )),
        )
    } else {
        (n, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_capped_with_a_warning() {
        assert_eq!(cap_threads(8, 2), (8, None));
        let (n, w) = cap_threads(10_000, 2);
        assert_eq!(n, 8);
        assert!(w.is_some_and(|w| w.contains("10000") && w.contains("using 8")));
        assert_eq!(cap_threads(3, 0).0, 3);
    }
}
