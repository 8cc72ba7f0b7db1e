//! How ranks talk: the one collective the distributed executor needs, and its
//! in-process implementation over channels.
//!
//! [`Transport::all_gather`] is the only communication the [`crate::Ranks`]
//! executor does: every rank contributes a byte string and receives every
//! rank's, in rank order. It is a **collective**: every rank must call it the
//! same number of times, in the same order (the engine's control flow is the
//! same on every rank because every rank holds the same state). The MPI
//! transport (feature `mpi`) implements the same trait with nonblocking MPI
//! operations.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Mutex;

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
}

impl TrafficCounter {
    /// Counts `messages` messages of `bytes` payload bytes in all.
    pub fn add(&self, messages: u64, bytes: u64) {
        self.messages.fetch_add(messages, Ordering::Relaxed);
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    /// What was counted so far.
    pub fn total(&self) -> Traffic {
        Traffic {
            messages: self.messages.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
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

    /// Messages and bytes this rank sent so far.
    fn traffic(&self) -> Traffic;
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

    fn traffic(&self) -> Traffic {
        (**self).traffic()
    }
}

/// Where a rank receives one peer's messages.
type Inbox = Mutex<Receiver<Vec<u8>>>;

/// Ranks that are threads of one process, connected by channels: each rank
/// has its own memory, and everything it learns from a peer comes as a
/// message. A rank that ends (returns, errs or panics) drops its senders, so
/// its peers' next receive fails instead of hanging.
pub struct ChannelTransport {
    rank: usize,
    /// `to[j]` sends to rank `j` (none to itself).
    to: Vec<Option<Sender<Vec<u8>>>>,
    /// `from[j]` receives from rank `j`: one channel per pair keeps each
    /// sender's messages in order, so the k-th message from `j` is `j`'s part
    /// of the k-th collective.
    from: Vec<Option<Inbox>>,
    sent: TrafficCounter,
}

impl ChannelTransport {
    /// `ranks` connected transports, one per rank (index = rank).
    pub fn connected(ranks: usize) -> Vec<ChannelTransport> {
        let ranks = ranks.max(1);
        let mut to: Vec<Vec<Option<Sender<Vec<u8>>>>> = (0..ranks)
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
            })
            .collect()
    }
}

impl Transport for ChannelTransport {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.to.len()
    }

    fn all_gather(&self, mine: Vec<u8>) -> Result<Vec<Vec<u8>>, RankFailure> {
        let gone = |j: usize| RankFailure {
            rank: self.rank,
            what: format!("rank {j} is gone (its channel closed)"),
        };
        for (j, to) in self.to.iter().enumerate() {
            if let Some(to) = to {
                to.send(mine.clone()).map_err(|_| gone(j))?;
                self.sent.add(1, mine.len() as u64);
            }
        }
        let mut all = Vec::with_capacity(self.to.len());
        for (j, from) in self.from.iter().enumerate() {
            match from {
                None => all.push(Vec::new()),
                Some(from) => {
                    let received = from
                        .lock()
                        .map_err(|_| gone(j))?
                        .recv()
                        .map_err(|_| gone(j))?;
                    all.push(received);
                }
            }
        }
        all[self.rank] = mine;
        Ok(all)
    }

    fn traffic(&self) -> Traffic {
        self.sent.total()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rank_gets_every_part_in_rank_order_and_a_lost_rank_is_an_error() {
        let transports = ChannelTransport::connected(3);
        let results: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = transports
                .iter()
                .map(|t| {
                    s.spawn(move || {
                        (0..5)
                            .map(|round| {
                                let mine = vec![t.rank() as u8; round + t.rank()];
                                t.all_gather(mine).unwrap()
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
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
}
