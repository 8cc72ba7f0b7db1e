//! The commit of a window: retiring calm innermost layers (`acm-spec.md`
//! §4, "Retiring layers").

use weft_core::StencilKey;
use weft_geom::ccd::{proximity, CcdStats};

use super::predict::Predicted;
use super::Engine;
use crate::executor::{CommError, Executor};
use crate::layers::LayerState;
use crate::trace;

impl<E: Executor> Engine<E> {
    /// Retires calm innermost layers; returns how many were retired, and how
    /// many of the `predicted` layers were never reached (their stencil
    /// certified to stay outside its first predicted layer over the window).
    ///
    /// A stencil is calm in a window when it is certified to stay farther than
    /// `eta_depth` over the whole window, T1 included (by the narrow phase, or
    /// because its DOPs are apart: farther than `eta_1`). After
    /// `retire_after_windows` calm windows in a row its innermost layer is
    /// retired, then the next innermost as long as it is certified too — the
    /// active set stays a prefix `1..=depth` — and the counter restarts.
    pub(super) fn commit(
        &mut self,
        candidates: &[StencilKey],
        predicted: &Predicted,
    ) -> Result<(u64, u64), CommError> {
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
        // Both in key order: one merge walk.
        debug_assert!(candidates.windows(2).all(|p| p[0] < p[1]));
        let mut rest = candidates.iter().peekable();
        let near: Vec<bool> = (entries.iter())
            .map(|(key, _)| {
                while rest.next_if(|c| *c < key).is_some() {}
                rest.peek() == Some(&key)
            })
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
            let states: Vec<(LayerState, u64, u64)> = runs[t]
                .iter()
                .map(|&n| {
                    let (key, mut s) = entries[n];
                    let tr = near[n].then(|| key.v.map(|i| traj.of(i as usize)));
                    let mut certified_outside = |eta: f64| -> bool {
                        tr.as_ref()
                            .is_none_or(|tr| !proximity(key.kind, tr, eta, &mut ccd))
                    };
                    // Predicted layers never reached: the stencil stayed
                    // outside its first predicted layer (statistics only).
                    let unreached = predicted.of(&key).map_or(0, |(before, added)| {
                        let outside = certified_outside(w.schedule.eta(before + 1));
                        u64::from(outside) * added as u64
                    });
                    if !certified_outside(w.schedule.eta(s.depth)) {
                        s.calm_windows = 0;
                        return (s, 0, unreached);
                    }
                    s.calm_windows += 1;
                    if s.calm_windows < hysteresis {
                        return (s, 0, unreached);
                    }
                    s.calm_windows = 0;
                    s.depth -= 1;
                    let mut retired = 1;
                    while s.depth > 0 && certified_outside(w.schedule.eta(s.depth)) {
                        s.depth -= 1;
                        retired += 1;
                    }
                    (s, retired, unreached)
                })
                .collect();
            (states, ccd)
        })?;
        let (mut retired, mut unreached) = (0, 0);
        // (every entry is in exactly one run: each slot is overwritten)
        let mut decided_states: Vec<(LayerState, u64, u64)> =
            entries.iter().map(|&(_, s)| (s, 0, 0)).collect();
        for ((states, ccd), run) in decided.into_iter().zip(&runs) {
            self.ccd.merge(&ccd);
            for (state, &n) in states.into_iter().zip(*run) {
                decided_states[n] = state;
            }
        }
        // `entries` are the map's entries in its own order, and nothing
        // changed the map since: update each in place and drop the retired
        // (one walk, instead of a search per stencil on every rank).
        let layers = &mut self.world.layers.stencils;
        debug_assert_eq!(layers.len(), decided_states.len());
        for (state, (s, r, u)) in layers.values_mut().zip(decided_states) {
            retired += r;
            unreached += u;
            *state = s;
        }
        layers.retain(|_, s| s.depth > 0);
        Ok((retired, unreached))
    }
}
