//! The narrow phase of a pass (`acm-spec.md` §4.3): every candidate
//! stencil certified to stay outside `eta_(depth+1)`, or reported.

use std::time::Instant;

use weft_core::StencilKey;
use weft_geom::ccd::{proximity, CcdStats};

use super::{events, Engine, Snapshot};
use crate::balance::{locality_aware, CollisionTasks};
use crate::clock::Tick;
use crate::executor::{CommError, Executor};
use crate::trace;

/// A pass that ran to the window end: the window's start state and the
/// pass's first and end ticks, from which each scripted vertex's polyline
/// is replayed.
pub(super) type Replay<'a> = (&'a Snapshot, (Tick, Tick));

impl<E: Executor> Engine<E> {
    /// Over ranks: every rank gets, from the ranks that hold them, the
    /// polylines of the vertices its tasks read and does not hold itself.
    /// `reads[r]` is what rank `r`'s tasks read (in any order, each vertex
    /// once): all of it for this rank, for another only the vertices
    /// this rank holds (the rest travels between other ranks: every rank
    /// listing every rank's reads was memory and work each one repeated).
    /// Every rank works out the same traffic from the same placement, so
    /// nothing is requested: holders send, readers receive, point to point,
    /// exact bits (`Trajectories::fetched`). The scripted vertices this
    /// rank's tasks read and another rank holds, `replayed`, are computed
    /// here from the window start `replay` instead, while the words travel
    /// (`events::scripted_polyline`; no rank lists them in `reads`), each
    /// checked against the tally and the end position every rank holds
    /// (`Trajectories::computed`). The polylines stay cached until the
    /// pass is decided, less those the commit will not read
    /// (`Trajectories::keep_fetched`, at the end of the narrow phase).
    pub(super) fn fetch_trajectories(
        &mut self,
        mut reads: Vec<Vec<u32>>,
        replayed: &[u32],
        replay: Option<Replay<'_>>,
    ) -> Result<(), CommError> {
        let me = self.exec.rank();
        let holders = self.traj.holders();
        // (holder, reader) → vertices, ascending; only pairs with this rank.
        let mut travel: std::collections::BTreeMap<(usize, usize), Vec<u32>> = Default::default();
        for (r, list) in reads.iter_mut().enumerate() {
            debug_assert!(r == me || list.iter().all(|&v| holders[v as usize] as usize == me));
            list.sort_unstable();
            debug_assert!(list.windows(2).all(|p| p[0] < p[1]), "each vertex once");
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
        let (exec, w) = (&self.exec, &self.world);
        let mut computed = Vec::new();
        let received = exec.exchange_words(sends, &lens, &mut || {
            let Some((start, pass)) = replay else {
                return;
            };
            computed = exec.map(replayed.len(), &|k| {
                let i = replayed[k] as usize;
                let at_start = (start.x[i], start.v[i], start.tau[i]);
                events::scripted_polyline(w, i, at_start, pass)
            });
        })?;
        for ((_, vertices), words) in recvs.iter().zip(received) {
            let mut at = 0;
            for &v in vertices {
                at += self.traj.fetched(v as usize, &words[at..]);
            }
        }
        for (&i, (times, points)) in replayed.iter().zip(computed) {
            let end = self.world.x[i as usize];
            self.traj.computed(i as usize, times, points, end);
        }
        Ok(())
    }

    /// Stencils among `candidates` (sorted) that may come within
    /// `eta_(depth+1)`, in key order; and over ranks, per candidate, the
    /// rank that tested it (it holds the polylines of the candidate's
    /// vertices, fetched or computed for the pass, and keeps those of the
    /// active candidates for the commit; empty on one rank).
    ///
    /// Candidates are grouped by partition pair and split into tasks whose
    /// cost is predicted from the previous pass ([`crate::balance`]); the
    /// executor gets them largest first. Each candidate is tested once and
    /// the answers are sorted, so the result does not depend on the tasks.
    ///
    /// Over ranks, the tasks are placed by the paper's Algorithm 2
    /// ([`crate::balance::locality_aware`]: home rank first while under the
    /// average load) and every rank gets every answer.
    ///
    /// `replay`: the window start and the pass's ticks when the pass ran to
    /// the window end; the scripted vertices' polylines are then computed
    /// where they are read ([`Engine::fetch_trajectories`]).
    pub(super) fn narrow_phase(
        &mut self,
        candidates: &[StencilKey],
        replay: Option<Replay<'_>>,
    ) -> Result<(Vec<StencilKey>, Vec<u32>), CommError> {
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
        let mut tested_on = Vec::new();
        if ranks > 1 {
            tested_on = vec![0u32; candidates.len()];
            // The partitions' home ranks, placed once for the run.
            let home = self.share.as_ref().map_or(&[][..], |s| &s.home[..]);
            let by_load: Vec<_> = order.iter().map(|&t| tasks.tasks[t].clone()).collect();
            let (assigned, _) = locality_aware(&by_load, ranks, &|p| home[p as usize] as usize);
            // What each rank's tasks read: all of it for this rank, for
            // another what this rank holds (what it sends there).
            // Each vertex is listed once per rank (`listed[v]`: the last rank
            // that listed it; the ranks come in order): four reads per
            // candidate with their repeats were 4.2 MB at a rank's memory
            // peak (the fetch) on the 50k twister over 32 ranks.
            // A scripted vertex travels to no rank when the pass can be
            // replayed: this rank computes those its tasks read.
            let (me, holders) = (self.exec.rank(), self.traj.holders());
            let w = &self.world;
            let travels = |v: u32| replay.is_none() || !events::replayable(w, v as usize);
            let mut reads = vec![Vec::new(); ranks];
            let mut replayed = Vec::new();
            let mut listed = vec![u32::MAX; holders.len()];
            for (r, mine) in assigned.iter().enumerate() {
                for &n in mine {
                    owner[n] = r as u32;
                    let task = &tasks.tasks[order[n]];
                    for &c in &tasks.order[task.range.clone()] {
                        for &v in &candidates[c as usize].v {
                            let held_here = holders[v as usize] as usize == me;
                            if (r == me || held_here) && listed[v as usize] != r as u32 {
                                listed[v as usize] = r as u32;
                                if travels(v) {
                                    reads[r].push(v);
                                } else if !held_here {
                                    replayed.push(v);
                                }
                            }
                        }
                        tested_on[c as usize] = r as u32;
                    }
                }
            }
            drop(listed);
            self.fetch_trajectories(reads, &replayed, replay)?;
        }
        let w = &self.world;
        let depths = if ranks > 1 {
            // Only the depths of this rank's tasks' candidates (the others
            // are never read here): a merge walk over every candidate was
            // work each rank repeated.
            let me = self.exec.rank() as u32;
            let mut mine: Vec<u32> = (0..order.len())
                .filter(|&n| owner[n] == me)
                .flat_map(|n| &tasks.order[tasks.tasks[order[n]].range.clone()])
                .copied()
                .collect();
            mine.sort_unstable();
            let keys: Vec<StencilKey> = mine.iter().map(|&c| candidates[c as usize]).collect();
            let mut depths = vec![0; candidates.len()];
            for (&c, d) in mine.iter().zip(w.layers.depths_of(&keys)) {
                depths[c as usize] = d;
            }
            depths
        } else {
            w.layers.depths_of(candidates)
        };
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
                let eta = w.schedule.eta(depths[c as usize] + 1);
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
        if ranks > 1 && reported.is_empty() {
            // The commit certifies again only the active candidates, each
            // where it was tested (`commit.rs`): of the polylines fetched
            // here it reads only theirs. The others go before it, where a
            // rank's memory peaks (the 50k twister over 32 ranks). A pass
            // with a report rolls back and forgets them all.
            let me = self.exec.rank() as u32;
            let mut kept = vec![false; self.traj.len()];
            for n in (0..order.len()).filter(|&n| owner[n] == me) {
                for &c in &tasks.order[tasks.tasks[order[n]].range.clone()] {
                    if depths[c as usize] > 0 {
                        for &v in &candidates[c as usize].v {
                            kept[v as usize] = true;
                        }
                    }
                }
            }
            self.traj.keep_fetched(|i| kept[i]);
        }
        Ok((reported, tested_on))
    }
}
