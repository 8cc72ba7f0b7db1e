//! Top-down construction.
//!
//! Each node's range of leaves is split at its median along the axis (x, y or z)
//! where the leaves' DOP centers spread most; leaves are ordered by
//! `(center[axis], leaf id)` with `f64::total_cmp`, a total order, so the split
//! is unique and the tree does not depend on the input's incidental properties
//! (NaN centers of empty DOPs included). The median split gives depth
//! `ceil(log2(n / MAX_LEAF_SIZE)) + 1`; an explicit stack avoids recursion.
//! Cost `O(n log n)`.

use super::{Bvh, Node, LEAF, MAX_LEAF_SIZE};
use crate::dop::Dop26;

impl Bvh {
    /// Builds the hierarchy over `leaves` (leaf `i` = `leaves[i]`).
    ///
    /// Deterministic: the same input gives the same tree. Leaf counts beyond
    /// `u32::MAX - 1` are not supported (ids are `u32`); such input is truncated
    /// to that many leaves.
    pub fn build(leaves: &[Dop26]) -> Bvh {
        let n = leaves.len().min(u32::MAX as usize - 1);
        let leaves = &leaves[..n];
        if n == 0 {
            return Bvh::default();
        }
        let mut bvh = Bvh::shaped_by(leaves);
        bvh.refit_in_place(leaves);
        bvh
    }

    /// As [`Bvh::build`] (the same tree), but the leaves are moved into
    /// the tree's order rather than copied: a one-off tree over many
    /// leaves (a mesh's self-intersection check) holds them once.
    pub fn build_owned(mut leaves: Vec<Dop26>) -> Bvh {
        leaves.truncate(u32::MAX as usize - 1);
        if leaves.is_empty() {
            return Bvh::default();
        }
        let mut bvh = Bvh::shaped_by(&leaves);
        // leaf_bounds[i] = leaves[order[i]], permuted cycle by cycle: each
        // place is read before it is written, the cycle's first saved.
        let order = &bvh.order;
        let mut placed = vec![false; leaves.len()];
        for first in 0..leaves.len() {
            if placed[first] {
                continue;
            }
            let saved = leaves[first];
            let mut j = first;
            loop {
                placed[j] = true;
                let k = order[j] as usize;
                if k == first {
                    leaves[j] = saved;
                    break;
                }
                leaves[j] = leaves[k];
                j = k;
            }
        }
        bvh.leaf_bounds = leaves;
        bvh.fit_nodes();
        bvh
    }

    /// The tree's nodes and leaf order over `leaves` (non-empty), its
    /// bounds not yet fitted.
    fn shaped_by(leaves: &[Dop26]) -> Bvh {
        let n = leaves.len();
        // (center, id) pairs, permuted in place so the splits read memory
        // sequentially; `order` is their id column at the end.
        let mut items: Vec<([f64; 3], u32)> = leaves
            .iter()
            .enumerate()
            .map(|(i, d)| (d.center().to_array(), i as u32))
            .collect();
        let mut nodes = Vec::with_capacity(2 * n.div_ceil(MAX_LEAF_SIZE));
        nodes.push(Node {
            start: 0,
            count: n as u32,
            child: LEAF,
        });
        let mut stack = vec![0usize];
        while let Some(k) = stack.pop() {
            let node = nodes[k];
            if node.count as usize <= MAX_LEAF_SIZE {
                continue;
            }
            let range = node.range();
            // axis of largest center extent (f64::max / min ignore NaN)
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for (c, _) in &items[range.clone()] {
                for a in 0..3 {
                    lo[a] = lo[a].min(c[a]);
                    hi[a] = hi[a].max(c[a]);
                }
            }
            let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
            let mut axis = 0;
            for a in 1..3 {
                if ext[a] > ext[axis] || (ext[axis].is_nan() && !ext[a].is_nan()) {
                    axis = a;
                }
            }
            let half = node.count as usize / 2;
            items[range].select_nth_unstable_by(half, |(ci, i), (cj, j)| {
                ci[axis].total_cmp(&cj[axis]).then(i.cmp(j))
            });
            let child = nodes.len();
            nodes.push(Node {
                start: node.start,
                count: half as u32,
                child: LEAF,
            });
            nodes.push(Node {
                start: node.start + half as u32,
                count: node.count - half as u32,
                child: LEAF,
            });
            nodes[k].child = child as u32;
            stack.push(child + 1);
            stack.push(child);
        }
        Bvh {
            bounds: vec![Dop26::empty(); nodes.len()],
            nodes,
            leaf_bounds: Vec::new(),
            order: items.into_iter().map(|(_, i)| i).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn owned_leaves_give_the_same_tree() {
        for n in [0usize, 1, 7, 100, 1000] {
            let leaves: Vec<Dop26> = (0..n)
                .map(|i| {
                    let mut d = Dop26::empty();
                    let x = (i * 7919 % 1000) as f64 * 1e-3;
                    let y = (i * 104_729 % 997) as f64 * 1e-3;
                    d.add_point(DVec3::new(x, y, 0.5 * x));
                    d.add_point(DVec3::new(x + 0.01, y - 0.02, y));
                    d
                })
                .collect();
            let copied = Bvh::build(&leaves);
            let owned = Bvh::build_owned(leaves);
            assert_eq!(owned.nodes, copied.nodes, "n = {n}");
            assert_eq!(owned.order, copied.order, "n = {n}");
            assert_eq!(owned.leaf_bounds, copied.leaf_bounds, "n = {n}");
            assert_eq!(owned.bounds, copied.bounds, "n = {n}");
        }
    }
}
