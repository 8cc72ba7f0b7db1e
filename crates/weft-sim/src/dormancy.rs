//! Which active stencils a penalty batch must look at.
//!
//! A batch at tick `t` fires layers `first..` (its outermost firing layer is
//! `first`, whose `eta` is the largest); a stencil whose distance is certainly
//! at least `eta_first` kicks zero in it. Each stencil has a **reach**: the
//! outermost layers it may still be inside. A batch reads a stencil only if
//! `first ≤ reach`.
//!
//! * *awake*: reach = its depth (every batch of its layers reads it);
//! * *dozing*: certified outside `eta_(m+1)` until some tick (as long as its
//!   vertices keep their velocities, `engine::events::island::sleep`): reach
//!   = `m`, so batches of the deeper layers `m+1..` only (the frequent ones:
//!   `h_l` shrinks as `l^(-3/2)`) skip it;
//! * *asleep*: certified outside `eta_1` until some tick: reach 0, no batch
//!   reads it.
//!
//! A dozing or asleep stencil wakes (reach back to its depth) when its tick
//! comes (a min-heap of wake ticks) or when one of its vertices changes
//! velocity (a vertex → stencils index), whichever is first; an internal
//! tick changes every velocity and wakes them all. So a batch costs what the
//! stencils that may kick in it cost, not what the whole active set does.
//!
//! Skipping only ever drops stencils whose kicks are zero, so the results are
//! the same bits as visiting every stencil.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use weft_core::NONE;

use crate::clock::Tick;

/// The reach of every active stencil of one pass.
#[derive(Clone, Debug, Default)]
pub struct Dormancy {
    /// Per stencil: its depth, and the outermost layers a batch must read
    /// it for (≤ depth; 0: asleep).
    depth: Vec<u32>,
    reach: Vec<u32>,
    /// Per stencil below its depth: the tick its reach is restored.
    until: Vec<Tick>,
    /// Bumped on every doze or sleep, so stale heap entries are ignored.
    generation: Vec<u32>,
    due: BinaryHeap<Reverse<(Tick, u32, u32)>>,
    /// Stencils with a reach above 0, unordered.
    awake: Vec<u32>,
    /// Vertex → active stencils (CSR).
    offsets: Vec<u32>,
    of_vertex: Vec<u32>,
}

impl Dormancy {
    /// Every stencil awake, for stencils of the given depths on the vertices
    /// `stencils` (four each; `NONE` entries are vertices whose velocity never
    /// changes here, and are left out of the index) over `n` vertices.
    pub fn reset(&mut self, stencils: &[[u32; 4]], depths: &[u32], n: usize) {
        let m = stencils.len();
        self.depth.clear();
        self.depth.extend_from_slice(depths);
        self.reach.clear();
        self.reach.extend_from_slice(depths);
        self.until.clear();
        self.until.resize(m, 0);
        self.generation.clear();
        self.generation.resize(m, 0);
        self.due.clear();
        self.awake.clear();
        self.awake.extend(0..m as u32);
        self.offsets.clear();
        self.offsets.resize(n + 1, 0);
        let listed = |v: &[u32; 4]| v.iter().copied().filter(|&i| i != NONE).collect::<Vec<_>>();
        for v in stencils {
            for i in listed(v) {
                self.offsets[i as usize + 1] += 1;
            }
        }
        for i in 0..n {
            self.offsets[i + 1] += self.offsets[i];
        }
        self.of_vertex.clear();
        self.of_vertex.resize(self.offsets[n] as usize, 0);
        let mut fill = self.offsets.clone();
        for (a, v) in stencils.iter().enumerate() {
            for i in listed(v) {
                self.of_vertex[fill[i as usize] as usize] = a as u32;
                fill[i as usize] += 1;
            }
        }
    }

    /// The stencils a batch may read (reach above 0), unordered.
    pub fn awake(&self) -> &[u32] {
        &self.awake
    }

    /// Stencil `a`'s reach: a batch whose outermost firing layer is deeper
    /// skips it.
    pub fn reach(&self, a: u32) -> u32 {
        self.reach[a as usize]
    }

    /// The earliest tick at which a dozing or asleep stencil is due to wake
    /// (stale entries included: never later than the truth).
    pub fn next_due(&self) -> Option<Tick> {
        self.due.peek().map(|r| r.0 .0)
    }

    /// Wakes the stencils whose wake tick is at or before `t`.
    pub fn wake_due(&mut self, t: Tick) {
        while let Some(&Reverse((at, a, generation))) = self.due.peek() {
            if at > t {
                break;
            }
            self.due.pop();
            if self.generation[a as usize] == generation {
                self.wake(a);
            }
        }
    }

    /// Wakes the stencils of vertex `i` (its velocity changed).
    pub fn wake_vertex(&mut self, i: usize) {
        let (s, e) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        for k in s..e {
            self.wake(self.of_vertex[k]);
        }
    }

    /// Wakes every stencil (every velocity changed).
    pub fn wake_all(&mut self) {
        for a in 0..self.reach.len() as u32 {
            self.wake(a);
        }
        self.due.clear();
    }

    fn wake(&mut self, a: u32) {
        let (reach, depth) = (self.reach[a as usize], self.depth[a as usize]);
        if reach < depth {
            if reach == 0 {
                self.awake.push(a);
            }
            self.reach[a as usize] = depth;
            // Its heap entry, if any, is stale now.
            self.generation[a as usize] = self.generation[a as usize].wrapping_add(1);
        }
    }

    /// Lowers stencil `a`'s reach to `reach` (0: asleep) until tick `until`
    /// (`Tick::MAX`: until a velocity change). Call
    /// [`Dormancy::drop_sleepers`] after a round of these.
    pub fn doze(&mut self, a: u32, reach: u32, until: Tick) {
        let i = a as usize;
        debug_assert!(reach < self.depth[i]);
        if reach == self.reach[i] && until <= self.until[i] {
            return; // what it certifies holds already, at least as long
        }
        self.reach[i] = reach;
        self.until[i] = until;
        self.generation[a as usize] = self.generation[a as usize].wrapping_add(1);
        if until != Tick::MAX {
            self.due
                .push(Reverse((until, a, self.generation[a as usize])));
        }
    }

    /// Removes the stencils put to sleep (reach 0) from the awake list.
    pub fn drop_sleepers(&mut self) {
        let reach = &self.reach;
        self.awake.retain(|&a| reach[a as usize] > 0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stencils_wake_on_time_on_a_velocity_change_or_all_at_once() {
        // Vertex 1 never changes velocity (left out of the index).
        let stencils = [[0, NONE, 2, 3], [4, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[1, 1, 3], 8);
        let sorted = |d: &Dormancy| {
            let mut v = d.awake().to_vec();
            v.sort_unstable();
            v
        };
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        d.doze(0, 0, 10);
        d.doze(1, 0, Tick::MAX);
        d.doze(2, 0, 20);
        d.drop_sleepers();
        assert!(d.awake().is_empty());
        assert_eq!(d.next_due(), Some(10));
        d.wake_due(9);
        assert!(d.awake().is_empty());
        d.wake_due(10);
        assert_eq!(sorted(&d), vec![0]);
        // Vertex 4 is in stencils 1 and 2.
        d.wake_vertex(4);
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        assert_eq!(d.reach(2), 3);
        // Stencil 2's old wake tick is stale once it slept again.
        d.doze(2, 0, 100);
        d.drop_sleepers();
        d.wake_due(20);
        assert_eq!(sorted(&d), vec![0, 1]);
        d.doze(0, 0, 50);
        d.drop_sleepers();
        d.wake_all();
        assert_eq!(sorted(&d), vec![0, 1, 2]);
    }

    #[test]
    fn a_dozing_stencil_stays_listed_with_a_lower_reach_until_it_wakes() {
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[5, 5], 8);
        d.doze(0, 2, 30);
        d.drop_sleepers();
        assert_eq!(
            d.awake().len(),
            2,
            "a dozing stencil is still read by outer layers"
        );
        assert_eq!((d.reach(0), d.reach(1)), (2, 5));
        d.wake_due(29);
        assert_eq!(d.reach(0), 2);
        d.wake_due(30);
        assert_eq!(d.reach(0), 5);
        // A velocity change wakes a dozing stencil at once, and its old
        // wake tick no longer counts.
        d.doze(1, 1, 40);
        d.wake_vertex(6);
        assert_eq!(d.reach(1), 5);
        d.doze(1, 0, 90);
        d.drop_sleepers();
        d.wake_due(40);
        assert_eq!((d.reach(1), d.awake().len()), (0, 1));
    }
}
