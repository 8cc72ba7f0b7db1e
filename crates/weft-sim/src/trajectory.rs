//! Per-window vertex trajectories (`acm-spec.md` §4.1).
//!
//! Within a window each vertex moves on a polyline with a breakpoint at every
//! kick that changed its velocity. Breakpoints are stored exactly (f64 times in
//! ticks relative to the window start — integers below 2^53, so exact — and the
//! positions the engine actually wrote). Storage is reused across windows and
//! bounded by a memory budget.
//!
//! # Staged internal ticks
//!
//! An internal tick gives every moving vertex a breakpoint. Pushed at once,
//! each would go to the tail of its own vertex's arrays: tens of thousands
//! of scattered writes per tick, most into a cache line not touched since
//! the last window, which measured about 100 ns a breakpoint (18 % of a
//! twister window). So an internal tick's breakpoints are **staged**: its
//! positions go to a column of [`STAGED_TICKS`] tick-major columns (one
//! sequential write per vertex), and a full set of columns is stored vertex
//! by vertex, [`STAGED_TICKS`] consecutive breakpoints at a time
//! ([`TrajectoryRun::stage`], [`Trajectories::flush`]). A vertex's staged
//! breakpoints are stored before any other of its breakpoints is recorded,
//! so every polyline keeps its time order, bit for bit what pushing at once
//! gave; its count and last time are kept at once, as before.
//!
//! # Over ranks
//!
//! Each vertex has a *holder* rank that stores its breakpoints
//! ([`Trajectories::hold_only`]; on one memory every vertex is held). Every
//! rank still knows, between passes, for every vertex, how many breakpoints
//! it has and when its last one was (within a pass a rank follows only the
//! vertices it keeps current; the owners' tallies reach every rank at the
//! pass end, [`Trajectories::set_tally`]), and the total against the budget
//! at every step: the budget, the statistics and the lengths of what travels
//! are the same everywhere. A rank that reads a vertex it
//! does not hold (a narrow-phase or retirement task with a vertex of another
//! rank's partition) first receives its polyline from the holder into a
//! per-pass cache ([`Trajectories::fetched`]), exactly, bit for bit; after a
//! pass that ran to the window end, a scripted vertex's polyline, which
//! follows from its window start and its script alone, the reader computes
//! instead ([`Trajectories::computed`]).
//! The breakpoint storage and the staged columns hold only the vertices
//! held here: a rank of `R` keeps about `1/R` of them.

use glam::DVec3;
use weft_geom::ccd::bounds::{TrajectoryBounds, FANOUT};
use weft_geom::ccd::Trajectory;

use crate::clock::Tick;

/// Bytes per stored breakpoint: time and position, and at most 7 bytes of
/// block bounds ([`weft_geom::ccd::bounds`]: a 48-byte box per 8
/// breakpoints, per 64, …).
pub const BYTES_PER_BREAKPOINT: usize =
    std::mem::size_of::<f64>() + std::mem::size_of::<DVec3>() + 7;

/// Internal ticks staged before their breakpoints are stored (see the
/// module docs).
pub const STAGED_TICKS: usize = 16;

/// Bytes per held vertex of the staged columns: a position and a mark per
/// staged tick, and a count.
pub const STAGED_BYTES_PER_VERTEX: usize = STAGED_TICKS * (std::mem::size_of::<DVec3>() + 1) + 1;

/// Staged internal-tick breakpoints (see the module docs).
#[derive(Clone, Debug, Default)]
struct Staged {
    /// The staged ticks' times (relative ticks), at most [`STAGED_TICKS`].
    times: Vec<f64>,
    /// Per staged tick: every held vertex's position (vertex `i` at
    /// `Trajectories::column_of[i]`), and whether it is a breakpoint (the
    /// vertex moved).
    points: Vec<Vec<DVec3>>,
    marked: Vec<Vec<bool>>,
    /// Per vertex: its staged breakpoints already stored (a vertex stores
    /// its own before a breakpoint is recorded out of turn).
    stored: Vec<u8>,
}

/// The trajectories of all vertices over one window.
#[derive(Clone, Debug, Default)]
pub struct Trajectories {
    start: Tick,
    /// per held vertex (vertex `i` at `column_of[i]`): its breakpoints'
    /// times and points,
    times: Vec<Vec<f64>>,
    points: Vec<Vec<DVec3>>,
    /// and block bounds over them, built as they are recorded (the narrow
    /// phase's and the commit's certificates bound long stretches with
    /// them).
    bounds: Vec<TrajectoryBounds>,
    /// per vertex: the time of its last breakpoint (relative ticks) and how
    /// many it has — kept for every vertex, held here or not.
    last: Vec<f64>,
    count: Vec<u32>,
    /// per vertex: the rank that stores its breakpoints, and this rank.
    holder: Vec<u32>,
    me: u32,
    /// per vertex and one more: how many vertices below it are held here,
    /// which is a held vertex's place in the staged columns and the held
    /// storage (a run of vertices `a..b` has their places
    /// `column_of[a]..column_of[b]`).
    column_of: Vec<u32>,
    /// polylines of vertices held elsewhere, received this window.
    cache: std::collections::HashMap<u32, (Vec<f64>, Vec<DVec3>, TrajectoryBounds)>,
    /// internal ticks whose breakpoints are not stored yet, and the times
    /// of those being stored.
    staged: Staged,
    flushed_times: Vec<f64>,
    total: usize,
    budget: usize,
}

/// Notes a breakpoint at relative time `rel` of a vertex whose last one was
/// at `last` (storing it when `store`); returns whether one was added (the
/// same instant again — the window end right after a kick — only keeps the
/// newest position, which equals the previous one bit for bit).
#[inline]
fn push_breakpoint(
    last: &mut f64,
    count: &mut u32,
    store: Option<Stored<'_>>,
    rel: f64,
    p: DVec3,
) -> bool {
    if *last == rel {
        if let Some((_, points, bounds)) = store {
            *points.last_mut().expect("non-empty") = p;
            bounds.replace_last(points.len(), p);
        }
        return false;
    }
    *last = rel;
    *count += 1;
    if let Some((times, points, bounds)) = store {
        times.push(rel);
        points.push(p);
        // (touches the bounds once per 8 breakpoints)
        if (points.len() - 1) % FANOUT == 0 {
            bounds.update(times, points);
        }
    }
    true
}

/// Stores a breakpoint whose count and last time were kept when it was
/// staged.
#[inline]
fn store_breakpoint(store: Stored<'_>, rel: f64, p: DVec3) {
    let (times, points, bounds) = store;
    times.push(rel);
    points.push(p);
    if (points.len() - 1) % FANOUT == 0 {
        bounds.update(times, points);
    }
}

/// Stores the staged breakpoints at place `j` of the columns (whole or a
/// run's part of them) from column `from` on, in time order (`times[k]` the
/// staged ticks' times), into `store`.
#[inline]
fn store_staged<P: AsRef<[DVec3]>, M: AsRef<[bool]>>(
    store: Stored<'_>,
    times: &[f64],
    points: &[P],
    marked: &[M],
    j: usize,
    from: usize,
) {
    let (t, p, b) = store;
    for k in from..times.len() {
        if marked[k].as_ref()[j] {
            store_breakpoint((&mut *t, &mut *p, &mut *b), times[k], points[k].as_ref()[j]);
        }
    }
}

/// A held vertex's breakpoint storage: times, points, block bounds.
type Stored<'a> = (
    &'a mut Vec<f64>,
    &'a mut Vec<DVec3>,
    &'a mut TrajectoryBounds,
);

/// The trajectories of a run of vertices at one internal tick (see
/// [`Trajectories::runs`]): its vertices' storage and their part of the
/// staged columns.
pub struct TrajectoryRun<'a> {
    me: u32,
    times: &'a mut [Vec<f64>],
    points: &'a mut [Vec<DVec3>],
    bounds: &'a mut [TrajectoryBounds],
    last: &'a mut [f64],
    count: &'a mut [u32],
    holder: &'a [u32],
    /// The run's vertices' places in the staged columns, less the run's
    /// first (the run's part of the columns starts there).
    column_of: &'a [u32],
    column_base: u32,
    /// The staged ticks to store first ([`TrajectoryRun::prepare`]; empty
    /// when the columns are not full), and their columns.
    flush_times: &'a [f64],
    staged_points: Vec<&'a mut [DVec3]>,
    staged_marked: Vec<&'a mut [bool]>,
    stored: &'a mut [u8],
    /// The column of this tick (`None`: the run only stores or records),
    /// and its time.
    column: Option<usize>,
    rel: f64,
    /// The times of the staged columns a [`TrajectoryRun::record`] stores
    /// first, and the window start.
    staged_times: &'a [f64],
    start: Tick,
}

impl TrajectoryRun<'_> {
    /// Stores the run's staged breakpoints if the columns are full, and
    /// clears this tick's column: call once, before [`TrajectoryRun::stage`].
    pub fn prepare(&mut self) {
        if !self.flush_times.is_empty() {
            for j in 0..self.holder.len() {
                let from = std::mem::take(&mut self.stored[j]) as usize;
                if self.holder[j] == self.me {
                    let c = self.column(j);
                    let store = (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]);
                    store_staged(
                        store,
                        self.flush_times,
                        &self.staged_points,
                        &self.staged_marked,
                        c,
                        from,
                    );
                }
            }
        }
        if let Some(k) = self.column {
            self.staged_marked[k].fill(false);
        }
    }

    /// Records that the run's vertex `j` is at `p` at tick `t`, out of turn
    /// (as [`Trajectories::record`]: its staged breakpoints are stored
    /// first); returns whether a breakpoint was added.
    #[inline]
    pub fn record(&mut self, j: usize, t: Tick, p: DVec3) -> bool {
        let now = self.staged_times.len();
        let from = std::mem::replace(&mut self.stored[j], now as u8) as usize;
        let held = self.holder[j] == self.me;
        let c = if held { self.column(j) } else { 0 };
        if held && from < now {
            let store = (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]);
            store_staged(
                store,
                self.staged_times,
                &self.staged_points,
                &self.staged_marked,
                c,
                from,
            );
        }
        let rel = (t - self.start) as f64;
        let store = held.then(|| (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]));
        push_breakpoint(&mut self.last[j], &mut self.count[j], store, rel, p)
    }

    /// Stages a breakpoint of the run's vertex `j` at `p` at this tick;
    /// returns whether one was added (see [`Trajectories::record`]).
    #[inline]
    pub fn stage(&mut self, j: usize, p: DVec3) -> bool {
        let k = self.column.expect("a run of an internal tick");
        if self.last[j] == self.rel {
            // The same instant again (an internal tick at the window
            // start): its newest position replaces the stored one.
            let held = self.holder[j] == self.me;
            let c = if held { self.column(j) } else { 0 };
            let store =
                held.then(|| (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]));
            return push_breakpoint(&mut self.last[j], &mut self.count[j], store, self.rel, p);
        }
        self.last[j] = self.rel;
        self.count[j] += 1;
        if self.holder[j] == self.me {
            let c = self.column(j);
            self.staged_points[k][c] = p;
            self.staged_marked[k][c] = true;
        }
        true
    }

    /// The place of the run's held vertex `j` in its part of the staged
    /// columns and of the held storage.
    #[inline]
    fn column(&self, j: usize) -> usize {
        (self.column_of[j] - self.column_base) as usize
    }
}

/// The window's breakpoints would exceed the memory budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BudgetExceeded {
    pub breakpoints: usize,
    pub budget_bytes: usize,
}

impl Trajectories {
    /// Storage for `n` vertices with a budget of `budget_bytes`, every
    /// vertex held here.
    pub fn new(n: usize, budget_bytes: usize) -> Self {
        Self::held_by(vec![0; n], 0, budget_bytes)
    }

    /// Storage for the vertices `holder` gives to rank `me` (one entry per
    /// vertex), as [`Trajectories::new`] then [`Trajectories::hold_only`]
    /// would leave it, without first making room for every vertex (112
    /// bytes a vertex, at the moment a rank's engine is made).
    pub fn held_by(holder: Vec<u32>, me: u32, budget_bytes: usize) -> Self {
        let mut column_of = Vec::with_capacity(holder.len() + 1);
        let mut held = 0u32;
        for &h in &holder {
            column_of.push(held);
            held += u32::from(h == me);
        }
        column_of.push(held);
        let (n, held) = (holder.len(), held as usize);
        Self {
            start: 0,
            times: vec![Vec::new(); held],
            points: vec![Vec::new(); held],
            bounds: vec![TrajectoryBounds::default(); held],
            last: vec![0.0; n],
            count: vec![0; n],
            holder,
            me,
            column_of,
            cache: Default::default(),
            staged: Staged::default(),
            flushed_times: Vec::new(),
            total: 0,
            budget: budget_bytes,
        }
    }

    /// Sets the budget (bytes) checked from the next breakpoint on.
    pub fn set_budget(&mut self, budget_bytes: usize) {
        self.budget = budget_bytes;
    }

    /// Stores from now on only the breakpoints of the vertices `holder`
    /// gives to rank `me` (one entry per vertex); frees the others', and
    /// sizes the staged columns for the vertices held (what was staged is
    /// stored first).
    pub fn hold_only(&mut self, holder: Vec<u32>, me: u32) {
        assert_eq!(holder.len(), self.len(), "one holder per vertex");
        for i in 0..self.len() {
            self.store_staged_of(i);
        }
        self.staged.times.clear();
        self.staged.stored.iter_mut().for_each(|s| *s = 0);
        // The storage of the vertices held from now on: kept where they
        // were held already, empty where not.
        let kept = holder.iter().filter(|&&h| h == me).count();
        let mut times = Vec::with_capacity(kept);
        let mut points = Vec::with_capacity(kept);
        let mut bounds = Vec::with_capacity(kept);
        let mut held = 0;
        for (i, &h) in holder.iter().enumerate() {
            if h == me {
                if self.holder[i] == self.me {
                    let c = self.column_of[i] as usize;
                    times.push(std::mem::take(&mut self.times[c]));
                    points.push(std::mem::take(&mut self.points[c]));
                    bounds.push(std::mem::take(&mut self.bounds[c]));
                } else {
                    times.push(Vec::new());
                    points.push(Vec::new());
                    bounds.push(TrajectoryBounds::default());
                }
            }
            self.column_of[i] = held;
            held += u32::from(h == me);
        }
        self.column_of[holder.len()] = held;
        (self.times, self.points, self.bounds) = (times, points, bounds);
        self.holder = holder;
        self.me = me;
        if !self.staged.points.is_empty() {
            self.make_staged_columns();
        }
    }

    /// The rank that stores each vertex's breakpoints.
    pub fn holders(&self) -> &[u32] {
        &self.holder
    }

    /// Whether vertex `i`'s breakpoints are stored here.
    #[inline]
    pub fn holds(&self, i: usize) -> bool {
        self.holder[i] == self.me
    }

    /// Starts a window at `start` with every vertex at `x` (keeps capacity;
    /// empties the cache of fetched polylines).
    pub fn begin(&mut self, start: Tick, x: &[DVec3]) {
        self.start = start;
        self.cache.clear();
        let n = x.len();
        self.staged.times.clear();
        self.staged.stored.clear();
        self.staged.stored.resize(n, 0);
        for (i, &p) in x.iter().enumerate() {
            self.last[i] = 0.0;
            self.count[i] = 1;
            if self.holder[i] == self.me {
                let c = self.column_of[i] as usize;
                self.times[c].clear();
                self.points[c].clear();
                self.bounds[c].clear();
                self.times[c].push(0.0);
                self.points[c].push(p);
            }
        }
        self.total = x.len();
    }

    /// Makes room for `per_vertex` breakpoints in each held vertex that
    /// `moves` (a vertex the internal ticks move gets one per tick): one
    /// allocation each, made with the engine, instead of a doubling every
    /// few flushes of the staged ticks, which took 10 ms a flush on the
    /// 10k twister and did not scale over threads (the allocator's lock).
    /// Capacity is kept across windows; nothing is reserved beyond the
    /// trajectory budget (the budget error then comes from the breakpoints
    /// themselves).
    pub fn reserve(&mut self, per_vertex: usize, moves: impl Fn(usize) -> bool) {
        let reserved = (0..self.len())
            .filter(|&i| self.holder[i] == self.me && moves(i))
            .count();
        if reserved.saturating_mul(per_vertex) > self.budget / BYTES_PER_BREAKPOINT {
            return;
        }
        for i in 0..self.len() {
            let c = self.column_of[i] as usize;
            if self.holder[i] == self.me && moves(i) && self.times[c].capacity() < per_vertex {
                let more = per_vertex.saturating_sub(self.times[c].len());
                self.times[c].reserve_exact(more);
                self.points[c].reserve_exact(more);
                self.bounds[c].reserve_for(per_vertex);
            }
        }
    }

    /// Records that vertex `i` is at `p` at tick `t` (its velocity changes there).
    #[inline]
    pub fn record(&mut self, i: usize, t: Tick, p: DVec3) -> Result<(), BudgetExceeded> {
        self.store_staged_of(i);
        let rel = (t - self.start) as f64;
        let c = self.column_of[i] as usize;
        let store = (self.holder[i] == self.me)
            .then(|| (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]));
        if push_breakpoint(&mut self.last[i], &mut self.count[i], store, rel, p) {
            self.add_recorded(1)?;
        }
        Ok(())
    }

    /// The storage of consecutive runs of vertices (cut at `bounds`, as for
    /// [`crate::Executor::for_each_chunk`]), to stage the breakpoints of the
    /// internal tick `t` on several threads (`None`: only to store what is
    /// staged, as [`Trajectories::flush`] does). Each run must
    /// [`TrajectoryRun::prepare`] first; report what they added with
    /// [`Trajectories::add_recorded`].
    pub fn runs(&mut self, bounds: &[usize], t: Option<Tick>) -> Vec<TrajectoryRun<'_>> {
        self.make_staged_columns();
        let flush = match t {
            Some(_) => self.staged_full(),
            None => !self.staged.times.is_empty(),
        };
        self.runs_with(bounds, t, flush)
    }

    /// Makes the staged columns ([`STAGED_BYTES_PER_VERTEX`] per vertex)
    /// unless they are there: once, by the first [`Trajectories::runs`] or
    /// ahead of it (`Engine::new`, so that a run's first window does not pay
    /// for it); trajectories recorded only out of turn (the layer
    /// predictor's) never make them.
    pub fn make_staged_columns(&mut self) {
        let n = self.column_of.last().map_or(0, |&c| c as usize);
        if self.staged.points.len() != STAGED_TICKS || self.staged.points[0].len() != n {
            self.staged.points = vec![vec![DVec3::ZERO; n]; STAGED_TICKS];
            self.staged.marked = vec![vec![false; n]; STAGED_TICKS];
        }
    }

    /// The storage of consecutive runs of vertices (as for
    /// [`Trajectories::runs`]), to record breakpoints out of turn on several
    /// threads ([`TrajectoryRun::record`]; no [`TrajectoryRun::prepare`]).
    pub fn record_runs(&mut self, bounds: &[usize]) -> Vec<TrajectoryRun<'_>> {
        self.runs_with(bounds, None, false)
    }

    /// Whether `n` more breakpoints fit in the budget.
    pub fn fits(&self, n: usize) -> bool {
        (self.total + n).saturating_mul(BYTES_PER_BREAKPOINT) <= self.budget
    }

    fn runs_with(
        &mut self,
        bounds: &[usize],
        t: Option<Tick>,
        flush: bool,
    ) -> Vec<TrajectoryRun<'_>> {
        use crate::executor::split_chunks;
        let (me, start) = (self.me, self.start);
        let staged = &mut self.staged;
        let flush_times: &[f64] = if flush {
            let times = std::mem::take(&mut staged.times);
            self.flushed_times = times;
            &self.flushed_times
        } else {
            &[]
        };
        let column = t.map(|t| {
            staged.times.push((t - self.start) as f64);
            staged.times.len() - 1
        });
        let staged_times: &[f64] = &staged.times;
        let rel = column.map_or(0.0, |k| staged_times[k]);
        // The runs' parts of the staged columns: their held vertices'.
        let column_of = &self.column_of;
        let held_bounds: Vec<usize> = bounds.iter().map(|&b| column_of[b] as usize).collect();
        let mut columns: Vec<std::vec::IntoIter<(usize, &mut [DVec3])>> =
            (staged.points.iter_mut())
                .map(|c| split_chunks(c, &held_bounds).into_iter())
                .collect();
        let mut marks: Vec<std::vec::IntoIter<(usize, &mut [bool])>> = (staged.marked.iter_mut())
            .map(|c| split_chunks(c, &held_bounds).into_iter())
            .collect();
        let stored = split_chunks(&mut staged.stored, bounds);
        let times = split_chunks(&mut self.times, &held_bounds);
        let points = split_chunks(&mut self.points, &held_bounds);
        let boxes = split_chunks(&mut self.bounds, &held_bounds);
        let last = split_chunks(&mut self.last, bounds);
        let count = split_chunks(&mut self.count, bounds);
        let holder = &self.holder;
        (times.into_iter().zip(points).zip(boxes))
            .zip(last.into_iter().zip(count).zip(stored))
            .map(
                |(
                    (((k, times), (_, points)), (_, boxes)),
                    (((_, last), (_, count)), (_, stored)),
                )| {
                    TrajectoryRun {
                        me,
                        times,
                        points,
                        bounds: boxes,
                        last,
                        count,
                        holder: &holder[bounds[k]..bounds[k + 1]],
                        column_of: &column_of[bounds[k]..bounds[k + 1]],
                        column_base: column_of[bounds[k]],
                        flush_times,
                        staged_points: columns
                            .iter_mut()
                            .map(|c| c.next().expect("a run").1)
                            .collect(),
                        staged_marked: marks
                            .iter_mut()
                            .map(|c| c.next().expect("a run").1)
                            .collect(),
                        stored,
                        column,
                        rel,
                        staged_times,
                        start,
                    }
                },
            )
            .collect()
    }

    /// Whether the staged columns are full: the next internal tick's
    /// [`Trajectories::runs`] would store them first (an early
    /// [`Trajectories::flush`] gives the same polylines).
    pub fn staged_full(&self) -> bool {
        self.staged.times.len() == STAGED_TICKS
    }

    /// Stores every staged breakpoint, in runs of vertices (cut at
    /// `bounds`) on `exec`.
    pub fn flush<E: crate::executor::Executor>(&mut self, exec: &E, bounds: &[usize]) {
        let mut runs = self.runs(bounds, None);
        exec.for_each_item(&mut runs, &|_, run| run.prepare());
    }

    /// Stores vertex `i`'s staged breakpoints that are not stored yet.
    #[inline]
    fn store_staged_of(&mut self, i: usize) {
        let staged = &mut self.staged;
        let from = staged.stored.get(i).copied().unwrap_or(0) as usize;
        if from >= staged.times.len() {
            return;
        }
        staged.stored[i] = staged.times.len() as u8;
        if self.holder[i] != self.me {
            return;
        }
        let c = self.column_of[i] as usize;
        let store = (&mut self.times[c], &mut self.points[c], &mut self.bounds[c]);
        store_staged(
            store,
            &staged.times,
            &staged.points,
            &staged.marked,
            c,
            from,
        );
    }

    /// The error of adding `n` breakpoints one by one when they do not all
    /// fit: the count at the first one that breaks the budget.
    pub fn over_budget(&self, n: usize) -> BudgetExceeded {
        let fitting = self.budget / BYTES_PER_BREAKPOINT;
        BudgetExceeded {
            breakpoints: (self.total + 1).max(fitting + 1).min(self.total + n),
            budget_bytes: self.budget,
        }
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

    /// The polyline of vertex `i`: stored here, or fetched this window.
    ///
    /// # Panics
    /// If vertex `i` is held by another rank and was not fetched: a caller
    /// that forgot [`Trajectories::fetched`] (a bug, never bad input).
    #[inline]
    pub fn of(&self, i: usize) -> Trajectory<'_> {
        debug_assert!(self.staged.times.is_empty(), "read before a flush");
        if self.holder[i] == self.me {
            let c = self.column_of[i] as usize;
            return Trajectory {
                times: &self.times[c],
                points: &self.points[c],
                bounds: Some(&self.bounds[c]),
            };
        }
        let (times, points, bounds) = self.cache.get(&(i as u32)).unwrap_or_else(|| {
            panic!(
                "rank {}: vertex {i}'s trajectory is held by rank {} and was not fetched",
                self.me, self.holder[i]
            )
        });
        Trajectory {
            times,
            points,
            bounds: Some(bounds),
        }
    }

    /// Drops the polylines fetched for this pass's narrow phase and commit,
    /// memory included, once the pass is decided (committed or rolled
    /// back): nothing reads them after that, and a rollback's next pass
    /// would otherwise hold them through its start, where a rank's memory
    /// peaks on the 50k twister over 32 ranks.
    pub fn forget_fetched(&mut self) {
        self.cache = Default::default();
    }

    /// Keeps of the polylines fetched (or computed) here only those of the
    /// vertices `keep` names; the others are dropped, memory included.
    pub fn keep_fetched(&mut self, keep: impl Fn(usize) -> bool) {
        self.cache.retain(|&i, _| keep(i as usize));
        self.cache.shrink_to_fit();
    }

    /// Breakpoints of vertex `i` this window (known on every rank).
    pub fn count(&self, i: usize) -> usize {
        self.count[i] as usize
    }

    /// Whether vertex `i`'s polyline can be read here ([`Trajectories::of`]).
    pub fn readable(&self, i: usize) -> bool {
        self.holder[i] == self.me || self.cache.contains_key(&(i as u32))
    }

    /// Vertex `i`'s polyline as words: its times, then its points' coordinates
    /// (`4 × count(i)` words), for another rank.
    pub fn words_of(&self, i: usize, out: &mut Vec<f64>) {
        let t = self.of(i);
        out.extend_from_slice(t.times);
        out.extend(t.points.iter().flat_map(|p| p.to_array()));
    }

    /// Keeps vertex `i`'s polyline received from its holder as the words of
    /// [`Trajectories::words_of`]; returns how many words it took. Its
    /// block bounds are built here, as the holder built its own.
    pub fn fetched(&mut self, i: usize, words: &[f64]) -> usize {
        let n = self.count[i] as usize;
        let times = words[..n].to_vec();
        let points: Vec<DVec3> = words[n..4 * n]
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        self.keep(i, times, points);
        4 * n
    }

    /// Keeps vertex `i`'s polyline, held by another rank, as this rank
    /// computed it (a scripted vertex's, replayed from the window start),
    /// as [`Trajectories::fetched`] keeps a received one.
    ///
    /// # Panics
    /// If it does not end where every rank's tally of the vertex says (its
    /// count and last time) or at `end`, the vertex's position at the pass
    /// end that every rank holds (bit for bit: each breakpoint's position
    /// is drifted from the one before, so a replay that strayed anywhere
    /// ends elsewhere): a bug.
    pub fn computed(&mut self, i: usize, times: Vec<f64>, points: Vec<DVec3>, end: DVec3) {
        let bits = |p: &DVec3| p.to_array().map(f64::to_bits);
        assert!(
            times.len() == points.len()
                && times.len() == self.count[i] as usize
                && times.last() == Some(&self.last[i])
                && points.last().map(bits) == Some(bits(&end)),
            "rank {}: vertex {i}'s computed polyline ({} breakpoints, the last at {:?}, at {:?}) \
             is not the one its tally gives ({} breakpoints, the last at {}, at {end:?})",
            self.me,
            times.len(),
            times.last(),
            points.last(),
            self.count[i],
            self.last[i]
        );
        self.keep(i, times, points);
    }

    /// Caches vertex `i`'s polyline from elsewhere, with its block bounds
    /// built as its holder built them.
    fn keep(&mut self, i: usize, times: Vec<f64>, points: Vec<DVec3>) {
        let bounds = TrajectoryBounds::from_points(&times, &points);
        self.cache.insert(i as u32, (times, points, bounds));
    }

    /// Bytes of block bounds held (their capacity).
    pub fn bounds_bytes(&self) -> usize {
        self.bounds.iter().map(TrajectoryBounds::bytes).sum()
    }

    /// Bytes of breakpoints held (the capacity of their times and points).
    pub fn breakpoint_bytes(&self) -> usize {
        let times: usize = self.times.iter().map(Vec::capacity).sum();
        let points: usize = self.points.iter().map(Vec::capacity).sum();
        times * std::mem::size_of::<f64>() + points * std::mem::size_of::<DVec3>()
    }

    /// The window's start tick.
    pub fn start(&self) -> Tick {
        self.start
    }

    /// Vertex `i`'s breakpoint count and the relative time of its last one
    /// (what every rank keeps of every vertex).
    pub fn tally(&self, i: usize) -> (u32, f64) {
        (self.count[i], self.last[i])
    }

    /// Sets vertex `i`'s tally to its owner's (over ranks, at the end of a
    /// pass in which this rank did not follow the vertex).
    pub fn set_tally(&mut self, i: usize, (count, last): (u32, f64)) {
        (self.count[i], self.last[i]) = (count, last);
    }

    /// Breakpoints this window (the start points included), of every vertex
    /// — held here or not.
    pub fn breakpoints(&self) -> usize {
        self.total
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.count.len()
    }

    /// True when there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.count.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same window on one memory and on two ranks that each hold half
    /// the vertices: records through `record` and staged through runs (over
    /// more than one set of staged columns, with a breakpoint recorded out
    /// of turn), an instant recorded twice, then every polyline read on
    /// rank 0 (its own, and the others fetched from rank 1) has the bits of
    /// the one-memory polyline, which has the bits of every breakpoint
    /// pushed at once.
    #[test]
    fn held_and_fetched_polylines_equal_the_one_memory_ones() {
        let n = 7;
        let x: Vec<DVec3> = (0..n).map(|i| DVec3::new(i as f64, 0.5, -1.0)).collect();
        let holder: Vec<u32> = (0..n).map(|i| (i % 2) as u32).collect();
        let mut all = Trajectories::new(n, usize::MAX);
        // Rank 0 held all, then its own only; rank 1 made holding its own.
        let mut ranks: Vec<Trajectories> = vec![
            Trajectories::new(n, usize::MAX),
            Trajectories::held_by(holder.clone(), 1, usize::MAX),
        ];
        ranks[0].hold_only(holder.clone(), 0);
        let bounds = [0, 3, n];
        for t in std::iter::once(&mut all).chain(ranks.iter_mut()) {
            t.begin(100, &x);
            for step in 1..=3u64 {
                for i in (0..n).filter(|i| (i + step as usize) % 3 != 0) {
                    let p = x[i] + DVec3::splat(step as f64 * 0.1 + i as f64 * 1e-3);
                    t.record(i, 100 + 10 * step, p).unwrap();
                }
                // the window end right after a kick: the same instant again
                t.record(2, 100 + 10 * step, DVec3::splat(-0.25)).unwrap();
            }
            // Staged internal ticks, more than a set of columns, with a
            // breakpoint recorded out of turn among them.
            let mut added = 0;
            for tick in 0..STAGED_TICKS as u64 + 5 {
                for mut run in t.runs(&bounds, Some(150 + tick)) {
                    run.prepare();
                    for j in (0..run.holder.len()).filter(|j| (j + tick as usize) % 4 != 0) {
                        added += usize::from(run.stage(j, DVec3::new(j as f64, tick as f64, 0.5)));
                    }
                }
                if tick == 7 {
                    t.record(4, 150 + tick, DVec3::splat(-0.5)).unwrap();
                }
            }
            t.add_recorded(added).unwrap();
            t.flush(&crate::executor::Serial, &bounds);
        }
        assert!(ranks.iter().all(|t| t.breakpoints() == all.breakpoints()));
        // Each rank's staged columns hold its own vertices only.
        for (r, t) in ranks.iter().enumerate() {
            let held = holder.iter().filter(|&&h| h == r as u32).count();
            assert_eq!(t.staged.points[0].len(), held, "rank {r}");
            assert_eq!(t.staged.marked[0].len(), held, "rank {r}");
        }
        assert_eq!(all.staged.points[0].len(), n);
        // rank 1 sends rank 0 the polylines of the vertices it holds
        let theirs: Vec<usize> = (0..n).filter(|&i| holder[i] == 1).collect();
        let mut words = Vec::new();
        for &i in &theirs {
            assert!(ranks[1].holds(i) && !ranks[0].readable(i));
            ranks[1].words_of(i, &mut words);
        }
        let mut at = 0;
        for &i in &theirs {
            at += ranks[0].fetched(i, &words[at..]);
        }
        assert_eq!(at, words.len());
        let bits = |t: Trajectory<'_>| {
            let times: Vec<u64> = t.times.iter().map(|v| v.to_bits()).collect();
            let points: Vec<[u64; 3]> = t
                .points
                .iter()
                .map(|p| p.to_array().map(f64::to_bits))
                .collect();
            (times, points)
        };
        // The reference: the same breakpoints pushed one by one, unstaged.
        let mut pushed = Trajectories::new(n, usize::MAX);
        pushed.begin(100, &x);
        for step in 1..=3u64 {
            for i in (0..n).filter(|i| (i + step as usize) % 3 != 0) {
                let p = x[i] + DVec3::splat(step as f64 * 0.1 + i as f64 * 1e-3);
                pushed.record(i, 100 + 10 * step, p).unwrap();
            }
            pushed
                .record(2, 100 + 10 * step, DVec3::splat(-0.25))
                .unwrap();
        }
        for tick in 0..STAGED_TICKS as u64 + 5 {
            for j in 0..n {
                let local = if j < 3 { j } else { j - 3 };
                if (local + tick as usize) % 4 != 0 {
                    let p = DVec3::new(local as f64, tick as f64, 0.5);
                    pushed.record(j, 150 + tick, p).unwrap();
                }
            }
            if tick == 7 {
                pushed.record(4, 150 + tick, DVec3::splat(-0.5)).unwrap();
            }
        }
        assert_eq!(pushed.breakpoints(), all.breakpoints());
        for i in 0..n {
            assert_eq!(bits(all.of(i)), bits(pushed.of(i)), "vertex {i}, staged");
            assert_eq!(ranks[0].count(i), all.of(i).times.len(), "vertex {i}");
            assert_eq!(bits(ranks[0].of(i)), bits(all.of(i)), "vertex {i}");
        }
        // a decided pass forgets the fetched polylines, and so does a new
        // window
        ranks[0].forget_fetched();
        assert!(ranks[0].cache.capacity() == 0);
        assert!(!ranks[0].readable(1) && ranks[0].readable(0));
        ranks[0].fetched(1, &words);
        assert!(ranks[0].readable(1));
        ranks[0].begin(200, &x);
        assert!(!ranks[0].readable(1) && ranks[0].readable(0));
    }

    /// A new holder while ticks are staged (as a placement between windows
    /// may come): what was staged is stored first, the columns shrink to
    /// the vertices now held, and their polylines keep every bit.
    #[test]
    fn a_new_holder_keeps_the_staged_breakpoints_and_shrinks_the_columns() {
        let n = 9;
        let x: Vec<DVec3> = (0..n).map(|i| DVec3::new(i as f64, 0.0, 1.0)).collect();
        let bounds = [0, 4, n];
        let stage = |t: &mut Trajectories, ticks: std::ops::Range<u64>| {
            let mut added = 0;
            for tick in ticks {
                for mut run in t.runs(&bounds, Some(10 + tick)) {
                    run.prepare();
                    for j in 0..run.holder.len() {
                        let p = DVec3::new(j as f64, tick as f64, -2.0);
                        added += usize::from(run.stage(j, p));
                    }
                }
            }
            t.add_recorded(added).unwrap();
        };
        let mut moved = Trajectories::new(n, usize::MAX);
        let mut kept = Trajectories::new(n, usize::MAX);
        for t in [&mut moved, &mut kept] {
            t.begin(0, &x);
            stage(t, 0..5);
        }
        // Vertices 2, 3 and 7 stay with rank 0; the rest go to rank 1.
        let holder: Vec<u32> = (0..n).map(|i| u32::from(![2, 3, 7].contains(&i))).collect();
        moved.hold_only(holder, 0);
        assert_eq!(moved.staged.points[0].len(), 3);
        for t in [&mut moved, &mut kept] {
            stage(t, 5..STAGED_TICKS as u64 + 3);
            t.flush(&crate::executor::Serial, &bounds);
        }
        for i in [2, 3, 7] {
            let (a, b) = (moved.of(i), kept.of(i));
            assert_eq!(a.times, b.times, "vertex {i}");
            assert_eq!(a.points, b.points, "vertex {i}");
            assert_eq!(a.times.len(), STAGED_TICKS + 4);
        }
    }

    /// The block bounds cost at most a quarter of the breakpoints they
    /// bound (by construction 48 bytes per 8 + per 64 + …: 21 %), on
    /// polylines of every length up to 10^4, recorded one by one.
    #[test]
    fn block_bounds_cost_at_most_a_quarter_of_the_breakpoints() {
        let n = 40;
        let x = vec![DVec3::ZERO; n];
        let mut t = Trajectories::new(n, usize::MAX);
        t.begin(0, &x);
        for i in 0..n {
            // vertex i gets 250 i breakpoints
            for k in 1..=250 * i as u64 {
                t.record(i, k, DVec3::new(k as f64, i as f64, 0.5)).unwrap();
            }
        }
        let (bounds, points) = (t.bounds_bytes(), t.breakpoint_bytes());
        assert!(
            bounds * 4 <= points,
            "{bounds} bytes of bounds for {points}"
        );
        assert!(
            bounds * 6 >= points,
            "{bounds} bytes of bounds for {points}: kept?"
        );
        // and they are the bounds the certificates use
        assert!(t.of(39).bounds.is_some_and(|b| b.matches(250 * 39 + 1)));
    }

    /// Room is made for the moving vertices this rank holds, once, and
    /// never beyond the budget.
    #[test]
    fn reserve_makes_room_for_moving_held_vertices_within_the_budget() {
        let x = vec![DVec3::ZERO; 4];
        let mut t = Trajectories::new(4, usize::MAX);
        t.hold_only(vec![0, 0, 0, 1], 0);
        t.begin(0, &x);
        t.reserve(100, |i| i != 1);
        // Vertex 3, held elsewhere, has no storage here at all.
        assert_eq!((t.times.len(), t.points.len(), t.bounds.len()), (3, 3, 3));
        for (i, room) in [(0, true), (1, false), (2, true)] {
            let (times, points) = (t.times[i].capacity(), t.points[i].capacity());
            assert_eq!((times >= 100, points >= 100), (room, room), "vertex {i}");
        }
        // a second window keeps the room and reserves nothing more
        t.begin(10, &x);
        let before = t.points[0].capacity();
        t.reserve(100, |_| true);
        assert_eq!(t.points[0].capacity(), before);
        // 4 moving vertices × 100 breakpoints do not fit in 200 breakpoints
        let mut small = Trajectories::new(4, 200 * BYTES_PER_BREAKPOINT);
        small.begin(0, &x);
        small.reserve(100, |_| true);
        assert!((0..4).all(|i| small.points[i].capacity() < 100));
    }

    #[test]
    #[should_panic(expected = "held by rank 1 and was not fetched")]
    fn reading_an_unfetched_polyline_is_a_bug_caught_loudly() {
        let mut t = Trajectories::new(2, usize::MAX);
        t.hold_only(vec![0, 1], 0);
        t.begin(0, &[DVec3::ZERO, DVec3::ONE]);
        let _ = t.of(1);
    }

    /// A polyline computed here is kept as a fetched one, and only when it
    /// ends where the vertex's tally says, at its end position bit for bit.
    #[test]
    fn a_computed_polyline_is_read_as_fetched_and_must_match_the_tally_until_dropped() {
        let mut t = Trajectories::new(2, usize::MAX);
        t.hold_only(vec![0, 1], 0);
        t.begin(0, &[DVec3::ZERO, DVec3::ONE]);
        t.set_tally(1, (2, 16.0));
        t.computed(1, vec![0.0, 16.0], vec![DVec3::ONE, DVec3::X], DVec3::X);
        assert_eq!(t.of(1).times, [0.0, 16.0]);
        assert_eq!(t.of(1).points, [DVec3::ONE, DVec3::X]);
        let caught = |times: Vec<f64>, points: Vec<DVec3>| {
            let mut t = t.clone();
            let run = std::panic::AssertUnwindSafe(move || t.computed(1, times, points, DVec3::X));
            std::panic::catch_unwind(run).is_err()
        };
        // One breakpoint short, another last time, a point missing.
        assert!(caught(vec![16.0], vec![DVec3::X]));
        assert!(caught(vec![0.0, 15.0], vec![DVec3::ONE, DVec3::X]));
        assert!(caught(vec![0.0, 16.0], vec![DVec3::ONE]));
        // Ending elsewhere, or at a zero of the other sign.
        assert!(caught(vec![0.0, 16.0], vec![DVec3::ONE, DVec3::Y]));
        let signed_zero = DVec3::new(1.0, -0.0, 0.0);
        assert!(caught(vec![0.0, 16.0], vec![DVec3::ONE, signed_zero]));
        // Kept while named, dropped when not (the held ones stay readable).
        t.keep_fetched(|i| i == 1);
        assert!(t.readable(1));
        t.keep_fetched(|i| i != 1);
        assert!(!t.readable(1) && t.readable(0));
    }
}
