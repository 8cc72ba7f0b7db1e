//! The `Ranks` executor: one rank of a run spread over ranks that share no
//! memory, talking only through a [`Transport`].
//!
//! Between passes every rank holds every vertex's position and velocity
//! (trajectory breakpoints only for the vertices it owns; within a pass it
//! keeps current only the vertices it owns or reads, `weft_sim::share`) and
//! runs the engine's control flow; the heavy stages are spread: a rank evaluates the internal forces of
//! the partitions placed on it, the penalty closest points and kicks of its
//! contact islands, the broad phase's DOPs of the vertices it holds and the
//! traversals of its partitions, the narrow-phase tasks
//! the locality-aware balancer gives it (Algorithm 2 of the paper), and the
//! retirement certificates of the stencils whose first vertex it holds. The
//! contact islands' results, the new velocities of an internal tick and the
//! broad phase's vertex DOPs go only where they are read
//! ([`Executor::all_to_all`]); after each other stage one all-gather hands
//! every rank every result, so every rank
//! applies the same values in the same order — and every rank's state, and
//! the result, has the same bits as on one memory. The exchanges that are not
//! collectives ([`Executor::exchange_words`], point to point) carry the
//! internal forces' boundary slots to the neighbouring ranks that fold them,
//! overlapped with the interior partitions (Algorithm 1), and the polylines
//! a task reads from the ranks that hold them. The rollback decision needs no
//! extra reduction: every rank sees every narrow-phase answer.
//!
//! Within a rank, the rank's own share runs on a local executor (threads).

use glam::DVec3;
use weft_sim::{CommError, Executor, Message, Serial};

use super::transport::{ChannelTransport, Traffic, Transport};

/// One rank: a transport to its peers and a local executor for its share.
pub struct Ranks<T: Transport, E: Executor = Serial> {
    transport: T,
    local: E,
}

impl<T: Transport, E: Executor> Ranks<T, E> {
    /// This rank of `transport`'s ranks, running its share on `local`.
    pub fn new(transport: T, local: E) -> Self {
        Self { transport, local }
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The local executor.
    pub fn local(&self) -> &E {
        &self.local
    }

    fn encode<R: serde::Serialize + ?Sized>(&self, value: &R) -> Result<Vec<u8>, CommError> {
        postcard::to_allocvec(value).map_err(|e| {
            CommError(format!(
                "rank {}: cannot encode a message: {e}",
                self.rank()
            ))
        })
    }

    fn decode<R: Message>(&self, from: usize, bytes: &[u8]) -> Result<R, CommError> {
        postcard::from_bytes(bytes).map_err(|e| {
            CommError(format!(
                "rank {}: the message from rank {from} is malformed: {e}",
                self.rank()
            ))
        })
    }

    fn check_owner(&self, n: usize, owner: &[u32]) -> Result<(), CommError> {
        let size = self.transport.size();
        if owner.len() != n || owner.iter().any(|&r| r as usize >= size) {
            return Err(CommError(format!(
                "rank {}: a work placement names {} items for {n} (ranks 0..{size})",
                self.rank(),
                owner.len()
            )));
        }
        Ok(())
    }

    /// The all-to-alls' common part: each peer's part of `parts` encoded
    /// (`encode`; empty bytes send nothing) and what arrives decoded
    /// (`decode`, with the sender's rank); this rank's own part stays here,
    /// not encoded. One rank: `(vec![head], parts)`.
    fn all_to_all_encoded<P, Encode, Decode>(
        &self,
        head: Vec<u64>,
        parts: Vec<P>,
        overlap: &mut dyn FnMut() -> bool,
        encode: Encode,
        decode: Decode,
    ) -> Result<weft_sim::executor::AddressedParts<P>, CommError>
    where
        Encode: Fn(P) -> Result<Vec<u8>, CommError>,
        Decode: Fn(usize, &[u8]) -> Result<P, CommError>,
    {
        let size = self.transport.size();
        let me = self.rank();
        if parts.len() != size {
            return Err(CommError(format!(
                "rank {me}: an all-to-all with {} parts for {size} ranks",
                parts.len()
            )));
        }
        if size == 1 {
            return Ok((vec![head], parts));
        }
        let mut own = None;
        let mut bytes = Vec::with_capacity(size);
        for (j, part) in parts.into_iter().enumerate() {
            bytes.push(if j == me {
                own = Some(part);
                Vec::new()
            } else {
                encode(part)?
            });
        }
        let (heads, received) = self.transport.all_to_all(head, bytes, overlap)?;
        let mut out = Vec::with_capacity(size);
        for (j, part) in received.into_iter().enumerate() {
            out.push(match j == me {
                true => own.take().expect("this rank's own part"),
                false => decode(j, &part)?,
            });
        }
        Ok((heads, out))
    }
}

impl<T: Transport, E: Executor> Executor for Ranks<T, E> {
    fn for_each_chunk<D: Send>(
        &self,
        data: &mut [D],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [D]) + Sync),
    ) {
        self.local.for_each_chunk(data, bounds, task);
    }

    fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
        self.local.map(n, f)
    }

    fn threads_per_rank(&self) -> usize {
        self.local.threads_per_rank()
    }

    fn name(&self) -> String {
        format!(
            "rank {} of {} ({})",
            self.rank(),
            self.transport.size(),
            self.local.name()
        )
    }

    fn ranks(&self) -> usize {
        self.transport.size()
    }

    fn rank(&self) -> usize {
        self.transport.rank()
    }

    fn traffic(&self) -> Traffic {
        self.transport.traffic()
    }

    fn cpu_seconds(&self) -> f64 {
        self.transport.cpu_seconds()
    }

    fn map_on_ranks<R: Message>(
        &self,
        n: usize,
        owner: &[u32],
        f: &(dyn Fn(usize) -> R + Sync),
    ) -> Result<Vec<R>, CommError> {
        self.check_owner(n, owner)?;
        if self.transport.size() == 1 {
            return Ok(self.local.map(n, f));
        }
        // Each rank's items, ascending, in one walk of `owner` (a walk per
        // rank before: at 32 ranks the walks cost more than the decoding).
        let me = self.rank();
        let mut items: Vec<Vec<usize>> = vec![Vec::new(); self.transport.size()];
        for (i, &r) in owner.iter().enumerate() {
            items[r as usize].push(i);
        }
        let mine = std::mem::take(&mut items[me]);
        let results = self.local.map(mine.len(), &|k| f(mine[k]));
        let parts = self.transport.all_gather(self.encode(&results)?)?;
        let mut slots: Vec<Option<R>> = (0..n).map(|_| None).collect();
        for (j, (part, theirs)) in parts.iter().zip(&items).enumerate() {
            if j == me {
                continue; // placed below, without a decode
            }
            let values: Vec<R> = self.decode(j, part)?;
            if values.len() != theirs.len() {
                return Err(CommError(format!(
                    "rank {me}: rank {j} sent {} results for {} items",
                    values.len(),
                    theirs.len()
                )));
            }
            for (&i, value) in theirs.iter().zip(values) {
                slots[i] = Some(value);
            }
        }
        for (i, value) in mine.into_iter().zip(results) {
            slots[i] = Some(value);
        }
        slots
            .into_iter()
            .map(|s| s.ok_or_else(|| CommError(format!("rank {me}: a result never came"))))
            .collect()
    }

    fn all_to_all<R: Message>(
        &self,
        head: Vec<u64>,
        parts: Vec<Option<R>>,
        overlap: &mut dyn FnMut() -> bool,
    ) -> Result<weft_sim::executor::Addressed<R>, CommError> {
        // A part travels as an encoded `Option` (never empty); `None`, as
        // nothing at all.
        self.all_to_all_encoded(
            head,
            parts,
            overlap,
            |part| match part {
                None => Ok(Vec::new()),
                Some(value) => self.encode(&Some(value)),
            },
            |j, bytes: &[u8]| match bytes.is_empty() {
                true => Ok(None),
                false => self.decode::<Option<R>>(j, bytes),
            },
        )
    }

    fn all_to_all_vectors(
        &self,
        head: Vec<u64>,
        parts: Vec<Vec<DVec3>>,
    ) -> Result<weft_sim::executor::AddressedVectors, CommError> {
        let me = self.rank();
        self.all_to_all_encoded(
            head,
            parts,
            &mut || false,
            |part: Vec<DVec3>| Ok(vector_bytes(&part)),
            |j, bytes: &[u8]| bytes_vectors(me, j, bytes),
        )
    }

    fn chunks_on_ranks<D: Message>(
        &self,
        data: &mut [D],
        bounds: &[usize],
        task: &(dyn Fn(usize, &mut [D]) + Sync),
    ) -> Result<(), CommError> {
        let chunks = bounds.len().saturating_sub(1);
        let sizes = (0..chunks).map(|k| bounds[k + 1] - bounds[k]);
        let owner = weft_sim::executor::place_by_size(sizes, self.transport.size());
        let me = self.rank() as u32;
        self.local.for_each_chunk(data, bounds, &|k, chunk| {
            if owner[k] == me {
                task(k, chunk);
            }
        });
        if self.transport.size() == 1 {
            return Ok(());
        }
        // My chunks, concatenated in chunk order.
        let mine: Vec<&[D]> = (0..chunks)
            .filter(|&k| owner[k] == me)
            .map(|k| &data[bounds[k]..bounds[k + 1]])
            .collect();
        let parts = self.transport.all_gather(self.encode(&mine)?)?;
        for (j, part) in parts.iter().enumerate() {
            if j == me as usize {
                continue;
            }
            let theirs: Vec<usize> = (0..chunks).filter(|&k| owner[k] as usize == j).collect();
            let values: Vec<Vec<D>> = self.decode(j, part)?;
            let fits = values.len() == theirs.len()
                && theirs
                    .iter()
                    .zip(&values)
                    .all(|(&k, v)| v.len() == bounds[k + 1] - bounds[k]);
            if !fits {
                return Err(CommError(format!(
                    "rank {me}: rank {j}'s chunks do not fit the placement"
                )));
            }
            for (k, chunk) in theirs.into_iter().zip(values) {
                for (slot, value) in data[bounds[k]..bounds[k + 1]].iter_mut().zip(chunk) {
                    *slot = value;
                }
            }
        }
        Ok(())
    }

    fn all_gather_vectors(&self, mine: &[DVec3]) -> Result<Vec<Vec<DVec3>>, CommError> {
        if self.transport.size() == 1 {
            return Ok(vec![mine.to_vec()]);
        }
        let me = self.rank();
        let parts = self.transport.all_gather(vector_bytes(mine))?;
        parts
            .into_iter()
            .enumerate()
            .map(|(j, part)| {
                if j == me {
                    Ok(mine.to_vec())
                } else {
                    bytes_vectors(me, j, &part)
                }
            })
            .collect()
    }

    fn exchange_words(
        &self,
        sends: Vec<(usize, Vec<f64>)>,
        recvs: &[(usize, usize)],
        overlap: &mut dyn FnMut(),
    ) -> Result<Vec<Vec<f64>>, CommError> {
        Ok(self.transport.exchange(sends, recvs, overlap)?)
    }
}

/// Raw little-endian bits, eight bytes per word (`n` of them): exact, and
/// far cheaper than a generic encoding for what travels every internal tick.
fn word_bytes(n: usize, words: impl IntoIterator<Item = f64>) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(8 * n);
    for w in words {
        bytes.extend_from_slice(&w.to_le_bytes());
    }
    bytes
}

/// The words of [`word_bytes`] (`bytes.len()` a multiple of 8).
fn bytes_words(bytes: &[u8]) -> impl Iterator<Item = f64> + '_ {
    (bytes.chunks_exact(8)).map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
}

/// The coordinates of `values` as [`word_bytes`].
fn vector_bytes(values: &[DVec3]) -> Vec<u8> {
    word_bytes(3 * values.len(), values.iter().flat_map(|v| v.to_array()))
}

/// The vectors of [`vector_bytes`], received by rank `me` from rank `from`.
fn bytes_vectors(me: usize, from: usize, bytes: &[u8]) -> Result<Vec<DVec3>, CommError> {
    if bytes.len() % 24 != 0 {
        return Err(CommError(format!(
            "rank {me}: rank {from} sent {} bytes, not whole vectors",
            bytes.len()
        )));
    }
    Ok(bytes
        .chunks_exact(24)
        .map(|v| {
            let mut w = bytes_words(v);
            let mut next = || w.next().expect("three words");
            DVec3::new(next(), next(), next())
        })
        .collect())
}

/// Runs `body` on `ranks` threads standing in for processes: each gets its
/// own [`Ranks`] executor over channels, with the local executor
/// `local(rank)`, and builds its own state. Returns each rank's result, in
/// rank order. A rank that fails drops its channels, so its peers' next
/// collective fails instead of hanging; a rank's panic is re-raised here.
pub fn in_process<E, R>(
    ranks: usize,
    local: impl Fn(usize) -> E + Sync,
    body: impl Fn(Ranks<ChannelTransport, E>) -> R + Sync,
) -> Vec<R>
where
    E: Executor + Send,
    R: Send,
{
    let transports = ChannelTransport::connected(ranks);
    std::thread::scope(|s| {
        let handles: Vec<_> = transports
            .into_iter()
            .enumerate()
            .map(|(rank, t)| {
                let (local, body) = (&local, &body);
                std::thread::Builder::new()
                    .name(format!("weft-rank-{rank}"))
                    .spawn_scoped(s, move || body(Ranks::new(t, local(rank))))
                    .expect("spawning a rank thread")
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rank_gets_every_result_computed_once_by_its_owner() {
        let transports = ChannelTransport::connected(3);
        let n = 50;
        let outs: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = transports
                .into_iter()
                .map(|t| {
                    s.spawn(move || {
                        let r = Ranks::new(t, Serial);
                        let owner: Vec<u32> = (0..n).map(|i| (i * 7 % 3) as u32).collect();
                        let calls = std::sync::atomic::AtomicUsize::new(0);
                        let squares = r
                            .map_on_ranks(n, &owner, &|i| {
                                calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                                (i * i) as f64
                            })
                            .unwrap();
                        let mut data = vec![-1.0f64; 100];
                        let bounds = [0, 10, 10, 45, 90, 100];
                        r.chunks_on_ranks(&mut data, &bounds, &|k, chunk: &mut [f64]| {
                            for (j, x) in chunk.iter_mut().enumerate() {
                                *x = (k * 1000 + j) as f64 + 0.5;
                            }
                        })
                        .unwrap();
                        let stop = r.any_rank(r.rank() == 2).unwrap();
                        // -0.0 and NaN payloads must survive.
                        let mine: Vec<DVec3> = (0..r.rank() + 2)
                            .map(|j| {
                                let nan = f64::from_bits(0x7ff8_0000_0000_0000 | j as u64);
                                DVec3::new(r.rank() as f64 + 0.25, -0.0, nan)
                            })
                            .collect();
                        let all = r.all_gather_vectors(&mine).unwrap();
                        assert_eq!(all.len(), 3);
                        for (k, part) in all.iter().enumerate() {
                            assert_eq!(part.len(), k + 2);
                            for (j, v) in part.iter().enumerate() {
                                assert_eq!(v.x, k as f64 + 0.25);
                                assert_eq!(v.y.to_bits(), (-0.0f64).to_bits());
                                assert_eq!(v.z.to_bits(), 0x7ff8_0000_0000_0000 | j as u64);
                            }
                        }
                        (squares, calls.into_inner(), data, stop)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let mut serial = vec![0.0; 100];
        let bounds = [0, 10, 10, 45, 90, 100];
        Serial.for_each_chunk(&mut serial, &bounds, &|k, chunk: &mut [f64]| {
            for (j, x) in chunk.iter_mut().enumerate() {
                *x = (k * 1000 + j) as f64 + 0.5;
            }
        });
        let mut total_calls = 0;
        for (squares, calls, data, stop) in outs {
            assert_eq!(squares, (0..n).map(|i| (i * i) as f64).collect::<Vec<_>>());
            assert_eq!(data, serial);
            assert!(stop);
            total_calls += calls;
        }
        assert_eq!(total_calls, n, "each item computed on one rank only");
    }

    #[test]
    fn all_to_all_vectors_hands_each_rank_its_vectors_bit_for_bit() {
        // On 4 ranks, rank r sends rank j (j != r, (r + j) % 3 != 0) r + j
        // vectors carrying NaN payloads, signed zeros and infinities;
        // nothing to the others. Its own part stays as it was.
        let part = |r: usize, j: usize| -> Vec<DVec3> {
            if (r + j) % 3 == 0 && r != j {
                return Vec::new();
            }
            (0..r + j)
                .map(|k| {
                    let nan = f64::from_bits(0x7ff0_0000_0000_0001 | (r * 16 + j + k) as u64);
                    DVec3::new(nan, -0.0, if k % 2 == 0 { f64::INFINITY } else { k as f64 })
                })
                .collect()
        };
        let outs = in_process(
            4,
            |_| Serial,
            |ranks| {
                let me = ranks.rank();
                let parts: Vec<Vec<DVec3>> = (0..4).map(|j| part(me, j)).collect();
                ranks.all_to_all_vectors(vec![me as u64, 7], parts).unwrap()
            },
        );
        let bits = |vs: &[DVec3]| -> Vec<[u64; 3]> {
            vs.iter().map(|v| v.to_array().map(f64::to_bits)).collect()
        };
        for (me, (heads, parts)) in outs.into_iter().enumerate() {
            assert_eq!(heads, (0..4).map(|r| vec![r as u64, 7]).collect::<Vec<_>>());
            assert_eq!(parts.len(), 4);
            for (j, got) in parts.iter().enumerate() {
                assert_eq!(bits(got), bits(&part(j, me)), "rank {me} from rank {j}");
            }
        }
    }
}
