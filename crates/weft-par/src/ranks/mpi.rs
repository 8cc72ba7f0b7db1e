//! [`Transport`] over MPI (feature `mpi`): ranks are processes started by
//! `mpirun`, and [`Transport::all_gather`] is two nonblocking MPI
//! collectives.
//!
//! The project's rule is **never block in an MPI wait inside a thread-pool
//! task**: the simulation loop runs on a rayon pool thread, and a blocking
//! `MPI_Wait` there would also stall whatever that thread is asked to help
//! with. So every collective here is started as an immediate (nonblocking)
//! operation and completed by polling `MPI_Test` with a back-off (spin, then
//! yield for a few milliseconds, then sleep growing to 200 µs).
//!
//! MPI is initialized with thread level `MPI_THREAD_SERIALIZED`: any thread
//! may call into MPI, one at a time. [`MpiTransport`] enforces that itself: a
//! lock is held for each MPI call (starting an operation, one test), and a
//! second lock for a whole collective, so two threads of one rank can never
//! interleave their collectives' parts.
//!
//! Running it: `mpirun -n 3 --bind-to none PROGRAM` (`--bind-to none` lets a
//! rank's threads use more than one core). As root OpenMPI also wants
//! `OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1`; more ranks
//! than cores need `OMPI_MCA_rmaps_base_oversubscribe=1`; in containers set
//! `OMPI_MCA_btl_vader_single_copy_mechanism=none`.

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use mpi::datatype::PartitionMut;
use mpi::environment::Universe;
use mpi::point_to_point::Status;
use mpi::request::{Request, Scope};
use mpi::traits::*;
use mpi::{Count, Threading};

use super::transport::{HeadsAndParts, RankFailure, Traffic, TrafficCounter, Transport};

/// This process's rank in `MPI_COMM_WORLD`, as a [`Transport`].
///
/// It owns the MPI [`Universe`]: dropping it finalizes MPI (after which MPI
/// cannot be initialized again in this process), or, while the thread
/// panics, aborts every rank (see its `Drop`). It is `Send + Sync` without
/// any `unsafe`: it keeps no communicator handle (rsmpi's handles hold raw
/// pointers), only the `Universe`, and makes the world communicator anew
/// (a constant handle, nothing to allocate or free) for each call.
pub struct MpiTransport {
    /// Held for each single MPI call, so calls stay serialized (the thread
    /// level is `MPI_THREAD_SERIALIZED`) while none waits on another rank.
    universe: Mutex<Universe>,
    /// Held for a whole collective ([`Transport::all_gather`],
    /// [`MpiTransport::barrier`]), so one thread's collective is not
    /// interleaved with another's.
    collective: Mutex<()>,
    rank: usize,
    size: usize,
    sent: TrafficCounter,
}

impl MpiTransport {
    /// Initializes MPI (thread level `MPI_THREAD_SERIALIZED`) and returns
    /// this process's rank in the world communicator.
    ///
    /// MPI can be initialized once per process: this fails if it already was
    /// (by an earlier call or by other code), or if the MPI library does not
    /// provide the serialized thread level (MPI is finalized again then).
    pub fn init() -> Result<MpiTransport, String> {
        let (universe, provided) = mpi::initialize_with_threading(Threading::Serialized)
            .ok_or_else(|| {
                "MPI is already initialized (it can be initialized once per process)".to_string()
            })?;
        if provided < Threading::Serialized {
            return Err(format!(
                "the MPI library provides thread level {provided:?}, weft needs Serialized"
            ));
        }
        let world = universe.world();
        let rank = usize::try_from(world.rank())
            .map_err(|_| format!("MPI gave a negative rank {}", world.rank()))?;
        let size = usize::try_from(world.size())
            .map_err(|_| format!("MPI gave a negative size {}", world.size()))?;
        Ok(MpiTransport {
            universe: Mutex::new(universe),
            collective: Mutex::new(()),
            rank,
            size,
            sent: TrafficCounter::default(),
        })
    }

    /// Ends every rank of the run at once (`MPI_Abort` on the world
    /// communicator), with exit code `code` where the MPI launcher passes one
    /// on. For an error one rank hits and the others cannot know about: they
    /// would otherwise wait forever in their next collective.
    ///
    /// Not a collective: one rank calls it. It waits only for an MPI call of
    /// this rank already under way (a start or a test, never a wait).
    pub fn abort(&self, code: i32) -> ! {
        let universe = self.mpi_call();
        universe.world().abort(code)
    }

    /// **Collective** (nonblocking `MPI_Ibarrier`, completed by polling):
    /// returns once every rank has called it.
    pub fn barrier(&self) {
        let _collective = self
            .collective
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let request = self.mpi_call().world().immediate_barrier();
        self.complete(request);
    }

    /// The lock for one MPI call. A poisoned lock is taken all the same: it
    /// guards no data of ours, only the order of calls.
    fn mpi_call(&self) -> MutexGuard<'_, Universe> {
        self.universe.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Completes `request` by polling `MPI_Test` with a back-off, never
    /// blocking in an MPI wait. A request must not be dropped unfinished, so
    /// this does not give up: a peer that never joins the collective hangs
    /// it (the launcher ends the run when a rank's process dies, and a rank
    /// that fails calls [`MpiTransport::abort`]).
    /// The polling is counted as waiting, not work (`Traffic::wait_cpu_ns`);
    /// a request already complete at its first test reads no clock.
    fn complete<'a, D: ?Sized, S: Scope<'a>>(&self, request: Request<'a, D, S>) -> Status {
        self.complete_while(request, &mut || false)
    }

    /// [`Self::complete`], running `work` while the request is unfinished,
    /// for as long as it runs a piece (`transport::pieces`); only the
    /// polling after that counts as waiting.
    fn complete_while<'a, D: ?Sized, S: Scope<'a>>(
        &self,
        mut request: Request<'a, D, S>,
        work: &mut dyn FnMut() -> bool,
    ) -> Status {
        loop {
            match self.test(request) {
                Ok(status) => return status,
                Err(unfinished) => request = unfinished,
            }
            if !work() {
                break;
            }
        }
        self.sent.waiting(|| {
            let mut backoff = Backoff::default();
            loop {
                match self.test(request) {
                    Ok(status) => return status,
                    Err(unfinished) => {
                        request = unfinished;
                        backoff.snooze();
                    }
                }
            }
        })
    }

    /// One `MPI_Test` of `request`: its status, or the request unfinished.
    fn test<'a, D: ?Sized, S: Scope<'a>>(
        &self,
        request: Request<'a, D, S>,
    ) -> Result<Status, Request<'a, D, S>> {
        let _call = self.mpi_call();
        request.test()
    }

    fn failure(&self, what: String) -> RankFailure {
        RankFailure {
            rank: self.rank,
            what,
        }
    }
}

/// Dropping it finalizes MPI (`MPI_Finalize`, which waits for every rank to
/// finalize too) — except while this thread panics: the other ranks may be
/// waiting in a collective this rank will never join, so it aborts the whole
/// run instead ([`MpiTransport::abort`] with code 101, a panic's exit code).
impl Drop for MpiTransport {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!(
                "rank {}: panicked with MPI initialized: aborting every rank",
                self.rank
            );
            self.abort(PANIC_EXIT_CODE);
        }
    }
}

/// The exit code of a Rust program that panicked.
const PANIC_EXIT_CODE: i32 = 101;

impl Transport for MpiTransport {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    /// **Collective**, made of two nonblocking MPI collectives, each
    /// completed by polling: an `MPI_Iallgather` of every rank's length (one
    /// `u64` each), then an `MPI_Iallgatherv` of the bytes. Every rank learns
    /// all lengths before the second, so all agree on whether it can go on:
    /// MPI counts are C `int`s, and a gather of 2 GiB or more in all is an
    /// error on every rank alike.
    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure> {
        let _collective = self
            .collective
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let size = self.size;

        // Collective 1: the lengths.
        let my_len = mine.len() as u64;
        let mut lens = vec![0u64; size];
        mpi::request::scope(|scope| {
            let request =
                self.mpi_call()
                    .world()
                    .immediate_all_gather_into(scope, &my_len, &mut lens[..]);
            self.complete(request);
        });

        let mut counts: Vec<Count> = Vec::with_capacity(size);
        let mut displs: Vec<Count> = Vec::with_capacity(size);
        let mut total: Count = 0;
        for (j, &len) in lens.iter().enumerate() {
            let count = Count::try_from(len)
                .ok()
                .filter(|&c| total.checked_add(c).is_some())
                .ok_or_else(|| {
                    self.failure(format!(
                        "all-gather too large for MPI: rank {j} sends {len} bytes, \
                         {total} bytes before it (the total must stay below 2 GiB)"
                    ))
                })?;
            counts.push(count);
            displs.push(total);
            total += count;
        }

        // Collective 2: the bytes, each rank's at its displacement. Skipped
        // on every rank alike when nobody sends a byte: OpenMPI rejects an
        // all-gather into an empty buffer (MPI_ERR_ARG).
        let mut all = vec![0u8; total as usize];
        if total > 0 {
            let mut partition = PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
            mpi::request::scope(|scope| {
                let request = self.mpi_call().world().immediate_all_gather_varcount_into(
                    scope,
                    &mine[..],
                    &mut partition,
                );
                self.complete(request);
            });
        }

        let peers = size.saturating_sub(1) as u64;
        self.sent.add(peers, peers * my_len);
        self.sent.collective();

        let mut parts: Vec<Vec<u8>> = counts
            .iter()
            .zip(&displs)
            .map(|(&c, &d)| all[d as usize..(d + c) as usize].to_vec())
            .collect();
        parts[self.rank] = mine;
        Ok(parts)
    }

    /// **Collective**: an `MPI_Ialltoall` of each rank's head and each
    /// part's length (`2 + head.len()` words to every rank: the length, a
    /// flag, the head), completed by polling, then the non-empty parts point
    /// to point (tag [`ALL_TO_ALL_TAG`]; their lengths are known to both
    /// sides by then). A rank whose part is too large for MPI still takes
    /// part in the dense step, with its flag set: every rank then learns it,
    /// none posts a part, and all fail alike (a rank that returned early
    /// would leave the others waiting in the collective).
    fn all_to_all(
        &self,
        head: Vec<u64>,
        mut parts: Vec<Vec<u8>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<HeadsAndParts, RankFailure> {
        let _collective = self
            .collective
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let (size, me) = (self.size, self.rank);
        if parts.len() != size {
            return Err(self.failure(format!(
                "an all-to-all with {} parts for {size} ranks",
                parts.len()
            )));
        }
        let too_large = parts.iter().position(|p| Count::try_from(p.len()).is_err());
        let words = head.len() + 2;
        let send: Vec<u64> = (0..size)
            .flat_map(|j| {
                let len = if too_large.is_some() {
                    0
                } else {
                    parts[j].len() as u64
                };
                [len, u64::from(too_large.is_some())]
                    .into_iter()
                    .chain(head.iter().copied())
            })
            .collect();
        let mut recv = vec![0u64; words * size];
        // The parts leave with the heads (none from a rank with a part too
        // large: its head says so, with lengths 0), `overlap` runs while
        // they travel, then the heads are completed and the parts announced
        // received. Every announced part is received and every send
        // completed, also when a rank then reports a part too large, so no
        // request is left behind.
        let mut overlap = super::transport::pieces(overlap);
        let (counts, mut received) = mpi::request::scope(|scope| {
            let mut sent = Vec::new();
            for (j, part) in parts.iter().enumerate() {
                if too_large.is_none() && j != me && !part.is_empty() {
                    let world = self.mpi_call().world();
                    sent.push(
                        world
                            .process_at_rank(j as mpi::Rank)
                            .immediate_send_with_tag(scope, &part[..], ALL_TO_ALL_TAG),
                    );
                }
            }
            mpi::request::scope(|heads| {
                let request = self.mpi_call().world().immediate_all_to_all_into(
                    heads,
                    &send[..],
                    &mut recv[..],
                );
                self.complete_while(request, &mut overlap);
            });
            let mut received: Vec<Vec<u8>> = (recv.chunks_exact(words).enumerate())
                .map(|(j, c)| vec![0u8; if j == me { 0 } else { c[0] as usize }])
                .collect();
            let counts = mpi::request::scope(|arrivals| {
                let mut arriving = Vec::new();
                for (j, buffer) in received.iter_mut().enumerate() {
                    if !buffer.is_empty() {
                        let world = self.mpi_call().world();
                        let request = world
                            .process_at_rank(j as mpi::Rank)
                            .immediate_receive_into_with_tag(
                                arrivals,
                                &mut buffer[..],
                                ALL_TO_ALL_TAG,
                            );
                        arriving.push((j, request));
                    }
                }
                (arriving.into_iter())
                    .map(|(j, request)| {
                        let status = self.complete_while(request, &mut overlap);
                        (j, status.count(u8::equivalent_datatype()))
                    })
                    .collect::<Vec<(usize, Count)>>()
            });
            for request in sent {
                self.complete(request);
            }
            (counts, received)
        });
        if let Some(j) = too_large {
            return Err(self.failure(format!(
                "{} bytes to rank {j}: too large for MPI",
                parts[j].len()
            )));
        }
        if let Some(j) = recv.chunks_exact(words).position(|c| c[1] != 0) {
            return Err(self.failure(format!(
                "rank {j} had a part too large for MPI in an all-to-all"
            )));
        }
        let heads: Vec<Vec<u64>> = recv.chunks_exact(words).map(|c| c[2..].to_vec()).collect();
        let lens: Vec<usize> = recv.chunks_exact(words).map(|c| c[0] as usize).collect();
        for (j, count) in counts {
            if usize::try_from(count).ok() != Some(lens[j]) {
                return Err(
                    self.failure(format!("rank {j} sent {count} bytes, {} expected", lens[j]))
                );
            }
        }
        let peers = size.saturating_sub(1) as u64;
        // (Counted as the head and length the channel transport sends.)
        self.sent.add(peers, peers * 8 * (words as u64 - 1));
        for (j, part) in parts.iter().enumerate() {
            if j != me && !part.is_empty() {
                self.sent.add(1, part.len() as u64);
            }
        }
        self.sent.collective();
        received[me] = std::mem::take(&mut parts[me]);
        Ok((heads, received))
    }

    /// **Point to point**: an `MPI_Isend` to each peer of `sends` and an
    /// `MPI_Irecv` from each peer of `recvs` (tag [`EXCHANGE_TAG`]; MPI keeps
    /// messages with one source, tag and communicator in order), then
    /// `overlap` runs while they travel, then each is completed by polling.
    /// The lengths are known to both sides, so no length travels first.
    fn exchange(
        &self,
        sends: Vec<(usize, Vec<u8>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<u8>>, RankFailure> {
        let _collective = self
            .collective
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let peer = |j: usize| {
            mpi::Rank::try_from(j)
                .ok()
                .filter(|&r| j < self.size && j != self.rank && r >= 0)
                .ok_or_else(|| self.failure(format!("no peer rank {j} to exchange with")))
        };
        for &(j, len) in recvs {
            peer(j)?;
            Count::try_from(len).map_err(|_| {
                self.failure(format!("{len} bytes from rank {j}: too large for MPI"))
            })?;
        }
        for (j, bytes) in &sends {
            peer(*j)?;
            Count::try_from(bytes.len()).map_err(|_| {
                self.failure(format!(
                    "{} bytes to rank {j}: too large for MPI",
                    bytes.len()
                ))
            })?;
        }
        let mut received: Vec<Vec<u8>> = recvs.iter().map(|&(_, len)| vec![0u8; len]).collect();
        let counts = mpi::request::scope(|scope| {
            let mut sent = Vec::with_capacity(sends.len());
            for (j, bytes) in &sends {
                let world = self.mpi_call().world();
                sent.push(
                    world
                        .process_at_rank(*j as mpi::Rank)
                        .immediate_send_with_tag(scope, &bytes[..], EXCHANGE_TAG),
                );
            }
            let mut arriving = Vec::with_capacity(recvs.len());
            for (&(j, _), buffer) in recvs.iter().zip(received.iter_mut()) {
                let world = self.mpi_call().world();
                arriving.push(
                    world
                        .process_at_rank(j as mpi::Rank)
                        .immediate_receive_into_with_tag(scope, &mut buffer[..], EXCHANGE_TAG),
                );
            }
            overlap();
            let counts: Vec<Count> = arriving
                .into_iter()
                .map(|request| self.complete(request).count(u8::equivalent_datatype()))
                .collect();
            for request in sent {
                self.complete(request);
            }
            counts
        });
        for (&(j, len), count) in recvs.iter().zip(counts) {
            if usize::try_from(count).ok() != Some(len) {
                return Err(self.failure(format!("rank {j} sent {count} bytes, {len} expected")));
            }
        }
        for (_, bytes) in &sends {
            self.sent.add(1, bytes.len() as u64);
        }
        if !sends.is_empty() || !recvs.is_empty() {
            self.sent.exchange();
        }
        Ok(received)
    }

    fn traffic(&self) -> Traffic {
        self.sent.total()
    }
}

/// The tag of [`Transport::exchange`]'s messages.
pub const EXCHANGE_TAG: mpi::Tag = 7;

/// The tag of [`Transport::all_to_all`]'s parts.
pub const ALL_TO_ALL_TAG: mpi::Tag = 8;

/// Waiting between polls: a few spins first (a collective among ranks on
/// one machine often completes within microseconds), then yields, then
/// sleeps that double up to [`Backoff::MAX_SLEEP`].
#[derive(Default)]
struct Backoff {
    polls: u32,
    sleep: Option<Duration>,
}

impl Backoff {
    // The engine's collectives come every internal tick (about a
    // millisecond of work apart): a peer is usually microseconds away, and a
    // long sleep here would cost every rank that much per tick. So yield for
    // a few milliseconds (cheap when the core has nothing else to run, fair
    // when ranks share cores), and only then sleep, briefly.
    const SPINS: u32 = 16;
    const YIELDS: u32 = 4096;
    const FIRST_SLEEP: Duration = Duration::from_micros(20);
    const MAX_SLEEP: Duration = Duration::from_micros(200);

    fn snooze(&mut self) {
        self.polls = self.polls.saturating_add(1);
        if self.polls <= Self::SPINS {
            for _ in 0..(1 << self.polls.min(6)) {
                std::hint::spin_loop();
            }
        } else if self.polls <= Self::SPINS + Self::YIELDS {
            std::thread::yield_now();
        } else {
            let sleep = self
                .sleep
                .map_or(Self::FIRST_SLEEP, |s| (s * 2).min(Self::MAX_SLEEP));
            self.sleep = Some(sleep);
            std::thread::sleep(sleep);
        }
    }
}
