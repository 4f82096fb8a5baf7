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

/// Buffers lent to the tasks of parallel passes and taken back: a pass over many boxes
/// or planes then allocates about one buffer per thread, once, instead of one per task
/// and every time (large allocations are fresh pages from the system, each one
/// faulted in).
#[derive(Debug, Default)]
pub struct Pool<T>(std::sync::Mutex<Vec<T>>);

impl<T: Default> Pool<T> {
    /// Run `f` with a buffer from the pool (a new one when none is free), then return
    /// the buffer to the pool.
    pub fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        let taken = self.0.lock().expect("pool lock").pop();
        let mut buf = taken.unwrap_or_default();
        let r = f(&mut buf);
        self.0.lock().expect("pool lock").push(buf);
        r
    }
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

    #[test]
    fn a_pool_lends_its_buffers_again() {
        let pool: Pool<Vec<u8>> = Pool::default();
        pool.with(|b| b.reserve(1000));
        // The same buffer comes back, with its allocation.
        assert!(pool.with(|b| b.capacity()) >= 1000);
        // Nested use needs a second buffer.
        let caps = pool.with(|a| (a.capacity(), pool.with(|b| b.capacity())));
        assert!(caps.0 >= 1000 && caps.1 == 0, "{caps:?}");
        assert_eq!(pool.0.lock().unwrap().len(), 2);
    }
}
