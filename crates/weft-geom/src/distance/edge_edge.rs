//! Edge–edge (segment–segment) distance.
//!
//! With `e = p1 - p0`, `f = q1 - q0`, `r = p0 - q0` and `m = e x f`, the lines'
//! closest points `P = p0 + s e`, `Q = q0 + t f` solve the normal equations
//!
//! ```text
//!     [ e.e  -e.f ] [s]   [ -e.r ]
//!     [ e.f  -f.f ] [t] = [ -f.r ]
//! ```
//!
//! whose determinant is `-(|e|^2 |f|^2 - (e.f)^2) = -|m|^2`; so
//! `s = ((e.f)(f.r) - (f.f)(e.r)) / |m|^2` and `t = ((e.e)(f.r) - (e.f)(e.r)) / |m|^2`.
//! When `m != 0` and both lie in `[0, 1]` the segments' closest points are
//! interior and `d = |r . m| / |m|`, `n = sign(r . m) m / |m|` (the plane
//! formula, accurate for nearly touching edges). Otherwise one closest point is
//! an endpoint and `d` is the minimum of the four endpoint–segment distances,
//! ties going to the first in the order `p0, p1` vs `[q0, q1]`, then `q0, q1`
//! vs `[p0, p1]`. This covers parallel, collinear and zero-length edges.
//!
//! Nearly parallel edges (`|m|^2 <= 1e-8 |e|^2 |f|^2`, an angle below about
//! 1e-4 rad) have a badly conditioned `m`, `s` and `t`; there the interior
//! candidate is the distance between the points at `s, t` (a realizable pair,
//! never below the true minimum) and it is compared with the endpoint
//! candidates: the smaller wins. Every candidate is the distance of an actual
//! pair of points, so the result never underestimates.

use super::{fallback_normal, normal_along, point_segment, Closest};
use weft_core::DVec3;

/// Distance between the closed segments `[p0, p1]` and `[q0, q1]`.
///
/// Returns `coeff = [1-s, s, -(1-t), -t]` with closest points
/// `(1-s) p0 + s p1` and `(1-t) q0 + t q1`, and `n` pointing from the second
/// segment to the first. When `d == 0` the normal is `(p1 - p0) x (q1 - q0)`
/// normalized, or for parallel / degenerate edges the fallback of
/// [`super::fallback_normal`] perpendicular to the longer edge.
pub fn edge_edge(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> Closest {
    let e = p1 - p0;
    let f = q1 - q0;
    let r = p0 - q0;
    let m = e.cross(f);
    let mm = m.dot(m);
    let ee = e.dot(e);
    let ff = f.dot(f);

    let mut interior: Option<Closest> = None;
    if mm > 0.0 && mm.is_finite() {
        let ef = e.dot(f);
        let er = e.dot(r);
        let fr = f.dot(r);
        let inv_mm = 1.0 / mm;
        let s = (ef * fr - ff * er) * inv_mm;
        let t = (ee * fr - ef * er) * inv_mm;
        if (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t) {
            let inv_len = 1.0 / mm.sqrt();
            let signed = r.dot(m) * inv_len;
            let unit_m = m * inv_len;
            let n = if signed < 0.0 { -unit_m } else { unit_m };
            let cand = Closest {
                d: signed.abs(),
                n,
                coeff: [1.0 - s, s, -(1.0 - t), -t],
            };
            let nearly_parallel = mm <= 1e-8 * ee * ff;
            if !nearly_parallel {
                return cand;
            }
            // Nearly parallel: `s, t` are ill-conditioned and the plane
            // formula is the distance of the *lines*, which can be far below
            // that of the segments. Keep only what is realizable: the distance
            // between the two points at `s, t` (a pair of points of the
            // segments, so never below the true minimum).
            // One alternating projection from there (each step can only
            // lower the distance of the pair) sharpens crossings at tiny angles.
            let t2 = ((p0 + e * s - q0).dot(f) / ff).clamp(0.0, 1.0);
            let s2 = ((q0 + f * t2 - p0).dot(e) / ee).clamp(0.0, 1.0);
            let pair = |s: f64, t: f64| (p0 + e * s) - (q0 + f * t);
            let (s, t) = if pair(s2, t2).length() < pair(s, t).length() {
                (s2, t2)
            } else {
                (s, t)
            };
            let diff = pair(s, t);
            let d = diff.length();
            interior = Some(Closest {
                d,
                n: normal_along(diff, d).unwrap_or(cand.n),
                coeff: [1.0 - s, s, -(1.0 - t), -t],
            });
        }
    }

    // Endpoint candidates (squared distances). `diff` always points from the
    // q-side to the p-side.
    let (ta, da, ga) = point_segment(p0, q0, q1);
    let (tb, db, gb) = point_segment(p1, q0, q1);
    let (tc, dc, gc) = point_segment(q0, p0, p1);
    let (td, dd, gd) = point_segment(q1, p0, p1);
    let mut best = (da, ga, [1.0, 0.0, -(1.0 - ta), -ta]);
    if db < best.0 {
        best = (db, gb, [0.0, 1.0, -(1.0 - tb), -tb]);
    }
    if dc < best.0 {
        best = (dc, -gc, [1.0 - tc, tc, -1.0, 0.0]);
    }
    if dd < best.0 {
        best = (dd, -gd, [1.0 - td, td, 0.0, -1.0]);
    }
    let (dist2, diff, coeff) = best;
    let d = dist2.sqrt();
    if let Some(c) = interior {
        if c.d <= d {
            return c;
        }
    }
    let n =
        normal_along(diff, d).unwrap_or_else(|| fallback_normal(m, if ee >= ff { e } else { f }));
    Closest { d, n, coeff }
}
