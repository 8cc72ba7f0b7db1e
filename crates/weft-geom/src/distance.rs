//! Unsigned distances between the primitives of a contact stencil, with the
//! gradient data the penalty layers need.
//!
//! # Convention
//!
//! Every function returns a [`Closest`]: the unsigned distance `d`, the unit
//! normal `n` pointing **from the second primitive to the first**, and four
//! coefficients `c` such that, with the closest points' barycentric weights held
//! fixed,
//!
//! ```text
//!     dd/dx_j = c[j] * n        (j = 0..4, the stencil's vertices in order)
//! ```
//!
//! * VF, `x = [p, a, b, c]`: closest point `w0 a + w1 b + w2 c`,
//!   `c = [1, -w0, -w1, -w2]`, `n = (p - closest) / d`.
//! * EE, `x = [p0, p1, q0, q1]`: closest points `(1-s) p0 + s p1` and
//!   `(1-t) q0 + t q1`, `c = [1-s, s, -(1-t), -t]`, `n = (P - Q) / d`.
//!
//! The weights are those of the exact closest points (an envelope argument: the
//! derivative of `d = min |P(w) - Q(w)|` with respect to the positions is the
//! partial derivative at the minimizer). The coefficients of each side sum to
//! `±1`, so a kick `-k (d - eta) c[j] n` scaled by vertex weights conserves
//! linear momentum; since the two closest points lie on the line spanned by `n`
//! it also conserves angular momentum.
//!
//! # Robustness
//!
//! The functions never divide by a quantity that may vanish without checking it,
//! and never return NaN for finite input:
//!
//! * the interior candidates (face interior for VF, segment interiors for EE) are
//!   used only when the primitive is non-degenerate (nonzero cross product) and
//!   the closest point's weights lie in `[0, 1]`; otherwise the minimum over
//!   point–segment distances is taken, which covers zero-area triangles,
//!   zero-length edges and parallel or collinear edges;
//! * for nearly degenerate configurations (sliver triangles, nearly parallel
//!   edges) the interior candidate's plane-based distance is additionally compared
//!   with the boundary candidates and the smaller one is kept, so rounding in a
//!   badly conditioned normal can only make `d` smaller (conservative for
//!   contact), never larger than a true boundary distance;
//! * when `d == 0` the normal is undefined; a deterministic fallback is used, see
//!   [`fallback_normal`].
//!
//! Squared lengths of cross products (fourth powers of lengths) are formed, so
//! results are accurate when coordinate differences lie within about
//! `[1e-70, 1e70]`; cloth in metres is far inside. Outside that range the results
//! stay free of NaN but may lose accuracy.
//!
//! Only `+ - * /` and `sqrt` are used (IEEE-754 correctly rounded), so results are
//! bitwise identical across machines.

mod edge_edge;
mod vertex_face;

pub use edge_edge::edge_edge;
pub use vertex_face::vertex_face;

use weft_core::{DVec3, StencilKind};

/// Closest-point data of a stencil.
///
/// `d` is the unsigned distance, `n` the unit normal pointing from the second
/// primitive to the first, and `coeff` the coefficients with
/// `dd/dx_j = coeff[j] * n` (barycentric weights held fixed). See the module
/// documentation for the per-kind layout.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Closest {
    /// unsigned distance between the two primitives (`>= 0`, finite for finite input).
    pub d: f64,
    /// unit normal from the second primitive to the first.
    pub n: DVec3,
    /// `dd/dx_j = coeff[j] * n`.
    pub coeff: [f64; 4],
}

impl Closest {
    /// The gradient `dd/dx_j = coeff[j] * n` of the distance, one vector per
    /// stencil vertex.
    #[inline]
    pub fn gradient(&self) -> [DVec3; 4] {
        [
            self.n * self.coeff[0],
            self.n * self.coeff[1],
            self.n * self.coeff[2],
            self.n * self.coeff[3],
        ]
    }
}

/// Closest-point data of the stencil `x` of the given kind: `x = [p, a, b, c]`
/// for [`StencilKind::VertexFace`], `x = [p0, p1, q0, q1]` for
/// [`StencilKind::EdgeEdge`].
#[inline]
pub fn stencil_closest(kind: StencilKind, x: &[DVec3; 4]) -> Closest {
    match kind {
        StencilKind::VertexFace => vertex_face(x[0], x[1], x[2], x[3]),
        StencilKind::EdgeEdge => edge_edge(x[0], x[1], x[2], x[3]),
    }
}

/// Unit vector along `v`, computed without underflow; `None` when `v == 0` or
/// `v` is not finite.
///
/// For `|v| >= 1e-150` the plain `v / |v|` is used (its squared length cannot
/// underflow to a value that loses relative accuracy); below, `v` is first
/// divided by its largest absolute component, which is exact up to one rounding
/// per component and brings the largest component to 1.
#[inline]
pub(crate) fn unit(v: DVec3) -> Option<DVec3> {
    let len = v.length();
    if len >= 1e-150 && len.is_finite() {
        return Some(v / len);
    }
    let m = v.abs().max_element();
    if m > 0.0 && m.is_finite() {
        let w = v / m;
        Some(w / w.length())
    } else {
        None
    }
}

/// Deterministic unit normal used when the distance is zero and no direction is
/// defined by the closest points.
///
/// In order of preference: the unit vector along `primary` (the face normal
/// `(b - a) x (c - a)` for VF, the edge cross product `(p1 - p0) x (q1 - q0)` for
/// EE); else a unit vector perpendicular to `dir` (an edge direction), namely
/// `dir x e_k` with `e_k` the axis of `dir`'s smallest absolute component (first
/// such axis on ties); else `+z`.
pub fn fallback_normal(primary: DVec3, dir: DVec3) -> DVec3 {
    if let Some(n) = unit(primary) {
        return n;
    }
    unit(dir.cross(smallest_axis(dir))).unwrap_or(DVec3::Z)
}

/// The coordinate axis of `v`'s smallest absolute component (the first such
/// axis on ties): the axis least parallel to `v`.
pub fn smallest_axis(v: DVec3) -> DVec3 {
    let a = v.abs();
    if a.x <= a.y && a.x <= a.z {
        DVec3::X
    } else if a.y <= a.z {
        DVec3::Y
    } else {
        DVec3::Z
    }
}

/// Closest point of segment `[a, b]` to `p`: returns `(t, dist2, diff)` with the
/// closest point `a + t (b - a)` (exactly `b` for `t = 1`), `t` in `[0, 1]`,
/// `diff = p - closest` and `dist2 = |diff|^2` (callers compare squared
/// distances and take one square root for the winner).
///
/// `t = clamp((p - a).(b - a) / |b - a|^2, 0, 1)`; a zero-length segment gives
/// `t = 0`.
#[inline]
pub(crate) fn point_segment(p: DVec3, a: DVec3, b: DVec3) -> (f64, f64, DVec3) {
    let e = b - a;
    let ee = e.dot(e);
    let num = (p - a).dot(e);
    // Clamp before dividing (no division in the vertex regions); a zero-length
    // segment, or a NaN from overflowing input, gives t = 0.
    let t = if num.is_nan() || num <= 0.0 || ee <= 0.0 {
        0.0
    } else if num >= ee {
        1.0
    } else {
        num / ee
    };
    let closest = if t >= 1.0 { b } else { a + e * t };
    let diff = p - closest;
    (t, diff.dot(diff), diff)
}

/// Unit normal along `diff` given its length `d = |diff|`, or `None` when
/// `d == 0` (the caller's fallback applies).
#[inline]
pub(crate) fn normal_along(diff: DVec3, d: f64) -> Option<DVec3> {
    if d >= 1e-150 && d.is_finite() {
        Some(diff * (1.0 / d))
    } else if d > 0.0 {
        unit(diff)
    } else {
        None
    }
}
