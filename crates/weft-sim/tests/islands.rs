//! Contact islands against a brute-force connected-components oracle.

use std::collections::BTreeSet;

use weft_core::StencilKey;
use weft_sim::islands::Islands;
use weft_testkit::Rng;

/// Random active stencils over `n` vertices, in key order, every one with a
/// dynamic vertex (as the engine's active sets are).
fn random_active(rng: &mut Rng, n: u32, m: usize, inv_mass: &[f64]) -> Vec<StencilKey> {
    let mut keys = BTreeSet::new();
    while keys.len() < m {
        let mut v = [0u32; 4];
        for x in &mut v {
            *x = rng.below(n as u64) as u32;
        }
        let distinct = v.iter().collect::<BTreeSet<_>>().len() == 4;
        if !distinct || !v.iter().any(|&i| inv_mass[i as usize] > 0.0) {
            continue;
        }
        keys.insert(if rng.below(2) == 0 {
            StencilKey::vertex_face(v[0], [v[1], v[2], v[3]])
        } else {
            StencilKey::edge_edge([v[0], v[1]], [v[2], v[3]])
        });
    }
    keys.into_iter().collect()
}

/// The islands by breadth-first search over "shares a dynamic vertex",
/// numbered by first stencil: (stencils, dynamic vertices) per island.
fn oracle(active: &[StencilKey], inv_mass: &[f64]) -> Vec<(Vec<u32>, Vec<u32>)> {
    let dynamic = |k: &StencilKey| -> BTreeSet<u32> {
        k.v.iter()
            .copied()
            .filter(|&i| inv_mass[i as usize] > 0.0)
            .collect()
    };
    let mut island = vec![usize::MAX; active.len()];
    let mut out = Vec::new();
    for start in 0..active.len() {
        if island[start] != usize::MAX {
            continue;
        }
        let id = out.len();
        island[start] = id;
        let mut queue = vec![start];
        let (mut stencils, mut vertices) = (Vec::new(), BTreeSet::new());
        while let Some(a) = queue.pop() {
            stencils.push(a as u32);
            let va = dynamic(&active[a]);
            vertices.extend(va.iter().copied());
            for b in 0..active.len() {
                if island[b] == usize::MAX && !va.is_disjoint(&dynamic(&active[b])) {
                    island[b] = id;
                    queue.push(b);
                }
            }
        }
        stencils.sort_unstable();
        out.push((stencils, vertices.into_iter().collect()));
    }
    out
}

/// A random case: 8 to 8 + `more_vertices` vertices, each kinematic with
/// probability `kinematic_share`, and up to `max_stencils` active stencils;
/// `None` when no vertex is dynamic.
fn random_case(
    rng: &mut Rng,
    more_vertices: u64,
    kinematic_share: f64,
    max_stencils: u64,
) -> Option<(Vec<StencilKey>, Vec<f64>)> {
    let n = 8 + rng.below(more_vertices) as u32;
    let inv_mass: Vec<f64> = (0..n)
        .map(|_| {
            if rng.uniform(0.0, 1.0) < kinematic_share {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    if !inv_mass.iter().any(|&w| w > 0.0) {
        return None;
    }
    let m = rng.below(max_stencils) as usize;
    Some((random_active(rng, n, m, &inv_mass), inv_mass))
}

#[test]
fn islands_are_the_connected_components_of_dynamic_vertices() {
    let mut rng = Rng(7);
    let mut sizes = BTreeSet::new();
    for case in 0..300 {
        // Some cases with many kinematic vertices (a rod, pinned rows).
        let kinematic_share = [0.0, 0.3, 0.7][case % 3];
        let Some((active, inv_mass)) = random_case(&mut rng, 60, kinematic_share, 40) else {
            continue;
        };
        let islands = Islands::build(&active, &inv_mass);
        let expected = oracle(&active, &inv_mass);
        assert_eq!(islands.len(), expected.len(), "case {case}");
        for (k, (stencils, vertices)) in expected.iter().enumerate() {
            assert_eq!(
                islands.stencils_of(k),
                &stencils[..],
                "case {case}, island {k}"
            );
            assert_eq!(
                islands.vertices_of(k),
                &vertices[..],
                "case {case}, island {k}"
            );
            sizes.insert(stencils.len());
        }
    }
    // Singletons, mid-sized and large islands all occurred.
    assert!(
        sizes.contains(&1) && sizes.iter().any(|&s| s >= 10),
        "{sizes:?}"
    );
}

/// A kinematic vertex shared by two stencils does not join them.
#[test]
fn kinematic_vertices_join_nothing() {
    let inv_mass = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    let a = StencilKey::vertex_face(1, [0, 2, 3]);
    let b = StencilKey::vertex_face(4, [0, 5, 6]);
    let islands = Islands::build(&[a, b], &inv_mass);
    assert_eq!(islands.len(), 2);
    assert_eq!(islands.vertices_of(0), &[1, 2, 3]);
    assert_eq!(islands.vertices_of(1), &[4, 5, 6]);
    let joined = Islands::build(&[a, b], &[1.0; 7]);
    assert_eq!(joined.len(), 1);
    assert!(Islands::build(&[], &inv_mass).is_empty());
}

#[test]
fn merged_is_one_island_of_every_stencil() {
    let inv_mass = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    let a = StencilKey::vertex_face(1, [0, 2, 3]);
    let b = StencilKey::vertex_face(4, [0, 5, 6]);
    let one = Islands::merged(&[a, b], &inv_mass);
    assert_eq!(one.len(), 1);
    assert_eq!(one.stencils_of(0), &[0, 1]);
    assert_eq!(one.vertices_of(0), &[1, 2, 3, 4, 5, 6]);
    assert!(Islands::merged(&[], &inv_mass).is_empty());
}

/// Packs are unions of whole islands: every island in exactly one pack,
/// stencils and vertices ascending; an island of at least the minimum alone;
/// every pack of small islands but the last reaches the minimum.
#[test]
fn packs_are_unions_of_whole_islands() {
    let mut rng = Rng(11);
    for case in 0..200 {
        let Some((active, inv_mass)) = random_case(&mut rng, 80, 0.3, 60) else {
            continue;
        };
        let islands = Islands::build(&active, &inv_mass);
        let min = 1 + rng.below(8) as usize;
        let packs = islands.packed(min);
        assert_eq!(packs.is_empty(), islands.is_empty(), "case {case}");
        let mut island_of = vec![usize::MAX; active.len()];
        for k in 0..islands.len() {
            for &a in islands.stencils_of(k) {
                island_of[a as usize] = k;
            }
        }
        let mut packed = vec![false; islands.len()];
        for p in 0..packs.len() {
            let members: BTreeSet<usize> = (packs.stencils_of(p).iter())
                .map(|&a| island_of[a as usize])
                .collect();
            let (mut stencils, mut vertices) = (Vec::new(), Vec::new());
            for &k in &members {
                assert!(!packed[k], "case {case}: island {k} in two packs");
                packed[k] = true;
                stencils.extend_from_slice(islands.stencils_of(k));
                vertices.extend_from_slice(islands.vertices_of(k));
            }
            stencils.sort_unstable();
            vertices.sort_unstable();
            assert_eq!(packs.stencils_of(p), &stencils[..], "case {case}, pack {p}");
            assert_eq!(packs.vertices_of(p), &vertices[..], "case {case}, pack {p}");
            let big = (members.iter())
                .filter(|&&k| islands.stencils_of(k).len() >= min)
                .count();
            match big {
                0 => assert!(stencils.len() >= min || p + 1 == packs.len(), "case {case}"),
                1 => assert_eq!(
                    members.len(),
                    1,
                    "case {case}: a big island shares pack {p}"
                ),
                _ => panic!("case {case}: two big islands in pack {p}"),
            }
        }
        assert!(
            packed.iter().all(|&p| p),
            "case {case}: every island packed"
        );
    }
}
