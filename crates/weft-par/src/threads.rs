//! The `Threads` executor: the engine's tasks on a rayon pool.

use rayon::prelude::*;
use weft_sim::Executor;

/// Runs the engine's tasks on its own pool of `n` threads (work stealing:
/// chunks and map items are taken by whichever thread is idle). Clones share
/// the pool.
#[derive(Clone)]
pub struct Threads {
    pool: std::sync::Arc<rayon::ThreadPool>,
}

impl Threads {
    /// A pool of `n` threads (`0`: one per logical core).
    pub fn new(n: usize) -> Result<Self, rayon::ThreadPoolBuildError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("weft-{i}"))
            .build()?;
        Ok(Self {
            pool: std::sync::Arc::new(pool),
        })
    }

    /// Runs `f` on one of the pool's threads. Run the whole simulation loop
    /// this way: its serial parts then run on a pool thread and the pool's
    /// other threads are the only others, instead of an extra thread that
    /// competes with workers spinning for work between parallel stages.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.pool.install(f)
    }

    /// The number of threads in the pool.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }
}

impl std::fmt::Debug for Threads {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Threads({})", self.threads())
    }
}

impl Executor for Threads {
    fn for_each_chunk<T: Send>(
        &self,
        data: &mut [T],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [T]) + Sync),
    ) {
        if bounds.len() <= 2 {
            // One chunk (or none): no one to share it with.
            return weft_sim::Serial.for_each_chunk(data, bounds, task);
        }
        let chunks = weft_sim::executor::split_chunks(data, bounds);
        // Every chunk its own task (`with_max_len(1)`): rayon otherwise
        // splits a loop into about as many pieces as threads and runs each
        // piece in order unless it is stolen, so a thread that comes free
        // late (a join's other side done) found nothing left to take.
        self.pool.install(|| {
            (chunks.into_par_iter().with_max_len(1)).for_each(|(k, chunk)| task(k, chunk));
        });
    }

    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
        if n <= 1 {
            return (0..n).map(f).collect();
        }
        // `collect` on an indexed parallel iterator keeps index order; each
        // item its own task, as above.
        self.pool
            .install(|| (0..n).into_par_iter().with_max_len(1).map(f).collect())
    }

    fn name(&self) -> String {
        format!("threads({})", self.threads())
    }

    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        self.pool.install(|| rayon::join(a, b));
    }

    fn threads_per_rank(&self) -> usize {
        self.threads()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_are_disjoint_and_complete_and_maps_ordered() {
        let t = Threads::new(3).unwrap();
        let mut data = vec![0u32; 100];
        let bounds = [0, 7, 7, 50, 99, 100];
        t.for_each_chunk(&mut data, &bounds, &|k, chunk: &mut [u32]| {
            for x in chunk {
                *x += k as u32 + 1;
            }
        });
        for k in 0..bounds.len() - 1 {
            assert!(data[bounds[k]..bounds[k + 1]]
                .iter()
                .all(|&x| x == k as u32 + 1));
        }
        let squares = t.map(1000, &|i| i * i);
        assert!(squares.iter().enumerate().all(|(i, &s)| s == i * i));
        assert_eq!(t.threads(), 3);
    }

    #[test]
    fn join_runs_both_sides_at_once() {
        // Each side waits until the other has started: on one thread in
        // order this would never end, so the pool must run them together
        // (bounded: a side gives up after 10 s and the test fails).
        use std::sync::atomic::{AtomicUsize, Ordering};
        let t = Threads::new(2).unwrap();
        let started = AtomicUsize::new(0);
        let meet = || {
            started.fetch_add(1, Ordering::SeqCst);
            let clock = std::time::Instant::now();
            while started.load(Ordering::SeqCst) < 2 {
                assert!(clock.elapsed().as_secs() < 10, "the other side never ran");
                std::thread::yield_now();
            }
            t.map(100, &|i| i).len()
        };
        let (mut a, mut b) = (0, 0);
        t.join(&mut || a = meet(), &mut || b = meet());
        assert_eq!((a, b), (100, 100));
        // In order on one thread.
        let order = std::sync::Mutex::new(Vec::new());
        weft_sim::Serial.join(&mut || order.lock().unwrap().push('a'), &mut || {
            order.lock().unwrap().push('b')
        });
        assert_eq!(*order.lock().unwrap(), ['a', 'b']);
    }
}
