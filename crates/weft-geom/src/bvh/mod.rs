//! Bounding-volume hierarchy of 26-DOPs (the broad phase, spec §4.2).
//!
//! A [`Bvh`] is built over a slice of leaf [`Dop26`]s (leaf `i` is, for the
//! simulator, triangle `i`). It is split by operation:
//!
//! * [`build`](Bvh::build) (`build.rs`): deterministic top-down median split
//!   along the axis of largest leaf-center extent, explicit stack;
//! * [`refit`](Bvh::refit) (`refit.rs`): new leaf bounds, same topology,
//!   bottom-up;
//! * [`self_overlaps`](Bvh::self_overlaps) and [`overlaps_with`](Bvh::overlaps_with)
//!   (`traverse.rs`): simultaneous descent with an explicit stack; the self
//!   descent also splits into independent tasks
//!   ([`self_overlap_tasks`](Bvh::self_overlap_tasks), each run by
//!   [`overlaps_from`](Bvh::overlaps_from)) for parallel callers, and so
//!   does the descent of two trees
//!   ([`cross_overlap_tasks_into`](Bvh::cross_overlap_tasks_into), each run
//!   by [`overlaps_with_from`](Bvh::overlaps_with_from));
//! * [`validate`](Bvh::validate) (`validate.rs`): structural and bounding checks
//!   for tests.
//!
//! [`brute_force_self_pairs`] is the all-pairs oracle the traversal is tested
//! against.
//!
//! # Layout
//!
//! Nodes live in one vector, root at index 0, the two children of an internal
//! node at consecutive indices `child, child + 1`, always greater than the
//! parent's index (so a reverse sweep visits children before parents). Every node
//! covers the contiguous range `order[start .. start + count]` of leaf ids; leaf
//! nodes hold at most [`MAX_LEAF_SIZE`] leaves. The leaf DOPs are copied in
//! `order`, so traversal reads them contiguously and needs no access to the
//! caller's slice.
//!
//! # Exactness
//!
//! The traversal only calls [`Dop26::overlaps`] and node bounds are unions
//! (exact `min` / `max`) of leaf bounds, so a node pair is pruned only when some
//! pair of its leaves could not overlap either: the reported pairs are exactly
//! those of [`brute_force_self_pairs`], whatever the rounding.

mod build;
mod refit;
mod traverse;
mod validate;

use crate::dop::Dop26;

/// Most leaves stored in one leaf node.
pub const MAX_LEAF_SIZE: usize = 4;

/// Marker of "no child" (a leaf node).
const LEAF: u32 = u32::MAX;

/// One node: the range `order[start .. start + count]` it covers and, for an
/// internal node, the index of its first child (the second is `child + 1`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Node {
    pub(crate) start: u32,
    pub(crate) count: u32,
    pub(crate) child: u32,
}

impl Node {
    #[inline]
    pub(crate) fn is_leaf(&self) -> bool {
        self.child == LEAF
    }

    #[inline]
    pub(crate) fn range(&self) -> std::ops::Range<usize> {
        self.start as usize..(self.start + self.count) as usize
    }
}

/// A BVH of 26-DOPs over leaves `0 .. n`.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// the tree, root first.
    pub(crate) nodes: Vec<Node>,
    /// `bounds[k]` bounds every leaf below node `k`.
    pub(crate) bounds: Vec<Dop26>,
    /// leaf ids in tree order.
    pub(crate) order: Vec<u32>,
    /// `leaf_bounds[i]` is the DOP of leaf `order[i]`.
    pub(crate) leaf_bounds: Vec<Dop26>,
}

impl Bvh {
    /// Number of leaves.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// True when built over no leaves.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Number of nodes (internal and leaf).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Bounds of the whole tree (empty DOP for an empty tree).
    pub fn root_bounds(&self) -> Dop26 {
        self.bounds.first().copied().unwrap_or_else(Dop26::empty)
    }
}

/// The oracle: every unordered pair `(i, j)`, `i < j`, of overlapping leaves, in
/// lexicographic order. `O(n^2)`; tests only.
pub fn brute_force_self_pairs(leaves: &[Dop26]) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for i in 0..leaves.len() {
        for j in i + 1..leaves.len() {
            if leaves[i].overlaps(&leaves[j]) {
                out.push((i as u32, j as u32));
            }
        }
    }
    out
}
