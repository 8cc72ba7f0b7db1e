//! Strain measures of a deformed triangle.

use glam::DVec3;

/// Largest absolute principal value of the Green strain `G = (FᵀF - I) / 2`
/// of a triangle whose deformation gradient has the columns `f0`, `f1` (its
/// rest triangle described in an orthonormal frame of its plane). `G` is a
/// symmetric 2×2 matrix, so its eigenvalues are `mean ± radius` of its Mohr
/// circle; 0 at the rest shape.
pub fn max_principal_green(f0: DVec3, f1: DVec3) -> f64 {
    let (g00, g11, g01) = (
        0.5 * (f0.dot(f0) - 1.0),
        0.5 * (f1.dot(f1) - 1.0),
        0.5 * f0.dot(f1),
    );
    let mean = 0.5 * (g00 + g11);
    let half = 0.5 * (g00 - g11);
    let radius = (half * half + g01 * g01).sqrt();
    (mean + radius).abs().max((mean - radius).abs())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn principal_values() {
        assert_eq!(max_principal_green(DVec3::X, DVec3::Y), 0.0);
        // Stretch by 1.1 along x: G_xx = (1.21 - 1) / 2.
        let g = max_principal_green(DVec3::X * 1.1, DVec3::Y);
        assert!((g - 0.105).abs() < 1e-15, "{g}");
        // Compression counts by magnitude.
        let g = max_principal_green(DVec3::X, DVec3::Y * 0.9);
        assert!((g - 0.095).abs() < 1e-15, "{g}");
    }
}
