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
//!   vertices stay under their speed caps, `engine::events::island::sleep`):
//!   reach = `m`, so batches of the deeper layers `m+1..` only (the frequent
//!   ones: `h_l` shrinks as `l^(-3/2)`) skip it;
//! * *asleep*: certified outside `eta_1` until some tick: reach 0, no batch
//!   reads it.
//!
//! A dozing or asleep stencil wakes (reach back to its depth) when its tick
//! comes (a min-heap of wake ticks) or when one of its vertices breaks its
//! certificate's assumption (a vertex → stencils index), whichever is first.
//!
//! ## Speed caps
//!
//! Each vertex has a **speed cap**, and a certificate assumes that its
//! vertices move no faster than their caps, not that they keep their
//! velocities. Every velocity change of a vertex is shown to
//! [`Dormancy::observe`]: a new speed above the cap wakes the vertex's
//! stencils and raises the cap ([`HEADROOM`] above the speed); under the cap
//! nothing wakes. An internal tick changes every velocity, usually a little:
//! under caps, a certificate outlives it, and an asleep island stays
//! asleep over many internal ticks instead of being read again after each.
//!
//! Lowering a cap needs no wake: a certificate made under a higher cap is
//! only woken sooner. Raising one does (its stencils' certificates may
//! assume the lower cap), so a cap rises only with a wake.
//!
//! A vertex also wakes its stencils after [`BREAKPOINTS_PER_WAKE`]
//! breakpoints, which bounds the rounding of the positions drifted over them
//! that a certificate must allow for.
//!
//! So a batch costs what the stencils that may kick in it cost, not what the
//! whole active set does.
//!
//! Skipping only ever drops stencils whose kicks are zero, so the results are
//! the same bits as visiting every stencil.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec3;
use weft_core::NONE;

use crate::clock::Tick;

/// A raised speed cap is this much above the speed that raised it.
pub const HEADROOM: f64 = 1.25;

/// A vertex wakes its stencils after this many breakpoints.
pub const BREAKPOINTS_PER_WAKE: u32 = 1024;

/// The reach of every active stencil of one pass.
#[derive(Clone, Debug, Default)]
pub struct Dormancy {
    /// Per stencil: its depth, and the outermost layers a batch must read
    /// it for (≤ depth; 0: asleep).
    depth: Vec<u32>,
    reach: Vec<u32>,
    /// Per stencil below its depth: the tick its reach is restored.
    until: Vec<Tick>,
    /// Wake ticks, `(until - base) << 32 | stencil` (one word: the heap
    /// costs a fifth of a contact-heavy pass's penalty work); an entry whose
    /// stencil is awake, or dozes until another tick, is stale and ignored.
    due: BinaryHeap<Reverse<u64>>,
    /// The tick wake ticks count from (the pass's start).
    base: Tick,
    /// `by_reach[r]`: the stencils of reach `r ≥ 1`, unordered (a batch
    /// whose outermost firing layer is `first` reads the lists `first..`
    /// only, and the schedule asks for the largest reach at every tick);
    /// `slot[a]`: stencil `a`'s place in its list.
    by_reach: Vec<Vec<u32>>,
    slot: Vec<u32>,
    /// Vertex → active stencils (CSR).
    offsets: Vec<u32>,
    of_vertex: Vec<u32>,
    /// Per vertex: its speed cap, and its breakpoints since it last woke
    /// its stencils.
    cap: Vec<f64>,
    since: Vec<u32>,
}

impl Dormancy {
    /// Every stencil awake, for stencils of the given depths on the vertices
    /// `stencils` (four each; `NONE` entries are vertices whose velocity never
    /// changes here, and are left out of the index) over `n` vertices; every
    /// speed cap 0 (show each vertex's velocity to [`Dormancy::observe`]
    /// before the first certificate); no wake tick before `base`.
    pub fn reset(&mut self, stencils: &[[u32; 4]], depths: &[u32], n: usize, base: Tick) {
        let m = stencils.len();
        self.depth.clear();
        self.depth.extend_from_slice(depths);
        self.reach.clear();
        self.reach.extend_from_slice(depths);
        self.until.clear();
        self.until.resize(m, 0);
        self.due.clear();
        self.base = base;
        let deepest = depths.iter().copied().max().unwrap_or(0) as usize;
        self.by_reach.iter_mut().for_each(Vec::clear);
        self.by_reach.resize(deepest + 1, Vec::new());
        self.slot.clear();
        self.slot.resize(m, 0);
        for (a, &d) in depths.iter().enumerate() {
            self.slot[a] = self.by_reach[d as usize].len() as u32;
            self.by_reach[d as usize].push(a as u32);
        }
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
        self.cap.clear();
        self.cap.resize(n, 0.0);
        self.since.clear();
        self.since.resize(n, 0);
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
    pub fn awake(&self) -> impl Iterator<Item = u32> + '_ {
        self.reading(1)
    }

    /// The stencils a batch whose outermost firing layer is `first` reads
    /// (reach at least `first`), unordered.
    pub fn reading(&self, first: u32) -> impl Iterator<Item = u32> + '_ {
        (self.by_reach.iter().skip(first.max(1) as usize)).flat_map(|list| list.iter().copied())
    }

    /// The largest reach of any stencil (0: all asleep).
    pub fn max_reach(&self) -> u32 {
        (self.by_reach.iter().skip(1))
            .rposition(|list| !list.is_empty())
            .map_or(0, |r| r as u32 + 1)
    }

    /// Stencil `a`'s reach: a batch whose outermost firing layer is deeper
    /// skips it.
    pub fn reach(&self, a: u32) -> u32 {
        self.reach[a as usize]
    }

    /// The earliest tick at which a dozing or asleep stencil is due to wake
    /// (stale entries included: never later than the truth).
    pub fn next_due(&self) -> Option<Tick> {
        self.due.peek().map(|r| self.base + (r.0 >> 32))
    }

    /// Wakes the stencils whose wake tick is at or before `t`.
    pub fn wake_due(&mut self, t: Tick) {
        while let Some(&Reverse(key)) = self.due.peek() {
            let at = self.base + (key >> 32);
            if at > t {
                break;
            }
            self.due.pop();
            let a = key as u32;
            let i = a as usize;
            if self.reach[i] < self.depth[i] && self.until[i] == at {
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

    /// Vertex `i`'s speed cap: a certificate may assume that it moves no
    /// faster until one of its stencils wakes.
    #[inline]
    pub fn cap(&self, i: usize) -> f64 {
        self.cap[i]
    }

    /// Vertex `i` has a new velocity `v` (and a breakpoint): wakes its
    /// stencils if its speed exceeds its cap (or is not finite) and raises
    /// the cap, or if it has had [`BREAKPOINTS_PER_WAKE`] breakpoints since
    /// it last woke them; lowers the cap when the speed fell below half of
    /// it (free: see the module docs).
    ///
    /// The test compares squares: the computed `|v|^2` and `cap^2` are
    /// within a few ulps of the exact ones, which the certificates' `2^-40`
    /// margin on the caps covers (`engine::events::island::sleep`).
    #[inline]
    pub fn observe(&mut self, i: usize, v: DVec3) {
        self.since[i] += 1;
        let s2 = v.length_squared();
        let cap = self.cap[i];
        if !(s2 <= cap * cap) || self.since[i] >= BREAKPOINTS_PER_WAKE {
            self.wake_vertex(i);
            // (a speed that is not finite gets an infinite cap: no
            // certificate then; NaN would read as 0 in `f64::max`)
            self.cap[i] = if s2 <= f64::MAX {
                s2.sqrt() * HEADROOM
            } else {
                f64::INFINITY
            };
            self.since[i] = 0;
        } else if 4.0 * s2 < cap * cap {
            self.cap[i] = s2.sqrt() * HEADROOM;
        }
    }

    fn wake(&mut self, a: u32) {
        let (reach, depth) = (self.reach[a as usize], self.depth[a as usize]);
        if reach < depth {
            self.set_reach(a, depth); // (its heap entry, if any, is stale now)
        }
    }

    /// Moves stencil `a` to the list of reach `r` (none for 0).
    fn set_reach(&mut self, a: u32, r: u32) {
        let i = a as usize;
        let old = self.reach[i] as usize;
        if old == r as usize {
            return;
        }
        if old > 0 {
            let list = &mut self.by_reach[old];
            let at = self.slot[i] as usize;
            list.swap_remove(at);
            if let Some(&moved) = list.get(at) {
                self.slot[moved as usize] = at as u32;
            }
        }
        if r > 0 {
            let list = &mut self.by_reach[r as usize];
            self.slot[i] = list.len() as u32;
            list.push(a);
        }
        self.reach[i] = r;
    }

    /// Lowers stencil `a`'s reach to `reach` (0: asleep) until tick `until`
    /// (`Tick::MAX`: until one of its vertices wakes it).
    pub fn doze(&mut self, a: u32, reach: u32, until: Tick) {
        let i = a as usize;
        debug_assert!(reach < self.depth[i]);
        debug_assert!(until > self.base);
        // A wake tick more than 2^32 ticks after the base wakes it there
        // instead (earlier is always safe).
        let until = if until == Tick::MAX {
            until
        } else {
            until.min(self.base + u32::MAX as Tick)
        };
        if reach == self.reach[i] && until <= self.until[i] {
            return; // what it certifies holds already, at least as long
        }
        self.set_reach(a, reach);
        self.until[i] = until;
        if until != Tick::MAX {
            self.due.push(Reverse((until - self.base) << 32 | a as u64));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stencils_wake_on_time_or_on_a_velocity_change() {
        // Vertex 1 never changes velocity (left out of the index).
        let stencils = [[0, NONE, 2, 3], [4, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[1, 1, 3], 8, 0);
        let sorted = |d: &Dormancy| {
            let mut v: Vec<u32> = d.awake().collect();
            v.sort_unstable();
            v
        };
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        d.doze(0, 0, 10);
        d.doze(1, 0, Tick::MAX);
        d.doze(2, 0, 20);
        assert!(d.awake().next().is_none());
        assert_eq!(d.next_due(), Some(10));
        d.wake_due(9);
        assert!(d.awake().next().is_none());
        d.wake_due(10);
        assert_eq!(sorted(&d), vec![0]);
        // Vertex 4 is in stencils 1 and 2.
        d.wake_vertex(4);
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        assert_eq!(d.reach(2), 3);
        // Stencil 2's old wake tick is stale once it slept again.
        d.doze(2, 0, 100);
        d.wake_due(20);
        assert_eq!(sorted(&d), vec![0, 1]);
    }

    #[test]
    fn a_velocity_change_wakes_only_above_the_cap_or_after_many_breakpoints() {
        let sorted = |d: &Dormancy| {
            let mut v: Vec<u32> = d.awake().collect();
            v.sort_unstable();
            v
        };
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[2, 2], 8, 0);
        for i in 0..8 {
            d.observe(i, DVec3::X);
        }
        assert_eq!(d.cap(0), HEADROOM);
        d.doze(0, 0, Tick::MAX);
        d.doze(1, 0, Tick::MAX);
        // Turning at the same speed, or up to the cap: nothing wakes.
        d.observe(1, DVec3::Y);
        d.observe(1, DVec3::Z * HEADROOM);
        assert!(d.awake().next().is_none());
        // Slower by more than half: the cap comes down, nothing wakes.
        d.observe(5, DVec3::X * 0.1);
        assert!(d.awake().next().is_none());
        assert_eq!(d.cap(5), 0.1 * HEADROOM);
        // Faster than the cap: the vertex's stencils wake, the cap rises.
        d.observe(5, DVec3::X * 0.2);
        assert_eq!(d.awake().collect::<Vec<_>>(), [1]);
        assert_eq!(d.cap(5), 0.2 * HEADROOM);
        // Stencil 0 wakes on its vertex's BREAKPOINTS_PER_WAKE-th
        // breakpoint since it last woke, however slow.
        for _ in 1..BREAKPOINTS_PER_WAKE {
            d.observe(2, DVec3::ZERO);
        }
        assert_eq!(d.awake().collect::<Vec<_>>(), [1]);
        d.observe(2, DVec3::ZERO);
        assert_eq!(sorted(&d), [0, 1]);
        // A speed that is not finite wakes, and leaves no finite cap.
        d.doze(0, 0, Tick::MAX);
        d.observe(3, DVec3::NAN);
        assert_eq!(sorted(&d), [0, 1]);
        assert_eq!(d.cap(3), f64::INFINITY);
    }

    #[test]
    fn a_dozing_stencil_stays_listed_with_a_lower_reach_until_it_wakes() {
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[5, 5], 8, 0);
        d.doze(0, 2, 30);
        assert_eq!(
            d.awake().count(),
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
        d.wake_due(40);
        assert_eq!((d.reach(1), d.awake().count()), (0, 1));
    }
}
