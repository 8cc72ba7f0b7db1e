//! Collectives in `⌈log2 R⌉` rounds of point-to-point messages, shared by
//! the transports.
//!
//! Open MPI 4.1 runs the nonblocking `MPI_Iallgather` and `MPI_Ialltoall`
//! (`coll/libnbc`) linearly: every rank posts a message to every other
//! rank, `R - 1` each way, and pays a CPU overhead for each. The engine
//! meets a collective at every internal tick, so past about a hundred ranks
//! those overheads cost more than the work between two ticks
//! (`docs/performance.md`, "Linear collectives"). weft's transports therefore
//! gather by **Bruck's algorithm** (Bruck, Ho, Kipnis, Upfal, Weathersby,
//! *Efficient algorithms for all-to-all communications in multiport
//! message-passing systems*, IEEE TPDS 1997), built on their own
//! point-to-point messages:
//!
//! ```text
//! blocks = [mine]                      // blocks[i]: rank (r + i) mod R's
//! for d = 1, 2, 4, … while d < R:
//!     c = min(d, R - d)
//!     send blocks[0..c]            to   rank (r - d) mod R
//!     receive blocks[d..d + c]     from rank (r + d) mod R
//! ```
//!
//! After round `d` a rank holds the blocks of ranks `r .. r + min(2d, R)`,
//! so `⌈log2 R⌉` rounds gather all `R`. Each rank still sends and receives
//! the other `R - 1` blocks once each, as linearly, but in `⌈log2 R⌉`
//! messages instead of `R - 1`. The blocks land in rank order whatever the
//! order of their arrival: the bits are those of any other all-gather.
//!
//! A message of `c` blocks is their `c` lengths (little-endian `u64`) and
//! then their bytes; the receiver knows `c` and checks the rest.
//!
//! An all-to-all's dense step is such an all-gather too (`head_block`,
//! `read_heads`): each rank's head, and the lengths of the non-empty parts
//! it sends, as `(peer, length)` pairs (a rank sends parts to its
//! neighbours, not to all `R`: dense lengths would gather `R²` words).

use super::transport::RankFailure;

/// The number of rounds of an all-gather over `ranks` ranks: `⌈log2 R⌉`.
pub fn rounds(ranks: usize) -> u32 {
    ranks.max(1).next_power_of_two().trailing_zeros()
}

/// A transport's half of a round: sends `bytes` to rank `to`, and returns
/// the message of this round from rank `from` (waiting for it, with the
/// transport's own overlapped work and polling).
pub(crate) type Round<'a> = dyn FnMut(usize, Vec<u8>, usize) -> Result<Vec<u8>, RankFailure> + 'a;

/// **Collective.** Bruck's all-gather (module doc): every rank's `mine`, in
/// rank order, this rank being `rank` of `size`; `round` moves each round's
/// messages.
pub(crate) fn all_gather(
    rank: usize,
    size: usize,
    mine: Vec<u8>,
    round: &mut Round<'_>,
) -> Result<Vec<Vec<u8>>, RankFailure> {
    let mut blocks = Vec::with_capacity(size);
    blocks.push(mine);
    let mut d = 1;
    while d < size {
        let c = d.min(size - d);
        let to = (rank + size - d) % size;
        let from = (rank + d) % size;
        let got = round(to, frame(&blocks[..c]), from)?;
        unframe(&got, c, &mut blocks).map_err(|what| RankFailure {
            rank,
            what: format!("rank {from} sent a malformed gather message: {what}"),
        })?;
        d *= 2;
    }
    // blocks[i] is rank (rank + i)'s: rotate into rank order.
    blocks.rotate_right(rank);
    Ok(blocks)
}

/// `blocks` as one message: their lengths, then their bytes.
fn frame(blocks: &[Vec<u8>]) -> Vec<u8> {
    let total = blocks.iter().map(Vec::len).sum::<usize>();
    let mut out = Vec::with_capacity(8 * blocks.len() + total);
    for b in blocks {
        out.extend_from_slice(&(b.len() as u64).to_le_bytes());
    }
    for b in blocks {
        out.extend_from_slice(b);
    }
    out
}

/// Appends the `count` blocks of `message` ([`frame`]) to `blocks`.
fn unframe(message: &[u8], count: usize, blocks: &mut Vec<Vec<u8>>) -> Result<(), String> {
    let table = 8 * count;
    if message.len() < table {
        return Err(format!(
            "{} bytes, shorter than its {count} lengths",
            message.len()
        ));
    }
    let lens: Vec<u64> = words(&message[..table]);
    let total = lens.iter().try_fold(0u64, |s, &l| s.checked_add(l));
    if total != Some((message.len() - table) as u64) {
        return Err(format!(
            "{} bytes of blocks, its lengths say {lens:?}",
            message.len() - table
        ));
    }
    let mut at = table;
    for len in lens {
        let end = at + len as usize;
        blocks.push(message[at..end].to_vec());
        at = end;
    }
    Ok(())
}

/// Little-endian `u64` words of `bytes` (a whole number of them).
fn words(bytes: &[u8]) -> Vec<u64> {
    (bytes.chunks_exact(8))
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect()
}

/// A rank's block of an all-to-all's gathered heads, as little-endian
/// `u64` words: a flag (1: one of its parts is too large for the transport,
/// and it sends none), the head's word count, the head, the number of parts
/// it sends to other ranks, then each such part's `(peer, length)`.
pub(crate) fn head_block(rank: usize, head: &[u64], parts: &[Vec<u8>], too_large: bool) -> Vec<u8> {
    let sent: Vec<(usize, usize)> = if too_large {
        Vec::new()
    } else {
        (parts.iter().enumerate())
            .filter(|&(j, p)| j != rank && !p.is_empty())
            .map(|(j, p)| (j, p.len()))
            .collect()
    };
    let words = [u64::from(too_large), head.len() as u64]
        .into_iter()
        .chain(head.iter().copied())
        .chain([sent.len() as u64])
        .chain(sent.iter().flat_map(|&(j, len)| [j as u64, len as u64]));
    words.flat_map(u64::to_le_bytes).collect()
}

/// What a rank learns from the gathered [`head_block`]s.
#[derive(Debug)]
pub(crate) struct Heads {
    /// Every rank's head, in rank order.
    pub heads: Vec<Vec<u64>>,
    /// The length of the part each rank sends this one (0: none comes).
    pub incoming: Vec<usize>,
    /// The first rank with a part too large for the transport, if any.
    pub too_large: Option<usize>,
}

/// Reads the gathered head blocks (`blocks[j]`: rank `j`'s) at rank `rank`,
/// whose head has `words` words: every rank's must have as many.
pub(crate) fn read_heads(
    rank: usize,
    words_in_head: usize,
    blocks: &[Vec<u8>],
) -> Result<Heads, RankFailure> {
    let fail = |what: String| RankFailure { rank, what };
    let mut heads = Vec::with_capacity(blocks.len());
    let mut incoming = vec![0; blocks.len()];
    let mut too_large = None;
    for (j, block) in blocks.iter().enumerate() {
        // (the block's words read in place: a vector of them per rank and
        // all-to-all was most of this rank's allocations at 32 ranks)
        let len = block.len() / 8;
        let word =
            |k: usize| u64::from_le_bytes(block[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        if block.len() % 8 != 0 || len < 2 {
            return Err(fail(format!(
                "rank {j} sent a head block of {} bytes",
                block.len()
            )));
        }
        if word(0) != 0 && too_large.is_none() {
            too_large = Some(j);
        }
        let n = word(1) as usize;
        if n != words_in_head {
            return Err(fail(format!(
                "rank {j} sent a head of {n} words, {words_in_head} expected"
            )));
        }
        if len < 3 + n {
            return Err(fail(format!(
                "rank {j} sent a head block of {len} words, without its count of parts"
            )));
        }
        let pairs = word(2 + n) as usize;
        if Some(len - 3 - n) != pairs.checked_mul(2) {
            return Err(fail(format!(
                "rank {j} sent a head block of {len} words for {pairs} parts"
            )));
        }
        heads.push((2..2 + n).map(word).collect());
        for p in 0..pairs {
            if word(3 + n + 2 * p) == rank as u64 {
                incoming[j] = word(4 + n + 2 * p) as usize;
            }
        }
    }
    Ok(Heads {
        heads,
        incoming,
        too_large,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc::{channel, Receiver, Sender};

    /// A rank's blocks gathered, and the (messages, bytes) it sent.
    type Gathered = (Vec<Vec<u8>>, (u64, u64));

    /// [`all_gather`] of `parts` (rank `j`'s is `parts[j]`) on one thread
    /// per rank, over a channel per pair of ranks; every rank's result and
    /// its (messages, bytes) sent.
    fn gather_on_threads(parts: &[Vec<u8>]) -> Vec<Gathered> {
        let size = parts.len();
        let mut senders: Vec<Vec<Option<Sender<Vec<u8>>>>> = vec![vec![None; size]; size];
        let mut receivers: Vec<Vec<Option<Receiver<Vec<u8>>>>> = (0..size)
            .map(|_| (0..size).map(|_| None).collect())
            .collect();
        for a in 0..size {
            for b in 0..size {
                let (s, r) = channel();
                senders[a][b] = Some(s);
                receivers[b][a] = Some(r);
            }
        }
        std::thread::scope(|scope| {
            let handles: Vec<_> = (senders.into_iter().zip(receivers).enumerate())
                .map(|(rank, (to, from))| {
                    let mine = parts[rank].clone();
                    scope.spawn(move || {
                        let mut sent = (0u64, 0u64);
                        let got = all_gather(rank, size, mine, &mut |j, bytes, k| {
                            sent.0 += 1;
                            sent.1 += bytes.len() as u64;
                            to[j].as_ref().unwrap().send(bytes).unwrap();
                            Ok(from[k].as_ref().unwrap().recv().unwrap())
                        })
                        .unwrap();
                        (got, sent)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        })
    }

    #[test]
    fn every_rank_gathers_every_block_in_rank_order_in_log2_rounds() {
        for size in 1..=37 {
            let parts: Vec<Vec<u8>> = (0..size)
                .map(|j| vec![j as u8; (j * 7 + size) % 11])
                .collect();
            let gathered = gather_on_threads(&parts);
            for (r, (got, (messages, _))) in gathered.iter().enumerate() {
                assert_eq!(got, &parts, "{size} ranks, rank {r}");
                assert_eq!(*messages, u64::from(rounds(size)), "{size} ranks");
            }
            // Every block reaches the R - 1 other ranks once, with its
            // length: the bytes of a linear all-gather and 8 a block more.
            let total: u64 = gathered.iter().map(|g| g.1 .1).sum();
            let want: u64 = (parts.iter())
                .map(|p| (size as u64 - 1) * (8 + p.len() as u64))
                .sum();
            assert_eq!(total, want, "{size} ranks");
        }
        assert_eq!(
            (rounds(1), rounds(2), rounds(3), rounds(32), rounds(33)),
            (0, 1, 2, 5, 6)
        );
    }

    #[test]
    fn a_malformed_message_is_an_error_naming_its_sender() {
        let err = all_gather(0, 2, vec![1], &mut |_, _, _| {
            Ok(vec![5, 0, 0, 0, 0, 0, 0, 0, 1])
        })
        .unwrap_err();
        assert!(err.to_string().contains("rank 1 sent a malformed"), "{err}");
        let err = all_gather(0, 2, vec![1], &mut |_, _, _| Ok(vec![1, 2])).unwrap_err();
        assert!(
            err.to_string().contains("shorter than its 1 lengths"),
            "{err}"
        );
    }

    #[test]
    fn head_blocks_carry_heads_and_the_lengths_of_non_empty_parts() {
        // Three ranks; rank j sends rank k (j + k) % 3 bytes.
        let parts = |j: usize| -> Vec<Vec<u8>> { (0..3).map(|k| vec![0; (j + k) % 3]).collect() };
        let blocks: Vec<Vec<u8>> = (0..3)
            .map(|j| head_block(j, &[10 * j as u64, 7], &parts(j), false))
            .collect();
        for me in 0..3 {
            let heads = read_heads(me, 2, &blocks).unwrap();
            for j in 0..3 {
                assert_eq!(heads.heads[j], vec![10 * j as u64, 7]);
                let want = if j == me { 0 } else { (j + me) % 3 };
                assert_eq!(heads.incoming[j], want, "{me} from {j}");
            }
            assert_eq!(heads.too_large, None);
        }
        // Rank 1 flags a part too large: it announces none.
        let mut flagged = blocks.clone();
        flagged[1] = head_block(1, &[10, 7], &parts(1), true);
        let heads = read_heads(0, 2, &flagged).unwrap();
        assert_eq!((heads.too_large, heads.incoming[1]), (Some(1), 0));
        // A head of another length, a truncated block: errors.
        let err = read_heads(0, 3, &blocks).unwrap_err();
        assert!(err.to_string().contains("2 words, 3 expected"), "{err}");
        let mut cut = blocks.clone();
        let shorter = cut[2].len() - 8;
        cut[2].truncate(shorter);
        let err = read_heads(0, 2, &cut).unwrap_err();
        assert!(
            err.to_string().contains("rank 2 sent a head block"),
            "{err}"
        );
        // Cut to its head, without the count of parts (it panicked once).
        let mut headless = blocks;
        headless[1].truncate(8 * 4);
        let err = read_heads(0, 2, &headless).unwrap_err();
        assert!(
            err.to_string().contains("without its count of parts"),
            "{err}"
        );
    }
}
