//! Mesh validation: errors name the offending element.
//!
//! [`validate`] runs the checks below in this order and stops at the first
//! error, so a message always describes the most basic problem:
//!
//! 1. the mesh has at least one triangle ([`MeshError::Empty`]);
//! 2. every coordinate is finite ([`MeshError::NonFiniteCoordinate`]);
//! 3. every index is in range ([`MeshError::IndexOutOfRange`]);
//! 4. no triangle repeats a vertex ([`MeshError::RepeatedVertex`]);
//! 5. no triangle has (near-)zero area ([`MeshError::DegenerateTriangle`]);
//! 6. no two triangles use the same three vertices ([`MeshError::DuplicateTriangle`]);
//! 7. every edge has at most two triangles ([`MeshError::NonManifoldEdge`]).
//!
//! A mesh that passes may still produce [`MeshWarning`]s (unreferenced vertices,
//! inconsistently oriented faces). All indices in messages are 0-based positions
//! in the mesh, and every message says so.

use crate::mesh::TriMesh;
use crate::topology::Topology;
use thiserror::Error;

/// Relative area tolerance: a triangle is degenerate when its area is at most
/// `DEGENERATE_AREA_REL * diag²`, where `diag` is the mesh's bounding-box
/// diagonal (so the test is independent of the mesh's units).
pub const DEGENERATE_AREA_REL: f64 = 1e-14;

/// How many vertex ids [`MeshWarning::UnreferencedVertices`] lists.
const LISTED_IDS: usize = 5;

/// A mesh that cannot be simulated. Indices are 0-based positions in the mesh.
///
/// When this error occurs: [`validate`] or [`Topology::build`] was given a mesh
/// that breaks one of the invariants the simulator relies on. How to handle it:
/// fix the named element in the source file (or the code that generated it).
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    #[error("the mesh has no triangles")]
    Empty,
    #[error("vertex {vertex} (0-based) has a non-finite {axis} coordinate ({value})")]
    NonFiniteCoordinate {
        vertex: usize,
        axis: char,
        value: f64,
    },
    #[error("triangle {triangle} (0-based) refers to vertex {index}, but the mesh has only {num_vertices} vertices (valid indices 0..={})", num_vertices.saturating_sub(1))]
    IndexOutOfRange {
        triangle: usize,
        index: u32,
        num_vertices: usize,
    },
    #[error("triangle {triangle} (vertices {}, {}, {}; 0-based) repeats a vertex", vertices[0], vertices[1], vertices[2])]
    RepeatedVertex { triangle: usize, vertices: [u32; 3] },
    #[error("triangle {triangle} (vertices {}, {}, {}; 0-based) has zero area (area {area:e}, tolerance {tolerance:e})", vertices[0], vertices[1], vertices[2])]
    DegenerateTriangle {
        triangle: usize,
        vertices: [u32; 3],
        area: f64,
        tolerance: f64,
    },
    #[error("triangle {triangle} (vertices {}, {}, {}; 0-based) duplicates triangle {first} (same three vertices)", vertices[0], vertices[1], vertices[2])]
    DuplicateTriangle {
        triangle: usize,
        first: usize,
        vertices: [u32; 3],
    },
    #[error("edge ({}, {}) is shared by {} triangles {triangles:?} (0-based; non-manifold: at most two allowed)", edge[0], edge[1], triangles.len())]
    NonManifoldEdge {
        edge: [u32; 2],
        triangles: Vec<usize>,
    },
}

impl MeshError {
    /// The triangle the error is about, if any (for a duplicate, the later
    /// copy; for a non-manifold edge, the triangle that made it non-manifold).
    /// Readers use it to map the error back to a source line.
    pub fn triangle(&self) -> Option<usize> {
        match self {
            Self::IndexOutOfRange { triangle, .. }
            | Self::RepeatedVertex { triangle, .. }
            | Self::DegenerateTriangle { triangle, .. }
            | Self::DuplicateTriangle { triangle, .. } => Some(*triangle),
            Self::NonManifoldEdge { triangles, .. } => triangles.last().copied(),
            Self::Empty | Self::NonFiniteCoordinate { .. } => None,
        }
    }
}

/// A mesh that can be simulated but is probably not what the user meant.
/// Indices are 0-based positions in the mesh.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MeshWarning {
    /// Vertices no triangle uses: they are simulated as free particles.
    #[error(
        "{count} vertices are used by no triangle (first 0-based ids: {})",
        join(first)
    )]
    UnreferencedVertices { count: usize, first: Vec<u32> },
    /// Interior edges traversed in the same direction by both of their
    /// triangles: normals flip across them, so bending rest angles and
    /// one-sided contact see a fold. Reports the first such edge.
    #[error("{count} interior edges are inconsistently oriented; first: edge ({}, {}) is traversed {} -> {} by both triangles {} and {} (0-based)", edge[0], edge[1], edge[0], edge[1], triangles[0], triangles[1])]
    InconsistentOrientation {
        count: usize,
        edge: [u32; 2],
        triangles: [usize; 2],
    },
}

fn join(ids: &[u32]) -> String {
    ids.iter()
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Validates `mesh`; returns warnings, or the first error found (see the
/// module docs for the order of the checks).
pub fn validate(mesh: &TriMesh) -> Result<Vec<MeshWarning>, MeshError> {
    let n = mesh.num_vertices();
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty);
    }
    for (v, p) in mesh.positions.iter().enumerate() {
        for (axis, value) in ['x', 'y', 'z'].into_iter().zip(p.to_array()) {
            if !value.is_finite() {
                return Err(MeshError::NonFiniteCoordinate {
                    vertex: v,
                    axis,
                    value,
                });
            }
        }
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&v| v as usize >= n) {
            return Err(MeshError::IndexOutOfRange {
                triangle: f,
                index,
                num_vertices: n,
            });
        }
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return Err(MeshError::RepeatedVertex {
                triangle: f,
                vertices: *t,
            });
        }
    }
    check_areas(mesh)?;
    check_duplicates(&mesh.triangles)?;
    let topo = Topology::build(n, &mesh.triangles)?;

    let mut warnings = Vec::new();
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let unused: Vec<u32> = (0..n as u32).filter(|&v| !used[v as usize]).collect();
    if !unused.is_empty() {
        warnings.push(MeshWarning::UnreferencedVertices {
            count: unused.len(),
            first: unused[..unused.len().min(LISTED_IDS)].to_vec(),
        });
    }
    // `Hinge::edge` is oriented as faces[0] traverses it; a consistent
    // neighbour must traverse it the other way.
    let mut bad = topo.hinges.iter().filter(|h| {
        let tb = &mesh.triangles[h.faces[1] as usize];
        (0..3).any(|k| tb[k] == h.edge[0] && tb[(k + 1) % 3] == h.edge[1])
    });
    if let Some(first) = bad.next() {
        warnings.push(MeshWarning::InconsistentOrientation {
            count: 1 + bad.count(),
            edge: first.edge,
            triangles: [first.faces[0] as usize, first.faces[1] as usize],
        });
    }
    Ok(warnings)
}

fn check_areas(mesh: &TriMesh) -> Result<(), MeshError> {
    let (lo, hi) = mesh.positions.iter().fold(
        (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let tolerance = DEGENERATE_AREA_REL * (hi - lo).length_squared();
    for f in 0..mesh.num_triangles() {
        let [a, b, c] = mesh.corners(f);
        let area = 0.5 * (b - a).cross(c - a).length();
        if area <= tolerance {
            return Err(MeshError::DegenerateTriangle {
                triangle: f,
                vertices: mesh.triangles[f],
                area,
                tolerance,
            });
        }
    }
    Ok(())
}

fn check_duplicates(triangles: &[[u32; 3]]) -> Result<(), MeshError> {
    let mut keyed: Vec<([u32; 3], usize)> = triangles
        .iter()
        .enumerate()
        .map(|(f, t)| {
            let mut k = *t;
            k.sort_unstable();
            (k, f)
        })
        .collect();
    keyed.sort_unstable();
    // Report the duplicate with the lowest triangle id, against its first copy.
    let mut found: Option<(usize, usize)> = None;
    let mut i = 0;
    while i < keyed.len() {
        let mut j = i + 1;
        while j < keyed.len() && keyed[j].0 == keyed[i].0 {
            j += 1;
        }
        if j - i > 1 {
            let (first, dup) = (keyed[i].1, keyed[i + 1].1);
            if found.is_none_or(|(_, d)| dup < d) {
                found = Some((first, dup));
            }
        }
        i = j;
    }
    match found {
        Some((first, triangle)) => Err(MeshError::DuplicateTriangle {
            triangle,
            first,
            vertices: triangles[triangle],
        }),
        None => Ok(()),
    }
}
