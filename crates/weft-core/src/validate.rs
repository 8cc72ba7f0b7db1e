//! Mesh validation: errors name the offending element.

use crate::mesh::TriMesh;
use thiserror::Error;

/// A mesh that cannot be simulated. Indices are 0-based positions in the mesh.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    #[error("triangle {triangle} refers to vertex {index}, but the mesh has only {num_vertices} vertices")]
    IndexOutOfRange {
        triangle: usize,
        index: u32,
        num_vertices: usize,
    },
    #[error("triangle {triangle} repeats a vertex: {vertices:?}")]
    RepeatedVertex { triangle: usize, vertices: [u32; 3] },
    #[error("edge {edge:?} is shared by {} triangles {triangles:?} (non-manifold; at most two allowed)", triangles.len())]
    NonManifoldEdge { edge: [u32; 2], triangles: Vec<usize> },
}

/// A mesh that can be simulated but is probably not what the user meant.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum MeshWarning {}

/// Validates `mesh`; returns warnings, or the first error found.
pub fn validate(mesh: &TriMesh) -> Result<Vec<MeshWarning>, MeshError> {
    crate::topology::Topology::build(mesh.num_vertices(), &mesh.triangles)?;
    Ok(Vec::new())
}
