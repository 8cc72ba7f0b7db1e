//! The state hash: a fixed algorithm (XXH3-128) over the bits of the state in
//! input order, so two runs agree on it exactly when their states are equal.

use crate::world::World;

/// Hex digest of tick, window index, x, v, tau (all vertices in input order) and
/// the sorted active-layer set with depths and retirement counters.
pub fn state_hash(w: &World) -> String {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(&w.tick.to_le_bytes());
    h.update(&w.window_index.to_le_bytes());
    for i in 0..w.x.len() {
        for c in w.x[i].to_array().into_iter().chain(w.v[i].to_array()) {
            h.update(&c.to_bits().to_le_bytes());
        }
        h.update(&w.tau[i].to_le_bytes());
    }
    h.update(&(w.layers.stencils.len() as u64).to_le_bytes());
    for (k, s) in &w.layers.stencils {
        h.update(&[k.kind as u8]);
        for id in k.v {
            h.update(&id.to_le_bytes());
        }
        h.update(&s.depth.to_le_bytes());
        h.update(&s.calm_windows.to_le_bytes());
    }
    format!("{:032x}", h.digest128())
}

/// Hex digest of what a world is built from and does not change while it
/// runs: triangles, masses (hence which vertices are kinematic) and the
/// initial positions and velocities. A checkpoint stores it so a resume can
/// refuse a scene whose meshes changed since.
pub fn world_fingerprint(w: &World) -> String {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(&(w.x.len() as u64).to_le_bytes());
    for t in &w.triangles {
        for i in t {
            h.update(&i.to_le_bytes());
        }
    }
    for i in 0..w.x.len() {
        let values = [w.mass[i], w.inv_mass[i]]
            .into_iter()
            .chain(w.x[i].to_array())
            .chain(w.v[i].to_array());
        for c in values {
            h.update(&c.to_bits().to_le_bytes());
        }
    }
    format!("{:032x}", h.digest128())
}
