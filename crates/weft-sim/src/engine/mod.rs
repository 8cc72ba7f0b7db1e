//! The speculative ACM loop (`acm-spec.md` §4): per window, run every event in
//! time order, detect, and either commit or roll back with more layers.
//!
//! ```text
//! predict: deepen the stencils the extrapolated motion brings into a layer
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
//! Its stages, each in a module of its own: the prediction of layers
//! (`predict.rs`), the events of a pass
//! (`events/`: internal ticks, contact islands and their penalty-layer
//! batches, trajectories), the broad phase ([`crate::broad`]), the narrow
//! phase (`narrow.rs`), the commit (`commit.rs`: retiring layers) and the
//! window's statistics (`stats.rs`).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

mod commit;
mod events;
mod narrow;
mod placement;
mod predict;
mod stats;

use glam::DVec3;
use weft_core::{StencilKey, StencilKind};
use weft_geom::ccd::CcdStats;
use weft_geom::distance::stencil_closest;

use crate::balance::CostModel;
use crate::broad::BroadPhase;
use crate::clock::Tick;
use crate::diagnostics::{CommittedWindow, PenaltyWork, StageSeconds, WindowTiming};
use crate::error::SimError;
use crate::executor::{Executor, Serial};
use crate::layers::LayerState;
use crate::share::RankShare;
use crate::state::EngineState;
use crate::trace;
use crate::trajectory::Trajectories;
use crate::world::World;
use events::Workspace;
use placement::EventsLoad;
use predict::{Predicted, Predictor};

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

/// A stage's wall clock, its rank's work CPU clock
/// ([`Executor::work_cpu_seconds`]: polling for peers left out) and the
/// bytes the rank sent.
struct StageClock {
    wall: Instant,
    cpu: f64,
    sent: u64,
}

impl StageClock {
    fn start<E: Executor>(exec: &E) -> Self {
        Self {
            wall: Instant::now(),
            cpu: exec.work_cpu_seconds(),
            sent: exec.traffic().bytes,
        }
    }

    /// Wall and work-CPU seconds and bytes sent since the start.
    fn stop<E: Executor>(&self, exec: &E) -> (f64, f64, f64) {
        (
            self.wall.elapsed().as_secs_f64(),
            exec.work_cpu_seconds() - self.cpu,
            (exec.traffic().bytes - self.sent) as f64,
        )
    }

    fn add_to<E: Executor>(&self, exec: &E, (wall, cpu, sent): (&mut f64, &mut f64, &mut f64)) {
        let (w, c, b) = self.stop(exec);
        *wall += w;
        *cpu += c;
        *sent += b;
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

/// `contact.split_islands` unset, the islands are split (also on one
/// rank) from this many threads per rank on: measured on 16 cores
/// (`docs/performance.md`, "Sixteen cores"), the split was faster from 8
/// threads on (the 10k twister 338 against 371 ms a window at 8, 257
/// against 348 at 16; 50k 1.14× and 1.31×) and 2–11 % slower at 2 and 4.
const SPLIT_FROM_THREADS: usize = 8;

/// `contact.split_islands` unset, the islands are split over this many
/// ranks and more: on 2 ranks the partitions placed by load balance a
/// giant island whole (the split cost 9 % more CPU there for the same
/// time), from 4 on a rank's share falls towards the island's cost, which
/// no placement splits (10k twister under `mpirun`, the busiest rank's
/// CPU: 4 ranks the same either way, 8 ranks 0.40 s split against 0.45
/// whole; at 50k on 8 and 16 ranks of a 16-core machine the giant
/// island's units on one rank took 2.2–2.4× the time of its units spread;
/// `docs/performance.md`, "The islands split from 4 ranks by default").
const SPLIT_FROM_RANKS: usize = 4;

/// The ACM engine over a [`World`], running its stages on an [`Executor`].
pub struct Engine<E: Executor = Serial> {
    pub world: World,
    exec: E,
    traj: Trajectories,
    /// The layer predictor's scratch (`predict.rs`): made with the engine
    /// when prediction is on, else on first use (a resume may turn it on).
    predictor: Option<Predictor>,
    ws: Workspace,
    /// The broad phase's trees and scratch, reused across passes.
    broad: BroadPhase,
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
    /// Over ranks: what the last committed window's events stage cost this
    /// rank (`placement.rs`), taken at the next window's start.
    events_load: Option<EventsLoad>,
    /// How many times the partitions were placed again (`placement.rs`).
    pub placements: u64,
    /// Over ranks with `contact.split_islands`: vertices whose unit moved
    /// to another rank when a promotion merged units of two ranks, since
    /// the start.
    pub moved_between_ranks: u64,
    /// Evaluate every penalty-layer event exactly (no sleeping, no
    /// distance-bound skip): the same bits, slower; for verifying the skips.
    every_layer_event: bool,
    /// Run every active stencil as one island (the global schedule).
    one_island: bool,
    /// Islands of fewer stencils run packed together (`Islands::packed`).
    island_pack: usize,
    /// Keep the far stencils out of the islands while they are certified
    /// outside `eta_1` (`events/far.rs`): the next pass splits the islands.
    far_stencils: bool,
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
    pub fn new(mut world: World, exec: E) -> Result<Self, SimError> {
        let n = world.num_vertices();
        let budget = world.limits.trajectory_budget_bytes;
        let share = (exec.ranks() > 1).then(|| RankShare::new(&world, exec.rank(), exec.ranks()));
        if let Some(share) = &share {
            // The internal elements of this rank's partitions only, and the
            // folds of the vertices it owns; the whole world's go before
            // anything else is made (they were a rank's memory peak).
            let (home, me) = (&share.home, share.rank as u32);
            let folds = placement::holds_fold(&world.partitioning.of_vertex, home, me);
            let part = world.internal.held_only(|p| home[p] == me, folds);
            world.internal = Arc::new(part);
        }
        // Over ranks a vertex's breakpoints are stored by its owner only;
        // others fetch what their tasks read.
        let mut traj = match &share {
            Some(share) => Trajectories::held_by(share.owner.clone(), share.rank as u32, budget),
            None => Trajectories::new(n, budget),
        };
        // (The columns hold the vertices held here.)
        traj.make_staged_columns();
        reserve_trajectories(&mut traj, &world);
        let mut broad = BroadPhase::grouped(&world.partitioning.of_triangle);
        if exec.ranks() > 1 {
            // Each rank builds its partitions' trees and their neighbours'.
            broad.spread(world.internal.home_ranks(exec.ranks()));
        }
        let mut engine = Self {
            ws: Workspace::new(&world, share.as_ref()),
            broad,
            world,
            exec,
            traj,
            predictor: None,
            totals: RunTotals::default(),
            ccd: CcdStats::default(),
            interrupt: None,
            narrow_costs: CostModel::default(),
            narrow_load: NarrowLoad::default(),
            share,
            events_load: None,
            placements: 0,
            moved_between_ranks: 0,
            every_layer_event: false,
            one_island: false,
            island_pack: events::PACK_STENCILS,
            far_stencils: false,
        };
        // Unset, the islands are split from `SPLIT_FROM_RANKS` ranks on
        // (their units spread: a giant island whole on one rank leaves the
        // others waiting for it) and from `SPLIT_FROM_THREADS` threads per
        // rank on (whole, it keeps one thread busy while the others wait).
        let (ranks, threads) = (engine.exec.ranks(), engine.exec.threads_per_rank());
        engine.far_stencils = (engine.world.contact.split_islands)
            .unwrap_or(ranks >= SPLIT_FROM_RANKS || threads >= SPLIT_FROM_THREADS);
        if engine.world.contact.predict {
            engine.make_predictor();
        }
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
    /// sleeps and none is skipped by its distance bound. An event is skipped
    /// only where the exact distance is certainly outside its layer, so the
    /// bits are the same wherever the evaluated distance errs by less than
    /// the margin (tested on random scenes; sliver triangles and nearly
    /// parallel edges can err more: `weft_geom::distance`); only the time
    /// differs.
    pub fn evaluate_every_layer_event(&mut self, on: bool) {
        self.every_layer_event = on;
    }

    /// Runs every active stencil as one contact island when `on`: one batch
    /// per tick over every stencil, the global schedule of batches the
    /// islands reproduce bit for bit (tested); only the time differs. A pass
    /// that blows up (always rolled back) is the exception: it ends where
    /// the island holding the blow-up stopped, so which layers it adds
    /// depends on which islands ran together (ARCHITECTURE.md).
    pub fn run_as_one_island(&mut self, on: bool) {
        self.one_island = on;
    }

    /// Packs the islands of fewer than `min_stencils` stencils into units of
    /// work of about that many (default 64; 1 runs every island alone). Any
    /// packing gives the same bits (tested) in every pass that does not blow
    /// up; only the time differs. (The packing depends on the active set
    /// only, so a run's bits never depend on threads, ranks or partitions.)
    pub fn set_island_packing(&mut self, min_stencils: usize) {
        self.island_pack = min_stencils.max(1);
    }

    /// Keeps the far stencils (two dynamic vertices, certified outside
    /// `eta_1`) out of the contact islands when `on`, from the next window
    /// on (default: the scene's `contact.split_islands`; unset, on from 4
    /// ranks and from 8 threads per rank), so that
    /// the islands are those of the stencils in or near contact, and
    /// promotes one into them when it may come within `eta_1`, running the
    /// segment again where it was already run. The same bits either way
    /// (tested); the islands, the time and the counts of evaluations differ.
    pub fn split_far_stencils(&mut self, on: bool) {
        self.far_stencils = on;
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
            // Contact islands join stencils through their moving vertices;
            // the broad phase never makes a stencil of kinematic ones only.
            if key
                .v
                .iter()
                .all(|&i| self.world.inv_mass[i as usize] == 0.0)
            {
                return bad(format!(
                    "active layer on vertices {:?} joins only pinned or scripted vertices",
                    key.v
                ));
            }
            layers.insert(*key, *s);
        }
        let w = &mut self.world;
        w.tick = state.tick;
        w.window_index = state.window_index;
        // (Collected in place, into the decoded vectors: a decoder grows a
        // long one by doubling, so each is made to its length, a megabyte
        // less of each at 50k vertices on every rank.)
        w.x = state.x.into_iter().map(DVec3::from_array).collect();
        w.v = state.v.into_iter().map(DVec3::from_array).collect();
        w.tau = state.tau;
        for column in [&mut w.x, &mut w.v] {
            column.shrink_to_fit();
        }
        w.tau.shrink_to_fit();
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
        let keys = self.broad.candidates_on(
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
        world.lattice.drift(world.x[i], world.v[i], world.tau[i], t)
    }

    /// Runs one window to commit (with as many rollbacks as it needs).
    ///
    /// On an error (an interrupt included) the world is left exactly at the
    /// last committed state — positions, velocities, clocks and the active
    /// layers, without the layers this window's rollbacks added — so a
    /// checkpoint taken then resumes bit-identically.
    pub fn step_window(&mut self) -> Result<CommittedWindow, SimError> {
        // The committed layers, to put back if the window fails: as a
        // sorted list (28 bytes a stencil), not a clone of the map with its
        // nodes' spare room, since it is held through the window's memory
        // peak (the map is rebuilt from it, in order, only on failure).
        let committed: Vec<(StencilKey, LayerState)> = (self.world.layers.stencils.iter())
            .map(|(k, s)| (*k, *s))
            .collect();
        let result = self.run_window();
        if result.is_err() {
            self.world.layers.stencils = committed.into_iter().collect();
        }
        result
    }

    fn run_window(&mut self) -> Result<CommittedWindow, SimError> {
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
        let ccd_before = self.ccd;
        // The deepest layer a stencil may get (about 30 `pow` calls: once
        // per window, not per rollback).
        let resolved = self.world.schedule.resolved_depth();
        self.place_partitions_by_load()?;
        let clock = StageClock::start(&self.exec);
        let site = trace::site("predict");
        let predicted = if self.world.contact.predict {
            self.predict_layers(resolved)?
        } else {
            Predicted::default()
        };
        drop(site);
        (stages.predict, stages.cpu.predict, stages.sent.predict) = clock.stop(&self.exec);
        let mut detected_layers = 0u64;
        let mut island_cpu = 0.0;
        loop {
            let clock = StageClock::start(&self.exec);
            let events = trace::stage("events", Some(("pass", rollbacks as u64)));
            let mut counts = match self.run_events(t0, t1) {
                Ok(c) => c,
                Err(e) => {
                    snap.restore(&mut self.world);
                    return Err(e);
                }
            };
            drop(events);
            let stage = (
                &mut stages.events,
                &mut stages.cpu.events,
                &mut stages.sent.events,
            );
            clock.add_to(&self.exec, stage);
            stages.internal += counts.internal_seconds;
            island_cpu += counts.island_cpu;
            if let Some(e) = counts.interrupted.take() {
                snap.restore(&mut self.world);
                return Err(e);
            }
            let clock = StageClock::start(&self.exec);
            let broad = trace::stage("broad", None);
            let candidates = {
                let w = &self.world;
                self.broad.candidates_on(
                    &self.exec,
                    &w.triangles,
                    &w.inv_mass,
                    &self.traj,
                    0.5 * w.schedule.eta_1,
                )
            };
            drop(broad);
            let stage = (
                &mut stages.broad,
                &mut stages.cpu.broad,
                &mut stages.sent.broad,
            );
            clock.add_to(&self.exec, stage);
            let clock = StageClock::start(&self.exec);
            let count = candidates.as_ref().map_or(0, |c| c.len() as u64);
            let narrow = trace::stage("narrow", Some(("candidates", count)));
            // (a pass cut short fetches its scripted vertices' polylines)
            let replay = counts.truncated.is_none().then_some((&snap, (t0, t1)));
            let found = candidates.and_then(|c| Ok((self.narrow_phase(&c, replay)?, c)));
            let ((reported, tested_on), candidates) = match found {
                Ok(found) => found,
                Err(e) => {
                    snap.restore(&mut self.world);
                    return Err(e.into());
                }
            };
            drop(narrow);
            let stage = (
                &mut stages.narrow,
                &mut stages.cpu.narrow,
                &mut stages.sent.narrow,
            );
            clock.add_to(&self.exec, stage);
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
                let clock = StageClock::start(&self.exec);
                let _commit = trace::stage("commit", None);
                let committed = (self.commit(&candidates, &tested_on, &predicted))
                    .and_then(|done| Ok((done, self.stats_sums(&candidates)?)));
                let ((retired, unreached), sums) = match committed {
                    Ok(done) => done,
                    Err(e) => {
                        snap.restore(&mut self.world);
                        return Err(e.into());
                    }
                };
                self.traj.forget_fetched();
                self.world.tick = t1;
                let penalty_work = PenaltyWork {
                    split: counts.split,
                    layer_evaluations: counts.layer_evaluations,
                    far_stencils: counts.far.far,
                    far_promoted: counts.far.promoted,
                    island_reruns: counts.far.reruns,
                    largest_unit_layer_events: counts.far.largest,
                };
                let mut stats = self.window_stats(
                    counts,
                    sums,
                    rollbacks,
                    candidates.len() as u64,
                    confirmed,
                    retired,
                    &candidates,
                );
                let stage = (
                    &mut stages.commit,
                    &mut stages.cpu.commit,
                    &mut stages.sent.commit,
                );
                clock.add_to(&self.exec, stage);
                if self.share.is_some() {
                    self.events_load = Some(EventsLoad {
                        islands: island_cpu,
                        rest: (stages.cpu.events - island_cpu).max(0.0),
                    });
                }
                let timing = WindowTiming {
                    window: stats.window,
                    wall_seconds: started.elapsed().as_secs_f64(),
                    stage_seconds: stages,
                    penalty_work,
                };
                stats.predicted_layers = predicted.layers;
                stats.predicted_unreached = unreached;
                stats.detected_layers = detected_layers;
                stats.certified_intervals =
                    self.ccd.certified_intervals - ccd_before.certified_intervals;
                stats.block_certified_intervals =
                    self.ccd.block_certified - ccd_before.block_certified;
                self.world.window_index += 1;
                self.totals.windows += 1;
                self.totals.rollbacks += rollbacks as u64;
                self.totals.max_depth = self.totals.max_depth.max(stats.max_depth);
                self.totals.max_active_stencils =
                    self.totals.max_active_stencils.max(stats.active_stencils);
                return Ok(CommittedWindow { stats, timing });
            }
            confirmed += reported.len() as u64;
            // Roll back: forget the polylines fetched for the pass (the next
            // pass fetches its own), restore the state, keep (and extend)
            // the layers.
            self.traj.forget_fetched();
            snap.restore(&mut self.world);
            // Each reported stencil gets `layers_per_detection` more layers,
            // or, with prediction on, more when its closing energy at the
            // window start needs them (`predict::layers_to_hold`); at most as
            // many as remain down to the deepest resolved one (only a stencil
            // already there has none left to get). With prediction off the
            // layers are exactly the detection's, as before prediction.
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
                let added = if self.world.contact.predict {
                    let w = &self.world;
                    predict::layers_to_hold(
                        w,
                        key,
                        &predict::closest_now(w, key),
                        depth,
                        extra,
                        resolved,
                    )
                } else {
                    extra.min(resolved - depth)
                };
                self.world.layers.deepen(*key, added);
                detected_layers += added as u64;
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
        for &f in w.vertex_faces.of(i) {
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

    /// Hash of the state: see [`crate::hash::state_hash`].
    pub fn state_hash(&self) -> String {
        crate::hash::state_hash(&self.world)
    }
}

/// Makes room for a window's breakpoints of every moving vertex `traj`
/// holds (one per internal tick): made with the engine (and when the
/// partitions are placed again), as the staged columns are; made by a
/// pass, a run's first window paid for it (22 ms at 10k,
/// `docs/performance.md`).
fn reserve_trajectories(traj: &mut Trajectories, world: &World) {
    let per_window = (world.lattice.window() / world.lattice.internal_step()) as usize + 2;
    traj.reserve(per_window, |i| {
        world.inv_mass[i] > 0.0 || world.script_of[i].is_some()
    });
}

fn kind_name(k: StencilKind) -> &'static str {
    match k {
        StencilKind::VertexFace => "vertex-face",
        StencilKind::EdgeEdge => "edge-edge",
    }
}
