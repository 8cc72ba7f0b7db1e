//! Naming a mesh file's elements the way the file numbers them, for
//! validation messages ([`weft_core::ElementNames`]): an OBJ file's vertices by
//! their 1-based `v` numbers and its faces by source line, a PLY file's by
//! their 0-based element indices (the PLY convention), a triangle by the face
//! it was cut from. Each message says once which numbering it uses.

use weft_core::names::join;
use weft_core::ElementNames;

/// How a mesh file numbers its elements.
#[derive(Clone, Copy, Debug)]
pub enum FileNames<'a> {
    /// `face_lines[t]`: the source line of triangle `t`.
    Obj { face_lines: &'a [usize] },
    /// `face_of_triangle[t]`: the face element triangle `t` was cut from.
    Ply { face_of_triangle: &'a [usize] },
}

impl ElementNames for FileNames<'_> {
    fn vertex(&self, v: u32) -> String {
        match self {
            Self::Obj { .. } => format!("v {}", u64::from(v) + 1),
            Self::Ply { .. } => format!("vertex {v} (0-based)"),
        }
    }

    fn vertices(&self, vs: &[u32]) -> String {
        match self {
            Self::Obj { .. } => vs
                .iter()
                .map(|&v| self.vertex(v))
                .collect::<Vec<_>>()
                .join(", "),
            Self::Ply { .. } => format!("vertices {}; 0-based", join(vs)),
        }
    }

    fn triangle(&self, f: usize) -> String {
        match self {
            Self::Obj { face_lines } => match face_lines.get(f) {
                Some(line) => format!("the face on line {line}"),
                None => format!("triangle {f} (0-based)"),
            },
            Self::Ply { face_of_triangle } => match face_of_triangle.get(f) {
                Some(face) => format!("face {face}"),
                None => format!("triangle {f} (0-based)"),
            },
        }
    }

    fn triangles(&self, fs: &[usize]) -> String {
        match self {
            Self::Obj { face_lines } => {
                let lines: Vec<usize> = fs
                    .iter()
                    .filter_map(|&f| face_lines.get(f).copied())
                    .collect();
                format!("faces on lines {}", join(&lines))
            }
            Self::Ply { face_of_triangle } => {
                let faces: Vec<usize> = fs
                    .iter()
                    .filter_map(|&f| face_of_triangle.get(f).copied())
                    .collect();
                format!("faces {} (0-based)", join(&faces))
            }
        }
    }
}
