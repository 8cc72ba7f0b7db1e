//! Where partitions and vertices live when the world is spread over ranks,
//! and what each rank must send and receive for internal forces.
//!
//! A rank owns the partitions placed on it and the vertices whose home
//! partition it owns. It evaluates its partitions' stencils, which also read
//! *ghost* vertices owned elsewhere; it folds the forces of the vertices it
//! owns, which also collect contributions (output slots) computed elsewhere.
//! A partition is *boundary* when it reads a ghost, *interior* otherwise: the
//! interior ones can run while the ghosts' positions are in flight
//! (Algorithm 1 of Ni, Kale, Tamstorf 2015).

use std::collections::{BTreeMap, BTreeSet};

use weft_core::NONE;
use weft_sim::share::RankShare;
use weft_sim::World;

/// Places partitions on `ranks` ranks: contiguous runs of partition ids with
/// about equal numbers of output slots (the internal-force work).
pub fn place_partitions(world: &World, ranks: usize) -> Vec<u32> {
    world.internal.home_ranks(ranks)
}

/// One rank's share.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RankPlan {
    /// Its partitions, boundary ones first (ascending within each kind).
    pub partitions: Vec<usize>,
    /// How many of `partitions` are boundary partitions.
    pub boundary: usize,
    /// The vertices it owns (ascending).
    pub owned: Vec<u32>,
    /// Owned vertices whose fold needs no remote slot (foldable before the
    /// contributions arrive), and the others.
    pub interior_vertices: Vec<u32>,
    pub boundary_vertices: Vec<u32>,
    /// Per peer rank: owned vertices whose state the peer reads (ascending).
    pub send_state: BTreeMap<u32, Vec<u32>>,
    /// Per peer rank: ghost vertices received from it (ascending; equal to the
    /// peer's `send_state` for this rank).
    pub recv_state: BTreeMap<u32, Vec<u32>>,
    /// Per peer rank: slots computed here that the peer's vertices fold.
    pub send_slots: BTreeMap<u32, Vec<u32>>,
    /// Per peer rank: slots computed there that this rank's vertices fold.
    pub recv_slots: BTreeMap<u32, Vec<u32>>,
}

/// The plans of all `ranks` ranks for `world`, with the partitions placed
/// by [`place_partitions`]. Which slots travel between which ranks is the
/// engine's own [`RankShare`] (the same lists the engine exchanges); the
/// plan adds the ghosts, for ranks that hold only what they own.
pub fn plan(world: &World, ranks: usize) -> Vec<RankPlan> {
    let internal = &world.internal;
    let rank_of_partition = place_partitions(world, ranks);
    let owner = |i: u32| -> u32 {
        let p = world.partitioning.of_vertex[i as usize];
        if p == NONE {
            NONE // an obstacle vertex: in no stencil of the internal forces
        } else {
            rank_of_partition[p as usize]
        }
    };
    let mut plans = vec![RankPlan::default(); ranks];
    let mut boundary_parts: Vec<Vec<usize>> = vec![Vec::new(); ranks];
    let mut interior_parts: Vec<Vec<usize>> = vec![Vec::new(); ranks];
    for p in 0..internal.partitions.len() {
        let r = rank_of_partition[p];
        let mut reads_ghost = false;
        for i in internal.slot_vertices(p) {
            let o = owner(i);
            if o != r {
                reads_ghost = true;
                plans[o as usize].send_state.entry(r).or_default().push(i);
                plans[r as usize].recv_state.entry(o).or_default().push(i);
            }
        }
        if reads_ghost {
            boundary_parts[r as usize].push(p);
        } else {
            interior_parts[r as usize].push(p);
        }
    }
    for (r, plan) in plans.iter_mut().enumerate() {
        let share = RankShare::new(world, r, ranks);
        let peers = |lists: Vec<(usize, Vec<u32>)>| -> BTreeMap<u32, Vec<u32>> {
            lists.into_iter().map(|(j, l)| (j as u32, l)).collect()
        };
        plan.send_slots = peers(share.send_slots);
        plan.recv_slots = peers(share.recv_slots);
        let remote: BTreeSet<u32> = plan.recv_slots.values().flatten().copied().collect();
        for i in 0..world.num_vertices() as u32 {
            if owner(i) != r as u32 {
                continue;
            }
            plan.owned.push(i);
            if internal
                .incidence(i as usize)
                .iter()
                .any(|s| remote.contains(s))
            {
                plan.boundary_vertices.push(i);
            } else {
                plan.interior_vertices.push(i);
            }
        }
        for list in plan
            .send_state
            .values_mut()
            .chain(plan.recv_state.values_mut())
        {
            list.sort_unstable();
            list.dedup();
        }
        plan.boundary = boundary_parts[r].len();
        plan.partitions = std::mem::take(&mut boundary_parts[r]);
        plan.partitions.append(&mut interior_parts[r]);
    }
    plans
}
