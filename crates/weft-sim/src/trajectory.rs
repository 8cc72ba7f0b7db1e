//! Per-window vertex trajectories (`acm-spec.md` §4.1).
//!
//! Within a window each vertex moves on a polyline with a breakpoint at every
//! kick that changed its velocity. Breakpoints are stored exactly (f64 times in
//! ticks relative to the window start — integers below 2^53, so exact — and the
//! positions the engine actually wrote). Storage is reused across windows and
//! bounded by a memory budget.

use glam::DVec3;
use weft_geom::ccd::Trajectory;

use crate::clock::Tick;

/// Bytes per stored breakpoint (time + position).
pub const BYTES_PER_BREAKPOINT: usize = std::mem::size_of::<f64>() + std::mem::size_of::<DVec3>();

/// The trajectories of all vertices over one window.
#[derive(Clone, Debug, Default)]
pub struct Trajectories {
    start: Tick,
    times: Vec<Vec<f64>>,
    points: Vec<Vec<DVec3>>,
    total: usize,
    budget: usize,
}

/// Appends a breakpoint at relative time `rel`; returns whether one was added
/// (the same instant again — the window end right after a kick — only keeps
/// the newest position, which equals the previous one bit for bit).
#[inline]
fn push_breakpoint(times: &mut Vec<f64>, points: &mut Vec<DVec3>, rel: f64, p: DVec3) -> bool {
    if times.last() == Some(&rel) {
        *points.last_mut().expect("non-empty") = p;
        return false;
    }
    times.push(rel);
    points.push(p);
    true
}

/// The trajectories of a run of vertices (see [`Trajectories::runs`]).
pub struct TrajectoryRun<'a> {
    start: Tick,
    times: &'a mut [Vec<f64>],
    points: &'a mut [Vec<DVec3>],
}

impl TrajectoryRun<'_> {
    /// Records that the run's vertex `j` is at `p` at tick `t`; returns
    /// whether a breakpoint was added.
    #[inline]
    pub fn record(&mut self, j: usize, t: Tick, p: DVec3) -> bool {
        let rel = (t - self.start) as f64;
        push_breakpoint(&mut self.times[j], &mut self.points[j], rel, p)
    }
}

/// The window's breakpoints would exceed the memory budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BudgetExceeded {
    pub breakpoints: usize,
    pub budget_bytes: usize,
}

impl Trajectories {
    /// Storage for `n` vertices with a budget of `budget_bytes`.
    pub fn new(n: usize, budget_bytes: usize) -> Self {
        Self {
            start: 0,
            times: vec![Vec::new(); n],
            points: vec![Vec::new(); n],
            total: 0,
            budget: budget_bytes,
        }
    }

    /// Starts a window at `start` with every vertex at `x` (keeps capacity).
    pub fn begin(&mut self, start: Tick, x: &[DVec3]) {
        self.start = start;
        for (i, &p) in x.iter().enumerate() {
            self.times[i].clear();
            self.points[i].clear();
            self.times[i].push(0.0);
            self.points[i].push(p);
        }
        self.total = x.len();
    }

    /// Records that vertex `i` is at `p` at tick `t` (its velocity changes there).
    #[inline]
    pub fn record(&mut self, i: usize, t: Tick, p: DVec3) -> Result<(), BudgetExceeded> {
        let rel = (t - self.start) as f64;
        if push_breakpoint(&mut self.times[i], &mut self.points[i], rel, p) {
            self.add_recorded(1)?;
        }
        Ok(())
    }

    /// The storage of consecutive runs of vertices (cut at `bounds`, as for
    /// [`crate::Executor::for_each_chunk`]), to record on several threads;
    /// report what they added with [`Trajectories::add_recorded`].
    pub fn runs(&mut self, bounds: &[usize]) -> Vec<TrajectoryRun<'_>> {
        let start = self.start;
        let times = crate::executor::split_chunks(&mut self.times, bounds);
        let points = crate::executor::split_chunks(&mut self.points, bounds);
        times
            .into_iter()
            .zip(points)
            .map(|((_, times), (_, points))| TrajectoryRun {
                start,
                times,
                points,
            })
            .collect()
    }

    /// Counts `n` breakpoints recorded through [`TrajectoryRun`]s against the
    /// budget.
    pub fn add_recorded(&mut self, n: usize) -> Result<(), BudgetExceeded> {
        self.total += n;
        if self.total * BYTES_PER_BREAKPOINT > self.budget {
            return Err(BudgetExceeded {
                breakpoints: self.total,
                budget_bytes: self.budget,
            });
        }
        Ok(())
    }

    /// The polyline of vertex `i`.
    #[inline]
    pub fn of(&self, i: usize) -> Trajectory<'_> {
        Trajectory {
            times: &self.times[i],
            points: &self.points[i],
        }
    }

    /// The window's start tick.
    pub fn start(&self) -> Tick {
        self.start
    }

    /// Breakpoints stored this window (the start points included).
    pub fn breakpoints(&self) -> usize {
        self.total
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// True when there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }
}
