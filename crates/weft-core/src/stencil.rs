//! Contact stencils and their global keys.
//!
//! A stencil is a vertex and a triangle not containing it (VF) or two edges with
//! no shared vertex (EE). Its key is built from **input** vertex ids in a
//! canonical order, so it is the same for any partitioning, thread or rank
//! count, and sorting by key gives the fold order of penalty contributions.

use serde::{Deserialize, Serialize};

/// The two kinds of contact stencil.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum StencilKind {
    /// vertex `v[0]` against triangle `(v[1], v[2], v[3])`.
    VertexFace,
    /// edge `(v[0], v[1])` against edge `(v[2], v[3])`.
    EdgeEdge,
}

/// Canonical global key of a contact stencil.
///
/// * VF: `v = [vertex, a, b, c]` with the triangle's corners rotated so the
///   smallest id comes first while keeping the triangle's orientation.
/// * EE: each edge's ids sorted ascending, and the edge with the smaller first
///   id (then second id) first.
///
/// The derived `Ord` (kind, then ids) is the fold order of contributions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct StencilKey {
    pub kind: StencilKind,
    pub v: [u32; 4],
}

impl StencilKey {
    /// VF key for `vertex` against triangle `tri` (input ids).
    pub fn vertex_face(vertex: u32, tri: [u32; 3]) -> Self {
        let r = (0..3).min_by_key(|&i| tri[i]).unwrap_or(0);
        Self {
            kind: StencilKind::VertexFace,
            v: [vertex, tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]],
        }
    }

    /// EE key for edges `a` and `b` (input ids), canonicalized: the same key
    /// whichever way round the edges and their ends are given.
    ///
    /// ```
    /// use weft_core::StencilKey;
    /// let k = StencilKey::edge_edge([8, 3], [1, 6]);
    /// assert_eq!(k, StencilKey::edge_edge([6, 1], [3, 8]));
    /// assert_eq!(k.v, [1, 6, 3, 8]);
    /// ```
    pub fn edge_edge(a: [u32; 2], b: [u32; 2]) -> Self {
        let a = if a[0] <= a[1] { a } else { [a[1], a[0]] };
        let b = if b[0] <= b[1] { b } else { [b[1], b[0]] };
        let (e0, e1) = if a <= b { (a, b) } else { (b, a) };
        Self {
            kind: StencilKind::EdgeEdge,
            v: [e0[0], e0[1], e1[0], e1[1]],
        }
    }

    /// True when two of the four vertices coincide (such a pair is not a stencil).
    pub fn shares_vertex(&self) -> bool {
        match self.kind {
            StencilKind::VertexFace => self.v[1..].contains(&self.v[0]),
            StencilKind::EdgeEdge => self.v[..2].iter().any(|a| self.v[2..].contains(a)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_face_key_keeps_orientation() {
        let k = StencilKey::vertex_face(9, [5, 2, 7]);
        assert_eq!(k.v, [9, 2, 7, 5]);
        assert!(!k.shares_vertex());
        assert!(StencilKey::vertex_face(2, [5, 2, 7]).shares_vertex());
    }

    #[test]
    fn edge_edge_key_is_canonical() {
        let a = StencilKey::edge_edge([8, 3], [1, 6]);
        let b = StencilKey::edge_edge([6, 1], [3, 8]);
        assert_eq!(a, b);
        assert_eq!(a.v, [1, 6, 3, 8]);
        assert!(StencilKey::edge_edge([1, 2], [2, 3]).shares_vertex());
    }
}
