//! The scene file schema (TOML, version 1). Every table rejects unknown keys.
//! Units are SI (m, kg, s, Pa, rad). `docs/scenes.md` documents each key.

use serde::Deserialize;

/// Current schema version.
pub const SCENE_VERSION: u32 = 1;

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Schema version; must be 1.
    pub version: u32,
    #[serde(default)]
    pub name: Option<String>,
    /// Approximate number of cloth vertices; generators scale their resolution
    /// to reach it (0 = the generators' own resolution). An integer, or a
    /// whole number written as a float (`1e6`).
    #[serde(default, deserialize_with = "whole_number")]
    pub size: u64,
    /// Gravity (m/s²).
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    #[serde(default)]
    pub time: TimeSection,
    #[serde(default)]
    pub contact: ContactSection,
    #[serde(default)]
    pub output: OutputSection,
    #[serde(default)]
    pub cloth: Vec<ClothSection>,
    #[serde(default)]
    pub obstacle: Vec<ObstacleSection>,
    #[serde(default)]
    pub pin: Vec<PinSection>,
    /// Where a renderer looks from (optional).
    #[serde(default)]
    pub camera: Option<CameraSection>,
    /// Partitions of the cloth triangles, the unit of parallel work (0: one
    /// per 512 cloth triangles, 1 to 256; results never depend on it).
    #[serde(default = "default_partitions")]
    pub partitions: usize,
}

/// A non-negative integer, also when written as a float (`--set size=1e6`).
fn whole_number<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    struct Whole;
    impl serde::de::Visitor<'_> for Whole {
        type Value = u64;
        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a non-negative whole number")
        }
        fn visit_u64<E: serde::de::Error>(self, n: u64) -> Result<u64, E> {
            Ok(n)
        }
        fn visit_i64<E: serde::de::Error>(self, n: i64) -> Result<u64, E> {
            u64::try_from(n).map_err(|_| E::custom(format!("{n} is negative")))
        }
        fn visit_f64<E: serde::de::Error>(self, x: f64) -> Result<u64, E> {
            // 2^64 is the first float beyond u64.
            if x >= 0.0 && x.fract() == 0.0 && x < 18_446_744_073_709_551_616.0 {
                Ok(x as u64)
            } else {
                Err(E::custom(format!("{x} is not a non-negative whole number")))
            }
        }
    }
    d.deserialize_any(Whole)
}

fn default_gravity() -> [f64; 3] {
    [0.0, -9.81, 0.0]
}

fn default_partitions() -> usize {
    0
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSection {
    /// End time (s).
    #[serde(default = "default_end")]
    pub end: f64,
    /// Internal step (s); absent = derived from the assembled rest system.
    #[serde(default)]
    pub internal_step: Option<f64>,
    /// Safety factor of the derived step, in (0, 0.5].
    #[serde(default = "default_beta")]
    pub beta: f64,
    /// Internal steps per collision window (absent = 100, or derived from
    /// `window` and `internal_step`).
    #[serde(default)]
    pub steps_per_window: Option<u64>,
    /// Collision window length (s), an alternative to `steps_per_window`.
    #[serde(default)]
    pub window: Option<f64>,
}

fn default_end() -> f64 {
    1.0
}
fn default_beta() -> f64 {
    0.3
}
/// Internal steps per window when neither `steps_per_window` nor `window`
/// is given.
pub const DEFAULT_STEPS_PER_WINDOW: u64 = 100;

impl Default for TimeSection {
    fn default() -> Self {
        Self {
            end: default_end(),
            internal_step: None,
            beta: default_beta(),
            steps_per_window: None,
            window: None,
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactSection {
    /// Outer contact thickness eta_1 (m).
    #[serde(default = "default_thickness")]
    pub thickness: f64,
    /// Separation floor as a fraction of eta_1.
    #[serde(default = "default_floor")]
    pub floor: f64,
    /// Layer-1 stiffness (N/m); absent = automatic.
    #[serde(default)]
    pub stiffness: Option<f64>,
    /// Layer 1's step is `h_el / 2^layer1_step_shift`; its automatic
    /// stiffness grows as the square of the inverse step.
    #[serde(default)]
    pub layer1_step_shift: u32,
    /// Layers activated per detection.
    #[serde(default = "default_layers")]
    pub layers_per_detection: u32,
    /// Coulomb friction coefficient.
    #[serde(default)]
    pub friction: f64,
    /// Calm windows before a layer is retired.
    #[serde(default = "default_retire")]
    pub retire_after_windows: u32,
    /// Activate layers ahead of detection from the extrapolated motion.
    #[serde(default = "default_predict")]
    pub predict: bool,
    /// Keep far stencils out of the contact islands while certified
    /// (absent: from 4 ranks and from 8 threads per rank on).
    #[serde(default)]
    pub split_islands: Option<bool>,
    /// Rollback cap per window.
    #[serde(default = "default_max_rollbacks")]
    pub max_rollbacks: u32,
}

fn default_thickness() -> f64 {
    1e-3
}
fn default_floor() -> f64 {
    0.1
}
fn default_layers() -> u32 {
    5
}
fn default_retire() -> u32 {
    3
}
fn default_predict() -> bool {
    true
}
fn default_max_rollbacks() -> u32 {
    1000
}

impl Default for ContactSection {
    fn default() -> Self {
        Self {
            thickness: default_thickness(),
            floor: default_floor(),
            stiffness: None,
            layer1_step_shift: 0,
            layers_per_detection: default_layers(),
            friction: 0.0,
            retire_after_windows: default_retire(),
            predict: default_predict(),
            split_islands: None,
            max_rollbacks: default_max_rollbacks(),
        }
    }
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSection {
    /// Frames per second of output.
    #[serde(default = "default_frame_rate")]
    pub frame_rate: f64,
    /// Frame formats, any of "ply", "obj", "vtk".
    #[serde(default = "default_formats")]
    pub formats: Vec<String>,
    /// Write a checkpoint every this many committed windows (0 = only at
    /// `--stop-after`, on signals and at the rollback cap).
    #[serde(default = "default_checkpoint_every")]
    pub checkpoint_every: u64,
    /// Also write a checkpoint once this many minutes of wall time have
    /// passed since the last one (0 = by window count only).
    #[serde(default = "default_checkpoint_minutes")]
    pub checkpoint_minutes: f64,
}

fn default_frame_rate() -> f64 {
    30.0
}
fn default_formats() -> Vec<String> {
    vec!["ply".into()]
}
fn default_checkpoint_every() -> u64 {
    100
}
fn default_checkpoint_minutes() -> f64 {
    10.0
}

impl Default for OutputSection {
    fn default() -> Self {
        Self {
            frame_rate: default_frame_rate(),
            formats: default_formats(),
            checkpoint_every: default_checkpoint_every(),
            checkpoint_minutes: default_checkpoint_minutes(),
        }
    }
}

/// A cloth object: a mesh file or a generator, and a material.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothSection {
    pub name: String,
    /// Friction coefficient of this cloth (default: `contact.friction`).
    #[serde(default)]
    pub friction: Option<f64>,
    /// Mesh file (OBJ or PLY), relative to the scene file.
    #[serde(default)]
    pub mesh: Option<String>,
    /// Generator, when no mesh file is given.
    #[serde(default)]
    pub grid: Option<GridSection>,
    /// Ribbon generator: a strip along a polyline or tied in a knot, resting
    /// on its flat strip (`scene/ribbon.rs`).
    #[serde(default)]
    pub ribbon: Option<super::ribbon::RibbonSection>,
    /// Tube generator: an open sleeve (a sheet closed around an axis).
    #[serde(default)]
    pub tube: Option<TubeSection>,
    #[serde(default)]
    pub transform: Transform,
    /// Initial velocity of every vertex (m/s).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Initial angular velocity (rad/s) about `spin_center`.
    #[serde(default)]
    pub spin: [f64; 3],
    #[serde(default)]
    pub spin_center: [f64; 3],
    /// Rest shape: "initial" (the start shape), "flat" (generators only:
    /// the grid before `wave` and transform, a tube at its `rest_radius`) or
    /// "uv" (the mesh file's texture coordinates).
    #[serde(default = "default_rest")]
    pub rest: String,
    /// With `rest = "uv"`: metres per UV unit.
    #[serde(default)]
    pub uv_scale: Option<f64>,
    /// Rest shape from a mesh file with the same connectivity (relative to
    /// the scene file; the cloth's transform applies to it too).
    #[serde(default)]
    pub rest_mesh: Option<String>,
    #[serde(default)]
    pub material: MaterialSection,
}

fn default_rest() -> String {
    "initial".into()
}

/// A rectangle-grid generator.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSection {
    /// Side lengths (m).
    pub size: [f64; 2],
    /// Vertices along each side (scaled by the scene's `size`, if set).
    pub resolution: [usize; 2],
    /// Center (m).
    #[serde(default)]
    pub center: [f64; 3],
    /// Plane: "xz" (horizontal, default), "xy" or "yz".
    #[serde(default = "default_plane")]
    pub plane: String,
    /// Out-of-plane sinusoidal perturbation amplitude (m) of the start shape.
    #[serde(default)]
    pub wave: f64,
    /// Number of half-waves of the perturbation along each side.
    #[serde(default = "default_wave_count")]
    pub wave_count: [f64; 2],
    /// A round hole punched through the grid.
    #[serde(default)]
    pub hole: Option<HoleSection>,
}

/// An open tube (sleeve) generator.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TubeSection {
    /// Axis end points (m).
    pub from: [f64; 3],
    pub to: [f64; 3],
    /// Radius of the start shape (m).
    pub radius: f64,
    /// Vertices around and rings along (scaled by the scene's `size`, if set).
    pub resolution: [usize; 2],
    /// Radius of the rest shape (`rest = "flat"`), absent = `radius`.
    #[serde(default)]
    pub rest_radius: Option<f64>,
}

/// A round hole in a generated grid.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HoleSection {
    /// Radius (m): every grid vertex closer than this to the center goes.
    pub radius: f64,
    /// Center as offsets (m) from the grid's center along its two sides.
    #[serde(default)]
    pub center: [f64; 2],
    /// Radius of the hole in the rest shape (`rest = "flat"`), absent = `radius`;
    /// the rest shape is remapped radially out to twice the larger radius.
    #[serde(default)]
    pub rest_radius: Option<f64>,
}

fn default_plane() -> String {
    "xz".into()
}
fn default_wave_count() -> [f64; 2] {
    [1.0, 1.0]
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSection {
    /// Area density (kg/m²).
    #[serde(default = "default_density")]
    pub density: f64,
    /// Young's modulus (Pa).
    #[serde(default = "default_youngs")]
    pub youngs_modulus: f64,
    #[serde(default = "default_poisson")]
    pub poisson_ratio: f64,
    /// Thickness (m).
    #[serde(default = "default_cloth_thickness")]
    pub thickness: f64,
    /// Bending stiffness k_b (J); absent = D/6.
    #[serde(default)]
    pub bending_stiffness: Option<f64>,
    /// Viscous strain-rate damping (s).
    #[serde(default)]
    pub stretch_damping: f64,
    /// Hinge-rate damping (J·s).
    #[serde(default)]
    pub bend_damping: f64,
}

fn default_density() -> f64 {
    0.2
}
fn default_youngs() -> f64 {
    1e5
}
fn default_poisson() -> f64 {
    0.3
}
fn default_cloth_thickness() -> f64 {
    1e-3
}

impl Default for MaterialSection {
    fn default() -> Self {
        Self {
            density: default_density(),
            youngs_modulus: default_youngs(),
            poisson_ratio: default_poisson(),
            thickness: default_cloth_thickness(),
            bending_stiffness: None,
            stretch_damping: 0.0,
            bend_damping: 0.0,
        }
    }
}

/// A kinematic obstacle.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSection {
    pub name: String,
    /// Friction coefficient of this obstacle (default: `contact.friction`).
    #[serde(default)]
    pub friction: Option<f64>,
    #[serde(default)]
    pub mesh: Option<String>,
    #[serde(default)]
    pub sphere: Option<SphereSection>,
    #[serde(default, rename = "box")]
    pub cuboid: Option<BoxSection>,
    #[serde(default)]
    pub cylinder: Option<CylinderSection>,
    /// An animated mesh: frames read from files, interpolated linearly.
    #[serde(default)]
    pub mesh_sequence: Option<MeshSequenceSection>,
    #[serde(default)]
    pub transform: Transform,
    #[serde(default)]
    pub motion: MotionSection,
}

/// Frames of an animated obstacle (same connectivity in every file).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSequenceSection {
    /// Frame files in order (relative to the scene file).
    #[serde(default)]
    pub files: Vec<String>,
    /// Or a pattern with `*` / `?` in the file name (`walk/f*.obj`); the
    /// matching files are taken in name order.
    #[serde(default)]
    pub pattern: Option<String>,
    /// Frames per second of the sequence.
    pub frame_rate: f64,
    /// Time of the first frame (s).
    #[serde(default)]
    pub start: f64,
}

/// Camera of a renderer (not used by the simulation).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSection {
    /// Eye position (m).
    pub eye: [f64; 3],
    /// Point looked at (m).
    pub target: [f64; 3],
    /// Up direction.
    #[serde(default = "default_up")]
    pub up: [f64; 3],
    /// Vertical field of view (degrees).
    #[serde(default = "default_fov")]
    pub fov_degrees: f64,
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}
fn default_fov() -> f64 {
    40.0
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereSection {
    pub center: [f64; 3],
    pub radius: f64,
    #[serde(default = "default_subdivisions")]
    pub subdivisions: u32,
}

fn default_subdivisions() -> u32 {
    3
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSection {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CylinderSection {
    pub from: [f64; 3],
    pub to: [f64; 3],
    pub radius: f64,
    #[serde(default = "default_segments")]
    pub segments: usize,
    #[serde(default = "default_rings")]
    pub rings: usize,
}

fn default_segments() -> usize {
    24
}
fn default_rings() -> usize {
    8
}

/// Scale, then rotate (axis-angle, radians), then translate.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transform {
    /// One factor, or one per axis.
    #[serde(default)]
    pub scale: Option<Scale>,
    #[serde(default)]
    pub rotate_axis: Option<[f64; 3]>,
    #[serde(default)]
    pub rotate_angle: f64,
    #[serde(default)]
    pub translate: [f64; 3],
}

/// `transform.scale`: `s` or `[sx, sy, sz]`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(
    untagged,
    expecting = "a number or an array of three numbers [sx, sy, sz]"
)]
pub enum Scale {
    Uniform(f64),
    PerAxis([f64; 3]),
}

impl Scale {
    /// The factor along each axis.
    pub fn per_axis(self) -> [f64; 3] {
        match self {
            Scale::Uniform(s) => [s; 3],
            Scale::PerAxis(s) => s,
        }
    }
}

/// A scripted motion.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSection {
    /// "fixed" (default), "translate" or "rotate".
    #[serde(default)]
    pub kind: Option<String>,
    /// Velocity for "translate" (m/s).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// "translate" only: moves for t < until (s), then stays; absent = forever.
    #[serde(default)]
    pub until: Option<f64>,
    /// Rotation axis and a point on it, for "rotate".
    #[serde(default)]
    pub axis: [f64; 3],
    #[serde(default)]
    pub center: [f64; 3],
    /// Angular velocity profile: [[t, omega], ...] (s, rad/s), linear in between.
    #[serde(default)]
    pub omega: Vec<[f64; 2]>,
}

/// A set of pinned cloth vertices with a motion.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinSection {
    pub name: String,
    /// Name of the cloth object.
    pub object: String,
    /// Vertex indices of the object (0-based).
    #[serde(default)]
    pub indices: Vec<u32>,
    /// Or every vertex inside this axis-aligned box (start positions).
    #[serde(default)]
    pub box_min: Option<[f64; 3]>,
    #[serde(default)]
    pub box_max: Option<[f64; 3]>,
    /// The box corners are fractions of the object's bounding box (0 = its
    /// minimum, 1 = its maximum, per axis), not metres.
    #[serde(default)]
    pub relative: bool,
    /// And/or the object's boundary vertices: "all", or "outer" (the
    /// boundary loop of greatest length, e.g. a sheet's border, not its holes).
    #[serde(default)]
    pub boundary: Option<String>,
    #[serde(default)]
    pub motion: MotionSection,
}
