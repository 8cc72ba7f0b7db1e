//! `validate`: one test per error and warning class, each checking that the
//! message names the element with 0-based indices (the `Display` numbering).

use weft_core::{validate, DVec3, MeshError, MeshWarning, TriMesh};

/// Unit square in z = 0 split into two counter-clockwise triangles.
fn square() -> TriMesh {
    TriMesh::new(
        vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    )
}

fn message(err: &MeshError) -> String {
    let msg = err.to_string();
    assert!(
        msg.contains("0-based"),
        "message must say indices are 0-based: {msg}"
    );
    msg
}

#[test]
fn valid_square_has_no_warnings() {
    assert_eq!(validate(&square()), Ok(vec![]));
}

#[test]
fn empty_mesh() {
    let mesh = TriMesh::new(vec![DVec3::ZERO], vec![]);
    assert_eq!(validate(&mesh), Err(MeshError::Empty));
    assert!(MeshError::Empty.to_string().contains("no triangles"));
}

#[test]
fn non_finite_coordinate_names_vertex_and_axis() {
    let mut mesh = square();
    mesh.positions[2].y = f64::INFINITY;
    let err = validate(&mesh).unwrap_err();
    assert!(matches!(
        err,
        MeshError::NonFiniteCoordinate {
            vertex: 2,
            axis: 'y',
            ..
        }
    ));
    let msg = message(&err);
    assert!(
        msg.contains("vertex 2") && msg.contains(" y ") && msg.contains("inf"),
        "{msg}"
    );
    mesh.positions[1].x = f64::NAN;
    let msg = message(&validate(&mesh).unwrap_err());
    assert!(msg.contains("vertex 1") && msg.contains("NaN"), "{msg}");
}

#[test]
fn index_out_of_range() {
    let mut mesh = square();
    mesh.triangles[1] = [0, 2, 7];
    let err = validate(&mesh).unwrap_err();
    assert_eq!(
        err,
        MeshError::IndexOutOfRange {
            triangle: 1,
            index: 7,
            num_vertices: 4
        }
    );
    assert_eq!(err.triangle(), Some(1));
    let msg = message(&err);
    assert!(
        msg.contains("triangle 1") && msg.contains("vertex 7"),
        "{msg}"
    );
}

#[test]
fn repeated_vertex() {
    let mut mesh = square();
    mesh.triangles[0] = [0, 1, 0];
    let err = validate(&mesh).unwrap_err();
    assert_eq!(
        err,
        MeshError::RepeatedVertex {
            triangle: 0,
            vertices: [0, 1, 0]
        }
    );
    assert!(message(&err).contains("triangle 0 (vertices 0, 1, 0"));
}

#[test]
fn degenerate_triangle_names_vertices_and_area() {
    let mut mesh = square();
    // Vertex 4 lies on the edge 0-1: triangle [0, 1, 4] is collinear.
    mesh.positions.push(DVec3::new(0.5, 0.0, 0.0));
    mesh.triangles.push([0, 1, 4]);
    let err = validate(&mesh).unwrap_err();
    assert!(matches!(
        err,
        MeshError::DegenerateTriangle { triangle: 2, vertices: [0, 1, 4], area, .. } if area == 0.0
    ));
    let msg = message(&err);
    assert!(
        msg.contains("triangle 2 (vertices 0, 1, 4")
            && msg.contains("zero area: its corners are collinear"),
        "{msg}"
    );
}

#[test]
fn degenerate_tolerance_is_relative_to_bounding_box() {
    // The same tiny-but-regular square is fine at any scale.
    for scale in [1e-6, 1.0, 1e6] {
        let mut mesh = square();
        for p in &mut mesh.positions {
            *p *= scale;
        }
        assert_eq!(validate(&mesh), Ok(vec![]), "scale {scale}");
    }
    // A sliver with area 1e-16 in a unit box is degenerate.
    let mut mesh = square();
    mesh.positions.push(DVec3::new(0.5, 1e-16, 0.0));
    mesh.triangles.push([0, 1, 4]);
    assert!(matches!(
        validate(&mesh),
        Err(MeshError::DegenerateTriangle { triangle: 2, .. })
    ));
}

/// What used to happen: one vertex at 1e30 made every ordinary triangle "have
/// zero area (area 1.07e-4, tolerance 1e46)". The message now says the triangle
/// is too small for the mesh's extent and names the far vertex.
#[test]
fn a_stray_far_vertex_is_named_instead_of_a_zero_area() {
    let mut mesh = square();
    mesh.positions.push(DVec3::new(1e30, 0.0, 0.0));
    mesh.positions.push(DVec3::new(1e30, 1.0, 0.0));
    mesh.positions.push(DVec3::new(1e30, 0.0, 1.0));
    mesh.triangles.push([4, 5, 6]);
    let err = validate(&mesh).unwrap_err();
    assert!(
        matches!(
            err,
            MeshError::TooSmallForExtent {
                triangle: 0,
                far_vertex: 4,
                ..
            }
        ),
        "{err:?}"
    );
    let msg = message(&err);
    assert!(!msg.contains("zero area"), "{msg}");
    assert!(
        msg.contains("too small to resolve in a mesh 1.000e30 m across")
            && msg.contains("vertex 4 (0-based) at (1e30, 0e0, 0e0)")
            && msg.contains("stray vertex")
            && msg.contains("at most 7.071e6 m"),
        "{msg}"
    );
}

#[test]
fn coordinates_beyond_the_simulated_range_are_named() {
    assert_eq!(weft_core::MAX_COORDINATE, 2f64.powi(500));
    let mut mesh = square();
    mesh.positions[3].z = -1e200;
    let err = validate(&mesh).unwrap_err();
    assert_eq!(
        err,
        MeshError::CoordinateTooLarge {
            vertex: 3,
            axis: 'z',
            value: -1e200
        }
    );
    let msg = message(&err);
    assert!(
        msg.contains("vertex 3 (0-based) has z = -1e200 m, beyond the largest magnitude")
            && msg.contains("3.273e150 m"),
        "{msg}"
    );
    // At the limit, the mesh is accepted (a uniformly huge mesh is not wrong).
    for p in &mut mesh.positions {
        *p = *p / 1e200 * weft_core::MAX_COORDINATE;
    }
    mesh.positions[3].z = 0.0;
    assert_eq!(validate(&mesh), Ok(vec![]));
}

#[test]
fn duplicate_triangle_names_both() {
    let mut mesh = square();
    mesh.triangles.push([2, 0, 1]); // same vertex set as triangle 0
    let err = validate(&mesh).unwrap_err();
    assert_eq!(
        err,
        MeshError::DuplicateTriangle {
            triangle: 2,
            first: 0,
            vertices: [2, 0, 1]
        }
    );
    let msg = message(&err);
    assert!(
        msg.contains("triangle 2") && msg.contains("triangle 0"),
        "{msg}"
    );
}

#[test]
fn non_manifold_edge() {
    let mut mesh = square();
    mesh.positions.push(DVec3::new(0.5, 0.5, 1.0));
    mesh.triangles.push([0, 2, 4]); // third triangle on edge 0-2
    let err = validate(&mesh).unwrap_err();
    assert_eq!(
        err,
        MeshError::NonManifoldEdge {
            edge: [0, 2],
            triangles: vec![0, 1, 2]
        }
    );
    assert_eq!(err.triangle(), Some(2));
    let msg = message(&err);
    assert!(
        msg.contains("edge (vertices 0, 2; 0-based) is shared by 3 triangles 0, 1, 2"),
        "{msg}"
    );
}

#[test]
fn checks_run_in_documented_order() {
    // Non-finite coordinate wins over an out-of-range index.
    let mut mesh = square();
    mesh.positions[3].z = f64::NAN;
    mesh.triangles[1] = [0, 0, 9];
    assert!(matches!(
        validate(&mesh),
        Err(MeshError::NonFiniteCoordinate { .. })
    ));
    // Out-of-range (triangle 1) wins over a repeated vertex (triangle 0).
    let mut mesh = square();
    mesh.triangles[0] = [0, 0, 1];
    mesh.triangles[1] = [0, 2, 9];
    assert!(matches!(
        validate(&mesh),
        Err(MeshError::IndexOutOfRange { triangle: 1, .. })
    ));
}

#[test]
fn unreferenced_vertices_warning() {
    let mut mesh = square();
    mesh.positions
        .extend((0..7).map(|i| DVec3::new(2.0 + i as f64, 0.0, 0.0)));
    let warnings = validate(&mesh).unwrap();
    assert_eq!(
        warnings,
        vec![MeshWarning::UnreferencedVertices {
            count: 7,
            first: vec![4, 5, 6, 7, 8]
        }]
    );
    let msg = warnings[0].to_string();
    assert!(
        msg.contains("7 vertices") && msg.contains("4, 5, 6, 7, 8") && msg.contains("0-based"),
        "{msg}"
    );
}

#[test]
fn inconsistent_orientation_warning() {
    let mut mesh = square();
    mesh.triangles[1] = [0, 3, 2]; // flipped: both faces now traverse 0→2
    let warnings = validate(&mesh).unwrap();
    assert_eq!(
        warnings,
        vec![MeshWarning::InconsistentOrientation {
            count: 1,
            edge: [2, 0],
            triangles: [0, 1]
        }]
    );
    let msg = warnings[0].to_string();
    assert!(
        msg.contains("from vertex 2 (0-based) to vertex 0 (0-based)")
            && msg.contains("both triangle 0 and triangle 1"),
        "{msg}"
    );
}

#[test]
fn coincident_vertices_are_grouped_exactly() {
    use weft_core::coincident::coincident_vertices;
    let p = [
        DVec3::new(1.0, 2.0, 3.0),
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 2.0, 3.0),
        DVec3::new(-0.0, 0.0, -0.0), // the same position as vertex 1
        DVec3::new(1.0, 2.0, 3.0 + 1e-15),
        DVec3::new(1.0, 2.0, 3.0),
    ];
    assert_eq!(coincident_vertices(&p), vec![vec![0, 2, 5], vec![1, 3]]);
    assert!(coincident_vertices(&square().positions).is_empty());
}
