//! Over ranks a rank holds the internal elements of its own partitions
//! only (`InternalForces::held_only`), and a partition placed on another
//! rank moves its elements there as words (`partition_words`,
//! `place_again`). A part must evaluate, mask, list and weigh its
//! partitions with every bit of the whole world's elements, and a moved
//! partition must arrive whole.

use std::path::Path;

use glam::DVec3;
use weft_io::scene::load_scene;
use weft_sim::internal::InternalForces;
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
    mask: Option<&weft_sim::internal::ElementMask>,
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
/// masks and energies, bit for bit; and it holds no other.
fn agrees(part: &InternalForces, w: &World, held: &[bool], rng: &mut Rng) {
    let whole = &w.internal;
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
    assert!(
        energies.windows(2).all(|e| e[0].0 < e[1].0),
        "ascending keys"
    );
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
    // Every rank's part, and an empty and a full one.
    let mut key_count = 0;
    for r in 0..ranks as u32 {
        let held: Vec<bool> = home.iter().map(|&h| h == r).collect();
        let part = whole.held_only(|p| held[p]);
        assert!(!part.is_whole());
        assert_eq!(part.num_stencils(), whole.num_stencils());
        agrees(&part, &w, &held, &mut rng);
        key_count += part.held_energies(&w.x).len();
    }
    assert_eq!(
        key_count,
        whole.num_stencils(),
        "the parts hold every element once"
    );
    for all in [false, true] {
        let held = vec![all; PARTITIONS];
        agrees(&whole.held_only(|_| all), &w, &held, &mut rng);
    }
    // (The slots every rank folds stay whole, as the evaluation needs.)
    let part = whole.held_only(|p| home[p] == 0);
    let mut out = vec![DVec3::ZERO; whole.num_slots()];
    let bounds = whole.slot_bounds();
    let own: Vec<bool> = home.iter().map(|&h| h == 0).collect();
    part.evaluate(&Serial, &bounds, &w.x, &w.v, &mut out, Some(&own));
    for i in 0..w.num_vertices() {
        assert_eq!(part.incidence(i), whole.incidence(i), "vertex {i}'s fold");
    }
    for p in 0..PARTITIONS {
        assert_eq!(part.reads(p), whole.reads(p), "partition {p}'s reads");
    }
}

#[test]
fn partitions_placed_again_move_their_elements_with_every_bit() {
    let w = crumple();
    let whole = &w.internal;
    let mut rng = Rng(29);
    let ranks = 3u64;
    let mut home = placement(&mut rng, ranks);
    let mut parts: Vec<InternalForces> = (0..ranks as u32)
        .map(|r| whole.held_only(|p| home[p] == r))
        .collect();
    for round in 0..4 {
        // Every third round all on one rank: the others hold nothing.
        let next = match round % 3 {
            2 => vec![rng.below(ranks) as u32; PARTITIONS],
            _ => placement(&mut rng, ranks),
        };
        let words: Vec<Vec<f64>> = (0..PARTITIONS)
            .map(|p| parts[home[p] as usize].partition_words(p))
            .collect();
        for (p, words) in words.iter().enumerate() {
            assert_eq!(words.len(), whole.moved_words(p), "partition {p}'s words");
        }
        for (r, part) in parts.iter_mut().enumerate() {
            let arrived = (0..PARTITIONS)
                .filter(|&p| next[p] == r as u32 && home[p] != r as u32)
                .map(|p| (p, words[p].clone()))
                .collect();
            part.place_again(|p| next[p] == r as u32, arrived).unwrap();
            let held: Vec<bool> = next.iter().map(|&h| h == r as u32).collect();
            agrees(part, &w, &held, &mut rng);
            let fresh = whole.held_only(|p| held[p]);
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
    let part = whole.held_only(|p| p % 2 == 0);
    let words = part.partition_words(2);
    let mut other = whole.held_only(|p| p % 2 == 1);
    // Missing.
    let err = other
        .clone()
        .place_again(|p| p == 2, Vec::new())
        .unwrap_err();
    assert!(
        err.contains("partition 2") && err.contains("did not arrive"),
        "{err}"
    );
    // Cut short.
    let short = vec![(2, words[..words.len() - 1].to_vec())];
    let err = other.clone().place_again(|p| p == 2, short).unwrap_err();
    assert!(
        err.contains("partition 2") && err.contains("words instead of"),
        "{err}"
    );
    // A vertex id that is not one, and a material out of range.
    for (at, bad, says) in [(0, 0.5, "not a vertex id"), (7, 1e6, "does not decode")] {
        let mut broken = words.clone();
        broken[at] = bad;
        let err = other
            .clone()
            .place_again(|p| p == 2, vec![(2, broken)])
            .unwrap_err();
        assert!(err.contains("partition 2") && err.contains(says), "{err}");
    }
    // Whole, it arrives.
    other
        .place_again(|p| p == 2 || p % 2 == 1, vec![(2, words)])
        .unwrap();
    assert!(other.holds(2) && other.holds(1) && !other.holds(0));
}
