//! The BVH self-traversal split into tasks (`Bvh::self_overlap_tasks` +
//! `Bvh::overlaps_from`): over the union of the tasks every overlapping pair of
//! distinct leaves is reported exactly once, for any task count, and the tasks
//! are independent of the order they run in.

use weft_core::DVec3;
use weft_geom::bvh::{brute_force_self_pairs, Bvh, MAX_LEAF_SIZE};
use weft_geom::dop::Dop26;
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
