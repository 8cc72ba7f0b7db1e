//! # weft-io — file formats
//!
//! Mesh input and output for weft:
//!
//! * [`obj`] — Wavefront OBJ reader (every face form, relative indices,
//!   polygons, objects, UVs) and a bit-exact writer;
//! * [`ply`] — PLY reader (ASCII and both binary encodings, any scalar type,
//!   optional `vx vy vz` velocities) and a binary little-endian writer;
//! * [`atomic`] — [`write_atomic`], used by every writer so an existing file
//!   is never left half-written;
//! * [`vtk`] — VTK XML unstructured grids (`.vtu`, f64 points, velocities)
//!   and their `.pvd` series index, for ParaView;
//! * [`checkpoint`] — checkpoint files (postcard + zstd, version header,
//!   checksum), written atomically;
//! * [`read_mesh`] — picks the reader from the extension and runs
//!   [`weft_core::validate`](fn@weft_core::validate), mapping an OBJ triangle
//!   back to its source line;
//! * [`names`] — messages about a file's elements in the file's own
//!   numbering (OBJ `v` numbers and face lines, PLY element indices).
//!
//! Every error is an [`IoError`] whose `Display` names the file and the line
//! (or, for binary PLY, the byte offset and element), e.g.
//! `cloth.obj:12: face has 2 vertices; at least 3 are needed`.
//! Floating-point values are written in shortest round-trip form (OBJ) or as
//! raw `f64` (PLY), so `read(write(x)) == x` bit for bit.

pub mod atomic;
pub mod checkpoint;
pub mod error;
pub mod names;
pub mod obj;
pub mod ply;
pub mod scene;
pub mod vtk;

pub use atomic::write_atomic;
pub use error::IoError;
pub use names::FileNames;
pub use obj::{encode_obj, parse_obj, read_obj, write_obj, ObjData, ObjObject};
pub use ply::{encode_ply, parse_ply, read_ply, write_ply, PlyData};

use glam::DVec3;
use std::path::Path;
use weft_core::{MeshWarning, TriMesh};

/// A validated mesh read by [`read_mesh`], with what its format carries.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshFile {
    pub mesh: TriMesh,
    /// OBJ only: the 1-based source line of each triangle.
    pub face_lines: Option<Vec<usize>>,
    /// PLY only: the face element (0-based) each triangle was cut from.
    pub face_of_triangle: Option<Vec<usize>>,
    /// OBJ only, if the file has `vt` records.
    pub uvs: Option<Vec<[f64; 2]>>,
    /// OBJ only, if every face corner has a texture index.
    pub face_uvs: Option<Vec<[u32; 3]>>,
    /// OBJ only: the `o` / `g` objects (empty for PLY).
    pub objects: Vec<ObjObject>,
    /// PLY only, if the vertices have `vx vy vz`.
    pub velocities: Option<Vec<DVec3>>,
    /// What [`weft_core::validate`](fn@weft_core::validate) found suspicious
    /// but simulable.
    pub warnings: Vec<MeshWarning>,
}

impl MeshFile {
    /// The source line of triangle `f` (OBJ), for `file:line` messages.
    pub fn line_of_triangle(&self, f: usize) -> Option<usize> {
        self.face_lines.as_ref()?.get(f).copied()
    }

    /// How messages name this file's vertices and faces.
    pub fn names(&self) -> FileNames<'_> {
        match (&self.face_lines, &self.face_of_triangle) {
            (Some(face_lines), _) => FileNames::Obj { face_lines },
            (None, Some(face_of_triangle)) => FileNames::Ply { face_of_triangle },
            (None, None) => FileNames::Ply {
                face_of_triangle: &[],
            },
        }
    }
}

/// The mesh formats [`read_mesh`] and [`write_mesh`] know, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Obj,
    Ply,
}

fn format_of(path: &Path) -> Result<Format, IoError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "obj" => Ok(Format::Obj),
        "ply" => Ok(Format::Ply),
        _ => Err(IoError::UnsupportedFormat {
            path: path.to_path_buf(),
            extension: ext,
        }),
    }
}

/// Reads a `.obj` or `.ply` file (extension case-insensitive) and validates
/// the mesh. A validation error comes back as [`IoError::Mesh`] with the OBJ
/// source line of the offending triangle where there is one, naming elements
/// as the file numbers them ([`MeshFile::names`]).
pub fn read_mesh(path: &Path) -> Result<MeshFile, IoError> {
    let file = match format_of(path)? {
        Format::Obj => {
            let d = read_obj(path)?;
            MeshFile {
                mesh: d.mesh,
                face_lines: Some(d.face_lines),
                face_of_triangle: None,
                uvs: (!d.uvs.is_empty()).then_some(d.uvs),
                face_uvs: d.face_uvs,
                objects: d.objects,
                velocities: None,
                warnings: Vec::new(),
            }
        }
        Format::Ply => {
            let d = read_ply(path)?;
            MeshFile {
                mesh: d.mesh,
                face_lines: None,
                face_of_triangle: Some(d.face_of_triangle),
                uvs: None,
                face_uvs: None,
                objects: Vec::new(),
                velocities: d.velocities,
                warnings: Vec::new(),
            }
        }
    };
    match weft_core::validate(&file.mesh) {
        Ok(warnings) => Ok(MeshFile { warnings, ..file }),
        Err(mesh) => Err(IoError::Mesh {
            path: path.to_path_buf(),
            line: mesh.triangle().and_then(|f| file.line_of_triangle(f)),
            message: mesh.describe(&file.names()),
            mesh: Box::new(mesh),
        }),
    }
}

/// Writes `.obj` or `.ply` (binary, with `velocities` if given; OBJ has no
/// place for them and refuses them) by extension, atomically.
pub fn write_mesh(
    path: &Path,
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    velocities: Option<&[DVec3]>,
) -> Result<(), IoError> {
    match format_of(path)? {
        Format::Obj if velocities.is_some() => Err(IoError::InvalidInput {
            path: path.to_path_buf(),
            message: "OBJ files cannot store velocities; write a .ply file".into(),
        }),
        Format::Obj => write_obj(path, positions, triangles),
        Format::Ply => write_ply(path, positions, triangles, velocities),
    }
}

/// Checks that the writers can represent the data in a file their readers
/// accept: finite values, indices in range (and below 2^31 for PLY's `int`),
/// one velocity per vertex.
fn check_writable(
    path: &Path,
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    velocities: Option<&[DVec3]>,
) -> Result<(), IoError> {
    let invalid = |message: String| IoError::InvalidInput {
        path: path.to_path_buf(),
        message,
    };
    let n = positions.len().min(i32::MAX as usize);
    if let Some((f, t)) = triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
    {
        return Err(invalid(format!(
            "triangle {f} (0-based) has vertices {t:?}, but there are only {} vertices",
            positions.len()
        )));
    }
    let arrays =
        std::iter::once(("position", positions)).chain(velocities.map(|v| ("velocity", v)));
    for (what, values) in arrays {
        if let Some(i) = values.iter().position(|p| !p.is_finite()) {
            return Err(invalid(format!(
                "the {what} of vertex {i} (0-based) is not finite: {:?}",
                values[i]
            )));
        }
    }
    if let Some(v) = velocities {
        if v.len() != positions.len() {
            return Err(invalid(format!(
                "{} velocities for {} vertices",
                v.len(),
                positions.len()
            )));
        }
    }
    Ok(())
}
