//! Scene files: TOML → validated [`Scene`] (a `WorldSpec` plus run settings).
//!
//! Loading reads the file, applies `--set key.path=value` overrides, rejects
//! unknown keys and wrong types with the file, line and key, resolves mesh files
//! relative to the scene, runs the generators and validates every value.

pub mod memory;
pub mod ribbon;
pub mod schema;

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Deserialize;
use thiserror::Error;
use weft_core::mesh::bounding_box;
use weft_core::{ElementNames, TriMesh};
use weft_sim::config::{ContactConfig, LimitsConfig, TimeConfig};
use weft_sim::kinematics::{Keyframes, Motion};
use weft_sim::materials::Material;
use weft_sim::{ObjectKind, ObjectSpec, PinSpec, WorldSpec};

use memory::{MemoryBudget, MemoryLimit};
use schema::{
    CameraSection, ClothSection, MeshSequenceSection, MotionSection, SceneFile, TimeSection,
    Transform, DEFAULT_STEPS_PER_WINDOW, SCENE_VERSION,
};

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
    /// Wall-time minutes after which a checkpoint is written even before
    /// `checkpoint_every` windows (0 = never on wall time).
    pub checkpoint_minutes: f64,
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

/// Where a renderer looks from: `[camera]` of the scene (the simulation
/// ignores it).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Eye position (m).
    pub eye: [f64; 3],
    /// Point looked at (m).
    pub target: [f64; 3],
    /// Up direction (not parallel to `target - eye`).
    pub up: [f64; 3],
    /// Vertical field of view (degrees, in (0, 180)).
    pub fov_degrees: f64,
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub path: PathBuf,
    pub world: WorldSpec,
    pub end_time: f64,
    pub output: OutputSettings,
    /// The `[camera]` table, if the scene has one.
    pub camera: Option<CameraSettings>,
    /// The effective overrides, as given.
    pub overrides: Vec<String>,
    /// XXH3-128 of the scene with its overrides applied, `time.end` left out
    /// (a run may be resumed with a later end time): checkpoints record it and
    /// `--resume` refuses a scene that differs.
    pub fingerprint: String,
    /// What loading found suspicious but simulable (mesh warnings, naming
    /// elements as their files do), for the start-up warnings.
    pub warnings: Vec<String>,
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
    // Nor does the partition count: results never depend on it, so a run
    // resumes on any partitioning.
    if let Some(root) = table.as_table_mut() {
        root.remove("partitions");
    }
    // Nor do the layer activation policies: which layers are active never
    // changes the trajectory (policy independence, `acm-spec.md` §4), so a
    // run resumes, and `weft bench` starts, under another policy; nor how
    // the penalty stage is split into islands (the same bits).
    if let Some(contact) = table.get_mut("contact").and_then(|t| t.as_table_mut()) {
        for key in [
            "predict",
            "layers_per_detection",
            "retire_after_windows",
            "split_islands",
        ] {
            contact.remove(key);
        }
    }
    // `toml::Table` keeps keys sorted, so equal scenes print equal text.
    let canonical = toml::to_string(&table).unwrap_or_default();
    scene.fingerprint = format!("{:032x}", xxhash_rust::xxh3::xxh3_128(canonical.as_bytes()));
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
    let s = v3(t.scale.map_or([1.0; 3], schema::Scale::per_axis));
    if !(s.cmpgt(DVec3::ZERO).all() && s.is_finite()) {
        return Err(invalid(
            path,
            format!("{key}.transform.scale"),
            "must be a positive number, or [sx, sy, sz] of positive numbers",
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
    let kind = m.kind.as_deref().unwrap_or("fixed");
    if m.until.is_some() && kind != "translate" {
        return Err(invalid(
            path,
            format!("{key}.motion.until"),
            format!("`until` belongs to kind = \"translate\", not \"{kind}\""),
        ));
    }
    match kind {
        "fixed" => Ok(Motion::Fixed),
        "translate" => {
            if let Some(u) = m.until {
                if !(u >= 0.0 && u.is_finite()) {
                    return Err(invalid(
                        path,
                        format!("{key}.motion.until"),
                        format!("{u} must be a non-negative number of seconds"),
                    ));
                }
            }
            Ok(Motion::Translate {
                velocity: v3(m.velocity),
                until: m.until,
            })
        }
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

/// An object's own friction coefficient, checked.
fn object_friction(mu: Option<f64>, path: &Path, key: &str) -> Result<Option<f64>, SceneError> {
    match mu {
        Some(m) if !(m >= 0.0 && m.is_finite()) => Err(invalid(
            path,
            format!("{key}.friction"),
            "must be a non-negative number",
        )),
        _ => Ok(mu),
    }
}

/// Reads a mesh file for `key`; what validation found suspicious but
/// simulable goes to `notes`, naming elements as the file numbers them.
fn load_mesh_file(
    scene: &Path,
    file: &str,
    key: &str,
    notes: &mut Vec<String>,
) -> Result<crate::MeshFile, SceneError> {
    let m = load_mesh_full(scene, file, key)?;
    let names = m.names();
    notes.extend(
        m.warnings
            .iter()
            .map(|w| format!("{key}: {file}: {}", w.describe(&names))),
    );
    Ok(m)
}

/// How many places [`refuse_unwelded`] lists.
const LISTED_PLACES: usize = 4;

/// Refuses a cloth mesh with vertices at exactly the same position: an
/// unwelded mesh (one vertex per triangle corner, as some exporters write)
/// holds together nowhere and starts in contact with itself everywhere. Only
/// vertices a triangle uses count: a stray duplicate no triangle uses (an
/// export leftover validation warns about) joins nothing apart.
fn refuse_unwelded(
    m: &crate::MeshFile,
    scene: &Path,
    key: &str,
    file: &str,
) -> Result<(), SceneError> {
    let mut used = vec![false; m.mesh.positions.len()];
    for t in &m.mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut groups: Vec<Vec<u32>> = weft_core::coincident::coincident_vertices(&m.mesh.positions)
        .into_iter()
        .map(|g| {
            g.into_iter()
                .filter(|&v| used[v as usize])
                .collect::<Vec<_>>()
        })
        .filter(|g| g.len() > 1)
        .collect();
    groups.sort_unstable_by_key(|g| g[0]);
    if groups.is_empty() {
        return Ok(());
    }
    let names = m.names();
    let extra: usize = groups.iter().map(|g| g.len() - 1).sum();
    let places: Vec<String> = groups
        .iter()
        .take(LISTED_PLACES)
        .map(|g| {
            g.iter()
                .map(|&v| names.vertex(v))
                .collect::<Vec<_>>()
                .join(" = ")
        })
        .collect();
    Err(SceneError::Mesh {
        path: scene.to_path_buf(),
        key: key.to_string(),
        message: format!(
            "{file}: {extra} vertices lie exactly on other vertices, at {} places ({}{}): \
             the triangles there are not joined, so the cloth would fall apart and start in \
             contact with itself; weld the mesh ({extra} coincident vertices), e.g. Blender's \
             Merge by Distance",
            groups.len(),
            places.join("; "),
            if groups.len() > LISTED_PLACES {
                "; …"
            } else {
                ""
            }
        ),
    })
}

/// Reads a mesh file with what its format carries (UVs, source lines).
fn load_mesh_full(scene: &Path, file: &str, key: &str) -> Result<crate::MeshFile, SceneError> {
    let p = scene.parent().unwrap_or(Path::new(".")).join(file);
    crate::read_mesh(&p).map_err(|e| SceneError::Mesh {
        path: scene.to_path_buf(),
        key: key.to_string(),
        message: e.to_string(),
    })
}

/// `rest = "uv"`: each vertex's texture coordinates `(u, v) · uv_scale` in
/// the xy plane. Needs an OBJ file with a UV on every face corner and one UV
/// per vertex (no seams).
fn uv_rest(scene: &Path, c: &ClothSection, key: &str) -> Result<Vec<DVec3>, SceneError> {
    let rest_key = format!("{key}.rest");
    let Some(f) = &c.mesh else {
        return Err(invalid(
            scene,
            rest_key,
            "\"uv\" needs a cloth read from a mesh file (`mesh`) with texture coordinates",
        ));
    };
    let scale = c.uv_scale.unwrap_or(1.0);
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(invalid(
            scene,
            format!("{key}.uv_scale"),
            "must be a positive number of metres per UV unit",
        ));
    }
    let file = load_mesh_full(scene, f, key)?;
    let (Some(uvs), Some(face_uvs)) = (&file.uvs, &file.face_uvs) else {
        return Err(invalid(
            scene,
            rest_key,
            format!("\"uv\" needs texture coordinates (`vt`, `f a/t ...`) on every face corner; {f} has none on some faces"),
        ));
    };
    let mut per_vertex: Vec<Option<[f64; 2]>> = vec![None; file.mesh.num_vertices()];
    for (t, (tri, tuv)) in file.mesh.triangles.iter().zip(face_uvs).enumerate() {
        for corner in 0..3 {
            let v = tri[corner] as usize;
            let uv = uvs[tuv[corner] as usize];
            match per_vertex[v] {
                None => per_vertex[v] = Some(uv),
                Some(prev) if prev == uv => {}
                Some(prev) => {
                    let line = file
                        .line_of_triangle(t)
                        .map_or(String::new(), |l| format!(":{l}"));
                    return Err(invalid(
                        scene,
                        rest_key,
                        format!(
                            "{f}{line}: v {} has two texture coordinates ({:?} and {:?}): a UV \
                             seam; \"uv\" needs one per vertex (split the mesh along the seam)",
                            v + 1,
                            prev,
                            uv
                        ),
                    ));
                }
            }
        }
    }
    per_vertex
        .iter()
        .enumerate()
        .map(|(v, uv)| match uv {
            Some([u, w]) => Ok(DVec3::new(u * scale, w * scale, 0.0)),
            None => Err(invalid(
                scene,
                format!("{key}.rest"),
                format!(
                    "{f}: v {} is in no face, so it has no texture coordinate",
                    v + 1
                ),
            )),
        })
        .collect()
}

/// Checks that `other` (read from `file`) has the connectivity of `mesh`.
fn same_connectivity(
    mesh: &TriMesh,
    other: &TriMesh,
    scene: &Path,
    key: &str,
    file: &str,
    what: &str,
) -> Result<(), SceneError> {
    if other.num_vertices() != mesh.num_vertices() {
        return Err(invalid(
            scene,
            key,
            format!(
                "{file} has {} vertices, {what} has {}",
                other.num_vertices(),
                mesh.num_vertices()
            ),
        ));
    }
    if other.num_triangles() != mesh.num_triangles() {
        return Err(invalid(
            scene,
            key,
            format!(
                "{file} has {} triangles, {what} has {}",
                other.num_triangles(),
                mesh.num_triangles()
            ),
        ));
    }
    if let Some(f) = (0..mesh.num_triangles()).find(|&f| mesh.triangles[f] != other.triangles[f]) {
        return Err(invalid(
            scene,
            key,
            format!(
                "{file}: triangle {f} is {:?}, in {what} it is {:?} (the connectivity must be the same)",
                other.triangles[f], mesh.triangles[f]
            ),
        ));
    }
    Ok(())
}

/// `true` if `name` matches `pattern` (`*` any run of characters, `?` one).
fn glob_match(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    // matched[j]: p[..i] matches n[..j].
    let mut matched = vec![false; n.len() + 1];
    matched[0] = true;
    for &pc in &p {
        let mut next = vec![false; n.len() + 1];
        match pc {
            '*' => {
                let mut any = false;
                for j in 0..=n.len() {
                    any |= matched[j];
                    next[j] = any;
                }
            }
            _ => {
                for j in 0..n.len() {
                    next[j + 1] = matched[j] && (pc == '?' || pc == n[j]);
                }
            }
        }
        matched = next;
    }
    matched[n.len()]
}

/// The frame files of a mesh sequence, relative to the scene's folder.
fn sequence_files(
    scene: &Path,
    seq: &MeshSequenceSection,
    key: &str,
) -> Result<Vec<String>, SceneError> {
    let key = format!("{key}.mesh_sequence");
    match (&seq.pattern, seq.files.is_empty()) {
        (Some(_), false) => Err(invalid(scene, key, "give `files` or `pattern`, not both")),
        (None, true) => Err(invalid(
            scene,
            key,
            "give the frame `files = [...]` or a `pattern = \"dir/f*.obj\"`",
        )),
        (None, false) => Ok(seq.files.clone()),
        (Some(pattern), true) => {
            let (dir, name) = match pattern.rsplit_once('/') {
                Some((d, n)) => (d, n),
                None => ("", pattern.as_str()),
            };
            if dir.contains(['*', '?']) {
                return Err(invalid(
                    scene,
                    format!("{key}.pattern"),
                    format!("'{pattern}': wildcards are allowed in the file name only"),
                ));
            }
            let base = scene.parent().unwrap_or(Path::new("."));
            let folder = base.join(if dir.is_empty() { "." } else { dir });
            let entries = std::fs::read_dir(&folder).map_err(|e| {
                invalid(
                    scene,
                    format!("{key}.pattern"),
                    format!("cannot list {}: {e}", folder.display()),
                )
            })?;
            let mut names: Vec<String> = entries
                .filter_map(|e| e.ok())
                .filter(|e| e.file_type().is_ok_and(|t| !t.is_dir()))
                .filter_map(|e| e.file_name().to_str().map(str::to_string))
                .filter(|n| glob_match(name, n))
                .collect();
            names.sort();
            if names.is_empty() {
                return Err(invalid(
                    scene,
                    format!("{key}.pattern"),
                    format!("'{pattern}' matches no file in {}", folder.display()),
                ));
            }
            Ok(names
                .into_iter()
                .map(|n| {
                    if dir.is_empty() {
                        n
                    } else {
                        format!("{dir}/{n}")
                    }
                })
                .collect())
        }
    }
}

/// Reads a mesh sequence: the first frame's mesh (transformed) and the
/// keyframed motion of its vertices. Every frame must have the first one's
/// connectivity; the transform applies to every frame.
fn load_sequence(
    scene: &Path,
    seq: &MeshSequenceSection,
    transform: &Transform,
    key: &str,
    notes: &mut Vec<String>,
) -> Result<(TriMesh, Keyframes), SceneError> {
    let seq_key = format!("{key}.mesh_sequence");
    if !(seq.frame_rate > 0.0 && seq.frame_rate.is_finite()) {
        return Err(invalid(
            scene,
            format!("{seq_key}.frame_rate"),
            "must be a positive number of frames per second",
        ));
    }
    if !seq.start.is_finite() {
        return Err(invalid(
            scene,
            format!("{seq_key}.start"),
            "must be a finite time (s)",
        ));
    }
    let files = sequence_files(scene, seq, key)?;
    let mut first: Option<TriMesh> = None;
    let mut frames = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        // Every frame has the first one's connectivity, so its notes stand
        // for all of them.
        let mut later_notes = Vec::new();
        let sink = if i == 0 {
            &mut *notes
        } else {
            &mut later_notes
        };
        let mut m = load_mesh_file(scene, f, &format!("{seq_key}.files[{i}]"), sink)?.mesh;
        apply_transform(&mut m, transform, scene, key)?;
        match &first {
            None => first = Some(m.clone()),
            Some(m0) => same_connectivity(
                m0,
                &m,
                scene,
                &format!("{seq_key}.files[{i}]"),
                f,
                &format!("the first frame ({})", files[0]),
            )?,
        }
        frames.push(m.positions);
    }
    let mesh = first.expect("at least one frame");
    Ok((
        mesh,
        Keyframes {
            frame_rate: seq.frame_rate,
            start: seq.start,
            frames,
        },
    ))
}

/// A generator's resolution as written and, when the scene's `size` scaled
/// it, as scaled (for the memory refusal).
fn resolution_source(written: [usize; 2], scaled: [f64; 2], size: u64) -> String {
    let scaled = format!("[{:.0}, {:.0}]", scaled[0], scaled[1]);
    match size {
        0 => format!("resolution {scaled}"),
        _ => format!("resolution {written:?}, scaled by size = {size} to {scaled},"),
    }
}

/// `[time]`: the internal step (if given or implied) and the steps per
/// window, from any two of `window`, `internal_step`, `steps_per_window`.
fn resolve_time(t: &TimeSection, path: &Path) -> Result<(Option<f64>, u64), SceneError> {
    let pos = |x: f64| x > 0.0 && x.is_finite();
    if t.steps_per_window == Some(0) {
        return Err(invalid(path, "time.steps_per_window", "must be at least 1"));
    }
    if let Some(h) = t.internal_step {
        if !pos(h) {
            return Err(invalid(
                path,
                "time.internal_step",
                "must be a positive number of seconds",
            ));
        }
    }
    let Some(w) = t.window else {
        return Ok((
            t.internal_step,
            t.steps_per_window.unwrap_or(DEFAULT_STEPS_PER_WINDOW),
        ));
    };
    if !pos(w) {
        return Err(invalid(
            path,
            "time.window",
            "must be a positive number of seconds",
        ));
    }
    match t.internal_step {
        Some(h) => {
            let ratio = w / h;
            let n = ratio.round();
            if !(n >= 1.0 && n < u32::MAX as f64) {
                return Err(invalid(
                    path,
                    "time.window",
                    format!(
                        "a window of {w:e} s holds {ratio:.3} internal steps of {h:e} s; it must hold at least one"
                    ),
                ));
            }
            let n = n as u64;
            if let Some(s) = t.steps_per_window {
                if s != n {
                    return Err(invalid(
                        path,
                        "time.steps_per_window",
                        format!(
                            "{s} contradicts time.window / time.internal_step = {w:e} s / {h:e} s = \
                             {ratio:.3} steps; give two of the three"
                        ),
                    ));
                }
            }
            Ok((Some(h), n))
        }
        None => {
            let s = t.steps_per_window.unwrap_or(DEFAULT_STEPS_PER_WINDOW);
            Ok((Some(w / s as f64), s))
        }
    }
}

/// Validates `[camera]`.
fn camera(c: &CameraSection, path: &Path) -> Result<CameraSettings, SceneError> {
    let finite = |a: [f64; 3]| a.iter().all(|x| x.is_finite());
    for (k, a) in [("eye", c.eye), ("target", c.target), ("up", c.up)] {
        if !finite(a) {
            return Err(invalid(path, format!("camera.{k}"), "must be finite"));
        }
    }
    let view = v3(c.target) - v3(c.eye);
    if !(view.length() > 0.0) {
        return Err(invalid(
            path,
            "camera.target",
            "must differ from camera.eye",
        ));
    }
    let up = v3(c.up);
    if !(up.cross(view).length() > 1e-9 * up.length() * view.length()) {
        return Err(invalid(
            path,
            "camera.up",
            "must be a non-zero vector not parallel to target - eye",
        ));
    }
    if !(c.fov_degrees > 0.0 && c.fov_degrees < 180.0) {
        return Err(invalid(
            path,
            "camera.fov_degrees",
            "must be in (0, 180) degrees",
        ));
    }
    Ok(CameraSettings {
        eye: c.eye,
        target: c.target,
        up: c.up,
        fov_degrees: c.fov_degrees,
    })
}

/// Pin selection `box_min`, `box_max` on `object` (object-local ids of the
/// vertices inside the closed box). With `relative`, the corners are fractions
/// of the object's bounding box. A box that selects nothing is refused: it is
/// a typo or a unit mistake, and the pin would silently hold less.
fn pin_box(
    object: &ObjectSpec,
    lo: DVec3,
    hi: DVec3,
    relative: bool,
    path: &Path,
    key: &str,
) -> Result<Vec<u32>, SceneError> {
    let positions = &object.mesh.positions;
    let (min, max) = bounding_box(positions);
    // min·(1 - t) + max·t is exactly min at t = 0 and max at t = 1.
    let at = |t: DVec3| min * (DVec3::ONE - t) + max * t;
    let given = (lo.to_array(), hi.to_array());
    let (lo, hi) = if relative { (at(lo), at(hi)) } else { (lo, hi) };
    let inside: Vec<u32> = (0..positions.len() as u32)
        .filter(|&i| {
            let x = positions[i as usize];
            x.cmpge(lo).all() && x.cmple(hi).all()
        })
        .collect();
    if inside.is_empty() {
        return Err(invalid(
            path,
            format!("{key}.box_min"),
            format!(
                "the box from {:?} to {:?} m{} selects no vertex of cloth '{}', whose bounding \
                 box runs from {:?} to {:?} m",
                lo.to_array(),
                hi.to_array(),
                if relative {
                    format!(
                        " (relative = true: {:?} to {:?} of the bounding box)",
                        given.0, given.1
                    )
                } else {
                    String::new()
                },
                object.name,
                min.to_array(),
                max.to_array()
            ),
        ));
    }
    Ok(inside)
}

/// Pin selection `boundary = "all" | "outer"` on `mesh` (object-local ids).
fn boundary_vertices(
    mesh: &TriMesh,
    which: &str,
    path: &Path,
    key: &str,
) -> Result<Vec<u32>, SceneError> {
    let loops = weft_geom::shapes::boundary_components(mesh.num_vertices(), &mesh.triangles);
    if loops.is_empty() {
        return Err(invalid(
            path,
            format!("{key}.boundary"),
            "the object is closed: it has no boundary",
        ));
    }
    match which {
        "all" => Ok(loops.concat()),
        "outer" => {
            let extent = |l: &Vec<u32>| {
                let (lo, hi) = l.iter().fold(
                    (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                    |(lo, hi), &i| {
                        let p = mesh.positions[i as usize];
                        (lo.min(p), hi.max(p))
                    },
                );
                (hi - lo).length()
            };
            let mut best = 0;
            for (i, l) in loops.iter().enumerate() {
                if extent(l) > extent(&loops[best]) {
                    best = i;
                }
            }
            Ok(loops[best].clone())
        }
        other => Err(invalid(
            path,
            format!("{key}.boundary"),
            format!("unknown boundary '{other}' (expected all or outer)"),
        )),
    }
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
    let (internal_step, steps_per_window) = resolve_time(&file.time, path)?;
    // Every object is admitted against the machine's memory before (for a
    // generator) or as it is built.
    let mut budget = MemoryBudget::new(MemoryLimit::this_machine(), steps_per_window);
    if !pos(file.output.frame_rate) {
        return Err(invalid(path, "output.frame_rate", "must be positive"));
    }
    let minutes = file.output.checkpoint_minutes;
    if !(minutes >= 0.0 && minutes.is_finite()) {
        return Err(invalid(
            path,
            "output.checkpoint_minutes",
            format!("{minutes} must be a non-negative number of minutes (0: none on wall time)"),
        ));
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
        return Err(invalid(
            path,
            "output.formats",
            "must name at least one format",
        ));
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
        .map(|g| g.resolution[0] as f64 * g.resolution[1] as f64)
        .sum::<f64>()
        + file
            .cloth
            .iter()
            .filter_map(|c| c.ribbon.as_ref())
            .map(ribbon::written_vertices)
            .sum::<f64>()
        + file
            .cloth
            .iter()
            .filter_map(|c| c.tube.as_ref())
            .map(|t| t.resolution[0] as f64 * t.resolution[1] as f64)
            .sum::<f64>();
    let res_scale = if file.size > 0 && generated > 0.0 {
        (file.size as f64 / generated).sqrt()
    } else {
        1.0
    };
    let mut objects = Vec::new();
    let mut notes = Vec::new();
    for (ci, c) in file.cloth.iter().enumerate() {
        let key = format!("cloth[{ci}] '{}'", c.name);
        let (mut mesh, flat) = match (&c.mesh, &c.grid) {
            _ if c.tube.is_some()
                && (c.mesh.is_some() || c.grid.is_some() || c.ribbon.is_some()) =>
            {
                return Err(invalid(
                    path,
                    key,
                    "give exactly one of `mesh`, `grid`, `ribbon` or `tube`",
                ))
            }
            _ if c.tube.is_some() => {
                let t = c.tube.as_ref().expect("checked by the guard");
                let tube_key = format!("{key}.tube");
                let rest_radius = t.rest_radius.unwrap_or(t.radius);
                if !(pos(t.radius) && pos(rest_radius)) {
                    return Err(invalid(
                        path,
                        tube_key,
                        "radius and rest_radius must be positive",
                    ));
                }
                let (a, b) = (v3(t.from), v3(t.to));
                if !(a.is_finite() && b.is_finite() && (b - a).length() > 0.0) {
                    return Err(invalid(
                        path,
                        tube_key,
                        "from and to must be distinct finite points",
                    ));
                }
                let res = [
                    (t.resolution[0] as f64 * res_scale).round().max(3.0),
                    (t.resolution[1] as f64 * res_scale).round().max(2.0),
                ];
                budget.admit(
                    path,
                    &format!("{tube_key}.resolution"),
                    &resolution_source(t.resolution, res, file.size),
                    res[0] * res[1],
                    2.0 * res[0] * (res[1] - 1.0),
                    true,
                )?;
                let res = res.map(|r| r as usize);
                let m = weft_geom::shapes::tube(a, b, t.radius, res);
                let rest = weft_geom::shapes::tube(a, b, rest_radius, res);
                (m, Some(rest))
            }
            (None, None) if c.ribbon.is_some() => {
                let r = c.ribbon.as_ref().expect("checked by the guard");
                let target = (file.size > 0 && generated > 0.0)
                    .then(|| (ribbon::written_vertices(r) * file.size as f64 / generated).round());
                let vertices = target.unwrap_or_else(|| ribbon::written_vertices(r));
                let source = match target {
                    Some(_) => format!("the ribbon, scaled by size = {},", file.size),
                    None => format!("the ribbon with across = {}", r.across),
                };
                let ribbon_key = format!("{key}.ribbon");
                budget.admit(path, &ribbon_key, &source, vertices, 2.0 * vertices, true)?;
                let target = target.map(|n| n as usize);
                let rb = ribbon::build(r, path, &key, file.contact.thickness, target)?;
                (rb.mesh, Some(rb.flat))
            }
            _ if c.ribbon.is_some() => {
                return Err(invalid(
                    path,
                    key,
                    "give exactly one of `mesh`, `grid`, `ribbon` or `tube`",
                ))
            }
            (Some(f), None) => {
                let m = load_mesh_file(path, f, &key, &mut notes)?;
                let (v, t) = (m.mesh.num_vertices() as f64, m.mesh.num_triangles() as f64);
                budget.admit(path, &key, &format!("the mesh {f}"), v, t, true)?;
                refuse_unwelded(&m, path, &key, f)?;
                (m.mesh, None)
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
                    (g.resolution[0] as f64 * res_scale).round().max(2.0),
                    (g.resolution[1] as f64 * res_scale).round().max(2.0),
                ];
                budget.admit(
                    path,
                    &format!("{key}.grid.resolution"),
                    &resolution_source(g.resolution, res, file.size),
                    res[0] * res[1],
                    2.0 * (res[0] - 1.0) * (res[1] - 1.0),
                    true,
                )?;
                let res = res.map(|r| r as usize);
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
                let mut flat = flat;
                if let Some(h) = &g.hole {
                    let hole_key = format!("{key}.grid.hole");
                    let rest_radius = h.rest_radius.unwrap_or(h.radius);
                    if !(pos(h.radius) && pos(rest_radius)) {
                        return Err(invalid(
                            path,
                            hole_key,
                            "radius and rest_radius must be positive",
                        ));
                    }
                    if !h.center.iter().all(|x| x.is_finite()) {
                        return Err(invalid(path, hole_key, "center must be finite"));
                    }
                    // The rest shape is remapped out to twice the larger radius;
                    // that band must lie inside the sheet.
                    let band = 2.0 * h.radius.max(rest_radius);
                    if h.center[0].abs() + band > 0.5 * g.size[0]
                        || h.center[1].abs() + band > 0.5 * g.size[1]
                    {
                        return Err(invalid(
                            path,
                            hole_key,
                            format!(
                                "the hole and its band (out to {band} m from its center) must lie inside the {} m × {} m grid",
                                g.size[0], g.size[1]
                            ),
                        ));
                    }
                    let c = v3(g.center) + eu * h.center[0] + ev * h.center[1];
                    let (holed, index) = weft_geom::shapes::grid_with_hole(
                        v3(g.center),
                        eu,
                        ev,
                        g.size,
                        res,
                        h.center,
                        h.radius,
                    )
                    .map_err(|e| {
                        invalid(
                            path,
                            hole_key.clone(),
                            format!("{e}; raise the resolution or the radius"),
                        )
                    })?;
                    // Start shape: the grid's own (waved) positions where a
                    // vertex kept its place; the rim ring and the relaxed cut
                    // get the wave at their position.
                    let n = eu.cross(ev);
                    let positions = holed
                        .positions
                        .iter()
                        .zip(&index)
                        .map(|(p, i)| match i {
                            Some(i) if *p == flat.positions[*i as usize] => {
                                m.positions[*i as usize]
                            }
                            _ if g.wave != 0.0 => {
                                let d = *p - v3(g.center);
                                let s = d.dot(eu) / g.size[0] + 0.5;
                                let t = d.dot(ev) / g.size[1] + 0.5;
                                let amp = libm::sin(std::f64::consts::PI * g.wave_count[0] * s)
                                    * libm::sin(std::f64::consts::PI * g.wave_count[1] * t);
                                *p + n * (g.wave * amp)
                            }
                            _ => *p,
                        })
                        .collect();
                    m = TriMesh::new(positions, holed.triangles.clone());
                    flat = holed;
                    let normal = eu.cross(ev);
                    for p in &mut flat.positions {
                        *p = weft_geom::shapes::radial_remap(
                            *p,
                            c,
                            normal,
                            h.radius,
                            rest_radius,
                            band,
                        );
                    }
                }
                (m, Some(flat))
            }
            _ => return Err(invalid(path, key, "give exactly one of `mesh` or `grid`")),
        };
        apply_transform(&mut mesh, &c.transform, path, &key)?;
        if c.rest_mesh.is_some() && c.rest != "initial" {
            return Err(invalid(
                path,
                format!("{key}.rest_mesh"),
                format!("give `rest_mesh` or rest = \"{}\", not both", c.rest),
            ));
        }
        let rest = match c.rest.as_str() {
            // A ribbon always rests on its flat strip.
            "initial" if c.ribbon.is_none() => None,
            "initial" | "flat" => match flat {
                Some(f) => Some(f.positions),
                None => {
                    return Err(invalid(
                        path,
                        format!("{key}.rest"),
                        "\"flat\" needs a generated cloth",
                    ))
                }
            },
            "uv" => Some(uv_rest(path, c, &key)?),
            other => {
                return Err(invalid(
                    path,
                    format!("{key}.rest"),
                    format!("unknown rest shape '{other}' (expected initial, flat or uv)"),
                ))
            }
        };
        if c.uv_scale.is_some() && c.rest != "uv" {
            return Err(invalid(
                path,
                format!("{key}.uv_scale"),
                "belongs to rest = \"uv\"",
            ));
        }
        let rest = match &c.rest_mesh {
            None => rest,
            Some(f) => {
                let rest_key = format!("{key}.rest_mesh");
                // The cloth's own file has already said what is suspicious
                // about this connectivity.
                let mut r = load_mesh_file(path, f, &rest_key, &mut Vec::new())?.mesh;
                same_connectivity(&mesh, &r, path, &rest_key, f, "the cloth mesh")?;
                apply_transform(&mut r, &c.transform, path, &key)?;
                Some(r.positions)
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
            friction: object_friction(c.friction, path, &key)?,
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
        let mut keyframes = None;
        let mut mesh = match (&o.mesh, &o.sphere, &o.cuboid, &o.cylinder) {
            _ if o.mesh_sequence.is_some()
                && [
                    o.mesh.is_some(),
                    o.sphere.is_some(),
                    o.cuboid.is_some(),
                    o.cylinder.is_some(),
                ]
                .contains(&true) =>
            {
                return Err(invalid(
                    path,
                    key,
                    "give exactly one of `mesh`, `mesh_sequence`, `sphere`, `box` or `cylinder`",
                ))
            }
            _ if o.mesh_sequence.is_some() => {
                if o.motion.kind.as_deref().is_some_and(|k| k != "fixed") {
                    return Err(invalid(
                        path,
                        format!("{key}.motion"),
                        "a mesh_sequence obstacle moves with its frames; leave `motion` out",
                    ));
                }
                let seq = o.mesh_sequence.as_ref().expect("checked");
                let (m, k) = load_sequence(path, seq, &o.transform, &key, &mut notes)?;
                keyframes = Some(k);
                m
            }
            (Some(f), None, None, None) => load_mesh_file(path, f, &key, &mut notes)?.mesh,
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
                let (around, along) = (c.segments.max(3) as f64, c.rings.max(1) as f64);
                budget.admit(
                    path,
                    &format!("{key}.cylinder"),
                    &format!("segments = {}, rings = {}", c.segments, c.rings),
                    around * (along + 1.0) + 2.0,
                    2.0 * around * (along + 1.0),
                    false,
                )?;
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
                    "give exactly one of `mesh`, `mesh_sequence`, `sphere`, `box` or `cylinder`",
                ))
            }
        };
        if o.cylinder.is_none() {
            let (v, t) = (mesh.num_vertices() as f64, mesh.num_triangles() as f64);
            budget.admit(path, &key, "the obstacle", v, t, false)?;
        }
        let motion = match keyframes {
            // The frames are already transformed.
            Some(k) => Motion::Sequence(k),
            None => {
                apply_transform(&mut mesh, &o.transform, path, &key)?;
                motion(&o.motion, path, &key)?
            }
        };
        objects.push(ObjectSpec {
            friction: object_friction(o.friction, path, &key)?,
            name: o.name.clone(),
            mesh,
            kind: ObjectKind::Obstacle { motion },
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
            (Some(lo), Some(hi)) => vertices.extend(pin_box(
                &objects[object],
                v3(lo),
                v3(hi),
                p.relative,
                path,
                &key,
            )?),
            (None, None) if p.relative => {
                return Err(invalid(
                    path,
                    format!("{key}.relative"),
                    "belongs to a box: give box_min and box_max",
                ))
            }
            (None, None) => {}
            _ => return Err(invalid(path, key, "give both box_min and box_max")),
        }
        if let Some(which) = &p.boundary {
            vertices.extend(boundary_vertices(&objects[object].mesh, which, path, &key)?);
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
            predict: file.contact.predict,
            split_islands: file.contact.split_islands,
            friction: file.contact.friction,
            max_rollbacks: file.contact.max_rollbacks,
        },
        time: TimeConfig {
            internal_step,
            beta: file.time.beta,
            steps_per_window,
        },
        limits: LimitsConfig::default(),
        partitions: file.partitions,
        workers: 1,
    };
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
            checkpoint_minutes: file.output.checkpoint_minutes,
        },
        camera: file.camera.as_ref().map(|c| camera(c, path)).transpose()?,
        overrides: overrides.to_vec(),
        fingerprint: String::new(),
        warnings: notes,
    })
}
