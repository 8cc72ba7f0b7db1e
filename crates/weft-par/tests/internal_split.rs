//! The internal forces evaluated in two parts — the elements a mask keeps,
//! then the others — give every output slot the bits of one evaluation of
//! all elements: what lets an internal tick compute the elements no contact
//! island touches while the islands run (`weft-sim`'s `engine/events`). So
//! do both evaluated in pieces of elements rather than whole partitions.

use std::path::Path;

use glam::DVec3;
use weft_io::scene::load_scene;
use weft_par::Threads;
use weft_sim::{Executor, Serial, World};
use weft_testkit::Rng;

fn crumple(partitions: usize) -> World {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let scene = load_scene(
        &path,
        &["size=300".into(), format!("partitions={partitions}")],
    )
    .unwrap();
    weft_par::build_world(&scene.world).unwrap()
}

fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
    v.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
}

fn split_matches_whole<E: Executor>(exec: &E, w: &World, rng: &mut Rng) {
    let bounds = w.internal.slot_bounds();
    let n = w.num_vertices();
    // Positions and velocities away from rest, so that every element has
    // a nonzero stretch, bend and damping force.
    let x: Vec<DVec3> = w.x.iter().map(|&p| p + rng.vec(2e-3)).collect();
    let v: Vec<DVec3> = (0..n).map(|_| rng.vec(0.5)).collect();
    let mut whole = vec![DVec3::ZERO; w.internal.num_slots()];
    w.internal.evaluate(exec, &bounds, &x, &v, &mut whole, None);
    assert!(whole.iter().all(|g| g.is_finite()));
    assert!(whole.iter().filter(|g| **g != DVec3::ZERO).count() > whole.len() / 2);
    // In pieces of elements (one memory's evaluations), every slot written.
    let mut pieces = vec![DVec3::NAN; whole.len()];
    (w.internal).evaluate_in_pieces(exec, (&x, &v), &mut pieces, None);
    assert_eq!(bits(&pieces), bits(&whole));
    // Masks by vertex as the islands make them: a random share of the
    // vertices (none, some, all) lies in an island.
    for share in [0.0, 0.05, 0.3, 0.7, 1.0] {
        let in_island: Vec<bool> = (0..n).map(|_| rng.uniform(0.0, 1.0) < share).collect();
        let mask = w.internal.mask_where(|i| !in_island[i as usize]);
        let kept = mask.stretch.iter().chain(&mask.hinges).filter(|&&b| b);
        let all = mask.stretch.len() + mask.hinges.len();
        let expected = if share == 0.0 {
            all..all + 1
        } else if share == 1.0 {
            0..1
        } else {
            1..all
        };
        assert!(expected.contains(&kept.count()), "share {share}");
        // Poisoned slots: each must be written by exactly one of the parts.
        let mut split = vec![DVec3::NAN; whole.len()];
        w.internal
            .evaluate_masked(exec, &bounds, &x, &v, &mut split, (&mask, true), None);
        w.internal
            .evaluate_masked(exec, &bounds, &x, &v, &mut split, (&mask, false), None);
        assert_eq!(bits(&split), bits(&whole), "share {share}");
        // Each part alone writes only its own elements' slots.
        let mut only_kept = vec![DVec3::NAN; whole.len()];
        w.internal
            .evaluate_masked(exec, &bounds, &x, &v, &mut only_kept, (&mask, true), None);
        let written = only_kept.iter().filter(|g| !g.is_nan()).count();
        let kept_slots: usize = (mask.stretch.iter().filter(|&&b| b).count() * 3)
            + mask.hinges.iter().filter(|&&b| b).count() * 4;
        assert_eq!(written, kept_slots, "share {share}");
        // The same halves in pieces.
        let mut in_pieces = vec![DVec3::NAN; whole.len()];
        (w.internal).evaluate_in_pieces(exec, (&x, &v), &mut in_pieces, Some((&mask, true)));
        let written = in_pieces.iter().filter(|g| !g.is_nan()).count();
        assert_eq!(written, kept_slots, "share {share}, in pieces");
        (w.internal).evaluate_in_pieces(exec, (&x, &v), &mut in_pieces, Some((&mask, false)));
        assert_eq!(bits(&in_pieces), bits(&whole), "share {share}, in pieces");
    }
}

#[test]
fn masked_halves_give_the_whole_evaluation_bit_for_bit() {
    let mut rng = Rng(17);
    for partitions in [1, 7, 32] {
        let w = crumple(partitions);
        split_matches_whole(&Serial, &w, &mut rng);
        split_matches_whole(&Threads::new(2).unwrap(), &w, &mut rng);
    }
}

/// The fold reads a vertex's slots in global key order wherever they lie;
/// the layout puts them side by side. Every slot a vertex folds belongs to
/// an element corner at that vertex, and inside each piece of a partition
/// (at most `ELEMENTS_PER_PIECE` elements) the slots run by vertex: a
/// partition's slot vertices descend at most once per piece boundary.
#[test]
fn slots_are_laid_out_by_vertex_within_pieces() {
    use weft_sim::internal::ELEMENTS_PER_PIECE;
    for partitions in [1, 7, 32] {
        let w = crumple(partitions);
        let f = &w.internal;
        let mut vertex_of_slot = vec![u32::MAX; f.num_slots()];
        for (p, part) in f.partitions.iter().enumerate() {
            let vertices = f.slot_vertices(p);
            assert_eq!(vertices.len(), part.slots.len());
            let elements = part.stretch.len() + part.hinges.len();
            let pieces = elements.div_ceil(ELEMENTS_PER_PIECE).max(1);
            let descents = vertices.windows(2).filter(|v| v[1] < v[0]).count();
            assert!(
                descents < pieces,
                "partition {p}: {descents} descents, {pieces} pieces"
            );
            vertex_of_slot[part.slots.clone()].copy_from_slice(&vertices);
        }
        let mut folded = vec![false; f.num_slots()];
        for i in 0..w.num_vertices() {
            for &s in f.incidence(i) {
                assert_eq!(vertex_of_slot[s as usize], i as u32, "slot {s}");
                assert!(!folded[s as usize], "slot {s} folded twice");
                folded[s as usize] = true;
            }
        }
        // Every slot of a dynamic vertex's corner is folded.
        for (s, &i) in vertex_of_slot.iter().enumerate() {
            assert_eq!(folded[s], w.inv_mass[i as usize] > 0.0, "slot {s}");
        }
    }
}
