//! A rank's share of the internal ticks when the run is spread over ranks
//! that each hold every vertex's position and velocity (`Executor::ranks() >
//! 1`).
//!
//! Rank `r` evaluates the internal stencils of the partitions placed on it
//! ([`crate::internal::InternalForces::home_ranks`]), and folds and advances
//! the vertices it *owns*: the cloth vertices whose home partition is placed
//! on it, and a block of the others (obstacle vertices). Per internal tick
//! two exchanges keep every rank's state whole:
//!
//! 1. **boundary slots**, point to point (Algorithm 1 of the paper): each
//!    rank sends each neighbour the output slots it computed that a vertex
//!    the neighbour owns folds. The *boundary* partitions (those computing
//!    such a slot) are evaluated first, their slots sent, and the *interior*
//!    partitions evaluated while the messages travel;
//! 2. **new velocities** of the owned vertices, to every rank (a
//!    collective), so every rank can apply the tick to every vertex
//!    (positions, trajectories) as on one memory.
//!
//! Each value is computed once, by its owner, and copied with its exact
//! bits; every fold reads the same slots in the same key order as on one
//! memory. So the bits do not change with the rank count.

use std::collections::BTreeMap;

use glam::DVec3;
use weft_core::NONE;

use crate::executor::{place_in_blocks, CommError, Executor};
use crate::world::World;

/// What one rank computes of each internal tick, and what travels.
#[derive(Clone, Debug)]
pub struct RankShare {
    pub rank: usize,
    pub ranks: usize,
    /// Per partition: the rank it is placed on (its home rank).
    pub home: Vec<u32>,
    /// Per partition: evaluated on this rank and computes a slot another
    /// rank folds (evaluated first; its slots travel).
    pub boundary_partition: Vec<bool>,
    /// Per partition: evaluated on this rank, all its slots folded here
    /// (evaluated while the boundary slots travel).
    pub interior_partition: Vec<bool>,
    /// Per vertex: the rank that folds and advances it (its owner).
    pub owner: Vec<u32>,
    /// Per peer rank (ascending): the slots this rank computes that the
    /// peer's vertices fold (ascending).
    pub send_slots: Vec<(usize, Vec<u32>)>,
    /// Per peer rank (ascending): the slots the peer computes that this
    /// rank's vertices fold (ascending; the peer's `send_slots` for this
    /// rank).
    pub recv_slots: Vec<(usize, Vec<u32>)>,
    /// Per rank: the vertices it owns (ascending).
    pub owned: Vec<Vec<u32>>,
}

impl RankShare {
    /// The share of `rank` of `ranks` in `world`.
    pub fn new(world: &World, rank: usize, ranks: usize) -> Self {
        let internal = &world.internal;
        let home = internal.home_ranks(ranks);
        let n = world.num_vertices();
        // Vertices outside every partition (obstacles) in blocks.
        let blocks = place_in_blocks(n, ranks);
        let owner: Vec<u32> = (0..n)
            .map(|i| match world.partitioning.of_vertex.get(i) {
                Some(&p) if p != NONE => home[p as usize],
                _ => blocks[i],
            })
            .collect();
        let mut slot_partition = vec![0u32; internal.num_slots()];
        for (p, part) in internal.partitions.iter().enumerate() {
            slot_partition[part.slots.clone()].fill(p as u32);
        }
        // (from, to) → slots computed on `from`, folded on `to`.
        let mut travel: BTreeMap<(usize, usize), Vec<u32>> = BTreeMap::new();
        let mut owned = vec![Vec::new(); ranks];
        for i in 0..n {
            let to = owner[i] as usize;
            owned[to].push(i as u32);
            for &s in internal.incidence(i) {
                let from = home[slot_partition[s as usize] as usize] as usize;
                if from != to {
                    travel.entry((from, to)).or_default().push(s);
                }
            }
        }
        let mut boundary_partition = vec![false; home.len()];
        let mut send_slots = Vec::new();
        let mut recv_slots = Vec::new();
        for ((from, to), mut slots) in travel {
            slots.sort_unstable();
            slots.dedup();
            if from == rank {
                for &s in &slots {
                    boundary_partition[slot_partition[s as usize] as usize] = true;
                }
                send_slots.push((to, slots));
            } else if to == rank {
                recv_slots.push((from, slots));
            }
        }
        recv_slots.sort_unstable_by_key(|(from, _)| *from);
        let interior_partition = (0..home.len())
            .map(|p| home[p] as usize == rank && !boundary_partition[p])
            .collect();
        RankShare {
            rank,
            ranks,
            boundary_partition,
            interior_partition,
            home,
            owner,
            send_slots,
            recv_slots,
            owned,
        }
    }

    /// Whether vertex `i` is folded and advanced on this rank.
    #[inline]
    pub fn owns(&self, i: usize) -> bool {
        self.owner[i] as usize == self.rank
    }

    /// **Point to point with the neighbours.** Sends the boundary slots of
    /// `out` (computed already) to the ranks whose vertices fold them, runs
    /// `interior` while they travel, and writes the slots received into
    /// `out` (exchange 1).
    pub fn exchange_slots<E: Executor>(
        &self,
        exec: &E,
        out: &mut [DVec3],
        interior: &mut dyn FnMut(&mut [DVec3]),
    ) -> Result<(), CommError> {
        let sends: Vec<(usize, Vec<f64>)> = self
            .send_slots
            .iter()
            .map(|(peer, slots)| {
                let words = slots.iter().flat_map(|&k| out[k as usize].to_array());
                (*peer, words.collect())
            })
            .collect();
        let recvs: Vec<(usize, usize)> = self
            .recv_slots
            .iter()
            .map(|(peer, slots)| (*peer, 3 * slots.len()))
            .collect();
        let received = exec.exchange_words(sends, &recvs, &mut || interior(out))?;
        for ((_, slots), words) in self.recv_slots.iter().zip(received) {
            for (&k, c) in slots.iter().zip(words.chunks_exact(3)) {
                out[k as usize] = DVec3::new(c[0], c[1], c[2]);
            }
        }
        Ok(())
    }

    /// **Collective.** Hands every rank the new velocities of the vertices
    /// the others own (exchange 2).
    pub fn exchange_velocities<E: Executor>(
        &self,
        exec: &E,
        v_new: &mut [DVec3],
    ) -> Result<(), CommError> {
        let lists = &self.owned;
        let mine: Vec<DVec3> = lists[self.rank]
            .iter()
            .map(|&k| v_new[k as usize])
            .collect();
        let all = exec.all_gather_vectors(&mine)?;
        if all.len() != self.ranks {
            return Err(CommError(format!(
                "rank {}: an exchange brought {} parts for {} ranks",
                self.rank,
                all.len(),
                self.ranks
            )));
        }
        for (j, values) in all.into_iter().enumerate() {
            if j == self.rank {
                continue;
            }
            if values.len() != lists[j].len() {
                return Err(CommError(format!(
                    "rank {}: rank {j} sent {} values for {}",
                    self.rank,
                    values.len(),
                    lists[j].len()
                )));
            }
            for (&k, value) in lists[j].iter().zip(values) {
                v_new[k as usize] = value;
            }
        }
        Ok(())
    }
}
