//! The penalty-layer batches of one contact island (`crate::islands`)
//! between two internal ticks.
//!
//! An island holds its dynamic vertices' state (`x`, `v`, `tau`) while it
//! runs a segment of ticks, and every batch reads and writes only those
//! vertices (kinematic ones are read from the world; no kick moves them).
//! It runs its own schedule restricted to itself: at each tick where one of
//! its layers fires, in (tick, layer, key) order, the same batch as the
//! global schedule's — Jacobi reads of the velocities, the asleep stencils
//! skipped, the distance-bound skip, kicks summed per vertex in (layer, key)
//! order with the friction clamp, only vertices whose velocity changed get a
//! breakpoint — so every vertex ends with exactly the global schedule's
//! bits. At the internal tick that ends the segment it computes its layers'
//! kicks and hands them, in fold order, to the internal tick, which folds
//! them after the internal forces exactly where the global schedule did.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use weft_core::{nan_max, StencilKey, StencilKind, NONE};
use weft_geom::distance::{separation_lower_bound, stencil_closest, Closest, Direction};

use crate::clock::Tick;
use crate::dormancy::{Dormancy, SharedCaps};
use crate::executor::Executor;
use crate::layers::{penalty_kick, FrictionClamp, PenaltyImpulse};
use crate::trace;
use crate::world::World;

/// The normal of a stencil's last exact evaluation in this pass, scaled
/// to a norm of at most 1: the direction its later distance lower bounds
/// separate it along ([`separation_lower_bound`]).
type Anchor = Direction;

/// Islands of at least this many vertices index their vertices by a dense
/// map while they are built ([`Island::of`]).
const DENSE_LOCAL_VERTICES: usize = 64;

/// What the penalty scan decided for a stencil it read (stencils certainly
/// outside every firing layer without room to doze leave no verdict).
#[derive(Clone, Copy, Debug)]
enum Verdict {
    /// Certified outside layers `reach + 1..` (`eta_(reach+1)`) until this
    /// tick or a velocity change; reach 0: outside every layer, asleep
    /// (`crate::dormancy`).
    Doze(u32, Tick),
    /// Evaluated exactly at these positions.
    Near(Closest),
}

/// The stencil's vertices `0..split` are one primitive, `split..4` the other.
fn split_of(kind: StencilKind) -> usize {
    match kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    }
}

/// How long a stencil whose distance is at least `lower` at tick `t` (a
/// lower bound of the exact distance of the positions the engine computes
/// at `t`, rounding included: [`separation_lower_bound`]) stays
/// outside `eta` (a layer's thickness) while its vertices move no faster
/// than their speed caps `caps` (`crate::dormancy`): returns the first tick it
/// may not, and the room `lower - eta` less a rounding slack (no doze
/// unless positive).
///
/// Between its breakpoints a vertex moves on a straight segment, by exactly
/// `|v| Δt q` at a speed `|v| ≤ cap`, so from `t` to `t'` it moves by at
/// most `cap (t' - t) q` however often its velocity changes under the cap
/// (the triangle inequality over the segments); the lower bound at `t'` is
/// then at least `lower - (c_a + c_b) (t' - t) q`, `c_a`, `c_b` the largest
/// caps on each side. The caps are taken `2^-40` larger, which covers the
/// rounding of the speed test against them and of the division here.
///
/// The positions the engine computes differ from that exact motion by the
/// rounding of each breakpoint's drift `x + v Δt q` (about one ulp of the
/// coordinates, at most `2 u M` in norm, `u = 2^-53`, `M` the largest
/// coordinate on the way: at most `max |x| + lower`, since a vertex moves
/// less than `lower` before the stencil wakes). A vertex wakes its stencils
/// after at most [`crate::dormancy::BREAKPOINTS_PER_WAKE`] breakpoints, so the drift
/// rounding adds at most `1025 · 2 u M = 2050 u M` on each side, `4100 u
/// M` for both. The slack `2^-39 (1 + max |x| + |lower|)`, `16384 u` of
/// it, covers that about four times over. (It once
/// also covered the rounding of an evaluated distance, assumed a few ulps
/// of the coordinates; the bound no longer rests on an evaluated distance,
/// and on sliver triangles and nearly parallel edges that assumption was
/// false.)
pub(super) fn sleep(
    kind: StencilKind,
    lower: f64,
    eta: f64,
    x: &[DVec3; 4],
    caps: &[f64; 4],
    quantum: f64,
    t: Tick,
) -> (Tick, f64) {
    let split = split_of(kind);
    let scale = x.iter().fold(0.0f64, |m, p| m.max(p.abs().max_element()));
    let room = lower - eta - (1.0 + scale + lower.abs()) * f64::powi(2.0, -39);
    if !(room > 0.0) {
        return (t, room);
    }
    // (a NaN cap stays NaN, and then certifies nothing: `f64::max` would
    // drop it and leave the other caps)
    let cap = |r: std::ops::Range<usize>| r.map(|j| caps[j]).fold(0.0f64, |m, c| nan_max(c, m));
    let s = (cap(0..split) + cap(split..4)) * (1.0 + f64::powi(2.0, -40)) * quantum;
    let ticks = room / s; // +inf when nothing moves
    let awake_at = if ticks >= (Tick::MAX - t) as f64 {
        Tick::MAX
    } else if ticks >= 1.0 {
        t + ticks.floor() as Tick
    } else {
        return (t, 0.0); // would wake at once: not worth it
    };
    (awake_at, room)
}

/// Below this many stencils in a batch its scan and kicks run inline:
/// handing out tasks would cost more than it saves (the same bits).
const PARALLEL_MIN_STENCILS: usize = 256;

/// Stencils per task of a batch's scan and kicks on the executor.
const PENALTY_RUN: usize = 128;

/// What every island of a pass reads (nothing it writes): the world, the
/// layer constants `(eta_l, k_l, h_l)`, and how batches run.
#[derive(Clone, Copy)]
pub(super) struct Pass<'a> {
    pub world: &'a World,
    pub layer_consts: &'a [(f64, f64, Tick)],
    /// Evaluate every layer event exactly (no sleeping, no skip).
    pub exhaustive: bool,
    /// The end of the pass: the islands and their dormancy end there.
    pub pass_end: Tick,
    /// Split a batch of at least [`PARALLEL_MIN_STENCILS`] stencils over
    /// the executor's threads (off while the calm part of the internal tick
    /// runs beside the islands: it keeps the other threads busy, and a
    /// giant island's batches handed to them only delayed it).
    pub split_batches: bool,
}

/// What every island reads in a segment: the pass's [`Pass`], and the
/// speed caps the units keep for it (`super::units`).
pub(super) struct Shared<'a> {
    pub pass: Pass<'a>,
    /// Per vertex, the far stencils' speed cap (`super::far`; empty: no
    /// far stencil): a new speed above it is reported in
    /// [`SegmentOutput::fast`].
    pub far_cap: &'a [f64],
    /// The kinematic vertices' speed caps, kept once for every island
    /// (`crate::dormancy::SharedCaps`, by slot), and those that broke them
    /// at the internal tick before this segment (ascending): an island
    /// wakes its stencils of these before its first batch.
    pub kinematic_caps: &'a [f64],
    pub kinematic_woken: &'a [u32],
}

impl<'a> Shared<'a> {
    /// `pass` with the units' caps.
    pub(super) fn new(
        pass: &Pass<'a>,
        far_cap: &'a [f64],
        kinematic_caps: &'a [f64],
        kinematic_woken: &'a [u32],
    ) -> Self {
        Shared {
            pass: *pass,
            far_cap,
            kinematic_caps,
            kinematic_woken,
        }
    }

    /// Layer `l`'s constants.
    fn layer(&self, l: u32) -> (f64, f64, Tick) {
        self.pass.layer_consts[l as usize - 1]
    }
}

/// One stencil of an island.
#[derive(Clone, Copy, Debug)]
struct Member {
    key: StencilKey,
    depth: u32,
    /// Its vertices' indices in the island (`NONE`: kinematic).
    local: [u32; 4],
    /// Its vertices' indices in the island's dormancy: the island's
    /// vertices, then the kinematic ones its stencils read.
    watch: [u32; 4],
    /// Its friction coefficient.
    mu: f64,
}

/// What an island's segment changed and saw: applied by the engine in
/// island order (the islands' vertices are disjoint, so the order does not
/// change any bit), and over ranks sent to every rank.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub(super) struct SegmentOutput {
    /// The new `(x, v, tau)` of every island vertex the segment moved.
    pub moved: Vec<(u32, DVec3, DVec3, Tick)>,
    /// Breakpoints `(vertex, tick, position)`, each vertex's in time order.
    pub breakpoints: Vec<(u32, Tick, DVec3)>,
    /// The island's impulses at the internal tick ending the segment,
    /// `(vertex, impulse)` in fold order: each vertex's normal and clamped
    /// friction impulses in (layer, key) order, as separate terms.
    pub at_internal: Vec<(u32, DVec3)>,
    /// Every new velocity of a vertex whose speed broke its far stencils'
    /// cap (`Shared::far_cap`): `(vertex, speed²)`. Over ranks with the
    /// units spread, sent to every rank (each checks every far stencil).
    pub fast: Vec<(u32, f64)>,
    /// Over ranks with the units spread: the segment's breakpoints of each
    /// vertex a far stencil watches, `(vertex, count)`, sent to every rank
    /// (where the island ran, `breakpoints` tells them).
    pub far_added: Vec<(u32, u32)>,
    /// Exact evaluations, kicks and the smallest distance evaluated.
    pub evaluations: u64,
    pub kicks: u64,
    pub min_separation: f64,
    /// The tick and vertex where a value became non-finite: the island
    /// stopped there, before writing it.
    pub blew_up: Option<(Tick, u32)>,
    /// Wall seconds the segment took (the island's cost for the next one).
    pub seconds: f64,
    /// What the far stencils did (in the one output per segment and rank
    /// that carries them, `super::units`).
    #[serde(skip)]
    pub far: super::units::FarCounts,
}

impl SegmentOutput {
    /// Drops every entry of the vertices `gone` (ascending): over ranks,
    /// the results of units merged and run again.
    pub(super) fn drop_vertices(&mut self, gone: &[u32]) {
        let kept = |i: u32| gone.binary_search(&i).is_err();
        self.moved.retain(|m| kept(m.0));
        self.breakpoints.retain(|b| kept(b.0));
        self.at_internal.retain(|k| kept(k.0));
        self.fast.retain(|f| kept(f.0));
        self.far_added.retain(|f| kept(f.0));
    }
}

/// A contact island's stencils, its vertices' state while it runs, and
/// what persists over the pass (dormancy, anchors). (`Default`: an island
/// placed on another rank, never run here.)
#[derive(Debug, Default)]
pub(super) struct Island {
    /// Its dynamic vertices (global ids, ascending) and, per vertex, the
    /// inverse mass.
    vertices: Vec<u32>,
    inv_mass: Vec<f64>,
    members: Vec<Member>,
    max_depth: u32,
    /// The kinematic vertices' slots in the shared caps
    /// (`Shared::kinematic_caps`), as `kinematic`.
    kin_slot: Vec<u32>,
    /// The kinematic vertices its stencils read (global ids, ascending):
    /// the dormancy watches them after the island's own.
    kinematic: Vec<u32>,
    /// The last segment ended with an internal tick: every vertex may have
    /// a new velocity, shown to the dormancy before the next segment.
    after_internal: bool,
    dormancy: Dormancy,
    anchors: Vec<Option<Anchor>>,
    // The state during a segment of the vertices a batch of it moved
    // (`moved`, listed in `moved_list`); the others' is the world's (read
    // there: copying every vertex in at every segment cost more than the
    // segment's batches of a small island).
    x: Vec<DVec3>,
    v: Vec<DVec3>,
    tau: Vec<Tick>,
    moved: Vec<bool>,
    moved_list: Vec<u32>,
    // A batch's scratch.
    acc: Vec<DVec3>,
    is_touched: Vec<bool>,
    touched: Vec<u32>,
    friction: FrictionClamp,
    scan: Vec<u32>,
    verdicts: Vec<(u32, Verdict)>,
    hits: Vec<(u32, Closest)>,
    kick_items: Vec<(u32, u32)>,
    kicks: Vec<Option<PenaltyImpulse>>,
    /// The kicks that are not zero: (stencil, index in `kicks`).
    kicked: Vec<(u32, u32)>,
}

impl Island {
    /// The island of the dynamic `vertices` (ascending) of the stencils
    /// `members` (key, depth; in key order), all awake, from tick `start`,
    /// where the world holds its vertices' state; its kinematic vertices'
    /// speed caps are those of `shared` (which keeps every one).
    pub(super) fn of(
        vertices: Vec<u32>,
        members: Vec<(StencilKey, u32)>,
        w: &World,
        start: Tick,
        shared: &SharedCaps,
    ) -> Self {
        // A global vertex's index among the island's: a dense map for a
        // large island (a search per stencil vertex was most of building
        // the twister's giant one, on one thread at the pass's start), a
        // search for a small one (the map's memory would cost more).
        let dense = (vertices.len() >= DENSE_LOCAL_VERTICES).then(|| {
            let mut map = vec![NONE; w.num_vertices()];
            for (j, &i) in vertices.iter().enumerate() {
                map[i as usize] = j as u32;
            }
            map
        });
        let local = |i: u32| match &dense {
            Some(map) => map[i as usize],
            None => vertices.binary_search(&i).map_or(NONE, |j| j as u32),
        };
        let mut kinematic: Vec<u32> = (members.iter())
            .flat_map(|a| a.0.v)
            .filter(|&i| local(i) == NONE)
            .collect();
        kinematic.sort_unstable();
        kinematic.dedup();
        let n = vertices.len();
        let watch = |i: u32| match local(i) {
            NONE => (n + kinematic.binary_search(&i).expect("listed")) as u32,
            j => j,
        };
        let members: Vec<Member> = (members.iter())
            .map(|&(key, depth)| Member {
                key,
                depth,
                local: key.v.map(local),
                watch: key.v.map(watch),
                mu: w.stencil_friction(&key),
            })
            .collect();
        let mut dormancy = Dormancy::default();
        let watched: Vec<[u32; 4]> = members.iter().map(|m| m.watch).collect();
        let depths: Vec<u32> = members.iter().map(|m| m.depth).collect();
        dormancy.reset(&watched, &depths, n + kinematic.len(), start);
        for (j, &i) in vertices.iter().enumerate() {
            dormancy.observe(j, w.v[i as usize]);
        }
        let kin_slot = (kinematic.iter())
            .map(|&i| {
                shared
                    .slot(i)
                    .expect("every active stencil's kinematic vertex") as u32
            })
            .collect();
        Island {
            kin_slot,
            inv_mass: vertices.iter().map(|&i| w.inv_mass[i as usize]).collect(),
            max_depth: members.iter().map(|m| m.depth).max().unwrap_or(0),
            kinematic,
            after_internal: false,
            anchors: vec![None; members.len()],
            x: vec![DVec3::ZERO; n],
            v: vec![DVec3::ZERO; n],
            tau: vec![0; n],
            moved: vec![false; n],
            moved_list: Vec::new(),
            acc: vec![DVec3::ZERO; n],
            is_touched: vec![false; n],
            friction: FrictionClamp::new(n),
            vertices,
            members,
            dormancy,
            touched: Vec::new(),
            scan: Vec::new(),
            verdicts: Vec::new(),
            hits: Vec::new(),
            kick_items: Vec::new(),
            kicks: Vec::new(),
            kicked: Vec::new(),
        }
    }

    /// Its dynamic vertices, ascending.
    pub(super) fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// After a visit: whether nothing is awake, and then the tick it is
    /// next due to wake (`Some(Tick::MAX)`: none); and the most breakpoints
    /// any of its vertices has had since it last woke its stencils. When
    /// nothing is awake it also writes its vertices' speed caps into
    /// `mirror` (by global vertex, the bits of an `f64`; the units' islands
    /// hold disjoint vertices): what lets the units skip it without a visit
    /// while nothing can wake it. (A unit with a stencil awake is visited
    /// next time anyway: its caps are not read, and the giant island does
    /// not write its tens of thousands at every segment.)
    pub(super) fn report(&mut self, mirror: &[AtomicU64]) -> (Option<Tick>, u32) {
        let n = self.vertices.len();
        let due =
            (self.dormancy.max_reach() == 0).then(|| self.dormancy.next_due().unwrap_or(Tick::MAX));
        if due.is_some() {
            for (j, &i) in self.vertices.iter().enumerate() {
                mirror[i as usize].store(self.dormancy.cap(j).to_bits(), Ordering::Relaxed);
            }
        }
        (due, self.dormancy.most_breakpoints(n))
    }

    /// Its vertices had `ticks` internal ticks' breakpoints while it was
    /// not visited, none of them above its cap (the units' check).
    pub(super) fn catch_up(&mut self, ticks: u32) {
        if ticks > 0 {
            self.dormancy.add_breakpoints(self.vertices.len(), ticks);
        }
    }

    /// How many stencils it holds.
    pub(super) fn stencils(&self) -> usize {
        self.members.len()
    }

    /// Its stencils (key, depth), in key order.
    pub(super) fn members(&self) -> impl Iterator<Item = (StencilKey, u32)> + '_ {
        self.members.iter().map(|m| (m.key, m.depth))
    }

    /// Runs the island's penalty-only batches at the ticks of `[s, e)` (no
    /// internal tick lies in it) and, when `internal_at_e`, computes its
    /// kicks at the internal tick `e`. The world holds the island's vertices'
    /// state at `s` and is not written.
    pub(super) fn run_segment<E: Executor>(
        &mut self,
        exec: &E,
        sh: &Shared<'_>,
        (s, e): (Tick, Tick),
        internal_at_e: bool,
    ) -> Option<SegmentOutput> {
        if std::mem::take(&mut self.after_internal) {
            // The internal tick before this segment gave every vertex a new
            // velocity (and a breakpoint): stencils whose vertices broke
            // their speed caps wake, the others' certificates stand.
            let w = sh.pass.world;
            for (j, &i) in self.vertices.iter().enumerate() {
                self.dormancy.observe(j, w.v[i as usize]);
            }
        }
        // The kinematic vertices that broke their shared caps at that tick
        // (a new island is awake already).
        let n = self.vertices.len();
        for &i in sh.kinematic_woken {
            if let Ok(k) = self.kinematic.binary_search(&i) {
                self.dormancy.wake_vertex(n + k);
            }
        }
        // Nothing awake and nothing due to wake before the segment's last
        // batch: no batch of the segment reads a stencil, so none kicks.
        let last = if internal_at_e {
            e
        } else {
            e.saturating_sub(1)
        };
        let idle =
            self.dormancy.max_reach() == 0 && self.dormancy.next_due().is_none_or(|due| due > last);
        self.after_internal = internal_at_e;
        if idle {
            return None;
        }
        let clock = Instant::now();
        let mut out = SegmentOutput {
            min_separation: f64::INFINITY,
            ..Default::default()
        };
        {
            self.run_ticks(exec, sh, s, e, &mut out);
            if internal_at_e && out.blew_up.is_none() {
                let firing: Vec<u32> = (1..=self.max_depth)
                    .filter(|&l| e % sh.layer(l).2 == 0)
                    .collect();
                if !firing.is_empty() {
                    // (It applies nothing, so it cannot blow up.)
                    let _ = self.batch(exec, sh, e, &firing, true, &mut out);
                }
            }
            for &j in &self.moved_list {
                let j = j as usize;
                self.moved[j] = false;
                let i = self.vertices[j];
                out.moved.push((i, self.x[j], self.v[j], self.tau[j]));
            }
            self.moved_list.clear();
        }
        out.seconds = clock.elapsed().as_secs_f64();
        Some(out)
    }

    /// The penalty-only batches at the ticks of `[s, e)` where one of the
    /// island's layers fires and may read a stencil, in tick order, until a
    /// value blows up.
    ///
    /// A batch whose outermost firing layer lies beyond every listed
    /// stencil's reach reads nothing and kicks nothing, so only the ticks of
    /// layers `1..=reach` (the largest reach) are visited; a stencil that
    /// wakes at a due tick raises the reach from that tick on.
    fn run_ticks<E: Executor>(
        &mut self,
        exec: &E,
        sh: &Shared<'_>,
        s: Tick,
        e: Tick,
        out: &mut SegmentOutput,
    ) {
        // The first tick of layer l at or after `from` (clocks tick at
        // n h_l, n ≥ 1).
        let at_or_after = |from: Tick, l: u32| {
            let p = sh.layer(l).2;
            from.max(1).div_ceil(p) * p
        };
        let mut firing: Vec<u32> = Vec::with_capacity(self.max_depth as usize);
        let mut from = s;
        while from < e {
            let reach = self.dormancy.max_reach();
            let t = (1..=reach)
                .map(|l| at_or_after(from, l))
                .min()
                .unwrap_or(Tick::MAX);
            // Stencils due to wake at or before that tick may raise the
            // reach (and add firing layers at it): wake them and look again
            // from their tick.
            if let Some(due) = self.dormancy.next_due().filter(|&due| due <= t && due < e) {
                self.dormancy.wake_due(due.max(from));
                from = due.max(from);
                continue;
            }
            if t >= e {
                break;
            }
            firing.clear();
            firing.extend((1..=reach).filter(|&l| t % sh.layer(l).2 == 0));
            if let Err(j) = self.batch(exec, sh, t, &firing, false, out) {
                out.blew_up = Some((t, self.vertices[j as usize]));
                return;
            }
            from = t + 1;
        }
    }

    /// Position of island vertex `j` (or of kinematic vertex `i`, from the
    /// world) at tick `t`, by the engine's drift `x + (t - tau) q v`.
    #[inline]
    fn position(&self, w: &World, local: u32, i: u32, t: Tick) -> DVec3 {
        let (x, v, tau) = if local != NONE && self.moved[local as usize] {
            let j = local as usize;
            (self.x[j], self.v[j], self.tau[j])
        } else {
            let i = i as usize;
            (w.x[i], w.v[i], w.tau[i])
        };
        w.lattice.drift(x, v, tau, t)
    }

    /// Velocity of a stencil vertex (the island's, or a kinematic one's).
    #[inline]
    fn velocity(&self, w: &World, local: u32, i: u32) -> DVec3 {
        if local != NONE && self.moved[local as usize] {
            self.v[local as usize]
        } else {
            w.v[i as usize]
        }
    }

    /// One batch at tick `t` of the layers `firing` (ascending), its
    /// figures added to `out`. A penalty-only batch applies its kicks to the
    /// island's vertices (breakpoints to `out`) and returns the island
    /// vertex whose new state is not finite, if any (it and the later ones
    /// are not applied). At an internal tick (`internal`) the kicks go to
    /// `out.at_internal` in fold order instead.
    fn batch<E: Executor>(
        &mut self,
        exec: &E,
        sh: &Shared<'_>,
        t: Tick,
        firing: &[u32],
        internal: bool,
        out: &mut SegmentOutput,
    ) -> Result<(), u32> {
        let w = sh.pass.world;
        let first = firing[0];
        let eta_first = sh.layer(first).0;
        // Phase 1: the closest-point data of the awake stencils of the
        // outermost firing layer (which holds every stencil firing now, and
        // whose eta is the largest, so a stencil certainly outside it is
        // outside every firing layer), in key order.
        self.dormancy.wake_due(t);
        self.scan.clear();
        let dormancy = &self.dormancy;
        for list in dormancy.reading_lists(first) {
            self.scan.extend_from_slice(list);
        }
        if self.scan.is_empty() {
            return Ok(()); // nothing read: nothing kicks
        }
        self.scan.sort_unstable();
        let mut verdicts = std::mem::take(&mut self.verdicts);
        verdicts.clear();
        let this = &*self;
        let scan = |run: &[u32], verdicts: &mut Vec<(u32, Verdict)>| {
            for &a in run {
                let m = &this.members[a as usize];
                let x: [DVec3; 4] =
                    std::array::from_fn(|j| this.position(w, m.local[j], m.key.v[j], t));
                let lower = this.anchors[a as usize].map_or(f64::NEG_INFINITY, |n| {
                    separation_lower_bound(m.key.kind, n, &x)
                });
                // Its exact distance is certainly outside every firing
                // layer: no contact force is skipped. It sleeps (outside
                // eta_1) or dozes (outside the layers it is not in) for as
                // long as its vertices' speed caps certify it. Skipping
                // leaves the bits of an evaluation wherever the evaluated
                // distance is not below the exact one by more than
                // `lower - eta_first`: on well-shaped stencils it is within
                // a few ulps; on sliver triangles and nearly parallel edges
                // it has been measured up to 2e-11 of the coordinates below
                // (`weft_geom::distance`), where an evaluation could kick a
                // stencil whose exact distance is outside.
                if lower >= eta_first && !sh.pass.exhaustive {
                    let n = this.vertices.len();
                    let caps = m.watch.map(|j| match (j as usize).checked_sub(n) {
                        None => this.dormancy.cap(j as usize),
                        Some(k) => sh.kinematic_caps[this.kin_slot[k] as usize],
                    });
                    let q = w.lattice.quantum;
                    let (awake_at, room) = sleep(m.key.kind, lower, sh.layer(1).0, &x, &caps, q, t);
                    if room > 0.0 {
                        verdicts.push((a, Verdict::Doze(0, awake_at)));
                    } else {
                        // The layers 1..=reach it may be inside (reach <
                        // first: it is outside eta_first).
                        let reach =
                            (1..first).take_while(|&l| sh.layer(l).0 > lower).count() as u32;
                        if reach > 0 {
                            let eta = sh.layer(reach + 1).0;
                            let (awake_at, room) = sleep(m.key.kind, lower, eta, &x, &caps, q, t);
                            if room > 0.0 {
                                verdicts.push((a, Verdict::Doze(reach, awake_at)));
                            }
                        }
                    }
                } else {
                    verdicts.push((a, Verdict::Near(stencil_closest(m.key.kind, &x))));
                }
            }
        };
        let list = &self.scan;
        if sh.pass.split_batches && list.len() >= PARALLEL_MIN_STENCILS {
            // A big batch (a giant island): its scan on the executor's
            // threads, in runs (Algorithm 4's node-level sharing).
            let _span = trace::span_with("penalty closest", "stencils", list.len() as u64);
            let parts = exec.map(list.len().div_ceil(PENALTY_RUN), &|r| {
                let mut part = Vec::new();
                scan(
                    &list[r * PENALTY_RUN..((r + 1) * PENALTY_RUN).min(list.len())],
                    &mut part,
                );
                part
            });
            verdicts.extend(parts.into_iter().flatten());
        } else {
            scan(list, &mut verdicts);
        }
        // Apply the verdicts; only the evaluated stencils (hits) can kick.
        // A certificate outlives internal ticks (it assumes speed caps, not
        // velocities), so it holds at an internal tick's batch too.
        self.hits.clear();
        for &(a, verdict) in &verdicts {
            match verdict {
                Verdict::Doze(reach, until) => {
                    // Certified to the end of the pass (where the islands
                    // end): no wake tick to keep.
                    let until = if until >= sh.pass.pass_end {
                        Tick::MAX
                    } else {
                        until
                    };
                    self.dormancy.doze(a, reach, until);
                }
                Verdict::Near(c) => {
                    out.evaluations += 1;
                    out.min_separation = out.min_separation.min(c.d);
                    self.anchors[a as usize] = Some(Direction::along(c.n));
                    self.hits.push((a, c));
                }
            }
        }
        self.verdicts = verdicts;
        // Phase 2: the kicks of the stencils inside their layer, computed
        // independently (they read the velocities at the start of the
        // batch), in (layer, key) order.
        self.kick_items.clear();
        for &l in firing {
            let eta_l = sh.layer(l).0;
            for (h, (a, c)) in self.hits.iter().enumerate() {
                if self.members[*a as usize].depth >= l && c.d < eta_l {
                    self.kick_items.push((l, h as u32)); // else a zero kick (NaN too)
                }
            }
        }
        let mut kicks = std::mem::take(&mut self.kicks);
        kicks.clear();
        let this = &*self;
        let kick_of = |&(l, h): &(u32, u32)| {
            let (a, c) = &this.hits[h as usize];
            let m = &this.members[*a as usize];
            let (eta_l, k_l, step) = sh.layer(l);
            let v = std::array::from_fn(|j| this.velocity(w, m.local[j], m.key.v[j]));
            let inv = m.local.map(|j| {
                if j == NONE {
                    0.0
                } else {
                    this.inv_mass[j as usize]
                }
            });
            penalty_kick(eta_l, k_l, w.lattice.seconds(step), c, &v, &inv, m.mu)
        };
        let items = &self.kick_items;
        if sh.pass.split_batches && items.len() >= PARALLEL_MIN_STENCILS {
            let _span = trace::span_with("penalty kicks", "stencils", items.len() as u64);
            let parts = exec.map(items.len().div_ceil(PENALTY_RUN), &|r| {
                let run = &items[r * PENALTY_RUN..((r + 1) * PENALTY_RUN).min(items.len())];
                run.iter().map(kick_of).collect::<Vec<_>>()
            });
            kicks.extend(parts.into_iter().flatten());
        } else {
            kicks.extend(items.iter().map(kick_of));
        }
        // Fold in (layer, key) order: the friction clamp's sums first, then
        // each kick with its friction scaled as a whole (`FrictionClamp`).
        self.kicked.clear();
        for (n, (&(_, h), k)) in self.kick_items.iter().zip(&kicks).enumerate() {
            if k.is_some() {
                self.kicked.push((self.hits[h as usize].0, n as u32));
            }
        }
        let kick = |n: u32| kicks[n as usize].as_ref().expect("a kick");
        for &(a, n) in &self.kicked {
            let m = &self.members[a as usize];
            if m.mu > 0.0 {
                self.friction.add(&m.local, kick(n));
            }
        }
        for &(a, n) in &self.kicked {
            let (m, k) = (&self.members[a as usize], kick(n));
            let rubs = m.mu > 0.0;
            let s = if rubs {
                self.friction.scale(&m.local, k)
            } else {
                0.0
            };
            for j in 0..4 {
                let local = m.local[j];
                if local == NONE {
                    continue;
                }
                let friction = k.friction[j] * s;
                if internal {
                    out.at_internal.push((m.key.v[j], k.normal[j]));
                    if rubs {
                        out.at_internal.push((m.key.v[j], friction));
                    }
                } else {
                    let jl = local as usize;
                    self.acc[jl] += k.normal[j];
                    if rubs {
                        self.acc[jl] += friction;
                    }
                    if !self.is_touched[jl] {
                        self.is_touched[jl] = true;
                        self.touched.push(local);
                    }
                }
            }
        }
        for &(a, _) in &self.kicked {
            let m = &self.members[a as usize];
            if m.mu > 0.0 {
                self.friction.clear(&m.local);
            }
        }
        out.kicks += self.kicked.len() as u64;
        self.kicks = kicks;
        if internal {
            Ok(())
        } else {
            self.apply(w, sh.far_cap, t, out)
        }
    }

    /// The end of a penalty-only batch at tick `t`: its touched vertices in
    /// order take their new velocity and their position at `t`, and get a
    /// breakpoint where the velocity changed. The first vertex whose new
    /// state is not finite stops it (returned; it and the later ones are
    /// not applied, and the batch's impulses are forgotten).
    fn apply(
        &mut self,
        w: &World,
        far_cap: &[f64],
        t: Tick,
        out: &mut SegmentOutput,
    ) -> Result<(), u32> {
        let mut result = Ok(());
        for &j in &self.touched {
            let jl = j as usize;
            let impulse = std::mem::take(&mut self.acc[jl]);
            self.is_touched[jl] = false;
            if result.is_err() {
                continue;
            }
            let v_old = self.velocity(w, j, self.vertices[jl]);
            let v_new = v_old + impulse * self.inv_mass[jl];
            if v_new != v_old {
                let x = self.position(w, j, self.vertices[jl], t);
                if !(x.is_finite() && v_new.is_finite()) {
                    result = Err(j);
                    continue;
                }
                (self.x[jl], self.v[jl], self.tau[jl]) = (x, v_new, t);
                if !self.moved[jl] {
                    self.moved[jl] = true;
                    self.moved_list.push(j);
                }
                self.dormancy.observe(jl, v_new);
                let i = self.vertices[jl];
                if let Some(&cap) = far_cap.get(i as usize) {
                    let speed2 = v_new.length_squared();
                    if speed2 > cap * cap {
                        out.fast.push((i, speed2));
                    }
                }
                out.breakpoints.push((i, t, x));
            }
        }
        self.touched.clear();
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift64*: uniform numbers in [0, 1).
    struct Rng(u64);

    impl Rng {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }

        fn unit(&mut self) -> DVec3 {
            loop {
                let v = DVec3::new(self.uniform(), self.uniform(), self.uniform()) * 2.0 - 1.0;
                if (0.01..=1.0).contains(&v.length_squared()) {
                    return v.normalize();
                }
            }
        }
    }

    /// A certificate whose length in ticks is near the end of the clock,
    /// where `Tick::MAX - t` is rounded as a float, ends after its tick
    /// without overflowing, and a cap that is not a number certifies
    /// nothing. (Non-finite positions never give a bound that could
    /// certify: `weft-geom`'s `tests/separation.rs`.)
    #[test]
    fn certificates_near_the_end_of_the_clock_or_with_a_nan_cap() {
        let x0 = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
        let caps = [1.0, 0.0, 0.0, 0.0];
        for t in [1, 1500, 1 << 20] {
            for k in 0..4096u64 {
                let lower = 1.844_674_407_370_95e19 + (k * 1024) as f64;
                let (at, room) = sleep(StencilKind::VertexFace, lower, 0.0, &x0, &caps, 1.0, t);
                assert!(room > 0.0 && at > t, "{t}, {k}: {at}");
            }
        }
        // A cap that is not a number certifies nothing (wherever it is).
        for j in 0..4 {
            let mut caps = [1.0, 0.5, 0.0, 0.25];
            caps[j] = f64::NAN;
            for kind in [StencilKind::VertexFace, StencilKind::EdgeEdge] {
                let (at, _) = sleep(kind, 10.0, 1.0, &x0, &caps, 1.0, 7);
                assert_eq!(at, 7, "{kind:?}, NaN cap of vertex {j}");
            }
        }
    }

    /// A certificate made under speed caps holds however the velocities
    /// change under them: vertices driven at their caps straight at each
    /// other, turning at up to `BREAKPOINTS_PER_WAKE` breakpoints drifted
    /// as the engine drifts them (`x + v (t - tau) q`), never come within
    /// `eta` before the tick the certificate names. A bound that forgot a
    /// side, a vertex or the turns would let them.
    #[test]
    fn a_sleep_certificate_holds_under_any_velocities_below_the_caps() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let (eta, q) = (1e-3, 2.5e-9);
        let mut certified = 0;
        let (mut head_on_cases, mut tight) = (0, 0);
        for case in 0..400 {
            let kind = if case % 2 == 0 {
                StencilKind::VertexFace
            } else {
                StencilKind::EdgeEdge
            };
            let split = split_of(kind);
            let far = eta * (1.5 + 8.0 * rng.uniform());
            let offset = DVec3::new(0.3, -0.7, 1.1) * (case as f64 * 0.01);
            let mut x: [DVec3; 4] =
                std::array::from_fn(|j| offset + rng.unit() * 0.02 * (j as f64 + 1.0));
            // Move the first primitive so that the stencil is `far` apart.
            let c = stencil_closest(kind, &x);
            let shift = c.n * (far - c.d);
            for p in &mut x[..split] {
                *p += shift;
            }
            let c = stencil_closest(kind, &x);
            // Head on: each side at one speed straight at the other, so
            // the primitives translate and close by exactly the bound.
            let head_on = case % 4 < 2;
            let mut caps: [f64; 4] = std::array::from_fn(|_| 0.05 + rng.uniform());
            if head_on {
                caps = std::array::from_fn(|j| if j < split { caps[0] } else { caps[3] });
            }
            let lower = separation_lower_bound(kind, Direction::along(c.n), &x);
            let t0: Tick = 1 << 30;
            let (awake_at, room) = sleep(kind, lower, eta, &x, &caps, q, t0);
            if !(room > 0.0) || awake_at == Tick::MAX {
                continue;
            }
            certified += 1;
            // Drive every vertex at its cap, mostly along the closing
            // direction, turning at random ticks up to the wake tick.
            let closing = |j: usize| if j < split { -c.n } else { c.n };
            let mut state: [(DVec3, DVec3, Tick); 4] =
                std::array::from_fn(|j| (x[j], closing(j) * caps[j], t0));
            let turns = 1 + (rng.uniform() * 1023.0) as u64;
            let mut closest = f64::INFINITY;
            for k in 1..=turns {
                let t = t0 + (awake_at - t0) * k / turns;
                let at: [DVec3; 4] = std::array::from_fn(|j| {
                    state[j].0 + state[j].1 * ((t - state[j].2) as f64 * q)
                });
                let d = stencil_closest(kind, &at).d;
                closest = closest.min(d);
                assert!(
                    d >= eta,
                    "case {case}: {d} < eta = {eta} at turn {k} of {turns}, before the wake tick"
                );
                for j in 0..4 {
                    let dir = if head_on || rng.uniform() < 0.8 {
                        closing(j)
                    } else {
                        rng.unit()
                    };
                    let mut v = dir * caps[j];
                    // The dormancy lets a velocity stand while |v|^2 <= cap^2.
                    while v.length_squared() > caps[j] * caps[j] {
                        v *= 1.0 - f64::EPSILON;
                    }
                    state[j] = (at[j], v, t);
                }
            }
            if head_on {
                head_on_cases += 1;
                if closest < eta + 1e-3 * (far - eta) {
                    tight += 1;
                }
            }
        }
        assert!(certified > 300, "only {certified} cases certified");
        // The bound is not slack: driven head on, the stencil comes within
        // a thousandth of its room of eta.
        assert_eq!(tight, head_on_cases, "head-on cases that came close");
    }
}
