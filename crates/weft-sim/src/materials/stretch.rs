//! Constant-strain triangle with the St. Venant–Kirchhoff membrane energy.
//!
//! Rest data: the rest edges `Dm = [X1 - X0, X2 - X0]` written in an orthonormal
//! 2-D frame of the rest triangle whose first axis is `X1 - X0`, so `Dm` is upper
//! triangular,
//!
//! ```text
//!     Dm = [ a  b ]      a = |X1 - X0|,  b = (X2 - X0)·(X1 - X0)/a,  c = 2 A / a
//!          [ 0  c ]      Dm^-1 = [ 1/a  -b/(a c) ] = [ p  q ]
//!                                [ 0     1/c     ]   [ 0  r ]
//! ```
//!
//! and only `p, q, r` and the rest area `A` are stored. With `Ds = [x1 - x0, x2 - x0]`:
//!
//! ```text
//!     F = Ds Dm^-1 = [f0 f1],    f0 = p d1,  f1 = q d1 + r d2
//!     G = (F^T F - I)/2,         S = 2 mu G + lambda tr(G) I
//!     V = A h (mu tr(G²) + lambda/2 tr(G)²)
//!     dV/dDs = A h F S Dm^-T  =>  g1 = A h (P0 p + P1 q),  g2 = A h P1 r,  g0 = -(g1 + g2)
//! ```
//!
//! with `P = F S = [P0 P1]`. `V` depends on `x` only through `F^T F`, so it is
//! invariant under rigid motions and its gradient conserves linear and angular
//! momentum. Damping uses the same path with the viscous stress
//! `S_d = c (2 mu Ġ + lambda tr(Ġ) I)`, `Ġ = sym(F^T Ḟ)`, `Ḟ = Dv Dm^-1`: `Ġ = 0`
//! for a rigid velocity, and the force is `-∂/∂x (S_d : G)` at frozen `S_d`, the
//! gradient of a rotation-invariant function, so it conserves both momenta.

use super::{Material, MaterialError};
use glam::DVec3;

/// Rest triangles with `2 A / (longest edge)²` at or below this are rejected.
pub const MIN_TRIANGLE_QUALITY: f64 = 1e-10;

/// One constant-strain membrane triangle (48 bytes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StretchElement {
    /// Vertex input ids `[x0, x1, x2]`.
    pub verts: [u32; 3],
    /// `[p, q, r]` of `Dm^-1 = [[p, q], [0, r]]`.
    dm_inv: [f64; 3],
    /// Rest area `A`.
    area: f64,
}

impl StretchElement {
    /// Words per element in [`StretchElement::to_words`].
    pub const WORDS: usize = 7;

    /// The element as words, every bit kept (its vertex ids exactly, as
    /// integers below 2^53): what moves with a partition to another rank.
    pub fn to_words(&self) -> [f64; Self::WORDS] {
        let [a, b, c] = self.verts.map(f64::from);
        let [p, q, r] = self.dm_inv;
        [a, b, c, p, q, r, self.area]
    }

    /// The element of [`StretchElement::to_words`]; `None` when a vertex
    /// id is not a `u32`.
    pub fn from_words(w: &[f64; Self::WORDS]) -> Option<Self> {
        let id = super::vertex_id_of_word;
        Some(Self {
            verts: [id(w[0])?, id(w[1])?, id(w[2])?],
            dm_inv: [w[3], w[4], w[5]],
            area: w[6],
        })
    }

    /// Builds the element from its rest positions (which may differ from the
    /// initial shape). Fails on a non-finite or (near-)degenerate rest triangle.
    pub fn new(verts: [u32; 3], rest: [DVec3; 3]) -> Result<Self, MaterialError> {
        let e1 = rest[1] - rest[0];
        let e2 = rest[2] - rest[0];
        let e3 = rest[2] - rest[1];
        let a = e1.length();
        let nn = e1.cross(e2).length(); // 2 A
        let longest2 = e1
            .length_squared()
            .max(e2.length_squared())
            .max(e3.length_squared());
        let quality = nn / longest2;
        if !(quality.is_finite() && quality > MIN_TRIANGLE_QUALITY) {
            return Err(MaterialError::DegenerateTriangle {
                verts,
                quality,
                min_quality: MIN_TRIANGLE_QUALITY,
            });
        }
        let b = e2.dot(e1) / a;
        Ok(Self {
            verts,
            dm_inv: [1.0 / a, -b / nn, a / nn],
            area: 0.5 * nn,
        })
    }

    /// Rest area `A`, m².
    #[inline]
    pub fn rest_area(&self) -> f64 {
        self.area
    }

    /// Largest absolute principal Green strain at `x` (0 at the rest shape):
    /// the eigenvalues of `G = (FᵀF - I) / 2`, a symmetric 2×2 matrix.
    pub fn max_principal_strain(&self, x: &[DVec3; 3]) -> f64 {
        let (f0, f1) = self.deformation(x);
        weft_geom::strain::max_principal_green(f0, f1)
    }

    /// Deformation gradient columns `f0, f1`.
    #[inline(always)]
    fn deformation(&self, x: &[DVec3; 3]) -> (DVec3, DVec3) {
        let [p, q, r] = self.dm_inv;
        let d1 = x[1] - x[0];
        let d2 = x[2] - x[0];
        (d1 * p, d1 * q + d2 * r)
    }

    /// `[g0, g1, g2]` for the first Piola–Kirchhoff stress `F S` of the symmetric
    /// stress `S = [[s00, s01], [s01, s11]]`, scaled by `scale`.
    #[inline(always)]
    fn nodal(&self, f0: DVec3, f1: DVec3, s00: f64, s01: f64, s11: f64, scale: f64) -> [DVec3; 3] {
        let [p, q, r] = self.dm_inv;
        let p0 = f0 * s00 + f1 * s01;
        let p1 = f0 * s01 + f1 * s11;
        let g1 = (p0 * p + p1 * q) * scale;
        let g2 = p1 * (r * scale);
        [-(g1 + g2), g1, g2]
    }

    /// Membrane energy `A h (mu tr(G²) + lambda/2 tr(G)²)`, J.
    #[inline]
    pub fn energy(&self, x: &[DVec3; 3], m: &Material) -> f64 {
        let (lambda, mu) = m.lame();
        let (f0, f1) = self.deformation(x);
        let g00 = 0.5 * (f0.dot(f0) - 1.0);
        let g11 = 0.5 * (f1.dot(f1) - 1.0);
        let g01 = 0.5 * f0.dot(f1);
        let tr = g00 + g11;
        self.area
            * m.thickness
            * (mu * (g00 * g00 + g11 * g11 + 2.0 * g01 * g01) + 0.5 * lambda * tr * tr)
    }

    /// `dV/dx` for the three vertices (the gradient, not the force).
    #[inline(always)]
    pub fn gradient(&self, x: &[DVec3; 3], m: &Material) -> [DVec3; 3] {
        let (lambda, mu) = m.lame();
        let (f0, f1) = self.deformation(x);
        let g00 = 0.5 * (f0.dot(f0) - 1.0);
        let g11 = 0.5 * (f1.dot(f1) - 1.0);
        let g01 = 0.5 * f0.dot(f1);
        let lt = lambda * (g00 + g11);
        let mu2 = 2.0 * mu;
        self.nodal(
            f0,
            f1,
            mu2 * g00 + lt,
            mu2 * g01,
            mu2 * g11 + lt,
            self.area * m.thickness,
        )
    }

    /// Viscous membrane force (a force, not a gradient) for vertex velocities `v`:
    /// stress `stretch_damping · (2 mu Ġ + lambda tr(Ġ) I)`, `Ġ = sym(F^T Ḟ)`.
    /// Sums to zero, has zero torque and vanishes for rigid motion.
    #[inline(always)]
    pub fn damping_force(&self, x: &[DVec3; 3], v: &[DVec3; 3], m: &Material) -> [DVec3; 3] {
        let c = m.stretch_damping;
        if c == 0.0 {
            return [DVec3::ZERO; 3];
        }
        let (lambda, mu) = m.lame();
        let (f0, f1) = self.deformation(x);
        let (fd0, fd1) = self.deformation(v);
        let gd00 = f0.dot(fd0);
        let gd11 = f1.dot(fd1);
        let gd01 = 0.5 * (f0.dot(fd1) + f1.dot(fd0));
        let lt = lambda * (gd00 + gd11);
        let mu2 = 2.0 * mu;
        self.nodal(
            f0,
            f1,
            mu2 * gd00 + lt,
            mu2 * gd01,
            mu2 * gd11 + lt,
            -c * self.area * m.thickness,
        )
    }
}
