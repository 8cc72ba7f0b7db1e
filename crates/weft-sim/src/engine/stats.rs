//! A committed window's statistics (`stats.jsonl`): counts from the pass,
//! and sums over the state — energies, momenta, the smallest separation.
//!
//! The sums are split into fixed tasks of [`STATS_TASK`] items (vertices,
//! elements in key order, active stencils in key order, candidates), each
//! task's partial sums are computed on one rank (round robin), and every
//! rank folds the partials in task order. The split does not depend on the
//! rank count, so the sums have the same bits on every executor, and over
//! ranks no rank repeats them all (at 32 simulated ranks on the 10k twister
//! they had been about 5 % of all CPU). Over ranks a rank holds the
//! internal elements of its own partitions only: each element's energy is
//! computed there and sent to the rank that sums its task.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use weft_core::StencilKey;
use weft_geom::distance::stencil_closest;

use super::events::PassCounts;
use super::Engine;
use crate::diagnostics::WindowStats;
use crate::executor::{CommError, Executor};
use crate::layers::LayerState;
use crate::world::World;

/// Items per task of the sums.
const STATS_TASK: usize = 4096;

/// What one task sums (zero for the items it does not hold).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub(super) struct Sums {
    kinetic: f64,
    gravity: f64,
    elastic: f64,
    penalty: f64,
    linear: [f64; 3],
    angular: [f64; 3],
    /// The smallest closest distance of the task's candidates (infinite
    /// for none).
    min_separation: f64,
}

impl Sums {
    const EMPTY: Sums = Sums {
        kinetic: 0.0,
        gravity: 0.0,
        elastic: 0.0,
        penalty: 0.0,
        linear: [0.0; 3],
        angular: [0.0; 3],
        min_separation: f64::INFINITY,
    };

    /// The partials folded in task order.
    fn fold(parts: impl IntoIterator<Item = Sums>) -> Sums {
        let mut all = Sums::EMPTY;
        for p in parts {
            all.kinetic += p.kinetic;
            all.gravity += p.gravity;
            all.elastic += p.elastic;
            all.penalty += p.penalty;
            for k in 0..3 {
                all.linear[k] += p.linear[k];
                all.angular[k] += p.angular[k];
            }
            all.min_separation = all.min_separation.min(p.min_separation);
        }
        all
    }
}

/// One task: a range of one kind of item.
#[derive(Clone, Copy, Debug)]
enum Task {
    Vertices(usize, usize),
    Elements(usize, usize),
    Active(usize, usize),
    Candidates(usize, usize),
}

/// The tasks over `n` items of one kind.
fn split(n: usize, make: fn(usize, usize) -> Task) -> impl Iterator<Item = Task> {
    (0..n.div_ceil(STATS_TASK)).map(move |t| make(t * STATS_TASK, ((t + 1) * STATS_TASK).min(n)))
}

/// The tasks of the sums over a state, with its active stencils in key order.
struct Plan<'a> {
    world: &'a World,
    active: Vec<(&'a StencilKey, &'a LayerState)>,
    candidates: &'a [StencilKey],
    tasks: Vec<Task>,
    /// Over ranks, per task, the elastic energy of the element tasks this
    /// rank sums ([`Engine::elastic_by_task`]).
    elastic: Option<Vec<Option<f64>>>,
}

impl<'a> Plan<'a> {
    fn new(world: &'a World, candidates: &'a [StencilKey]) -> Self {
        let active: Vec<(&StencilKey, &LayerState)> = world.layers.stencils.iter().collect();
        let (stretch, hinges) = world.internal.elements_by_key();
        let tasks = split(world.x.len(), Task::Vertices)
            .chain(split(stretch + hinges, Task::Elements))
            .chain(split(active.len(), Task::Active))
            .chain(split(candidates.len(), Task::Candidates))
            .collect();
        Self {
            world,
            active,
            candidates,
            tasks,
            elastic: None,
        }
    }

    /// Task `t`'s partial sums.
    fn sums(&self, t: usize) -> Sums {
        let w = self.world;
        let mut s = Sums::EMPTY;
        match self.tasks[t] {
            Task::Vertices(a, b) => {
                let (mut lin, mut ang) = (DVec3::ZERO, DVec3::ZERO);
                for i in (a..b).filter(|&i| w.inv_mass[i] > 0.0) {
                    s.kinetic += 0.5 * w.mass[i] * w.v[i].length_squared();
                    s.gravity -= w.mass[i] * w.gravity.dot(w.x[i]);
                    let p = w.v[i] * w.mass[i];
                    lin += p;
                    ang += w.x[i].cross(p);
                }
                (s.linear, s.angular) = (lin.to_array(), ang.to_array());
            }
            Task::Elements(a, b) => {
                s.elastic = match &self.elastic {
                    Some(summed) => summed[t].expect("an element task summed on its rank"),
                    None => w.internal.energy_of(&w.x, a..b),
                }
            }
            Task::Active(a, b) => {
                for (key, state) in &self.active[a..b] {
                    let x = key.v.map(|i| w.x[i as usize]);
                    let d = stencil_closest(key.kind, &x).d;
                    s.penalty += w.schedule.energy_through(state.depth, d);
                }
            }
            Task::Candidates(a, b) => {
                for key in &self.candidates[a..b] {
                    let x = key.v.map(|i| w.x[i as usize]);
                    s.min_separation = s.min_separation.min(stencil_closest(key.kind, &x).d);
                }
            }
        }
        s
    }

    /// Every task on this memory, folded: the same bits as spread over ranks.
    fn local(&self) -> Sums {
        Sums::fold((0..self.tasks.len()).map(|t| self.sums(t)))
    }
}

impl<E: Executor> Engine<E> {
    /// The state's sums at the current (synchronized) state, with the
    /// smallest closest distance of `candidates`; the tasks dealt round
    /// robin over the ranks (a collective).
    pub(super) fn stats_sums(&self, candidates: &[StencilKey]) -> Result<Sums, CommError> {
        let mut plan = Plan::new(&self.world, candidates);
        let ranks = self.exec.ranks() as u32;
        let owner: Vec<u32> = (0..plan.tasks.len() as u32).map(|t| t % ranks).collect();
        if ranks > 1 {
            plan.elastic = Some(self.elastic_by_task(&plan.tasks, &owner)?);
        }
        let parts = self
            .exec
            .map_on_ranks(plan.tasks.len(), &owner, &|t| plan.sums(t))?;
        Ok(Sums::fold(parts))
    }

    /// **Collective over ranks** (an all-to-all). The elastic energy of
    /// each element task (`tasks`) that this rank sums (`owner`): every
    /// element's energy is computed on the rank that holds it and sent to
    /// the rank that sums its task, which adds them in key order, as
    /// [`crate::internal::InternalForces::energy_of`] does on one memory:
    /// the same bits.
    fn elastic_by_task(
        &self,
        tasks: &[Task],
        owner: &[u32],
    ) -> Result<Vec<Option<f64>>, CommError> {
        let (ranks, me) = (self.exec.ranks(), self.exec.rank());
        let first = tasks.iter().position(|t| matches!(t, Task::Elements(..)));
        let mut parts = vec![Vec::new(); ranks];
        for (n, e) in self.world.internal.held_energies(&self.world.x) {
            let t = first.expect("an element task per element") + n as usize / STATS_TASK;
            parts[owner[t] as usize].push(DVec3::new(f64::from(n), e, 0.0));
        }
        let (_, received) = self.exec.all_to_all_vectors(Vec::new(), parts)?;
        // (sorted into key order here: each rank sent its elements in the
        // order it holds them)
        let mut energies: Vec<(u32, f64)> = (received.into_iter().flatten())
            .map(|v| (v.x as u32, v.y))
            .collect();
        energies.sort_unstable_by_key(|e| e.0);
        let mut energies = energies.into_iter();
        let mut elastic = vec![None; tasks.len()];
        for (t, task) in tasks.iter().enumerate() {
            let Task::Elements(a, b) = *task else {
                continue;
            };
            if owner[t] as usize != me {
                continue;
            }
            let mut sum = 0.0;
            for n in a..b {
                match energies.next() {
                    Some((k, e)) if k as usize == n => sum += e,
                    _ => {
                        return Err(CommError(format!(
                            "rank {me}: the energy of element {n} (in key order) did not arrive"
                        )))
                    }
                }
            }
            elastic[t] = Some(sum);
        }
        Ok(elastic)
    }

    /// (kinetic, elastic + gravity, penalty) energy at the current
    /// (synchronized) state, as in `stats.jsonl`; on one memory (over ranks
    /// a rank holds its partitions' internal elements only: the window's
    /// statistics have the sums).
    pub fn energies(&self) -> (f64, f64, f64) {
        let s = Plan::new(&self.world, &[]).local();
        (s.kinetic, s.elastic + s.gravity, s.penalty)
    }

    /// Linear and angular momentum (about the origin) of the dynamic
    /// vertices, as in `stats.jsonl`; on this memory alone.
    pub fn momenta(&self) -> (DVec3, DVec3) {
        let s = Plan::new(&self.world, &[]).local();
        (DVec3::from_array(s.linear), DVec3::from_array(s.angular))
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn window_stats(
        &self,
        counts: PassCounts,
        sums: Sums,
        rollbacks: u32,
        candidates: u64,
        confirmed: u64,
        retired: u64,
        candidate_keys: &[StencilKey],
    ) -> WindowStats {
        let w = &self.world;
        let min_sep = counts.min_separation.min(sums.min_separation);
        let hist = w.layers.depth_histogram();
        WindowStats {
            window: w.window_index,
            time: w.time(),
            tick: w.tick,
            internal_events: counts.internal_events,
            internal_stencil_evaluations: counts.internal_events * w.internal.num_stencils() as u64,
            layer_events: counts.layer_events,
            layer_kicks: counts.layer_kicks,
            islands: counts.islands,
            largest_island_layer_events: counts.largest_island_layer_events,
            rollbacks,
            active_stencils: w.layers.stencils.len() as u64,
            max_depth: hist.len() as u32,
            depth_histogram: hist,
            candidates,
            confirmed,
            retired_layers: retired,
            predicted_layers: 0,
            detected_layers: 0,
            predicted_unreached: 0,
            breakpoints: self.traj.breakpoints() as u64,
            queried_breakpoints: (candidate_keys.iter())
                .flat_map(|k| k.v)
                .map(|i| self.traj.count(i as usize) as u64)
                .sum(),
            certified_intervals: 0,
            block_certified_intervals: 0,
            min_separation: min_sep.is_finite().then_some(min_sep),
            kinetic_energy: sums.kinetic,
            potential_energy: (sums.elastic + sums.gravity) + sums.penalty,
            contact_energy: sums.penalty,
            linear_momentum: sums.linear,
            angular_momentum: sums.angular,
        }
    }
}
