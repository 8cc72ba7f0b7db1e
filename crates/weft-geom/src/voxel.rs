//! Overlapping pairs of a few large DOPs by a voxel grid: the global broad
//! phase over partitions (`acm-spec.md` §5, "Broad phase across partitions").
//!
//! Each partition's window hull is a [`Dop26`]; [`overlapping_pairs`] returns
//! every pair `(i, j)`, `i < j`, with `hulls[i].overlaps(&hulls[j])`: exactly
//! the pairs of the all-pairs test ([`brute_force_pairs`]), found without
//! testing all of them.
//!
//! # The grid, and why it misses no pair
//!
//! A hull is *regular* when its three axis intervals (`lo[k] <= hi[k]`,
//! `k < 3`, the DOP's exact coordinate bounds) are finite. Cell coordinates
//! along axis `k` are `c(x) = floor((x - o_k) / s) as i64` for one origin `o`
//! and one voxel size `s > 0`. That map is monotone non-decreasing in `x`:
//! the rounded subtraction and division are monotone (rounding is), `floor` is,
//! and Rust's float-to-integer `as` saturates monotonically (infinities and
//! huge values included). A regular hull covers the cells
//! `c(lo[k]) ..= c(hi[k])` on each axis. If two hulls overlap, then on each
//! axis `p = max(lo_a, lo_b)` lies in both intervals (`overlaps` compares
//! exactly, `lo_a <= hi_b` and `lo_b <= hi_a`), so `c(p)` is in both cell
//! ranges: the two hulls share the cell `(c(p_x), c(p_y), c(p_z))`. No pair of
//! overlapping regular hulls is therefore missed by pairing the hulls of each
//! cell, whatever the rounding.
//!
//! Hulls that are not regular (empty, NaN or unbounded), and hulls covering
//! more than [`MAX_CELLS`] cells (a floor under a whole scene), are *irregular*
//! and tested against every other hull directly. Every pair found through a
//! cell is confirmed with [`Dop26::overlaps`] (all 13 directions), so the
//! result is exactly the all-pairs answer.
//!
//! The voxel size is the median of the regular hulls' largest axis extents, so
//! a typical hull covers at most 2 × 2 × 2 cells. The pairs come out sorted;
//! nothing depends on hashing order (the grid is a sorted list of
//! `(cell, hull)` entries, not a hash map).

use crate::dop::Dop26;

/// Most cells a hull may cover before it is tested against every hull
/// instead.
pub const MAX_CELLS: i128 = 64;

/// Every pair `(i, j)`, `i < j`, of overlapping hulls, sorted: the same as
/// [`brute_force_pairs`], through a voxel grid (module documentation).
pub fn overlapping_pairs(hulls: &[Dop26]) -> Vec<(u32, u32)> {
    let regular =
        |d: &Dop26| (0..3).all(|k| d.lo[k] <= d.hi[k] && d.hi[k] - d.lo[k] < f64::INFINITY);
    let mut extents: Vec<f64> = hulls
        .iter()
        .filter(|d| regular(d))
        .map(|d| (0..3).map(|k| d.hi[k] - d.lo[k]).fold(0.0, f64::max))
        .collect();
    extents.sort_by(f64::total_cmp);
    // Any positive finite size keeps the grid exact; the median keeps it small.
    let size = match extents.get(extents.len() / 2) {
        Some(&s) if s > 0.0 => s,
        _ => 1.0,
    };
    let mut origin = [f64::INFINITY; 3];
    for d in hulls.iter().filter(|d| regular(d)) {
        for k in 0..3 {
            origin[k] = origin[k].min(d.lo[k]);
        }
    }
    let cell = |k: usize, x: f64| ((x - origin[k]) / size).floor() as i64;

    let mut entries: Vec<([i64; 3], u32)> = Vec::new();
    let mut irregular: Vec<u32> = Vec::new();
    for (i, d) in hulls.iter().enumerate() {
        let i = i as u32;
        if !regular(d) {
            irregular.push(i);
            continue;
        }
        let lo = [cell(0, d.lo[0]), cell(1, d.lo[1]), cell(2, d.lo[2])];
        let hi = [cell(0, d.hi[0]), cell(1, d.hi[1]), cell(2, d.hi[2])];
        // Each axis spans at most 2^64 cells; their product can overflow
        // even i128 (a hull across 1e300 m): count it as too many.
        let count: i128 = (0..3)
            .try_fold(1i128, |n, k| {
                n.checked_mul(i128::from(hi[k]) - i128::from(lo[k]) + 1)
            })
            .unwrap_or(i128::MAX);
        if count > MAX_CELLS {
            irregular.push(i);
            continue;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    entries.push(([x, y, z], i));
                }
            }
        }
    }
    entries.sort_unstable();

    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for run in entries.chunk_by(|a, b| a.0 == b.0) {
        for (n, &(_, i)) in run.iter().enumerate() {
            for &(_, j) in &run[n + 1..] {
                // a run is sorted by hull: i < j
                pairs.push((i, j));
            }
        }
    }
    for &i in &irregular {
        for j in 0..hulls.len() as u32 {
            if j != i {
                pairs.push((i.min(j), i.max(j)));
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs.retain(|&(i, j)| hulls[i as usize].overlaps(&hulls[j as usize]));
    pairs
}

/// The oracle: every pair `(i, j)`, `i < j`, with overlapping hulls, in
/// lexicographic order. `O(n^2)`.
pub fn brute_force_pairs(hulls: &[Dop26]) -> Vec<(u32, u32)> {
    let n = hulls.len() as u32;
    (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .filter(|&(i, j)| hulls[i as usize].overlaps(&hulls[j as usize]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// The DOP of the box's eight corners.
    fn boxed(lo: DVec3, hi: DVec3) -> Dop26 {
        Dop26::from_points((0..8).map(|c| {
            let pick = |bit: usize, l: f64, h: f64| if c >> bit & 1 == 0 { l } else { h };
            DVec3::new(
                pick(0, lo.x, hi.x),
                pick(1, lo.y, hi.y),
                pick(2, lo.z, hi.z),
            )
        }))
    }

    #[test]
    fn touching_hulls_across_a_cell_boundary_pair_up() {
        // Two unit boxes touching at x = 1 (closed intervals overlap), and a
        // third one just past it.
        let a = boxed(DVec3::ZERO, DVec3::ONE);
        let b = boxed(DVec3::new(1.0, 0.0, 0.0), DVec3::new(2.0, 1.0, 1.0));
        let c = boxed(DVec3::new(2.0 + 1e-9, 0.0, 0.0), DVec3::new(3.0, 1.0, 1.0));
        let hulls = [a, b, c];
        assert_eq!(overlapping_pairs(&hulls), vec![(0, 1)]);
        assert_eq!(overlapping_pairs(&hulls), brute_force_pairs(&hulls));
    }

    #[test]
    fn empty_unbounded_and_huge_hulls_are_tested_directly() {
        let unit = boxed(DVec3::ZERO, DVec3::ONE);
        let far = boxed(DVec3::splat(10.0), DVec3::splat(11.0));
        let floor = boxed(DVec3::splat(-1e6), DVec3::splat(1e6));
        let mut inf = unit;
        inf.hi[0] = f64::INFINITY;
        let mut nan = unit;
        nan.lo[1] = f64::NAN;
        let hulls = [unit, Dop26::empty(), far, floor, inf, nan, unit];
        let got = overlapping_pairs(&hulls);
        assert_eq!(got, brute_force_pairs(&hulls));
        assert!(got.contains(&(0, 3)) && got.contains(&(2, 3)) && got.contains(&(0, 4)));
        assert!(got.contains(&(0, 6)));
        assert!(!got
            .iter()
            .any(|&(i, j)| i == 1 || j == 1 || i == 5 || j == 5));
    }

    /// A hull across 1e300 m among unit ones: its cell count overflows
    /// even i128 (2^64 cells per axis), so it is tested directly.
    #[test]
    fn a_hull_of_astronomical_size_is_tested_directly() {
        let unit = boxed(DVec3::ZERO, DVec3::ONE);
        let far = boxed(DVec3::splat(5.0), DVec3::splat(6.0));
        let thrown = boxed(DVec3::splat(0.5), DVec3::splat(1e300));
        let hulls = [unit, far, thrown, unit];
        let got = overlapping_pairs(&hulls);
        assert_eq!(got, brute_force_pairs(&hulls));
        assert!(got.contains(&(0, 2)) && got.contains(&(1, 2)) && got.contains(&(2, 3)));
    }

    #[test]
    fn degenerate_inputs() {
        assert!(overlapping_pairs(&[]).is_empty());
        let p = Dop26::from_point(DVec3::new(0.5, -2.0, 3.0));
        // every hull a single point: the voxel size falls back to 1
        assert_eq!(overlapping_pairs(&[p, p, p]), vec![(0, 1), (0, 2), (1, 2)]);
    }
}
