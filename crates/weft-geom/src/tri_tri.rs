//! Exact intersection test of two closed triangles in 3D.
//!
//! All decisions are signs of Shewchuk's adaptive-precision `orient3d` /
//! `orient2d` determinants (crate `geometry-predicates`), which are exact for
//! finite inputs whose magnitudes stay within about `[1e-142, 1e201]` (or are
//! zero): no tolerance, so touching at a single point counts as intersecting and
//! a miss by one ulp does not.
//!
//! # Method
//!
//! Two closed convex sets `A`, `B` of a triangle's kind intersect iff an edge of
//! one meets the other triangle:
//!
//! * if the planes differ, `A ∩ B` lies on the line `L` of the two planes, and
//!   `A ∩ L`, `B ∩ L` are segments whose endpoints lie on edges of `A` and `B`; two
//!   intersecting segments share an endpoint of one of them;
//! * if they are coplanar, two convex polygons intersect iff their boundaries
//!   cross or one contains the other, in which case it contains a vertex (an edge
//!   point) of the other;
//! * a zero-area triangle is the union of its edges.
//!
//! So: both non-degenerate — any edge of `A` against triangle `B` or any edge of
//! `B` against `A`; one degenerate — its edges against the other; both
//! degenerate — all edge pairs as segments.
//!
//! *Segment `PQ` against non-degenerate triangle `T`*: with
//! `o_P = orient3d(T, P)`, `o_Q = orient3d(T, Q)`: same strict sign — disjoint;
//! not both zero — the segment reaches the plane, and it meets the closed
//! triangle iff the line `PQ` does, i.e. iff `orient3d(P, Q, t_i, t_j)` over the
//! three edges has no two opposite strict signs (Plücker side test); both zero —
//! coplanar: drop the coordinate along which `T`'s projection is non-degenerate
//! (an exact `orient2d` test, so the projection is a bijection of the plane) and
//! test in 2D: an endpoint inside `T` or a crossing with an edge of `T`.
//!
//! *Segment against segment*: disjoint unless coplanar (`orient3d == 0`); if some
//! three of the four points are non-collinear, project along an axis where that
//! triple's `orient2d` is nonzero and use the 2D segment test; if all four are
//! collinear, compare intervals along an axis on which their coordinates differ.

use geometry_predicates::{orient2d, orient3d};
use weft_core::DVec3;

#[inline]
fn sign(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

#[inline]
fn o3(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> i8 {
    sign(orient3d(
        a.to_array(),
        b.to_array(),
        c.to_array(),
        d.to_array(),
    ))
}

/// Projection dropping coordinate `k` (a bijection on any plane whose normal has
/// a nonzero `k` component).
#[inline]
fn proj(p: DVec3, k: usize) -> [f64; 2] {
    match k {
        0 => [p.y, p.z],
        1 => [p.z, p.x],
        _ => [p.x, p.y],
    }
}

#[inline]
pub(crate) fn o2(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> i8 {
    sign(orient2d(a, b, c))
}

/// A projection axis along which `a, b, c` are not collinear, or `None` when they
/// are collinear in 3D (the cross product's components are the three `orient2d`s).
fn non_degenerate_axis(a: DVec3, b: DVec3, c: DVec3) -> Option<usize> {
    (0..3)
        .rev()
        .find(|&k| o2(proj(a, k), proj(b, k), proj(c, k)) != 0)
}

/// True when no two of the signs are strictly opposite.
#[inline]
fn no_mixed(s: [i8; 3]) -> bool {
    !(s.contains(&1) && s.contains(&-1))
}

/// `c` lies on the closed segment `[a, b]`, given that the three are collinear.
#[inline]
fn on_segment_2d(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> bool {
    a[0].min(b[0]) <= c[0]
        && c[0] <= a[0].max(b[0])
        && a[1].min(b[1]) <= c[1]
        && c[1] <= a[1].max(b[1])
}

/// Closed 2D segments `[p, q]` and `[r, s]` intersect (exact; degenerate
/// segments allowed).
pub(crate) fn segments_2d(p: [f64; 2], q: [f64; 2], r: [f64; 2], s: [f64; 2]) -> bool {
    let d1 = o2(p, q, r);
    let d2 = o2(p, q, s);
    let d3 = o2(r, s, p);
    let d4 = o2(r, s, q);
    if d1 * d2 < 0 && d3 * d4 < 0 {
        return true;
    }
    (d1 == 0 && on_segment_2d(p, q, r))
        || (d2 == 0 && on_segment_2d(p, q, s))
        || (d3 == 0 && on_segment_2d(r, s, p))
        || (d4 == 0 && on_segment_2d(r, s, q))
}

/// Point in closed 2D triangle (non-degenerate in this projection).
pub(crate) fn point_in_triangle_2d(p: [f64; 2], t: [[f64; 2]; 3]) -> bool {
    no_mixed([o2(t[0], t[1], p), o2(t[1], t[2], p), o2(t[2], t[0], p)])
}

/// Closed segments `[p, q]` and `[r, s]` in 3D intersect (exact).
pub fn segments_intersect(p: DVec3, q: DVec3, r: DVec3, s: DVec3) -> bool {
    if o3(p, q, r, s) != 0 {
        return false;
    }
    for (a, b, c) in [(p, q, r), (p, q, s), (r, s, p), (r, s, q)] {
        if let Some(k) = non_degenerate_axis(a, b, c) {
            return segments_2d(proj(p, k), proj(q, k), proj(r, k), proj(s, k));
        }
    }
    // all four collinear: 1D interval overlap along an axis where they differ
    for k in 0..3 {
        let (a0, a1, b0, b1) = (p[k], q[k], r[k], s[k]);
        if a0 != a1 || a0 != b0 || a0 != b1 {
            return a0.min(a1) <= b0.max(b1) && b0.min(b1) <= a0.max(a1);
        }
    }
    true // all four points coincide
}

/// Closed segment `[p, q]` meets the closed triangle `t`, which must be
/// non-degenerate (not collinear); `axis` is a projection axis along which it is
/// non-degenerate.
fn segment_triangle(p: DVec3, q: DVec3, t: &[DVec3; 3], axis: usize) -> bool {
    let op = o3(t[0], t[1], t[2], p);
    let oq = o3(t[0], t[1], t[2], q);
    if op * oq > 0 {
        return false;
    }
    if op != 0 || oq != 0 {
        return no_mixed([
            o3(p, q, t[0], t[1]),
            o3(p, q, t[1], t[2]),
            o3(p, q, t[2], t[0]),
        ]);
    }
    let (p2, q2) = (proj(p, axis), proj(q, axis));
    let t2 = [proj(t[0], axis), proj(t[1], axis), proj(t[2], axis)];
    point_in_triangle_2d(p2, t2)
        || point_in_triangle_2d(q2, t2)
        || segments_2d(p2, q2, t2[0], t2[1])
        || segments_2d(p2, q2, t2[1], t2[2])
        || segments_2d(p2, q2, t2[2], t2[0])
}

fn edges(t: &[DVec3; 3]) -> [(DVec3, DVec3); 3] {
    [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]
}

/// True when the closed triangles `a` and `b` share at least one point (exact;
/// touching at a point or along an edge counts, coplanar and zero-area triangles
/// are handled). See the module documentation for the method and the input range
/// of exactness.
pub fn triangles_intersect(a: &[DVec3; 3], b: &[DVec3; 3]) -> bool {
    // Exact bounding-box rejection (comparisons only).
    let (amin, amax) = (a[0].min(a[1]).min(a[2]), a[0].max(a[1]).max(a[2]));
    let (bmin, bmax) = (b[0].min(b[1]).min(b[2]), b[0].max(b[1]).max(b[2]));
    if amin.cmpgt(bmax).any() || bmin.cmpgt(amax).any() {
        return false;
    }
    let ka = non_degenerate_axis(a[0], a[1], a[2]);
    let kb = non_degenerate_axis(b[0], b[1], b[2]);
    match (ka, kb) {
        (Some(ka), Some(kb)) => {
            edges(a).iter().any(|&(p, q)| segment_triangle(p, q, b, kb))
                || edges(b).iter().any(|&(p, q)| segment_triangle(p, q, a, ka))
        }
        (None, Some(kb)) => edges(a).iter().any(|&(p, q)| segment_triangle(p, q, b, kb)),
        (Some(ka), None) => edges(b).iter().any(|&(p, q)| segment_triangle(p, q, a, ka)),
        (None, None) => edges(a).iter().any(|&(p, q)| {
            edges(b)
                .iter()
                .any(|&(r, s)| segments_intersect(p, q, r, s))
        }),
    }
}
