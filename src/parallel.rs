//! Parallel loops over blocks with a bounded number of blocks in flight.
//!
//! The memory budget decides how many workers may hold a block at once; results come
//! back in input order, so reductions over them are independent of the thread count.

use rayon::prelude::*;

/// Map `f` over `items` with at most `workers` calls running at once (and never more
/// than the current rayon pool has threads). Results are in the order of `items`; the
/// first error stops the loop.
pub fn map_bounded<I, R, E, F>(items: &[I], workers: usize, f: F) -> Result<Vec<R>, E>
where
    I: Sync,
    R: Send,
    E: Send,
    F: Fn(&I) -> Result<R, E> + Sync + Send,
{
    let threads = rayon::current_num_threads();
    if workers >= threads {
        return items.par_iter().with_max_len(1).map(&f).collect();
    }
    if workers <= 1 {
        return items.iter().map(&f).collect();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(workers)
        .build()
        .expect("a rayon pool of a few threads can always be built");
    pool.install(|| items.par_iter().with_max_len(1).map(&f).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_keep_input_order() {
        let items: Vec<u64> = (0..100).collect();
        for w in [1, 2, 8] {
            let r: Vec<u64> = map_bounded(&items, w, |&i| Ok::<_, ()>(i * i)).unwrap();
            assert_eq!(r, items.iter().map(|i| i * i).collect::<Vec<_>>());
        }
        let e = map_bounded(&items, 2, |&i| if i == 50 { Err(i) } else { Ok(i) });
        assert_eq!(e, Err(50));
    }
}
