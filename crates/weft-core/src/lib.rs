//! # weft-core — the vocabulary every other weft crate speaks
//!
//! * [`Real`] is `f64` everywhere; vectors are glam's [`DVec3`].
//! * Vertex and triangle indices are `u32` **input ids**: the position of the
//!   vertex / triangle in the scene's concatenated input meshes. Every key that
//!   decides an order (stencil keys, fold orders, output order) is built from
//!   input ids, so results never depend on how the mesh is split or renumbered.
//! * [`TriMesh`] is a plain indexed triangle mesh; [`topology::Topology`] derives
//!   edges, hinges, adjacency and boundary from it; [`validate`](fn@validate) checks a mesh and
//!   names the offending element in every error; [`coincident`] finds
//!   vertices at exactly the same position (an unwelded mesh).
//! * [`StencilKey`] is the global, partition-independent key of a contact stencil.

pub mod coincident;
pub mod mesh;
pub mod names;
pub mod stencil;
pub mod topology;
pub mod validate;

pub use glam::DVec3;
pub use mesh::TriMesh;
pub use names::{ElementNames, MeshIds};
pub use stencil::{StencilKey, StencilKind};
pub use topology::{Hinge, Topology, VertexFaces};
pub use validate::{validate, MeshError, MeshWarning, MAX_COORDINATE};

/// The one floating-point type of weft.
pub type Real = f64;

/// The smaller of `a` and `b`, or NaN if either is one. `f64::min` drops a
/// NaN, and a bound folded that way would lose the NaN that must make it
/// certify nothing.
#[inline]
pub fn nan_min(a: f64, b: f64) -> f64 {
    if a < b || a.is_nan() {
        a
    } else {
        b
    }
}

/// The larger of `a` and `b`, or NaN if either is one (see [`nan_min`]).
#[inline]
pub fn nan_max(a: f64, b: f64) -> f64 {
    if a > b || a.is_nan() {
        a
    } else {
        b
    }
}

/// Marker for "no such element" in `u32` index arrays (e.g. the missing face of a
/// boundary edge).
pub const NONE: u32 = u32::MAX;
