//! 26-DOPs: discrete oriented polytopes bounded by 13 pairs of planes.
//!
//! The 13 **normalized** directions are the 3 coordinate axes, the 6 face
//! diagonals `(±1, 1, 0)/√2`-style and the 4 body diagonals `(±1, ±1, 1)/√3`. A
//! [`Dop26`] stores, per direction `d_k`, an interval `[lo_k, hi_k]` that contains
//! the **exact** projection `d_k* . p` of every point `p` added to it, where `d_k*`
//! is the exact (irrational) unit direction — not only its floating-point
//! rounding. Because the directions are unit vectors, projections are 1-Lipschitz,
//! which is what makes inflation by a distance meaningful (see [`Dop26::overlaps`]).
//!
//! # Floating-point bound of [`Dop26::add_point`]
//!
//! Let `u = 2^-53` (unit roundoff), `p` a finite point, `S = |p_x| + |p_y| + |p_z|`
//! and `d` the stored direction, whose components are `0`, `±1`, `±fl(1/√2)` or
//! `±fl(1/√3)`, each within relative error `u` of the exact component (the
//! literals below are correctly rounded). The computed projection
//! `v = fl(d . p)` (three products, two additions) satisfies
//!
//! ```text
//!  |v - d.p|    <= γ3 Σ|d_i p_i| + 3·2^-1075 <= γ3 S + 3·2^-1075   (Higham, Thm 3.1; γ3 = 3u/(1-3u);
//!                                                                 the last term covers underflow of products)
//!  |d.p - d*.p| <= Σ|d_i - d*_i| |p_i| <= u S                      (|d*_i| <= 1)
//! ```
//!
//! so `|v - d*.p| <= (γ3 + u) S + 3·2^-1075 < 4.01 u S + 2·2^-1074`. The
//! computed `s = fl(fl(|p_x| + |p_y|) + |p_z|) >= S (1 - 2u)`, hence
//! `S <= 1.0001 s` and `|v - d*.p| <= 4.02 u s + 2·2^-1074`. The margin is
//! `e = fl(fl(8u·s) + 4·2^-1074)`; `8u = 2^-50` is a power of two, so `fl(8u·s)`
//! is exact unless it underflows (error `<= 2^-1075`), and the computed
//! `e >= 8u s (1 - u) + 3·2^-1074`. The stored bound is `lo = fl(v - e)`. Round
//! to nearest moves a normal result by at most `u` relative (a subnormal
//! difference is exact), and `|v - e| <= 1.0003 s + 4·2^-1074`, so
//!
//! ```text
//!   lo <= (v - e) + u |v - e|
//!      <= d*.p + (4.02 u s + 2·2^-1074) - (8u s (1 - u) + 3·2^-1074) + 1.0004 u s
//!      <  d*.p,
//! ```
//!
//! and symmetrically `hi = fl(v + e) > d*.p`. Therefore `lo <= d*.p <= hi`; the
//! interval is at most about `2^-49 s` wider than the rounded projection.
//!
//! [`Dop26::inflate`] and [`Dop26::union`] are likewise exact or rounded outward,
//! and [`Dop26::overlaps`] only compares floats (exact). No "no overlap" answer
//! can therefore be caused by rounding.

use weft_core::DVec3;

/// `fl(1/√2)`, correctly rounded.
const S2: f64 = std::f64::consts::FRAC_1_SQRT_2;
/// `fl(1/√3)`, correctly rounded (the exact value is 0.57735026918962576450914878...).
const S3: f64 = 0.577_350_269_189_625_7;

/// The 13 normalized 26-DOP directions: 3 axes, 6 face diagonals (`/√2`),
/// 4 body diagonals (`/√3`), each the correctly rounded unit vector.
pub const DIRECTIONS: [DVec3; 13] = [
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 1.0, 0.0),
    DVec3::new(0.0, 0.0, 1.0),
    DVec3::new(S2, S2, 0.0),
    DVec3::new(S2, -S2, 0.0),
    DVec3::new(S2, 0.0, S2),
    DVec3::new(S2, 0.0, -S2),
    DVec3::new(0.0, S2, S2),
    DVec3::new(0.0, S2, -S2),
    DVec3::new(S3, S3, S3),
    DVec3::new(S3, S3, -S3),
    DVec3::new(S3, -S3, S3),
    DVec3::new(-S3, S3, S3),
];

/// Smallest positive subnormal, `2^-1074`.
const DENORM_MIN: f64 = f64::from_bits(1);
/// `8u = 2^-50` (`f64::EPSILON` is `2u = 2^-52`).
const EIGHT_U: f64 = 4.0 * f64::EPSILON;

/// Next representable float towards `-inf` (identity on `-inf` and NaN).
#[inline]
pub(crate) fn next_down(x: f64) -> f64 {
    if x.is_nan() || x == f64::NEG_INFINITY {
        return x;
    }
    if x == 0.0 {
        return -DENORM_MIN;
    }
    let b = x.to_bits();
    f64::from_bits(if x > 0.0 { b - 1 } else { b + 1 })
}

/// Next representable float towards `+inf` (identity on `+inf` and NaN).
#[inline]
pub(crate) fn next_up(x: f64) -> f64 {
    -next_down(-x)
}

/// A 26-DOP: per [`DIRECTIONS`]`[k]` the interval `[lo[k], hi[k]]`.
///
/// Invariant (for DOPs built with [`Dop26::from_point`] / [`Dop26::add_point`] /
/// [`Dop26::merge`] / [`Dop26::inflate`]): every interval contains the exact
/// projection of every added point onto the exact unit direction, widened by the
/// total inflation.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Dop26 {
    /// lower bound per direction.
    pub lo: [f64; 13],
    /// upper bound per direction.
    pub hi: [f64; 13],
}

impl Default for Dop26 {
    fn default() -> Self {
        Self::empty()
    }
}

impl Dop26 {
    /// The empty DOP (`lo = +inf`, `hi = -inf`): contains nothing, overlaps
    /// nothing, and is the identity of [`Dop26::union`].
    pub const fn empty() -> Self {
        Self {
            lo: [f64::INFINITY; 13],
            hi: [f64::NEG_INFINITY; 13],
        }
    }

    /// The DOP of one point.
    #[inline]
    pub fn from_point(p: DVec3) -> Self {
        let mut d = Self::empty();
        d.add_point(p);
        d
    }

    /// The DOP of a point set (for the broad phase: every breakpoint of a
    /// triangle's three vertices in the window), empty for no points.
    pub fn from_points(points: impl IntoIterator<Item = DVec3>) -> Self {
        let mut d = Self::empty();
        for p in points {
            d.add_point(p);
        }
        d
    }

    /// Grows the DOP to contain `p`, rounding outward by the bound derived in the
    /// module documentation (`e = 2^-50 (|p_x| + |p_y| + |p_z|) + 2^-1072`; the
    /// axis projections are exact and get no margin).
    #[inline]
    pub fn add_point(&mut self, p: DVec3) {
        let s = p.x.abs() + p.y.abs() + p.z.abs();
        let e = EIGHT_U * s + 4.0 * DENORM_MIN;
        let x = p.x;
        let y = p.y;
        let z = p.z;
        // Same arithmetic as DIRECTIONS[k].dot(p), with the zero products dropped
        // (exact) and the ±1 products exact: the bound above still holds.
        let proj: [f64; 13] = [
            x,
            y,
            z,
            S2 * x + S2 * y,
            S2 * x - S2 * y,
            S2 * x + S2 * z,
            S2 * x - S2 * z,
            S2 * y + S2 * z,
            S2 * y - S2 * z,
            S3 * x + S3 * y + S3 * z,
            S3 * x + S3 * y - S3 * z,
            S3 * x - S3 * y + S3 * z,
            -(S3 * x) + S3 * y + S3 * z,
        ];
        for k in 0..3 {
            // axis projections are exact
            self.lo[k] = self.lo[k].min(proj[k]);
            self.hi[k] = self.hi[k].max(proj[k]);
        }
        for k in 3..13 {
            self.lo[k] = self.lo[k].min(proj[k] - e);
            self.hi[k] = self.hi[k].max(proj[k] + e);
        }
    }

    /// The smallest DOP containing both (exact: only `min` / `max`).
    #[inline]
    pub fn union(&self, other: &Dop26) -> Dop26 {
        let mut r = *self;
        r.merge(other);
        r
    }

    /// `self = self ∪ other` (exact).
    #[inline]
    pub fn merge(&mut self, other: &Dop26) {
        for k in 0..13 {
            self.lo[k] = self.lo[k].min(other.lo[k]);
            self.hi[k] = self.hi[k].max(other.hi[k]);
        }
    }

    /// Widens every interval by `r >= 0` on both sides, rounding outward (one ulp
    /// past the rounded result), so the new interval contains the exact
    /// `[lo - r, hi + r]`. An empty DOP stays empty; a negative or NaN `r` is
    /// treated as 0.
    #[inline]
    pub fn inflate(&mut self, r: f64) {
        if r.is_nan() || r <= 0.0 || self.is_empty() {
            return;
        }
        for k in 0..13 {
            self.lo[k] = next_down(self.lo[k] - r);
            self.hi[k] = next_up(self.hi[k] + r);
        }
    }

    /// True when some interval is empty (`lo > hi`) or NaN.
    #[inline]
    pub fn is_empty(&self) -> bool {
        (0..13).any(|k| self.lo[k].is_nan() || self.hi[k].is_nan() || self.lo[k] > self.hi[k])
    }

    /// True when the intervals overlap (closed: touching counts) along all 13
    /// directions.
    ///
    /// **Guarantee.** Let `A` and `B` be point sets, and let each DOP contain the
    /// points of its set (all of them added) and then be inflated by `r` (or
    /// inflated by `r_A`, `r_B`). If some `a` in the convex hull of `A` and `b` in
    /// the convex hull of `B` satisfy `|a - b| <= 2r` (`<= r_A + r_B`), this
    /// returns `true`: for every exact unit direction `d*`,
    /// `|d*.a - d*.b| <= |a - b| <= 2r`, the exact projections of `a` and `b` lie
    /// in the exact hulls' projection intervals, which the stored intervals
    /// contain widened by `r` (module documentation), so the stored intervals
    /// intersect. The comparisons are exact. The converse does not hold (a DOP is
    /// larger than the hull): `true` only means "possibly close".
    #[inline]
    pub fn overlaps(&self, other: &Dop26) -> bool {
        let mut ok = true;
        for k in 0..13 {
            ok &= self.lo[k] <= other.hi[k] && other.lo[k] <= self.hi[k];
        }
        ok
    }

    /// True when `other` lies inside `self` along every direction (an empty
    /// `other` is contained in anything).
    #[inline]
    pub fn contains(&self, other: &Dop26) -> bool {
        other.is_empty() || (0..13).all(|k| self.lo[k] <= other.lo[k] && other.hi[k] <= self.hi[k])
    }

    /// Midpoint of the axis intervals (used to order leaves when building a BVH).
    #[inline]
    pub fn center(&self) -> DVec3 {
        DVec3::new(
            0.5 * self.lo[0] + 0.5 * self.hi[0],
            0.5 * self.lo[1] + 0.5 * self.hi[1],
            0.5 * self.lo[2] + 0.5 * self.hi[2],
        )
    }
}
