//! Scene files: TOML → validated [`Scene`] (a `WorldSpec` plus run settings).
//!
//! Loading reads the file, applies `--set key.path=value` overrides, rejects
//! unknown keys and wrong types with the file, line and key, resolves mesh files
//! relative to the scene, runs the generators and validates every value.

pub mod schema;

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Deserialize;
use thiserror::Error;
use weft_core::TriMesh;
use weft_sim::config::{ContactConfig, LimitsConfig, TimeConfig};
use weft_sim::kinematics::Motion;
use weft_sim::materials::Material;
use weft_sim::{ObjectKind, ObjectSpec, PinSpec, WorldSpec};

use schema::{MotionSection, SceneFile, Transform, SCENE_VERSION};

/// A scene that cannot be loaded. Messages name the file and, where known, the
/// line and key.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum SceneError {
    #[error("{path}: cannot read the scene file: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Syntax { path: PathBuf, message: String },
    #[error("{path}: --set {assignment}: {message}")]
    Override {
        path: PathBuf,
        assignment: String,
        message: String,
    },
    #[error("{path}: {key}: {message}")]
    Invalid {
        path: PathBuf,
        key: String,
        message: String,
    },
    #[error("{path}: {key}: cannot load mesh: {message}")]
    Mesh {
        path: PathBuf,
        key: String,
        message: String,
    },
}

/// Output settings of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSettings {
    pub frame_rate: f64,
    /// Formats every frame is written in (at least one, no repeats).
    pub formats: Vec<FrameFormat>,
    /// Committed windows between checkpoints (0 = none on a schedule).
    pub checkpoint_every: u64,
}

/// Frame file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFormat {
    /// Binary little-endian PLY with f64 positions and per-vertex velocities.
    Ply,
    /// Wavefront OBJ (positions and faces).
    Obj,
    /// VTK XML unstructured grid (`.vtu`) with velocities, indexed by a `.pvd`.
    Vtk,
}

impl FrameFormat {
    /// The file extension (and folder name) of the format.
    pub fn extension(self) -> &'static str {
        match self {
            FrameFormat::Ply => "ply",
            FrameFormat::Obj => "obj",
            FrameFormat::Vtk => "vtu",
        }
    }
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub path: PathBuf,
    pub world: WorldSpec,
    pub end_time: f64,
    pub output: OutputSettings,
    /// The effective overrides, as given.
    pub overrides: Vec<String>,
    /// XXH3-128 of the scene with its overrides applied, `time.end` left out
    /// (a run may be resumed with a later end time): checkpoints record it and
    /// `--resume` refuses a scene that differs.
    pub fingerprint: String,
}

/// Loads `path` with `overrides` (`key.path=value`, applied in order).
pub fn load_scene(path: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|e| SceneError::Read {
        path: path.to_path_buf(),
        source: e,
    })?;
    parse_scene(&text, path, overrides)
}

/// Parses scene `text` (errors name `path`).
pub fn parse_scene(text: &str, path: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
    let syntax = |e: toml::de::Error| SceneError::Syntax {
        path: path.to_path_buf(),
        message: e.to_string().trim_end().to_string(),
    };
    // Deserialize the file as written first: its errors carry line numbers.
    let _: SceneFile = toml::from_str(text).map_err(syntax)?;
    let mut table = toml::Value::Table(text.parse().map_err(syntax)?);
    for a in overrides {
        apply_override(&mut table, a).map_err(|message| SceneError::Override {
            path: path.to_path_buf(),
            assignment: a.clone(),
            message,
        })?;
    }
    let file = SceneFile::deserialize(table.clone()).map_err(|e| SceneError::Override {
        path: path.to_path_buf(),
        assignment: overrides.join(" "),
        message: e.to_string().trim_end().to_string(),
    })?;
    let mut scene = build(file, path, overrides)?;
    if let Some(time) = table.get_mut("time").and_then(|t| t.as_table_mut()) {
        time.remove("end");
    }
    // `toml::Table` keeps keys sorted, so equal scenes print equal text.
    let canonical = toml::to_string(&table).unwrap_or_default();
    scene.fingerprint = format!(
        "{:032x}",
        xxhash_rust::xxh3::xxh3_128(canonical.as_bytes())
    );
    Ok(scene)
}

/// Sets `key.path=value` in `root` (a table); `value` is TOML (a number,
/// boolean, array, quoted string) or else taken as a bare string. Numeric path
/// segments index arrays of tables (`cloth.0.material.density=0.3`).
pub fn apply_override(root: &mut toml::Value, assignment: &str) -> Result<(), String> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| "expected key.path=value".to_string())?;
    let key = key.trim();
    let value: toml::Value = match format!("v = {}", raw.trim()).parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or(toml::Value::String(raw.trim().into())),
        Err(_) => toml::Value::String(raw.trim().into()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err(format!("malformed key '{key}'"));
    }
    let mut cur = root;
    for (n, part) in parts.iter().enumerate() {
        let last = n + 1 == parts.len();
        cur = match cur {
            toml::Value::Table(t) => {
                if last {
                    t.insert(part.to_string(), value);
                    return Ok(());
                }
                t.entry(part.to_string())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            }
            toml::Value::Array(arr) => {
                let i: usize = part
                    .parse()
                    .map_err(|_| format!("'{part}' must be an index into the array"))?;
                let len = arr.len();
                let slot = arr
                    .get_mut(i)
                    .ok_or_else(|| format!("index {i} is out of range (the array has {len})"))?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
            _ => return Err(format!("'{part}' is inside a value that is not a table")),
        };
    }
    Ok(())
}

fn v3(a: [f64; 3]) -> DVec3 {
    DVec3::from_array(a)
}

fn invalid(path: &Path, key: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError::Invalid {
        path: path.to_path_buf(),
        key: key.into(),
        message: message.into(),
    }
}

fn apply_transform(
    m: &mut TriMesh,
    t: &Transform,
    path: &Path,
    key: &str,
) -> Result<(), SceneError> {
    let s = t.scale.unwrap_or(1.0);
    if !(s > 0.0 && s.is_finite()) {
        return Err(invalid(
            path,
            format!("{key}.transform.scale"),
            "must be a positive number",
        ));
    }
    let axis = match t.rotate_axis {
        Some(a) => {
            let a = v3(a);
            if !(a.length() > 0.0 && a.is_finite()) {
                return Err(invalid(
                    path,
                    format!("{key}.transform.rotate_axis"),
                    "must be a non-zero vector",
                ));
            }
            Some(a.normalize())
        }
        None => None,
    };
    for p in &mut m.positions {
        let mut q = *p * s;
        if let Some(a) = axis {
            q = weft_sim::kinematics::rotate(q, a, t.rotate_angle);
        }
        *p = q + v3(t.translate);
    }
    Ok(())
}

fn motion(m: &MotionSection, path: &Path, key: &str) -> Result<Motion, SceneError> {
    match m.kind.as_deref().unwrap_or("fixed") {
        "fixed" => Ok(Motion::Fixed),
        "translate" => Ok(Motion::Translate {
            velocity: v3(m.velocity),
        }),
        "rotate" => {
            if m.omega.is_empty() {
                return Err(invalid(
                    path,
                    format!("{key}.motion.omega"),
                    "rotate needs an angular-velocity profile [[t, omega], ...]",
                ));
            }
            Ok(Motion::Rotate {
                center: v3(m.center),
                axis: v3(m.axis),
                profile: m.omega.iter().map(|p| (p[0], p[1])).collect(),
            })
        }
        other => Err(invalid(
            path,
            format!("{key}.motion.kind"),
            format!("unknown motion '{other}' (expected fixed, translate or rotate)"),
        )),
    }
}

fn load_mesh_file(scene: &Path, file: &str, key: &str) -> Result<TriMesh, SceneError> {
    let p = scene.parent().unwrap_or(Path::new(".")).join(file);
    crate::read_mesh(&p)
        .map(|m| m.mesh)
        .map_err(|e| SceneError::Mesh {
            path: scene.to_path_buf(),
            key: key.to_string(),
            message: e.to_string(),
        })
}

fn build(file: SceneFile, path: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
    if file.version != SCENE_VERSION {
        return Err(invalid(
            path,
            "version",
            format!(
                "this weft reads scene version {SCENE_VERSION}, the file says {}",
                file.version
            ),
        ));
    }
    let pos = |x: f64| x > 0.0 && x.is_finite();
    if !pos(file.time.end) {
        return Err(invalid(
            path,
            "time.end",
            "must be a positive number of seconds",
        ));
    }
    if file.time.steps_per_window == 0 {
        return Err(invalid(path, "time.steps_per_window", "must be at least 1"));
    }
    if !pos(file.output.frame_rate) {
        return Err(invalid(path, "output.frame_rate", "must be positive"));
    }
    let mut formats = Vec::new();
    for (i, f) in file.output.formats.iter().enumerate() {
        let format = match f.as_str() {
            "ply" => FrameFormat::Ply,
            "obj" => FrameFormat::Obj,
            "vtk" => FrameFormat::Vtk,
            other => {
                return Err(invalid(
                    path,
                    format!("output.formats[{i}]"),
                    format!("unknown format '{other}' (expected ply, obj or vtk)"),
                ))
            }
        };
        if formats.contains(&format) {
            return Err(invalid(
                path,
                format!("output.formats[{i}]"),
                format!("'{f}' is listed twice"),
            ));
        }
        formats.push(format);
    }
    if formats.is_empty() {
        return Err(invalid(path, "output.formats", "must name at least one format"));
    }
    if file.cloth.is_empty() {
        return Err(invalid(
            path,
            "cloth",
            "the scene needs at least one [[cloth]]",
        ));
    }
    // `size`: scale generator resolutions to reach about that many cloth vertices.
    let generated: f64 = file
        .cloth
        .iter()
        .filter_map(|c| c.grid.as_ref())
        .map(|g| (g.resolution[0] * g.resolution[1]) as f64)
        .sum();
    let res_scale = if file.size > 0 && generated > 0.0 {
        (file.size as f64 / generated).sqrt()
    } else {
        1.0
    };
    let mut objects = Vec::new();
    for (ci, c) in file.cloth.iter().enumerate() {
        let key = format!("cloth[{ci}] '{}'", c.name);
        let (mut mesh, flat) = match (&c.mesh, &c.grid) {
            (Some(f), None) => {
                let m = load_mesh_file(path, f, &key)?;
                (m, None)
            }
            (None, Some(g)) => {
                let (eu, ev) = match g.plane.as_str() {
                    "xz" => (DVec3::X, DVec3::Z),
                    "xy" => (DVec3::X, DVec3::Y),
                    "yz" => (DVec3::Y, DVec3::Z),
                    other => {
                        return Err(invalid(
                            path,
                            format!("{key}.grid.plane"),
                            format!("unknown plane '{other}' (expected xz, xy or yz)"),
                        ))
                    }
                };
                if !(pos(g.size[0]) && pos(g.size[1])) {
                    return Err(invalid(
                        path,
                        format!("{key}.grid.size"),
                        "side lengths must be positive",
                    ));
                }
                let res = [
                    ((g.resolution[0] as f64 * res_scale).round() as usize).max(2),
                    ((g.resolution[1] as f64 * res_scale).round() as usize).max(2),
                ];
                let flat = weft_geom::shapes::grid(v3(g.center), eu, ev, g.size, res);
                let mut m = flat.clone();
                if g.wave != 0.0 {
                    let n = eu.cross(ev);
                    for (k, p) in m.positions.iter_mut().enumerate() {
                        let (i, j) = (k % res[0], k / res[0]);
                        let s = i as f64 / (res[0] - 1) as f64;
                        let t = j as f64 / (res[1] - 1) as f64;
                        let amp = libm::sin(std::f64::consts::PI * g.wave_count[0] * s)
                            * libm::sin(std::f64::consts::PI * g.wave_count[1] * t);
                        *p += n * (g.wave * amp);
                    }
                }
                (m, Some(flat))
            }
            _ => return Err(invalid(path, key, "give exactly one of `mesh` or `grid`")),
        };
        apply_transform(&mut mesh, &c.transform, path, &key)?;
        let rest = match c.rest.as_str() {
            "initial" => None,
            "flat" => match flat {
                Some(f) => Some(f.positions),
                None => {
                    return Err(invalid(
                        path,
                        format!("{key}.rest"),
                        "\"flat\" needs a generated cloth",
                    ))
                }
            },
            other => {
                return Err(invalid(
                    path,
                    format!("{key}.rest"),
                    format!("unknown rest shape '{other}' (expected initial or flat)"),
                ))
            }
        };
        let spin = v3(c.spin);
        let velocity = mesh
            .positions
            .iter()
            .map(|p| v3(c.velocity) + spin.cross(*p - v3(c.spin_center)))
            .collect();
        let m = &c.material;
        let mut material =
            Material::plate(m.density, m.youngs_modulus, m.poisson_ratio, m.thickness);
        if let Some(k_b) = m.bending_stiffness {
            material.bending_stiffness = k_b;
        }
        material.stretch_damping = m.stretch_damping;
        material.bend_damping = m.bend_damping;
        objects.push(ObjectSpec {
            name: c.name.clone(),
            mesh,
            kind: ObjectKind::Cloth {
                material,
                rest,
                velocity,
            },
        });
    }
    for (oi, o) in file.obstacle.iter().enumerate() {
        let key = format!("obstacle[{oi}] '{}'", o.name);
        let mut mesh = match (&o.mesh, &o.sphere, &o.cuboid, &o.cylinder) {
            (Some(f), None, None, None) => load_mesh_file(path, f, &key)?,
            (None, Some(s), None, None) => {
                if !pos(s.radius) || s.subdivisions > 7 {
                    return Err(invalid(
                        path,
                        format!("{key}.sphere"),
                        "radius must be positive and subdivisions at most 7",
                    ));
                }
                weft_geom::shapes::sphere(v3(s.center), s.radius, s.subdivisions)
            }
            (None, None, Some(b), None) => {
                if !(0..3).all(|k| b.max[k] > b.min[k]) {
                    return Err(invalid(
                        path,
                        format!("{key}.box"),
                        "max must exceed min on every axis",
                    ));
                }
                weft_geom::shapes::cuboid(v3(b.min), v3(b.max))
            }
            (None, None, None, Some(c)) => {
                if !pos(c.radius) || v3(c.from) == v3(c.to) {
                    return Err(invalid(
                        path,
                        format!("{key}.cylinder"),
                        "needs a positive radius and distinct ends",
                    ));
                }
                weft_geom::shapes::capped_cylinder(
                    v3(c.from),
                    v3(c.to),
                    c.radius,
                    c.segments,
                    c.rings,
                )
            }
            _ => {
                return Err(invalid(
                    path,
                    key,
                    "give exactly one of `mesh`, `sphere`, `box` or `cylinder`",
                ))
            }
        };
        apply_transform(&mut mesh, &o.transform, path, &key)?;
        objects.push(ObjectSpec {
            name: o.name.clone(),
            mesh,
            kind: ObjectKind::Obstacle {
                motion: motion(&o.motion, path, &key)?,
            },
        });
    }
    let mut pins = Vec::new();
    for (pi, p) in file.pin.iter().enumerate() {
        let key = format!("pin[{pi}] '{}'", p.name);
        let object = file
            .cloth
            .iter()
            .position(|c| c.name == p.object)
            .ok_or_else(|| {
                invalid(
                    path,
                    format!("{key}.object"),
                    format!("no cloth named '{}'", p.object),
                )
            })?;
        let mut vertices = p.indices.clone();
        match (p.box_min, p.box_max) {
            (Some(lo), Some(hi)) => {
                let (lo, hi) = (v3(lo), v3(hi));
                for (i, x) in objects[object].mesh.positions.iter().enumerate() {
                    if x.cmpge(lo).all() && x.cmple(hi).all() {
                        vertices.push(i as u32);
                    }
                }
            }
            (None, None) => {}
            _ => return Err(invalid(path, key, "give both box_min and box_max")),
        }
        vertices.sort_unstable();
        vertices.dedup();
        pins.push(PinSpec {
            name: p.name.clone(),
            object,
            vertices,
            motion: motion(&p.motion, path, &key)?,
        });
    }
    let world = WorldSpec {
        objects,
        pins,
        gravity: v3(file.gravity),
        contact: ContactConfig {
            thickness: file.contact.thickness,
            floor_fraction: file.contact.floor,
            stiffness: file.contact.stiffness,
            layer1_step_shift: file.contact.layer1_step_shift,
            layers_per_detection: file.contact.layers_per_detection,
            retire_after_windows: file.contact.retire_after_windows,
            friction: file.contact.friction,
            max_rollbacks: file.contact.max_rollbacks,
        },
        time: TimeConfig {
            internal_step: file.time.internal_step,
            beta: file.time.beta,
            steps_per_window: file.time.steps_per_window,
        },
        limits: LimitsConfig::default(),
        partitions: file.partitions.max(1),
    };
    if file.contact.layer1_step_shift > 16 {
        return Err(invalid(
            path,
            "contact.layer1_step_shift",
            "must be at most 16",
        ));
    }
    if !(file.contact.friction >= 0.0 && file.contact.friction.is_finite()) {
        return Err(invalid(
            path,
            "contact.friction",
            "must be a non-negative number",
        ));
    }
    Ok(Scene {
        name: file.name.clone().unwrap_or_else(|| {
            path.file_stem()
                .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned())
        }),
        path: path.to_path_buf(),
        world,
        end_time: file.time.end,
        output: OutputSettings {
            frame_rate: file.output.frame_rate,
            formats,
            checkpoint_every: file.output.checkpoint_every,
        },
        overrides: overrides.to_vec(),
        fingerprint: String::new(),
    })
}
