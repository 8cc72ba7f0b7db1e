//! Which active stencils a penalty batch must look at.
//!
//! A stencil certified to stay outside the outermost layer `eta_1` until some
//! tick, as long as its vertices keep their velocities (`engine::sleep`), is
//! *asleep*: batches skip it without reading it. It wakes when that tick
//! comes (a min-heap of wake ticks) or when one of its vertices changes
//! velocity (a vertex → stencils index), whichever is first; an internal tick
//! changes every velocity and wakes them all. So a batch costs what its awake
//! stencils cost, not what the whole active set does.
//!
//! Skipping only ever drops stencils whose kicks are zero, so the results are
//! the same bits as visiting every stencil.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use weft_core::NONE;

use crate::clock::Tick;

/// The awake and asleep active stencils of one pass.
#[derive(Clone, Debug, Default)]
pub struct Dormancy {
    asleep: Vec<bool>,
    /// Bumped on every sleep, so stale heap entries are ignored.
    generation: Vec<u32>,
    due: BinaryHeap<Reverse<(Tick, u32, u32)>>,
    /// Awake stencils, unordered (`asleep[a]` false).
    awake: Vec<u32>,
    /// Vertex → active stencils (CSR).
    offsets: Vec<u32>,
    of_vertex: Vec<u32>,
}

impl Dormancy {
    /// Every stencil awake, for stencils on the vertices `stencils` (four
    /// each; `NONE` entries are vertices whose velocity never changes here,
    /// and are left out of the index) over `n` vertices.
    pub fn reset(&mut self, stencils: &[[u32; 4]], n: usize) {
        let m = stencils.len();
        self.asleep.clear();
        self.asleep.resize(m, false);
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

    /// The earliest tick at which an asleep stencil is due to wake (stale
    /// entries included: never later than the truth).
    pub fn next_due(&self) -> Option<Tick> {
        self.due.peek().map(|r| r.0 .0)
    }

    /// The awake stencils (unordered).
    pub fn awake(&self) -> &[u32] {
        &self.awake
    }

    /// Wakes the stencils whose wake tick is at or before `t`.
    pub fn wake_due(&mut self, t: Tick) {
        while let Some(&Reverse((at, a, generation))) = self.due.peek() {
            if at > t {
                break;
            }
            self.due.pop();
            if self.asleep[a as usize] && self.generation[a as usize] == generation {
                self.wake(a);
            }
        }
    }

    /// Wakes the stencils of vertex `i` (its velocity changed).
    pub fn wake_vertex(&mut self, i: usize) {
        let (s, e) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        for k in s..e {
            let a = self.of_vertex[k];
            if self.asleep[a as usize] {
                self.wake(a);
            }
        }
    }

    /// Wakes every stencil (every velocity changed).
    pub fn wake_all(&mut self) {
        if self.awake.len() == self.asleep.len() {
            return;
        }
        for a in 0..self.asleep.len() as u32 {
            if self.asleep[a as usize] {
                self.wake(a);
            }
        }
        self.due.clear();
    }

    fn wake(&mut self, a: u32) {
        self.asleep[a as usize] = false;
        self.awake.push(a);
    }

    /// Puts stencil `a` to sleep until tick `until` (`Tick::MAX`: until a
    /// velocity change). Call [`Dormancy::drop_sleepers`] after a round of
    /// these.
    pub fn sleep(&mut self, a: u32, until: Tick) {
        self.asleep[a as usize] = true;
        self.generation[a as usize] = self.generation[a as usize].wrapping_add(1);
        if until != Tick::MAX {
            self.due
                .push(Reverse((until, a, self.generation[a as usize])));
        }
    }

    /// Removes the stencils put to sleep from the awake list.
    pub fn drop_sleepers(&mut self) {
        let asleep = &self.asleep;
        self.awake.retain(|&a| !asleep[a as usize]);
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
        d.reset(&stencils, 8);
        let sorted = |d: &Dormancy| {
            let mut v = d.awake().to_vec();
            v.sort_unstable();
            v
        };
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        d.sleep(0, 10);
        d.sleep(1, Tick::MAX);
        d.sleep(2, 20);
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
        // Stencil 2's old wake tick is stale once it slept again.
        d.sleep(2, 100);
        d.drop_sleepers();
        d.wake_due(20);
        assert_eq!(sorted(&d), vec![0, 1]);
        d.sleep(0, 50);
        d.drop_sleepers();
        d.wake_all();
        assert_eq!(sorted(&d), vec![0, 1, 2]);
    }
}
