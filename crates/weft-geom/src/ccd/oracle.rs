//! Slow exact oracle for tests — independent of the certificate.
//!
//! Exact rational arithmetic ([`BigRational`]) on dense time samples: at a
//! sample time `t` (rational) every position is computed exactly by linear
//! interpolation of the exact breakpoints, and the squared distance between the
//! primitives exactly (VF: point–triangle with the face-interior candidate
//! taken only when the exact barycentric coordinates are inside, plus the
//! three point–segment distances; EE: the four endpoint–segment distances plus
//! the interior–interior candidate of non-parallel segments). The oracle
//! answers "close" only when some sample has `d^2 <= eta^2` exactly, so it may
//! under-report (a contact between samples is missed) but never over-reports:
//! a predicate that says "no" where the oracle says "yes" has a false negative.
//!
//! Shares nothing with [`super::certificate`] or [`crate::distance`].

use num_bigint::BigInt;
use num_rational::BigRational;
use num_traits::{One, Signed, Zero};
use weft_core::{DVec3, StencilKind};

use super::Trajectory;

/// Exact rational 3-vector.
pub type QVec = [BigRational; 3];

/// The exact value of a finite `f64`; `None` for NaN or infinities.
pub fn rational(x: f64) -> Option<BigRational> {
    BigRational::from_float(x)
}

/// Exact rational vector of a finite `DVec3`.
pub fn qvec(v: DVec3) -> Option<QVec> {
    Some([rational(v.x)?, rational(v.y)?, rational(v.z)?])
}

fn sub(a: &QVec, b: &QVec) -> QVec {
    [&a[0] - &b[0], &a[1] - &b[1], &a[2] - &b[2]]
}

fn dot(a: &QVec, b: &QVec) -> BigRational {
    &a[0] * &b[0] + &a[1] * &b[1] + &a[2] * &b[2]
}

fn axpy(a: &QVec, s: &BigRational, d: &QVec) -> QVec {
    [&a[0] + s * &d[0], &a[1] + s * &d[1], &a[2] + s * &d[2]]
}

fn cross(a: &QVec, b: &QVec) -> QVec {
    [
        &a[1] * &b[2] - &a[2] * &b[1],
        &a[2] * &b[0] - &a[0] * &b[2],
        &a[0] * &b[1] - &a[1] * &b[0],
    ]
}

/// Exact squared distance from `p` to the segment `[a, b]`.
pub fn point_segment_sq(p: &QVec, a: &QVec, b: &QVec) -> BigRational {
    let ab = sub(b, a);
    let ap = sub(p, a);
    let len2 = dot(&ab, &ab);
    if len2.is_zero() {
        return dot(&ap, &ap);
    }
    let mut t = dot(&ap, &ab) / &len2;
    if t.is_negative() {
        t = BigRational::zero();
    } else if t > BigRational::one() {
        t = BigRational::one();
    }
    let c = axpy(a, &t, &ab);
    let pc = sub(p, &c);
    dot(&pc, &pc)
}

/// Exact squared distance from `p` to the triangle `(a, b, c)` (any shape,
/// degenerate included).
pub fn point_triangle_sq(p: &QVec, a: &QVec, b: &QVec, c: &QVec) -> BigRational {
    let mut best = point_segment_sq(p, a, b);
    for d in [point_segment_sq(p, b, c), point_segment_sq(p, c, a)] {
        if d < best {
            best = d;
        }
    }
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let w = sub(p, a);
    let (a11, a12, a22) = (dot(&e1, &e1), dot(&e1, &e2), dot(&e2, &e2));
    let det = &a11 * &a22 - &a12 * &a12;
    if !det.is_zero() {
        let (r1, r2) = (dot(&e1, &w), dot(&e2, &w));
        let u = (&a22 * &r1 - &a12 * &r2) / &det;
        let v = (&a11 * &r2 - &a12 * &r1) / &det;
        if !u.is_negative() && !v.is_negative() && &u + &v <= BigRational::one() {
            let q = axpy(&axpy(a, &u, &e1), &v, &e2);
            let pq = sub(p, &q);
            let d = dot(&pq, &pq);
            if d < best {
                best = d;
            }
        }
    }
    best
}

/// Exact squared distance between the segments `[p0, p1]` and `[q0, q1]`.
pub fn segment_segment_sq(p0: &QVec, p1: &QVec, q0: &QVec, q1: &QVec) -> BigRational {
    let mut best = point_segment_sq(p0, q0, q1);
    for d in [
        point_segment_sq(p1, q0, q1),
        point_segment_sq(q0, p0, p1),
        point_segment_sq(q1, p0, p1),
    ] {
        if d < best {
            best = d;
        }
    }
    let u = sub(p1, p0);
    let v = sub(q1, q0);
    if dot(&cross(&u, &v), &cross(&u, &v)).is_zero() {
        return best;
    }
    // Interior critical point of |p0 + s u - q0 - t v|^2.
    let w = sub(p0, q0);
    let (a, b, c) = (dot(&u, &u), dot(&u, &v), dot(&v, &v));
    let (d, e) = (dot(&u, &w), dot(&v, &w));
    let den = &a * &c - &b * &b;
    let s = (&b * &e - &c * &d) / &den;
    let t = (&a * &e - &b * &d) / &den;
    let zero = BigRational::zero();
    let one = BigRational::one();
    if s >= zero && s <= one && t >= zero && t <= one {
        let pp = axpy(p0, &s, &u);
        let qq = axpy(q0, &t, &v);
        let diff = sub(&pp, &qq);
        let dd = dot(&diff, &diff);
        if dd < best {
            best = dd;
        }
    }
    best
}

/// Exact squared distance between the primitives of a stencil.
pub fn stencil_distance_sq(kind: StencilKind, x: &[QVec; 4]) -> BigRational {
    match kind {
        StencilKind::VertexFace => point_triangle_sq(&x[0], &x[1], &x[2], &x[3]),
        StencilKind::EdgeEdge => segment_segment_sq(&x[0], &x[1], &x[2], &x[3]),
    }
}

/// Exact position of `tr` at the rational time `t` (clamped to its span);
/// `None` for non-finite data.
pub fn position_at(tr: &Trajectory<'_>, t: &BigRational) -> Option<QVec> {
    let times: Vec<BigRational> = tr
        .times
        .iter()
        .map(|&s| rational(s))
        .collect::<Option<_>>()?;
    let n = times.len();
    if n == 0 || tr.points.len() != n {
        return None;
    }
    let k = times.partition_point(|s| s <= t);
    if k == 0 {
        return qvec(tr.points[0]);
    }
    if k >= n {
        return qvec(tr.points[n - 1]);
    }
    let a = qvec(tr.points[k - 1])?;
    let b = qvec(tr.points[k])?;
    let alpha = (t - &times[k - 1]) / (&times[k] - &times[k - 1]);
    Some(axpy(&a, &alpha, &sub(&b, &a)))
}

/// Exact squared distance of the stencil at the rational time `t`.
pub fn distance_sq_at(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    t: &BigRational,
) -> Option<BigRational> {
    let x = [
        position_at(&traj[0], t)?,
        position_at(&traj[1], t)?,
        position_at(&traj[2], t)?,
        position_at(&traj[3], t)?,
    ];
    Some(stencil_distance_sq(kind, &x))
}

/// Sample times: `samples + 1` uniform rational times over the common span
/// `[T0, T1]` of the trajectories, plus every breakpoint of every trajectory.
pub fn sample_times(traj: &[Trajectory<'_>; 4], samples: u32) -> Option<Vec<BigRational>> {
    let t0 = rational(*traj[0].times.first()?)?;
    let t1 = rational(*traj[0].times.last()?)?;
    let mut out = Vec::new();
    let n = samples.max(1);
    let span = &t1 - &t0;
    for k in 0..=n {
        let f = BigRational::new(BigInt::from(k), BigInt::from(n));
        out.push(&t0 + &span * f);
    }
    for tr in traj {
        for &s in tr.times {
            out.push(rational(s)?);
        }
    }
    out.sort();
    out.dedup();
    Some(out)
}

/// `true` when some sample time has exact `d^2 <= eta^2` (a trustworthy
/// "close"); `false` means only "no sample was close". `None` for non-finite
/// input.
pub fn sampled_proximity(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    eta: f64,
    samples: u32,
) -> Option<bool> {
    let e = rational(eta.max(0.0))?;
    let e2 = &e * &e;
    for t in sample_times(traj, samples)? {
        if distance_sq_at(kind, traj, &t)? <= e2 {
            return Some(true);
        }
    }
    Some(false)
}
