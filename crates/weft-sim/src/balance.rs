//! Narrow-phase load balance (Ni, Kale, Tamstorf 2015, §V; `acm-spec.md` §5).
//!
//! Candidate stencils are grouped by the pair of partitions they couple;
//! every candidate of a group is assumed to cost the same, measured per
//! group in the previous detection pass (cost grows with trajectory length,
//! which changes slowly). Groups above a load threshold are split into
//! tasks. Tasks are then handed out largest first ([`CollisionTasks::by_load`])
//! or, across ranks, placed by the paper's locality-aware Algorithm 2
//! ([`locality_aware`]).
//!
//! None of this changes what is computed — every candidate is tested exactly
//! once and the answers are merged in key order — only where and when.

use std::collections::BTreeMap;
use std::ops::Range;

use weft_core::{StencilKey, NONE};

use crate::partition::Partitioning;

/// A partition pair `(a, b)`, `a <= b`; [`NONE`] stands for kinematic
/// obstacles (replicated everywhere).
pub type PartitionPair = (u32, u32);

/// The partition pair of a stencil.
pub fn pair_of(p: &Partitioning, key: &StencilKey) -> PartitionPair {
    let (a, b) = p.sides(key);
    (a.min(b), a.max(b))
}

/// Per-pair cost of one narrow-phase query, measured in the last pass.
#[derive(Clone, Debug, Default)]
pub struct CostModel {
    /// (seconds, queries) per pair in the last pass.
    per_pair: BTreeMap<PartitionPair, (f64, u64)>,
}

impl CostModel {
    /// The predicted cost of one query of `pair`: its last measured mean, or
    /// the mean over all pairs for a pair not seen before (1 when nothing
    /// was measured yet: loads are then candidate counts).
    pub fn per_query(&self, pair: PartitionPair) -> f64 {
        if let Some(&(s, q)) = self.per_pair.get(&pair) {
            if q > 0 && s > 0.0 {
                return s / q as f64;
            }
        }
        self.mean()
    }

    /// The mean cost of one query over all measured pairs (1 when nothing
    /// was measured).
    pub fn mean(&self) -> f64 {
        let (s, q) = self
            .per_pair
            .values()
            .fold((0.0, 0u64), |(s, q), &(a, b)| (s + a, q + b));
        if q > 0 && s > 0.0 {
            s / q as f64
        } else {
            1.0
        }
    }

    /// Replaces the measurements with those of a pass: `(pair, seconds,
    /// queries)` per executed task.
    pub fn record(&mut self, measured: impl IntoIterator<Item = (PartitionPair, f64, u64)>) {
        self.per_pair.clear();
        for (pair, s, q) in measured {
            let e = self.per_pair.entry(pair).or_insert((0.0, 0));
            e.0 += s;
            e.1 += q;
        }
    }
}

/// One collision task: a run of candidates of one partition pair.
#[derive(Clone, Debug, PartialEq)]
pub struct CollisionTask {
    pub pair: PartitionPair,
    /// Indices into [`CollisionTasks::order`].
    pub range: Range<usize>,
    /// Predicted cost (seconds, or candidates before any measurement).
    pub load: f64,
}

/// The candidates of a pass, grouped and split into tasks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CollisionTasks {
    /// Candidate indices, grouped by partition pair (pairs ascending, keys
    /// ascending within a pair).
    pub order: Vec<u32>,
    pub tasks: Vec<CollisionTask>,
}

impl CollisionTasks {
    /// Groups `candidates` (sorted keys) by partition pair and splits every
    /// group into tasks of predicted load at most `max_load` (and at least
    /// one candidate each).
    pub fn build(
        candidates: &[StencilKey],
        partitioning: &Partitioning,
        costs: &CostModel,
        max_load: f64,
    ) -> Self {
        let mut keyed: Vec<(PartitionPair, u32)> = candidates
            .iter()
            .enumerate()
            .map(|(i, k)| (pair_of(partitioning, k), i as u32))
            .collect();
        keyed.sort_unstable();
        let order: Vec<u32> = keyed.iter().map(|&(_, i)| i).collect();
        let mut tasks = Vec::new();
        let mut start = 0;
        while start < keyed.len() {
            let pair = keyed[start].0;
            let end = start + keyed[start..].iter().take_while(|e| e.0 == pair).count();
            let per = costs.per_query(pair);
            let per_task = ((max_load / per).floor() as usize).max(1);
            let mut s = start;
            while s < end {
                let e = (s + per_task).min(end);
                tasks.push(CollisionTask {
                    pair,
                    range: s..e,
                    load: per * (e - s) as f64,
                });
                s = e;
            }
            start = end;
        }
        Self { order, tasks }
    }

    /// Task indices from the largest predicted load to the smallest (ties by
    /// index), the order a shared queue hands them out in.
    pub fn by_load(&self) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.tasks.len()).collect();
        idx.sort_by(|&a, &b| {
            self.tasks[b]
                .load
                .total_cmp(&self.tasks[a].load)
                .then(a.cmp(&b))
        });
        idx
    }

    /// Total predicted load.
    pub fn total_load(&self) -> f64 {
        self.tasks.iter().map(|t| t.load).sum()
    }
}

/// Algorithm 2 of the paper: places `tasks` on `nodes` ranks. A task goes to
/// a home rank (one holding either of its partitions, `home(p)`; obstacles
/// have none) while that rank stays under the average load; the rest go,
/// largest first, to the least-loaded rank (ties: the lowest rank). Returns
/// each rank's task indices and the loads.
pub fn locality_aware(
    tasks: &[CollisionTask],
    nodes: usize,
    home: &dyn Fn(u32) -> usize,
) -> (Vec<Vec<usize>>, Vec<f64>) {
    let nodes = nodes.max(1);
    let mut load = vec![0.0f64; nodes];
    let mut assigned = vec![Vec::new(); nodes];
    let average = tasks.iter().map(|t| t.load).sum::<f64>() / nodes as f64;
    let mut pending = Vec::new();
    for (i, t) in tasks.iter().enumerate() {
        let homes = [t.pair.0, t.pair.1]
            .into_iter()
            .filter(|&p| p != NONE)
            .map(|p| home(p).min(nodes - 1));
        let mut placed = false;
        for r in homes {
            if load[r] + t.load < average {
                load[r] += t.load;
                assigned[r].push(i);
                placed = true;
                break;
            }
        }
        if !placed {
            pending.push(i);
        }
    }
    pending.sort_by(|&a, &b| tasks[b].load.total_cmp(&tasks[a].load).then(a.cmp(&b)));
    for i in pending {
        let r = (0..nodes)
            .min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b)))
            .unwrap_or(0);
        load[r] += tasks[i].load;
        assigned[r].push(i);
    }
    (assigned, load)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn task(pair: (u32, u32), load: f64) -> CollisionTask {
        CollisionTask {
            pair,
            range: 0..1,
            load,
        }
    }

    #[test]
    fn every_task_is_placed_once_homes_first_and_the_rest_evens_out() {
        // Partition p lives on rank p % 2.
        let home = |p: u32| (p % 2) as usize;
        let tasks = vec![
            task((0, 0), 4.0),
            task((0, 2), 4.0),
            task((0, 1), 1.0),
            task((2, 2), 3.0),
            task((1, 3), 1.0),
            task((0, NONE), 1.0),
        ];
        let (assigned, load) = locality_aware(&tasks, 2, &home);
        let mut all: Vec<usize> = assigned.concat();
        all.sort_unstable();
        assert_eq!(all, (0..tasks.len()).collect::<Vec<_>>());
        // Average 7: rank 0 takes (0,0); (0,2) would reach 8, rank 1 is not
        // a home of it: pending. (0,1) → rank 0 (5). (2,2) would reach 8 on
        // rank 0: pending. (1,3) → rank 1 (1). (0,NONE) → rank 0 (6).
        // Pending largest first: (0,2) 4 → rank 1 (5), (2,2) 3 → rank 1? no:
        // rank 1 has 5, rank 0 has 6 → rank 1 (8).
        assert_eq!(assigned[0], vec![0, 2, 5]);
        assert_eq!(assigned[1], vec![4, 1, 3]);
        assert_eq!(load, vec![6.0, 8.0]);
        let total: f64 = tasks.iter().map(|t| t.load).sum();
        assert_eq!(load.iter().sum::<f64>(), total);
    }

    #[test]
    fn the_greedy_round_never_leaves_a_rank_above_average_plus_largest_task() {
        let mut rng = weft_testkit::Rng(7);
        for _ in 0..200 {
            let nodes = 1 + rng.below(5) as usize;
            let tasks: Vec<CollisionTask> = (0..rng.below(40))
                .map(|_| {
                    let pair = (rng.below(8) as u32, rng.below(8) as u32);
                    task(pair, rng.uniform(0.1, 5.0))
                })
                .collect();
            let (assigned, load) = locality_aware(&tasks, nodes, &|p| p as usize % nodes);
            let mut all: Vec<usize> = assigned.concat();
            all.sort_unstable();
            assert_eq!(all, (0..tasks.len()).collect::<Vec<_>>());
            let total: f64 = tasks.iter().map(|t| t.load).sum();
            let largest = tasks.iter().map(|t| t.load).fold(0.0, f64::max);
            for l in load {
                assert!(l <= total / nodes as f64 + largest + 1e-9);
            }
        }
    }

    #[test]
    fn groups_split_under_the_threshold_and_cover_every_candidate() {
        use crate::partition::{Contiguous, Partitioning};
        use weft_core::Topology;
        // A strip of 8 triangles in 4 parts.
        let tris: Vec<[u32; 3]> = (0..4u32)
            .flat_map(|q| [[q, q + 1, q + 5], [q + 1, q + 6, q + 5]])
            .collect();
        let topo = Topology::build(10, &tris).unwrap();
        let p = Partitioning::build(&Contiguous, 4, 1, &tris, &[true; 8], &topo, 10).unwrap();
        let mut keys: Vec<StencilKey> = Vec::new();
        for v in 0..10 {
            for t in &tris {
                if !t.contains(&v) {
                    keys.push(StencilKey::vertex_face(v, *t));
                }
            }
        }
        keys.sort_unstable();
        keys.dedup();
        let tasks = CollisionTasks::build(&keys, &p, &CostModel::default(), 5.0);
        let mut seen: Vec<u32> = tasks.order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..keys.len() as u32).collect::<Vec<_>>());
        for t in &tasks.tasks {
            assert!(t.load <= 5.0 && !t.range.is_empty());
            for &i in &tasks.order[t.range.clone()] {
                assert_eq!(pair_of(&p, &keys[i as usize]), t.pair);
            }
        }
        let by_load = tasks.by_load();
        assert!(by_load
            .windows(2)
            .all(|w| tasks.tasks[w[0]].load >= tasks.tasks[w[1]].load));
        // Measured costs change the split: a pair measured at 5 s per query
        // gets one candidate per task.
        let mut costs = CostModel::default();
        let pair = tasks.tasks[0].pair;
        costs.record([(pair, 50.0, 10)]);
        let again = CollisionTasks::build(&keys, &p, &costs, 5.0);
        assert!(again
            .tasks
            .iter()
            .filter(|t| t.pair == pair)
            .all(|t| t.range.len() == 1));
        // An unmeasured pair is predicted at the mean over measured pairs.
        assert_eq!(costs.per_query((99, 99)), 5.0);
    }
}
