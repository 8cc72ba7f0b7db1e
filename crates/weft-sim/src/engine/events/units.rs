//! The units of work of a pass's penalty stage: the contact islands a rank
//! runs, and with `contact.split_islands` the far stencils
//! ([`super::far`]) watched beside them and promoted into them when they may
//! come within `eta_1`.
//!
//! A unit is any union of islands of the stencils it runs (the same bits as
//! running them apart). Without the split the units are the islands of the
//! whole active set, the small ones packed (`Islands::packed`); over ranks
//! each runs on one rank for the pass. With it, each island of the near
//! stencils is a unit of its own (packed, a promotion would merge every
//! island of the units it touches); over ranks the units are spread
//! ([`Spread`]): every rank knows every unit, runs those placed on it and
//! watches some far stencils, and the engine agrees the promotions between
//! the steps here ([`Units::renew`], [`Units::promote_agreed`],
//! [`Units::run`], [`Units::check`], [`Units::check_agreed`],
//! [`Units::rerun`], [`Units::finish`]), so a promotion may merge units of
//! two ranks; the new unit's vertices then move to its rank. A promotion merges the units
//! holding the far stencil's dynamic vertices, the stencil and its vertices
//! outside every unit into one new unit, built from the world's state at the
//! segment start (all awake: dormancy skips only zero kicks); if the segment
//! already ran, the new unit runs it again and its output replaces those of
//! the units it merged.
//!
//! Every choice here (units, promotions, reruns) follows from the state, not
//! from the executor: the counts of evaluations agree on every one.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use weft_core::{StencilKey, NONE};

use super::far::{Checked, FarSet};
use super::island::{Island, Pass, SegmentOutput, Shared};
use super::{BINS_PER_RANK, BINS_PER_THREAD, CAP_CHECK_RUN};
use crate::clock::Tick;
use crate::dormancy::{changes_cap, SharedCaps, BREAKPOINTS_PER_WAKE};
use crate::executor::Executor;
use crate::trace;
use crate::world::World;

/// What the far stencils did in a pass, summed over segments and ranks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct FarCounts {
    /// Far stencils when the pass started.
    pub far: u64,
    /// Far stencils promoted into the units.
    pub promoted: u64,
    /// Units that ran a segment again after a promotion.
    pub reruns: u64,
    /// The layer events of the pass of the largest unit at its end (the
    /// largest over ranks).
    pub largest: u64,
}

/// The units this rank runs in a pass.
#[derive(Debug, Default)]
pub(super) struct Units {
    /// Each unit that runs here, locked by the task that runs it; `None`
    /// for a unit another rank runs and for one emptied into another by a
    /// merge. (Boxed: spread over ranks a rank runs a share of the units,
    /// and an inline island per unit of every rank was 744 bytes each,
    /// allocated and first touched at every pass start: on the 100k
    /// twister over 8 simulated ranks, page faults for about 60 ms of each
    /// rank's pass.)
    islands: Vec<UnitSlot>,
    /// Whether a unit still runs (not merged into another).
    live: Vec<bool>,
    /// The live units that run here, ascending: what a segment's
    /// bookkeeping loops over (spread over ranks, a rank runs a share of
    /// every rank's units, and a loop over all of them at every segment
    /// was work that did not shrink with the ranks).
    mine: Vec<u32>,
    /// The dynamic vertices of those units, ascending (kept through the
    /// merges): what the speed-cap check after an internal tick scans.
    my_vertices: Vec<u32>,
    /// Each unit's cost: its stencils at first, then the seconds its last
    /// segment took; units are dealt largest first.
    cost: Vec<f64>,
    /// Per vertex: the unit holding it (`NONE`: none).
    unit_of_vertex: Vec<u32>,
    far: FarSet,
    /// The last segment ended with an internal tick.
    after_internal: bool,
    /// To report with the next segment: the pass-start far count and
    /// certificate evaluations.
    pending: (FarCounts, Checked),
    /// Per depth `d`: the layer events of a stencil of depth `d` in the
    /// pass.
    events_at_depth: Vec<u64>,
    /// The kinematic vertices' speed caps, kept once for every unit (each
    /// unit would otherwise show every internal tick's rod velocities to
    /// its own caps), and those that broke them at the last internal tick.
    kinematic: SharedCaps,
    kinematic_woken: Vec<u32>,
    /// Per unit, after its last visit: `Some(due)` when nothing of it was
    /// awake (`due`: its next wake tick), the most breakpoints of its
    /// vertices since they woke their stencils, and the internal ticks it
    /// was skipped since. With each vertex's speed cap (`caps`, the bits of
    /// an `f64`), what tells that a unit would find nothing to do.
    quiet: Vec<Option<Tick>>,
    most_breakpoints: Vec<u32>,
    skipped: Vec<u32>,
    caps: Vec<AtomicU64>,
    /// Over ranks with `contact.split_islands`, the units are spread
    /// (`spread`): per unit the rank running it (every rank agrees), and
    /// the spec of each unit another rank runs (what a merge here would
    /// build it from). Not spread: every unit runs here.
    spread: bool,
    rank_of: Vec<u32>,
    remote: Vec<Option<UnitSpec>>,
    me: u32,
    /// Spread over ranks: every rank's far stencils (key, depth; a
    /// promotion names one by its index here), and per vertex the ranks
    /// watching a far stencil of it (CSR) — where its new states, speeds
    /// and breakpoints go. `far` holds the far stencils this rank watches.
    far_all: Vec<(StencilKey, u32)>,
    watcher_start: Vec<u32>,
    watcher_ranks: Vec<u32>,
    /// Spread over ranks, per vertex: 0 for a vertex of a far stencil
    /// (every new speed of it is reported, for the ranks watching it to
    /// compare with their caps), `+inf` for the others.
    report_cap: Vec<f64>,
    /// The segment's far-stencil counts and evaluations so far
    /// ([`Units::renew`] to [`Units::finish`]).
    seg_counts: FarCounts,
    seg_checked: Checked,
    /// The new units of the last promotion that run here, to build
    /// ([`Units::build`]).
    to_build: Vec<(u32, Mutex<Option<UnitSpec>>)>,
}

/// How the units are spread over ranks: this rank, each unit's rank, and
/// every rank's far stencils (key, depth) with the rank watching each.
#[derive(Debug, Default)]
pub(super) struct Spread {
    pub me: u32,
    pub rank_of: Vec<u32>,
    pub far_all: Vec<(StencilKey, u32)>,
    pub watcher: Vec<u32>,
}

/// Over ranks with the units spread, per vertex: its home (where a unit
/// of loose vertices is placed: the owner under the placement by size) and
/// its owner (where its state is current). Empty on one memory.
pub(super) type Homes<'a> = (&'a [u32], &'a [u32]);

/// A vertex whose unit moved to another rank: `(vertex, from, to)`.
pub(super) type Move = (u32, u32, u32);

/// What a promotion merged: the new units (every rank's), the units
/// emptied into them, the dynamic vertices of the new units, and the
/// vertices whose unit now runs on another rank.
#[derive(Debug, Default)]
pub(super) struct Merged {
    pub changed: Vec<u32>,
    pub emptied: Vec<u32>,
    pub vertices: Vec<u32>,
    pub moves: Vec<Move>,
}

/// A unit to build: its dynamic vertices (ascending) and its stencils
/// (key, depth; in key order).
pub(super) type UnitSpec = (Vec<u32>, Vec<(StencilKey, u32)>);

/// A unit's island where it runs here (see [`Units::islands`]).
type UnitSlot = Mutex<Option<Box<Island>>>;

/// Every kinematic vertex of the stencils `active`, ascending, once: what a
/// pass's units may come to read of them (a merged unit any). (Marked per
/// vertex: listed four per stencil before a dedup, they were a megabyte at
/// the pass start on the 50k twister, where a rank's memory peaks.)
pub(super) fn kinematic_of<'a>(
    w: &World,
    active: impl Iterator<Item = &'a StencilKey>,
) -> Vec<u32> {
    let mut read = vec![false; w.num_vertices()];
    for i in active.flat_map(|k| k.v) {
        read[i as usize] |= w.inv_mass[i as usize] == 0.0;
    }
    (0..read.len() as u32)
        .filter(|&i| read[i as usize])
        .collect()
}

/// The island in a unit's slot: the caller runs or reads a unit that runs
/// here.
fn running(slot: &mut Option<Box<Island>>) -> &mut Island {
    slot.as_mut().expect("a unit that runs here")
}

impl Units {
    /// The units `specs`, built from the world's state at the pass start
    /// `t0` (on the executor), and the far stencils watched beside them
    /// (`checked`: what choosing them evaluated); `kinematic`: the
    /// kinematic vertices of the active stencils ([`kinematic_of`]).
    pub(super) fn new<E: Executor>(
        exec: &E,
        w: &World,
        specs: Vec<UnitSpec>,
        kinematic: Vec<u32>,
        far: FarSet,
        checked: Checked,
        t0: Tick,
        events_at_depth: Vec<u64>,
        spread: Option<Spread>,
    ) -> Self {
        let spreads = spread.is_some();
        let Spread {
            me,
            rank_of,
            far_all,
            watcher,
        } = spread.unwrap_or_default();
        // Per vertex, the ranks watching a far stencil of it (ascending).
        let n = w.num_vertices();
        let (watcher_start, watcher_ranks) = watchers_by_vertex(n, &far_all, &watcher);
        let mut report_cap = Vec::new();
        if !far_all.is_empty() {
            report_cap = vec![f64::INFINITY; n];
            for i in 0..n {
                if watcher_start[i] < watcher_start[i + 1] {
                    report_cap[i] = 0.0;
                }
            }
        }
        let here = |u: usize| !spreads || rank_of[u] == me;
        let mine: Vec<u32> = (0..specs.len() as u32)
            .filter(|&u| here(u as usize))
            .collect();
        let mut my_vertices: Vec<u32> = (mine.iter())
            .flat_map(|&u| specs[u as usize].0.iter().copied())
            .collect();
        my_vertices.sort_unstable();
        let mut unit_of_vertex = vec![NONE; w.num_vertices()];
        for (u, (vertices, _)) in specs.iter().enumerate() {
            for &i in vertices {
                unit_of_vertex[i as usize] = u as u32;
            }
        }
        let cost = specs.iter().map(|s| s.1.len() as f64).collect();
        let n_units = specs.len();
        // (a unit built later by a promotion reads only these kinematic
        // vertices)
        let kinematic = SharedCaps::new(kinematic, |i| w.v[i as usize]);
        // The units another rank runs keep their specs here; the others
        // are built on the executor.
        let mut remote: Vec<Option<UnitSpec>> = Vec::new();
        let mut specs: Vec<Mutex<Option<UnitSpec>>> =
            specs.into_iter().map(|s| Mutex::new(Some(s))).collect();
        if spreads {
            remote = (specs.iter_mut().enumerate())
                .map(|(u, spec)| {
                    (!here(u))
                        .then(|| spec.get_mut().expect("a spec").take())
                        .flatten()
                })
                .collect();
        }
        let islands = exec.map(specs.len(), &|u| {
            let spec = specs[u].lock().expect("a spec").take();
            let island = spec.map(|(vertices, members)| {
                Box::new(Island::of(vertices, members, w, t0, &kinematic))
            });
            Mutex::new(island)
        });
        let pending = (
            FarCounts {
                // (spread over ranks: every rank's)
                far: far.len().max(far_all.len()) as u64,
                ..Default::default()
            },
            checked,
        );
        Units {
            live: vec![true; islands.len()],
            mine,
            my_vertices,
            islands,
            cost,
            unit_of_vertex,
            far,
            after_internal: false,
            pending,
            events_at_depth,
            kinematic,
            kinematic_woken: Vec::new(),
            quiet: vec![None; n_units],
            most_breakpoints: vec![0; n_units],
            skipped: vec![0; n_units],
            caps: (0..w.num_vertices()).map(|_| AtomicU64::new(0)).collect(),
            spread: spreads,
            rank_of,
            remote,
            me,
            far_all,
            watcher_start,
            watcher_ranks,
            report_cap,
            seg_counts: FarCounts::default(),
            seg_checked: Checked::default(),
            to_build: Vec::new(),
        }
    }

    /// Whether unit `u` runs on this rank.
    fn here(&self, u: usize) -> bool {
        !self.spread || self.rank_of[u] == self.me
    }

    /// Whether the units are spread over ranks.
    pub(super) fn spread(&self) -> bool {
        self.spread
    }

    /// Spread over ranks: how many far stencils every rank watches
    /// together (what a promotion may name).
    pub(super) fn far_count(&self) -> usize {
        self.far_all.len()
    }

    /// Spread over ranks: the ranks watching a far stencil of vertex `i`.
    pub(super) fn watchers(&self, i: u32) -> &[u32] {
        match self.watcher_start.get(i as usize..i as usize + 2) {
            Some(&[a, b]) => &self.watcher_ranks[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Far stencil `f`'s key and depth (spread over ranks: `f` among every
    /// rank's far stencils).
    fn far_stencil(&self, f: u32) -> (StencilKey, u32) {
        match self.far_all.get(f as usize) {
            Some(&stencil) if self.spread() => stencil,
            _ => {
                let (key, depth, _) = self.far.stencil(f);
                (key, depth)
            }
        }
    }

    /// Every unit's segment `[s, e)` (and its kicks at the internal tick `e`
    /// when `internal`), in parallel, with the far stencils' steps around
    /// it: certified again before, checked after, promoted and the segment
    /// run again where a check fails. Returns the units' outputs in unit
    /// order, then one output holding the far stencils' evaluations and
    /// counts. (Every unit runs here: one memory, or over ranks the units
    /// of this rank's packs. Spread over ranks, the engine runs the same
    /// steps with the exchanges between them.)
    pub(super) fn segment<E: Executor>(
        &mut self,
        exec: &E,
        pass: &Pass<'_>,
        (s, e): (Tick, Tick),
        internal: bool,
    ) -> Vec<SegmentOutput> {
        let w = pass.world;
        let (promote, checked) = self.renew(exec, w, (s, e));
        let moves = self.promote_agreed(&promote, checked, w, (&[], &[]));
        debug_assert!(moves.is_empty(), "every unit runs here");
        self.build(exec, w, s);
        let mut outputs = self.run(exec, pass, (s, e), internal);
        let _after = trace::span("far after");
        loop {
            let fast = outputs.iter().flat_map(|o| o.1.fast.iter().copied());
            let added = (outputs.iter()).flat_map(|o| o.1.breakpoints.iter().map(|b| (b.0, 1)));
            let (promote, last) = self.check(w, (s, e), fast, added);
            let Some(merged) = self.check_agreed(&promote, last, w, (&[], &[])) else {
                break;
            };
            self.build(exec, w, s);
            let rerun = self.rerun(exec, pass, (s, e), internal, &merged.changed);
            let gone = |u: &u32| merged.changed.contains(u) || merged.emptied.contains(u);
            outputs.retain(|(u, _)| !gone(u));
            outputs.extend(rerun);
        }
        outputs.sort_unstable_by_key(|o| o.0);
        let mut outputs: Vec<SegmentOutput> = outputs.into_iter().map(|o| o.1).collect();
        outputs.push(self.finish(internal));
        outputs
    }

    /// A segment's first step, at its start `s` (the world holds the state
    /// at `s`): the kinematic vertices' caps shown the internal tick's
    /// velocities and the far stencils this rank watches certified again.
    /// Returns those that cannot be, to promote (spread over ranks: by
    /// their index among every rank's far stencils), and what certifying
    /// evaluated.
    pub(super) fn renew<E: Executor>(
        &mut self,
        exec: &E,
        w: &World,
        (s, e): (Tick, Tick),
    ) -> (Vec<u32>, Checked) {
        self.kinematic_woken.clear();
        if self.after_internal {
            // The internal tick gave the kinematic vertices new velocities.
            (self.kinematic).observe(|i| w.v[i as usize], &mut self.kinematic_woken);
        }
        // (The pass start's counts: the same on every rank.)
        let (counts, checked) = std::mem::take(&mut self.pending);
        self.seg_counts = counts;
        self.seg_checked = checked;
        let _span = trace::span("far before");
        let mut renewed = Checked::default();
        let promote = (self.far).before_segment(exec, w, (s, e), self.after_internal, &mut renewed);
        (self.global_ids(promote), renewed)
    }

    /// `local` far stencils as the ids promotions name them.
    fn global_ids(&self, local: Vec<u32>) -> Vec<u32> {
        match self.spread() {
            true => local.into_iter().map(|f| self.far.stencil(f).2).collect(),
            false => local,
        }
    }

    /// The promotions of a segment's start, agreed by every rank (`fs`,
    /// ascending; `checked`: what certifying evaluated over every rank),
    /// merged. Returns the vertices whose unit now runs on another rank.
    pub(super) fn promote_agreed(
        &mut self,
        fs: &[u32],
        checked: Checked,
        w: &World,
        homes: Homes<'_>,
    ) -> Vec<Move> {
        self.seg_checked.add(&checked);
        if fs.is_empty() {
            return Vec::new();
        }
        let _span = trace::span("far promote");
        self.seg_counts.promoted += fs.len() as u64;
        self.promote(fs, w, homes).moves
    }

    /// The units visited this segment, run here in parallel: `(unit,
    /// output)` in unit order.
    pub(super) fn run<E: Executor>(
        &mut self,
        exec: &E,
        pass: &Pass<'_>,
        (s, e): (Tick, Tick),
        internal: bool,
    ) -> Vec<(u32, SegmentOutput)> {
        let visit = self.units_to_visit(exec, pass.world, e, internal);
        let sh = with_caps(
            pass,
            (&self.far, &self.report_cap),
            &self.kinematic,
            &self.kinematic_woken,
        );
        let (reports, outputs) = run_bins(
            exec,
            &sh,
            (&self.islands, &visit, &mut self.cost),
            (&self.skipped, &self.caps),
            (s, e),
            internal,
        );
        self.note_visits(&reports);
        outputs
    }

    /// A segment's check, after every unit ran it: `fast` the far vertices'
    /// speeds² (at least those that broke their caps) and `added` their
    /// breakpoints `(vertex, count)`, over every unit's output (reruns
    /// included). Returns the far stencils this rank watches that must be
    /// promoted (as [`Units::renew`]) and what the check evaluated.
    pub(super) fn check(
        &mut self,
        w: &World,
        (s, e): (Tick, Tick),
        fast: impl Iterator<Item = (u32, f64)>,
        added: impl Iterator<Item = (u32, u32)>,
    ) -> (Vec<u32>, Checked) {
        let mut last = Checked::default();
        let promote = (self.far).check(w, (s, e), fast, added, &mut last);
        (self.global_ids(promote), last)
    }

    /// A check's promotions agreed by every rank (`fs`, ascending; `last`:
    /// what the check evaluated over every rank). With none, the segment's
    /// far-stencil bookkeeping is committed and `None` returned (only the
    /// last check's evaluations count: a check after a rerun checks again
    /// the stencils of every unit, which depends on what the reruns gave);
    /// else they are merged (the new units to run the segment again, then
    /// to check again).
    pub(super) fn check_agreed(
        &mut self,
        fs: &[u32],
        last: Checked,
        w: &World,
        homes: Homes<'_>,
    ) -> Option<Merged> {
        if fs.is_empty() {
            self.seg_checked.add(&last);
            self.far.commit();
            return None;
        }
        self.seg_counts.promoted += fs.len() as u64;
        let merged = self.promote(fs, w, homes);
        self.seg_counts.reruns += merged.changed.len() as u64;
        Some(merged)
    }

    /// The new units `changed` that run here, run again over the segment
    /// from the state at `s`: `(unit, output)`.
    pub(super) fn rerun<E: Executor>(
        &mut self,
        exec: &E,
        pass: &Pass<'_>,
        (s, e): (Tick, Tick),
        internal: bool,
        changed: &[u32],
    ) -> Vec<(u32, SegmentOutput)> {
        let here: Vec<u32> = (changed.iter().copied())
            .filter(|&u| self.here(u as usize))
            .collect();
        let _span = trace::span_with("island rerun", "units", here.len() as u64);
        let sh = with_caps(
            pass,
            (&self.far, &self.report_cap),
            &self.kinematic,
            &self.kinematic_woken,
        );
        let islands = &self.islands;
        let caps = &self.caps;
        let rerun = exec.map(here.len(), &|k| {
            let mut slot = islands[here[k] as usize].lock().expect("a unit's lock");
            let island = running(&mut slot);
            let out = island.run_segment(exec, &sh, (s, e), internal);
            (out, (here[k], island.report(caps)))
        });
        let (rerun, reports): (Vec<_>, Vec<_>) = rerun.into_iter().unzip();
        self.note_visits(&reports);
        let mut outputs = Vec::new();
        for (&u, out) in here.iter().zip(rerun) {
            if let Some(out) = out {
                self.cost[u as usize] += out.seconds;
                outputs.push((u, out));
            }
        }
        outputs
    }

    /// A segment's end: one output holding the far stencils' evaluations
    /// and counts (and at the pass's last segment its largest unit, over
    /// every rank's units).
    pub(super) fn finish(&mut self, internal: bool) -> SegmentOutput {
        let mut counts = std::mem::take(&mut self.seg_counts);
        let checked = std::mem::take(&mut self.seg_checked);
        if !internal {
            // The pass's last segment: its largest unit.
            counts.largest = (0..self.islands.len())
                .filter(|&u| self.live[u])
                .map(|u| self.events_of(u))
                .max()
                .unwrap_or(0);
        }
        self.after_internal = internal;
        SegmentOutput {
            evaluations: checked.evaluations,
            min_separation: checked.min_separation,
            far: counts,
            ..Default::default()
        }
    }

    /// Unit `u`'s layer events in the pass.
    fn events_of(&self, u: usize) -> u64 {
        let depths: Vec<u32> = match &self.remote.get(u).and_then(Option::as_ref) {
            Some(spec) => spec.1.iter().map(|m| m.1).collect(),
            None => (running(&mut self.islands[u].lock().expect("a unit")).members())
                .map(|m| m.1)
                .collect(),
        };
        depths
            .iter()
            .map(|&d| self.events_at_depth[d as usize])
            .sum()
    }

    /// Which live units the segment ending at `e` visits: a unit with a stencil
    /// awake or due to wake in it, or — after an internal tick — one of
    /// whose vertices' new speed would change its speed cap (break it, or
    /// fall below half of it: `dormancy::changes_cap`) or that reached its
    /// breakpoints' limit, or any when a kinematic vertex broke its shared
    /// cap. The others would find nothing to do: observing their vertices'
    /// new velocities would change no cap and wake nothing, and every batch
    /// would read no stencil. They are skipped, the internal tick's
    /// breakpoint counted for their next visit: every cap, so every later
    /// certificate and count, is what visiting them would leave (a skip
    /// that let a cap stay above a speed that would have lowered it could
    /// give later certificates other lengths, so other evaluation counts
    /// than the global schedule's).
    fn units_to_visit<E: Executor>(
        &mut self,
        exec: &E,
        w: &World,
        e: Tick,
        internal: bool,
    ) -> Vec<u32> {
        let last = if internal { e } else { e.saturating_sub(1) };
        // (A unit another rank runs is never visited here: only `mine`.)
        let mine = &self.mine;
        let mut visit: Vec<bool> = (mine.iter())
            .map(|&u| self.quiet[u as usize].is_none_or(|due| due <= last))
            .collect();
        if self.after_internal {
            let all = !self.kinematic_woken.is_empty();
            for (k, &u) in mine.iter().enumerate() {
                let u = u as usize;
                let limit = self.most_breakpoints[u] + self.skipped[u] + 1 >= BREAKPOINTS_PER_WAKE;
                visit[k] |= all || limit;
            }
            // The units of the vertices whose new speed would change their
            // cap, found on the executor (reads only) over the vertices of
            // the units that run here.
            let mut seen = vec![false; self.islands.len()];
            for (k, &u) in mine.iter().enumerate() {
                seen[u as usize] = visit[k];
            }
            let (of_vertex, caps, seen, vertices) =
                (&self.unit_of_vertex, &self.caps, &seen, &self.my_vertices);
            let broke = exec.map(vertices.len().div_ceil(CAP_CHECK_RUN), &|r| {
                let mut units = Vec::new();
                let run =
                    &vertices[r * CAP_CHECK_RUN..((r + 1) * CAP_CHECK_RUN).min(vertices.len())];
                for &i in run {
                    let u = of_vertex[i as usize];
                    if !seen[u as usize] && units.last() != Some(&u) {
                        let cap = f64::from_bits(caps[i as usize].load(Ordering::Relaxed));
                        if changes_cap(w.v[i as usize], cap) {
                            units.push(u);
                        }
                    }
                }
                units
            });
            let broke = (broke.into_iter().flatten())
                .map(|u| mine.binary_search(&u).expect("a unit that runs here"));
            for k in broke {
                visit[k] = true;
            }
            debug_assert_eq!(
                self.my_vertices,
                self.vertices_by_unit_of_vertex(),
                "the vertices kept for the units that run here"
            );
            debug_assert_eq!(
                visit,
                self.visits_by_vertex(w, last),
                "the units' vertices are the vertices of their units"
            );
            for (k, &u) in mine.iter().enumerate() {
                if !visit[k] {
                    self.skipped[u as usize] += 1;
                }
            }
        }
        (mine.iter().zip(visit))
            .filter_map(|(&u, v)| v.then_some(u))
            .collect()
    }

    /// The vertices of the units that run here, from each vertex's unit
    /// (the reference for `my_vertices`; debug builds compare them).
    fn vertices_by_unit_of_vertex(&self) -> Vec<u32> {
        let runs = |u: u32| self.mine.binary_search(&u).is_ok();
        (0..self.unit_of_vertex.len() as u32)
            .filter(|&i| {
                let u = self.unit_of_vertex[i as usize];
                u != NONE && runs(u)
            })
            .collect()
    }

    /// [`Units::units_to_visit`]'s choice after an internal tick, found
    /// vertex by vertex over the world (the reference for the search over
    /// `my_vertices`; debug builds compare them).
    fn visits_by_vertex(&self, w: &World, last: Tick) -> Vec<bool> {
        let all = !self.kinematic_woken.is_empty();
        let mut visit: Vec<bool> = vec![false; self.islands.len()];
        for &u in &self.mine {
            let u = u as usize;
            let limit = self.most_breakpoints[u] + self.skipped[u] + 1 >= BREAKPOINTS_PER_WAKE;
            visit[u] = all || limit || self.quiet[u].is_none_or(|due| due <= last);
        }
        let runs = |u: u32| self.mine.binary_search(&u).is_ok();
        for (i, &u) in self.unit_of_vertex.iter().enumerate() {
            if u != NONE && runs(u) {
                let cap = f64::from_bits(self.caps[i].load(Ordering::Relaxed));
                visit[u as usize] |= changes_cap(w.v[i], cap);
            }
        }
        self.mine.iter().map(|&u| visit[u as usize]).collect()
    }

    /// What the units visited reported (`Island::report`).
    fn note_visits(&mut self, reports: &[Report]) {
        for &(u, (due, most)) in reports {
            let u = u as usize;
            self.quiet[u] = due;
            self.most_breakpoints[u] = most;
            self.skipped[u] = 0;
        }
    }

    /// Promotes the far stencils `fs` at tick `s` (the world holds the
    /// state at `s`): each joins the units holding its dynamic vertices and
    /// its vertices outside every unit; stencils that share a unit or a
    /// vertex join the same new unit. Each new unit takes the slot of the
    /// lowest unit it merged (or a new slot) and, spread over ranks, the
    /// rank holding most of its stencils (the lowest of equals; with none,
    /// `home` of its lowest vertex): every rank merges alike, and builds
    /// the new units that run on it.
    fn promote(&mut self, fs: &[u32], w: &World, homes: Homes<'_>) -> Merged {
        // What each stencil joins: units (`u`) and loose vertices
        // (`1 << 32 | i`), grouped by union over the stencils.
        #[derive(Default)]
        struct Group {
            joins: Vec<u64>,
            stencils: Vec<u32>,
        }
        let mut group_of: BTreeMap<u64, usize> = BTreeMap::new();
        let mut groups: Vec<Option<Group>> = Vec::new();
        for &f in fs {
            let (key, _) = self.far_stencil(f);
            let mut joins: Vec<u64> = (key.v.iter())
                .filter(|&&i| w.inv_mass[i as usize] > 0.0)
                .map(|&i| match self.unit_of_vertex[i as usize] {
                    NONE => 1 << 32 | i as u64,
                    u => u as u64,
                })
                .collect();
            joins.sort_unstable();
            joins.dedup();
            let mut found: Vec<usize> = joins
                .iter()
                .filter_map(|j| group_of.get(j).copied())
                .collect();
            found.sort_unstable();
            found.dedup();
            let g = match found.first() {
                Some(&g) => g,
                None => {
                    groups.push(Some(Group::default()));
                    groups.len() - 1
                }
            };
            for &other in &found[found.len().min(1)..] {
                let moved = groups[other].take().expect("a live group");
                for &j in &moved.joins {
                    group_of.insert(j, g);
                }
                let target = groups[g].as_mut().expect("a live group");
                target.joins.extend(moved.joins);
                target.stencils.extend(moved.stencils);
            }
            let target = groups[g].as_mut().expect("a live group");
            for j in joins {
                if group_of.insert(j, g).is_none() {
                    target.joins.push(j);
                }
            }
            target.stencils.push(f);
        }
        let mut merged = Merged::default();
        // Each group's new unit's vertices and members (merged here, in the
        // order of `changed`; those that run here built on the executor
        // below).
        let mut built: Vec<(u32, Mutex<Option<UnitSpec>>)> = Vec::new();
        // The vertices of the new units that run here, and of those that
        // run elsewhere (`my_vertices` is updated with them).
        let (mut joined, mut left) = (Vec::new(), Vec::new());
        for group in groups.into_iter().flatten() {
            let mut units: Vec<u32> = (group.joins.iter())
                .filter(|&&j| j >> 32 == 0)
                .map(|&j| j as u32)
                .collect();
            units.sort_unstable();
            let mut vertices: Vec<u32> = (group.joins.iter())
                .filter(|&&j| j >> 32 == 1)
                .map(|&j| j as u32)
                .collect();
            let rank = self.rank_for(&units, &vertices, homes.0);
            // (A loose vertex's state is current on its owner.)
            for &i in vertices.iter().filter(|_| self.spread()) {
                let owner = homes.1[i as usize];
                if owner != rank {
                    merged.moves.push((i, owner, rank));
                }
            }
            let mut members: Vec<(StencilKey, u32)> = (group.stencils.iter())
                .map(|&f| self.far_stencil(f))
                .collect();
            let mut cost = 0.0;
            for &u in &units {
                let (their_vertices, their_members) = self.take(u as usize);
                if self.spread() && self.rank_of[u as usize] != rank {
                    let from = self.rank_of[u as usize];
                    (merged.moves).extend(their_vertices.iter().map(|&i| (i, from, rank)));
                }
                vertices.extend(their_vertices);
                members.extend(their_members);
                cost += self.cost[u as usize];
            }
            let slot = match units.first() {
                Some(&u) => u,
                None => {
                    self.islands.push(Mutex::default());
                    self.live.push(true);
                    self.cost.push(0.0);
                    self.quiet.push(None);
                    self.most_breakpoints.push(0);
                    self.skipped.push(0);
                    if self.spread() {
                        self.rank_of.push(rank);
                        self.remote.push(None);
                    }
                    (self.islands.len() - 1) as u32
                }
            };
            for &u in units.iter().skip(1) {
                self.live[u as usize] = false;
                self.cost[u as usize] = 0.0;
                merged.emptied.push(u);
                set_member(&mut self.mine, u, false);
            }
            for &i in &vertices {
                self.unit_of_vertex[i as usize] = slot;
            }
            self.cost[slot as usize] = cost + members.len() as f64 * 1e-9;
            // (built awake: visited)
            self.quiet[slot as usize] = None;
            self.skipped[slot as usize] = 0;
            self.most_breakpoints[slot as usize] = 0;
            vertices.sort_unstable();
            vertices.dedup();
            members.sort_unstable_by_key(|m| m.0);
            merged.vertices.extend_from_slice(&vertices);
            if self.spread() {
                self.rank_of[slot as usize] = rank;
            }
            let here = self.here(slot as usize);
            set_member(&mut self.mine, slot, here);
            if here {
                joined.extend_from_slice(&vertices);
                built.push((slot, Mutex::new(Some((vertices, members)))));
            } else {
                left.extend_from_slice(&vertices);
                self.remote[slot as usize] = Some((vertices, members));
            }
            merged.changed.push(slot);
        }
        self.to_build = built;
        joined.sort_unstable();
        left.sort_unstable();
        self.my_vertices = with_and_without(&self.my_vertices, &joined, &left);
        merged.changed.sort_unstable();
        merged.emptied.sort_unstable();
        merged.vertices.sort_unstable();
        merged
    }

    /// Builds the new units of the last promotion that run here, from the
    /// world's state at `s` (over ranks, once the vertices that moved here
    /// have arrived: a unit reads its vertices' velocities when built).
    pub(super) fn build<E: Executor>(&mut self, exec: &E, w: &World, s: Tick) {
        let built = std::mem::take(&mut self.to_build);
        let kinematic = &self.kinematic;
        let islands = exec.map(built.len(), &|g| {
            let (vertices, members) =
                (built[g].1.lock().expect("a group").take()).expect("built once");
            Island::of(vertices, members, w, s, kinematic)
        });
        for ((slot, _), island) in built.iter().zip(islands) {
            *self.islands[*slot as usize].lock().expect("a unit") = Some(Box::new(island));
        }
    }

    /// Unit `u`'s vertices and stencils, taken out of it (it runs here, or
    /// its spec is kept here).
    fn take(&mut self, u: usize) -> UnitSpec {
        if let Some(spec) = self.remote.get_mut(u).and_then(Option::take) {
            return spec;
        }
        let island = (self.islands[u].lock().expect("a unit").take())
            .expect("a unit that runs here or whose spec is kept here");
        (island.vertices().to_vec(), island.members().collect())
    }

    /// The rank a unit merged of `units` and the loose vertices `loose`
    /// runs on: the rank holding most of their stencils (the lowest of
    /// equals), or with no unit the home of the lowest loose vertex; this
    /// rank when the units are not spread.
    fn rank_for(&self, units: &[u32], loose: &[u32], home: &[u32]) -> u32 {
        if !self.spread() {
            return self.me;
        }
        let mut weight: BTreeMap<u32, usize> = BTreeMap::new();
        for &u in units {
            let u = u as usize;
            let stencils = match self.remote.get(u).and_then(Option::as_ref) {
                Some(spec) => spec.1.len(),
                None => running(&mut self.islands[u].lock().expect("a unit")).stencils(),
            };
            *weight.entry(self.rank_of[u]).or_default() += stencils;
        }
        let heaviest = (weight.iter()).max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)));
        match heaviest {
            Some((&rank, _)) => rank,
            None => home[*loose.iter().min().expect("a far stencil's vertex") as usize],
        }
    }
}

/// Puts `u` in the ascending list `list` (`true`) or takes it out.
fn set_member(list: &mut Vec<u32>, u: u32, member: bool) {
    match (list.binary_search(&u), member) {
        (Err(at), true) => list.insert(at, u),
        (Ok(at), false) => {
            list.remove(at);
        }
        _ => {}
    }
}

/// The ascending set `set` with the ascending `joined` (none in `left`)
/// and without the ascending `left`, in one pass.
fn with_and_without(set: &[u32], joined: &[u32], left: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(set.len() + joined.len());
    let (mut j, mut l) = (0, 0);
    for &i in set {
        while j < joined.len() && joined[j] < i {
            out.push(joined[j]);
            j += 1;
        }
        while l < left.len() && left[l] < i {
            l += 1;
        }
        if j < joined.len() && joined[j] == i {
            j += 1;
        }
        if l < left.len() && left[l] == i {
            continue;
        }
        out.push(i);
    }
    out.extend_from_slice(&joined[j..]);
    out
}

/// Per vertex of `n`, the ranks watching a far stencil of it, ascending
/// (CSR: starts, ranks; both empty without far stencils), from the far
/// stencils `far` and the rank watching each: counted into buckets by
/// vertex, then each bucket sorted and its repeats dropped (every rank
/// builds it at every pass start, and a sort of all the pairs was a
/// measurable part of a rank's pass at 100k vertices).
fn watchers_by_vertex(
    n: usize,
    far: &[(StencilKey, u32)],
    watcher: &[u32],
) -> (Vec<u32>, Vec<u32>) {
    if far.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let mut start = vec![0u32; n + 1];
    for f in far {
        for i in f.0.v {
            start[i as usize + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut next = start.clone();
    let mut ranks = vec![0u32; start[n] as usize];
    for (f, &r) in far.iter().zip(watcher) {
        for i in f.0.v {
            ranks[next[i as usize] as usize] = r;
            next[i as usize] += 1;
        }
    }
    // Each vertex's bucket sorted, its repeats dropped, compacted in place.
    let mut kept = 0usize;
    for i in 0..n {
        let (a, b) = (start[i] as usize, start[i + 1] as usize);
        start[i] = kept as u32;
        ranks[a..b].sort_unstable();
        let mut last = None;
        for k in a..b {
            if last != Some(ranks[k]) {
                last = Some(ranks[k]);
                ranks[kept] = ranks[k];
                kept += 1;
            }
        }
    }
    start[n] = kept as u32;
    ranks.truncate(kept);
    (start, ranks)
}

/// The cost of a unit whose last segment was idle.
const IDLE_SECONDS: f64 = 1e-7;

/// What the units read: `pass` with the far stencils' speed caps (spread
/// over ranks, `report_cap`: every far vertex's speeds reported) and the
/// kinematic vertices' shared caps.
fn with_caps<'a>(
    pass: &Pass<'a>,
    (far, report_cap): (&'a FarSet, &'a [f64]),
    kinematic: &'a SharedCaps,
    woken: &'a [u32],
) -> Shared<'a> {
    let far_cap = if report_cap.is_empty() {
        far.caps()
    } else {
        report_cap
    };
    Shared::new(pass, far_cap, kinematic.caps(), woken)
}

/// The live units' segment `[s, e)` (and their kicks at the internal tick
/// `e` when `internal`), in parallel: dealt into bins largest first (by the
/// seconds of their last segment, which become the new costs) to the
/// least-loaded bin, so a few tasks carry the many small units (a task per
/// unit would cost more than most units do). Returns `(unit, output)` in
/// unit order, for the units that read a stencil (an idle unit, nothing
/// awake or due, reports nothing and costs next to nothing next time).
fn run_bins<E: Executor>(
    exec: &E,
    shared: &Shared<'_>,
    (islands, visit, cost): (&[UnitSlot], &[u32], &mut [f64]),
    (skipped, caps): (&[u32], &[AtomicU64]),
    (s, e): (Tick, Tick),
    internal: bool,
) -> (Vec<Report>, Vec<(u32, SegmentOutput)>) {
    let _span = trace::span_with("islands", "islands", islands.len() as u64);
    let per_rank = if exec.ranks() == 1 {
        BINS_PER_THREAD * exec.threads_per_rank().max(1)
    } else {
        BINS_PER_RANK
    };
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); per_rank];
    let mut load = vec![0.0f64; per_rank];
    // The units that worked last segment, largest first, then the idle
    // ones in turn (sorting thousands of idle units at every segment cost
    // more than their checks).
    let (mut busy, idle): (Vec<u32>, Vec<u32>) =
        (visit.iter()).partition(|&&k| cost[k as usize] > IDLE_SECONDS);
    busy.sort_by(|&a, &b| {
        cost[b as usize]
            .total_cmp(&cost[a as usize])
            .then(a.cmp(&b))
    });
    // The least-loaded bin (the lowest of equal loads) from a heap: a scan
    // of every bin per unit cost more than the dealing saved at 16 threads.
    // (Costs are finite and non-negative, so their bits order as they do.)
    let mut least: BinaryHeap<Reverse<(u64, usize)>> = (0..per_rank)
        .map(|b| Reverse((0f64.to_bits(), b)))
        .collect();
    for k in busy {
        let Reverse((_, b)) = least.pop().expect("a bin");
        load[b] += cost[k as usize];
        bins[b].push(k);
        least.push(Reverse((load[b].to_bits(), b)));
    }
    for (n, k) in idle.into_iter().enumerate() {
        bins[n % per_rank].push(k);
    }
    let binned = exec.map(bins.len(), &|b| {
        let _span = trace::span_with("island task", "islands", bins[b].len() as u64);
        (bins[b].iter())
            .map(|&k| {
                let mut slot = islands[k as usize].lock().expect("an island's lock");
                let island = running(&mut slot);
                island.catch_up(skipped[k as usize]);
                let out = island.run_segment(exec, shared, (s, e), internal);
                (k, out, island.report(caps))
            })
            .collect::<Vec<_>>()
    });
    let visited = binned.iter().map(Vec::len).sum();
    let (mut mine, mut reports) = (Vec::with_capacity(visited), Vec::with_capacity(visited));
    for (k, output, quiet) in binned.into_iter().flatten() {
        reports.push((k, quiet));
        match output {
            Some(output) => {
                cost[k as usize] = output.seconds;
                mine.push((k, output));
            }
            None => cost[k as usize] = IDLE_SECONDS,
        }
    }
    (reports, by_unit(mine))
}

/// `outputs` in unit order. An output is large, and a sort moves each many
/// times (on the 50k twister, 2,400 a segment took 40 ms a window): the
/// indices are sorted, and each output moved twice.
fn by_unit(outputs: Vec<(u32, SegmentOutput)>) -> Vec<(u32, SegmentOutput)> {
    let mut order: Vec<(u32, u32)> = (outputs.iter().enumerate())
        .map(|(j, o)| (o.0, j as u32))
        .collect();
    order.sort_unstable();
    let mut slots: Vec<Option<(u32, SegmentOutput)>> = outputs.into_iter().map(Some).collect();
    (order.iter())
        .map(|&(_, j)| slots[j as usize].take().expect("each output once"))
        .collect()
}

/// What a visited unit reported: its index and `Island::report`.
type Report = (u32, (Option<Tick>, u32));

#[cfg(test)]
mod tests {
    use super::*;
    use weft_core::StencilKind;

    /// xorshift64*: numbers below `n`.
    struct Rng(u64);

    impl Rng {
        fn below(&mut self, n: u64) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) % n
        }
    }

    /// The counted buckets give what sorting every (vertex, rank) pair and
    /// dropping the repeats gives, on random far stencils sharing vertices
    /// (some watched by the same rank twice).
    #[test]
    fn watchers_by_vertex_are_the_sorted_distinct_pairs() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for case in 0..50 {
            let n = 1 + rng.below(40) as usize;
            let ranks = 1 + rng.below(6);
            let far: Vec<(StencilKey, u32)> = (0..rng.below(60))
                .map(|_| {
                    let v = [0; 4].map(|_| rng.below(n as u64) as u32);
                    let kind = StencilKind::EdgeEdge;
                    (StencilKey { kind, v }, 1)
                })
                .collect();
            let watcher: Vec<u32> = far.iter().map(|_| rng.below(ranks) as u32).collect();
            let (start, got) = watchers_by_vertex(n, &far, &watcher);
            let mut pairs: Vec<(u32, u32)> = (far.iter().zip(&watcher))
                .flat_map(|(f, &r)| f.0.v.map(|i| (i, r)))
                .collect();
            pairs.sort_unstable();
            pairs.dedup();
            if far.is_empty() {
                assert!(start.is_empty() && got.is_empty(), "case {case}");
                continue;
            }
            assert_eq!(start.len(), n + 1, "case {case}");
            for i in 0..n {
                let want: Vec<u32> = (pairs.iter())
                    .filter(|p| p.0 == i as u32)
                    .map(|p| p.1)
                    .collect();
                let (a, b) = (start[i] as usize, start[i + 1] as usize);
                assert_eq!(got[a..b], want[..], "case {case}, vertex {i}");
            }
            assert_eq!(got.len(), pairs.len(), "case {case}");
        }
    }

    /// `with_and_without` is the set union and difference.
    #[test]
    fn with_and_without_is_the_union_then_the_difference() {
        let mut rng = Rng(11);
        for case in 0..300 {
            let mut pick = |k: u64| {
                let mut v: Vec<u32> = (0..rng.below(k)).map(|_| rng.below(60) as u32).collect();
                v.sort_unstable();
                v.dedup();
                v
            };
            let (set, joined, left) = (pick(40), pick(20), pick(20));
            let left: Vec<u32> = left
                .into_iter()
                .filter(|i| joined.binary_search(i).is_err())
                .collect();
            let mut want: std::collections::BTreeSet<u32> = set.iter().copied().collect();
            want.extend(&joined);
            for i in &left {
                want.remove(i);
            }
            let got = with_and_without(&set, &joined, &left);
            assert_eq!(got, want.into_iter().collect::<Vec<_>>(), "case {case}");
        }
    }

    /// `set_member` keeps a list ascending and free of repeats, as a set.
    #[test]
    fn set_member_keeps_an_ascending_set() {
        let mut rng = Rng(7);
        let mut list = Vec::new();
        let mut reference = std::collections::BTreeSet::new();
        for _ in 0..2000 {
            let u = rng.below(50) as u32;
            let member = rng.below(2) == 0;
            set_member(&mut list, u, member);
            match member {
                true => reference.insert(u),
                false => reference.remove(&u),
            };
            assert_eq!(list, reference.iter().copied().collect::<Vec<_>>());
        }
    }
}
