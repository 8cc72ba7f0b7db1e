//! The simulated world: state, topology, forces, scripts and schedules, built
//! from a [`WorldSpec`].
//!
//! Vertices of all objects are concatenated in object order: a vertex's index in
//! [`World::x`] is its **input id**, the id every key and every output uses.

use std::ops::Range;
use std::sync::Arc;

use glam::DVec3;
use weft_core::{StencilKey, StencilKind, Topology, TriMesh, VertexFaces};

use crate::clock::{Lattice, Tick};
use crate::config::{ContactConfig, LimitsConfig, TimeConfig};
use crate::error::{Place, SimError};
use crate::executor::{Executor, Serial};
use crate::internal::InternalForces;
use crate::kinematics::{Motion, Script};
use crate::layers::{resolved_depth, ActiveLayers, LayerSchedule};
use crate::materials::{self, Material};
use crate::partition::{Contiguous, Partitioner, Partitioning};

/// What an object is.
#[derive(Clone, Debug, PartialEq)]
pub enum ObjectKind {
    /// Deformable cloth with a material, a rest shape and initial velocities.
    Cloth {
        material: Material,
        /// Rest shape (same connectivity); `None` = the initial shape.
        rest: Option<Vec<DVec3>>,
        /// Initial velocity of every vertex (m/s); empty = zero.
        velocity: Vec<DVec3>,
    },
    /// A kinematic obstacle moving along a script.
    Obstacle { motion: Motion },
}

/// One object of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSpec {
    pub name: String,
    pub mesh: TriMesh,
    pub kind: ObjectKind,
    /// Coulomb friction coefficient of the object's surface; `None` = the
    /// scene's `contact.friction`. A contact between two objects uses the
    /// geometric mean of theirs (their common value when they agree).
    pub friction: Option<f64>,
}

/// Cloth vertices held by a script.
#[derive(Clone, Debug, PartialEq)]
pub struct PinSpec {
    pub name: String,
    /// Index of the object in [`WorldSpec::objects`].
    pub object: usize,
    /// Object-local vertex indices.
    pub vertices: Vec<u32>,
    pub motion: Motion,
}

/// Everything needed to build a [`World`].
#[derive(Clone, Debug, PartialEq)]
pub struct WorldSpec {
    pub objects: Vec<ObjectSpec>,
    pub pins: Vec<PinSpec>,
    pub gravity: DVec3,
    pub contact: ContactConfig,
    pub time: TimeConfig,
    pub limits: LimitsConfig,
    /// Number of partitions the cloth triangles are split into (0: automatic,
    /// see [`crate::partition::auto_count`]; results do not depend on it).
    pub partitions: usize,
    /// Ranks × threads the world will run on (0 counts as 1): the
    /// automatic partition count gives each at least 4 partitions.
    pub workers: usize,
}

/// An object after concatenation.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectInfo {
    pub name: String,
    pub vertices: Range<u32>,
    pub triangles: Range<u32>,
    pub is_cloth: bool,
}

/// The simulated world.
#[derive(Clone, Debug)]
pub struct World {
    pub objects: Vec<ObjectInfo>,
    /// Positions (valid at `tau`), velocities, the time positions are valid at.
    pub x: Vec<DVec3>,
    pub v: Vec<DVec3>,
    pub tau: Vec<Tick>,
    pub mass: Vec<f64>,
    /// Inverse masses; 0 for kinematic vertices.
    pub inv_mass: Vec<f64>,
    pub triangles: Vec<[u32; 3]>,
    /// The faces around each vertex and the internal elements never change
    /// after the build: shared by a world's clones (a bench's runs,
    /// simulated ranks), not copied. Of the mesh's topology only the faces
    /// around each vertex are kept (the edges and hinges live on in the
    /// internal elements): every rank holds the world's.
    pub vertex_faces: Arc<VertexFaces>,
    pub internal: Arc<InternalForces>,
    pub gravity: DVec3,
    pub scripts: Vec<Script>,
    /// `script_of[i]` = (script, index in script) for kinematic vertex i.
    pub script_of: Vec<Option<(u32, u32)>>,
    pub schedule: LayerSchedule,
    pub contact: ContactConfig,
    pub lattice: Lattice,
    pub limits: LimitsConfig,
    /// Current time: the start of the next window.
    pub tick: Tick,
    /// Committed windows so far.
    pub window_index: u64,
    pub layers: ActiveLayers,
    /// Largest angular frequency of the assembled rest system (rad/s).
    pub omega_max: f64,
    /// Largest damping rate `λ_max(M⁻¹C)` of the rest system (1/s, 0
    /// without damping); with `omega_max` it bounds the internal step.
    pub damping_rate: f64,
    /// Friction coefficient of each vertex's object.
    pub vertex_friction: Vec<f64>,
    /// Which partition each triangle and vertex belongs to.
    pub partitioning: Partitioning,
}

impl World {
    /// Friction coefficient of a stencil: the geometric mean of its two
    /// sides' objects (the vertex or first edge, and the face or second
    /// edge), or their common value when they agree (exactly the scene's
    /// `contact.friction` when no object sets its own).
    pub fn stencil_friction(&self, key: &weft_core::StencilKey) -> f64 {
        let split = match key.kind {
            weft_core::StencilKind::VertexFace => 1,
            weft_core::StencilKind::EdgeEdge => 2,
        };
        let a = self.vertex_friction[key.v[0] as usize];
        let b = self.vertex_friction[key.v[split] as usize];
        if a == b {
            a
        } else {
            (a * b).sqrt()
        }
    }

    /// Builds and validates a world, partitioned into contiguous runs of
    /// triangles. Does not check the initial state for contact (see
    /// [`crate::engine::Engine::new`]).
    pub fn build(spec: &WorldSpec) -> Result<Self, SimError> {
        Self::build_with(spec, &Contiguous)
    }

    /// [`World::build`] with the partitions made by `partitioner`.
    pub fn build_with(spec: &WorldSpec, partitioner: &dyn Partitioner) -> Result<Self, SimError> {
        Self::build_on(spec, partitioner, &Serial)
    }

    /// [`World::build_with`], estimating the internal step (two Lanczos
    /// iterations over the assembled rest system, most of the build) on
    /// `exec`'s threads and ranks: the same world, bit for bit, on any
    /// number. **Collective over ranks**: every rank builds the world, and
    /// each assembles its share of the estimate's products.
    pub fn build_on<E: Executor>(
        spec: &WorldSpec,
        partitioner: &dyn Partitioner,
        exec: &E,
    ) -> Result<Self, SimError> {
        if !spec.gravity.is_finite() {
            return Err(SimError::Config(format!(
                "gravity {:?} is not finite",
                spec.gravity.to_array()
            )));
        }
        if spec.objects.is_empty() {
            return Err(SimError::Config("the scene has no objects".into()));
        }
        let mut objects = Vec::new();
        let mut all = TriMesh::default();
        let mut rest_all: Vec<DVec3> = Vec::new();
        let mut v = Vec::new();
        let mut tri_material: Vec<Option<u16>> = Vec::new();
        let mut materials_list: Vec<Material> = Vec::new();
        let mut scripts = Vec::new();
        let mut kinematic = Vec::new();
        let mut vertex_friction = Vec::new();
        for obj in &spec.objects {
            weft_core::validate(&obj.mesh).map_err(|e| SimError::Mesh {
                object: obj.name.clone(),
                source: e,
            })?;
            let mu = obj.friction.unwrap_or(spec.contact.friction);
            if !(mu >= 0.0 && mu.is_finite()) {
                return Err(SimError::Config(format!(
                    "object '{}': friction {mu} must be a non-negative number",
                    obj.name
                )));
            }
            vertex_friction.extend(std::iter::repeat_n(mu, obj.mesh.num_vertices()));
            let v0 = all.positions.len() as u32;
            let t0 = all.triangles.len() as u32;
            all.append(&obj.mesh);
            let n = obj.mesh.num_vertices();
            match &obj.kind {
                ObjectKind::Cloth {
                    material,
                    rest,
                    velocity,
                } => {
                    material.validate().map_err(|e| SimError::Material {
                        object: obj.name.clone(),
                        source: e,
                    })?;
                    let rest = rest.clone().unwrap_or_else(|| obj.mesh.positions.clone());
                    if rest.len() != n {
                        return Err(SimError::Config(format!(
                            "object '{}': rest shape has {} vertices, the mesh has {n}",
                            obj.name,
                            rest.len()
                        )));
                    }
                    if let Some(i) = rest.iter().position(|p| !p.is_finite()) {
                        return Err(SimError::Config(format!(
                            "object '{}': rest-shape vertex {i} is not finite",
                            obj.name
                        )));
                    }
                    rest_all.extend_from_slice(&rest);
                    match velocity.len() {
                        0 => v.extend(std::iter::repeat_n(DVec3::ZERO, n)),
                        m if m == n => v.extend_from_slice(velocity),
                        m => {
                            return Err(SimError::Config(format!(
                                "object '{}': {m} initial velocities for {n} vertices",
                                obj.name
                            )))
                        }
                    }
                    if let Some(i) = v[v0 as usize..].iter().position(|p| !p.is_finite()) {
                        return Err(SimError::Config(format!(
                            "object '{}': initial velocity of vertex {i} is not finite",
                            obj.name
                        )));
                    }
                    let m = materials_list.len() as u16;
                    materials_list.push(*material);
                    tri_material.extend(std::iter::repeat_n(Some(m), obj.mesh.num_triangles()));
                    kinematic.extend(std::iter::repeat_n(false, n));
                }
                ObjectKind::Obstacle { motion } => {
                    let motion = normalize_motion(motion, &obj.name, n)?;
                    // A keyframed obstacle starts where its sequence is at t = 0.
                    if let Motion::Sequence(frames) = &motion {
                        for (k, p) in all.positions[v0 as usize..].iter_mut().enumerate() {
                            *p = frames.position(k, 0.0);
                        }
                    }
                    let start = all.positions[v0 as usize..].to_vec();
                    rest_all.extend_from_slice(&start);
                    v.extend(std::iter::repeat_n(DVec3::ZERO, n));
                    tri_material.extend(std::iter::repeat_n(None, obj.mesh.num_triangles()));
                    kinematic.extend(std::iter::repeat_n(true, n));
                    scripts.push(Script {
                        name: obj.name.clone(),
                        vertices: (v0..v0 + n as u32).collect(),
                        rest: start,
                        motion,
                    });
                }
            }
            objects.push(ObjectInfo {
                name: obj.name.clone(),
                vertices: v0..v0 + n as u32,
                triangles: t0..all.triangles.len() as u32,
                is_cloth: matches!(obj.kind, ObjectKind::Cloth { .. }),
            });
        }
        for pin in &spec.pins {
            let obj = objects.get(pin.object).ok_or_else(|| {
                SimError::Config(format!("pin '{}' names object {}", pin.name, pin.object))
            })?;
            if !obj.is_cloth {
                return Err(SimError::Config(format!(
                    "pin '{}' holds object '{}', which is an obstacle (already kinematic)",
                    pin.name, obj.name
                )));
            }
            let n = obj.vertices.len() as u32;
            let mut ids = Vec::with_capacity(pin.vertices.len());
            for &lv in &pin.vertices {
                if lv >= n {
                    return Err(SimError::Config(format!(
                        "pin '{}': vertex {lv} is out of range (object '{}' has {n} vertices)",
                        pin.name, obj.name
                    )));
                }
                let g = obj.vertices.start + lv;
                if kinematic[g as usize] {
                    return Err(SimError::Config(format!(
                        "pin '{}': vertex {lv} of '{}' is already held by another pin",
                        pin.name, obj.name
                    )));
                }
                kinematic[g as usize] = true;
                ids.push(g);
            }
            if ids.is_empty() {
                return Err(SimError::Config(format!(
                    "pin '{}' selects no vertices",
                    pin.name
                )));
            }
            scripts.push(Script {
                name: pin.name.clone(),
                rest: ids.iter().map(|&g| all.positions[g as usize]).collect(),
                motion: normalize_motion(&pin.motion, &pin.name, ids.len())?,
                vertices: ids,
            });
        }
        // (Grown object by object: their spare room would be kept for the
        // run, on every rank.)
        all.positions.shrink_to_fit();
        all.triangles.shrink_to_fit();
        let nv = all.positions.len();
        let topology = Topology::build(nv, &all.triangles).map_err(|e| SimError::Mesh {
            object: "(all objects)".into(),
            source: e,
        })?;

        // Masses: lumped cloth masses; kinematic vertices get w = 0.
        let density: Vec<f64> = tri_material
            .iter()
            .map(|m| m.map_or(0.0, |m| materials_list[m as usize].area_density))
            .collect();
        let mass = materials::lumped_masses(nv, &all.triangles, &rest_all, &density);
        let mut inv_mass = vec![0.0; nv];
        for i in 0..nv {
            if !kinematic[i] {
                if !(mass[i] > 0.0) {
                    let place = place_of(&objects, i as u32);
                    return Err(SimError::Config(format!(
                        "cloth vertex {place} has no mass: it belongs to no triangle, or all \
                         its triangles have zero rest area; remove it or fix the rest shape"
                    )));
                }
                inv_mass[i] = 1.0 / mass[i];
            }
        }
        let mut script_of = vec![None; nv];
        for (s, script) in scripts.iter().enumerate() {
            for (k, &g) in script.vertices.iter().enumerate() {
                script_of[g as usize] = Some((s as u32, k as u32));
            }
        }

        let is_cloth: Vec<bool> = tri_material.iter().map(Option::is_some).collect();
        let partitioning = Partitioning::build(
            partitioner,
            spec.partitions,
            spec.workers,
            &all.triangles,
            &is_cloth,
            &topology,
            nv,
        )
        .map_err(|m| SimError::Config(format!("partitioning: {m}")))?;
        let internal = InternalForces::build(
            &all.triangles,
            &tri_material,
            &topology,
            &rest_all,
            &materials_list,
            &inv_mass,
            &partitioning.of_triangle,
            partitioning.count,
        )
        .map_err(|(f, e)| {
            let object = object_of_triangle(&objects, f);
            SimError::Material {
                object: object.map_or("?".into(), |o| o.name.clone()),
                source: e.in_object(object.map_or(0, |o| o.vertices.start)),
            }
        })?;

        // Internal step: beta times the explicit stability limit `2 /
        // omega_max` of the assembled rest system, and at most
        // `DAMPING_SAFETY` times its limit with damping (the root of
        // `h γ + h² ω² / 2 = 2`, `step.rs`).
        let omega_max = internal.max_frequency(exec, &rest_all, &mass)?;
        let gamma_max = internal.max_damping_rate(exec, &rest_all, &mass)?;
        let h_el = match spec.time.internal_step {
            Some(h) if h > 0.0 && h.is_finite() => {
                // A given step may not exceed the explicit stability limit
                // 2 / omega_max of the assembled rest system (beta = 1).
                let limit = materials::stable_step(omega_max, 1.0);
                if h > limit {
                    return Err(SimError::Config(format!(
                        "the internal step {h:e} s (time.internal_step, or time.window / \
                         time.steps_per_window) exceeds the stability step 2 / omega_max = \
                         {limit:e} s of the assembled rest system (omega_max = {omega_max:e} \
                         rad/s); use a step of at most {limit:e} s, or leave time.internal_step \
                         out to derive beta · 2 / omega_max"
                    )));
                }
                if h > materials::damping_step_limit(omega_max, gamma_max) {
                    let cloths: Vec<&ObjectInfo> = objects.iter().filter(|o| o.is_cloth).collect();
                    return Err(damping_refusal(
                        h, omega_max, &internal, &rest_all, &mass, &cloths,
                    ));
                }
                h
            }
            Some(h) => {
                return Err(SimError::Config(format!(
                    "time.internal_step = {h} must be a positive number of seconds"
                )))
            }
            None => {
                if !(spec.time.beta > 0.0 && spec.time.beta <= 0.5) {
                    return Err(SimError::Config(format!(
                        "time.beta = {} must be in (0, 0.5]",
                        spec.time.beta
                    )));
                }
                if !(omega_max > 0.0 && omega_max.is_finite()) {
                    return Err(SimError::Config(
                        "no cloth stiffness to derive the internal step from; set time.internal_step"
                            .into(),
                    ));
                }
                let stiff = materials::stable_step(omega_max, spec.time.beta);
                if gamma_max > 0.0 {
                    stiff.min(DAMPING_SAFETY * materials::damping_step_limit(omega_max, gamma_max))
                } else {
                    stiff
                }
            }
        };
        let lattice = Lattice::new(h_el, spec.time.steps_per_window);
        initial_speeds_resolvable(&objects, &all.positions, &v, &kinematic, h_el)?;

        // Contact thickness: at most half the smallest cloth triangle altitude.
        let c = &spec.contact;
        if !(c.thickness > 0.0 && c.thickness.is_finite()) {
            return Err(SimError::Config(format!(
                "contact.thickness = {} must be positive",
                c.thickness
            )));
        }
        if !(0.0..1.0).contains(&c.floor_fraction) {
            return Err(SimError::Config(format!(
                "contact.floor = {} must be in [0, 1)",
                c.floor_fraction
            )));
        }
        if c.layers_per_detection == 0 {
            return Err(SimError::Config(
                "contact.layers_per_detection must be at least 1".into(),
            ));
        }
        let min_alt = all
            .triangles
            .iter()
            .zip(&tri_material)
            .filter(|(_, m)| m.is_some())
            .map(|(t, _)| {
                min_altitude([
                    all.positions[t[0] as usize],
                    all.positions[t[1] as usize],
                    all.positions[t[2] as usize],
                ])
            })
            .fold(f64::INFINITY, f64::min);
        let eta_1 = c.thickness.min(0.5 * min_alt);
        // Layer 1's step, h_el / 2^shift, and the deepest layer whose step
        // h_1 l^(-3/2) the tick lattice still resolves (at least one tick):
        // a shift that leaves fewer than MIN_RESOLVED_LAYERS is refused, not
        // capped — a deeper layer's step would round up and break its
        // stability.
        let h1_of = |shift: u32| lattice.internal_step().checked_shr(shift).unwrap_or(0);
        let ticks_h1 = h1_of(c.layer1_step_shift);
        let resolved = resolved_depth(ticks_h1);
        if resolved < MIN_RESOLVED_LAYERS {
            let max_shift = (0..c.layer1_step_shift.min(Tick::BITS))
                .rev()
                .find(|&s| resolved_depth(h1_of(s)) >= MIN_RESOLVED_LAYERS)
                .unwrap_or(0);
            return Err(SimError::Config(format!(
                "contact.layer1_step_shift = {shift} gives layer 1 a step of {ticks_h1} ticks \
                 (h_el / 2^{shift}, with {} ticks per internal step), and the tick lattice then \
                 resolves the steps h_l = h_1 l^(-3/2) of {resolved} layers only, fewer than \
                 the {MIN_RESOLVED_LAYERS} a deep contact may need; use at most {max_shift}",
                lattice.internal_step(),
                shift = c.layer1_step_shift,
            )));
        }
        let h_1 = lattice.seconds(ticks_h1);
        let m_min = mass
            .iter()
            .zip(&inv_mass)
            .filter(|(_, &w)| w > 0.0)
            .map(|(&m, _)| m)
            .fold(f64::INFINITY, f64::min);
        // The automatic k_1 = m_min (0.1 / h_1)² / 2 puts layer 1 at
        // omega_1 h_1 = 0.1 with omega_1² ≤ 2 k_1 w_max (`acm-spec.md` §3),
        // and every deeper layer has the same omega h: it is the largest
        // stiffness within that bound.
        let k_max = m_min * (0.1 / h_1) * (0.1 / h_1) / 2.0;
        let k_1 = match c.stiffness {
            Some(k) if k > 0.0 && k.is_finite() => {
                if m_min.is_finite() && k > k_max {
                    let omega_h = (2.0 * k / m_min).sqrt() * h_1;
                    return Err(SimError::Config(format!(
                        "contact.stiffness = {k:e} N/m is above the layer stability bound \
                         omega_1 h_1 ≤ 0.1 for layer 1's step h_1 = {h_1:.4e} s: it gives \
                         omega_1 h_1 = {omega_h:.3} (lightest cloth vertex {m_min:.3e} kg), and \
                         the bound allows at most {k_max:.4e} N/m (the automatic value); lower \
                         it or leave it out, or shorten layer 1's step with \
                         contact.layer1_step_shift (each step halves h_1 and allows 4× the \
                         stiffness)"
                    )));
                }
                k
            }
            Some(k) => {
                return Err(SimError::Config(format!(
                    "contact.stiffness = {k} must be positive"
                )))
            }
            None if m_min.is_finite() => k_max,
            None => 1.0,
        };
        let schedule = LayerSchedule {
            eta_1,
            eta_inf: c.floor_fraction * eta_1,
            k_1,
            h_1: ticks_h1,
        };

        let mut world = World {
            objects,
            x: all.positions,
            v,
            tau: vec![0; nv],
            mass,
            inv_mass,
            triangles: all.triangles,
            vertex_faces: Arc::new(topology.vertex_faces),
            internal: Arc::new(internal),
            gravity: spec.gravity,
            scripts,
            script_of,
            schedule,
            contact: spec.contact.clone(),
            lattice,
            limits: spec.limits.clone(),
            tick: 0,
            window_index: 0,
            layers: ActiveLayers::default(),
            omega_max,
            damping_rate: gamma_max,
            vertex_friction,
            partitioning,
        };
        // Kinematic vertices start on the chord to their scripted position one
        // internal step later.
        let h = world.lattice.h_el();
        for i in 0..nv {
            if let Some((s, k)) = world.script_of[i] {
                world.v[i] =
                    world.scripts[s as usize].chord_velocity(k as usize, world.x[i], 0.0, h);
            }
        }
        Ok(world)
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.x.len()
    }

    /// Object name and object-local index of vertex `i`.
    pub fn place(&self, i: u32) -> Place {
        place_of(&self.objects, i)
    }

    /// A stencil's two primitives for messages, by object and object-local
    /// vertex index: "vertex cloth #12 and triangle floor #3, #4, #5", or
    /// "edge a #0–#1 and edge b #7–#8".
    pub fn describe_stencil(&self, key: &StencilKey) -> String {
        let group = |vs: &[u32], sep: &str| -> String {
            let places: Vec<Place> = vs.iter().map(|&i| self.place(i)).collect();
            if places.iter().all(|p| p.object == places[0].object) {
                let locals: Vec<String> = places.iter().map(|p| format!("#{}", p.local)).collect();
                format!("{} {}", places[0].object, locals.join(sep))
            } else {
                let all: Vec<String> = places.iter().map(Place::to_string).collect();
                all.join(sep)
            }
        };
        match key.kind {
            StencilKind::VertexFace => format!(
                "vertex {} and triangle {}",
                self.place(key.v[0]),
                group(&key.v[1..], ", ")
            ),
            StencilKind::EdgeEdge => format!(
                "edge {} and edge {}",
                group(&key.v[..2], "–"),
                group(&key.v[2..], "–")
            ),
        }
    }

    /// Object name and object-local index of triangle `f`.
    pub fn triangle_place(&self, f: u32) -> Place {
        place_of_triangle(&self.objects, f)
    }

    /// Simulated time in seconds.
    pub fn time(&self) -> f64 {
        self.lattice.seconds(self.tick)
    }
}

/// The fewest penalty layers whose steps the tick lattice must resolve (the
/// 100 m/s impacts of the tests reach depth 100).
const MIN_RESOLVED_LAYERS: u32 = 100;

/// The fraction of the damped rest system's explicit stability limit a
/// derived internal step may use. `beta` (≤ 0.5) leaves room for StVK's
/// stiffening, which is cubic in the stretch; the strain-rate damping grows
/// only with `|F|²` (1.44× at 20 % stretch), so half its rest limit leaves
/// room for stretches up to about 40 %.
const DAMPING_SAFETY: f64 = 0.5;

/// The error for a given internal step `h` above the damping's explicit
/// stability limit: names the cloth whose damping is too strong, which of
/// its two dampings contributes most, and the largest values that pass at
/// `h` (both scaled by one factor: a cloth's damping rate scales with it).
///
/// The limit `h γ + h² ω² / 2 ≤ 2` allows a damping rate up to
/// `γ_allowed = (2 − h² ω² / 2) / h` (positive: `h ≤ 2 / ω` was checked).
/// Cloths share no vertex, so each cloth's own rate `γ_o` must stay below
/// it; the worst one is named.
fn damping_refusal(
    h: f64,
    omega_max: f64,
    internal: &InternalForces,
    rest: &[DVec3],
    mass: &[f64],
    cloths: &[&ObjectInfo],
) -> SimError {
    let allowed = (2.0 - 0.5 * h * h * omega_max * omega_max) / h;
    let (m, rates) = (0..internal.materials.len())
        .map(|m| (m, internal.damping_rates_of(m, rest, mass)))
        .max_by(|a, b| a.1[2].total_cmp(&b.1[2]))
        .expect("damping implies a cloth");
    let [stretch_rate, bend_rate, rate] = rates;
    let material = &internal.materials[m];
    let scale = allowed / rate;
    let culprit = if stretch_rate >= bend_rate {
        "stretch_damping"
    } else {
        "bend_damping"
    };
    // Three significant digits, rounded down: the suggested values pass.
    let down = |x: f64| {
        if x > 0.0 {
            let e = libm::pow(10.0, libm::floor(libm::log10(x)) - 2.0);
            libm::floor(x / e) * e
        } else {
            0.0
        }
    };
    let name = cloths.get(m).map_or("?", |o| o.name.as_str());
    SimError::Config(format!(
        "cloth '{name}': its damping is too strong for the internal step {h:.4e} s \
         (time.internal_step): mostly its {culprit} (stretch_damping = {:e} s, \
         bend_damping = {:e} J s give a damping rate of {rate:.4e} 1/s, the step allows \
         {allowed:.4e} 1/s). At this step the largest values that pass are \
         stretch_damping = {:.2e} s and bend_damping = {:.2e} J s (both scaled by {scale:.3}); or \
         leave time.internal_step out, and the step is derived from the damping limit too",
        material.stretch_damping,
        material.bend_damping,
        down(material.stretch_damping * scale),
        down(material.bend_damping * scale),
    ))
}

/// Validates a script's motion for `n` vertices (axis normalized).
fn normalize_motion(m: &Motion, name: &str, n: usize) -> Result<Motion, SimError> {
    match m {
        Motion::Rotate {
            center,
            axis,
            profile,
        } => {
            let len = axis.length();
            if !(len > 0.0 && len.is_finite() && center.is_finite()) {
                return Err(SimError::Config(format!(
                    "script '{name}': rotation axis must be a non-zero finite vector"
                )));
            }
            if profile.windows(2).any(|w| !(w[1].0 >= w[0].0))
                || profile.iter().any(|p| !p.0.is_finite() || !p.1.is_finite())
            {
                return Err(SimError::Config(format!(
                    "script '{name}': the angular-velocity profile needs finite (time, omega) points in increasing time"
                )));
            }
            Ok(Motion::Rotate {
                center: *center,
                axis: *axis / len,
                profile: profile.clone(),
            })
        }
        Motion::Translate { velocity, .. } if !velocity.is_finite() => Err(SimError::Config(
            format!("script '{name}': velocity must be finite"),
        )),
        Motion::Translate {
            until: Some(u), ..
        } if !(*u >= 0.0 && u.is_finite()) => Err(SimError::Config(format!(
            "script '{name}': translation end time `until` = {u} must be a non-negative number of seconds"
        ))),
        Motion::Sequence(frames) => match frames.validate(n) {
            Ok(()) => Ok(m.clone()),
            Err(e) => Err(SimError::Config(format!(
                "script '{name}': mesh sequence: {e}"
            ))),
        },
        other => Ok(other.clone()),
    }
}

/// Refuses a cloth vertex whose initial speed carries it farther in one
/// internal step `h_el` than the whole scene is across (the diagonal of the
/// bounding box of every initial position, at least 1 m): no penalty layer
/// can act on such a motion, so every stencil on its path would be detected
/// and rolled back up to `contact.max_rollbacks` (a cloth thrown at 1e307
/// m/s made no progress in minutes). At 1 m across and a 3.5e-5 s step this
/// allows about 28 km/s, far beyond any cloth; such a speed is almost always
/// a unit mistake.
fn initial_speeds_resolvable(
    objects: &[ObjectInfo],
    x: &[DVec3],
    v: &[DVec3],
    kinematic: &[bool],
    h_el: f64,
) -> Result<(), SimError> {
    let (lo, hi) = x
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    let across = (hi - lo).length().max(1.0);
    let fastest = (v.iter().zip(kinematic).enumerate())
        .filter(|(_, (_, &k))| !k)
        .map(|(i, (u, _))| {
            // |u| without overflow: u.length() squares 1e307 to infinity.
            let m = u.abs().max_element();
            (i, if m > 0.0 { m * (*u / m).length() } else { 0.0 })
        })
        // The first of the fastest: the message names the lowest vertex id.
        .fold(None, |best: Option<(usize, f64)>, (i, s)| match best {
            Some((_, b)) if b >= s => best,
            _ => Some((i, s)),
        });
    match fastest {
        Some((i, speed)) if speed * h_el > across => Err(SimError::Config(format!(
            "object '{}': initial velocity of vertex {} is {speed:.3e} m/s, which crosses \
             {:.3e} m in one internal step of {h_el:.3e} s, more than the whole scene \
             ({across:.3e} m across); contact cannot act on such a motion — check the \
             velocity's units (m/s)",
            place_of(objects, i as u32).object,
            place_of(objects, i as u32).local,
            speed * h_el,
        ))),
        _ => Ok(()),
    }
}

fn place_of(objects: &[ObjectInfo], i: u32) -> Place {
    objects.iter().find(|o| o.vertices.contains(&i)).map_or(
        Place {
            object: "?".into(),
            local: i,
        },
        |o| Place {
            object: o.name.clone(),
            local: i - o.vertices.start,
        },
    )
}

/// The object triangle `f` belongs to.
fn object_of_triangle(objects: &[ObjectInfo], f: u32) -> Option<&ObjectInfo> {
    objects.iter().find(|o| o.triangles.contains(&f))
}

fn place_of_triangle(objects: &[ObjectInfo], f: u32) -> Place {
    object_of_triangle(objects, f).map_or(
        Place {
            object: "?".into(),
            local: f,
        },
        |o| Place {
            object: o.name.clone(),
            local: f - o.triangles.start,
        },
    )
}

/// Smallest altitude of a triangle: 2 A / longest edge.
pub fn min_altitude(p: [DVec3; 3]) -> f64 {
    let area2 = (p[1] - p[0]).cross(p[2] - p[0]).length();
    let longest = (p[1] - p[0])
        .length()
        .max((p[2] - p[1]).length())
        .max((p[0] - p[2]).length());
    if longest > 0.0 {
        area2 / longest
    } else {
        0.0
    }
}
