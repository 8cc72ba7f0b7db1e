//! Wavefront OBJ: a reader for the triangle-mesh subset that DCC tools export,
//! and a writer whose output reads back bit for bit.
//!
//! Read: `v` (extra components such as `w` or vertex colours ignored), `vt`,
//! `vn` (checked, then discarded), `f` in every corner form (`a`, `a/b`,
//! `a//c`, `a/b/c`) with positive or negative (relative) indices, polygons
//! triangulated by ear clipping in their plane ([`weft_geom::polygon`]; one the
//! clipping cannot triangulate, such as a self-intersecting one, is refused),
//! `o` / `g` as object boundaries. A UTF-8 byte-order mark is skipped. Everything else (`s`,
//! `usemtl`, `mtllib`, `l`, curves, unknown records) is ignored: none of it
//! affects a simulated cloth. `#` starts a comment anywhere on a line.
//!
//! Errors name the file and the 1-based line, like a compiler:
//! `cloth.obj:12: face has 2 vertices; at least 3 are needed`.

use crate::atomic::write_atomic;
use crate::error::IoError;
use glam::DVec3;
use std::fmt::Write as _;
use std::path::Path;
use weft_core::TriMesh;

/// A run of consecutive triangles introduced by an `o` or `g` record.
///
/// Objects partition the triangles in file order. Triangles before the first
/// record form an object named `""`. A record directly followed by another
/// (no faces in between) is merged into it, taking the later name unless that
/// one is empty, so a file with `o cloth` then `g cloth_mat` yields one object.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ObjObject {
    pub name: String,
    pub first_triangle: usize,
    pub triangle_count: usize,
}

/// The contents of an OBJ file.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjData {
    /// Positions in file order, triangles after triangulating the polygons.
    pub mesh: TriMesh,
    /// Objects in file order; they partition `mesh.triangles`.
    pub objects: Vec<ObjObject>,
    /// All `vt` records (u, v) in file order.
    pub uvs: Vec<[f64; 2]>,
    /// Per triangle, indices into `uvs`; present only if every face corner
    /// has a texture index.
    pub face_uvs: Option<Vec<[u32; 3]>>,
    /// `face_lines[f]`: the 1-based source line of triangle `f`, so callers
    /// can report `file.obj:123`.
    pub face_lines: Vec<usize>,
}

/// Reads and parses an OBJ file. Bytes that are not UTF-8 (e.g. Latin-1 in
/// comments) are replaced, not rejected.
pub fn read_obj(path: &Path) -> Result<ObjData, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    parse_obj(&String::from_utf8_lossy(&bytes), path)
}

/// Parses OBJ text; `path_for_errors` only labels error messages.
pub fn parse_obj(text: &str, path_for_errors: &Path) -> Result<ObjData, IoError> {
    // Editors on Windows start UTF-8 files with a byte-order mark; left in, it
    // would hide the first record's keyword.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut p = Parser::default();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("");
        p.record(content, line).map_err(|message| IoError::Parse {
            path: path_for_errors.to_path_buf(),
            line: Some(line),
            message,
        })?;
    }
    Ok(p.finish())
}

#[derive(Default)]
struct Parser {
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    face_lines: Vec<usize>,
    uvs: Vec<[f64; 2]>,
    face_uvs: Vec<[u32; 3]>,
    /// Cleared by the first face corner without a texture index.
    all_faces_have_uvs: bool,
    seen_face: bool,
    num_normals: usize,
    objects: Vec<ObjObject>,
    /// The current face's corners (vertex, texture), kept between faces so
    /// that reading a face allocates nothing.
    corners: Vec<(u32, Option<u32>)>,
}

impl Parser {
    fn record(&mut self, content: &str, line: usize) -> Result<(), String> {
        let mut tokens = content.split_whitespace();
        let Some(keyword) = tokens.next() else {
            return Ok(());
        };
        match keyword {
            "v" => {
                let [x, y, z] = numbers(&mut tokens, "v", ["x", "y", "z"])?;
                for (axis, value) in ["x", "y", "z"].iter().zip([x, y, z]) {
                    if !value.is_finite() {
                        return Err(format!(
                            "vertex {} (1-based OBJ index) has a non-finite {axis} coordinate ({value})",
                            self.positions.len() + 1
                        ));
                    }
                }
                self.positions.push(DVec3::new(x, y, z));
            }
            "vt" => {
                let [u] = numbers(&mut tokens, "vt", ["u"])?;
                let v = match tokens.next() {
                    Some(t) => number(t, "vt", "v")?,
                    None => 0.0,
                };
                self.uvs.push([u, v]);
            }
            "vn" => {
                numbers(&mut tokens, "vn", ["x", "y", "z"])?;
                self.num_normals += 1;
            }
            "f" => self.face(tokens, line)?,
            "o" | "g" => self.start_object(tokens.collect::<Vec<_>>().join(" ")),
            _ => {}
        }
        Ok(())
    }

    fn face<'a>(
        &mut self,
        tokens: impl Iterator<Item = &'a str>,
        line: usize,
    ) -> Result<(), String> {
        let mut corners = std::mem::take(&mut self.corners);
        corners.clear();
        for tok in tokens {
            corners.push(self.corner(tok)?);
        }
        if corners.len() < 3 {
            return Err(format!(
                "face has {} vertices; at least 3 are needed",
                corners.len()
            ));
        }
        if !self.seen_face {
            self.seen_face = true;
            self.all_faces_have_uvs = true;
        }
        let has_uvs = corners.iter().all(|c| c.1.is_some());
        self.all_faces_have_uvs &= has_uvs;
        if corners.len() == 3 {
            // Most faces: no polygon to triangulate, nothing to allocate.
            self.push_triangle(&corners, [0, 1, 2], has_uvs, line);
        } else {
            let positions: Vec<DVec3> = corners
                .iter()
                .map(|c| self.positions[c.0 as usize])
                .collect();
            let triangles = weft_geom::polygon::triangulate(&positions).map_err(|e| {
                format!(
                    "the face with {} corners cannot be triangulated: {}",
                    corners.len(),
                    e.describe(&|k| format!("v {}", corners[k].0 + 1))
                )
            })?;
            for t in triangles {
                self.push_triangle(&corners, t, has_uvs, line);
            }
        }
        self.corners = corners;
        Ok(())
    }

    /// Adds the triangle of face corners `[a, b, c]` read on `line`, with its
    /// texture indices when the face has them.
    fn push_triangle(
        &mut self,
        corners: &[(u32, Option<u32>)],
        [a, b, c]: [usize; 3],
        has_uvs: bool,
        line: usize,
    ) {
        self.triangles
            .push([corners[a].0, corners[b].0, corners[c].0]);
        self.face_lines.push(line);
        if has_uvs {
            let uv = |k: usize| corners[k].1.expect("every corner has a texture index");
            self.face_uvs.push([uv(a), uv(b), uv(c)]);
        }
    }

    /// Parses one face corner `v`, `v/t`, `v//n` or `v/t/n` into 0-based
    /// (vertex, texture) indices.
    fn corner(&self, tok: &str) -> Result<(u32, Option<u32>), String> {
        let mut parts = tok.split('/');
        let v = parts.next().unwrap_or("");
        let t = parts.next().filter(|s| !s.is_empty());
        let n = parts.next().filter(|s| !s.is_empty());
        if parts.next().is_some() {
            return Err(format!(
                "face corner \"{tok}\" has more than three '/'-separated parts"
            ));
        }
        if v.is_empty() {
            return Err(format!("face corner \"{tok}\" has no vertex index"));
        }
        let v = resolve(v, self.positions.len(), ("vertex", "vertices"), tok)?;
        let t = t
            .map(|t| {
                resolve(
                    t,
                    self.uvs.len(),
                    ("texture coordinate", "texture coordinates"),
                    tok,
                )
            })
            .transpose()?;
        if let Some(n) = n {
            resolve(n, self.num_normals, ("normal", "normals"), tok)?;
        }
        Ok((v, t))
    }

    fn start_object(&mut self, name: String) {
        let tri = self.triangles.len();
        if let Some(last) = self.objects.last_mut() {
            last.triangle_count = tri - last.first_triangle;
        } else if tri > 0 {
            self.objects.push(ObjObject {
                name: String::new(),
                first_triangle: 0,
                triangle_count: tri,
            });
        }
        match self.objects.last_mut() {
            Some(last) if last.triangle_count == 0 => {
                if !name.is_empty() {
                    last.name = name;
                }
            }
            _ => self.objects.push(ObjObject {
                name,
                first_triangle: tri,
                triangle_count: 0,
            }),
        }
    }

    fn finish(mut self) -> ObjData {
        self.start_object(String::new());
        self.objects.retain(|o| o.triangle_count > 0);
        let has_uvs = self.all_faces_have_uvs && !self.triangles.is_empty();
        ObjData {
            mesh: TriMesh::new(self.positions, self.triangles),
            objects: self.objects,
            uvs: self.uvs,
            face_uvs: has_uvs.then_some(self.face_uvs),
            face_lines: self.face_lines,
        }
    }
}

fn number(tok: &str, record: &str, what: &str) -> Result<f64, String> {
    tok.parse::<f64>()
        .map_err(|_| format!("invalid number \"{tok}\" for {what} in `{record}` record"))
}

/// Parses the first `N` numbers of a record; extra tokens are ignored.
fn numbers<'a, const N: usize>(
    tokens: &mut impl Iterator<Item = &'a str>,
    record: &str,
    names: [&str; N],
) -> Result<[f64; N], String> {
    let mut out = [0.0; N];
    for (k, name) in names.iter().enumerate() {
        let tok = tokens.next().ok_or_else(|| {
            format!(
                "`{record}` record has {k} values; expected at least {N} ({})",
                names.join(" ")
            )
        })?;
        out[k] = number(tok, record, name)?;
    }
    Ok(out)
}

/// Resolves a 1-based or negative (relative to the `count` elements defined so
/// far) OBJ index to a 0-based one.
fn resolve(s: &str, count: usize, (kind, kinds): (&str, &str), tok: &str) -> Result<u32, String> {
    let i: i64 = s
        .parse()
        .map_err(|_| format!("invalid {kind} index \"{s}\" in face corner \"{tok}\""))?;
    let resolved = match i {
        0 => {
            return Err(format!(
                "{kind} index 0 in face corner \"{tok}\" is invalid (OBJ indices start at 1; \
                 negative ones count back from the last definition)"
            ))
        }
        i if i > 0 => i - 1,
        i => count as i64 + i,
    };
    if resolved < 0 || resolved >= count as i64 {
        return Err(format!(
            "{kind} index {i} in face corner \"{tok}\" is out of range: \
             {count} {kinds} are defined before this line"
        ));
    }
    u32::try_from(resolved).map_err(|_| format!("{kind} index {i} does not fit in 32 bits"))
}

/// The OBJ text [`write_obj`] writes: a comment, `v` records with shortest
/// round-trip decimals (so reading them back gives the same bits), then
/// 1-based `f a b c` records.
pub fn encode_obj(positions: &[DVec3], triangles: &[[u32; 3]]) -> String {
    let mut s = String::with_capacity(40 * positions.len() + 24 * triangles.len() + 64);
    let _ = writeln!(
        s,
        "# weft: {} vertices, {} triangles",
        positions.len(),
        triangles.len()
    );
    for p in positions {
        // `{:?}` is the shortest representation that round-trips (and keeps
        // -0.0 and exponents); `{}` never uses exponents, so 1e-300 would be
        // 300 digits long.
        let _ = writeln!(s, "v {:?} {:?} {:?}", p.x, p.y, p.z);
    }
    for t in triangles {
        let [a, b, c] = t.map(|i| u64::from(i) + 1);
        let _ = writeln!(s, "f {a} {b} {c}");
    }
    s
}

/// Writes an OBJ file atomically (see [`write_atomic`]). Fails without touching
/// `path` if a coordinate is not finite or an index is out of range, since the
/// reader would reject the file.
pub fn write_obj(path: &Path, positions: &[DVec3], triangles: &[[u32; 3]]) -> Result<(), IoError> {
    crate::check_writable(path, positions, triangles, None)?;
    write_atomic(path, encode_obj(positions, triangles).as_bytes())
}
