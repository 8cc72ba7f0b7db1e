//! Structural validation (used by the tests after every build and refit).

use super::{Bvh, MAX_LEAF_SIZE};
use crate::dop::Dop26;

impl Bvh {
    /// Checks that the tree is a valid BVH of `leaves`:
    ///
    /// * `order` is a permutation of `0 .. leaves.len()` and the stored leaf DOPs
    ///   are bitwise those of `leaves`;
    /// * every node is reached exactly once from the root, children follow their
    ///   parent, and the children's ranges split the parent's range;
    /// * leaf nodes hold between 1 and [`MAX_LEAF_SIZE`] leaves, so every leaf id
    ///   appears in exactly one leaf node;
    /// * every node's bounds contain its children's bounds (leaf nodes: the DOPs
    ///   of their leaves).
    ///
    /// Returns a message naming the first violated property.
    pub fn validate(&self, leaves: &[Dop26]) -> Result<(), String> {
        let n = leaves.len();
        if self.order.len() != n || self.leaf_bounds.len() != n {
            return Err(format!(
                "tree holds {} leaves ({} bounds), expected {n}",
                self.order.len(),
                self.leaf_bounds.len()
            ));
        }
        if self.bounds.len() != self.nodes.len() {
            return Err("one bounds per node expected".into());
        }
        if n == 0 {
            return if self.nodes.is_empty() {
                Ok(())
            } else {
                Err("empty tree with nodes".into())
            };
        }
        let mut seen = vec![false; n];
        for (pos, &i) in self.order.iter().enumerate() {
            let i = i as usize;
            if i >= n || seen[i] {
                return Err(format!("leaf id {i} out of range or repeated in order"));
            }
            seen[i] = true;
            if !same_bits(&self.leaf_bounds[pos], &leaves[i]) {
                return Err(format!("stored DOP of leaf {i} differs from the input"));
            }
        }
        let root = self.nodes.first().copied().ok_or("no root")?;
        if root.start != 0 || root.count as usize != n {
            return Err("root does not cover all leaves".into());
        }
        let mut visited = vec![false; self.nodes.len()];
        let mut covered = 0usize;
        let mut stack = vec![0usize];
        while let Some(k) = stack.pop() {
            if std::mem::replace(&mut visited[k], true) {
                return Err(format!("node {k} reached twice"));
            }
            let node = self.nodes[k];
            let bk = &self.bounds[k];
            if node.is_leaf() {
                if node.count == 0 || node.count as usize > MAX_LEAF_SIZE {
                    return Err(format!("leaf node {k} holds {} leaves", node.count));
                }
                for pos in node.range() {
                    if !bk.contains(&self.leaf_bounds[pos]) {
                        return Err(format!(
                            "leaf node {k} does not bound leaf {}",
                            self.order[pos]
                        ));
                    }
                }
                covered += node.count as usize;
                continue;
            }
            let c = node.child as usize;
            if c <= k || c + 1 >= self.nodes.len() {
                return Err(format!("node {k} has bad child index {c}"));
            }
            let (l, r) = (self.nodes[c], self.nodes[c + 1]);
            if l.start != node.start
                || r.start != l.start + l.count
                || l.count + r.count != node.count
                || l.count == 0
                || r.count == 0
            {
                return Err(format!("children of node {k} do not split its range"));
            }
            for cc in [c, c + 1] {
                if !bk.contains(&self.bounds[cc]) {
                    return Err(format!("node {k} does not bound its child {cc}"));
                }
            }
            stack.push(c);
            stack.push(c + 1);
        }
        if let Some(k) = visited.iter().position(|v| !v) {
            return Err(format!("node {k} unreachable"));
        }
        if covered != n {
            return Err(format!("leaf nodes cover {covered} leaves, expected {n}"));
        }
        Ok(())
    }
}

fn same_bits(a: &Dop26, b: &Dop26) -> bool {
    (0..13)
        .all(|k| a.lo[k].to_bits() == b.lo[k].to_bits() && a.hi[k].to_bits() == b.hi[k].to_bits())
}
