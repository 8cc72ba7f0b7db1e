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

use super::{Bvh, Node};

impl Bvh {
    /// Calls `f(i, j)` with `i < j` exactly once for every pair of distinct
    /// leaves whose DOPs overlap (adjacent triangles included; a leaf is never
    /// paired with itself). The call order is deterministic but unspecified.
    pub fn self_overlaps(&self, mut f: impl FnMut(u32, u32)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack: Vec<(u32, u32)> = vec![(0, 0)];
        while let Some((a, b)) = stack.pop() {
            let na = self.nodes[a as usize];
            if a == b {
                if na.is_leaf() {
                    let r = na.range();
                    for i in r.clone() {
                        for j in i + 1..r.end {
                            if self.leaf_bounds[i].overlaps(&self.leaf_bounds[j]) {
                                f_sorted(&mut f, self.order[i], self.order[j]);
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
                continue;
            }
            let nb = self.nodes[b as usize];
            self.descend_pair(self, a, na, b, nb, &mut stack, &mut |i, j| {
                f_sorted(&mut f, i, j)
            });
        }
    }

    /// Calls `f(i, j)` once for every leaf `i` of `self` and leaf `j` of `other`
    /// whose DOPs overlap. The call order is deterministic but unspecified.
    pub fn overlaps_with(&self, other: &Bvh, mut f: impl FnMut(u32, u32)) {
        if self.nodes.is_empty() || other.nodes.is_empty() {
            return;
        }
        if !self.bounds[0].overlaps(&other.bounds[0]) {
            return;
        }
        let mut stack: Vec<(u32, u32)> = vec![(0, 0)];
        while let Some((a, b)) = stack.pop() {
            let na = self.nodes[a as usize];
            let nb = other.nodes[b as usize];
            self.descend_pair(other, a, na, b, nb, &mut stack, &mut f);
        }
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
