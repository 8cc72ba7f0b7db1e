//! `weft bench --ranks 1,2,4,… --project R,…`: the time per window on more
//! ranks than this machine has cores, **projected** by a model, never read
//! off the wall clock of oversubscribed runs.
//!
//! The simulated ranks of a counted run record every communication step
//! ([`SyncStep`]: the rank's work CPU since its previous step, and the bytes
//! the step moved). Two uses:
//!
//! * **Replay** ([`replay`]) of one measured run under a LogGP network: each
//!   rank's clock advances by its measured work; an all-gather starts when
//!   the last rank reaches it and takes `⌈log2 R⌉ (L + 2o) + G S (R-1)/R`
//!   for `S` bytes in all (Bruck's rounds, as weft's transports gather:
//!   `weft_par::ranks::dissemination`; with `--collectives linear`, each
//!   rank's part to each other rank, `L + 2 o + G S (R-1)/R`, as Open
//!   MPI 4.1's nonblocking collectives would); an all-to-all
//!   all-gathers every rank's block of its head and its parts' lengths and
//!   then moves its parts as point-to-point messages; a
//!   point-to-point message leaves after the sender's overhead `o` and
//!   arrives `L + G b` later, and the receiver pays `o` (no overlap of work
//!   and messages is credited; the recorded ranks, for the same reason, run
//!   no work in an all-to-all's wait, which on an oversubscribed machine
//!   would put a rank's next internal tick's calm part in whichever interval
//!   the scheduler chose: at 8 simulated ranks of the 10k twister, 1.52
//!   times the mean rank's work between collectives instead of 1.25). So
//!   the replay keeps the measured load imbalance between every two
//!   collectives, which a per-window sum would average away.
//! * **Projection** ([`project`]) to rank counts not measured: the engine's
//!   collective schedule does not depend on the rank count, so the work of
//!   the busiest rank between collectives `c - 1` and `c` is fitted per
//!   interval as `W_c(R) = a_c + b_c / R` over the measured rank counts
//!   (least squares, `a_c, b_c ≥ 0`: `a_c` is what every rank repeats, or
//!   what one rank cannot share, `b_c` what is shared; the measured
//!   imbalance is in the fit). Each interval's all-gather keeps its
//!   measured total bytes; its point-to-point traffic keeps the largest
//!   rank's message count and shrinks its bytes as a partition's boundary
//!   does on a surface, `∝ (R_max / R)^(1/2)`.
//!
//! What the model leaves out: contention in the network, the work after a
//! window's last collective, and any change of the schedule itself with R
//! (more partitions per rank are not modelled). One rank is such a change:
//! it runs without a rank share, repeats nothing and meets no collective,
//! so the fit's `a + b` (which counts what every rank of a run over ranks
//! repeats) overstates it — 1.46× the measured time on 16 cores, with the
//! fit over 2–16 ranks. `weft bench` therefore reports one rank's measured
//! time where `--ranks` ran it, and the model only above.

use serde::Serialize;
use std::collections::{HashMap, VecDeque};
use weft_par::ranks::SyncStep;

/// A LogGP network: latency `L`, per-message CPU overhead `o`, and seconds
/// per byte `G` (the inverse bandwidth), all in seconds; and how the MPI
/// library runs the nonblocking collectives.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Network {
    pub latency: f64,
    pub overhead: f64,
    pub seconds_per_byte: f64,
    pub collectives: Collectives,
}

/// How a nonblocking all-gather (and an all-to-all's heads) travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Collectives {
    // (Plain comments: doc comments would turn `weft bench --help` into
    // clap's long layout.)
    // Bruck's all-gather, `⌈log2 R⌉` rounds of one message each way: how
    // weft's transports run their collectives
    // (`weft_par::ranks::dissemination`). (`tree`: the name before.)
    #[value(alias = "tree")]
    #[serde(rename = "dissemination")]
    Dissemination,
    // Every rank sends its part to every other rank, `R - 1` messages each
    // way: Open MPI 4.1's `MPI_Iallgather` and `MPI_Ialltoall`
    // (`coll/libnbc`), which weft's MPI transport called before it had
    // its own.
    Linear,
}

impl Network {
    /// One message of `bytes`: from the sender's call to the receiver's
    /// completion.
    fn message(&self, bytes: f64) -> f64 {
        self.latency + 2.0 * self.overhead + self.seconds_per_byte * bytes
    }

    /// An all-gather of `total` bytes over `ranks` ranks (each rank
    /// receives all but its own part): Bruck's, `⌈log2 R⌉` rounds of
    /// `L + 2o`; or linear, the `R - 1` messages each way in flight
    /// together, an overhead `o` for each and one latency.
    fn all_gather(&self, ranks: usize, total: f64) -> f64 {
        if ranks <= 1 {
            return 0.0;
        }
        let others = (ranks - 1) as f64;
        let messages = match self.collectives {
            Collectives::Dissemination => {
                (ranks as f64).log2().ceil() * (self.latency + 2.0 * self.overhead)
            }
            Collectives::Linear => self.latency + 2.0 * others * self.overhead,
        };
        messages + self.seconds_per_byte * total * others / ranks as f64
    }
}

impl Network {
    /// The gathered heads of an all-to-all: every rank's block of `head`
    /// bytes (its head and its parts' lengths, the mean over the ranks) to
    /// every rank, as an all-gather of them.
    fn all_to_all_heads(&self, ranks: usize, head: f64) -> f64 {
        self.all_gather(ranks, head * ranks as f64)
    }

    /// A rank's parts of an all-to-all after the heads: `sent` and
    /// `received` (per peer, bytes). As a message (`L + 2o + G b`) per part,
    /// the rank's parts in flight together: the overheads of the busier
    /// direction, one latency, and the bytes of the busier direction.
    fn all_to_all_parts(&self, sent: &[(u32, u64)], received: &[(u32, u64)]) -> f64 {
        if sent.is_empty() && received.is_empty() {
            return 0.0;
        }
        let bytes = |v: &[(u32, u64)]| v.iter().map(|&(_, b)| b as f64).sum::<f64>();
        2.0 * sent.len().max(received.len()) as f64 * self.overhead
            + self.latency
            + self.seconds_per_byte * bytes(sent).max(bytes(received))
    }
}

/// Replays the ranks' steps (`steps[r]`: rank `r`'s, in order) under `net`;
/// returns the simulated seconds until the last rank completes its last
/// step. An error means the steps do not form one run (a collective some
/// rank never reaches, a message never sent).
pub fn replay(steps: &[Vec<SyncStep>], net: &Network) -> Result<f64, String> {
    let n = steps.len();
    let mut t = vec![0.0f64; n];
    let mut at = vec![0usize; n];
    // After an exchange's sends are posted: the sender's clock.
    let mut posted: Vec<Option<f64>> = vec![None; n];
    // Arrival times of the messages in flight, per (from, to).
    let mut flight: HashMap<(u32, u32), VecDeque<f64>> = HashMap::new();
    loop {
        let mut progress = false;
        for r in 0..n {
            while let Some(s) = steps[r].get(at[r]) {
                if s.collective {
                    break;
                }
                let post = match posted[r] {
                    Some(p) => p,
                    None => {
                        let mut p = t[r] + s.work_ns as f64 * 1e-9;
                        for &(j, bytes) in &s.sent {
                            p += net.overhead;
                            let arrive = p + net.latency + net.seconds_per_byte * bytes as f64;
                            flight.entry((r as u32, j)).or_default().push_back(arrive);
                        }
                        posted[r] = Some(p);
                        progress = true;
                        p
                    }
                };
                let mut wanted: HashMap<u32, usize> = HashMap::new();
                for &(j, _) in &s.received {
                    *wanted.entry(j).or_default() += 1;
                }
                let ready = wanted
                    .iter()
                    .all(|(&j, &k)| flight.get(&(j, r as u32)).map_or(0, VecDeque::len) >= k);
                if !ready {
                    break;
                }
                let mut done = post;
                for &(j, _) in &s.received {
                    let queue = flight.get_mut(&(j, r as u32)).expect("checked above");
                    let arrive = queue.pop_front().expect("checked above");
                    done = done.max(arrive) + net.overhead;
                }
                t[r] = done;
                posted[r] = None;
                at[r] += 1;
                progress = true;
            }
        }
        if (0..n).all(|r| at[r] == steps[r].len()) {
            return Ok(t.into_iter().fold(0.0, f64::max));
        }
        let gathering = (0..n).all(|r| steps[r].get(at[r]).is_some_and(|s| s.collective));
        if gathering {
            let mut start = 0.0f64;
            let mut total = 0.0;
            let mut parts = 0.0f64;
            let mut heads = None;
            let kind = steps[0][at[0]].head_bytes.is_some();
            if (0..n).any(|r| steps[r][at[r]].head_bytes.is_some() != kind) {
                return Err(format!(
                    "the ranks' steps do not form one run (a collective that is an \
                     all-to-all on some ranks and not on others, at steps {at:?})"
                ));
            }
            for r in 0..n {
                let s = &steps[r][at[r]];
                start = start.max(t[r] + s.work_ns as f64 * 1e-9);
                match s.head_bytes {
                    Some(h) => {
                        *heads.get_or_insert(0.0) += h as f64;
                        parts = parts.max(net.all_to_all_parts(&s.sent, &s.received));
                    }
                    None => total += s.sent.iter().map(|&(_, b)| b as f64).sum::<f64>(),
                }
            }
            let end = start
                + match heads {
                    Some(h) => net.all_to_all_heads(n, h / n as f64) + parts,
                    None => net.all_gather(n, total),
                };
            for r in 0..n {
                t[r] = end;
                at[r] += 1;
            }
            progress = true;
        }
        if !progress {
            return Err(format!(
                "the ranks' steps do not form one run (stuck at steps {at:?})"
            ));
        }
    }
}

/// The work and traffic between two collectives, per rank.
#[derive(Clone, Debug, Default)]
pub struct Interval {
    /// Each rank's work in the interval, seconds (up to and including the
    /// work before the collective that ends it).
    pub work: Vec<f64>,
    /// The bytes the ending all-gather moves in all.
    pub gathered: f64,
    /// The ending collective is an all-to-all whose ranks' head blocks
    /// hold these bytes on average (its parts are counted with the
    /// point-to-point traffic).
    pub head: Option<f64>,
    /// The point-to-point messages and bytes of the busiest rank (sent and
    /// received).
    pub messages: f64,
    pub bytes: f64,
    /// Where the ranks were when they began the ending collective
    /// (`weft_sim::trace::site`; as the first rank saw it).
    pub site: &'static str,
}

/// The ranks' steps cut at their collectives (every rank must have the same
/// number); point-to-point steps after the last collective are left out.
pub fn intervals(steps: &[Vec<SyncStep>]) -> Result<Vec<Interval>, String> {
    let n = steps.len();
    let count = |s: &Vec<SyncStep>| s.iter().filter(|s| s.collective).count();
    let c = steps.first().map_or(0, count);
    if steps.iter().any(|s| count(s) != c) {
        return Err("the ranks took part in different numbers of collectives".into());
    }
    let mut out = vec![
        Interval {
            work: vec![0.0; n],
            ..Interval::default()
        };
        c
    ];
    let mut traffic = vec![vec![(0.0f64, 0.0f64); n]; c];
    // Per collective: whether it is an all-to-all, as the first rank saw
    // it.
    let mut kinds: Vec<Option<bool>> = vec![None; c];
    for (r, rank) in steps.iter().enumerate() {
        let mut k = 0;
        for s in rank {
            if k == c {
                break;
            }
            out[k].work[r] += s.work_ns as f64 * 1e-9;
            if !s.collective || s.head_bytes.is_some() {
                let moved = s.sent.iter().chain(&s.received);
                for &(_, b) in moved {
                    traffic[k][r].0 += 1.0;
                    traffic[k][r].1 += b as f64;
                }
            }
            if s.collective {
                if r == 0 {
                    out[k].site = s.site;
                }
                let kind = s.head_bytes.is_some();
                if *kinds[k].get_or_insert(kind) != kind {
                    return Err(format!(
                        "collective {k} is an all-to-all on some ranks and not on others"
                    ));
                }
                match s.head_bytes {
                    Some(h) => *out[k].head.get_or_insert(0.0) += h as f64 / n as f64,
                    None => out[k].gathered += s.sent.iter().map(|&(_, b)| b as f64).sum::<f64>(),
                }
                k += 1;
            }
        }
    }
    for (i, t) in out.iter_mut().zip(traffic) {
        let busiest =
            (t.iter().copied()).fold((0.0f64, 0.0f64), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        (i.messages, i.bytes) = busiest;
    }
    Ok(out)
}

/// `y ≈ a + b x` by least squares with `a, b ≥ 0`.
fn fit_nonnegative(points: &[(f64, f64)]) -> (f64, f64) {
    let k = points.len() as f64;
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |s, p| (s.0 + p.0, s.1 + p.1));
    let (mx, my) = (sx / k, sy / k);
    let sxx: f64 = points.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let a = my - b * mx;
    if b < 0.0 {
        return (my.max(0.0), 0.0);
    }
    if a < 0.0 {
        let sxx0: f64 = points.iter().map(|p| p.0 * p.0).sum();
        let sxy0: f64 = points.iter().map(|p| p.0 * p.1).sum();
        return (
            0.0,
            if sxx0 > 0.0 {
                (sxy0 / sxx0).max(0.0)
            } else {
                0.0
            },
        );
    }
    (a, b)
}

/// The busiest rank's work in each interval fitted as `a + b / R` over the
/// measured rank counts (the same collective schedule in each: [`project`]
/// checks it; intervals past the shortest schedule are left out here).
pub fn fitted(measured: &[(usize, Vec<Interval>)]) -> Vec<(f64, f64)> {
    let c = measured.iter().map(|m| m.1.len()).min().unwrap_or(0);
    (0..c)
        .map(|k| {
            let points: Vec<(f64, f64)> = (measured.iter())
                .map(|(r, iv)| (1.0 / *r as f64, busiest(&iv[k].work)))
                .collect();
            fit_nonnegative(&points)
        })
        .collect()
}

/// The most work of any rank.
fn busiest(work: &[f64]) -> f64 {
    work.iter().copied().fold(0.0, f64::max)
}

/// Summed over the intervals of one run: the busiest rank's work and the
/// mean rank's (seconds). Their ratio is the load imbalance the ranks meet
/// between collectives, which a per-window sum of each rank's work
/// averages away (each rank's busy intervals may be others' idle ones).
pub fn between_collectives(intervals: &[Interval]) -> (f64, f64) {
    intervals.iter().fold((0.0, 0.0), |(most, mean), iv| {
        let n = iv.work.len().max(1) as f64;
        (
            most + busiest(&iv.work),
            mean + iv.work.iter().sum::<f64>() / n,
        )
    })
}

/// The intervals that end at the collectives of one site, over the
/// measured rank counts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SiteShare {
    /// The site (`weft_sim::trace::site`; "" outside every site).
    pub site: &'static str,
    /// How many intervals end there.
    pub intervals: usize,
    /// The fit of their busiest rank's work, summed ([`fitted`]; seconds):
    /// what does not shrink with the ranks (Σ a) and what is shared (Σ b).
    pub fit: (f64, f64),
    /// At the largest measured rank count, summed over them: the busiest
    /// rank's work and the mean rank's (seconds; [`between_collectives`]).
    pub most: f64,
    pub mean: f64,
}

/// [`fitted`] and [`between_collectives`] told apart by the site of the
/// collective that ends each interval: where the work that does not shrink
/// with the ranks, and the ranks' imbalance, are. Sorted by Σ a, largest
/// first (then by site).
pub fn by_site(measured: &[(usize, Vec<Interval>)]) -> Vec<SiteShare> {
    let fit = fitted(measured);
    let Some((_, largest)) = measured.iter().max_by_key(|m| m.0) else {
        return Vec::new();
    };
    let mut sites: std::collections::BTreeMap<&'static str, SiteShare> = Default::default();
    for (k, (a, b)) in fit.into_iter().enumerate() {
        let iv = &largest[k];
        let (most, mean) = between_collectives(std::slice::from_ref(iv));
        let share = sites.entry(iv.site).or_insert(SiteShare {
            site: iv.site,
            intervals: 0,
            fit: (0.0, 0.0),
            most: 0.0,
            mean: 0.0,
        });
        share.intervals += 1;
        share.fit.0 += a;
        share.fit.1 += b;
        share.most += most;
        share.mean += mean;
    }
    let mut out: Vec<SiteShare> = sites.into_values().collect();
    out.sort_by(|x, y| y.fit.0.total_cmp(&x.fit.0).then(x.site.cmp(y.site)));
    out
}

/// One projected rank count.
#[derive(Clone, Debug, Serialize)]
pub struct Projected {
    pub ranks: usize,
    /// Seconds of the modelled run: the critical work, the all-gathers and
    /// the point-to-point messages.
    pub seconds: f64,
    pub work: f64,
    pub collectives: f64,
    pub point_to_point: f64,
    /// Not modelled: one rank measured (`bench/mod.rs`, `projection`).
    pub measured: bool,
}

/// The modelled time of `targets` rank counts from the intervals of the
/// measured counts (`measured`: rank count and its intervals; at least two
/// counts, the same collective schedule).
pub fn project(
    measured: &[(usize, Vec<Interval>)],
    targets: &[usize],
    net: &Network,
) -> Result<Vec<Projected>, String> {
    if measured.len() < 2 {
        return Err("the projection needs two or more measured rank counts above 1".into());
    }
    let c = measured[0].1.len();
    if measured.iter().any(|m| m.1.len() != c) {
        return Err(format!(
            "the collective schedule differs between the measured rank counts ({})",
            measured
                .iter()
                .map(|m| format!("{} ranks: {} collectives", m.0, m.1.len()))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let (largest, at_largest) = measured
        .iter()
        .max_by_key(|m| m.0)
        .map(|m| (m.0, &m.1))
        .expect("two or more");
    let model = fitted(measured);
    Ok(targets
        .iter()
        .map(|&r| {
            let (mut work, mut gather, mut p2p) = (0.0, 0.0, 0.0);
            for (k, &(a, b)) in model.iter().enumerate() {
                let iv = &at_largest[k];
                work += a + b / r as f64;
                gather += match iv.head {
                    Some(h) => net.all_to_all_heads(r, h),
                    None => net.all_gather(r, iv.gathered),
                };
                if r > 1 && iv.messages > 0.0 {
                    let shrink = (largest as f64 / r as f64).sqrt();
                    let per = iv.bytes * shrink / iv.messages;
                    p2p += iv.messages * net.message(per);
                }
            }
            Projected {
                ranks: r,
                seconds: work + gather + p2p,
                work,
                collectives: gather,
                point_to_point: p2p,
                measured: false,
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(
        work_us: u64,
        collective: bool,
        sent: &[(u32, u64)],
        received: &[(u32, u64)],
    ) -> SyncStep {
        SyncStep {
            work_ns: work_us * 1000,
            collective,
            head_bytes: None,
            sent: sent.to_vec(),
            received: received.to_vec(),
            site: "",
        }
    }

    const NET: Network = Network {
        latency: 1e-6,
        overhead: 0.5e-6,
        seconds_per_byte: 1e-9,
        collectives: Collectives::Dissemination,
    };

    #[test]
    fn linear_collectives_pay_an_overhead_per_peer_and_bruck_ones_a_round_per_doubling() {
        let linear = Network {
            collectives: Collectives::Linear,
            ..NET
        };
        // Two ranks: one message each way either way.
        assert_eq!(linear.all_gather(2, 1000.0), NET.all_gather(2, 1000.0));
        // 384 ranks, 8 bytes a rank: 383 overheads each way and one
        // latency, against 9 rounds.
        let bytes = 1e-9 * 8.0 * 383.0;
        let l = linear.all_gather(384, 8.0 * 384.0);
        assert!(
            (l - (1e-6 + 2.0 * 383.0 * 0.5e-6 + bytes)).abs() < 1e-15,
            "{l}"
        );
        let t = NET.all_gather(384, 8.0 * 384.0);
        assert!((t - (9.0 * 2e-6 + bytes)).abs() < 1e-15, "{t}");
        assert!(l > 10.0 * t);
        assert_eq!(linear.all_gather(1, 8.0), 0.0);
    }

    #[test]
    fn a_collective_waits_for_the_slowest_rank() {
        // 10 µs and 30 µs of work, then an all-gather of 100 + 100 bytes.
        let steps = vec![
            vec![step(10, true, &[(0, 100)], &[])],
            vec![step(30, true, &[(1, 100)], &[])],
        ];
        let t = replay(&steps, &NET).unwrap();
        let expected = 30e-6 + (1e-6 + 1e-6) + 1e-9 * 200.0 / 2.0;
        assert!((t - expected).abs() < 1e-12, "{t} vs {expected}");
    }

    #[test]
    fn a_message_arrives_after_its_sender_sent_it() {
        // Rank 0 works 50 µs and sends 1000 bytes; rank 1 works 5 µs and
        // waits for them; then both gather nothing.
        let steps = vec![
            vec![
                step(50, false, &[(1, 1000)], &[]),
                step(0, true, &[(0, 0)], &[]),
            ],
            vec![
                step(5, false, &[], &[(0, 1000)]),
                step(0, true, &[(1, 0)], &[]),
            ],
        ];
        let t = replay(&steps, &NET).unwrap();
        let arrive = 50e-6 + 0.5e-6 + 1e-6 + 1e-6;
        let expected = arrive + 0.5e-6 + (1e-6 + 1e-6);
        assert!((t - expected).abs() < 1e-12, "{t} vs {expected}");
    }

    #[test]
    fn an_all_to_all_waits_for_the_last_rank_then_moves_heads_and_parts() {
        // Rank 0 works 20 µs and sends rank 1 500 bytes; rank 1 works 30 µs
        // and sends nothing; head blocks of 40 bytes (rank 0's names its
        // part) and 24.
        let a2a = |work, head, sent: &[(u32, u64)], received: &[(u32, u64)]| SyncStep {
            head_bytes: Some(head),
            ..step(work, true, sent, received)
        };
        let steps = vec![
            vec![a2a(20, 40, &[(1, 500)], &[])],
            vec![a2a(30, 24, &[], &[(0, 500)])],
        ];
        let t = replay(&steps, &NET).unwrap();
        // One round of heads (L + 2o, and the peer's block: half of the
        // 64 bytes on average), then a message of 500 bytes: its overhead
        // on each side, L and its bytes.
        let heads = (1e-6 + 1e-6) + 1e-9 * 32.0;
        let parts = 2.0 * 0.5e-6 + 1e-6 + 1e-9 * 500.0;
        let expected = 30e-6 + heads + parts;
        assert!((t - expected).abs() < 1e-12, "{t} vs {expected}");
        // The interval holds the mean head block, and the parts as the
        // busiest rank's traffic.
        let iv = intervals(&steps).unwrap();
        assert_eq!(iv[0].head, Some(32.0));
        assert_eq!((iv[0].messages, iv[0].bytes), (1.0, 500.0));
        assert_eq!(iv[0].gathered, 0.0);
        // An all-to-all on one rank is an all-gather on the other: no run.
        let mixed = vec![
            vec![a2a(20, 40, &[(1, 500)], &[])],
            vec![step(30, true, &[(1, 0)], &[])],
        ];
        assert!(replay(&mixed, &NET).is_err());
        assert!(intervals(&mixed).is_err());
    }

    #[test]
    fn mismatched_steps_are_an_error() {
        let steps = vec![
            vec![step(1, true, &[(0, 1)], &[])],
            vec![step(1, false, &[], &[(0, 8)])],
        ];
        assert!(replay(&steps, &NET).is_err());
        assert!(intervals(&steps).is_err());
    }

    #[test]
    fn between_collectives_sums_each_intervals_busiest_and_mean_rank() {
        // Two intervals where the ranks take turns at being busy: each rank
        // works 40 µs in all, but every interval waits for a 30 µs rank.
        let steps = vec![
            vec![
                step(30, true, &[(0, 8)], &[]),
                step(10, true, &[(0, 8)], &[]),
            ],
            vec![
                step(10, true, &[(1, 8)], &[]),
                step(30, true, &[(1, 8)], &[]),
            ],
        ];
        let iv = intervals(&steps).unwrap();
        let (most, mean) = between_collectives(&iv);
        assert!((most - 60e-6).abs() < 1e-15, "{most}");
        assert!((mean - 40e-6).abs() < 1e-15, "{mean}");
        // The replay pays the busiest rank of each interval.
        assert!(replay(&steps, &NET).unwrap() >= most);
    }

    #[test]
    fn by_site_tells_the_fit_and_the_imbalance_apart_by_the_ending_collective() {
        // Three collectives, at sites "a", "b", "a"; per rank count R, each
        // rank's work (µs) before each.
        let run = |work: &[[u64; 3]]| -> Vec<Vec<SyncStep>> {
            (work.iter())
                .map(|w| {
                    (w.iter().zip(["a", "b", "a"]))
                        .map(|(&us, site)| SyncStep {
                            site,
                            ..step(us, true, &[(0, 8)], &[])
                        })
                        .collect()
                })
                .collect()
        };
        // Busiest rank: interval 0 30 → 20 µs (a = 10, b = 40), interval 1
        // 14 → 14 (a = 14, b = 0), interval 2 12 → 6 (a = 0, b = 24).
        let two = run(&[[30, 14, 12], [10, 14, 0]]);
        let four = run(&[[20, 14, 6], [10, 14, 6], [10, 14, 6], [0, 14, 6]]);
        let measured = vec![
            (2, intervals(&two).unwrap()),
            (4, intervals(&four).unwrap()),
        ];
        assert_eq!(measured[1].1[1].site, "b");
        let sites = by_site(&measured);
        let close = |x: f64, us: f64| (x - us * 1e-6).abs() < 1e-12;
        assert_eq!(sites.len(), 2);
        // Largest Σ a first.
        let (b, a) = (&sites[0], &sites[1]);
        assert_eq!((b.site, b.intervals, a.site, a.intervals), ("b", 1, "a", 2));
        assert!(close(b.fit.0, 14.0) && close(b.fit.1, 0.0), "{b:?}");
        assert!(close(a.fit.0, 10.0) && close(a.fit.1, 64.0), "{a:?}");
        // At 4 ranks: "a" waits for 20 + 6 µs against a mean of 10 + 6.
        assert!(close(a.most, 26.0) && close(a.mean, 16.0), "{a:?}");
        assert!(close(b.most, 14.0) && close(b.mean, 14.0), "{b:?}");
        // The sites' sums are the whole fit's and the whole imbalance's.
        let whole = between_collectives(&measured[1].1);
        assert!((whole.0 - (a.most + b.most)).abs() < 1e-15);
        assert!((whole.1 - (a.mean + b.mean)).abs() < 1e-15);
    }

    #[test]
    fn the_fit_separates_repeated_from_shared_work() {
        // mean work 2 + 8 / R at R = 2, 4, 8: a = 2, b = 8.
        let (a, b) = fit_nonnegative(&[(0.5, 6.0), (0.25, 4.0), (0.125, 3.0)]);
        assert!(
            (a - 2.0).abs() < 1e-12 && (b - 8.0).abs() < 1e-12,
            "{a} {b}"
        );
        // Work that grows with R is all repeated: b clamps to 0.
        let (a, b) = fit_nonnegative(&[(0.5, 1.0), (0.25, 2.0)]);
        assert_eq!((a, b), (1.5, 0.0));
    }

    #[test]
    fn projection_reproduces_a_schedule_that_follows_the_model() {
        // Two intervals whose per-rank work is 1 + 6 / R ms (rank 0:
        // 1 + 9 / R, the busiest) and 3 / R ms; measured at 2 and 4 ranks.
        let make = |r: usize| {
            let steps: Vec<Vec<SyncStep>> = (0..r)
                .map(|q| {
                    vec![
                        step(
                            (1000.0 + (if q == 0 { 9000.0 } else { 6000.0 }) / r as f64) as u64,
                            true,
                            &[(q as u32, 40 / r as u64)],
                            &[],
                        ),
                        step(
                            (3000.0 / r as f64) as u64,
                            true,
                            &[(q as u32, 40 / r as u64)],
                            &[],
                        ),
                    ]
                })
                .collect();
            (r, intervals(&steps).unwrap(), replay(&steps, &NET).unwrap())
        };
        let (m2, m4) = (make(2), make(4));
        let p = project(&[(2, m2.1), (4, m4.1)], &[2, 4, 64], &NET).unwrap();
        assert!((p[0].seconds - m2.2).abs() < 1e-9, "{:?} vs {}", p[0], m2.2);
        assert!((p[1].seconds - m4.2).abs() < 1e-9, "{:?} vs {}", p[1], m4.2);
        let work64 = 1e-3 + 12e-3 / 64.0;
        assert!((p[2].work - work64).abs() < 1e-9, "{:?}", p[2]);
        assert!(p[2].collectives > p[1].collectives);
    }
}
