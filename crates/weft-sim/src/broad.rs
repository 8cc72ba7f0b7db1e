//! Broad phase: candidate stencils of one window (`acm-spec.md` §4.2).
//!
//! Each triangle's leaf is a 26-DOP bounding every breakpoint of its three
//! vertices in the window (the convex hull of those points contains the swept
//! triangle), inflated by `eta_1 / 2` (the DOP adds its own rounding margin), so
//! two leaves overlap whenever their triangles come within `eta_1` at any time.
//! Self-traversal yields triangle pairs — including pairs that share a vertex or
//! an edge — and stencils are filtered at the stencil level: VF when the vertex
//! is not a corner of the face, EE when the edges share no vertex. Stencils whose
//! four vertices are all kinematic are dropped; keys are canonical input ids and
//! the result is sorted and deduplicated. Finally each stencil's two primitives
//! must have overlapping DOPs of their own (inflated likewise).

use weft_core::StencilKey;
use weft_geom::bvh::Bvh;
use weft_geom::dop::Dop26;

use crate::trajectory::Trajectories;

/// Reusable broad-phase workspace.
#[derive(Clone, Debug, Default)]
pub struct BroadPhase {
    vertex_dops: Vec<Dop26>,
    tri_dops: Vec<Dop26>,
    bvh: Option<Bvh>,
    pairs: Vec<(u32, u32)>,
    /// Triangle pairs found by the last pass.
    pub last_pairs: usize,
}

impl BroadPhase {
    /// Candidate stencils of the window whose trajectories are `traj`.
    pub fn candidates(
        &mut self,
        triangles: &[[u32; 3]],
        inv_mass: &[f64],
        traj: &Trajectories,
        inflate: f64,
    ) -> Vec<StencilKey> {
        self.vertex_dops.clear();
        for i in 0..traj.len() {
            let t = traj.of(i);
            let mut d = Dop26::empty();
            for &p in t.points {
                d.add_point(p);
            }
            self.vertex_dops.push(d);
        }
        self.tri_dops.clear();
        for t in triangles {
            let mut d = self.vertex_dops[t[0] as usize];
            d.merge(&self.vertex_dops[t[1] as usize]);
            d.merge(&self.vertex_dops[t[2] as usize]);
            d.inflate(inflate);
            self.tri_dops.push(d);
        }
        match &mut self.bvh {
            Some(b) if b.len() == self.tri_dops.len() => b.refit(&self.tri_dops),
            slot => *slot = Some(Bvh::build(&self.tri_dops)),
        }
        self.pairs.clear();
        if let Some(bvh) = &self.bvh {
            let pairs = &mut self.pairs;
            bvh.self_overlaps(|a, b| pairs.push((a, b)));
        }
        self.last_pairs = self.pairs.len();
        let mut keys = Vec::with_capacity(self.pairs.len() * 4);
        for &(a, b) in &self.pairs {
            stencils_of_pair(
                triangles[a as usize],
                triangles[b as usize],
                inv_mass,
                &mut keys,
            );
        }
        keys.sort_unstable();
        keys.dedup();
        // Stencil-level filter: the two primitives' own DOPs must overlap.
        let vd = &self.vertex_dops;
        let hull = |ids: &[u32]| {
            let mut d = vd[ids[0] as usize];
            for &i in &ids[1..] {
                d.merge(&vd[i as usize]);
            }
            d.inflate(inflate);
            d
        };
        keys.retain(|k| {
            let split = match k.kind {
                weft_core::StencilKind::VertexFace => 1,
                weft_core::StencilKind::EdgeEdge => 2,
            };
            hull(&k.v[..split]).overlaps(&hull(&k.v[split..]))
        });
        keys
    }
}

/// Appends the VF and EE stencils between triangles `ta` and `tb`.
pub fn stencils_of_pair(ta: [u32; 3], tb: [u32; 3], inv_mass: &[f64], out: &mut Vec<StencilKey>) {
    let dynamic = |k: &StencilKey| k.v.iter().any(|&i| inv_mass[i as usize] > 0.0);
    let mut push = |k: StencilKey| {
        if !k.shares_vertex() && dynamic(&k) {
            out.push(k);
        }
    };
    for &p in &ta {
        push(StencilKey::vertex_face(p, tb));
    }
    for &p in &tb {
        push(StencilKey::vertex_face(p, ta));
    }
    for i in 0..3 {
        let ea = [ta[i], ta[(i + 1) % 3]];
        for j in 0..3 {
            push(StencilKey::edge_edge(ea, [tb[j], tb[(j + 1) % 3]]));
        }
    }
}
