//! [`Transport`] over MPI (feature `mpi`): ranks are processes started by
//! `mpirun`. The collectives are weft's own, Bruck's all-gather in
//! `⌈log2 R⌉` rounds of point-to-point messages ([`dissemination`]): Open
//! MPI 4.1's nonblocking ones send `R - 1` messages each way.
//!
//! The project's rule is **never block in an MPI wait inside a thread-pool
//! task**: the simulation loop runs on a rayon pool thread, and a blocking
//! `MPI_Wait` there would also stall whatever that thread is asked to help
//! with. So every operation here is started as an immediate (nonblocking)
//! one and completed by polling `MPI_Test` (or `MPI_Improbe`, for a message
//! whose length only its sender knows) with a back-off (spin, then yield for
//! a few milliseconds, then sleep growing to 200 µs).
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

use mpi::environment::Universe;
use mpi::point_to_point::Status;
use mpi::request::{Request, Scope};
use mpi::traits::*;
use mpi::{Count, Threading};

use super::dissemination;
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
    /// The largest piece of a gather round's message, in bytes
    /// ([`MpiTransport::set_message_limit`]).
    message_limit: usize,
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
            message_limit: Self::DEFAULT_MESSAGE_LIMIT,
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

    /// One round of a gather ([`dissemination`]): sends `bytes` to rank
    /// `to` and returns this round's message from rank `from` (tag
    /// [`ROUND_TAG`]), whose length only the sender knows: it is probed
    /// (`MPI_Improbe`, polled with `work` and then the back-off) and
    /// received into a buffer of that length (`MPI_Imrecv`). A message
    /// travels in pieces of at most [`MpiTransport::message_limit`] bytes
    /// (MPI counts are C `int`s), the last one shorter, empty where need
    /// be, which tells the receiver it is the last. Messages with one
    /// source, tag and communicator stay in order, so the pieces, and the
    /// rounds of consecutive collectives, never mix.
    fn round(
        &self,
        to: usize,
        bytes: Vec<u8>,
        from: usize,
        work: &mut dyn FnMut() -> bool,
    ) -> Vec<u8> {
        let limit = self.message_limit;
        let pieces: Vec<&[u8]> = bytes
            .chunks(limit)
            .chain((bytes.len() % limit == 0).then_some(&[][..]))
            .collect();
        self.sent.add(pieces.len() as u64, bytes.len() as u64);
        mpi::request::scope(|scope| {
            let sent: Vec<_> = (pieces.iter())
                .map(|piece| {
                    let world = self.mpi_call().world();
                    world
                        .process_at_rank(to as mpi::Rank)
                        .immediate_send_with_tag(scope, *piece, ROUND_TAG)
                })
                .collect();
            let mut got = Vec::new();
            loop {
                let (message, status) = self.probe_while(from, ROUND_TAG, work);
                let count = usize::try_from(status.count(u8::equivalent_datatype()))
                    .expect("a message's count is not negative");
                let start = got.len();
                got.resize(start + count, 0u8);
                mpi::request::scope(|arrival| {
                    let request = {
                        let _call = self.mpi_call();
                        message.immediate_matched_receive_into(arrival, &mut got[start..])
                    };
                    self.complete(request);
                });
                if count < limit {
                    break;
                }
            }
            for request in sent {
                self.complete(request);
            }
            got
        })
    }

    /// The next message from rank `from` with tag `tag`, matched
    /// (`MPI_Improbe`): polled while `work` runs pieces, then with the
    /// back-off, counted as waiting.
    fn probe_while(
        &self,
        from: usize,
        tag: mpi::Tag,
        work: &mut dyn FnMut() -> bool,
    ) -> (mpi::point_to_point::Message, Status) {
        let probe = || {
            let universe = self.mpi_call();
            let world = universe.world();
            let found = world
                .process_at_rank(from as mpi::Rank)
                .immediate_matched_probe_with_tag(tag);
            found
        };
        loop {
            if let Some(found) = probe() {
                return found;
            }
            if !work() {
                break;
            }
        }
        self.sent.waiting(|| {
            let mut backoff = Backoff::default();
            loop {
                if let Some(found) = probe() {
                    return found;
                }
                backoff.snooze();
            }
        })
    }

    /// Splits every message of a gather's round into pieces of at most
    /// `bytes` bytes (default [`MpiTransport::DEFAULT_MESSAGE_LIMIT`], 1 GiB;
    /// below 2 GiB, the most an MPI count holds). Small limits are for
    /// tests: every rank must use the same.
    pub fn set_message_limit(&mut self, bytes: usize) {
        self.message_limit = bytes.clamp(1, Self::DEFAULT_MESSAGE_LIMIT);
    }

    /// See [`MpiTransport::set_message_limit`].
    pub const DEFAULT_MESSAGE_LIMIT: usize = 1 << 30;
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

    /// **Collective**: Bruck's all-gather ([`dissemination`]), `⌈log2 R⌉`
    /// rounds of one message each way (`MpiTransport::round`), not Open
    /// MPI's linear `MPI_Iallgather`.
    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure> {
        let _collective = self
            .collective
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let all = dissemination::all_gather(self.rank, self.size, mine, &mut |to, bytes, from| {
            Ok(self.round(to, bytes, from, &mut || false))
        })?;
        self.sent.collective();
        Ok(all)
    }

    /// **Collective**: the non-empty parts leave point to point (tag
    /// [`ALL_TO_ALL_TAG`]), every rank's head and its parts' lengths are
    /// all-gathered (`dissemination::head_block`, Bruck's rounds) while
    /// they travel and `overlap` runs, then the announced parts are
    /// received. A rank whose part is too large for MPI still takes part in
    /// the gather, with its flag set and no part sent: every rank then
    /// learns it and all fail alike (a rank that returned early would leave
    /// the others waiting). Every announced part is received and every send
    /// completed before that, so no request is left behind.
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
        let block = dissemination::head_block(me, &head, &parts, too_large.is_some());
        let mut overlap = super::transport::pieces(overlap);
        let outcome = mpi::request::scope(|scope| {
            let mut sent = Vec::new();
            for (j, part) in parts.iter().enumerate() {
                if too_large.is_none() && j != me && !part.is_empty() {
                    let world = self.mpi_call().world();
                    sent.push(
                        world
                            .process_at_rank(j as mpi::Rank)
                            .immediate_send_with_tag(scope, &part[..], ALL_TO_ALL_TAG),
                    );
                    self.sent.add(1, part.len() as u64);
                }
            }
            let gathered = dissemination::all_gather(me, size, block, &mut |to, bytes, from| {
                Ok(self.round(to, bytes, from, &mut overlap))
            })
            .and_then(|blocks| dissemination::read_heads(me, head.len(), &blocks));
            let outcome = gathered.map(|gathered| {
                let mut received: Vec<Vec<u8>> = gathered
                    .incoming
                    .iter()
                    .map(|&len| vec![0u8; len])
                    .collect();
                let counts = mpi::request::scope(|arrivals| {
                    let mut arriving = Vec::new();
                    for (j, buffer) in received.iter_mut().enumerate() {
                        if j != me && !buffer.is_empty() {
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
                (gathered, received, counts)
            });
            for request in sent {
                self.complete(request);
            }
            outcome
        });
        let (gathered, mut received, counts) = outcome?;
        if let Some(j) = too_large {
            return Err(self.failure(format!(
                "{} bytes to rank {j}: too large for MPI",
                parts[j].len()
            )));
        }
        if let Some(j) = gathered.too_large {
            return Err(self.failure(format!(
                "rank {j} had a part too large for MPI in an all-to-all"
            )));
        }
        for (j, count) in counts {
            let len = gathered.incoming[j];
            if usize::try_from(count).ok() != Some(len) {
                return Err(self.failure(format!("rank {j} sent {count} bytes, {len} expected")));
            }
        }
        self.sent.collective();
        let mut heads = gathered.heads;
        heads[me] = head;
        received[me] = std::mem::take(&mut parts[me]);
        Ok((heads, received))
    }

    /// **Point to point**: an `MPI_Isend` to each peer of `sends` and an
    /// `MPI_Irecv` from each peer of `recvs` (tag [`EXCHANGE_TAG`]; MPI keeps
    /// messages with one source, tag and communicator in order), then
    /// `overlap` runs while they travel, then each is completed by polling.
    /// The lengths are known to both sides, so no length travels first.
    /// The words go as `MPI_DOUBLE` from the caller's buffer and arrive in
    /// the one returned: no byte copy on either side, and MPI moves a
    /// contiguous predefined type between ranks of one byte order as it
    /// is, bit for bit (`tests/mpi_transport.rs` sends NaN payloads,
    /// signed zeros and subnormals).
    fn exchange(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, RankFailure> {
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
                self.failure(format!("{len} words from rank {j}: too large for MPI"))
            })?;
        }
        for (j, words) in &sends {
            peer(*j)?;
            Count::try_from(words.len()).map_err(|_| {
                self.failure(format!(
                    "{} words to rank {j}: too large for MPI",
                    words.len()
                ))
            })?;
        }
        let mut received: Vec<Vec<f64>> = recvs.iter().map(|&(_, n)| vec![0.0; n]).collect();
        let counts = mpi::request::scope(|scope| {
            let mut sent = Vec::with_capacity(sends.len());
            for (j, words) in &sends {
                let world = self.mpi_call().world();
                sent.push(
                    world
                        .process_at_rank(*j as mpi::Rank)
                        .immediate_send_with_tag(scope, &words[..], EXCHANGE_TAG),
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
                .map(|request| self.complete(request).count(f64::equivalent_datatype()))
                .collect();
            for request in sent {
                self.complete(request);
            }
            counts
        });
        for (&(j, len), count) in recvs.iter().zip(counts) {
            if usize::try_from(count).ok() != Some(len) {
                return Err(self.failure(format!("rank {j} sent {count} words, {len} expected")));
            }
        }
        for (_, words) in &sends {
            self.sent.add(1, 8 * words.len() as u64);
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

/// The tag of the collectives' rounds ([`dissemination`]).
pub const ROUND_TAG: mpi::Tag = 9;

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
