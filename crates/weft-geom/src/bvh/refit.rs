//! Refitting: new leaf DOPs, same topology.
//!
//! Leaf DOPs are copied in tree order, then node bounds are recomputed in one
//! reverse sweep over the nodes (children have larger indices than their parent,
//! so they are final when the parent is visited). Unions are exact, so the
//! result is the same as a fresh build's bounds for the same topology. Cost
//! `O(n)`; the tree's quality degrades if leaves move far (rebuild then).

use super::Bvh;
use crate::dop::Dop26;

impl Bvh {
    /// Replaces the leaf bounds by `leaves` (leaf `i` = `leaves[i]`) and
    /// recomputes every node's bounds.
    ///
    /// If `leaves.len()` differs from the number of leaves the tree was built
    /// over, the tree is rebuilt instead (a refit needs the same leaf set).
    pub fn refit(&mut self, leaves: &[Dop26]) {
        if leaves.len() != self.order.len() {
            *self = Bvh::build(leaves);
            return;
        }
        self.refit_in_place(leaves);
    }

    /// The refit proper; `leaves.len() == self.order.len()`.
    pub(super) fn refit_in_place(&mut self, leaves: &[Dop26]) {
        self.leaf_bounds.clear();
        self.leaf_bounds
            .extend(self.order.iter().map(|&i| leaves[i as usize]));
        self.fit_nodes();
    }

    /// Every node's bounds from the leaf bounds (in tree order).
    pub(super) fn fit_nodes(&mut self) {
        for k in (0..self.nodes.len()).rev() {
            let node = self.nodes[k];
            let b = if node.is_leaf() {
                let mut b = Dop26::empty();
                for d in &self.leaf_bounds[node.range()] {
                    b.merge(d);
                }
                b
            } else {
                let c = node.child as usize;
                self.bounds[c].union(&self.bounds[c + 1])
            };
            self.bounds[k] = b;
        }
    }
}
