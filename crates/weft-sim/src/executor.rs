//! The executor abstraction the engine runs on.
//!
//! The engine expresses its parallel stages as per-partition tasks that write
//! disjoint chunks of an output buffer, and as independent maps; per-vertex sums
//! are ordered folds done afterwards, so the result is the same bits on any
//! executor and any partitioning. [`Serial`] runs everything on the calling
//! thread; the threaded and multi-rank executors implement the same trait.

/// Runs the engine's parallel stages.
pub trait Executor: Sync {
    /// Calls `task(k, chunk_k)` for every chunk of `data` between consecutive
    /// `bounds` (ascending; `bounds[0] == 0`, last `== data.len()`).
    fn for_each_chunk<T: Send>(
        &self,
        data: &mut [T],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [T]) + Sync),
    );

    /// `(0..n).map(f)`, possibly in parallel; results in index order.
    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R>;

    /// A short name for logs and benchmarks.
    fn name(&self) -> String;
}

/// `data` cut at `bounds` (ascending; `bounds[0] == 0`, last `== data.len()`)
/// into numbered disjoint chunks: what [`Executor::for_each_chunk`] hands out.
pub fn split_chunks<'a, T>(data: &'a mut [T], bounds: &[usize]) -> Vec<(usize, &'a mut [T])> {
    let mut chunks = Vec::with_capacity(bounds.len().saturating_sub(1));
    let mut rest = data;
    for k in 0..bounds.len().saturating_sub(1) {
        let (chunk, tail) = std::mem::take(&mut rest).split_at_mut(bounds[k + 1] - bounds[k]);
        chunks.push((k, chunk));
        rest = tail;
    }
    chunks
}

/// Everything on the calling thread, in order.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

impl Executor for Serial {
    fn for_each_chunk<T: Send>(
        &self,
        data: &mut [T],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [T]) + Sync),
    ) {
        for (k, chunk) in split_chunks(data, bounds) {
            task(k, chunk);
        }
    }

    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
        (0..n).map(f).collect()
    }

    fn name(&self) -> String {
        "serial".into()
    }
}
