//! Overlap queries by simultaneous descent.
//!
//! A stack of node pairs `(a, b)` whose bounds overlap. For `a == b` the node is
//! paired with itself: a leaf tests its leaves pairwise, an internal node pushes
//! `(l, l)`, `(r, r)` and, if their bounds overlap, `(l, r)`. For `a != b` the
//! subtrees are disjoint: two leaves test all cross pairs, otherwise the node
//! with more leaves (an internal one) is opened and each child whose bounds
//! overlap the other node is pushed. Every unordered pair of distinct leaves is
//! therefore examined at most once, and it is examined whenever the two leaf DOPs
//! overlap (all their ancestors' bounds then overlap too). The stack is a local
//! heap `Vec` (one allocation per query, not per pair), so deep trees (1e6
//! leaves and more) cannot overflow the call stack.
//!
//! # Tasks
//!
//! [`self_overlap_tasks`](Bvh::self_overlap_tasks) expands the root pair
//! `(0, 0)` breadth-first with the same rules until there are enough node pairs
//! (or only leaf-level pairs are left), and [`overlaps_from`](Bvh::overlaps_from)
//! runs the descent from one such pair. The subtrees of pair space below the
//! tasks are disjoint and together cover exactly what the descent from the root
//! covers, so the union of the tasks' reports is [`self_overlaps`](Bvh::self_overlaps)'s
//! (each pair exactly once), and tasks can run in any order or in parallel.

use super::{Bvh, Node};

impl Bvh {
    /// Calls `f(i, j)` with `i < j` exactly once for every pair of distinct
    /// leaves whose DOPs overlap (adjacent triangles included; a leaf is never
    /// paired with itself). The call order is deterministic but unspecified.
    pub fn self_overlaps(&self, f: impl FnMut(u32, u32)) {
        self.overlaps_from((0, 0), f);
    }

    /// Splits [`self_overlaps`](Bvh::self_overlaps) into independent tasks: the
    /// node pairs reached by expanding the root pair `(0, 0)` breadth-first with
    /// the descent's rules until there are at least `min_tasks` pairs or none
    /// is left to expand (pairs whose next step only tests leaves stay as they
    /// are). Running [`overlaps_from`](Bvh::overlaps_from) on every task reports
    /// every overlapping pair of distinct leaves exactly once in total.
    ///
    /// Deterministic; empty for an empty tree, `[(0, 0)]` when `min_tasks <= 1`.
    pub fn self_overlap_tasks(&self, min_tasks: usize) -> Vec<(u32, u32)> {
        let mut tasks = Vec::new();
        self.self_overlap_tasks_into(min_tasks, &mut tasks);
        tasks
    }

    /// [`self_overlap_tasks`](Bvh::self_overlap_tasks) into `tasks` (cleared
    /// first; its capacity is reused).
    pub fn self_overlap_tasks_into(&self, min_tasks: usize, tasks: &mut Vec<(u32, u32)>) {
        tasks.clear();
        if self.nodes.is_empty() {
            return;
        }
        // `tasks[..done]` are leaf-level pairs kept as they are; `tasks[head..]`
        // is the FIFO queue of pairs still to expand (`tasks[done..head]` are
        // expanded pairs, dropped at the end).
        tasks.push((0, 0));
        let (mut done, mut head) = (0, 0);
        let mut children = Vec::with_capacity(3);
        while head < tasks.len() && done + (tasks.len() - head) < min_tasks {
            let pair = tasks[head];
            head += 1;
            if self.is_leaf_level(pair) {
                tasks.swap(done, head - 1);
                done += 1;
                continue;
            }
            children.clear();
            self.step(pair, &mut children, &mut |_, _| {
                unreachable!("an internal pair tests no leaves")
            });
            tasks.extend_from_slice(&children);
        }
        tasks.drain(done..head);
    }

    /// Calls `f(i, j)` with `i < j` once for every pair of distinct overlapping
    /// leaves found by the descent from the node pair `task` (one of
    /// [`self_overlap_tasks`](Bvh::self_overlap_tasks); `(0, 0)` is the whole
    /// tree). The call order is deterministic but unspecified.
    pub fn overlaps_from(&self, task: (u32, u32), mut f: impl FnMut(u32, u32)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack: Vec<(u32, u32)> = vec![task];
        while let Some(pair) = stack.pop() {
            self.step(pair, &mut stack, &mut f);
        }
    }

    /// True when the next step of `pair` tests leaves and pushes nothing.
    #[inline]
    fn is_leaf_level(&self, (a, b): (u32, u32)) -> bool {
        self.nodes[a as usize].is_leaf() && self.nodes[b as usize].is_leaf()
    }

    /// One step of the self-descent for the node pair `(a, b)` of overlapping
    /// bounds: reports leaf pairs (`i < j`) through `f`, pushes child pairs.
    #[inline]
    fn step(&self, (a, b): (u32, u32), stack: &mut Vec<(u32, u32)>, f: &mut impl FnMut(u32, u32)) {
        let na = self.nodes[a as usize];
        if a == b {
            if na.is_leaf() {
                let r = na.range();
                for i in r.clone() {
                    for j in i + 1..r.end {
                        if self.leaf_bounds[i].overlaps(&self.leaf_bounds[j]) {
                            f_sorted(f, self.order[i], self.order[j]);
                        }
                    }
                }
            } else {
                let (l, r) = (na.child, na.child + 1);
                stack.push((l, l));
                stack.push((r, r));
                if self.bounds[l as usize].overlaps(&self.bounds[r as usize]) {
                    stack.push((l, r));
                }
            }
            return;
        }
        let nb = self.nodes[b as usize];
        self.descend_pair(self, a, na, b, nb, stack, &mut |i, j| f_sorted(f, i, j));
    }

    /// Calls `f(i, j)` once for every leaf `i` of `self` and leaf `j` of `other`
    /// whose DOPs overlap. The call order is deterministic but unspecified.
    pub fn overlaps_with(&self, other: &Bvh, f: impl FnMut(u32, u32)) {
        if self.roots_overlap(other) {
            self.overlaps_with_from(other, (0, 0), f);
        }
    }

    /// Splits [`overlaps_with`](Bvh::overlaps_with)`(other, ..)` into
    /// independent tasks, as [`self_overlap_tasks_into`](Bvh::self_overlap_tasks_into)
    /// does for the self-descent: the node pairs (`a` in `self`, `b` in
    /// `other`) reached by expanding the root pair breadth-first until there
    /// are at least `min_tasks` of them or only leaf pairs are left. Running
    /// [`overlaps_with_from`](Bvh::overlaps_with_from) on every task reports
    /// every overlapping leaf pair exactly once in total (the subtrees of pair
    /// space below the tasks are disjoint and cover the whole descent).
    ///
    /// `tasks` is cleared first; empty when either tree is empty or the roots
    /// do not overlap.
    pub fn cross_overlap_tasks_into(
        &self,
        other: &Bvh,
        min_tasks: usize,
        tasks: &mut Vec<(u32, u32)>,
    ) {
        tasks.clear();
        if !self.roots_overlap(other) {
            return;
        }
        // Same queue discipline as the self version: `tasks[..done]` are leaf
        // pairs, `tasks[head..]` the pairs still to expand.
        tasks.push((0, 0));
        let (mut done, mut head) = (0, 0);
        let mut children = Vec::with_capacity(2);
        while head < tasks.len() && done + (tasks.len() - head) < min_tasks {
            let (a, b) = tasks[head];
            head += 1;
            let (na, nb) = (self.nodes[a as usize], other.nodes[b as usize]);
            if na.is_leaf() && nb.is_leaf() {
                tasks.swap(done, head - 1);
                done += 1;
                continue;
            }
            children.clear();
            self.descend_pair(other, a, na, b, nb, &mut children, &mut |_, _| {
                unreachable!("an internal pair tests no leaves")
            });
            tasks.extend_from_slice(&children);
        }
        tasks.drain(done..head);
    }

    /// Calls `f(i, j)` (`i` a leaf of `self`, `j` of `other`) once for every
    /// pair of overlapping leaves found by the descent from the node pair
    /// `task` (one of [`cross_overlap_tasks_into`](Bvh::cross_overlap_tasks_into);
    /// `(0, 0)` is the whole descent when the roots overlap).
    pub fn overlaps_with_from(&self, other: &Bvh, task: (u32, u32), mut f: impl FnMut(u32, u32)) {
        if self.nodes.is_empty() || other.nodes.is_empty() {
            return;
        }
        let mut stack: Vec<(u32, u32)> = vec![task];
        while let Some((a, b)) = stack.pop() {
            let na = self.nodes[a as usize];
            let nb = other.nodes[b as usize];
            self.descend_pair(other, a, na, b, nb, &mut stack, &mut f);
        }
    }

    /// Both trees are non-empty and their root bounds overlap.
    fn roots_overlap(&self, other: &Bvh) -> bool {
        !self.nodes.is_empty()
            && !other.nodes.is_empty()
            && self.bounds[0].overlaps(&other.bounds[0])
    }

    /// One step for a pair of overlapping nodes from disjoint subtrees (`a` in
    /// `self`, `b` in `other`).
    #[inline]
    fn descend_pair(
        &self,
        other: &Bvh,
        a: u32,
        na: Node,
        b: u32,
        nb: Node,
        stack: &mut Vec<(u32, u32)>,
        f: &mut impl FnMut(u32, u32),
    ) {
        if na.is_leaf() && nb.is_leaf() {
            for i in na.range() {
                let di = &self.leaf_bounds[i];
                for j in nb.range() {
                    if di.overlaps(&other.leaf_bounds[j]) {
                        f(self.order[i], other.order[j]);
                    }
                }
            }
        } else if !na.is_leaf() && (nb.is_leaf() || na.count >= nb.count) {
            let bb = &other.bounds[b as usize];
            for c in [na.child, na.child + 1] {
                if self.bounds[c as usize].overlaps(bb) {
                    stack.push((c, b));
                }
            }
        } else {
            let ba = &self.bounds[a as usize];
            for c in [nb.child, nb.child + 1] {
                if other.bounds[c as usize].overlaps(ba) {
                    stack.push((a, c));
                }
            }
        }
    }
}

#[inline]
fn f_sorted(f: &mut impl FnMut(u32, u32), i: u32, j: u32) {
    if i < j {
        f(i, j)
    } else {
        f(j, i)
    }
}
