//! An internal tick: stretch, bend, damping, gravity and the scripts, with
//! the penalty layers that fire at the same tick folded after them.

use std::time::Instant;

use glam::DVec3;

use super::island::SegmentOutput;
use super::{bucket_by_run, budget_error, CalmDone, CalmProgress, VERTEX_RUN};
use crate::clock::Tick;
use crate::engine::Engine;
use crate::error::SimError;
use crate::executor::{split_chunks, Executor};
use crate::share::Slots;
use crate::trace;
use crate::world::World;

impl<E: Executor> Engine<E> {
    /// The internal batch at tick `t`: positions at `t`, the internal forces
    /// (over ranks: Algorithm 1, boundary partitions first, their slots sent
    /// to the ranks that fold them while the interior ones are evaluated),
    /// each vertex's ordered fold of its internal slots and then of its
    /// island's kicks at `t` (`islands`, in island order: each vertex's
    /// terms in (layer, key) order, where the global schedule folds them),
    /// new velocities, and the new states with their breakpoints. What of
    /// the calm part ([`super::Calm`]) ran with the islands, `calm_done` —
    /// the positions of the vertices outside every island and the internal
    /// forces of the elements among them, and on one memory the folds of
    /// the calm vertices, with each run's first calm vertex that blows up —
    /// is not computed again here.
    pub(super) fn internal_tick(
        &mut self,
        t: Tick,
        islands: &[SegmentOutput],
        calm_done: CalmDone,
        counts: &mut super::PassCounts,
    ) -> Result<(), SimError> {
        let _span = trace::span("internal tick");
        let clock = Instant::now();
        counts.internal_events += 1;
        let w = &self.world;
        let ws = &mut self.ws;
        // Per-vertex stages run on the executor in fixed runs of vertices;
        // each writes only its own vertices' entries.
        // Over ranks only the live vertices (owned here, or read here by a
        // partition or an island) are advanced; the others stay as they
        // were until the pass ends.
        let share = self.share.as_ref();
        // (Over ranks the calm part may have been computed only in part:
        // `progress`.)
        let no_progress = CalmProgress::default();
        let (calm, calm_bad, progress) = match &calm_done {
            CalmDone::Nothing => (None, None, &no_progress),
            CalmDone::Partly(progress) => (ws.calm.as_ref(), None, progress),
            CalmDone::ForcesAndFolds(bad) => (ws.calm.as_ref(), Some(bad), &no_progress),
        };
        let positions = progress.positions || calm_bad.is_some();
        let live_in_run = match (share, calm) {
            (_, Some(calm)) if positions => Some(&calm.island_in_run[..]),
            (Some(_), _) => Some(&ws.live_in_run[..]),
            (None, _) => None,
        };
        let positions = trace::span("tick positions");
        self.exec
            .for_each_chunk(&mut ws.xt, &ws.vertex_runs, &|k, run| {
                let live = live_in_run.map(|l| &l[k][..]);
                each_in_run(live, run.len(), |j| {
                    run[j] = Self::pos_at(w, k * VERTEX_RUN + j, t);
                });
            });
        drop(positions);
        let (exec, bounds, xt) = (&self.exec, &ws.bounds, &ws.xt);
        // The elements not computed with the islands (of the partitions
        // `only` marks).
        let rest = |out: &mut [DVec3], only: Option<&[bool]>| match calm {
            None => (w.internal).evaluate(exec, bounds, xt, &w.v, out, only),
            Some(calm) => {
                let mask = (&calm.elements, false);
                (w.internal).evaluate_masked(exec, bounds, xt, &w.v, out, mask, only)
            }
        };
        match share {
            // On one memory in pieces of elements (`evaluate_in_pieces`).
            None => {
                let mask = calm.map(|calm| (&calm.elements, false));
                (w.internal).evaluate_in_pieces(exec, (xt, &w.v), &mut ws.out, mask);
            }
            Some(share) => {
                // Of each kind of partition, those whose calm elements are
                // done get the rest, the others all their elements.
                let done = &progress.elements;
                let split = |kind: &[bool]| -> (Vec<bool>, Vec<bool>) {
                    let of = |want: bool| {
                        (kind.iter().enumerate())
                            .map(|(p, &k)| k && done.get(p).copied().unwrap_or(false) == want)
                            .collect()
                    };
                    (of(true), of(false))
                };
                let run = |out: &mut [DVec3], (rest_of, whole): &(Vec<bool>, Vec<bool>)| {
                    (w.internal).evaluate(exec, bounds, xt, &w.v, out, Some(whole));
                    if calm.is_some() {
                        rest(out, Some(rest_of));
                    }
                };
                run(&mut ws.out, &split(&share.boundary_partition));
                let interior = split(&share.interior_partition);
                let _site = trace::site("events: internal forces' slots");
                share.exchange_slots(exec, &mut ws.out, &mut |out| run(out, &interior))?;
            }
        }
        // One pass per run of vertices: the ordered fold of the internal
        // slots, then the islands' kicks at `t` (bucketed by run, each
        // vertex's in island order), then the new velocity, and the first
        // vertex whose new state is not finite. Over ranks each rank does
        // this for the vertices it owns, sends their new velocities to the
        // ranks that read them, and its first non-finite vertex to every
        // rank.
        let velocities = trace::span("tick velocities");
        let h = w.lattice.h_el();
        let tsec = w.lattice.seconds(t);
        let owned = |i: usize| share.is_none_or(|s| s.owns(i));
        let runs = &ws.vertex_runs;
        let at_internal = islands.iter().flat_map(|island| &island.at_internal);
        let owned_kicks = at_internal.filter(|&&(i, _)| owned(i as usize)).copied();
        bucket_by_run(&mut ws.kicks_by_run, runs, owned_kicks);
        let mut fused = FoldRun::runs(&mut ws.acc, &mut ws.v_new, runs);
        let rank = share.map(|s| &s.slots);
        let (out, xt, kicks) = (Slots { out: &ws.out, rank }, &ws.xt, &ws.kicks_by_run);
        let owned_in_run = &ws.owned_in_run;
        let tick = TickConsts { out, xt, tsec, h };
        // Over ranks, the runs whose calm folds ran while this rank waited.
        let folded = &progress.folds;
        self.exec.for_each_item(&mut fused, &|k, r| {
            let start = k * VERTEX_RUN;
            match (share, calm) {
                (None, None) => r.fold(w, &tick, start, &kicks[k], 0..r.acc.len(), false),
                (None, Some(calm)) => {
                    let rest = calm.rest_fold_in_run[k].iter().map(|&j| usize::from(j));
                    r.fold(w, &tick, start, &kicks[k], rest, false)
                }
                (Some(_), _) => {
                    let owned = owned_in_run[k].iter().map(|&j| usize::from(j));
                    let Some(&Some(calm_bad)) = folded.get(k) else {
                        return r.fold(w, &tick, start, &kicks[k], owned, true);
                    };
                    // The rest, then the first of both that blows up and
                    // the owned velocities that change before it.
                    let calm = calm.expect("calm folds come with a calm part");
                    let rest = calm.rest_fold_in_run[k].iter().map(|&j| usize::from(j));
                    r.fold(w, &tick, start, &kicks[k], rest, false);
                    r.bad = r.bad.into_iter().chain(calm_bad).min();
                    let end = r.bad.map_or(usize::MAX, |b| b - start);
                    r.changed = owned
                        .filter(|&j| j < end && r.v_new[j] != w.v[start + j])
                        .count();
                }
            }
        });
        if let Some(calm_bad) = calm_bad {
            // Each run's first vertex that blows up, of the calm ones and
            // the others.
            for (r, &calm) in fused.iter_mut().zip(calm_bad) {
                r.bad = r.bad.into_iter().chain(calm).min();
            }
        }
        let bad = fused.iter().find_map(|r| r.bad);
        // Before the first non-finite vertex only.
        let changed = (fused.iter())
            .take_while(|r| r.bad.is_none())
            .chain(fused.iter().find(|r| r.bad.is_some()))
            .map(|r| r.changed)
            .sum();
        drop(fused);
        drop(velocities);
        counts.internal_seconds += clock.elapsed().as_secs_f64();
        let (bad, recorded) = match share {
            None => (bad, None),
            Some(share) => {
                let below = |v_new: &[DVec3], b: usize| {
                    (share.owned[share.rank].iter())
                        .map(|&i| i as usize)
                        .take_while(|&i| i < b)
                        .filter(|&i| v_new[i] != w.v[i])
                        .count()
                };
                let _site = trace::site("events: new velocities");
                let (bad, changed) = share.exchange_velocities(
                    &self.exec,
                    &ws.pass_share,
                    &mut ws.v_new,
                    (bad, changed),
                    &below,
                )?;
                // The scripted vertices kept current here and owned
                // elsewhere: the chord from their position, as their owner
                // computes it (a script ignores the impulse).
                for &i in &ws.pass_share.scripted {
                    let i = i as usize;
                    ws.v_new[i] = new_velocity(w, i, ws.xt[i], DVec3::ZERO, tsec, h);
                }
                // Every vertex that changes velocity gets a breakpoint, but
                // none at the window start, where each has one already.
                let at_start = t == self.traj.start();
                (bad, Some(if at_start { 0 } else { changed }))
            }
        };
        self.apply_internal(t, bad, recorded)
    }

    /// The end of an internal batch at tick `t`, on the executor in runs of
    /// vertices: each vertex whose velocity changed takes its new velocity
    /// (`ws.v_new`) and its position at `t`, and gets a breakpoint (over
    /// ranks: each live vertex). As on one thread in vertex order, a
    /// non-finite new state stops the batch at the first such vertex, `bad`:
    /// the vertices before it are applied, it and the later ones are not.
    /// Over ranks, `recorded` is the breakpoints the tick adds over every
    /// rank (each rank stages only its live vertices').
    fn apply_internal(
        &mut self,
        t: Tick,
        bad: Option<usize>,
        recorded: Option<usize>,
    ) -> Result<(), SimError> {
        let _span = trace::span("tick states");
        let ws = &mut self.ws;
        let n = self.world.x.len();
        let xt = &ws.xt;
        let v_new = &ws.v_new;
        let bounds = &ws.vertex_runs;
        let limit = bad.unwrap_or(n);
        let live_in_run = self.share.as_ref().map(|_| &ws.live_in_run[..]);
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
            .runs(bounds, Some(t))
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
        self.exec.for_each_item(&mut apply_runs, &|k, r| {
            r.traj.prepare();
            // The run's vertices before `limit` (over ranks, the live ones).
            let end = r.x.len().min(limit.saturating_sub(r.start));
            each_in_run(live_in_run.map(|l| &l[k][..]), end, |j| {
                let i = r.start + j;
                if v_new[i] != r.v[j] {
                    r.x[j] = xt[i];
                    r.tau[j] = t;
                    r.v[j] = v_new[i];
                    r.added += usize::from(r.traj.stage(j, xt[i]));
                }
            });
        });
        let added = recorded.unwrap_or_else(|| apply_runs.iter().map(|r| r.added).sum());
        drop(apply_runs);
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

/// Calls `f` with each offset below `end` of a run of vertices, ascending:
/// every one (`listed` none: one memory), or those `listed` (over ranks: the
/// vertices the rank keeps current, [`super::Workspace`]'s `live_in_run`;
/// on one memory with islands, the island vertices or the others, the two
/// sides of [`super::Calm`]).
#[inline]
pub(super) fn each_in_run(listed: Option<&[u16]>, end: usize, mut f: impl FnMut(usize)) {
    match listed {
        None => (0..end).for_each(f),
        Some(list) => {
            for &j in list {
                let j = usize::from(j);
                if j >= end {
                    break;
                }
                f(j);
            }
        }
    }
}

/// One run of vertices of an internal tick's fused per-vertex pass: its
/// impulses and new velocities, its first vertex whose new state is not
/// finite, and (over ranks) how many before it change velocity.
struct FoldRun<'a> {
    acc: &'a mut [DVec3],
    v_new: &'a mut [DVec3],
    bad: Option<usize>,
    /// Owned vertices before `bad` whose velocity changes.
    changed: usize,
}

/// What every run of an internal tick reads: the internal forces' output
/// slots, the positions at the tick, its time and the step.
struct TickConsts<'a> {
    out: Slots<'a>,
    xt: &'a [DVec3],
    tsec: f64,
    h: f64,
}

/// The fused per-vertex pass at tick `t` over the vertices `listed` in each
/// run of vertices (offsets; the runs cut at `runs`) that no island kicks:
/// the calm part of an internal tick ([`super::Calm`]). Returns each run's
/// first listed vertex that blows up.
pub(super) fn fold_listed<E: Executor>(
    exec: &E,
    w: &World,
    (out, xt): (Slots<'_>, &[DVec3]),
    t: Tick,
    (listed, runs): (&[Vec<u16>], &[usize]),
    (acc, v_new): (&mut [DVec3], &mut [DVec3]),
) -> Vec<Option<usize>> {
    let mut fused = FoldRun::runs(acc, v_new, runs);
    exec.for_each_item(&mut fused, &|k, r| {
        let run = (&mut *r.acc, &mut *r.v_new);
        r.bad = fold_run_listed(w, (out, xt), t, (k * VERTEX_RUN, &listed[k]), run);
    });
    fused.iter().map(|r| r.bad).collect()
}

/// The fused per-vertex pass at tick `t` over the vertices at the offsets
/// `listed` of the run of vertices from `start` (`acc` and `v_new` that
/// run's), that no island kicks: a run's calm folds (each run's, through
/// [`fold_listed`], on one memory; over ranks, one run per piece while the
/// rank waits). Returns its first listed vertex that blows up.
pub(super) fn fold_run_listed(
    w: &World,
    (out, xt): (Slots<'_>, &[DVec3]),
    t: Tick,
    (start, listed): (usize, &[u16]),
    (acc, v_new): (&mut [DVec3], &mut [DVec3]),
) -> Option<usize> {
    let (h, tsec) = (w.lattice.h_el(), w.lattice.seconds(t));
    let tick = TickConsts { out, xt, tsec, h };
    let mut run = FoldRun {
        acc,
        v_new,
        bad: None,
        changed: 0,
    };
    let js = listed.iter().map(|&j| usize::from(j));
    run.fold(w, &tick, start, &[], js, false);
    run.bad
}

impl<'a> FoldRun<'a> {
    /// One per run of vertices (cut at `runs`) over the impulses `acc` and
    /// new velocities `v_new`.
    fn runs(acc: &'a mut [DVec3], v_new: &'a mut [DVec3], runs: &[usize]) -> Vec<Self> {
        let mut v_runs = split_chunks(v_new, runs).into_iter();
        (split_chunks(acc, runs).into_iter())
            .map(|(_, acc)| FoldRun {
                acc,
                v_new: v_runs.next().expect("one per run").1,
                bad: None,
                changed: 0,
            })
            .collect()
    }

    /// The fused pass over the run's vertices at the offsets `js`
    /// (ascending; every vertex of the run on one memory, the owned ones
    /// over ranks) from vertex `start`: the ordered fold of the internal
    /// slots, then the islands' `kicks` (in fold order), the new velocity,
    /// the first vertex that blows up, and with `count` the velocities that
    /// change before it.
    #[inline]
    fn fold(
        &mut self,
        w: &World,
        tick: &TickConsts<'_>,
        start: usize,
        kicks: &[(u32, DVec3)],
        js: impl Iterator<Item = usize> + Clone,
        count: bool,
    ) {
        for j in js.clone() {
            let i = start + j;
            if w.inv_mass[i] > 0.0 {
                let g = tick.out.fold(&w.internal, i) - w.gravity * w.mass[i];
                self.acc[j] = g * -tick.h;
            }
        }
        for &(j, impulse) in kicks {
            self.acc[j as usize] += impulse;
        }
        for j in js.clone() {
            let i = start + j;
            self.v_new[j] = new_velocity(w, i, tick.xt[i], self.acc[j], tick.tsec, tick.h);
        }
        self.bad = (js.clone())
            .find(|&j| blows_up(w, start + j, tick.xt, self.v_new[j]))
            .map(|j| start + j);
        if count {
            let end = self.bad.map_or(usize::MAX, |b| b - start);
            self.changed = js
                .filter(|&j| j < end && self.v_new[j] != w.v[start + j])
                .count();
        }
    }
}

/// Whether vertex `i` changes velocity to `v_new` at this internal tick with
/// a non-finite state (its position there `xt[i]`, or `v_new`).
#[inline]
fn blows_up(w: &World, i: usize, xt: &[DVec3], v_new: DVec3) -> bool {
    v_new != w.v[i] && !(xt[i].is_finite() && v_new.is_finite())
}

/// Vertex `i`'s velocity after the internal batch at `tsec` in which it
/// received the impulse `impulse` (internal forces, then normal and clamped
/// friction kicks); `x` is its position at the batch. A scripted vertex
/// follows the chord of its script.
pub(super) fn new_velocity(
    w: &World,
    i: usize,
    x: DVec3,
    impulse: DVec3,
    tsec: f64,
    h: f64,
) -> DVec3 {
    match w.script_of[i] {
        Some((s, k)) => w.scripts[s as usize].chord_velocity(k as usize, x, tsec, h),
        None => w.v[i] + impulse * w.inv_mass[i],
    }
}
