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
//! 2. **new velocities** of the owned vertices that another rank reads, to
//!    the ranks that read them (an all-to-all: each rank's first non-finite
//!    vertex and count of changed velocities to every rank, the velocities
//!    only where they are read): the vertices an internal stencil reads off
//!    its vertex's owner (the boundary) and those of contact islands placed
//!    off their owner ([`PassShare`]). A rank advances the vertices it owns
//!    or reads (by its partitions' stencils or its islands') at each
//!    internal tick; every other vertex it leaves as it was until the pass
//!    ends, when each rank hands every other its owned vertices' states
//!    (one collective per pass), so every rank holds every vertex's state
//!    again for the stages after the pass.
//!
//! Each rank's first vertex whose new state is not finite travels with its
//! velocities, so every rank stops the tick at the same vertex.
//!
//! Each value is computed once, by its owner, and copied with its exact
//! bits; every fold reads the same slots in the same key order as on one
//! memory. So the bits do not change with the rank count.

use std::collections::BTreeMap;

use glam::DVec3;
use weft_core::NONE;

use crate::executor::{place_in_blocks, CommError, Executor};
use crate::internal::InternalForces;
use crate::world::World;

/// The internal forces' output slots a fold reads: the world's on one
/// memory (`rank` none), a rank's over ranks ([`RankSlots`]: its own and
/// those it received, at their places there). The internal tick and the
/// layer predictor fold through it.
#[derive(Clone, Copy)]
pub(crate) struct Slots<'a> {
    pub(crate) out: &'a [DVec3],
    pub(crate) rank: Option<&'a RankSlots>,
}

impl Slots<'_> {
    /// The ordered fold of vertex `i`'s slots (over ranks, an owned one's).
    #[inline]
    pub(crate) fn fold(&self, internal: &InternalForces, i: usize) -> DVec3 {
        match self.rank {
            None => internal.fold(i, self.out),
            Some(rank) => rank.fold(i, self.out),
        }
    }
}

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
    /// Per vertex: its owner under the placement by size
    /// ([`crate::internal::InternalForces::home_ranks`]), whatever the
    /// placement now: where a contact island counts its vertices to find
    /// its home, so that moving partitions away from a rank loaded with
    /// islands does not move its islands after them.
    pub reference_owner: Vec<u32>,
    /// Per peer rank (ascending): the slots this rank computes that the
    /// peer's vertices fold (ascending).
    pub send_slots: Vec<(usize, Vec<u32>)>,
    /// Per peer rank (ascending): the slots the peer computes that this
    /// rank's vertices fold (ascending; the peer's `send_slots` for this
    /// rank).
    pub recv_slots: Vec<(usize, Vec<u32>)>,
    /// Per rank: the vertices it owns (ascending).
    pub owned: Vec<Vec<u32>>,
    /// Per vertex: an internal stencil of a partition placed on this rank
    /// reads it.
    pub read_here: Vec<bool>,
    /// Per vertex: owned here, and folds a slot computed on another rank
    /// (its fold waits for the boundary slots).
    pub folds_remote: Vec<bool>,
    /// Per vertex: follows a script (kinematic), so whoever keeps it
    /// current computes its new velocities ([`PassShare::scripted`]).
    pub scripted: Vec<bool>,
    /// Per vertex `i`: the ranks other than its owner whose partitions read
    /// it (`reader_ranks[reader_start[i]..reader_start[i + 1]]`, ascending).
    reader_start: Vec<u32>,
    reader_ranks: Vec<u32>,
    /// This rank's output slots ([`RankSlots`]): only its partitions' and
    /// those it receives, not the world's.
    pub slots: RankSlots,
}

/// Where a rank keeps the internal forces' output slots it computes or
/// folds: each of its partitions' slots in one run (partition `p`'s at
/// `bounds[p]..bounds[p + 1]`, an empty run for another rank's partition),
/// in partition order, then the slots received from each peer in one run
/// (in [`RankShare::recv_slots`] order). A rank so holds about its share
/// of the slots, not the world's (at 50k vertices the world's are 21 MB),
/// and each owned vertex folds its slots at these places in global key
/// order, the order of [`crate::internal::InternalForces::fold`].
#[derive(Clone, Debug, Default)]
pub struct RankSlots {
    /// Per partition the start of its run, and the end of the last (the
    /// evaluations' chunk bounds).
    pub bounds: Vec<usize>,
    /// How many slots the rank holds.
    pub len: usize,
    /// Per peer of [`RankShare::send_slots`]: the places of the slots sent.
    send: Vec<Vec<u32>>,
    /// Per peer of [`RankShare::recv_slots`]: where its slots go.
    recv_at: Vec<usize>,
    /// Per vertex `i` owned here, its slots' places in global key order
    /// (`fold_slots[fold_start[i]..fold_start[i + 1]]`; empty for others).
    fold_start: Vec<u32>,
    fold_slots: Vec<u32>,
}

impl RankSlots {
    /// The ordered fold of owned vertex `i`'s slots in `out` (laid out as
    /// this describes): the bits of the fold of the world's slots.
    #[inline]
    pub fn fold(&self, i: usize, out: &[DVec3]) -> DVec3 {
        let (a, b) = (self.fold_start[i] as usize, self.fold_start[i + 1] as usize);
        let mut sum = DVec3::ZERO;
        for &s in &self.fold_slots[a..b] {
            sum += out[s as usize];
        }
        sum
    }
}

/// What a rank keeps current through one pass's internal ticks.
#[derive(Clone, Debug, Default)]
pub struct PassShare {
    /// Per vertex: advanced on this rank at every internal tick (owned
    /// here, or read here: by a partition or an island placed here).
    pub live: Vec<bool>,
    /// Per peer rank: the vertices this rank owns that the peer keeps live
    /// (ascending), whose new velocities it sends there at each internal
    /// tick.
    pub send: Vec<Vec<u32>>,
    /// Per peer rank: the vertices the peer owns that this rank keeps live
    /// (ascending; the peer's `send` for this rank).
    pub recv: Vec<Vec<u32>>,
    /// The scripted vertices this rank keeps live and does not own
    /// (ascending): their new velocity at an internal tick is their
    /// script's chord from their position there, which this rank computes
    /// itself with the owner's bits, so it is neither sent nor received.
    /// (In `send` and `recv` they would go from the rod's owner to every
    /// rank at every internal tick: on the 50k twister over 32 ranks, 60
    /// MB a window from one rank.)
    pub scripted: Vec<u32>,
}

/// A peer rank and slots (global numbers) that travel to or from it.
type PeerSlots = (usize, Vec<u32>);

/// Rank `rank`'s [`RankSlots`], its partitions placed on ranks `home`,
/// vertices owned as `owner` says, with the slots it sends and receives
/// (global slot numbers).
fn rank_slots(
    world: &World,
    rank: usize,
    (home, owner): (&[u32], &[u32]),
    (send_slots, recv_slots): (&[PeerSlots], &[PeerSlots]),
) -> RankSlots {
    let internal = &world.internal;
    let mut bounds = Vec::with_capacity(home.len() + 1);
    let mut len = 0;
    for (p, part) in internal.partitions.iter().enumerate() {
        bounds.push(len);
        if home[p] as usize == rank {
            len += part.slots.len();
        }
    }
    bounds.push(len);
    // The place of each slot of this rank's partitions: a partition's runs
    // keep their order, so a binary search over the partitions finds it.
    let starts: Vec<usize> = internal.partitions.iter().map(|p| p.slots.start).collect();
    let own_place = |s: u32| -> u32 {
        let p = starts.partition_point(|&start| start <= s as usize) - 1;
        debug_assert_eq!(home[p] as usize, rank, "slot {s} is not computed here");
        (bounds[p] + s as usize - starts[p]) as u32
    };
    let send = (send_slots.iter())
        .map(|(_, slots)| slots.iter().map(|&s| own_place(s)).collect())
        .collect();
    let mut recv_at = Vec::with_capacity(recv_slots.len());
    // (global slot, place) of the received slots, sorted by slot.
    let mut received: Vec<(u32, u32)> = Vec::new();
    for (_, slots) in recv_slots {
        recv_at.push(len);
        received.extend(
            slots
                .iter()
                .enumerate()
                .map(|(k, &s)| (s, (len + k) as u32)),
        );
        len += slots.len();
    }
    received.sort_unstable();
    let place = |s: u32| -> u32 {
        match received.binary_search_by_key(&s, |&(slot, _)| slot) {
            Ok(k) => received[k].1,
            Err(_) => own_place(s),
        }
    };
    let n = world.num_vertices();
    let mut fold_start = Vec::with_capacity(n + 1);
    let mut fold_slots = Vec::new();
    for i in 0..n {
        fold_start.push(fold_slots.len() as u32);
        if owner[i] as usize == rank {
            fold_slots.extend(internal.incidence(i).iter().map(|&s| place(s)));
        }
    }
    fold_start.push(fold_slots.len() as u32);
    RankSlots {
        bounds,
        len,
        send,
        recv_at,
        fold_start,
        fold_slots,
    }
}

impl RankShare {
    /// The share of `rank` of `ranks` in `world`, the partitions placed by
    /// size ([`crate::internal::InternalForces::home_ranks`]).
    pub fn new(world: &World, rank: usize, ranks: usize) -> Self {
        Self::placed(world, rank, ranks, world.internal.home_ranks(ranks))
    }

    /// The share of `rank` of `ranks` in `world` with partition `p` placed
    /// on rank `home[p]`.
    pub fn placed(world: &World, rank: usize, ranks: usize, home: Vec<u32>) -> Self {
        let internal = &world.internal;
        assert_eq!(
            home.len(),
            internal.partitions.len(),
            "a rank per partition"
        );
        let n = world.num_vertices();
        // Vertices outside every partition (obstacles) in blocks.
        let blocks = place_in_blocks(n, ranks);
        let owner_under = |home: &[u32]| -> Vec<u32> {
            (0..n)
                .map(|i| match world.partitioning.of_vertex.get(i) {
                    Some(&p) if p != NONE => home[p as usize],
                    _ => blocks[i],
                })
                .collect()
        };
        let owner = owner_under(&home);
        let reference_owner = owner_under(&internal.home_ranks(ranks));
        // The partition of a slot (the partitions' slots are consecutive
        // runs in partition order).
        let starts: Vec<usize> = internal.partitions.iter().map(|p| p.slots.start).collect();
        let slot_partition = |s: u32| starts.partition_point(|&start| start <= s as usize) - 1;
        // (from, to) → slots computed on `from`, folded on `to`, of this
        // rank's: what it receives for the vertices it owns (their folds
        // are held here), and what its partitions compute for the dynamic
        // vertices (those that fold) another rank owns.
        let mut travel: BTreeMap<(usize, usize), Vec<u32>> = BTreeMap::new();
        let mut owned = vec![Vec::new(); ranks];
        let mut folds_remote = vec![false; n];
        for i in 0..n {
            let to = owner[i] as usize;
            owned[to].push(i as u32);
            if to != rank {
                continue;
            }
            for &s in internal.incidence(i) {
                let from = home[slot_partition(s)] as usize;
                if from != to {
                    travel.entry((from, to)).or_default().push(s);
                    folds_remote[i] = true;
                }
            }
        }
        for p in (0..home.len()).filter(|&p| home[p] as usize == rank) {
            let first = internal.partitions[p].slots.start;
            for (k, i) in internal.slot_vertices(p).into_iter().enumerate() {
                let to = owner[i as usize] as usize;
                if to != rank && world.inv_mass[i as usize] > 0.0 {
                    travel
                        .entry((rank, to))
                        .or_default()
                        .push((first + k) as u32);
                }
            }
        }
        // What a partition's elements read: their vertices, kinematic ones
        // too (those fold no slot). (Every rank has these lists whole; the
        // elements themselves only of its own partitions.)
        let mut read_here = vec![false; n];
        let mut off_owner: Vec<(u32, u32)> = Vec::new();
        for p in 0..internal.partitions.len() {
            for &i in internal.reads(p) {
                if owner[i as usize] != home[p] {
                    off_owner.push((i, home[p]));
                }
                if home[p] as usize == rank {
                    read_here[i as usize] = true;
                }
            }
        }
        off_owner.sort_unstable();
        off_owner.dedup();
        let mut reader_start = vec![0u32; n + 1];
        for &(i, _) in &off_owner {
            reader_start[i as usize + 1] += 1;
        }
        for i in 0..n {
            reader_start[i + 1] += reader_start[i];
        }
        let reader_ranks = off_owner.iter().map(|&(_, r)| r).collect();
        let mut boundary_partition = vec![false; home.len()];
        let mut send_slots = Vec::new();
        let mut recv_slots = Vec::new();
        for ((from, to), mut slots) in travel {
            slots.sort_unstable();
            slots.dedup();
            if from == rank {
                for &s in &slots {
                    boundary_partition[slot_partition(s)] = true;
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
        let slots = rank_slots(world, rank, (&home, &owner), (&send_slots, &recv_slots));
        RankShare {
            rank,
            ranks,
            boundary_partition,
            interior_partition,
            home,
            owner,
            reference_owner,
            send_slots,
            recv_slots,
            owned,
            read_here,
            folds_remote,
            reader_start,
            reader_ranks,
            slots,
            scripted: world.script_of.iter().map(Option::is_some).collect(),
        }
    }

    /// The ranks other than vertex `i`'s owner whose partitions read it
    /// (ascending).
    pub fn readers(&self, i: usize) -> &[u32] {
        &self.reader_ranks[self.reader_start[i] as usize..self.reader_start[i + 1] as usize]
    }

    /// The share of a pass whose contact islands read the vertices
    /// `island_reads` (vertex, the rank its island runs on): this rank keeps
    /// current those it owns or reads, receives the new velocities of those
    /// it reads off their owner, and sends its own to the ranks that read
    /// them; a scripted vertex's new velocity is computed where it is
    /// kept current, never sent ([`PassShare::scripted`]).
    pub fn pass(&self, island_reads: impl IntoIterator<Item = (u32, u32)>) -> PassShare {
        let me = self.rank as u32;
        let mut live = self.read_here.clone();
        let mut send = vec![Vec::new(); self.ranks];
        for (i, r) in island_reads {
            if r == me {
                live[i as usize] = true;
            } else if self.owns(i as usize) && !self.scripted[i as usize] {
                send[r as usize].push(i);
            }
        }
        let mut recv = vec![Vec::new(); self.ranks];
        let mut scripted = Vec::new();
        for (i, l) in live.iter_mut().enumerate() {
            if self.owns(i) {
                *l = true;
                if !self.scripted[i] {
                    for &r in self.readers(i) {
                        send[r as usize].push(i as u32);
                    }
                }
            } else if *l && self.scripted[i] {
                scripted.push(i as u32);
            } else if *l {
                recv[self.owner[i] as usize].push(i as u32);
            }
        }
        for list in &mut send {
            list.sort_unstable();
            list.dedup();
        }
        PassShare {
            live,
            send,
            recv,
            scripted,
        }
    }

    /// Vertex `i` is kept current on rank `rank` from now on in the pass
    /// `pass` (over ranks, a unit holding it moved there): there it is
    /// live and received off its owner at the internal ticks, and its owner
    /// sends it there (a scripted vertex's computed there instead). Every
    /// rank calls this alike. Returns whether it became live here.
    pub fn keep_live(&self, pass: &mut PassShare, i: usize, rank: u32) -> bool {
        let owner = self.owner[i];
        let me = self.rank as u32;
        if rank == owner {
            return false;
        }
        let add = |list: &mut Vec<u32>| {
            if let Err(at) = list.binary_search(&(i as u32)) {
                list.insert(at, i as u32);
            }
        };
        let scripted = self.scripted[i];
        if rank == me {
            if pass.live[i] {
                return false;
            }
            pass.live[i] = true;
            add(if scripted {
                &mut pass.scripted
            } else {
                &mut pass.recv[owner as usize]
            });
            return true;
        }
        if owner == me && !scripted {
            add(&mut pass.send[rank as usize]);
        }
        false
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
        let sends: Vec<(usize, Vec<f64>)> = (self.send_slots.iter())
            .zip(&self.slots.send)
            .map(|((peer, _), places)| {
                let words = places.iter().flat_map(|&k| out[k as usize].to_array());
                (*peer, words.collect())
            })
            .collect();
        let recvs: Vec<(usize, usize)> = self
            .recv_slots
            .iter()
            .map(|(peer, slots)| (*peer, 3 * slots.len()))
            .collect();
        let received = exec.exchange_words(sends, &recvs, &mut || interior(out))?;
        for (&at, words) in self.slots.recv_at.iter().zip(received) {
            for (k, c) in words.chunks_exact(3).enumerate() {
                out[at + k] = DVec3::new(c[0], c[1], c[2]);
            }
        }
        Ok(())
    }

    /// **Collective** (an all-to-all). Sends the new velocities of the
    /// owned vertices other ranks read to those ranks, receives those this
    /// rank reads off their owners, and agrees on the first vertex whose new
    /// state is not finite and on how many vertices before it change
    /// velocity (exchange 2). `bad` is this rank's first among the vertices
    /// it owns, `changed` how many it owns before it change velocity, and
    /// `changed_below(v_new, b)` how many it owns before `b` change velocity
    /// (asked only when another rank's `bad` comes first: one more
    /// collective, in a pass that is about to end). Returns the first `bad`
    /// over all ranks and the vertices before it that change velocity, over
    /// all ranks.
    pub fn exchange_velocities<E: Executor>(
        &self,
        exec: &E,
        pass: &PassShare,
        v_new: &mut [DVec3],
        (bad, changed): (Option<usize>, usize),
        changed_below: &dyn Fn(&[DVec3], usize) -> usize,
    ) -> Result<(Option<usize>, usize), CommError> {
        // The head: `bad` (none: all ones) and `changed`.
        let flag = bad.map_or(u64::MAX, |b| b as u64);
        let parts: Vec<Vec<DVec3>> = (pass.send.iter())
            .map(|list| list.iter().map(|&k| v_new[k as usize]).collect())
            .collect();
        let (heads, parts) = exec.all_to_all_vectors(vec![flag, changed as u64], parts)?;
        if heads.len() != self.ranks || parts.len() != self.ranks {
            return Err(CommError(format!(
                "rank {}: an exchange brought {} heads for {} ranks",
                self.rank,
                heads.len(),
                self.ranks
            )));
        }
        let mut first = bad;
        for (j, head) in heads.iter().enumerate() {
            if head.len() != 2 {
                return Err(CommError(format!(
                    "rank {}: rank {j} sent a head of {} words",
                    self.rank,
                    head.len()
                )));
            }
            if head[0] != u64::MAX {
                first = Some(first.map_or(head[0] as usize, |f| f.min(head[0] as usize)));
            }
        }
        for (j, part) in parts.into_iter().enumerate() {
            if j == self.rank {
                continue;
            }
            let list = &pass.recv[j];
            let values = part;
            if values.len() != list.len() {
                return Err(CommError(format!(
                    "rank {}: rank {j} sent {} velocities for {}",
                    self.rank,
                    values.len(),
                    list.len()
                )));
            }
            for (&k, value) in list.iter().zip(values) {
                v_new[k as usize] = value;
            }
        }
        let Some(b) = first else {
            return Ok((None, heads.iter().map(|h| h[1] as usize).sum()));
        };
        // Each rank counted up to its own first non-finite vertex; count
        // again up to the first of all (its rank's count stands).
        let mine = if heads[self.rank][0] == b as u64 {
            changed
        } else {
            changed_below(v_new, b)
        };
        let mine = [DVec3::new(f64::from_bits(mine as u64), 0.0, 0.0)];
        let all = self.gathered(exec.all_gather_vectors(&mine)?)?;
        let below = all
            .iter()
            .map(|v| v.first().map_or(0, |c| c.x.to_bits() as usize));
        Ok((first, below.sum()))
    }

    /// **Collective.** Hands every rank the states of the vertices the
    /// others own (at the end of a pass: what the ranks did not keep
    /// current), with their exact bits.
    pub fn gather_states<E: Executor>(
        &self,
        exec: &E,
        x: &mut [DVec3],
        v: &mut [DVec3],
        tau: &mut [crate::clock::Tick],
        traj: &mut crate::trajectory::Trajectories,
    ) -> Result<(), CommError> {
        let lists = &self.owned;
        // Per vertex: x, v, and tau, the breakpoint count and the last
        // breakpoint's time as the bits of the third entry.
        let mine: Vec<DVec3> = (lists[self.rank].iter())
            .flat_map(|&k| {
                let k = k as usize;
                let (count, last) = traj.tally(k);
                let bits = f64::from_bits;
                [
                    x[k],
                    v[k],
                    DVec3::new(bits(tau[k]), bits(count.into()), last),
                ]
            })
            .collect();
        let all = self.gathered(exec.all_gather_vectors(&mine)?)?;
        for (j, values) in all.into_iter().enumerate() {
            if j == self.rank {
                continue;
            }
            if values.len() != 3 * lists[j].len() {
                return Err(CommError(format!(
                    "rank {}: rank {j} sent {} values for {} states",
                    self.rank,
                    values.len(),
                    lists[j].len()
                )));
            }
            for (&k, c) in lists[j].iter().zip(values.chunks_exact(3)) {
                let k = k as usize;
                (x[k], v[k], tau[k]) = (c[0], c[1], c[2].x.to_bits());
                traj.set_tally(k, (c[2].y.to_bits() as u32, c[2].z));
            }
        }
        Ok(())
    }

    /// The parts of an all-gather, checked one per rank.
    fn gathered(&self, all: Vec<Vec<DVec3>>) -> Result<Vec<Vec<DVec3>>, CommError> {
        if all.len() != self.ranks {
            return Err(CommError(format!(
                "rank {}: an exchange brought {} parts for {} ranks",
                self.rank,
                all.len(),
                self.ranks
            )));
        }
        Ok(all)
    }
}
