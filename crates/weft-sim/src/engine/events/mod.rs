//! The events of one pass (`acm-spec.md` §2): every clock's batches in time
//! order over `[T0, T1)`, recording trajectory breakpoints.
//!
//! A batch at tick `t` holds every clock that fires at `t`: the internal clock
//! (stretch, bend, damping, gravity, scripts) and each active layer `l` with
//! `t % h_l == 0`. All forces read positions at `t` and the velocities at the
//! start of the batch (Jacobi semantics for damping and friction); each vertex
//! sums its impulses in (clock, stencil key) order; only vertices whose velocity
//! changes are drifted to `t` and get a breakpoint, so zero kicks leave no trace.
//!
//! The pass runs as **segments** between consecutive internal ticks. In a
//! segment only penalty layers fire, and their work splits into contact
//! islands ([`crate::islands`]) that share no dynamic vertex: each island
//! runs its own batches ([`island`]), all islands at once on the executor
//! (over ranks: placed largest first near the owners of their vertices,
//! each rank handed only what it keeps of their results, in one all-to-all).
//! The islands run as units ([`units`]: small ones packed); with
//! `contact.split_islands` the far stencils stay out of them ([`far`]).
//! Then the internal tick
//! ([`internal`]) folds the internal forces and, after them, each island's
//! kicks at that tick. Every vertex folds the same kicks in the same order as
//! one global schedule of batches would: the same bits.

mod far;
mod internal;
mod island;
mod scripted;
mod units;

use std::time::Instant;

use glam::DVec3;
use weft_core::StencilKey;

use super::Engine;
use crate::clock::Tick;
use crate::error::SimError;
use crate::executor::Executor;
use crate::islands::Islands;
use crate::share::RankShare;
use crate::trace;
use crate::world::World;
use far::{may_be_far, Checked, FarSet};
use island::{Pass, SegmentOutput};
use units::{FarCounts, Spread, UnitSpec, Units};

pub(super) use scripted::{replayable, scripted_polyline};

/// Tasks per thread that the islands of a segment are dealt to on one
/// memory (on the twister 50k with 2 threads, the island stage reached 90 %
/// of its ideal with 2 per thread, 81 % with 8 and 74 % with 32).
pub(super) const BINS_PER_THREAD: usize = 2;

/// Tasks per rank over ranks: every rank must deal the same tasks
/// (`map_on_ranks` takes one list), so their number cannot follow a rank's
/// own thread count there.
pub(super) const BINS_PER_RANK: usize = 8;

/// Islands of fewer stencils are packed together (`Islands::packed`): a
/// pack runs with the bits of its islands run apart, but each island costs
/// a visit of its state per segment, and most islands are a stencil or two.
pub(super) const PACK_STENCILS: usize = 64;

/// Vertices per task of the per-vertex stages of an internal tick.
const VERTEX_RUN: usize = 512;

/// Vertices per task of the speed-cap checks after an internal tick (the
/// units' and the far stencils'): a read and a compare each.
const CAP_CHECK_RUN: usize = 1024;

/// Counters of one pass over a window.
#[derive(Debug, Default)]
pub(super) struct PassCounts {
    pub(super) internal_events: u64,
    pub(super) layer_events: u64,
    pub(super) layer_evaluations: u64,
    pub(super) layer_kicks: u64,
    pub(super) islands: u64,
    pub(super) largest_island_layer_events: u64,
    pub(super) min_separation: f64,
    /// What the far stencils did (`far`).
    pub(super) far: FarCounts,
    /// Wall seconds of the internal-force part of internal ticks (up to
    /// the new velocities).
    pub(super) internal_seconds: f64,
    /// Over ranks: this rank's work CPU seconds in its islands' segments.
    pub(super) island_cpu: f64,
    /// The far stencils were kept out of the islands.
    pub(super) split: bool,
    /// The pass ended early because a value became non-finite.
    pub(super) truncated: Option<SimError>,
    /// The pass stopped early because the engine was interrupted.
    pub(super) interrupted: Option<SimError>,
}

/// Scratch memory reused across windows.
#[derive(Debug, Default)]
pub(super) struct Workspace {
    /// Positions at an internal tick, and the internal forces' output slots.
    xt: Vec<DVec3>,
    out: Vec<DVec3>,
    /// Per vertex: an internal tick's impulses (internal forces, then the
    /// islands' kicks).
    acc: Vec<DVec3>,
    bounds: Vec<usize>,
    /// New velocities of an internal tick.
    v_new: Vec<DVec3>,
    /// Bounds of the fixed runs of vertices of the per-vertex stages.
    vertex_runs: Vec<usize>,
    /// The units of the pass's penalty stage this rank runs (islands of
    /// the near stencils, packed; the far stencils beside them).
    units: Units,
    /// The pass has no active stencil (on every rank alike).
    no_islands: bool,
    /// The end of the pass being run.
    pass_end: Tick,
    /// The islands' breakpoints of a segment by vertex run: (vertex in the
    /// run, tick, position).
    breakpoints_by_run: Vec<Vec<(u32, (Tick, DVec3))>>,
    /// The islands' kicks at an internal tick by vertex run: (vertex in the
    /// run, impulse), each vertex's in fold order.
    kicks_by_run: Vec<Vec<(u32, DVec3)>>,
    /// Over ranks: the vertices this rank keeps current through the pass.
    pass_share: crate::share::PassShare,
    /// Over ranks, per vertex run: the offsets in the run of the vertices
    /// this rank owns (fixed for the run), and of those it keeps current
    /// through the pass, so that the per-vertex stages of an internal tick
    /// visit only those instead of testing every vertex.
    owned_in_run: Vec<Vec<u16>>,
    live_in_run: Vec<Vec<u16>>,
    /// On one memory, with islands: what of each internal tick runs while
    /// the islands of the segment before it run.
    calm: Option<Calm>,
}

/// What of an internal tick does not wait for the contact islands of the
/// segment before it. Between two internal ticks the islands move only
/// their own vertices, so every other vertex's position at the tick, the
/// internal forces of the elements all of whose vertices lie outside every
/// island, and the fold and new velocity of each vertex outside every
/// island all of whose elements are such, are known when the segment
/// starts. On one memory they are computed while the islands run
/// ([`Executor::join`]: a giant island keeps one thread, the others take
/// these), the rest at the tick. Over ranks they are a rank's work while
/// it waits for the other ranks' island results (message-driven: a rank
/// with a light share of the islands works through what a heavy one makes
/// it wait for): the calm positions, then its partitions' calm elements
/// one partition at a time, boundary ones first, then one run of vertices'
/// calm folds at a time (of the owned vertices that also fold no slot
/// from another rank), for as long as the results have not all come; what
/// is left runs at the tick (the boundary partitions before their slots
/// are sent, the interior ones while they travel, the other folds after).
/// Each value is computed once, from the same state, so the bits are those
/// of computing everything at the tick.
#[derive(Debug)]
pub(super) struct Calm {
    /// The elements with no island vertex.
    elements: crate::internal::ElementMask,
    /// Per run of vertices: the offsets of the island vertices, and of the
    /// others (over ranks: of those this rank keeps current).
    island_in_run: Vec<Vec<u16>>,
    calm_in_run: Vec<Vec<u16>>,
    /// Per run of vertices: the offsets of the vertices outside every
    /// island with only calm elements (their fold is calm too), and of the
    /// others (over ranks: of the owned vertices, those that also fold no
    /// slot from another rank, and the other owned ones).
    calm_fold_in_run: Vec<Vec<u16>>,
    rest_fold_in_run: Vec<Vec<u16>>,
    /// Over ranks: this rank's partitions with a calm element, boundary
    /// ones first (the order their calm elements are computed in).
    partitions: Vec<u32>,
}

/// What of an internal tick ran before it, beside or after the islands of
/// the segment before it ([`Calm`]).
pub(super) enum CalmDone {
    /// Nothing: the whole tick runs at the tick.
    Nothing,
    /// Over ranks: how far the pieces got while this rank waited.
    Partly(CalmProgress),
    /// On one memory: the calm positions, elements and folds, with each
    /// run of vertices' first calm vertex that blew up.
    ForcesAndFolds(Vec<Option<usize>>),
}

/// Over ranks, the calm part of one internal tick done while the rank
/// waited for the islands' results: held by the tick's [`CalmDone`], so
/// no mark outlives its tick.
#[derive(Debug, Default)]
pub(super) struct CalmProgress {
    /// The calm positions.
    pub(super) positions: bool,
    /// Per partition: its calm elements.
    pub(super) elements: Vec<bool>,
    /// Per run of vertices: its calm folds, with the first of them that
    /// blows up.
    pub(super) folds: Vec<Option<Option<usize>>>,
}

/// The calm part's positions at tick `e` (those of the vertices outside
/// every island).
fn calm_positions<E: Executor>(
    exec: &E,
    world: &World,
    calm: &Calm,
    vertex_runs: &[usize],
    xt: &mut [DVec3],
    e: Tick,
) {
    exec.for_each_chunk(xt, vertex_runs, &|k, run| {
        internal::each_in_run(Some(&calm.calm_in_run[k]), run.len(), |j| {
            run[j] = Engine::<E>::pos_at(world, k * VERTEX_RUN + j, e);
        });
    });
}

/// On one memory: the calm part's positions at tick `e` and its elements'
/// internal forces.
fn calm_forces<E: Executor>(
    exec: &E,
    world: &World,
    calm: &Calm,
    vertex_runs: &[usize],
    (xt, out): (&mut [DVec3], &mut [DVec3]),
    e: Tick,
) {
    let _span = trace::span("calm forces");
    calm_positions(exec, world, calm, vertex_runs, xt, e);
    let mask = Some((&calm.elements, true));
    (world.internal).evaluate_in_pieces(exec, (xt, &world.v), out, mask);
}

/// The parts of an all-to-all that other ranks sent this rank `me`, in
/// rank order.
fn from_peers(
    received: Vec<Option<SegmentOutput>>,
    me: usize,
) -> impl Iterator<Item = SegmentOutput> {
    (received.into_iter().enumerate())
        .filter(move |(j, _)| *j != me)
        .filter_map(|(_, part)| part)
}

/// Inserts `j` into the ascending `list` unless it is there.
fn insert_sorted(list: &mut Vec<u16>, j: u16) {
    if let Err(at) = list.binary_search(&j) {
        list.insert(at, j);
    }
}

/// The offsets in each run of [`VERTEX_RUN`] vertices (cut at `runs`) of
/// the vertices `pick` keeps.
fn in_runs(runs: &[usize], pick: impl Fn(usize) -> bool) -> Vec<Vec<u16>> {
    (runs.windows(2))
        .map(|r| {
            (r[0]..r[1])
                .filter(|&i| pick(i))
                .map(|i| (i - r[0]) as u16)
                .collect()
        })
        .collect()
}

impl Workspace {
    /// Scratch for the world's vertices and internal force slots (over
    /// ranks, `share`: only the slots the rank computes or folds,
    /// [`crate::share::RankSlots`]).
    pub(super) fn new(world: &World, share: Option<&RankShare>) -> Self {
        let n = world.num_vertices();
        let (bounds, slots) = match share {
            None => (world.internal.slot_bounds(), world.internal.num_slots()),
            Some(share) => (share.slots.bounds.clone(), share.slots.len),
        };
        Workspace {
            out: vec![DVec3::ZERO; slots],
            vertex_runs: (0..=n.div_ceil(VERTEX_RUN))
                .map(|k| (k * VERTEX_RUN).min(n))
                .collect(),
            bounds,
            ..Default::default()
        }
    }

    /// A pass starts: the per-vertex scratch of its internal ticks, for
    /// the `n` vertices (every value is written at a tick before it is
    /// read there).
    fn begin_pass(&mut self, n: usize) {
        for buffer in [&mut self.xt, &mut self.acc, &mut self.v_new] {
            buffer.resize(n, DVec3::ZERO);
        }
    }

    /// A pass ended (run through, cut short or failed): its scratch and
    /// units go. Nothing of them is read after the pass, and the broad and
    /// narrow phases and the commit that follow it are where a rank's
    /// memory peaks (the fetched polylines): held through them, the
    /// scratch (three vectors per vertex of the world) and the units were
    /// about 5 MB of a rank's 85 MB heap at its peak on the 50k twister
    /// over 32 ranks.
    fn end_pass(&mut self) {
        for buffer in [&mut self.xt, &mut self.acc, &mut self.v_new] {
            *buffer = Vec::new();
        }
        self.units = Units::default();
        self.calm = None;
        self.breakpoints_by_run = Vec::new();
        self.kicks_by_run = Vec::new();
    }

    /// Over ranks: the partitions were placed again (the owned vertices
    /// changed, and the slots the rank holds, `share.slots`).
    pub(super) fn placed_again(&mut self, share: &RankShare) {
        self.owned_in_run.clear();
        self.bounds.clone_from(&share.slots.bounds);
        self.out = vec![DVec3::ZERO; share.slots.len];
    }

    /// The internal forces' slot bounds and output slots, as scratch
    /// between passes (the predictor's accelerations).
    pub(super) fn internal_scratch(&mut self) -> (&[usize], &mut [DVec3]) {
        (&self.bounds, &mut self.out)
    }
}

/// Sorts `items` (vertex, value) into one bucket per run of vertices (cut
/// at `runs`, every [`VERTEX_RUN`]) as (vertex in the run, value), each
/// bucket in the order of `items`; the buckets keep their memory.
fn bucket_by_run<T>(
    buckets: &mut Vec<Vec<(u32, T)>>,
    runs: &[usize],
    items: impl Iterator<Item = (u32, T)>,
) {
    buckets.resize_with(runs.len().saturating_sub(1), Vec::new);
    buckets.iter_mut().for_each(Vec::clear);
    for (i, value) in items {
        let i = i as usize;
        buckets[i / VERTEX_RUN].push(((i % VERTEX_RUN) as u32, value));
    }
}

/// How many ticks of a clock of period `p` fall in `[t0, t1)` (clocks tick
/// at `n p`, `n ≥ 1`).
fn ticks_in(t0: Tick, t1: Tick, p: Tick) -> u64 {
    let upto = |t: Tick| t.saturating_sub(1) / p; // multiples in [1, t)
    upto(t1) - upto(t0)
}

/// The first tick of a clock of period `p` at or after `t` (clocks tick at
/// `n p`, `n ≥ 1`).
fn tick_at_or_after(t: Tick, p: Tick) -> Tick {
    t.max(1).div_ceil(p) * p
}

/// The items of the given costs, largest first (ties: the lower index).
fn largest_first(costs: &[f64]) -> Vec<u32> {
    let mut order: Vec<u32> = (0..costs.len() as u32).collect();
    order.sort_by(|&a, &b| {
        costs[b as usize]
            .total_cmp(&costs[a as usize])
            .then(a.cmp(&b))
    });
    order
}

/// How far above the mean load a rank may be filled with items at home
/// ([`place_near_home`]).
const HOME_SLACK: f64 = 0.1;

/// **Collective** (an all-gather): whether each stencil of `keys` is far
/// at the pass start, and then the tick its certificate ends
/// ([`far::far_at_start`]), each rank certifying its contiguous share;
/// what certifying evaluated is added to `checked`.
fn far_at_start_shared<E: crate::executor::Executor>(
    exec: &E,
    w: &World,
    share: &RankShare,
    keys: &[StencilKey],
    (t0, first_internal, _): (Tick, Tick, Tick),
    checked: &mut Checked,
) -> Result<Vec<Option<Tick>>, SimError> {
    let (n, ranks) = (keys.len(), share.ranks);
    let range = |r: usize| r * n / ranks..(r + 1) * n / ranks;
    let mine = far::far_at_start(exec, w, &keys[range(share.rank)], (t0, first_internal));
    // (far, distance, the certificate's end tick as the bits of a word)
    let words: Vec<DVec3> = (mine.iter())
        .map(|&(until, d)| {
            let far = f64::from(u8::from(until.is_some()));
            DVec3::new(far, d, f64::from_bits(until.unwrap_or(0)))
        })
        .collect();
    let _site = trace::site("events: pass start's far stencils");
    let all = exec.all_gather_vectors(&words)?;
    let mut is_far = Vec::with_capacity(n);
    for (r, part) in all.iter().enumerate() {
        if part.len() != range(r).len() {
            return Err(SimError::Ranks(crate::executor::CommError(format!(
                "rank {r} certified {} far-stencil candidates for {}",
                part.len(),
                range(r).len()
            ))));
        }
        for c in part {
            checked.saw(c.y);
            is_far.push((c.x == 1.0).then(|| c.z.to_bits()));
        }
    }
    Ok(is_far)
}

/// Over ranks with `contact.split_islands`, the units spread: each unit
/// placed near its home by its stencils, and each far stencil watched by
/// the rank of the unit of its lowest dynamic vertex in a unit (else by
/// its vertices' home). Returns the far stencils this rank watches (each
/// tagged with its index in `far_all`, with its certificate's end from
/// `until`, as all-gathered at the pass start) and the spread.
fn spread_units(
    w: &World,
    share: &RankShare,
    specs: &[UnitSpec],
    far_all: Vec<(StencilKey, u32)>,
    until: &[Tick],
    pass: (Tick, Tick, Tick),
) -> (FarSet, Spread) {
    let cost: Vec<f64> = specs.iter().map(|s| s.1.len() as f64).collect();
    let home: Vec<u32> = (specs.iter()).map(|s| home_rank(share, &s.0)).collect();
    let rank_of = place_near_home(&cost, &home, share.ranks);
    let mut unit_of = vec![u32::MAX; w.num_vertices()];
    for (u, spec) in specs.iter().enumerate() {
        spec.0.iter().for_each(|&i| unit_of[i as usize] = u as u32);
    }
    let watcher: Vec<u32> = (far_all.iter())
        .map(|(key, _)| {
            let dynamic: Vec<u32> = (key.v.iter().copied())
                .filter(|&i| w.inv_mass[i as usize] > 0.0)
                .collect();
            let in_units = dynamic.iter().filter(|&&i| unit_of[i as usize] != u32::MAX);
            match in_units.min() {
                Some(&i) => rank_of[unit_of[i as usize] as usize],
                None => home_rank(share, &dynamic),
            }
        })
        .collect();
    let me = share.rank as u32;
    let watched: Vec<(StencilKey, u32, u32, Tick)> = (far_all.iter().zip(&watcher).enumerate())
        .filter(|(_, (_, &r))| r == me)
        .map(|(g, (&(key, depth), _))| (key, depth, g as u32, until[g]))
        .collect();
    let far = FarSet::of_certified(w, watched, pass);
    let spread = Spread {
        me,
        rank_of,
        far_all,
        watcher,
    };
    (far, spread)
}

impl Spread {
    /// Every vertex read over the pass by a rank other than its owner's
    /// partitions, with the rank (`u32::MAX`: every rank): the units'
    /// stencils' vertices on the unit's rank, the far stencils' on their
    /// watcher, and the kinematic vertices of the active stencils
    /// (`kinematic`, each once) everywhere (a merged unit may come to read
    /// any; listed once per stencil, they were read once per stencil and
    /// rank by every rank at every pass start).
    fn reads<'a>(
        &'a self,
        specs: &'a [UnitSpec],
        kinematic: &'a [u32],
    ) -> impl Iterator<Item = (u32, u32)> + 'a {
        let units = (specs.iter().zip(&self.rank_of))
            .flat_map(|(spec, &r)| spec.1.iter().flat_map(move |m| m.0.v.map(|i| (i, r))));
        let far =
            (self.far_all.iter().zip(&self.watcher)).flat_map(|(f, &r)| f.0.v.map(|i| (i, r)));
        units
            .chain(far)
            .chain(kinematic.iter().map(|&i| (i, u32::MAX)))
    }
}

/// The rank owning most of `vertices` under the placement by size
/// (`reference_owner`: not moved by the partitions placed by load), the
/// lowest of equals: the home of a pack or unit of them.
fn home_rank(share: &RankShare, vertices: &[u32]) -> u32 {
    most_voted(vertices.iter().map(|&i| share.reference_owner[i as usize]))
}

/// The rank named most often in `votes`, the lowest of equals (rank 0 for
/// none). Counted over the votes' sorted ranks, not a count per rank: a
/// unit's home is asked for every unit of every rank, so a count per rank
/// would cost units × ranks at every pass start.
fn most_voted(votes: impl Iterator<Item = u32>) -> u32 {
    let mut votes: Vec<u32> = votes.collect();
    votes.sort_unstable();
    let (mut best, mut most) = (0u32, 0usize);
    for run in votes.chunk_by(|a, b| a == b) {
        // (ascending: a later rank must have strictly more)
        if run.len() > most {
            (best, most) = (run[0], run.len());
        }
    }
    best
}

/// Places items of the given costs on `ranks` ranks, largest first (the
/// locality-aware balancing of the paper's Algorithm 2): on the item's
/// `home` rank (where most of what it reads and writes lives) while that
/// keeps the home within [`HOME_SLACK`] of the mean load, else on the
/// least-loaded rank (ties: the home, then the lower rank; so an island
/// larger than the limit still goes home while every rank is empty).
/// Returns each item's rank. Depends on the costs and homes only, so every
/// rank places alike.
fn place_near_home(costs: &[f64], home: &[u32], ranks: usize) -> Vec<u32> {
    let mut load = vec![0.0f64; ranks.max(1)];
    let limit = costs.iter().sum::<f64>() / load.len() as f64 * (1.0 + HOME_SLACK);
    let mut owner = vec![0u32; costs.len()];
    for k in largest_first(costs) {
        let (c, h) = (costs[k as usize], home[k as usize] as usize);
        let r = if load[h] + c <= limit {
            h
        } else {
            let key = |r: usize| (load[r], r != h, r);
            (0..load.len())
                .min_by(|&a, &b| {
                    let (ka, kb) = (key(a), key(b));
                    ka.0.total_cmp(&kb.0).then((ka.1, ka.2).cmp(&(kb.1, kb.2)))
                })
                .expect("a rank")
        };
        load[r] += c;
        owner[k as usize] = r as u32;
    }
    owner
}

impl<E: Executor> Engine<E> {
    /// Runs every event in `[t0, t1)` and drifts all vertices to `t1`,
    /// recording trajectories.
    pub(super) fn run_events(&mut self, t0: Tick, t1: Tick) -> Result<PassCounts, SimError> {
        self.ws.begin_pass(self.world.num_vertices());
        let pass = self.run_pass(t0, t1);
        self.ws.end_pass();
        pass
    }

    /// [`Engine::run_events`] with its scratch made.
    fn run_pass(&mut self, t0: Tick, t1: Tick) -> Result<PassCounts, SimError> {
        let mut counts = PassCounts {
            min_separation: f64::INFINITY,
            ..Default::default()
        };
        let begin = trace::span("pass begin");
        let h_el = self.world.lattice.internal_step();
        // (room for every internal tick's breakpoint of a moving vertex was
        // made with the engine, `Engine::new`)
        let active: Vec<(StencilKey, u32)> = (self.world.layers.stencils.iter())
            .map(|(k, s)| (*k, s.depth))
            .collect();
        let max_depth = active.iter().map(|a| a.1).max().unwrap_or(0);
        // (eta_l, k_l, h_l) of every layer in use, computed once per pass
        // (they involve libm::pow).
        let sched = &self.world.schedule;
        let layer_consts: Vec<(f64, f64, Tick)> = (1..=max_depth)
            .map(|l| (sched.eta(l), sched.k(l), sched.step(l)))
            .collect();
        self.begin_islands(&active, &layer_consts, (t0, t1), &mut counts)?;
        drop(begin);
        let mut end = t1;
        let mut s = t0;
        let mut segments = 0u64;
        loop {
            // The segment [s, e) up to the next internal tick (or the
            // window end), then that internal tick.
            let b = tick_at_or_after(s, h_el);
            let e = b.min(t1);
            let internal = b < t1;
            if segments == 1 {
                crate::failpoint::hit("mid-window", self.world.window_index);
            }
            if self.interrupted() {
                counts.interrupted = Some(SimError::Interrupted {
                    time: self.world.lattice.seconds(t0),
                });
                end = s;
                break;
            }
            segments += 1;
            // On one memory the calm part of the internal tick runs beside
            // the islands; each run of vertices' first calm vertex that
            // blows up comes back. Over ranks pieces of it run while this
            // rank waits for the other ranks' island results.
            let calm = internal && self.ws.calm.is_some();
            let (outputs, totals, calm_done) = match (calm, self.share.is_some()) {
                (true, false) => {
                    let (o, t, bad) = self.run_islands_and_calm(&layer_consts, (s, e), &mut counts);
                    (o, t, CalmDone::ForcesAndFolds(bad))
                }
                (calm, _) => {
                    self.run_islands(&layer_consts, (s, e), internal, calm, &mut counts)?
                }
            };
            if let Some(blew_up) = self.apply_islands(&outputs, &totals, t0, &mut counts)? {
                // A speculative pass that blew up in an island (typically a
                // stencil pushed through too few layers): that island
                // stopped before writing a non-finite value, the others
                // finished the segment; the pass ends here, and detection
                // decides whether more layers fix it.
                counts.truncated = Some(blew_up);
                end = e;
                break;
            }
            if !internal {
                break;
            }
            match self.internal_tick(b, &outputs, calm_done, &mut counts) {
                Ok(()) => {}
                Err(e @ SimError::NonFinite { .. }) => {
                    // As above, at the internal tick: the pass ends at `b`,
                    // before any non-finite value was written.
                    counts.truncated = Some(e);
                    end = b;
                    break;
                }
                Err(e) => return Err(e),
            }
            s = b + 1;
        }
        // Store the staged internal ticks' breakpoints, then drift everything
        // to the end of the pass (the window end unless the pass was cut
        // short); over ranks every rank first takes the states of the
        // vertices it did not keep current from their owners.
        let _end = trace::span("pass end");
        if let Some(share) = &self.share {
            let w = &mut self.world;
            let _site = trace::site("events: pass end's states");
            share.gather_states(&self.exec, &mut w.x, &mut w.v, &mut w.tau, &mut self.traj)?;
        }
        self.drift_to(end, t0)?;
        Ok(counts)
    }

    /// Stores the staged breakpoints and drifts every vertex to `end` with
    /// a breakpoint there, in runs of vertices on the executor (each
    /// vertex's position and breakpoint are its own: the bits of one loop).
    fn drift_to(&mut self, end: Tick, t0: Tick) -> Result<(), SimError> {
        use crate::executor::split_chunks;
        let w = &mut self.world;
        let bounds = &self.ws.vertex_runs;
        let lattice = w.lattice;
        struct Run<'a> {
            x: &'a mut [DVec3],
            v: &'a [DVec3],
            tau: &'a mut [Tick],
            traj: crate::trajectory::TrajectoryRun<'a>,
            added: usize,
        }
        let (x_runs, tau_runs) = (
            split_chunks(&mut w.x, bounds),
            split_chunks(&mut w.tau, bounds),
        );
        let v = &w.v;
        let mut runs: Vec<Run<'_>> = (self.traj.runs(bounds, None).into_iter())
            .zip(x_runs.into_iter().zip(tau_runs))
            .enumerate()
            .map(|(k, (traj, ((_, x), (_, tau))))| Run {
                x,
                v: &v[bounds[k]..bounds[k + 1]],
                tau,
                traj,
                added: 0,
            })
            .collect();
        self.exec.for_each_item(&mut runs, &|_, r| {
            // (the staged ticks stored first, as `Trajectories::flush`)
            r.traj.prepare();
            for j in 0..r.x.len() {
                let p = lattice.drift(r.x[j], r.v[j], r.tau[j], end);
                r.x[j] = p;
                r.tau[j] = end;
                r.added += usize::from(r.traj.record(j, end, p));
            }
        });
        let added = runs.iter().map(|r| r.added).sum();
        drop(runs);
        let w = &self.world;
        // (the error a breakpoint at a time would give: the first one over)
        if !self.traj.fits(added) {
            return Err(budget_error(w, t0, self.traj.over_budget(added)));
        }
        (self.traj.add_recorded(added)).map_err(|e| budget_error(w, t0, e))
    }

    /// The pass's contact islands, their units (all awake) and far
    /// stencils, and the counts that follow from the active set alone: the
    /// layer events of the window (each stencil of depth `d` at every tick
    /// of layers `1..=d`) and the largest island's; beside the units, the
    /// trajectories' start at `t0`.
    fn begin_islands(
        &mut self,
        active: &[(StencilKey, u32)],
        layer_consts: &[(f64, f64, Tick)],
        (t0, t1): (Tick, Tick),
        counts: &mut PassCounts,
    ) -> Result<(), SimError> {
        let w = &self.world;
        let keys = active.iter().map(|a| &a.0);
        let islands = if self.one_island {
            Islands::merged(keys, &w.inv_mass)
        } else {
            Islands::build(keys, &w.inv_mass)
        };
        // through[d]: the ticks of layers 1..=d in [t0, t1).
        let mut through = vec![0u64; layer_consts.len() + 1];
        for l in 1..through.len() {
            through[l] = through[l - 1] + ticks_in(t0, t1, layer_consts[l - 1].2);
        }
        let events_of = |k: usize| -> u64 {
            (islands.stencils_of(k).iter())
                .map(|&a| through[active[a as usize].1 as usize])
                .sum()
        };
        counts.islands = islands.len() as u64;
        counts.layer_events = (0..islands.len()).map(events_of).sum();
        counts.largest_island_layer_events = (0..islands.len()).map(events_of).max().unwrap_or(0);
        // The packs: the islands, the small ones packed; over ranks each
        // runs on one rank for the whole pass.
        let packs = islands.packed(self.island_pack);
        let me = self.exec.rank() as u32;
        let split = self.far_stencils && !self.one_island && !self.every_layer_event;
        counts.split = split;
        let spread = split && self.share.is_some();
        let pack_rank = match &self.share {
            Some(share) if !spread => {
                // Each pack's home: the rank owning most of its vertices
                // under the placement by size (`reference_owner`: not
                // moved by the partitions placed by load).
                let pack_cost: Vec<f64> = (0..packs.len())
                    .map(|k| packs.stencils_of(k).len() as f64)
                    .collect();
                let home: Vec<u32> = (0..packs.len())
                    .map(|k| home_rank(share, packs.vertices_of(k)))
                    .collect();
                place_near_home(&pack_cost, &home, share.ranks)
            }
            // (one memory, or the units spread: no pack is placed)
            _ => vec![me; packs.len()],
        };
        // This rank's packs as units; split, the islands of their near
        // stencils, with the far stencils beside. Split over ranks, the
        // units are spread: every rank builds every unit's spec, each unit
        // runs on the rank placed for it (near the owners of its vertices,
        // by its stencils) and each far stencil is watched by one rank
        // (`spread_units`).
        let mine = |k: u32| spread || pack_rank[k as usize] == me;
        let kinematic = units::kinematic_of(w, active.iter().map(|a| &a.0));
        let h_el = w.lattice.internal_step();
        let mut checked = Checked::default();
        // Over ranks: every vertex a unit's stencils read, with the unit's
        // rank (`u32::MAX`: every rank); only the reads that concern this
        // rank are kept (by it, or of a vertex it owns: all that
        // `RankShare::pass` reads; every rank's reads were 4 MB a pass on
        // the 100k twister, grown push by push on every rank).
        let mut reads: Vec<(u32, u32)> = Vec::new();
        let concerns_me = |&(i, r): &(u32, u32)| match &self.share {
            Some(share) => r == me || r == u32::MAX || share.owns(i as usize),
            None => false,
        };
        let (specs, far, rank_of) = if split {
            let mut pack_of = vec![0u32; active.len()];
            for k in 0..packs.len() {
                for &a in packs.stencils_of(k) {
                    pack_of[a as usize] = k as u32;
                }
            }
            let candidates: Vec<usize> = (0..active.len())
                .filter(|&a| mine(pack_of[a]) && may_be_far(w, &active[a].0))
                .collect();
            let pass = (t0, t0 + h_el, t1);
            // (spread: each candidate's certificate end, when far)
            let mut ends: Vec<Option<Tick>> = Vec::new();
            let (far, is_far) = match &self.share {
                Some(share) if spread => {
                    // (a share each, all-gathered: the units, and so the
                    // far stencils each rank watches, follow from all)
                    let keys: Vec<StencilKey> = candidates.iter().map(|&a| active[a].0).collect();
                    ends = far_at_start_shared(&self.exec, w, share, &keys, pass, &mut checked)?;
                    (
                        FarSet::default(),
                        ends.iter().map(Option::is_some).collect(),
                    )
                }
                _ => {
                    let listed: Vec<(StencilKey, u32, u32)> = (candidates.iter())
                        .map(|&a| (active[a].0, active[a].1, pack_of[a]))
                        .collect();
                    FarSet::new(&self.exec, w, &listed, &mine, pass, &mut checked)
                }
            };
            let mut near = vec![true; active.len()];
            for (&a, &f) in candidates.iter().zip(&is_far) {
                near[a] = !f;
            }
            let near: Vec<usize> = (0..active.len())
                .filter(|&a| near[a] && mine(pack_of[a]))
                .collect();
            // Each island of the near stencils alone: packed, a promotion
            // would merge every island of the packs it touches (measured:
            // the twister's units fused into one of 5,600 stencils within a
            // pass).
            let units = Islands::build(near.iter().map(|&a| &active[a].0), &w.inv_mass);
            let specs = (0..units.len())
                .map(|u| {
                    let members = (units.stencils_of(u).iter())
                        .map(|&a| active[near[a as usize]])
                        .collect();
                    (units.vertices_of(u).to_vec(), members)
                })
                .collect::<Vec<UnitSpec>>();
            let (far, spread) = match self.share.as_ref().filter(|_| spread) {
                None => (far, None),
                Some(share) => {
                    // (made to their length: every rank keeps `far_all`
                    // through the pass, and grown by doubling it was up to
                    // twice that, where a rank's memory peaks)
                    let count = ends.iter().flatten().count();
                    let mut far_all = Vec::with_capacity(count);
                    let mut until = Vec::with_capacity(count);
                    for (&a, end) in candidates.iter().zip(std::mem::take(&mut ends)) {
                        if let Some(end) = end {
                            far_all.push(active[a]);
                            until.push(end);
                        }
                    }
                    let (far, spread) = spread_units(w, share, &specs, far_all, &until, pass);
                    reads.extend(spread.reads(&specs, &kinematic).filter(concerns_me));
                    (far, Some(spread))
                }
            };
            (specs, far, spread)
        } else {
            let specs = (0..packs.len())
                .filter(|&k| mine(k as u32))
                .map(|k| {
                    let members = (packs.stencils_of(k).iter())
                        .map(|&a| active[a as usize])
                        .collect();
                    (packs.vertices_of(k).to_vec(), members)
                })
                .collect::<Vec<UnitSpec>>();
            (specs, FarSet::default(), None)
        };
        if self.share.is_some() && !spread {
            // Every vertex a pack's stencils read (near and far), with the
            // pack's rank.
            reads = (0..packs.len())
                .flat_map(|k| {
                    let r = pack_rank[k];
                    (packs.stencils_of(k).iter())
                        .flat_map(move |&a| active[a as usize].0.v.map(|i| (i, r)))
                })
                .filter(concerns_me)
                .collect();
        }
        // The trajectories' start (every vertex's first breakpoint: a
        // memory-bound loop) beside the units' states (a giant island's
        // takes one thread).
        let (traj, exec) = (&mut self.traj, &self.exec);
        let mut args = Some((specs, kinematic, far, checked, through, rank_of));
        let mut units = None;
        exec.join(&mut || traj.begin(t0, &w.x), &mut || {
            let (specs, kinematic, far, checked, through, rank_of) =
                args.take().expect("built once");
            units = Some(Units::new(
                exec, w, specs, kinematic, far, checked, t0, through, rank_of,
            ));
        });
        let ws = &mut self.ws;
        ws.pass_end = t1;
        ws.no_islands = packs.is_empty();
        ws.units = units.expect("built");
        let over_ranks = self.share.is_some();
        ws.calm = (!packs.is_empty()).then(|| {
            let mut in_island = vec![false; w.num_vertices()];
            for &i in (0..packs.len()).flat_map(|k| packs.vertices_of(k)) {
                in_island[i as usize] = true;
            }
            let elements = w.internal.mask_where(|i| !in_island[i as usize]);
            // A vertex folds calm when it is outside every island and
            // every element it sums is calm. (Over ranks a rank holds its
            // partitions' elements only: a vertex it owns that sums a slot
            // of another rank's element folds after the exchange anyway,
            // `folds_remote`.)
            let mut waits = in_island.clone();
            for verts in w.internal.verts_where(&elements, false) {
                verts.iter().for_each(|&i| waits[i as usize] = true);
            }
            if over_ranks {
                // The positions by whether the vertex is in an island (made
                // of those kept current here once the pass's share is
                // known, below); of the owned vertices, those that fold
                // calm and no slot from another rank, and the others.
                let share = self.share.as_ref().expect("over ranks");
                let local = |i: usize| share.owns(i) && !waits[i] && !share.folds_remote[i];
                let kinds = [&share.boundary_partition, &share.interior_partition];
                let partitions = (kinds.into_iter())
                    .flat_map(|kind| (0..kind.len()).filter(|&p| kind[p]))
                    .filter(|&p| elements.in_partition[p] > 0)
                    .map(|p| p as u32)
                    .collect();
                return Calm {
                    island_in_run: in_runs(&ws.vertex_runs, |i| in_island[i]),
                    calm_in_run: in_runs(&ws.vertex_runs, |i| !in_island[i]),
                    calm_fold_in_run: in_runs(&ws.vertex_runs, local),
                    rest_fold_in_run: in_runs(&ws.vertex_runs, |i| share.owns(i) && !local(i)),
                    elements,
                    partitions,
                };
            }
            Calm {
                elements,
                island_in_run: in_runs(&ws.vertex_runs, |i| in_island[i]),
                calm_in_run: in_runs(&ws.vertex_runs, |i| !in_island[i]),
                calm_fold_in_run: in_runs(&ws.vertex_runs, |i| !waits[i]),
                rest_fold_in_run: in_runs(&ws.vertex_runs, |i| waits[i]),
                partitions: Vec::new(),
            }
        });
        if let Some(share) = &self.share {
            // A read by every rank: of a scripted vertex, which no rank
            // sends (`PassShare::scripted`), only this rank's matters.
            let ranks = share.ranks as u32;
            let every = |(i, r): (u32, u32)| {
                let (from, to) = match r {
                    u32::MAX if share.scripted[i as usize] => (me, me + 1),
                    u32::MAX => (0, ranks),
                    r => (r, r + 1),
                };
                (from..to).map(move |r| (i, r))
            };
            ws.pass_share = share.pass(reads.into_iter().flat_map(every));
            let live = &ws.pass_share.live;
            ws.live_in_run = in_runs(&ws.vertex_runs, |i| live[i]);
            if let Some(calm) = &mut ws.calm {
                let runs = &ws.vertex_runs;
                let keep_live = |lists: &mut Vec<Vec<u16>>| {
                    for (k, list) in lists.iter_mut().enumerate() {
                        list.retain(|&j| live[runs[k] + usize::from(j)]);
                    }
                };
                keep_live(&mut calm.island_in_run);
                keep_live(&mut calm.calm_in_run);
            }
            if ws.owned_in_run.is_empty() {
                ws.owned_in_run = in_runs(&ws.vertex_runs, |i| share.owns(i));
            }
        }
        Ok(())
    }

    /// Every island's segment `[s, e)` (and its kicks at the internal tick
    /// `e` when `internal`), in parallel, in bins balanced by the seconds
    /// each island's last segment took. On one memory: every island's
    /// output, in island order. Over ranks each island runs on its rank,
    /// which keeps its output whole and hands each other rank, in one
    /// all-to-all, only what that rank keeps of it ([`Self::address`]):
    /// this rank's islands' outputs in island order, then one part from
    /// each peer that sent one, in rank order. With them, the totals every
    /// rank agrees on.
    fn run_islands(
        &mut self,
        layer_consts: &[(f64, f64, Tick)],
        (s, e): (Tick, Tick),
        internal: bool,
        calm: bool,
        counts: &mut PassCounts,
    ) -> Result<(Vec<SegmentOutput>, SegmentTotals, CalmDone), SimError> {
        if self.ws.no_islands {
            // (On every rank alike: no active stencil.)
            return Ok((Vec::new(), SegmentTotals::default(), CalmDone::Nothing));
        }
        let (ranks, me) = (self.exec.ranks(), self.exec.rank() as u32);
        let cpu = (ranks > 1).then(|| self.exec.work_cpu_seconds());
        let spread = self.ws.units.spread();
        if spread {
            let (promote, checked) = (self.ws.units).renew(&self.exec, &self.world, (s, e));
            let site = "events: promotions before a segment";
            let (promote, checked) = self.agree(promote, checked, site)?;
            let share = self.share.as_ref().expect("over ranks");
            let homes = (&share.reference_owner[..], &share.owner[..]);
            let moves = (self.ws.units).promote_agreed(&promote, checked, &self.world, homes);
            self.settle(&moves, s)?;
        }
        let pass = Pass {
            world: &self.world,
            layer_consts,
            exhaustive: self.every_layer_event,
            pass_end: self.ws.pass_end,
            split_batches: true,
        };
        // This rank's units' outputs (spread: with their units, and the far
        // stencils' counts kept apart: every rank has the same).
        let mut own: Vec<(u32, SegmentOutput)> = Vec::new();
        let outputs = if spread {
            own = (self.ws.units).run(&self.exec, &pass, (s, e), internal);
            Vec::new()
        } else {
            (self.ws.units).segment(&self.exec, &pass, (s, e), internal)
        };
        let mine = || own.iter().map(|o| &o.1).chain(&outputs);
        let totals = SegmentTotals::of(mine());
        if ranks == 1 {
            return Ok((outputs, totals, CalmDone::Nothing));
        }
        counts.island_cpu += self.exec.work_cpu_seconds() - cpu.expect("over ranks");
        let parts = self.address(mine());
        // While the islands' results travel, this rank computes pieces of
        // the calm part of the internal tick (they need none of them): the
        // calm positions, then one partition's calm elements per piece.
        let (exec, world, ws) = (&self.exec, &self.world, &mut self.ws);
        let rank = self.share.as_ref().map(|s| &s.slots);
        let runs = ws.vertex_runs.len().saturating_sub(1);
        let mut done = CalmProgress {
            positions: false,
            elements: vec![false; world.internal.partitions.len()],
            folds: vec![None; runs],
        };
        let (mut next, mut seconds) = (0, 0.0);
        let mut calm_piece = || -> bool {
            let Some(calm) = ws.calm.as_ref().filter(|_| calm) else {
                return false;
            };
            let clock = Instant::now();
            if !done.positions {
                calm_positions(exec, world, calm, &ws.vertex_runs, &mut ws.xt, e);
                done.positions = true;
            } else if let Some(&p) = calm.partitions.get(next) {
                let p = p as usize;
                let chunk = &mut ws.out[ws.bounds[p]..ws.bounds[p + 1]];
                let (xv, mask) = ((&ws.xt[..], &world.v[..]), (&calm.elements, true));
                (world.internal).evaluate_partition_masked(p, xv, chunk, mask);
                done.elements[p] = true;
                next += 1;
            } else if next < calm.partitions.len() + runs {
                // Once every calm element is in: a run of vertices' calm
                // folds (their slots are all calm and computed here).
                let k = next - calm.partitions.len();
                let (a, b) = (ws.vertex_runs[k], ws.vertex_runs[k + 1]);
                let listed = &calm.calm_fold_in_run[k];
                let out = crate::share::Slots { out: &ws.out, rank };
                let slots = (out, &ws.xt[..]);
                let fold = (&mut ws.acc[a..b], &mut ws.v_new[a..b]);
                let bad = internal::fold_run_listed(world, slots, e, (a, listed), fold);
                done.folds[k] = Some(bad);
                next += 1;
            }
            seconds += clock.elapsed().as_secs_f64();
            next < calm.partitions.len() + runs
        };
        let site = trace::site("events: units' outputs");
        let (heads, received) = exec.all_to_all(totals.words(), parts, &mut calm_piece)?;
        drop(site);
        counts.internal_seconds += seconds;
        let mut all = SegmentTotals::summed(&heads, me as usize)?;
        let mut outputs = outputs;
        outputs.extend(from_peers(received, me as usize));
        let done = match calm {
            true => CalmDone::Partly(done),
            false => CalmDone::Nothing,
        };
        if spread {
            let cpu = self.exec.work_cpu_seconds();
            all = self.check_spread(layer_consts, (s, e), internal, &mut own, &mut outputs, all)?;
            counts.island_cpu += self.exec.work_cpu_seconds() - cpu;
            own.extend(outputs.into_iter().map(|o| (u32::MAX, o)));
            outputs = own.into_iter().map(|o| o.1).collect();
        }
        Ok((outputs, all, done))
    }

    /// Over ranks with the units spread, after a segment's all-to-all:
    /// each rank checks the far stencils it watches against the units'
    /// outputs (this rank's units' `own`, and in `theirs` what the others
    /// sent it), and the promotions are agreed; while a check promotes, the
    /// merged units move to their ranks, run the segment again there, and
    /// their results replace the old ones in another all-to-all. Returns the segment's totals (`totals`: the
    /// first all-to-all's) with the far stencils' counts.
    fn check_spread(
        &mut self,
        layer_consts: &[(f64, f64, Tick)],
        (s, e): (Tick, Tick),
        internal: bool,
        own: &mut Vec<(u32, SegmentOutput)>,
        theirs: &mut Vec<SegmentOutput>,
        mut totals: SegmentTotals,
    ) -> Result<SegmentTotals, SimError> {
        let _span = trace::span("far after");
        let me = self.exec.rank();
        loop {
            let (promote, last) = {
                let fast = (own.iter().map(|o| &o.1).chain(theirs.iter()))
                    .flat_map(|o| o.fast.iter().copied());
                let here = (own.iter()).flat_map(|o| o.1.breakpoints.iter().map(|b| (b.0, 1)));
                let added = here.chain(theirs.iter().flat_map(|o| o.far_added.iter().copied()));
                (self.ws.units).check(&self.world, (s, e), fast, added)
            };
            let (promote, last) = self.agree(promote, last, "events: promotions after a check")?;
            let share = self.share.as_ref().expect("over ranks");
            let homes = (&share.reference_owner[..], &share.owner[..]);
            let merged = (self.ws.units).check_agreed(&promote, last, &self.world, homes);
            let Some(merged) = merged else {
                break;
            };
            self.settle(&merged.moves, s)?;
            let pass = Pass {
                world: &self.world,
                layer_consts,
                exhaustive: self.every_layer_event,
                pass_end: self.ws.pass_end,
                split_batches: true,
            };
            let rerun = (self.ws.units).rerun(&self.exec, &pass, (s, e), internal, &merged.changed);
            let gone = |u: &u32| {
                merged.changed.binary_search(u).is_ok() || merged.emptied.binary_search(u).is_ok()
            };
            own.retain(|(u, _)| !gone(u));
            for part in theirs.iter_mut() {
                part.drop_vertices(&merged.vertices);
            }
            let parts = self.address(rerun.iter().map(|o| &o.1));
            own.extend(rerun);
            own.sort_unstable_by_key(|o| o.0);
            let mine = SegmentTotals::of(own.iter().map(|o| &o.1));
            let _site = trace::site("events: rerun units' outputs");
            let (heads, received) = self.exec.all_to_all(mine.words(), parts, &mut || false)?;
            totals = SegmentTotals::summed(&heads, me)?;
            theirs.extend(from_peers(received, me));
        }
        let far = self.ws.units.finish(internal);
        totals.add(&SegmentTotals::of(std::iter::once(&far)));
        Ok(totals)
    }

    /// **Collective** (an all-gather), over ranks with the units spread:
    /// the far stencils each rank found to promote (`promote`, by their
    /// index among every rank's) and what finding them evaluated
    /// (`checked`), agreed: every rank's promotions, ascending (each far
    /// stencil has one watcher), and the evaluations summed. `site` names
    /// the all-gather ([`trace::site`]).
    fn agree(
        &self,
        promote: Vec<u32>,
        checked: Checked,
        site: &'static str,
    ) -> Result<(Vec<u32>, Checked), SimError> {
        let bits = f64::from_bits;
        let head = DVec3::new(bits(checked.evaluations), checked.min_separation, 0.0);
        let mine: Vec<DVec3> = std::iter::once(head)
            .chain(
                promote
                    .iter()
                    .map(|&f| DVec3::new(bits(f.into()), 0.0, 0.0)),
            )
            .collect();
        let _site = trace::site(site);
        let all = self.exec.all_gather_vectors(&mine)?;
        let (mut agreed, mut total) = (Vec::<u64>::new(), Checked::default());
        for part in &all {
            let Some((head, ids)) = part.split_first() else {
                return Err(SimError::Ranks(crate::executor::CommError(
                    "an empty part of the far stencils' agreement".into(),
                )));
            };
            total.add(&Checked {
                evaluations: head.x.to_bits(),
                min_separation: head.y,
            });
            agreed.extend(ids.iter().map(|c| c.x.to_bits()));
        }
        let far = self.ws.units.far_count() as u64;
        if let Some(bad) = agreed.iter().find(|&&f| f >= far) {
            return Err(SimError::Ranks(crate::executor::CommError(format!(
                "a rank named far stencil {bad} of {far} to promote"
            ))));
        }
        let mut agreed: Vec<u32> = agreed.into_iter().map(|f| f as u32).collect();
        agreed.sort_unstable();
        Ok((agreed, total))
    }

    /// Over ranks with the units spread, after a promotion at tick `s`:
    /// the vertices of `moves` go to their units' new ranks, then the new
    /// units of this rank are built (from their vertices' states there).
    fn settle(&mut self, moves: &[units::Move], s: Tick) -> Result<(), SimError> {
        self.migrate(moves)?;
        (self.ws.units).build(&self.exec, &self.world, s);
        Ok(())
    }

    /// Over ranks with the units spread: the vertices of `moves` whose unit
    /// now runs on another rank. Each goes from the rank that ran it to its
    /// new one with its state (point to point: every rank knows the moves),
    /// and from now on its owner sends that rank its new velocities at the
    /// internal ticks.
    fn migrate(&mut self, moves: &[units::Move]) -> Result<(), SimError> {
        if moves.is_empty() {
            return Ok(());
        }
        let share = self.share.as_ref().expect("over ranks");
        let me = share.rank as u32;
        let w = &mut self.world;
        let mut sends: std::collections::BTreeMap<usize, Vec<f64>> = Default::default();
        let mut recvs: std::collections::BTreeMap<usize, Vec<u32>> = Default::default();
        for &(i, from, to) in moves {
            let k = i as usize;
            if from == me && to != me {
                let words = sends.entry(to as usize).or_default();
                words.extend(w.x[k].to_array());
                words.extend(w.v[k].to_array());
                words.push(f64::from_bits(w.tau[k]));
            } else if to == me && from != me {
                recvs.entry(from as usize).or_default().push(i);
            }
        }
        let lengths: Vec<(usize, usize)> = (recvs.iter())
            .map(|(&peer, list)| (peer, 7 * list.len()))
            .collect();
        let _site = trace::site("events: moved units' vertices");
        let received =
            (self.exec).exchange_words(sends.into_iter().collect(), &lengths, &mut || {})?;
        for ((_, list), words) in recvs.iter().zip(received) {
            for (&i, c) in list.iter().zip(words.chunks_exact(7)) {
                let k = i as usize;
                w.x[k] = DVec3::new(c[0], c[1], c[2]);
                w.v[k] = DVec3::new(c[3], c[4], c[5]);
                w.tau[k] = c[6].to_bits();
            }
        }
        let ws = &mut self.ws;
        for &(i, _, to) in moves {
            if share.keep_live(&mut ws.pass_share, i as usize, to) {
                // Newly kept current here: positions at the internal ticks
                // too (an island vertex, so on the calm part's island side).
                let k = ws.vertex_runs.partition_point(|&b| b <= i as usize) - 1;
                let j = (i as usize - ws.vertex_runs[k]) as u16;
                insert_sorted(&mut ws.live_in_run[k], j);
                if let Some(calm) = &mut ws.calm {
                    insert_sorted(&mut calm.island_in_run[k], j);
                }
            }
        }
        self.moved_between_ranks += moves.iter().filter(|m| m.1 != m.2).count() as u64;
        Ok(())
    }

    /// On one memory, every island's segment `[s, e)` and its kicks at the
    /// internal tick `e`, while the calm part of that tick ([`Calm`]) runs
    /// beside it: the positions at `e` of the vertices outside every
    /// island, the internal forces of the elements among them, and the
    /// calm vertices' folds and new velocities, of which each run's first
    /// that blows up is returned. Its wall seconds count as internal-force
    /// time.
    fn run_islands_and_calm(
        &mut self,
        layer_consts: &[(f64, f64, Tick)],
        (s, e): (Tick, Tick),
        counts: &mut PassCounts,
    ) -> (Vec<SegmentOutput>, SegmentTotals, Vec<Option<usize>>) {
        let Engine {
            world,
            exec,
            ws,
            traj,
            ..
        } = self;
        let world = &*world;
        let pass = Pass {
            world,
            layer_consts,
            exhaustive: self.every_layer_event,
            pass_end: ws.pass_end,
            split_batches: false,
        };
        let Workspace {
            units,
            xt,
            out,
            acc,
            v_new,
            vertex_runs,
            calm,
            ..
        } = ws;
        let calm = calm.as_ref().expect("a calm part");
        let mut outputs = Vec::new();
        let (mut seconds, mut bad) = (0.0, Vec::new());
        let _join = trace::span("islands and calm");
        exec.join(
            &mut || {
                outputs = units.segment(exec, &pass, (s, e), true);
            },
            &mut || {
                // Full staged columns, which the tick would store first
                // (a loop bound by memory latency, vertex by vertex), are
                // stored here: the islands neither read nor write the
                // trajectories while they run, and the polylines are the
                // same whenever the staged ticks are stored.
                if traj.staged_full() {
                    let _span = trace::span("staged store");
                    traj.flush(exec, vertex_runs);
                }
                let clock = Instant::now();
                calm_forces(exec, world, calm, vertex_runs, (xt, out), e);
                let runs = (&calm.calm_fold_in_run[..], &vertex_runs[..]);
                let slots = (crate::share::Slots { out, rank: None }, &xt[..]);
                bad = internal::fold_listed(
                    exec,
                    world,
                    slots,
                    e,
                    runs,
                    (&mut acc[..], &mut v_new[..]),
                );
                seconds = clock.elapsed().as_secs_f64();
            },
        );
        counts.internal_seconds += seconds;
        let totals = SegmentTotals::of(&outputs);
        (outputs, totals, bad)
    }

    /// Over ranks: what each rank keeps of this rank's islands' `outputs`
    /// (one part per rank, `None` where nothing; this rank's own `None`):
    /// the new states of the vertices it keeps current through the pass (it
    /// owns them, or a partition placed on it reads them), and the
    /// breakpoints and the kicks at the internal tick of those it owns (it
    /// holds their trajectories and folds their velocities). The islands'
    /// vertices are disjoint, so each part keeps each vertex's entries in
    /// their order.
    fn address<'a>(
        &self,
        outputs: impl Iterator<Item = &'a SegmentOutput>,
    ) -> Vec<Option<SegmentOutput>> {
        let share = self.share.as_ref().expect("over ranks");
        let me = share.rank as u32;
        let mut parts: Vec<SegmentOutput> = vec![SegmentOutput::default(); share.ranks];
        let units = &self.ws.units;
        let spread = units.spread();
        let mut to: Vec<u32> = Vec::new();
        for out in outputs {
            for m in &out.moved {
                let i = m.0 as usize;
                to.clear();
                to.push(share.owner[i]);
                to.extend_from_slice(share.readers(i));
                if spread {
                    // (and the ranks watching a far stencil of it)
                    to.extend_from_slice(units.watchers(m.0));
                    to.sort_unstable();
                    to.dedup();
                }
                for &r in to.iter().filter(|&&r| r != me) {
                    parts[r as usize].moved.push(*m);
                }
            }
            if spread {
                // The largest speed² of each far vertex, and its
                // breakpoints counted (a vertex's are consecutive: one
                // island's, in time order), to the ranks watching it.
                let mut fast = out.fast.clone();
                fast.sort_unstable_by_key(|f| f.0);
                fast.dedup_by(|later, first| {
                    let same = later.0 == first.0;
                    if same {
                        first.1 = first.1.max(later.1);
                    }
                    same
                });
                let mut added: Vec<(u32, u32)> = Vec::new();
                for b in out.breakpoints.iter() {
                    match added.last_mut() {
                        Some(last) if last.0 == b.0 => last.1 += 1,
                        _ => added.push((b.0, 1)),
                    }
                }
                for &(i, speed2) in &fast {
                    for &r in units.watchers(i).iter().filter(|&&r| r != me) {
                        parts[r as usize].fast.push((i, speed2));
                    }
                }
                for &(i, count) in &added {
                    for &r in units.watchers(i).iter().filter(|&&r| r != me) {
                        parts[r as usize].far_added.push((i, count));
                    }
                }
            }
            for b in &out.breakpoints {
                let owner = share.owner[b.0 as usize];
                if owner != me {
                    parts[owner as usize].breakpoints.push(*b);
                }
            }
            for k in &out.at_internal {
                let owner = share.owner[k.0 as usize];
                if owner != me {
                    parts[owner as usize].at_internal.push(*k);
                }
            }
        }
        parts
            .into_iter()
            .map(|p| {
                let empty = p.moved.is_empty() && p.breakpoints.is_empty();
                let far = p.fast.is_empty() && p.far_added.is_empty();
                (!(empty && far && p.at_internal.is_empty())).then_some(p)
            })
            .collect()
    }

    /// Applies the islands' segment results: their vertices' new states and
    /// their breakpoints, each as present here (over ranks: what this rank
    /// keeps), the budget checked against `totals` (every rank's). Returns
    /// the blow-up to report (the earliest, then the lowest vertex) if an
    /// island stopped at one.
    fn apply_islands(
        &mut self,
        outputs: &[SegmentOutput],
        totals: &SegmentTotals,
        t0: Tick,
        counts: &mut PassCounts,
    ) -> Result<Option<SimError>, SimError> {
        let _span = trace::span("islands merge");
        let w = &mut self.world;
        // Every breakpoint of an island adds one to its vertex's polyline
        // (it is later than the vertex's last: no island batch falls on the
        // pass's first tick, an internal tick), so `totals.breakpoints` is
        // what the budget gains on every rank.
        let count = totals.breakpoints as usize;
        if count > 0 && !self.traj.fits(count) {
            return Err(budget_error(w, t0, self.traj.over_budget(count)));
        }
        // The breakpoints go to their vertices' runs, each run's in output
        // order (a vertex's are all one island's, in time order), and the
        // runs record them on the executor.
        let present: usize = outputs.iter().map(|o| o.breakpoints.len()).sum();
        if present > 0 {
            let runs = &self.ws.vertex_runs;
            let all = outputs.iter().flat_map(|out| &out.breakpoints);
            let breakpoints = all.map(|&(i, t, x)| (i, (t, x)));
            bucket_by_run(&mut self.ws.breakpoints_by_run, runs, breakpoints);
            let mut record = self.traj.record_runs(runs);
            let by_run = &self.ws.breakpoints_by_run;
            let added = std::sync::atomic::AtomicUsize::new(0);
            self.exec.for_each_item(&mut record, &|k, r| {
                let n = (by_run[k].iter())
                    .filter(|&&(j, (t, x))| r.record(j as usize, t, x))
                    .count();
                added.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
            });
            // Each breakpoint present here lengthens its polyline (see
            // above); over ranks these are the ones this rank keeps.
            debug_assert_eq!(added.into_inner(), present);
        }
        if count > 0 {
            self.traj
                .add_recorded(count)
                .map_err(|e| budget_error(w, t0, e))?;
        }
        for out in outputs {
            for &(i, x, v, tau) in &out.moved {
                let i = i as usize;
                (w.x[i], w.v[i], w.tau[i]) = (x, v, tau);
            }
        }
        counts.layer_evaluations += totals.evaluations;
        counts.layer_kicks += totals.kicks;
        counts.min_separation = counts.min_separation.min(totals.min_separation);
        counts.far.far += totals.far.far;
        counts.far.promoted += totals.far.promoted;
        counts.far.reruns += totals.far.reruns;
        counts.far.largest = counts.far.largest.max(totals.far.largest);
        Ok(totals.blew_up.map(|(t, i)| SimError::NonFinite {
            place: w.place(i),
            vertex: i,
            time: w.lattice.seconds(t),
        }))
    }
}

/// What every rank agrees on of a segment's islands: their counts summed,
/// the smallest distance, the earliest blow-up (then the lowest vertex) and
/// their breakpoints, over every rank's islands.
#[derive(Clone, Copy, Debug)]
pub(super) struct SegmentTotals {
    evaluations: u64,
    kicks: u64,
    min_separation: f64,
    blew_up: Option<(Tick, u32)>,
    breakpoints: u64,
    far: FarCounts,
}

/// No island: nothing counted, no distance seen.
impl Default for SegmentTotals {
    fn default() -> Self {
        SegmentTotals {
            evaluations: 0,
            kicks: 0,
            min_separation: f64::INFINITY,
            blew_up: None,
            breakpoints: 0,
            far: FarCounts::default(),
        }
    }
}

impl SegmentTotals {
    /// The totals of `outputs` (in their order).
    fn of<'a>(outputs: impl IntoIterator<Item = &'a SegmentOutput>) -> Self {
        let mut totals = SegmentTotals::default();
        for out in outputs {
            totals.add(&SegmentTotals {
                evaluations: out.evaluations,
                kicks: out.kicks,
                min_separation: out.min_separation,
                blew_up: out.blew_up,
                breakpoints: out.breakpoints.len() as u64,
                far: out.far,
            });
        }
        totals
    }

    fn add(&mut self, other: &SegmentTotals) {
        self.evaluations += other.evaluations;
        self.kicks += other.kicks;
        // (`+ 0.0` makes a zero positive: `min` may return either zero, and
        // the totals are folded in rank order, not island order.)
        self.min_separation = self.min_separation.min(other.min_separation) + 0.0;
        if let Some(b) = other.blew_up {
            self.blew_up = Some(self.blew_up.map_or(b, |a| a.min(b)));
        }
        self.breakpoints += other.breakpoints;
        self.far.far += other.far.far;
        self.far.promoted += other.far.promoted;
        self.far.reruns += other.far.reruns;
        self.far.largest = self.far.largest.max(other.far.largest);
    }

    /// As the words of an all-to-all's head (no blow-up: a tick of all
    /// ones).
    fn words(&self) -> Vec<u64> {
        let (t, i) = self.blew_up.unwrap_or((Tick::MAX, 0));
        let min = self.min_separation.to_bits();
        vec![
            self.evaluations,
            self.kicks,
            min,
            t,
            i.into(),
            self.breakpoints,
            self.far.far,
            self.far.promoted,
            self.far.reruns,
            self.far.largest,
        ]
    }

    /// The totals of every rank's head (as [`SegmentTotals::words`]), in
    /// rank order; `me`: this rank, for the error.
    fn summed(heads: &[Vec<u64>], me: usize) -> Result<Self, SimError> {
        let mut all = SegmentTotals::default();
        for (j, head) in heads.iter().enumerate() {
            let theirs = SegmentTotals::from_words(head).ok_or_else(|| {
                SimError::Ranks(crate::executor::CommError(format!(
                    "rank {me}: rank {j} sent a malformed segment head"
                )))
            })?;
            all.add(&theirs);
        }
        Ok(all)
    }

    fn from_words(w: &[u64]) -> Option<Self> {
        let &[evaluations, kicks, min, t, i, breakpoints, far, promoted, reruns, largest] = w
        else {
            return None;
        };
        Some(SegmentTotals {
            evaluations,
            kicks,
            min_separation: f64::from_bits(min),
            blew_up: (t != Tick::MAX).then_some((t, u32::try_from(i).ok()?)),
            breakpoints,
            far: FarCounts {
                far,
                promoted,
                reruns,
                largest,
            },
        })
    }
}

fn budget_error(w: &World, t0: Tick, e: crate::trajectory::BudgetExceeded) -> SimError {
    SimError::TrajectoryBudget {
        time: w.lattice.seconds(t0),
        breakpoints: e.breakpoints,
        budget_bytes: e.budget_bytes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clock_ticks_in_a_range() {
        assert_eq!(ticks_in(0, 10, 3), 3); // 3, 6, 9
        assert_eq!(ticks_in(3, 10, 3), 3);
        assert_eq!(ticks_in(4, 10, 3), 2);
        assert_eq!(ticks_in(4, 9, 3), 1);
        assert_eq!(tick_at_or_after(0, 5), 5);
        assert_eq!(tick_at_or_after(5, 5), 5);
        assert_eq!(tick_at_or_after(6, 5), 10);
    }

    #[test]
    fn most_voted_is_the_per_rank_counts_choice() {
        // Against a count per rank: the most votes, the lowest of equals,
        // rank 0 for none.
        let mut uniform = crate::uniform_numbers(0x9e37_79b9_7f4a_7c15);
        let mut next = |n: u64| (uniform() * n as f64) as u64;
        for _ in 0..500 {
            let ranks = 1 + next(12) as usize;
            let votes: Vec<u32> = (0..next(20)).map(|_| next(ranks as u64) as u32).collect();
            let mut count = vec![0usize; ranks];
            votes.iter().for_each(|&r| count[r as usize] += 1);
            let expected = (0..ranks)
                .max_by(|&a, &b| count[a].cmp(&count[b]).then(b.cmp(&a)))
                .unwrap() as u32;
            assert_eq!(most_voted(votes.iter().copied()), expected, "{votes:?}");
        }
    }

    #[test]
    fn largest_first_balances_and_is_deterministic() {
        let costs = [1.0, 5.0, 3.0, 3.0, 0.5];
        assert_eq!(largest_first(&costs), vec![1, 2, 3, 0, 4]);
        // All at home on rank 0: the limit is 1.1 × 12.5 / 2 = 6.875; 5 →
        // 0; 3 → 1 (8 > limit); 3 → 1 (3 < 5); 1 → 0 (6); 0.5 → 0 (6.5).
        assert_eq!(place_near_home(&costs, &[0; 5], 2), vec![0, 0, 1, 1, 0]);
        // Each at its own home while it fits: 5 → 0; 3 → 1; 3 (home 0: 8 >
        // limit) → 1, the least loaded; 1 (home 1: 7 > limit) → 0; 0.5 → 1.
        let home = [1, 0, 1, 0, 1];
        assert_eq!(place_near_home(&costs, &home, 2), vec![0, 0, 1, 1, 1]);
        assert_eq!(place_near_home(&[1.0, 2.0], &[0, 0], 1), vec![0, 0]);
        // A giant at home on rank 1 stays there while the ranks are empty.
        assert_eq!(place_near_home(&[9.0, 1.0], &[1, 1], 2), vec![1, 0]);
    }
}
