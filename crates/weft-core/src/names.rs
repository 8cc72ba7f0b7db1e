//! How messages name a mesh's vertices and triangles.
//!
//! Validation errors and warnings are about elements of a [`crate::TriMesh`]:
//! 0-based positions in it ([`MeshIds`]). A mesh read from a file is better
//! described the way the file numbers things (an OBJ file's 1-based `v` numbers
//! and the line of each face; weft-io implements that), so every message is
//! written once against [`ElementNames`] and rendered with either.

/// Names for a mesh's elements in messages.
pub trait ElementNames {
    /// One vertex: `vertex 3 (0-based)`, `v 4`.
    fn vertex(&self, v: u32) -> String;
    /// A list of vertices: `vertices 0, 1, 4; 0-based`, `v 1, v 2, v 5`.
    fn vertices(&self, vs: &[u32]) -> String;
    /// One triangle: `triangle 2`, `the face on line 12`.
    fn triangle(&self, f: usize) -> String;
    /// Several triangles: `triangles 0, 1, 2 (0-based)`, `faces on lines 6, 7, 9`.
    fn triangles(&self, fs: &[usize]) -> String;
}

/// 0-based positions in the mesh, and every message says so.
pub struct MeshIds;

impl ElementNames for MeshIds {
    fn vertex(&self, v: u32) -> String {
        format!("vertex {v} (0-based)")
    }
    fn vertices(&self, vs: &[u32]) -> String {
        format!("vertices {}; 0-based", join(vs))
    }
    fn triangle(&self, f: usize) -> String {
        format!("triangle {f}")
    }
    fn triangles(&self, fs: &[usize]) -> String {
        format!("triangles {} (0-based)", join(fs))
    }
}

/// `a, b, c`.
pub fn join<T: ToString>(ids: &[T]) -> String {
    ids.iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}
