//! The broad phase on `Threads` (1 to 4 threads) gives the same candidate list
//! and triangle-pair count as on `Serial`, on a folded, noisy grid large enough
//! for hundreds of traversal tasks.

use weft_core::DVec3;
use weft_par::Threads;
use weft_sim::broad::BroadPhase;
use weft_sim::trajectory::Trajectories;
use weft_sim::{Executor, Serial};

/// splitmix64 in `[-r, r)^3`.
fn noise(state: &mut u64, r: f64) -> DVec3 {
    let mut next = || {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 * r - r
    };
    DVec3::new(next(), next(), next())
}

/// An `n × n` vertex grid folded over itself along x = 0.5, with noise and
/// `steps` breakpoints per vertex; every 13th vertex kinematic.
fn folded(n: usize, steps: u64) -> (Vec<[u32; 3]>, Vec<f64>, Trajectories) {
    let mut s = 7u64;
    let h = 1.0 / (n - 1) as f64;
    let mut x = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let u = i as f64 * h;
            let p = if u > 0.5 {
                DVec3::new(1.0 - u, j as f64 * h, 0.5 * h + 0.2 * (u - 0.5) * (u - 0.5))
            } else {
                DVec3::new(u, j as f64 * h, 0.0)
            };
            x.push(p + noise(&mut s, 0.2 * h));
        }
    }
    let id = |i: usize, j: usize| (j * n + i) as u32;
    let mut tris = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let inv_mass = (0..x.len())
        .map(|i| if i % 13 == 0 { 0.0 } else { 1.0 })
        .collect();
    let mut traj = Trajectories::new(x.len(), usize::MAX);
    traj.begin(0, &x);
    for k in 1..=steps {
        for (i, p) in x.iter().enumerate() {
            traj.record(i, 64 * k, *p + noise(&mut s, 0.1 * h) * k as f64)
                .unwrap();
        }
    }
    (tris, inv_mass, traj)
}

#[test]
fn threads_match_serial() {
    let (tris, inv_mass, traj) = folded(120, 2);
    let h = 1.0 / 119.0;
    let mut serial = BroadPhase::default();
    let expected = serial
        .candidates_on(&Serial, &tris, &inv_mass, &traj, 0.3 * h)
        .unwrap();
    assert!(expected.len() > 10_000, "{} candidates", expected.len());
    assert!(
        expected.windows(2).all(|w| w[0] < w[1]),
        "sorted and unique"
    );
    for threads in 1..=4 {
        let exec = Threads::new(threads).unwrap();
        let mut bp = BroadPhase::default();
        for round in 0..2 {
            // the second round refits the tree and reuses every buffer
            let got = bp
                .candidates_on(&exec, &tris, &inv_mass, &traj, 0.3 * h)
                .unwrap();
            assert_eq!(got, expected, "{threads} threads, round {round}");
            assert_eq!(bp.last_pairs, serial.last_pairs);
        }
    }
}

#[test]
fn ranks_match_serial() {
    let (tris, inv_mass, traj) = folded(60, 2);
    let h = 1.0 / 59.0;
    let expected = BroadPhase::default().candidates(&tris, &inv_mass, &traj, 0.3 * h);
    assert!(expected.len() > 1_000, "{} candidates", expected.len());
    for ranks in 1..=3 {
        let got = weft_par::ranks::in_process(
            ranks,
            |_| Serial,
            |exec| {
                let mut bp = BroadPhase::default();
                let keys = bp
                    .candidates_on(&exec, &tris, &inv_mass, &traj, 0.3 * h)
                    .unwrap();
                (keys, exec.traffic().messages)
            },
        );
        for (rank, (keys, messages)) in got.into_iter().enumerate() {
            assert_eq!(keys, expected, "rank {rank} of {ranks}");
            assert_eq!(messages > 0, ranks > 1, "rank {rank} of {ranks}");
        }
    }
}

/// Spread over ranks ([`BroadPhase::spread`]): each rank builds the trees of
/// its own groups and of the groups its traversals pair with them, not all
/// of them, and every rank still gets the candidates of one tree over all
/// triangles, with the same triangle-pair count.
#[test]
fn spread_ranks_build_their_neighbourhood_and_match_serial() {
    let n = 60;
    let (tris, inv_mass, traj) = folded(n, 2);
    let h = 1.0 / (n - 1) as f64;
    let expected = BroadPhase::default().candidates(&tris, &inv_mass, &traj, 0.3 * h);
    let mut one = BroadPhase::default();
    one.candidates(&tris, &inv_mass, &traj, 0.3 * h);
    // 12 groups of whole rows (the fold brings each row close to itself
    // only), the last 40 triangles under an unplaced label (`NONE`, as the
    // obstacles have): 13 groups.
    let groups = 12;
    let labels: Vec<u32> = (0..tris.len())
        .map(|t| {
            if t + 40 >= tris.len() {
                weft_core::NONE
            } else {
                (t * groups / tris.len()) as u32
            }
        })
        .collect();
    for ranks in 1..=4 {
        let got = weft_par::ranks::in_process(
            ranks,
            |_| Serial,
            |exec| {
                // Each rank holds a scattered share of the vertices' breakpoints
                // (their DOPs travel to the ranks whose trees read them).
                let mut traj = traj.clone();
                let holder = (0..traj.len())
                    .map(|i| ((i * 7 + 3) % ranks) as u32)
                    .collect();
                traj.hold_only(holder, exec.rank() as u32);
                let mut bp = BroadPhase::grouped(&labels);
                bp.spread((0..groups).map(|g| (g * ranks / groups) as u32).collect());
                let mut rounds = Vec::new();
                for _ in 0..2 {
                    // the second round refits the trees
                    let keys = bp
                        .candidates_on(&exec, &tris, &inv_mass, &traj, 0.3 * h)
                        .unwrap();
                    rounds.push((keys, bp.last_pairs, bp.last_trees));
                }
                rounds
            },
        );
        for (rank, rounds) in got.into_iter().enumerate() {
            for (round, (keys, pairs, trees)) in rounds.into_iter().enumerate() {
                let at = format!("rank {rank} of {ranks}, round {round}");
                println!("{at}: {trees} trees");
                assert_eq!(keys, expected, "{at}");
                assert_eq!(pairs, one.last_pairs, "{at}");
                if ranks == 1 {
                    assert_eq!(trees, groups + 1, "{at}");
                } else {
                    // its own 3 to 6 row groups (and the unplaced group on
                    // the last rank), their neighbours, and not the rest
                    assert!(trees < groups + 1 - 2, "{at}: {trees} trees");
                }
            }
        }
    }
}
