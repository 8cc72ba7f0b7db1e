//! Vertices at exactly the same position.
//!
//! Some exporters write one vertex per triangle corner (an *unwelded* mesh):
//! neighbouring triangles then share positions but no vertices, so a cloth
//! made of them holds together nowhere and starts in contact with itself
//! everywhere. Finding them is a sort of the exact positions, `O(n log n)`.

use glam::DVec3;

/// Groups of two or more vertices at exactly the same position: each group in
/// increasing vertex order, the groups ordered by their first vertex.
/// Positions must be finite (`0.0` and `-0.0` are the same position).
pub fn coincident_vertices(positions: &[DVec3]) -> Vec<Vec<u32>> {
    // `+ 0.0` turns -0.0 into 0.0, so equal positions have equal bits.
    let key = |v: u32| {
        (positions[v as usize] + DVec3::ZERO)
            .to_array()
            .map(f64::to_bits)
    };
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_unstable_by_key(|&v| (key(v), v));
    let mut groups: Vec<Vec<u32>> = order
        .chunk_by(|&a, &b| key(a) == key(b))
        .filter(|run| run.len() > 1)
        .map(<[u32]>::to_vec)
        .collect();
    groups.sort_unstable_by_key(|g| g[0]);
    groups
}
