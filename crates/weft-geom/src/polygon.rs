//! Triangulating a polygon face (an OBJ or PLY n-gon) by ear clipping in its
//! best-fit plane, as DCC importers do.
//!
//! The plane's normal is Newell's (the sum of the edge cross products about the
//! centroid): it is twice the vector area of the polygon, so it is defined for
//! non-convex and slightly warped polygons alike, and its direction gives the
//! orientation the triangles keep. The corners are projected along the axis
//! that normal leans on most, onto the coordinate plane facing the polygon:
//! for a planar polygon that is an exact affine map of its plane (ears,
//! convexity and straight corners are affine notions), with no rounding, and
//! every decision is an exact `orient2d` sign on those points, so the checks
//! below and the clipping never contradict one another.
//!
//! A polygon of more than [`MAX_CORNERS`] corners is refused: the checks
//! and the ear search below take time quadratic in the corners.
//!
//! A polygon is refused, not guessed at, when it has no area (collinear
//! corners), two consecutive corners coincide, it folds back on itself at a
//! corner, or two of its edges cross or touch. A strictly convex polygon is
//! fanned from its first corner (exact for it, and what weft has always made
//! of such faces). Any other simple polygon is ear-clipped, and never into a
//! zero-area triangle: a corner where the
//! boundary goes straight on (zero turn) is never the tip of an ear, and an ear
//! is clipped only when no other corner lies in it or on its border, so such a
//! corner ends up as the base corner of a neighbouring ear. Among the ears, the
//! best-shaped is clipped first, which keeps slivers (and the small altitudes
//! that limit the contact thickness) out of the result.

use glam::DVec3;

use crate::tri_tri::{o2, point_in_triangle_2d, segments_2d};

/// Why a polygon cannot be triangulated. Corners are 0-based positions in the
/// polygon's corner list; [`PolygonError::describe`] names them the way the
/// caller's file does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PolygonError {
    /// The polygon has no area, so no plane: its corners are collinear, or it
    /// crosses itself so that its loops cancel (a symmetric figure-eight).
    ZeroArea,
    /// Consecutive corners `a` and `b` are at the same position.
    CoincidentCorners { a: usize, b: usize },
    /// The boundary turns back on itself at `corner`: its two edges overlap.
    FoldsBack { corner: usize },
    /// Two edges (each given by its two corners) cross or touch.
    SelfIntersecting { edges: [[usize; 2]; 2] },
    /// No ear was found (a numerically degenerate polygon; not expected for
    /// the simple polygons that pass the checks).
    NoEar,
    /// The polygon has more than [`MAX_CORNERS`] corners: its checks and
    /// ear clipping take time quadratic in the corners (a face of 50,000
    /// would take minutes), so it is refused at once.
    TooManyCorners { corners: usize },
}

/// The most corners [`triangulate`] takes: at this size its quadratic
/// simplicity check and ear search take some 10 ms.
pub const MAX_CORNERS: usize = 1000;

impl PolygonError {
    /// A message for the user; `corner(k)` names corner `k` (e.g. `v 12`).
    pub fn describe(&self, corner: &dyn Fn(usize) -> String) -> String {
        let edge = |[a, b]: [usize; 2]| format!("{}–{}", corner(a), corner(b));
        match *self {
            Self::ZeroArea => "the polygon has zero area: its corners are collinear, or it \
                               crosses itself so that its loops cancel"
                .into(),
            Self::CoincidentCorners { a, b } => format!(
                "corners {} and {} are at the same position; remove the repeated corner",
                corner(a),
                corner(b)
            ),
            Self::FoldsBack { corner: c } => format!(
                "the boundary turns back on itself at {}: its two edges there overlap",
                corner(c)
            ),
            Self::SelfIntersecting { edges: [e, f] } => format!(
                "its edges {} and {} cross or touch: the polygon intersects itself; \
                 split it into simple polygons",
                edge(e),
                edge(f)
            ),
            Self::NoEar => "no ear could be clipped (the polygon is numerically degenerate); \
                 split it into triangles"
                .into(),
            Self::TooManyCorners { corners } => format!(
                "weft triangulates polygons of at most {MAX_CORNERS} corners, and this one has \
                 {corners}; triangulate it in the program that wrote the file, or split it into \
                 smaller polygons"
            ),
        }
    }
}

/// Triangulates the polygon with corners `corners` (in boundary order, at least
/// 3): `n - 2` triangles as indices into `corners`, oriented like the polygon.
/// A triangle (3 corners) is returned as it is, even if degenerate: mesh
/// validation reports it with its own words. A polygon of more than
/// [`MAX_CORNERS`] corners is refused.
pub fn triangulate(corners: &[DVec3]) -> Result<Vec<[usize; 3]>, PolygonError> {
    let n = corners.len();
    if n <= 3 {
        return Ok(if n == 3 { vec![[0, 1, 2]] } else { Vec::new() });
    }
    if n > MAX_CORNERS {
        return Err(PolygonError::TooManyCorners { corners: n });
    }
    let p = project(corners)?;
    check_simple(corners, &p)?;
    if (0..n).all(|i| o2(p[(i + n - 1) % n], p[i], p[(i + 1) % n]) > 0) {
        // Strictly convex: the fan from the first corner is exact, and it is
        // what weft always made of such faces (results stay the same).
        return Ok((1..n - 1).map(|k| [0, k, k + 1]).collect());
    }
    clip_ears(&p)
}

/// The corners in 2D, counter-clockwise when seen against Newell's normal:
/// the two coordinates other than the one the normal leans on most. For a
/// planar polygon that is an exact affine map of its plane (no rounding), so
/// straight corners stay exactly straight.
fn project(corners: &[DVec3]) -> Result<Vec<[f64; 2]>, PolygonError> {
    let n = corners.len();
    let centroid = corners.iter().copied().sum::<DVec3>() / n as f64;
    let normal: DVec3 = (0..n)
        .map(|i| (corners[i] - centroid).cross(corners[(i + 1) % n] - centroid))
        .sum();
    if !(normal.length_squared() > 0.0 && normal.is_finite()) {
        return Err(PolygonError::ZeroArea);
    }
    let a = normal.abs();
    let (k, along) = if a.x >= a.y && a.x >= a.z {
        (0, normal.x)
    } else if a.y >= a.z {
        (1, normal.y)
    } else {
        (2, normal.z)
    };
    // (y, z), (z, x), (x, y): counter-clockwise about +x, +y, +z.
    Ok(corners
        .iter()
        .map(|c| {
            let q = match k {
                0 => [c.y, c.z],
                1 => [c.z, c.x],
                _ => [c.x, c.y],
            };
            if along > 0.0 {
                q
            } else {
                [q[1], q[0]]
            }
        })
        .collect())
}

/// Refuses a polygon that is not simple in its plane (`p`: the corners
/// projected onto it).
fn check_simple(corners: &[DVec3], p: &[[f64; 2]]) -> Result<(), PolygonError> {
    let n = p.len();
    for i in 0..n {
        let j = (i + 1) % n;
        if corners[i] == corners[j] || p[i] == p[j] {
            return Err(PolygonError::CoincidentCorners { a: i, b: j });
        }
    }
    for i in 0..n {
        let (a, c, b) = (p[(i + n - 1) % n], p[i], p[(i + 1) % n]);
        let same_way = (a[0] - c[0]) * (b[0] - c[0]) + (a[1] - c[1]) * (b[1] - c[1]) > 0.0;
        if o2(a, c, b) == 0 && same_way {
            return Err(PolygonError::FoldsBack { corner: i });
        }
    }
    // Every pair of edges that share no corner (closed segments: touching
    // counts). Polygons are at most MAX_CORNERS, so the quadratic scan is
    // cheap.
    for i in 0..n {
        for j in i + 2..n {
            if i == 0 && j == n - 1 {
                continue; // adjacent through corner 0
            }
            if segments_2d(p[i], p[(i + 1) % n], p[j], p[(j + 1) % n]) {
                return Err(PolygonError::SelfIntersecting {
                    edges: [[i, (i + 1) % n], [j, (j + 1) % n]],
                });
            }
        }
    }
    Ok(())
}

/// Ear clipping over a circular list of the remaining corners. A corner's ear
/// is re-evaluated when a neighbour is clipped; clipping can also unblock
/// other ears, so when none is known every remaining corner is looked at
/// again before giving up.
fn clip_ears(p: &[[f64; 2]]) -> Result<Vec<[usize; 3]>, PolygonError> {
    let n = p.len();
    let ear = |a: usize, b: usize, c: usize, next: &[usize]| ear_quality(p, a, b, c, next);
    let mut prev: Vec<usize> = (0..n).map(|i| (i + n - 1) % n).collect();
    let mut next: Vec<usize> = (0..n).map(|i| (i + 1) % n).collect();
    let mut remaining = vec![true; n];
    let mut quality: Vec<Option<f64>> = (0..n).map(|i| ear(prev[i], i, next[i], &next)).collect();
    let mut triangles = Vec::with_capacity(n - 2);
    for left in (4..=n).rev() {
        let tip = match best_ear(&quality, &remaining) {
            Some(tip) => tip,
            None => {
                for i in (0..n).filter(|&i| remaining[i]) {
                    quality[i] = ear(prev[i], i, next[i], &next);
                }
                best_ear(&quality, &remaining).ok_or(PolygonError::NoEar)?
            }
        };
        let (a, c) = (prev[tip], next[tip]);
        triangles.push([a, tip, c]);
        remaining[tip] = false;
        next[a] = c;
        prev[c] = a;
        if left > 4 {
            quality[a] = ear(prev[a], a, c, &next);
            quality[c] = ear(a, c, next[c], &next);
        } else {
            quality[a] = None;
            quality[c] = None;
        }
    }
    let first = (0..n).find(|&i| remaining[i]).ok_or(PolygonError::NoEar)?;
    let last = [prev[first], first, next[first]];
    let [a, b, c] = last;
    if o2(p[a], p[b], p[c]) <= 0 {
        return Err(PolygonError::NoEar);
    }
    triangles.push(last);
    Ok(triangles)
}

/// The remaining corner with the best known ear; the lowest corner on ties,
/// so the result is reproducible.
fn best_ear(quality: &[Option<f64>], remaining: &[bool]) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, q) in quality.iter().enumerate() {
        if let (true, Some(q)) = (remaining[i], *q) {
            if best.is_none_or(|(_, b)| q > b) {
                best = Some((i, q));
            }
        }
    }
    best.map(|(i, _)| i)
}

/// The shape quality of the ear at `b` (between `a` and `c`), or `None` when it
/// is not an ear: the turn at `b` is not strictly convex in the plane, or
/// another remaining corner lies in the closed triangle. Quality is `area / (sum of squared edge
/// lengths)`, largest for an equilateral triangle.
fn ear_quality(p: &[[f64; 2]], a: usize, b: usize, c: usize, next: &[usize]) -> Option<f64> {
    if o2(p[a], p[b], p[c]) <= 0 {
        return None;
    }
    let t = [p[a], p[b], p[c]];
    let mut k = next[c];
    while k != a {
        if point_in_triangle_2d(p[k], t) {
            return None;
        }
        k = next[k];
    }
    let sq = |x: [f64; 2], y: [f64; 2]| (x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2);
    let twice_area =
        (t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[1][1] - t[0][1]) * (t[2][0] - t[0][0]);
    Some(twice_area / (sq(t[0], t[1]) + sq(t[1], t[2]) + sq(t[2], t[0])))
}
