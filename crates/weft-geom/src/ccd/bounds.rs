//! Hierarchical bounds over a trajectory's breakpoints (deep contact).
//!
//! A vertex in deep contact has a breakpoint at every kick of every active
//! layer: hundreds to thousands per window. The certificates of
//! [`super::certificate`] walk every sub-segment of the interval they are
//! asked about, so a long interval costs as many steps as it holds
//! breakpoints, at every level of the bisection. These bounds let a
//! certificate answer a long stretch of time at once and walk the segments
//! only where the bound is not enough.
//!
//! ## The structure
//!
//! Level `l` (from 0) cuts the polyline into blocks of `S_l = 8^(l+1)`
//! segments; block `j` is the axis-aligned box of the breakpoints
//! `j S_l ..= (j+1) S_l`, kept once it is closed (its last breakpoint
//! exists). A block's box holds every point of its segments: each segment is the convex
//! hull of its two end breakpoints, which are in the box. The boxes are the
//! exact minima and maxima of the stored coordinates — no rounding at all, so
//! a certificate may treat their corners as exact points.
//!
//! The boxes are built as the breakpoints are recorded
//! ([`TrajectoryBounds::update`] when a block closes, from the 9
//! breakpoints just written; a level-`l+1` block from the 8 level-`l` boxes
//! just made), never by a pass over the window. The same step checks the
//! block's times and coordinates, so the predicate need not re-validate a
//! long polyline point by point. Memory: a 48-byte box per 8 breakpoints at level 0, per
//! 64 at level 1, …: at most `48 / 7 = 6.9` bytes per breakpoint, 21 % of
//! the 32 bytes of the breakpoint itself. (Blocks of 8 rather than 16: the
//! ragged ends of a range cost half as many steps; measured on crumple's
//! queries, 8 was faster than 4 and 16.)
//!
//! [`TrajectoryBounds::cover`] gives the box of the breakpoints `k0 ..= k1`
//! from the largest aligned blocks inside that range and single breakpoints
//! at its ragged ends: at most `7` steps per level and side.

use weft_core::DVec3;

/// Segments per block of level 0, and blocks of level `l` per block of level
/// `l + 1`: `2^FANOUT_BITS`.
pub const FANOUT: usize = 1 << FANOUT_BITS;
const FANOUT_BITS: u32 = 3;

/// An axis-aligned box of exact stored points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// the smallest coordinates.
    pub lo: DVec3,
    /// the largest coordinates.
    pub hi: DVec3,
}

impl Aabb {
    /// The box of one point.
    #[inline]
    pub fn point(p: DVec3) -> Self {
        Self { lo: p, hi: p }
    }

    /// Grows the box to hold `p` (exact: min and max round nothing).
    #[inline]
    pub fn add(&mut self, p: DVec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }

    /// Grows the box to hold `other`.
    #[inline]
    pub fn union(&mut self, other: &Aabb) {
        self.lo = self.lo.min(other.lo);
        self.hi = self.hi.max(other.hi);
    }

    /// The corner of the box with the smallest projection on `n`
    /// (`n . corner = min over the box of n . x`, exactly).
    #[inline]
    pub fn lowest_corner(&self, n: DVec3) -> DVec3 {
        DVec3::select(n.cmpge(DVec3::ZERO), self.lo, self.hi)
    }

    /// The corner with the largest projection on `n`.
    #[inline]
    pub fn highest_corner(&self, n: DVec3) -> DVec3 {
        DVec3::select(n.cmpge(DVec3::ZERO), self.hi, self.lo)
    }
}

/// The block boxes of one polyline (see the module docs). Keeps its capacity
/// when cleared, like the breakpoints themselves.
///
/// Only *closed* blocks are stored (block `j` of level `l` closes with
/// breakpoint `(j+1) S_l`): a range of breakpoints that exist only ever
/// covers closed blocks. A block is boxed when it closes, from the
/// polyline's tail, which was just written: recording a breakpoint touches
/// these bounds once per 8 breakpoints ([`TrajectoryBounds::update`]).
#[derive(Clone, Debug)]
pub struct TrajectoryBounds {
    /// the closed blocks of level 0: `first[j]` is the box of breakpoints
    /// `8j ..= 8j + 8` (kept apart from the levels above: one indirection
    /// fewer when a block closes).
    first: Vec<Aabb>,
    /// `upper[l - 1][j]`: the box of breakpoints `j S_l ..= (j+1) S_l` of
    /// level `l >= 1`, for the closed blocks (after
    /// [`TrajectoryBounds::clear`] a level may be empty).
    upper: Vec<Vec<Aabb>>,
    /// over the closed level-0 blocks: every time finite and strictly
    /// increasing, every coordinate finite and at most
    /// [`super::COORD_LIMIT`] in magnitude, what [`super::proximity`] would
    /// otherwise check point by point (`true` before the first block).
    valid: bool,
    /// the largest absolute coordinate of the closed blocks.
    max_abs: f64,
}

impl Default for TrajectoryBounds {
    /// The bounds of an empty polyline.
    fn default() -> Self {
        Self {
            first: Vec::new(),
            upper: Vec::new(),
            valid: true,
            max_abs: 0.0,
        }
    }
}

/// `S_l = FANOUT^(l+1)`, segments per block of level `l`.
#[inline]
fn block_len(level: usize) -> usize {
    1 << block_shift(level)
}

/// `log2 S_l`.
#[inline]
fn block_shift(level: usize) -> u32 {
    FANOUT_BITS * (level as u32 + 1)
}

/// Whether `times` are finite and strictly increasing and `points` finite
/// and within [`super::COORD_LIMIT`]; and their largest absolute coordinate.
fn check(times: &[f64], points: &[DVec3]) -> (bool, f64) {
    let mut valid = times.iter().all(|t| t.is_finite()) && times.windows(2).all(|w| w[0] < w[1]);
    let mut m = 0.0f64;
    for p in points {
        let a = p.abs().max_element();
        // (`max_element` ignores NaN, hence the explicit finiteness test.)
        valid &= p.is_finite() && a <= super::COORD_LIMIT;
        m = m.max(a);
    }
    (valid, m)
}

impl TrajectoryBounds {
    /// The bounds of the polyline `times`, `points`.
    pub fn from_points(times: &[f64], points: &[DVec3]) -> Self {
        let mut b = Self::default();
        b.reserve_for(points.len());
        b.update(times, points);
        b
    }

    /// Makes room for the level-0 blocks of a polyline of `len`
    /// breakpoints, in one allocation: grown by doubling, the level that
    /// holds 7/8 of the boxes kept up to half of its memory unused. (The
    /// levels above are an eighth of it and are left to grow.)
    pub fn reserve_for(&mut self, len: usize) {
        let blocks = len / FANOUT;
        self.first
            .reserve_exact(blocks.saturating_sub(self.first.len()));
    }

    /// Forgets every breakpoint (keeps the storage).
    pub fn clear(&mut self) {
        self.first.clear();
        for level in &mut self.upper {
            level.clear();
        }
        self.valid = true;
        self.max_abs = 0.0;
    }

    /// Breakpoints covered by closed level-0 blocks, plus the open tail's
    /// start: the index where the open block starts.
    #[inline]
    fn closed_end(&self) -> usize {
        self.first.len() * FANOUT
    }

    /// Whether these bounds are those of a polyline of `len` breakpoints
    /// (every block that `len` closes is closed, no other).
    pub fn matches(&self, len: usize) -> bool {
        len > 0 && self.closed_end() / FANOUT == (len - 1) / FANOUT
    }

    /// Closes the blocks that the polyline `times`, `points` (the one these
    /// bounds were built from, grown at its end) closes since the last
    /// call. Call it after every new breakpoint, or once after many.
    #[inline]
    /// (A polyline with fewer times than points is closed only as far as
    /// its times go; the predicate refuses such input anyway.)
    pub fn update(&mut self, times: &[f64], points: &[DVec3]) {
        let len = times.len().min(points.len());
        while self.closed_end() + FANOUT < len {
            self.close(times, points);
        }
    }

    /// Closes the next level-0 block, and the blocks above whose end it is.
    #[cold]
    fn close(&mut self, times: &[f64], points: &[DVec3]) {
        let k = self.closed_end();
        let span = k..=k + FANOUT;
        let (valid, m) = check(&times[span.clone()], &points[span.clone()]);
        self.valid &= valid;
        self.max_abs = self.max_abs.max(m);
        let mut b = Aabb::point(points[k]);
        for &p in &points[span] {
            b.add(p);
        }
        self.first.push(b);
        let end = k + FANOUT;
        let mut level = 1;
        while end & (block_len(level) - 1) == 0 {
            if self.upper.len() < level {
                self.upper.push(Vec::new());
            }
            let (below, here) = self.upper.split_at_mut(level - 1);
            let below: &[Aabb] = match below.last() {
                Some(l) => l,
                None => &self.first,
            };
            let mut b = below[below.len() - FANOUT];
            for c in &below[below.len() - FANOUT + 1..] {
                b.union(c);
            }
            here[0].push(b);
            level += 1;
        }
    }

    /// Whether the polyline `times`, `points` (these bounds' own) has
    /// finite, strictly increasing times and finite coordinates of magnitude
    /// at most [`super::COORD_LIMIT`]; and its largest absolute coordinate.
    /// Checked block by block as they closed; only the open tail here.
    pub fn summary(&self, times: &[f64], points: &[DVec3]) -> (bool, f64) {
        let tail = self.closed_end().min(points.len().saturating_sub(1))..points.len();
        let (valid, m) = check(&times[tail.clone()], &points[tail]);
        (self.valid && valid, self.max_abs.max(m))
    }

    /// The last breakpoint (index `len - 1` of the polyline) was replaced
    /// by `p` (the same instant recorded again): every closed box that holds
    /// it also takes `p`. The boxes stay supersets of the stored points,
    /// which is all a certificate needs.
    pub fn replace_last(&mut self, len: usize, p: DVec3) {
        let i = len.saturating_sub(1);
        if i == 0 || i != self.closed_end() {
            return;
        }
        let a = p.abs().max_element();
        self.valid &= p.is_finite() && a <= super::COORD_LIMIT;
        self.max_abs = self.max_abs.max(a);
        let levels = std::iter::once(&mut self.first).chain(self.upper.iter_mut());
        for (level, blocks) in levels.enumerate() {
            if i & (block_len(level) - 1) != 0 {
                break;
            }
            // the closed block that ends at i
            if let Some(b) = blocks.last_mut() {
                b.add(p);
            }
        }
    }

    /// The box of `points[k0 ..= k1]`, where `points` are the breakpoints
    /// these bounds were built from (`k0 <= k1 < len`): aligned blocks as
    /// large as fit inside the range, single breakpoints at its ragged ends.
    pub fn cover(&self, points: &[DVec3], k0: usize, k1: usize) -> Aabb {
        let mut b = Aabb::point(points[k0]);
        let mut k = k0;
        // Up: single segments (level "-1"), then blocks of each level, until
        // k is aligned to the next level or its block would pass k1.
        let mut level = 0; // unit of the current step: 1 segment at level 0 here
        let mut step = 1;
        loop {
            let next = step * FANOUT;
            while k % next != 0 && k + step <= k1 {
                self.add_unit(&mut b, points, level, k);
                k += step;
            }
            if k + next > k1 || level > self.upper.len() {
                break;
            }
            level += 1;
            step = next;
        }
        // Down: the largest units that still fit.
        loop {
            while k + step <= k1 {
                self.add_unit(&mut b, points, level, k);
                k += step;
            }
            if level == 0 {
                return b;
            }
            level -= 1;
            step /= FANOUT;
        }
    }

    /// Adds the unit of `level` starting at breakpoint `k` to `b`: level 0
    /// is one segment (its far end, breakpoint `k + 1`), level `l + 1` the
    /// block `k / S_l` of level `l`.
    #[inline]
    fn add_unit(&self, b: &mut Aabb, points: &[DVec3], level: usize, k: usize) {
        if level == 0 {
            b.add(points[k + 1]);
        } else {
            let blocks = match level {
                1 => &self.first,
                _ => &self.upper[level - 2],
            };
            b.union(&blocks[k >> block_shift(level - 1)]);
        }
    }

    /// Bytes held (capacity).
    pub fn bytes(&self) -> usize {
        let boxes: usize =
            self.first.capacity() + self.upper.iter().map(Vec::capacity).sum::<usize>();
        boxes * std::mem::size_of::<Aabb>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(points: &[DVec3], k0: usize, k1: usize) -> Aabb {
        let mut b = Aabb::point(points[k0]);
        for &p in &points[k0..=k1] {
            b.add(p);
        }
        b
    }

    fn times(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64).collect()
    }

    fn wiggle(n: usize) -> Vec<DVec3> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                DVec3::new((t * 0.37).sin(), (t * 0.11).cos() * t, (i % 7) as f64 - 3.0)
            })
            .collect()
    }

    /// Every range's cover equals the brute-force box, for lengths around
    /// the block sizes (a level starts at 8, 64, 512, 4096 segments).
    #[test]
    fn cover_is_the_exact_box_of_every_range() {
        for n in [
            1, 2, 8, 9, 10, 63, 64, 65, 66, 511, 512, 513, 514, 600, 4097, 4098,
        ] {
            let pts = wiggle(n);
            let b = TrajectoryBounds::from_points(&times(n), &pts);
            assert!(b.matches(n));
            let step = (n / 97).max(1);
            for k0 in (0..n).step_by(step) {
                for k1 in (k0..n).step_by(step.max(3)) {
                    assert_eq!(
                        b.cover(&pts, k0, k1),
                        brute(&pts, k0, k1),
                        "n {n} [{k0}, {k1}]"
                    );
                }
                assert_eq!(b.cover(&pts, k0, n - 1), brute(&pts, k0, n - 1));
            }
        }
    }

    /// Room made for a length is used without growing: built at once or
    /// breakpoint by breakpoint up to that length, the level-0 boxes take
    /// one allocation, with no spare room (the fetched polylines' bounds
    /// were grown by doubling), and the boxes are those built without it.
    #[test]
    fn reserved_bounds_grow_into_their_room_only() {
        for n in [1, 8, 9, 100, 513, 1000] {
            let (ts, pts) = (times(n), wiggle(n));
            let built = TrajectoryBounds::from_points(&ts, &pts);
            assert!(built.first.capacity() <= (n / FANOUT).max(1), "n = {n}");
            let mut grown = TrajectoryBounds::default();
            grown.reserve_for(n);
            let room = grown.first.capacity();
            for i in 0..n {
                grown.update(&ts[..=i], &pts[..=i]);
            }
            assert_eq!(grown.first.capacity(), room, "n = {n}");
            assert_eq!((&grown.first, &grown.upper), (&built.first, &built.upper));
        }
    }

    /// After a replaced last point the cover holds the new point (and may
    /// still hold the old one); cleared bounds start over.
    #[test]
    fn replaced_last_points_stay_covered_and_clear_starts_over() {
        let mut pts = wiggle(300);
        let ts = times(300);
        let mut b = TrajectoryBounds::from_points(&[], &[]);
        for i in 0..300 {
            b.update(&ts[..=i], &pts[..=i]);
            if i % 5 == 0 {
                let q = pts[i] + DVec3::new(0.5, -2.0, 1.0);
                b.replace_last(i + 1, q);
                pts[i] = q;
            }
        }
        assert!(b.matches(300));
        for k0 in (0..300).step_by(7) {
            for k1 in (k0..300).step_by(11) {
                let c = b.cover(&pts, k0, k1);
                let e = brute(&pts, k0, k1);
                assert!(c.lo.cmple(e.lo).all() && c.hi.cmpge(e.hi).all());
            }
        }
        b.clear();
        let fresh = wiggle(40);
        b.update(&times(40), &fresh);
        assert_eq!(b.cover(&fresh, 0, 39), brute(&fresh, 0, 39));
        assert!(b.summary(&times(40), &fresh).0);
        let mut bad = times(40);
        bad[3] = bad[2];
        assert!(
            !TrajectoryBounds::from_points(&bad, &fresh)
                .summary(&bad, &fresh)
                .0
        );
        let mut nan = fresh.clone();
        nan[39].y = f64::NAN;
        assert!(
            !TrajectoryBounds::from_points(&times(40), &nan)
                .summary(&times(40), &nan)
                .0
        );
        assert!(b.bytes() > 0);
    }
}
