//! Geometry tests of weft-geom: distances (values, finite-difference gradients,
//! degenerate sweeps against dense sampling), 26-DOPs, the BVH (against brute
//! force) and exact triangle–triangle intersection (against brute force).

use weft_core::DVec3;

fn v(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

mod distance {
    use super::v;
    use weft_core::{DVec3, StencilKind};
    use weft_geom::distance::{edge_edge, stencil_closest, vertex_face, Closest};
    use weft_testkit::assert_gradient;

    const H: f64 = 1e-6;
    const TOL: f64 = 1e-5;

    /// A tilted, non-axis-aligned frame so that no test depends on exact zeros of
    /// coordinates.
    fn frame(p: DVec3) -> DVec3 {
        let ex = v(0.8, 0.36, -0.48);
        let ey = v(-0.6, 0.48, -0.64);
        let ez = ex.cross(ey);
        v(0.3, -0.7, 1.1) + ex * p.x + ey * p.y + ez * p.z
    }

    fn closest_points(kind: StencilKind, x: &[DVec3; 4], c: &Closest) -> (DVec3, DVec3) {
        match kind {
            StencilKind::VertexFace => (
                x[0],
                -(x[1] * c.coeff[1] + x[2] * c.coeff[2] + x[3] * c.coeff[3]),
            ),
            StencilKind::EdgeEdge => (
                x[0] * c.coeff[0] + x[1] * c.coeff[1],
                -(x[2] * c.coeff[2] + x[3] * c.coeff[3]),
            ),
        }
    }

    /// Invariants every result must satisfy: finite, unit normal, weights in
    /// [0, 1] summing to 1 per side, and `d` equal to the distance of the
    /// reported closest points with `n` along their difference.
    fn check_invariants(kind: StencilKind, x: &[DVec3; 4], c: &Closest) {
        assert!(c.d.is_finite() && c.d >= 0.0, "d = {} for {x:?}", c.d);
        assert!(c.n.is_finite(), "n = {:?} for {x:?}", c.n);
        assert!(
            (c.n.length() - 1.0).abs() < 1e-12,
            "|n| = {} for {x:?}",
            c.n.length()
        );
        for w in c.coeff {
            assert!(
                w.is_finite() && w.abs() <= 1.0 + 1e-12,
                "coeff {:?}",
                c.coeff
            );
        }
        let (lo, hi) = match kind {
            StencilKind::VertexFace => (c.coeff[0], -(c.coeff[1] + c.coeff[2] + c.coeff[3])),
            StencilKind::EdgeEdge => (c.coeff[0] + c.coeff[1], -(c.coeff[2] + c.coeff[3])),
        };
        assert!(
            (lo - 1.0).abs() < 1e-12 && (hi - 1.0).abs() < 1e-12,
            "coeff {:?}",
            c.coeff
        );
        let (pa, pb) = closest_points(kind, x, c);
        let scale = x.iter().map(|p| p.abs().max_element()).fold(1.0, f64::max);
        let diff = pa - pb;
        assert!(
            (diff.length() - c.d).abs() <= 1e-12 * scale,
            "d = {} but closest points are {} apart ({x:?})",
            c.d,
            diff.length()
        );
        if c.d > 1e-9 * scale {
            assert!(
                (diff / c.d - c.n).length() < 1e-6,
                "n {:?} vs {:?}",
                c.n,
                diff / c.d
            );
        }
    }

    fn dist(kind: StencilKind, x: &[DVec3]) -> f64 {
        stencil_closest(kind, &[x[0], x[1], x[2], x[3]]).d
    }

    /// FD checks of d and of a penalty energy k/2 (eta - d)^2 (active, d < eta).
    fn check_gradients(kind: StencilKind, x: [DVec3; 4]) -> Closest {
        let c = stencil_closest(kind, &x);
        check_invariants(kind, &x, &c);
        assert_gradient(|y| dist(kind, y), &x, &c.gradient(), H, TOL);
        let (k, eta) = (3.5, c.d * 1.7 + 0.05);
        let e = |y: &[DVec3]| {
            let d = dist(kind, y);
            if d < eta {
                0.5 * k * (eta - d) * (eta - d)
            } else {
                0.0
            }
        };
        let g = c.gradient().map(|g| g * (-k * (eta - c.d)));
        assert_gradient(e, &x, &g, H, TOL);
        c
    }

    fn tri() -> [DVec3; 3] {
        [
            frame(v(0.0, 0.0, 0.0)),
            frame(v(1.0, 0.0, 0.0)),
            frame(v(0.2, 0.9, 0.0)),
        ]
    }

    #[test]
    fn vertex_face_all_seven_voronoi_regions() {
        let [a, b, c] = tri();
        // (point in local coordinates, expected nonzero weights pattern, expected d)
        let cases: [(DVec3, [bool; 3], f64); 7] = [
            (v(0.4, 0.3, 0.5), [true, true, true], 0.5),
            (v(0.5, -0.3, 0.4), [true, true, false], 0.5),
            (
                v(0.2 + 0.8 * 0.5, 0.9 * 0.5, 0.0)
                    + v(0.9, 0.8, 0.0).normalize() * 0.3
                    + v(0.0, 0.0, -0.4),
                [false, true, true],
                0.5,
            ),
            (
                v(0.1, 0.45, 0.4) + v(-0.9, 0.2, 0.0).normalize() * 0.3,
                [true, false, true],
                0.5,
            ),
            (
                v(-0.3, -0.2, 0.1),
                [true, false, false],
                (0.09f64 + 0.04 + 0.01).sqrt(),
            ),
            (
                v(1.4, -0.2, 0.3),
                [false, true, false],
                (0.16f64 + 0.04 + 0.09).sqrt(),
            ),
            (
                v(0.1, 1.5, -0.2),
                [false, false, true],
                (0.01f64 + 0.36 + 0.04).sqrt(),
            ),
        ];
        for (i, (pl, pattern, d_expected)) in cases.into_iter().enumerate() {
            let x = [frame(pl), a, b, c];
            let r = check_gradients(StencilKind::VertexFace, x);
            let got = [r.coeff[1] != 0.0, r.coeff[2] != 0.0, r.coeff[3] != 0.0];
            assert_eq!(got, pattern, "case {i}: region, coeff {:?}", r.coeff);
            assert!(
                (r.d - d_expected).abs() < 1e-12,
                "case {i}: d {} vs {d_expected}",
                r.d
            );
        }
    }

    #[test]
    fn vertex_face_normal_points_from_face_to_vertex() {
        let [a, b, c] = tri();
        for z in [0.3, -0.3] {
            let p = frame(v(0.4, 0.3, z));
            let r = vertex_face(p, a, b, c);
            let centroid = (a + b + c) / 3.0;
            assert!(r.n.dot(p - centroid) > 0.0, "n must point towards p");
        }
    }

    #[test]
    fn edge_edge_interior_endpoint_and_parallel() {
        let f = frame;
        let cases: [([DVec3; 4], [f64; 2], f64); 6] = [
            // crossing skew edges: interior
            (
                [
                    f(v(-1.0, 0.2, 0.3)),
                    f(v(1.0, 0.2, 0.3)),
                    f(v(0.4, -1.0, 0.0)),
                    f(v(0.4, 1.0, 0.0)),
                ],
                [0.7, 0.6],
                0.3,
            ),
            // s clamped to 1 (edge p ends before reaching q)
            (
                [
                    f(v(-1.0, 0.2, 0.3)),
                    f(v(0.0, 0.2, 0.3)),
                    f(v(0.4, -1.0, 0.0)),
                    f(v(0.4, 1.0, 0.0)),
                ],
                [1.0, 0.6],
                0.5,
            ),
            // both clamped: endpoint–endpoint
            (
                [
                    f(v(-1.0, 0.0, 0.3)),
                    f(v(0.0, 0.0, 0.3)),
                    f(v(0.4, 0.2, 0.0)),
                    f(v(0.4, 1.0, 0.0)),
                ],
                [1.0, 0.0],
                (0.16f64 + 0.04 + 0.09).sqrt(),
            ),
            // parallel, offset along the axis: endpoint–endpoint (smooth)
            (
                [
                    f(v(0.0, 0.0, 0.3)),
                    f(v(1.0, 0.0, 0.3)),
                    f(v(1.5, 0.0, 0.0)),
                    f(v(2.5, 0.0, 0.0)),
                ],
                [1.0, 0.0],
                (0.25f64 + 0.09).sqrt(),
            ),
            // parallel in a plane, offset along the axis
            (
                [
                    f(v(0.0, 0.4, 0.0)),
                    f(v(1.0, 0.4, 0.0)),
                    f(v(-2.0, 0.0, 0.0)),
                    f(v(-0.5, 0.0, 0.0)),
                ],
                [0.0, 1.0],
                (0.25f64 + 0.16).sqrt(),
            ),
            // T configuration: endpoint of q against interior of p
            (
                [
                    f(v(-1.0, 0.0, 0.0)),
                    f(v(1.0, 0.0, 0.0)),
                    f(v(0.25, 0.0, 0.2)),
                    f(v(0.25, 0.0, 1.0)),
                ],
                [0.625, 0.0],
                0.2,
            ),
        ];
        for (i, (x, st, d_expected)) in cases.into_iter().enumerate() {
            let r = check_gradients(StencilKind::EdgeEdge, x);
            assert!(
                (r.coeff[1] - st[0]).abs() < 1e-12,
                "case {i}: s {} vs {}",
                r.coeff[1],
                st[0]
            );
            assert!(
                (-r.coeff[3] - st[1]).abs() < 1e-12,
                "case {i}: t {} vs {}",
                -r.coeff[3],
                st[1]
            );
            assert!(
                (r.d - d_expected).abs() < 1e-12,
                "case {i}: d {} vs {d_expected}",
                r.d
            );
        }
    }

    #[test]
    fn edge_edge_normal_points_from_second_to_first() {
        let r = edge_edge(
            v(-1.0, 0.0, 1.0),
            v(1.0, 0.0, 1.0),
            v(0.0, -1.0, 0.0),
            v(0.0, 1.0, 0.0),
        );
        assert!((r.n - DVec3::Z).length() < 1e-15 && r.d == 1.0);
        let r = edge_edge(
            v(0.0, -1.0, 0.0),
            v(0.0, 1.0, 0.0),
            v(-1.0, 0.0, 1.0),
            v(1.0, 0.0, 1.0),
        );
        assert!((r.n + DVec3::Z).length() < 1e-15 && r.d == 1.0);
    }

    // ---------- brute-force oracles (dense sampling) ----------

    const N: usize = 240;

    fn sampled_vf(x: &[DVec3; 4]) -> f64 {
        let mut best = f64::INFINITY;
        for i in 0..=N {
            for j in 0..=(N - i) {
                let (w1, w2) = (i as f64 / N as f64, j as f64 / N as f64);
                let q = x[1] * (1.0 - w1 - w2) + x[2] * w1 + x[3] * w2;
                best = best.min((x[0] - q).length());
            }
        }
        // exact vertices and edge points are included above (i = 0, j = 0, i + j = N)
        best
    }

    fn sampled_ee(x: &[DVec3; 4]) -> f64 {
        let mut best = f64::INFINITY;
        for i in 0..=N {
            let s = i as f64 / N as f64;
            let p = x[0] * (1.0 - s) + x[1] * s;
            // exact closest point on q's segment to the sample p: 1D, done densely too
            for j in 0..=N {
                let t = j as f64 / N as f64;
                best = best.min((p - (x[2] * (1.0 - t) + x[3] * t)).length());
            }
        }
        best
    }

    /// Upper bound on how far the sampled minimum can sit above the true one:
    /// the sampling grid's spacing times the largest edge length (per side).
    fn sampling_slack(x: &[DVec3; 4], kind: StencilKind) -> f64 {
        let l = match kind {
            StencilKind::VertexFace => {
                (x[1] - x[2])
                    .length()
                    .max((x[2] - x[3]).length())
                    .max((x[3] - x[1]).length())
                    * 2.0
            }
            StencilKind::EdgeEdge => (x[1] - x[0]).length() + (x[3] - x[2]).length(),
        };
        l / N as f64 + 1e-14
    }

    fn check_against_sampling(kind: StencilKind, x: [DVec3; 4]) {
        let r = stencil_closest(kind, &x);
        check_invariants(kind, &x, &r);
        let sampled = match kind {
            StencilKind::VertexFace => sampled_vf(&x),
            StencilKind::EdgeEdge => sampled_ee(&x),
        };
        assert!(
            r.d <= sampled + 1e-14,
            "d = {} above sampled minimum {sampled} for {x:?}",
            r.d
        );
        assert!(
            r.d >= sampled - sampling_slack(&x, kind),
            "d = {} far below sampled minimum {sampled} for {x:?}",
            r.d
        );
    }

    const OFFSETS: [f64; 5] = [0.0, 1e-12, -1e-12, 1e-300, -1e-7];

    #[test]
    fn vertex_face_degenerate_sweep() {
        let [a, b, c] = tri();
        let nrm = (b - a).cross(c - a).normalize();
        let mut count = 0;
        for off in OFFSETS {
            // point over the interior, over an edge, at a vertex, beyond a vertex
            for q in [
                a * 0.3 + b * 0.3 + c * 0.4,
                (a + b) * 0.5,
                a,
                b * 1.5 - a * 0.5,
                (b + c) * 0.5 + (b + c - a * 2.0) * 1e-12,
            ] {
                check_against_sampling(StencilKind::VertexFace, [q + nrm * off, a, b, c]);
                count += 1;
            }
            // degenerate triangles: collinear, coincident corners, one repeated corner, a sliver
            let mid = (a + b) * 0.5;
            let p = frame(v(0.3, 0.2, off));
            for t in [
                [a, b, mid],
                [a, a, a],
                [a, a, b],
                [a, b, mid + nrm * 1e-13],
                [b, a, mid + (b - a).cross(nrm) * 1e-9],
            ] {
                check_against_sampling(StencilKind::VertexFace, [p, t[0], t[1], t[2]]);
                check_against_sampling(
                    StencilKind::VertexFace,
                    [mid + nrm * off, t[0], t[1], t[2]],
                );
                count += 2;
            }
        }
        assert_eq!(count, OFFSETS.len() * 15);
    }

    #[test]
    fn vertex_face_zero_distance_uses_face_normal() {
        let [a, b, c] = tri();
        let nrm = (b - a).cross(c - a).normalize();
        for p in [a, (a + b) * 0.5, a * 0.2 + b * 0.3 + c * 0.5] {
            let r = vertex_face(p, a, b, c);
            assert!(r.d < 1e-15);
            if r.d == 0.0 {
                assert!(
                    (r.n - nrm).length() < 1e-12,
                    "fallback normal {:?} vs {nrm:?}",
                    r.n
                );
            }
        }
        // fully degenerate: deterministic and finite
        let r = vertex_face(a, a, a, a);
        assert_eq!(r.d, 0.0);
        assert_eq!(r.n, DVec3::Z);
    }

    #[test]
    fn edge_edge_degenerate_sweep() {
        let f = frame;
        let mut count = 0;
        for off in OFFSETS {
            let o = v(0.0, 0.0, off);
            let cases: [[DVec3; 4]; 10] = [
                // crossing (skew) at distance `off`
                [
                    f(v(-1.0, 0.0, 0.0) + o),
                    f(v(1.0, 0.0, 0.0) + o),
                    f(v(0.3, -1.0, 0.0)),
                    f(v(0.3, 1.0, 0.0)),
                ],
                // nearly parallel crossing
                [
                    f(v(-1.0, 0.0, 0.0) + o),
                    f(v(1.0, 0.0, 0.0) + o),
                    f(v(-1.0, -1e-9, 0.0)),
                    f(v(1.0, 1e-9, 0.0)),
                ],
                // parallel overlapping
                [
                    f(v(0.0, 0.0, 0.0) + o),
                    f(v(1.0, 0.0, 0.0) + o),
                    f(v(0.5, 0.0, 0.0)),
                    f(v(1.5, 0.0, 0.0)),
                ],
                // parallel, opposite directions, coplanar offset in y
                [
                    f(v(0.0, off, 0.0)),
                    f(v(1.0, off, 0.0)),
                    f(v(1.2, 0.0, 0.0)),
                    f(v(0.2, 0.0, 0.0)),
                ],
                // collinear disjoint
                [
                    f(v(0.0, 0.0, 0.0) + o),
                    f(v(1.0, 0.0, 0.0) + o),
                    f(v(1.0 + 1e-12, 0.0, 0.0)),
                    f(v(2.0, 0.0, 0.0)),
                ],
                // coplanar, non-crossing (T near miss)
                [
                    f(v(-1.0, 0.0, 0.0)),
                    f(v(1.0, 0.0, 0.0)),
                    f(v(0.2, 1e-12 + off.abs(), 0.0)),
                    f(v(0.2, 1.0, 0.0)),
                ],
                // zero-length first edge over the second
                [
                    f(v(0.3, 0.0, 0.0) + o),
                    f(v(0.3, 0.0, 0.0) + o),
                    f(v(0.0, 0.0, 0.0)),
                    f(v(1.0, 0.0, 0.0)),
                ],
                // both zero length
                [
                    f(v(0.3, 0.2, 0.0) + o),
                    f(v(0.3, 0.2, 0.0) + o),
                    f(v(0.3, 0.2, 0.0)),
                    f(v(0.3, 0.2, 0.0)),
                ],
                // shared endpoint position (touching)
                [
                    f(v(0.0, 0.0, 0.0) + o),
                    f(v(1.0, 0.0, 0.0)),
                    f(v(0.0, 0.0, 0.0)),
                    f(v(0.0, 1.0, 0.0)),
                ],
                // nearly parallel, non-overlapping in s
                [
                    f(v(0.0, 0.0, 0.0) + o),
                    f(v(1.0, 1e-10, 0.0) + o),
                    f(v(1.0 + 1e-9, 0.0, 0.0)),
                    f(v(2.0, -1e-10, 0.0)),
                ],
            ];
            for x in cases {
                check_against_sampling(StencilKind::EdgeEdge, x);
                // swapping the edges flips the normal and keeps d
                let a = edge_edge(x[0], x[1], x[2], x[3]);
                let b = edge_edge(x[2], x[3], x[0], x[1]);
                assert!(
                    (a.d - b.d).abs() <= 1e-15 * (1.0 + a.d),
                    "swap changed d: {} vs {}",
                    a.d,
                    b.d
                );
                if a.d > 1e-9 {
                    // The direction of a near-parallel pair at distance d is
                    // known to about (coordinate rounding) / d.
                    let tol = 1e-9f64.max(1e-14 / a.d);
                    assert!((a.n + b.n).length() < tol, "{x:?} {a:?} {b:?}");
                }
                count += 1;
            }
        }
        assert_eq!(count, OFFSETS.len() * 10);
    }

    #[test]
    fn edge_edge_zero_distance_normals_are_deterministic() {
        // crossing at a point: the edge cross product
        let r = edge_edge(
            v(-1.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(0.0, -1.0, 0.0),
            v(0.0, 1.0, 0.0),
        );
        assert_eq!(r.d, 0.0);
        assert_eq!(r.n, DVec3::Z);
        // collinear overlapping: perpendicular to the edge, fixed axis choice
        let r = edge_edge(
            v(0.0, 0.0, 0.0),
            v(2.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(3.0, 0.0, 0.0),
        );
        assert_eq!(r.d, 0.0);
        assert!(r.n.is_finite() && (r.n.length() - 1.0).abs() < 1e-15 && r.n.x == 0.0);
    }

    /// Distances scale linearly over the documented range of magnitudes.
    #[test]
    fn scale_invariance_over_the_supported_range() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for i in 0..200 {
            let mut x = [DVec3::ZERO; 4];
            for p in &mut x {
                *p = v(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                );
            }
            let kind = if i % 2 == 0 {
                StencilKind::VertexFace
            } else {
                StencilKind::EdgeEdge
            };
            let r = stencil_closest(kind, &x);
            for scale in [1e-60, 1e-20, 1e20, 1e60] {
                let xs = x.map(|p| p * scale);
                let rs = stencil_closest(kind, &xs);
                check_invariants(kind, &xs, &rs);
                assert!(
                    (rs.d / scale - r.d).abs() <= 1e-12 * (1.0 + r.d),
                    "scale {scale}: {} vs {}",
                    rs.d / scale,
                    r.d
                );
            }
        }
    }

    #[test]
    fn random_stencils_match_sampling() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for i in 0..60 {
            let mut x = [DVec3::ZERO; 4];
            for p in &mut x {
                *p = v(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                );
            }
            let kind = if i % 2 == 0 {
                StencilKind::VertexFace
            } else {
                StencilKind::EdgeEdge
            };
            check_against_sampling(kind, x);
            // generic positions are differentiable: check the gradient too
            check_gradients(kind, x);
        }
    }
}

/// Shared random helpers.
mod rnd {
    use super::v;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use weft_core::DVec3;

    pub fn rng(seed: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(seed)
    }

    pub fn point(rng: &mut ChaCha8Rng, half: f64) -> DVec3 {
        v(
            rng.gen_range(-half..half),
            rng.gen_range(-half..half),
            rng.gen_range(-half..half),
        )
    }

    /// A random triangle of size up to `size` around a random center in the box.
    pub fn triangle(rng: &mut ChaCha8Rng, half: f64, size: f64) -> [DVec3; 3] {
        let c = point(rng, half);
        [
            c + point(rng, size),
            c + point(rng, size),
            c + point(rng, size),
        ]
    }
}

mod dop {
    use super::{rnd, v};
    use num_bigint::BigInt;
    use num_rational::BigRational;
    use num_traits::{Signed, Zero};
    use rand::Rng;
    use weft_core::DVec3;
    use weft_geom::dop::{Dop26, DIRECTIONS};

    fn q(x: f64) -> BigRational {
        BigRational::from_float(x).expect("finite")
    }

    /// Exact test of `a <= b / sqrt(k)` for rationals `a`, `b` and `k > 0`.
    fn le_div_sqrt(a: &BigRational, b: &BigRational, k: i64) -> bool {
        let k = BigRational::from_integer(BigInt::from(k));
        if !b.is_negative() {
            !a.is_positive() || &k * a * a <= b * b
        } else {
            a.is_negative() && &k * a * a >= b * b
        }
    }

    /// Exact projection of `p` onto the exact unit direction `k`, as `b / sqrt(m)`.
    fn exact_projection(k: usize, p: DVec3) -> (BigRational, i64) {
        let dir = DIRECTIONS[k];
        let sgn = |c: f64| {
            if c > 0.0 {
                1
            } else if c < 0.0 {
                -1
            } else {
                0
            }
        };
        let s = [sgn(dir.x), sgn(dir.y), sgn(dir.z)];
        let nonzero = s.iter().filter(|&&c| c != 0).count() as i64;
        let mut b = BigRational::zero();
        for (c, x) in s.into_iter().zip(p.to_array()) {
            b += q(x) * BigRational::from_integer(BigInt::from(c));
        }
        (b, nonzero)
    }

    fn assert_contains_exact(d: &Dop26, p: DVec3) {
        for k in 0..13 {
            let (b, m) = exact_projection(k, p);
            assert!(
                le_div_sqrt(&q(d.lo[k]), &b, m),
                "lo[{k}] = {} above the exact projection of {p:?}",
                d.lo[k]
            );
            // hi >= b/sqrt(m)  <=>  -hi <= -b/sqrt(m)
            assert!(
                le_div_sqrt(&-q(d.hi[k]), &-b, m),
                "hi[{k}] = {} below the exact projection of {p:?}",
                d.hi[k]
            );
        }
    }

    #[test]
    fn directions_are_the_correctly_rounded_unit_vectors() {
        // 3 axes, 6 face diagonals, 4 body diagonals, pairwise non-parallel
        let nz: Vec<usize> = DIRECTIONS
            .iter()
            .map(|d| d.to_array().iter().filter(|c| **c != 0.0).count())
            .collect();
        assert_eq!(nz, [1, 1, 1, 2, 2, 2, 2, 2, 2, 3, 3, 3, 3]);
        for (i, a) in DIRECTIONS.iter().enumerate() {
            assert!((a.length() - 1.0).abs() < 3e-16);
            for b in &DIRECTIONS[i + 1..] {
                assert!(a.cross(*b).length() > 0.1);
            }
        }
        // each nonzero component c is the float nearest to 1/sqrt(m): |m c^2 - 1|
        // is smaller than for both neighbouring floats
        for d in DIRECTIONS {
            let c = d.x.abs().max(d.y.abs()).max(d.z.abs());
            let m = d.to_array().iter().filter(|c| **c != 0.0).count() as i64;
            let err = |x: f64| {
                (BigRational::from_integer(BigInt::from(m)) * q(x) * q(x)
                    - BigRational::from_integer(BigInt::from(1)))
                .abs()
            };
            let up = f64::from_bits(c.to_bits() + 1);
            let down = f64::from_bits(c.to_bits() - 1);
            assert!(
                err(c) < err(up) && err(c) < err(down),
                "component {c} of {d:?} is not correctly rounded"
            );
        }
    }

    #[test]
    fn add_point_contains_the_exact_projection() {
        let mut rng = rnd::rng(11);
        let mut pts: Vec<DVec3> = vec![
            v(0.0, 0.0, 0.0),
            v(1.0, 1.0, 1.0),
            v(-3.0, 1e-300, 5e-324),
            v(1e200, -1e200, 3.0),
        ];
        for i in 0..400 {
            let scale = 10f64.powi(rng.gen_range(-200..200));
            let mut p = rnd::point(&mut rng, 1.0) * scale;
            if i % 5 == 0 {
                // cancellation: nearly on the plane orthogonal to a body diagonal
                p = v(p.x, -p.x, p.z * 1e-17);
            }
            pts.push(p);
        }
        for p in pts {
            let d = Dop26::from_point(p);
            assert_contains_exact(&d, p);
            // and not absurdly loose: within ~2^-49 of the magnitude
            let s = p.x.abs() + p.y.abs() + p.z.abs();
            for k in 0..13 {
                assert!(
                    d.hi[k] - d.lo[k] <= 1e-14 * s + 1e-300,
                    "interval {k} too wide for {p:?}"
                );
            }
        }
    }

    #[test]
    fn union_merge_inflate_and_empty() {
        let e = Dop26::empty();
        assert!(e.is_empty());
        let a = Dop26::from_point(v(1.0, 2.0, 3.0));
        assert!(!a.is_empty());
        assert!(!e.overlaps(&a) && !a.overlaps(&e) && !e.overlaps(&e));
        assert_eq!(e.union(&a), a);
        let mut m = e;
        m.merge(&a);
        assert_eq!(m, a);
        let mut ei = e;
        ei.inflate(1.0);
        assert!(ei.is_empty());
        let b = Dop26::from_point(v(1.0, 2.0, 3.5));
        assert_eq!(
            Dop26::from_points([v(1.0, 2.0, 3.0), v(1.0, 2.0, 3.5)]),
            a.union(&b)
        );
        assert!(Dop26::from_points([]).is_empty());
        let u = a.union(&b);
        assert!(u.contains(&a) && u.contains(&b));
        assert!(!a.overlaps(&b));
        let mut ai = a;
        ai.inflate(0.25);
        let mut bi = b;
        bi.inflate(0.25);
        assert!(ai.overlaps(&bi), "points 0.5 apart, each inflated by 0.25");
        let mut bj = b;
        bj.inflate(0.2);
        let mut aj = a;
        aj.inflate(0.2);
        assert!(!aj.overlaps(&bj), "points 0.5 apart, each inflated by 0.2");
        assert!(ai.contains(&a) && !a.contains(&ai));
    }

    /// Two point sets whose hulls come within 2r, each DOP inflated by r, must
    /// overlap; sets much farther apart than the DOP's slack must not.
    #[test]
    fn overlap_guarantee_under_inflation() {
        let mut rng = rnd::rng(12);
        for i in 0..3000 {
            let scale = 10f64.powi(rng.gen_range(-3..9));
            let r = scale * 10f64.powi(rng.gen_range(-17..-1));
            let center = rnd::point(&mut rng, scale);
            // the closest pair: x in A, y = x + delta in B, |delta| <= 2r
            let dir = rnd::point(&mut rng, 1.0).normalize_or(DVec3::X);
            let delta = dir
                * (2.0
                    * r
                    * (1.0 - 1e-12)
                    * if i % 3 == 0 {
                        1.0
                    } else {
                        rng.gen_range(0.0..1.0)
                    });
            let mut a = Dop26::from_point(center);
            let mut b = Dop26::from_point(center + delta);
            for _ in 0..3 {
                // more points on the far sides
                a.add_point(center - rnd::point(&mut rng, r).abs() * dir.signum() - dir * r);
                b.add_point(center + delta + dir * (3.0 * r));
            }
            a.inflate(r);
            b.inflate(r);
            assert!(a.overlaps(&b), "missed overlap at scale {scale}, r {r}");
            // far apart (distance 4r + slack along an axis): no overlap
            let far = Dop26::from_point(center + DVec3::X * (4.0 * r + 1e-12 * scale));
            let mut far = far;
            far.inflate(r);
            let mut c = Dop26::from_point(center);
            c.inflate(r);
            assert!(
                !c.overlaps(&far),
                "spurious overlap at scale {scale}, r {r}"
            );
        }
    }
}

mod bvh {
    use super::{rnd, v};
    use rand::Rng;
    use weft_core::DVec3;
    use weft_geom::bvh::{brute_force_self_pairs, Bvh};
    use weft_geom::dop::Dop26;

    fn tri_dop(t: &[DVec3; 3], r: f64) -> Dop26 {
        let mut d = Dop26::empty();
        for p in t {
            d.add_point(*p);
        }
        d.inflate(r);
        d
    }

    /// Self pairs from the tree, checked for duplicates and ordering, sorted.
    fn tree_pairs(bvh: &Bvh) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        bvh.self_overlaps(|i, j| {
            assert!(i < j, "pair ({i}, {j}) not ordered");
            out.push((i, j));
        });
        let n = out.len();
        out.sort_unstable();
        out.dedup();
        assert_eq!(out.len(), n, "a pair was reported twice");
        out
    }

    fn check_self(leaves: &[Dop26]) -> usize {
        let bvh = Bvh::build(leaves);
        bvh.validate(leaves).unwrap();
        let expected = brute_force_self_pairs(leaves);
        assert_eq!(tree_pairs(&bvh), expected);
        expected.len()
    }

    fn random_triangles(seed: u64, n: usize, half: f64, size: f64, r: f64) -> Vec<Dop26> {
        let mut rng = rnd::rng(seed);
        (0..n)
            .map(|_| {
                let t = rnd::triangle(&mut rng, half, size);
                tri_dop(&t, r * rng.gen_range(0.0..1.0))
            })
            .collect()
    }

    #[test]
    fn random_triangle_scenes_match_brute_force() {
        let mut total = 0;
        for (seed, n) in [(1, 2), (2, 5), (3, 17), (4, 300), (5, 1200)] {
            total += check_self(&random_triangles(seed, n, 1.0, 0.08, 0.02));
        }
        assert!(
            total > 100,
            "scenes too sparse to test anything ({total} pairs)"
        );
    }

    #[test]
    fn random_point_clouds_with_random_inflation() {
        let mut rng = rnd::rng(21);
        for n in [1, 3, 64, 700] {
            let leaves: Vec<Dop26> = (0..n)
                .map(|_| {
                    let mut d = Dop26::from_point(rnd::point(&mut rng, 1.0));
                    d.inflate(rng.gen_range(0.0..0.15));
                    d
                })
                .collect();
            check_self(&leaves);
        }
    }

    fn grid(nx: usize, ny: usize) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let mut x = Vec::new();
        for j in 0..=ny {
            for i in 0..=nx {
                x.push(v(i as f64 * 0.1, j as f64 * 0.1, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        let mut t = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (x, t)
    }

    #[test]
    fn grid_mesh_reports_adjacent_triangles_and_matches_brute_force() {
        let (x, tris) = grid(23, 17);
        for r in [0.0, 0.01, 0.06] {
            let leaves: Vec<Dop26> = tris
                .iter()
                .map(|t| tri_dop(&t.map(|i| x[i as usize]), r))
                .collect();
            let bvh = Bvh::build(&leaves);
            bvh.validate(&leaves).unwrap();
            let pairs = tree_pairs(&bvh);
            assert_eq!(pairs, brute_force_self_pairs(&leaves));
            // the two triangles of a quad share the diagonal; triangle 0 shares an
            // edge with triangle 3 and only a vertex with triangle 2; triangle 1
            // shares its top edge with the first triangle of the second row
            for pair in [(0, 1), (0, 3), (0, 2), (1, 2 * 23)] {
                assert!(
                    pairs.contains(&pair),
                    "adjacent pair {pair:?} missing (r = {r})"
                );
            }
            assert!(!pairs.iter().any(|&(i, j)| i == j));
        }
    }

    #[test]
    fn refit_with_moved_leaves() {
        let mut rng = rnd::rng(31);
        let n = 500;
        let mut tris: Vec<[DVec3; 3]> = (0..n).map(|_| rnd::triangle(&mut rng, 1.0, 0.1)).collect();
        let leaves: Vec<Dop26> = tris.iter().map(|t| tri_dop(t, 0.01)).collect();
        let mut bvh = Bvh::build(&leaves);
        bvh.validate(&leaves).unwrap();
        for step in 0..5 {
            for t in &mut tris {
                let d = rnd::point(&mut rng, 0.05 * (step + 1) as f64);
                for p in t.iter_mut() {
                    *p += d + rnd::point(&mut rng, 0.01);
                }
            }
            let moved: Vec<Dop26> = tris.iter().map(|t| tri_dop(t, 0.01)).collect();
            // the old tree is no longer valid for the moved leaves
            assert!(
                bvh.validate(&moved).is_err(),
                "validate must notice stale bounds"
            );
            bvh.refit(&moved);
            bvh.validate(&moved).unwrap();
            assert_eq!(
                tree_pairs(&bvh),
                brute_force_self_pairs(&moved),
                "step {step}"
            );
        }
        // refit with a different leaf count rebuilds
        let fewer = &tris[..37]
            .iter()
            .map(|t| tri_dop(t, 0.01))
            .collect::<Vec<_>>();
        bvh.refit(fewer);
        bvh.validate(fewer).unwrap();
        assert_eq!(tree_pairs(&bvh), brute_force_self_pairs(fewer));
    }

    #[test]
    fn overlaps_with_matches_brute_force() {
        let a = random_triangles(41, 400, 1.0, 0.1, 0.02);
        let b = random_triangles(42, 250, 1.0, 0.1, 0.02);
        let (ta, tb) = (Bvh::build(&a), Bvh::build(&b));
        ta.validate(&a).unwrap();
        tb.validate(&b).unwrap();
        let mut got = Vec::new();
        ta.overlaps_with(&tb, |i, j| got.push((i, j)));
        let n = got.len();
        got.sort_unstable();
        got.dedup();
        assert_eq!(got.len(), n, "duplicate cross pair");
        let mut expected = Vec::new();
        for (i, da) in a.iter().enumerate() {
            for (j, db) in b.iter().enumerate() {
                if da.overlaps(db) {
                    expected.push((i as u32, j as u32));
                }
            }
        }
        assert!(!expected.is_empty());
        assert_eq!(got, expected);
        // and with an empty tree
        let empty = Bvh::build(&[]);
        empty.validate(&[]).unwrap();
        ta.overlaps_with(&empty, |_, _| panic!("pair with an empty tree"));
        empty.self_overlaps(|_, _| panic!("pair in an empty tree"));
    }

    #[test]
    fn identical_and_empty_leaves() {
        // all leaves equal: every pair overlaps
        let d = tri_dop(&[v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)], 0.0);
        let leaves = vec![d; 40];
        assert_eq!(check_self(&leaves), 40 * 39 / 2);
        // empty DOPs mixed in overlap nothing
        let mut leaves = random_triangles(51, 100, 1.0, 0.2, 0.05);
        for k in (0..100).step_by(7) {
            leaves[k] = Dop26::empty();
        }
        let pairs = {
            let bvh = Bvh::build(&leaves);
            bvh.validate(&leaves).unwrap();
            tree_pairs(&bvh)
        };
        assert_eq!(pairs, brute_force_self_pairs(&leaves));
        assert!(!pairs.iter().any(|&(i, j)| i % 7 == 0 || j % 7 == 0));
    }

    #[test]
    fn deterministic_build() {
        let leaves = random_triangles(61, 1000, 1.0, 0.1, 0.02);
        let collect = || {
            let mut out = Vec::new();
            Bvh::build(&leaves).self_overlaps(|i, j| out.push((i, j)));
            out
        };
        assert_eq!(
            collect(),
            collect(),
            "same input must give the same call order"
        );
    }

    /// A large, badly distributed input (all leaves on one line, then all equal
    /// centers) must build and traverse without deep recursion.
    #[test]
    fn large_inputs_use_no_recursion() {
        let n = 200_000;
        let leaves: Vec<Dop26> = (0..n)
            .map(|i| {
                let mut d = Dop26::from_point(v(i as f64 * 1e-3, 0.0, 0.0));
                d.inflate(6e-4); // overlaps the next leaf (1.2e-3 > 1e-3), not the one after
                d
            })
            .collect();
        let bvh = Bvh::build(&leaves);
        bvh.validate(&leaves).unwrap();
        let mut count = 0usize;
        bvh.self_overlaps(|i, j| {
            assert_eq!(j, i + 1);
            count += 1;
        });
        assert_eq!(count, n - 1);
    }
}

mod tri_tri {
    use super::{rnd, v};
    use rand::Rng;
    use weft_core::DVec3;
    use weft_geom::intersections::mesh_self_intersections;
    use weft_geom::tri_tri::{segments_intersect, triangles_intersect};

    /// Checks the answer under swapping the triangles and permuting corners.
    fn check(a: [DVec3; 3], b: [DVec3; 3], expected: bool, what: &str) {
        let perms = [
            [0, 1, 2],
            [1, 2, 0],
            [2, 0, 1],
            [0, 2, 1],
            [2, 1, 0],
            [1, 0, 2],
        ];
        for pa in perms {
            for pb in perms {
                let a2 = pa.map(|i| a[i]);
                let b2 = pb.map(|i| b[i]);
                assert_eq!(
                    triangles_intersect(&a2, &b2),
                    expected,
                    "{what}: {a2:?} vs {b2:?}"
                );
                assert_eq!(triangles_intersect(&b2, &a2), expected, "{what} (swapped)");
            }
        }
    }

    fn base() -> [DVec3; 3] {
        [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)]
    }

    #[test]
    fn crossing_and_separated() {
        let a = base();
        check(
            a,
            [v(0.2, 0.2, -0.5), v(0.3, 0.2, 0.5), v(0.2, 0.4, 0.5)],
            true,
            "piercing",
        );
        check(
            a,
            [v(0.5, -0.5, 0.5), v(0.5, 0.5, -0.5), v(0.5, 1.5, 0.5)],
            true,
            "crossing band",
        );
        check(
            a,
            [v(0.2, 0.2, 0.1), v(0.3, 0.2, 0.5), v(0.2, 0.4, 0.5)],
            false,
            "above",
        );
        check(
            a,
            [v(0.8, 0.8, -0.5), v(0.8, 0.8, 0.5), v(1.5, 1.5, 0.0)],
            false,
            "beside, spanning the plane",
        );
    }

    #[test]
    fn touching_counts() {
        let a = base();
        check(
            a,
            [v(0.25, 0.25, 0.0), v(0.3, 0.2, 0.5), v(0.2, 0.4, 0.5)],
            true,
            "vertex on face",
        );
        check(
            a,
            [v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.5), v(2.0, 1.0, 0.5)],
            true,
            "vertex on vertex",
        );
        check(
            a,
            [v(0.5, 0.0, 0.0), v(0.5, -1.0, 0.5), v(0.5, -1.0, -0.5)],
            true,
            "vertex on edge",
        );
        check(
            a,
            [v(0.2, 0.0, 0.0), v(0.7, 0.0, 0.0), v(0.5, -1.0, 0.5)],
            true,
            "edge along edge",
        );
        check(
            a,
            [v(0.5, -0.5, 0.0), v(0.5, 0.5, 0.0), v(0.5, 0.0, 1.0)],
            true,
            "edge across the face",
        );
        check(
            a,
            [v(0.5, 0.5, -1.0), v(0.5, 0.5, 1.0), v(2.0, 2.0, 0.0)],
            true,
            "edge through hypotenuse",
        );
    }

    #[test]
    fn coplanar_cases() {
        let a = base();
        check(
            a,
            [v(0.2, 0.2, 0.0), v(1.0, 1.0, 0.0), v(0.2, 1.0, 0.0)],
            true,
            "overlapping",
        );
        check(
            a,
            [v(0.1, 0.1, 0.0), v(0.3, 0.1, 0.0), v(0.1, 0.3, 0.0)],
            true,
            "contained",
        );
        check(
            a,
            [v(0.6, 0.6, 0.0), v(1.0, 0.6, 0.0), v(0.6, 1.0, 0.0)],
            false,
            "disjoint",
        );
        check(
            a,
            [v(0.5, 0.5, 0.0), v(1.0, 1.0, 0.0), v(0.5, 1.0, 0.0)],
            true,
            "touching the hypotenuse at a point",
        );
        check(
            a,
            [v(1.0, 0.0, 0.0), v(1.0, 1.0, 0.0), v(0.0, 1.0, 0.0)],
            true,
            "sharing the hypotenuse",
        );
        check(
            a,
            [v(0.5 + 1e-15, 0.5, 0.0), v(1.0, 1.0, 0.0), v(0.5, 1.0, 0.0)],
            false,
            "coplanar miss by 1e-15",
        );
        // a tilted plane x + y + z = 1, with exactly representable points on it
        let t = [v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0), v(0.0, 0.0, 1.0)];
        check(
            t,
            [v(0.25, 0.25, 0.5), v(0.5, 0.5, 0.0), v(0.0, 0.5, 0.5)],
            true,
            "tilted coplanar",
        );
        check(
            t,
            [v(0.5, 0.5, 0.0), v(1.0, 1.0, -1.0), v(0.5, 1.0, -0.5)],
            true,
            "tilted coplanar, touching at a point",
        );
    }

    #[test]
    fn near_misses_by_1e_15() {
        let a = base();
        check(
            a,
            [v(0.25, 0.25, 1e-15), v(0.3, 0.2, 0.5), v(0.2, 0.4, 0.5)],
            false,
            "above by 1e-15",
        );
        check(
            a,
            [v(0.25, 0.25, -1e-15), v(0.3, 0.2, 0.5), v(0.2, 0.4, 0.5)],
            true,
            "below by 1e-15",
        );
        let t = [v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0), v(0.0, 0.0, 1.0)];
        check(
            t,
            [
                v(0.25, 0.25, 0.5 + 1e-15),
                v(1.0, 1.0, 1.0),
                v(1.0, 0.5, 1.0),
            ],
            false,
            "tilted, outside by 1e-15",
        );
        check(
            t,
            [v(0.25, 0.25, 0.5), v(1.0, 1.0, 1.0), v(1.0, 0.5, 1.0)],
            true,
            "tilted, touching",
        );
        check(
            t,
            [
                v(0.25, 0.25, 0.5 - 1e-15),
                v(1.0, 1.0, 1.0),
                v(1.0, 0.5, 1.0),
            ],
            true,
            "tilted, through by 1e-15",
        );
        // edge passing 1e-15 beside the triangle's corner
        check(
            a,
            [
                v(1.0 + 1e-15, 0.0, -1.0),
                v(1.0 + 1e-15, 0.0, 1.0),
                v(3.0, 0.0, 0.0),
            ],
            false,
            "edge beside corner",
        );
        check(
            a,
            [v(1.0, 0.0, -1.0), v(1.0, 0.0, 1.0), v(3.0, 0.0, 0.0)],
            true,
            "edge through corner",
        );
    }

    #[test]
    fn degenerate_triangles() {
        let a = base();
        let seg = |p: DVec3, q: DVec3| [p, q, (p + q) * 0.5];
        check(
            a,
            seg(v(0.2, 0.2, -1.0), v(0.2, 0.2, 1.0)),
            true,
            "segment through face",
        );
        check(
            a,
            seg(v(0.7, 0.7, -1.0), v(0.7, 0.7, 1.0)),
            false,
            "segment beside face",
        );
        check(
            a,
            seg(v(-1.0, 0.3, 0.0), v(2.0, 0.3, 0.0)),
            true,
            "coplanar segment across",
        );
        check(a, [v(0.3, 0.3, 0.0); 3], true, "point on face");
        check(a, [v(0.3, 0.3, 1e-15); 3], false, "point above face");
        check(
            seg(v(0.0, 0.0, 0.0), v(1.0, 1.0, 0.0)),
            seg(v(0.0, 1.0, 0.0), v(1.0, 0.0, 0.0)),
            true,
            "two crossing segments",
        );
        check(
            seg(v(0.0, 0.0, 0.0), v(1.0, 1.0, 0.0)),
            seg(v(0.0, 1.0, 1e-15), v(1.0, 0.0, 1e-15)),
            false,
            "skew segments",
        );
        check(
            seg(v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0)),
            seg(v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.0)),
            true,
            "collinear touching",
        );
        check(
            seg(v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0)),
            seg(v(1.0 + 1e-15, 0.0, 0.0), v(2.0, 0.0, 0.0)),
            false,
            "collinear apart",
        );
        check(
            [v(0.5, 0.5, 0.5); 3],
            [v(0.5, 0.5, 0.5); 3],
            true,
            "same point",
        );
        assert!(segments_intersect(
            v(0.0, 0.0, 0.0),
            v(0.0, 0.0, 2.0),
            v(0.0, 0.0, 1.0),
            v(0.0, 0.0, 3.0)
        ));
        assert!(!segments_intersect(
            v(0.0, 0.0, 0.0),
            v(0.0, 0.0, 1.0),
            v(0.0, 0.0, 2.0),
            v(0.0, 0.0, 3.0)
        ));
    }

    /// Independent floating-point oracle for generic configurations: the
    /// triangles intersect iff an edge of one crosses the other's interior
    /// (Möller–Trumbore); returns None when any quantity is within a safety
    /// margin of a decision boundary.
    fn float_oracle(a: &[DVec3; 3], b: &[DVec3; 3]) -> Option<bool> {
        let mut hit = false;
        for (s, t) in [(a, b), (b, a)] {
            for k in 0..3 {
                let (p, q) = (s[k], s[(k + 1) % 3]);
                let dir = q - p;
                let e1 = t[1] - t[0];
                let e2 = t[2] - t[0];
                let h = dir.cross(e2);
                let det = e1.dot(h);
                if det.abs() < 1e-6 {
                    return None;
                }
                let sv = p - t[0];
                let u = sv.dot(h) / det;
                let qv = sv.cross(e1);
                let w = dir.dot(qv) / det;
                let tt = e2.dot(qv) / det;
                let m = 1e-7;
                for x in [u, w, u + w, tt] {
                    if (x.abs() < m) || ((x - 1.0).abs() < m) {
                        return None;
                    }
                }
                if u > 0.0 && w > 0.0 && u + w < 1.0 && tt > 0.0 && tt < 1.0 {
                    hit = true;
                }
            }
        }
        Some(hit)
    }

    #[test]
    fn random_pairs_match_float_oracle() {
        let mut rng = rnd::rng(71);
        let (mut yes, mut no) = (0, 0);
        for _ in 0..20000 {
            let a = rnd::triangle(&mut rng, 0.5, 0.6);
            let b = rnd::triangle(&mut rng, 0.5, 0.6);
            if let Some(expected) = float_oracle(&a, &b) {
                assert_eq!(triangles_intersect(&a, &b), expected, "{a:?} vs {b:?}");
                if expected {
                    yes += 1
                } else {
                    no += 1
                }
            }
        }
        assert!(yes > 500 && no > 500, "{yes} intersecting, {no} disjoint");
    }

    fn brute_force(x: &[DVec3], tris: &[[u32; 3]]) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        for i in 0..tris.len() {
            for j in i + 1..tris.len() {
                if tris[i].iter().any(|v| tris[j].contains(v)) {
                    continue;
                }
                let a = tris[i].map(|k| x[k as usize]);
                let b = tris[j].map(|k| x[k as usize]);
                if triangles_intersect(&a, &b) {
                    out.push((i as u32, j as u32));
                }
            }
        }
        out
    }

    #[test]
    fn mesh_self_intersections_match_brute_force_on_soups() {
        let mut rng = rnd::rng(81);
        let mut total = 0;
        for round in 0..40 {
            // small-integer lattice points: many exact touchings and coplanar pairs
            let lattice = round % 2 == 0;
            let nv = rng.gen_range(6..60);
            let x: Vec<DVec3> = (0..nv)
                .map(|_| {
                    if lattice {
                        v(
                            rng.gen_range(0..4) as f64,
                            rng.gen_range(0..4) as f64,
                            rng.gen_range(0..3) as f64,
                        ) * 0.25
                    } else {
                        rnd::point(&mut rng, 1.0)
                    }
                })
                .collect();
            let nt = rng.gen_range(2..40);
            let tris: Vec<[u32; 3]> = (0..nt)
                .map(|_| {
                    [
                        rng.gen_range(0..nv as u32),
                        rng.gen_range(0..nv as u32),
                        rng.gen_range(0..nv as u32),
                    ]
                })
                .collect();
            let got = mesh_self_intersections(&x, &tris);
            assert_eq!(got, brute_force(&x, &tris), "round {round}");
            total += got.len();
        }
        assert!(total > 50, "soups too sparse ({total} intersecting pairs)");
    }

    #[test]
    fn mesh_self_intersections_on_a_folded_grid() {
        // a flat grid has no intersections (adjacent triangles share vertices)
        let n = 12;
        let mut x = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                x.push(v(i as f64, j as f64, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut tris = Vec::new();
        for j in 0..n {
            for i in 0..n {
                tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        assert!(mesh_self_intersections(&x, &tris).is_empty());
        // a second sheet placed exactly in the plane, overlapping: intersects
        let off = x.len() as u32;
        x.extend([v(2.5, 2.5, 0.0), v(3.5, 2.5, 0.0), v(2.5, 3.5, 0.0)]);
        tris.push([off, off + 1, off + 2]);
        let got = mesh_self_intersections(&x, &tris);
        assert!(!got.is_empty());
        assert!(got.iter().all(|&(_, j)| j as usize == tris.len() - 1));
        assert_eq!(got, brute_force(&x, &tris));
        // lifted by 1e-15: no intersection
        for p in &mut x[off as usize..] {
            p.z = 1e-15;
        }
        assert!(mesh_self_intersections(&x, &tris).is_empty());
    }
}

/// Polygon triangulation (`weft_geom::polygon`) against a brute-force check in
/// exact integer arithmetic: the triangles cover the polygon — their areas sum
/// to its area, none is inverted or of zero area, each lies inside the polygon
/// and no two overlap.
mod polygon {
    use super::{rnd, v};
    use rand::Rng;
    use weft_core::DVec3;
    use weft_geom::polygon::{triangulate, PolygonError};

    type P = [i64; 2];

    fn orient(a: P, b: P, c: P) -> i128 {
        let (a, b, c) = (a.map(i128::from), b.map(i128::from), c.map(i128::from));
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    }

    /// Twice the signed area of a polygon (counter-clockwise positive).
    fn twice_area(poly: &[P]) -> i128 {
        (0..poly.len())
            .map(|i| {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                i128::from(a[0]) * i128::from(b[1]) - i128::from(b[0]) * i128::from(a[1])
            })
            .sum()
    }

    /// The open segments `ab` and `cd` cross at a point inside both.
    fn cross_properly(a: P, b: P, c: P, d: P) -> bool {
        let s = |x: i128| x.signum();
        s(orient(a, b, c)) * s(orient(a, b, d)) < 0 && s(orient(c, d, a)) * s(orient(c, d, b)) < 0
    }

    /// `q` (coordinates times 3, for centroids) strictly inside `poly` (times 1),
    /// by the crossing number; `q` is never on the boundary here.
    fn inside3(poly: &[P], q: P) -> bool {
        let mut inside = false;
        for i in 0..poly.len() {
            let (a, b) = (
                poly[i].map(|x| 3 * x),
                poly[(i + 1) % poly.len()].map(|x| 3 * x),
            );
            if (a[1] > q[1]) != (b[1] > q[1]) {
                let o = orient(a, b, q);
                if (o > 0) == (b[1] > a[1]) {
                    inside = !inside;
                }
            }
        }
        inside
    }

    fn centroid3(t: [P; 3]) -> P {
        [t[0][0] + t[1][0] + t[2][0], t[0][1] + t[1][1] + t[2][1]]
    }

    /// Embeds integer 2D points exactly in a tilted plane of 3D space.
    fn embed(poly: &[P], origin: [i64; 3], u: [i64; 3], w: [i64; 3]) -> Vec<DVec3> {
        poly.iter()
            .map(|p| {
                let c = |k: usize| (origin[k] + p[0] * u[k] + p[1] * w[k]) as f64;
                v(c(0), c(1), c(2))
            })
            .collect()
    }

    fn assert_covers(poly: &[P], corners: &[DVec3], tris: &[[usize; 3]]) {
        let n = poly.len();
        assert_eq!(tris.len(), n - 2, "{poly:?}");
        let newell: DVec3 = (0..n).map(|i| corners[i].cross(corners[(i + 1) % n])).sum();
        let t2: Vec<[P; 3]> = tris.iter().map(|t| t.map(|i| poly[i])).collect();
        for (k, t) in tris.iter().enumerate() {
            assert!(t.iter().all(|&i| i < n) && t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
            assert!(
                orient(t2[k][0], t2[k][1], t2[k][2]) > 0,
                "triangle {t:?} is inverted or flat in {poly:?}"
            );
            let [a, b, c] = t.map(|i| corners[i]);
            assert!(
                (b - a).cross(c - a).dot(newell) > 0.0,
                "3D normal of {t:?} is inverted"
            );
            assert!(
                inside3(poly, centroid3(t2[k])),
                "triangle {t:?} is outside {poly:?}"
            );
            for e in 0..3 {
                let (p, q) = (t2[k][e], t2[k][(e + 1) % 3]);
                for i in 0..n {
                    assert!(
                        !cross_properly(p, q, poly[i], poly[(i + 1) % n]),
                        "an edge of {t:?} crosses the boundary of {poly:?}"
                    );
                }
            }
        }
        let sum: i128 = t2.iter().map(|t| orient(t[0], t[1], t[2])).sum();
        assert_eq!(sum, twice_area(poly), "the triangles' areas do not add up");
        // No two overlap: no proper edge crossing, neither holds the other's centroid.
        for i in 0..t2.len() {
            for j in i + 1..t2.len() {
                let in_tri = |t: [P; 3], q: P| {
                    let t = t.map(|p| p.map(|x| 3 * x));
                    (0..3).all(|e| orient(t[e], t[(e + 1) % 3], q) > 0)
                };
                assert!(!in_tri(t2[i], centroid3(t2[j])) && !in_tri(t2[j], centroid3(t2[i])));
                for e in 0..3 {
                    for f in 0..3 {
                        assert!(!cross_properly(
                            t2[i][e],
                            t2[i][(e + 1) % 3],
                            t2[j][f],
                            t2[j][(f + 1) % 3]
                        ));
                    }
                }
            }
        }
    }

    fn triangulate_2d(poly: &[P]) -> Result<(Vec<DVec3>, Vec<[usize; 3]>), PolygonError> {
        let corners = embed(poly, [7, -3, 11], [2, 1, -1], [-1, 3, 2]);
        triangulate(&corners).map(|t| (corners, t))
    }

    /// Star-shaped polygons with very uneven radii (deeply non-convex), with
    /// extra corners on some edges (zero turn), embedded in tilted planes.
    #[test]
    fn random_star_polygons_with_straight_corners_are_covered_exactly() {
        let mut rng = rnd::rng(41);
        let mut checked = 0;
        for case in 0..400 {
            let n = rng.gen_range(4..24);
            // Distinct sectors keep the polygon star-shaped about the origin
            // after rounding to even integers.
            let mut poly: Vec<P> = (0..n)
                .map(|k| {
                    let angle =
                        (k as f64 + rng.gen_range(0.1..0.9)) * std::f64::consts::TAU / n as f64;
                    let r = rng.gen_range(50.0..1000.0);
                    [
                        2 * (r * angle.cos() / 2.0).round() as i64,
                        2 * (r * angle.sin() / 2.0).round() as i64,
                    ]
                })
                .collect();
            poly.dedup();
            if twice_area(&poly) <= 0
                || (0..poly.len()).any(|i| orient([0, 0], poly[i], poly[(i + 1) % poly.len()]) <= 0)
            {
                continue; // rounding broke star-shapedness: not a valid case
            }
            // Midpoints (exact: even coordinates) on every third edge.
            let mut with_mid = Vec::new();
            for i in 0..poly.len() {
                with_mid.push(poly[i]);
                if (i + case) % 3 == 0 {
                    let b = poly[(i + 1) % poly.len()];
                    with_mid.push([(poly[i][0] + b[0]) / 2, (poly[i][1] + b[1]) / 2]);
                }
            }
            let (corners, tris) =
                triangulate_2d(&with_mid).unwrap_or_else(|e| panic!("{with_mid:?}: {e:?}"));
            assert_covers(&with_mid, &corners, &tris);
            checked += 1;
        }
        assert!(checked > 300, "only {checked} valid random polygons");
    }

    /// Shapes a fan from the first corner gets wrong: a comb (its first corner
    /// sees only part of it) and a square with several corners on each side.
    #[test]
    fn comb_and_subdivided_square() {
        let mut comb: Vec<P> = vec![[0, 0], [90, 0]];
        for k in (0..4).rev() {
            let x = 20 * k + 10;
            comb.extend([[x + 10, 60], [x + 5, 60], [x + 5, 10], [x, 10], [x, 60]]);
        }
        comb.extend([[0, 60]]);
        comb.dedup();
        let (c, t) = triangulate_2d(&comb).unwrap();
        assert_covers(&comb, &c, &t);
        let square: Vec<P> = vec![
            [0, 0],
            [2, 0],
            [4, 0],
            [6, 0],
            [6, 2],
            [6, 4],
            [6, 6],
            [4, 6],
            [2, 6],
            [0, 6],
            [0, 4],
            [0, 2],
        ];
        let (c, t) = triangulate_2d(&square).unwrap();
        assert_covers(&square, &c, &t);
        // An arrow whose first corner is reflex: the fan from it crosses outside.
        let arrow: Vec<P> = vec![[0, 0], [-4, -4], [8, 0], [-4, 4]];
        let (c, t) = triangulate_2d(&arrow).unwrap();
        assert_covers(&arrow, &c, &t);
    }

    #[test]
    fn a_warped_quad_keeps_its_orientation() {
        let q = [
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.1),
            v(1.0, 1.0, 0.0),
            v(0.0, 1.0, 0.1),
        ];
        let t = triangulate(&q).unwrap();
        assert_eq!(t.len(), 2);
        for tri in t {
            let [a, b, c] = tri.map(|i| q[i]);
            assert!((b - a).cross(c - a).z > 0.0);
        }
    }

    #[test]
    fn polygons_that_cannot_be_triangulated_are_refused_with_the_reason() {
        let e = |poly: &[P]| triangulate_2d(poly).map(|_| ()).unwrap_err();
        // A lopsided bow tie: edges 0–1 and 2–3 cross.
        assert_eq!(
            e(&[[0, 0], [4, 4], [4, 0], [0, 6]]),
            PolygonError::SelfIntersecting {
                edges: [[0, 1], [2, 3]]
            }
        );
        // A corner touching a non-adjacent edge.
        assert!(matches!(
            e(&[[0, 0], [6, 0], [6, 6], [3, 0], [0, 6]]),
            PolygonError::SelfIntersecting { .. }
        ));
        assert_eq!(e(&[[0, 0], [2, 0], [4, 0], [6, 0]]), PolygonError::ZeroArea);
        // Too many corners for the quadratic checks: refused before them.
        let circle: Vec<DVec3> = (0..1001)
            .map(|k| {
                let a = k as f64 / 1001.0 * std::f64::consts::TAU;
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        assert_eq!(
            triangulate(&circle),
            Err(PolygonError::TooManyCorners { corners: 1001 })
        );
        assert_eq!(triangulate(&circle[..1000]).map(|t| t.len()), Ok(998));
        // A symmetric bow tie: its two loops cancel.
        assert_eq!(e(&[[0, 0], [4, 4], [4, 0], [0, 4]]), PolygonError::ZeroArea);
        assert_eq!(
            e(&[[0, 0], [4, 0], [4, 0], [4, 4], [0, 4]]),
            PolygonError::CoincidentCorners { a: 1, b: 2 }
        );
        // A spike: the boundary goes out to (8, 2) and back along the same line.
        assert_eq!(
            e(&[[0, 0], [4, 0], [4, 2], [8, 2], [6, 2], [6, 4], [0, 4]]),
            PolygonError::FoldsBack { corner: 3 }
        );
        let named = PolygonError::SelfIntersecting {
            edges: [[0, 1], [2, 3]],
        }
        .describe(&|k| format!("v {}", k + 10));
        assert!(named.contains("v 10–v 11 and v 12–v 13"), "{named}");
    }

    /// Large random polygons stay fast (the ear cache) and exact.
    #[test]
    fn a_thousand_corner_star() {
        let mut rng = rnd::rng(7);
        let n = 1000;
        let poly: Vec<P> = (0..n)
            .map(|k| {
                let angle = (k as f64 + 0.5) * std::f64::consts::TAU / n as f64;
                let r = rng.gen_range(4.0e5..1.0e6);
                [
                    (r * angle.cos()).round() as i64,
                    (r * angle.sin()).round() as i64,
                ]
            })
            .collect();
        let (c, t) = triangulate_2d(&poly).unwrap();
        assert_eq!(t.len(), n - 2);
        let sum: i128 = t
            .iter()
            .map(|t| orient(poly[t[0]], poly[t[1]], poly[t[2]]))
            .sum();
        assert_eq!(sum, twice_area(&poly));
        assert!(t.iter().all(|t| {
            let [a, b, cc] = t.map(|i| c[i]);
            (b - a).cross(cc - a).length() > 0.0
        }));
    }
}
