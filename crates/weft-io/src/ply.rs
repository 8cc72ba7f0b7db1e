//! Stanford PLY: a reader for triangle/polygon meshes in all three encodings
//! (`ascii`, `binary_little_endian`, `binary_big_endian`) and a binary
//! little-endian writer.
//!
//! Read: the `vertex` element's `x y z` (any scalar type; required) and
//! `vx vy vz` (optional, all three or none); the `face` element's
//! `vertex_indices` (or `vertex_index`) list with any integer count and index
//! types, polygons triangulated by ear clipping in their plane
//! ([`weft_geom::polygon`]; one it cannot triangulate is refused). Other properties and elements are skipped
//! (a binary reader still has to walk them to know their sizes).
//!
//! Errors name the file and the header line, the ASCII body line, or the byte
//! offset of a binary body, plus the element and property being read.

use crate::atomic::write_atomic;
use crate::error::IoError;
use glam::DVec3;
use std::path::Path;
use weft_core::TriMesh;

/// The contents of a PLY file.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyData {
    pub mesh: TriMesh,
    /// Per-vertex velocities from `vx vy vz`, if the file has them.
    pub velocities: Option<Vec<DVec3>>,
    /// `face_of_triangle[t]`: the face element (0-based) triangle `t` was cut
    /// from, so messages name what the file holds.
    pub face_of_triangle: Vec<usize>,
}

/// Reads and parses a PLY file.
pub fn read_ply(path: &Path) -> Result<PlyData, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    parse_ply(&bytes, path)
}

/// Parses PLY bytes; `path_for_errors` only labels error messages.
pub fn parse_ply(bytes: &[u8], path_for_errors: &Path) -> Result<PlyData, IoError> {
    let err = |line: Option<usize>, message: String| IoError::Parse {
        path: path_for_errors.to_path_buf(),
        line,
        message,
    };
    let header = parse_header(bytes).map_err(|(line, m)| err(Some(line), m))?;
    let mut body = match header.format {
        Format::Ascii => Body::Ascii {
            bytes,
            pos: header.body_offset,
            line: header.body_line,
            token_line: header.body_line,
        },
        Format::BinaryLe | Format::BinaryBe => Body::Binary {
            bytes,
            pos: header.body_offset,
            big_endian: header.format == Format::BinaryBe,
        },
    };
    read_body(&header, &mut body).map_err(|(line, m)| err(line, m))
}

/// Scalar property types, with their PLY names and byte sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }

    /// Inclusive range of an integer type (all fit exactly in `f64`).
    fn int_range(self) -> (i64, i64) {
        match self {
            Self::I8 => (i8::MIN.into(), i8::MAX.into()),
            Self::U8 => (0, u8::MAX.into()),
            Self::I16 => (i16::MIN.into(), i16::MAX.into()),
            Self::U16 => (0, u16::MAX.into()),
            Self::I32 => (i32::MIN.into(), i32::MAX.into()),
            Self::U32 => (0, u32::MAX.into()),
            Self::F32 | Self::F64 => (i64::MIN, i64::MAX),
        }
    }
}

#[derive(Clone, Debug)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Self::Scalar { name, .. } | Self::List { name, .. } => name,
        }
    }
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
    /// 1-based header line of the `element` record.
    line: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    body_offset: usize,
    /// 1-based line on which an ASCII body starts.
    body_line: usize,
}

/// A header error: 1-based line and message.
type HeaderError = (usize, String);

fn parse_header(bytes: &[u8]) -> Result<Header, HeaderError> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        line_no += 1;
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(if line_no == 1 && !bytes.starts_with(b"ply") {
                (1, "not a PLY file: it does not start with \"ply\"".into())
            } else {
                (
                    line_no,
                    "the header ends without an \"end_header\" line (truncated file?)".into(),
                )
            });
        };
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        let text = std::str::from_utf8(raw)
            .map_err(|_| (line_no, "header line is not ASCII text".to_string()))?
            .trim();
        if line_no == 1 {
            if text != "ply" {
                return Err((1, "not a PLY file: it does not start with \"ply\"".into()));
            }
            continue;
        }
        let tokens: Vec<&str> = text.split_whitespace().collect();
        match tokens.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["end_header"] => break,
            ["format", f, _version] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLe,
                    "binary_big_endian" => Format::BinaryBe,
                    other => {
                        return Err((line_no, format!(
                            "unknown PLY format \"{other}\" (expected ascii, binary_little_endian or binary_big_endian)"
                        )))
                    }
                });
            }
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| {
                    (
                        line_no,
                        format!("invalid count \"{count}\" for element \"{name}\""),
                    )
                })?;
                if elements.iter().any(|e| e.name == *name) {
                    return Err((line_no, format!("element \"{name}\" is declared twice")));
                }
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                    line: line_no,
                });
            }
            ["property", rest @ ..] => {
                let property = parse_property(rest).map_err(|m| (line_no, m))?;
                let element = elements
                    .last_mut()
                    .ok_or_else(|| (line_no, "property declared before any element".to_string()))?;
                element.properties.push(property);
            }
            _ => return Err((line_no, format!("unrecognised header line \"{text}\""))),
        }
    }
    let format = format.ok_or((line_no, "the header has no \"format\" line".to_string()))?;
    Ok(Header {
        format,
        elements,
        body_offset: pos,
        body_line: line_no + 1,
    })
}

fn parse_property(tokens: &[&str]) -> Result<Property, String> {
    let ty = |t: &str| Scalar::parse(t).ok_or_else(|| format!("unknown property type \"{t}\""));
    match tokens {
        ["list", count, item, name] => {
            let count = ty(count)?;
            if !count.is_integer() {
                return Err(format!("list \"{name}\" has a non-integer count type"));
            }
            Ok(Property::List {
                name: name.to_string(),
                count,
                item: ty(item)?,
            })
        }
        [t, name] => Ok(Property::Scalar {
            name: name.to_string(),
            ty: ty(t)?,
        }),
        _ => Err(format!(
            "malformed property line \"property {}\"",
            tokens.join(" ")
        )),
    }
}

/// A body error: the line for ASCII bodies (None for binary) and a message.
type BodyError = (Option<usize>, String);

enum Body<'a> {
    Ascii {
        bytes: &'a [u8],
        pos: usize,
        /// Line of the read position.
        line: usize,
        /// Line of the last token read: errors point there, not past a
        /// trailing newline.
        token_line: usize,
    },
    Binary {
        bytes: &'a [u8],
        pos: usize,
        big_endian: bool,
    },
}

impl Body<'_> {
    /// Reads one value of type `ty`; `what` describes it for error messages
    /// (e.g. `property "y" of vertex 17`).
    fn read(&mut self, ty: Scalar, what: &dyn Fn() -> String) -> Result<f64, BodyError> {
        match self {
            Body::Binary {
                bytes,
                pos,
                big_endian,
            } => {
                let size = ty.size();
                let Some(raw) = bytes.get(*pos..*pos + size) else {
                    return Err((None, format!(
                        "unexpected end of file at byte {pos} reading {} (the file has {} bytes; truncated?)",
                        what(),
                        bytes.len()
                    )));
                };
                *pos += size;
                Ok(decode(ty, raw, *big_endian))
            }
            Body::Ascii {
                bytes,
                pos,
                line,
                token_line,
            } => {
                while *pos < bytes.len() && bytes[*pos].is_ascii_whitespace() {
                    if bytes[*pos] == b'\n' {
                        *line += 1;
                    }
                    *pos += 1;
                }
                let start = *pos;
                while *pos < bytes.len() && !bytes[*pos].is_ascii_whitespace() {
                    *pos += 1;
                }
                if start == *pos {
                    return Err((
                        Some(*token_line),
                        format!("unexpected end of file reading {} (truncated?)", what()),
                    ));
                }
                *token_line = *line;
                let line = Some(*line);
                let tok = String::from_utf8_lossy(&bytes[start..*pos]);
                if ty.is_integer() {
                    let (lo, hi) = ty.int_range();
                    match tok.parse::<i64>() {
                        Ok(v) if (lo..=hi).contains(&v) => Ok(v as f64),
                        Ok(v) => Err((
                            line,
                            format!(
                                "value {v} of {} is out of range for its type {}",
                                what(),
                                ty.name()
                            ),
                        )),
                        Err(_) => Err((line, format!("invalid integer \"{tok}\" for {}", what()))),
                    }
                } else {
                    tok.parse::<f64>()
                        .map_err(|_| (line, format!("invalid number \"{tok}\" for {}", what())))
                }
            }
        }
    }

    fn line(&self) -> Option<usize> {
        match self {
            Body::Ascii { token_line, .. } => Some(*token_line),
            Body::Binary { .. } => None,
        }
    }
}

fn decode(ty: Scalar, raw: &[u8], big_endian: bool) -> f64 {
    macro_rules! num {
        ($t:ty) => {{
            let a = raw.try_into().unwrap_or_default();
            (if big_endian {
                <$t>::from_be_bytes(a)
            } else {
                <$t>::from_le_bytes(a)
            }) as f64
        }};
    }
    match ty {
        Scalar::I8 => num!(i8),
        Scalar::U8 => num!(u8),
        Scalar::I16 => num!(i16),
        Scalar::U16 => num!(u16),
        Scalar::I32 => num!(i32),
        Scalar::U32 => num!(u32),
        Scalar::F32 => num!(f32),
        Scalar::F64 => num!(f64),
    }
}

/// Where the interesting properties of the vertex element are.
struct VertexLayout {
    xyz: [usize; 3],
    velocity: Option<[usize; 3]>,
}

fn vertex_layout(el: &Element) -> Result<VertexLayout, BodyError> {
    let find = |name: &str| -> Result<Option<usize>, BodyError> {
        match el.properties.iter().position(|p| p.name() == name) {
            Some(i) if matches!(el.properties[i], Property::List { .. }) => Err((
                Some(el.line),
                format!("vertex property \"{name}\" is a list; expected a scalar"),
            )),
            found => Ok(found),
        }
    };
    let mut xyz = [0; 3];
    for (k, name) in ["x", "y", "z"].iter().enumerate() {
        xyz[k] = find(name)?.ok_or_else(|| {
            (
                Some(el.line),
                format!("the vertex element has no \"{name}\" property"),
            )
        })?;
    }
    let v = [find("vx")?, find("vy")?, find("vz")?];
    let velocity = match v {
        [Some(a), Some(b), Some(c)] => Some([a, b, c]),
        [None, None, None] => None,
        _ => {
            return Err((
                Some(el.line),
                "the vertex element has some but not all of \"vx\", \"vy\", \"vz\"".into(),
            ))
        }
    };
    Ok(VertexLayout { xyz, velocity })
}

fn face_list(el: &Element) -> Result<usize, BodyError> {
    let i = el
        .properties
        .iter()
        .position(|p| matches!(p.name(), "vertex_indices" | "vertex_index"))
        .ok_or_else(|| {
            (
                Some(el.line),
                "the face element has no \"vertex_indices\" list".to_string(),
            )
        })?;
    match el.properties[i] {
        Property::List { item, .. } if item.is_integer() => Ok(i),
        _ => Err((
            Some(el.line),
            format!(
                "face property \"{}\" must be a list of integers",
                el.properties[i].name()
            ),
        )),
    }
}

fn read_body(header: &Header, body: &mut Body) -> Result<PlyData, BodyError> {
    let mut positions = Vec::new();
    let mut velocities: Option<Vec<DVec3>> = None;
    // The faces' corners, triangulated once every vertex is known (a face
    // element may come before the vertex element).
    let mut faces = Faces::default();
    let mut has_vertex = false;
    let mut values: Vec<f64> = Vec::new();
    let mut list: Vec<f64> = Vec::new();
    for el in &header.elements {
        let vertex = (el.name == "vertex")
            .then(|| vertex_layout(el))
            .transpose()?;
        let face = (el.name == "face").then(|| face_list(el)).transpose()?;
        has_vertex |= vertex.is_some();
        // Capacity from the header is capped by the file size: a corrupt count
        // must not allocate gigabytes before the truncation is noticed.
        let cap = el.count.min(body_len(body));
        if vertex.as_ref().is_some_and(|v| v.velocity.is_some()) {
            velocities = Some(Vec::with_capacity(cap));
        }
        if vertex.is_some() {
            positions.reserve(cap);
        }
        if el.properties.is_empty() {
            // Nothing to read, however large the count.
            continue;
        }
        for i in 0..el.count {
            values.clear();
            for (pi, prop) in el.properties.iter().enumerate() {
                let what = || format!("property \"{}\" of {} {i} (0-based)", prop.name(), el.name);
                match *prop {
                    Property::Scalar { ty, .. } => values.push(body.read(ty, &what)?),
                    Property::List { count, item, .. } => {
                        let n = body.read(count, &|| format!("the length of {}", what()))?;
                        // The list's line (ASCII), for errors about the whole list.
                        let line = body.line();
                        if n < 0.0 {
                            return Err((line, format!("negative list length {n} for {}", what())));
                        }
                        let keep = face == Some(pi);
                        list.clear();
                        for k in 0..n as usize {
                            let v = body.read(item, &|| format!("item {k} of {}", what()))?;
                            if keep {
                                list.push(v);
                            }
                        }
                        if keep {
                            faces.add(&list, i, line)?;
                        }
                        values.push(n);
                    }
                }
            }
            if let Some(layout) = &vertex {
                let p = |ix: [usize; 3]| DVec3::new(values[ix[0]], values[ix[1]], values[ix[2]]);
                positions.push(p(layout.xyz));
                if let (Some(ix), Some(vel)) = (layout.velocity, velocities.as_mut()) {
                    vel.push(p(ix));
                }
            }
        }
    }
    if !has_vertex {
        return Err((None, "the header declares no \"vertex\" element".into()));
    }
    let (triangles, face_of_triangle) = faces.triangulate(&positions)?;
    Ok(PlyData {
        mesh: TriMesh::new(positions, triangles),
        velocities,
        face_of_triangle,
    })
}

fn body_len(body: &Body) -> usize {
    match body {
        Body::Ascii { bytes, .. } | Body::Binary { bytes, .. } => bytes.len(),
    }
}

/// The face element's polygons, in file order.
#[derive(Default)]
struct Faces {
    corners: Vec<u32>,
    /// Per face: its index in the element, its line (ASCII) and where its
    /// corners start in `corners`.
    faces: Vec<(usize, Option<usize>, usize)>,
}

impl Faces {
    fn add(&mut self, list: &[f64], face: usize, line: Option<usize>) -> Result<(), BodyError> {
        if list.len() < 3 {
            return Err((
                line,
                format!(
                    "face {face} (0-based) has {} vertices; at least 3 are needed",
                    list.len()
                ),
            ));
        }
        self.faces.push((face, line, self.corners.len()));
        for &v in list {
            if v < 0.0 || v > u32::MAX as f64 {
                return Err((
                    line,
                    format!("face {face} (0-based) has an invalid vertex index {v}"),
                ));
            }
            self.corners.push(v as u32);
        }
        Ok(())
    }

    /// Triangles of every face, in face order, and the face of each, after
    /// checking the indices against the `positions` read.
    fn triangulate(&self, positions: &[DVec3]) -> Result<(Vec<[u32; 3]>, Vec<usize>), BodyError> {
        let n = positions.len();
        let count = self.corners.len().saturating_sub(2 * self.faces.len());
        let mut triangles = Vec::with_capacity(count);
        let mut face_of_triangle = Vec::with_capacity(count);
        for (k, &(face, line, start)) in self.faces.iter().enumerate() {
            let end = self.faces.get(k + 1).map_or(self.corners.len(), |f| f.2);
            let ids = &self.corners[start..end];
            if let Some(&v) = ids.iter().find(|&&v| v as usize >= n) {
                return Err((
                    line,
                    format!(
                        "face {face} (0-based) refers to vertex {v}, but the file has only {n} vertices"
                    ),
                ));
            }
            if let &[a, b, c] = ids {
                // Most faces: no polygon to triangulate.
                triangles.push([a, b, c]);
                face_of_triangle.push(face);
                continue;
            }
            let corners: Vec<DVec3> = ids.iter().map(|&v| positions[v as usize]).collect();
            let local = weft_geom::polygon::triangulate(&corners).map_err(|e| {
                (
                    line,
                    format!(
                        "face {face} (0-based) with {} corners cannot be triangulated: {}",
                        ids.len(),
                        e.describe(&|k| format!("vertex {}", ids[k]))
                    ),
                )
            })?;
            face_of_triangle.extend(std::iter::repeat_n(face, local.len()));
            triangles.extend(local.into_iter().map(|t| t.map(|c| ids[c])));
        }
        Ok((triangles, face_of_triangle))
    }
}

/// The bytes [`write_ply`] writes: binary little-endian, `double x y z`
/// (`double vx vy vz` with velocities), `list uchar int vertex_indices`.
///
/// # Panics
/// If `velocities` is given with a length other than `positions.len()`
/// (a caller bug; [`write_ply`] checks it and returns an error instead).
pub fn encode_ply(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    velocities: Option<&[DVec3]>,
) -> Vec<u8> {
    if let Some(v) = velocities {
        assert_eq!(v.len(), positions.len(), "one velocity per vertex");
    }
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by weft\nelement vertex {}\n\
         property double x\nproperty double y\nproperty double z\n",
        positions.len()
    );
    if velocities.is_some() {
        header.push_str("property double vx\nproperty double vy\nproperty double vz\n");
    }
    header.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        triangles.len()
    ));
    let per_vertex = if velocities.is_some() { 48 } else { 24 };
    let mut out =
        Vec::with_capacity(header.len() + per_vertex * positions.len() + 13 * triangles.len());
    out.extend_from_slice(header.as_bytes());
    for (i, p) in positions.iter().enumerate() {
        for c in p.to_array() {
            out.extend_from_slice(&c.to_le_bytes());
        }
        if let Some(v) = velocities {
            for c in v[i].to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    for t in triangles {
        out.push(3);
        for &i in t {
            // `int` is what every PLY tool reads; indices < 2^31 are checked
            // by write_ply.
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    out
}

/// Writes a binary little-endian PLY file atomically (see [`write_atomic`]).
/// Fails without touching `path` on a non-finite value, an index out of range
/// or a velocity count that differs from the vertex count.
pub fn write_ply(
    path: &Path,
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    velocities: Option<&[DVec3]>,
) -> Result<(), IoError> {
    crate::check_writable(path, positions, triangles, velocities)?;
    write_atomic(path, &encode_ply(positions, triangles, velocities))
}
