//! Predictive activation: layers given before a window runs, to the
//! stencils its motion is about to bring into them, so that the detection
//! does not have to ask for them with a rollback.
//!
//! Why it is free to guess: a layer kicks only inside its `eta_l`, and a
//! zero kick leaves no trace, so an active layer that is never reached
//! changes nothing. A committed window keeps every stencil outside its first
//! inactive layer, so its trajectory is that of "every layer always active",
//! whichever layers were active (policy independence, `acm-spec.md` §4; held
//! by `weft-par/tests/policy.rs`). A wrong guess costs a layer that sleeps
//! until it retires (little since sleep certificates outlive internal
//! ticks, `crate::dormancy`, but not nothing: it joins islands, and is read
//! again whenever one of its vertices outruns its speed cap); a missed one
//! costs what it costs without prediction, a rollback. On by default
//! (`contact.predict`): over whole runs of the bundled scenes it costs at
//! most a few per cent and saves up to a third of a window's time;
//! `docs/performance.md`, "Fewer passes", has where it pays and where not.
//!
//! **Inactive stencils** (new contacts). From the state at the window start,
//!
//! ```text
//! x_i(t) = x_i + v_i t + clamp(a_i t²/2, eta_1)   a_i = (f_internal,i + m_i g) / m_i
//! x_i(t) = P_i(T0 + t)                             a scripted vertex: its script
//! ```
//!
//! sampled every half window up to [`HORIZON_HALF_WINDOWS`] half windows
//! (`a_i = 0` for a vertex of a stencil inside `eta_1` now: contact forces,
//! left out here, hold it). The broad phase over the sampled polylines finds
//! the stencils that may come near; one whose distance at a sample is inside
//! [`NEW_CONTACT_MARGIN`] `eta_1` ([`CLOSING_CONTACT_MARGIN`] when it closes
//! at the window start already) gets layers as a detection would give them
//! ([`layers_to_hold`]). The acceleration's displacement is clamped to
//! `eta_1`: a larger one comes from stiff elastic modes that oscillate many
//! times within a window instead of carrying the vertex along (unclamped,
//! `crumple`'s wavy start predicted 7,125 contacts at window 0; none was
//! real).
//!
//! **Active stencils** (deeper layers). Their layers push back, so the
//! extrapolated motion is no guide (it deepened `crumple`'s stencils by
//! 5 layers a window, to depth 60); they get more layers when they rest
//! inside their layers within [`RESTING_MARGIN`] of the next one, or when
//! their closing kinetic energy exceeds what their active layers store on
//! the way to it ([`reaches_next_layer`]).
//!
//! **How many layers.** A predicted or detected stencil gets at least
//! `layers_per_detection` layers, and as many more as its closing kinetic
//! energy at the window start (twice the stencil's own,
//! [`CLOSING_ENERGY_FACTOR`]) needs to be stored before the next inactive
//! layer ([`layers_to_hold`]): a fast impact gets its layers at once instead
//! of 5 per rollback.
//!
//! Measured on `crumple` (`docs/performance.md`, "Fewer passes": what the
//! rollbacks that prediction missed were): new contacts hovering just
//! outside `eta_1` (at 1.00–1.3 `eta_1` at the window start, predicted just
//! outside it), resting contacts inside their deepest layer that sank one
//! layer deeper, and fast impacts that took 5 layers per rollback, up to
//! four rollbacks a window. The margin and the energy count took its
//! rollbacks from 73 to 52, and the 10k twister's from 2 in 3 windows to
//! none; the resting margin took `crumple`'s on to 35, twice the closing
//! energy to 31, and the wider margin for contacts already closing to 27.
//!
//! Predicted layers retire like any other, after `retire_after_windows` calm
//! windows. Measured on the 10k twister from its checkpoint: every stencil a
//! rollback reported was a new contact of sleeve and rod, just outside
//! `eta_1` and closing faster than its start velocity says: the cloth
//! accelerates onto the turning rod. Velocity alone foresaw the rollbacks of
//! no window; with the acceleration and the rod's script over one and a half
//! windows, 5 of 6 windows ran without one. Dropping a predicted layer at
//! once when it was not reached (instead of letting it retire) brought a
//! rollback back into every window: the stencils that hover near the rod
//! need the memory the retirement hysteresis gives.

use glam::DVec3;
use weft_core::StencilKey;
use weft_geom::distance::{stencil_closest, Closest};

use super::Engine;
use crate::executor::{CommError, Executor};
use crate::trace;
use crate::trajectory::Trajectories;

/// How far ahead the motion is sampled, in half windows.
const HORIZON_HALF_WINDOWS: u64 = 3;

/// A new contact is predicted when its sampled distance comes within this
/// many `eta_1`: the extrapolation is rough, and contacts hovering just
/// outside `eta_1` dip into it between samples. Measured (with the energy
/// count of [`layers_to_hold`]): from 1 to 1.25 the 10k twister's
/// rollbacks went from 2 in 3 windows to none, `crumple`'s from 69 to 52,
/// and the bundled twister from 1.0 s to 1.6 s from 43 to 5 in 0.88× the
/// time. A wider margin costs more than it saves: every stencil hovering
/// within it is active, asleep or not (its islands, its sleep and wake
/// bookkeeping); at 2 the bundled twister held twice the active stencils
/// and took 1.12× the time, at 1.5 0.98×, for no fewer rollbacks. Measured
/// again with the resting margin and twice the closing energy: at 1.5
/// `crumple` took 27 rollbacks instead of 31, but the bundled twister's
/// whole run 1.07× the time.
const NEW_CONTACT_MARGIN: f64 = 1.25;

/// The margin for a new contact that already closes at the window start
/// (its closing energy is positive, [`closing_energy`]): such a stencil
/// keeps coming, and in `crumple`'s collapsing heap it arrived within the
/// window from beyond 1.25 `eta_1`. Stencils that hover without closing
/// (the twister's sleeve beside the rod) keep [`NEW_CONTACT_MARGIN`], which
/// a wider margin for every stencil made cost 1.07× the bundled twister's
/// time. Measured with 2 (pairs at the same time, one thread, the same
/// frames): `crumple` 31 → 27 rollbacks in 0.99× the time, `drape` 46 → 31
/// in 0.97×, `bowline` `size=500` 265 → 176 in 0.94×, `reef-knot`
/// `size=400` 209 → 180 in 0.99×, `two-cloths` to 1 s 49 → 35 in 0.97×,
/// the bundled twister 45 → 45 in 1.00×; at 1.5 `crumple` took 28.
const CLOSING_CONTACT_MARGIN: f64 = 2.0;

/// The predictor's memory, reused across windows.
#[derive(Debug)]
pub(super) struct Predictor {
    /// The sampled predicted motions the broad phase reads.
    traj: Trajectories,
    /// Per vertex: its predicted acceleration.
    acc: Vec<DVec3>,
    /// Per vertex: of a stencil resting inside its layers now (no
    /// acceleration).
    at_rest: Vec<bool>,
}

impl Predictor {
    /// Over ranks: from now on each vertex's samples are kept by the rank
    /// `holder` gives it (the partitions placed again).
    pub(super) fn hold_only(&mut self, holder: Vec<u32>, me: u32) {
        self.traj.hold_only(holder, me);
    }

    /// For `n` vertices; over ranks each vertex's samples are kept by the
    /// rank `holder` gives it, as for the window's trajectories.
    pub fn new(n: usize, holder: Option<(Vec<u32>, u32)>) -> Self {
        let traj = match holder {
            Some((holder, me)) => Trajectories::held_by(holder, me, usize::MAX),
            None => Trajectories::new(n, usize::MAX),
        };
        Self {
            traj,
            acc: Vec::new(),
            at_rest: Vec::new(),
        }
    }
}

/// `a`, shortened to at most `max` long.
fn clamp_length(a: DVec3, max: f64) -> DVec3 {
    let len = a.length();
    if len > max {
        a * (max / len)
    } else {
        a
    }
}

/// An active stencil resting inside its layers (`d < eta_1`) within this
/// factor of its first inactive layer, `d < RESTING_MARGIN eta_next`, gets
/// more layers before the window. Measured on `crumple`, where the heap
/// presses its resting contacts deeper as it grows (every rollback's
/// stencils logged, build `5c811ef`): 40 of its 52 rollbacks reported such
/// stencils, 70 % of them within 1.05 `eta_next`. Rollbacks by margin: 1.02
/// → 48, 1.05 → 45, **1.1 → 35**, 1.2 → 33, 1.4 → 32. Since the layers
/// crowd together at depth (`eta_(l+1) / eta_l ≈ 1 - 1/(4l)`), a wider
/// margin hands a deep stencil many layers it never reaches: at 1.2 the
/// bundled twister's first second took 1.23× the time (its sleeve gripping
/// the rod went from depth 7 to 12), at 1.1 the same time.
const RESTING_MARGIN: f64 = 1.1;

/// The closing kinetic energy the energy count reckons with, as a multiple
/// of the stencil's own (`m min(0, d')² / 2`, with the stencil's effective
/// mass): the cloth around its vertices pushes on, and it speeds up within
/// the window. Measured on `crumple` (with the resting margin; one thread,
/// rollbacks and wall, pairs run at the same time): 1 → 35 rollbacks in
/// 8.30 s, **2 → 31 in 8.18 s**, 4 → 30 in 8.35 s, 8 → 28 in 8.63 s; at 4
/// `drape` took 1.05× the time of 2 (its impacts got layers they never
/// reached), at 2 no bundled scene changed by more than 1.6 %.
const CLOSING_ENERGY_FACTOR: f64 = 2.0;

/// The closest points of `key`'s primitives at the state now (the window
/// start): what every decision of the predictor and the energy count
/// start from, computed once per decision.
pub(super) fn closest_now(w: &crate::world::World, key: &StencilKey) -> Closest {
    stencil_closest(key.kind, &key.v.map(|i| w.x[i as usize]))
}

/// The closing kinetic energy the energy count reckons with, of `key` at
/// its closest points `c`: along the normal, with `d' = Σ_j c_j n·v_j` and
/// the effective mass `m = 1 / Σ_j c_j² w_j` (dynamic vertices only),
/// `F m min(0, d')² / 2` with `F` = [`CLOSING_ENERGY_FACTOR`]; `None` when
/// no vertex is dynamic.
fn closing_energy(w: &crate::world::World, key: &StencilKey, c: &Closest) -> Option<f64> {
    let (mut rate, mut m_inv) = (0.0, 0.0);
    for j in 0..4 {
        let i = key.v[j] as usize;
        rate += c.coeff[j] * c.n.dot(w.v[i]);
        m_inv += c.coeff[j] * c.coeff[j] * w.inv_mass[i];
    }
    (m_inv > 0.0).then(|| CLOSING_ENERGY_FACTOR * 0.5 * rate.min(0.0) * rate.min(0.0) / m_inv)
}

/// Whether an active stencil (depth ≥ 1) may reach its first inactive
/// layer `eta_next`: it rests inside its layers within [`RESTING_MARGIN`]
/// of it, or its closing kinetic energy exceeds the energy its active
/// layers store between its distance now and `eta_next`. The extrapolated
/// motion is no guide here, since the active layers push back; measured on
/// `crumple`, extrapolating through them deepened stencils without end.
///
/// Along the normal, with `d' = Σ_j c_j n·v_j` and the effective mass
/// `m = 1 / Σ_j c_j² w_j` (dynamic vertices only):
///
/// ```text
/// d < eta_1  and  d < RESTING_MARGIN eta_next,   or
/// F m min(0, d')² / 2  >  Σ_l≤depth V_l(eta_next) - V_l(d)      (F = CLOSING_ENERGY_FACTOR)
/// ```
fn reaches_next_layer(
    w: &crate::world::World,
    key: &StencilKey,
    c: &Closest,
    depth: u32,
    eta_next: f64,
) -> bool {
    if !(c.d > eta_next) || (c.d < w.schedule.eta_1 && c.d < RESTING_MARGIN * eta_next) {
        return true;
    }
    let Some(closing) = closing_energy(w, key, c) else {
        return false;
    };
    let barrier =
        w.schedule.energy_through(depth, eta_next) - w.schedule.energy_through(depth, c.d);
    closing > barrier
}

/// How many layers a stencil of depth `depth` gets when it is predicted or
/// detected: at least `min` (`layers_per_detection`), and as many more as
/// its closing kinetic energy needs, as in [`reaches_next_layer`]: the
/// smallest `D - depth` with
///
/// ```text
/// F m min(0, d')² / 2  ≤  Σ_l≤D V_l(eta_(D+1)) - V_l(d)     (d < eta_(D+1) counts as not enough)
/// ```
///
/// at most `resolved - depth`, with `F` = [`CLOSING_ENERGY_FACTOR`] for the
/// energy the cloth around brings; the detection still asks for more when
/// it does not hold. `c`: the stencil's closest points now
/// ([`closest_now`]).
pub(super) fn layers_to_hold(
    w: &crate::world::World,
    key: &StencilKey,
    c: &Closest,
    depth: u32,
    min: u32,
    resolved: u32,
) -> u32 {
    let room = resolved.saturating_sub(depth);
    let Some(closing) = closing_energy(w, key, c) else {
        return min.min(room);
    };
    // Whether `deep` layers hold it. Monotone in `deep` (a deeper next
    // layer, and more layers each storing more on the way to it); each test
    // sums `deep` energies.
    let holds = |deep: u32| {
        let eta_next = w.schedule.eta(deep + 1);
        c.d > eta_next
            && closing
                <= w.schedule.energy_through(deep, eta_next) - w.schedule.energy_through(deep, c.d)
    };
    let first = depth.saturating_add(min).min(resolved);
    smallest_holding(first, resolved, holds) - depth
}

/// The smallest `deep` in `first..resolved` for which the monotone `holds`
/// is true, `resolved` when none is (`first` itself when `first ≥
/// resolved`). A fast impact may need thousands of the resolved layers, but
/// most answers lie a few layers past `first`: the search gallops out from
/// `first` (steps 1, 2, 4, …) and then bisects, so it tests about
/// `2 log2(answer - first)` depths. Bisecting all of `(first, resolved]`
/// instead, the same answers, cost `crumple` a third of its run in `pow`
/// (each test sums `deep` layer energies).
fn smallest_holding(first: u32, resolved: u32, holds: impl Fn(u32) -> bool) -> u32 {
    if first >= resolved || holds(first) {
        return first;
    }
    // holds(lo) is false; the answer is in (lo, hi].
    let (mut lo, mut step) = (first, 1u32);
    let mut hi = loop {
        let probe = lo.saturating_add(step);
        if probe >= resolved {
            break resolved;
        }
        if holds(probe) {
            break probe;
        }
        lo = probe;
        step = step.saturating_mul(2);
    };
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if holds(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// The stencils the predictor deepened before a window, in key order: each
/// with its depth before and the layers it got; and the layers in all.
#[derive(Clone, Debug, Default)]
pub(super) struct Predicted {
    pub stencils: Vec<(StencilKey, u32, u32)>,
    pub layers: u64,
}

impl Predicted {
    /// `key`'s depth before the prediction and the layers the prediction
    /// gave it, if it was predicted.
    pub fn of(&self, key: &StencilKey) -> Option<(u32, u32)> {
        let n = self.stencils.binary_search_by(|(k, ..)| k.cmp(key)).ok()?;
        let (_, before, added) = self.stencils[n];
        Some((before, added))
    }
}

impl<E: Executor> Engine<E> {
    /// The predictor, made unless it is there: a run without prediction
    /// keeps no memory for it.
    pub(super) fn make_predictor(&mut self) {
        let n = self.world.num_vertices();
        let share = &self.share;
        self.predictor.get_or_insert_with(|| {
            Predictor::new(n, share.as_ref().map(|s| (s.owner.clone(), s.rank as u32)))
        });
    }

    /// Activates the predicted layers at the window start (every vertex is
    /// synchronized at `world.tick`). The same on every rank: the broad
    /// phase gives every rank every candidate, and the decisions read only
    /// positions, velocities, scripts and the layer set, which every rank
    /// has in full, and the accelerations, which every rank gets from the
    /// vertices' owners; each decision is made on one rank and gathered.
    pub(super) fn predict_layers(&mut self, resolved: u32) -> Result<Predicted, CommError> {
        let _span = trace::span("predict");
        self.make_predictor();
        let predictor = self.predictor.as_mut().expect("made above");
        let w = &self.world;
        let exec = &self.exec;
        // Accelerations from the internal forces and gravity (no contact:
        // the penalty forces only ever push apart). Over ranks each vertex's
        // is computed by its owner, from its partitions' slots and the
        // boundary slots its neighbours send (as at an internal tick), and
        // every rank gets every one with its exact bits.
        let forces = trace::span("predict forces");
        let (bounds, out) = self.ws.internal_scratch();
        match &self.share {
            None => (w.internal).evaluate_in_pieces(exec, (&w.x, &w.v), out, None),
            Some(share) => {
                let boundary = Some(&share.boundary_partition[..]);
                w.internal.evaluate(exec, bounds, &w.x, &w.v, out, boundary);
                share.exchange_slots(exec, out, &mut |out| {
                    let interior = Some(&share.interior_partition[..]);
                    w.internal.evaluate(exec, bounds, &w.x, &w.v, out, interior);
                })?;
            }
        }
        // A vertex of a stencil inside its layers now is held by contact
        // forces this leaves out (a cloth resting on a sphere would be
        // predicted to fall into it): it moves on with its velocity only.
        // Each active stencil is tested on one rank (round robin).
        let active: Vec<&StencilKey> = w.layers.stencils.keys().collect();
        let ranks = exec.ranks() as u32;
        let round_robin = |n: usize| -> Vec<u32> { (0..n as u32).map(|k| k % ranks).collect() };
        let resting = exec.map_on_ranks(active.len(), &round_robin(active.len()), &|n| {
            closest_now(w, active[n]).d < w.schedule.eta_1
        })?;
        let at_rest = &mut predictor.at_rest;
        at_rest.clear();
        at_rest.resize(w.x.len(), false);
        for (key, _) in active.iter().zip(&resting).filter(|(_, &r)| r) {
            key.v.iter().for_each(|&i| at_rest[i as usize] = true);
        }
        let at_rest: &[bool] = at_rest;
        let out: &[DVec3] = out;
        // (Over ranks an owned vertex's slots are at the rank's places.)
        let rank = self.share.as_ref().map(|s| &s.slots);
        let slots = crate::share::Slots { out, rank };
        let acc_of = |i: usize| match w.inv_mass[i] > 0.0 && !at_rest[i] {
            true => (slots.fold(&w.internal, i) - w.gravity * w.mass[i]) * -w.inv_mass[i],
            false => DVec3::ZERO,
        };
        let acc = &mut predictor.acc;
        match &self.share {
            None => {
                acc.clear();
                acc.extend((0..w.x.len()).map(acc_of));
            }
            Some(share) => *acc = exec.map_on_ranks(w.x.len(), &share.owner, &acc_of)?,
        }
        let acc: &[DVec3] = acc;
        drop(forces);
        let samples = trace::span("predict samples");
        let half = w.lattice.window() / 2;
        let now = w.time();
        let reach = w.schedule.eta_1;
        // Where vertex `i` is predicted `k` half windows ahead.
        let ahead = |i: usize, k: u64| -> DVec3 {
            let t = w.lattice.seconds(half * k);
            match w.script_of[i] {
                Some((s, j)) => w.scripts[s as usize].position(j as usize, now + t),
                None => w.x[i] + w.v[i] * t + clamp_length(acc[i] * (0.5 * t * t), reach),
            }
        };
        let traj = &mut predictor.traj;
        traj.begin(w.tick, &w.x);
        // Over ranks a vertex's samples are kept (and read by the broad
        // phase) on its holder only.
        for i in 0..w.x.len() {
            if !traj.holds(i) {
                continue;
            }
            for k in 1..=HORIZON_HALF_WINDOWS {
                traj.record(i, w.tick + half * k, ahead(i, k))
                    .expect("the predicted motions have no budget");
            }
        }
        drop(samples);
        let keys = self.broad.candidates_on(
            &self.exec,
            &w.triangles,
            &w.inv_mass,
            &predictor.traj,
            0.5 * w.schedule.eta_1,
        )?;
        // Over ranks each candidate is decided on one rank (round robin:
        // neighbouring keys cost alike), with the layers it gets (the
        // energy count reads the state only, not the layers the others get),
        // and every rank gets every answer.
        let extra = w.contact.layers_per_detection;
        let _decide = trace::span("predict decide");
        // (over ranks only the depths of this rank's keys, every `ranks`-th:
        // a merge walk over every key was work each rank repeated)
        let stride = ranks as usize;
        let me = exec.rank();
        let depths = match stride {
            1 => w.layers.depths_of(&keys),
            _ => {
                let mine: Vec<StencilKey> = keys.iter().skip(me).step_by(stride).copied().collect();
                w.layers.depths_of(&mine)
            }
        };
        let decided: Vec<Option<(u32, u32)>> =
            exec.map_on_ranks(keys.len(), &round_robin(keys.len()), &|n| {
                let key = &keys[n];
                debug_assert_eq!(n % stride, me, "round robin");
                let depth = depths[n / stride];
                let eta_next = w.schedule.eta(depth + 1);
                if depth >= resolved {
                    return None;
                }
                let c = closest_now(w, key);
                let deeper = if depth > 0 {
                    reaches_next_layer(w, key, &c, depth, eta_next)
                } else {
                    let closing = closing_energy(w, key, &c).is_some_and(|e| e > 0.0);
                    let margin = match closing {
                        true => CLOSING_CONTACT_MARGIN,
                        false => NEW_CONTACT_MARGIN,
                    };
                    (1..=HORIZON_HALF_WINDOWS).any(|k| {
                        let x = key.v.map(|i| ahead(i as usize, k));
                        stencil_closest(key.kind, &x).d < margin * eta_next
                    })
                };
                deeper.then(|| (depth, layers_to_hold(w, key, &c, depth, extra, resolved)))
            })?;
        let mut predicted = Predicted::default();
        for (key, decided) in keys.iter().zip(decided) {
            if let Some((before, added)) = decided {
                self.world.layers.deepen(*key, added);
                predicted.stencils.push((*key, before, added));
                predicted.layers += added as u64;
            }
        }
        Ok(predicted)
    }
}

#[cfg(test)]
mod tests {
    use super::smallest_holding;
    use std::cell::Cell;

    /// Against a linear scan, for every threshold (the first depth that
    /// holds) around and beyond the range, and with few tests.
    #[test]
    fn the_galloping_search_finds_the_smallest_depth_that_holds() {
        for first in [0u32, 1, 5, 17] {
            for resolved in [0u32, 1, 6, 18, 40, 1000, 10_321] {
                for threshold in (0..=resolved + 3).filter(|t| *t < 60 || t % 97 == 0) {
                    let tests = Cell::new(0u32);
                    let holds = |deep: u32| {
                        tests.set(tests.get() + 1);
                        deep >= threshold
                    };
                    let scan = (first..resolved)
                        .find(|&d| d >= threshold)
                        .unwrap_or(resolved.max(first));
                    let found = smallest_holding(first, resolved, holds);
                    assert_eq!(
                        found, scan,
                        "first {first} resolved {resolved} threshold {threshold}"
                    );
                    let span = (found.saturating_sub(first) + 2) as f64;
                    assert!(
                        tests.get() as f64 <= 2.0 * span.log2() + 3.0,
                        "{} tests for an answer {} past the first",
                        tests.get(),
                        found - first.min(found)
                    );
                }
            }
        }
    }
}
