//! METIS partitions of the cloth triangles' dual graph (`acm-spec.md` §5):
//! triangles are graph vertices, an interior edge between two cloth triangles
//! is a graph edge, and METIS's k-way partitioning keeps the parts balanced
//! while cutting few edges — so few stencils read another part's vertices.
//!
//! The seed is fixed, so one machine always makes the same parts; the results
//! of a run never depend on them anyway (every sum is a fold in key order).

use metis::{Graph, Idx};
use weft_core::NONE;
use weft_sim::partition::{PartitionInput, Partitioner};
use weft_sim::{Executor, SimError, World, WorldSpec};

/// The METIS partitioner (`METIS_PartGraphKway` on the dual graph).
#[derive(Clone, Copy, Debug, Default)]
pub struct Metis;

impl Partitioner for Metis {
    fn assign(&self, input: &PartitionInput<'_>) -> Result<Vec<u32>, String> {
        let cloth = input.cloth_triangles();
        let mut index = vec![NONE; input.triangles.len()];
        for (k, &f) in cloth.iter().enumerate() {
            index[f as usize] = k as u32;
        }
        // Dual graph in CSR form, neighbours in ascending order.
        let mut pairs: Vec<(u32, u32)> = Vec::new();
        for &[fa, fb] in &input.topology.edge_faces {
            if fb == NONE {
                continue;
            }
            let (a, b) = (index[fa as usize], index[fb as usize]);
            if a != NONE && b != NONE {
                pairs.push((a, b));
                pairs.push((b, a));
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let too_big = |_| "the mesh is too large for METIS's index type".to_string();
        let mut xadj: Vec<Idx> = vec![0; cloth.len() + 1];
        for &(a, _) in &pairs {
            xadj[a as usize + 1] += 1;
        }
        for k in 0..cloth.len() {
            xadj[k + 1] += xadj[k];
        }
        let adjncy: Vec<Idx> = pairs
            .iter()
            .map(|&(_, b)| Idx::try_from(b).map_err(too_big))
            .collect::<Result<_, _>>()?;
        let parts = Idx::try_from(input.parts).map_err(too_big)?;
        let mut part: Vec<Idx> = vec![0; cloth.len()];
        // METIS's random generator is process-global state: two calls at once
        // (ranks on threads, tests in one process) perturb each other's parts.
        // One call at a time makes the same parts for the same graph.
        static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
        let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        Graph::new(1, parts, &xadj, &adjncy)
            .map_err(|e| format!("METIS refused the dual graph: {e}"))?
            .set_option(metis::option::Seed(1))
            .part_kway(&mut part)
            .map_err(|e| format!("METIS failed: {e}"))?;
        let mut out = vec![NONE; input.triangles.len()];
        for (k, &f) in cloth.iter().enumerate() {
            out[f as usize] = u32::try_from(part[k]).map_err(|_| "METIS gave a negative part")?;
        }
        Ok(out)
    }

    fn name(&self) -> &'static str {
        "metis"
    }
}

/// Builds `spec`'s world with METIS partitions.
pub fn build_world(spec: &WorldSpec) -> Result<World, SimError> {
    World::build_with(spec, &Metis)
}

/// [`build_world`] with the internal step estimated on `exec`'s threads
/// and ranks (`World::build_on`: the same world on any number; collective
/// over ranks).
pub fn build_world_on<E: Executor>(spec: &WorldSpec, exec: &E) -> Result<World, SimError> {
    World::build_on(spec, &Metis, exec)
}

#[cfg(test)]
mod tests {
    use super::*;
    use weft_core::Topology;
    use weft_sim::partition::{Contiguous, Partitioning};

    /// A `n × n` grid of quads, two triangles each.
    fn grid(n: u32) -> (Vec<[u32; 3]>, usize) {
        let id = |i: u32, j: u32| i * (n + 1) + j;
        let mut t = Vec::new();
        for i in 0..n {
            for j in 0..n {
                t.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                t.push([id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (t, ((n + 1) * (n + 1)) as usize)
    }

    /// Edges of the dual graph whose two triangles lie in different parts.
    fn cut(p: &Partitioning, topo: &Topology) -> usize {
        topo.edge_faces
            .iter()
            .filter(|[a, b]| *b != NONE && p.of_triangle[*a as usize] != p.of_triangle[*b as usize])
            .count()
    }

    #[test]
    fn metis_parts_are_balanced_and_cut_fewer_edges_than_strips() {
        let (tris, nv) = grid(32);
        let topo = Topology::build(nv, &tris).unwrap();
        let cloth = vec![true; tris.len()];
        for parts in [4, 16, 64] {
            let m = Partitioning::build(&Metis, parts, 1, &tris, &cloth, &topo, nv).unwrap();
            let c = Partitioning::build(&Contiguous, parts, 1, &tris, &cloth, &topo, nv).unwrap();
            assert_eq!(m.count, parts);
            let mut sizes = vec![0usize; parts];
            for &p in &m.of_triangle {
                sizes[p as usize] += 1;
            }
            let ideal = tris.len() as f64 / parts as f64;
            let largest = *sizes.iter().max().unwrap() as f64;
            assert!(largest <= 1.1 * ideal, "P = {parts}: {sizes:?}");
            assert!(sizes.iter().all(|&s| s > 0), "P = {parts}: {sizes:?}");
            // Square-ish blocks beat strips of rows once strips get thin.
            if parts >= 16 {
                assert!(cut(&m, &topo) < cut(&c, &topo), "P = {parts}");
            }
            // The same machine makes the same parts.
            let again = Partitioning::build(&Metis, parts, 1, &tris, &cloth, &topo, nv).unwrap();
            assert_eq!(again, m);
        }
    }

    #[test]
    fn obstacle_triangles_get_no_part_and_disconnected_cloths_work() {
        let (mut tris, nv) = grid(8);
        let shift = nv as u32;
        let second: Vec<[u32; 3]> = tris.iter().map(|t| t.map(|i| i + shift)).collect();
        let n = tris.len();
        tris.extend(second);
        let topo = Topology::build(2 * nv, &tris).unwrap();
        let mut cloth = vec![true; tris.len()];
        cloth[n..n + 10].fill(false);
        let m = Partitioning::build(&Metis, 8, 1, &tris, &cloth, &topo, 2 * nv).unwrap();
        assert!(m.of_triangle[n..n + 10].iter().all(|&p| p == NONE));
        assert!(m.of_triangle[..n].iter().all(|&p| p < 8));
        assert_eq!(m.method, "metis");
    }
}
