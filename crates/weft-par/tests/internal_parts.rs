//! Over ranks a rank holds the internal elements of its own partitions
//! and the folds of its own vertices only (`InternalForces::held_only`),
//! and a partition placed on another rank moves its elements and its
//! vertices' folds there as words (`partition_words`, `place_again`). A
//! part must evaluate, mask, list, fold and weigh what it holds with every
//! bit of the whole world's elements, a rank's share of the internal ticks
//! must be the same from its part as from the whole, and a moved partition
//! must arrive whole.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;
use weft_core::NONE;
use weft_io::scene::load_scene;
use weft_sim::internal::{ElementMask, InternalForces, Moved};
use weft_sim::share::RankShare;
use weft_sim::{Serial, World};
use weft_testkit::Rng;

const PARTITIONS: usize = 16;

fn crumple() -> World {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let partitions = format!("partitions={PARTITIONS}");
    let scene = load_scene(&path, &["size=300".into(), partitions]).unwrap();
    weft_par::build_world(&scene.world).unwrap()
}

fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
    v.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
}

/// A random placement of the partitions on `ranks` ranks.
fn placement(rng: &mut Rng, ranks: u64) -> Vec<u32> {
    (0..PARTITIONS).map(|_| rng.below(ranks) as u32).collect()
}

/// Whether rank `r` holds vertex `i`'s fold under `home`: the home of its
/// partition (a vertex of no partition folds nothing), as the engine.
fn holds_fold<'a>(w: &'a World, home: &[u32], r: u32) -> impl Fn(usize) -> bool + 'a {
    let home = home.to_vec();
    let of_vertex = &w.partitioning.of_vertex;
    move |i| {
        of_vertex
            .get(i)
            .is_none_or(|&p| p == NONE || home[p as usize] == r)
    }
}

/// The vertices whose folds move with partition `p`.
fn vertices_of(w: &World, p: usize) -> Vec<u32> {
    let of_vertex = &w.partitioning.of_vertex;
    (0..of_vertex.len() as u32)
        .filter(|&i| of_vertex[i as usize] == p as u32)
        .collect()
}

/// Positions away from rest and random velocities: every element has a
/// nonzero stretch, bend and damping force, and energy.
fn state(w: &World, rng: &mut Rng) -> (Vec<DVec3>, Vec<DVec3>) {
    let x = w.x.iter().map(|&p| p + rng.vec(2e-3)).collect();
    let v = (0..w.num_vertices()).map(|_| rng.vec(0.5)).collect();
    (x, v)
}

/// Partition `p`'s output slots evaluated by `f` (all its elements, or
/// with `mask` those whose entry is `true`).
fn evaluated(
    f: &InternalForces,
    p: usize,
    (x, v): (&[DVec3], &[DVec3]),
    mask: Option<&ElementMask>,
) -> Vec<[u64; 3]> {
    let mut chunk = vec![DVec3::ZERO; f.partitions[p].slots.len()];
    match mask {
        None => f.evaluate_partition(p, x, v, &mut chunk),
        Some(m) => f.evaluate_partition_masked(p, (x, v), &mut chunk, (m, true)),
    }
    bits(&chunk)
}

/// What `part` holds agrees with `w`'s whole elements on every partition
/// `held` names: the same elements, slots, evaluations (whole and masked),
/// masks and energies, bit for bit; and it holds no other. It holds the
/// folds of the vertices `folds` names, the whole world's.
fn agrees(
    part: &InternalForces,
    w: &World,
    held: &[bool],
    folds: &dyn Fn(usize) -> bool,
    rng: &mut Rng,
) {
    let whole = &w.internal;
    for i in 0..w.num_vertices() {
        assert_eq!(
            part.fold_len(i),
            whole.fold_len(i),
            "vertex {i}'s fold length"
        );
        if folds(i) {
            assert_eq!(part.incidence(i), whole.incidence(i), "vertex {i}'s fold");
        }
    }
    let (x, v) = state(w, rng);
    let xv = (&x[..], &v[..]);
    let pick_seed = rng.next_u64();
    let pick = |i: u32| (u64::from(i) ^ pick_seed).count_ones() % 3 != 0;
    let (m_part, m_whole) = (part.mask_where(pick), whole.mask_where(pick));
    let mut expected_verts: Vec<Vec<u32>> = Vec::new();
    for (p, range) in whole.partitions.iter().enumerate() {
        assert_eq!(part.holds(p), held[p], "partition {p} held");
        if !held[p] {
            assert_eq!(m_part.in_partition[p], 0, "partition {p} is not held");
            assert!(m_part.stretch[range.stretch.clone()].iter().all(|&b| !b));
            assert!(m_part.hinges[range.hinges.clone()].iter().all(|&b| !b));
            continue;
        }
        assert_eq!(
            evaluated(part, p, xv, None),
            evaluated(whole, p, xv, None),
            "partition {p}"
        );
        let masked = (
            evaluated(part, p, xv, Some(&m_part)),
            evaluated(whole, p, xv, Some(&m_whole)),
        );
        assert_eq!(masked.0, masked.1, "partition {p}, masked");
        assert_eq!(
            part.slot_vertices(p),
            whole.slot_vertices(p),
            "partition {p}'s slots"
        );
        assert_eq!(
            m_part.in_partition[p], m_whole.in_partition[p],
            "partition {p}'s mask"
        );
        assert_eq!(
            m_part.stretch[range.stretch.clone()],
            m_whole.stretch[range.stretch.clone()]
        );
        assert_eq!(
            m_part.hinges[range.hinges.clone()],
            m_whole.hinges[range.hinges.clone()]
        );
        let stretch = (range.stretch.clone()).filter(|&s| !m_whole.stretch[s]);
        expected_verts.extend(stretch.map(|s| whole.stretch[s].verts.to_vec()));
        let hinges = (range.hinges.clone()).filter(|&h| !m_whole.hinges[h]);
        expected_verts.extend(hinges.map(|h| whole.hinges[h].verts.to_vec()));
    }
    let verts: Vec<Vec<u32>> = part
        .verts_where(&m_part, false)
        .map(<[u32]>::to_vec)
        .collect();
    assert_eq!(verts, expected_verts, "the held elements outside the mask");
    // Each held element's energy, with its place in key order, has the
    // bits of the whole world's energy of that one element.
    let energies = part.held_energies(&x);
    let mut keys: Vec<u32> = energies.iter().map(|e| e.0).collect();
    keys.sort_unstable();
    assert!(keys.windows(2).all(|k| k[0] < k[1]), "each key once");
    let held_elements: usize = (whole.partitions.iter().enumerate())
        .filter(|&(p, _)| held[p])
        .map(|(_, r)| r.stretch.len() + r.hinges.len())
        .sum();
    assert_eq!(energies.len(), held_elements);
    for &(n, e) in &energies {
        let n = n as usize;
        assert_eq!(
            e.to_bits(),
            whole.energy_of(&x, n..n + 1).to_bits(),
            "element {n}"
        );
        assert!(e > 0.0, "element {n} has energy away from rest");
    }
}

#[test]
fn a_ranks_part_holds_its_partitions_with_the_bits_of_the_whole() {
    let w = crumple();
    let whole = &w.internal;
    assert!(whole.is_whole());
    let mut rng = Rng(17);
    let ranks = 3;
    let home = placement(&mut rng, ranks);
    let mut key_count = 0;
    for r in 0..ranks as u32 {
        let held: Vec<bool> = home.iter().map(|&h| h == r).collect();
        let folds = holds_fold(&w, &home, r);
        let part = whole.held_only(|p| held[p], &folds);
        assert!(!part.is_whole());
        assert_eq!(part.num_stencils(), whole.num_stencils());
        agrees(&part, &w, &held, &folds, &mut rng);
        key_count += part.held_energies(&w.x).len();
        for p in 0..PARTITIONS {
            assert_eq!(part.reads(p), whole.reads(p), "partition {p}'s reads");
        }
        // The rank's share of the internal ticks: the same from its part
        // as from the whole world.
        let mut w_part = w.clone();
        w_part.internal = Arc::new(part);
        let share = |w: &World| RankShare::placed(w, r as usize, ranks as usize, home.clone());
        let (from_part, from_whole) = (share(&w_part), share(&w));
        assert_eq!(
            format!("{from_part:?}"),
            format!("{from_whole:?}"),
            "rank {r}'s share"
        );
        assert!(!from_whole.send_slots.is_empty() && !from_whole.recv_slots.is_empty());
    }
    assert_eq!(
        key_count,
        whole.num_stencils(),
        "the parts hold every element once"
    );
    for all in [false, true] {
        let held = vec![all; PARTITIONS];
        let part = whole.held_only(|_| all, |_| all);
        agrees(&part, &w, &held, &|_| all, &mut rng);
        // (An evaluation of the partitions `only` marks reads those only.)
        let mut out = vec![DVec3::ZERO; whole.num_slots()];
        part.evaluate(
            &Serial,
            &whole.slot_bounds(),
            &w.x,
            &w.v,
            &mut out,
            Some(&held),
        );
    }
}

#[test]
fn partitions_placed_again_move_their_elements_and_folds_with_every_bit() {
    let w = crumple();
    let whole = &w.internal;
    let mut rng = Rng(29);
    let ranks = 3u64;
    let mut home = placement(&mut rng, ranks);
    let mut parts: Vec<InternalForces> = (0..ranks as u32)
        .map(|r| whole.held_only(|p| home[p] == r, holds_fold(&w, &home, r)))
        .collect();
    for round in 0..4 {
        // Every third round all on one rank: the others hold nothing.
        let next = match round % 3 {
            2 => vec![rng.below(ranks) as u32; PARTITIONS],
            _ => placement(&mut rng, ranks),
        };
        let moved = |p: usize| Moved {
            partition: p,
            vertices: vertices_of(&w, p),
            words: parts[home[p] as usize].partition_words(p, &vertices_of(&w, p)),
        };
        let moved: Vec<Moved> = (0..PARTITIONS).map(moved).collect();
        for m in &moved {
            let expected = whole.moved_words(m.partition, &m.vertices);
            assert_eq!(m.words.len(), expected, "partition {}'s words", m.partition);
        }
        for (r, part) in parts.iter_mut().enumerate() {
            let r = r as u32;
            let arrived = (moved.iter())
                .filter(|m| next[m.partition] == r && home[m.partition] != r)
                .cloned()
                .collect();
            let folds = holds_fold(&w, &next, r);
            part.place_again(|p| next[p] == r, &folds, arrived).unwrap();
            let held: Vec<bool> = next.iter().map(|&h| h == r).collect();
            agrees(part, &w, &held, &folds, &mut rng);
            let fresh = whole.held_only(|p| held[p], &folds);
            assert_eq!(part.stretch, fresh.stretch, "round {round}, rank {r}");
            assert_eq!(part.hinges, fresh.hinges, "round {round}, rank {r}");
            assert_eq!(part.stretch_material, fresh.stretch_material);
            assert_eq!(part.hinge_material, fresh.hinge_material);
        }
        home = next;
    }
}

#[test]
fn a_moved_partition_that_does_not_arrive_whole_is_an_error_naming_it() {
    let w = crumple();
    let whole = &w.internal;
    let odd = |p: usize| p % 2 == 1;
    let home: Vec<u32> = (0..PARTITIONS as u32).map(|p| p % 2).collect();
    let part = whole.held_only(|p| !odd(p), holds_fold(&w, &home, 0));
    let vertices = vertices_of(&w, 2);
    assert!(!vertices.is_empty());
    let words = part.partition_words(2, &vertices);
    let other = whole.held_only(odd, holds_fold(&w, &home, 1));
    let mut next = home.clone();
    next[2] = 1;
    let place = |arrived: Vec<Moved>| {
        (other.clone()).place_again(|p| next[p] == 1, holds_fold(&w, &next, 1), arrived)
    };
    let arrive = |words: Vec<f64>| {
        place(vec![Moved {
            partition: 2,
            vertices: vertices.clone(),
            words,
        }])
    };
    // Missing.
    let err = place(Vec::new()).unwrap_err();
    assert!(
        err.contains("partition 2") && err.contains("did not arrive"),
        "{err}"
    );
    // Cut short in the elements, and in the folds.
    let elements = whole.moved_words(2, &[]);
    let err = arrive(words[..elements - 1].to_vec()).unwrap_err();
    assert!(
        err.contains("partition 2") && err.contains("words instead of"),
        "{err}"
    );
    let err = arrive(words[..words.len() - 1].to_vec()).unwrap_err();
    assert!(
        err.contains("fold has") && err.contains("slots instead of"),
        "{err}"
    );
    // A vertex id that is not one, a material out of range, a slot that
    // is not one.
    let cases = [
        (0, 0.5, "not a vertex id"),
        (7, 1e6, "does not decode"),
        (elements, -1.0, "not one"),
    ];
    for (at, bad, says) in cases {
        let mut broken = words.clone();
        broken[at] = bad;
        let err = arrive(broken).unwrap_err();
        assert!(err.contains(says), "{err}");
    }
    // The fold of a vertex (of partition 0) that no rank sent.
    let mut folds_of = home.clone();
    folds_of[0] = 1;
    let err = (other.clone())
        .place_again(|p| home[p] == 1, holds_fold(&w, &folds_of, 1), Vec::new())
        .unwrap_err();
    assert!(
        err.contains("vertex") && err.contains("did not arrive"),
        "{err}"
    );
    // Whole, it arrives.
    arrive(words).unwrap();
}
