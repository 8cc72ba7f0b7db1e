//! Partitions: the cloth triangles split into parts, the unit of parallel work
//! (`acm-spec.md` §5). A partition owns its triangles' stretch stencils and
//! the hinges whose first face it owns.
//!
//! Results never depend on the partitioning: every per-vertex sum is a fold in
//! global key order. A partition only decides which task computes what, so a
//! [`Partitioner`] is free to be heuristic (METIS lives in `weft-par`);
//! [`Contiguous`] is the dependency-free fallback.

use weft_core::{StencilKey, StencilKind, Topology, NONE};

/// What a partitioner sees: the concatenated mesh and which triangles are
/// cloth (obstacle triangles carry no internal stencils and get no partition).
pub struct PartitionInput<'a> {
    pub triangles: &'a [[u32; 3]],
    pub is_cloth: &'a [bool],
    pub topology: &'a Topology,
    /// The number of parts wanted (≥ 1, at most the number of cloth triangles).
    pub parts: usize,
}

impl PartitionInput<'_> {
    /// The cloth triangles in input order.
    pub fn cloth_triangles(&self) -> Vec<u32> {
        (0..self.triangles.len() as u32)
            .filter(|&f| self.is_cloth[f as usize])
            .collect()
    }
}

/// Splits cloth triangles into parts.
pub trait Partitioner {
    /// A part index `< input.parts` for every cloth triangle (any value for
    /// obstacle triangles; it is ignored).
    fn assign(&self, input: &PartitionInput<'_>) -> Result<Vec<u32>, String>;

    /// A short name for logs.
    fn name(&self) -> &'static str;
}

/// Contiguous runs of cloth triangles in input order.
#[derive(Clone, Copy, Debug, Default)]
pub struct Contiguous;

impl Partitioner for Contiguous {
    fn assign(&self, input: &PartitionInput<'_>) -> Result<Vec<u32>, String> {
        let cloth = input.cloth_triangles();
        let mut part = vec![NONE; input.triangles.len()];
        for (k, &f) in cloth.iter().enumerate() {
            part[f as usize] = (k * input.parts / cloth.len()) as u32;
        }
        Ok(part)
    }

    fn name(&self) -> &'static str {
        "contiguous"
    }
}

/// The partition count used when a scene asks for `partitions = 0` (auto),
/// for a run on `workers` = ranks × threads: one part per 512 cloth
/// triangles, and at least 4 per worker (the over-decomposition the ranks'
/// placement and the threads' balance need), but no part under 32
/// triangles (scheduling would cost more than the work). Results never
/// depend on the count.
pub fn auto_count(cloth_triangles: usize, workers: usize) -> usize {
    let wanted = (cloth_triangles / 512).max(4 * workers.max(1));
    wanted.min(cloth_triangles / 32).max(1)
}

/// The partition layout of a built world.
#[derive(Clone, Debug, PartialEq)]
pub struct Partitioning {
    /// Number of partitions.
    pub count: usize,
    /// Which partitioner made it.
    pub method: &'static str,
    /// Partition of each triangle (`NONE` for obstacle triangles).
    pub of_triangle: Vec<u32>,
    /// Home partition of each vertex: that of its lowest-id cloth triangle
    /// (`NONE` for obstacle vertices).
    pub of_vertex: Vec<u32>,
}

impl Partitioning {
    /// Runs `partitioner` for `requested` parts (0 = [`auto_count`] for
    /// `workers`) and checks its answer.
    pub fn build(
        partitioner: &dyn Partitioner,
        requested: usize,
        workers: usize,
        triangles: &[[u32; 3]],
        is_cloth: &[bool],
        topology: &Topology,
        num_vertices: usize,
    ) -> Result<Self, String> {
        let cloth = is_cloth.iter().filter(|&&c| c).count();
        let wanted = if requested == 0 {
            auto_count(cloth, workers)
        } else {
            requested
        };
        let count = wanted.clamp(1, cloth.max(1));
        let input = PartitionInput {
            triangles,
            is_cloth,
            topology,
            parts: count,
        };
        let mut of_triangle = if count == 1 {
            vec![0; triangles.len()]
        } else {
            partitioner.assign(&input)?
        };
        if of_triangle.len() != triangles.len() {
            return Err(format!(
                "the {} partitioner returned {} parts for {} triangles",
                partitioner.name(),
                of_triangle.len(),
                triangles.len()
            ));
        }
        let mut of_vertex = vec![NONE; num_vertices];
        for (f, t) in triangles.iter().enumerate() {
            if !is_cloth[f] {
                of_triangle[f] = NONE;
                continue;
            }
            let p = of_triangle[f];
            if p as usize >= count {
                return Err(format!(
                    "the {} partitioner put triangle {f} in part {p} of {count}",
                    partitioner.name()
                ));
            }
            for &i in t {
                if of_vertex[i as usize] == NONE {
                    of_vertex[i as usize] = p;
                }
            }
        }
        Ok(Self {
            count,
            method: if count == 1 {
                "single"
            } else {
                partitioner.name()
            },
            of_triangle,
            of_vertex,
        })
    }

    /// The home partitions of a stencil's two sides (the vertex or first
    /// edge, and the face or second edge), each that of the side's first
    /// vertex; `NONE` for an obstacle side.
    pub fn sides(&self, key: &StencilKey) -> (u32, u32) {
        let split = match key.kind {
            StencilKind::VertexFace => 1,
            StencilKind::EdgeEdge => 2,
        };
        (
            self.of_vertex[key.v[0] as usize],
            self.of_vertex[key.v[split] as usize],
        )
    }

    /// Whether a stencil couples two different cloth partitions.
    pub fn spans(&self, key: &StencilKey) -> bool {
        let (a, b) = self.sides(key);
        a != NONE && b != NONE && a != b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use weft_core::TriMesh;

    #[test]
    fn contiguous_parts_cover_cloth_only_and_homes_are_lowest_triangles() {
        // Two strips of 4 triangles; the second is an obstacle.
        let mut tris = Vec::new();
        for s in 0..2u32 {
            let b = 6 * s;
            tris.extend([[b, b + 1, b + 3], [b + 1, b + 4, b + 3]]);
            tris.extend([[b + 1, b + 2, b + 4], [b + 2, b + 5, b + 4]]);
        }
        let mesh = TriMesh {
            positions: vec![glam::DVec3::ZERO; 12],
            triangles: tris.clone(),
        };
        let topo = Topology::build(12, &mesh.triangles).unwrap();
        let cloth = [true, true, true, true, false, false, false, false];
        let p = Partitioning::build(&Contiguous, 2, 1, &tris, &cloth, &topo, 12).unwrap();
        assert_eq!(p.count, 2);
        assert_eq!(p.of_triangle[..4], [0, 0, 1, 1]);
        assert!(p.of_triangle[4..].iter().all(|&x| x == NONE));
        assert_eq!(p.of_vertex[..6], [0, 0, 1, 0, 0, 1]);
        assert!(p.of_vertex[6..].iter().all(|&x| x == NONE));
        let vf = StencilKey::vertex_face(2, [0, 1, 3]);
        assert!(p.spans(&vf));
        let obstacle = StencilKey::vertex_face(2, [6, 7, 9]);
        assert!(!p.spans(&obstacle));
        // Asking for more parts than cloth triangles gets one per triangle;
        // 0 asks for the automatic count.
        assert_eq!(
            Partitioning::build(&Contiguous, 99, 1, &tris, &cloth, &topo, 12)
                .unwrap()
                .count,
            4
        );
        assert_eq!(
            Partitioning::build(&Contiguous, 0, 1, &tris, &cloth, &topo, 12)
                .unwrap()
                .count,
            1
        );
    }

    /// One part per 512 cloth triangles, at least 4 per worker, no part
    /// under 32 triangles, never none; no cap at 256 (the scale-out issue).
    #[test]
    fn the_automatic_count_over_decomposes_for_the_workers() {
        assert_eq!(auto_count(0, 1), 1);
        assert_eq!(auto_count(100, 1), 3); // 4 wanted, 32 triangles at least
        assert_eq!(auto_count(20_000, 1), 39);
        assert_eq!(auto_count(20_000, 2), 39);
        assert_eq!(auto_count(20_000, 16), 64);
        assert_eq!(auto_count(20_000, 0), auto_count(20_000, 1));
        // The 100k twister: 199,920 cloth triangles.
        assert_eq!(auto_count(199_920, 1), 390);
        assert_eq!(auto_count(199_920, 384), 1536);
        assert_eq!(auto_count(199_920, 768), 3072);
        assert_eq!(auto_count(199_920, 10_000), 199_920 / 32);
        for (c, w) in [(1, 1), (31, 4), (5000, 3), (1 << 20, 1000)] {
            let n = auto_count(c, w);
            assert!(n >= 1 && (n == 1 || n * 32 <= c), "{c} {w}: {n}");
        }
    }

    #[test]
    fn a_bad_partitioner_answer_is_an_error() {
        struct Bad;
        impl Partitioner for Bad {
            fn assign(&self, input: &PartitionInput<'_>) -> Result<Vec<u32>, String> {
                Ok(vec![input.parts as u32; input.triangles.len()])
            }
            fn name(&self) -> &'static str {
                "bad"
            }
        }
        let tris = vec![[0, 1, 2], [1, 3, 2]];
        let topo = Topology::build(4, &tris).unwrap();
        let e = Partitioning::build(&Bad, 2, 1, &tris, &[true, true], &topo, 4).unwrap_err();
        assert!(e.contains("triangle 0 in part 2 of 2"), "{e}");
    }
}
