//! The separation lower bound (`weft_geom::distance::separation_lower_bound`)
//! against exact rational arithmetic: it never exceeds the exact distance,
//! nor the exact separation along its direction (the rounding analysis), on
//! well-shaped stencils, sliver triangles, nearly parallel edges, touching
//! primitives, far from the origin and along poor directions; and it is
//! tight along an exact evaluation's normal. Also how far the evaluated
//! distance (`stencil_closest`) is from the exact one on slivers.

use num_rational::BigRational;
use num_traits::ToPrimitive;
use weft_core::{DVec3, StencilKind};
use weft_geom::ccd::oracle::{qvec, rational, stencil_distance_sq, QVec};
use weft_geom::distance::{separation_lower_bound, stencil_closest, Direction};
use weft_testkit::Rng;

const KINDS: [StencilKind; 2] = [StencilKind::VertexFace, StencilKind::EdgeEdge];

fn split(kind: StencilKind) -> usize {
    match kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    }
}

fn qdot(a: &QVec, b: &QVec) -> BigRational {
    &a[0] * &b[0] + &a[1] * &b[1] + &a[2] * &b[2]
}

/// The exact separation `min_j n . x_j - max_k n . x_k` (first primitive's
/// vertices `j`, second's `k`).
fn exact_separation(kind: StencilKind, n: &QVec, x: &[QVec; 4]) -> BigRational {
    let s = split(kind);
    let t: Vec<BigRational> = x.iter().map(|p| qdot(n, p)).collect();
    let lo = t[..s].iter().min().unwrap().clone();
    let hi = t[s..].iter().max().unwrap().clone();
    lo - hi
}

/// The same separation in floating point without the rounding slack (what
/// the bound would be if it trusted its arithmetic).
fn unslacked(kind: StencilKind, n: DVec3, x: &[DVec3; 4]) -> f64 {
    let t: Vec<f64> = x.iter().map(|p| n.dot(*p - x[0])).collect();
    let s = split(kind);
    let lo = t[..s].iter().copied().fold(f64::INFINITY, f64::min);
    let hi = t[s..].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    lo - hi
}

/// A unit vector in a random direction.
fn unit(rng: &mut Rng) -> DVec3 {
    loop {
        let v = rng.vec(1.0);
        if (0.01..=1.0).contains(&v.length_squared()) {
            return v.normalize();
        }
    }
}

/// Two unit vectors perpendicular to each other.
fn frame(rng: &mut Rng) -> (DVec3, DVec3) {
    let e1 = unit(rng);
    let e2 = e1.cross(unit(rng)).normalize();
    (e1, e2)
}

/// A stencil of `kind` of one of several shapes: generic, a sliver triangle
/// or nearly parallel edges (thinness down to 1e-15), or primitives that
/// touch, of size `scale`, at `offset` from the origin.
fn stencil(rng: &mut Rng, kind: StencilKind, shape: u64) -> [DVec3; 4] {
    let scale = 10f64.powf(rng.uniform(-3.0, 1.0));
    let offset = rng.vec(1.0) * 10f64.powf(rng.uniform(-2.0, 6.0));
    let thin = 10f64.powf(rng.uniform(-15.0, -2.0));
    let gap = if shape == 3 {
        0.0
    } else {
        10f64.powf(rng.uniform(-8.0, 0.0))
    };
    let (e1, e2) = frame(rng);
    let e3 = e1.cross(e2);
    let x = match (shape, kind) {
        (1 | 3, StencilKind::VertexFace) => {
            // A sliver: the third corner a thin distance off the long edge;
            // the point above an interior point or near an edge.
            let a = DVec3::ZERO;
            let b = e1;
            let c = e1 * rng.uniform(0.0, 1.0) + e2 * thin;
            let (w1, w2) = (rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
            let (w1, w2) = if w1 + w2 > 1.0 {
                (1.0 - w1, 1.0 - w2)
            } else {
                (w1, w2)
            };
            let foot = b * w1 + c * w2 + e2 * (thin * rng.uniform(-2.0, 2.0));
            [foot + e3 * gap, a, b, c]
        }
        (1 | 3, StencilKind::EdgeEdge) => {
            // Nearly parallel edges, overlapping along their length.
            let dir = (e1 + e2 * thin).normalize();
            let p0 = e3 * gap + e1 * rng.uniform(-0.5, 0.5);
            let q0 = e2 * (thin * rng.uniform(-1.0, 1.0));
            [p0, p0 + e1, q0, q0 + dir * rng.uniform(0.5, 1.5)]
        }
        (2, _) => {
            // Crossing or touching at a random point, one side lifted.
            let x: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
            let c = stencil_closest(kind, &x);
            let s = split(kind);
            std::array::from_fn(|j| {
                if j < s {
                    x[j] - c.n * (c.d - gap)
                } else {
                    x[j]
                }
            })
        }
        _ => std::array::from_fn(|_| rng.vec(1.0)),
    };
    x.map(|p| offset + p * scale)
}

/// Directions of several qualities: an exact evaluation's normal, that
/// normal tilted, a random direction, and non-unit vectors.
fn direction(rng: &mut Rng, kind: StencilKind, x: &[DVec3; 4], which: u64) -> DVec3 {
    let n = stencil_closest(kind, x).n;
    match which {
        0 => n,
        1 => n + unit(rng) * 10f64.powf(rng.uniform(-12.0, -1.0)),
        2 => unit(rng),
        _ => n * 10f64.powf(rng.uniform(-6.0, 6.0)),
    }
}

#[test]
fn the_separation_bound_never_exceeds_the_exact_distance() {
    let mut rng = Rng(0x5e9a_7a71);
    let (mut positive, mut trusted_too_much, mut cases) = (0, 0, 0);
    let mut evaluated_error = (0.0f64, 0.0f64);
    for case in 0..6000u64 {
        let kind = KINDS[(case % 2) as usize];
        let x = stencil(&mut rng, kind, (case / 2) % 4);
        let n = Direction::along(direction(&mut rng, kind, &x, (case / 8) % 4));
        let lower = separation_lower_bound(kind, n, &x);
        assert!(!lower.is_nan(), "case {case}: NaN for finite input");
        let what = || format!("case {case} ({kind:?}): x = {x:?}, n = {n:?}, bound {lower}");
        // The direction's norm is at most 1, exactly.
        let qn = qvec(n.vector()).unwrap();
        assert!(qdot(&qn, &qn) <= rational(1.0).unwrap(), "{}", what());
        // The bound is below the exact separation along it (the rounding
        // analysis), hence below the exact distance (weak duality).
        let qx: [QVec; 4] = std::array::from_fn(|j| qvec(x[j]).unwrap());
        let separation = exact_separation(kind, &qn, &qx);
        let q_lower = rational(lower).unwrap();
        assert!(q_lower <= separation, "{}: above the separation", what());
        let d2 = stencil_distance_sq(kind, &qx);
        if lower > 0.0 {
            positive += 1;
            assert!(&q_lower * &q_lower <= d2, "{}: above the distance", what());
        }
        // How far the evaluated distance is from the exact one, in units of
        // the slack the certificates once assumed (reported, not held).
        let exact = d2.to_f64().unwrap().sqrt();
        let scale = x.iter().fold(0.0f64, |m, p| m.max(p.abs().max_element()));
        let err = (stencil_closest(kind, &x).d - exact) / ((1.0 + scale) * f64::powi(2.0, -40));
        evaluated_error = (evaluated_error.0.min(err), evaluated_error.1.max(err));
        // Without its slack the bound would sometimes have exceeded the
        // exact separation: the slack is what keeps it below.
        if rational(unslacked(kind, n.vector(), &x)).unwrap() > separation {
            trusted_too_much += 1;
        }
        cases += 1;
    }
    println!(
        "{cases} cases, {positive} positive bounds, {trusted_too_much} unslacked above the exact"
    );
    println!(
        "evaluated distance minus exact, in units of 2^-40 (1 + max |x|): {:.3e} to {:.3e}",
        evaluated_error.0, evaluated_error.1
    );
    assert!(positive > cases / 4, "too few positive bounds: {positive}");
    assert!(trusted_too_much > 0, "no case needed the slack");
}

/// Along an exact evaluation's normal, on a well-shaped stencil near the
/// origin, the bound is the computed distance up to rounding: the
/// certificates built on it lose nothing.
#[test]
fn the_separation_bound_is_tight_along_the_closest_points_normal() {
    let mut rng = Rng(0x71_9475);
    let mut worst: f64 = 0.0;
    for case in 0..4000u64 {
        let kind = KINDS[(case % 2) as usize];
        let x: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        let c = stencil_closest(kind, &x);
        let lower = separation_lower_bound(kind, Direction::along(c.n), &x);
        // the tightness, relative to the stencil's size (about 1)
        let gap = c.d - lower;
        assert!(
            gap >= -1e-15,
            "case {case}: bound {lower} above the distance {}",
            c.d
        );
        worst = worst.max(gap);
    }
    println!("largest gap to the computed distance: {worst:e}");
    assert!(worst < 1e-12, "loose by {worst:e}");
}

/// A position or a direction that is not finite never gives a nonnegative
/// bound (it could certify a stencil asleep).
#[test]
fn the_separation_bound_of_non_finite_input_is_never_nonnegative() {
    let x0 = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z * 2.0];
    for kind in KINDS {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for j in 0..4 {
                for axis in 0..3 {
                    let mut x = x0;
                    x[j][axis] = bad;
                    for n in [DVec3::X, DVec3::Y, DVec3::Z, -DVec3::Z] {
                        let lower = separation_lower_bound(kind, Direction::along(n), &x);
                        assert!(!(lower >= 0.0), "{kind:?} x[{j}][{axis}] = {bad}: {lower}");
                    }
                }
            }
            for axis in 0..3 {
                let mut n = DVec3::Z;
                n[axis] = bad;
                let lower = separation_lower_bound(kind, Direction::along(n), &x0);
                assert!(!(lower >= 0.0), "{kind:?} n[{axis}] = {bad}: {lower}");
            }
        }
        let zero = separation_lower_bound(kind, Direction::along(DVec3::ZERO), &x0);
        assert!(!(zero >= 0.0), "{kind:?}, zero direction: {zero}");
    }
}

/// A point `h = 0.5` above a triangle's interior, along the face normal:
/// the bound is the height, less its slack of a few ulps.
#[test]
fn the_separation_bound_of_a_point_above_a_face_is_its_height() {
    let x = [DVec3::new(0.25, 0.25, 0.5), DVec3::ZERO, DVec3::X, DVec3::Y];
    let lower = separation_lower_bound(StencilKind::VertexFace, Direction::along(DVec3::Z), &x);
    assert!(lower <= 0.5 && lower > 0.5 * (1.0 - 1e-14), "{lower}");
}

/// Underflow and overflow, where the rounding analysis of the normal range
/// does not hold (found by a second reader): directions whose `n . n`
/// underflows or overflows keep a norm of at most 1 and their direction,
/// and coordinate differences near the smallest normal number (subnormal
/// products) still give a bound below the exact distance.
#[test]
fn the_separation_bound_holds_under_underflow_and_overflow() {
    let one = rational(1.0).unwrap();
    let unit_tetra = [DVec3::X, DVec3::ZERO, DVec3::Y, DVec3::Z];
    // `n . n` rounds to a subnormal (the scaled direction had norm 1.18) or
    // to 0, or overflows (it became the zero vector).
    for n in [
        DVec3::new(2.63e-162, 0.0, 0.0),
        DVec3::new(1.5688e-159, 0.0, -1.1053e-159),
        DVec3::new(3e-320, 0.0, 0.0),
        DVec3::new(1e200, 0.0, 0.0),
        DVec3::new(f64::MAX, 1e300, 0.0),
    ] {
        let d = Direction::along(n);
        let q = qvec(d.vector()).unwrap();
        assert!(qdot(&q, &q) <= one, "{n:?}: {d:?}");
        let lower = separation_lower_bound(StencilKind::VertexFace, d, &unit_tetra);
        assert!(lower <= 1.0 && lower > 0.0, "{n:?}: {lower}");
    }
    let mut rng = Rng(0x0de7);
    for case in 0..20_000u64 {
        // tiny or huge directions
        let n = unit(&mut rng) * 10f64.powf(rng.uniform(-320.0, 300.0));
        let d = Direction::along(n);
        let q = qvec(d.vector()).unwrap();
        assert!(qdot(&q, &q) <= one, "case {case}: {n:?} gave {d:?}");
        // stencils of subnormal or nearly subnormal size
        let kind = KINDS[(case % 2) as usize];
        let scale = f64::powi(2.0, -1074 + (rng.below(80) as i32));
        let x: [DVec3; 4] = std::array::from_fn(|_| {
            DVec3::new(
                rng.below(9) as f64 - 4.0,
                rng.below(9) as f64 - 4.0,
                rng.below(9) as f64 - 4.0,
            ) * scale
        });
        let dir = Direction::along(if case % 3 == 0 { unit(&mut rng) } else { n });
        let lower = separation_lower_bound(kind, dir, &x);
        if lower > 0.0 {
            let qx: [QVec; 4] = std::array::from_fn(|j| qvec(x[j]).unwrap());
            let q_lower = rational(lower).unwrap();
            assert!(
                &q_lower * &q_lower <= stencil_distance_sq(kind, &qx),
                "case {case} ({kind:?}): x = {x:?}, n = {dir:?}, bound {lower}"
            );
        }
    }
    // The second reader's example: differences of one subnormal step.
    let m = f64::from_bits(1);
    let x = [
        DVec3::ZERO,
        DVec3::new(-m, -m, 0.0),
        DVec3::new(-m, -m, 0.0),
        DVec3::new(-m, -m, 0.0),
    ];
    let lower = separation_lower_bound(
        StencilKind::VertexFace,
        Direction::along(DVec3::new(1.0, 1.0, 0.0)),
        &x,
    );
    assert!(lower <= 0.0, "{lower}");
}

/// A sliver triangle's evaluated distance: the plane formula's normal is
/// badly conditioned there, and it is dropped where its error bound exceeds
/// the triangle's smallest height. A second reader's case (edges of length
/// about 1, twice its area 4e-12) was evaluated at 1.5e-6 from a point
/// 7.8e-6 away; on random slivers of thinness 1e-15 to 1e-2 the evaluated
/// distance now stays within 1e-9 of the coordinates of the exact one
/// (about 1e-8 before, measured on a similar set).
#[test]
fn a_sliver_triangles_evaluated_distance_is_near_the_exact_one() {
    let x = [
        DVec3::new(-0.5831685645129732, -0.4035145165657616, 0.4457651894558375),
        DVec3::ZERO,
        DVec3::new(-0.6962142684431744, -0.4817443117737689, 0.5321730080432052),
        DVec3::new(
            -0.6100165503631112,
            -0.4220999432892985,
            0.46628510399837425,
        ),
    ];
    let exact = |x: &[DVec3; 4]| {
        let qx: [QVec; 4] = std::array::from_fn(|j| qvec(x[j]).unwrap());
        stencil_distance_sq(StencilKind::VertexFace, &qx)
            .to_f64()
            .unwrap()
            .sqrt()
    };
    let d = stencil_closest(StencilKind::VertexFace, &x).d;
    assert!((d - exact(&x)).abs() < 1e-11, "{d} against {}", exact(&x));
    let mut rng = Rng(0x511e);
    let mut worst: f64 = 0.0;
    for case in 0..4000 {
        let x = stencil(&mut rng, StencilKind::VertexFace, 1 + 2 * (case % 2));
        let scale = x.iter().fold(1.0f64, |m, p| m.max(p.abs().max_element()));
        let d = stencil_closest(StencilKind::VertexFace, &x).d;
        worst = worst.max((d - exact(&x)).abs() / scale);
    }
    println!("largest error of the evaluated distance on slivers: {worst:e} of the coordinates");
    assert!(worst < 1e-9, "{worst:e}");
}
