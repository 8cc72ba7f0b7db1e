//! Over ranks: the partitions placed again by the load the last window
//! measured.
//!
//! The partitions start placed by size (contiguous runs of about equal
//! internal-force work, [`crate::internal::InternalForces::home_ranks`]).
//! But a contact island runs whole on one rank, and with layer prediction
//! one giant island holds almost all the penalty work (the twister's 99.9 %
//! of the layer events): the rank holding it evaluates its partitions after
//! the island, and every other rank waits for it at each internal tick.
//!
//! So at each window start the ranks share what the last window's events
//! stage cost each of them — the work CPU of its islands and of the rest —
//! and the partitions are placed again in contiguous runs (METIS numbers
//! neighbouring parts close), each rank's run grown or shrunk by the slots
//! that bring its load to the mean at its own measured cost per slot: a
//! rank loaded with islands gets fewer. Only a largest load more than
//! [`TOLERATED_IMBALANCE`] above the mean is acted on. The islands keep their
//! homes, which count votes under the placement by size
//! ([`RankShare::reference_owner`]), so moving partitions away from an
//! island does not move the island after them.
//!
//! Which rank computes a value never changes its bits (each is computed
//! once, by its owner, and copied exactly; `weft-par/tests/determinism.rs`
//! holds every rank and partition count to one hash), so the placement can
//! follow measured times. Every rank computes it from the same gathered
//! numbers and so takes the same one.

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::DVec3;

use super::Engine;
use crate::executor::{CommError, Executor};
use crate::internal::Moved;
use crate::share::RankShare;
use weft_core::NONE;

/// The partitions are placed again only when the largest load of a rank
/// is this fraction above the mean (measured times vary from window to
/// window; each new placement costs every rank a rebuild of its share and
/// new homes for some trajectories).
pub(super) const TOLERATED_IMBALANCE: f64 = 0.05;

/// One rank's work CPU seconds in the events stage of a committed window:
/// its contact islands' segments and everything else.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct EventsLoad {
    pub(super) islands: f64,
    pub(super) rest: f64,
}

impl<E: Executor> Engine<E> {
    /// **Collective over ranks** (one all-gather, at a window start after
    /// a committed window). Places the partitions again by the load the
    /// last window measured, when its largest load is too far above the
    /// mean.
    pub(super) fn place_partitions_by_load(&mut self) -> Result<(), CommError> {
        let (Some(load), Some(share)) = (self.events_load.take(), &self.share) else {
            return Ok(());
        };
        let mine = [DVec3::new(load.islands, load.rest, 0.0)];
        let _site = crate::trace::site("placement by load");
        let all = self.exec.all_gather_vectors(&mine)?;
        let mut islands = Vec::with_capacity(all.len());
        let mut rest = Vec::with_capacity(all.len());
        for (r, got) in all.iter().enumerate() {
            let [load] = got[..] else {
                return Err(CommError(format!(
                    "rank {}: rank {r} sent {} loads instead of one",
                    share.rank,
                    got.len()
                )));
            };
            islands.push(load.x);
            rest.push(load.y);
        }
        let slots: Vec<usize> = (self.world.internal.partitions.iter())
            .map(|p| p.slots.len())
            .collect();
        if let Some(home) = place_by_load(&slots, &share.home, &islands, &rest) {
            self.place_partitions(home)?;
        }
        Ok(())
    }

    /// Over ranks, between windows, on every rank alike: places partition
    /// `p` on rank `home[p]` (this rank's share, which trajectories it
    /// stores, the broad phase's trees, and the internal elements it holds:
    /// a partition's move from the rank that held it, point to point).
    /// The engine does it itself by the measured load; any placement gives
    /// the same bits (held by `weft-par/tests/determinism.rs` with
    /// placements changed by hand).
    pub fn place_partitions(&mut self, home: Vec<u32>) -> Result<(), CommError> {
        let (rank, ranks) = (self.exec.rank(), self.exec.ranks());
        if ranks < 2 {
            return Ok(());
        }
        assert!(
            home.iter().all(|&r| (r as usize) < ranks),
            "a rank per partition"
        );
        self.move_elements(&home)?;
        self.placements += 1;
        let share = RankShare::placed(&self.world, rank, ranks, home.clone());
        self.traj.hold_only(share.owner.clone(), rank as u32);
        super::reserve_trajectories(&mut self.traj, &self.world);
        if let Some(predictor) = &mut self.predictor {
            predictor.hold_only(share.owner.clone(), rank as u32);
        }
        self.broad.spread(home);
        self.ws.placed_again(&share);
        self.share = Some(share);
        Ok(())
    }

    /// Over ranks, before the partitions are placed on `home`: each
    /// partition that changes rank sends its elements, and the folds of
    /// the vertices whose owner it makes (they move with it), from the rank
    /// that held them to the one it goes to (in one message per pair of
    /// ranks, partitions in order), and each rank holds those of its
    /// partitions and owned vertices under `home` from then on.
    fn move_elements(&mut self, home: &[u32]) -> Result<(), CommError> {
        let me = self.exec.rank() as u32;
        let old = &self.share.as_ref().expect("over ranks").home;
        let (internal, of_vertex) = (&self.world.internal, &self.world.partitioning.of_vertex);
        let mut moving: BTreeMap<usize, Vec<u32>> = (0..home.len())
            .filter(|&p| old[p] != home[p] && (old[p] == me || home[p] == me))
            .map(|p| (p, Vec::new()))
            .collect();
        for (i, &p) in of_vertex.iter().enumerate() {
            if let Some(vertices) = moving.get_mut(&(p as usize)) {
                vertices.push(i as u32);
            }
        }
        let mut sends: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
        // Per rank sending here: its partitions, in order, and their words.
        let mut recvs: BTreeMap<usize, (Vec<usize>, usize)> = BTreeMap::new();
        for (&p, vertices) in &moving {
            if old[p] == me {
                let words = sends.entry(home[p] as usize).or_default();
                words.extend(internal.partition_words(p, vertices));
            } else {
                let (parts, len) = recvs.entry(old[p] as usize).or_default();
                parts.push(p);
                *len += internal.moved_words(p, vertices);
            }
        }
        let lens: Vec<(usize, usize)> = recvs.iter().map(|(&r, &(_, len))| (r, len)).collect();
        let received =
            (self.exec).exchange_words(sends.into_iter().collect(), &lens, &mut || {})?;
        let mut arrived = Vec::new();
        for ((parts, _), words) in recvs.into_values().zip(received) {
            let mut at = 0;
            for p in parts {
                let vertices = moving.remove(&p).expect("listed above");
                let len = internal.moved_words(p, &vertices);
                let Some(words) = words.get(at..at + len) else {
                    return Err(CommError(format!(
                        "rank {me}: partition {p}'s elements arrived cut short"
                    )));
                };
                let words = words.to_vec();
                arrived.push(Moved {
                    partition: p,
                    vertices,
                    words,
                });
                at += len;
            }
        }
        let keep = |p: usize| home[p] == me;
        let folds = holds_fold(of_vertex, home, me);
        let internal = Arc::make_mut(&mut self.world.internal);
        (internal.place_again(keep, folds, arrived))
            .map_err(|m| CommError(format!("rank {me}: {m}")))
    }
}

/// Whether rank `me` holds vertex `i`'s fold (the slots it sums) with the
/// partitions on `home` (each vertex's partition `of_vertex`): its owner
/// does, the home of its partition; a vertex of no partition folds nothing.
pub(super) fn holds_fold<'a>(
    of_vertex: &'a [u32],
    home: &'a [u32],
    me: u32,
) -> impl Fn(usize) -> bool + 'a {
    move |i| (of_vertex.get(i)).is_none_or(|&p| p == NONE || home[p as usize] == me)
}

/// The partitions (of `slots` output slots each, now on ranks `home`)
/// placed for ranks whose islands cost `islands` and whose other work cost
/// `rest` (seconds, per rank): each rank's run of slots grown or shrunk by
/// what brings its load to the mean at its own cost per slot (the
/// partitions near an island cost more per slot than the others: they
/// fold its kicks), in contiguous runs. Measured again the next window,
/// the placement so converges on balance. `None` when the largest load is
/// within [`TOLERATED_IMBALANCE`] of the mean, the runs would not change, or
/// there is nothing to measure by.
pub(super) fn place_by_load(
    slots: &[usize],
    home: &[u32],
    islands: &[f64],
    rest: &[f64],
) -> Option<Vec<u32>> {
    let ranks = islands.len();
    let total_slots: usize = slots.iter().sum();
    let total_rest: f64 = rest.iter().sum();
    let finite = islands
        .iter()
        .chain(rest)
        .all(|s| s.is_finite() && *s >= 0.0);
    if ranks < 2 || rest.len() != ranks || total_slots == 0 || !finite || total_rest <= 0.0 {
        return None;
    }
    let mut held = vec![0usize; ranks];
    for (&r, &s) in home.iter().zip(slots) {
        held[r as usize] += s;
    }
    let load: Vec<f64> = islands.iter().zip(rest).map(|(i, r)| i + r).collect();
    let mean = load.iter().sum::<f64>() / ranks as f64;
    let peak = load.iter().copied().fold(0.0, f64::max);
    if peak <= (1.0 + TOLERATED_IMBALANCE) * mean {
        return None;
    }
    let mean_per_slot = total_rest / total_slots as f64;
    let room: Vec<f64> = (0..ranks)
        .map(|r| {
            let per_slot = match held[r] {
                0 => mean_per_slot,
                n => (rest[r] / n as f64).max(f64::MIN_POSITIVE),
            };
            (held[r] as f64 + (mean - load[r]) / per_slot).max(0.0)
        })
        .collect();
    if room.iter().sum::<f64>() <= 0.0 {
        return None;
    }
    let placed = place_by_room(slots, &room);
    (placed != home).then_some(placed)
}

/// Consecutive items of the given sizes placed on ranks in contiguous runs
/// proportional to `room` (rank order): item `k` goes to the rank whose run
/// contains its middle. A rank with no room gets no item.
fn place_by_room(sizes: &[usize], room: &[f64]) -> Vec<u32> {
    let total = sizes.iter().sum::<usize>() as f64;
    let all_room: f64 = room.iter().sum();
    // ends[r]: where rank r's run ends, in slots.
    let mut ends = Vec::with_capacity(room.len());
    let mut at = 0.0;
    for &r in room {
        at += r / all_room * total;
        ends.push(at);
    }
    let last = room.len() - 1;
    let mut before = 0usize;
    let mut rank = 0;
    sizes
        .iter()
        .map(|&size| {
            let mid = before as f64 + size as f64 / 2.0;
            before += size;
            while rank < last && mid >= ends[rank] {
                rank += 1;
            }
            rank as u32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn room_gives_contiguous_runs_in_proportion() {
        // Eight equal items, rank 1 with no room, rank 2 with three times
        // rank 0's.
        let placed = place_by_room(&[1; 8], &[1.0, 0.0, 3.0]);
        assert_eq!(placed, vec![0, 0, 2, 2, 2, 2, 2, 2]);
        let placed = place_by_room(&[4, 4, 4, 4], &[1.0, 1.0]);
        assert_eq!(placed, vec![0, 0, 1, 1]);
    }

    #[test]
    fn a_rank_loaded_with_islands_gets_fewer_partitions() {
        // 20 partitions of 10 slots on 2 ranks, rank 1 with islands as
        // costly as 100 slots: balanced, rank 1 keeps 50 slots, rank 0 150.
        let slots = vec![10; 20];
        let home: Vec<u32> = (0..20).map(|p| u32::from(p >= 10)).collect();
        let placed = place_by_load(&slots, &home, &[0.0, 1.0], &[1.0, 1.0]).expect("better");
        let on = |r: u32| {
            placed
                .iter()
                .zip(&slots)
                .filter(|(&h, _)| h == r)
                .map(|(_, s)| s)
                .sum::<usize>()
        };
        assert_eq!((on(0), on(1)), (150, 50));
        // Contiguous, in rank order.
        assert!(placed.windows(2).all(|w| w[0] <= w[1]));
        // Balanced already: kept.
        assert_eq!(
            place_by_load(&slots, &placed, &[0.0, 1.0], &[1.5, 0.5]),
            None
        );
        // Islands beyond the mean load: that rank gets no partition.
        let placed = place_by_load(&slots, &home, &[0.0, 5.0], &[1.0, 1.0]).expect("better");
        assert!(placed.iter().all(|&r| r == 0));
    }

    #[test]
    fn nothing_to_measure_by_keeps_the_placement() {
        let slots = vec![10; 4];
        let home = vec![0, 0, 1, 1];
        assert_eq!(place_by_load(&slots, &home, &[0.0], &[1.0]), None);
        assert_eq!(place_by_load(&slots, &home, &[0.0, 1.0], &[0.0, 0.0]), None);
        assert_eq!(
            place_by_load(&slots, &home, &[f64::NAN, 1.0], &[1.0, 1.0]),
            None
        );
        assert_eq!(
            place_by_load(&[0; 4], &home, &[0.0, 1.0], &[1.0, 1.0]),
            None
        );
    }
}
