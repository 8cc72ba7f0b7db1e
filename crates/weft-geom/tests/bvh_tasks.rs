//! The BVH self-traversal split into tasks (`Bvh::self_overlap_tasks` +
//! `Bvh::overlaps_from`), and the two-tree traversal likewise
//! (`Bvh::cross_overlap_tasks_into` + `Bvh::overlaps_with_from`): over the
//! union of the tasks every overlapping pair of leaves is reported exactly
//! once, for any task count, and the tasks are independent of the order they
//! run in. Also the voxel grid of the global broad phase
//! (`weft_geom::voxel::overlapping_pairs`) against its all-pairs oracle.

use weft_core::DVec3;
use weft_geom::bvh::{brute_force_self_pairs, Bvh, MAX_LEAF_SIZE};
use weft_geom::dop::Dop26;
use weft_geom::voxel::{brute_force_pairs, overlapping_pairs};
use weft_testkit::Rng;

/// Random triangles of size up to `size` in a box of half-width `half`, each
/// inflated by a random radius up to `r`; every 11th leaf is empty.
fn random_leaves(seed: u64, n: usize, half: f64, size: f64, r: f64) -> Vec<Dop26> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|k| {
            if k % 11 == 10 {
                return Dop26::empty();
            }
            let c = rng.vec(half);
            let mut d = Dop26::empty();
            for _ in 0..3 {
                d.add_point(c + rng.vec(size));
            }
            d.inflate(r * rng.uniform(0.0, 1.0));
            d
        })
        .collect()
}

/// The pairs of all tasks, run last task first, checked for ordering and
/// duplicates, sorted.
fn task_pairs(bvh: &Bvh, min_tasks: usize) -> Vec<(u32, u32)> {
    let tasks = bvh.self_overlap_tasks(min_tasks);
    let mut seen = tasks.clone();
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(seen.len(), tasks.len(), "a task appears twice");
    let mut out = Vec::new();
    for &task in tasks.iter().rev() {
        bvh.overlaps_from(task, |i, j| {
            assert!(i < j, "pair ({i}, {j}) not ordered");
            out.push((i, j));
        });
    }
    let n = out.len();
    out.sort_unstable();
    out.dedup();
    assert_eq!(
        out.len(),
        n,
        "a pair was reported twice (min_tasks {min_tasks})"
    );
    out
}

#[test]
fn tasks_match_brute_force_for_any_task_count() {
    let mut total = 0;
    for (seed, n) in [(1, 1), (2, 3), (3, 9), (4, 80), (5, 700), (6, 2500)] {
        let leaves = random_leaves(seed, n, 1.0, 0.08, 0.03);
        let bvh = Bvh::build(&leaves);
        bvh.validate(&leaves).unwrap();
        let expected = brute_force_self_pairs(&leaves);
        total += expected.len();
        for min_tasks in [0, 1, 2, 3, 7, 64, 512, n, 4 * n + 10] {
            let tasks = bvh.self_overlap_tasks(min_tasks);
            if min_tasks <= 1 {
                assert_eq!(tasks, vec![(0, 0)]);
            }
            assert_eq!(
                task_pairs(&bvh, min_tasks),
                expected,
                "n {n}, min_tasks {min_tasks}"
            );
        }
    }
    assert!(total > 500, "scenes too sparse ({total} pairs)");
}

#[test]
fn many_tasks_reach_the_leaf_level_or_the_requested_count() {
    let leaves = random_leaves(7, 3000, 1.0, 0.05, 0.02);
    let bvh = Bvh::build(&leaves);
    for min_tasks in [2, 10, 100, 1000] {
        let tasks = bvh.self_overlap_tasks(min_tasks);
        assert!(tasks.len() >= min_tasks, "{} < {min_tasks}", tasks.len());
    }
    // more tasks than leaves: only leaf-level pairs are left
    let tasks = bvh.self_overlap_tasks(1 << 20);
    assert!(tasks.len() < 1 << 20);
    assert!(tasks.len() >= leaves.len().div_ceil(MAX_LEAF_SIZE));
    let mut count = 0;
    for &t in &tasks {
        bvh.overlaps_from(t, |_, _| count += 1);
    }
    assert_eq!(count, brute_force_self_pairs(&leaves).len());
}

#[test]
fn tasks_on_a_dense_line_and_on_identical_leaves() {
    // a long line of leaves each overlapping only its neighbour
    let n = 5000;
    let line: Vec<Dop26> = (0..n)
        .map(|i| {
            let mut d = Dop26::from_point(DVec3::new(i as f64 * 1e-3, 0.0, 0.0));
            d.inflate(6e-4);
            d
        })
        .collect();
    let bvh = Bvh::build(&line);
    for min_tasks in [1, 16, 512, 2 * n] {
        let pairs = task_pairs(&bvh, min_tasks);
        assert_eq!(pairs.len(), n - 1);
        assert!(pairs.iter().all(|&(i, j)| j == i + 1));
    }
    // all leaves equal: every pair overlaps
    let d = Dop26::from_point(DVec3::new(0.1, 0.2, 0.3));
    let same = vec![d; 50];
    let bvh = Bvh::build(&same);
    for min_tasks in [1, 5, 50, 5000] {
        assert_eq!(task_pairs(&bvh, min_tasks).len(), 50 * 49 / 2);
    }
}

#[test]
fn empty_tree_has_no_tasks() {
    let bvh = Bvh::build(&[]);
    assert!(bvh.self_overlap_tasks(8).is_empty());
    bvh.overlaps_from((0, 0), |_, _| panic!("pair in an empty tree"));
    bvh.self_overlaps(|_, _| panic!("pair in an empty tree"));
}

#[test]
fn tasks_are_deterministic() {
    let leaves = random_leaves(9, 1500, 1.0, 0.1, 0.02);
    let a = Bvh::build(&leaves).self_overlap_tasks(200);
    let b = Bvh::build(&leaves).self_overlap_tasks(200);
    assert_eq!(a, b);
}

/// Every pair of overlapping leaves between two leaf sets, all pairs tested.
fn brute_force_cross_pairs(a: &[Dop26], b: &[Dop26]) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for (i, da) in a.iter().enumerate() {
        for (j, db) in b.iter().enumerate() {
            if da.overlaps(db) {
                out.push((i as u32, j as u32));
            }
        }
    }
    out
}

#[test]
fn cross_tasks_match_brute_force_for_any_task_count() {
    let mut total = 0;
    for (seed, na, nb) in [
        (11, 1, 1),
        (12, 1, 40),
        (13, 9, 3),
        (14, 300, 700),
        (15, 2000, 1500),
    ] {
        let a = random_leaves(seed, na, 1.0, 0.08, 0.03);
        let b = random_leaves(seed + 50, nb, 1.0, 0.08, 0.03);
        let (ta, tb) = (Bvh::build(&a), Bvh::build(&b));
        let expected = brute_force_cross_pairs(&a, &b);
        total += expected.len();
        let mut whole = Vec::new();
        ta.overlaps_with(&tb, |i, j| whole.push((i, j)));
        whole.sort_unstable();
        assert_eq!(whole, expected, "overlaps_with, {na} x {nb}");
        let mut tasks = vec![(7, 7)];
        for min_tasks in [0, 1, 2, 5, 64, 512, na + nb, 1 << 20] {
            ta.cross_overlap_tasks_into(&tb, min_tasks, &mut tasks);
            let mut seen = tasks.clone();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), tasks.len(), "a task appears twice");
            let mut got = Vec::new();
            for &t in tasks.iter().rev() {
                ta.overlaps_with_from(&tb, t, |i, j| got.push((i, j)));
            }
            let n = got.len();
            got.sort_unstable();
            got.dedup();
            assert_eq!(n, got.len(), "a pair was reported twice");
            assert_eq!(got, expected, "{na} x {nb}, min_tasks {min_tasks}");
            // Expansion stops at the requested count or at leaf pairs, each
            // of which reports at most MAX_LEAF_SIZE² pairs.
            let floor = min_tasks.min(expected.len().div_ceil(MAX_LEAF_SIZE * MAX_LEAF_SIZE));
            assert!(tasks.len() >= floor, "{} < {floor}", tasks.len());
        }
    }
    assert!(total > 500, "scenes too sparse ({total} pairs)");
    // separated roots and empty trees: no task, no pair
    let a = random_leaves(16, 50, 1.0, 0.05, 0.0);
    let far: Vec<Dop26> = a
        .iter()
        .map(|d| {
            let mut d = *d;
            d.lo[0] += 10.0;
            d.hi[0] += 10.0;
            d
        })
        .collect();
    let mut tasks = Vec::new();
    Bvh::build(&a).cross_overlap_tasks_into(&Bvh::build(&far), 8, &mut tasks);
    assert!(tasks.is_empty());
    Bvh::build(&a).cross_overlap_tasks_into(&Bvh::build(&[]), 8, &mut tasks);
    assert!(tasks.is_empty());
}

#[test]
fn voxel_grid_pairs_match_brute_force() {
    let mut total = 0;
    for (seed, n, half, size) in [
        (21, 2, 1.0, 0.5),
        (22, 40, 1.0, 0.3),
        (23, 300, 1.0, 0.2),
        (24, 1000, 5.0, 0.5),
        (25, 200, 1e-12, 3e-13),
        (26, 200, 1e9, 3e8),
    ] {
        let mut hulls = random_leaves(seed, n, half, size, 0.1 * size);
        // a few huge hulls (irregular: tested against all) and exact copies
        for k in (0..n).step_by(37) {
            hulls[k].merge(&Dop26::from_point(DVec3::splat(50.0 * half)));
        }
        for k in (5..n).step_by(53) {
            hulls[k] = hulls[k - 5];
        }
        let expected = brute_force_pairs(&hulls);
        total += expected.len();
        assert_eq!(overlapping_pairs(&hulls), expected, "seed {seed}");
    }
    assert!(total > 1000, "scenes too sparse ({total} pairs)");
}
