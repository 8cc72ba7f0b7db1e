//! Vertex–face (point–triangle) distance.
//!
//! With `u = b - a`, `v = c - a`, `w = p - a` and the (unnormalized) face normal
//! `m = u x v`, the projection of `p` onto the triangle's plane has barycentric
//! weights
//!
//! ```text
//!     w1 = (w x v) . m / |m|^2,   w2 = (u x w) . m / |m|^2,   w0 = 1 - w1 - w2
//! ```
//!
//! (write `w = w1 u + w2 v + h m/|m|`; the `h` terms are perpendicular to `m`).
//! When all three are `>= 0` the closest point is the projection (face region)
//! and `d = |w . m| / |m|`, `n = sign(w . m) m / |m|` — the plane formula, which
//! stays accurate for points very close to the face. Otherwise the closest point
//! lies on an edge (edge or vertex Voronoi region) and `d` is the minimum of the
//! three point–segment distances, ties going to the first edge in the order
//! `ab, bc, ca`.
//!
//! A sliver triangle (`|m|^2 <= 1e-8 |u|^2 |v|^2`, i.e. a smallest angle below
//! about 1e-4 rad) has a badly conditioned normal; there the face candidate is
//! also compared with the edge candidates and the smaller distance wins, and
//! where the plane formula's error bound exceeds the triangle's smallest
//! height (how far the edge candidates can be off) the face candidate is
//! dropped. A zero-area triangle (`m == 0`) has no face candidate at all.

use super::{fallback_normal, normal_along, point_segment, Closest};
use weft_core::DVec3;

/// Distance from the point `p` to the closed triangle `(a, b, c)`.
///
/// Returns `coeff = [1, -w0, -w1, -w2]` with the closest point
/// `w0 a + w1 b + w2 c` and `n` pointing from the triangle to `p`. When `d == 0`
/// the normal is the face normal `(b - a) x (c - a)` normalized, or for a
/// zero-area triangle the fallback of [`super::fallback_normal`] built from the
/// longest edge direction.
pub fn vertex_face(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Closest {
    let u = b - a;
    let v = c - a;
    let w = p - a;
    let m = u.cross(v);
    let mm = m.dot(m);

    let mut face: Option<Closest> = None;
    if mm > 0.0 && mm.is_finite() {
        let inv_mm = 1.0 / mm;
        let w1 = w.cross(v).dot(m) * inv_mm;
        let w2 = u.cross(w).dot(m) * inv_mm;
        let w0 = 1.0 - w1 - w2;
        if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
            let inv_len = 1.0 / mm.sqrt();
            let signed = w.dot(m) * inv_len;
            let unit_m = m * inv_len;
            let n = if signed < 0.0 { -unit_m } else { unit_m };
            let cand = Closest {
                d: signed.abs(),
                n,
                coeff: [1.0, -w0, -w1, -w2],
            };
            let (uu, vv) = (u.dot(u), v.dot(v));
            let sliver = mm <= 1e-8 * uu * vv;
            if !sliver {
                return cand;
            }
            // The plane formula errs by about `|w| |delta m| / |m|`, the
            // rounding of `m` being up to `2.83 u |u| |v|` (`u = 2^-53`),
            // while every point of the triangle lies within its smallest
            // height `h = |m| / (longest edge)` of the boundary, so the
            // boundary candidates alone err by at most `h`. Keep the face
            // candidate only where its error bound is the smaller (down to
            // a thinness of about `sqrt(u)`, the larger error is then
            // below about 1e-8 of the triangle's size).
            let longest = uu.max(vv).max((c - b).dot(c - b)).sqrt();
            let plane_error = 8.0 * f64::powi(2.0, -53) * w.length() * (uu * vv).sqrt() * inv_len;
            if plane_error < mm.sqrt() / longest {
                face = Some(cand);
            }
        }
    }

    // Edge / vertex regions: minimum over the three closed edges (squared
    // distances compared, one square root for the winner).
    let (t0, d0, g0) = point_segment(p, a, b);
    let (t1, d1, g1) = point_segment(p, b, c);
    let (t2, d2, g2) = point_segment(p, c, a);
    let (dist2, diff, coeff) = if d0 <= d1 && d0 <= d2 {
        (d0, g0, [1.0, -(1.0 - t0), -t0, 0.0])
    } else if d1 <= d2 {
        (d1, g1, [1.0, 0.0, -(1.0 - t1), -t1])
    } else {
        (d2, g2, [1.0, -t2, 0.0, -(1.0 - t2)])
    };
    let d = dist2.sqrt();
    if let Some(f) = face {
        if f.d <= d {
            return f;
        }
    }
    let n = normal_along(diff, d).unwrap_or_else(|| {
        // Longest edge direction for the perpendicular fallback.
        let e1 = c - b;
        let longest = if u.dot(u) >= e1.dot(e1) && u.dot(u) >= v.dot(v) {
            u
        } else if e1.dot(e1) >= v.dot(v) {
            e1
        } else {
            v
        };
        fallback_normal(m, longest)
    });
    Closest { d, n, coeff }
}
