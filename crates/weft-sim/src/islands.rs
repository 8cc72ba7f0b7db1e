//! Contact islands (`acm-spec.md` §5): the active stencils of a pass grouped
//! by the connected components of their **dynamic** vertices.
//!
//! Between two internal ticks a penalty kick changes only the velocities of
//! its stencil's dynamic vertices, and reads the positions and velocities of
//! its stencil's vertices. Two stencils that share no dynamic vertex can only
//! meet through a kinematic vertex, whose velocity changes at internal ticks
//! only (its script's chord) and which no kick moves. So the stencils of one
//! island read and write only the island's vertices (plus kinematic ones,
//! read-only) between internal ticks, and each island can run its own
//! penalty ticks in (tick, layer, key) order on its own: every vertex folds
//! exactly the kicks, in exactly the order, of the global schedule.
//!
//! Kinematic vertices join nothing: a rod gripped along a whole sleeve would
//! otherwise fuse every contact into one island.
//!
//! Islands are numbered in the order of their first stencil (key order), so
//! the numbering depends on the active set only, never on the partitioning
//! or on where the work runs.

use weft_core::StencilKey;

/// The islands of a set of active stencils.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Islands {
    /// Island `k`'s stencils are `stencils[stencil_start[k]..stencil_start[k + 1]]`
    /// (indices into the active list, ascending: key order).
    stencil_start: Vec<u32>,
    stencils: Vec<u32>,
    /// Island `k`'s dynamic vertices, ascending.
    vertex_start: Vec<u32>,
    vertices: Vec<u32>,
}

/// A union-find forest over vertex ids, with path halving.
struct UnionFind(Vec<u32>);

impl UnionFind {
    fn root(&mut self, mut i: u32) -> u32 {
        while self.0[i as usize] != i {
            let grand = self.0[self.0[i as usize] as usize];
            self.0[i as usize] = grand;
            i = grand;
        }
        i
    }

    fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.root(a), self.root(b));
        // The smaller root wins: the forest depends on the input only.
        if ra < rb {
            self.0[rb as usize] = ra;
        } else {
            self.0[ra as usize] = rb;
        }
    }
}

impl Islands {
    /// The islands of `active` (stencil keys, in key order) over `n`
    /// vertices, where vertex `i` is dynamic when `inv_mass[i] > 0`. Every
    /// active stencil has a dynamic vertex (stencils of kinematic vertices
    /// only are never active).
    pub fn build<'a>(active: impl IntoIterator<Item = &'a StencilKey>, inv_mass: &[f64]) -> Self {
        let keys: Vec<&StencilKey> = active.into_iter().collect();
        let n = inv_mass.len();
        let dynamic = |i: u32| inv_mass[i as usize] > 0.0;
        let mut forest = UnionFind((0..n as u32).collect());
        for key in &keys {
            let mut first = None;
            for &i in key.v.iter().filter(|&&i| dynamic(i)) {
                match first {
                    None => first = Some(i),
                    Some(f) => forest.join(f, i),
                }
            }
        }
        // Number the islands by their first stencil; count their members.
        const NONE: u32 = u32::MAX;
        let mut island_of_root = vec![NONE; n];
        let mut of_stencil = Vec::with_capacity(keys.len());
        let mut stencil_count: Vec<u32> = Vec::new();
        for key in &keys {
            let i = *key
                .v
                .iter()
                .find(|&&i| dynamic(i))
                .expect("an active stencil has a dynamic vertex");
            let r = forest.root(i) as usize;
            if island_of_root[r] == NONE {
                island_of_root[r] = stencil_count.len() as u32;
                stencil_count.push(0);
            }
            let k = island_of_root[r];
            stencil_count[k as usize] += 1;
            of_stencil.push(k);
        }
        let count = stencil_count.len();
        let mut stencil_start = vec![0u32; count + 1];
        for k in 0..count {
            stencil_start[k + 1] = stencil_start[k] + stencil_count[k];
        }
        let mut fill = stencil_start.clone();
        let mut stencils = vec![0u32; keys.len()];
        for (a, &k) in of_stencil.iter().enumerate() {
            stencils[fill[k as usize] as usize] = a as u32;
            fill[k as usize] += 1;
        }
        // Each dynamic vertex once, in its island, ascending.
        let mut members: Vec<(u32, u32)> = Vec::new();
        let mut seen = vec![false; n];
        for key in &keys {
            for &i in key.v.iter().filter(|&&i| dynamic(i)) {
                if !std::mem::replace(&mut seen[i as usize], true) {
                    members.push((island_of_root[forest.root(i) as usize], i));
                }
            }
        }
        members.sort_unstable();
        let mut vertex_start = vec![0u32; count + 1];
        for &(k, _) in &members {
            vertex_start[k as usize + 1] += 1;
        }
        for k in 0..count {
            vertex_start[k + 1] += vertex_start[k];
        }
        Islands {
            stencil_start,
            stencils,
            vertex_start,
            vertices: members.into_iter().map(|(_, i)| i).collect(),
        }
    }

    /// All of `active` as one island, whatever joins it: run as one, its
    /// batches are the global schedule's (one batch per tick over every
    /// stencil), the reference the islands are checked against.
    pub fn merged<'a>(active: impl IntoIterator<Item = &'a StencilKey>, inv_mass: &[f64]) -> Self {
        let keys: Vec<&StencilKey> = active.into_iter().collect();
        if keys.is_empty() {
            return Self::default();
        }
        let mut vertices: Vec<u32> = (keys.iter().flat_map(|k| k.v))
            .filter(|&i| inv_mass[i as usize] > 0.0)
            .collect();
        vertices.sort_unstable();
        vertices.dedup();
        Islands {
            stencil_start: vec![0, keys.len() as u32],
            stencils: (0..keys.len() as u32).collect(),
            vertex_start: vec![0, vertices.len() as u32],
            vertices,
        }
    }

    /// How many islands.
    pub fn len(&self) -> usize {
        self.stencil_start.len().saturating_sub(1)
    }

    /// Whether there is none (no active stencil).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The islands packed into units of work: each island of at least
    /// `min_stencils` stencils alone, the others gathered in island order
    /// until a pack holds `min_stencils` (the last pack may hold fewer). A pack's stencils and
    /// vertices are the union of its islands', ascending.
    ///
    /// A pack runs as one island with the same bits (its islands share no
    /// dynamic vertex, and each vertex still folds its kicks in (layer, key)
    /// order), but costs one task and one pass over its state instead of
    /// one per tiny island.
    pub fn packed(&self, min_stencils: usize) -> Islands {
        let mut packs = Islands {
            stencil_start: vec![0],
            vertex_start: vec![0],
            ..Islands::default()
        };
        let (mut open_stencils, mut open_vertices) = (Vec::new(), Vec::new());
        let close = |packs: &mut Islands, stencils: &mut Vec<u32>, vertices: &mut Vec<u32>| {
            if stencils.is_empty() {
                return;
            }
            stencils.sort_unstable();
            vertices.sort_unstable();
            packs.stencils.append(stencils);
            packs.vertices.append(vertices);
            packs.stencil_start.push(packs.stencils.len() as u32);
            packs.vertex_start.push(packs.vertices.len() as u32);
        };
        for k in 0..self.len() {
            let (stencils, vertices) = (self.stencils_of(k), self.vertices_of(k));
            if stencils.len() >= min_stencils {
                close(&mut packs, &mut stencils.to_vec(), &mut vertices.to_vec());
                continue;
            }
            open_stencils.extend_from_slice(stencils);
            open_vertices.extend_from_slice(vertices);
            if open_stencils.len() >= min_stencils {
                close(&mut packs, &mut open_stencils, &mut open_vertices);
            }
        }
        close(&mut packs, &mut open_stencils, &mut open_vertices);
        if packs.stencils.is_empty() {
            return Islands::default();
        }
        packs
    }

    /// Island `k`'s stencils: indices into the active list, ascending.
    pub fn stencils_of(&self, k: usize) -> &[u32] {
        &self.stencils[self.stencil_start[k] as usize..self.stencil_start[k + 1] as usize]
    }

    /// Island `k`'s dynamic vertices, ascending.
    pub fn vertices_of(&self, k: usize) -> &[u32] {
        &self.vertices[self.vertex_start[k] as usize..self.vertex_start[k + 1] as usize]
    }
}
