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
//! (over ranks: placed largest first on the least-loaded rank, their results
//! handed to every rank in one collective). Then the internal tick
//! ([`internal`]) folds the internal forces and, after them, each island's
//! kicks at that tick. Every vertex folds the same kicks in the same order as
//! one global schedule of batches would: the same bits.

mod internal;
mod island;

use std::sync::Mutex;

use glam::DVec3;
use weft_core::StencilKey;

use super::Engine;
use crate::clock::Tick;
use crate::error::SimError;
use crate::executor::Executor;
use crate::islands::Islands;
use crate::trace;
use crate::world::World;
use island::{Island, SegmentOutput, Shared};

/// Tasks per thread that the islands of a segment are dealt to on one
/// memory (on the twister 50k with 2 threads, the island stage reached 90 %
/// of its ideal with 2 per thread, 81 % with 8 and 74 % with 32).
const BINS_PER_THREAD: usize = 2;

/// Tasks per rank over ranks: every rank must deal the same tasks
/// (`map_on_ranks` takes one list), so their number cannot follow a rank's
/// own thread count there.
const BINS_PER_RANK: usize = 8;

/// Islands of fewer stencils are packed together (`Islands::packed`): a
/// pack runs with the bits of its islands run apart, but each island costs
/// a visit of its state per segment, and most islands are a stencil or two.
pub(super) const PACK_STENCILS: usize = 64;

/// Vertices per task of the per-vertex stages of an internal tick.
const VERTEX_RUN: usize = 512;

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
    /// Wall seconds of the internal-force part of internal ticks (up to
    /// the new velocities).
    pub(super) internal_seconds: f64,
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
    /// The pass's contact islands (each locked by the task that runs it).
    islands: Vec<Mutex<Island>>,
    /// Over ranks, the rank each island runs on for the whole pass (what it
    /// keeps between segments — its anchors and dormancy — stays there).
    island_rank: Vec<u32>,
    /// Each island's cost: its stencils at first, then the seconds its last
    /// segment took; islands are handed out largest first.
    island_cost: Vec<f64>,
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
}

impl Workspace {
    /// Scratch for the world's vertices and internal force slots.
    pub(super) fn new(world: &World) -> Self {
        let n = world.num_vertices();
        Workspace {
            xt: vec![DVec3::ZERO; n],
            out: vec![DVec3::ZERO; world.internal.num_slots()],
            acc: vec![DVec3::ZERO; n],
            v_new: vec![DVec3::ZERO; n],
            vertex_runs: (0..=n.div_ceil(VERTEX_RUN))
                .map(|k| (k * VERTEX_RUN).min(n))
                .collect(),
            bounds: world.internal.slot_bounds(),
            ..Default::default()
        }
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

/// Places items of the given costs on `ranks` ranks, largest first on the
/// least-loaded rank (ties: the lower rank); returns each item's rank.
/// Depends on the costs only, so every rank places alike.
fn place_largest_first(costs: &[f64], ranks: usize) -> Vec<u32> {
    let mut load = vec![0.0f64; ranks.max(1)];
    let mut owner = vec![0u32; costs.len()];
    for k in largest_first(costs) {
        let r = (0..load.len())
            .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
            .expect("a rank");
        load[r] += costs[k as usize];
        owner[k as usize] = r as u32;
    }
    owner
}

impl<E: Executor> Engine<E> {
    /// Runs every event in `[t0, t1)` and drifts all vertices to `t1`,
    /// recording trajectories.
    pub(super) fn run_events(&mut self, t0: Tick, t1: Tick) -> Result<PassCounts, SimError> {
        let mut counts = PassCounts {
            min_separation: f64::INFINITY,
            ..Default::default()
        };
        let begin = trace::span("pass begin");
        self.traj.begin(t0, &self.world.x);
        let h_el = self.world.lattice.internal_step();
        let w = &self.world;
        // every internal tick gives a moving vertex a breakpoint
        self.traj.reserve(ticks_in(t0, t1, h_el) as usize + 2, |i| {
            w.inv_mass[i] > 0.0 || w.script_of[i].is_some()
        });
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
        self.begin_islands(&active, &layer_consts, (t0, t1), &mut counts);
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
            let outputs = self.run_islands(&layer_consts, (s, e), internal)?;
            if let Some(blew_up) = self.apply_islands(&outputs, t0, &mut counts)? {
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
            match self.internal_tick(b, &outputs, &mut counts) {
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
            share.gather_states(&self.exec, &mut w.x, &mut w.v, &mut w.tau, &mut self.traj)?;
        }
        self.traj.flush(&self.exec, &self.ws.vertex_runs);
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

    /// The pass's contact islands, all awake, and the counts that follow from
    /// the active set alone: the layer events of the window (each stencil of
    /// depth `d` at every tick of layers `1..=d`) and the largest island's.
    fn begin_islands(
        &mut self,
        active: &[(StencilKey, u32)],
        layer_consts: &[(f64, f64, Tick)],
        (t0, t1): (Tick, Tick),
        counts: &mut PassCounts,
    ) {
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
        // The units of work: the islands, the small ones packed.
        let packs = islands.packed(self.island_pack);
        let ws = &mut self.ws;
        ws.pass_end = t1;
        ws.island_cost = (0..packs.len())
            .map(|k| packs.stencils_of(k).len() as f64)
            .collect();
        ws.island_rank = place_largest_first(&ws.island_cost, self.exec.ranks());
        // Each rank builds the islands placed on it (they run there for the
        // whole pass; the others' results arrive with every segment).
        let me = self.exec.rank() as u32;
        ws.islands = (0..packs.len())
            .map(|k| match ws.island_rank[k] == me {
                true => Mutex::new(Island::new(&packs, k, active, w, t0)),
                false => Mutex::default(),
            })
            .collect();
        if let Some(share) = &self.share {
            // Every vertex an island's stencils read, with the island's rank.
            let reads = (0..packs.len()).flat_map(|k| {
                let r = ws.island_rank[k];
                (packs.stencils_of(k).iter())
                    .flat_map(move |&a| active[a as usize].0.v.map(|i| (i, r)))
            });
            ws.pass_share = share.pass(reads);
        }
    }

    /// Every island's segment `[s, e)` (and its kicks at the internal tick
    /// `e` when `internal`), in parallel, in bins balanced by the seconds
    /// each island's last segment took; over ranks each island runs on its
    /// rank and every rank gets every result (one collective). Results in
    /// island order.
    fn run_islands(
        &mut self,
        layer_consts: &[(f64, f64, Tick)],
        (s, e): (Tick, Tick),
        internal: bool,
    ) -> Result<Vec<SegmentOutput>, SimError> {
        let n = self.ws.islands.len();
        if n == 0 {
            return Ok(Vec::new());
        }
        let _span = trace::span_with("islands", "islands", n as u64);
        // Bins of islands: each rank's islands dealt largest first (by the
        // seconds of their last segment) to the least-loaded of its bins, so
        // a few tasks carry the many small islands (a task per island would
        // cost more than most islands do).
        let ranks = self.exec.ranks();
        let per_rank = if ranks == 1 {
            BINS_PER_THREAD * self.exec.threads_per_rank().max(1)
        } else {
            BINS_PER_RANK
        };
        let mut bins: Vec<Vec<u32>> = vec![Vec::new(); ranks * per_rank];
        let mut load = vec![0.0f64; bins.len()];
        for k in largest_first(&self.ws.island_cost) {
            let r = self.ws.island_rank[k as usize] as usize;
            let b = (r * per_rank..(r + 1) * per_rank)
                .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
                .expect("a bin");
            load[b] += self.ws.island_cost[k as usize].max(1e-9);
            bins[b].push(k);
        }
        let owner: Vec<u32> = (0..bins.len()).map(|b| (b / per_rank) as u32).collect();
        let shared = Shared {
            world: &self.world,
            layer_consts,
            exhaustive: self.every_layer_event,
            pass_end: self.ws.pass_end,
        };
        let (islands, exec) = (&self.ws.islands, &self.exec);
        let binned = self.exec.map_on_ranks(bins.len(), &owner, &|b| {
            let _span = trace::span_with("island task", "islands", bins[b].len() as u64);
            (bins[b].iter())
                .map(|&k| {
                    let mut island = islands[k as usize].lock().expect("an island's lock");
                    island.run_segment(exec, &shared, (s, e), internal)
                })
                .collect::<Vec<_>>()
        })?;
        let mut outputs = vec![SegmentOutput::default(); n];
        for (k, output) in bins.into_iter().flatten().zip(binned.into_iter().flatten()) {
            self.ws.island_cost[k as usize] = output.seconds;
            outputs[k as usize] = output;
        }
        Ok(outputs)
    }

    /// Applies the islands' segment results in island order: their vertices'
    /// new states, their breakpoints (the budget checked), their counts.
    /// Returns the blow-up to report (the earliest, then the lowest vertex)
    /// if an island stopped at one.
    fn apply_islands(
        &mut self,
        outputs: &[SegmentOutput],
        t0: Tick,
        counts: &mut PassCounts,
    ) -> Result<Option<SimError>, SimError> {
        let _span = trace::span("islands merge");
        let w = &mut self.world;
        let mut blew_up: Option<(Tick, u32)> = None;
        // The breakpoints go to their vertices' runs, each run's in island
        // order (a vertex's are all one island's, in time order), and the
        // runs record them on the executor. Near the budget they are
        // recorded one by one instead, so the error names the breakpoint
        // that broke it.
        let count: usize = outputs.iter().map(|o| o.breakpoints.len()).sum();
        let parallel = count > 0 && self.traj.fits(count);
        if parallel {
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
            drop(record);
            self.traj
                .add_recorded(added.into_inner())
                .map_err(|e| budget_error(w, t0, e))?;
        }
        for out in outputs {
            for &(i, x, v, tau) in &out.moved {
                let i = i as usize;
                (w.x[i], w.v[i], w.tau[i]) = (x, v, tau);
            }
            if !parallel {
                for &(i, t, x) in &out.breakpoints {
                    self.traj
                        .record(i as usize, t, x)
                        .map_err(|e| budget_error(w, t0, e))?;
                }
            }
            counts.layer_evaluations += out.evaluations;
            counts.layer_kicks += out.kicks;
            counts.min_separation = counts.min_separation.min(out.min_separation);
            if let Some(b) = out.blew_up {
                blew_up = Some(blew_up.map_or(b, |a| a.min(b)));
            }
        }
        Ok(blew_up.map(|(t, i)| SimError::NonFinite {
            place: w.place(i),
            vertex: i,
            time: w.lattice.seconds(t),
        }))
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
    fn largest_first_balances_and_is_deterministic() {
        let costs = [1.0, 5.0, 3.0, 3.0, 0.5];
        assert_eq!(largest_first(&costs), vec![1, 2, 3, 0, 4]);
        // 5 → rank 0; 3, 3 → rank 1; 1 → rank 0 (5 < 6); 0.5 → rank 0 (6 = 6).
        assert_eq!(place_largest_first(&costs, 2), vec![0, 0, 1, 1, 0]);
        assert_eq!(place_largest_first(&[1.0, 2.0], 1), vec![0, 0]);
    }
}
