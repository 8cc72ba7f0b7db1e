//! Triangle-mesh topology: edges, hinges, adjacency, boundary.
//!
//! [`Topology::build`] derives everything in one sort of the (edge, face)
//! incidences, so all outputs are in a deterministic order (by sorted edge, then
//! by face id) that does not depend on hashing.

/// A bending hinge: an interior edge with its two wing vertices.
///
/// Orientation follows the discrete-shells formulas of `acm-spec.md` §2.1:
/// `edge = [x0, x1]` is traversed x0 → x1 by face `faces[0]` (face A, whose
/// third vertex is `wings[0]` = x2); `faces[1]` (face B) has third vertex
/// `wings[1]` = x3. With consistently oriented faces, nA = (x1-x0)×(x2-x0)
/// and nB = (x3-x0)×(x1-x0) both point to the same side of a flat sheet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hinge {
    pub edge: [u32; 2],
    pub wings: [u32; 2],
    pub faces: [u32; 2],
}

use crate::validate::MeshError;
use crate::NONE;

/// Edges, hinges, adjacency and boundary of a triangle mesh (indices are the
/// mesh's own, i.e. input ids when the mesh is the scene's input).
#[derive(Clone, Debug, Default)]
pub struct Topology {
    pub num_vertices: usize,
    /// Unique undirected edges `[a, b]` with `a < b`, sorted ascending.
    pub edges: Vec<[u32; 2]>,
    /// For triangle `[a, b, c]`: the edge indices of (a,b), (b,c), (c,a).
    pub face_edges: Vec<[u32; 3]>,
    /// The faces of each edge in ascending order; `[f, NONE]` on the boundary.
    pub edge_faces: Vec<[u32; 2]>,
    /// One hinge per interior edge, in edge order.
    pub hinges: Vec<Hinge>,
    /// The faces incident to each vertex, ascending.
    pub vertex_faces: VertexFaces,
    /// `true` for vertices on a boundary edge.
    pub is_boundary_vertex: Vec<bool>,
}

impl Topology {
    /// Derives the topology of `triangles` over `num_vertices` vertices.
    ///
    /// Fails on an index out of range, a triangle that repeats a vertex, or an
    /// edge shared by more than two triangles (non-manifold), naming the element.
    /// Geometry (zero area) and duplicate faces are not checked here: run
    /// [`crate::validate`](fn@crate::validate) on user input first.
    pub fn build(num_vertices: usize, triangles: &[[u32; 3]]) -> Result<Self, MeshError> {
        for (f, t) in triangles.iter().enumerate() {
            for &v in t {
                if v as usize >= num_vertices {
                    return Err(MeshError::IndexOutOfRange {
                        triangle: f,
                        index: v,
                        num_vertices,
                    });
                }
            }
            if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
                return Err(MeshError::RepeatedVertex {
                    triangle: f,
                    vertices: *t,
                });
            }
        }
        // (edge, face) incidences sorted by edge then face.
        let mut inc: Vec<([u32; 2], u32)> = Vec::with_capacity(triangles.len() * 3);
        for (f, t) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                inc.push(([a.min(b), a.max(b)], f as u32));
            }
        }
        inc.sort_unstable();
        let mut edges: Vec<[u32; 2]> = Vec::new();
        let mut edge_faces: Vec<[u32; 2]> = Vec::new();
        let mut i = 0;
        while i < inc.len() {
            let e = inc[i].0;
            let mut j = i;
            while j < inc.len() && inc[j].0 == e {
                j += 1;
            }
            if j - i > 2 {
                return Err(MeshError::NonManifoldEdge {
                    edge: e,
                    triangles: inc[i..j].iter().map(|x| x.1 as usize).collect(),
                });
            }
            edges.push(e);
            edge_faces.push([inc[i].1, if j - i == 2 { inc[i + 1].1 } else { NONE }]);
            i = j;
        }
        let edge_index = |a: u32, b: u32| -> u32 {
            let key = [a.min(b), a.max(b)];
            edges.binary_search(&key).map(|i| i as u32).unwrap_or(NONE)
        };
        let face_edges: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| {
                [
                    edge_index(t[0], t[1]),
                    edge_index(t[1], t[2]),
                    edge_index(t[2], t[0]),
                ]
            })
            .collect();
        let third = |t: &[u32; 3], e: [u32; 2]| -> u32 {
            *t.iter().find(|&&v| v != e[0] && v != e[1]).unwrap_or(&NONE)
        };
        let mut hinges = Vec::new();
        let mut is_boundary_vertex = vec![false; num_vertices];
        for (&[a, b], &[fa, fb]) in edges.iter().zip(edge_faces.iter()) {
            if fb == NONE {
                is_boundary_vertex[a as usize] = true;
                is_boundary_vertex[b as usize] = true;
                continue;
            }
            // Orient the edge as face A (the lower face id) traverses it.
            let ta = &triangles[fa as usize];
            let on_edge = |v: u32| v == a || v == b;
            let k = (0..3)
                .find(|&k| on_edge(ta[k]) && on_edge(ta[(k + 1) % 3]))
                .unwrap_or(0);
            let (x0, x1) = (ta[k], ta[(k + 1) % 3]);
            hinges.push(Hinge {
                edge: [x0, x1],
                wings: [third(ta, [a, b]), third(&triangles[fb as usize], [a, b])],
                faces: [fa, fb],
            });
        }
        let mut counts = vec![0u32; num_vertices + 1];
        for t in triangles {
            for &v in t {
                counts[v as usize + 1] += 1;
            }
        }
        for v in 0..num_vertices {
            counts[v + 1] += counts[v];
        }
        let vertex_face_offsets = counts.clone();
        let mut vertex_faces = vec![0u32; triangles.len() * 3];
        let mut fill = counts;
        for (f, t) in triangles.iter().enumerate() {
            for &v in t {
                vertex_faces[fill[v as usize] as usize] = f as u32;
                fill[v as usize] += 1;
            }
        }
        Ok(Self {
            num_vertices,
            edges,
            face_edges,
            edge_faces,
            hinges,
            vertex_faces: VertexFaces {
                offsets: vertex_face_offsets,
                faces: vertex_faces,
            },
            is_boundary_vertex,
        })
    }

    /// Faces incident to vertex `v`, ascending.
    pub fn faces_of_vertex(&self, v: u32) -> &[u32] {
        self.vertex_faces.of(v)
    }

    /// Index of edge `{a, b}`, if it exists.
    pub fn edge_index(&self, a: u32, b: u32) -> Option<u32> {
        self.edges
            .binary_search(&[a.min(b), a.max(b)])
            .ok()
            .map(|i| i as u32)
    }
}

/// The faces incident to each vertex, ascending (CSR): all a built world
/// keeps of its topology (the edges and hinges are in its internal
/// elements by then).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct VertexFaces {
    /// `faces[offsets[v]..offsets[v + 1]]` are vertex `v`'s.
    offsets: Vec<u32>,
    faces: Vec<u32>,
}

impl VertexFaces {
    /// How many vertices.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Faces incident to vertex `v`, ascending.
    pub fn of(&self, v: u32) -> &[u32] {
        let (a, b) = (
            self.offsets[v as usize] as usize,
            self.offsets[v as usize + 1] as usize,
        );
        &self.faces[a..b]
    }
}
