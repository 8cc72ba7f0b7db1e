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

//!
//! # Two levels: within a partition, across partitions
//!
//! As in the paper (§III-B), collisions within a partition and among
//! partitions are found differently. The triangles are grouped — one group per
//! cloth partition, one for the obstacles ([`BroadPhase::grouped`]) — and each
//! group has a BVH of its own: its self-traversal finds the pairs within it.
//! Each group's root bound is its *window hull*; the overlapping hull pairs
//! come from a voxel grid ([`weft_geom::voxel::overlapping_pairs`]: exactly
//! the pairs whose hulls overlap), and a two-tree traversal of each such pair
//! finds the pairs across groups. A pair of overlapping leaves in two groups
//! has overlapping hulls (a hull is the exact `min` / `max` union of its
//! leaves), so together these report exactly the overlapping leaf pairs of one
//! tree over all triangles, for any grouping. One exception, which changes no
//! stencil: a group all of whose vertices are kinematic (the obstacles) skips
//! its self-traversal, whose stencils would all be dropped.
//!
//! # On an executor
//!
//! [`BroadPhase::candidates_on`] computes the vertex and triangle DOPs in fixed
//! runs of [`RUN`] elements (each element is a function of its inputs alone;
//! over ranks each vertex DOP, which reads every breakpoint of the vertex, is
//! computed by the rank holding them) and refits the groups' trees one group per task. The traversals are
//! split into node-pair tasks ([`Bvh::self_overlap_tasks_into`],
//! [`Bvh::cross_overlap_tasks_into`]), each group (pair) getting a share of
//! [`MIN_TASKS`] by its size, dealt to the ranks round robin (neighbouring
//! tasks cost alike, so contiguous blocks would be unbalanced); each task
//! generates the stencils of its triangle
//! pairs, applies the stencil-level filter to each as it is generated, and
//! sorts and deduplicates the survivors. The tasks' keys are then
//! concatenated, sorted and deduplicated. The filter is a pure function of the
//! key ([`primitives_overlap`]), so filtering before deduplication keeps the
//! same set.
//!
//! The filter reads DOPs inflated once per vertex instead of inflating each
//! primitive's hull, with the same answers bit for bit: per direction,
//! inflation maps `lo` to `next_down(lo - r)` and `hi` to `next_up(hi + r)`,
//! both monotone (rounding is monotone), and a monotone map commutes with `min`
//! / `max` — so the union of inflated non-empty DOPs *is* the inflated union
//! (`±0` round to the same `-r`; no NaN in a non-empty DOP; `r <= 0` or NaN
//! inflates nothing either way). A face's hull is then its triangle's leaf and an
//! edge's the union of its two inflated vertex DOPs. If some vertex DOP is empty
//! (non-finite positions) the filter falls back to [`primitives_overlap`].
//!
//! Over ranks with the groups placed ([`BroadPhase::spread`]), each rank
//! builds only its own groups' trees, the window hulls are all-gathered,
//! and each traversal runs whole on one rank, which builds the other side's
//! tree too (`spread_candidates`); the vertex DOPs travel point to point from
//! the ranks holding the vertices to those whose trees read them.
//!
//! Which task finds a pair, and in which order tasks run, changes nothing: the
//! result is the sorted set of keys, the same on every executor, for every
//! grouping, and as a serial pass.

use std::collections::BTreeMap;

use weft_core::{StencilKey, StencilKind};
use weft_geom::bvh::Bvh;
use weft_geom::dop::Dop26;
use weft_geom::voxel::overlapping_pairs;

use crate::executor::{CommError, Executor, Serial};
use crate::trajectory::Trajectories;

/// Vertices (or triangles) per DOP task.
pub const RUN: usize = 1024;

/// Traversal tasks requested in all (8 × 64: many more than threads, so work
/// stealing evens out their unequal sizes), shared among the groups and the
/// group pairs by size.
pub const MIN_TASKS: usize = 512;

/// Reusable broad-phase workspace.
#[derive(Clone, Debug, Default)]
pub struct BroadPhase {
    /// group of each triangle as given to [`BroadPhase::grouped`] (empty: one
    /// group).
    labels: Vec<u32>,
    /// the groups' trees, built on the first pass over a mesh.
    groups: Vec<Group>,
    /// per vertex: the DOP of its breakpoints, and that DOP inflated. Spread
    /// over ranks, per slot of `dop_slot`: only the vertices a rank holds or
    /// received.
    vertex_dops: Vec<[Dop26; 2]>,
    /// Spread over ranks: per vertex, its place in `vertex_dops`
    /// ([`NO_DOP`]: not here this pass). Empty on one memory.
    dop_slot: Vec<u32>,
    tri_dops: Vec<Dop26>,
    /// chunk bounds of the current parallel step.
    bounds: Vec<usize>,
    /// traversal tasks, and the rank each runs on.
    tasks: Vec<Task>,
    owners: Vec<u32>,
    /// Triangle pairs found by the last pass.
    pub last_pairs: usize,
    /// Overlapping group pairs (window hulls) of the last pass.
    pub last_group_pairs: Vec<(u32, u32)>,
    /// Over ranks, the rank of each label (a partition's home rank; a label
    /// past the end, such as `NONE` for the obstacles, goes to the last
    /// rank). Empty: every rank builds every tree.
    label_ranks: Vec<u32>,
    /// Groups whose leaves and tree this rank computed in the last pass (all
    /// of them on one memory; over ranks with [`BroadPhase::spread`], its own
    /// and those its traversals pair with them).
    pub last_trees: usize,
}

/// The triangles of one group and their tree.
#[derive(Clone, Debug, Default)]
struct Group {
    /// the label its triangles carry.
    label: u32,
    /// triangle ids, ascending (tree leaf `i` is triangle `members[i]`).
    members: Vec<u32>,
    /// every vertex of every member is kinematic (set every pass).
    kinematic: bool,
    /// the members' leaves of this pass, in member order.
    leaves: Vec<Dop26>,
    bvh: Bvh,
}

/// A traversal task: node pair `nodes` of group `a`'s tree with itself
/// (`a == b`) or with group `b`'s tree.
#[derive(Clone, Copy, Debug)]
struct Task {
    a: u32,
    b: u32,
    nodes: (u32, u32),
}

/// What one traversal task found.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct TaskOut {
    /// its filtered stencil keys, sorted and deduplicated.
    keys: Vec<StencilKey>,
    /// triangle pairs it found.
    pairs: usize,
}

impl BroadPhase {
    /// A workspace whose triangles are grouped by `labels` (one label per
    /// triangle: its partition, or `NONE` for an obstacle triangle). Any
    /// grouping gives the same candidates; a group is the unit of the local
    /// trees and of the window hulls.
    pub fn grouped(labels: &[u32]) -> Self {
        Self {
            labels: labels.to_vec(),
            ..Self::default()
        }
    }

    /// Over ranks: each group's leaves and tree are computed by the rank of
    /// its label (`label_ranks[label]`, a partition's home rank; labels past
    /// the end go to the last rank), and by the ranks whose traversals pair
    /// a group of theirs with it; the window hulls are all-gathered.
    /// Without it (or on one memory) every rank builds every tree.
    pub fn spread(&mut self, label_ranks: Vec<u32>) {
        self.label_ranks = label_ranks;
    }

    /// Candidate stencils of the window whose trajectories are `traj`, on the
    /// calling thread (`candidates_on(&Serial, ..)`).
    pub fn candidates(
        &mut self,
        triangles: &[[u32; 3]],
        inv_mass: &[f64],
        traj: &Trajectories,
        inflate: f64,
    ) -> Vec<StencilKey> {
        self.candidates_on(&Serial, triangles, inv_mass, traj, inflate)
            .expect("one memory: no rank to lose")
    }

    /// Candidate stencils of the window whose trajectories are `traj`, computed
    /// on `exec`: sorted, deduplicated, the same on every executor.
    ///
    /// The vertex DOPs (each on the rank holding the vertex's breakpoints)
    /// and the traversal tasks (round robin) are spread over the ranks
    /// ([`Executor::map_on_ranks`]); the triangle DOPs, the trees and the
    /// voxel grid are computed on every rank, unless the groups were given
    /// ranks ([`BroadPhase::spread`]): then a rank builds only its groups'
    /// trees and those its traversals pair with them.
    ///
    /// # Panics
    /// If the workspace was [`grouped`](BroadPhase::grouped) with a label
    /// count other than `triangles.len()`.
    pub fn candidates_on<E: Executor>(
        &mut self,
        exec: &E,
        triangles: &[[u32; 3]],
        inv_mass: &[f64],
        traj: &Trajectories,
        inflate: f64,
    ) -> Result<Vec<StencilKey>, CommError> {
        assert!(
            self.labels.is_empty() || self.labels.len() == triangles.len(),
            "broad phase grouped for {} triangles, called with {}",
            self.labels.len(),
            triangles.len()
        );
        let leaf_count: usize = self.groups.iter().map(|g| g.members.len()).sum();
        if leaf_count != triangles.len() {
            self.groups = make_groups(&self.labels, triangles.len());
        }
        let Self {
            labels: _,
            groups,
            vertex_dops,
            dop_slot,
            tri_dops,
            bounds,
            tasks,
            owners,
            last_pairs,
            last_group_pairs,
            label_ranks,
            last_trees,
        } = self;

        if exec.ranks() > 1 && !label_ranks.is_empty() && groups.len() > 1 {
            let input = Input {
                triangles,
                inv_mass,
                traj,
                inflate,
            };
            let dops = (vertex_dops, dop_slot);
            let found = spread_candidates(exec, groups, label_ranks, &input, dops, bounds)?;
            (*last_trees, *last_pairs, *last_group_pairs) =
                (found.trees, found.pairs, found.group_pairs);
            return Ok(found.keys);
        }

        // Vertex DOPs: every breakpoint of the vertex in the window. Over
        // ranks each vertex's DOP is computed by the rank that holds its
        // breakpoints (the one step that reads them all), and every rank gets
        // every DOP with its exact bits; the inflated copies are made locally.
        let raw = exec.map_on_ranks(traj.len(), traj.holders(), &|i| {
            Dop26::from_points(traj.of(i).points.iter().copied())
        })?;
        runs(traj.len(), bounds);
        vertex_dops.resize(traj.len(), [Dop26::empty(); 2]);
        let raw: &[Dop26] = &raw;
        exec.for_each_chunk(vertex_dops, bounds, &|k, chunk: &mut [[Dop26; 2]]| {
            for (&raw, d) in raw[k * RUN..].iter().zip(chunk.iter_mut()) {
                *d = raw_and_inflated(raw, inflate);
            }
        });
        dop_slot.clear();
        let vd: &[[Dop26; 2]] = vertex_dops;
        let filter = Filter {
            triangles,
            inv_mass,
            vertex_dops: VertexDops {
                dops: vd,
                slot: &[],
            },
            inflate,
            exact_unions: !vd.iter().any(|d| d[0].is_empty()),
        };

        // Triangle DOPs: the union of the corners', inflated.
        tri_dops.resize(triangles.len(), Dop26::empty());
        runs(triangles.len(), bounds);
        exec.for_each_chunk(tri_dops, bounds, &|k, chunk: &mut [Dop26]| {
            for (t, d) in triangles[k * RUN..].iter().zip(chunk.iter_mut()) {
                *d = filter.leaf(*t);
            }
        });

        // Each group's tree: built on the first pass, refitted after.
        let td: &[Dop26] = tri_dops;
        bounds.clear();
        bounds.extend(0..=groups.len());
        exec.for_each_chunk(groups, bounds, &|_, chunk: &mut [Group]| {
            chunk[0].update(&filter, |t| td[t as usize]);
        });
        *last_trees = groups.len();

        // Window hulls, their overlapping pairs, and the traversal tasks.
        let hulls: Vec<Dop26> = groups.iter().map(|g| g.bvh.root_bounds()).collect();
        *last_group_pairs = overlapping_pairs(&hulls);
        make_tasks(groups, last_group_pairs, triangles.len(), tasks);

        let n = tasks.len();
        let (groups, tasks): (&[Group], &[Task]) = (groups, tasks);
        // Task costs differ by orders of magnitude (a partition's own pairs
        // against a pair of partitions that barely touch) and neighbouring
        // tasks are alike, so over ranks they are dealt round robin.
        owners.clear();
        owners.extend((0..n).map(|k| (k % exec.ranks()) as u32));
        let outs = exec.map_on_ranks(n, owners, &|k| {
            let Task { a, b, nodes } = tasks[k];
            let (ga, gb) = (&groups[a as usize], &groups[b as usize]);
            let mut out = TaskOut::default();
            let mut found = |i: u32, j: u32| filter.found(ga, i, gb, j, &mut out);
            if a == b {
                ga.bvh.overlaps_from(nodes, &mut found);
            } else {
                ga.bvh.overlaps_with_from(&gb.bvh, nodes, &mut found);
            }
            out.finish()
        })?;
        let found = merge(outs);
        *last_pairs = found.pairs;
        Ok(found.keys)
    }
}

/// What a broad-phase pass found.
#[derive(Default)]
struct Found {
    keys: Vec<StencilKey>,
    pairs: usize,
    trees: usize,
    group_pairs: Vec<(u32, u32)>,
}

/// The tasks' keys concatenated, sorted and deduplicated (concatenated
/// sorted runs: the stable sort merges them), and their pair count.
fn merge(outs: Vec<TaskOut>) -> Found {
    let pairs = outs.iter().map(|o| o.pairs).sum();
    let mut keys = Vec::with_capacity(outs.iter().map(|o| o.keys.len()).sum());
    for o in &outs {
        keys.extend_from_slice(&o.keys);
    }
    keys.sort();
    keys.dedup();
    Found {
        keys,
        pairs,
        ..Found::default()
    }
}

/// A vertex's DOP as the filter keeps it: raw, and inflated by `inflate`.
fn raw_and_inflated(raw: Dop26, inflate: f64) -> [Dop26; 2] {
    let mut inflated = raw;
    inflated.inflate(inflate);
    [raw, inflated]
}

/// What the spread broad phase reads of the window.
struct Input<'a> {
    triangles: &'a [[u32; 3]],
    inv_mass: &'a [f64],
    traj: &'a Trajectories,
    inflate: f64,
}

impl<'a> Input<'a> {
    /// The filter over `vertex_dops`.
    fn filter(&self, vertex_dops: VertexDops<'a>, exact_unions: bool) -> Filter<'a> {
        Filter {
            triangles: self.triangles,
            inv_mass: self.inv_mass,
            vertex_dops,
            inflate: self.inflate,
            exact_unions,
        }
    }
}

/// A vertex DOP as it travels: the vertex and its raw DOP.
type VertexDop = (u32, Dop26);

/// A vertex without a DOP on this rank this pass (`BroadPhase::dop_slot`).
const NO_DOP: u32 = u32::MAX;

/// The vertex DOPs (raw and inflated) a filter reads: per vertex, or, with
/// `slot` (spread over ranks), at each vertex's slot.
#[derive(Clone, Copy)]
struct VertexDops<'a> {
    dops: &'a [[Dop26; 2]],
    slot: &'a [u32],
}

impl<'a> VertexDops<'a> {
    /// Vertex `v`'s DOPs. A vertex with no DOP here ([`NO_DOP`]) is a bug
    /// (what no one sent must not be read): the index panics.
    #[inline]
    fn of(&self, v: u32) -> &'a [Dop26; 2] {
        match self.slot {
            [] => &self.dops[v as usize],
            slot => &self.dops[slot[v as usize] as usize],
        }
    }
}

/// The broad phase spread over ranks ([`BroadPhase::spread`]).
///
/// 1. Each rank computes the DOPs of the vertices whose breakpoints it
///    holds, and sends each rank those of its vertices that rank's own
///    groups' triangles use (an all-to-all; whether any DOP is empty travels
///    in its head, so every rank filters alike).
/// 2. Each rank computes the leaves and the tree of its own groups.
/// 3. The window hulls (each group's root bound) and kinematic flags are
///    all-gathered: every rank finds the same overlapping pairs.
/// 4. Each traversal — a group with itself, or an overlapping pair — runs
///    whole on one rank: a group's self-traversal on its rank; a pair on the
///    rank of its dynamic side if the other is kinematic (the obstacles pair
///    with many groups), else on the rank of `a` or `b` by the parity of
///    `a + b`. Every rank knows every traversal's rank, so the holders send
///    a traversal's rank the DOPs of the other side's vertices point to
///    point (an all-to-all), and it computes that side's leaves and tree.
/// 5. The traversals' keys reach every rank, as on one memory.
///
/// A rank so computes the trees of its own groups and their overlapping
/// neighbours', not all of them, and receives only the vertex DOPs those
/// read. The candidates are the same set: the pairs of overlapping hulls
/// and the leaves of each tree are those of one memory, whoever computes
/// them. A rank's `vertex_dops` hold this pass's DOP only for the vertices
/// it holds or received; the others are never read.
fn spread_candidates<E: Executor>(
    exec: &E,
    groups: &mut [Group],
    label_ranks: &[u32],
    input: &Input<'_>,
    (vertex_dops, dop_slot): (&mut Vec<[Dop26; 2]>, &mut Vec<u32>),
    bounds: &mut Vec<usize>,
) -> Result<Found, CommError> {
    let (me, ranks) = (exec.rank() as u32, exec.ranks());
    let last = ranks as u32 - 1;
    let rank: Vec<u32> = (groups.iter())
        .map(|g| {
            label_ranks
                .get(g.label as usize)
                .copied()
                .unwrap_or(last)
                .min(last)
        })
        .collect();
    let (traj, triangles) = (input.traj, input.triangles);
    // 1. The held vertices' DOPs, then those the own groups use. A rank
    // keeps DOPs only for the vertices it holds or receives: the held ones
    // first, in vertex order, then each received one at the next slot.
    let n = traj.len();
    let held: Vec<u32> = (0..n as u32).filter(|&i| traj.holds(i as usize)).collect();
    dop_slot.clear();
    dop_slot.resize(n, NO_DOP);
    for (k, &v) in held.iter().enumerate() {
        dop_slot[v as usize] = k as u32;
    }
    vertex_dops.clear();
    vertex_dops.resize(held.len(), [Dop26::empty(); 2]);
    runs(held.len(), bounds);
    let inflate = input.inflate;
    exec.for_each_chunk(vertex_dops, bounds, &|k, chunk: &mut [[Dop26; 2]]| {
        for (&v, d) in held[k * RUN..].iter().zip(chunk.iter_mut()) {
            let raw = Dop26::from_points(traj.of(v as usize).points.iter().copied());
            *d = raw_and_inflated(raw, inflate);
        }
    });
    let held_empty = vertex_dops.iter().any(|d| d[0].is_empty());
    // The DOPs this rank holds of the vertices of a group's triangles, to `r`.
    let send_group = |sends: &mut [Vec<u32>], group: &Group, r: u32| {
        for &t in &group.members {
            for &v in &triangles[t as usize] {
                if traj.holds(v as usize) {
                    sends[r as usize].push(v);
                }
            }
        }
    };
    let mut sends = vec![Vec::new(); ranks];
    for g in 0..groups.len() {
        if rank[g] != me {
            send_group(&mut sends, &groups[g], rank[g]);
        }
    }
    let heads = deliver_dops(
        exec,
        vec![u64::from(held_empty)],
        sends,
        (vertex_dops, dop_slot),
        inflate,
    )?;
    let exact_unions = !heads.iter().any(|h| h.first() != Some(&0));
    // 2. The own groups' trees.
    {
        let dops = VertexDops {
            dops: vertex_dops,
            slot: dop_slot,
        };
        let filter = input.filter(dops, exact_unions);
        let direct = |t: u32| filter.leaf(filter.triangles[t as usize]);
        bounds.clear();
        bounds.extend(0..=groups.len());
        exec.for_each_chunk(groups, bounds, &|g, chunk: &mut [Group]| {
            if rank[g] == me {
                chunk[0].update(&filter, direct);
            }
        });
    }
    // 3. The hulls.
    let gathered = {
        let groups: &[Group] = groups;
        exec.map_on_ranks(groups.len(), &rank, &|g| {
            (groups[g].bvh.root_bounds(), groups[g].kinematic)
        })?
    };
    let hulls: Vec<Dop26> = gathered.iter().map(|h| h.0).collect();
    let kinematic: Vec<bool> = gathered.iter().map(|h| h.1).collect();
    let group_pairs = overlapping_pairs(&hulls);
    // 4. The traversals: (a, b), a == b for a group with itself, and the rank
    // each runs on.
    let mut items: Vec<(u32, u32)> = Vec::new();
    let mut owner: Vec<u32> = Vec::new();
    for g in 0..groups.len() {
        if !kinematic[g] {
            items.push((g as u32, g as u32));
            owner.push(rank[g]);
        }
    }
    for &(a, b) in &group_pairs {
        let (ka, kb) = (kinematic[a as usize], kinematic[b as usize]);
        if ka && kb {
            continue;
        }
        let side = if ka || (!kb && (a + b) % 2 == 1) {
            b
        } else {
            a
        };
        items.push((a, b));
        owner.push(rank[side as usize]);
    }
    // The other sides of each rank's traversals: the holders send their
    // vertices' DOPs there, and this rank computes the leaves and trees of
    // its own traversals' other sides.
    let mut needed = vec![false; groups.len()];
    let mut sends = vec![Vec::new(); ranks];
    let mut sent = std::collections::BTreeSet::new();
    for (&(a, b), &r) in items.iter().zip(&owner) {
        for g in [a, b] {
            if rank[g as usize] == r {
                continue;
            }
            if r == me {
                needed[g as usize] = true;
            } else if sent.insert((r, g)) {
                send_group(&mut sends, &groups[g as usize], r);
            }
        }
    }
    deliver_dops(exec, Vec::new(), sends, (vertex_dops, dop_slot), inflate)?;
    let dops = VertexDops {
        dops: vertex_dops,
        slot: dop_slot,
    };
    let filter = input.filter(dops, exact_unions);
    let direct = |t: u32| filter.leaf(filter.triangles[t as usize]);
    bounds.clear();
    bounds.extend(0..=groups.len());
    exec.for_each_chunk(groups, bounds, &|g, chunk: &mut [Group]| {
        if needed[g] {
            chunk[0].update(&filter, direct);
        }
    });
    let trees = (0..groups.len())
        .filter(|&g| rank[g] == me || needed[g])
        .count();
    let groups: &[Group] = groups;
    let filter = &filter;
    let outs = exec.map_on_ranks(items.len(), &owner, &|k| {
        let (a, b) = items[k];
        let (ga, gb) = (&groups[a as usize], &groups[b as usize]);
        let mut out = TaskOut::default();
        let mut found = |i: u32, j: u32| filter.found(ga, i, gb, j, &mut out);
        if a == b {
            ga.bvh.self_overlaps(&mut found);
        } else {
            ga.bvh.overlaps_with(&gb.bvh, &mut found);
        }
        out.finish()
    })?;
    Ok(Found {
        trees,
        group_pairs,
        ..merge(outs)
    })
}

/// **Collective** (an all-to-all): sends each rank `r` the raw DOPs of the
/// vertices `sends[r]` (held here; deduplicated here), with `head` to every
/// rank, and stores the DOPs received (raw and inflated by `inflate`) in
/// `vertex_dops`, each at its vertex's slot (a new one at the end for a
/// vertex first received). Returns every rank's head.
fn deliver_dops<E: Executor>(
    exec: &E,
    head: Vec<u64>,
    sends: Vec<Vec<u32>>,
    (vertex_dops, dop_slot): (&mut Vec<[Dop26; 2]>, &mut [u32]),
    inflate: f64,
) -> Result<Vec<Vec<u64>>, CommError> {
    let me = exec.rank();
    let parts: Vec<Option<Vec<VertexDop>>> = (sends.into_iter().enumerate())
        .map(|(r, mut list)| {
            list.sort_unstable();
            list.dedup();
            let dops = (list.iter()).map(|&v| (v, vertex_dops[dop_slot[v as usize] as usize][0]));
            (r != me && !list.is_empty()).then(|| dops.collect())
        })
        .collect();
    let (heads, received) = exec.all_to_all(head, parts, &mut || false)?;
    for (r, part) in received.into_iter().enumerate() {
        if r == me {
            continue;
        }
        for (v, raw) in part.into_iter().flatten() {
            let slot = dop_slot.get_mut(v as usize).ok_or_else(|| {
                CommError(format!(
                    "rank {me}: rank {r} sent the DOP of vertex {v}, past the end"
                ))
            })?;
            if *slot == NO_DOP {
                *slot = vertex_dops.len() as u32;
                vertex_dops.push([Dop26::empty(); 2]);
            }
            vertex_dops[*slot as usize] = raw_and_inflated(raw, inflate);
        }
    }
    Ok(heads)
}

impl Group {
    /// This pass's leaves (`leaf(t)` for each member `t`), kinematic flag and
    /// tree: built on the first pass, refitted after.
    fn update(&mut self, filter: &Filter, leaf: impl Fn(u32) -> Dop26) {
        let (triangles, inv_mass) = (filter.triangles, filter.inv_mass);
        self.kinematic = self.members.iter().all(|&t| {
            triangles[t as usize]
                .iter()
                .all(|&v| inv_mass[v as usize] <= 0.0)
        });
        self.leaves.clear();
        self.leaves.extend(self.members.iter().map(|&t| leaf(t)));
        if self.bvh.len() == self.leaves.len() {
            self.bvh.refit(&self.leaves);
        } else {
            self.bvh = Bvh::build(&self.leaves);
        }
    }
}

impl TaskOut {
    /// Sorted and deduplicated.
    fn finish(mut self) -> Self {
        self.keys.sort_unstable();
        self.keys.dedup();
        self
    }
}

/// The groups of `labels` (one group per distinct label, in label order; all
/// `triangles` in one group when `labels` is empty), with empty trees.
fn make_groups(labels: &[u32], triangles: usize) -> Vec<Group> {
    let mut by_label: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for t in 0..triangles {
        let label = labels.get(t).copied().unwrap_or(0);
        by_label.entry(label).or_default().push(t as u32);
    }
    by_label
        .into_iter()
        .map(|(label, members)| Group {
            label,
            members,
            ..Group::default()
        })
        .collect()
}

/// The traversal tasks of one pass: each group's self-traversal (skipped for
/// a kinematic group) and each overlapping group pair's two-tree traversal
/// (skipped when both are kinematic), split into node-pair tasks — a share of
/// [`MIN_TASKS`] proportional to the group's size, or to the smaller group's
/// for a pair (a traversal of two trees descends no deeper than the smaller).
fn make_tasks(groups: &[Group], pairs: &[(u32, u32)], leaves: usize, tasks: &mut Vec<Task>) {
    tasks.clear();
    let share = |n: usize| (MIN_TASKS * n).div_ceil(leaves.max(1));
    let mut nodes = Vec::new();
    for (g, group) in groups.iter().enumerate() {
        if group.kinematic {
            continue;
        }
        group
            .bvh
            .self_overlap_tasks_into(share(group.members.len()), &mut nodes);
        let g = g as u32;
        tasks.extend(nodes.iter().map(|&nodes| Task { a: g, b: g, nodes }));
    }
    for &(a, b) in pairs {
        let (ga, gb) = (&groups[a as usize], &groups[b as usize]);
        if ga.kinematic && gb.kinematic {
            continue;
        }
        let smaller = ga.members.len().min(gb.members.len());
        ga.bvh
            .cross_overlap_tasks_into(&gb.bvh, share(smaller), &mut nodes);
        tasks.extend(nodes.iter().map(|&nodes| Task { a, b, nodes }));
    }
}

/// Chunk bounds of `n` elements in runs of [`RUN`].
fn runs(n: usize, bounds: &mut Vec<usize>) {
    bounds.clear();
    bounds.extend((0..n).step_by(RUN));
    bounds.push(n);
}

/// What generating and filtering a triangle pair's stencils reads.
struct Filter<'a> {
    triangles: &'a [[u32; 3]],
    inv_mass: &'a [f64],
    /// per vertex: raw and inflated DOP.
    vertex_dops: VertexDops<'a>,
    inflate: f64,
    /// every vertex DOP is non-empty: unions of inflated DOPs are the
    /// inflated unions (module documentation).
    exact_unions: bool,
}

impl Filter<'_> {
    /// Triangle `t`'s leaf: the union of its corners' DOPs, inflated.
    #[inline]
    fn leaf(&self, t: [u32; 3]) -> Dop26 {
        let vd = self.vertex_dops;
        let mut d = vd.of(t[0])[0];
        d.merge(&vd.of(t[1])[0]);
        d.merge(&vd.of(t[2])[0]);
        d.inflate(self.inflate);
        d
    }

    /// A traversal found leaves `i` of `ga` and `j` of `gb` overlapping:
    /// their triangles' stencils that pass the filter go to `out`.
    #[inline]
    fn found(&self, ga: &Group, i: u32, gb: &Group, j: u32, out: &mut TaskOut) {
        let (i, j) = (i as usize, j as usize);
        out.pairs += 1;
        let (ta, tb) = (ga.members[i] as usize, gb.members[j] as usize);
        self.stencils_of_pair(ta, tb, [&ga.leaves[i], &gb.leaves[j]], &mut out.keys);
    }

    /// Appends the stencils of [`stencils_of_pair`] between triangles `a` and
    /// `b` (whose leaves are `leaves`) that pass [`primitives_overlap`] (same
    /// answers, cheaper DOPs).
    #[inline]
    fn stencils_of_pair(&self, a: usize, b: usize, leaves: [&Dop26; 2], out: &mut Vec<StencilKey>) {
        let (ta, tb) = (self.triangles[a], self.triangles[b]);
        let vd = self.vertex_dops;
        let keep = |k: &StencilKey| {
            !k.shares_vertex() && k.v.iter().any(|&i| self.inv_mass[i as usize] > 0.0)
        };
        if !self.exact_unions {
            let start = out.len();
            stencils_of_pair(ta, tb, self.inv_mass, out);
            let mut k = start;
            for i in start..out.len() {
                if primitives_overlap_by(|v| &vd.of(v)[0], &out[i], self.inflate) {
                    out[k] = out[i];
                    k += 1;
                }
            }
            out.truncate(k);
            return;
        }
        // The cheap necessary conditions (no shared vertex, DOPs overlap) first;
        // all are pure and conjunctive, so the order changes nothing.
        for (tv, face, fd) in [(ta, tb, leaves[1]), (tb, ta, leaves[0])] {
            for &p in &tv {
                if !face.contains(&p) && overlap(&vd.of(p)[1], fd) {
                    let k = StencilKey::vertex_face(p, face);
                    if keep(&k) {
                        out.push(k);
                    }
                }
            }
        }
        for i in 0..3 {
            let ea = [ta[i], ta[(i + 1) % 3]];
            for j in 0..3 {
                let eb = [tb[j], tb[(j + 1) % 3]];
                if !eb.contains(&ea[0])
                    && !eb.contains(&ea[1])
                    && unions_overlap(
                        [&vd.of(ea[0])[1], &vd.of(ea[1])[1]],
                        [&vd.of(eb[0])[1], &vd.of(eb[1])[1]],
                    )
                {
                    let k = StencilKey::edge_edge(ea, eb);
                    if keep(&k) {
                        out.push(k);
                    }
                }
            }
        }
    }
}

/// `(a[0] ∪ a[1]).overlaps(b[0] ∪ b[1])` without building the unions; stops
/// at the first separating direction (most candidates are separated).
#[inline]
fn unions_overlap(a: [&Dop26; 2], b: [&Dop26; 2]) -> bool {
    (0..13).all(|k| {
        let (alo, ahi) = (a[0].lo[k].min(a[1].lo[k]), a[0].hi[k].max(a[1].hi[k]));
        let (blo, bhi) = (b[0].lo[k].min(b[1].lo[k]), b[0].hi[k].max(b[1].hi[k]));
        alo <= bhi && blo <= ahi
    })
}

/// `a.overlaps(b)`, stopping at the first separating direction.
#[inline]
fn overlap(a: &Dop26, b: &Dop26) -> bool {
    (0..13).all(|k| a.lo[k] <= b.hi[k] && b.lo[k] <= a.hi[k])
}

/// The stencil-level filter: the DOPs of the stencil's two primitives (the
/// union of their vertices' DOPs, inflated by `inflate`) overlap.
pub fn primitives_overlap(vertex_dops: &[Dop26], key: &StencilKey, inflate: f64) -> bool {
    primitives_overlap_by(|i| &vertex_dops[i as usize], key, inflate)
}

/// [`primitives_overlap`] with vertex `i`'s DOP given by `dop(i)`.
fn primitives_overlap_by<'a>(
    dop: impl Fn(u32) -> &'a Dop26,
    key: &StencilKey,
    inflate: f64,
) -> bool {
    let hull = |ids: &[u32]| {
        let mut d = *dop(ids[0]);
        for &i in &ids[1..] {
            d.merge(dop(i));
        }
        d.inflate(inflate);
        d
    };
    let split = match key.kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    };
    hull(&key.v[..split]).overlaps(&hull(&key.v[split..]))
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use weft_geom::shapes::grid;
    use weft_testkit::Rng;

    /// An executor that runs chunks and map items last first (results still in
    /// index order): the broad phase must not depend on the order of tasks.
    struct Backwards;

    impl Executor for Backwards {
        fn for_each_chunk<T: Send>(
            &self,
            data: &mut [T],
            bounds: &[usize],
            task: &(dyn Fn(usize, &mut [T]) + Sync),
        ) {
            let chunks = crate::executor::split_chunks(data, bounds);
            for (k, chunk) in chunks.into_iter().rev() {
                task(k, chunk);
            }
        }

        fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
            let mut out: Vec<R> = (0..n).rev().map(f).collect();
            out.reverse();
            out
        }

        fn name(&self) -> String {
            "backwards".into()
        }
    }

    /// A crumpled `res × res` grid (folded over itself so distant triangles come
    /// close) with `steps` breakpoints per vertex; some vertices kinematic.
    fn crumpled(seed: u64, res: usize, steps: usize) -> (Vec<[u32; 3]>, Vec<f64>, Trajectories) {
        crumpled_with(seed, res, steps, &[])
    }

    /// [`crumpled`] with the vertices in `poison` at non-finite positions and
    /// without breakpoints (their DOPs are empty).
    fn crumpled_with(
        seed: u64,
        res: usize,
        steps: usize,
        poison: &[usize],
    ) -> (Vec<[u32; 3]>, Vec<f64>, Trajectories) {
        let mesh = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [1.0, 1.0], [res, res]);
        let mut rng = Rng(seed);
        let x: Vec<DVec3> = mesh
            .positions
            .iter()
            .map(|p| {
                // fold along x = 0 onto itself with a small gap, plus noise
                let fold = if p.x > 0.0 {
                    DVec3::new(-p.x, p.y, 0.02 + 0.3 * p.x * p.x)
                } else {
                    *p
                };
                fold + rng.vec(0.01)
            })
            .collect();
        let mut x = x;
        for (n, &i) in poison.iter().enumerate() {
            x[i] = DVec3::splat([f64::NAN, f64::INFINITY][n % 2]);
        }
        let inv_mass: Vec<f64> = (0..x.len())
            .map(|i| if i % 13 < 3 { 0.0 } else { 1.0 })
            .collect();
        let mut traj = Trajectories::new(x.len(), usize::MAX);
        traj.begin(0, &x);
        for s in 1..=steps {
            for (i, p) in x.iter().enumerate() {
                if rng.below(3) > 0 && !poison.contains(&i) {
                    let q = *p + rng.vec(0.004) * s as f64;
                    traj.record(i, 100 * s as u64, q).unwrap();
                }
            }
        }
        (mesh.triangles, inv_mass, traj)
    }

    /// The oracle: every pair of triangles whose inflated DOPs (over all their
    /// corners' breakpoints) overlap, tested pairwise; their stencils; the
    /// primitive-level filter.
    fn brute_force(
        triangles: &[[u32; 3]],
        inv_mass: &[f64],
        traj: &Trajectories,
        inflate: f64,
    ) -> (Vec<StencilKey>, usize) {
        let vd: Vec<Dop26> = (0..traj.len())
            .map(|i| Dop26::from_points(traj.of(i).points.iter().copied()))
            .collect();
        let td: Vec<Dop26> = triangles
            .iter()
            .map(|t| {
                let mut d = Dop26::from_points(
                    t.iter()
                        .flat_map(|&v| traj.of(v as usize).points.iter().copied()),
                );
                d.inflate(inflate);
                d
            })
            .collect();
        let mut keys = Vec::new();
        let mut pairs = 0;
        for a in 0..triangles.len() {
            for b in a + 1..triangles.len() {
                if td[a].overlaps(&td[b]) {
                    pairs += 1;
                    stencils_of_pair(triangles[a], triangles[b], inv_mass, &mut keys);
                }
            }
        }
        keys.retain(|k| primitives_overlap(&vd, k, inflate));
        keys.sort_unstable();
        keys.dedup();
        (keys, pairs)
    }

    #[test]
    fn matches_brute_force_on_any_executor() {
        let mut total = 0;
        for (seed, res, steps, inflate) in [(1, 12, 2, 0.01), (2, 24, 3, 0.02), (3, 40, 1, 0.005)] {
            let (tris, inv_mass, traj) = crumpled(seed, res, steps);
            let (expected, pairs) = brute_force(&tris, &inv_mass, &traj, inflate);
            total += expected.len();
            // a fresh workspace, then one reused with another mesh's buffers in it
            let mut reused = BroadPhase::default();
            let (t2, m2, tr2) = crumpled(seed + 100, 9, 2);
            reused
                .candidates_on(&Backwards, &t2, &m2, &tr2, inflate)
                .unwrap();
            for (name, got, bp) in [
                {
                    let mut bp = BroadPhase::default();
                    let got = bp.candidates(&tris, &inv_mass, &traj, inflate);
                    ("serial", got, bp)
                },
                {
                    let mut bp = BroadPhase::default();
                    let got = bp
                        .candidates_on(&Backwards, &tris, &inv_mass, &traj, inflate)
                        .unwrap();
                    ("backwards", got, bp)
                },
                {
                    let got = reused
                        .candidates_on(&Backwards, &tris, &inv_mass, &traj, inflate)
                        .unwrap();
                    ("reused", got, reused.clone())
                },
            ] {
                assert_eq!(got, expected, "{name}: res {res}");
                assert_eq!(bp.last_pairs, pairs, "{name}: res {res}");
            }
            // refit path: same mesh, new trajectories
            let (_, _, moved) = crumpled(seed + 7, res, steps);
            let mut bp = BroadPhase::default();
            bp.candidates(&tris, &inv_mass, &traj, inflate);
            assert_eq!(
                bp.candidates_on(&Backwards, &tris, &inv_mass, &moved, inflate)
                    .unwrap(),
                brute_force(&tris, &inv_mass, &moved, inflate).0
            );
        }
        assert!(total > 1000, "scenes too sparse ({total} candidates)");
    }

    #[test]
    fn any_grouping_gives_the_same_candidates() {
        use weft_core::NONE;
        for (seed, res, steps, inflate) in [(5, 16, 2, 0.01), (6, 30, 2, 0.02)] {
            let (tris, mut inv_mass, traj) = crumpled(seed, res, steps);
            // an obstacle: the first rows of triangles kinematic
            for t in &tris[..4 * res] {
                for &v in t {
                    inv_mass[v as usize] = 0.0;
                }
            }
            let (expected, pairs) = brute_force(&tris, &inv_mass, &traj, inflate);
            let mut rng = Rng(seed);
            let kinematic = |t: &[u32; 3]| t.iter().all(|&v| inv_mass[v as usize] <= 0.0);
            let groupings: Vec<(&str, Vec<u32>)> = vec![
                (
                    "blocks of 7",
                    (0..tris.len() as u32).map(|t| t / 7).collect(),
                ),
                (
                    "random of 5",
                    tris.iter().map(|_| rng.below(5) as u32).collect(),
                ),
                ("one each", (0..tris.len() as u32).collect()),
                (
                    "kinematic apart",
                    tris.iter()
                        .enumerate()
                        .map(|(t, tri)| if kinematic(tri) { NONE } else { t as u32 / 40 })
                        .collect(),
                ),
            ];
            for (name, labels) in groupings {
                let mut bp = BroadPhase::grouped(&labels);
                for pass in 0..2 {
                    let got = bp
                        .candidates_on(&Backwards, &tris, &inv_mass, &traj, inflate)
                        .unwrap();
                    assert_eq!(got, expected, "{name}, pass {pass}: res {res}");
                    assert!(bp.last_pairs <= pairs, "{name}");
                }
                match name {
                    // the obstacle's own pairs are not traversed
                    "kinematic apart" => assert!(bp.last_pairs < pairs, "{name}: res {res}"),
                    // no kinematic group (nor pair of them)
                    "random of 5" => assert_eq!(bp.last_pairs, pairs, "{name}"),
                    _ => {}
                }
                assert!(!bp.last_group_pairs.is_empty(), "{name}");
            }
        }
    }

    #[test]
    fn vertices_with_empty_dops_take_the_general_filter() {
        let (tris, inv_mass, traj) = crumpled_with(4, 20, 2, &[5, 77, 150, 151, 299]);
        for bad in [f64::NAN, f64::INFINITY] {
            assert!(Dop26::from_point(DVec3::splat(bad)).is_empty());
        }
        for inflate in [0.0, 0.01, 0.03] {
            let (expected, pairs) = brute_force(&tris, &inv_mass, &traj, inflate);
            assert!(!expected.is_empty());
            let mut bp = BroadPhase::default();
            assert_eq!(
                bp.candidates_on(&Backwards, &tris, &inv_mass, &traj, inflate)
                    .unwrap(),
                expected
            );
            assert_eq!(bp.last_pairs, pairs);
        }
    }

    #[test]
    fn empty_inputs() {
        let traj = Trajectories::new(0, usize::MAX);
        let mut bp = BroadPhase::default();
        assert!(bp
            .candidates_on(&Backwards, &[], &[], &traj, 0.1)
            .unwrap()
            .is_empty());
        assert_eq!(bp.last_pairs, 0);
    }
}
