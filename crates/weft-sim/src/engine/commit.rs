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
        // Tasks are runs of entries; each stencil is decided on a rank that
        // holds one of its vertices' breakpoints (`deciding_ranks`; on one
        // memory every vertex is held by rank 0). Only the stencils among
        // the candidates are certified again, so only their polylines are
        // read — over ranks, fetched when held elsewhere.
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
        let keys: Vec<&StencilKey> = entries.iter().map(|(k, _)| k).collect();
        let by_rank = deciding_ranks(&keys, &near, holders, ranks);
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

/// The entries (stencil keys, in key order) each rank decides: a stencil
/// goes to a rank holding one of its vertices' breakpoints, the only one
/// where a single rank holds them all; else the one with the fewest
/// stencils to certify (`near`) so far, counting first every rank's own
/// (ties: the lower rank). A contact region on a border is so shared
/// between the ranks beside it (the deciding rank fetches the polylines of
/// the vertices it does not hold, as on its first vertex's rank). The same
/// on every rank: it reads only the keys, `near` and the holders.
fn deciding_ranks(
    keys: &[&StencilKey],
    near: &[bool],
    holders: &[u32],
    ranks: usize,
) -> Vec<Vec<usize>> {
    let holder = |v: &u32| holders[*v as usize] as usize;
    let single = |key: &StencilKey| key.v.iter().all(|v| holder(v) == holder(&key.v[0]));
    let mut certify = vec![0usize; ranks];
    for (key, _) in keys.iter().zip(near).filter(|(k, &n)| n && single(k)) {
        certify[holder(&key.v[0])] += 1;
    }
    let mut by_rank: Vec<Vec<usize>> = vec![Vec::new(); ranks];
    for (n, key) in keys.iter().enumerate() {
        let r = if single(key) {
            holder(&key.v[0])
        } else {
            let r = (key.v.iter().map(holder))
                .min_by_key(|&r| (certify[r], r))
                .expect("a stencil has vertices");
            certify[r] += usize::from(near[n]);
            r
        };
        by_rank[r].push(n);
    }
    by_rank
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn border_stencils_go_to_the_rank_with_less_to_certify() {
        // Vertices 0..8 on rank 0, 8..16 on rank 1, 16..24 on rank 2.
        let holders: Vec<u32> = (0..24).map(|v| v / 8).collect();
        // Rank 0 certifies 6 stencils of its own, rank 1 none, rank 2 one
        // (and one far away, not to certify); 8 stencils straddle ranks 0
        // and 1, of which 6 are to certify.
        let mut keys = Vec::new();
        let mut near = Vec::new();
        for k in 0..6u32 {
            keys.push(StencilKey::vertex_face(k % 4, [4, 5, 6]));
            near.push(true);
        }
        keys.push(StencilKey::vertex_face(16, [17, 18, 19]));
        near.push(true);
        keys.push(StencilKey::vertex_face(20, [21, 22, 23]));
        near.push(false);
        for k in 0..8u32 {
            keys.push(StencilKey::vertex_face(k % 4, [8 + k % 3, 12, 13]));
            near.push(k < 6);
        }
        let refs: Vec<&StencilKey> = keys.iter().collect();
        let by_rank = deciding_ranks(&refs, &near, &holders, 3);
        // Every stencil once, on a rank holding one of its vertices.
        let mut all: Vec<usize> = by_rank.concat();
        all.sort_unstable();
        assert_eq!(all, (0..keys.len()).collect::<Vec<_>>());
        for (r, mine) in by_rank.iter().enumerate() {
            for &n in mine {
                assert!(keys[n].v.iter().any(|&v| holders[v as usize] as usize == r));
            }
        }
        // The border's six to certify all go to rank 1 (6 against 0); its
        // two others then find a tie and go to the lower rank.
        let certified = |r: usize| by_rank[r].iter().filter(|&&n| near[n]).count();
        assert_eq!((certified(0), certified(1), certified(2)), (6, 6, 1));
        assert_eq!(
            by_rank.iter().map(Vec::len).collect::<Vec<_>>(),
            vec![8, 6, 2]
        );
        // Decided on the first vertex's rank, rank 0 would certify 12.
    }
}
