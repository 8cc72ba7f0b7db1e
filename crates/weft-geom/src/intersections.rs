//! Self-intersections of a triangle mesh (the initial-state check of spec §4).
//!
//! Broad phase: a [`Bvh`] over each triangle's 26-DOP with zero inflation. The
//! rounding margin is built into [`Dop26::add_point`], whose intervals contain
//! the exact projections of the corners, so two triangles that share even a
//! single point have overlapping DOPs and are never pruned. Narrow phase: the
//! exact [`triangles_intersect`]. Pairs that share a vertex id are skipped
//! (adjacent triangles always touch).

use crate::bvh::Bvh;
use crate::dop::Dop26;
use crate::tri_tri::triangles_intersect;
use weft_core::DVec3;

/// All pairs `(i, j)`, `i < j`, of triangles that share no vertex id and
/// intersect (touching counts), sorted ascending.
///
/// Triangles referencing a vertex outside `positions` are ignored (mesh
/// validation in `weft-core` rejects such meshes before this is called).
pub fn mesh_self_intersections(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let valid = |t: &[u32; 3]| t.iter().all(|&v| (v as usize) < positions.len());
    let leaves: Vec<Dop26> = triangles
        .iter()
        .map(|t| {
            let mut d = Dop26::empty();
            if valid(t) {
                for &v in t {
                    d.add_point(positions[v as usize]);
                }
            }
            d
        })
        .collect();
    let corners = |t: &[u32; 3]| t.map(|v| positions[v as usize]);
    // The leaves moved into the tree, not copied: on a large mesh this
    // check is the peak of a rank's memory at the start (208 bytes a
    // triangle).
    let bvh = Bvh::build_owned(leaves);
    let mut out = Vec::new();
    bvh.self_overlaps(|i, j| {
        let (ti, tj) = (&triangles[i as usize], &triangles[j as usize]);
        if ti.iter().any(|v| tj.contains(v)) {
            return;
        }
        if triangles_intersect(&corners(ti), &corners(tj)) {
            out.push((i, j));
        }
    });
    out.sort_unstable();
    out
}
