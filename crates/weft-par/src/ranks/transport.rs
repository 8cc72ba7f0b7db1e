//! How ranks talk: the collectives and exchanges the distributed executor
//! needs, and their in-process implementation over channels.
//!
//! The [`crate::Ranks`] executor communicates in three ways:
//!
//! * [`Transport::all_gather`]: every rank contributes a byte string and
//!   receives every rank's, in rank order. It is a **collective**: every rank
//!   must call it the same number of times, in the same order (the engine's
//!   control flow is the same on every rank because every rank holds the same
//!   state).
//! * [`Transport::all_to_all`]: a **collective** in which every rank hands
//!   every rank a few words (its *head*, the same for all) and each peer its
//!   own byte string, empty ones sending nothing: what a rank computed for
//!   the vertices another rank keeps, with what every rank must agree on.
//!
//! Both collectives gather in `⌈log2 R⌉` rounds of point-to-point messages
//! ([`super::dissemination`]), not `R - 1` messages each way.
//! * [`Transport::exchange`]: **point to point** between neighbours — byte
//!   strings to some peers, from some peers, with work run while they travel.
//!   Only the ranks named take part, each at the same point of its run.
//!
//! The MPI transport (feature `mpi`) implements the same trait with
//! nonblocking MPI point-to-point operations.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::sync::{Arc, Mutex};

use super::dissemination;

/// What an all-to-all brings a rank: every rank's head, in rank order, and
/// the part each rank addressed to it.
pub type HeadsAndParts = (Vec<Vec<u64>>, Vec<Vec<u8>>);

/// A rank that stopped answering (it failed, or its process is gone).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("rank {rank}: {what}")]
pub struct RankFailure {
    /// The rank that noticed.
    pub rank: usize,
    pub what: String,
}

impl From<RankFailure> for weft_sim::CommError {
    fn from(e: RankFailure) -> Self {
        weft_sim::CommError(e.to_string())
    }
}

pub use weft_sim::Traffic;

/// Counters a transport keeps of what it sent.
#[derive(Debug, Default)]
pub struct TrafficCounter {
    messages: AtomicU64,
    bytes: AtomicU64,
    collectives: AtomicU64,
    exchanges: AtomicU64,
    wait_cpu_ns: AtomicU64,
}

impl TrafficCounter {
    /// Counts `messages` messages of `bytes` payload bytes in all.
    pub fn add(&self, messages: u64, bytes: u64) {
        self.messages.fetch_add(messages, Ordering::Relaxed);
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    /// Counts one collective this rank took part in.
    pub fn collective(&self) {
        self.collectives.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts one point-to-point exchange with at least one peer.
    pub fn exchange(&self) {
        self.exchanges.fetch_add(1, Ordering::Relaxed);
    }

    /// Runs `wait` (a rank waiting for its peers) and counts the CPU time
    /// the calling thread spent in it as polling, not work.
    pub fn waiting<R>(&self, wait: impl FnOnce() -> R) -> R {
        let start = weft_sim::cpu::thread_seconds();
        let r = wait();
        let ns = ((weft_sim::cpu::thread_seconds() - start) * 1e9).max(0.0);
        self.wait_cpu_ns.fetch_add(ns as u64, Ordering::Relaxed);
        r
    }

    /// What was counted so far.
    pub fn total(&self) -> Traffic {
        Traffic {
            messages: self.messages.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            collectives: self.collectives.load(Ordering::Relaxed),
            exchanges: self.exchanges.load(Ordering::Relaxed),
            wait_cpu_ns: self.wait_cpu_ns.load(Ordering::Relaxed),
        }
    }
}

/// The communication between ranks.
pub trait Transport: Send + Sync {
    /// This rank, `0..size()`.
    fn rank(&self) -> usize;

    /// The number of ranks.
    fn size(&self) -> usize;

    /// **Collective.** Every rank passes `mine`; each gets all ranks' byte
    /// strings in rank order (its own included). An error means a peer is
    /// gone: the run cannot go on.
    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure>;

    /// **Collective.** Every rank passes `head` (as many words on every
    /// rank) and `parts`, one byte string per rank (`parts[j]` for rank `j`;
    /// its own is kept, not sent). Each gets every rank's head in rank order,
    /// and the part each rank addressed to it (its own `parts[rank]` in its
    /// place). An empty part sends no message: the heads and the lengths of
    /// the non-empty parts are all-gathered, the parts travel point to
    /// point. While this rank
    /// waits for the others' heads and parts (its own on their way),
    /// `overlap` runs pieces of work that need none of them, one per call,
    /// until it returns `false` (no piece left) or everything has arrived;
    /// the pieces left are the caller's. It must not communicate.
    fn all_to_all(
        &self,
        head: Vec<u64>,
        parts: Vec<Vec<u8>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<HeadsAndParts, RankFailure>;

    /// **Point to point.** Starts sending the words `sends[k].1` to rank
    /// `sends[k].0` and receiving `recvs[k].1` words from rank `recvs[k].0`,
    /// runs `overlap` while they travel, then completes them; returns the
    /// received words in `recvs` order, with their exact bits. The caller's
    /// words are sent where they lie (no byte copy: the narrow phase's
    /// trajectories, the largest exchange, were held twice at a rank's
    /// peak). Every
    /// peer named must make the matching call (what `i` sends to `j` is what
    /// `j` receives from `i`, the same length) at the same point of its run;
    /// messages between two ranks arrive in the order they were sent. An
    /// error means a peer is gone or broke that contract. Traffic counts 8
    /// bytes a word.
    fn exchange(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, RankFailure>;

    /// Messages and bytes this rank sent so far.
    fn traffic(&self) -> Traffic;

    /// CPU seconds this rank has used ([`weft_sim::Executor::cpu_seconds`]):
    /// its process's, where it is a process of its own.
    fn cpu_seconds(&self) -> f64 {
        weft_sim::cpu::process_seconds()
    }
}

/// A borrowed transport: lets a caller keep its transport (to abort, or to
/// finalize MPI after the engine is gone) while an executor uses it.
impl<T: Transport + ?Sized> Transport for &T {
    fn rank(&self) -> usize {
        (**self).rank()
    }

    fn size(&self) -> usize {
        (**self).size()
    }

    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure> {
        (**self).all_gather(mine)
    }

    fn all_to_all(
        &self,
        head: Vec<u64>,
        parts: Vec<Vec<u8>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<HeadsAndParts, RankFailure> {
        (**self).all_to_all(head, parts, overlap)
    }

    fn exchange(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, RankFailure> {
        (**self).exchange(sends, recvs, overlap)
    }

    fn traffic(&self) -> Traffic {
        (**self).traffic()
    }

    fn cpu_seconds(&self) -> f64 {
        (**self).cpu_seconds()
    }
}

/// One communication step of a rank, as a replay under a network model
/// needs it (`weft bench --project`): the work before it and what it moved.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SyncStep {
    /// The rank's work (thread CPU, polling left out) since the start of
    /// its previous step, in nanoseconds: what it computed before this step
    /// could begin, including the work overlapped with the previous one.
    pub work_ns: u64,
    /// A collective (every rank takes part: an all-gather, or an
    /// all-to-all when `head_bytes` is set); else a point-to-point exchange.
    pub collective: bool,
    /// An all-to-all: the bytes of this rank's block of the gathered heads
    /// (its head and its parts' lengths; it differs between ranks).
    pub head_bytes: Option<u64>,
    /// All-gather: this rank's part, in bytes. All-to-all and exchange: the
    /// bytes sent, per peer.
    pub sent: Vec<(u32, u64)>,
    /// All-to-all and exchange: the bytes received, per peer, in the order
    /// received.
    pub received: Vec<(u32, u64)>,
    /// Where the rank was when it began the step
    /// ([`weft_sim::trace::site`]; "" outside every site).
    pub site: &'static str,
}

/// `overlap` (one piece of work per call, `false` once none is left) as
/// a wait's work: each call runs a piece and says whether it ran one, and
/// `overlap` is not called again once it said none is left.
pub(crate) fn pieces(overlap: &mut dyn FnMut() -> bool) -> impl FnMut() -> bool + '_ {
    let mut more = true;
    move || {
        let ran = more;
        if more {
            more = overlap();
        }
        ran
    }
}

/// Where a rank's [`SyncStep`]s go while they are recorded.
pub type StepSink = Arc<Mutex<Vec<SyncStep>>>;

/// The recording of a rank's steps: the sink and the work at the start of
/// the last step.
#[derive(Debug)]
struct StepLog {
    sink: StepSink,
    mark_ns: u64,
}

/// One message between two ranks of a [`ChannelTransport`]: the bytes of a
/// collective, or the words of an exchange, moved as they are.
#[derive(Debug)]
enum Payload {
    Bytes(Vec<u8>),
    Words(Vec<f64>),
}

/// Where a rank receives one peer's messages.
type Inbox = Mutex<Receiver<Payload>>;

/// Ranks that are threads of one process, connected by channels: each rank
/// has its own memory, and everything it learns from a peer comes as a
/// message. A rank that ends (returns, errs or panics) drops its senders, so
/// its peers' next receive fails instead of hanging.
pub struct ChannelTransport {
    rank: usize,
    /// `to[j]` sends to rank `j` (none to itself).
    to: Vec<Option<Sender<Payload>>>,
    /// `from[j]` receives from rank `j`: one channel per pair keeps each
    /// sender's messages in order, so the k-th message from `j` is `j`'s part
    /// of the k-th collective.
    from: Vec<Option<Inbox>>,
    sent: TrafficCounter,
    /// The steps being recorded, if any ([`ChannelTransport::record_steps`]).
    steps: Mutex<Option<StepLog>>,
}

impl ChannelTransport {
    /// `ranks` connected transports, one per rank (index = rank).
    pub fn connected(ranks: usize) -> Vec<ChannelTransport> {
        let ranks = ranks.max(1);
        let mut to: Vec<Vec<Option<Sender<Payload>>>> = (0..ranks)
            .map(|_| (0..ranks).map(|_| None).collect())
            .collect();
        let mut from: Vec<Vec<Option<Inbox>>> = (0..ranks)
            .map(|_| (0..ranks).map(|_| None).collect())
            .collect();
        for a in 0..ranks {
            for b in 0..ranks {
                if a != b {
                    let (s, r) = channel();
                    to[a][b] = Some(s);
                    from[b][a] = Some(Mutex::new(r));
                }
            }
        }
        to.into_iter()
            .zip(from)
            .enumerate()
            .map(|(rank, (to, from))| ChannelTransport {
                rank,
                to,
                from,
                sent: TrafficCounter::default(),
                steps: Mutex::new(None),
            })
            .collect()
    }

    /// From now on, appends every collective and exchange of this rank to
    /// `sink` as a [`SyncStep`] (the work is this thread's CPU: one thread
    /// per rank).
    pub fn record_steps(&self, sink: StepSink) {
        let mark_ns = self.work_ns();
        *self.steps.lock().expect("the step log") = Some(StepLog { sink, mark_ns });
    }

    /// This thread's CPU less the polling counted so far, in nanoseconds.
    fn work_ns(&self) -> u64 {
        let cpu = (weft_sim::cpu::thread_seconds() * 1e9) as u64;
        cpu.saturating_sub(self.sent.total().wait_cpu_ns)
    }

    /// Records a step that begins now, if steps are recorded.
    fn step(
        &self,
        collective: bool,
        head_bytes: Option<u64>,
        sent: Vec<(u32, u64)>,
        received: Vec<(u32, u64)>,
    ) {
        let mut log = self.steps.lock().expect("the step log");
        if let Some(log) = log.as_mut() {
            let now = self.work_ns();
            let work_ns = now.saturating_sub(log.mark_ns);
            log.mark_ns = now;
            log.sink.lock().expect("the step sink").push(SyncStep {
                work_ns,
                collective,
                head_bytes,
                sent,
                received,
                site: weft_sim::trace::current_site(),
            });
        }
    }
}

impl ChannelTransport {
    /// Completes the step recorded last with what it received (an
    /// all-to-all learns it only as its parts arrive).
    fn step_received(&self, received: Vec<(u32, u64)>) {
        let log = self.steps.lock().expect("the step log");
        if let Some(log) = log.as_ref() {
            let mut sink = log.sink.lock().expect("the step sink");
            if let Some(last) = sink.last_mut() {
                last.received = received;
            }
        }
    }

    fn gone(&self, j: usize) -> RankFailure {
        RankFailure {
            rank: self.rank,
            what: format!("rank {j} is gone (its channel closed)"),
        }
    }

    /// The end of a channel with rank `j` in `ends` (`to` or `from`).
    fn end<'a, C>(&self, ends: &'a [Option<C>], j: usize) -> Result<&'a C, RankFailure> {
        ends.get(j)
            .and_then(Option::as_ref)
            .ok_or_else(|| RankFailure {
                rank: self.rank,
                what: format!("no channel with rank {j}"),
            })
    }

    /// Sends `bytes` to rank `j` (not this rank).
    fn send(&self, j: usize, bytes: Vec<u8>) -> Result<(), RankFailure> {
        let len = bytes.len() as u64;
        self.send_payload(j, Payload::Bytes(bytes), len)
    }

    /// Sends `payload` (`len` bytes) to rank `j` (not this rank).
    fn send_payload(&self, j: usize, payload: Payload, len: u64) -> Result<(), RankFailure> {
        let to = self.end(&self.to, j)?;
        to.send(payload).map_err(|_| self.gone(j))?;
        self.sent.add(1, len);
        Ok(())
    }

    /// The next message from rank `j` (not this rank), waiting for it. A
    /// message already there is taken without reading the CPU clock (two
    /// system calls, which at 32 ranks cost more than most messages' work);
    /// only a wait is timed and counted as polling.
    fn receive(&self, j: usize) -> Result<Vec<u8>, RankFailure> {
        self.receive_while(j, &mut || false)
    }

    /// [`Self::receive`], running `work` while the message has not come,
    /// for as long as it runs a piece ([`pieces`]).
    fn receive_while(
        &self,
        j: usize,
        work: &mut dyn FnMut() -> bool,
    ) -> Result<Vec<u8>, RankFailure> {
        match self.receive_payload(j, work)? {
            Payload::Bytes(bytes) => Ok(bytes),
            Payload::Words(_) => Err(self.out_of_step(j)),
        }
    }

    /// The next message from rank `j`, of either kind ([`Self::receive_while`]).
    fn receive_payload(
        &self,
        j: usize,
        work: &mut dyn FnMut() -> bool,
    ) -> Result<Payload, RankFailure> {
        let from = self.end(&self.from, j)?;
        let inbox = from.lock().map_err(|_| self.gone(j))?;
        loop {
            match inbox.try_recv() {
                Ok(payload) => return Ok(payload),
                Err(TryRecvError::Disconnected) => return Err(self.gone(j)),
                Err(TryRecvError::Empty) if work() => {}
                Err(TryRecvError::Empty) => {
                    return self.sent.waiting(|| inbox.recv()).map_err(|_| self.gone(j));
                }
            }
        }
    }

    /// Rank `j`'s next message is of the other kind: an exchange where a
    /// collective was expected, or the reverse.
    fn out_of_step(&self, j: usize) -> RankFailure {
        RankFailure {
            rank: self.rank,
            what: format!("rank {j} is out of step (an exchange met a collective)"),
        }
    }
}

impl Transport for ChannelTransport {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.to.len()
    }

    /// Bruck's all-gather ([`dissemination`]): `⌈log2 R⌉` rounds, one
    /// message each way a round.
    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure> {
        self.sent.collective();
        self.step(
            true,
            None,
            vec![(self.rank as u32, mine.len() as u64)],
            Vec::new(),
        );
        dissemination::all_gather(self.rank, self.size(), mine, &mut |to, bytes, from| {
            self.send(to, bytes)?;
            self.receive(from)
        })
    }

    /// The heads (with the lengths of the non-empty parts) gathered in
    /// `⌈log2 R⌉` rounds ([`dissemination`]), then each non-empty part as a
    /// message of its own. Channels buffer: the sends complete at once;
    /// each receive runs `overlap`'s pieces while its message has not come.
    /// A pair's channel carries its round message before its part, the
    /// order in which the receiver takes them.
    fn all_to_all(
        &self,
        head: Vec<u64>,
        mut parts: Vec<Vec<u8>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<HeadsAndParts, RankFailure> {
        let n = self.size();
        if parts.len() != n {
            return Err(RankFailure {
                rank: self.rank,
                what: format!("an all-to-all with {} parts for {n} ranks", parts.len()),
            });
        }
        self.sent.collective();
        let others = |lens: &mut dyn Iterator<Item = (usize, usize)>| -> Vec<(u32, u64)> {
            lens.filter(|&(j, len)| j != self.rank && len > 0)
                .map(|(j, len)| (j as u32, len as u64))
                .collect()
        };
        let block = dissemination::head_block(self.rank, &head, &parts, false);
        self.step(
            true,
            Some(block.len() as u64),
            others(&mut parts.iter().map(Vec::len).enumerate()),
            Vec::new(),
        );
        // While steps are recorded, no work runs in the wait: the replay
        // (`weft bench --project`) credits no overlap of work with a
        // collective, and work run in a wait would land in whichever
        // interval the machine's scheduling of the ranks chose (with more
        // ranks than cores, a rank that ran first does its next internal
        // tick's calm part while the others catch up, and the intervals'
        // imbalance is the scheduler's, not the engine's).
        let recording = self.steps.lock().expect("the step log").is_some();
        let mut nothing = || false;
        let overlap: &mut dyn FnMut() -> bool = if recording { &mut nothing } else { overlap };
        let mut overlap = pieces(overlap);
        let blocks = dissemination::all_gather(self.rank, n, block, &mut |to, bytes, from| {
            self.send(to, bytes)?;
            self.receive_while(from, &mut overlap)
        })?;
        let mut gathered = dissemination::read_heads(self.rank, head.len(), &blocks)?;
        if let Some(j) = gathered.too_large {
            // (Channels take parts of any length: only a peer on another
            // transport's rules would flag one.)
            return Err(RankFailure {
                rank: self.rank,
                what: format!("rank {j} had a part too large for its transport"),
            });
        }
        for j in (0..n).filter(|&j| j != self.rank) {
            if !parts[j].is_empty() {
                self.send(j, std::mem::take(&mut parts[j]))?;
            }
        }
        let mut received = vec![Vec::new(); n];
        for j in (0..n).filter(|&j| j != self.rank) {
            let len = gathered.incoming[j];
            if len > 0 {
                received[j] = self.receive_while(j, &mut overlap)?;
                if received[j].len() != len {
                    return Err(RankFailure {
                        rank: self.rank,
                        what: format!("rank {j} sent {} bytes, {len} expected", received[j].len()),
                    });
                }
            }
        }
        self.step_received(others(&mut gathered.incoming.iter().copied().enumerate()));
        gathered.heads[self.rank] = head;
        received[self.rank] = std::mem::take(&mut parts[self.rank]);
        Ok((gathered.heads, received))
    }

    fn exchange(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, RankFailure> {
        // Channels buffer: the sends complete at once, the work runs, then
        // the receives wait for what the peers sent.
        if !sends.is_empty() || !recvs.is_empty() {
            self.sent.exchange();
        }
        self.step(
            false,
            None,
            (sends.iter())
                .map(|(j, w)| (*j as u32, 8 * w.len() as u64))
                .collect(),
            (recvs.iter())
                .map(|&(j, n)| (j as u32, 8 * n as u64))
                .collect(),
        );
        for (j, words) in sends {
            let len = 8 * words.len() as u64;
            self.send_payload(j, Payload::Words(words), len)?;
        }
        overlap();
        recvs
            .iter()
            .map(|&(j, n)| {
                let Payload::Words(words) = self.receive_payload(j, &mut || false)? else {
                    return Err(self.out_of_step(j));
                };
                if words.len() != n {
                    return Err(RankFailure {
                        rank: self.rank,
                        what: format!("rank {j} sent {} words, {n} expected", words.len()),
                    });
                }
                Ok(words)
            })
            .collect()
    }

    fn traffic(&self) -> Traffic {
        self.sent.total()
    }

    /// A rank that is a thread of the process: its own thread's CPU (its
    /// work with one thread per rank).
    fn cpu_seconds(&self) -> f64 {
        weft_sim::cpu::thread_seconds()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `body(transport)` on one thread per rank of `transports`; the results
    /// in rank order.
    fn on_each_rank<R: Send>(
        transports: &[ChannelTransport],
        body: impl Fn(&ChannelTransport) -> R + Sync,
    ) -> Vec<R> {
        std::thread::scope(|s| {
            let handles: Vec<_> = transports.iter().map(|t| s.spawn(|| body(t))).collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        })
    }

    #[test]
    fn every_rank_gets_every_part_in_rank_order_and_a_lost_rank_is_an_error() {
        let transports = ChannelTransport::connected(3);
        let results = on_each_rank(&transports, |t| {
            (0..5)
                .map(|round| {
                    let mine = vec![t.rank() as u8; round + t.rank()];
                    t.all_gather(mine).unwrap()
                })
                .collect::<Vec<_>>()
        });
        for rounds in &results {
            for (round, all) in rounds.iter().enumerate() {
                for (j, part) in all.iter().enumerate() {
                    assert_eq!(part, &vec![j as u8; round + j]);
                }
            }
        }
        assert_eq!(transports[1].traffic().messages, 10);

        let mut transports = ChannelTransport::connected(2);
        let last = transports.pop().unwrap();
        drop(last);
        let err = transports[0].all_gather(vec![1]).unwrap_err();
        assert!(err.to_string().contains("rank 1 is gone"), "{err}");
    }

    /// A rank waiting in an all-to-all runs the pieces of work it is
    /// offered, unless it records its steps (the replay credits no overlap,
    /// and what runs in a wait would follow the machine's scheduling).
    #[test]
    fn a_recording_rank_runs_no_work_in_an_all_to_alls_wait() {
        let transports = ChannelTransport::connected(2);
        transports[1].record_steps(StepSink::default());
        let pieces = on_each_rank(&transports, |t| {
            let r = t.rank();
            (0..2)
                .map(|round| {
                    // Each round, the other rank comes late: the waiting
                    // one has pieces to run (ten at most).
                    if r != round {
                        std::thread::sleep(std::time::Duration::from_millis(50));
                    }
                    let mut ran = 0;
                    let mut overlap = || {
                        ran += 1;
                        ran < 10
                    };
                    t.all_to_all(vec![], vec![vec![1], vec![2]], &mut overlap)
                        .unwrap();
                    ran
                })
                .collect::<Vec<_>>()
        });
        // Rank 0 waited in round 0 and ran pieces; rank 1, recording,
        // waited in round 1 and ran none.
        assert!(pieces[0][0] > 0, "{pieces:?}");
        assert_eq!(pieces[1], [0, 0], "{pieces:?}");
    }

    #[test]
    fn all_to_all_hands_each_rank_its_part_and_every_head() {
        // Rank r sends rank j (r + j) % 3 bytes of value 10 r + j (none when
        // 0), with a head [r, round]; an all-gather between rounds keeps
        // them apart.
        let transports = ChannelTransport::connected(3);
        let sink: StepSink = Arc::default();
        transports[1].record_steps(sink.clone());
        let results = on_each_rank(&transports, |t| {
            let r = t.rank();
            (0..3u64)
                .map(|round| {
                    let parts = (0..3)
                        .map(|j| vec![(10 * r + j) as u8; (r + j + round as usize) % 3])
                        .collect();
                    // Pieces of work run while the others' messages have
                    // not come, at most the three offered.
                    let mut overlapped = 0;
                    let mut overlap = || {
                        overlapped += 1;
                        overlapped < 3
                    };
                    let got = (t.all_to_all(vec![r as u64, round], parts, &mut overlap)).unwrap();
                    assert!(overlapped <= 3, "{overlapped} pieces");
                    // (Rank 1 records its steps: it runs nothing in a wait.)
                    assert!(r != 1 || overlapped == 0, "{overlapped} pieces on rank 1");
                    t.all_gather(vec![r as u8]).unwrap();
                    got
                })
                .collect::<Vec<_>>()
        });
        for (r, rounds) in results.iter().enumerate() {
            for (round, (heads, parts)) in rounds.iter().enumerate() {
                for j in 0..3 {
                    assert_eq!(heads[j], vec![j as u64, round as u64]);
                    let len = (j + r + round) % 3;
                    assert_eq!(parts[j], vec![(10 * j + r) as u8; len], "{r} from {j}");
                }
            }
        }
        // Rank 1's first step, as recorded: its block of the heads (the
        // flag, the word count, two words, one part and its peer and
        // length); a byte to rank 0 and one from it (its parts with rank 2
        // are empty, and nothing travels for them).
        let steps = sink.lock().unwrap();
        let first = &steps[0];
        assert!(first.collective);
        assert_eq!(first.head_bytes, Some(8 * 7));
        assert_eq!(first.sent, vec![(0, 1)]);
        assert_eq!(first.received, vec![(0, 1)]);
        // a part list of the wrong length is an error
        let transports = ChannelTransport::connected(2);
        let err = transports[0]
            .all_to_all(vec![], vec![vec![]], &mut || false)
            .unwrap_err();
        assert!(err.to_string().contains("1 parts for 2 ranks"), "{err}");
    }

    #[test]
    fn collectives_on_many_ranks_carry_several_blocks_a_round_and_keep_parts_apart() {
        // 11 ranks: Bruck's rounds d = 1, 2, 4, 8 carry 1, 2, 4 and 3
        // blocks. Rank r sends rank j a part of (r * j + round) % 4 bytes
        // (some empty), with a head of r and the round, and exchanges with
        // its ring neighbours between the collectives, so that a pair's
        // channel carries round messages, parts and exchanges in turn.
        let n = 11;
        let transports = ChannelTransport::connected(n);
        let results = on_each_rank(&transports, |t| {
            let r = t.rank();
            (0..4usize)
                .map(|round| {
                    let parts = (0..n)
                        .map(|j| vec![(r + 16 * j) as u8; (r * j + round) % 4])
                        .collect();
                    let got = t
                        .all_to_all(vec![r as u64, round as u64], parts, &mut || false)
                        .unwrap();
                    let (next, prev) = ((r + 1) % n, (r + n - 1) % n);
                    let ring = t
                        .exchange(vec![(next, vec![r as f64; 3])], &[(prev, 3)], &mut || {})
                        .unwrap();
                    assert_eq!(ring, vec![vec![prev as f64; 3]]);
                    let all = t.all_gather(vec![r as u8; (r + round) % 3]).unwrap();
                    (got, all)
                })
                .collect::<Vec<_>>()
        });
        for (r, rounds) in results.iter().enumerate() {
            for (round, ((heads, parts), all)) in rounds.iter().enumerate() {
                for j in 0..n {
                    assert_eq!(heads[j], vec![j as u64, round as u64]);
                    let len = (j * r + round) % 4;
                    assert_eq!(parts[j], vec![(j + 16 * r) as u8; len], "{r} from {j}");
                    assert_eq!(all[j], vec![j as u8; (j + round) % 3]);
                }
            }
        }
        // Two collectives and an exchange a round: 4 messages a gather,
        // the ring's one, and the non-empty parts to others.
        for (r, t) in transports.iter().enumerate() {
            let parts: u64 = (0..4usize)
                .map(|round| {
                    (0..n)
                        .filter(|&j| j != r && (r * j + round) % 4 > 0)
                        .count() as u64
                })
                .sum();
            assert_eq!(t.traffic().messages, 4 * (4 + 4 + 1) + parts, "rank {r}");
        }
    }

    #[test]
    fn exchanges_reach_their_peers_in_order_between_collectives() {
        // A ring: rank r sends round-dependent words to r + 1 and receives
        // from r - 1, with an all-gather between the exchanges; the overlap
        // runs once per exchange.
        let transports = ChannelTransport::connected(3);
        let results = on_each_rank(&transports, |t| {
            let (r, n) = (t.rank(), t.size());
            let (next, prev) = ((r + 1) % n, (r + n - 1) % n);
            let mut overlaps = 0;
            let mut got = Vec::new();
            for round in 0..4usize {
                let mine = vec![(10 * r + round) as f64; r + round];
                let len = prev + round;
                let recv = t
                    .exchange(vec![(next, mine)], &[(prev, len)], &mut || overlaps += 1)
                    .unwrap();
                got.push(recv[0].clone());
                t.all_gather(vec![r as u8]).unwrap();
            }
            (prev, overlaps, got)
        });
        for (prev, overlaps, got) in results {
            assert_eq!(overlaps, 4);
            for (round, words) in got.iter().enumerate() {
                assert_eq!(words, &vec![(10 * prev + round) as f64; prev + round]);
            }
        }
        // a wrong length is an error, not a silent misread
        let transports = ChannelTransport::connected(2);
        std::thread::scope(|s| {
            let t1 = &transports[1];
            s.spawn(move || {
                t1.exchange(vec![(0, vec![1.0, 2.0, 3.0])], &[], &mut || {})
                    .unwrap()
            });
            let err = transports[0]
                .exchange(vec![], &[(1, 2)], &mut || {})
                .unwrap_err();
            assert!(err.to_string().contains("3 words, 2 expected"), "{err}");
        });
        // an exchange that meets a collective is an error, not a misread
        let transports = ChannelTransport::connected(2);
        std::thread::scope(|s| {
            let t1 = &transports[1];
            s.spawn(move || t1.exchange(vec![(0, vec![1.0])], &[], &mut || {}).unwrap());
            let err = transports[0].all_gather(vec![0u8]).unwrap_err();
            assert!(err.to_string().contains("out of step"), "{err}");
        });
        let mut transports = ChannelTransport::connected(2);
        let last = transports.pop().unwrap();
        drop(last);
        let err = transports[0]
            .exchange(vec![], &[(1, 4)], &mut || {})
            .unwrap_err();
        assert!(err.to_string().contains("rank 1 is gone"), "{err}");
    }
}
