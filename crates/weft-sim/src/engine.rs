//! The speculative ACM loop (`acm-spec.md` §4): per window, run every event in
//! time order, detect, and either commit or roll back with more layers.
//!
//! ```text
//! snapshot (x, v, tau)                      -- not the active layers
//! loop:
//!     events in [T0, T1), batched per tick; record trajectory breakpoints
//!     drift every vertex to T1
//!     broad phase → candidate stencils → narrow phase: d ≤ eta_(depth+1) ever?
//!     none: commit, retire calm innermost layers, diagnostics; done
//!     else: restore the snapshot, activate depth+1 ..= depth+L of each reported
//!           stencil (the layer set only grows within a window), run again
//! ```
//!
//! A batch at tick `t` holds every clock that fires at `t`: the internal clock
//! (stretch, bend, damping, gravity, scripts) and each active layer `l` with
//! `t % h_l == 0`. All forces read positions at `t` and the velocities at the
//! start of the batch (Jacobi semantics for damping and friction); each vertex
//! sums its impulses in (clock, stencil key) order; only vertices whose velocity
//! changes are drifted to `t` and get a breakpoint, so zero kicks leave no trace.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use weft_core::{StencilKey, StencilKind};
use weft_geom::ccd::{proximity, CcdStats};
use weft_geom::distance::{stencil_closest, Closest};

use crate::balance::{locality_aware, CollisionTasks, CostModel};
use crate::broad::BroadPhase;
use crate::clock::{next_multiple_after, Tick};
use crate::diagnostics::{StageSeconds, WindowStats};
use crate::dormancy::Dormancy;
use crate::error::SimError;
use crate::executor::{place_in_blocks, split_chunks, CommError, Executor, Serial};
use crate::layers::{penalty_kick, FrictionClamp, LayerState, PenaltyImpulse};
use crate::share::RankShare;
use crate::state::EngineState;
use crate::trace;
use crate::trajectory::Trajectories;
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

/// The state restored on rollback.
#[derive(Clone, Debug)]
struct Snapshot {
    x: Vec<DVec3>,
    v: Vec<DVec3>,
    tau: Vec<Tick>,
}

impl Snapshot {
    fn restore(&self, w: &mut World) {
        w.x.copy_from_slice(&self.x);
        w.v.copy_from_slice(&self.v);
        w.tau.copy_from_slice(&self.tau);
    }
}

/// Counters of one pass over a window.
#[derive(Debug, Default)]
struct PassCounts {
    internal_events: u64,
    layer_events: u64,
    layer_evaluations: u64,
    layer_kicks: u64,
    min_separation: f64,
    /// Wall seconds of the internal-force part of internal ticks.
    internal_seconds: f64,
    /// The pass ended early because a value became non-finite.
    truncated: Option<SimError>,
    /// The pass stopped early because the engine was interrupted.
    interrupted: Option<SimError>,
}

/// Scratch memory reused across windows.
#[derive(Debug, Default)]
struct Workspace {
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
    broad: BroadPhase,
}

impl Workspace {
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

/// Totals over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunTotals {
    pub windows: u64,
    pub rollbacks: u64,
    pub narrow_queries: u64,
    pub max_depth: u32,
    pub max_active_stencils: u64,
}

/// The ACM engine over a [`World`], running its stages on an [`Executor`].
pub struct Engine<E: Executor = Serial> {
    pub world: World,
    exec: E,
    traj: Trajectories,
    ws: Workspace,
    pub totals: RunTotals,
    pub ccd: CcdStats,
    /// Set from outside (a signal handler, a deadline) to stop at the next
    /// event batch, back at the window start.
    interrupt: Option<Arc<AtomicBool>>,
    /// Narrow-phase cost per partition pair, measured in the last pass.
    narrow_costs: CostModel,
    /// Over ranks: measured narrow-phase seconds per rank, since the start.
    pub narrow_load: NarrowLoad,
    /// Over ranks: this rank's share of the internal ticks.
    share: Option<RankShare>,
    /// Evaluate every penalty-layer event exactly (no sleeping, no
    /// distance-bound skip): the same bits, slower; for verifying the skips.
    every_layer_event: bool,
}

/// Narrow-phase work per rank (measured task seconds, summed over passes):
/// as placed by the balancer, and as it would have fallen with every task on
/// the home rank of its first partition (no balancer). Empty on one rank.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NarrowLoad {
    pub balanced: Vec<f64>,
    pub home_only: Vec<f64>,
}

impl NarrowLoad {
    /// max / mean of `loads` (1 is perfect balance; `None` without work).
    pub fn imbalance(loads: &[f64]) -> Option<f64> {
        let total: f64 = loads.iter().sum();
        let max = loads.iter().copied().fold(0.0, f64::max);
        (total > 0.0).then(|| max * loads.len() as f64 / total)
    }
}

impl<E: Executor> Engine<E> {
    /// Wraps `world`, refusing an initial state in which a stencil is within
    /// the floor `eta_inf` or two triangles intersect.
    pub fn new(world: World, exec: E) -> Result<Self, SimError> {
        let n = world.num_vertices();
        let mut traj = Trajectories::new(n, world.limits.trajectory_budget_bytes);
        let share = (exec.ranks() > 1).then(|| RankShare::new(&world, exec.rank(), exec.ranks()));
        if let Some(share) = &share {
            // A vertex's breakpoints are stored by its owner only; others
            // fetch what their tasks read.
            traj.hold_only(share.owner.clone(), share.rank as u32);
        }
        let mut engine = Self {
            ws: Workspace {
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
                broad: BroadPhase::grouped(&world.partitioning.of_triangle),
                ..Default::default()
            },
            world,
            exec,
            traj,
            totals: RunTotals::default(),
            ccd: CcdStats::default(),
            interrupt: None,
            narrow_costs: CostModel::default(),
            narrow_load: NarrowLoad::default(),
            share,
            every_layer_event: false,
        };
        engine.check_initial_state()?;
        Ok(engine)
    }

    /// Sets the memory budget of a window's trajectory breakpoints (bytes),
    /// for example to go on after [`SimError::TrajectoryBudget`].
    pub fn set_trajectory_budget(&mut self, bytes: usize) {
        self.world.limits.trajectory_budget_bytes = bytes;
        self.traj.set_budget(bytes);
    }

    /// Evaluates every penalty-layer event exactly when `on`: no stencil
    /// sleeps and none is skipped by its distance bound. Skipped events kick
    /// zero, so the bits are the same (tested); only the time differs.
    pub fn evaluate_every_layer_event(&mut self, on: bool) {
        self.every_layer_event = on;
    }

    /// The executor.
    pub fn executor(&self) -> &E {
        &self.exec
    }

    /// Makes [`Engine::step_window`] return [`SimError::Interrupted`] (with the
    /// window start restored) soon after `flag` becomes true.
    pub fn set_interrupt(&mut self, flag: Arc<AtomicBool>) {
        self.interrupt = Some(flag);
    }

    fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    }

    /// The resumable state (call between windows).
    pub fn state(&self) -> EngineState {
        let w = &self.world;
        EngineState {
            tick: w.tick,
            window_index: w.window_index,
            x: w.x.iter().map(|p| p.to_array()).collect(),
            v: w.v.iter().map(|p| p.to_array()).collect(),
            tau: w.tau.clone(),
            layers: w.layers.stencils.iter().map(|(k, s)| (*k, *s)).collect(),
            totals: self.totals,
        }
    }

    /// Continues from `state`, checked against this world: sizes, a tick on a
    /// window boundary, finite values, every `tau` at the tick (states are
    /// saved synchronized), layer keys that are stencils of this mesh.
    pub fn restore(&mut self, state: EngineState) -> Result<(), SimError> {
        let n = self.world.num_vertices();
        let bad = |m: String| Err(SimError::StateMismatch(m));
        if state.x.len() != n || state.v.len() != n || state.tau.len() != n {
            return bad(format!(
                "it has {} vertices, the scene has {n}",
                state.x.len()
            ));
        }
        let window = self.world.lattice.window();
        if state.tick % window != 0 || state.tick / window != state.window_index {
            return bad(format!(
                "tick {} and window {} are not a window boundary of this scene's \
                 lattice (window = {window} ticks)",
                state.tick, state.window_index
            ));
        }
        for i in 0..n {
            if state.tau[i] != state.tick {
                return bad(format!("vertex {i} is not synchronized at the saved tick"));
            }
            let finite = state.x[i].iter().chain(&state.v[i]).all(|c| c.is_finite());
            if !finite {
                return bad(format!("vertex {i} has a non-finite position or velocity"));
            }
        }
        let mut layers = BTreeMap::new();
        for (key, s) in &state.layers {
            if key.v.iter().any(|&i| i as usize >= n) || s.depth == 0 {
                return bad(format!(
                    "active layer {key:?} (depth {}) is not a stencil of this mesh",
                    s.depth
                ));
            }
            layers.insert(*key, *s);
        }
        let w = &mut self.world;
        w.tick = state.tick;
        w.window_index = state.window_index;
        w.x = state.x.into_iter().map(DVec3::from_array).collect();
        w.v = state.v.into_iter().map(DVec3::from_array).collect();
        w.tau = state.tau;
        w.layers.stencils = layers;
        self.totals = state.totals;
        Ok(())
    }

    /// Refuses a start in which two triangles intersect (checked first, so
    /// that crossing geometry is called so) or a stencil's primitives are
    /// within the separation floor.
    fn check_initial_state(&mut self) -> Result<(), SimError> {
        let w = &self.world;
        let hits = weft_geom::intersections::mesh_self_intersections(&w.x, &w.triangles);
        let dynamic = |f: u32| {
            w.triangles[f as usize]
                .iter()
                .any(|&i| w.inv_mass[i as usize] > 0.0)
        };
        if let Some(&(a, b)) = hits.iter().find(|&&(a, b)| dynamic(a) || dynamic(b)) {
            return Err(SimError::InitialIntersection {
                a: w.triangle_place(a),
                b: w.triangle_place(b),
            });
        }
        self.traj.begin(w.tick, &w.x);
        let keys = self.ws.broad.candidates_on(
            &self.exec,
            &w.triangles,
            &w.inv_mass,
            &self.traj,
            0.5 * w.schedule.eta_1,
        )?;
        for key in keys {
            let x = key.v.map(|i| w.x[i as usize]);
            let c = stencil_closest(key.kind, &x);
            if !(c.d > w.schedule.eta_inf) {
                return Err(SimError::InitialContact {
                    kind: kind_name(key.kind),
                    key,
                    pair: w.describe_stencil(&key),
                    distance: c.d,
                    floor: w.schedule.eta_inf,
                });
            }
        }
        Ok(())
    }

    /// Position of vertex `i` at tick `t` (drift without writing).
    #[inline]
    fn pos_at(world: &World, i: usize, t: Tick) -> DVec3 {
        world.x[i] + world.v[i] * ((t - world.tau[i]) as f64 * world.lattice.quantum)
    }

    /// Runs one window to commit (with as many rollbacks as it needs).
    ///
    /// On an error (an interrupt included) the world is left exactly at the
    /// last committed state — positions, velocities, clocks and the active
    /// layers, without the layers this window's rollbacks added — so a
    /// checkpoint taken then resumes bit-identically.
    pub fn step_window(&mut self) -> Result<WindowStats, SimError> {
        let committed_layers = self.world.layers.clone();
        let result = self.run_window();
        if result.is_err() {
            self.world.layers = committed_layers;
        }
        result
    }

    fn run_window(&mut self) -> Result<WindowStats, SimError> {
        let _span = trace::span_with("window", "window", self.world.window_index);
        let started = Instant::now();
        let t0 = self.world.tick;
        let t1 = t0 + self.world.lattice.window();
        let snap = Snapshot {
            x: self.world.x.clone(),
            v: self.world.v.clone(),
            tau: self.world.tau.clone(),
        };
        let mut rollbacks = 0u32;
        let mut blown_up = 0u32;
        let mut confirmed = 0u64;
        let mut stages = StageSeconds::default();
        // The deepest layer a stencil may get (about 30 `pow` calls: once
        // per window, not per rollback).
        let resolved = self.world.schedule.resolved_depth();
        loop {
            let clock = Instant::now();
            let events_span = trace::span_with("events", "pass", rollbacks as u64);
            let mut counts = match self.run_events(t0, t1) {
                Ok(c) => c,
                Err(e) => {
                    snap.restore(&mut self.world);
                    return Err(e);
                }
            };
            drop(events_span);
            stages.events += clock.elapsed().as_secs_f64();
            stages.internal += counts.internal_seconds;
            if let Some(e) = counts.interrupted.take() {
                snap.restore(&mut self.world);
                return Err(e);
            }
            let clock = Instant::now();
            let broad_span = trace::span("broad");
            let candidates = {
                let w = &self.world;
                self.ws.broad.candidates_on(
                    &self.exec,
                    &w.triangles,
                    &w.inv_mass,
                    &self.traj,
                    0.5 * w.schedule.eta_1,
                )
            };
            drop(broad_span);
            stages.broad += clock.elapsed().as_secs_f64();
            let clock = Instant::now();
            let count = candidates.as_ref().map_or(0, |c| c.len() as u64);
            let narrow_span = trace::span_with("narrow", "candidates", count);
            let found = candidates.and_then(|c| Ok((self.narrow_phase(&c)?, c)));
            let (reported, candidates) = match found {
                Ok(found) => found,
                Err(e) => {
                    snap.restore(&mut self.world);
                    return Err(e.into());
                }
            };
            drop(narrow_span);
            stages.narrow += clock.elapsed().as_secs_f64();
            // A pass that blew up is a detection too: the stencils near the
            // vertex that went non-finite (typically pushed through too few
            // layers) get more layers, like the reported ones, bounded by
            // the rollback cap. With no stencil near it the blow-up is a
            // real instability and the run stops with it.
            let mut reported = reported;
            if let Some(e) = counts.truncated.take() {
                let &SimError::NonFinite { vertex, .. } = &e else {
                    unreachable!("a pass is truncated by a non-finite value only")
                };
                let near = self.stencils_near(vertex, &candidates);
                if reported.is_empty() && near.is_empty() {
                    snap.restore(&mut self.world);
                    return Err(e);
                }
                reported.extend(near);
                reported.sort_unstable();
                reported.dedup();
                blown_up += 1;
            }
            if reported.is_empty() {
                let clock = Instant::now();
                let _commit_span = trace::span("commit");
                let retired = match self.commit(&candidates) {
                    Ok(retired) => retired,
                    Err(e) => {
                        snap.restore(&mut self.world);
                        return Err(e.into());
                    }
                };
                self.world.tick = t1;
                let mut stats = self.window_stats(
                    counts,
                    rollbacks,
                    candidates.len() as u64,
                    confirmed,
                    retired,
                    &candidates,
                    started,
                );
                stages.commit += clock.elapsed().as_secs_f64();
                stats.stage_seconds = stages;
                self.world.window_index += 1;
                self.totals.windows += 1;
                self.totals.rollbacks += rollbacks as u64;
                self.totals.max_depth = self.totals.max_depth.max(stats.max_depth);
                self.totals.max_active_stencils =
                    self.totals.max_active_stencils.max(stats.active_stencils);
                return Ok(stats);
            }
            confirmed += reported.len() as u64;
            // Roll back: restore the state, keep (and extend) the layers.
            snap.restore(&mut self.world);
            // Each reported stencil gets `layers_per_detection` more layers,
            // or as many as remain down to the deepest resolved one; only a
            // stencil already there has none left to get.
            let extra = self.world.contact.layers_per_detection;
            for key in &reported {
                let depth = self.world.layers.depth(key);
                if depth >= resolved {
                    let w = &self.world;
                    return Err(SimError::LayerTooDeep {
                        time: w.lattice.seconds(t0),
                        key: *key,
                        pair: w.describe_stencil(key),
                        depth: depth + 1,
                        resolved,
                    });
                }
                self.world.layers.deepen(*key, extra.min(resolved - depth));
            }
            rollbacks += 1;
            let so_far = self.totals.rollbacks + rollbacks as u64;
            crate::failpoint::hit("mid-rollback", so_far);
            if crate::failpoint::triggered("interrupt-after-rollback", so_far) {
                if let Some(flag) = &self.interrupt {
                    flag.store(true, Ordering::Relaxed);
                }
            }
            if rollbacks > self.world.contact.max_rollbacks {
                let key = reported[reported.len() - 1];
                let w = &self.world;
                return Err(SimError::RollbackCap {
                    time: w.lattice.seconds(t0),
                    cap: w.contact.max_rollbacks,
                    kind: kind_name(key.kind),
                    key,
                    pair: w.describe_stencil(&key),
                    position: w.x[key.v[0] as usize].to_array(),
                    depth: w.layers.depth(&key),
                    blown_up,
                });
            }
        }
    }

    /// The stencils near vertex `i` that went non-finite in a pass: the
    /// active ones and this pass's candidates with a vertex in `i`'s ring
    /// (`i` and the vertices of its triangles), in key order.
    fn stencils_near(&self, i: u32, candidates: &[StencilKey]) -> Vec<StencilKey> {
        let w = &self.world;
        let mut ring: Vec<u32> = vec![i];
        for &f in w.topology.faces_of_vertex(i) {
            ring.extend_from_slice(&w.triangles[f as usize]);
        }
        ring.sort_unstable();
        ring.dedup();
        let touches = |k: &&StencilKey| k.v.iter().any(|v| ring.binary_search(v).is_ok());
        let mut near: Vec<StencilKey> = (w.layers.stencils.keys())
            .chain(candidates)
            .filter(touches)
            .copied()
            .collect();
        near.sort_unstable();
        near.dedup();
        near
    }

    /// Runs every event in `[t0, t1)` and drifts all vertices to `t1`,
    /// recording trajectories.
    fn run_events(&mut self, t0: Tick, t1: Tick) -> Result<PassCounts, SimError> {
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

    /// Over ranks: every rank gets, from the ranks that hold them, the
    /// polylines of the vertices its tasks read (`reads[r]` for rank `r`,
    /// in any order, repeats allowed) and does not hold itself. Every rank
    /// works out the same traffic from the same placement, so nothing is
    /// requested: holders send, readers receive, point to point, exact bits
    /// (`Trajectories::fetched`). The polylines stay cached for the window.
    fn fetch_trajectories(&mut self, mut reads: Vec<Vec<u32>>) -> Result<(), CommError> {
        let me = self.exec.rank();
        let holders = self.traj.holders();
        // (holder, reader) → vertices, ascending; only pairs with this rank.
        let mut travel: std::collections::BTreeMap<(usize, usize), Vec<u32>> = Default::default();
        for (r, list) in reads.iter_mut().enumerate() {
            list.sort_unstable();
            list.dedup();
            for &v in list.iter() {
                let h = holders[v as usize] as usize;
                if h != r && (r == me || h == me) {
                    travel.entry((h, r)).or_default().push(v);
                }
            }
        }
        let mut sends: Vec<(usize, Vec<f64>)> = Vec::new();
        let mut recvs: Vec<(usize, Vec<u32>)> = Vec::new();
        for ((h, r), vertices) in travel {
            if r == me {
                recvs.push((h, vertices));
            } else {
                let mut words = Vec::new();
                for &v in &vertices {
                    self.traj.words_of(v as usize, &mut words);
                }
                sends.push((r, words));
            }
        }
        let lens: Vec<(usize, usize)> = recvs
            .iter()
            .map(|(h, vs)| {
                (
                    *h,
                    vs.iter().map(|&v| 4 * self.traj.count(v as usize)).sum(),
                )
            })
            .collect();
        let received = self.exec.exchange_words(sends, &lens, &mut || {})?;
        for ((_, vertices), words) in recvs.iter().zip(received) {
            let mut at = 0;
            for &v in vertices {
                at += self.traj.fetched(v as usize, &words[at..]);
            }
        }
        Ok(())
    }

    /// Stencils among `candidates` (sorted) that may come within
    /// `eta_(depth+1)`, in key order.
    ///
    /// Candidates are grouped by partition pair and split into tasks whose
    /// cost is predicted from the previous pass ([`crate::balance`]); the
    /// executor gets them largest first. Each candidate is tested once and
    /// the answers are sorted, so the result does not depend on the tasks.
    ///
    /// Over ranks, the tasks are placed by the paper's Algorithm 2
    /// ([`crate::balance::locality_aware`]: home rank first while under the
    /// average load) and every rank gets every answer.
    fn narrow_phase(&mut self, candidates: &[StencilKey]) -> Result<Vec<StencilKey>, CommError> {
        const TASK: f64 = 64.0;
        let costs = &self.narrow_costs;
        let tasks = CollisionTasks::build(
            candidates,
            &self.world.partitioning,
            costs,
            TASK * costs.mean(),
        );
        let order = tasks.by_load();
        let ranks = self.exec.ranks();
        let mut owner = vec![0u32; order.len()];
        if ranks > 1 {
            // The partitions' home ranks, placed once for the run.
            let home = self.share.as_ref().map_or(&[][..], |s| &s.home[..]);
            let by_load: Vec<_> = order.iter().map(|&t| tasks.tasks[t].clone()).collect();
            let (assigned, _) = locality_aware(&by_load, ranks, &|p| home[p as usize] as usize);
            let mut reads = vec![Vec::new(); ranks];
            for (r, mine) in assigned.iter().enumerate() {
                for &n in mine {
                    owner[n] = r as u32;
                    let task = &tasks.tasks[order[n]];
                    for &c in &tasks.order[task.range.clone()] {
                        reads[r].extend_from_slice(&candidates[c as usize].v);
                    }
                }
            }
            self.fetch_trajectories(reads)?;
        }
        let w = &self.world;
        let traj = &self.traj;
        let costs = &mut self.narrow_costs;
        let home = self.share.as_ref().map_or(&[][..], |s| &s.home[..]);
        let answers = self.exec.map_on_ranks(order.len(), &owner, &|n| {
            let task = &tasks.tasks[order[n]];
            let _span = trace::span_with("narrow task", "candidates", task.range.len() as u64);
            let clock = Instant::now();
            let mut stats = CcdStats::default();
            let mut reported = Vec::new();
            for &c in &tasks.order[task.range.clone()] {
                let key = &candidates[c as usize];
                let eta = w.schedule.eta(w.layers.depth(key) + 1);
                let tr = key.v.map(|i| traj.of(i as usize));
                if proximity(key.kind, &tr, eta, &mut stats) {
                    reported.push(*key);
                }
            }
            let seconds = clock.elapsed().as_secs_f64();
            (
                reported,
                stats,
                (task.pair, seconds, task.range.len() as u64),
            )
        })?;
        self.totals.narrow_queries += candidates.len() as u64;
        let mut reported = Vec::new();
        let mut measured = Vec::with_capacity(answers.len());
        let load = &mut self.narrow_load;
        if ranks > 1 {
            load.balanced.resize(ranks, 0.0);
            load.home_only.resize(ranks, 0.0);
        }
        for (n, (r, stats, m)) in answers.into_iter().enumerate() {
            reported.extend(r);
            self.ccd.merge(&stats);
            if ranks > 1 {
                let (a, b) = m.0;
                let first = if a != weft_core::NONE { a } else { b };
                let home_rank = home.get(first as usize).map_or(0, |&r| r as usize);
                load.balanced[owner[n] as usize] += m.1;
                load.home_only[home_rank] += m.1;
            }
            measured.push(m);
        }
        costs.record(measured);
        reported.sort_unstable();
        Ok(reported)
    }

    /// Retires calm innermost layers; returns how many were retired.
    ///
    /// A stencil is calm in a window when it is certified to stay farther than
    /// `eta_depth` over the whole window, T1 included (by the narrow phase, or
    /// because its DOPs are apart: farther than `eta_1`). After
    /// `retire_after_windows` calm windows in a row its innermost layer is
    /// retired, then the next innermost as long as it is certified too — the
    /// active set stays a prefix `1..=depth` — and the counter restarts.
    fn commit(&mut self, candidates: &[StencilKey]) -> Result<u64, CommError> {
        const TASK: usize = 64;
        let entries: Vec<(StencilKey, LayerState)> = (self.world.layers.stencils.iter())
            .map(|(k, s)| (*k, *s))
            .collect();
        // Each stencil's new state depends on its own certificates only, so
        // the stencils are decided on the executor and applied in key order.
        // Tasks are runs of entries; each stencil is decided on the rank
        // that holds its first vertex's breakpoints (on one memory every
        // vertex is held by rank 0). Only the stencils among the candidates
        // are certified again, so only their polylines are read — over
        // ranks, fetched when held elsewhere.
        let ranks = self.exec.ranks();
        let holders = self.traj.holders();
        let near: Vec<bool> = (entries.iter())
            .map(|(key, _)| candidates.binary_search(key).is_ok())
            .collect();
        let mut by_rank: Vec<Vec<usize>> = vec![Vec::new(); ranks];
        for (n, (key, _)) in entries.iter().enumerate() {
            by_rank[holders[key.v[0] as usize] as usize].push(n);
        }
        let mut runs: Vec<&[usize]> = Vec::new();
        let mut owner: Vec<u32> = Vec::new();
        for (r, mine) in by_rank.iter().enumerate() {
            for run in mine.chunks(TASK) {
                runs.push(run);
                owner.push(r as u32);
            }
        }
        if ranks > 1 {
            let mut reads = vec![Vec::new(); ranks];
            for (run, &r) in runs.iter().zip(&owner) {
                for &n in run.iter().filter(|&&n| near[n]) {
                    reads[r as usize].extend_from_slice(&entries[n].0.v);
                }
            }
            self.fetch_trajectories(reads)?;
        }
        let w = &self.world;
        let traj = &self.traj;
        let hysteresis = w.contact.retire_after_windows;
        let decided = self.exec.map_on_ranks(runs.len(), &owner, &|t| {
            let _span = trace::span_with("commit task", "first", runs[t][0] as u64);
            let mut ccd = CcdStats::default();
            let states: Vec<(LayerState, u64)> = runs[t]
                .iter()
                .map(|&n| {
                    let (key, mut s) = entries[n];
                    let tr = near[n].then(|| key.v.map(|i| traj.of(i as usize)));
                    let mut certified_outside = |eta: f64| -> bool {
                        tr.as_ref()
                            .is_none_or(|tr| !proximity(key.kind, tr, eta, &mut ccd))
                    };
                    if !certified_outside(w.schedule.eta(s.depth)) {
                        s.calm_windows = 0;
                        return (s, 0);
                    }
                    s.calm_windows += 1;
                    if s.calm_windows < hysteresis {
                        return (s, 0);
                    }
                    s.calm_windows = 0;
                    s.depth -= 1;
                    let mut retired = 1;
                    while s.depth > 0 && certified_outside(w.schedule.eta(s.depth)) {
                        s.depth -= 1;
                        retired += 1;
                    }
                    (s, retired)
                })
                .collect();
            (states, ccd)
        })?;
        let mut retired = 0;
        // (every entry is in exactly one run: each slot is overwritten)
        let mut decided_states: Vec<(LayerState, u64)> =
            entries.iter().map(|&(_, s)| (s, 0)).collect();
        for ((states, ccd), run) in decided.into_iter().zip(&runs) {
            self.ccd.merge(&ccd);
            for (state, &n) in states.into_iter().zip(*run) {
                decided_states[n] = state;
            }
        }
        let layers = &mut self.world.layers.stencils;
        for ((key, _), (s, r)) in entries.iter().zip(decided_states) {
            retired += r;
            if s.depth == 0 {
                layers.remove(key);
            } else {
                layers.insert(*key, s);
            }
        }
        Ok(retired)
    }

    #[allow(clippy::too_many_arguments)]
    fn window_stats(
        &self,
        counts: PassCounts,
        rollbacks: u32,
        candidates: u64,
        confirmed: u64,
        retired: u64,
        candidate_keys: &[StencilKey],
        started: Instant,
    ) -> WindowStats {
        let w = &self.world;
        let mut min_sep = counts.min_separation;
        for key in candidate_keys {
            let x = key.v.map(|i| w.x[i as usize]);
            min_sep = min_sep.min(stencil_closest(key.kind, &x).d);
        }
        let e = self.energies();
        let (lin, ang) = self.momenta();
        let hist = w.layers.depth_histogram();
        WindowStats {
            window: w.window_index,
            time: w.time(),
            tick: w.tick,
            internal_events: counts.internal_events,
            internal_stencil_evaluations: counts.internal_events * w.internal.num_stencils() as u64,
            layer_events: counts.layer_events,
            layer_evaluations: counts.layer_evaluations,
            layer_kicks: counts.layer_kicks,
            rollbacks,
            active_stencils: w.layers.stencils.len() as u64,
            max_depth: hist.len() as u32,
            depth_histogram: hist,
            candidates,
            confirmed,
            retired_layers: retired,
            breakpoints: self.traj.breakpoints() as u64,
            min_separation: min_sep.is_finite().then_some(min_sep),
            kinetic_energy: e.0,
            potential_energy: e.1 + e.2,
            contact_energy: e.2,
            linear_momentum: lin.to_array(),
            angular_momentum: ang.to_array(),
            wall_seconds: started.elapsed().as_secs_f64(),
            stage_seconds: StageSeconds::default(),
        }
    }

    /// (kinetic, elastic + gravity, penalty) energy at the current
    /// (synchronized) state.
    pub fn energies(&self) -> (f64, f64, f64) {
        let w = &self.world;
        let mut kin = 0.0;
        let mut grav = 0.0;
        for i in 0..w.x.len() {
            if w.inv_mass[i] > 0.0 {
                kin += 0.5 * w.mass[i] * w.v[i].length_squared();
                grav -= w.mass[i] * w.gravity.dot(w.x[i]);
            }
        }
        let elastic = w.internal.energy(&w.x);
        let mut penalty = 0.0;
        for (key, s) in &w.layers.stencils {
            let x = key.v.map(|i| w.x[i as usize]);
            let d = stencil_closest(key.kind, &x).d;
            penalty += w.schedule.energy_through(s.depth, d);
        }
        (kin, elastic + grav, penalty)
    }

    /// Linear and angular momentum (about the origin) of the dynamic vertices.
    pub fn momenta(&self) -> (DVec3, DVec3) {
        let w = &self.world;
        let mut lin = DVec3::ZERO;
        let mut ang = DVec3::ZERO;
        for i in 0..w.x.len() {
            if w.inv_mass[i] > 0.0 {
                let p = w.v[i] * w.mass[i];
                lin += p;
                ang += w.x[i].cross(p);
            }
        }
        (lin, ang)
    }

    /// Hash of the state: see [`crate::hash::state_hash`].
    pub fn state_hash(&self) -> String {
        crate::hash::state_hash(&self.world)
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

fn kind_name(k: StencilKind) -> &'static str {
    match k {
        StencilKind::VertexFace => "vertex-face",
        StencilKind::EdgeEdge => "edge-edge",
    }
}
