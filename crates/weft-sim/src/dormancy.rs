//! Which active stencils a penalty batch must look at.
//!
//! A batch at tick `t` fires layers `first..` (its outermost firing layer is
//! `first`, whose `eta` is the largest); a stencil whose distance is certainly
//! at least `eta_first` kicks zero in it. Each stencil has a **reach**: the
//! outermost layers it may still be inside. A batch reads a stencil only if
//! `first ≤ reach`.
//!
//! * *awake*: reach = its depth (every batch of its layers reads it);
//! * *dozing*: certified outside `eta_(m+1)` until some tick (as long as its
//!   vertices stay under their speed caps, `engine::events::island::sleep`):
//!   reach = `m`, so batches of the deeper layers `m+1..` only (the frequent
//!   ones: `h_l` shrinks as `l^(-3/2)`) skip it;
//! * *asleep*: certified outside `eta_1` until some tick: reach 0, no batch
//!   reads it.
//!
//! A dozing or asleep stencil wakes (reach back to its depth) when its tick
//! comes (a queue of wake ticks, `WakeQueue`) or when one of its vertices
//! breaks its certificate's assumption (a vertex → stencils index),
//! whichever is first.
//!
//! ## Speed caps
//!
//! Each vertex has a **speed cap**, and a certificate assumes that its
//! vertices move no faster than their caps, not that they keep their
//! velocities. Every velocity change of a vertex is shown to
//! [`Dormancy::observe`]: a new speed above the cap wakes the vertex's
//! stencils and raises the cap ([`HEADROOM`] above the speed); under the cap
//! nothing wakes. An internal tick changes every velocity, usually a little:
//! under caps, a certificate outlives it, and an asleep island stays
//! asleep over many internal ticks instead of being read again after each.
//!
//! Lowering a cap needs no wake: a certificate made under a higher cap is
//! only woken sooner. Raising one does (its stencils' certificates may
//! assume the lower cap), so a cap rises only with a wake.
//!
//! A vertex also wakes its stencils after [`BREAKPOINTS_PER_WAKE`]
//! breakpoints, which bounds the rounding of the positions drifted over them
//! that a certificate must allow for.
//!
//! The kinematic vertices (a rod, a paddle) are read by many islands; their
//! caps are kept once, by [`SharedCaps`], and shown each internal tick's
//! velocities once: a vertex that breaks its cap is reported, and each
//! island watching it wakes its stencils of it before its next batch.
//!
//! So a batch costs what the stencils that may kick in it cost, not what the
//! whole active set does.
//!
//! Skipping only ever drops stencils whose exact distance is outside the
//! firing layers, so their kicks are zero and the results are the same bits
//! as visiting every stencil, wherever an evaluation errs by less than the
//! certificates' margin (`engine::events::island`).

use glam::DVec3;
use weft_core::NONE;

use crate::clock::Tick;

/// A raised speed cap is this much above the speed that raised it.
pub const HEADROOM: f64 = 1.25;

/// A vertex wakes its stencils after this many breakpoints.
pub const BREAKPOINTS_PER_WAKE: u32 = 1024;

/// The reach of every active stencil of one pass.
#[derive(Clone, Debug, Default)]
pub struct Dormancy {
    /// Per stencil: what its wake-ups and dozes read and write, in one
    /// record (a wake due from the queue reads one record, not four arrays).
    stencils: Vec<Reach>,
    /// Wake ticks, counted from `base`; an entry whose stencil is awake, or
    /// dozes until another tick, is stale and ignored.
    due: WakeQueue,
    /// The tick wake ticks count from (the pass's start).
    base: Tick,
    /// `by_reach[r]`: the stencils of reach `r ≥ 1`, unordered (a batch
    /// whose outermost firing layer is `first` reads the lists `first..`
    /// only, and the schedule asks for the largest reach at every tick).
    by_reach: Vec<Vec<u32>>,
    /// Vertex → active stencils (CSR).
    offsets: Vec<u32>,
    of_vertex: Vec<u32>,
    /// Per vertex: its speed cap, and its breakpoints since it last woke
    /// its stencils.
    cap: Vec<f64>,
    since: Vec<u32>,
}

impl Dormancy {
    /// Every stencil awake, for stencils of the given depths on the vertices
    /// `stencils` (four each; `NONE` entries are vertices whose velocity never
    /// changes here, and are left out of the index) over `n` vertices; every
    /// speed cap 0 (show each vertex's velocity to [`Dormancy::observe`]
    /// before the first certificate); no wake tick before `base`.
    pub fn reset(&mut self, stencils: &[[u32; 4]], depths: &[u32], n: usize, base: Tick) {
        self.stencils.clear();
        self.due.clear();
        self.base = base;
        let deepest = depths.iter().copied().max().unwrap_or(0) as usize;
        self.by_reach.iter_mut().for_each(Vec::clear);
        self.by_reach.resize(deepest + 1, Vec::new());
        for (a, &depth) in depths.iter().enumerate() {
            let list = &mut self.by_reach[depth as usize];
            self.stencils.push(Reach {
                depth,
                reach: depth,
                slot: list.len() as u32,
                until: 0,
            });
            list.push(a as u32);
        }
        self.offsets.clear();
        self.offsets.resize(n + 1, 0);
        let listed = |v: &[u32; 4]| v.iter().copied().filter(|&i| i != NONE).collect::<Vec<_>>();
        for v in stencils {
            for i in listed(v) {
                self.offsets[i as usize + 1] += 1;
            }
        }
        for i in 0..n {
            self.offsets[i + 1] += self.offsets[i];
        }
        self.cap.clear();
        self.cap.resize(n, 0.0);
        self.since.clear();
        self.since.resize(n, 0);
        self.of_vertex.clear();
        self.of_vertex.resize(self.offsets[n] as usize, 0);
        let mut fill = self.offsets.clone();
        for (a, v) in stencils.iter().enumerate() {
            for i in listed(v) {
                self.of_vertex[fill[i as usize] as usize] = a as u32;
                fill[i as usize] += 1;
            }
        }
    }

    /// The stencils a batch may read (reach above 0), unordered.
    pub fn awake(&self) -> impl Iterator<Item = u32> + '_ {
        self.reading(1)
    }

    /// The stencils a batch whose outermost firing layer is `first` reads
    /// (reach at least `first`), unordered.
    pub fn reading(&self, first: u32) -> impl Iterator<Item = u32> + '_ {
        self.reading_lists(first)
            .flat_map(|list| list.iter().copied())
    }

    /// [`Dormancy::reading`] as the lists it is made of (copied whole, they
    /// cost a batch less than one stencil at a time: with many small
    /// islands, batches are many).
    pub fn reading_lists(&self, first: u32) -> impl Iterator<Item = &[u32]> + '_ {
        (self.by_reach.iter().skip(first.max(1) as usize)).map(Vec::as_slice)
    }

    /// The largest reach of any stencil (0: all asleep).
    pub fn max_reach(&self) -> u32 {
        (self.by_reach.iter().skip(1))
            .rposition(|list| !list.is_empty())
            .map_or(0, |r| r as u32 + 1)
    }

    /// Stencil `a`'s reach: a batch whose outermost firing layer is deeper
    /// skips it.
    pub fn reach(&self, a: u32) -> u32 {
        self.stencils[a as usize].reach
    }

    /// The earliest tick at which a dozing or asleep stencil is due to wake
    /// (stale entries included: never later than the truth).
    pub fn next_due(&mut self) -> Option<Tick> {
        self.due.least().map(|at| self.base + at as Tick)
    }

    /// Wakes the stencils whose wake tick is at or before `t` (never before
    /// a tick already passed here: the ticks only go forward).
    pub fn wake_due(&mut self, t: Tick) {
        let through = t.saturating_sub(self.base).min(u32::MAX as Tick) as u32;
        while let Some((at, due)) = self.due.take_through(through) {
            for &(_, a) in &due {
                let s = &self.stencils[a as usize];
                if s.reach < s.depth && s.until == self.base + at as Tick {
                    self.wake(a);
                }
            }
            self.due.give_back(due);
        }
    }

    /// Wakes the stencils of vertex `i` (its velocity changed).
    pub fn wake_vertex(&mut self, i: usize) {
        let (s, e) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        for k in s..e {
            self.wake(self.of_vertex[k]);
        }
    }

    /// Vertex `i`'s speed cap: a certificate may assume that it moves no
    /// faster until one of its stencils wakes.
    #[inline]
    pub fn cap(&self, i: usize) -> f64 {
        self.cap[i]
    }

    /// The most breakpoints any of vertices `0..n` has had since it last
    /// woke its stencils.
    pub fn most_breakpoints(&self, n: usize) -> u32 {
        self.since[..n].iter().copied().max().unwrap_or(0)
    }

    /// Vertices `0..n` had `k` breakpoints more, none of them with a speed
    /// above its cap (internal ticks while their island was not visited:
    /// the units checked their speeds against the caps), and fewer than
    /// [`BREAKPOINTS_PER_WAKE`] in all since they last woke their stencils.
    pub fn add_breakpoints(&mut self, n: usize, k: u32) {
        for s in &mut self.since[..n] {
            *s += k;
            debug_assert!(*s < BREAKPOINTS_PER_WAKE);
        }
    }

    /// Vertex `i` has a new velocity `v` (and a breakpoint): wakes its
    /// stencils when [`speed_cap_rule`] says so.
    #[inline]
    pub fn observe(&mut self, i: usize, v: DVec3) {
        if speed_cap_rule(&mut self.cap[i], &mut self.since[i], v) {
            self.wake_vertex(i);
        }
    }

    fn wake(&mut self, a: u32) {
        let s = &self.stencils[a as usize];
        if s.reach < s.depth {
            self.set_reach(a, s.depth); // (its queued wake, if any, is stale now)
        }
    }

    /// Moves stencil `a` to the list of reach `r` (none for 0).
    fn set_reach(&mut self, a: u32, r: u32) {
        let i = a as usize;
        let old = self.stencils[i].reach as usize;
        if old == r as usize {
            return;
        }
        if old > 0 {
            let list = &mut self.by_reach[old];
            let at = self.stencils[i].slot as usize;
            list.swap_remove(at);
            if let Some(&moved) = list.get(at) {
                self.stencils[moved as usize].slot = at as u32;
            }
        }
        if r > 0 {
            let list = &mut self.by_reach[r as usize];
            self.stencils[i].slot = list.len() as u32;
            list.push(a);
        }
        self.stencils[i].reach = r;
    }

    /// Lowers stencil `a`'s reach to `reach` (0: asleep) until tick `until`
    /// (`Tick::MAX`: until one of its vertices wakes it).
    pub fn doze(&mut self, a: u32, reach: u32, until: Tick) {
        let i = a as usize;
        debug_assert!(reach < self.stencils[i].depth);
        debug_assert!(until > self.base);
        // A wake tick more than 2^32 ticks after the base wakes it there
        // instead (earlier is always safe).
        let until = if until == Tick::MAX {
            until
        } else {
            until.min(self.base + u32::MAX as Tick)
        };
        let s = &self.stencils[i];
        if reach == s.reach && until <= s.until {
            return; // what it certifies holds already, at least as long
        }
        if until != Tick::MAX {
            let at = (until - self.base) as u32;
            if at <= self.due.last {
                // Only 2^32 ticks or more after the base (the clamp): a wake
                // tick the queue has passed, which it cannot take. It would
                // wake at the next look for due stencils, before any batch
                // reads it: it wakes now instead.
                self.wake(a);
                return;
            }
            self.due.push(at, a);
        }
        self.set_reach(a, reach);
        self.stencils[i].until = until;
    }
}

/// One vertex's speed cap with a new velocity `v` (and a breakpoint):
/// returns whether the vertex must wake its stencils — its speed exceeds
/// the cap (or is not finite), and the cap is raised to [`HEADROOM`] × the
/// speed, or it has had [`BREAKPOINTS_PER_WAKE`] breakpoints since it last
/// woke them; lowers the cap (no wake) when the speed fell below half of it
/// (free: see the module docs).
///
/// The test compares squares: the computed `|v|^2` and `cap^2` are within
/// a few ulps of the exact ones, which the certificates' `2^-40` margin on
/// the caps covers (`engine::events::island::sleep`).
#[inline]
pub fn speed_cap_rule(cap: &mut f64, since: &mut u32, v: DVec3) -> bool {
    *since += 1;
    let s2 = v.length_squared();
    if breaks_cap(v, *cap) || *since >= BREAKPOINTS_PER_WAKE {
        // (a speed that is not finite gets an infinite cap: no certificate
        // then; NaN would read as 0 in `f64::max`)
        *cap = if s2 <= f64::MAX {
            s2.sqrt() * HEADROOM
        } else {
            f64::INFINITY
        };
        *since = 0;
        true
    } else {
        if lowers_cap(s2, *cap) {
            *cap = s2.sqrt() * HEADROOM;
        }
        false
    }
}

/// Whether a speed² `s2` under cap `cap` lowers it in [`speed_cap_rule`]:
/// the speed fell below half of the cap.
#[inline]
fn lowers_cap(s2: f64, cap: f64) -> bool {
    4.0 * s2 < cap * cap
}

/// Whether [`speed_cap_rule`] would change cap `cap` with the new velocity
/// `v` (raise it with a wake, or lower it): what an island that skips
/// observing a velocity must rule out, so that the skip leaves every cap —
/// and so every later certificate and count — as the observation would.
#[inline]
pub fn changes_cap(v: DVec3, cap: f64) -> bool {
    breaks_cap(v, cap) || lowers_cap(v.length_squared(), cap)
}

/// Whether velocity `v` breaks speed cap `cap`: its speed is above it or
/// not finite (the test of [`speed_cap_rule`], which anything that skips
/// the rule must make the same way).
#[inline]
pub fn breaks_cap(v: DVec3, cap: f64) -> bool {
    !(v.length_squared() <= cap * cap)
}

/// Speed caps kept once for vertices that many islands watch: the
/// kinematic vertices (a rod every unit touching it reads), whose velocity
/// changes only at internal ticks. The same rule as a [`Dormancy`]'s own
/// vertices ([`speed_cap_rule`]); a vertex that must wake its stencils is
/// reported, and every island watching it wakes its stencils of it before
/// its next batch (`engine::events::island`), so a certificate may assume
/// these caps as it does its own.
#[derive(Clone, Debug, Default)]
pub struct SharedCaps {
    /// The vertices (ascending).
    ids: Vec<u32>,
    cap: Vec<f64>,
    since: Vec<u32>,
}

impl SharedCaps {
    /// The caps of the vertices `ids` (ascending), their velocities `v(i)`
    /// shown once.
    pub fn new(ids: Vec<u32>, v: impl Fn(u32) -> DVec3) -> Self {
        let mut caps = SharedCaps {
            cap: vec![0.0; ids.len()],
            since: vec![0; ids.len()],
            ids,
        };
        caps.observe(v, &mut Vec::new());
        caps
    }

    /// Every vertex has a new velocity `v(i)` (an internal tick): appends
    /// to `woken` (ascending) those that must wake their stencils.
    pub fn observe(&mut self, v: impl Fn(u32) -> DVec3, woken: &mut Vec<u32>) {
        for (k, &i) in self.ids.iter().enumerate() {
            if speed_cap_rule(&mut self.cap[k], &mut self.since[k], v(i)) {
                woken.push(i);
            }
        }
    }

    /// Vertex `i`'s slot (`None`: not kept here).
    pub fn slot(&self, i: u32) -> Option<usize> {
        self.ids.binary_search(&i).ok()
    }

    /// The caps, by slot.
    pub fn caps(&self) -> &[f64] {
        &self.cap
    }
}

/// One stencil's reach and what keeps it (24 bytes).
#[derive(Clone, Copy, Debug)]
struct Reach {
    depth: u32,
    /// The outermost layers a batch must read it for (≤ depth; 0: asleep).
    reach: u32,
    /// Its place in `Dormancy::by_reach[reach]`.
    slot: u32,
    /// Below its depth: the tick its reach is restored (`Tick::MAX`: when
    /// a vertex wakes it).
    until: Tick,
}

/// The wake ticks of the dozing stencils: a monotone priority queue (a
/// radix heap, Ahuja, Mehlhorn, Orlin and Tarjan 1990). Every tick pushed
/// is later than every tick taken (a stencil dozes until after the batch
/// that certified it, and batches go forward; past the clamp of wake ticks
/// 2^32 ticks after the base, `Dormancy::doze` wakes it instead of pushing
/// a tick already passed), which lets entries wait in
/// buckets by their highest bit that differs from the last tick taken:
/// pushing is one append, and each entry is moved to a lower bucket a few
/// times before it is taken. A binary heap of one word per entry cost a
/// third of the giant island's time on the 50k twister (a pop per wake, 4
/// million a window, each a 16-level sift through a heap of L2 size).
///
/// Entries at the same tick come out in no particular order: waking sets a
/// stencil's reach, and the batch sorts what it reads.
#[derive(Clone, Debug, Default)]
struct WakeQueue {
    /// `buckets[b]` (b = 1..=32): the entries `(tick, stencil)` whose tick
    /// first differs from `last` in bit `b - 1` (they are all later than
    /// `last`: that bit is 1 in them, 0 in `last`); `buckets[0]` is empty
    /// between calls. Entries of a lower bucket are all earlier than those
    /// of a higher one.
    buckets: Vec<Vec<(u32, u32)>>,
    /// Bit `b` set: `buckets[b]` is not empty.
    occupied: u64,
    /// The tick last taken (0 at first).
    last: u32,
    /// The earliest tick queued, when known (`Some(None)`: none queued).
    least: Option<Option<u32>>,
}

impl WakeQueue {
    const BUCKETS: usize = 33;

    fn clear(&mut self) {
        self.buckets.iter_mut().for_each(Vec::clear);
        self.buckets.resize(Self::BUCKETS, Vec::new());
        self.occupied = 0;
        self.last = 0;
        self.least = Some(None);
    }

    /// The bucket of `tick` (> `last`) relative to `last`.
    #[inline]
    fn bucket(&self, tick: u32) -> usize {
        (32 - (tick ^ self.last).leading_zeros()) as usize
    }

    /// Queues `stencil` at `tick` (after [`WakeQueue::clear`], which
    /// `Dormancy::reset` calls).
    fn push(&mut self, tick: u32, stencil: u32) {
        debug_assert!(tick > self.last, "wake ticks go forward");
        let b = self.bucket(tick);
        self.buckets[b].push((tick, stencil));
        self.occupied |= 1 << b;
        if let Some(least) = &mut self.least {
            *least = Some(least.map_or(tick, |m| m.min(tick)));
        }
    }

    /// The earliest tick queued (the first occupied bucket's least).
    fn least(&mut self) -> Option<u32> {
        if let Some(least) = self.least {
            return least;
        }
        let least = (self.occupied != 0).then(|| {
            let b = self.occupied.trailing_zeros() as usize;
            self.buckets[b].iter().map(|e| e.0).min().expect("occupied")
        });
        self.least = Some(least);
        least
    }

    /// Takes the entries queued at the earliest tick if it is at or before
    /// `through`: that tick and the entries `(tick, stencil)` (hand the list
    /// back with [`WakeQueue::give_back`], which keeps its memory).
    fn take_through(&mut self, through: u32) -> Option<(u32, Vec<(u32, u32)>)> {
        let at = self.least()?;
        if at > through {
            return None;
        }
        // The earliest tick becomes `last`: the entries of its bucket move
        // to lower ones (those at `at` itself to bucket 0); the higher
        // buckets' entries differ from `at` first where they differed from
        // the old `last` (`at` agrees with it above bit b - 1).
        let b = self.occupied.trailing_zeros() as usize;
        self.last = at;
        let mut moving = std::mem::take(&mut self.buckets[b]);
        self.occupied &= !(1 << b);
        for &(tick, a) in &moving {
            let nb = self.bucket(tick);
            self.buckets[nb].push((tick, a));
            self.occupied |= 1 << nb;
        }
        moving.clear();
        self.buckets[b] = moving;
        self.occupied &= !1;
        self.least = None;
        Some((at, std::mem::take(&mut self.buckets[0])))
    }

    fn give_back(&mut self, mut taken: Vec<(u32, u32)>) {
        taken.clear();
        self.buckets[0] = taken;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stencils_wake_on_time_or_on_a_velocity_change() {
        // Vertex 1 never changes velocity (left out of the index).
        let stencils = [[0, NONE, 2, 3], [4, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[1, 1, 3], 8, 0);
        let sorted = |d: &Dormancy| {
            let mut v: Vec<u32> = d.awake().collect();
            v.sort_unstable();
            v
        };
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        d.doze(0, 0, 10);
        d.doze(1, 0, Tick::MAX);
        d.doze(2, 0, 20);
        assert!(d.awake().next().is_none());
        assert_eq!(d.next_due(), Some(10));
        d.wake_due(9);
        assert!(d.awake().next().is_none());
        d.wake_due(10);
        assert_eq!(sorted(&d), vec![0]);
        // Vertex 4 is in stencils 1 and 2.
        d.wake_vertex(4);
        assert_eq!(sorted(&d), vec![0, 1, 2]);
        assert_eq!(d.reach(2), 3);
        // Stencil 2's old wake tick is stale once it slept again.
        d.doze(2, 0, 100);
        d.wake_due(20);
        assert_eq!(sorted(&d), vec![0, 1]);
    }

    #[test]
    fn a_velocity_change_wakes_only_above_the_cap_or_after_many_breakpoints() {
        let sorted = |d: &Dormancy| {
            let mut v: Vec<u32> = d.awake().collect();
            v.sort_unstable();
            v
        };
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[2, 2], 8, 0);
        for i in 0..8 {
            d.observe(i, DVec3::X);
        }
        assert_eq!(d.cap(0), HEADROOM);
        d.doze(0, 0, Tick::MAX);
        d.doze(1, 0, Tick::MAX);
        // Turning at the same speed, or up to the cap: nothing wakes.
        d.observe(1, DVec3::Y);
        d.observe(1, DVec3::Z * HEADROOM);
        assert!(d.awake().next().is_none());
        // Slower by more than half: the cap comes down, nothing wakes.
        d.observe(5, DVec3::X * 0.1);
        assert!(d.awake().next().is_none());
        assert_eq!(d.cap(5), 0.1 * HEADROOM);
        // Faster than the cap: the vertex's stencils wake, the cap rises.
        d.observe(5, DVec3::X * 0.2);
        assert_eq!(d.awake().collect::<Vec<_>>(), [1]);
        assert_eq!(d.cap(5), 0.2 * HEADROOM);
        // Stencil 0 wakes on its vertex's BREAKPOINTS_PER_WAKE-th
        // breakpoint since it last woke, however slow.
        for _ in 1..BREAKPOINTS_PER_WAKE {
            d.observe(2, DVec3::ZERO);
        }
        assert_eq!(d.awake().collect::<Vec<_>>(), [1]);
        d.observe(2, DVec3::ZERO);
        assert_eq!(sorted(&d), [0, 1]);
        // A speed that is not finite wakes, and leaves no finite cap.
        d.doze(0, 0, Tick::MAX);
        d.observe(3, DVec3::NAN);
        assert_eq!(sorted(&d), [0, 1]);
        assert_eq!(d.cap(3), f64::INFINITY);
    }

    /// Shared caps follow the same rule and report the vertices that must
    /// wake their stencils, in ascending order: above the cap, not
    /// finite, or on the `BREAKPOINTS_PER_WAKE`-th breakpoint.
    #[test]
    fn shared_caps_report_the_vertices_that_broke_them() {
        let mut caps = SharedCaps::new(vec![2, 5, 9], |_| DVec3::X);
        assert_eq!(caps.caps(), [HEADROOM; 3]);
        assert_eq!((caps.slot(5), caps.slot(4)), (Some(1), None));
        let mut woken = Vec::new();
        caps.observe(
            |i| if i == 5 { DVec3::X * 2.0 } else { DVec3::Y },
            &mut woken,
        );
        assert_eq!(woken, [5]);
        assert_eq!(caps.caps()[1], 2.0 * HEADROOM);
        woken.clear();
        caps.observe(|i| if i == 9 { DVec3::NAN } else { DVec3::Y }, &mut woken);
        assert_eq!(woken, [9]);
        assert_eq!(caps.caps()[2], f64::INFINITY);
        // Slow and steady: vertex 2 wakes on its BREAKPOINTS_PER_WAKE-th
        // breakpoint since it last woke (the first look, which raised its
        // cap from 0; it has had 2 since).
        woken.clear();
        for _ in 3..BREAKPOINTS_PER_WAKE {
            caps.observe(|_| DVec3::ZERO, &mut woken);
        }
        assert!(!woken.contains(&2), "{woken:?}");
        caps.observe(|_| DVec3::ZERO, &mut woken);
        assert_eq!(woken.last(), Some(&2));
    }

    /// Past 2^32 ticks after the base, wake ticks are clamped there: a
    /// stencil dozing until a later tick is queued at the clamp, woken when
    /// the batches pass it, and one dozing after that (a wake tick the
    /// queue has passed) wakes at once, as the binary heap before woke it
    /// at its next look, before any batch read it.
    #[test]
    fn wake_ticks_past_the_clamp_wake_no_later_than_the_clamp() {
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[3, 3], 8, 10);
        let clamp = 10 + u32::MAX as Tick;
        d.doze(0, 0, clamp + 100);
        d.doze(1, 1, 50);
        assert_eq!(d.next_due(), Some(50));
        d.wake_due(50);
        assert_eq!((d.reach(0), d.reach(1)), (0, 3));
        assert_eq!(d.next_due(), Some(clamp));
        d.wake_due(clamp - 1);
        assert_eq!(d.reach(0), 0);
        d.wake_due(clamp + 5);
        assert_eq!(d.reach(0), 3, "woken at the clamp");
        // A batch past the clamp certifies both again: the clamped wake
        // tick is behind the queue, so they stay awake; one that never
        // wakes on time dozes.
        d.doze(0, 0, clamp + 1_000);
        d.doze(1, 2, clamp + 7);
        assert_eq!((d.reach(0), d.reach(1)), (3, 3));
        assert_eq!(d.next_due(), None);
        d.doze(0, 0, Tick::MAX);
        assert_eq!(d.reach(0), 0);
    }

    /// The radix queue against a sorted list: random pushes of later ticks
    /// (near and far, repeated ticks and stencils) between takes through
    /// ticks that go forward; every entry comes out at its tick, in tick
    /// order, and `least` is the earliest queued.
    #[test]
    fn the_wake_queue_takes_what_a_sorted_list_would() {
        let mut rng = crate::uniform_numbers(0x5eed_d0e5);
        let mut next = |n: u32| (rng() * n as f64) as u32;
        for round in 0..200 {
            let mut q = WakeQueue::default();
            q.clear();
            let mut oracle: Vec<(u32, u32)> = Vec::new();
            let mut now = 0u32;
            let spread = [4, 1 << 10, 1 << 20, u32::MAX / 4][round % 4];
            for _ in 0..300 {
                for _ in 0..next(6) {
                    let Some(tick) = now.checked_add(1 + next(spread)) else {
                        continue;
                    };
                    let a = next(50);
                    q.push(tick, a);
                    oracle.push((tick, a));
                }
                assert_eq!(q.least(), oracle.iter().map(|e| e.0).min());
                now = now.saturating_add(next(spread / 2 + 1));
                let mut taken = Vec::new();
                while let Some((at, due)) = q.take_through(now) {
                    assert!(due.iter().all(|e| e.0 == at) && !due.is_empty());
                    assert!(taken.last().is_none_or(|&(t, _)| t < at), "tick order");
                    taken.extend(due.iter().copied());
                    q.give_back(due);
                }
                let mut expected: Vec<(u32, u32)> =
                    oracle.iter().copied().filter(|e| e.0 <= now).collect();
                oracle.retain(|e| e.0 > now);
                expected.sort_unstable();
                taken.sort_unstable();
                assert_eq!(taken, expected);
            }
        }
    }

    #[test]
    fn a_dozing_stencil_stays_listed_with_a_lower_reach_until_it_wakes() {
        let stencils = [[0, 1, 2, 3], [4, 5, 6, 7]];
        let mut d = Dormancy::default();
        d.reset(&stencils, &[5, 5], 8, 0);
        d.doze(0, 2, 30);
        assert_eq!(
            d.awake().count(),
            2,
            "a dozing stencil is still read by outer layers"
        );
        assert_eq!((d.reach(0), d.reach(1)), (2, 5));
        d.wake_due(29);
        assert_eq!(d.reach(0), 2);
        d.wake_due(30);
        assert_eq!(d.reach(0), 5);
        // A velocity change wakes a dozing stencil at once, and its old
        // wake tick no longer counts.
        d.doze(1, 1, 40);
        d.wake_vertex(6);
        assert_eq!(d.reach(1), 5);
        d.doze(1, 0, 90);
        d.wake_due(40);
        assert_eq!((d.reach(1), d.awake().count()), (0, 1));
    }
}
