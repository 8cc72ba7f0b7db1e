//! Internal forces over ranks with separate memory (`weft_par::ranks`) give
//! the same bits as the shared-memory evaluation and fold, for 1 to 4 ranks
//! and several partition counts — and a rank that misses one ghost is caught.

use std::path::Path;

use glam::DVec3;
use weft_io::scene::load_scene;
use weft_par::ranks::{self, internal::advance};
use weft_sim::{Serial, World};

fn world(partitions: usize) -> World {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let scene = load_scene(
        &path,
        &["size=300".into(), format!("partitions={partitions}")],
    )
    .unwrap();
    weft_par::build_world(&scene.world).unwrap()
}

/// The same ticks in one memory: evaluate every partition, fold, advance.
fn reference(w: &World, ticks: usize) -> (Vec<DVec3>, Vec<DVec3>) {
    let (mut x, mut v) = (w.x.clone(), w.v.clone());
    let mut out = vec![DVec3::ZERO; w.internal.num_slots()];
    let bounds = w.internal.slot_bounds();
    let h = w.lattice.h_el();
    let cloth: Vec<usize> = (0..w.num_vertices())
        .filter(|&i| w.partitioning.of_vertex[i] != weft_core::NONE)
        .collect();
    for _ in 0..ticks {
        w.internal
            .evaluate(&Serial, &bounds, &x, &v, &mut out, None);
        for &i in &cloth {
            let f = w.internal.fold(i, &out);
            advance(w, i, f, &mut x[i], &mut v[i], h);
        }
    }
    (x, v)
}

fn bits(p: DVec3) -> [u64; 3] {
    p.to_array().map(f64::to_bits)
}

#[test]
fn ranks_match_the_shared_fold_bit_for_bit() {
    const TICKS: usize = 40;
    for partitions in [4, 16, 64] {
        let w = world(partitions);
        let (x0, v0) = reference(&w, TICKS);
        let cloth = w.objects[0].vertices.clone();
        // The cloth moved: the comparison is not of untouched data.
        assert!(cloth.clone().any(|i| x0[i as usize] != w.x[i as usize]));
        for ranks in 1..=4 {
            let plans = ranks::plan(&w, ranks);
            let (x, v, traffic) = ranks::run_ticks(&w, &plans, TICKS);
            for i in cloth.clone() {
                let i = i as usize;
                assert_eq!(
                    bits(x[i]),
                    bits(x0[i]),
                    "P = {partitions}, R = {ranks}, x[{i}]"
                );
                assert_eq!(
                    bits(v[i]),
                    bits(v0[i]),
                    "P = {partitions}, R = {ranks}, v[{i}]"
                );
            }
            let owned: usize = plans.iter().map(|p| p.owned.len()).sum();
            assert_eq!(owned, cloth.len(), "every cloth vertex has one owner");
            if ranks > 1 {
                assert!(traffic.iter().all(|t| t.messages > 0), "{traffic:?}");
                assert!(plans.iter().all(|p| p.boundary > 0));
            } else {
                assert_eq!(traffic[0].messages, 0);
            }
            if partitions == 64 && ranks > 1 {
                // Over-decomposition leaves interior partitions to overlap
                // with the ghost messages.
                assert!(plans.iter().all(|p| p.partitions.len() > p.boundary));
            }
        }
    }
}

#[test]
fn a_missing_ghost_poisons_the_result() {
    let w = world(16);
    let mut plans = ranks::plan(&w, 2);
    // Rank 1 forgets the first ghost it should receive from rank 0 (and rank
    // 0 stops sending it).
    let lost = plans[1].recv_state.get_mut(&0).unwrap().remove(0);
    plans[0]
        .send_state
        .get_mut(&1)
        .unwrap()
        .retain(|&i| i != lost);
    let (x, _, _) = ranks::run_ticks(&w, &plans, 3);
    assert!(
        w.objects[0]
            .vertices
            .clone()
            .any(|i| x[i as usize].is_nan()),
        "a stencil read vertex {lost} without its state and nothing showed it"
    );
}

#[test]
fn placement_balances_slots() {
    let w = world(64);
    for ranks in 2..=4 {
        let placement = ranks::place_partitions(&w, ranks);
        let mut load = vec![0usize; ranks];
        for (p, &r) in placement.iter().enumerate() {
            load[r as usize] += w.internal.partitions[p].slots.len();
        }
        let mean = w.internal.num_slots() as f64 / ranks as f64;
        let worst = *load.iter().max().unwrap() as f64;
        assert!(worst <= 1.15 * mean, "R = {ranks}: {load:?}");
    }
}

/// The engine's share of the internal ticks over ranks (`RankShare`): what
/// one rank sends another is what that rank expects from it; only boundary
/// partitions send (interior ones are evaluated while the messages travel,
/// so a slot they computed could not be sent yet); and every slot a rank's
/// vertices fold is computed there or received.
#[test]
fn rank_shares_mirror_and_cover_every_fold() {
    use weft_sim::share::RankShare;
    for partitions in [4, 16, 64] {
        let w = world(partitions);
        let mut slot_partition = vec![0usize; w.internal.num_slots()];
        for (p, part) in w.internal.partitions.iter().enumerate() {
            slot_partition[part.slots.clone()].fill(p);
        }
        for ranks in 1..=4 {
            let shares: Vec<RankShare> = (0..ranks).map(|r| RankShare::new(&w, r, ranks)).collect();
            let mut traffic = 0;
            for (r, share) in shares.iter().enumerate() {
                let ctx = format!("P = {partitions}, R = {ranks}, rank {r}");
                for (peer, slots) in &share.send_slots {
                    assert_ne!(*peer, r, "{ctx}: sends to itself");
                    let theirs = shares[*peer].recv_slots.iter().find(|(from, _)| *from == r);
                    assert_eq!(theirs.map(|(_, s)| s), Some(slots), "{ctx}: to {peer}");
                    for &s in slots {
                        let p = slot_partition[s as usize];
                        assert!(
                            share.boundary_partition[p],
                            "{ctx}: slot {s} of partition {p}"
                        );
                    }
                    traffic += slots.len();
                }
                for (peer, _) in &share.recv_slots {
                    assert!(
                        shares[*peer].send_slots.iter().any(|(to, _)| *to == r),
                        "{ctx}: expects from {peer}, which sends nothing"
                    );
                }
                let received: std::collections::BTreeSet<u32> = share
                    .recv_slots
                    .iter()
                    .flat_map(|(_, s)| s.iter().copied())
                    .collect();
                for i in 0..w.num_vertices() {
                    if !share.owns(i) {
                        continue;
                    }
                    for &s in w.internal.incidence(i) {
                        let p = slot_partition[s as usize];
                        let here = share.boundary_partition[p] || share.interior_partition[p];
                        assert!(
                            here || received.contains(&s),
                            "{ctx}: vertex {i} folds slot {s} of partition {p}, neither computed nor received"
                        );
                    }
                }
                // Every vertex a partition evaluated here reads (the
                // vertices folding its slots) is kept current here: owned
                // or shared; and a pass's island off its vertex's owner
                // makes that vertex shared (advanced on every rank).
                let pass = share.pass([(0u32, ((share.owner[0] + 1) % ranks as u32))]);
                let inf = &w.internal;
                for (p, part) in inf.partitions.iter().enumerate() {
                    if !(share.boundary_partition[p] || share.interior_partition[p]) {
                        continue;
                    }
                    let reads = (part.stretch.clone())
                        .flat_map(|s| inf.stretch[s].verts.to_vec())
                        .chain(
                            part.hinges
                                .clone()
                                .flat_map(|h| inf.hinges[h].verts.to_vec()),
                        );
                    for i in reads {
                        assert!(
                            pass.live[i as usize],
                            "{ctx}: partition {p} reads vertex {i}"
                        );
                    }
                }
                // Vertex 0's owner sends its velocity to the island's rank.
                let island_rank = (share.owner[0] + 1) % ranks as u32;
                if share.owns(0) && ranks > 1 {
                    assert!(
                        pass.send[island_rank as usize].contains(&0),
                        "{ctx}: an island off vertex 0's owner"
                    );
                }
                // What this rank receives from each peer is what the peer
                // sends it, and it receives every vertex it keeps current
                // but does not own, from its owner.
                for peer in 0..ranks {
                    if peer == r {
                        continue;
                    }
                    let theirs = shares[peer].pass([(0u32, island_rank)]);
                    assert_eq!(pass.recv[peer], theirs.send[r], "{ctx}: from {peer}");
                }
                // A scripted vertex is never received: a rank keeping it
                // current computes its chord itself.
                let scripted = |i: usize| w.script_of[i].is_some();
                assert!((0..w.num_vertices()).any(scripted), "{ctx}: an obstacle");
                for i in 0..w.num_vertices() {
                    let received = pass.recv[share.owner[i] as usize].contains(&(i as u32));
                    let elsewhere = pass.live[i] && !share.owns(i);
                    assert_eq!(
                        received,
                        elsewhere && !scripted(i),
                        "{ctx}: vertex {i} received"
                    );
                    let computed = pass.scripted.binary_search(&(i as u32)).is_ok();
                    assert_eq!(
                        computed,
                        elsewhere && scripted(i),
                        "{ctx}: vertex {i} computed here"
                    );
                }
                // Units moved to other ranks mid-pass (`keep_live`, called
                // alike on every rank): the vertices are kept current where
                // they went, and each rank still receives from each peer
                // exactly what the peer sends it.
                let n = w.num_vertices();
                // (the last vertices are the obstacle's, scripted)
                let moves: Vec<(usize, u32)> = (0..40)
                    .map(|k| ((k * 7919 + 13) % n, ((k * 31) % ranks) as u32))
                    .chain((n - 5..n).map(|i| (i, ((i * 7) % ranks) as u32)))
                    .collect();
                assert!(moves.iter().any(|&(i, _)| scripted(i)));
                let moved = |s: &RankShare| {
                    let mut pass = s.pass([(0u32, island_rank)]);
                    for &(i, to) in &moves {
                        s.keep_live(&mut pass, i, to);
                    }
                    pass
                };
                let mine = moved(share);
                for &(i, to) in &moves {
                    if to as usize == r {
                        assert!(mine.live[i], "{ctx}: vertex {i} moved here");
                    }
                }
                for peer in (0..ranks).filter(|&p| p != r) {
                    let theirs = moved(&shares[peer]);
                    assert_eq!(mine.recv[peer], theirs.send[r], "{ctx}: moved, from {peer}");
                }
                for i in 0..n {
                    let received = mine.recv[share.owner[i] as usize].contains(&(i as u32));
                    let elsewhere = mine.live[i] && !share.owns(i);
                    let computed = mine.scripted.binary_search(&(i as u32)).is_ok();
                    assert_eq!(received, elsewhere && !scripted(i), "{ctx}: moved {i}");
                    assert_eq!(computed, elsewhere && scripted(i), "{ctx}: moved {i}");
                }
                assert!(mine.scripted.is_sorted(), "{ctx}");
                // Live here: owned, or read here by a partition or the
                // island (never more).
                for i in 0..w.num_vertices() {
                    let read = share.read_here[i] || (i == 0 && island_rank == r as u32);
                    assert_eq!(pass.live[i], share.owns(i) || read, "{ctx}: vertex {i}");
                }
                // each partition is evaluated on exactly one rank
                for p in 0..partitions {
                    let evaluated = shares
                        .iter()
                        .filter(|s| s.boundary_partition[p] || s.interior_partition[p])
                        .count();
                    assert_eq!(evaluated, 1, "{ctx}: partition {p}");
                }
            }
            assert_eq!(traffic == 0, ranks == 1, "P = {partitions}, R = {ranks}");
            if partitions >= 64 {
                // there is interior work to overlap the messages with (with
                // 4 partitions per rank of this small cloth, all may border)
                assert!(
                    shares
                        .iter()
                        .all(|s| s.interior_partition.iter().any(|&i| i)),
                    "P = {partitions}, R = {ranks}: a rank has no interior partition"
                );
            }
        }
    }
}

/// A rank keeps only the output slots it computes or receives
/// (`RankShare::slots`), each partition of its own in one run and the
/// received ones after them. Evaluated there and exchanged (the engine's
/// `exchange_slots`, on ranks in one process), every owned vertex's fold of
/// them has the bits of the fold of the world's slots, for placements by
/// size and random ones, some ranks with no partition at all.
#[test]
fn rank_slots_fold_the_bits_of_the_world_slots() {
    use weft_sim::share::RankShare;
    use weft_sim::Executor;
    let mut rng = weft_testkit::Rng(5);
    for partitions in [4, 16, 64] {
        let w = world(partitions);
        let n = w.num_vertices();
        let x: Vec<DVec3> = w.x.iter().map(|&p| p + rng.vec(2e-3)).collect();
        let v: Vec<DVec3> = (0..n).map(|_| rng.vec(0.5)).collect();
        let mut whole = vec![DVec3::ZERO; w.internal.num_slots()];
        let bounds = w.internal.slot_bounds();
        w.internal
            .evaluate(&Serial, &bounds, &x, &v, &mut whole, None);
        for ranks in 1..=4usize {
            let random: Vec<u32> = (0..partitions)
                .map(|_| rng.below(ranks as u64) as u32)
                .collect();
            for home in [w.internal.home_ranks(ranks), random] {
                let folds = ranks::in_process(
                    ranks,
                    |_| Serial,
                    |exec| {
                        let r = exec.rank();
                        let share = RankShare::placed(&w, r, ranks, home.clone());
                        let slots = &share.slots;
                        let own: usize = (w.internal.partitions.iter().zip(&home))
                            .filter(|(_, &h)| h as usize == r)
                            .map(|(p, _)| p.slots.len())
                            .sum();
                        let received: usize = share.recv_slots.iter().map(|(_, s)| s.len()).sum();
                        assert_eq!(slots.len, own + received, "rank {r} of {ranks}");
                        let mut out = vec![DVec3::NAN; slots.len];
                        let (boundary, interior) =
                            (&share.boundary_partition, &share.interior_partition);
                        w.internal.evaluate(
                            &Serial,
                            &slots.bounds,
                            &x,
                            &v,
                            &mut out,
                            Some(boundary),
                        );
                        share
                            .exchange_slots(&exec, &mut out, &mut |out| {
                                w.internal.evaluate(
                                    &Serial,
                                    &slots.bounds,
                                    &x,
                                    &v,
                                    out,
                                    Some(interior),
                                );
                            })
                            .expect("in process");
                        (0..n)
                            .filter(|&i| share.owns(i))
                            .map(|i| (i, slots.fold(i, &out)))
                            .collect::<Vec<_>>()
                    },
                );
                let mut seen = vec![false; n];
                for (i, f) in folds.into_iter().flatten() {
                    assert!(!seen[i], "vertex {i} owned twice");
                    seen[i] = true;
                    let expected = w.internal.fold(i, &whole);
                    assert_eq!(
                        bits(f),
                        bits(expected),
                        "P = {partitions}, R = {ranks}, vertex {i}"
                    );
                }
                assert!(seen.iter().all(|&s| s), "every vertex owned");
            }
        }
    }
}

/// Every rank builds the world, and the internal step's two Lanczos
/// estimates and their Gershgorin bound are assembled range by range, each
/// rank its block of ranges on its threads, the blocks gathered: the same
/// `omega_max`, damping rate and internal step, bit for bit, as one memory,
/// on any number of ranks and threads (also when the ranks' thread counts
/// differ), with the ranks' shares sent.
#[test]
fn the_step_estimate_spread_over_ranks_has_one_memorys_bits() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    // Threads per rank; the fourth case's differ, as `--threads 0` may on
    // hosts of different sizes. The last, on a cloth of 4 vertices (12 with
    // the ground's), cuts fewer ranges than ranks: a rank holds none.
    for (size, threads) in [
        (300, &[1, 1][..]),
        (300, &[2, 2, 2]),
        (300, &[1; 5]),
        (300, &[1, 3, 2]),
        (4, &[1; 13]),
    ] {
        let scene = load_scene(&path, &[format!("size={size}")]).unwrap();
        let one = weft_par::build_world(&scene.world).unwrap();
        assert!(one.damping_rate > 0.0, "a damped cloth");
        let step = |w: &World| [w.omega_max, w.damping_rate, w.lattice.h_el()].map(f64::to_bits);
        let ranks = threads.len();
        let built = ranks::in_process(
            ranks,
            |r| weft_par::Threads::new(threads[r]).unwrap(),
            |exec| {
                let w = weft_par::build_world_on(&scene.world, &exec).unwrap();
                (step(&w), weft_sim::Executor::traffic(&exec))
            },
        );
        for (rank, (bits, traffic)) in built.iter().enumerate() {
            assert_eq!(
                *bits,
                step(&one),
                "rank {rank} of {ranks}, threads {threads:?}"
            );
            // An all-gather per Lanczos step of either iteration (at least
            // ten each before the first convergence check), one for the
            // threads and one for the bound.
            assert!(traffic.collectives >= 23, "rank {rank}: {traffic:?}");
        }
    }
}
