//! A plain indexed triangle mesh.

use glam::DVec3;

/// An indexed triangle mesh: positions and counter-clockwise triangles
/// (indices into `positions`, 0-based).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    pub fn new(positions: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Self {
        Self {
            positions,
            triangles,
        }
    }

    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    pub fn num_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Appends `other`, offsetting its indices; returns the index offset used.
    pub fn append(&mut self, other: &TriMesh) -> u32 {
        let offset = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
        offset
    }

    /// The three corner positions of triangle `f`.
    pub fn corners(&self, f: usize) -> [DVec3; 3] {
        let t = self.triangles[f];
        [
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
        ]
    }
}

/// The smallest and largest coordinates of `points`, per axis (infinite,
/// inverted bounds for no points).
pub fn bounding_box(points: &[DVec3]) -> (DVec3, DVec3) {
    points
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        })
}
