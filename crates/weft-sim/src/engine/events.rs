//! The events of one pass (`acm-spec.md` §2): every clock's batches in
//! time order over `[T0, T1)`, recording trajectory breakpoints.
//!
//! A batch at tick `t` holds every clock that fires at `t`: the internal clock
//! (stretch, bend, damping, gravity, scripts) and each active layer `l` with
//! `t % h_l == 0`. All forces read positions at `t` and the velocities at the
//! start of the batch (Jacobi semantics for damping and friction); each vertex
//! sums its impulses in (clock, stencil key) order; only vertices whose velocity
//! changes are drifted to `t` and get a breakpoint, so zero kicks leave no trace.

use std::time::Instant;

use glam::DVec3;
use weft_core::{StencilKey, StencilKind};
use weft_geom::distance::{stencil_closest, Closest};

use super::Engine;
use crate::clock::{next_multiple_after, Tick};
use crate::dormancy::Dormancy;
use crate::error::SimError;
use crate::executor::{place_in_blocks, split_chunks, Executor};
use crate::layers::{penalty_kick, FrictionClamp, PenaltyImpulse};
use crate::trace;
use crate::world::World;

/// The last exact evaluation of a stencil in this pass: its distance and its
/// vertices' positions (what [`distance_lower_bound`] starts from).
type Anchor = (f64, [DVec3; 4]);

/// What the penalty scan decided for an awake stencil (stencils certainly
/// outside every firing layer without room to sleep leave no verdict).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
enum Verdict {
    /// Certified outside `eta_1` until this tick or a velocity change.
    Sleep(Tick),
    /// Evaluated exactly at these positions.
    Near(Closest, [DVec3; 4]),
}

/// Lower bound of a stencil's distance at positions `x`, given its exact
/// distance `d0` at earlier positions `x0` of the same pass.
///
/// Each point of a primitive is a fixed convex combination of its vertices, so
/// it moved by at most the largest of their displacements; the closest pair at
/// `x` was therefore at least `d0 - move_a - move_b` apart. The subtracted
/// slack covers the rounding of `d0` and of the displacement norms (a few ulps
/// of the coordinates, bounded generously by `2^-40 (1 + max |coordinate|)`).
fn distance_lower_bound(kind: StencilKind, d0: f64, x0: &[DVec3; 4], x: &[DVec3; 4]) -> f64 {
    let split = match kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    };
    let moved =
        |r: std::ops::Range<usize>| r.map(|j| (x[j] - x0[j]).length()).fold(0.0f64, f64::max);
    let scale = x
        .iter()
        .chain(x0)
        .fold(0.0f64, |m, p| m.max(p.abs().max_element()));
    d0 - moved(0..split) - moved(split..4) - (1.0 + scale) * f64::powi(2.0, -40)
}

/// Below this many stencils in a batch the penalty stage runs inline: handing
/// out tasks would cost more than it saves (the results are the same bits).
const PARALLEL_MIN_STENCILS: usize = 256;

/// Vertices per task of the per-vertex stages of an internal batch.
const VERTEX_RUN: usize = 2048;

/// Stencils per task of the penalty stage.
const PENALTY_RUN: usize = 128;

/// How long a stencil whose distance is at least `lower` at tick `t` (a
/// lower bound of the computed distance, see [`distance_lower_bound`]) stays
/// outside `eta_1`, the outermost layer, if its vertices keep their current
/// velocities: returns the first tick it may not, and the room `lower - eta_1`
/// less a rounding slack (no sleep unless positive).
///
/// With velocities fixed each vertex moves by exactly `|v| (t' - t) q` (its
/// position is `x + v (t' - tau) q`), so the anchor-based lower bound at `t'`
/// is at least `lower - (s_a + s_b) (t' - t) q`, `s_a`, `s_b` the largest
/// speeds on each side. The extra slack `2^-40 (1 + max |coordinate|)`
/// covers the rounding of the speeds and of the later positions, as in
/// [`distance_lower_bound`].
fn sleep(
    key: &StencilKey,
    lower: f64,
    eta_1: f64,
    x: &[DVec3; 4],
    w: &World,
    t: Tick,
) -> (Tick, f64) {
    let split = match key.kind {
        StencilKind::VertexFace => 1,
        StencilKind::EdgeEdge => 2,
    };
    let scale = x.iter().fold(0.0f64, |m, p| m.max(p.abs().max_element()));
    let room = lower - eta_1 - (1.0 + scale) * f64::powi(2.0, -40);
    if !(room > 0.0) {
        return (t, room);
    }
    let speed = |r: std::ops::Range<usize>| {
        r.map(|j| w.v[key.v[j] as usize].length())
            .fold(0.0f64, f64::max)
    };
    let s = (speed(0..split) + speed(split..4)) * w.lattice.quantum;
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

/// Counters of one pass over a window.
#[derive(Debug, Default)]
pub(super) struct PassCounts {
    pub(super) internal_events: u64,
    pub(super) layer_events: u64,
    pub(super) layer_evaluations: u64,
    pub(super) layer_kicks: u64,
    pub(super) min_separation: f64,
    /// Wall seconds of the internal-force part of internal ticks.
    pub(super) internal_seconds: f64,
    /// The pass ended early because a value became non-finite.
    pub(super) truncated: Option<SimError>,
    /// The pass stopped early because the engine was interrupted.
    pub(super) interrupted: Option<SimError>,
}

/// Scratch memory reused across windows.
#[derive(Debug, Default)]
pub(super) struct Workspace {
    xt: Vec<DVec3>,
    out: Vec<DVec3>,
    /// Per vertex: the batch's impulses (internal, normal, clamped friction).
    acc: Vec<DVec3>,
    /// The batch's friction clamp (scratch, clear between batches).
    friction: FrictionClamp,
    touched: Vec<u32>,
    is_touched: Vec<bool>,
    /// Per active stencil: its anchor, if evaluated in this pass.
    anchors: Vec<Option<Anchor>>,
    bounds: Vec<usize>,
    /// Active stencils of a batch evaluated exactly, with their closest
    /// points (key order).
    hits: Vec<(u32, Closest)>,
    /// Awake stencils of the batch's outermost firing layer.
    scan: Vec<u32>,
    /// Which active stencils a batch may skip.
    dormancy: Dormancy,
    /// (layer, index in `hits`) of the batch's stencils inside their layer.
    kick_items: Vec<(u32, u32)>,
    /// The penalty scan's verdicts and the kicks of a batch.
    verdicts: Vec<(u32, Verdict)>,
    kicks: Vec<Option<(PenaltyImpulse, f64)>>,
    /// New velocities of an internal batch.
    v_new: Vec<DVec3>,
    /// Bounds of the fixed runs of vertices of the per-vertex stages.
    vertex_runs: Vec<usize>,
}

impl Workspace {
    /// Scratch for the world's vertices and internal force slots.
    pub(super) fn new(world: &World) -> Self {
        let n = world.num_vertices();
        Workspace {
            xt: vec![DVec3::ZERO; n],
            out: vec![DVec3::ZERO; world.internal.num_slots()],
            acc: vec![DVec3::ZERO; n],
            friction: FrictionClamp::new(n),
            is_touched: vec![false; n],
            v_new: vec![DVec3::ZERO; n],
            vertex_runs: (0..=n.div_ceil(VERTEX_RUN))
                .map(|k| (k * VERTEX_RUN).min(n))
                .collect(),
            bounds: world.internal.slot_bounds(),
            ..Default::default()
        }
    }

    /// Forgets the impulses of an unfinished batch.
    fn clear_accumulators(&mut self) {
        self.acc.fill(DVec3::ZERO);
        self.is_touched.fill(false);
        self.touched.clear();
    }

    /// No impulse of an earlier batch is left (what every batch starts from).
    fn accumulators_are_clear(&self) -> bool {
        self.touched.is_empty()
            && !self.is_touched.contains(&true)
            && self.acc.iter().all(|a| *a == DVec3::ZERO)
    }
}

impl<E: Executor> Engine<E> {
    /// Runs every event in `[t0, t1)` and drifts all vertices to `t1`,
    /// recording trajectories.
    pub(super) fn run_events(&mut self, t0: Tick, t1: Tick) -> Result<PassCounts, SimError> {
        let mut counts = PassCounts {
            min_separation: f64::INFINITY,
            ..Default::default()
        };
        debug_assert!(
            self.ws.accumulators_are_clear(),
            "impulses of an unfinished batch survived into a new pass"
        );
        self.traj.begin(t0, &self.world.x);
        let active: Vec<(StencilKey, u32)> = self
            .world
            .layers
            .stencils
            .iter()
            .map(|(k, s)| (*k, s.depth))
            .collect();
        let max_depth = active.iter().map(|a| a.1).max().unwrap_or(0);
        // Clock periods: [internal, layer 1, ..., layer max_depth].
        // (eta_l, k_l, h_l) of every layer in use, computed once per pass
        // (they involve libm::pow).
        let sched = &self.world.schedule;
        let layer_consts: Vec<(f64, f64, Tick)> = (1..=max_depth)
            .map(|l| (sched.eta(l), sched.k(l), sched.step(l)))
            .collect();
        let mut periods = vec![self.world.lattice.internal_step()];
        periods.extend(layer_consts.iter().map(|c| c.2));
        let first_at_or_after = |p: Tick| {
            if t0 > 0 && t0 % p == 0 {
                t0
            } else {
                next_multiple_after(t0, p)
            }
        };
        let mut next: Vec<Tick> = periods.iter().map(|&p| first_at_or_after(p)).collect();
        let mut firing: Vec<u32> = Vec::new();
        let mut end = t1;
        // by_layer[l - 1]: indices of the stencils with depth ≥ l, in key order.
        let mut by_layer: Vec<Vec<u32>> = vec![Vec::new(); max_depth as usize];
        for (a, &(_, depth)) in active.iter().enumerate() {
            for list in &mut by_layer[..depth as usize] {
                list.push(a as u32);
            }
        }
        self.ws.anchors.clear();
        self.ws.anchors.resize(active.len(), None);
        self.ws.dormancy.reset(&active, self.world.x.len());
        let mut batches = 0u64;
        loop {
            let t = next.iter().copied().min().unwrap_or(t1);
            if t >= t1 {
                break;
            }
            if batches == 1 {
                crate::failpoint::hit("mid-window", self.world.window_index);
            }
            if self.interrupted() {
                counts.interrupted = Some(SimError::Interrupted {
                    time: self.world.lattice.seconds(t0),
                });
                end = t;
                break;
            }
            batches += 1;
            firing.clear();
            for (c, nt) in next.iter_mut().enumerate() {
                if *nt == t {
                    firing.push(c as u32);
                    *nt += periods[c];
                }
            }
            match self.batch(t, &firing, &active, &by_layer, &layer_consts, &mut counts) {
                Ok(()) => {}
                Err(e @ SimError::NonFinite { .. }) => {
                    // A speculative pass that blew up (typically a stencil
                    // pushed through too few layers): end the pass at `t`,
                    // before any non-finite value was written, and let
                    // detection decide whether more layers fix it. The
                    // batch's impulses die with it.
                    self.ws.clear_accumulators();
                    counts.truncated = Some(e);
                    end = t;
                    break;
                }
                Err(e) => {
                    // A budget or communication error: the window is
                    // abandoned; no impulse of the batch may reach a later
                    // pass (the caller may raise the budget and step again).
                    self.ws.clear_accumulators();
                    return Err(e);
                }
            }
        }
        // Drift everything to the end of the pass (the window end unless the
        // pass was truncated).
        let w = &mut self.world;
        for i in 0..w.x.len() {
            let p = Self::pos_at(w, i, end);
            w.x[i] = p;
            w.tau[i] = end;
            self.traj
                .record(i, end, p)
                .map_err(|e| budget_error(w, t0, e))?;
        }
        Ok(counts)
    }

    /// One batch: every clock in `firing` (0 = internal, l = layer l) at tick `t`.
    fn batch(
        &mut self,
        t: Tick,
        firing: &[u32],
        active: &[(StencilKey, u32)],
        by_layer: &[Vec<u32>],
        layer_consts: &[(f64, f64, Tick)],
        counts: &mut PassCounts,
    ) -> Result<(), SimError> {
        let internal = firing.first() == Some(&0);
        let w = &self.world;
        let ws = &mut self.ws;
        if internal {
            let _span = trace::span("internal tick");
            let clock = Instant::now();
            counts.internal_events += 1;
            // Per-vertex stages run on the executor in fixed runs of
            // vertices; each writes only its own vertices' entries.
            self.exec
                .for_each_chunk(&mut ws.xt, &ws.vertex_runs, &|k, run| {
                    for (j, p) in run.iter_mut().enumerate() {
                        *p = Self::pos_at(w, k * VERTEX_RUN + j, t);
                    }
                });
            // Over ranks (Algorithm 1): this rank's boundary partitions, then
            // their slots go to the neighbours that fold them while the
            // interior partitions are evaluated, then the neighbours' slots
            // come in; it folds only the vertices it owns.
            let share = self.share.as_ref();
            let (exec, bounds, xt) = (&self.exec, &ws.bounds, &ws.xt);
            match share {
                None => w
                    .internal
                    .evaluate(exec, bounds, xt, &w.v, &mut ws.out, None),
                Some(share) => {
                    let boundary = Some(&share.boundary_partition[..]);
                    w.internal
                        .evaluate(exec, bounds, xt, &w.v, &mut ws.out, boundary);
                    share.exchange_slots(exec, &mut ws.out, &mut |out| {
                        let interior = Some(&share.interior_partition[..]);
                        w.internal.evaluate(exec, bounds, xt, &w.v, out, interior);
                    })?;
                }
            }
            let h = w.lattice.h_el();
            let out = &ws.out;
            self.exec
                .for_each_chunk(&mut ws.acc, &ws.vertex_runs, &|k, run| {
                    for (j, a) in run.iter_mut().enumerate() {
                        let i = k * VERTEX_RUN + j;
                        if share.is_some_and(|s| !s.owns(i)) {
                            continue; // folded by its owner
                        }
                        if w.inv_mass[i] > 0.0 {
                            let g = w.internal.fold(i, out) - w.gravity * w.mass[i];
                            *a = g * -h;
                        }
                    }
                });
            ws.is_touched.fill(true);
            counts.internal_seconds += clock.elapsed().as_secs_f64();
        }
        // Penalty layers, in (layer, key) order.
        let layer_clocks = if internal { &firing[1..] } else { firing };
        if let Some(&first) = layer_clocks.first() {
            let xt = internal.then_some(&ws.xt[..]);
            let eta_first = layer_consts[first as usize - 1].0;
            let eta_1 = w.schedule.eta_1;
            // Phase 1: the closest-point data of every stencil of the batch,
            // once per batch (positions are those at `t` for every layer),
            // cached with the batch's tick as stamp. Every stencil firing now
            // is in layer `first` (the list of the outermost firing layer
            // holds the deeper ones), whose eta is the largest, so a stencil
            // certainly outside it is outside every firing layer.
            //
            // Asleep stencils (certified outside `eta_1` until a tick or a
            // velocity change, see `sleep` and `crate::dormancy`) are not
            // read; the awake ones of the outermost firing layer are
            // restamped and evaluated, on the executor when there are enough
            // of them (each entry's update depends on that entry alone).
            ws.dormancy.wake_due(t);
            ws.scan.clear();
            ws.scan.extend(
                ws.dormancy
                    .awake()
                    .iter()
                    .copied()
                    .filter(|&a| active[a as usize].1 >= first),
            );
            // In key order, so the verdicts and hits come out in key order.
            ws.scan.sort_unstable();
            let anchors = &ws.anchors;
            let exhaustive = self.every_layer_event;
            // (Serial batches fill reused buffers: allocating per batch
            // scatters the trajectories' storage and slows the narrow phase.)
            let scan = |run: &[u32], verdicts: &mut Vec<(u32, Verdict)>| {
                for &a in run {
                    let key = &active[a as usize].0;
                    let x = key.v.map(|i| match xt {
                        Some(xt) => xt[i as usize],
                        None => Self::pos_at(w, i as usize, t),
                    });
                    let lower = anchors[a as usize]
                        .as_ref()
                        .map_or(f64::NEG_INFINITY, |(d0, x0)| {
                            distance_lower_bound(key.kind, *d0, x0, &x)
                        });
                    // Certainly outside every firing layer: its kicks are
                    // zero, so skipping the evaluation leaves the same bits.
                    if lower >= eta_first && !exhaustive {
                        let (awake_at, room) = sleep(key, lower, eta_1, &x, w, t);
                        if room > 0.0 {
                            verdicts.push((a, Verdict::Sleep(awake_at)));
                        }
                    } else {
                        verdicts.push((a, Verdict::Near(stencil_closest(key.kind, &x), x)));
                    }
                }
            };
            let list = &ws.scan;
            let parallel = list.len() >= PARALLEL_MIN_STENCILS;
            // Spans only for the batches that run on the executor (the many
            // small ones would flood the timeline).
            let closest_span = parallel
                .then(|| trace::span_with("penalty closest", "stencils", list.len() as u64));
            ws.verdicts.clear();
            if parallel {
                let runs = list.len().div_ceil(PENALTY_RUN);
                let owner = place_in_blocks(runs, self.exec.ranks());
                let parts = self.exec.map_on_ranks(runs, &owner, &|r| {
                    let mut verdicts = Vec::new();
                    let run = &list[r * PENALTY_RUN..((r + 1) * PENALTY_RUN).min(list.len())];
                    scan(run, &mut verdicts);
                    verdicts
                })?;
                for part in parts {
                    ws.verdicts.extend(part);
                }
            } else {
                scan(list, &mut ws.verdicts);
            }
            drop(closest_span);
            // Apply the verdicts. Only evaluated stencils (the hits) can
            // kick; they go to phase 2 in key order (active index order, the
            // order of the scan list).
            ws.hits.clear();
            for &(a, verdict) in &ws.verdicts {
                match verdict {
                    Verdict::Sleep(until) => ws.dormancy.sleep(a, until),
                    Verdict::Near(c, x) => {
                        counts.layer_evaluations += 1;
                        counts.min_separation = counts.min_separation.min(c.d);
                        ws.anchors[a as usize] = Some((c.d, x));
                        ws.hits.push((a, c));
                    }
                }
            }
            ws.dormancy.drop_sleepers();
            // Phase 2: the kicks of stencils inside their layer, computed
            // independently (they read the velocities at the start of the
            // batch) and then summed per vertex in (layer, key) order: the
            // hits are in key order, and layer `l` holds those of depth ≥ l.
            ws.kick_items.clear();
            for &l in layer_clocks {
                let eta_l = layer_consts[l as usize - 1].0;
                counts.layer_events += by_layer[l as usize - 1].len() as u64;
                for (h, (a, c)) in ws.hits.iter().enumerate() {
                    if active[*a as usize].1 >= l && c.d < eta_l {
                        ws.kick_items.push((l, h as u32)); // else a zero kick (NaN too)
                    }
                }
            }
            let hits = &ws.hits;
            let kick_of = |&(l, h): &(u32, u32)| {
                let (a, c) = &hits[h as usize];
                let key = &active[*a as usize].0;
                let (eta_l, k_l, step) = layer_consts[l as usize - 1];
                let v = key.v.map(|i| w.v[i as usize]);
                let inv = key.v.map(|i| w.inv_mass[i as usize]);
                let mu = w.stencil_friction(key);
                penalty_kick(eta_l, k_l, w.lattice.seconds(step), c, &v, &inv, mu).map(|k| (k, mu))
            };
            let items = &ws.kick_items;
            let big = items.len() >= PARALLEL_MIN_STENCILS;
            let _kicks_span =
                big.then(|| trace::span_with("penalty kicks", "stencils", items.len() as u64));
            ws.kicks.clear();
            if big {
                let runs = items.len().div_ceil(PENALTY_RUN);
                let owner = place_in_blocks(runs, self.exec.ranks());
                let parts = self.exec.map_on_ranks(runs, &owner, &|r| {
                    let run = &items[r * PENALTY_RUN..((r + 1) * PENALTY_RUN).min(items.len())];
                    run.iter().map(kick_of).collect::<Vec<_>>()
                })?;
                for part in parts {
                    ws.kicks.extend(part);
                }
            } else {
                ws.kicks.extend(items.iter().map(kick_of));
            }
            // Fold in (layer, key) order: the friction clamp's sums first,
            // then each kick with its friction scaled as a whole (see
            // `FrictionClamp`), then the clamp's scratch is cleared.
            let kicked = || {
                (items.iter().zip(&ws.kicks)).filter_map(|(&(_, h), kick)| {
                    let (k, mu) = kick.as_ref()?;
                    Some((&active[ws.hits[h as usize].0 as usize].0, k, *mu > 0.0))
                })
            };
            for (key, k, _) in kicked().filter(|k| k.2) {
                ws.friction.add(&key.v, &w.inv_mass, k);
            }
            for (key, k, rubs) in kicked() {
                counts.layer_kicks += 1;
                let s = if rubs {
                    ws.friction.scale(&key.v, &w.inv_mass, k)
                } else {
                    0.0
                };
                for j in 0..4 {
                    let i = key.v[j] as usize;
                    if w.inv_mass[i] > 0.0 {
                        ws.acc[i] += k.normal[j];
                        if rubs {
                            ws.acc[i] += k.friction[j] * s;
                        }
                        if !ws.is_touched[i] {
                            ws.is_touched[i] = true;
                            ws.touched.push(i as u32);
                        }
                    }
                }
            }
            for (key, _, _) in kicked().filter(|k| k.2) {
                ws.friction.clear(&key.v);
            }
        }
        // Apply: new velocities (on the executor for an internal batch, which
        // touches every vertex); then, in vertex order, drift and record only
        // where v changed.
        let h = w.lattice.h_el();
        let tsec = w.lattice.seconds(t);
        if internal {
            let (xt, acc) = (&ws.xt, &ws.acc);
            let share = self.share.as_ref();
            self.exec
                .for_each_chunk(&mut ws.v_new, &ws.vertex_runs, &|k, run| {
                    for (j, v) in run.iter_mut().enumerate() {
                        let i = k * VERTEX_RUN + j;
                        if share.is_some_and(|s| !s.owns(i)) {
                            continue; // advanced by its owner
                        }
                        *v = new_velocity(w, i, true, xt[i], acc[i], tsec, h);
                    }
                });
            if let Some(share) = share {
                share.exchange_velocities(&self.exec, &mut ws.v_new)?;
            }
        }
        let window_start = self.traj.start();
        if internal {
            return self.apply_internal(t);
        }
        // A penalty-only batch: the touched vertices, in order. (On an
        // error the caller clears what is left of the batch.)
        let world = &mut self.world;
        for &i in &ws.touched {
            let i = i as usize;
            let v_old = world.v[i];
            let x = Self::pos_at(world, i, t);
            let v_new = new_velocity(world, i, false, x, ws.acc[i], tsec, h);
            ws.acc[i] = DVec3::ZERO;
            ws.is_touched[i] = false;
            if v_new != v_old {
                if !(x.is_finite() && v_new.is_finite()) {
                    return Err(SimError::NonFinite {
                        place: world.place(i as u32),
                        vertex: i as u32,
                        time: world.lattice.seconds(t),
                    });
                }
                world.x[i] = x;
                world.tau[i] = t;
                world.v[i] = v_new;
                ws.dormancy.wake_vertex(i);
                self.traj
                    .record(i, t, x)
                    .map_err(|e| budget_error(world, window_start, e))?;
            }
        }
        ws.touched.clear();
        Ok(())
    }

    /// The end of an internal batch at tick `t`, on the executor in runs of
    /// vertices: each vertex whose velocity changed takes its new velocity
    /// (`ws.v_new`) and its position at `t`, and gets a breakpoint. As on one
    /// thread in vertex order, a non-finite new state stops the batch at the
    /// first such vertex: the vertices before it are applied, it and the
    /// later ones are not.
    fn apply_internal(&mut self, t: Tick) -> Result<(), SimError> {
        let ws = &mut self.ws;
        let w = &self.world;
        let n = w.x.len();
        let runs = ws.vertex_runs.len().saturating_sub(1);
        let (xt, v_new) = (&ws.xt, &ws.v_new);
        let bounds = &ws.vertex_runs;
        let bad = self
            .exec
            .map(runs, &|k| {
                (bounds[k]..bounds[k + 1])
                    .find(|&i| v_new[i] != w.v[i] && !(xt[i].is_finite() && v_new[i].is_finite()))
            })
            .into_iter()
            .flatten()
            .next();
        let limit = bad.unwrap_or(n);
        struct Run<'a> {
            start: usize,
            x: &'a mut [DVec3],
            v: &'a mut [DVec3],
            tau: &'a mut [Tick],
            traj: crate::trajectory::TrajectoryRun<'a>,
            added: usize,
        }
        let world = &mut self.world;
        let mut x_runs = split_chunks(&mut world.x, bounds).into_iter();
        let mut v_runs = split_chunks(&mut world.v, bounds).into_iter();
        let mut tau_runs = split_chunks(&mut world.tau, bounds).into_iter();
        let mut apply_runs: Vec<Run<'_>> = self
            .traj
            .runs(bounds)
            .into_iter()
            .enumerate()
            .map(|(k, traj)| Run {
                start: bounds[k],
                x: x_runs.next().expect("one per run").1,
                v: v_runs.next().expect("one per run").1,
                tau: tau_runs.next().expect("one per run").1,
                traj,
                added: 0,
            })
            .collect();
        let one_each: Vec<usize> = (0..=apply_runs.len()).collect();
        self.exec
            .for_each_chunk(&mut apply_runs, &one_each, &|_, chunk| {
                for r in chunk {
                    let end = r.x.len().min(limit.saturating_sub(r.start));
                    for j in 0..end {
                        let i = r.start + j;
                        if v_new[i] != r.v[j] {
                            r.x[j] = xt[i];
                            r.tau[j] = t;
                            r.v[j] = v_new[i];
                            r.added += usize::from(r.traj.record(j, t, xt[i]));
                        }
                    }
                }
            });
        let added = apply_runs.iter().map(|r| r.added).sum();
        drop(apply_runs);
        // The batch touched every vertex: clear the accumulators (all of
        // them, also when it stopped early, so nothing leaks into the next
        // pass); every velocity changed (or may have): every stencil wakes.
        ws.clear_accumulators();
        ws.dormancy.wake_all();
        let world = &self.world;
        self.traj
            .add_recorded(added)
            .map_err(|e| budget_error(world, self.traj.start(), e))?;
        if let Some(i) = bad {
            return Err(SimError::NonFinite {
                place: world.place(i as u32),
                vertex: i as u32,
                time: world.lattice.seconds(t),
            });
        }
        Ok(())
    }
}

/// Vertex `i`'s velocity after a batch at `tsec` in which it received the
/// impulse `impulse` (internal, normal and clamped friction); `x` is its
/// position at the batch. A scripted vertex follows the chord of its script
/// at internal ticks and keeps its velocity otherwise.
fn new_velocity(
    w: &World,
    i: usize,
    internal: bool,
    x: DVec3,
    impulse: DVec3,
    tsec: f64,
    h: f64,
) -> DVec3 {
    if let Some((s, k)) = w.script_of[i] {
        if internal {
            w.scripts[s as usize].chord_velocity(k as usize, x, tsec, h)
        } else {
            w.v[i]
        }
    } else {
        w.v[i] + impulse * w.inv_mass[i]
    }
}

fn budget_error(w: &World, t0: Tick, e: crate::trajectory::BudgetExceeded) -> SimError {
    SimError::TrajectoryBudget {
        time: w.lattice.seconds(t0),
        breakpoints: e.breakpoints,
        budget_bytes: e.budget_bytes,
    }
}
