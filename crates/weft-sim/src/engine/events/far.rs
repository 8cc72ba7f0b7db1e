//! Far stencils: active stencils kept out of the contact islands' union
//! while they are certified to stay outside `eta_1`.
//!
//! Layer prediction activates many stencils that are never reached (on the
//! 10k twister about 40,000 a window, 98 % of them), and each with two
//! dynamic vertices joins two islands: the sleeve's contacts fuse into one
//! island holding 99.7 % of the layer events, which runs on one thread and
//! one rank. A stencil outside `eta_1` kicks nothing, so it joins nothing
//! while that is *certified*; the islands are built from the other (near)
//! stencils, and a far stencil that may come within `eta_1` is **promoted**:
//! it joins the units its vertices lie in, merged into one.
//!
//! A far stencil's certificate is the dormancy's (`island.rs`, `sleep`):
//! exact at a segment start, it holds until a tick while its vertices move
//! no faster than their speed caps ([`FarSet`]'s, raised to
//! [`HEADROOM`] × a speed that breaks them) with at most
//! [`BREAKPOINTS_PER_WAKE`] breakpoints since it was made. Per segment
//! `[s, e]` (the penalty ticks between two internal ticks and the island
//! batch at the internal tick `e`):
//!
//! 1. **Before** ([`FarSet::before_segment`]): the velocities the internal
//!    tick gave are shown to the caps (and its breakpoint counted); every
//!    far stencil whose cap broke, whose certificate ends by `e`, whose
//!    vertices piled up breakpoints or that passed a check after the last
//!    segment is certified again from its distance at `s` (a lower bound of
//!    the exact distance, `separation_lower_bound`). One that
//!    cannot be certified through `e` is promoted before the segment runs.
//! 2. **During**: an island reports every far vertex whose new speed breaks
//!    its cap (`SegmentOutput::fast`), the caps being fixed for the segment
//!    (over ranks with the units spread, every new speed of a far vertex,
//!    and the ranks watching it compare the largest with their caps: the
//!    same decisions).
//! 3. **After** ([`FarSet::check`], then [`FarSet::commit`]): each far
//!    stencil with such a vertex, or with a vertex that piled up
//!    breakpoints, is checked over `[s, e]` from its distance bound at `s`
//!    and the largest speeds its vertices reached. One that fails is promoted and the merged unit runs
//!    the segment again from the state at `s` (the world is written only
//!    after), until every far stencil left passes.
//!
//! Why that gives the global schedule's bits: a far stencil kicks only
//! inside `eta_1`. Suppose one would, and take the first such kick in time,
//! at tick `t`. Up to `t` no far stencil kicked, so the islands' run equals
//! the global schedule there, and the stencil is within `eta_1` at `t` in
//! that run too (by its evaluated distance; the certificates bound the
//! exact one, so this takes the evaluation to err by less than their
//! margin, as `island.rs`'s scan does). Its certificate then failed at or
//! before `t`: a vertex
//! broke its cap or piled up breakpoints (seen in step 3 of that segment,
//! whose check from the distance bound at `s` and the speeds actually
//! reached is a sound bound and fails, so it is promoted and the segment
//! rerun with it), or the certificate ran out (seen in step 1). So no far
//! stencil left out of an island ever kicks, and zero kicks write nothing.
//!
//! Every decision reads only the state (positions at `s`, the speeds the
//! islands reached), never where anything runs: the units, promotions and
//! reruns — and so the counts of evaluations — are the same on every
//! executor.

use glam::DVec3;
use weft_core::{StencilKey, StencilKind};
use weft_geom::distance::{separation_lower_bound, stencil_closest, Direction};

use super::island::sleep;
use super::CAP_CHECK_RUN;
use crate::clock::Tick;
use crate::dormancy::{breaks_cap, BREAKPOINTS_PER_WAKE, HEADROOM};
use crate::executor::Executor;
use crate::world::World;

/// A far vertex's watchers are certified again after this many of its
/// breakpoints, so that a certificate never spans more than
/// [`BREAKPOINTS_PER_WAKE`] (the rounding `sleep` allows for): it was made
/// after the last renewal, and a segment that adds more than the rest is
/// checked on its own.
const RENEW_AFTER_BREAKPOINTS: u32 = BREAKPOINTS_PER_WAKE / 2;

/// Far stencils per task when they are certified again (a segment renews
/// a few hundred: small tasks keep many threads busy).
const RENEW_RUN: usize = 32;

/// The far stencils of a pass, their certificates and their vertices'
/// speed caps.
#[derive(Debug, Default)]
pub(super) struct FarSet {
    /// Per far stencil this rank watches: its key and depth, its tag (the
    /// caller's: over ranks with the units spread, its index among every
    /// rank's far stencils), the tick its certificate ends (exclusive) and
    /// whether it was promoted.
    key: Vec<StencilKey>,
    depth: Vec<u32>,
    tag: Vec<u32>,
    until: Vec<Tick>,
    promoted: Vec<bool>,
    /// Vertex → far stencils (CSR over every vertex).
    offsets: Vec<u32>,
    of_vertex: Vec<u32>,
    /// Per vertex: its speed cap (`+inf` for a vertex of no far stencil of
    /// this rank, so no island reports it).
    cap: Vec<f64>,
    /// A vertex's breakpoints since its watchers' certificates were last
    /// renewed are `clock - base[i]` ([`FarSet::since`]): `clock` counts the
    /// pass's internal ticks (each may give every vertex a breakpoint),
    /// `base` goes down by the breakpoints islands add. So an internal tick
    /// counts for every far vertex without a visit of each; `renew_at[c]`
    /// lists the vertices whose count reaches [`RENEW_AFTER_BREAKPOINTS`]
    /// when the clock reaches `c` if nothing changes it (stale entries are
    /// skipped).
    clock: i64,
    base: Vec<i64>,
    renew_at: Vec<Vec<u32>>,
    /// The vertices of this rank's far stencils, ascending.
    vertices: Vec<u32>,
    /// Certificate ends `(until, stencil)`; stale entries (promoted, or
    /// renewed to another tick) are skipped.
    due: ByStep,
    /// Far stencils to certify at the next segment start, and those the
    /// last check passed.
    renew: Vec<u32>,
    passed: Vec<u32>,
    /// Scratch of [`FarSet::after_segment`]: per vertex, the largest speed²
    /// an island reached and its breakpoints in the segment.
    fastest: Vec<f64>,
    added: Vec<u32>,
    touched: Vec<u32>,
    /// The pass's end (certificates reaching it need no renewal).
    pass_end: Tick,
}

/// Entries `(tick, id)` taken once a segment reaches their tick, bucketed
/// by the internal step the tick falls in: a heap's pops cost more than the
/// renewals they schedule (about 476,000 a window on the 50k twister).
#[derive(Debug, Default)]
struct ByStep {
    t0: Tick,
    step: Tick,
    /// `buckets[k]`: the entries of ticks in `(t0 + (k-1) step, t0 + k step]`.
    buckets: Vec<Vec<(Tick, u32)>>,
    /// The buckets below it are empty.
    first: usize,
}

impl ByStep {
    fn new(t0: Tick, step: Tick) -> Self {
        ByStep {
            t0,
            step: step.max(1),
            ..Default::default()
        }
    }

    fn slot(&self, t: Tick) -> usize {
        t.saturating_sub(self.t0).div_ceil(self.step) as usize
    }

    fn push(&mut self, t: Tick, id: u32) {
        let k = self.slot(t).max(self.first);
        if self.buckets.len() <= k {
            self.buckets.resize_with(k + 1, Vec::new);
        }
        self.buckets[k].push((t, id));
    }

    /// Calls `f` with (and drops) every entry of tick `<= e`.
    fn take_through(&mut self, e: Tick, mut f: impl FnMut(Tick, u32)) {
        let last = self.slot(e);
        while self.first < self.buckets.len() && self.first <= last {
            let k = self.first;
            let entries = std::mem::take(&mut self.buckets[k]);
            if k < last {
                entries.into_iter().for_each(|(t, id)| f(t, id));
                self.first += 1;
            } else {
                // (`e` inside the step: its later entries stay)
                let (now, later): (Vec<_>, Vec<_>) = entries.into_iter().partition(|p| p.0 <= e);
                now.into_iter().for_each(|(t, id)| f(t, id));
                self.buckets[k] = later;
                break;
            }
        }
    }
}

/// What a far-stencil check evaluated: exact distances, and the smallest.
#[derive(Clone, Copy, Debug)]
pub(super) struct Checked {
    pub evaluations: u64,
    pub min_separation: f64,
}

impl Default for Checked {
    fn default() -> Self {
        Checked {
            evaluations: 0,
            min_separation: f64::INFINITY,
        }
    }
}

impl Checked {
    /// Adds `other`'s evaluations.
    pub(super) fn add(&mut self, other: &Checked) {
        self.evaluations += other.evaluations;
        self.min_separation = self.min_separation.min(other.min_separation);
    }

    pub(super) fn saw(&mut self, d: f64) {
        self.evaluations += 1;
        self.min_separation = self.min_separation.min(d);
    }
}

/// Whether a stencil may be far: it has two dynamic vertices (with one it
/// joins no two islands, so leaving it out would split nothing).
pub(super) fn may_be_far(w: &World, key: &StencilKey) -> bool {
    key.v
        .iter()
        .filter(|&&i| w.inv_mass[i as usize] > 0.0)
        .count()
        >= 2
}

/// Position of vertex `i` at tick `t` (the engine's drift).
#[inline]
fn pos_at(w: &World, i: u32, t: Tick) -> DVec3 {
    let i = i as usize;
    w.lattice.drift(w.x[i], w.v[i], w.tau[i], t)
}

/// The tick up to which (exclusive) a stencil of vertices `v` is certified
/// outside `eta_1` from tick `t` on while its vertices keep to `caps`
/// (`None`: not even through `t + 1`), with the evaluated distance at `t`.
fn certify(
    w: &World,
    kind: StencilKind,
    v: &[u32; 4],
    caps: &[f64; 4],
    t: Tick,
) -> (Option<Tick>, f64) {
    let x: [DVec3; 4] = std::array::from_fn(|j| pos_at(w, v[j], t));
    let c = stencil_closest(kind, &x);
    let lower = separation_lower_bound(kind, Direction::along(c.n), &x);
    let (awake_at, room) = sleep(
        kind,
        lower,
        // (layer 1's thickness as the kicks compare it, which can be an
        // ulp off `eta_1`)
        w.schedule.eta(1),
        &x,
        caps,
        w.lattice.quantum,
        t,
    );
    ((room > 0.0 && awake_at > t).then_some(awake_at), c.d)
}

/// [`certify`] at `t`, under each vertex's cap `cap(i)`, of the `n`
/// stencils `key` gives (`None`: not one to certify), on the executor in
/// runs of [`RENEW_RUN`]; in order.
fn certify_in_runs<E: Executor>(
    exec: &E,
    w: &World,
    n: usize,
    key: &(dyn Fn(usize) -> Option<StencilKey> + Sync),
    cap: &(dyn Fn(u32) -> f64 + Sync),
    t: Tick,
) -> Vec<Option<(Option<Tick>, f64)>> {
    let runs = exec.map(n.div_ceil(RENEW_RUN), &|r| {
        (r * RENEW_RUN..((r + 1) * RENEW_RUN).min(n))
            .map(|k| key(k).map(|key| certify(w, key.kind, &key.v, &key.v.map(cap), t)))
            .collect::<Vec<_>>()
    });
    runs.into_iter().flatten().collect()
}

/// The pass start's cap of vertex `i`: [`HEADROOM`] × its speed.
fn start_cap(w: &World) -> impl Fn(u32) -> f64 + Sync + '_ {
    |i| cap_of(w.v[i as usize])
}

/// Of each of the stencils `keys`, whether it is far at the pass start
/// `t0` and then the tick its certificate ends (as [`FarSet::new`] decides
/// it: certified through `first_internal` under caps of [`HEADROOM`] × its
/// vertices' speeds), with the distance evaluated: over ranks with the
/// units spread, each rank certifies a share of the candidates, the ranks
/// all-gather the answers, and each builds the far stencils it watches
/// from them ([`FarSet::of_certified`]).
pub(super) fn far_at_start<E: Executor>(
    exec: &E,
    w: &World,
    keys: &[StencilKey],
    (t0, first_internal): (Tick, Tick),
) -> Vec<(Option<Tick>, f64)> {
    let certified = certify_in_runs(exec, w, keys.len(), &|k| Some(keys[k]), &start_cap(w), t0);
    (certified.into_iter())
        .map(|c| {
            let (until, d) = c.expect("each one certified");
            (until.filter(|&u| u > first_internal), d)
        })
        .collect()
}

/// The speed cap a velocity sets: [`HEADROOM`] × its speed.
fn cap_of(v: DVec3) -> f64 {
    HEADROOM * v.length()
}

impl FarSet {
    /// Of the `candidates` (active stencils that [`may_be_far`], with their
    /// depth and a tag, in key order), the far ones at the pass start `t0`:
    /// certified outside `eta_1` through the first internal tick after
    /// `t0` under caps of [`HEADROOM`] × their vertices' speeds. `mine`
    /// tells by tag which ones this rank keeps (the tag: a pack this rank
    /// runs); only those are certified (the others are returned as not
    /// far). (Over ranks with the units spread, the ranks certify shares
    /// of the candidates instead: [`far_at_start`].)
    /// Returns the set and, per candidate, whether it is far.
    pub(super) fn new<E: Executor>(
        exec: &E,
        w: &World,
        candidates: &[(StencilKey, u32, u32)],
        mine: &(dyn Fn(u32) -> bool + Sync),
        (t0, first_internal, pass_end): (Tick, Tick, Tick),
        checked: &mut Checked,
    ) -> (Self, Vec<bool>) {
        let mut is_far = vec![false; candidates.len()];
        // The certificates, on the executor in runs, then taken in order
        // (each vertex's cap from its speed as it is read: an array of
        // them over every vertex was made for a few).
        let mine_key = |c: usize| {
            let (key, _, pack) = candidates[c];
            mine(pack).then_some(key)
        };
        let certified = certify_in_runs(exec, w, candidates.len(), &mine_key, &start_cap(w), t0);
        let mut far = Vec::new();
        for (c, (&(key, depth, tag), certificate)) in candidates.iter().zip(certified).enumerate() {
            let Some((until, d)) = certificate else {
                continue;
            };
            checked.saw(d);
            let Some(until) = until.filter(|&u| u > first_internal) else {
                continue;
            };
            is_far[c] = true;
            far.push((key, depth, tag, until));
        }
        let set = Self::of_certified(w, far, (t0, first_internal, pass_end));
        (set, is_far)
    }

    /// The far stencils `far` (key, depth, tag, and the tick its
    /// certificate at the pass start `t0` ends, after `first_internal`; in
    /// key order), certified already ([`FarSet::new`], or
    /// [`far_at_start`] over ranks).
    pub(super) fn of_certified(
        w: &World,
        far: Vec<(StencilKey, u32, u32, Tick)>,
        (t0, first_internal, pass_end): (Tick, Tick, Tick),
    ) -> Self {
        let n = w.num_vertices();
        let mut set = FarSet {
            due: ByStep::new(t0, first_internal - t0),
            cap: vec![f64::INFINITY; n],
            base: vec![0; n],
            fastest: vec![0.0; n],
            added: vec![0; n],
            pass_end,
            ..Default::default()
        };
        for (key, depth, tag, until) in far {
            let f = set.key.len() as u32;
            set.key.push(key);
            set.depth.push(depth);
            set.tag.push(tag);
            set.until.push(until);
            set.promoted.push(false);
            if until < pass_end {
                set.due.push(until, f);
            }
        }
        // The vertex index over the far stencils, and their vertices' caps
        // (the others' +inf: nothing watches them).
        set.offsets = vec![0; n + 1];
        for key in &set.key {
            for &i in &key.v {
                set.offsets[i as usize + 1] += 1;
            }
        }
        for i in 0..n {
            set.offsets[i + 1] += set.offsets[i];
        }
        set.of_vertex = vec![0; set.offsets[n] as usize];
        let mut fill = set.offsets.clone();
        for (f, key) in set.key.iter().enumerate() {
            for &i in &key.v {
                set.of_vertex[fill[i as usize] as usize] = f as u32;
                fill[i as usize] += 1;
            }
        }
        for i in 0..n {
            if set.offsets[i] < set.offsets[i + 1] {
                set.cap[i] = cap_of(w.v[i]);
                set.vertices.push(i as u32);
            }
        }
        let limit = RENEW_AFTER_BREAKPOINTS as usize;
        set.renew_at = vec![Vec::new(); limit + 1];
        set.renew_at[limit] = set.vertices.clone();
        set
    }

    /// How many far stencils the pass started with.
    pub(super) fn len(&self) -> usize {
        self.key.len()
    }

    /// Per vertex, its speed cap (`+inf`: no far stencil watches it): what
    /// the islands report a breaking speed against.
    pub(super) fn caps(&self) -> &[f64] {
        &self.cap
    }

    /// Far stencil `f`'s key and depth (its layers when promoted) and tag.
    pub(super) fn stencil(&self, f: u32) -> (StencilKey, u32, u32) {
        let f = f as usize;
        (self.key[f], self.depth[f], self.tag[f])
    }

    /// Whether a far stencil watches vertex `i`.
    pub(super) fn watches(&self, i: usize) -> bool {
        self.offsets.get(i) != self.offsets.get(i + 1)
    }

    /// The far stencils watching vertex `i`.
    fn watchers(&self, i: usize) -> &[u32] {
        &self.of_vertex[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Vertex `i`'s breakpoints since its watchers were last certified.
    fn since(&self, i: usize) -> i64 {
        self.clock - self.base[i]
    }

    /// Vertex `i`'s count starts again, its watchers to be certified again
    /// at this segment's start.
    fn restart(&mut self, i: u32) {
        let iu = i as usize;
        self.base[iu] = self.clock;
        self.schedule_renewal(i);
        let (a, b) = (self.offsets[iu] as usize, self.offsets[iu + 1] as usize);
        self.renew.extend_from_slice(&self.of_vertex[a..b]);
    }

    /// Notes when vertex `i`'s count reaches the limit if nothing else
    /// changes it.
    fn schedule_renewal(&mut self, i: u32) {
        let at = self.base[i as usize] + i64::from(RENEW_AFTER_BREAKPOINTS);
        // (always after the clock: a count at the limit restarts at once;
        // were it not, the next internal tick still looks)
        let at = at.max(self.clock + 1) as usize;
        if self.renew_at.len() <= at {
            self.renew_at.resize_with(at + 1, Vec::new);
        }
        self.renew_at[at].push(i);
    }

    /// Step 1, at the start `s` of a segment ending at `e`: shows the
    /// velocities an internal tick gave to the caps, counts its breakpoint,
    /// and certifies again every far stencil that needs it. Returns those
    /// that cannot be certified through `e`, ascending (the caller promotes
    /// them; they are marked promoted here).
    pub(super) fn before_segment<E: Executor>(
        &mut self,
        exec: &E,
        w: &World,
        (s, e): (Tick, Tick),
        after_internal: bool,
        checked: &mut Checked,
    ) -> Vec<u32> {
        if self.key.is_empty() {
            return Vec::new();
        }
        if after_internal {
            // Every internal tick may give each vertex a breakpoint.
            self.clock += 1;
            // The far vertices whose new speed breaks their cap, found on
            // the executor (reads only), then given caps of their speeds.
            let (vertices, cap) = (&self.vertices, &self.cap);
            let broke = exec.map(vertices.len().div_ceil(CAP_CHECK_RUN), &|r| {
                let run =
                    &vertices[r * CAP_CHECK_RUN..((r + 1) * CAP_CHECK_RUN).min(vertices.len())];
                (run.iter().copied())
                    // (the units' test: a NaN speed breaks every cap)
                    .filter(|&i| breaks_cap(w.v[i as usize], cap[i as usize]))
                    .collect::<Vec<u32>>()
            });
            for i in broke.into_iter().flatten() {
                self.cap[i as usize] = cap_of(w.v[i as usize]);
                self.restart(i);
            }
            // Those whose breakpoints reached the limit.
            let reached = (self.renew_at.get_mut(self.clock as usize)).map(std::mem::take);
            for i in reached.unwrap_or_default() {
                if self.since(i as usize) >= i64::from(RENEW_AFTER_BREAKPOINTS) {
                    self.restart(i);
                }
            }
        }
        let (due, until, renew) = (&mut self.due, &self.until, &mut self.renew);
        due.take_through(e, |t, f| {
            if until[f as usize] == t {
                renew.push(f);
            }
        });
        let mut renew = std::mem::take(&mut self.renew);
        renew.sort_unstable();
        renew.dedup();
        renew.retain(|&f| !self.promoted[f as usize]);
        // The certificates, on the executor in runs, then applied in order.
        let key = |k: usize| Some(self.key[renew[k] as usize]);
        let cap = |i: u32| self.cap[i as usize];
        let certified = certify_in_runs(exec, w, renew.len(), &key, &cap, s);
        let certified = certified
            .into_iter()
            .map(|c| c.expect("each one certified"));
        let mut promote = Vec::new();
        for (&f, (until, d)) in renew.iter().zip(certified) {
            let fu = f as usize;
            checked.saw(d);
            match until.filter(|&u| u > e) {
                Some(u) => {
                    let u = if u >= self.pass_end { Tick::MAX } else { u };
                    self.until[fu] = u;
                    if u != Tick::MAX {
                        self.due.push(u, f);
                    }
                }
                None => {
                    self.promoted[fu] = true;
                    promote.push(f);
                }
            }
        }
        renew.clear();
        self.renew = renew;
        promote
    }

    /// Step 3, after the islands ran `[s, e]` from the world's state at `s`
    /// (not yet written): of the far stencils whose vertices broke their
    /// caps (`fast`: `(vertex, speed²)`) or piled up breakpoints (`added`:
    /// `(vertex, count)`) in the segment (over every unit's output, reruns
    /// included), those that may have come within `eta_1` in it. Returns
    /// them ascending, marked promoted (the
    /// caller merges them into units and reruns those, then checks again);
    /// with none, [`FarSet::commit`] ends the segment. Changes nothing else,
    /// so a check after a rerun sees only the final outputs.
    pub(super) fn check(
        &mut self,
        w: &World,
        (s, e): (Tick, Tick),
        fast: impl Iterator<Item = (u32, f64)>,
        added: impl Iterator<Item = (u32, u32)>,
        checked: &mut Checked,
    ) -> Vec<u32> {
        self.clear_scratch();
        if self.key.is_empty() {
            return Vec::new();
        }
        for (i, speed2) in fast {
            let iu = i as usize;
            self.touch(i);
            self.fastest[iu] = self.fastest[iu].max(speed2);
        }
        for (i, count) in added {
            let iu = i as usize;
            if self.watches(iu) && count > 0 {
                self.touch(i);
                self.added[iu] += count;
            }
        }
        let mut doubtful = Vec::new();
        for &i in &self.touched {
            let iu = i as usize;
            let broke = self.fastest[iu] > self.cap[iu] * self.cap[iu];
            let since = self.since(iu) + i64::from(self.added[iu]);
            if broke || since >= i64::from(RENEW_AFTER_BREAKPOINTS) {
                doubtful.extend_from_slice(self.watchers(iu));
            }
        }
        doubtful.sort_unstable();
        doubtful.dedup();
        let mut promote = Vec::new();
        self.passed.clear();
        for &f in &doubtful {
            let fu = f as usize;
            if self.promoted[fu] {
                continue;
            }
            let key = self.key[fu];
            // The segment's own breakpoints must stay within what the
            // bound's rounding allows for.
            let piled = (key.v.iter()).any(|&i| self.added[i as usize] > BREAKPOINTS_PER_WAKE);
            // Over [s, e] each vertex moved no faster than its cap, or than
            // the largest speed it reached where that broke the cap.
            let caps = key.v.map(|i| {
                let i = i as usize;
                self.cap[i].max(self.fastest[i].sqrt())
            });
            let (until, d) = certify(w, key.kind, &key.v, &caps, s);
            checked.saw(d);
            if piled || until.is_none_or(|u| u <= e) {
                self.promoted[fu] = true;
                promote.push(f);
            } else {
                self.passed.push(f);
            }
        }
        promote
    }

    /// The end of a segment whose last [`FarSet::check`] promoted nothing:
    /// the caps its outputs broke are raised, their breakpoints counted,
    /// and the far stencils that check passed (their premises failed in
    /// the segment, which they survived) are certified again at the next
    /// segment start.
    pub(super) fn commit(&mut self) {
        for k in 0..self.touched.len() {
            let i = self.touched[k];
            let iu = i as usize;
            if self.fastest[iu] > self.cap[iu] * self.cap[iu] {
                self.cap[iu] = HEADROOM * self.fastest[iu].sqrt();
            }
            if self.added[iu] > 0 {
                self.base[iu] -= i64::from(self.added[iu]);
                if self.since(iu) >= i64::from(RENEW_AFTER_BREAKPOINTS) {
                    // (its watchers were checked, `passed`)
                    self.base[iu] = self.clock;
                }
                self.schedule_renewal(i);
            }
        }
        self.renew.append(&mut self.passed);
        self.clear_scratch();
    }

    /// Lists vertex `i` in the check's scratch.
    fn touch(&mut self, i: u32) {
        let iu = i as usize;
        if self.fastest[iu] == 0.0 && self.added[iu] == 0 {
            self.touched.push(i);
        }
    }

    fn clear_scratch(&mut self) {
        for &i in &self.touched {
            self.fastest[i as usize] = 0.0;
            self.added[i as usize] = 0;
        }
        self.touched.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use weft_testkit::Rng;

    /// The certificate ends' buckets hand out exactly the entries a sorted
    /// list would, at every segment end (internal ticks, and ends inside a
    /// step), each once.
    #[test]
    fn certificate_ends_by_step_are_taken_as_a_sorted_list_takes_them() {
        let mut rng = Rng(0x5eed_2026);
        for case in 0..200 {
            let t0 = rng.below(1 << 40);
            let step = 1 + rng.below(1 << 20);
            let mut buckets = ByStep::new(t0, step);
            let mut oracle: Vec<(Tick, u32)> = Vec::new();
            let mut e = t0;
            let mut id = 0u32;
            for _ in 0..50 {
                // Entries are pushed after the last segment end, as
                // certificates end after the segment they were made in.
                for _ in 0..rng.below(20) {
                    let t = e + 1 + rng.below(4 * step);
                    buckets.push(t, id);
                    oracle.push((t, id));
                    id += 1;
                }
                e += if rng.below(4) == 0 {
                    1 + rng.below(step)
                } else {
                    step - (e - t0) % step
                };
                let mut got = Vec::new();
                buckets.take_through(e, |t, i| got.push((t, i)));
                let (mut want, rest): (Vec<_>, Vec<_>) = oracle.iter().partition(|p| p.0 <= e);
                oracle = rest;
                got.sort_unstable();
                want.sort_unstable();
                assert_eq!(got, want, "case {case}, segment end {e}");
            }
        }
    }
}
