//! Space–time separating-plane certificate with a rigorous rounding bound.
//!
//! ## The certificate
//!
//! Split the stencil's vertices into the two primitives: VF `A = {0}`,
//! `B = {1, 2, 3}`; EE `A = {0, 1}`, `B = {2, 3}`. For a direction `n` (any
//! nonzero vector) and a time `t`,
//!
//! ```text
//!     n . (x_i(t) - x_j(t)) > eta |n|    for every i in A, j in B        (*)
//! ```
//!
//! implies `n . (P - Q) > eta |n|` for every convex combination `P` of the
//! `x_i` and `Q` of the `x_j` (multiply by the weights and sum), hence
//! `|P - Q| > eta`: the primitives are farther than `eta` apart at `t`.
//! (The separating plane itself never has to be built: it is any plane between
//! `min_A n.x` and `max_B n.x`.)
//!
//! On the interval `[ta, tb]` take the **rotating normal** `n(t)` linear from
//! `na` (at `ta`) to `nb` (at `tb`). Cut `[ta, tb]` at every breakpoint of the
//! four trajectories that lies inside; on each sub-segment `[s0, s1]` every
//! vertex moves linearly and `n(t)` is linear (from `n0 = n(s0)` to
//! `n1 = n(s1)`, whatever floating values were computed for them — each
//! sub-segment is certified on its own, so continuity across sub-segments is not
//! needed). With `d_ij(t) = x_i(t) - x_j(t)` (linear) and `s` the normalized
//! time on the sub-segment, `h_ij(s) = n(s) . d_ij(s)` is a quadratic with
//! Bernstein coefficients
//!
//! ```text
//!     b0 = n0 . d0,   b1 = (n0 . d1 + n1 . d0) / 2,   b2 = n1 . d1
//! ```
//!
//! and `min_s h_ij(s) >= min(b0, b1, b2)` (convex-hull property of Bernstein
//! polynomials). Since `|n(s)| <= max(|n0|, |n1|)` (convexity of the norm),
//! `min(b0, b1, b2) > eta max(|n0|, |n1|)` for every pair certifies (*) on the
//! whole sub-segment. With `n0 == n1` this is the fixed-normal test (then
//! `h_ij` is linear and the bound is exact); the rotating normal makes the test
//! second-order accurate.
//!
//! ## Rounding-error bound (a running bound, computed next to each coefficient)
//!
//! `u = 2^-53`, `gamma_k = k u / (1 - k u)`. Standard model: a correctly
//! rounded operation returns `(x op y)(1 + delta)`, `|delta| <= u`, and also
//! `|fl(z) - z| <= u |fl(z)|`. No overflow: the caller guarantees finite
//! coordinates and `eta` of magnitude `<= 2^500`, and normals are used only
//! with `|n|_1 <= 2^64`. Underflow adds at most `2^-1075` per operation; the
//! absolute slack `2^-1000` added to every threshold covers it.
//!
//! 1. **Positions.** At a breakpoint of its own trajectory a vertex's position
//!    is stored, exact; a coordinate that does not move on the segment
//!    (`P_c == Q_c`) is also exact (`fl(Q-P) = 0`). Otherwise
//!    `x = P + alpha (Q - P)`, `alpha = (t - tk) / (tk1 - tk)`: `alpha` carries
//!    three roundings, `|alpha~ - alpha| <= gamma_3 alpha` (`0 <= alpha <= 1`);
//!    `D = Q - P` one; the product one: `|fl(alpha~ fl(D)) - alpha D| <= gamma_5 |D|`;
//!    the final sum one more, `<= u (|x| + gamma_5 |D|)`. With
//!    `|D|, |x| <= |P| + |Q|`: `|x~ - x| <= 6.1 u (|P_c| + |Q_c|) =: e_c`; the
//!    code uses `8 u (|P_c| + |Q_c|)`.
//! 2. **Differences** `d~ = fl(x~_i - x~_j)`:
//!    `|d~_c - d_c| <= e_ic + e_jc + u |d~_c| =: E_c`.
//! 3. **Dot products** with a floating normal `n` (used as exact):
//!    `|fl(n . d~) - n . d| <= sum_c |n_c| E_c + gamma_3 sum_c |n_c| |d~_c|`
//!    (Higham, Thm 3.1, for the three-term dot product); this bounds `b0`, `b2`.
//! 4. **Middle coefficient** `b1 = 0.5 (n0.d1 + n1.d0)`: the two dot-product
//!    bounds plus `u |fl(n0.d1 + n1.d0)|` for the sum, halved (exact).
//! 5. **Threshold.** `|n|` is bounded above by `sqrt(fl(n.n)) (1 + 4u)`
//!    (`fl(n.n) >= (1 - gamma_3) n.n`, one rounding in `sqrt`); `eta nmax` is
//!    computed with one more rounding, covered by another factor `1 + 4u`.
//!
//! Certify iff `b~ > eta nmax (1 + 4u) + 2^-1000 + C E~` for each of the three
//! coefficients of every pair, with `E~` the bound of steps 3–4 evaluated in
//! floating point and [`MARGIN_C`] `= 4`. The bounds are sums of at most a dozen
//! products of nonnegative floats, so the computed `E~` is within a relative
//! `gamma_12 < 2e-15` of the exact bound and `C = 4` leaves a factor of almost
//! 4 to spare (besides step 1 already rounding `6.1 u` up to `8 u`). Hence
//! `b~ > threshold` implies `b > eta max|n|` for the exact coefficient `b`: the
//! certificate holds for the exact trajectories. glam's `dot` is the
//! left-to-right `x*x' + y*y' + z*z'` and the interpolation is written out as
//! above, without fused multiply-adds (which would only remove roundings).
//!
//! The running bound is what makes the erleben benchmark scenes (axis-aligned
//! geometry with coordinates like `1e-17` next to `1.0`) certifiable: a static
//! or axis-aligned coordinate contributes no error at all, where a global
//! `u * max|x|` margin would swamp gaps of `1e-16`.

use weft_core::{DVec3, StencilKind};

use super::bounds::{Aabb, TrajectoryBounds};
use super::{interpolate, Trajectory, U};

/// Safety factor `C` applied to the running error bound (see module docs).
pub const MARGIN_C: f64 = 4.0;

/// Normals with a 1-norm above this are not used (keeps products finite).
const NORMAL_LIMIT: f64 = 18_446_744_073_709_551_616.0; // 2^64

/// Absolute slack for underflow (each underflowing operation errs by at most
/// `2^-1075`; a certificate performs well under 2^70 of them).
const UNDERFLOW_SLACK: f64 = 9.332_636_185_032_189e-302; // 2^-1000

/// Pairs `(i, j)`, `i` on the first primitive, `j` on the second.
const VF_PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (0, 3)];
const EE_PAIRS: [(usize, usize); 4] = [(0, 2), (0, 3), (1, 2), (1, 3)];

/// Pairs of vertices across the two primitives of `kind`.
pub fn pairs(kind: StencilKind) -> &'static [(usize, usize)] {
    match kind {
        StencilKind::VertexFace => &VF_PAIRS,
        StencilKind::EdgeEdge => &EE_PAIRS,
    }
}

/// Segments (summed over the four vertices) up to which an interval is
/// walked segment by segment instead of bounded by blocks first.
const LEAF_SEGMENTS: usize = 8;

/// `true` when the rotating plane from `na` (at `ta`) to `nb` (at `tb`)
/// certifies `d > eta` at every instant of `[ta, tb]` for the exact
/// trajectories. Preconditions (checked by [`super::proximity`]): finite
/// coordinates and `eta` of magnitude `<= 2^500`, strictly increasing times,
/// `ta <= tb` within the trajectories' span. `false` means "not certified",
/// never "close". `walked` is set when some segment had to be walked (the
/// block bounds alone did not certify the interval).
///
/// With [block bounds](super::bounds) on all four trajectories a long
/// interval is first tested against the boxes of the breakpoints covering
/// it ([`boxes_apart`]); where that fails, it is cut at a middle breakpoint
/// (the normal there interpolated: any value is valid, each piece is
/// certified on its own, see the module docs) down to intervals of at most
/// [`LEAF_SEGMENTS`] segments, which are walked.
#[allow(clippy::too_many_arguments)]
pub(crate) fn certify(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    ta: f64,
    tb: f64,
    na: DVec3,
    nb: DVec3,
    eta: f64,
    walked: &mut bool,
) -> bool {
    if ta.is_nan() || tb.is_nan() || ta > tb {
        return false;
    }
    let [Some(b0), Some(b1), Some(b2), Some(b3)] = traj.map(|tr| tr.bounds) else {
        *walked = true;
        return certify_segments(kind, traj, ta, tb, na, nb, eta);
    };
    let blocks = Blocks {
        kind,
        traj,
        bounds: [b0, b1, b2, b3],
        eta,
    };
    let ranges: [(usize, usize); 4] = std::array::from_fn(|i| {
        let tr = &traj[i];
        covering(tr.times, (0, tr.times.len() - 1), ta, tb)
    });
    blocks.certify(ranges, ta, tb, na, nb, walked)
}

/// The block-bounded recursion of [`certify`].
struct Blocks<'a, 'b> {
    kind: StencilKind,
    traj: &'a [Trajectory<'b>; 4],
    bounds: [&'a TrajectoryBounds; 4],
    eta: f64,
}

impl Blocks<'_, '_> {
    /// [`certify`] on `[ta, tb]`, whose covering breakpoints are `ranges`.
    fn certify(
        &self,
        ranges: [(usize, usize); 4],
        ta: f64,
        tb: f64,
        na: DVec3,
        nb: DVec3,
        walked: &mut bool,
    ) -> bool {
        let segments: usize = ranges.iter().map(|&(k0, k1)| k1 - k0).sum();
        if segments <= LEAF_SEGMENTS {
            *walked = true;
            return certify_segments(self.kind, self.traj, ta, tb, na, nb, self.eta);
        }
        let traj = self.traj;
        let boxes: [Aabb; 4] =
            std::array::from_fn(|i| self.bounds[i].cover(traj[i].points, ranges[i].0, ranges[i].1));
        if boxes_apart(self.kind, &boxes, na, nb, self.eta) {
            return true;
        }
        // Cut at the middle breakpoint of the vertex with the most segments:
        // strictly inside (ta, tb), since that vertex has at least two.
        let (v, &(k0, k1)) = (ranges.iter().enumerate())
            .max_by_key(|(_, &(k0, k1))| k1 - k0)
            .expect("four vertices");
        let m = (k0 + k1) / 2;
        let s = traj[v].times[m];
        let ns = na + (nb - na) * ((s - ta) / (tb - ta));
        let mut left = ranges;
        let mut right = ranges;
        for i in 0..4 {
            if i == v {
                left[i].1 = m;
                right[i].0 = m;
            } else {
                left[i] = covering(traj[i].times, ranges[i], ta, s);
                right[i] = covering(traj[i].times, ranges[i], s, tb);
            }
        }
        self.certify(left, ta, s, na, ns, walked) && self.certify(right, s, tb, ns, nb, walked)
    }
}

/// Breakpoint indices `k0 ..= k1` covering `[ta, tb]` on a polyline with
/// breakpoint `times`: from the last at or before `ta` to the first at or
/// after `tb`, searched within `within`, a range that covers `[ta, tb]`.
#[inline]
fn covering(times: &[f64], within: (usize, usize), ta: f64, tb: f64) -> (usize, usize) {
    let (w0, w1) = within;
    let span = &times[w0..=w1];
    let k0 = w0 + span.partition_point(|&s| s <= ta).saturating_sub(1);
    let k1 = w0 + span.partition_point(|&s| s < tb).min(span.len() - 1);
    (k0, k1.max(k0))
}

/// Box certificate: every vertex `i` stays in the box `boxes[i]` over an
/// interval on which the normal rotates linearly from `na` to `nb`.
///
/// For `n(t) = (1 - s) na + s nb` and any `d = x_i - x_j` with `x_i` in box
/// `i` (first primitive) and `x_j` in box `j` (second),
/// `n(t) . d >= min(na . d, nb . d)` and `|n(t)| <= max(|na|, |nb|)`; and
/// `min over the boxes of n . (x_i - x_j) = n . c_i - n . c_j` with `c_i`
/// the lowest corner of box `i` along `n` and `c_j` the highest of box `j`.
/// So if for both `n` in `{na, nb}` the smallest `n . c_i` exceeds the
/// largest `n . c_j` by more than `eta max(|na|, |nb|)`, then (*) of the
/// module docs holds at every instant: `d > eta`.
///
/// Rounding: the corners are stored coordinates, exact; `fl(n . c)` errs by
/// at most `gamma_3 (|n| . |c|)` (Higham, Thm 3.1), so the exact extremes
/// are within `e = gamma_3 max(|n| . |c|)` over the corners used of the
/// computed ones, and the computed gap (one subtraction) within
/// `2 e + u |gap|` of the exact gap. `max(|na|, |nb|)` is bounded above as in
/// step 5. Certify iff
/// `gap > eta nmax (1 + 4u) + MARGIN_C (2 e + u |gap|) + 2^-1000` for both
/// normals; `MARGIN_C = 4` covers the rounding of the bound itself (a handful of operations, relative `gamma_6`). Overflow
/// turns a value infinite or NaN, which fails the strict comparison.
pub(crate) fn boxes_apart(
    kind: StencilKind,
    boxes: &[Aabb; 4],
    na: DVec3,
    nb: DVec3,
    eta: f64,
) -> bool {
    let split = match kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    };
    let l1 = na.abs().element_sum().max(nb.abs().element_sum());
    if l1.is_nan() || l1 > NORMAL_LIMIT || l1 == 0.0 {
        return false;
    }
    let nmax = na.dot(na).max(nb.dot(nb)).sqrt() * (1.0 + 4.0 * U);
    let thr = eta * nmax * (1.0 + 4.0 * U) + UNDERFLOW_SLACK;
    let g3 = 3.0 * U * (1.0 + 4.0 * U);
    let apart = |n: DVec3| {
        let an = n.abs();
        let mut e = 0.0f64;
        let mut lo_first = f64::INFINITY;
        for b in &boxes[..split] {
            let c = b.lowest_corner(n);
            lo_first = lo_first.min(n.dot(c));
            e = e.max(an.dot(c.abs()));
        }
        let mut hi_second = f64::NEG_INFINITY;
        for b in &boxes[split..] {
            let c = b.highest_corner(n);
            hi_second = hi_second.max(n.dot(c));
            e = e.max(an.dot(c.abs()));
        }
        let gap = lo_first - hi_second;
        gap > thr + MARGIN_C * (2.0 * g3 * e + U * gap.abs())
    };
    apart(na) && (nb == na || apart(nb))
}

/// The segment-by-segment walk of [`certify`].
fn certify_segments(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    ta: f64,
    tb: f64,
    na: DVec3,
    nb: DVec3,
    eta: f64,
) -> bool {
    let pairs = pairs(kind);
    // Per vertex: index of the segment containing the current sub-segment.
    let mut seg: [usize; 4] = std::array::from_fn(|i| segment_index(&traj[i], ta));
    let diffs = |seg: &[usize; 4], t: f64| -> [(DVec3, DVec3); 4] {
        std::array::from_fn(|k| {
            let (i, j) = pairs.get(k).copied().unwrap_or(pairs[0]);
            pair_difference(&traj[i], seg[i], &traj[j], seg[j], t)
        })
    };
    let mut s0 = ta;
    let mut d0 = diffs(&seg, ta);
    let mut n0 = na;
    let span = tb - ta;
    loop {
        // Next breakpoint strictly after s0 (of any vertex), capped at tb.
        let mut s1 = tb;
        for i in 0..4 {
            let times = traj[i].times;
            if let Some(&t) = times.get(seg[i] + 1) {
                if t > s0 && t < s1 {
                    s1 = t;
                }
            }
        }
        let d1 = diffs(&seg, s1);
        let n1 = if s1 == tb {
            nb
        } else {
            // Any floating value is valid here (see module docs).
            na + (nb - na) * ((s1 - ta) / span)
        };
        if !sub_segment(&d0[..pairs.len()], &d1[..pairs.len()], n0, n1, eta) {
            return false;
        }
        if s1 >= tb {
            return true;
        }
        // Advance the vertices whose segment ends at s1 (their positions at
        // s1 are the stored breakpoints either way).
        for i in 0..4 {
            let times = traj[i].times;
            if times.get(seg[i] + 1) == Some(&s1) && seg[i] + 2 < times.len() {
                seg[i] += 1;
            }
        }
        s0 = s1;
        d0 = diffs(&seg, s1);
        n0 = n1;
    }
}

/// Index `k` of the segment `[times[k], times[k+1]]` that holds `t` and
/// continues after it (`times[k] <= t < times[k+1]`, or the last segment).
pub(crate) fn segment_index(tr: &Trajectory<'_>, t: f64) -> usize {
    let k = tr.times.partition_point(|&s| s <= t);
    k.saturating_sub(1).min(tr.times.len().saturating_sub(2))
}

/// Position of `tr` at `t` on segment `k` (as [`interpolate`]) and a bound on
/// its rounding error per coordinate (module docs, step 1): zero at the
/// vertex's own breakpoints and for coordinates that do not move on the
/// segment, else `8 u (|P_c| + |Q_c|)`.
#[inline]
fn position_with_error(tr: &Trajectory<'_>, k: usize, t: f64) -> (DVec3, DVec3) {
    let x = interpolate(tr, k, t);
    let times = tr.times;
    if k + 1 >= times.len() || t == times[k] || t == times[k + 1] {
        return (x, DVec3::ZERO);
    }
    let (p, q) = (tr.points[k], tr.points[k + 1]);
    let e = DVec3::select(p.cmpeq(q), DVec3::ZERO, (p.abs() + q.abs()) * (8.0 * U));
    (x, e)
}

/// `x_i(t) - x_j(t)` for vertex `i` on its segment `ki` and `j` on `kj`, with
/// a per-coordinate bound on the rounding error (module docs, steps 1–2).
///
/// When both segments span the same two times (always so for linear motion)
/// the difference is interpolated from the breakpoint differences
/// `A = P_i - P_j`, `B = Q_i - Q_j`: `d = A + alpha (B - A)`, with error at
/// most `8 u (|A~| + |B~|)` (step 1 applied to `A~`, `B~`, plus their own
/// roundings `u max(|A~|, |B~|)`), `u |A~|` where `A~_c == B~_c`, and `u |d~|`
/// at the segment's ends. The error then scales with the *separation* rather
/// than with the coordinates, which certifies gaps far below `u |x|`.
/// Otherwise the two positions are interpolated separately.
#[inline]
pub(crate) fn pair_difference(
    ti: &Trajectory<'_>,
    ki: usize,
    tj: &Trajectory<'_>,
    kj: usize,
    t: f64,
) -> (DVec3, DVec3) {
    if ki + 1 < ti.times.len() && kj + 1 < tj.times.len() {
        let (t0, t1) = (ti.times[ki], ti.times[ki + 1]);
        if t0 == tj.times[kj] && t1 == tj.times[kj + 1] {
            let a = ti.points[ki] - tj.points[kj];
            let b = ti.points[ki + 1] - tj.points[kj + 1];
            if t == t0 {
                return (a, a.abs() * U);
            }
            if t == t1 {
                return (b, b.abs() * U);
            }
            let alpha = (t - t0) / (t1 - t0);
            let d = a + (b - a) * alpha;
            let e = DVec3::select(a.cmpeq(b), a.abs() * U, (a.abs() + b.abs()) * (8.0 * U));
            return (d, e);
        }
    }
    let (xi, ei) = position_with_error(ti, ki, t);
    let (xj, ej) = position_with_error(tj, kj, t);
    let d = xi - xj;
    (d, ei + ej + d.abs() * U)
}

/// Bernstein test of one sub-segment (see module docs): per pair, the
/// difference and its error bound at the sub-segment's two ends.
#[inline]
fn sub_segment(
    d0: &[(DVec3, DVec3)],
    d1: &[(DVec3, DVec3)],
    n0: DVec3,
    n1: DVec3,
    eta: f64,
) -> bool {
    let l1 = n0.abs().element_sum().max(n1.abs().element_sum());
    if l1.is_nan() || l1 > NORMAL_LIMIT || l1 == 0.0 {
        return false;
    }
    let nmax = n0.dot(n0).max(n1.dot(n1)).sqrt() * (1.0 + 4.0 * U);
    let thr = eta * nmax * (1.0 + 4.0 * U) + UNDERFLOW_SLACK;
    let (a0, a1) = (n0.abs(), n1.abs());
    let g3 = 3.0 * U * (1.0 + 4.0 * U);
    for (&(d0, e0), &(d1, e1)) in d0.iter().zip(d1) {
        let (ad0, ad1) = (d0.abs(), d1.abs());
        // Step 3: |fl(n.d~) - n.d| <= |n|.e + gamma_3 |n|.|d~|.
        let eb0 = a0.dot(e0) + g3 * a0.dot(ad0);
        let eb2 = a1.dot(e1) + g3 * a1.dot(ad1);
        let p01 = n0.dot(d1);
        let p10 = n1.dot(d0);
        let b0 = n0.dot(d0);
        let b2 = n1.dot(d1);
        let b1 = 0.5 * (p01 + p10);
        // Step 4: the middle coefficient adds one rounding of the sum.
        let eb1 = 0.5
            * (a0.dot(e1)
                + g3 * a0.dot(ad1)
                + a1.dot(e0)
                + g3 * a1.dot(ad0)
                + U * (p01 + p10).abs());
        // Step 5: the bounds are computed within a relative gamma_12; the
        // factor MARGIN_C covers it with room to spare.
        if !(b0 > thr + MARGIN_C * eb0 && b1 > thr + MARGIN_C * eb1 && b2 > thr + MARGIN_C * eb2) {
            return false;
        }
    }
    true
}

/// Fixed-plane hull certificate over `[ta, tb]`.
///
/// Each primitive at time `t` is the convex hull of its vertices at `t`, and
/// over `[ta, tb]` each vertex stays in the convex hull of its breakpoints from
/// the last one at or before `ta` to the first one at or after `tb` (exact
/// stored points: no interpolation error). So if, along a fixed direction `n`
/// (any vector, taken as exact), every such breakpoint of the first
/// primitive's vertices projects above every one of the second primitive's
/// vertices by more than `eta |n|`, then `d > eta` at every instant of
/// `[ta, tb]`.
///
/// Rounding: with `M` the largest absolute breakpoint coordinate, a computed
/// projection `fl(n·p)` differs from `n·p` by at most `γ_3 Σ|n_k||p_k| ≤
/// γ_3 |n|_1 M` (`γ_3 = 3u/(1-3u)`); the computed gap (one more subtraction)
/// is then within `2 γ_3 |n|_1 M + u |gap|` of the exact gap of the computed
/// extremes, and `|n|_2` computed is within `(1 + 2u)` of exact. We demand
/// `gap > eta |n|_2 (1 + 4u) + MARGIN_C (2 γ_3 |n|_1 M + u |gap|) + 2^-1000`.
///
/// With [block bounds](super::bounds) the boxes of the covering breakpoints
/// are tested instead ([`boxes_apart`] with a fixed normal: a box holds its
/// breakpoints, so it is a looser hull, but it costs `O(log)` instead of a
/// scan; on `crumple`'s queries, also scanning the breakpoints of short
/// ranges where the boxes fail changed neither the answers nor the time).
/// `walked` is set when the breakpoints were scanned.
#[allow(clippy::too_many_arguments)]
pub(crate) fn fixed_plane_hull(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    ta: f64,
    tb: f64,
    n: DVec3,
    eta: f64,
    max_coord: f64,
    walked: &mut bool,
) -> bool {
    let split = match kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    };
    // Breakpoints covering [ta, tb]: from the last at or before ta to the
    // first at or after tb.
    let ranges: [(usize, usize); 4] = std::array::from_fn(|i| {
        let tr = &traj[i];
        covering(tr.times, (0, tr.times.len() - 1), ta, tb)
    });
    if let [Some(b0), Some(b1), Some(b2), Some(b3)] = traj.map(|tr| tr.bounds) {
        let bounds = [b0, b1, b2, b3];
        let boxes: [Aabb; 4] =
            std::array::from_fn(|i| bounds[i].cover(traj[i].points, ranges[i].0, ranges[i].1));
        return boxes_apart(kind, &boxes, n, n, eta);
    }
    *walked = true;
    let covering = |i: usize| ranges[i].0..ranges[i].1 + 1;
    let mut lo_first = f64::INFINITY;
    for (i, tr) in traj[..split].iter().enumerate() {
        for p in &tr.points[covering(i)] {
            lo_first = lo_first.min(n.dot(*p));
        }
    }
    let mut hi_second = f64::NEG_INFINITY;
    for (i, tr) in traj.iter().enumerate().skip(split) {
        for p in &tr.points[covering(i)] {
            hi_second = hi_second.max(n.dot(*p));
        }
    }
    let gap = lo_first - hi_second;
    let gamma3 = 3.0 * U / (1.0 - 3.0 * U);
    let n1 = n.x.abs() + n.y.abs() + n.z.abs();
    let err = 2.0 * gamma3 * n1 * max_coord + U * gap.abs();
    let need = eta * n.length() * (1.0 + 4.0 * U) + MARGIN_C * err + UNDERFLOW_SLACK;
    gap.is_finite() && gap > need
}
