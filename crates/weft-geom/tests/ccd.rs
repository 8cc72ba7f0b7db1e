//! Tests of the continuous proximity predicate (`weft_geom::ccd`): the public
//! benchmarks (zero false negatives), positive separations, large
//! coordinates, planted near-misses in exact arithmetic, random
//! piecewise-linear trajectories against the exact sampling oracle, degenerate
//! input, and the benchmark reader's error reporting.
//!
//! Data: `../shared/data/ccd` relative to the project root; a missing folder
//! fails the test with a message saying where it was looked for.

use std::path::{Path, PathBuf};

use num_rational::BigRational;
use num_traits::ToPrimitive;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use weft_core::{DVec3, StencilKind};
use weft_geom::ccd::benchmark::{
    exact_f64, load_benchmark, run_benchmark_repeated, BenchFolder, CcdDataError, CcdQuery,
};
use weft_geom::ccd::{linear_proximity, oracle, proximity, CcdStats, Trajectory};

const VF: StencilKind = StencilKind::VertexFace;
const EE: StencilKind = StencilKind::EdgeEdge;

// ---------------------------------------------------------------- helpers

fn data_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ccd")
}

/// Loads one dataset folder; panics (fails the test) with a clear message
/// when it is missing or unreadable.
fn load_dataset(name: &str) -> Vec<BenchFolder> {
    let dir = data_root().join(name);
    assert!(
        dir.is_dir(),
        "CCD benchmark data missing: expected the folder {} (the shared data \
         checkout `../shared/data/ccd` next to the project root)",
        dir.display()
    );
    load_benchmark(&dir).unwrap_or_else(|e| panic!("cannot load {}: {e}", dir.display()))
}

fn all_queries() -> Vec<CcdQuery> {
    let mut v = Vec::new();
    for name in ["wang2021", "belgrod2023"] {
        for f in load_dataset(name) {
            v.extend(f.queries);
        }
    }
    v
}

fn lin(q: &CcdQuery, eta: f64) -> bool {
    linear_proximity(q.kind, &q.start, &q.end, eta, &mut CcdStats::default())
}

/// Diagonal of the bounding box of the query's eight points.
fn scale(q: &CcdQuery) -> f64 {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for p in q.start.iter().chain(q.end.iter()) {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    (hi - lo).length()
}

fn q(x: f64) -> BigRational {
    oracle::rational(x).expect("finite")
}

/// `a + b`, asserting that the floating sum is exact.
fn add_exact(a: f64, b: f64) -> f64 {
    let s = a + b;
    assert_eq!(q(s), q(a) + q(b), "{a} + {b} is not exact");
    s
}

fn add3(a: DVec3, b: DVec3) -> DVec3 {
    DVec3::new(
        add_exact(a.x, b.x),
        add_exact(a.y, b.y),
        add_exact(a.z, b.z),
    )
}

/// `a + b` when the floating sum is exact in every coordinate.
fn try_add3(a: DVec3, b: DVec3) -> Option<DVec3> {
    let s = a + b;
    (0..3).all(|c| q(s[c]) == q(a[c]) + q(b[c])).then_some(s)
}

// ---------------------------------------------------------------- 1. benchmarks

#[test]
fn benchmarks_have_zero_false_negatives() {
    let expected = [("wang2021", 1500, 1324), ("belgrod2023", 893, 4633)];
    for (name, vf, ee) in expected {
        let folders = load_dataset(name);
        let t = std::time::Instant::now();
        let report = run_benchmark_repeated(&folders, 0.0, 3);
        println!(
            "== {name} (eta = 0), {:.2} s\n{}",
            t.elapsed().as_secs_f64(),
            report.to_table()
        );
        assert_eq!(
            report.vertex_face.queries, vf,
            "{name}: vertex-face query count"
        );
        assert_eq!(
            report.edge_edge.queries, ee,
            "{name}: edge-edge query count"
        );
        for f in &report.folders {
            assert_eq!(
                f.summary.false_negatives, 0,
                "false negatives in {} ({} queries)",
                f.path, f.summary.queries
            );
        }
        assert_eq!(report.total.false_negatives, 0);
    }
}

// ---------------------------------------------------------------- 2. positive eta

#[test]
fn true_positives_are_reported_at_positive_eta() {
    let queries = all_queries();
    let mut checked = 0;
    for (i, qq) in queries.iter().enumerate().filter(|(_, qq)| qq.truth) {
        let s = scale(qq);
        for rel in [1e-9, 1e-5] {
            assert!(
                lin(qq, rel * s),
                "query {i} (truth yes) missed at eta = {rel} x {s}"
            );
            checked += 1;
        }
    }
    println!("{checked} (query, eta) pairs reported");
    assert!(checked > 1000);
}

// ---------------------------------------------------------------- 3. large coordinates

#[test]
fn true_positives_survive_large_coordinates() {
    let queries = all_queries();
    // Scaling by 1024 is exact (no overflow or underflow here) and keeps the
    // truth; translating by 1024 is exact only for some queries: those are
    // used, after checking every coordinate in exact arithmetic.
    let mut scaled = 0;
    let mut translated = 0;
    for (i, qq) in queries.iter().enumerate().filter(|(_, qq)| qq.truth) {
        let mut s = *qq;
        for p in s.start.iter_mut().chain(s.end.iter_mut()) {
            *p *= 1024.0;
        }
        assert!(lin(&s, 0.0), "query {i} scaled by 1024 missed");
        scaled += 1;
        let off = DVec3::new(1024.0, -1024.0, 1024.0);
        let exact = qq
            .start
            .iter()
            .chain(qq.end.iter())
            .all(|p| (0..3).all(|c| q(p[c] + off[c]) == q(p[c]) + q(off[c])));
        if exact {
            let mut t = *qq;
            for p in t.start.iter_mut().chain(t.end.iter_mut()) {
                *p += off;
            }
            assert!(lin(&t, 0.0), "query {i} translated by 1024 missed");
            translated += 1;
        }
    }
    println!("{scaled} true positives scaled, {translated} translated exactly");
    assert!(scaled > 1000);
    assert!(
        translated > 100,
        "too few exactly translatable queries ({translated})"
    );
}

#[test]
fn planted_near_misses_far_from_the_origin_are_reported() {
    // The planted configurations of test 4 at distance eta (1 - 2^-30),
    // translated to coordinates near 10^3 (exact: every coordinate is a
    // multiple of 2^-42, checked by `add3`).
    let off = DVec3::new(1024.0, 1536.0, -1280.0);
    let (eta, eta5) = (2f64.powi(-10), 5.0 * 2f64.powi(-12));
    let f = 1.0 - 2f64.powi(-30);
    for (idx, (kind, x)) in static_configs(eta * f, eta5 * f).into_iter().enumerate() {
        let e = if (2..=4).contains(&idx) { eta5 } else { eta };
        let x = x.map(|p| add3(p, off));
        assert!(
            exact_static_distance(kind, &x) < q(e) * q(e),
            "config {idx}"
        );
        assert!(
            linear_proximity(kind, &x, &x, e, &mut CcdStats::default()),
            "translated config {idx} missed"
        );
        for (v, (times, pts, t_star)) in moving_variants(&x).into_iter().enumerate() {
            let traj = traj_of(&times, &pts);
            assert!(exact_distance_at(kind, &traj, &t_star) < q(e) * q(e));
            assert!(
                proximity(kind, &traj, e, &mut CcdStats::default()),
                "translated moving config {idx} variant {v} missed"
            );
        }
    }
}

// ---------------------------------------------------------------- 4. planted near-misses

/// Static planted configurations at distance `h` (VF) / `h` (EE), built from
/// dyadic coordinates: `k = h5 / 5` must be exact for the 3-4-5 cases.
fn static_configs(h: f64, h5: f64) -> Vec<(StencilKind, [DVec3; 4])> {
    let k = h5 / 5.0;
    let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
    vec![
        // VF, face interior.
        (VF, [DVec3::new(0.25, 0.25, h), a, b, c]),
        // VF, beside edge ab, in the plane and out of it.
        (VF, [DVec3::new(0.5, -h, 0.0), a, b, c]),
        (VF, [DVec3::new(0.5, -3.0 * k, 4.0 * k), a, b, c]),
        // VF, beside corner a.
        (VF, [DVec3::new(-3.0 * k, -4.0 * k, 0.0), a, b, c]),
        (VF, [DVec3::new(-3.0 * k, 0.0, -4.0 * k), a, b, c]),
        // EE, crossing.
        (
            EE,
            [
                DVec3::new(-1.0, 0.25, h),
                DVec3::new(1.0, 0.25, h),
                DVec3::new(0.5, -1.0, 0.0),
                DVec3::new(0.5, 1.0, 0.0),
            ],
        ),
        // EE, nearly parallel (projections cross at x = 1/5).
        (
            EE,
            [
                DVec3::new(0.0, 0.0, h),
                DVec3::new(1.0, 2f64.powi(-20), h),
                DVec3::new(0.0, 2f64.powi(-22), 0.0),
                DVec3::new(1.0, 0.0, 0.0),
            ],
        ),
        // EE, an endpoint beside the other edge's interior.
        (
            EE,
            [
                DVec3::new(-1.0, 0.0, 0.0),
                DVec3::new(-h, 0.0, 0.0),
                DVec3::new(0.0, -1.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
            ],
        ),
    ]
}

/// Exact squared distance of a static configuration.
fn exact_static_distance(kind: StencilKind, x: &[DVec3; 4]) -> BigRational {
    let qx: [oracle::QVec; 4] = std::array::from_fn(|i| oracle::qvec(x[i]).expect("finite"));
    oracle::stencil_distance_sq(kind, &qx)
}

fn exact_distance_at(
    kind: StencilKind,
    traj: &[Trajectory<'_>; 4],
    t: &BigRational,
) -> BigRational {
    oracle::distance_sq_at(kind, traj, t).expect("finite")
}

/// Moving versions of a static configuration `x` (planted at t = 1/3, or at
/// the breakpoint t = 0.375): all run through `x` exactly at that time.
/// Returns (times, points) per vertex and the planted time; variants whose
/// coordinates would not be exact are left out.
/// Per-vertex breakpoint times and positions, and the planted (exact) time.
type Moving = ([Vec<f64>; 4], [Vec<DVec3>; 4], BigRational);

fn moving_variants(x: &[DVec3; 4]) -> Vec<Moving> {
    let third = BigRational::new(1.into(), 3.into());
    let mut out = Vec::new();
    let shift = |v: DVec3| -> Option<[DVec3; 4]> {
        let r = x.map(|p| try_add3(p, v));
        r.iter()
            .all(Option::is_some)
            .then(|| r.map(|p| p.unwrap_or_default()))
    };
    // (a) common translation: x(t) = x + (t - 1/3) 3w, w dyadic.
    let w = DVec3::new(0.125, -0.3125, 0.21875);
    if let (Some(start), Some(end), Some(mid)) = (shift(-w), shift(2.0 * w), shift(0.5 * w)) {
        out.push((
            std::array::from_fn(|_| vec![0.0, 1.0]),
            std::array::from_fn(|i| vec![start[i], end[i]]),
            third.clone(),
        ));
        // (b) the same motion with a breakpoint at t = 1/2 (x(1/2) = x + w/2).
        out.push((
            std::array::from_fn(|_| vec![0.0, 0.5, 1.0]),
            std::array::from_fn(|i| vec![start[i], mid[i], end[i]]),
            third,
        ));
    }
    // (c) a bounce: every vertex drifts with a common velocity and has a
    // breakpoint at t = 0.375 exactly at its planted position; vertex 0 also
    // comes down before and goes up after.
    let up = DVec3::new(0.0, 0.0, 0.5);
    let drift = DVec3::new(0.0625, 0.03125, 0.0);
    if let (Some(before), Some(after)) = (shift(-drift * 0.375), shift(drift * 0.625)) {
        let lift = |i: usize, p: DVec3| if i == 0 { try_add3(p, up) } else { Some(p) };
        let b0 = lift(0, before[0]);
        let a0 = lift(0, after[0]);
        if let (Some(b0), Some(a0)) = (b0, a0) {
            let pts: [Vec<DVec3>; 4] = std::array::from_fn(|i| {
                if i == 0 {
                    vec![b0, x[0], a0]
                } else {
                    vec![before[i], x[i], after[i]]
                }
            });
            out.push((
                std::array::from_fn(|_| vec![0.0, 0.375, 1.0]),
                pts,
                BigRational::new(3.into(), 8.into()),
            ));
        }
    }
    out
}

fn traj_of<'a>(times: &'a [Vec<f64>; 4], pts: &'a [Vec<DVec3>; 4]) -> [Trajectory<'a>; 4] {
    std::array::from_fn(|i| Trajectory::new(&times[i], &pts[i]))
}

#[test]
fn planted_near_misses_are_reported() {
    // eta and h = eta (1 - 2^-40); the 3-4-5 configurations use eta5 = 5 * 2^-12.
    let mut n = 0;
    for (eta, eta5) in [
        (2f64.powi(-10), 5.0 * 2f64.powi(-12)),
        (2f64.powi(-30), 5.0 * 2f64.powi(-32)),
    ] {
        let h = eta * (1.0 - 2f64.powi(-40));
        let h5 = eta5 * (1.0 - 2f64.powi(-40));
        for (idx, (kind, x)) in static_configs(h, h5).into_iter().enumerate() {
            let e = if (2..=4).contains(&idx) { eta5 } else { eta };
            let e2 = q(e) * q(e);
            let d2 = exact_static_distance(kind, &x);
            assert!(d2 < e2, "config {idx}: planted distance not below eta");
            let lo = q(e * (1.0 - 2f64.powi(-39)));
            assert!(d2 >= &lo * &lo, "config {idx}: planted distance too small");
            assert!(
                linear_proximity(kind, &x, &x, e, &mut CcdStats::default()),
                "static config {idx} (eta {e}) missed"
            );
            n += 1;
            for (v, (times, pts, t_star)) in moving_variants(&x).into_iter().enumerate() {
                let traj = traj_of(&times, &pts);
                let d2 = exact_distance_at(kind, &traj, &t_star);
                assert!(
                    d2 < e2,
                    "config {idx} variant {v}: planted distance not below eta"
                );
                assert!(
                    proximity(kind, &traj, e, &mut CcdStats::default()),
                    "moving config {idx} variant {v} (eta {e}) missed"
                );
                n += 1;
            }
        }
    }
    println!("{n} planted near-misses reported");
}

#[test]
fn planted_clear_misses_are_mostly_certified() {
    let eta = 2f64.powi(-10);
    let eta5 = 5.0 * 2f64.powi(-12);
    let (mut total, mut certified) = (0, 0);
    for (idx, (kind, x)) in static_configs(2.0 * eta, 2.0 * eta5)
        .into_iter()
        .enumerate()
    {
        let e = if (2..=4).contains(&idx) { eta5 } else { eta };
        total += 1;
        if !linear_proximity(kind, &x, &x, e, &mut CcdStats::default()) {
            certified += 1;
        }
        for (times, pts, t_star) in moving_variants(&x) {
            let traj = traj_of(&times, &pts);
            let _ = t_star;
            // The exact minimum over the samples is at least 2 eta only for
            // motions that keep the distance; check with the oracle first.
            let close = oracle::sampled_proximity(kind, &traj, 2.0 * e * (1.0 - 1e-9), 256)
                .expect("finite");
            if close {
                continue;
            }
            total += 1;
            if !proximity(kind, &traj, e, &mut CcdStats::default()) {
                certified += 1;
            }
        }
    }
    println!("clear misses certified: {certified} / {total}");
    assert!(total >= 16);
    assert!(
        certified * 10 >= total * 9,
        "only {certified} of {total} certified"
    );
}

// ---------------------------------------------------------------- 5. random trajectories

struct RandomCase {
    kind: StencilKind,
    times: [Vec<f64>; 4],
    pts: [Vec<DVec3>; 4],
}

fn random_case(rng: &mut ChaCha8Rng) -> RandomCase {
    let kind = if rng.gen_bool(0.5) { VF } else { EE };
    let t_end = 1.0;
    let base: [DVec3; 4] = std::array::from_fn(|i| {
        let side = if i < (if kind == VF { 1 } else { 2 }) {
            0.3
        } else {
            -0.3
        };
        DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-0.5..0.5) + side,
        )
    });
    let vel: [DVec3; 4] = std::array::from_fn(|_| {
        DVec3::new(
            rng.gen_range(-0.5..0.5),
            rng.gen_range(-0.5..0.5),
            rng.gen_range(-0.8..0.8),
        )
    });
    let mut times: [Vec<f64>; 4] = Default::default();
    let mut pts: [Vec<DVec3>; 4] = Default::default();
    for i in 0..4 {
        let nb = rng.gen_range(0..5);
        let mut ts: Vec<f64> = (0..nb)
            .map(|_| rng.gen_range(1..1024) as f64 / 1024.0)
            .collect();
        ts.push(0.0);
        ts.push(t_end);
        ts.sort_by(|a, b| a.total_cmp(b));
        ts.dedup();
        let jitter = rng.gen_range(0.0..0.2);
        // Coordinates on a 2^-24 grid keep the exact oracle fast; the
        // predicate still rounds at every interpolated time.
        let grid = |v: DVec3| (v * 16_777_216.0).round() / 16_777_216.0;
        pts[i] = ts
            .iter()
            .map(|&t| {
                grid(
                    base[i]
                        + vel[i] * t
                        + DVec3::new(
                            rng.gen_range(-jitter..=jitter),
                            rng.gen_range(-jitter..=jitter),
                            rng.gen_range(-jitter..=jitter),
                        ),
                )
            })
            .collect();
        times[i] = ts;
    }
    RandomCase { kind, times, pts }
}

/// Checks one random case against the oracle; returns (oracle contacts,
/// reported at eta = dmin / 2) and adds the predicate's counters to `stats`.
fn check_random_case(case: usize, c: &RandomCase, stats: &mut CcdStats) -> (u32, bool) {
    let traj = traj_of(&c.times, &c.pts);
    // Exact minimum of d^2 over the samples.
    let d2min = oracle::sample_times(&traj, 16)
        .expect("finite")
        .iter()
        .map(|t| exact_distance_at(c.kind, &traj, t))
        .min()
        .expect("samples");
    let dmin = d2min.to_f64().expect("finite").sqrt();
    let mut contacts = 0;
    let mut half_reported = false;
    // Around the sampled minimum (both sides), plus 0.
    for factor in [0.0, 0.5, 0.999, 1.0 + 1e-12, 1.001, 1.5] {
        let eta = dmin * factor;
        let e = q(eta);
        let truth = d2min <= &e * &e;
        let yes = proximity(c.kind, &traj, eta, stats);
        if truth {
            contacts += 1;
            assert!(
                yes,
                "case {case}: oracle contact at eta = {eta} missed: {:?} {:?}",
                c.times, c.pts
            );
        }
        if factor == 0.5 {
            half_reported = yes;
        }
    }
    (contacts, half_reported)
}

#[test]
fn random_trajectories_never_miss_an_oracle_contact() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_cc0d);
    let cases: Vec<RandomCase> = (0..2000).map(|_| random_case(&mut rng)).collect();
    // The exact oracle is slow: spread the cases over threads (each case is
    // independent, so the outcome does not depend on the split).
    let threads = std::thread::available_parallelism()
        .map_or(4, |n| n.get())
        .min(16);
    let chunk = cases.len().div_ceil(threads);
    let results: Vec<(u32, u32, CcdStats)> = std::thread::scope(|scope| {
        let handles: Vec<_> = cases
            .chunks(chunk)
            .enumerate()
            .map(|(k, part)| {
                scope.spawn(move || {
                    let mut stats = CcdStats::default();
                    let (mut contacts, mut half) = (0, 0);
                    for (j, c) in part.iter().enumerate() {
                        let (n, h) = check_random_case(k * chunk + j, c, &mut stats);
                        contacts += n;
                        half += h as u32;
                    }
                    (contacts, half, stats)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("worker panicked"))
            .collect()
    });
    let mut stats = CcdStats::default();
    let (mut oracle_yes, mut below_half_reported) = (0, 0);
    for (n, h, s) in &results {
        oracle_yes += n;
        below_half_reported += h;
        stats.merge(s);
    }
    let below_half = cases.len() as u32;
    println!(
        "{oracle_yes} oracle contacts all reported; at eta = dmin/2: {below_half_reported} / \
         {below_half} reported; {stats:?}"
    );
    assert!(oracle_yes as usize > cases.len());
    // At half the sampled minimum distance, true contacts are rare (only
    // between samples); a predicate reporting many of them is useless.
    assert!(
        below_half_reported * 10 < below_half,
        "false-positive rate too high"
    );
}

/// Sub-ulp near contacts: a vertex (VF) or an edge (EE) slides over the other
/// primitive in the parallel plane `z = c + h`, `h` between `2^-60` and
/// `2^-45` (far below `u |x|` for in-plane coordinates near 1), with random in-plane
/// paths and breakpoints. With `eta = h` the exact distance is `eta` whenever
/// the projections overlap, so every sampled overlap is an oracle contact;
/// with `eta = h (1 - 2^-20)` there is none, which measures how much of the
/// sub-ulp regime the certificate resolves.
#[test]
fn sub_ulp_sliding_contacts_are_never_missed() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x0005_11de);
    let (mut contacts, mut clear, mut clear_certified) = (0, 0, 0);
    for case in 0..600 {
        let kind = if case % 2 == 0 { VF } else { EE };
        // A plane height with few bits, so that c + h is exact.
        let c = rng.gen_range(-1024..1024) as f64 * 2f64.powi(-46);
        let h = 2f64.powi(-rng.gen_range(45..=60));
        let z_top = c + h;
        if q(z_top) != q(c) + q(h) {
            continue; // keep the gap exact
        }
        let n_first = if kind == VF { 1 } else { 2 };
        let mut times: [Vec<f64>; 4] = Default::default();
        let mut pts: [Vec<DVec3>; 4] = Default::default();
        for i in 0..4 {
            let nb = rng.gen_range(0..3);
            let mut ts: Vec<f64> = (0..nb)
                .map(|_| rng.gen_range(1..256) as f64 / 256.0)
                .collect();
            ts.extend([0.0, 1.0]);
            ts.sort_by(|a, b| a.total_cmp(b));
            ts.dedup();
            let z = if i < n_first { z_top } else { c };
            let base = DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), z);
            let vel = DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), 0.0);
            pts[i] = ts
                .iter()
                .map(|&t| {
                    let p = base + vel * t;
                    DVec3::new(p.x, p.y, z)
                })
                .collect();
            times[i] = ts;
        }
        let traj = traj_of(&times, &pts);
        let samples = oracle::sample_times(&traj, 32).expect("finite");
        let e2 = q(h) * q(h);
        let touching = samples
            .iter()
            .any(|t| exact_distance_at(kind, &traj, t) <= e2);
        let mut stats = CcdStats::default();
        if touching {
            contacts += 1;
            assert!(
                proximity(kind, &traj, h, &mut stats),
                "case {case}: sub-ulp contact at eta = {h} missed: {times:?} {pts:?}"
            );
        }
        // Below the gap: the exact distance is never below h.
        clear += 1;
        if !proximity(kind, &traj, h * (1.0 - 2f64.powi(-20)), &mut stats) {
            clear_certified += 1;
        }
    }
    println!(
        "sub-ulp sliding: {contacts} oracle contacts reported; {clear_certified} / {clear} \
         clear cases certified"
    );
    assert!(contacts > 150);
    assert!(clear > 500);
}

// ---------------------------------------------------------------- 6. degenerate input

#[test]
fn degenerate_inputs_are_conservative_and_never_panic() {
    let mut s = CcdStats::default();
    let p = |x: f64, y: f64, z: f64| DVec3::new(x, y, z);
    let tri = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0)];
    // NaN / infinite coordinates and eta: "maybe close".
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let x = [p(bad, 0.0, 1.0), tri[0], tri[1], tri[2]];
        let y = [p(0.2, 0.2, 1.0), tri[0], tri[1], tri[2]];
        for kind in [VF, EE] {
            assert!(linear_proximity(kind, &x, &y, 0.1, &mut s));
            assert!(linear_proximity(kind, &y, &x, 0.1, &mut s));
            assert!(linear_proximity(kind, &y, &y, bad, &mut s));
        }
    }
    // All points coincident: touching.
    let same = [p(0.3, 0.3, 0.3); 4];
    for kind in [VF, EE] {
        assert!(linear_proximity(kind, &same, &same, 0.0, &mut s));
    }
    // Zero-length edges and zero-area triangles: touching when they touch,
    // certified when clearly apart.
    let point_edges = [
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, 1.0),
        p(0.0, 0.0, 1.0),
    ];
    assert!(!linear_proximity(
        EE,
        &point_edges,
        &point_edges,
        0.5,
        &mut s
    ));
    assert!(linear_proximity(
        EE,
        &point_edges,
        &point_edges,
        1.0,
        &mut s
    ));
    let moving = [
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, -1.0),
        p(0.0, 0.0, -1.0),
    ];
    assert!(linear_proximity(EE, &point_edges, &moving, 0.0, &mut s));
    let collinear = [
        p(0.5, 0.5, 0.5),
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(2.0, 0.0, 0.0),
    ];
    assert!(!linear_proximity(VF, &collinear, &collinear, 0.1, &mut s));
    let through = [
        p(0.5, 0.0, 0.0),
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(2.0, 0.0, 0.0),
    ];
    assert!(linear_proximity(VF, &through, &through, 0.0, &mut s));
    let dot_tri = [
        p(0.0, 0.0, 1.0),
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, 0.0),
        p(0.0, 0.0, 0.0),
    ];
    assert!(!linear_proximity(VF, &dot_tri, &dot_tri, 0.5, &mut s));
    // Parallel overlapping edges sliding along each other at distance 0.
    let par0 = [
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(0.5, 0.0, 0.0),
        p(1.5, 0.0, 0.0),
    ];
    let par1 = [
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(-0.5, 0.0, 0.0),
        p(0.5, 0.0, 0.0),
    ];
    assert!(linear_proximity(EE, &par0, &par1, 0.0, &mut s));
    // Negative eta behaves as 0.
    assert!(linear_proximity(EE, &par0, &par1, -1.0, &mut s));
    // Huge and tiny coordinates: no panic; huge ones answer "maybe".
    let huge = [
        p(1e300, 0.0, 0.0),
        p(-1e300, 1.0, 0.0),
        p(0.0, 1e300, 1.0),
        p(0.0, -1e300, 1.0),
    ];
    assert!(linear_proximity(EE, &huge, &huge, 0.0, &mut s));
    let tiny = tri.map(|v| v * 1e-300);
    let tiny = [p(0.2e-300, 0.2e-300, 1e-300), tiny[0], tiny[1], tiny[2]];
    let _ = linear_proximity(VF, &tiny, &tiny, 0.0, &mut s);
    let _ = linear_proximity(VF, &tiny, &tiny, 1e-310, &mut s);
    // Malformed trajectories: "maybe".
    let pts = [p(0.0, 0.0, 1.0), p(0.0, 0.0, 2.0)];
    let far = [p(5.0, 5.0, 5.0), p(5.0, 5.0, 5.0)];
    let good_t = [0.0, 1.0];
    let bad_times: [&[f64]; 6] = [
        &[1.0, 0.0],      // decreasing
        &[0.0, 0.0],      // repeated
        &[0.0, 2.0],      // different end
        &[0.0, f64::NAN], // NaN time
        &[0.0],           // length mismatch
        &[],              // empty
    ];
    for (k, first) in bad_times.iter().enumerate() {
        let traj: [Trajectory<'_>; 4] = std::array::from_fn(|i| {
            Trajectory::new(
                if i == 0 { first } else { &good_t },
                if i == 0 { &pts } else { &far },
            )
        });
        for kind in [VF, EE] {
            assert!(proximity(kind, &traj, 0.1, &mut s), "malformed case {k}");
        }
    }
    assert!(s.invalid_input > 0);
    // A single instant (one breakpoint per vertex) is a static test.
    let t1 = [0.5];
    let one = [[p(0.2, 0.2, 1.0)], [tri[0]], [tri[1]], [tri[2]]];
    let traj: [Trajectory<'_>; 4] = std::array::from_fn(|i| Trajectory::new(&t1, &one[i]));
    assert!(!proximity(VF, &traj, 0.5, &mut s));
    assert!(proximity(VF, &traj, 1.0, &mut s));
}

// ---------------------------------------------------------------- reader

#[test]
fn exact_f64_conversion_accepts_exact_fractions_only() {
    let b = |s: &str| s.parse::<num_bigint::BigInt>().expect("int");
    assert_eq!(exact_f64(&b("1"), &b("2")), Ok(0.5));
    assert_eq!(exact_f64(&b("-3"), &b("4")), Ok(-0.75));
    assert_eq!(exact_f64(&b("6"), &b("3")), Ok(2.0));
    assert_eq!(exact_f64(&b("0"), &b("7")), Ok(0.0));
    assert_eq!(
        exact_f64(&b("6896999465383287"), &b("36028797018963968")),
        Ok(6896999465383287.0 / 36028797018963968.0)
    );
    assert!(exact_f64(&b("1"), &b("3")).is_err());
    assert!(exact_f64(&b("1"), &b("0")).is_err());
    assert!(exact_f64(&b("9007199254740993"), &b("1")).is_err()); // 2^53 + 1
    let huge = format!("1{}", "0".repeat(400));
    assert!(exact_f64(&b(&huge), &b("1")).is_err());
}

fn write(dir: &Path, rel: &str, text: &str) {
    let p = dir.join(rel);
    std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
    std::fs::write(p, text).expect("write");
}

#[test]
fn malformed_benchmark_files_name_file_and_line() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let row = "0,1,1,1,0,1,1\n";
    // A good wang folder and a good belgrod file.
    let good = tmp.path().join("good");
    write(&good, "s/vertex-face/data_0_0.csv", &row.repeat(8));
    write(&good, "b/queries/1ee.csv", &"1,2,3,4,5,8\n".repeat(8));
    write(&good, "b/mma_bool/1ee_mma_bool.json", "[false]");
    let folders = load_benchmark(&good).expect("good data");
    assert_eq!(folders.len(), 2);
    assert_eq!(folders.iter().map(|f| f.queries.len()).sum::<usize>(), 2);
    assert!(folders.iter().any(|f| f.queries[0].truth));
    // Bad rows.
    let cases = [
        ("bad1", "0,1,1,1,0,1\n", 3, "columns"),
        ("bad2", "0,1,1,3,0,1,1\n", 3, "not exactly representable"),
        ("bad3", "0,1,x,1,0,1,1\n", 3, "not an integer"),
        ("bad4", "0,1,1,1,0,1,2\n", 3, "0 or 1"),
        ("bad5", "0,1,1,1,0,1,0\n", 3, "differs"),
    ];
    for (name, bad, line, what) in cases {
        let dir = tmp.path().join(name);
        let text = format!("{}{}{}", row.repeat(2), bad, row.repeat(5));
        write(&dir, "s/edge-edge/data_0_0.csv", &text);
        let err = load_benchmark(&dir).expect_err(name).to_string();
        assert!(err.contains("data_0_0.csv"), "{name}: {err}");
        assert!(err.contains(&format!(":{line}:")), "{name}: {err}");
        assert!(err.contains(what), "{name}: {err}");
    }
    // Truth file missing or of the wrong length.
    let dir = tmp.path().join("bel");
    write(&dir, "b/queries/1vf.csv", &"1,2,3,4,5,8\n".repeat(8));
    assert!(matches!(load_benchmark(&dir), Err(CcdDataError::Io { .. })));
    write(&dir, "b/mma_bool/1vf_mma_bool.json", "[true, false]");
    assert!(load_benchmark(&dir)
        .expect_err("len")
        .to_string()
        .contains("1vf.csv"));
    write(&dir, "b/mma_bool/1vf_mma_bool.json", "[1]");
    assert!(load_benchmark(&dir)
        .expect_err("json")
        .to_string()
        .contains("1vf_mma_bool.json"));
    // Missing root and empty root.
    assert!(load_benchmark(&tmp.path().join("nope")).is_err());
    std::fs::create_dir_all(tmp.path().join("empty")).expect("mkdir");
    assert!(matches!(
        load_benchmark(&tmp.path().join("empty")),
        Err(CcdDataError::NoData(_))
    ));
}

/// A query that runs out of its interval budget answers "yes" (the
/// conservative answer), whatever the truth. Edge B (0.1 m) turns once
/// around the x axis, tangent to a circle of radius `r` about edge A (the
/// axis), in 6,000 straight segments. Between breakpoints B's midpoint
/// moves on a chord (B stays perpendicular to it), so the exact distance
/// never drops below `r cos(π / 6000)`; `eta` lies 1e-9 below that. A plane
/// certificate over two segments misses the kink between them by `4 r
/// (2π / 6000)² / 8`, far more than the gap, so every segment needs an
/// interval of its own: more than `MAX_INTERVALS`.
#[test]
fn budget_exhaustion_answers_yes() {
    let (r, n) = (1e-3, 6000usize);
    let step = std::f64::consts::TAU / n as f64;
    let eta = r * (0.5 * step).cos() * (1.0 - 1e-9);
    let times: Vec<f64> = (0..=n).map(|k| k as f64 / n as f64).collect();
    let end = |sign: f64| -> Vec<DVec3> {
        (0..=n)
            .map(|k| {
                let th = k as f64 * step;
                let (radial, tangent) = (
                    DVec3::new(0.0, th.cos(), th.sin()),
                    DVec3::new(0.0, -th.sin(), th.cos()),
                );
                radial * r + tangent * (0.05 * sign)
            })
            .collect()
    };
    let still = |p: DVec3| vec![p, p];
    let times = [times.clone(), times, vec![0.0, 1.0], vec![0.0, 1.0]];
    let points = [end(-1.0), end(1.0), still(-DVec3::X), still(DVec3::X)];
    let traj = traj_of(&times, &points);
    let mut stats = CcdStats::default();
    assert!(
        proximity(EE, &traj, eta, &mut stats),
        "a query that ran out of budget must answer yes: {stats:?}"
    );
    assert_eq!(stats.budget_exhausted, 1, "{stats:?}");
    assert!(
        stats.intervals >= weft_geom::ccd::MAX_INTERVALS,
        "{stats:?}"
    );
    // With a gap the certificates resolve, the same motion is certified
    // within the budget: the "yes" above came from the budget.
    let mut stats = CcdStats::default();
    assert!(!proximity(EE, &traj, 0.5 * r, &mut stats), "{stats:?}");
    assert_eq!(stats.budget_exhausted, 0);
}
