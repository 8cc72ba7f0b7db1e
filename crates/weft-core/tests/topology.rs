//! `Topology::build` on small meshes whose topology is known by hand.

use weft_core::{MeshError, Topology, NONE};

/// A 2x2-quad grid (3x3 vertices, ids row-major), each quad split along its
/// (lower-left, upper-right) diagonal, all faces counter-clockwise seen from +z.
fn grid2x2() -> Vec<[u32; 3]> {
    let mut t = Vec::new();
    for j in 0..2u32 {
        for i in 0..2u32 {
            let v = j * 3 + i;
            t.push([v, v + 1, v + 4]);
            t.push([v, v + 4, v + 3]);
        }
    }
    t
}

fn tetrahedron() -> Vec<[u32; 3]> {
    vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]
}

fn octahedron() -> Vec<[u32; 3]> {
    // Vertices: 0 +x, 1 -x, 2 +y, 3 -y, 4 +z, 5 -z; outward orientation.
    vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ]
}

/// Whether triangle `t` traverses the directed edge a→b.
fn traverses(t: [u32; 3], a: u32, b: u32) -> bool {
    (0..3).any(|k| t[k] == a && t[(k + 1) % 3] == b)
}

/// Invariants that hold for every topology, checked against the triangles.
fn check_consistency(n: usize, tris: &[[u32; 3]], topo: &Topology) {
    assert_eq!(topo.num_vertices, n);
    assert!(
        topo.edges.windows(2).all(|w| w[0] < w[1]),
        "edges sorted, unique"
    );
    assert!(topo.edges.iter().all(|e| e[0] < e[1]));
    assert_eq!(topo.edges.len(), topo.edge_faces.len());
    assert_eq!(topo.face_edges.len(), tris.len());
    for (f, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let e = topo.face_edges[f][k];
            let (a, b) = (t[k], t[(k + 1) % 3]);
            assert_eq!(topo.edges[e as usize], [a.min(b), a.max(b)]);
            assert_eq!(topo.edge_index(a, b), Some(e));
            assert!(topo.edge_faces[e as usize].contains(&(f as u32)));
        }
    }
    for (e, ef) in topo.edge_faces.iter().enumerate() {
        assert!(ef[1] == NONE || ef[0] < ef[1], "edge {e}: faces ascending");
    }
    let interior = topo.edge_faces.iter().filter(|ef| ef[1] != NONE).count();
    assert_eq!(topo.hinges.len(), interior);
    assert_eq!(topo.vertex_faces.len(), n);
    for v in 0..n as u32 {
        let expect: Vec<u32> = (0..tris.len() as u32)
            .filter(|&f| tris[f as usize].contains(&v))
            .collect();
        assert_eq!(topo.faces_of_vertex(v), expect.as_slice(), "vertex {v}");
    }
}

/// For consistently oriented faces: faces[0] traverses edge[0]→edge[1] and
/// has third vertex wings[0]; faces[1] traverses it backwards with wings[1].
fn check_hinge_orientation(tris: &[[u32; 3]], topo: &Topology) {
    for h in &topo.hinges {
        let [x0, x1] = h.edge;
        let (ta, tb) = (tris[h.faces[0] as usize], tris[h.faces[1] as usize]);
        assert!(traverses(ta, x0, x1), "{h:?}: face A traverses x0->x1");
        assert!(traverses(tb, x1, x0), "{h:?}: face B traverses x1->x0");
        assert!(ta.contains(&h.wings[0]) && h.wings[0] != x0 && h.wings[0] != x1);
        assert!(tb.contains(&h.wings[1]) && h.wings[1] != x0 && h.wings[1] != x1);
        let e = topo.edge_index(x0, x1).unwrap() as usize;
        assert_eq!(topo.edge_faces[e], h.faces);
    }
}

#[test]
fn grid_2x2_counts_boundary_and_hinges() {
    let tris = grid2x2();
    let topo = Topology::build(9, &tris).unwrap();
    check_consistency(9, &tris, &topo);
    check_hinge_orientation(&tris, &topo);
    // V - E + F = 1 for a disk: 9 - 16 + 8.
    assert_eq!(topo.edges.len(), 16);
    assert_eq!(topo.hinges.len(), 8);
    let boundary = topo.edge_faces.iter().filter(|f| f[1] == NONE).count();
    assert_eq!(boundary, 8);
    let expect: Vec<bool> = (0..9).map(|v| v != 4).collect();
    assert_eq!(
        topo.is_boundary_vertex, expect,
        "only the centre is interior"
    );
    assert_eq!(topo.faces_of_vertex(4), &[0, 1, 3, 4, 6, 7]);
    assert_eq!(topo.faces_of_vertex(0), &[0, 1]);
    assert_eq!(topo.faces_of_vertex(2), &[2]);
}

#[test]
fn grid_hinge_across_diagonal() {
    let tris = grid2x2();
    let topo = Topology::build(9, &tris).unwrap();
    // Diagonal {0, 4} of the first quad: face 0 = [0, 1, 4] runs 0→1→4→0, so
    // it traverses 4→0 with wing 1; face 1 = [0, 4, 3] has wing 3.
    let h = topo.hinges.iter().find(|h| h.faces == [0, 1]).unwrap();
    assert_eq!(h.edge, [4, 0]);
    assert_eq!(h.wings, [1, 3]);
}

#[test]
fn closed_tetrahedron_and_octahedron_have_no_boundary() {
    for (n, tris) in [(4, tetrahedron()), (6, octahedron())] {
        let topo = Topology::build(n, &tris).unwrap();
        check_consistency(n, &tris, &topo);
        check_hinge_orientation(&tris, &topo);
        // Closed surface: every edge has two faces; Euler characteristic 2.
        assert!(topo.edge_faces.iter().all(|f| f[1] != NONE));
        assert!(topo.is_boundary_vertex.iter().all(|&b| !b));
        assert_eq!(topo.hinges.len(), topo.edges.len());
        assert_eq!(n as i64 - topo.edges.len() as i64 + tris.len() as i64, 2);
    }
}

#[test]
fn empty_mesh_and_isolated_vertices() {
    let topo = Topology::build(3, &[]).unwrap();
    assert!(topo.edges.is_empty() && topo.hinges.is_empty());
    assert_eq!(topo.vertex_faces.len(), 3);
    assert!((0..3).all(|v| topo.faces_of_vertex(v).is_empty()));
    assert_eq!(topo.is_boundary_vertex, vec![false; 3]);
}

#[test]
fn out_of_range_index_is_named() {
    let err = Topology::build(3, &[[0, 1, 2], [0, 2, 3]]).unwrap_err();
    assert_eq!(
        err,
        MeshError::IndexOutOfRange {
            triangle: 1,
            index: 3,
            num_vertices: 3
        }
    );
    let msg = err.to_string();
    assert!(
        msg.contains("triangle 1") && msg.contains("vertex 3"),
        "{msg}"
    );
}

#[test]
fn repeated_vertex_is_named() {
    let err = Topology::build(3, &[[0, 1, 2], [1, 2, 1]]).unwrap_err();
    assert_eq!(
        err,
        MeshError::RepeatedVertex {
            triangle: 1,
            vertices: [1, 2, 1]
        }
    );
}

#[test]
fn three_triangles_on_one_edge_are_non_manifold() {
    let err = Topology::build(5, &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap_err();
    assert_eq!(
        err,
        MeshError::NonManifoldEdge {
            edge: [0, 1],
            triangles: vec![0, 1, 2]
        }
    );
    assert!(err.to_string().contains("shared by 3 triangles"));
}

#[test]
fn hinge_orientation_follows_lower_face_even_if_inconsistent() {
    // Both faces traverse 0→1: the hinge is still oriented as face 0 sees it.
    let tris = [[0, 1, 2], [0, 1, 3]];
    let topo = Topology::build(4, &tris).unwrap();
    assert_eq!(topo.hinges.len(), 1);
    let h = topo.hinges[0];
    assert_eq!((h.edge, h.wings, h.faces), ([0, 1], [2, 3], [0, 1]));
}
