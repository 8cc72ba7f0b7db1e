//! Cloth materials: the internal forces of `acm-spec.md` §2.1.
//!
//! | file | what |
//! |------|------|
//! | [`stretch`] | constant-strain triangle, St. Venant–Kirchhoff membrane + viscous strain-rate damping |
//! | [`bend`] | discrete-shells hinge (signed dihedral angle) + hinge-rate damping |
//! | [`mass`] | lumped vertex masses, gravity |
//! | [`assembly`] | [`ElasticModel`]: the element sets of one scene, assembled energy / gradient / damping |
//! | [`step`] | `omega_max` of the assembled rest system (Lanczos + Gershgorin), stable step, damping limit |
//!
//! Every element returns the **gradient** `dV/dx` of its potential (the AVI kick is
//! `v_i -= h w_i g_i`); damping returns a **force**. All element code works on a
//! local copy of the stencil's positions (`[DVec3; 3]` or `[DVec3; 4]`), allocates
//! nothing and uses only `+ - * /` and `sqrt` except [`dihedral_angle`], which uses
//! `libm::atan2` so results are bit-identical on every platform.
//!
//! # Units
//!
//! SI throughout. [`Material::stretch_damping`] is a time (s): the viscous stress is
//! `stretch_damping · (2 mu Ġ + lambda tr(Ġ) I)`, i.e. stiffness-proportional
//! (Rayleigh) damping of the membrane. [`Material::bend_damping`] is `k_b · s` (J·s):
//! `bend_damping = alpha · k_b` gives stiffness-proportional damping of the hinges
//! with the same time constant `alpha`.
//!
//! # Bending calibration
//!
//! A flat regular mesh bends isometrically only by folding along a family of
//! parallel straight edge lines (the generators of the cylinder). With fold lines
//! `s` apart and edges of length `l` on them, each such hinge has `A_rest = l s`,
//! angle `theta = s / R` and weight `3 l² / (l s)`, and there is one per area `l s`:
//!
//! ```text
//!     V / area = k_b · 3 l/s · (s/R)² / (l s) = 3 k_b / R²
//! ```
//!
//! for every regular mesh (right-triangle grids along either axis or the diagonal,
//! equilateral meshes along an edge direction). A Kirchhoff plate bent to a
//! cylinder stores `D / (2 R²)`, hence `k_b = D/6`
//! ([`Material::default_bending_stiffness`]); `tests/materials.rs` checks both on
//! bent strips.

pub mod assembly;
pub mod bend;
pub mod mass;
pub mod step;
pub mod stretch;

pub use assembly::ElasticModel;
pub use bend::{dihedral_angle, HingeElement};
pub use mass::{gravity_gradient, lumped_masses};
pub use step::{damping_step_limit, stable_step};
pub use stretch::StretchElement;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// The whole number below `below` (at most 2^32) that word `x` holds
/// exactly; `None` for anything else: how ids and counts sent between
/// ranks as words are read back.
pub(crate) fn whole_below(x: f64, below: u64) -> Option<u32> {
    ((0.0..below as f64).contains(&x) && x.fract() == 0.0).then_some(x as u32)
}

/// The vertex id a word holds exactly ([`StretchElement::to_words`]);
/// `None` for anything but a whole number in `u32`'s range.
fn vertex_id_of_word(x: f64) -> Option<u32> {
    whole_below(x, 1 << 32)
}

/// An error in the material model: invalid parameters or a rest shape that
/// cannot carry an element.
///
/// When this error occurs: at setup, when a [`Material`] is validated, an element
/// is built from its rest shape, or damping is checked against the step. How to
/// handle it: the message names the parameter or element and the fix.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MaterialError {
    /// A material parameter is out of its admissible range.
    #[error("material parameter `{parameter}` = {value:e} is invalid: it must be {requirement}")]
    InvalidParameter {
        parameter: &'static str,
        value: f64,
        requirement: &'static str,
    },
    /// A rest triangle with (near-)zero area or a non-finite coordinate
    /// (`verts` are input ids; [`MaterialError::in_object`] makes them the
    /// object's own).
    #[error(
        "the rest triangle of vertices #{}, #{}, #{} is degenerate (2·area / longest edge² = \
         {quality:e}, needs > {min_quality:e} and finite coordinates): fix the rest shape of \
         this triangle or remove it",
        verts[0], verts[1], verts[2]
    )]
    DegenerateTriangle {
        verts: [u32; 3],
        quality: f64,
        min_quality: f64,
    },
    /// A rest hinge whose edge or one of whose wings is degenerate (input
    /// ids, as for `DegenerateTriangle`).
    #[error(
        "the bending hinge on edge #{}–#{} (wing vertices #{}, #{}) has a degenerate rest shape \
         ({what}): fix the rest shape of its two triangles",
        edge[0], edge[1], wings[0], wings[1]
    )]
    DegenerateHinge {
        verts: [u32; 4],
        edge: [u32; 2],
        wings: [u32; 2],
        what: &'static str,
    },
    /// Element arrays that do not fit together (a caller bug).
    #[error("inconsistent material input: {0}")]
    Inconsistent(String),
}

impl MaterialError {
    /// The same error with its vertex ids relative to an object whose
    /// vertices start at input id `first` (what messages name).
    pub fn in_object(self, first: u32) -> Self {
        let local = |v: u32| v - first;
        match self {
            Self::DegenerateTriangle {
                verts,
                quality,
                min_quality,
            } => Self::DegenerateTriangle {
                verts: verts.map(local),
                quality,
                min_quality,
            },
            Self::DegenerateHinge {
                verts,
                edge,
                wings,
                what,
            } => Self::DegenerateHinge {
                verts: verts.map(local),
                edge: edge.map(local),
                wings: wings.map(local),
                what,
            },
            other => other,
        }
    }
}

/// The material of one cloth (SI units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Mass per rest area, kg/m².
    pub area_density: f64,
    /// Young's modulus E, Pa.
    pub youngs_modulus: f64,
    /// Poisson's ratio nu, in (-1, 0.5).
    pub poisson_ratio: f64,
    /// Thickness h, m.
    pub thickness: f64,
    /// Hinge stiffness k_b, J (N·m); [`Material::default_bending_stiffness`] is the
    /// plate-calibrated value.
    pub bending_stiffness: f64,
    /// Viscous membrane time constant, s (0 = off).
    pub stretch_damping: f64,
    /// Hinge-rate damping coefficient, J·s (0 = off).
    pub bend_damping: f64,
}

impl Material {
    /// An undamped material with the plate-calibrated hinge stiffness
    /// `k_b = D / 6` ([`Material::default_bending_stiffness`]).
    pub fn plate(
        area_density: f64,
        youngs_modulus: f64,
        poisson_ratio: f64,
        thickness: f64,
    ) -> Self {
        let mut m = Self {
            area_density,
            youngs_modulus,
            poisson_ratio,
            thickness,
            bending_stiffness: 0.0,
            stretch_damping: 0.0,
            bend_damping: 0.0,
        };
        m.bending_stiffness = m.default_bending_stiffness();
        m
    }

    /// Checks every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<(), MaterialError> {
        let bad = |parameter, value, requirement| {
            Err(MaterialError::InvalidParameter {
                parameter,
                value,
                requirement,
            })
        };
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if !pos(self.area_density) {
            return bad("density", self.area_density, "finite and > 0 (kg/m²)");
        }
        if !pos(self.youngs_modulus) {
            return bad("youngs_modulus", self.youngs_modulus, "finite and > 0 (Pa)");
        }
        let nu = self.poisson_ratio;
        if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
            return bad(
                "poisson_ratio",
                nu,
                "in (-1, 0.5) (0.5 is incompressible, which plane stress cannot represent)",
            );
        }
        if !pos(self.thickness) {
            return bad("thickness", self.thickness, "finite and > 0 (m)");
        }
        if !nonneg(self.bending_stiffness) {
            return bad(
                "bending_stiffness",
                self.bending_stiffness,
                "finite and >= 0 (J); use default_bending_stiffness() for a plate",
            );
        }
        if !nonneg(self.stretch_damping) {
            return bad(
                "stretch_damping",
                self.stretch_damping,
                "finite and >= 0 (s)",
            );
        }
        if !nonneg(self.bend_damping) {
            return bad("bend_damping", self.bend_damping, "finite and >= 0 (J·s)");
        }
        Ok(())
    }

    /// Plane-stress Lamé parameters `(lambda, mu)`:
    /// `lambda = E nu / (1 - nu²)`, `mu = E / (2 (1 + nu))`.
    #[inline]
    pub fn lame(&self) -> (f64, f64) {
        let (e, nu) = (self.youngs_modulus, self.poisson_ratio);
        (e * nu / (1.0 - nu * nu), e / (2.0 * (1.0 + nu)))
    }

    /// Plate bending stiffness `D = E h³ / (12 (1 - nu²))`, N·m.
    pub fn plate_stiffness(&self) -> f64 {
        let (e, nu, h) = (self.youngs_modulus, self.poisson_ratio, self.thickness);
        e * h * h * h / (12.0 * (1.0 - nu * nu))
    }

    /// Hinge stiffness that makes a regular mesh bent to a cylinder store the
    /// Kirchhoff plate energy `D / (2 R²)` per area: `k_b = D / 6` (see the
    /// module docs).
    pub fn default_bending_stiffness(&self) -> f64 {
        self.plate_stiffness() / 6.0
    }
}
