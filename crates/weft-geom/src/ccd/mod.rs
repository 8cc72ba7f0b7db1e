//! # Continuous proximity predicate (the narrow phase, spec §4.3)
//!
//! Question: over a time span `[T0, T1]`, along given piecewise-linear vertex
//! trajectories, do the two primitives of a stencil (VF: vertex `x0` against
//! triangle `(x1, x2, x3)`; EE: edge `(x0, x1)` against edge `(x2, x3)`) ever
//! come within distance `eta` (`d <= eta`, touching counts)?
//!
//! * `true`  — they **may**: a "yes" needs no rigour; it may be a false positive.
//! * `false` — **certified**: `d > eta` at every instant of `[T0, T1]` for the
//!   exact trajectories (exact breakpoint coordinates, exact linear motion in
//!   between), whatever the floating-point rounding. No collision is ever missed.
//!
//! ## Algorithm: recursive space–time separating planes
//!
//! Time is cut recursively (bisection at floating midpoints, which cover the
//! span exactly because sibling intervals share their end point). At each
//! probe time (the span's ends, then every midpoint) three candidate
//! separating directions are computed (`Normals`):
//!
//! 1. **closest** — the closest-point direction. The barycentric weights come
//!    from [`crate::distance::stencil_closest`]; the vector itself is
//!    re-evaluated from the pair differences `x_i - x_j` interpolated from
//!    breakpoint *differences* (see [`certificate`]), which resolves gaps far
//!    below the rounding of the positions;
//! 2. **structural** — VF: the face normal; EE: the cross product of the edges
//!    (both from the same differences), oriented towards the first primitive;
//! 3. **denoised** — the closest direction with every component that is below
//!    its own rounding-error bound set to zero (sliding past with a sub-ulp
//!    offset: the separating direction lies in the other coordinates);
//! 4. **plain** — the closest direction of `stencil_closest` itself.
//!
//! Where the plain distance exceeds `FAR_FACTOR` times the yes threshold, only
//! the cheap candidates (plain, and structural from the rounded positions)
//! are computed. The candidates are tried in the order closest, structural,
//! plain, denoised; duplicates are skipped.
//!
//! An interval `[ta, tb]` is certified if one candidate, as a **linearly
//! rotating plane** `n(t)` from its value at `ta` to its value at `tb`,
//! separates the primitives by more than `eta` on the whole interval (see
//! [`certificate`]: Bernstein bounds, with a rigorous rounding bound). If none
//! does, the interval is split at its midpoint, unless the distance there is
//! within the yes threshold and no candidate certifies that single instant:
//! then the answer is "yes".
//!
//! Why a rotating plane: with a fixed normal the certificate is first-order
//! accurate — near a near-miss of gap `g` between rotating primitives it needs
//! intervals of width `~g` over a region of width `~sqrt(g)`, i.e. `~g^-1/2`
//! intervals. The interpolated normal is second-order accurate (its error is
//! `O(w^2)` on an interval of width `w`), so near a minimum of the distance
//! only `O(1)` intervals per bisection level stay uncertified. A fixed normal
//! is the special case `na == nb`.
//!
//! **Long trajectories.** A vertex in deep contact has hundreds to
//! thousands of breakpoints per window, and a certificate walks every
//! sub-segment of its interval. With [`bounds::TrajectoryBounds`] on all
//! four trajectories ([`Trajectory::bounds`]), both certificates first test
//! the exact boxes of the breakpoints covering the interval (a rotating
//! plane against boxes: [`certificate`]'s `boxes_apart`); where that fails
//! the rotating-plane certificate cuts the interval at a middle breakpoint,
//! down to pieces of a few segments that it walks. The answers stay
//! rigorous (a box holds its segments exactly; the rounding bound is next to
//! `boxes_apart`), the breakpoints are all kept, and validation reads the
//! bounds' block-by-block checks instead of every point. On `crumple`'s
//! queries (about 800 breakpoints per vertex) this cut the narrow phase from
//! about 240 to 13 µs per query, with the same answers.
//!
//! **Root probe.** When an uncertified interval has a sign change of the
//! orientation determinant (VF: `(b-a)x(c-a).(p-a)`; EE:
//! `(p1-p0)x(q1-q0).(p0-q0)`) between its ends, the coplanarity root inside is
//! located by Illinois regula falsi and the distance checked there (once per
//! chain of nested intervals). It only ever answers "yes" (it needs no
//! rigour); it makes crossings, the usual positives of the `eta = 0`
//! benchmarks, cost a dozen determinant evaluations instead of ~50 bisection
//! levels.
//!
//! ## Budget
//!
//! At most [`MAX_INTERVALS`] intervals and [`MAX_DEPTH`] bisection levels per
//! query; on exhaustion the answer is "yes" (conservative) and
//! [`CcdStats::budget_exhausted`] is incremented. An interval whose floating
//! midpoint is not strictly inside it (adjacent floats) also answers "yes".
//!
//! ## Floating point
//!
//! Every "no" comes from the certificate in [`certificate`], whose
//! rounding-error bound is derived next to it. It is a *running* bound: each
//! Bernstein coefficient `b~` is computed together with a bound `E` on
//! `|b~ - b|` built from the magnitudes actually involved (position errors
//! `8 u (|P_c| + |Q_c|)` per interpolated coordinate, zero at breakpoints and
//! for coordinates that do not move; `u |d|` per difference; `gamma_3 |n|.|d|`
//! per dot product), and a coefficient counts only if
//! `b~ > eta |n|_up + 4 E + 2^-1000`: four times the derived bound, plus an
//! absolute slack for underflow. Inputs outside the range where that analysis
//! holds answer "yes": non-finite coordinates, times or `eta`, times not
//! strictly increasing, spans that do not agree, coordinates or `eta` above
//! `2^500` in magnitude (no overflow can then occur). A negative `eta` is
//! treated as 0 (`d <= 0` is a superset of `d <= eta < 0`).
//!
//! The "yes" side needs no rigour: at a probe time, a computed distance
//! `<= eta + 256 u M` (`M` = largest absolute breakpoint coordinate) is
//! reported unless one of the candidate normals certifies that instant. The
//! remaining false positives of the benchmarks are near misses whose gap is
//! below what this floating-point certificate resolves (the erleben scenes of
//! the Wang benchmark, built to be degenerate), and queries that exhaust the
//! budget.

pub mod benchmark;
pub mod bounds;
pub mod certificate;
pub mod oracle;

use serde::Serialize;
use weft_core::{DVec3, StencilKind};

use crate::distance::stencil_closest;

/// Unit roundoff of `f64`, `2^-53`.
pub const U: f64 = f64::EPSILON * 0.5;

/// Largest number of intervals examined per query before answering "yes".
pub const MAX_INTERVALS: u64 = 2048;

/// Deepest bisection level before answering "yes".
pub const MAX_DEPTH: usize = 80;

/// Coordinates (and `eta`) above this answer "yes": it keeps every
/// intermediate of the certificate far from overflow. `2^500`; mesh
/// validation refuses coordinates beyond it.
pub const COORD_LIMIT: f64 = weft_core::MAX_COORDINATE;

/// A probe time whose computed distance is at most `eta + YES_C * u * M` is
/// answered "yes" unless a candidate normal certifies that instant. Not a
/// rigour question (a "yes" may be wrong): it only decides when to stop
/// bisecting around an apparent contact.
const YES_C: f64 = 256.0;

/// A probe time whose plain computed distance exceeds `FAR_FACTOR` times the
/// yes threshold uses the plain closest direction and skips the refined
/// (difference-based) evaluation of the candidate normals. Speed only.
const FAR_FACTOR: f64 = 1048576.0;

/// Piecewise-linear trajectory of one vertex: at `times[k]` the vertex is at
/// `points[k]`, linear in between. `times` must be strictly increasing and
/// `times.len() == points.len() >= 1`; the four trajectories of a stencil must
/// share their first and last time. A single point is a static vertex at one
/// instant (then all four must have the same single time).
#[derive(Clone, Copy, Debug)]
pub struct Trajectory<'a> {
    /// breakpoint times, strictly increasing.
    pub times: &'a [f64],
    /// positions at `times`.
    pub points: &'a [DVec3],
    /// block bounds over `points` ([`bounds`]), when kept: the
    /// certificates then bound long stretches at once. They must be the
    /// bounds of exactly these `times` and `points` (built from them, or
    /// updated as they were recorded): a certificate trusts their boxes.
    /// Bounds of another length are ignored.
    pub bounds: Option<&'a bounds::TrajectoryBounds>,
}

impl<'a> Trajectory<'a> {
    /// A polyline without block bounds.
    pub fn new(times: &'a [f64], points: &'a [DVec3]) -> Self {
        Self {
            times,
            points,
            bounds: None,
        }
    }
}

/// Counters of the narrow phase (summed over queries).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct CcdStats {
    /// queries answered.
    pub queries: u64,
    /// queries answered "yes" (maybe close).
    pub reported: u64,
    /// time intervals examined by the certificate.
    pub intervals: u64,
    /// closest-point evaluations.
    pub closest_evals: u64,
    /// queries answered "yes" because the interval or depth budget ran out.
    pub budget_exhausted: u64,
    /// queries answered "yes" because the input was outside the certified
    /// range (non-finite values, bad times, huge coordinates).
    pub invalid_input: u64,
    /// queries answered "yes" by the orientation root probe.
    pub root_probe_hits: u64,
    /// intervals certified by the structural normal (face normal / edge
    /// cross product) after the closest-point normal failed.
    pub structural_certified: u64,
    /// intervals certified by the denoised closest direction after the
    /// other two failed.
    pub denoised_certified: u64,
    /// queries and intervals certified by the fixed-plane hull test.
    pub hull_certified: u64,
    /// intervals certified (the whole-span fast path counted as one).
    #[serde(default)]
    pub certified_intervals: u64,
    /// of those, the ones certified by block bounds alone, no segment walked
    /// (see [`bounds`]).
    #[serde(default)]
    pub block_certified: u64,
}

impl CcdStats {
    /// Adds `other`'s counters to `self`.
    pub fn merge(&mut self, other: &CcdStats) {
        self.queries += other.queries;
        self.reported += other.reported;
        self.intervals += other.intervals;
        self.closest_evals += other.closest_evals;
        self.budget_exhausted += other.budget_exhausted;
        self.invalid_input += other.invalid_input;
        self.root_probe_hits += other.root_probe_hits;
        self.structural_certified += other.structural_certified;
        self.denoised_certified += other.denoised_certified;
        self.hull_certified += other.hull_certified;
        self.certified_intervals += other.certified_intervals;
        self.block_certified += other.block_certified;
    }
}

/// Conservative continuous proximity predicate.
///
/// `true`: the primitives of the stencil **may** come within `eta` (`d <= eta`)
/// at some time of the common span of `traj`; `false`: certified `d > eta` at
/// every instant, for the exact trajectories, including under floating-point
/// rounding. Never panics; invalid input (NaN, non-increasing times, spans
/// that disagree) answers `true`. See the module documentation.
pub fn proximity(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    eta: f64,
    stats: &mut CcdStats,
) -> bool {
    stats.queries += 1;
    let yes = match Query::new(kind, traj, eta) {
        Some(q) => q.run(stats),
        None => {
            stats.invalid_input += 1;
            true
        }
    };
    if yes {
        stats.reported += 1;
    }
    yes
}

/// [`proximity`] for linear motion from `start` (t = 0) to `end` (t = 1).
pub fn linear_proximity(
    kind: StencilKind,
    start: &[DVec3; 4],
    end: &[DVec3; 4],
    eta: f64,
    stats: &mut CcdStats,
) -> bool {
    const TIMES: [f64; 2] = [0.0, 1.0];
    let pts: [[DVec3; 2]; 4] = std::array::from_fn(|i| [start[i], end[i]]);
    let traj: [Trajectory<'_>; 4] = std::array::from_fn(|i| Trajectory::new(&TIMES, &pts[i]));
    proximity(kind, &traj, eta, stats)
}

/// Position of trajectory `tr` at time `t` (clamped to its span). Exact at a
/// breakpoint; elsewhere `P_k + alpha (P_k+1 - P_k)` with
/// `alpha = (t - t_k) / (t_k+1 - t_k)`, within `12 u M` of the exact position
/// per coordinate (derivation in [`certificate`]).
#[inline]
pub(crate) fn position(tr: &Trajectory<'_>, t: f64) -> DVec3 {
    let n = tr.times.len();
    let k = tr.times.partition_point(|&s| s <= t);
    if k == 0 {
        return tr.points[0];
    }
    if k >= n {
        return tr.points[n - 1];
    }
    interpolate(tr, k - 1, t)
}

/// Position on segment `k` (`times[k] <= t <= times[k+1]`) of `tr`.
#[inline]
pub(crate) fn interpolate(tr: &Trajectory<'_>, k: usize, t: f64) -> DVec3 {
    let ta = tr.times[k];
    if t == ta || k + 1 >= tr.times.len() {
        return tr.points[k];
    }
    let tb = tr.times[k + 1];
    if t == tb {
        return tr.points[k + 1];
    }
    let alpha = (t - ta) / (tb - ta);
    let a = tr.points[k];
    a + (tr.points[k + 1] - a) * alpha
}

/// A validated query.
struct Query<'a> {
    kind: StencilKind,
    /// the trajectories, with block bounds only where they match their
    /// polyline's length.
    traj: [Trajectory<'a>; 4],
    eta: f64,
    t0: f64,
    t1: f64,
    /// a computed distance at most this answers "yes".
    yes_threshold: f64,
    /// largest absolute breakpoint coordinate.
    max_coord: f64,
}

/// One pending interval of the recursion.
#[derive(Clone, Copy)]
struct Node {
    ta: f64,
    tb: f64,
    na: Normals,
    nb: Normals,
    depth: usize,
    /// a root probe already ran on an interval containing this one.
    probed: bool,
}

/// The two candidate separating directions at one time.
#[derive(Clone, Copy)]
struct Normals {
    /// closest-point direction (unit, from the second primitive to the first).
    closest: DVec3,
    /// VF: the face normal `(b-a)x(c-a)`; EE: `(p1-p0)x(q1-q0)`; oriented
    /// towards the first primitive. Exact in direction up to relative
    /// rounding of each component, so it stays meaningful for near-contacts
    /// below the resolution of the closest-point direction.
    structural: DVec3,
    /// `closest` with the components that are below their rounding-error
    /// bound zeroed: for near misses below the resolution of one coordinate
    /// (a vertex sliding past another along y with a `1e-17` offset in x
    /// and z), the separating direction lies in the other coordinates.
    denoised: DVec3,
    /// the closest direction of [`stencil_closest`] on the rounded positions
    /// (the refined `closest` is usually better; not always).
    plain: DVec3,
    /// the orientation determinant (only its sign is used: a sign change
    /// between the ends of an interval means a coplanarity root inside).
    orient: f64,
}

impl<'a> Query<'a> {
    /// Validates the input; `None` means "answer yes" (outside the certified range).
    fn new(kind: StencilKind, traj: &[Trajectory<'a>; 4], eta: f64) -> Option<Self> {
        if !eta.is_finite() || eta > COORD_LIMIT {
            return None;
        }
        let eta = eta.max(0.0);
        let first = traj[0].times.first().copied()?;
        let last = traj[0].times.last().copied()?;
        let mut m = 0.0f64;
        let mut traj = *traj;
        for tr in &mut traj {
            tr.bounds = tr.bounds.filter(|b| b.matches(tr.points.len()));
            if tr.times.len() != tr.points.len()
                || tr.times.first() != Some(&first)
                || tr.times.last() != Some(&last)
            {
                return None;
            }
            if let Some(b) = tr.bounds {
                // Checked as the breakpoints were recorded.
                let (valid, max_abs) = b.summary(tr.times, tr.points);
                if !valid {
                    return None;
                }
                m = m.max(max_abs);
                continue;
            }
            if !tr.times.iter().all(|t| t.is_finite()) || tr.times.windows(2).any(|w| w[0] >= w[1])
            {
                return None;
            }
            for p in tr.points {
                // (`max_element` ignores NaN, hence the explicit finiteness test.)
                let a = p.abs().max_element();
                if !p.is_finite() || a > COORD_LIMIT {
                    return None;
                }
                m = m.max(a);
            }
        }
        Some(Self {
            kind,
            traj,
            eta,
            t0: first,
            t1: last,
            yes_threshold: eta + YES_C * U * m,
            max_coord: m,
        })
    }

    fn positions(&self, t: f64) -> [DVec3; 4] {
        std::array::from_fn(|i| position(&self.traj[i], t))
    }

    /// Candidate normals at `t`, or `None` when the primitives are within the
    /// yes threshold there.
    ///
    /// The closest-point weights come from [`stencil_closest`] on the rounded
    /// positions; the closest vector is then re-evaluated from the pair
    /// differences `x_i - x_j` (interpolated from breakpoint differences, see
    /// [`certificate`]), which keeps its direction and length meaningful for
    /// gaps far below the rounding of the positions themselves. Its length is
    /// the distance between two points of the primitives (up to rounding), so
    /// a "yes" from it is a genuine near-contact; none of this needs rigour.
    fn normal_at(&self, t: f64, refine: bool, stats: &mut CcdStats) -> Option<Normals> {
        stats.closest_evals += 1;
        let x = self.positions(t);
        let c = stencil_closest(self.kind, &x);
        if c.d.is_nan() {
            return None;
        }
        if c.d > FAR_FACTOR * self.yes_threshold {
            // Clearly apart: the plain closest direction (and the structural
            // normal from the rounded positions) are good candidates, and no
            // "yes" is possible here; skip the refined evaluation.
            let (n, side) = match self.kind {
                StencilKind::VertexFace => ((x[2] - x[1]).cross(x[3] - x[1]), x[0] - x[1]),
                StencilKind::EdgeEdge => ((x[1] - x[0]).cross(x[3] - x[2]), x[0] - x[2]),
            };
            let orient = n.dot(side);
            return Some(Normals {
                closest: c.n,
                structural: if orient < 0.0 { -n } else { n },
                denoised: c.n,
                plain: c.n,
                orient,
            });
        }
        let seg: [usize; 4] = std::array::from_fn(|i| certificate::segment_index(&self.traj[i], t));
        let diff = |i: usize, j: usize| {
            certificate::pair_difference(&self.traj[i], seg[i], &self.traj[j], seg[j], t).0
        };
        // P - Q = sum over pairs (i in A, j in B) of coeff_i (-coeff_j) (x_i - x_j),
        // with a rough bound `ev` on its rounding error per coordinate.
        let mut v = DVec3::ZERO;
        let mut ev = DVec3::ZERO;
        for &(i, j) in certificate::pairs(self.kind) {
            let w = c.coeff[i] * -c.coeff[j];
            let (dij, eij) =
                certificate::pair_difference(&self.traj[i], seg[i], &self.traj[j], seg[j], t);
            v += dij * w;
            ev += (eij + dij.abs() * (4.0 * U)) * w.abs();
        }
        let noisy = v.abs().cmple(ev * 4.0);
        let denoised = DVec3::select(noisy, DVec3::ZERO, v);
        let denoised = denoised / denoised.length();
        let d = v.length();
        // A NaN distance also answers "yes".
        if d.is_nan() {
            return None;
        }
        let (n, side) = match self.kind {
            StencilKind::VertexFace => (diff(2, 1).cross(diff(3, 1)), diff(0, 1)),
            StencilKind::EdgeEdge => (diff(1, 0).cross(diff(3, 2)), diff(0, 2)),
        };
        // Any direction is a valid candidate; the orientation only decides
        // whether it can succeed.
        let orient = n.dot(side);
        let structural = if orient < 0.0 { -n } else { n };
        let scale = structural.abs().max_element();
        let structural = if scale > 0.0 && scale.is_finite() {
            structural / scale
        } else {
            structural
        };
        let normals = Normals {
            closest: v / d,
            structural,
            denoised,
            plain: c.n,
            orient,
        };
        if d <= self.yes_threshold {
            if !refine {
                return None;
            }
            // Within the yes threshold: report unless one of the candidate
            // normals certifies this very instant (a sub-ulp near miss, like
            // the sliding cases of the erleben benchmark scenes).
            let instant = |n: DVec3| {
                certificate::certify(self.kind, &self.traj, t, t, n, n, self.eta, &mut false)
            };
            if !(instant(normals.closest)
                || instant(normals.structural)
                || (noisy.any() && instant(normals.denoised))
                || instant(normals.plain))
            {
                return None;
            }
        }
        Some(normals)
    }

    /// The fixed-plane hull certificate over `[ta, tb]` along `n`; notes
    /// in `stats` whether the block bounds alone certified it.
    fn hull(&self, ta: f64, tb: f64, n: DVec3, stats: &mut CcdStats) -> bool {
        let mut walked = false;
        let yes = certificate::fixed_plane_hull(
            self.kind,
            &self.traj,
            ta,
            tb,
            n,
            self.eta,
            self.max_coord,
            &mut walked,
        );
        if yes {
            stats.hull_certified += 1;
            Self::certified(walked, stats);
        }
        yes
    }

    /// The rotating-plane certificate over `[ta, tb]` from `na` to `nb`;
    /// notes in `stats` whether the block bounds alone certified it.
    fn rotating(&self, ta: f64, tb: f64, na: DVec3, nb: DVec3, stats: &mut CcdStats) -> bool {
        let mut walked = false;
        let yes =
            certificate::certify(self.kind, &self.traj, ta, tb, na, nb, self.eta, &mut walked);
        if yes {
            Self::certified(walked, stats);
        }
        yes
    }

    fn certified(walked: bool, stats: &mut CcdStats) {
        stats.certified_intervals += 1;
        if !walked {
            stats.block_certified += 1;
        }
    }

    fn run(&self, stats: &mut CcdStats) -> bool {
        // Fast path: one fixed plane through the whole span, normal = the
        // closest direction at the middle time. Certifies the many stencils
        // whose gap stays well above `eta` (resting contact, neighbours) at
        // the cost of one dot product per breakpoint (per block box with
        // block bounds).
        let mid = 0.5 * (self.t0 + self.t1);
        let c = stencil_closest(self.kind, &self.positions(mid));
        if c.d.is_finite() && c.d > self.eta && self.hull(self.t0, self.t1, c.n, stats) {
            return false;
        }
        let Some(na) = self.normal_at(self.t0, true, stats) else {
            return true;
        };
        let Some(nb) = self.normal_at(self.t1, true, stats) else {
            return true;
        };
        let mut stack = [Node {
            ta: self.t0,
            tb: self.t1,
            na,
            nb,
            depth: 0,
            probed: false,
        }; MAX_DEPTH + 2];
        let mut len = 1usize;
        let mut budget = MAX_INTERVALS;
        while len > 0 {
            len -= 1;
            let node = stack[len];
            if budget == 0 {
                stats.budget_exhausted += 1;
                return true;
            }
            budget -= 1;
            stats.intervals += 1;
            let (na, nb) = (node.na, node.nb);
            let (ta, tb) = (node.ta, node.tb);
            // Cheap first: a fixed plane over the breakpoints covering the
            // interval, normal = the closest direction at either end.
            if self.hull(ta, tb, na.closest, stats) || self.hull(ta, tb, nb.closest, stats) {
                continue;
            }
            if self.rotating(ta, tb, na.closest, nb.closest, stats) {
                continue;
            }
            if self.rotating(ta, tb, na.structural, nb.structural, stats) {
                stats.structural_certified += 1;
                continue;
            }
            if (na.plain != na.closest || nb.plain != nb.closest)
                && self.rotating(ta, tb, na.plain, nb.plain, stats)
            {
                continue;
            }
            if (na.denoised != na.closest || nb.denoised != nb.closest)
                && self.rotating(ta, tb, na.denoised, nb.denoised, stats)
            {
                stats.denoised_certified += 1;
                continue;
            }
            // Uncertified with a coplanarity root inside: look for the contact
            // there (once per chain of nested intervals).
            let mut probed = node.probed;
            if !probed && na.orient * nb.orient < 0.0 {
                if self.root_probe(node.ta, node.tb, stats) {
                    stats.root_probe_hits += 1;
                    return true;
                }
                probed = true;
            }
            let mid = node.ta + 0.5 * (node.tb - node.ta);
            if !(node.ta < mid && mid < node.tb) || node.depth >= MAX_DEPTH {
                stats.budget_exhausted += 1;
                return true;
            }
            let Some(nm) = self.normal_at(mid, true, stats) else {
                return true;
            };
            // Left half on top: the intervals are examined in time order.
            stack[len] = Node {
                ta: mid,
                tb: node.tb,
                na: nm,
                nb: node.nb,
                depth: node.depth + 1,
                probed,
            };
            stack[len + 1] = Node {
                ta: node.ta,
                tb: mid,
                na: node.na,
                nb: nm,
                depth: node.depth + 1,
                probed,
            };
            len += 2;
        }
        false
    }

    /// Orientation determinant at `t` (VF: `(b-a)x(c-a).(p-a)`, EE:
    /// `(p1-p0)x(q1-q0).(p0-q0)`); zero when the four points are coplanar.
    fn orientation(&self, t: f64) -> f64 {
        let x = self.positions(t);
        match self.kind {
            StencilKind::VertexFace => (x[2] - x[1]).cross(x[3] - x[1]).dot(x[0] - x[1]),
            StencilKind::EdgeEdge => (x[1] - x[0]).cross(x[3] - x[2]).dot(x[0] - x[2]),
        }
    }

    /// Looks for a coplanarity root between `t0` and `t1` (where the
    /// orientation changes sign) and answers "yes" when the primitives are
    /// within the yes threshold there. Heuristic: it never answers "no".
    fn root_probe(&self, t0: f64, t1: f64, stats: &mut CcdStats) -> bool {
        let (mut a, mut b) = (t0, t1);
        let (mut fa, mut fb) = (self.orientation(a), self.orientation(b));
        let sign = fa * fb;
        if sign.is_nan() || sign >= 0.0 {
            return false;
        }
        // Illinois-modified regula falsi, falling back to bisection.
        let mut side = 0i8;
        let width = (b - a) * (1.0 / 1_125_899_906_842_624.0); // 2^-50 of the span
        for _ in 0..64 {
            if b - a <= width {
                break;
            }
            let mut c = (a * fb - b * fa) / (fb - fa);
            if !(a < c && c < b) {
                c = a + 0.5 * (b - a);
                if !(a < c && c < b) {
                    break;
                }
            }
            let fc = self.orientation(c);
            if fc == 0.0 {
                a = c;
                b = c;
                break;
            }
            if (fc < 0.0) == (fa < 0.0) {
                a = c;
                fa = fc;
                if side == -1 {
                    fb *= 0.5;
                }
                side = -1;
            } else {
                b = c;
                fb = fc;
                if side == 1 {
                    fa *= 0.5;
                }
                side = 1;
            }
        }
        self.normal_at(a, true, stats).is_none() || self.normal_at(b, true, stats).is_none()
    }
}
