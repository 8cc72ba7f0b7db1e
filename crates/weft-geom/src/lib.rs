//! # weft-geom — pure geometry, no simulation state
//!
//! Distances with gradients, 26-DOPs and their BVH, the conservative continuous
//! proximity predicate used by the narrow phase (and by `weft ccd-bench`),
//! exact triangle–triangle intersection, polygon triangulation for the mesh
//! readers, and the CCD benchmark reader.

pub mod bvh;
pub mod ccd;
pub mod distance;
pub mod dop;
pub mod intersections;
pub mod knots;
pub mod polygon;
pub mod ribbon;
pub mod shapes;
pub mod strain;
pub mod tri_tri;
pub mod voxel;
