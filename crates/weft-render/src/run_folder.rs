//! Reading a run folder written by `weft run`: `frames.jsonl`, the frame
//! files it lists, and `objects.json` (which triangles belong to which
//! object). The folder of a run still in progress reads too.

use crate::error::RenderError;
use crate::raster::Surface;
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// One line of `frames.jsonl`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct FrameEntry {
    /// Frame index (0-based).
    pub frame: u64,
    /// The frame file, relative to the run folder.
    pub file: String,
    /// Simulated time of the frame (s).
    pub time: f64,
    /// The window whose end the frame shows.
    #[serde(default)]
    pub window: u64,
}

/// One object of `objects.json`: half-open vertex and triangle ranges into
/// the concatenated frame mesh.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct ObjectRange {
    pub name: String,
    pub vertices: [usize; 2],
    pub triangles: [usize; 2],
    /// `true` for simulated cloth, `false` for obstacles.
    pub cloth: bool,
}

#[derive(Deserialize)]
struct ObjectsFile {
    objects: Vec<ObjectRange>,
}

/// One frame's geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// A run folder: its frame list and, where the run wrote `objects.json`, its
/// objects.
#[derive(Clone, Debug, PartialEq)]
pub struct RunFolder {
    pub dir: PathBuf,
    /// The lines of `frames.jsonl`, in file order.
    pub frames: Vec<FrameEntry>,
    /// `None` when `objects.json` is absent (older runs): every triangle is
    /// then drawn as cloth.
    pub objects: Option<Vec<ObjectRange>>,
    /// The (1-based) number of the last line of `frames.jsonl` when it was
    /// skipped as incomplete: no newline at its end and not a whole record,
    /// as while a run is still writing it.
    pub incomplete_last_line: Option<usize>,
}

impl RunFolder {
    /// Reads `dir/frames.jsonl` and `dir/objects.json` (if present). Errors
    /// name the file and, for a malformed line, the line; an incomplete last
    /// line (a run still writing it) is skipped and noted in
    /// [`RunFolder::incomplete_last_line`].
    pub fn open(dir: &Path) -> Result<RunFolder, RenderError> {
        if !dir.is_dir() {
            return Err(RenderError::format(
                dir,
                None,
                "no such folder (expected a run folder written by `weft run`)".into(),
            ));
        }
        let frames_path = dir.join("frames.jsonl");
        let text = std::fs::read_to_string(&frames_path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                RenderError::format(
                    &frames_path,
                    None,
                    "missing (is this a run folder written by `weft run`?)".into(),
                )
            } else {
                RenderError::io(&frames_path, e)
            }
        })?;
        let lines = crate::json_lines::parse::<FrameEntry>(&frames_path, &text, "frame record")?;
        let incomplete_last_line = lines.incomplete_last_line;
        let mut frames = Vec::with_capacity(lines.records.len());
        for (line, entry) in lines.records {
            if entry.file.is_empty() || !entry.time.is_finite() {
                return Err(RenderError::format(
                    &frames_path,
                    Some(line),
                    "frame record needs a file name and a finite time".into(),
                ));
            }
            frames.push(entry);
        }
        if frames.is_empty() {
            return Err(RenderError::format(
                &frames_path,
                None,
                "no frames listed".into(),
            ));
        }
        let objects_path = dir.join("objects.json");
        let objects = match std::fs::read_to_string(&objects_path) {
            Ok(text) => {
                let file: ObjectsFile = serde_json::from_str(&text).map_err(|e| {
                    RenderError::format(&objects_path, Some(e.line()), e.to_string())
                })?;
                for o in &file.objects {
                    if o.vertices[0] > o.vertices[1] || o.triangles[0] > o.triangles[1] {
                        return Err(RenderError::format(
                            &objects_path,
                            None,
                            format!("object {:?} has a decreasing range", o.name),
                        ));
                    }
                }
                Some(file.objects)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => return Err(RenderError::io(&objects_path, e)),
        };
        Ok(RunFolder {
            dir: dir.to_path_buf(),
            frames,
            objects,
            incomplete_last_line,
        })
    }

    /// The path of a frame file.
    pub fn frame_path(&self, entry: &FrameEntry) -> PathBuf {
        self.dir.join(&entry.file)
    }

    /// Reads a frame (PLY or OBJ by extension) and checks its indices.
    pub fn read_frame(&self, entry: &FrameEntry) -> Result<FrameMesh, RenderError> {
        let path = self.frame_path(entry);
        let frame_err = |error| RenderError::Frame {
            frame: entry.frame,
            error,
        };
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        // The plain readers skip mesh validation: a preview should show a
        // frame with a degenerate triangle rather than refuse it.
        let mesh = match ext.as_str() {
            "ply" => weft_io::read_ply(&path).map_err(frame_err)?.mesh,
            "obj" => weft_io::read_obj(&path).map_err(frame_err)?.mesh,
            _ => weft_io::read_mesh(&path).map_err(frame_err)?.mesh,
        };
        let n = mesh.positions.len();
        if let Some(f) = mesh
            .triangles
            .iter()
            .position(|t| t.iter().any(|&v| v as usize >= n))
        {
            return Err(RenderError::format(
                path,
                None,
                format!("triangle {f} refers to a vertex beyond the {n} vertices"),
            ));
        }
        Ok(FrameMesh {
            positions: mesh.positions,
            triangles: mesh.triangles,
        })
    }

    /// The surface of each of `num_triangles` triangles: from `objects.json`
    /// (the k-th cloth object is `Surface::Cloth(k)`), or all the first cloth
    /// without it. Triangles no object claims are the first cloth.
    pub fn surfaces(&self, num_triangles: usize) -> Result<Vec<Surface>, RenderError> {
        let mut s = vec![Surface::Cloth(0); num_triangles];
        let mut cloths = 0;
        for o in self.objects.iter().flatten() {
            let [a, b] = o.triangles;
            if b > num_triangles {
                return Err(RenderError::format(
                    self.dir.join("objects.json"),
                    None,
                    format!(
                        "object {:?} has triangles [{a}, {b}), but the frames have {num_triangles}",
                        o.name
                    ),
                ));
            }
            if o.cloth {
                s[a..b].fill(Surface::Cloth(cloths));
                cloths += 1;
            } else {
                s[a..b].fill(Surface::Obstacle);
            }
        }
        Ok(s)
    }

    /// The frame rate the frame times imply: frames over the time they span;
    /// `None` with fewer than two frames or no time between them.
    pub fn implied_frame_rate(&self) -> Option<f64> {
        let (first, last) = (self.frames.first()?, self.frames.last()?);
        let span = last.time - first.time;
        let rate = (self.frames.len() - 1) as f64 / span;
        (span > 0.0 && rate.is_finite()).then_some(rate)
    }
}
