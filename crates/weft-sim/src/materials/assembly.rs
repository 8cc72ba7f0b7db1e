//! The elastic element sets of a scene and their assembled energy, gradient and
//! damping force (used at setup for the step bound and by tests as the reference;
//! the engine evaluates the same element functions per event).

use super::{HingeElement, Material, MaterialError, StretchElement};
use glam::DVec3;

/// Borrowed view of all stretch and bend elements, each with an index into a
/// material table (hinges use their material's `bending_stiffness` and
/// `bend_damping`).
#[derive(Clone, Copy, Debug)]
pub struct ElasticModel<'a> {
    pub stretch: &'a [StretchElement],
    /// Material index of each stretch element.
    pub stretch_material: &'a [u16],
    pub hinges: &'a [HingeElement],
    /// Material index of each hinge.
    pub hinge_material: &'a [u16],
    /// The material table.
    pub materials: &'a [Material],
    /// The order the elements are summed in, as storage indices
    /// `(stretch, hinges)`: a partitioned store read in global key order
    /// without a copy of its elements. `None`: storage order.
    pub order: Option<(&'a [u32], &'a [u32])>,
}

/// Whether `order` holds each of `0..n` exactly once.
fn is_permutation(order: &[u32], n: usize) -> bool {
    let mut seen = vec![false; n];
    order.len() == n
        && order.iter().all(|&i| {
            seen.get_mut(i as usize)
                .is_some_and(|s| !std::mem::replace(s, true))
        })
}

/// The positions (or velocities) of an element's vertices.
#[inline(always)]
pub(super) fn gather<const N: usize>(x: &[DVec3], verts: [u32; N]) -> [DVec3; N] {
    verts.map(|i| x[i as usize])
}

impl<'a> ElasticModel<'a> {
    /// The stretch element `j`-th in summation order, with its material.
    #[inline]
    pub fn stretch_at(&self, j: usize) -> (&'a StretchElement, &'a Material) {
        let i = self.order.map_or(j, |(s, _)| s[j] as usize);
        (
            &self.stretch[i],
            &self.materials[self.stretch_material[i] as usize],
        )
    }

    /// The hinge `j`-th in summation order, with its material.
    #[inline]
    pub fn hinge_at(&self, j: usize) -> (&'a HingeElement, &'a Material) {
        let i = self.order.map_or(j, |(_, h)| h[j] as usize);
        (
            &self.hinges[i],
            &self.materials[self.hinge_material[i] as usize],
        )
    }

    /// Stretch elements with their materials, in summation order.
    pub fn stretch_iter(&self) -> impl Iterator<Item = (&'a StretchElement, &'a Material)> + 'a {
        let model = *self;
        (0..self.stretch.len()).map(move |j| model.stretch_at(j))
    }

    /// Hinges with their materials, in summation order.
    pub fn hinge_iter(&self) -> impl Iterator<Item = (&'a HingeElement, &'a Material)> + 'a {
        let model = *self;
        (0..self.hinges.len()).map(move |j| model.hinge_at(j))
    }

    /// Checks array lengths, vertex ids (`< num_vertices`) and every material.
    pub fn validate(&self, num_vertices: usize) -> Result<(), MaterialError> {
        if self.stretch.len() != self.stretch_material.len()
            || self.hinges.len() != self.hinge_material.len()
        {
            return Err(MaterialError::Inconsistent(format!(
                "{} stretch elements with {} material ids, {} hinges with {} material ids \
                 (one material id per element is required)",
                self.stretch.len(),
                self.stretch_material.len(),
                self.hinges.len(),
                self.hinge_material.len()
            )));
        }
        if let Some((s, h)) = self.order {
            for (what, order, n) in [
                ("stretch elements", s, self.stretch.len()),
                ("hinges", h, self.hinges.len()),
            ] {
                if !is_permutation(order, n) {
                    return Err(MaterialError::Inconsistent(format!(
                        "the summation order of the {what} ({} indices) is not an order of \
                         all {n} of them",
                        order.len()
                    )));
                }
            }
        }
        let nm = self.materials.len();
        if let Some(&id) = self
            .stretch_material
            .iter()
            .chain(self.hinge_material)
            .find(|&&id| id as usize >= nm)
        {
            return Err(MaterialError::Inconsistent(format!(
                "material id {id} out of range (the table has {nm} materials)"
            )));
        }
        let out = |v: &[u32]| v.iter().any(|&i| i as usize >= num_vertices);
        if let Some(e) = self.stretch.iter().find(|e| out(&e.verts)) {
            return Err(MaterialError::Inconsistent(format!(
                "stretch element {:?} names a vertex >= {num_vertices}",
                e.verts
            )));
        }
        if let Some(e) = self.hinges.iter().find(|e| out(&e.verts)) {
            return Err(MaterialError::Inconsistent(format!(
                "hinge {:?} names a vertex >= {num_vertices}",
                e.verts
            )));
        }
        for m in self.materials {
            m.validate()?;
        }
        Ok(())
    }

    /// Total elastic energy at `x`.
    pub fn energy(&self, x: &[DVec3]) -> f64 {
        let s: f64 = self
            .stretch_iter()
            .map(|(e, m)| e.energy(&gather(x, e.verts), m))
            .sum();
        let b: f64 = self
            .hinge_iter()
            .map(|(e, m)| e.energy(&gather(x, e.verts), m.bending_stiffness))
            .sum();
        s + b
    }

    /// Adds the assembled gradient `dV/dx` at `x` to `grad` (element order).
    pub fn add_gradient(&self, x: &[DVec3], grad: &mut [DVec3]) {
        for (e, m) in self.stretch_iter() {
            let g = e.gradient(&gather(x, e.verts), m);
            for k in 0..3 {
                grad[e.verts[k] as usize] += g[k];
            }
        }
        for (e, m) in self.hinge_iter() {
            let g = e.gradient(&gather(x, e.verts), m.bending_stiffness);
            for k in 0..4 {
                grad[e.verts[k] as usize] += g[k];
            }
        }
    }

    /// Adds the assembled damping force at `(x, v)` to `force` (element order).
    pub fn add_damping_force(&self, x: &[DVec3], v: &[DVec3], force: &mut [DVec3]) {
        for (e, m) in self.stretch_iter() {
            let f = e.damping_force(&gather(x, e.verts), &gather(v, e.verts), m);
            for k in 0..3 {
                force[e.verts[k] as usize] += f[k];
            }
        }
        for (e, m) in self.hinge_iter() {
            let f = e.damping_force(&gather(x, e.verts), &gather(v, e.verts), m);
            for k in 0..4 {
                force[e.verts[k] as usize] += f[k];
            }
        }
    }
}
