//! Lumped vertex masses and gravity.
//!
//! Each triangle of rest area `A` and area density `rho` gives `rho A / 3` to each
//! of its vertices, so the masses sum to `Σ rho A` exactly up to round-off.
//! Gravity is the linear potential `V_i = -m_i g·x_i` per vertex, gradient
//! `-m_i g`, kicked on the internal clock.

use glam::DVec3;

/// Lumped masses of `num_vertices` vertices: each triangle (input ids, already
/// validated to be in range) adds `area_density[t] · A_rest / 3` to each of its
/// vertices, the rest area taken from `rest`. Vertices in no triangle get 0.
///
/// Panics if `area_density` does not have one entry per triangle.
pub fn lumped_masses(
    num_vertices: usize,
    triangles: &[[u32; 3]],
    rest: &[DVec3],
    area_density: &[f64],
) -> Vec<f64> {
    assert_eq!(
        triangles.len(),
        area_density.len(),
        "lumped_masses: one area density per triangle is required"
    );
    let mut m = vec![0.0; num_vertices];
    for (t, &rho) in triangles.iter().zip(area_density) {
        let [a, b, c] = t.map(|i| rest[i as usize]);
        let third = rho * 0.5 * (b - a).cross(c - a).length() / 3.0;
        for &i in t {
            m[i as usize] += third;
        }
    }
    m
}

/// Gradient of the gravity potential `-m g·x` of a vertex of mass `mass` under the
/// acceleration `g` (e.g. `(0, 0, -9.81)` m/s²): `-m g`.
#[inline]
pub fn gravity_gradient(mass: f64, g: DVec3) -> DVec3 {
    -mass * g
}
