//! Ribbons: strips of width `w` along a centreline, with a flat rest strip.
//!
//! # The strip
//!
//! A centreline `c(s)` (arc length `s`) and a unit width direction `d(s)`
//! perpendicular to the tangent `T` span the surface `x(s, u) = c(s) + u d(s)`,
//! `u` in `[-w/2, w/2]`. Its rest shape is the flat rectangle `(s, u)` of the
//! same length. With the curvature `kappa`, the principal normal `N` and the
//! rate `theta'` at which `d` turns about `T` relative to a parallel-transported
//! frame, `d' = -kappa (N.d) T + theta' (T x d)`, so the metric is
//! `g_su = 0`, `g_uu = 1` and the only Green strain is along the strip:
//!
//! ```text
//!     E_ss(u) = -u kappa (N.d) + u^2 (kappa^2 (N.d)^2 + theta'^2) / 2
//! ```
//!
//! The first-order term vanishes when `d` is the binormal `B` (the strip then
//! bends about its width, like a tape), the second-order twist term
//! `(w/2)^2 theta'^2 / 2` stays small when `d` turns slowly. Where the curve is
//! nearly straight `kappa` is small and `d` may turn freely; where it bends
//! hard `d` must follow `B`. [`width_directions`] picks the angle `theta_i` of
//! `d` in a parallel-transported frame by minimizing
//!
//! ```text
//!     sum_i b_i h_i (kappa_i w/2)^2 sin^2(theta_i - beta_i)
//!   + sum_i t_i mu (theta_{i+1} - theta_i)^2 / h_i  +  hints
//! ```
//!
//! (`beta_i` the angle of the discrete binormal, taken modulo `pi` since `d`
//! and `-d` span the same strip; `mu = (w/2)^2`) by Gauss–Newton on a
//! tridiagonal system, starting from the binormal angles unwrapped along the
//! curve, so `theta` is continuous and the strip never flips. The weights
//! `b_i`, `t_i` start at 1 and are reweighted 20 times, each row or edge by
//! `(1 + its strain / the largest strain)^2` (first-order bend strain
//! `kappa w/2 |sin(theta - beta)|` for rows, twist strain
//! `(w/2)^2 theta'^2 / 2` for edges): the least-squares fit drifts towards
//! the smallest largest strain, twisting on the straight stretches rather
//! than where the strip bends. [`WidthHint`]s add preferred directions (a
//! knot's ribbon lying flat where another crosses it).
//!
//! # Discretization
//!
//! The centreline is resampled to `along` points equally spaced in arc length
//! ([`resample`]); vertex `(i, j)` (row `i` along, column `j` across, id
//! `i * across + j`) sits at `c_i + u_j d_i`. The rest strip uses the
//! cumulative chord lengths of the resampled centreline, so the centreline
//! itself is unstrained; the strain of the mesh is measured per triangle as the
//! largest absolute principal Green strain ([`max_green_strain`], the measure
//! `weft info` prints).
//!
//! [`min_clearance`] measures the smallest distance over the contact stencils
//! of a mesh (vertex–face with the vertex not a corner of the face, edge–edge
//! with no shared vertex), the pairs the engine checks at the start.

use glam::DVec3;
use thiserror::Error;
use weft_core::TriMesh;

use crate::bvh::Bvh;
use crate::distance::{edge_edge, vertex_face};
use crate::dop::Dop26;

/// A ribbon that cannot be generated.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum RibbonError {
    #[error("width must be a positive, finite length in metres (got {0})")]
    Width(f64),
    #[error("a ribbon needs at least 2 vertices across (got {0})")]
    Across(usize),
    #[error("a ribbon needs at least 2 rows of vertices along (got {0})")]
    Along(usize),
    #[error("the centreline needs at least 2 distinct points (got {0})")]
    TooFewPoints(usize),
    #[error("centreline point {index} is not finite")]
    NonFinite { index: usize },
    #[error("the centreline turns back on itself at point {index} (a turn of {degrees:.0} degrees between two samples)")]
    Fold { index: usize, degrees: f64 },
    #[error("the clearance {found:.4e} m between non-adjacent parts (near {near:?}) is below the required {required:.4e} m")]
    Clearance {
        found: f64,
        required: f64,
        near: [f64; 3],
    },
}

/// A generated ribbon: the start mesh, its flat rest strip (same vertex order)
/// and what was measured on it.
#[derive(Clone, Debug)]
pub struct Ribbon {
    /// Start shape; vertex `(i, j)` has id `i * across + j`.
    pub mesh: TriMesh,
    /// The flat rest rectangle in the plane z = 0: vertex `(i, j)` at
    /// `(s_i, -w/2 + j w / (across - 1), 0)`.
    pub rest: Vec<DVec3>,
    pub across: usize,
    pub along: usize,
    /// Length of the (resampled) centreline = length of the rest strip (m).
    pub length: f64,
    /// Largest |principal Green strain| of a triangle, start against rest.
    pub max_strain: f64,
    /// The resampled centreline and the unit width direction at each row.
    pub centreline: Vec<DVec3>,
    pub directions: Vec<DVec3>,
}

/// Length of a polyline (m).
pub fn polyline_length(points: &[DVec3]) -> f64 {
    points.windows(2).map(|p| (p[1] - p[0]).length()).sum()
}

/// Rejects non-finite points and fewer than two distinct points; returns the
/// points with exact repeats of their predecessor removed.
fn clean(points: &[DVec3]) -> Result<Vec<DVec3>, RibbonError> {
    let mut out: Vec<DVec3> = Vec::with_capacity(points.len());
    for (index, p) in points.iter().enumerate() {
        if !p.is_finite() {
            return Err(RibbonError::NonFinite { index });
        }
        if out.last() != Some(p) {
            out.push(*p);
        }
    }
    if out.len() < 2 {
        return Err(RibbonError::TooFewPoints(out.len()));
    }
    Ok(out)
}

/// `count >= 2` points equally spaced in arc length along the polyline
/// `points` (first and last point kept exactly).
pub fn resample(points: &[DVec3], count: usize) -> Result<Vec<DVec3>, RibbonError> {
    if count < 2 {
        return Err(RibbonError::Along(count));
    }
    let p = clean(points)?;
    let mut cum = Vec::with_capacity(p.len());
    let mut s = 0.0;
    cum.push(0.0);
    for w in p.windows(2) {
        s += (w[1] - w[0]).length();
        cum.push(s);
    }
    let total = s;
    let mut out = Vec::with_capacity(count);
    let mut seg = 0usize;
    for k in 0..count {
        if k + 1 == count {
            out.push(*p.last().unwrap_or(&DVec3::ZERO));
            break;
        }
        let target = total * k as f64 / (count - 1) as f64;
        while seg + 2 < cum.len() && cum[seg + 1] < target {
            seg += 1;
        }
        let len = cum[seg + 1] - cum[seg];
        let t = if len > 0.0 {
            ((target - cum[seg]) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(p[seg].lerp(p[seg + 1], t));
    }
    Ok(out)
}

/// A clamped uniform cubic B-spline over `control` points (the curve starts at
/// the first point, ends at the last, and is C2, so its curvature and binormal
/// vary continuously), sampled `per_span` times per knot span.
pub fn bspline(control: &[DVec3], per_span: usize) -> Vec<DVec3> {
    if control.len() < 2 {
        return control.to_vec();
    }
    let n = control.len();
    let mut q = Vec::with_capacity(n + 4);
    q.extend([control[0]; 2]);
    q.extend_from_slice(control);
    q.extend([control[n - 1]; 2]);
    let per_span = per_span.max(1);
    let mut out = Vec::with_capacity((q.len() - 3) * per_span + 1);
    for k in 0..q.len() - 3 {
        let (p0, p1, p2, p3) = (q[k], q[k + 1], q[k + 2], q[k + 3]);
        for m in 0..per_span {
            let t = m as f64 / per_span as f64;
            let (t2, t3) = (t * t, t * t * t);
            let b0 = (1.0 - t) * (1.0 - t) * (1.0 - t) / 6.0;
            let b1 = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
            let b2 = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
            let b3 = t3 / 6.0;
            out.push(p0 * b0 + p1 * b1 + p2 * b2 + p3 * b3);
        }
    }
    out.push(control[n - 1]);
    out.dedup();
    out
}

/// Samples the parametric curve `f` at `samples + 1` equally spaced
/// parameters in `[t0, t1]`.
pub fn sample_curve(f: impl Fn(f64) -> DVec3, t0: f64, t1: f64, samples: usize) -> Vec<DVec3> {
    let samples = samples.max(1);
    (0..=samples)
        .map(|k| f(t0 + (t1 - t0) * k as f64 / samples as f64))
        .collect()
}

/// Rows along a ribbon of `length` so that the spacing along matches the
/// spacing across, `width / (across - 1)`, as nearly as possible.
pub fn rows_for(length: f64, width: f64, across: usize) -> usize {
    let h = width / (across.max(2) - 1) as f64;
    ((length / h).round() as usize).saturating_add(1).max(2)
}

/// Vertices across and rows along for ribbons of the given `lengths` sharing
/// one `width` so that all of them together have about `target` vertices with
/// spacing along close to spacing across: the `across` (at least 2) whose
/// along/across spacing ratio at exactly `target` vertices is closest to 1.
/// Returns `(across, rows per ribbon)`.
pub fn resolution_for(lengths: &[f64], width: f64, target: usize) -> (usize, Vec<usize>) {
    let total: f64 = lengths.iter().sum();
    let mut best = (2usize, f64::INFINITY);
    if total > 0.0 && width > 0.0 {
        for across in 2..=4096usize {
            let rows = target as f64 / (across as f64 * lengths.len().max(1) as f64);
            let h_along = total / lengths.len().max(1) as f64 / (rows - 1.0).max(1.0);
            let h_across = width / (across - 1) as f64;
            let miss = (h_along / h_across).ln().abs();
            if miss < best.1 {
                best = (across, miss);
            }
            if h_across < 0.5 * h_along {
                break;
            }
        }
    }
    let across = best.0;
    // Distribute the target over the ribbons in proportion to their lengths.
    let rows = lengths
        .iter()
        .map(|&l| {
            let share = if total > 0.0 {
                l / total
            } else {
                1.0 / lengths.len() as f64
            };
            ((target as f64 * share / across as f64).round() as usize).max(2)
        })
        .collect();
    (across, rows)
}

/// Unit vertex tangents of a polyline (bisectors of the adjacent segments).
fn vertex_tangents(c: &[DVec3]) -> Vec<DVec3> {
    let n = c.len();
    let seg: Vec<DVec3> = c.windows(2).map(|p| (p[1] - p[0]).normalize()).collect();
    (0..n)
        .map(|i| {
            if i == 0 {
                seg[0]
            } else if i + 1 == n {
                seg[n - 2]
            } else {
                let t = seg[i - 1] + seg[i];
                if t.length_squared() > 1e-24 {
                    t.normalize()
                } else {
                    seg[i]
                }
            }
        })
        .collect()
}

/// A unit vector perpendicular to the unit vector `t`.
fn any_perpendicular(t: DVec3) -> DVec3 {
    let axis = crate::distance::smallest_axis(t);
    (axis - t * t.dot(axis)).normalize()
}

/// Rotates `v` by the smallest rotation taking unit `a` to unit `b`.
fn transport(v: DVec3, a: DVec3, b: DVec3) -> DVec3 {
    let axis = a.cross(b);
    let s = axis.length();
    let c = a.dot(b);
    if s < 1e-15 {
        return if c > 0.0 { v } else { -v };
    }
    let k = axis / s;
    v * c + k.cross(v) * s + k * k.dot(v) * (1.0 - c)
}

/// The default `twist_weight` of [`width_directions`].
pub const TWIST_WEIGHT: f64 = 1.0;

/// A preferred width direction over a stretch of a ribbon: every row whose
/// centreline arc length lies within `half_length` of `s` is pulled towards
/// `direction` (projected perpendicular to the tangent) with `weight`, in the
/// units of `(kappa w/2)^2`: a weight of `0.1^2` pulls as hard as a bend whose
/// first-order edge strain would be 10 %.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WidthHint {
    pub s: f64,
    pub half_length: f64,
    pub direction: DVec3,
    pub weight: f64,
}

impl WidthHint {
    /// The hint with its arc lengths multiplied by `scale` (mapping it onto a
    /// resampled polyline of a slightly different length).
    pub fn scaled(&self, scale: f64) -> Self {
        Self {
            s: self.s * scale,
            half_length: self.half_length * scale,
            ..*self
        }
    }
}

/// Unit width directions `d_i` (perpendicular to the vertex tangents, turning
/// continuously) for a ribbon of `width` along the polyline `c`, see the
/// module docs. `twist_weight` is `mu / (w/2)^2` (1 is a good default);
/// `hints` add preferred directions over stretches of the curve.
pub fn width_directions(
    c: &[DVec3],
    width: f64,
    twist_weight: f64,
    hints: &[WidthHint],
) -> Vec<DVec3> {
    let n = c.len();
    if n < 2 {
        return vec![any_perpendicular(DVec3::X); n];
    }
    let t = vertex_tangents(c);
    let h: Vec<f64> = c.windows(2).map(|p| (p[1] - p[0]).length()).collect();
    let mut s = vec![0.0; n];
    for i in 1..n {
        s[i] = s[i - 1] + h[i - 1];
    }
    // Parallel-transported frame (u_i, v_i = T_i x u_i).
    let mut u = Vec::with_capacity(n);
    u.push(any_perpendicular(t[0]));
    for i in 1..n {
        let w = transport(u[i - 1], t[i - 1], t[i]);
        let w = (w - t[i] * t[i].dot(w)).normalize();
        u.push(w);
    }
    let v: Vec<DVec3> = (0..n).map(|i| t[i].cross(u[i])).collect();
    let angle_of = |i: usize, d: DVec3| libm::atan2(d.dot(v[i]), d.dot(u[i]));
    // Targets per row: (angle, weight). The binormal with the squared
    // first-order strain amplitude (kappa_i w/2)^2, then any hints.
    let mut targets: Vec<Vec<(f64, f64)>> = vec![Vec::new(); n];
    let mut is_bend = vec![false; n];
    for i in 1..n - 1 {
        let e0 = (c[i] - c[i - 1]).normalize();
        let e1 = (c[i + 1] - c[i]).normalize();
        let b = e0.cross(e1);
        let sin = b.length();
        if sin > 1e-12 {
            let angle = libm::atan2(sin, e0.dot(e1));
            let kappa = 2.0 * libm::sin(0.5 * angle) / (0.5 * (h[i - 1] + h[i]));
            let a = kappa * 0.5 * width;
            targets[i].push((angle_of(i, b / sin), a * a));
            is_bend[i] = true;
        }
    }
    for hint in hints {
        for i in 0..n {
            if (s[i] - hint.s).abs() <= hint.half_length && hint.weight > 0.0 {
                let d = hint.direction - t[i] * t[i].dot(hint.direction);
                if d.length() > 1e-9 {
                    targets[i].push((angle_of(i, d.normalize()), hint.weight));
                }
            }
        }
    }
    let weight = |i: usize| targets[i].iter().map(|&(_, w)| w).sum::<f64>();
    let wmax = (0..n).map(weight).fold(0.0, f64::max);
    if !(wmax > 0.0) {
        // A straight ribbon without hints: any constant (transported) direction.
        return u;
    }
    // Initial guess: the strongest target at each row, unwrapped (mod pi)
    // along the curve, held over rows with weak targets.
    let strong = |i: usize| weight(i) > 0.01 * wmax;
    let dominant = |i: usize| {
        targets[i]
            .iter()
            .cloned()
            .fold((0.0, -1.0), |best, x| if x.1 > best.1 { x } else { best })
            .0
    };
    let mut theta = vec![0.0; n];
    let first = (0..n).find(|&i| strong(i)).unwrap_or(0);
    let mut prev = dominant(first);
    for i in 0..n {
        if strong(i) {
            prev = nearest_mod_pi(dominant(i), prev);
        }
        theta[i] = prev;
    }
    let mu = twist_weight.max(1e-9) * 0.25 * width * width;
    let eps = 1e-9 * wmax;
    let hv = |i: usize| {
        if i == 0 {
            0.5 * h[0]
        } else if i + 1 == n {
            0.5 * h[n - 2]
        } else {
            0.5 * (h[i - 1] + h[i])
        }
    };
    // Iteratively reweighted least squares towards the smallest largest
    // strain: after each solve, rows and edges whose first-order (bend) or
    // twist strain is close to the largest one get heavier.
    let mut bend_mult = vec![1.0f64; n];
    let mut twist_mult = vec![1.0f64; n - 1];
    let outer = 20;
    for round in 0..=outer {
        for _ in 0..4 {
            // Linearize each sin^2(theta - target) about the target angle
            // nearest (mod pi) to the current iterate.
            let mut diag = vec![0.0; n];
            let mut off = vec![0.0; n - 1];
            let mut rhs = vec![0.0; n];
            for i in 0..n {
                for (k, &(angle, w)) in targets[i].iter().enumerate() {
                    let m = if k == 0 && is_bend[i] {
                        bend_mult[i]
                    } else {
                        1.0
                    };
                    let wgt = w * m * hv(i);
                    diag[i] += wgt;
                    rhs[i] += wgt * nearest_mod_pi(angle, theta[i]);
                }
                diag[i] += eps;
                rhs[i] += eps * theta[i];
            }
            for i in 0..n - 1 {
                let k = mu * twist_mult[i] / h[i];
                diag[i] += k;
                diag[i + 1] += k;
                off[i] = -k;
            }
            theta = solve_tridiagonal(&diag, &off, &rhs);
        }
        if round == outer {
            break;
        }
        let bend: Vec<f64> = (0..n)
            .map(|i| {
                if is_bend[i] {
                    let (angle, w) = targets[i][0];
                    w.sqrt() * libm::sin(theta[i] - angle).abs()
                } else {
                    0.0
                }
            })
            .collect();
        let twist: Vec<f64> = (0..n - 1)
            .map(|i| {
                let rate = 0.5 * width * (theta[i + 1] - theta[i]) / h[i];
                0.5 * rate * rate
            })
            .collect();
        let worst = bend.iter().chain(&twist).cloned().fold(0.0, f64::max);
        if !(worst > 0.0) {
            break;
        }
        for i in 0..n {
            bend_mult[i] *= (1.0 + bend[i] / worst).powi(2);
        }
        for i in 0..n - 1 {
            twist_mult[i] *= (1.0 + twist[i] / worst).powi(2);
        }
    }
    (0..n)
        .map(|i| (u[i] * libm::cos(theta[i]) + v[i] * libm::sin(theta[i])).normalize())
        .collect()
}

/// `b + k pi` nearest to `x`.
fn nearest_mod_pi(b: f64, x: f64) -> f64 {
    let pi = std::f64::consts::PI;
    b + ((x - b) / pi).round() * pi
}

/// Solves the symmetric tridiagonal system (diagonal `d`, off-diagonal `e`)
/// by the Thomas algorithm (the system here is diagonally dominant).
fn solve_tridiagonal(d: &[f64], e: &[f64], r: &[f64]) -> Vec<f64> {
    let n = d.len();
    let mut c = vec![0.0; n];
    let mut y = vec![0.0; n];
    let mut m = d[0];
    c[0] = if n > 1 { e[0] / m } else { 0.0 };
    y[0] = r[0] / m;
    for i in 1..n {
        m = d[i] - e[i - 1] * c[i - 1];
        if i + 1 < n {
            c[i] = e[i] / m;
        }
        y[i] = (r[i] - e[i - 1] * y[i - 1]) / m;
    }
    for i in (0..n - 1).rev() {
        y[i] -= c[i] * y[i + 1];
    }
    y
}

/// Triangles of an `along x across` strip (ids `i * across + j`), quads split
/// along alternating diagonals, counter-clockwise in the rest plane (normal +z).
pub fn strip_triangles(along: usize, across: usize) -> Vec<[u32; 3]> {
    let id = |i: usize, j: usize| (i * across + j) as u32;
    let mut t = Vec::with_capacity(2 * (along - 1) * (across - 1));
    for i in 0..along - 1 {
        for j in 0..across - 1 {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                t.push([a, b, c]);
                t.push([a, c, d]);
            } else {
                t.push([a, b, d]);
                t.push([b, c, d]);
            }
        }
    }
    t
}

/// A ribbon of `width` with `across` vertices across along the centreline
/// polyline `points`, resampled to `along` rows.
pub fn ribbon(
    points: &[DVec3],
    width: f64,
    across: usize,
    along: usize,
) -> Result<Ribbon, RibbonError> {
    ribbon_with_hints(points, width, across, along, &[])
}

/// [`ribbon`] with preferred width directions over stretches of the
/// centreline (arc lengths and lengths along the given polyline `points`).
pub fn ribbon_with_hints(
    points: &[DVec3],
    width: f64,
    across: usize,
    along: usize,
    hints: &[WidthHint],
) -> Result<Ribbon, RibbonError> {
    if !(width > 0.0 && width.is_finite()) {
        return Err(RibbonError::Width(width));
    }
    if across < 2 {
        return Err(RibbonError::Across(across));
    }
    let c = resample(points, along)?;
    // A turn of more than 120 degrees between two samples cannot carry a strip.
    for i in 1..c.len() - 1 {
        let (e0, e1) = ((c[i] - c[i - 1]).normalize(), (c[i + 1] - c[i]).normalize());
        let degrees = libm::acos(e0.dot(e1).clamp(-1.0, 1.0)).to_degrees();
        if degrees > 120.0 {
            return Err(RibbonError::Fold { index: i, degrees });
        }
    }
    // Rows are equally spaced in the arc length of `points`; map the hints'
    // arc lengths onto the resampled polyline's.
    let scale = polyline_length(&c) / polyline_length(points).max(f64::MIN_POSITIVE);
    let hints: Vec<WidthHint> = hints.iter().map(|h| h.scaled(scale)).collect();
    let d = width_directions(&c, width, TWIST_WEIGHT, &hints);
    let mut positions = Vec::with_capacity(along * across);
    let mut rest = Vec::with_capacity(along * across);
    let mut s = 0.0;
    for i in 0..along {
        if i > 0 {
            s += (c[i] - c[i - 1]).length();
        }
        for j in 0..across {
            let u = width * (j as f64 / (across - 1) as f64 - 0.5);
            positions.push(c[i] + d[i] * u);
            rest.push(DVec3::new(s, u, 0.0));
        }
    }
    let triangles = strip_triangles(along, across);
    let max_strain = max_green_strain(&rest, &positions, &triangles);
    Ok(Ribbon {
        mesh: TriMesh::new(positions, triangles),
        rest,
        across,
        along,
        length: s,
        max_strain,
        centreline: c,
        directions: d,
    })
}

/// Largest absolute principal Green strain `G = (F^T F - I) / 2` over the
/// triangles, with `F` mapping each `rest` triangle onto its `start` triangle
/// (the figure `weft info` prints as the initial strain). Degenerate rest
/// triangles are skipped.
pub fn max_green_strain(rest: &[DVec3], start: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    let mut worst = 0.0f64;
    for t in triangles {
        let [r0, r1, r2] = t.map(|i| rest[i as usize]);
        let [x0, x1, x2] = t.map(|i| start[i as usize]);
        // Rest frame: e0 along r1 - r0, e1 in the triangle's plane.
        let a = r1 - r0;
        let b = r2 - r0;
        let la = a.length();
        let nrm = a.cross(b);
        if !(la > 0.0 && nrm.length() > 0.0) {
            continue;
        }
        let e0 = a / la;
        let e1 = nrm.cross(a).normalize();
        // Rest edge matrix D = [[la, b.e0], [0, b.e1]] and its inverse.
        let (d00, d01, d11) = (la, b.dot(e0), b.dot(e1));
        let (p, q, r) = (1.0 / d00, -d01 / (d00 * d11), 1.0 / d11);
        let (u, v) = (x1 - x0, x2 - x0);
        let f0 = u * p;
        let f1 = u * q + v * r;
        worst = worst.max(crate::strain::max_principal_green(f0, f1));
    }
    worst
}

/// The closest contact stencil of a mesh found within `probe`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clearance {
    /// Distance (m).
    pub distance: f64,
    /// The stencil's vertices: `[p, a, b, c]` (vertex–face) or `[p0, p1, q0, q1]`
    /// (edge–edge).
    pub vertices: [u32; 4],
    pub edge_edge: bool,
}

/// The smallest distance over the mesh's contact stencils (vertex–face with the
/// vertex not a corner of the face, edge–edge with no shared vertex) that is
/// below `probe`, or `None` when every stencil is at least `probe` apart.
/// Candidate triangle pairs come from a BVH of 26-DOPs inflated by `probe / 2`
/// (adjacent triangles included), so no pair within `probe` is missed.
pub fn min_clearance(positions: &[DVec3], triangles: &[[u32; 3]], probe: f64) -> Option<Clearance> {
    let leaves: Vec<Dop26> = triangles
        .iter()
        .map(|t| {
            let mut d = Dop26::empty();
            for &v in t {
                d.add_point(positions[v as usize]);
            }
            d.inflate(0.5 * probe);
            d
        })
        .collect();
    let bvh = Bvh::build(&leaves);
    let mut best: Option<Clearance> = None;
    let mut consider = |distance: f64, vertices: [u32; 4], ee: bool| {
        if distance < probe && best.is_none_or(|b| distance < b.distance) {
            best = Some(Clearance {
                distance,
                vertices,
                edge_edge: ee,
            });
        }
    };
    let x = |i: u32| positions[i as usize];
    bvh.self_overlaps(|i, j| {
        let (ti, tj) = (triangles[i as usize], triangles[j as usize]);
        for (s, f) in [(ti, tj), (tj, ti)] {
            for &p in &s {
                if !f.contains(&p) {
                    let c = vertex_face(x(p), x(f[0]), x(f[1]), x(f[2]));
                    consider(c.d, [p, f[0], f[1], f[2]], false);
                }
            }
        }
        for ea in 0..3 {
            let (p0, p1) = (ti[ea], ti[(ea + 1) % 3]);
            for eb in 0..3 {
                let (q0, q1) = (tj[eb], tj[(eb + 1) % 3]);
                if p0 == q0 || p0 == q1 || p1 == q0 || p1 == q1 {
                    continue;
                }
                let c = edge_edge(x(p0), x(p1), x(q0), x(q1));
                consider(c.d, [p0, p1, q0, q1], true);
            }
        }
    });
    best
}
