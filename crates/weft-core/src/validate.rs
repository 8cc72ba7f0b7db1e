//! Mesh validation: errors name the offending element.
//!
//! [`validate`] runs the checks below in this order and stops at the first
//! error, so a message always describes the most basic problem:
//!
//! 1. the mesh has at least one triangle ([`MeshError::Empty`]);
//! 2. every coordinate is finite ([`MeshError::NonFiniteCoordinate`]) and at
//!    most [`MAX_COORDINATE`] in magnitude ([`MeshError::CoordinateTooLarge`]);
//! 3. every index is in range ([`MeshError::IndexOutOfRange`]);
//! 4. no triangle repeats a vertex ([`MeshError::RepeatedVertex`]);
//! 5. no triangle has (near-)zero area: collinear corners
//!    ([`MeshError::DegenerateTriangle`]), or an area too small to resolve next
//!    to the mesh's extent ([`MeshError::TooSmallForExtent`], usually a stray
//!    vertex far away or wrong units);
//! 6. no two triangles use the same three vertices ([`MeshError::DuplicateTriangle`]);
//! 7. every edge has at most two triangles ([`MeshError::NonManifoldEdge`]).
//!
//! A mesh that passes may still produce [`MeshWarning`]s (unreferenced vertices,
//! inconsistently oriented faces). `Display` names elements by their 0-based
//! positions in the mesh and says so; [`MeshError::describe`] and
//! [`MeshWarning::describe`] name them as the source file does (see
//! [`crate::names`]).

use std::fmt;

use glam::DVec3;

use crate::mesh::{bounding_box, TriMesh};
use crate::names::{ElementNames, MeshIds};
use crate::topology::Topology;

/// Relative area tolerance: a triangle is degenerate when its area is at most
/// `DEGENERATE_AREA_REL * diag²`, where `diag` is the mesh's bounding-box
/// diagonal (so the test is independent of the mesh's units). Coordinates are
/// rounded relative to the mesh's extent, so a smaller area is rounding noise.
pub const DEGENERATE_AREA_REL: f64 = 1e-14;

/// The largest coordinate magnitude (m) weft simulates, `2^500`: the range
/// over which the narrow phase's rounding-error analysis holds
/// (`weft_geom::ccd::COORD_LIMIT`), and far below where squared distances
/// overflow.
pub const MAX_COORDINATE: f64 = 3.273_390_607_896_142e150;

/// How many vertex ids [`MeshWarning::UnreferencedVertices`] lists.
const LISTED_IDS: usize = 5;

/// A mesh that cannot be simulated. Indices are 0-based positions in the mesh.
///
/// When this error occurs: [`validate`] or [`Topology::build`] was given a mesh
/// that breaks one of the invariants the simulator relies on. How to handle it:
/// fix the named element in the source file (or the code that generated it).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    Empty,
    NonFiniteCoordinate {
        vertex: usize,
        axis: char,
        value: f64,
    },
    /// A coordinate beyond [`MAX_COORDINATE`].
    CoordinateTooLarge {
        vertex: usize,
        axis: char,
        value: f64,
    },
    IndexOutOfRange {
        triangle: usize,
        index: u32,
        num_vertices: usize,
    },
    RepeatedVertex {
        triangle: usize,
        vertices: [u32; 3],
    },
    /// Collinear (or coincident) corners: `area` is at most `tolerance`,
    /// [`DEGENERATE_AREA_REL`] times the square of the triangle's own longest
    /// edge `longest_edge`.
    DegenerateTriangle {
        triangle: usize,
        vertices: [u32; 3],
        area: f64,
        tolerance: f64,
        longest_edge: f64,
    },
    /// A triangle of a sound shape whose `area` is at most
    /// [`DEGENERATE_AREA_REL`] times the square of the mesh's extent `extent`
    /// (its bounding-box diagonal): lost in the rounding of coordinates that
    /// large. `far_vertex` (at `far_position`) is the vertex farthest from the
    /// triangle's first corner (`vertices[0]`; the triangle is tiny next to
    /// the extent, so that is about as far from the whole triangle): the
    /// usual culprit is a stray vertex.
    TooSmallForExtent {
        triangle: usize,
        vertices: [u32; 3],
        far_vertex: u32,
        area: f64,
        extent: f64,
        far_position: DVec3,
    },
    DuplicateTriangle {
        triangle: usize,
        first: usize,
        vertices: [u32; 3],
    },
    NonManifoldEdge {
        edge: [u32; 2],
        triangles: Vec<usize>,
    },
}

impl MeshError {
    /// The triangle the error is about, if any (for a duplicate, the later
    /// copy; for a non-manifold edge, the triangle that made it non-manifold).
    /// Readers use it to map the error back to a source line.
    pub fn triangle(&self) -> Option<usize> {
        match self {
            Self::IndexOutOfRange { triangle, .. }
            | Self::RepeatedVertex { triangle, .. }
            | Self::DegenerateTriangle { triangle, .. }
            | Self::TooSmallForExtent { triangle, .. }
            | Self::DuplicateTriangle { triangle, .. } => Some(*triangle),
            Self::NonManifoldEdge { triangles, .. } => triangles.last().copied(),
            Self::Empty | Self::NonFiniteCoordinate { .. } | Self::CoordinateTooLarge { .. } => {
                None
            }
        }
    }

    /// The message, naming elements with `names`.
    pub fn describe(&self, names: &dyn ElementNames) -> String {
        match self {
            Self::Empty => "the mesh has no triangles".into(),
            Self::NonFiniteCoordinate {
                vertex,
                axis,
                value,
            } => format!(
                "{} has a non-finite {axis} coordinate ({value})",
                names.vertex(*vertex as u32)
            ),
            Self::CoordinateTooLarge {
                vertex,
                axis,
                value,
            } => format!(
                "{} has {axis} = {value:e} m, beyond the largest magnitude weft can simulate \
                 ({MAX_COORDINATE:.3e} m); the coordinates are in the wrong units or corrupt: \
                 rescale the mesh file (a scene's transform.scale applies only after this check)",
                names.vertex(*vertex as u32)
            ),
            Self::IndexOutOfRange {
                triangle,
                index,
                num_vertices,
            } => format!(
                "{} refers to vertex {index}, but the mesh has only {num_vertices} vertices \
                 (valid indices 0..={}, 0-based)",
                names.triangle(*triangle),
                num_vertices.saturating_sub(1)
            ),
            Self::RepeatedVertex { triangle, vertices } => format!(
                "{} ({}) repeats a vertex",
                names.triangle(*triangle),
                names.vertices(vertices)
            ),
            Self::DegenerateTriangle {
                triangle,
                vertices,
                area,
                longest_edge,
                ..
            } => format!(
                "{} ({}) has zero area: its corners are collinear (area {area:.3e} m² for a \
                 longest edge of {longest_edge:.3e} m)",
                names.triangle(*triangle),
                names.vertices(vertices)
            ),
            Self::TooSmallForExtent {
                triangle,
                vertices,
                far_vertex,
                area,
                extent,
                far_position,
            } => format!(
                "{} ({}) has an area of {area:.3e} m², too small to resolve in a mesh \
                 {extent:.3e} m across (below {:.3e} m², areas are lost in the rounding of its \
                 coordinates; this triangle needs the mesh to span at most {:.3e} m). The \
                 vertex farthest from its corner {} is {} at ({:e}, {:e}, {:e}): delete it if it \
                 is a stray vertex; if the mesh is really that large, its units are wrong (weft \
                 uses metres)",
                names.triangle(*triangle),
                names.vertices(vertices),
                DEGENERATE_AREA_REL * extent * extent,
                (area / DEGENERATE_AREA_REL).sqrt(),
                names.vertex(vertices[0]),
                names.vertex(*far_vertex),
                far_position.x,
                far_position.y,
                far_position.z,
            ),
            Self::DuplicateTriangle {
                triangle,
                first,
                vertices,
            } => format!(
                "{} ({}) duplicates {} (same three vertices)",
                names.triangle(*triangle),
                names.vertices(vertices),
                names.triangle(*first)
            ),
            Self::NonManifoldEdge { edge, triangles } => format!(
                "the edge ({}) is shared by {} {} (non-manifold: at most two allowed)",
                names.vertices(edge),
                triangles.len(),
                names.triangles(triangles)
            ),
        }
    }
}

impl fmt::Display for MeshError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe(&MeshIds))
    }
}

impl std::error::Error for MeshError {}

/// A mesh that can be simulated but is probably not what the user meant.
/// Indices are 0-based positions in the mesh.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum MeshWarning {
    /// Vertices no triangle uses: they are simulated as free particles.
    UnreferencedVertices { count: usize, first: Vec<u32> },
    /// Interior edges traversed in the same direction by both of their
    /// triangles: normals flip across them, so bending rest angles and
    /// one-sided contact see a fold. Reports the first such edge.
    InconsistentOrientation {
        count: usize,
        edge: [u32; 2],
        triangles: [usize; 2],
    },
}

impl MeshWarning {
    /// The message, naming elements with `names`.
    pub fn describe(&self, names: &dyn ElementNames) -> String {
        match self {
            Self::UnreferencedVertices { count, first } => format!(
                "{count} vertices are used by no triangle (first: {})",
                names.vertices(first)
            ),
            Self::InconsistentOrientation {
                count,
                edge,
                triangles,
            } => format!(
                "{count} interior edges are inconsistently oriented; first: the edge from {} to \
                 {} is traversed in that direction by both {} and {} (flip one so that the \
                 normals agree)",
                names.vertex(edge[0]),
                names.vertex(edge[1]),
                names.triangle(triangles[0]),
                names.triangle(triangles[1])
            ),
        }
    }
}

impl fmt::Display for MeshWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe(&MeshIds))
    }
}

/// Validates `mesh`; returns warnings, or the first error found (see the
/// module docs for the order of the checks).
pub fn validate(mesh: &TriMesh) -> Result<Vec<MeshWarning>, MeshError> {
    let n = mesh.num_vertices();
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty);
    }
    for (v, p) in mesh.positions.iter().enumerate() {
        for (axis, value) in ['x', 'y', 'z'].into_iter().zip(p.to_array()) {
            if !value.is_finite() {
                return Err(MeshError::NonFiniteCoordinate {
                    vertex: v,
                    axis,
                    value,
                });
            }
        }
    }
    for (v, p) in mesh.positions.iter().enumerate() {
        for (axis, value) in ['x', 'y', 'z'].into_iter().zip(p.to_array()) {
            if value.abs() > MAX_COORDINATE {
                return Err(MeshError::CoordinateTooLarge {
                    vertex: v,
                    axis,
                    value,
                });
            }
        }
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&v| v as usize >= n) {
            return Err(MeshError::IndexOutOfRange {
                triangle: f,
                index,
                num_vertices: n,
            });
        }
    }
    for (f, t) in mesh.triangles.iter().enumerate() {
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return Err(MeshError::RepeatedVertex {
                triangle: f,
                vertices: *t,
            });
        }
    }
    check_areas(mesh)?;
    check_duplicates(&mesh.triangles)?;
    let topo = Topology::build(n, &mesh.triangles)?;

    let mut warnings = Vec::new();
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let unused: Vec<u32> = (0..n as u32).filter(|&v| !used[v as usize]).collect();
    if !unused.is_empty() {
        warnings.push(MeshWarning::UnreferencedVertices {
            count: unused.len(),
            first: unused[..unused.len().min(LISTED_IDS)].to_vec(),
        });
    }
    // `Hinge::edge` is oriented as faces[0] traverses it; a consistent
    // neighbour must traverse it the other way.
    let mut bad = topo.hinges.iter().filter(|h| {
        let tb = &mesh.triangles[h.faces[1] as usize];
        (0..3).any(|k| tb[k] == h.edge[0] && tb[(k + 1) % 3] == h.edge[1])
    });
    if let Some(first) = bad.next() {
        warnings.push(MeshWarning::InconsistentOrientation {
            count: 1 + bad.count(),
            edge: first.edge,
            triangles: [first.faces[0] as usize, first.faces[1] as usize],
        });
    }
    Ok(warnings)
}

fn check_areas(mesh: &TriMesh) -> Result<(), MeshError> {
    let (lo, hi) = bounding_box(&mesh.positions);
    let extent = (hi - lo).length();
    let tolerance = DEGENERATE_AREA_REL * extent * extent;
    for f in 0..mesh.num_triangles() {
        let [a, b, c] = mesh.corners(f);
        let area = 0.5 * (b - a).cross(c - a).length();
        if area > tolerance {
            continue;
        }
        // Which of the two reasons: the triangle's own shape, or its size
        // next to the rest of the mesh.
        let longest_edge = (b - a).length().max((c - b).length()).max((a - c).length());
        let own_tolerance = DEGENERATE_AREA_REL * longest_edge * longest_edge;
        let vertices = mesh.triangles[f];
        if area <= own_tolerance {
            return Err(MeshError::DegenerateTriangle {
                triangle: f,
                vertices,
                area,
                tolerance: own_tolerance,
                longest_edge,
            });
        }
        // The vertex farthest from the triangle's first corner (the first of
        // equals).
        let far_vertex = mesh
            .positions
            .iter()
            .map(|&p| (p - a).length())
            .enumerate()
            .fold(
                (0, 0.0),
                |best, (v, d)| if d > best.1 { (v, d) } else { best },
            )
            .0;
        return Err(MeshError::TooSmallForExtent {
            triangle: f,
            vertices,
            far_vertex: far_vertex as u32,
            area,
            extent,
            far_position: mesh.positions[far_vertex],
        });
    }
    Ok(())
}

fn check_duplicates(triangles: &[[u32; 3]]) -> Result<(), MeshError> {
    let mut keyed: Vec<([u32; 3], usize)> = triangles
        .iter()
        .enumerate()
        .map(|(f, t)| {
            let mut k = *t;
            k.sort_unstable();
            (k, f)
        })
        .collect();
    keyed.sort_unstable();
    // Report the duplicate with the lowest triangle id, against its first copy.
    let mut found: Option<(usize, usize)> = None;
    let mut i = 0;
    while i < keyed.len() {
        let mut j = i + 1;
        while j < keyed.len() && keyed[j].0 == keyed[i].0 {
            j += 1;
        }
        if j - i > 1 {
            let (first, dup) = (keyed[i].1, keyed[i + 1].1);
            if found.is_none_or(|(_, d)| dup < d) {
                found = Some((first, dup));
            }
        }
        i = j;
    }
    match found {
        Some((first, triangle)) => Err(MeshError::DuplicateTriangle {
            triangle,
            first,
            vertices: triangles[triangle],
        }),
        None => Ok(()),
    }
}
