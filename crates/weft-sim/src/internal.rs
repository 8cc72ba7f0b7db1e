//! Internal forces: stretch, bend and damping stencils split into partitions,
//! evaluated per partition (on one memory in pieces of a partition's
//! elements) and summed per vertex by an ordered fold.
//!
//! Storage is partition-major (each partition's elements, and their output
//! slots, are contiguous) while the per-vertex fold visits contributions in
//! **global key order** — stretch elements by triangle input id, then hinges by
//! edge — so the sum's bits do not depend on the partitioning. Inside each
//! piece of a partition (at most [`ELEMENTS_PER_PIECE`] elements) the slots
//! are laid out by vertex, so a vertex's fold reads short runs of
//! neighbouring slots rather than one slot per element scattered over the
//! partition.
//!
//! Over ranks a rank keeps the elements of the partitions placed on it
//! only, and the folds (the slots in key order) of the vertices it owns
//! ([`InternalForces::held_only`]): the partitions, their slots and pieces,
//! each vertex's fold length and what each partition reads stay whole (the
//! plan every rank computes alike reads them), and a partition placed again
//! elsewhere moves its elements and its vertices' folds there as words
//! ([`InternalForces::partition_words`], [`InternalForces::place_again`]).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::ops::Range;

use glam::DVec3;
use weft_core::{Topology, NONE};

use crate::executor::{split_chunks, CommError, Executor};
use crate::materials::{
    whole_below, ElasticModel, HingeElement, Material, MaterialError, StretchElement,
};

/// One partition's share of the internal stencils.
#[derive(Clone, Debug, PartialEq)]
pub struct Partition {
    pub stretch: Range<usize>,
    pub hinges: Range<usize>,
    /// Its output slots (3 per stretch element, then 4 per hinge).
    pub slots: Range<usize>,
}

/// At most this many elements per piece ([`InternalForces::evaluate_in_pieces`]).
pub const ELEMENTS_PER_PIECE: usize = 256;

// A corner's slot is kept as a `u16` offset in its piece (4 slots a hinge).
const _: () = assert!(4 * ELEMENTS_PER_PIECE <= 1 << 16);

/// A run of one partition's elements, in storage order (its stretch
/// elements, then its hinges), and so of its output slots.
#[derive(Clone, Debug, PartialEq)]
struct Piece {
    partition: u32,
    stretch: Range<usize>,
    hinges: Range<usize>,
}

impl Piece {
    /// Partition `p`, `part`, as a piece.
    fn of(p: usize, part: &Partition) -> Self {
        Piece {
            partition: p as u32,
            stretch: part.stretch.clone(),
            hinges: part.hinges.clone(),
        }
    }

    /// How many of its elements the per-element flags `stretch` and
    /// `hinges` (by storage index) mark.
    fn count_in(&self, stretch: &[bool], hinges: &[bool]) -> usize {
        let s = stretch[self.stretch.clone()].iter().filter(|&&b| b).count();
        s + hinges[self.hinges.clone()].iter().filter(|&&b| b).count()
    }
}

/// A subset of the internal elements: per stretch element and per hinge
/// (by storage index) whether it is in, and per partition (and piece) how
/// many of its elements are.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ElementMask {
    pub stretch: Vec<bool>,
    pub hinges: Vec<bool>,
    pub in_partition: Vec<usize>,
    /// Per piece ([`InternalForces::evaluate_in_pieces`]) how many of its
    /// elements are in.
    in_piece: Vec<usize>,
}

/// Where a held partition's elements start in the held storage.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Held {
    stretch: usize,
    hinges: usize,
}

/// Words per element that moves with its partition
/// ([`InternalForces::partition_words`]): a stretch element's 7, its
/// material, its key and its 3 corners' slots; a hinge's 6, its material,
/// its key and its 4 corners' slots.
const MOVED_WORDS: usize = 12;
const _: () = assert!(StretchElement::WORDS + 2 + 3 == MOVED_WORDS);
const _: () = assert!(HingeElement::WORDS + 2 + 4 == MOVED_WORDS);

/// The internal stencils of the world: all of them, or over ranks those of
/// the partitions held here ([`InternalForces::held_only`]).
#[derive(Clone, Debug)]
pub struct InternalForces {
    /// The held elements, partition by partition in storage order (all of
    /// them on one memory: then an element's index here is its storage
    /// index).
    pub stretch: Vec<StretchElement>,
    pub stretch_material: Vec<u16>,
    pub hinges: Vec<HingeElement>,
    pub hinge_material: Vec<u16>,
    pub materials: Vec<Material>,
    pub partitions: Vec<Partition>,
    /// Per partition, where its elements start in the held storage;
    /// `None` where it is not held here.
    held: Vec<Option<Held>>,
    /// Whether every element is held and indexed by storage index (a
    /// world as built); `false` after [`InternalForces::held_only`].
    whole: bool,
    /// Stretch elements and hinges of the world, held or not.
    num_stretch: usize,
    num_hinges: usize,
    /// Of a part ([`InternalForces::held_only`]): each held element's place
    /// in global key order among its kind (the statistics' sums run in
    /// that order). Empty when whole (`stretch_by_key` says it).
    stretch_key: Vec<u32>,
    hinge_key: Vec<u32>,
    /// Per partition, the vertices its elements read (ascending), in one
    /// list cut at `reads_start`: what every rank's plan of the exchanges
    /// reads ([`crate::share::RankShare`]).
    reads_start: Vec<u32>,
    reads: Vec<u32>,
    /// The partitions cut into pieces of at most [`ELEMENTS_PER_PIECE`]
    /// elements, with their slot bounds: on one memory the tasks of an
    /// evaluation (a few partitions can hold most of a masked evaluation's
    /// elements, and one partition per task left a thread idle at its end).
    pieces: Vec<Piece>,
    piece_bounds: Vec<usize>,
    /// The pieces by their lowest vertex id: the order their tasks are
    /// handed out in. A team's threads take tasks from the two ends of a
    /// loop (`weft-par`'s `Threads`), and the per-vertex loops after an
    /// evaluation run over vertex ids: in this order a thread folds mostly
    /// the slots it wrote, still in its cache (the partitions keep METIS's
    /// numbering, which places them on ranks).
    piece_order: Vec<u32>,
    /// Storage index of each stretch element and hinge in global key order
    /// (storage is partition-major): every sum over elements runs in this
    /// order, so its bits do not depend on the partitioning. Empty in a
    /// part (`stretch_key` says it).
    stretch_by_key: Vec<u32>,
    hinge_by_key: Vec<u32>,
    /// Per-vertex CSR of output slots in global key order (of a part: of
    /// the vertices it holds the folds of, the others' runs empty).
    incidence_offsets: Vec<u32>,
    incidence: Vec<u32>,
    /// Of a part: how many slots each vertex folds, held here or not (what
    /// a moved fold's words measure); empty when whole.
    fold_len: Vec<u32>,
    /// The output slot of each held element corner, from its piece's
    /// first slot: 3 per held stretch element, then 4 per held hinge, in
    /// the held storage's order.
    /// Within a piece the slots are laid out by vertex (then in the fold's
    /// order), not by element.
    corner_slot: Vec<u16>,
    /// The pieces of each partition (indices into `pieces`).
    pieces_of: Vec<Range<usize>>,
    damped: bool,
}

impl InternalForces {
    /// The rank each partition lives on when the world is spread over
    /// `ranks` ranks: contiguous runs of partitions with about equal
    /// internal-force work (output slots).
    pub fn home_ranks(&self, ranks: usize) -> Vec<u32> {
        crate::executor::place_by_size(self.partitions.iter().map(|p| p.slots.len()), ranks)
    }

    /// Builds the stencils of cloth triangles (`tri_material[f] = Some(m)`) and
    /// of interior edges between two cloth triangles, stored partition by
    /// partition: `part_of_tri[f] < n_parts` for every cloth triangle (a hinge
    /// belongs to the partition of its first face).
    pub fn build(
        triangles: &[[u32; 3]],
        tri_material: &[Option<u16>],
        topology: &Topology,
        rest: &[DVec3],
        materials_list: &[Material],
        inv_mass: &[f64],
        part_of_tri: &[u32],
        n_parts: usize,
    ) -> Result<Self, (u32, MaterialError)> {
        let cloth: Vec<u32> = (0..triangles.len() as u32)
            .filter(|&f| tri_material[f as usize].is_some())
            .collect();
        // (partition, global key) of every element.
        let mut stretch_keys: Vec<(u32, u32)> = cloth
            .iter()
            .map(|&f| (part_of_tri[f as usize], f))
            .collect();
        stretch_keys.sort_unstable();
        let mut hinge_keys: Vec<(u32, u32)> = Vec::new();
        for (e, &[fa, fb]) in topology.edge_faces.iter().enumerate() {
            if fb != NONE
                && tri_material[fa as usize].is_some()
                && tri_material[fb as usize].is_some()
            {
                hinge_keys.push((part_of_tri[fa as usize], e as u32));
            }
        }
        hinge_keys.sort_unstable();
        let hinge_of_edge = {
            let mut m = vec![NONE; topology.edges.len()];
            for (h, hinge) in topology.hinges.iter().enumerate() {
                if let Some(e) = topology.edge_index(hinge.edge[0], hinge.edge[1]) {
                    m[e as usize] = h as u32;
                }
            }
            m
        };

        let mut stretch = Vec::with_capacity(stretch_keys.len());
        let mut stretch_material = Vec::with_capacity(stretch_keys.len());
        for &(_, f) in &stretch_keys {
            let t = triangles[f as usize];
            let r = [
                rest[t[0] as usize],
                rest[t[1] as usize],
                rest[t[2] as usize],
            ];
            stretch.push(StretchElement::new(t, r).map_err(|e| (f, e))?);
            stretch_material.push(tri_material[f as usize].unwrap_or(0));
        }
        let mut hinges = Vec::with_capacity(hinge_keys.len());
        let mut hinge_material = Vec::with_capacity(hinge_keys.len());
        for &(_, e) in &hinge_keys {
            let h = topology.hinges[hinge_of_edge[e as usize] as usize];
            let verts = [h.edge[0], h.edge[1], h.wings[0], h.wings[1]];
            let r = verts.map(|i| rest[i as usize]);
            hinges.push(HingeElement::new(verts, r).map_err(|err| (h.faces[0], err))?);
            hinge_material.push(tri_material[h.faces[0] as usize].unwrap_or(0));
        }

        // Partition ranges and output slots.
        let mut parts = Vec::with_capacity(n_parts);
        let (mut s0, mut h0, mut slot) = (0usize, 0usize, 0usize);
        for p in 0..n_parts as u32 {
            let s1 = s0 + stretch_keys[s0..].iter().take_while(|k| k.0 == p).count();
            let h1 = h0 + hinge_keys[h0..].iter().take_while(|k| k.0 == p).count();
            let slots = slot..slot + 3 * (s1 - s0) + 4 * (h1 - h0);
            slot = slots.end;
            parts.push(Partition {
                stretch: s0..s1,
                hinges: h0..h1,
                slots,
            });
            (s0, h0) = (s1, h1);
        }

        // The elements cut into pieces (the tasks of an evaluation on one
        // memory), and each piece's slots laid out vertex by vertex: the
        // fold of a vertex then reads one short run of slots per piece its
        // elements lie in, and consecutive vertices read neighbouring runs
        // (it was bound by the latency of scattered loads). Each element
        // corner writes its own slot (`corner_slot`); the fold's order is
        // the incidence's, global key order, whatever the layout.
        let (pieces, piece_bounds, pieces_of) = cut_into_pieces(&parts);
        let ns = stretch.len();
        let corners_in_all = 3 * ns + 4 * hinges.len();
        let mut corner_slot = vec![0u16; corners_in_all];
        // The output slot of every corner (3 per stretch element, then 4
        // per hinge, in storage order).
        let mut slot_of_corner = vec![0u32; corners_in_all];
        // (vertex, class, key, corner, corner index in storage order) of
        // one piece.
        let mut corners: Vec<(u32, u32, u32, u32, usize)> = Vec::new();
        for (piece, &start) in pieces.iter().zip(&piece_bounds) {
            corners.clear();
            for s in piece.stretch.clone() {
                for (j, &vtx) in stretch[s].verts.iter().enumerate() {
                    corners.push((vtx, 0, stretch_keys[s].1, j as u32, 3 * s + j));
                }
            }
            for h in piece.hinges.clone() {
                for (j, &vtx) in hinges[h].verts.iter().enumerate() {
                    corners.push((vtx, 1, hinge_keys[h].1, j as u32, 3 * ns + 4 * h + j));
                }
            }
            corners.sort_unstable();
            for (k, &(.., c)) in corners.iter().enumerate() {
                corner_slot[c] = k as u16;
                slot_of_corner[c] = (start + k) as u32;
            }
        }
        // The incidence in global key order: each dynamic vertex's corners
        // placed by vertex (a count, then a prefix sum), each vertex's few
        // sorted by (class, key, corner), then mapped to their slots: the
        // order a sort of (vertex, class, key, corner, slot) tuples over
        // every corner gives, without their 20 bytes a corner (21 MB on the
        // 50k twister, on every rank, at the start).
        let vertex_of = |c: usize| match c.checked_sub(3 * ns) {
            None => stretch[c / 3].verts[c % 3],
            Some(h) => hinges[h / 4].verts[h % 4],
        };
        let order_of = |c: usize| match c.checked_sub(3 * ns) {
            None => (0, stretch_keys[c / 3].1, c % 3),
            Some(h) => (1, hinge_keys[h / 4].1, h % 4),
        };
        let nv = rest.len();
        let dynamic = |i: u32| inv_mass[i as usize] > 0.0;
        let mut incidence_offsets = vec![0u32; nv + 1];
        for c in 0..corners_in_all {
            let vtx = vertex_of(c);
            if dynamic(vtx) {
                incidence_offsets[vtx as usize + 1] += 1;
            }
        }
        for i in 0..nv {
            incidence_offsets[i + 1] += incidence_offsets[i];
        }
        let mut incidence = vec![0u32; incidence_offsets[nv] as usize];
        let mut next = incidence_offsets[..nv].to_vec();
        for c in 0..corners_in_all {
            let vtx = vertex_of(c) as usize;
            if dynamic(vtx as u32) {
                incidence[next[vtx] as usize] = c as u32;
                next[vtx] += 1;
            }
        }
        drop(next);
        for i in 0..nv {
            let run = incidence_offsets[i] as usize..incidence_offsets[i + 1] as usize;
            incidence[run].sort_unstable_by_key(|&c| order_of(c as usize));
        }
        for c in &mut incidence {
            *c = slot_of_corner[*c as usize];
        }
        drop(slot_of_corner);
        let by_key = |keys: &[(u32, u32)]| {
            let mut order: Vec<u32> = (0..keys.len() as u32).collect();
            order.sort_unstable_by_key(|&i| keys[i as usize].1);
            order
        };
        let damped = materials_list
            .iter()
            .any(|m| m.stretch_damping > 0.0 || m.bend_damping > 0.0);
        let first_vertex = |p: &Piece| -> u32 {
            let stretch = stretch[p.stretch.clone()].iter().map(|e| &e.verts[..]);
            let hinges = hinges[p.hinges.clone()].iter().map(|e| &e.verts[..]);
            stretch
                .chain(hinges)
                .flatten()
                .copied()
                .min()
                .unwrap_or(u32::MAX)
        };
        let mut piece_order: Vec<u32> = (0..pieces.len() as u32).collect();
        piece_order.sort_by_key(|&k| (first_vertex(&pieces[k as usize]), k));
        let (mut reads_start, mut reads) = (vec![0u32], Vec::new());
        for part in &parts {
            let stretch = stretch[part.stretch.clone()].iter().map(|e| &e.verts[..]);
            let hinges = hinges[part.hinges.clone()].iter().map(|e| &e.verts[..]);
            let mut read: Vec<u32> = stretch.chain(hinges).flatten().copied().collect();
            read.sort_unstable();
            read.dedup();
            reads.extend(read);
            reads_start.push(reads.len() as u32);
        }
        let held = (parts.iter())
            .map(|part| {
                Some(Held {
                    stretch: part.stretch.start,
                    hinges: part.hinges.start,
                })
            })
            .collect();
        Ok(Self {
            num_stretch: stretch.len(),
            num_hinges: hinges.len(),
            stretch,
            stretch_material,
            hinges,
            hinge_material,
            materials: materials_list.to_vec(),
            partitions: parts,
            held,
            whole: true,
            stretch_key: Vec::new(),
            hinge_key: Vec::new(),
            reads_start,
            reads,
            pieces,
            piece_bounds,
            piece_order,
            stretch_by_key: by_key(&stretch_keys),
            hinge_by_key: by_key(&hinge_keys),
            incidence_offsets,
            incidence,
            fold_len: Vec::new(),
            corner_slot,
            pieces_of,
            damped,
        })
    }

    /// Number of output slots.
    pub fn num_slots(&self) -> usize {
        self.partitions.last().map_or(0, |p| p.slots.end)
    }

    /// Number of internal stencils (stretch + hinge elements).
    pub fn num_stencils(&self) -> usize {
        self.num_stretch + self.num_hinges
    }

    /// Whether partition `p`'s elements are held here.
    pub fn holds(&self, p: usize) -> bool {
        self.held[p].is_some()
    }

    /// Whether every element is held (a world as built, not a rank's
    /// part).
    pub fn is_whole(&self) -> bool {
        self.whole
    }

    /// The vertices partition `p`'s elements read, ascending (held here or
    /// not).
    pub fn reads(&self, p: usize) -> &[u32] {
        &self.reads[self.reads_start[p] as usize..self.reads_start[p + 1] as usize]
    }

    /// Where partition `p`'s elements lie in the held storage (its stretch
    /// elements, its hinges); `None` where it is not held here.
    fn held_ranges(&self, p: usize) -> Option<(Range<usize>, Range<usize>)> {
        let (part, at) = (&self.partitions[p], self.held[p]?);
        let stretch = at.stretch..at.stretch + part.stretch.len();
        Some((stretch, at.hinges..at.hinges + part.hinges.len()))
    }

    /// [`InternalForces::held_ranges`] of a partition held here; another
    /// is a bug of the caller (a rank evaluates only the partitions placed
    /// on it).
    fn held_at(&self, p: usize) -> (Range<usize>, Range<usize>) {
        (self.held_ranges(p))
            .unwrap_or_else(|| panic!("partition {p}'s elements are not held here"))
    }

    /// Slot bounds of the partitions, for [`Executor::for_each_chunk`].
    pub fn slot_bounds(&self) -> Vec<usize> {
        let mut b = vec![0];
        b.extend(self.partitions.iter().map(|p| p.slots.end));
        b
    }

    /// Evaluates every element at positions `x` (and velocities `v` for
    /// damping, read at the start of the batch): writes `dV/dx - f_damping`
    /// per element corner into `out` (partition-major slots, each
    /// partition's laid out by vertex piece by piece).
    /// `only`, when given, says which partitions to evaluate (the others'
    /// slots are left as they are): a rank's share over ranks.
    pub fn evaluate<E: Executor>(
        &self,
        exec: &E,
        bounds: &[usize],
        x: &[DVec3],
        v: &[DVec3],
        out: &mut [DVec3],
        only: Option<&[bool]>,
    ) {
        exec.for_each_chunk(out, bounds, &|p, chunk: &mut [DVec3]| {
            if only.is_some_and(|own| !own[p]) {
                return;
            }
            let _span = crate::trace::span_with("partition", "partition", p as u64);
            self.evaluate_partition(p, x, v, chunk);
        });
    }

    /// As [`Self::evaluate`], but only the elements whose entry in `mask`
    /// is `want` (the others' slots are left as they are): an internal
    /// tick's elements split between the part computed while the contact
    /// islands run and the rest; of the partitions `only` marks (all with
    /// `None`). Each element writes its own slots, so the bits do not
    /// depend on the split.
    #[allow(clippy::too_many_arguments)]
    pub fn evaluate_masked<E: Executor>(
        &self,
        exec: &E,
        bounds: &[usize],
        x: &[DVec3],
        v: &[DVec3],
        out: &mut [DVec3],
        (mask, want): (&ElementMask, bool),
        only: Option<&[bool]>,
    ) {
        exec.for_each_chunk(out, bounds, &|p, chunk: &mut [DVec3]| {
            if only.is_some_and(|own| !own[p]) {
                return;
            }
            let part = &self.partitions[p];
            let all = part.stretch.len() + part.hinges.len();
            let wanted = wanted(all, mask.in_partition[p], want);
            if wanted == 0 {
                return;
            }
            let _span = crate::trace::span_with("partition", "partition", p as u64);
            if wanted == all {
                return self.evaluate_partition(p, x, v, chunk);
            }
            self.evaluate_elements(p, x, v, chunk, Some((mask, want)));
        });
    }

    /// On one memory: every element's internal force (`mask` `None`), or
    /// those whose entry in `mask` is `want`, into `out` (all the slots;
    /// the others' left as they are), in pieces of at most
    /// [`ELEMENTS_PER_PIECE`] elements on the executor. Each element writes
    /// its own slots, so the bits do not depend on the cut.
    pub fn evaluate_in_pieces<E: Executor>(
        &self,
        exec: &E,
        (x, v): (&[DVec3], &[DVec3]),
        out: &mut [DVec3],
        mask: Option<(&ElementMask, bool)>,
    ) {
        let mut chunks: Vec<Option<(usize, &mut [DVec3])>> =
            (split_chunks(out, &self.piece_bounds).into_iter())
                .map(Some)
                .collect();
        let mut in_order: Vec<(usize, &mut [DVec3])> = (self.piece_order.iter())
            .map(|&k| chunks[k as usize].take().expect("each piece once"))
            .collect();
        exec.for_each_item(&mut in_order, &|_, (k, chunk)| {
            let (k, chunk) = (*k, &mut **chunk);
            let piece = &self.pieces[k];
            if let Some((m, want)) = mask {
                let all = piece.stretch.len() + piece.hinges.len();
                let wanted = wanted(all, m.in_piece[k], want);
                if wanted == 0 {
                    return;
                }
                let mask = (wanted < all).then_some((m, want));
                return self.evaluate_range(piece, x, v, chunk, mask);
            }
            self.evaluate_range(piece, x, v, chunk, None);
        });
    }

    /// The held elements (by storage index) all of whose vertices `pick`
    /// keeps (an element not held here is not in).
    pub fn mask_where(&self, pick: impl Fn(u32) -> bool) -> ElementMask {
        let mut stretch = vec![false; self.num_stretch];
        let mut hinges = vec![false; self.num_hinges];
        for (p, part) in self.partitions.iter().enumerate() {
            let Some((s, h)) = self.held_ranges(p) else {
                continue;
            };
            for (flag, e) in stretch[part.stretch.clone()]
                .iter_mut()
                .zip(&self.stretch[s])
            {
                *flag = e.verts.iter().all(|&i| pick(i));
            }
            for (flag, e) in hinges[part.hinges.clone()].iter_mut().zip(&self.hinges[h]) {
                *flag = e.verts.iter().all(|&i| pick(i));
            }
        }
        let in_partition = (self.partitions.iter().enumerate())
            .map(|(p, part)| Piece::of(p, part).count_in(&stretch, &hinges))
            .collect();
        let in_piece = (self.pieces.iter())
            .map(|p| p.count_in(&stretch, &hinges))
            .collect();
        ElementMask {
            stretch,
            hinges,
            in_partition,
            in_piece,
        }
    }

    /// Evaluates the elements of partition `p` whose entry in `mask` is
    /// `want` into `chunk` (its output slots, `partitions[p].slots`).
    pub fn evaluate_partition_masked(
        &self,
        p: usize,
        (x, v): (&[DVec3], &[DVec3]),
        chunk: &mut [DVec3],
        (mask, want): (&ElementMask, bool),
    ) {
        self.evaluate_elements(p, x, v, chunk, Some((mask, want)));
    }

    /// Evaluates partition `p`'s elements into `chunk` (its output slots,
    /// `partitions[p].slots`), reading only the positions and velocities of
    /// their vertices.
    pub fn evaluate_partition(&self, p: usize, x: &[DVec3], v: &[DVec3], chunk: &mut [DVec3]) {
        self.evaluate_elements(p, x, v, chunk, None);
    }

    /// Evaluates the elements of partition `p` into their slots of `chunk`:
    /// every one, or (`mask`, `want`) those whose entry in `mask` is `want`.
    fn evaluate_elements(
        &self,
        p: usize,
        x: &[DVec3],
        v: &[DVec3],
        chunk: &mut [DVec3],
        mask: Option<(&ElementMask, bool)>,
    ) {
        let first = self.partitions[p].slots.start;
        for k in self.pieces_of[p].clone() {
            let slots = self.piece_bounds[k] - first..self.piece_bounds[k + 1] - first;
            self.evaluate_range(&self.pieces[k], x, v, &mut chunk[slots], mask);
        }
    }

    /// Evaluates the elements of `piece` (all, or those whose entry in
    /// `mask` is `want`) into `chunk`, the piece's output slots, each
    /// corner into its own slot.
    fn evaluate_range(
        &self,
        piece: &Piece,
        x: &[DVec3],
        v: &[DVec3],
        chunk: &mut [DVec3],
        mask: Option<(&ElementMask, bool)>,
    ) {
        let mut write = |corners: &[u16], g: &[DVec3]| {
            for (&slot, &g) in corners.iter().zip(g) {
                chunk[usize::from(slot)] = g;
            }
        };
        // Storage index `s` (`h`) is held element `s - ds` (`h - dh`).
        let p = piece.partition as usize;
        let (part, (s_at, h_at)) = (&self.partitions[p], self.held_at(p));
        let (ds, dh) = (
            part.stretch.start - s_at.start,
            part.hinges.start - h_at.start,
        );
        for s in piece.stretch.clone() {
            if mask.is_some_and(|(m, want)| m.stretch[s] != want) {
                continue;
            }
            let l = s - ds;
            let e = &self.stretch[l];
            let m = &self.materials[self.stretch_material[l] as usize];
            let xs = e.verts.map(|i| x[i as usize]);
            let mut g = e.gradient(&xs, m);
            if self.damped && m.stretch_damping > 0.0 {
                let vs = e.verts.map(|i| v[i as usize]);
                let f = e.damping_force(&xs, &vs, m);
                for j in 0..3 {
                    g[j] -= f[j];
                }
            }
            write(&self.corner_slot[3 * l..3 * l + 3], &g);
        }
        let hinge_corners = &self.corner_slot[3 * self.stretch.len()..];
        for h in piece.hinges.clone() {
            if mask.is_some_and(|(m, want)| m.hinges[h] != want) {
                continue;
            }
            let l = h - dh;
            let e = &self.hinges[l];
            let m = &self.materials[self.hinge_material[l] as usize];
            let xs = e.verts.map(|i| x[i as usize]);
            let mut g = e.gradient(&xs, m.bending_stiffness);
            if self.damped && m.bend_damping > 0.0 {
                let vs = e.verts.map(|i| v[i as usize]);
                let f = e.damping_force(&xs, &vs, m);
                for j in 0..4 {
                    g[j] -= f[j];
                }
            }
            write(&hinge_corners[4 * l..4 * l + 4], &g);
        }
    }

    /// The output slots vertex `i` sums, in global key order (of a part:
    /// a vertex whose fold it holds; another is a bug of the caller).
    pub fn incidence(&self, i: usize) -> &[u32] {
        let (a, b) = (
            self.incidence_offsets[i] as usize,
            self.incidence_offsets[i + 1] as usize,
        );
        assert!(
            self.whole || b - a == self.fold_len[i] as usize,
            "vertex {i}'s fold is not held here"
        );
        &self.incidence[a..b]
    }

    /// How many slots vertex `i` folds (held here or not).
    pub fn fold_len(&self, i: usize) -> usize {
        match self.whole {
            true => (self.incidence_offsets[i + 1] - self.incidence_offsets[i]) as usize,
            false => self.fold_len[i] as usize,
        }
    }

    /// The vertex of each output slot of partition `p` (held here), in
    /// slot order.
    pub fn slot_vertices(&self, p: usize) -> Vec<u32> {
        let part = &self.partitions[p];
        let first = part.slots.start;
        let mut out = vec![NONE; part.slots.len()];
        let ns = self.stretch.len();
        let (s_at, h_at) = self.held_at(p);
        let (ds, dh) = (
            part.stretch.start - s_at.start,
            part.hinges.start - h_at.start,
        );
        for k in self.pieces_of[p].clone() {
            let piece = &self.pieces[k];
            let at = self.piece_bounds[k] - first;
            let corners = (piece.stretch.clone().map(|s| s - ds))
                .map(|s| (&self.stretch[s].verts[..], 3 * s))
                .chain(
                    (piece.hinges.clone().map(|h| h - dh))
                        .map(|h| (&self.hinges[h].verts[..], 3 * ns + 4 * h)),
                );
            for (verts, c) in corners {
                for (j, &vtx) in verts.iter().enumerate() {
                    out[at + usize::from(self.corner_slot[c + j])] = vtx;
                }
            }
        }
        out
    }

    /// The ordered fold of vertex `i`'s contributions (global key order;
    /// a whole world's: over ranks a rank folds its slots at their places,
    /// [`crate::share::RankSlots`]).
    #[inline]
    pub fn fold(&self, i: usize, out: &[DVec3]) -> DVec3 {
        debug_assert!(self.whole, "a whole world's fold");
        let (a, b) = (
            self.incidence_offsets[i] as usize,
            self.incidence_offsets[i + 1] as usize,
        );
        let mut sum = DVec3::ZERO;
        for &s in &self.incidence[a..b] {
            sum += out[s as usize];
        }
        sum
    }

    /// How many stretch and hinge elements there are: the elements in
    /// global key order are the stretch elements, then the hinges, and
    /// [`InternalForces::energy_of`] sums a range of that order.
    pub fn elements_by_key(&self) -> (usize, usize) {
        (self.num_stretch, self.num_hinges)
    }

    /// The elastic energy of the elements `range` of the key order (see
    /// [`InternalForces::elements_by_key`]), summed in that order; of a
    /// whole world's (over ranks, [`InternalForces::held_energies`]).
    pub fn energy_of(&self, x: &[DVec3], range: std::ops::Range<usize>) -> f64 {
        self.assert_whole("the energy of a range of elements");
        let ns = self.stretch_by_key.len();
        let mut e = 0.0;
        for n in range {
            if n < ns {
                let s = self.stretch_by_key[n] as usize;
                let el = &self.stretch[s];
                let m = &self.materials[self.stretch_material[s] as usize];
                e += el.energy(&el.verts.map(|i| x[i as usize]), m);
            } else {
                let h = self.hinge_by_key[n - ns] as usize;
                let el = &self.hinges[h];
                let m = &self.materials[self.hinge_material[h] as usize];
                e += el.energy(&el.verts.map(|i| x[i as usize]), m.bending_stiffness);
            }
        }
        e
    }

    /// Every element, read in global key order where it is stored, for
    /// assembled quantities (the stable step, the damping limit) whose sums
    /// must not depend on the partitioning. (A copy of the elements in that
    /// order was a tenth of a rank's heap at the start of a run over ranks.)
    pub fn model(&self) -> ElasticModel<'_> {
        self.model_in_key_order(&self.materials)
    }

    /// [`InternalForces::model`] with the material table `materials` (this
    /// store's, or one with some dampings left out).
    fn model_in_key_order<'a>(&'a self, materials: &'a [Material]) -> ElasticModel<'a> {
        self.assert_whole("the elements in key order");
        ElasticModel {
            stretch: &self.stretch,
            stretch_material: &self.stretch_material,
            hinges: &self.hinges,
            hinge_material: &self.hinge_material,
            materials,
            order: Some((&self.stretch_by_key, &self.hinge_by_key)),
        }
    }

    /// Largest angular frequency of the assembled rest system, assembled on
    /// `exec`'s ranks and threads (the same bits on any number).
    /// **Collective over ranks.**
    pub fn max_frequency<E: Executor>(
        &self,
        exec: &E,
        rest: &[DVec3],
        mass: &[f64],
    ) -> Result<f64, CommError> {
        self.model().max_frequency_on(exec, rest, mass)
    }

    /// `gamma_max = λ_max(M⁻¹C)` (1/s) of the damping operator at the rest
    /// shape, 0 without damping: with `omega_max` it sets the explicit
    /// stability limit `h γ + h² ω² / 2 ≤ 2` ([`crate::materials::damping_step_limit`]).
    pub fn max_damping_rate<E: Executor>(
        &self,
        exec: &E,
        rest: &[DVec3],
        mass: &[f64],
    ) -> Result<f64, CommError> {
        if !self.damped {
            return Ok(0.0);
        }
        self.model().max_damping_rate_on(exec, rest, mass)
    }

    /// The damping rate of material `m`'s elements alone, keeping only its
    /// stretch damping, only its bend damping, or both (`[stretch, bend,
    /// both]`), to say which damping of which cloth is too strong. Cloths
    /// share no vertex, so `M⁻¹C` is block diagonal and
    /// [`InternalForces::max_damping_rate`] is the largest `both` over the
    /// materials; scaling both dampings of material `m` by `s` scales its
    /// rate by exactly `s`.
    pub fn damping_rates_of(&self, m: usize, rest: &[DVec3], mass: &[f64]) -> [f64; 3] {
        let rate = |stretch: bool, bend: bool| {
            let mut materials = self.materials.clone();
            for (j, material) in materials.iter_mut().enumerate() {
                if j != m || !stretch {
                    material.stretch_damping = 0.0;
                }
                if j != m || !bend {
                    material.bend_damping = 0.0;
                }
            }
            (self.model_in_key_order(&materials)).max_damping_rate(rest, mass)
        };
        [rate(true, false), rate(false, true), rate(true, true)]
    }
}

/// The held part of the elements over ranks: a rank keeps the elements of
/// the partitions placed on it and the folds of the vertices it owns, and
/// both move with a partition placed again.
impl InternalForces {
    fn assert_whole(&self, what: &str) {
        assert!(
            self.whole,
            "{what} needs every element; this rank holds a part"
        );
    }

    fn assert_part(&self) {
        assert!(!self.whole, "a rank's part keeps its elements' keys");
    }

    /// The vertices of each held element whose entry in `mask` is `want`.
    pub fn verts_where<'a>(
        &'a self,
        mask: &'a ElementMask,
        want: bool,
    ) -> impl Iterator<Item = &'a [u32]> + 'a {
        let held = (0..self.partitions.len()).filter_map(|p| Some((p, self.held_ranges(p)?)));
        held.flat_map(move |(p, (s, h))| {
            let part = &self.partitions[p];
            let stretch = (self.stretch[s].iter())
                .zip(&mask.stretch[part.stretch.clone()])
                .filter(move |(_, &m)| m == want)
                .map(|(e, _)| &e.verts[..]);
            let hinges = (self.hinges[h].iter())
                .zip(&mask.hinges[part.hinges.clone()])
                .filter(move |(_, &m)| m == want)
                .map(|(e, _)| &e.verts[..]);
            stretch.chain(hinges)
        })
    }

    /// A rank's part of a whole world's elements: those of the partitions
    /// `keep` names, and the folds (the slots in key order) of the vertices
    /// `holds_fold` names. The partitions, their slots and pieces, each
    /// vertex's fold length and what each partition reads stay whole; each
    /// held element also keeps its place in key order (for the statistics'
    /// sums, [`InternalForces::held_energies`]).
    pub fn held_only(
        &self,
        keep: impl Fn(usize) -> bool,
        holds_fold: impl Fn(usize) -> bool,
    ) -> Self {
        self.assert_whole("a rank's part");
        let inverse = |by_key: &[u32]| {
            let mut key = vec![0u32; by_key.len()];
            for (n, &at) in by_key.iter().enumerate() {
                key[at as usize] = n as u32;
            }
            key
        };
        let keys = (inverse(&self.stretch_by_key), inverse(&self.hinge_by_key));
        let mut part = self.clone_global();
        let mut hinge_corners = Vec::new();
        for p in (0..self.partitions.len()).filter(|&p| keep(p)) {
            part.append_held(self, p, (&keys.0, &keys.1), &mut hinge_corners);
        }
        part.corner_slot.extend(hinge_corners);
        let held_folds = |i: usize| holds_fold(i).then(|| Ok(Cow::Borrowed(self.incidence(i))));
        part.hold_folds(held_folds)
            .expect("every fold is held whole");
        part
    }

    /// Fills this part's folds: vertex `i`'s is `fold_of(i)` (`None`: not
    /// held here), which must hold [`InternalForces::fold_len`] slots
    /// (borrowed where it is read from another part: a copy of each was an
    /// allocation per vertex).
    fn hold_folds<'a>(
        &mut self,
        mut fold_of: impl FnMut(usize) -> Option<Result<Cow<'a, [u32]>, String>>,
    ) -> Result<(), String> {
        let n = self.fold_len.len();
        let (mut offsets, mut slots) = (Vec::with_capacity(n + 1), Vec::new());
        offsets.push(0);
        for i in 0..n {
            if let Some(fold) = fold_of(i) {
                let fold = fold?;
                if fold.len() != self.fold_len[i] as usize {
                    return Err(format!(
                        "vertex {i}'s fold has {} slots instead of {}",
                        fold.len(),
                        self.fold_len[i]
                    ));
                }
                slots.extend_from_slice(&fold);
            }
            offsets.push(slots.len() as u32);
        }
        (self.incidence_offsets, self.incidence) = (offsets, slots);
        Ok(())
    }

    /// Appends partition `p`'s elements as `from` holds them (with their
    /// places in key order `keys`, by held index) to this part's held
    /// storage; their hinges' corner slots go to `hinge_corners`, joined to
    /// `corner_slot` once every partition is in.
    fn append_held(
        &mut self,
        from: &Self,
        p: usize,
        (stretch_key, hinge_key): (&[u32], &[u32]),
        hinge_corners: &mut Vec<u16>,
    ) {
        let (s, h) = from.held_at(p);
        self.held[p] = Some(Held {
            stretch: self.stretch.len(),
            hinges: self.hinges.len(),
        });
        self.stretch.extend_from_slice(&from.stretch[s.clone()]);
        self.stretch_material
            .extend_from_slice(&from.stretch_material[s.clone()]);
        self.stretch_key.extend_from_slice(&stretch_key[s.clone()]);
        self.corner_slot
            .extend_from_slice(&from.corner_slot[3 * s.start..3 * s.end]);
        self.hinges.extend_from_slice(&from.hinges[h.clone()]);
        self.hinge_material
            .extend_from_slice(&from.hinge_material[h.clone()]);
        self.hinge_key.extend_from_slice(&hinge_key[h.clone()]);
        let hinges_at = 3 * from.stretch.len();
        hinge_corners
            .extend_from_slice(&from.corner_slot[hinges_at + 4 * h.start..hinges_at + 4 * h.end]);
    }

    /// A copy of what stays whole in a rank's part, with no element (no
    /// partition held) and no fold.
    fn clone_global(&self) -> Self {
        Self {
            stretch: Vec::new(),
            stretch_material: Vec::new(),
            hinges: Vec::new(),
            hinge_material: Vec::new(),
            materials: self.materials.clone(),
            partitions: self.partitions.clone(),
            held: vec![None; self.partitions.len()],
            whole: false,
            num_stretch: self.num_stretch,
            num_hinges: self.num_hinges,
            stretch_key: Vec::new(),
            hinge_key: Vec::new(),
            reads_start: self.reads_start.clone(),
            reads: self.reads.clone(),
            pieces: self.pieces.clone(),
            piece_bounds: self.piece_bounds.clone(),
            piece_order: self.piece_order.clone(),
            stretch_by_key: Vec::new(),
            hinge_by_key: Vec::new(),
            incidence_offsets: Vec::new(),
            incidence: Vec::new(),
            fold_len: (0..self.incidence_offsets.len().saturating_sub(1))
                .map(|i| self.fold_len(i) as u32)
                .collect(),
            corner_slot: Vec::new(),
            pieces_of: self.pieces_of.clone(),
            damped: self.damped,
        }
    }

    /// The elastic energy of each held element of a rank's part with its
    /// place in key order ([`InternalForces::elements_by_key`]: the
    /// stretch elements, then the hinges), in the order they are held. The
    /// statistics gather them where a range of that order is summed and
    /// sort them there (only there), to add them in the order of
    /// [`InternalForces::energy_of`], so the sum has its bits.
    pub fn held_energies(&self, x: &[DVec3]) -> Vec<(u32, f64)> {
        self.assert_part();
        let ns = self.num_stretch as u32;
        let stretch = (self
            .stretch
            .iter()
            .zip(&self.stretch_material)
            .zip(&self.stretch_key))
        .map(|((e, &m), &n)| {
            let m = &self.materials[m as usize];
            (n, e.energy(&e.verts.map(|i| x[i as usize]), m))
        });
        let hinges = (self
            .hinges
            .iter()
            .zip(&self.hinge_material)
            .zip(&self.hinge_key))
        .map(|((e, &m), &n)| {
            let k = self.materials[m as usize].bending_stiffness;
            (ns + n, e.energy(&e.verts.map(|i| x[i as usize]), k))
        });
        stretch.chain(hinges).collect()
    }

    /// How many words partition `p`'s elements and the folds of
    /// `vertices` move as ([`InternalForces::partition_words`]).
    pub fn moved_words(&self, p: usize, vertices: &[u32]) -> usize {
        let part = &self.partitions[p];
        let folds: usize = vertices.iter().map(|&i| self.fold_len(i as usize)).sum();
        MOVED_WORDS * (part.stretch.len() + part.hinges.len()) + folds
    }

    /// Partition `p`'s elements (held here) and the folds of `vertices`
    /// (held here: those that move with it) as words, every bit kept, for
    /// the rank it is placed on next: per stretch element its words, its
    /// material, its place in key order and its corners' slots, then the
    /// same per hinge, then each vertex's slots.
    pub fn partition_words(&self, p: usize, vertices: &[u32]) -> Vec<f64> {
        self.assert_part();
        let (s, h) = self.held_at(p);
        let mut words = Vec::with_capacity(self.moved_words(p, vertices));
        let hinge_corners = &self.corner_slot[3 * self.stretch.len()..];
        for l in s {
            words.extend(self.stretch[l].to_words());
            words.push(self.stretch_material[l].into());
            words.push(self.stretch_key[l].into());
            words.extend(
                self.corner_slot[3 * l..3 * l + 3]
                    .iter()
                    .map(|&c| f64::from(c)),
            );
        }
        for l in h {
            words.extend(self.hinges[l].to_words());
            words.push(self.hinge_material[l].into());
            words.push(self.hinge_key[l].into());
            words.extend(
                hinge_corners[4 * l..4 * l + 4]
                    .iter()
                    .map(|&c| f64::from(c)),
            );
        }
        for &i in vertices {
            words.extend(self.incidence(i as usize).iter().map(|&s| f64::from(s)));
        }
        words
    }

    /// A rank's part placed again: it holds the partitions `keep` names
    /// and the folds of the vertices `holds_fold` names from now on, those
    /// it held kept as they are and the others taken from `arrived` (the
    /// [`InternalForces::partition_words`] of a partition and the vertices
    /// that moved with it, from the rank that held them). An error names a
    /// partition or vertex whose words are missing or do not decode.
    pub fn place_again(
        &mut self,
        keep: impl Fn(usize) -> bool,
        holds_fold: impl Fn(usize) -> bool,
        arrived: Vec<Moved>,
    ) -> Result<(), String> {
        self.assert_part();
        let mut arrived_for: Vec<Option<Moved>> = vec![None; self.partitions.len()];
        for moved in arrived {
            let p = moved.partition;
            arrived_for[p] = Some(moved);
        }
        let mut next = self.clone_global();
        let mut hinge_corners = Vec::new();
        let mut folds: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for p in (0..self.partitions.len()).filter(|&p| keep(p)) {
            if self.holds(p) {
                let keys = (&self.stretch_key[..], &self.hinge_key[..]);
                next.append_held(self, p, keys, &mut hinge_corners);
                continue;
            }
            let moved = (arrived_for[p].take())
                .ok_or_else(|| format!("partition {p}'s elements did not arrive"))?;
            let (elements, rest) = moved
                .words
                .split_at(self.moved_words(p, &[]).min(moved.words.len()));
            next.append_moved(p, elements, &mut hinge_corners)
                .map_err(|what| format!("partition {p}'s elements arrived with {what}"))?;
            let mut rest = rest.iter();
            for &i in &moved.vertices {
                let fold: Option<Vec<u32>> = (rest.by_ref().take(self.fold_len(i as usize)))
                    .map(|&s| whole_below(s, self.num_slots() as u64))
                    .collect();
                let fold = fold.ok_or_else(|| {
                    format!("vertex {i}'s fold arrived with a slot that is not one")
                })?;
                folds.insert(i, fold);
            }
            if rest.next().is_some() {
                return Err(format!(
                    "partition {p}'s words arrived with more than its elements and folds"
                ));
            }
        }
        next.corner_slot.extend(hinge_corners);
        let fold_of = |i: usize| {
            holds_fold(i).then(|| match folds.remove(&(i as u32)) {
                Some(fold) => Ok(Cow::Owned(fold)),
                None if self.incidence_here(i).len() == self.fold_len(i) => {
                    Ok(Cow::Borrowed(self.incidence_here(i)))
                }
                None => Err(format!("vertex {i}'s fold did not arrive")),
            })
        };
        next.hold_folds(fold_of)?;
        *self = next;
        Ok(())
    }

    /// The slots of vertex `i`'s fold held here (none where it is not).
    fn incidence_here(&self, i: usize) -> &[u32] {
        &self.incidence[self.incidence_offsets[i] as usize..self.incidence_offsets[i + 1] as usize]
    }

    /// Appends partition `p`'s elements from their
    /// [`InternalForces::partition_words`] (as
    /// [`InternalForces::append_held`]); an error says what does not
    /// decode.
    fn append_moved(
        &mut self,
        p: usize,
        words: &[f64],
        hinge_corners: &mut Vec<u16>,
    ) -> Result<(), String> {
        let expected = self.moved_words(p, &[]);
        if words.len() != expected {
            return Err(format!("{} words instead of {expected}", words.len()));
        }
        self.held[p] = Some(Held {
            stretch: self.stretch.len(),
            hinges: self.hinges.len(),
        });
        let materials = self.materials.len() as u64;
        // An element's own words, then its material, its key and its
        // corners' slots, each a whole number below its bound.
        let split =
            |w: &[f64], own: usize, keys: usize| -> Option<(Vec<f64>, u16, u32, Vec<u16>)> {
                let int = whole_below;
                let material = int(w[own], materials)? as u16;
                let key = int(w[own + 1], keys as u64)?;
                let corners = (w[own + 2..].iter())
                    .map(|&c| int(c, 1 << 16).map(|c| c as u16))
                    .collect::<Option<_>>()?;
                Some((w[..own].to_vec(), material, key, corners))
            };
        let (stretch, hinges) = words.split_at(MOVED_WORDS * self.partitions[p].stretch.len());
        for w in stretch.chunks_exact(MOVED_WORDS) {
            let (own, material, key, corners) = split(w, StretchElement::WORDS, self.num_stretch)
                .ok_or("a stretch element that does not decode")?;
            let e = StretchElement::from_words(&own.try_into().expect("its words"))
                .ok_or("a stretch element's vertex that is not a vertex id")?;
            self.stretch.push(e);
            self.stretch_material.push(material);
            self.stretch_key.push(key);
            self.corner_slot.extend(corners);
        }
        for w in hinges.chunks_exact(MOVED_WORDS) {
            let (own, material, key, corners) = split(w, HingeElement::WORDS, self.num_hinges)
                .ok_or("a hinge that does not decode")?;
            let e = HingeElement::from_words(&own.try_into().expect("its words"))
                .ok_or("a hinge's vertex that is not a vertex id")?;
            self.hinges.push(e);
            self.hinge_material.push(material);
            self.hinge_key.push(key);
            hinge_corners.extend(corners);
        }
        Ok(())
    }
}

/// A partition's elements and the folds of the vertices that move with
/// it, as words ([`InternalForces::partition_words`]), arrived from the
/// rank that held them.
#[derive(Clone, Debug)]
pub struct Moved {
    pub partition: usize,
    /// The vertices whose folds follow the elements, in the order sent.
    pub vertices: Vec<u32>,
    pub words: Vec<f64>,
}

/// An owned set of elements with their materials, in the order they are
/// summed (tests build their models from one).
#[derive(Clone, Debug)]
pub struct KeyOrdered {
    pub stretch: Vec<StretchElement>,
    pub stretch_material: Vec<u16>,
    pub hinges: Vec<HingeElement>,
    pub hinge_material: Vec<u16>,
    pub materials: Vec<Material>,
}

impl KeyOrdered {
    /// A borrowed view for assembled quantities.
    pub fn model(&self) -> ElasticModel<'_> {
        ElasticModel {
            stretch: &self.stretch,
            stretch_material: &self.stretch_material,
            hinges: &self.hinges,
            hinge_material: &self.hinge_material,
            materials: &self.materials,
            order: None,
        }
    }
}

/// Of `all` elements of which `kept` are in a mask: how many an evaluation
/// of those whose entry is `want` runs.
fn wanted(all: usize, kept: usize, want: bool) -> usize {
    match want {
        true => kept,
        false => all - kept,
    }
}

/// The partitions' elements cut into pieces of at most
/// [`ELEMENTS_PER_PIECE`] (each partition into about equal pieces, in
/// storage order), with the pieces' slot bounds (3 slots per stretch
/// element, 4 per hinge, as the partitions') and each partition's pieces.
fn cut_into_pieces(parts: &[Partition]) -> (Vec<Piece>, Vec<usize>, Vec<Range<usize>>) {
    let mut pieces = Vec::new();
    let mut bounds = vec![0];
    let mut pieces_of = Vec::with_capacity(parts.len());
    for (p, part) in parts.iter().enumerate() {
        let (ns, nh) = (part.stretch.len(), part.hinges.len());
        let n = ns + nh;
        let count = n.div_ceil(ELEMENTS_PER_PIECE).max(1);
        pieces_of.push(pieces.len()..pieces.len() + count);
        let mut slot = part.slots.start;
        for c in 0..count {
            // Elements [a, b) of the partition's storage order.
            let (a, b) = (c * n / count, (c + 1) * n / count);
            let stretch = (part.stretch.start + a.min(ns))..(part.stretch.start + b.min(ns));
            let hinges = (part.hinges.start + a.max(ns) - ns)..(part.hinges.start + b.max(ns) - ns);
            slot += 3 * stretch.len() + 4 * hinges.len();
            bounds.push(slot);
            pieces.push(Piece {
                partition: p as u32,
                stretch,
                hinges,
            });
        }
        debug_assert_eq!(slot, part.slots.end);
    }
    (pieces, bounds, pieces_of)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::executor::Serial;
    use weft_geom::shapes::grid;

    /// A jittered 23 × 17 grid's elements over `n_parts` random partitions,
    /// with a few kinematic vertices (no fold), a triangle that is no cloth
    /// (no element) and a damped material: the rest positions, the inverse
    /// masses and the elements.
    fn grid_elements(
        n_parts: usize,
        next: &mut impl FnMut() -> f64,
    ) -> (Vec<DVec3>, Vec<f64>, InternalForces) {
        let mut mesh = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [1.0, 0.7], [23, 17]);
        for p in &mut mesh.positions {
            p.z = 0.01 * next();
        }
        let nv = mesh.positions.len();
        let topology = Topology::build(nv, &mesh.triangles).expect("a grid");
        let part_of_tri: Vec<u32> = (0..mesh.triangles.len())
            .map(|_| ((next() * n_parts as f64) as u32).min(n_parts as u32 - 1))
            .collect();
        let inv_mass: Vec<f64> = (0..nv)
            .map(|i| if i % 29 == 3 { 0.0 } else { 1.0 })
            .collect();
        let mut tri_material = vec![Some(0u16); mesh.triangles.len()];
        tri_material[7] = None;
        let material = Material {
            stretch_damping: 2e-5,
            bend_damping: 3e-9,
            ..Material::plate(0.2, 1e5, 0.3, 1e-3)
        };
        let f = InternalForces::build(
            &mesh.triangles,
            &tri_material,
            &topology,
            &mesh.positions,
            &[material],
            &inv_mass,
            &part_of_tri,
            n_parts,
        )
        .expect("valid elements");
        (mesh.positions, inv_mass, f)
    }

    /// A copy of every element in global key order: the reference the
    /// view in place is held to.
    fn copy_in_key_order(f: &InternalForces) -> KeyOrdered {
        let pick = |order: &[u32], material: &[u16]| -> Vec<u16> {
            order.iter().map(|&i| material[i as usize]).collect()
        };
        KeyOrdered {
            stretch: (f.stretch_by_key.iter())
                .map(|&i| f.stretch[i as usize])
                .collect(),
            stretch_material: pick(&f.stretch_by_key, &f.stretch_material),
            hinges: (f.hinge_by_key.iter())
                .map(|&i| f.hinges[i as usize])
                .collect(),
            hinge_material: pick(&f.hinge_by_key, &f.hinge_material),
            materials: f.materials.clone(),
        }
    }

    /// The step's estimates read the partitioned store in key order where
    /// it lies: the same elements in the same order as a copy in key
    /// order, and so the same bits of `omega_max`, `gamma_max` and the
    /// per-material damping rates.
    #[test]
    fn key_order_read_in_place_is_the_copy_bit_for_bit() {
        let mut next = crate::uniform_numbers(0x51ed_270b_1a2c_3d4e);
        for n_parts in [1usize, 3, 11] {
            let (rest, inv_mass, f) = grid_elements(n_parts, &mut next);
            let mass: Vec<f64> = (inv_mass.iter())
                .map(|&w| if w > 0.0 { 1.0 / w } else { 0.0 })
                .collect();
            let copy = copy_in_key_order(&f);
            let (copied, in_place) = (copy.model(), f.model());
            in_place.validate(rest.len()).expect("a valid order");
            // An order that repeats an element (and so leaves one out) is refused.
            let mut twice = f.stretch_by_key.clone();
            twice[1] = twice[0];
            let repeats = ElasticModel {
                order: Some((&twice, &f.hinge_by_key)),
                ..in_place
            };
            let refused = repeats.validate(rest.len()).unwrap_err().to_string();
            assert!(refused.contains("not an order of all"), "{refused}");
            let words = |(e, m): (&StretchElement, &Material)| (e.to_words(), *m);
            assert!((copied.stretch_iter().map(words)).eq(in_place.stretch_iter().map(words)));
            let verts = |(e, _): (&HingeElement, &Material)| e.verts;
            assert!((copied.hinge_iter().map(verts)).eq(in_place.hinge_iter().map(verts)));
            let bits = |o: f64| o.to_bits();
            assert_eq!(
                bits(copied.max_frequency(&rest, &mass)),
                bits(f.max_frequency(&Serial, &rest, &mass).unwrap()),
                "{n_parts} parts"
            );
            let gamma = f.max_damping_rate(&Serial, &rest, &mass).unwrap();
            assert!(gamma > 0.0, "a damped material");
            assert_eq!(bits(copied.max_damping_rate(&rest, &mass)), bits(gamma));
            assert_eq!(
                f.damping_rates_of(0, &rest, &mass)[2].to_bits(),
                gamma.to_bits()
            );
        }
    }

    /// The incidence built by vertex equals, vertex by vertex, a sort of
    /// every dynamic corner's (vertex, class, key, corner, slot): the
    /// fold's order, global key order (stretch by triangle, then hinges by
    /// edge), whatever the partitions and pieces.
    #[test]
    fn incidence_is_every_dynamic_corner_in_global_key_order() {
        let mut next = crate::uniform_numbers(0x9e37_79b9_7f4a_7c15);
        for n_parts in [1usize, 3, 11] {
            let (rest, inv_mass, f) = grid_elements(n_parts, &mut next);
            let nv = rest.len();
            // Each element's rank in key order among its class.
            let mut stretch_rank = vec![0u32; f.stretch.len()];
            for (r, &s) in f.stretch_by_key.iter().enumerate() {
                stretch_rank[s as usize] = r as u32;
            }
            let mut hinge_rank = vec![0u32; f.hinges.len()];
            for (r, &h) in f.hinge_by_key.iter().enumerate() {
                hinge_rank[h as usize] = r as u32;
            }
            let ns = f.stretch.len();
            let mut tuples = Vec::new();
            for (piece, &start) in f.pieces.iter().zip(&f.piece_bounds) {
                for s in piece.stretch.clone() {
                    for (j, &v) in f.stretch[s].verts.iter().enumerate() {
                        let slot = start + usize::from(f.corner_slot[3 * s + j]);
                        tuples.push((v, 0, stretch_rank[s], j, slot as u32));
                    }
                }
                for h in piece.hinges.clone() {
                    for (j, &v) in f.hinges[h].verts.iter().enumerate() {
                        let slot = start + usize::from(f.corner_slot[3 * ns + 4 * h + j]);
                        tuples.push((v, 1, hinge_rank[h], j, slot as u32));
                    }
                }
            }
            tuples.retain(|t| inv_mass[t.0 as usize] > 0.0);
            tuples.sort_unstable();
            let mut slots_seen = 0;
            for i in 0..nv {
                let expected: Vec<u32> = (tuples.iter())
                    .filter(|t| t.0 as usize == i)
                    .map(|t| t.4)
                    .collect();
                assert_eq!(f.incidence(i), &expected[..], "vertex {i}, {n_parts} parts");
                slots_seen += expected.len();
            }
            assert_eq!(slots_seen, tuples.len());
            assert!(tuples.len() > 4 * f.hinges.len(), "elements of every class");
        }
    }
}
