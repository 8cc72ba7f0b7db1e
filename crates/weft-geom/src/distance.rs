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
//!   contact), never larger than a true boundary distance; a sliver too thin
//!   for the plane formula (its error bound above the triangle's smallest
//!   height) has no face candidate;
//! * when `d == 0` the normal is undefined; a deterministic fallback is used, see
//!   [`fallback_normal`].
//!
//! These choices keep `d` free of NaN, not exact to rounding: where the plane
//! formula's normal is badly conditioned `d` can be off the exact distance by
//! far more than a few ulps. Measured against exact rationals
//! (`tests/separation.rs`) on sliver triangles and nearly parallel edges of
//! thinness 1e-15 to 1e-2: up to about 3e-9 of the coordinates above the
//! exact distance (touching primitives), 2e-11 below it. (Before a sliver's
//! face candidate was dropped where its error bound exceeds the triangle's
//! height, 1e-8 below it, and a second reader found a sliver evaluated at
//! 1.5e-6 from a point 7.8e-6 away.) What must never exceed the
//! exact distance — the certificates that let the engine skip an evaluation —
//! therefore uses [`separation_lower_bound`], which needs only a direction
//! and carries its own rounding bound.
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

use weft_core::{nan_max, nan_min, DVec3, StencilKind};

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

/// A direction of Euclidean norm at most 1, rounding included: what a
/// [`separation_lower_bound`] is taken along.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Direction(DVec3);

impl Direction {
    /// `n` scaled to a norm of at most 1 (a unit `n`, such as a
    /// [`Closest::n`], keeps its direction and a norm of about
    /// `1 - 2^-49`). Not finite or zero: a direction whose bound is never
    /// positive.
    ///
    /// With `u = 2^-53`, when `n . n` lies in `[2^-1000, f64::MAX]`: the
    /// computed `n . n` is at least `|n|^2 (1 - 3u - 3 · 2^-75)` (three
    /// nonnegative products, each off by at most `u` of itself or, where
    /// it underflows, `2^-1075`, against a sum of at least `2^-1000`), its
    /// square root `r` at least `|n| (1 - 2.51 u)`, the factor
    /// `c = fl((1 - 2^-49) / r)` at most `(1 - 16 u)(1 + u) / r <=
    /// (1 - 12.4 u) / |n|`, and the scaled vector, each component rounded
    /// once, has norm at most `|n| c (1 + u) <= 1 - 11.3 u`. (`1 - 2^-49`
    /// is exact.) Otherwise (`n . n` underflows or overflows) `n` is first
    /// divided by its largest absolute component, which only scales it
    /// (any direction will do, only the norm matters): that component
    /// becomes exactly 1, so `n . n` then lies in `[1, 3]`.
    #[inline]
    pub fn along(n: DVec3) -> Self {
        let nn = n.dot(n);
        let n = if (f64::powi(2.0, -1000)..=f64::MAX).contains(&nn) {
            n
        } else {
            n / n.abs().max_element() // (zero or not finite: NaN)
        };
        let c = (1.0 - f64::powi(2.0, -49)) / n.dot(n).sqrt();
        Self(n * c)
    }

    /// The direction as a vector (norm at most 1).
    #[inline]
    pub fn vector(self) -> DVec3 {
        self.0
    }
}

/// A lower bound of the exact distance between the stencil's primitives at
/// positions `x` (`[p, a, b, c]` or `[p0, p1, q0, q1]`), separating them
/// along `n` (which should point from the second primitive to the first,
/// as [`Closest::n`] does): never above the true distance, rounding
/// included, whatever `n` is; close to it when `n` is nearly the direction
/// of the closest points (the normal of an exact evaluation at nearby
/// positions). NaN or `-inf` when a position or `n` is not finite.
///
/// **Why it is a bound (weak duality).** For any `|n| <= 1` and any
/// points `P` of the first primitive and `Q` of the second,
/// `|P - Q| >= n . (P - Q) >= min_j n . x_j - max_k n . x_k` over the
/// vertices `j` of the first and `k` of the second, since a linear function
/// takes its extremes over a convex hull at the hull's vertices. With the
/// exact closest points and the exact normal the bound is the distance.
/// Unlike a bound carried from an earlier evaluation by the vertices'
/// displacements, it does not fall when both primitives move together, nor
/// when one slides along the other, and it does not rest on the accuracy
/// of [`stencil_closest`] (only on `n`'s being a direction): a sliver
/// triangle or nearly parallel edges can only make it looser.
///
/// **Rounding.** Everything is taken relative to `x_0` (the bound is
/// unchanged by a common translation): `d_j = fl(x_j - x_0)` and
/// `t_j = fl(n . d_j)`. With `u = 2^-53` and `|n_i| <= 1`, the rounding of
/// `d_j` moves `n . d_j` by at most `u |d_j|_1` and the dot product adds at
/// most `3.01 u |d_j|_1`; the minimum over the first primitive and the
/// maximum over the second (disjoint vertices) are therefore off by at most
/// `4.01 u s` together, `s = sum_j |d_j|_1`, and the difference `g` is
/// rounded once more (`u |g|`). The slack subtracted, `2^-50 (s + |g|)`
/// as computed, is at least `7.9 u (s + |g|)`, and the final subtraction
/// rounds by at most `u |g|` more: the result stays below
/// `g_exact - 3.8 u s - 5.8 u |g|`. That assumes no underflow; where the
/// products `n_i d_ji` or the slack underflow (coordinate differences
/// near `2^-1022`), each loses at most `2^-1075` absolutely, and the
/// smallest normal number `2^-1022` added to the slack covers them all (it
/// is absorbed by rounding unless the slack is below `2^-969`). A
/// non-finite input makes `s` or `g`
/// NaN or infinite and the result NaN or `-inf` (the extremes below keep
/// a NaN).
#[inline]
pub fn separation_lower_bound(kind: StencilKind, n: Direction, x: &[DVec3; 4]) -> f64 {
    let n = n.0;
    let d = [x[1] - x[0], x[2] - x[0], x[3] - x[0]];
    let t = [0.0, n.dot(d[0]), n.dot(d[1]), n.dot(d[2])];
    let s = d.iter().map(|v| v.abs().element_sum()).sum::<f64>();
    // (`f64::min`/`max` would drop a NaN: it must stay)
    let g = match kind {
        StencilKind::VertexFace => t[0] - nan_max(nan_max(t[1], t[2]), t[3]),
        StencilKind::EdgeEdge => nan_min(t[0], t[1]) - nan_max(t[2], t[3]),
    };
    g - (f64::powi(2.0, -50) * (s + g.abs()) + f64::MIN_POSITIVE)
}
