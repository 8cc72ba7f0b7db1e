//! A rank's share of the internal ticks when the run is spread over ranks
//! that each hold the whole state (`Executor::ranks() > 1`).
//!
//! Rank `r` evaluates the internal stencils of the partitions placed on it
//! ([`crate::internal::InternalForces::home_ranks`]), and folds and advances
//! the vertices it *owns*: the cloth vertices whose home partition is placed
//! on it, and a block of the others (obstacle vertices). Per internal tick
//! two exchanges keep every rank's state whole (Algorithm 1's messages, as
//! collectives):
//!
//! 1. **boundary slots**: each rank sends the output slots it computed that
//!    a vertex owned elsewhere folds — only stencils along partition
//!    boundaries between ranks;
//! 2. **new velocities** of the owned vertices, so every rank can apply the
//!    tick to every vertex (positions, trajectories) as on one memory.
//!
//! Each value is computed once, by its owner, and copied with its exact
//! bits; every fold reads the same slots in the same key order as on one
//! memory. So the bits do not change with the rank count.

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
    /// Per partition: evaluated on this rank.
    pub own_partition: Vec<bool>,
    /// Per vertex: folded and advanced on this rank.
    pub own_vertex: Vec<bool>,
    /// Per rank: the slots it sends (ascending): computed there, folded by a
    /// vertex another rank owns.
    pub sends: Vec<Vec<u32>>,
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
        let mut slot_rank = vec![0u32; internal.partitions.last().map_or(0, |p| p.slots.end)];
        for (p, part) in internal.partitions.iter().enumerate() {
            slot_rank[part.slots.clone()].fill(home[p]);
        }
        let mut sends = vec![Vec::new(); ranks];
        let mut owned = vec![Vec::new(); ranks];
        for i in 0..n {
            owned[owner[i] as usize].push(i as u32);
            for &s in internal.incidence(i) {
                let from = slot_rank[s as usize];
                if from != owner[i] {
                    sends[from as usize].push(s);
                }
            }
        }
        for list in &mut sends {
            list.sort_unstable();
            list.dedup();
        }
        RankShare {
            rank,
            ranks,
            own_partition: home.iter().map(|&r| r as usize == rank).collect(),
            home,
            own_vertex: owner.iter().map(|&r| r as usize == rank).collect(),
            sends,
            owned,
        }
    }

    /// **Collective.** Hands every rank the boundary slots the others
    /// computed (exchange 1).
    pub fn exchange_slots<E: Executor>(
        &self,
        exec: &E,
        out: &mut [DVec3],
    ) -> Result<(), CommError> {
        self.exchange(exec, out, &self.sends)
    }

    /// **Collective.** Hands every rank the new velocities of the vertices
    /// the others own (exchange 2).
    pub fn exchange_velocities<E: Executor>(
        &self,
        exec: &E,
        v_new: &mut [DVec3],
    ) -> Result<(), CommError> {
        self.exchange(exec, v_new, &self.owned)
    }

    /// Sends `data[lists[me]]`, and writes each peer `j`'s values into
    /// `data[lists[j]]`.
    fn exchange<E: Executor>(
        &self,
        exec: &E,
        data: &mut [DVec3],
        lists: &[Vec<u32>],
    ) -> Result<(), CommError> {
        let mine: Vec<DVec3> = lists[self.rank].iter().map(|&k| data[k as usize]).collect();
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
                data[k as usize] = value;
            }
        }
        Ok(())
    }
}
