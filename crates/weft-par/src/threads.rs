//! The `Threads` executor: the engine's tasks on a rayon pool, handed out
//! so that no thread sleeps between the many short loops of a window.
//!
//! An internal tick of the twister at 10k vertices takes about 2 ms on two
//! threads and holds several loops, each ending in a join. Rayon lets an
//! idle worker, and a caller waiting for a stolen piece, sleep after a few
//! microseconds, and waking a thread took about 100 µs on the development
//! machine. So each loop is run by a *team* (`Threads::team`: the
//! caller and one helper job per other worker take indices, the caller
//! from the front and the helpers from the back, so a thread keeps much
//! the same runs of vertices from loop to loop; the caller spins at the
//! end, running whatever the pool has),
//! and between loops the other workers are *kept awake*
//! (`Threads::keep_awake`). Which thread runs a task never changes its
//! result, so none of this changes a bit.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use weft_sim::Executor;

/// How long a kept-awake worker looks for work before it lets rayon put it
/// to sleep (see [`Threads::keep_awake`]): longer than the gaps between
/// the loops of an internal tick, short enough that a serial stretch (a
/// pass's start, the output) soon gets its core back.
const STAY_AWAKE: Duration = Duration::from_micros(1000);

/// How long a waiting thread spins before each further look for work
/// yields its core to the OS instead (when there are more threads than
/// cores, as in the test suite, the one it waits for may need it).
const SPIN_BEFORE_YIELD: Duration = Duration::from_micros(50);

/// Waits by spinning, then by yielding the core: see [`SPIN_BEFORE_YIELD`].
struct Backoff {
    since: Instant,
    spins: u32,
    yielding: bool,
}

impl Backoff {
    fn new() -> Self {
        Self {
            since: Instant::now(),
            spins: 0,
            yielding: false,
        }
    }

    /// Found nothing to do: wait a little.
    fn idle(&mut self) {
        if self.yielding {
            std::thread::yield_now();
            return;
        }
        self.spins = self.spins.wrapping_add(1);
        // The clock is read once every 64 turns.
        self.yielding = self.spins % 64 == 0 && self.since.elapsed() > SPIN_BEFORE_YIELD;
        std::hint::spin_loop();
    }

    /// Found work: start over.
    fn busy(&mut self) {
        *self = Self::new();
    }

    /// Runs one piece of the pool's work if there is any (and starts over),
    /// else waits a little.
    fn look(&mut self) {
        match rayon::yield_now() {
            Some(rayon::Yield::Executed) => self.busy(),
            _ => self.idle(),
        }
    }
}

/// Takes the next index of `lo..hi` (packed as `hi << 32 | lo`) from the
/// front or the back; `None` when none is left.
///
/// A team's caller takes from the front and its helpers from the back, so
/// in the loops of an internal tick over the same runs of vertices each
/// thread mostly gets the runs it had in the loop before, whose data its
/// cache still holds. With one shared counter the runs changed threads
/// from loop to loop: measured on the development machine (2 threads,
/// twister from its checkpoints, interleaved rounds), the window took 4 %
/// longer at 10k and 4–8 % longer at 50k.
fn claim(ends: &AtomicU64, front: bool) -> Option<usize> {
    let mut cur = ends.load(Ordering::Relaxed);
    loop {
        let (lo, hi) = (cur & 0xffff_ffff, cur >> 32);
        if lo >= hi {
            return None;
        }
        let (next, i) = if front {
            (cur + 1, lo)
        } else {
            (cur - (1 << 32), hi - 1)
        };
        match ends.compare_exchange_weak(cur, next, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return Some(i as usize),
            Err(now) => cur = now,
        }
    }
}

/// Takes the item out of a slot each index takes once (a lock never held
/// while a task runs, so never poisoned; if it were, the item is intact).
fn take<T>(slot: &std::sync::Mutex<Option<T>>) -> Option<T> {
    slot.lock().unwrap_or_else(|e| e.into_inner()).take()
}

thread_local! {
    /// How many of the executor's tasks this thread is inside (a task that
    /// waits for a nested loop's stolen piece is still inside it).
    static IN_TASK: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Runs `f` counted as inside one of the executor's tasks.
fn as_task<R>(f: impl FnOnce() -> R) -> R {
    struct Leave;
    impl Drop for Leave {
        fn drop(&mut self) {
            IN_TASK.with(|d| d.set(d.get() - 1));
        }
    }
    IN_TASK.with(|d| d.set(d.get() + 1));
    let _leave = Leave;
    f()
}

/// Runs the engine's tasks on its own pool of `n` threads (chunks, map
/// items and join sides are taken in order by whichever thread comes free;
/// nested loops are helped by threads waiting for their own). Clones share
/// the pool.
#[derive(Clone)]
pub struct Threads {
    pool: Arc<Pool>,
    /// Keep-awake jobs handed out and not yet ended.
    awake: Arc<AtomicUsize>,
}

/// Threads in every pool of this process now (simulated ranks each have
/// their own).
static THREADS_IN_POOLS: AtomicUsize = AtomicUsize::new(0);

/// A rayon pool, counted in [`THREADS_IN_POOLS`] while it lives.
struct Pool(rayon::ThreadPool);

impl std::ops::Deref for Pool {
    type Target = rayon::ThreadPool;
    fn deref(&self) -> &rayon::ThreadPool {
        &self.0
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        THREADS_IN_POOLS.fetch_sub(self.0.current_num_threads(), Ordering::Relaxed);
    }
}

/// Whether this process's pools have more threads than the machine has
/// cores: a kept-awake worker would then take a core from one with work.
fn oversubscribed() -> bool {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    let cores = *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    THREADS_IN_POOLS.load(Ordering::Relaxed) > cores
}

impl Threads {
    /// A pool of `n` threads (`0`: one per logical core).
    pub fn new(n: usize) -> Result<Self, rayon::ThreadPoolBuildError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("weft-{i}"))
            .build()?;
        Ok(Self {
            pool: Arc::new({
                THREADS_IN_POOLS.fetch_add(pool.current_num_threads(), Ordering::Relaxed);
                Pool(pool)
            }),
            awake: Arc::default(),
        })
    }

    /// Before a loop that is not inside another: makes sure each other
    /// worker of the pool runs a keep-awake job, which steals and runs the
    /// pool's work as it comes and ends only after [`STAY_AWAKE`] without
    /// any. The job goes to every worker (`spawn_broadcast`); it ends at
    /// once on the calling thread, and on a thread inside one of the
    /// executor's tasks (one waiting there for a stolen piece of a nested
    /// loop must not stay under a job that spins on). Not done when this
    /// process's pools hold more threads than there are cores (simulated
    /// ranks of several threads each): a spinning worker would then take a
    /// core from a thread with work.
    fn keep_awake(&self) {
        let threads = self.threads();
        if threads < 2 || IN_TASK.with(|d| d.get()) > 0 || oversubscribed() {
            return;
        }
        if self.awake.load(Ordering::Acquire) > 0 {
            return;
        }
        // Only for a caller on the pool (the simulation loop runs there,
        // `install`): a job injected from outside could otherwise run
        // inside a keep-awake job, which would stay counted meanwhile.
        let Some(caller) = rayon::current_thread_index() else {
            return;
        };
        // The calling thread's copy ends at once and is not counted: it
        // runs only when the caller next looks for work, maybe much later.
        self.awake.store(threads - 1, Ordering::Release);
        let awake = self.awake.clone();
        self.pool.spawn_broadcast(move |ctx| {
            if ctx.index() == caller {
                return;
            }
            if IN_TASK.with(|d| d.get()) == 0 {
                let mut wait = Backoff::new();
                while wait.since.elapsed() <= STAY_AWAKE {
                    wait.look();
                }
            }
            awake.fetch_sub(1, Ordering::AcqRel);
        });
    }

    /// Runs `f` on one of the pool's threads. Run the whole simulation loop
    /// this way: its serial parts then run on a pool thread and the pool's
    /// other threads are the only others, instead of an extra thread that
    /// competes with workers spinning for work between parallel stages.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.pool.install(f)
    }

    /// Runs `task(i)` for every `i` in `0..n` once, on the pool: the
    /// calling thread takes indices from the front and one helper job per
    /// other worker from the back ([`claim`]); the caller, its share done,
    /// waits for the indices taken elsewhere by running whatever work the
    /// pool has (a nested loop's pieces among it) and spinning ([`Backoff`]),
    /// instead of sleeping in rayon's wait. A panic in a task ends the
    /// wait and reaches the caller through the scope.
    fn team(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        use std::sync::atomic::AtomicBool;
        self.keep_awake();
        // The indices not yet taken, `lo..hi` packed in one word: the
        // caller takes from the front, the helpers from the back.
        let hi = u32::try_from(n).expect("fewer than 2^32 tasks in a loop");
        let ends = AtomicU64::new(u64::from(hi) << 32);
        let done = AtomicUsize::new(0);
        let panicked = AtomicBool::new(false);
        let work = |front: bool| {
            as_task(|| {
                while let Some(i) = claim(&ends, front) {
                    struct Watch<'a>(&'a AtomicBool);
                    impl Drop for Watch<'_> {
                        fn drop(&mut self) {
                            if std::thread::panicking() {
                                self.0.store(true, Ordering::Release);
                            }
                        }
                    }
                    let _watch = Watch(&panicked);
                    task(i);
                    done.fetch_add(1, Ordering::Release);
                }
            })
        };
        self.pool.install(|| {
            rayon::scope(|s| {
                for _ in 1..self.threads().min(n) {
                    s.spawn(|_| work(false));
                }
                work(true);
                let mut wait = Backoff::new();
                while done.load(Ordering::Acquire) < n && !panicked.load(Ordering::Acquire) {
                    wait.look();
                }
            })
        });
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
        let chunks: Vec<_> = (weft_sim::executor::split_chunks(data, bounds).into_iter())
            .map(|chunk| std::sync::Mutex::new(Some(chunk)))
            .collect();
        self.team(chunks.len(), &|i| {
            if let Some((k, chunk)) = take(&chunks[i]) {
                task(k, chunk);
            }
        });
    }

    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
        if n <= 1 {
            return (0..n).map(f).collect();
        }
        // Items are taken in runs of `grain` (one item each for short
        // lists, whose items may cost very unequally; maps over every
        // vertex or stencil would otherwise pay a shared counter and a lock
        // per item).
        let grain = (n / (64 * self.threads())).max(1);
        let mut out: Vec<Option<R>> = (0..n).map(|_| None).collect();
        let runs: Vec<_> = (out.chunks_mut(grain).enumerate())
            .map(|run| std::sync::Mutex::new(Some(run)))
            .collect();
        self.team(runs.len(), &|k| {
            if let Some((r, run)) = take(&runs[k]) {
                for (j, slot) in run.iter_mut().enumerate() {
                    *slot = Some(f(r * grain + j));
                }
            }
        });
        drop(runs);
        (out.into_iter())
            .map(|item| item.expect("every item mapped"))
            .collect()
    }

    fn name(&self) -> String {
        format!("threads({})", self.threads())
    }

    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        type Side<'a> = std::sync::Mutex<Option<&'a mut (dyn FnMut() + Send)>>;
        let sides: [Side<'_>; 2] = [Side::new(Some(a)), Side::new(Some(b))];
        self.team(2, &|i| {
            if let Some(side) = take(&sides[i]) {
                side();
            }
        });
    }

    fn threads_per_rank(&self) -> usize {
        self.threads()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn claims_from_both_ends_hand_out_every_index_once() {
        let ends = AtomicU64::new(5 << 32);
        let order: Vec<_> = [true, false, false, true, true, false]
            .into_iter()
            .map(|front| claim(&ends, front))
            .collect();
        assert_eq!(order, [Some(0), Some(4), Some(3), Some(1), Some(2), None]);
        // Taken at once by two threads at each end: each index once.
        let n = 100_000u32;
        let ends = AtomicU64::new(u64::from(n) << 32);
        let mut all: Vec<usize> = std::thread::scope(|s| {
            let takers: Vec<_> = [true, true, false, false]
                .into_iter()
                .map(|front| {
                    let ends = &ends;
                    s.spawn(move || std::iter::from_fn(|| claim(ends, front)).collect::<Vec<_>>())
                })
                .collect();
            takers.into_iter().flat_map(|t| t.join().unwrap()).collect()
        });
        all.sort_unstable();
        assert!(all.iter().copied().eq(0..n as usize));
    }

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

    #[test]
    fn nested_loops_run_every_index_once() {
        // Loops inside loops and join sides, with very unequal items: each
        // inner index runs exactly once, the results in index order.
        use std::sync::atomic::AtomicU64;
        for threads in [2, 3] {
            let t = Threads::new(threads).unwrap();
            let runs = AtomicU64::new(0);
            let outer = t.map(40, &|i| {
                let inner = t.map(i % 7 * 50, &|j| {
                    runs.fetch_add(1, Ordering::Relaxed);
                    (0..(j % 13) * 100).fold(j as u64, |a, k| a.wrapping_mul(31) ^ k as u64)
                });
                let mut sides = (0u64, 0u64);
                t.join(
                    &mut || sides.0 = inner.iter().fold(0, |a, x| a ^ x),
                    &mut || sides.1 = t.map(i, &|k| k as u64).iter().sum(),
                );
                sides
            });
            let expect: u64 = (0..40).map(|i| (i % 7 * 50) as u64).sum();
            assert_eq!(runs.load(Ordering::Relaxed), expect);
            for (i, &(_, side)) in outer.iter().enumerate() {
                assert_eq!(side, (0..i as u64).sum::<u64>());
            }
        }
    }

    #[test]
    fn a_panicking_task_reaches_the_caller_and_nothing_waits_on() {
        let t = Threads::new(2).unwrap();
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut data = vec![0u8; 64];
            let bounds: Vec<usize> = (0..=64).step_by(4).collect();
            t.for_each_chunk(&mut data, &bounds, &|k, _| assert!(k != 5, "chunk 5"));
        }));
        assert!(caught.is_err());
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            t.map(1000, &|i| assert!(i != 999, "item"))
        }));
        assert!(caught.is_err());
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            t.join(&mut || {}, &mut || panic!("side b"))
        }));
        assert!(caught.is_err());
        // The pool still works afterwards.
        assert_eq!(t.map(10, &|i| i).iter().sum::<usize>(), 45);
    }
}
