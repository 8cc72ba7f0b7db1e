//! The executor abstraction the engine runs on.
//!
//! The engine expresses its parallel stages as per-partition tasks that write
//! disjoint chunks of an output buffer, and as independent maps; per-vertex sums
//! are ordered folds done afterwards, so the result is the same bits on any
//! executor and any partitioning. [`Serial`] runs everything on the calling
//! thread; the threaded and multi-rank executors implement the same trait.
//!
//! Executors over *ranks* (processes, or threads standing in for them, each
//! with memory of its own) also spread the heavy stages over the ranks:
//! [`Executor::map_on_ranks`] and [`Executor::chunks_on_ranks`] compute each
//! item on one rank and hand every rank all results;
//! [`Executor::all_to_all`] hands each rank only what is addressed to it. They are **collective**:
//! every rank's engine calls them in the same order with the same arguments —
//! which holds because every rank takes the same decisions (from the same
//! positions, velocities and active layers). On a single-memory executor they are `map` and
//! `for_each_chunk`.

use serde::{de::DeserializeOwned, Serialize};

/// A value that travels between ranks, encoded with its exact bits.
pub trait Message: Serialize + DeserializeOwned + Send {}
impl<T: Serialize + DeserializeOwned + Send> Message for T {}

/// Messages and payload bytes a rank sent to its peers, and the
/// communication rounds it took part in: collectives (every rank waits for
/// every other) and point-to-point exchanges (a rank waits for its peers).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Traffic {
    pub messages: u64,
    pub bytes: u64,
    pub collectives: u64,
    pub exchanges: u64,
    /// CPU nanoseconds spent polling for peers' messages (a rank waiting,
    /// not working): left out of the counted CPU ([`Executor::work_cpu_seconds`]).
    #[serde(default)]
    pub wait_cpu_ns: u64,
}

/// What an all-to-all brings a rank: every rank's head, in rank order, and
/// the part each rank addressed to it.
pub type AddressedParts<P> = (Vec<Vec<u64>>, Vec<P>);

/// What [`Executor::all_to_all`] brings a rank (a part `None`: none).
pub type Addressed<T> = AddressedParts<Option<T>>;

/// What [`Executor::all_to_all_vectors`] brings a rank (a part empty: none).
pub type AddressedVectors = AddressedParts<Vec<glam::DVec3>>;

/// Ranks lost contact (a peer failed or is gone): the run cannot go on.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct CommError(pub String);

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

    /// Calls `task(k, &mut items[k])` for every item, each a task of its own
    /// (items that carry their own slices: runs of vertices, say).
    fn for_each_item<T: Send>(&self, items: &mut [T], task: &(dyn Fn(usize, &mut T) + Sync)) {
        let one_each: Vec<usize> = (0..=items.len()).collect();
        self.for_each_chunk(items, &one_each, &|k, chunk| task(k, &mut chunk[0]));
    }

    /// `(0..n).map(f)`, possibly in parallel; results in index order.
    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R>;

    /// Runs `a` and `b` to the end, at the same time where the executor has
    /// a thread to spare (`a` on the calling thread, `b` wherever a thread
    /// is free, each free to use the executor itself): work that shares
    /// nothing, such as a segment's contact islands and the internal forces
    /// that no island touches. In order on one thread.
    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        a();
        b();
    }

    /// A short name for logs and benchmarks.
    fn name(&self) -> String;

    /// How many ranks share the work (1 for a single memory).
    fn ranks(&self) -> usize {
        1
    }

    /// How many threads run [`Executor::map`]'s tasks on this rank.
    fn threads_per_rank(&self) -> usize {
        1
    }

    /// This rank, `0..ranks()`.
    fn rank(&self) -> usize {
        0
    }

    /// **Collective over ranks.** Whether any rank says `yes`: how ranks
    /// agree, at a window boundary, to stop when a signal or a deadline
    /// reached only some of them.
    fn any_rank(&self, yes: bool) -> Result<bool, CommError> {
        let owner: Vec<u32> = (0..self.ranks() as u32).collect();
        let said = self.map_on_ranks(owner.len(), &owner, &|_| yes)?;
        Ok(said.into_iter().any(|y| y))
    }

    /// CPU seconds this rank has used: the process's (every thread of it),
    /// unless the rank is a thread among others in one process
    /// ([`crate::cpu`]).
    fn cpu_seconds(&self) -> f64 {
        crate::cpu::process_seconds()
    }

    /// [`Executor::cpu_seconds`] less the CPU spent polling for peers: the
    /// rank's work.
    fn work_cpu_seconds(&self) -> f64 {
        self.cpu_seconds() - self.traffic().wait_cpu_ns as f64 * 1e-9
    }

    /// What this rank sent to other ranks so far (nothing on one memory).
    fn traffic(&self) -> Traffic {
        Traffic::default()
    }

    /// **Collective over ranks.** `(0..n).map(f)`, item `i` computed on rank
    /// `owner[i]` only; every rank gets all results, in index order.
    /// `owner` is ignored on a single memory.
    fn map_on_ranks<R: Message>(
        &self,
        n: usize,
        owner: &[u32],
        f: &(dyn Fn(usize) -> R + Sync),
    ) -> Result<Vec<R>, CommError> {
        let _ = owner;
        Ok(self.map(n, f))
    }

    /// **Collective over ranks.** [`Executor::for_each_chunk`] with chunk `k`
    /// computed on the rank that [`place_by_size`] gives it; afterwards every
    /// rank's `data` holds every chunk.
    fn chunks_on_ranks<T: Message>(
        &self,
        data: &mut [T],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [T]) + Sync),
    ) -> Result<(), CommError> {
        self.for_each_chunk(data, bounds, task);
        Ok(())
    }

    /// **Point to point between ranks, overlapped with work.** Sends
    /// `sends[k].1` to rank `sends[k].0`, receives `recvs[k].1` words from
    /// rank `recvs[k].0`, and runs `overlap` while the messages travel
    /// (Algorithm 1: the interior partitions are computed while the boundary
    /// contributions are in flight). Returns the received words in `recvs`
    /// order, with their exact bits.
    ///
    /// Not a collective: only the ranks named take part, but each must make
    /// the matching call at the same point of its run (rank `j` receives
    /// from `i` exactly what `i` sends to `j`, with the same length). On a
    /// single memory there is no peer: `overlap` runs and nothing is sent.
    fn exchange_words(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, CommError> {
        if !sends.is_empty() || !recvs.is_empty() {
            return Err(CommError(format!(
                "{}: no peer rank to exchange with on one memory",
                self.name()
            )));
        }
        overlap();
        Ok(Vec::new())
    }

    /// **Collective over ranks.** Every rank hands every rank `head` (as
    /// many words on every rank: what all must agree on) and rank `j` its
    /// `parts[j]` (one per rank; `None` sends nothing; this rank's own is
    /// kept). Returns every rank's head in rank order and the part each rank
    /// addressed to this one (its own in its place): results a rank computed
    /// for the vertices another keeps, sent only there. While this rank
    /// waits for the others' heads and parts (its own sent), `overlap` runs
    /// pieces of work that need none of them, one per call, until it
    /// returns `false` (no piece left) or everything has arrived: the
    /// pieces left are the caller's (message-driven overlap; `overlap` must
    /// not communicate). On a single memory nothing is awaited and the
    /// result is `(vec![head], parts)`.
    fn all_to_all<T: Message>(
        &self,
        head: Vec<u64>,
        parts: Vec<Option<T>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<Addressed<T>, CommError> {
        let _ = overlap;
        Ok((vec![head], parts))
    }

    /// **Collective over ranks.** [`Executor::all_to_all`] for parts of
    /// vectors, sent as raw bits (eight little-endian bytes per
    /// coordinate, as [`Executor::all_gather_vectors`]): what travels at
    /// every internal tick (a generic encoding of the new velocities was
    /// more than half of their exchange's cost). An empty part sends
    /// nothing and arrives empty; no overlap runs in the wait.
    fn all_to_all_vectors(
        &self,
        head: Vec<u64>,
        parts: Vec<Vec<glam::DVec3>>,
    ) -> Result<AddressedVectors, CommError> {
        Ok((vec![head], parts))
    }

    /// **Collective over ranks.** Every rank's `mine`, in rank order (this
    /// rank's included), sent as raw bits (eight little-endian bytes per
    /// coordinate): the exchanges of every internal tick
    /// ([`crate::share::RankShare`]).
    fn all_gather_vectors(&self, mine: &[glam::DVec3]) -> Result<Vec<Vec<glam::DVec3>>, CommError> {
        Ok(vec![mine.to_vec()])
    }
}

/// Places consecutive items of the given sizes on `ranks` ranks in
/// contiguous runs of about equal total size: item `k` goes to the rank whose
/// share contains its middle element. Partitions placed this way keep their
/// neighbours (METIS numbers neighbouring parts close) on the same rank.
pub fn place_by_size(sizes: impl IntoIterator<Item = usize>, ranks: usize) -> Vec<u32> {
    let sizes: Vec<usize> = sizes.into_iter().collect();
    let total: usize = sizes.iter().sum();
    let ranks = ranks.max(1);
    let mut before = 0usize;
    sizes
        .iter()
        .map(|&size| {
            let mid = before + size / 2;
            before += size;
            ((mid * ranks) / total.max(1)).min(ranks - 1) as u32
        })
        .collect()
}

/// `n` items in `ranks` contiguous blocks of about equal count.
pub fn place_in_blocks(n: usize, ranks: usize) -> Vec<u32> {
    let ranks = ranks.max(1);
    (0..n).map(|i| (i * ranks / n.max(1)) as u32).collect()
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
