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
        tested_on: &[u32],
        predicted: &Predicted,
    ) -> Result<(u64, u64), CommError> {
        const TASK: usize = 64;
        // (the map's entries by reference: 16 bytes a stencil, where a copy
        // took 28 at a rank's memory peak)
        let entries: Vec<(&StencilKey, &LayerState)> = self.world.layers.stencils.iter().collect();
        // Each stencil's new state depends on its own certificates only, so
        // the stencils are decided on the executor and applied in key order.
        // Tasks are runs of entries, each decided on one rank
        // (`deciding_ranks`; on one memory all on rank 0). Only the stencils
        // among the candidates are certified again, so only their polylines
        // are read: over ranks each is decided where the narrow phase
        // tested it (`tested_on`), which holds them, fetched or computed
        // for the pass and kept for the commit (`Trajectories::keep_fetched`),
        // so nothing travels, and the narrow phase's balance of the same
        // certificates holds for them too.
        let ranks = self.exec.ranks();
        let holders = self.traj.holders();
        // Per entry, its index among the candidates (both in key order: one
        // merge walk).
        debug_assert!(candidates.windows(2).all(|p| p[0] < p[1]));
        let mut rest = candidates.iter().enumerate().peekable();
        let candidate: Vec<Option<u32>> = (entries.iter())
            .map(|&(key, _)| {
                while rest.next_if(|c| c.1 < key).is_some() {}
                rest.peek().filter(|c| c.1 == key).map(|c| c.0 as u32)
            })
            .collect();
        let near: Vec<bool> = candidate.iter().map(Option::is_some).collect();
        let keys: Vec<&StencilKey> = entries.iter().map(|&(k, _)| k).collect();
        let by_rank = deciding_ranks(&keys, &candidate, tested_on, holders, ranks);
        let mut runs: Vec<&[usize]> = Vec::new();
        let mut owner: Vec<u32> = Vec::new();
        for (r, mine) in by_rank.iter().enumerate() {
            for run in mine.chunks(TASK) {
                runs.push(run);
                owner.push(r as u32);
            }
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
                    let (&key, &(mut s)) = entries[n];
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
            entries.iter().map(|&(_, &s)| (s, 0, 0)).collect();
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

/// The entries (stencil keys, in key order) each rank decides. A candidate
/// (`candidate[n]`, its index among the pass's candidates) goes to the rank
/// whose narrow-phase task tested it (`tested_on`), where its vertices'
/// polylines are; any other entry, which reads none, to the rank holding
/// its first vertex's breakpoints. On one rank (`tested_on` empty) all go
/// to rank 0. The same on every rank: it reads only the keys, the
/// candidates' ranks and the holders.
fn deciding_ranks(
    keys: &[&StencilKey],
    candidate: &[Option<u32>],
    tested_on: &[u32],
    holders: &[u32],
    ranks: usize,
) -> Vec<Vec<usize>> {
    let mut by_rank: Vec<Vec<usize>> = vec![Vec::new(); ranks.max(1)];
    for (n, (key, c)) in keys.iter().zip(candidate).enumerate() {
        let r = match (ranks, c) {
            (0 | 1, _) => 0,
            (_, Some(c)) => tested_on[*c as usize] as usize,
            (_, None) => holders[key.v[0] as usize] as usize,
        };
        by_rank[r].push(n);
    }
    by_rank
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_are_decided_where_the_narrow_phase_tested_them() {
        // Vertices 0..8 on rank 0, 8..16 on rank 1, 16..24 on rank 2.
        let holders: Vec<u32> = (0..24).map(|v| v / 8).collect();
        let keys: Vec<StencilKey> = vec![
            StencilKey::vertex_face(0, [1, 2, 3]), // candidate 0, tested on 2
            StencilKey::vertex_face(1, [9, 10, 11]), // not a candidate
            StencilKey::vertex_face(8, [16, 17, 18]), // candidate 1, tested on 0
            StencilKey::vertex_face(17, [4, 5, 6]), // not a candidate
            StencilKey::vertex_face(20, [21, 22, 9]), // candidate 2, tested on 2
        ];
        let candidate = [Some(0), None, Some(1), None, Some(2)];
        let tested_on = [2, 0, 2];
        let refs: Vec<&StencilKey> = keys.iter().collect();
        let by_rank = deciding_ranks(&refs, &candidate, &tested_on, &holders, 3);
        assert_eq!(by_rank, vec![vec![1, 2], vec![], vec![0, 3, 4]]);
        // Every entry once, in key order on each rank.
        let mut all = by_rank.concat();
        all.sort_unstable();
        assert_eq!(all, (0..keys.len()).collect::<Vec<_>>());
        // One rank decides all.
        let one = deciding_ranks(&refs, &candidate, &[], &holders, 1);
        assert_eq!(one, vec![(0..keys.len()).collect::<Vec<_>>()]);
    }
}
