//! The proximity predicate on long trajectories (deep contact: hundreds to
//! thousands of breakpoints per vertex), with and without block bounds
//! (`weft_geom::ccd::bounds`), against the exact-rational oracle. A false
//! negative fails; false positives are counted and printed.
//!
//! * random long polylines hovering near contact (10^3 to 10^4 breakpoints
//!   per stencil), `eta` set around the exact sampled minimum distance;
//! * a near approach hidden inside one segment of a long polyline (the
//!   closest instant is no breakpoint, and the rest of the polyline is far);
//! * sub-ulp sliding: a primitive slides along a long random path in a
//!   plane `h` above the other, `h` far below the rounding of the in-plane
//!   coordinates.

use num_rational::BigRational;
use num_traits::ToPrimitive;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use weft_core::{DVec3, StencilKind};
use weft_geom::ccd::bounds::TrajectoryBounds;
use weft_geom::ccd::{oracle, proximity, CcdStats, Trajectory};

const VF: StencilKind = StencilKind::VertexFace;
const EE: StencilKind = StencilKind::EdgeEdge;

/// One stencil's polylines.
struct Case {
    kind: StencilKind,
    times: [Vec<f64>; 4],
    pts: [Vec<DVec3>; 4],
}

impl Case {
    fn bounds(&self) -> [TrajectoryBounds; 4] {
        std::array::from_fn(|i| TrajectoryBounds::from_points(&self.times[i], &self.pts[i]))
    }

    /// The trajectories, with the block bounds `b` or without.
    fn traj<'a>(&'a self, b: Option<&'a [TrajectoryBounds; 4]>) -> [Trajectory<'a>; 4] {
        std::array::from_fn(|i| Trajectory {
            times: &self.times[i],
            points: &self.pts[i],
            bounds: b.map(|b| &b[i]),
        })
    }

    /// Exact squared distance at the oracle's sample times (every breakpoint
    /// and `samples + 1` uniform times), smallest first.
    fn sampled_min_sq(&self, samples: u32) -> BigRational {
        let traj = self.traj(None);
        oracle::sample_times(&traj, samples)
            .expect("finite")
            .iter()
            .map(|t| oracle::distance_sq_at(self.kind, &traj, t).expect("finite"))
            .min()
            .expect("samples")
    }

    /// The predicate with and without bounds: (bounded, flat).
    fn answer(&self, b: &[TrajectoryBounds; 4], eta: f64, stats: &mut [CcdStats; 2]) -> [bool; 2] {
        [
            proximity(self.kind, &self.traj(Some(b)), eta, &mut stats[0]),
            proximity(self.kind, &self.traj(None), eta, &mut stats[1]),
        ]
    }
}

fn q(x: f64) -> BigRational {
    oracle::rational(x).expect("finite")
}

/// A dyadic grid of `2^-bits`: coordinates with few bits keep the exact
/// oracle fast (the predicate still rounds at every interpolated time).
fn grid(v: DVec3, bits: i32) -> DVec3 {
    let s = 2f64.powi(bits);
    (v * s).round() / s
}

/// Sorted distinct breakpoint times: 0, the end, and `n` random ticks.
fn random_times(rng: &mut ChaCha8Rng, n: usize, end: u32) -> Vec<f64> {
    let mut ts: Vec<f64> = (0..n).map(|_| rng.gen_range(1..end) as f64).collect();
    ts.extend([0.0, end as f64]);
    ts.sort_by(|a, b| a.total_cmp(b));
    ts.dedup();
    ts
}

/// Deep contact: the first primitive hovers about `gap` above the second
/// (VF: a vertex over a triangle; EE: crossing edges) and every vertex walks
/// randomly around a common slow drift, with its own breakpoints (about
/// `per_vertex` each, some on a shared lattice as kicks of one layer are).
fn hovering_case(rng: &mut ChaCha8Rng, kind: StencilKind, per_vertex: usize) -> Case {
    let end = 1u32 << 20;
    let gap = rng.gen_range(1e-3..2e-2);
    let base: [DVec3; 4] = match kind {
        VF => [
            DVec3::new(0.25, 0.25, gap),
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        EE => [
            DVec3::new(-0.5, 0.1, gap),
            DVec3::new(0.5, -0.1, gap),
            DVec3::new(0.1, -0.5, 0.0),
            DVec3::new(-0.1, 0.5, 0.0),
        ],
    };
    let drift = DVec3::new(rng.gen_range(-0.2..0.2), rng.gen_range(-0.2..0.2), 0.0);
    let shared = random_times(rng, per_vertex / 2, end);
    let step = gap * rng.gen_range(0.02..0.3);
    let mut times: [Vec<f64>; 4] = Default::default();
    let mut pts: [Vec<DVec3>; 4] = Default::default();
    for i in 0..4 {
        let mut ts = random_times(rng, per_vertex / 2, end);
        ts.extend_from_slice(&shared);
        ts.sort_by(|a, b| a.total_cmp(b));
        ts.dedup();
        let mut walk = DVec3::ZERO;
        pts[i] = ts
            .iter()
            .map(|&t| {
                walk += DVec3::new(
                    rng.gen_range(-step..step),
                    rng.gen_range(-step..step),
                    rng.gen_range(-step..step) * 0.3,
                );
                // pulled back towards the base: the walk stays near contact
                walk *= 0.97;
                grid(base[i] + drift * (t / end as f64) + walk, 22)
            })
            .collect();
        times[i] = ts;
    }
    Case { kind, times, pts }
}

/// Checks `cases` on the available threads; returns (oracle contacts, clear
/// queries, clear queries certified with bounds, without) and the counters
/// of the bounded and the flat predicate.
fn check_around_minimum(cases: &[Case]) -> ([u64; 4], [CcdStats; 2]) {
    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(8);
    let chunk = cases.len().div_ceil(threads);
    let parts: Vec<([u64; 4], [CcdStats; 2])> = std::thread::scope(|scope| {
        let handles: Vec<_> = (cases.chunks(chunk).enumerate())
            .map(|(k, part)| {
                scope.spawn(move || {
                    let mut counts = [0u64; 4];
                    let mut stats = [CcdStats::default(); 2];
                    for (j, c) in part.iter().enumerate() {
                        let case = k * chunk + j;
                        let b = c.bounds();
                        let d2min = c.sampled_min_sq(64);
                        let dmin = d2min.to_f64().expect("finite").sqrt();
                        for factor in [0.5, 0.9, 0.999, 1.0 + 1e-12, 1.001, 1.5] {
                            let eta = dmin * factor;
                            let e = q(eta);
                            let truth = d2min <= &e * &e;
                            let [bounded, flat] = c.answer(&b, eta, &mut stats);
                            if truth {
                                counts[0] += 1;
                                assert!(
                                    bounded && flat,
                                    "case {case}: oracle contact at eta = {eta} missed \
                                     (bounded {bounded}, flat {flat})"
                                );
                            } else if factor < 0.95 {
                                counts[1] += 1;
                                counts[2] += u64::from(!bounded);
                                counts[3] += u64::from(!flat);
                            }
                        }
                    }
                    (counts, stats)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("worker"))
            .collect()
    });
    let mut counts = [0u64; 4];
    let mut stats = [CcdStats::default(); 2];
    for (c, s) in parts {
        for k in 0..4 {
            counts[k] += c[k];
        }
        stats[0].merge(&s[0]);
        stats[1].merge(&s[1]);
    }
    (counts, stats)
}

#[test]
fn long_random_polylines_never_miss_an_oracle_contact() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x10e6_0001);
    // 10^3 to 10^4 breakpoints per stencil.
    let mut cases: Vec<Case> = (0..12)
        .map(|k| {
            let kind = if k % 2 == 0 { VF } else { EE };
            let n = rng.gen_range(300..700);
            hovering_case(&mut rng, kind, n)
        })
        .collect();
    cases.push(hovering_case(&mut rng, VF, 2500));
    let per_stencil: Vec<usize> = (cases.iter())
        .map(|c| c.times.iter().map(Vec::len).sum())
        .collect();
    assert!(per_stencil.iter().all(|&n| n >= 1000));
    assert!(per_stencil.iter().any(|&n| n >= 10_000));
    let ([contacts, clear, bounded_certified, flat_certified], stats) =
        check_around_minimum(&cases);
    println!(
        "{contacts} oracle contacts all reported; below 0.95 dmin certified: bounded \
         {bounded_certified} / {clear}, flat {flat_certified} / {clear}; block-certified \
         intervals {} of {}",
        stats[0].block_certified, stats[0].certified_intervals
    );
    assert!(contacts >= cases.len() as u64);
    // The bounds must make the certificate cheaper, not weaker: at half and
    // 0.9 times the minimum distance nearly every query is certified.
    assert!(
        bounded_certified * 10 >= clear * 9,
        "bounded predicate too weak"
    );
    assert!(stats[0].block_certified > 0);
}

/// An edge slides across another inside one segment of a long polyline: the
/// closest approach (distance `g`, the height between the edges) lies
/// strictly inside that segment; before and after, the edge jitters far
/// away with hundreds of breakpoints.
/// Returns the case and the segment's start time.
fn hidden_segment_case(rng: &mut ChaCha8Rng, g: f64, per_vertex: usize) -> (Case, f64) {
    let end = 1u32 << 20;
    let mut times: [Vec<f64>; 4] = Default::default();
    let mut pts: [Vec<DVec3>; 4] = Default::default();
    // The segment [ts, te] where edge A (along y, at height g) crosses edge B
    // (along x, |x| <= 1): from x = -2 to x = +2.
    let ts = rng.gen_range(1..end - 2) as f64;
    let te = ts + 1.0;
    for i in 0..2 {
        let mut t = random_times(rng, per_vertex, end);
        t.retain(|&s| s != ts && s != te);
        t.extend([ts, te]);
        t.sort_by(|a, b| a.total_cmp(b));
        let y = if i == 0 { -0.5 } else { 0.5 };
        pts[i] = t
            .iter()
            .map(|&s| {
                let side = if s <= ts { -2.0 } else { 2.0 };
                let jitter = if s == ts || s == te {
                    DVec3::ZERO
                } else {
                    DVec3::new(rng.gen_range(-0.5..0.5), rng.gen_range(-0.2..0.2), 0.0)
                };
                // x beyond the crossing stays |x| >= 1.5: far from edge B
                grid(DVec3::new(side, y, g) + jitter, 40)
            })
            .collect();
        times[i] = t;
    }
    for (i, x) in [(2, -1.0), (3, 1.0)] {
        times[i] = random_times(rng, per_vertex, end);
        pts[i] = times[i].iter().map(|_| DVec3::new(x, 0.0, 0.0)).collect();
    }
    (
        Case {
            kind: EE,
            times,
            pts,
        },
        ts,
    )
}

#[test]
fn a_near_approach_hidden_in_one_segment_of_a_long_polyline_is_reported() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x10e6_0002);
    let (mut clear, mut certified) = (0, [0, 0]);
    let mut stats = [CcdStats::default(); 2];
    for case in 0..40 {
        let g = 2f64.powi(-rng.gen_range(4..40));
        let n = rng.gen_range(300..2500);
        let (c, ts) = hidden_segment_case(&mut rng, g, n);
        let b = c.bounds();
        // The exact distance is g while |x| <= 1 (inside the segment) and
        // larger everywhere else: touching at eta = g.
        let [bounded, flat] = c.answer(&b, g, &mut stats);
        assert!(
            bounded && flat,
            "case {case}: hidden approach at {g} missed"
        );
        // The oracle agrees at the segment's middle (the edges cross there).
        let at = q(ts) + q(0.5);
        let d2 = oracle::distance_sq_at(EE, &c.traj(None), &at).expect("finite");
        assert_eq!(
            d2,
            q(g) * q(g),
            "case {case}: the edges cross at distance g"
        );
        // Just below the gap nothing touches.
        clear += 1;
        let below = c.answer(&b, g * (1.0 - 2f64.powi(-20)), &mut stats);
        for k in 0..2 {
            certified[k] += u32::from(!below[k]);
        }
    }
    println!(
        "hidden approaches all reported; just below the gap certified: bounded {} / {clear}, \
         flat {} / {clear}",
        certified[0], certified[1]
    );
    assert!(certified[0] * 10 >= clear * 9, "bounded predicate too weak");
}

#[test]
fn sub_ulp_sliding_along_a_long_polyline_is_never_missed() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x10e6_0003);
    let end = 1u32 << 20;
    let (mut contacts, mut clear, mut certified) = (0, 0, 0);
    let mut stats = [CcdStats::default(); 2];
    for case in 0..24 {
        let kind = if case % 2 == 0 { VF } else { EE };
        let c = rng.gen_range(-1024..1024) as f64 * 2f64.powi(-46);
        let h = 2f64.powi(-rng.gen_range(45..=60));
        let z_top = c + h;
        if q(z_top) != q(c) + q(h) {
            continue;
        }
        let n_first = if kind == VF { 1 } else { 2 };
        let mut times: [Vec<f64>; 4] = Default::default();
        let mut pts: [Vec<DVec3>; 4] = Default::default();
        for i in 0..4 {
            let n = rng.gen_range(250..500);
            times[i] = random_times(&mut rng, n, end);
            let z = if i < n_first { z_top } else { c };
            let mut p = DVec3::new(rng.gen_range(-0.5..0.5), rng.gen_range(-0.5..0.5), z);
            pts[i] = times[i]
                .iter()
                .map(|_| {
                    p += DVec3::new(rng.gen_range(-0.01..0.01), rng.gen_range(-0.01..0.01), 0.0);
                    let g = grid(p, 24);
                    DVec3::new(g.x, g.y, z)
                })
                .collect();
        }
        let case_ = Case { kind, times, pts };
        let b = case_.bounds();
        let e2 = q(h) * q(h);
        if case_.sampled_min_sq(32) <= e2 {
            contacts += 1;
            let [bounded, flat] = case_.answer(&b, h, &mut stats);
            assert!(
                bounded && flat,
                "case {case}: sub-ulp contact at eta = {h} missed"
            );
        }
        clear += 1;
        let below = case_.answer(&b, h * (1.0 - 2f64.powi(-20)), &mut stats);
        certified += u32::from(!below[0]);
    }
    println!(
        "sub-ulp sliding on long polylines: {contacts} oracle contacts reported; {certified} / \
         {clear} clear cases certified with bounds"
    );
    assert!(contacts > 3 && clear > 15);
}
