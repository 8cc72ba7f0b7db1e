//! Discrete-shells bending hinge (Grinspun et al. 2003) with the exact angle gradient.
//!
//! A hinge is an interior edge `[x0, x1]` with wings `x2` (face A) and `x3` (face B),
//! oriented like [`weft_core::Hinge`]. With `e = x1 - x0`,
//!
//! ```text
//!     nA = e × (x2 - x0),   nB = (x3 - x0) × e
//!     theta = atan2( (nA × nB)·e/|e|,  nA·nB )                  (signed, in [-pi, pi])
//!     V = k_b · w · (theta - theta_rest)²,   w = 3 |e_rest|² / A_rest
//! ```
//!
//! where `A_rest` is the sum of the two rest triangle areas and the difference
//! `theta - theta_rest` is wrapped into `[-pi, pi]`, so a hinge folded through
//! `±pi` stays smooth. The angle gradient (`acm-spec.md` §2.1) is
//!
//! ```text
//!     dθ/dx2 = -|e| nA/|nA|²,   dθ/dx3 = -|e| nB/|nB|²
//!     dθ/dx0 = -[ ((x2-x1)·e)/(|e| |nA|²) nA + ((x3-x1)·e)/(|e| |nB|²) nB ]
//!     dθ/dx1 = +[ ((x2-x0)·e)/(|e| |nA|²) nA + ((x3-x0)·e)/(|e| |nB|²) nB ]
//! ```
//!
//! These sum to zero and have zero torque (theta is invariant under rigid motion).
//!
//! # Calibration
//!
//! A regular mesh bent to a cylinder of radius `R` folds along parallel edge lines
//! and stores `3 k_b / R²` per area (derivation in the [module docs](super)); a
//! plate stores `D / (2 R²)`, so `k_b = D/6`.
//!
//! # Damping
//!
//! Rayleigh dissipation `R = bend_damping · w · θ̇²`, force
//! `-2 · bend_damping · w · θ̇ · dθ/dx` with `θ̇ = Σ dθ/dx_i · v_i`: with
//! `bend_damping = alpha k_b` this is the stiffness-proportional damping
//! `alpha K_bend` at rest.

use super::{Material, MaterialError};
use core::f64::consts::PI;
use glam::DVec3;

/// A wing with `2·area / |e|² ` at or below this is degenerate.
pub const MIN_WING_QUALITY: f64 = 1e-10;

/// One bending hinge (32 bytes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HingeElement {
    /// Vertex input ids `[x0, x1, x2, x3]`: edge `[x0, x1]`, wings `[x2, x3]`.
    pub verts: [u32; 4],
    /// Rest dihedral angle.
    rest_angle: f64,
    /// `3 |e_rest|² / A_rest`.
    weight: f64,
}

/// Signed dihedral angle of the hinge `[x0, x1, x2, x3]`: 0 when flat, positive
/// when the wings fold towards `-nA` (see the module docs for the convention).
/// Returns 0 for a hinge with a zero-length edge or a collinear wing.
#[inline]
pub fn dihedral_angle(x: &[DVec3; 4]) -> f64 {
    let e = x[1] - x[0];
    let na = e.cross(x[2] - x[0]);
    let nb = (x[3] - x[0]).cross(e);
    let el = e.length();
    if el == 0.0 {
        return 0.0;
    }
    libm::atan2(na.cross(nb).dot(e) / el, na.dot(nb))
}

/// Wraps an angle difference in `[-2 pi, 2 pi]` into `[-pi, pi]`.
#[inline(always)]
fn wrap(d: f64) -> f64 {
    if d > PI {
        d - 2.0 * PI
    } else if d < -PI {
        d + 2.0 * PI
    } else {
        d
    }
}

/// `(theta, dθ/dx)`; the gradient is zero for a degenerate current shape.
#[inline(always)]
fn angle_and_gradient(x: &[DVec3; 4]) -> (f64, [DVec3; 4]) {
    match angle_terms(x) {
        Some((t, g)) => (libm::atan2(t.0, t.1), g),
        None => (dihedral_angle(x), [DVec3::ZERO; 4]),
    }
}

/// `dθ/dx` alone (zero for a degenerate current shape): the damping force
/// needs no angle, and `atan2` is the costliest step of a hinge (with two
/// per hinge, it took a fifth of a 10k twister run).
#[inline(always)]
fn angle_gradient(x: &[DVec3; 4]) -> [DVec3; 4] {
    angle_terms(x).map_or([DVec3::ZERO; 4], |(_, g)| g)
}

/// The arguments of the angle's `atan2`, `(y, x)`, and `dθ/dx`; `None` for
/// a degenerate current shape.
#[inline(always)]
fn angle_terms(x: &[DVec3; 4]) -> Option<((f64, f64), [DVec3; 4])> {
    let e = x[1] - x[0];
    let na = e.cross(x[2] - x[0]);
    let nb = (x[3] - x[0]).cross(e);
    let el2 = e.length_squared();
    let na2 = na.length_squared();
    let nb2 = nb.length_squared();
    if el2 == 0.0 || na2 == 0.0 || nb2 == 0.0 {
        return None;
    }
    let el = el2.sqrt();
    // One division for 1/|e|, 1/|nA|², 1/|nB|².
    let r = 1.0 / (el * na2 * nb2);
    let inv_el = r * na2 * nb2;
    let inv_na2 = r * el * nb2;
    let inv_nb2 = r * el * na2;
    let atan2_args = (na.cross(nb).dot(e) * inv_el, na.dot(nb));
    // Scaled normals: nA/|nA|², nB/|nB|².
    let ua = na * inv_na2;
    let ub = nb * inv_nb2;
    let g2 = ua * (-el);
    let g3 = ub * (-el);
    let g1 = ua * ((x[2] - x[0]).dot(e) * inv_el) + ub * ((x[3] - x[0]).dot(e) * inv_el);
    // The four sum to zero (translation invariance); this equals the dθ/dx0 formula.
    let g0 = -(g1 + g2 + g3);
    Some((atan2_args, [g0, g1, g2, g3]))
}

impl HingeElement {
    /// Words per element in [`HingeElement::to_words`].
    pub const WORDS: usize = 6;

    /// The element as words, every bit kept (its vertex ids exactly, as
    /// integers below 2^53): what moves with a partition to another rank.
    pub fn to_words(&self) -> [f64; Self::WORDS] {
        let [a, b, c, d] = self.verts.map(f64::from);
        [a, b, c, d, self.rest_angle, self.weight]
    }

    /// The element of [`HingeElement::to_words`]; `None` when a vertex id
    /// is not a `u32`.
    pub fn from_words(w: &[f64; Self::WORDS]) -> Option<Self> {
        let id = super::vertex_id_of_word;
        Some(Self {
            verts: [id(w[0])?, id(w[1])?, id(w[2])?, id(w[3])?],
            rest_angle: w[4],
            weight: w[5],
        })
    }

    /// Builds the hinge from its rest positions. Fails when the rest edge has zero
    /// length, a rest wing is (nearly) collinear with the edge, or a coordinate is
    /// not finite.
    pub fn new(verts: [u32; 4], rest: [DVec3; 4]) -> Result<Self, MaterialError> {
        let degenerate = |what| MaterialError::DegenerateHinge {
            verts,
            edge: [verts[0], verts[1]],
            wings: [verts[2], verts[3]],
            what,
        };
        if !rest.iter().all(|p| p.is_finite()) {
            return Err(degenerate("non-finite rest coordinate"));
        }
        let e = rest[1] - rest[0];
        let el2 = e.length_squared();
        if el2 == 0.0 {
            return Err(degenerate("zero-length rest edge"));
        }
        let na = e.cross(rest[2] - rest[0]).length();
        let nb = (rest[3] - rest[0]).cross(e).length();
        if na <= MIN_WING_QUALITY * el2 || nb <= MIN_WING_QUALITY * el2 {
            return Err(degenerate("a rest wing is collinear with the edge"));
        }
        let area = 0.5 * (na + nb);
        Ok(Self {
            verts,
            rest_angle: dihedral_angle(&rest),
            weight: 3.0 * el2 / area,
        })
    }

    /// Rest dihedral angle, rad.
    #[inline]
    pub fn rest_angle(&self) -> f64 {
        self.rest_angle
    }

    /// Geometric weight `3 |e_rest|² / A_rest` (dimensionless).
    #[inline]
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// Bending energy `k_b w (theta - theta_rest)²`, J.
    #[inline]
    pub fn energy(&self, x: &[DVec3; 4], k_b: f64) -> f64 {
        let d = wrap(dihedral_angle(x) - self.rest_angle);
        k_b * self.weight * d * d
    }

    /// `dV/dx` for the four vertices (the gradient, not the force).
    #[inline(always)]
    pub fn gradient(&self, x: &[DVec3; 4], k_b: f64) -> [DVec3; 4] {
        let (theta, g) = angle_and_gradient(x);
        let s = 2.0 * k_b * self.weight * wrap(theta - self.rest_angle);
        [g[0] * s, g[1] * s, g[2] * s, g[3] * s]
    }

    /// Hinge-rate damping force `-2 bend_damping w θ̇ dθ/dx` (a force). Sums to
    /// zero, has zero torque and vanishes for rigid motion.
    #[inline(always)]
    pub fn damping_force(&self, x: &[DVec3; 4], v: &[DVec3; 4], m: &Material) -> [DVec3; 4] {
        let c = m.bend_damping;
        if c == 0.0 {
            return [DVec3::ZERO; 4];
        }
        let g = angle_gradient(x);
        let rate = g[0].dot(v[0]) + g[1].dot(v[1]) + g[2].dot(v[2]) + g[3].dot(v[3]);
        let s = -2.0 * c * self.weight * rate;
        [g[0] * s, g[1] * s, g[2] * s, g[3] * s]
    }
}
