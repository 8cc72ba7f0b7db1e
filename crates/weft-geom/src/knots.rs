//! Knotted ribbons: a reef (square) knot of two ropes and a bowline, tied
//! loosely in ribbons that rest on their flat strips (see [`crate::ribbon`]).
//!
//! # What limits the shapes
//!
//! A ribbon of width `w` bends freely only about its width: where its
//! centreline bends hard, the width direction `d` must follow the binormal
//! (the edge strain is first order in `kappa (N.d) w/2`), and `d` may turn
//! about the tangent only slowly (the twist strain is `(w/2)^2 theta'^2 / 2`;
//! a quarter turn costs about 0.5 % over 8 w). So every knot here is built
//! from straight runs, where the ribbon can twist, and round bends of radius
//! 5 w to 7 w, where it cannot; its strain stays below 0.8 % (1 % is the
//! limit the scenes promise). Control points are in units of `w`, smoothed by
//! a clamped cubic B-spline ([`crate::ribbon::bspline`]), 1.5 w apart.
//!
//! # Reef: drawn in the plane with heights at the crossings
//!
//! Two ropes, each a U lying in the plane z = 0: rope 0 runs from its ends at
//! `x = -24, y = +-2` along straight legs that spread to `y = +-7` at
//! `x = 14`, where its bight (radius 7, centre `(14, 0)`) turns; rope 1 is
//! rope 0 turned half a turn about z (ends at `x = +24`). The bights
//! interlock in 6 crossings, found exactly on the smoothed curves; rope 0
//! passes under, over, under, under, over, under — the square knot (closed
//! end to end on each side it is the sum of a trefoil and its mirror image),
//! not the granny. On the straight legs a ribbon lies flat (a
//! [`crate::ribbon::WidthHint`] pulls `d` horizontal there, with 8 w of
//! straight leg left to turn on edge before a bight); in the bights it stands
//! on edge. A rope's height `z(s)` holds `+g/2` (over) or `-g/2` (under) on a
//! plateau around each of its crossings, as long as the two ribbons'
//! footprints overlap, and blends between plateaus by half cosines (staying
//! level between two passages on the same side). The gap `g` of a crossing is
//! `2 c + 0.1 w` plus `w/2` times the vertical extent `|d.z|` of each ribbon
//! there, found by a few fixed-point rounds (gap, heights, width directions).
//!
//! # Bowline: drawn in space (y up)
//!
//! One rope, from the standing part's end `(11.7, 32, -11.0) w` to the tail.
//! The nipping turn is a helix of radius 5 w about the y axis climbing 1.6 w
//! per turn, a turn and a quarter long, on which the ribbon lies flat like a
//! tape round a post. The standing part comes straight down, bends (radius
//! 5 w) into a 10 w straight run that meets the turn at its bottom, climbs
//! the turn, and leaves it at the top by another 10 w run (on the runs the
//! ribbon turns from standing across the bends to lying on the turn) and a
//! bend down into the fixed loop's first leg. The fixed loop is half a turn
//! of radius about 8 w in a vertical plane, its bottom at about
//! `(2.5, -23.7, 8.9) w`. Its second leg is the working part: it rises through
//! the nipping turn, leans over (70 degrees from vertical) to the standing
//! part, makes the collar (half a turn of radius 2.5 w) round it, and comes
//! back the same way, 5 w beside itself, down through the turn to the tail
//! at `(-0.3, -10, -3.2) w`, inside the fixed loop. The turn climbs in the
//! sense that puts the rope leaving it on top of the standing part where
//! they cross — the bowline as it is tied ("the rabbit comes up the hole,
//! round the tree and back down"), not the capsizing variant; the whole knot
//! is then turned 25 degrees about y so that no straight run is seen end on
//! from +z. The turn, the runs and the height of the lean (4 w above the
//! turn's bottom) are about as small as the strain limit allows: a pull sets
//! this knot tight, where the first design (a 6 w turn, 12 w runs, the lean
//! at 7 w, the collar 18 w from the turn's axis) kept more slack than any
//! pull along the rope took out (`docs/scenes.md`).
//!
//! # Checks
//!
//! The generated meshes are checked exactly: the smallest distance over all
//! contact stencils of the whole knot (vertex–face with the vertex not a
//! corner of the face, edge–edge with no shared vertex,
//! [`crate::ribbon::min_clearance`]) must be at least the clearance `c`, or
//! [`knot`] returns [`KnotError::Clearance`]. The initial strain of every
//! rope against its flat rest strip is measured as `weft info` measures it.
//! [`Knot::crossings`] lists the crossings of the projection onto z = 0 of
//! the generated centrelines, with which strand is on top.

use glam::{DVec2, DVec3};
use thiserror::Error;
use weft_core::TriMesh;

use crate::ribbon::{
    bspline, min_clearance, resolution_for, ribbon_with_hints, rows_for, width_directions,
    RibbonError, WidthHint,
};

/// The knots this module ties.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KnotKind {
    /// Reef (square) knot: two ropes.
    Reef,
    /// Bowline: one rope with a fixed loop.
    Bowline,
}

impl KnotKind {
    /// Every knot, in the order of their names.
    pub const ALL: [KnotKind; 2] = [KnotKind::Reef, KnotKind::Bowline];

    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            KnotKind::Reef => "reef",
            KnotKind::Bowline => "bowline",
        }
    }

    /// Parses a scene-file name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// A knot that cannot be tied.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum KnotError {
    #[error("width must be a positive, finite length in metres (got {0})")]
    Width(f64),
    #[error("clearance must be a positive length of at most width / 4 = {max:.4e} m for these knots (got {clearance})")]
    ClearanceRange { clearance: f64, max: f64 },
    #[error("vertices across must be at least 2 (got {0})")]
    Across(usize),
    #[error("the mesh is too fine for the clearance: its smallest triangle altitude {altitude:.4e} m is below the clearance {clearance:.4e} m (neighbouring vertices of the strip are closer than the clearance); use fewer vertices or a smaller clearance")]
    TooFine { altitude: f64, clearance: f64 },
    #[error("knot design: {0}")]
    Design(String),
    #[error("rope {rope}: {source}")]
    Ribbon {
        rope: usize,
        #[source]
        source: RibbonError,
    },
    #[error("the knot's clearance {found:.4e} m (between vertices {vertices:?}) is below the required {required:.4e} m")]
    Clearance {
        found: f64,
        required: f64,
        vertices: [u32; 4],
    },
}

/// Resolution of a generated knot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KnotResolution {
    /// This many vertices across every rope; rows along so that the spacing
    /// along matches the spacing across.
    Across(usize),
    /// About this many vertices in all ([`resolution_for`]).
    Vertices(usize),
}

/// Parameters of [`knot`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KnotParams {
    /// Ribbon width `w` (m).
    pub width: f64,
    /// Required clearance `c` between non-adjacent parts at the start (m).
    pub clearance: f64,
    pub resolution: KnotResolution,
}

/// One rope of a generated knot.
#[derive(Clone, Debug, PartialEq)]
pub struct Rope {
    /// Id of the rope's first vertex in [`Knot::mesh`]; the rope has
    /// `across * along` vertices, row `i` column `j` at `first + i * across + j`.
    pub first_vertex: u32,
    pub across: usize,
    pub along: usize,
    /// Length of the rope's centreline = of its rest strip (m).
    pub length: f64,
    /// Centres of the first and the last row (m).
    pub ends: [DVec3; 2],
    /// Outward unit directions of the rope at its two ends.
    pub end_directions: [DVec3; 2],
    /// The rope's initial strain (largest |principal Green strain|).
    pub max_strain: f64,
}

/// One crossing of the knot diagram (the projection onto z = 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// The two ropes and the arc lengths (m, along each rope's centreline
    /// polyline) where they cross; `a` passes over `b`.
    pub over: (usize, f64),
    pub under: (usize, f64),
    /// The crossing point in the plane.
    pub point: DVec2,
    /// Unit tangents (in the plane) of the over and the under strand there,
    /// each in its rope's direction.
    pub over_direction: DVec2,
    pub under_direction: DVec2,
    /// Height of the over strand's centreline above the under strand's there.
    pub gap: f64,
}

/// A generated knot.
#[derive(Clone, Debug)]
pub struct Knot {
    pub kind: KnotKind,
    /// Start shape: the ropes one after the other.
    pub mesh: TriMesh,
    /// Flat rest strips, same vertex order (rope `k` lies in the plane z = 0
    /// along x, shifted by `3 k w` in y).
    pub rest: Vec<DVec3>,
    pub ropes: Vec<Rope>,
    /// Largest initial strain over the ropes.
    pub max_strain: f64,
    /// Smallest distance over the mesh's contact stencils, measured up to
    /// `4 c` (a knot whose stencils are all farther reports `4 c`).
    pub clearance: f64,
    /// The crossings of the diagram of the ropes' centrelines.
    pub crossings: Vec<Crossing>,
}

/// The design of one rope drawn in the plane: control points in units of
/// the width and the over (true) / under sequence of its crossings in its
/// own order.
struct RopeDesign {
    control: Vec<DVec2>,
    over: Vec<bool>,
}

/// A knot's design: ropes drawn in the plane with their crossings, or ropes
/// drawn in space (control points in units of the width).
enum Design {
    Planar(Vec<RopeDesign>),
    Spatial(Vec<Vec<DVec3>>),
}

/// Points from `a` towards `b` spaced about `step` (excluding `b`).
fn line(out: &mut Vec<DVec2>, a: DVec2, b: DVec2, step: f64) {
    let n = ((b - a).length() / step).ceil().max(1.0) as usize;
    for k in 0..n {
        out.push(a.lerp(b, k as f64 / n as f64));
    }
}

/// Points on the arc about `c` of radius `r` from angle `a0` to `a1`
/// (radians; counter-clockwise when `a1 > a0`) spaced about `step` (excluding
/// the end).
fn arc(out: &mut Vec<DVec2>, c: DVec2, r: f64, a0: f64, a1: f64, step: f64) {
    let n = ((a1 - a0).abs() * r / step).ceil().max(1.0) as usize;
    for k in 0..n {
        let a = a0 + (a1 - a0) * k as f64 / n as f64;
        out.push(c + r * DVec2::new(libm::cos(a), libm::sin(a)));
    }
}

/// Spacing of the control points (units of the width).
const STEP: f64 = 1.5;

fn reef_design() -> Vec<RopeDesign> {
    use std::f64::consts::FRAC_PI_2;
    // Rope 0: top leg from the left end to the bight, the bight (radius 7
    // about (9, 0), clockwise), the bottom leg back to the left.
    let (xe, ya, xb, yb) = (-24.0, 2.0, 14.0, 7.0);
    let mut p = Vec::new();
    line(&mut p, DVec2::new(xe, ya), DVec2::new(xb, yb), STEP);
    arc(&mut p, DVec2::new(xb, 0.0), yb, FRAC_PI_2, -FRAC_PI_2, STEP);
    line(&mut p, DVec2::new(xb, -yb), DVec2::new(xe, -ya), STEP);
    p.push(DVec2::new(xe, -ya));
    // Rope 1: rope 0 turned half a turn about the z axis.
    let q: Vec<DVec2> = p.iter().map(|&v| -v).collect();
    vec![
        RopeDesign {
            control: p,
            over: vec![false, true, false, false, true, false],
        },
        RopeDesign {
            control: q,
            over: vec![true, false, true, true, false, true],
        },
    ]
}

/// Points of a circular arc of radius `r` that starts at `p` heading `h0`
/// and turns in the plane of `h0` and `h1` until it heads `h1` (unit
/// vectors, not parallel), spaced about `step` (the end excluded); returns
/// the end point.
fn bend(out: &mut Vec<DVec3>, p: DVec3, h0: DVec3, h1: DVec3, r: f64, step: f64) -> DVec3 {
    let m = (h1 - h0 * h0.dot(h1)).normalize();
    let c = p + m * r;
    let angle = libm::acos(h0.dot(h1).clamp(-1.0, 1.0));
    let n = (angle * r / step).ceil().max(1.0) as usize;
    let at = |t: f64| c + (-m * libm::cos(t) + h0 * libm::sin(t)) * r;
    for k in 0..n {
        out.push(at(angle * k as f64 / n as f64));
    }
    at(angle)
}

/// Points from `a` towards `b` spaced about `step` (excluding `b`).
fn line3(out: &mut Vec<DVec3>, a: DVec3, b: DVec3, step: f64) {
    let n = ((b - a).length() / step).ceil().max(1.0) as usize;
    for k in 0..n {
        out.push(a.lerp(b, k as f64 / n as f64));
    }
}

/// The bowline, drawn in space (y up): see the module docs.
fn bowline_design() -> Vec<Vec<DVec3>> {
    use std::f64::consts::{FRAC_PI_2, PI};
    // The nipping turn: a helix of radius r about the y axis climbing
    // `pitch` per turn, from angle -90 degrees (the back, z = -r) through a
    // turn and a quarter to angle 360 degrees (x = +r).
    let (r, pitch) = (5.0, 1.6);
    let turn = 2.5 * PI; // a turn and a quarter
    let rise = pitch / (2.0 * PI * r); // dy / du
    let helix = |psi: f64| {
        DVec3::new(
            r * libm::cos(psi),
            (psi + FRAC_PI_2) * r * rise,
            r * libm::sin(psi),
        )
    };
    let tangent = |psi: f64| DVec3::new(-libm::sin(psi), rise, libm::cos(psi)).normalize();
    let (psi0, psi1) = (-FRAC_PI_2, -FRAC_PI_2 + turn);
    let (h0, h1) = (helix(psi0), helix(psi1));
    // Straight runs into and out of the turn (where the ribbon turns from
    // lying on the turn to standing across the bends) and bends of radius
    // rho_b to and from vertical.
    let (run, rho_b) = (10.0, 5.0);
    // The standing part: down from y_top, a bend, the run into the turn.
    let t_in = tangent(psi0);
    let p_s = h0 - t_in * run;
    let mut back = Vec::new();
    let q = bend(&mut back, p_s, -t_in, DVec3::Y, rho_b, STEP);
    let y_top = 32.0;
    let mut p = Vec::new();
    line3(&mut p, DVec3::new(q.x, y_top, q.z), q, STEP);
    p.extend(back.iter().rev());
    line3(&mut p, p_s, h0, STEP);
    let n = ((psi1 - psi0) * r / STEP).ceil() as usize;
    for k in 0..n {
        p.push(helix(psi0 + (psi1 - psi0) * k as f64 / n as f64));
    }
    // Out of the turn, the bend down, the fixed loop's first leg.
    let t_out = tangent(psi1);
    let p_e = h1 + t_out * run;
    line3(&mut p, h1, p_e, STEP);
    let e = bend(&mut p, p_e, t_out, -DVec3::Y, rho_b, STEP);
    let y_loop = -16.0;
    let e_low = DVec3::new(e.x, y_loop, e.z);
    line3(&mut p, e, e_low, STEP);
    // The working part's legs inside the turn, a apart across the direction
    // from the turn's axis to the standing part, so that the standing part
    // passes between them where they lean over to it.
    let a = 2.5;
    let to_s = DVec3::new(q.x, 0.0, q.z);
    let dir = to_s.normalize();
    let across = DVec3::new(-to_s.z, 0.0, to_s.x).normalize();
    // The legs' middle sits `toward` from the axis towards the standing part.
    let toward = 2.0;
    let up_leg = dir * toward - across * a;
    let w_low = DVec3::new(up_leg.x, y_loop, up_leg.z);
    // The fixed loop: half a turn in the vertical plane of its two legs.
    let chord = w_low - e_low;
    let centre = 0.5 * (e_low + w_low);
    let lr = 0.5 * chord.length();
    let ex = chord.normalize();
    let nl = (PI * lr / STEP).ceil() as usize;
    for k in 0..nl {
        let t = PI * k as f64 / nl as f64;
        p.push(centre - ex * (lr * libm::cos(t)) - DVec3::Y * (lr * libm::sin(t)));
    }
    // Up, a bend leaning over towards the standing part, the lean, the
    // collar (half a turn of radius a) beyond the standing part, and the
    // same way back down through the turn to the tail.
    let y_bend = 4.0;
    let lean = 70.0f64.to_radians();
    let t_c = (dir * libm::sin(lean) + DVec3::Y * libm::cos(lean)).normalize();
    // The collar's middle lands 2.5 beyond the standing part.
    let reach = to_s.length() - toward - rho_b * (1.0 - libm::cos(lean)) + 2.5;
    let leg_len = reach / libm::sin(lean);
    let mut up = Vec::new();
    let b0 = DVec3::new(up_leg.x, y_bend, up_leg.z);
    line3(&mut up, w_low, b0, STEP);
    let l0 = bend(&mut up, b0, DVec3::Y, t_c, rho_b, STEP);
    line3(&mut up, l0, l0 + t_c * leg_len, STEP);
    p.extend(up.iter().copied());
    let c_c = l0 + t_c * leg_len + across * a;
    let nc = (PI * a / STEP).ceil() as usize;
    for k in 0..nc {
        let t = PI * k as f64 / nc as f64;
        p.push(c_c - across * (a * libm::cos(t)) + t_c * (a * libm::sin(t)));
    }
    let y_tail = -10.0;
    let shift = across * (2.0 * a);
    for q in up.iter().rev().filter(|q| q.y >= y_tail) {
        p.push(*q + shift);
    }
    p.push(DVec3::new(up_leg.x + shift.x, y_tail, up_leg.z + shift.z));
    // Mirror (x -> -x): the climbing turn drawn above is the left-handed
    // bowline; then turn about y so that no straight run is seen end-on
    // from +z.
    let yaw = 25.0f64.to_radians();
    let (sy, cy) = (libm::sin(yaw), libm::cos(yaw));
    for q in &mut p {
        let x = -q.x;
        *q = DVec3::new(cy * x + sy * q.z, q.y, -sy * x + cy * q.z);
    }
    vec![p]
}

/// A crossing of two dense polylines: rope, arc length, and direction for each.
#[derive(Clone, Copy, Debug)]
struct RawCrossing {
    a: (usize, f64, DVec2),
    b: (usize, f64, DVec2),
    point: DVec2,
}

/// Crossings of the projections onto z = 0 of the polylines `curves`
/// (self-crossings included, adjacent segments skipped), with arc lengths
/// along each curve's polyline and the tangents there.
fn raw_crossings(curves: &[Vec<DVec2>]) -> Vec<RawCrossing> {
    let mut cum: Vec<Vec<f64>> = Vec::new();
    for c in curves {
        let mut s = vec![0.0];
        for w in c.windows(2) {
            s.push(s.last().unwrap_or(&0.0) + (w[1] - w[0]).length());
        }
        cum.push(s);
    }
    // Chunks of 32 segments with bounding boxes, to prune.
    let mut chunks = Vec::new();
    for (ci, c) in curves.iter().enumerate() {
        let nseg = c.len().saturating_sub(1);
        let mut k = 0;
        while k < nseg {
            let end = (k + 32).min(nseg);
            let mut lo = c[k];
            let mut hi = c[k];
            for p in &c[k..=end] {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            chunks.push((ci, k, end, lo, hi));
            k = end;
        }
    }
    let mut out = Vec::new();
    for x in 0..chunks.len() {
        for y in x..chunks.len() {
            let (ca, ka0, ka1, alo, ahi) = chunks[x];
            let (cb, kb0, kb1, blo, bhi) = chunks[y];
            if alo.x > bhi.x || blo.x > ahi.x || alo.y > bhi.y || blo.y > ahi.y {
                continue;
            }
            for i in ka0..ka1 {
                let jstart = if x == y { i + 2 } else { kb0 };
                for j in jstart..kb1 {
                    if ca == cb && j <= i + 1 {
                        continue;
                    }
                    let (p, q) = (curves[ca][i], curves[ca][i + 1]);
                    let (r, s) = (curves[cb][j], curves[cb][j + 1]);
                    let (d1, d2) = (q - p, s - r);
                    let den = d1.perp_dot(d2);
                    if den == 0.0 {
                        continue;
                    }
                    let t = (r - p).perp_dot(d2) / den;
                    let u = (r - p).perp_dot(d1) / den;
                    if (0.0..1.0).contains(&t) && (0.0..1.0).contains(&u) {
                        out.push(RawCrossing {
                            a: (ca, cum[ca][i] + t * d1.length(), d1.normalize()),
                            b: (cb, cum[cb][j] + u * d2.length(), d2.normalize()),
                            point: p + d1 * t,
                        });
                    }
                }
            }
        }
    }
    out
}

/// Crossings of the projections onto z = 0 of the polylines `curves`, with
/// the strand passing over (the higher one at the crossing point) first; arc
/// lengths along each polyline. Adjacent segments of a curve are not tested.
pub fn planar_crossings(curves: &[Vec<DVec3>]) -> Vec<Crossing> {
    let flat: Vec<Vec<DVec2>> = curves
        .iter()
        .map(|c| c.iter().map(|p| p.truncate()).collect())
        .collect();
    let cum: Vec<Vec<f64>> = curves.iter().map(|c| cumulative(c)).collect();
    let cum2: Vec<Vec<f64>> = flat.iter().map(|c| cumulative2(c)).collect();
    raw_crossings(&flat)
        .into_iter()
        .map(|x| {
            let z = |(rope, s, _): (usize, f64, DVec2)| {
                let (i, t) = locate(&cum2[rope], s);
                let c = &curves[rope];
                c[i].z + (c[(i + 1).min(c.len() - 1)].z - c[i].z) * t
            };
            let s3 = |(rope, s, _): (usize, f64, DVec2)| map_arc(&cum2[rope], &cum[rope], s);
            let (za, zb) = (z(x.a), z(x.b));
            let (o, u) = if za >= zb { (x.a, x.b) } else { (x.b, x.a) };
            Crossing {
                over: (o.0, s3(o)),
                under: (u.0, s3(u)),
                point: x.point,
                over_direction: o.2,
                under_direction: u.2,
                gap: (za - zb).abs(),
            }
        })
        .collect()
}

fn cumulative(c: &[DVec3]) -> Vec<f64> {
    let mut s = Vec::with_capacity(c.len());
    let mut acc = 0.0;
    s.push(0.0);
    for w in c.windows(2) {
        acc += (w[1] - w[0]).length();
        s.push(acc);
    }
    s
}

fn cumulative2(c: &[DVec2]) -> Vec<f64> {
    let mut s = Vec::with_capacity(c.len());
    let mut acc = 0.0;
    s.push(0.0);
    for w in c.windows(2) {
        acc += (w[1] - w[0]).length();
        s.push(acc);
    }
    s
}

/// Segment index and fraction where the cumulative lengths `cum` reach `s`.
fn locate(cum: &[f64], s: f64) -> (usize, f64) {
    let n = cum.len();
    if n < 2 {
        return (0, 0.0);
    }
    let i = cum.partition_point(|&x| x <= s).clamp(1, n - 1) - 1;
    let len = cum[i + 1] - cum[i];
    let t = if len > 0.0 {
        ((s - cum[i]) / len).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (i, t)
}

/// The arc length in `to` at the point where `from` (same vertices) reaches `s`.
fn map_arc(from: &[f64], to: &[f64], s: f64) -> f64 {
    let (i, t) = locate(from, s);
    let j = (i + 1).min(to.len() - 1);
    to[i] + (to[j] - to[i]) * t
}

/// Largest discrete curvature of the polyline `c` within `radius` (arc
/// length) of `s`.
fn curvature_near(c: &[DVec2], cum: &[f64], s: f64, radius: f64) -> f64 {
    let mut k = 0.0f64;
    for i in 1..c.len() - 1 {
        if (cum[i] - s).abs() > radius {
            continue;
        }
        let (e0, e1) = (c[i] - c[i - 1], c[i + 1] - c[i]);
        let angle = libm::atan2(e0.perp_dot(e1).abs(), e0.dot(e1));
        k = k.max(angle / (0.5 * (e0.length() + e1.length())));
    }
    k
}

/// Heights `z(s)` at the arc lengths `s` of a rope: plateaus `(s_k, z_k,
/// p_k)` (height `z_k` on `[s_k - p_k, s_k + p_k]`), half-cosine blends
/// between them and to 0 over `ramp` before the first and after the last.
fn heights(s: &[f64], holds: &[(f64, f64, f64)], ramp: f64) -> Result<Vec<f64>, String> {
    // Merge plateaus into intervals [lo, hi] at z; consecutive plateaus on
    // the same side become one interval at the larger height (a strand does
    // not dip between two passages over).
    let mut iv: Vec<(f64, f64, f64)> = Vec::new();
    for &(sk, zk, pk) in holds {
        let (lo, hi) = (sk - pk, sk + pk);
        if let Some(last) = iv.last_mut() {
            if (zk > 0.0) == (last.2 > 0.0) {
                last.1 = last.1.max(hi);
                last.2 = if zk.abs() > last.2.abs() { zk } else { last.2 };
                continue;
            }
            if lo <= last.1 {
                return Err(format!(
                    "two crossings on opposite sides are too close along a rope (at arc length {:.3} and {:.3} m)",
                    last.1, sk
                ));
            }
        }
        iv.push((lo, hi, zk));
    }
    let blend = |a: f64, b: f64, t: f64| {
        a + (b - a) * 0.5 * (1.0 - libm::cos(std::f64::consts::PI * t.clamp(0.0, 1.0)))
    };
    Ok(s.iter()
        .map(|&x| {
            let Some(first) = iv.first() else { return 0.0 };
            if x < first.0 {
                return blend(0.0, first.2, 1.0 - (first.0 - x) / ramp);
            }
            for k in 0..iv.len() {
                let (lo, hi, z) = iv[k];
                if x <= hi && x >= lo {
                    return z;
                }
                if let Some(next) = iv.get(k + 1) {
                    if x > hi && x < next.0 {
                        return blend(z, next.2, (x - hi) / (next.0 - hi));
                    }
                }
            }
            let last = iv[iv.len() - 1];
            blend(last.2, 0.0, (x - last.1) / ramp)
        })
        .collect())
}

/// The centrelines of a knot before meshing.
struct Layout {
    /// Dense 3D centrelines.
    curves: Vec<Vec<DVec3>>,
    /// Width hints per rope (arc lengths along the dense curves).
    hints: Vec<Vec<WidthHint>>,
}

/// Lengths (m) of the ropes of `kind` tied in ribbons of `width`, measured on
/// the diagram (the 3D centrelines are longer by well under 0.1 %).
pub fn rope_lengths(kind: KnotKind, width: f64) -> Vec<f64> {
    let controls: Vec<Vec<DVec3>> = match kind.design() {
        Design::Planar(ropes) => ropes
            .iter()
            .map(|r| r.control.iter().map(|p| p.extend(0.0)).collect())
            .collect(),
        Design::Spatial(ropes) => ropes,
    };
    controls
        .iter()
        .map(|c| {
            let c: Vec<DVec3> = c.iter().map(|p| *p * width).collect();
            crate::ribbon::polyline_length(&bspline(&c, 16))
        })
        .collect()
}

impl KnotKind {
    fn design(self) -> Design {
        match self {
            KnotKind::Reef => Design::Planar(reef_design()),
            KnotKind::Bowline => Design::Spatial(bowline_design()),
        }
    }
}

fn layout(kind: KnotKind, w: f64, c: f64) -> Result<Layout, KnotError> {
    let design = match kind.design() {
        Design::Planar(ropes) => ropes,
        Design::Spatial(ropes) => {
            // Drawn in space with room between its parts: smooth, no hints.
            let curves: Vec<Vec<DVec3>> = ropes
                .iter()
                .map(|r| bspline(&r.iter().map(|p| *p * w).collect::<Vec<_>>(), 16))
                .collect();
            let hints = vec![Vec::new(); curves.len()];
            return Ok(Layout { curves, hints });
        }
    };
    let flat: Vec<Vec<DVec2>> = design
        .iter()
        .map(|r| {
            let c: Vec<DVec3> = r.control.iter().map(|p| (*p * w).extend(0.0)).collect();
            bspline(&c, 16).into_iter().map(|p| p.truncate()).collect()
        })
        .collect();
    let cum2: Vec<Vec<f64>> = flat.iter().map(|c| cumulative2(c)).collect();
    let raw = raw_crossings(&flat);
    // Passages per rope in order: (arc length, crossing, is the `a` side).
    let mut passages: Vec<Vec<(f64, usize, bool)>> = vec![Vec::new(); design.len()];
    for (k, x) in raw.iter().enumerate() {
        passages[x.a.0].push((x.a.1, k, true));
        passages[x.b.0].push((x.b.1, k, false));
    }
    let mut over_of = vec![[None::<bool>; 2]; raw.len()];
    for (r, p) in passages.iter_mut().enumerate() {
        p.sort_by(|x, y| x.0.total_cmp(&y.0));
        if p.len() != design[r].over.len() {
            return Err(KnotError::Design(format!(
                "rope {r} of the {} knot crosses {} times, the design lists {}",
                kind.name(),
                p.len(),
                design[r].over.len()
            )));
        }
        for (q, &(_, k, is_a)) in p.iter().enumerate() {
            over_of[k][usize::from(!is_a)] = Some(design[r].over[q]);
        }
    }
    for (k, o) in over_of.iter().enumerate() {
        if o[0] == o[1] {
            return Err(KnotError::Design(format!(
                "crossing {k} at {:?} has both strands on the same side",
                raw[k].point / w
            )));
        }
    }
    // Per crossing: plateau half-length (the ribbons' footprints overlap
    // there) and whether each strand bends in the plane (then it stands on
    // edge).
    // Plateau half-length along a strand: as long as the other ribbon's
    // footprint overlaps it, from each ribbon's horizontal half-extent
    // `e = w/2 sqrt(1 - tilt^2)` and the crossing angle.
    let sin_angle: Vec<f64> = raw
        .iter()
        .map(|x| x.a.2.perp_dot(x.b.2).abs().clamp(0.05, 1.0))
        .collect();
    let plateaus = |tilt: &[[f64; 2]]| -> Vec<[f64; 2]> {
        tilt.iter()
            .zip(&sin_angle)
            .map(|(t, &sin)| {
                let cos = (1.0 - sin * sin).sqrt();
                let e = t.map(|t| 0.5 * w * (1.0 - t * t).max(0.0).sqrt());
                [0, 1].map(|k| e[1 - k] / sin + e[k] * cos / sin + 0.25 * w)
            })
            .collect()
    };
    let plateau: Vec<f64> = plateaus(&vec![[0.0; 2]; raw.len()])
        .iter()
        .map(|p| p[0])
        .collect();
    // A strand lies flat at a crossing when it is straight there and for a
    // twist length beyond the plateau on both sides.
    let margin = 6.0;
    let straight = |rope: usize, s: f64, p: f64| {
        curvature_near(&flat[rope], &cum2[rope], s, p + margin * w) * w <= 0.05
    };
    let flat_side: Vec<[bool; 2]> = raw
        .iter()
        .zip(&plateau)
        .map(|(x, &p)| [straight(x.a.0, x.a.1, p), straight(x.b.0, x.b.1, p)])
        .collect();
    let mut tilt: Vec<[f64; 2]> = flat_side
        .iter()
        .map(|f| f.map(|flat| if flat { 0.0 } else { 1.0 }))
        .collect();
    let mut curves = Vec::new();
    let mut hints = Vec::new();
    for round in 0..4 {
        let gap: Vec<f64> = tilt
            .iter()
            .map(|t| 2.0 * c + 0.1 * w + 0.5 * w * (t[0] + t[1]))
            .collect();
        let plateau = plateaus(&tilt);
        curves.clear();
        hints.clear();
        for (r, f) in flat.iter().enumerate() {
            let holds: Vec<(f64, f64, f64)> = passages[r]
                .iter()
                .map(|&(s, k, is_a)| {
                    let up = over_of[k][usize::from(!is_a)] == Some(true);
                    let p = plateau[k][usize::from(!is_a)];
                    (s, if up { 0.5 * gap[k] } else { -0.5 * gap[k] }, p)
                })
                .collect();
            let z = heights(&cum2[r], &holds, 8.0 * w).map_err(KnotError::Design)?;
            let curve: Vec<DVec3> = f.iter().zip(&z).map(|(p, &z)| p.extend(z)).collect();
            let cum3 = cumulative(&curve);
            let h: Vec<WidthHint> = passages[r]
                .iter()
                .filter(|&&(_, k, is_a)| flat_side[k][usize::from(!is_a)])
                .map(|&(s, k, is_a)| {
                    let (i, _) = locate(&cum2[r], s);
                    let t = (f[(i + 1).min(f.len() - 1)] - f[i]).normalize();
                    WidthHint {
                        s: map_arc(&cum2[r], &cum3, s),
                        half_length: plateau[k][usize::from(!is_a)],
                        direction: DVec3::new(-t.y, t.x, 0.0),
                        weight: 0.01,
                    }
                })
                .collect();
            curves.push(curve);
            hints.push(h);
        }
        if round == 3 {
            break;
        }
        // Measure the vertical extent of the width direction on each plateau
        // at a fine resolution (w/4 along).
        let mut measured = vec![[0.0f64; 2]; raw.len()];
        for (r, curve) in curves.iter().enumerate() {
            let len = crate::ribbon::polyline_length(curve);
            let rows = ((len / (0.25 * w)).round() as usize).max(2) + 1;
            let c = crate::ribbon::resample(curve, rows)
                .map_err(|e| KnotError::Ribbon { rope: r, source: e })?;
            let scale = crate::ribbon::polyline_length(&c) / len;
            let hs: Vec<WidthHint> = hints[r].iter().map(|h| h.scaled(scale)).collect();
            let d = width_directions(&c, w, crate::ribbon::TWIST_WEIGHT, &hs);
            let cum = cumulative(&c);
            let cum3 = cumulative(curve);
            for &(s, k, is_a) in &passages[r] {
                let s3 = map_arc(&cum2[r], &cum3, s) * scale;
                let m = cum
                    .iter()
                    .zip(&d)
                    .filter(|(x, _)| (**x - s3).abs() <= plateau[k][usize::from(!is_a)])
                    .map(|(_, d)| d.z.abs())
                    .fold(0.0f64, f64::max);
                measured[k][usize::from(!is_a)] = m;
            }
        }
        tilt = measured;
    }
    Ok(Layout { curves, hints })
}

/// Ties a knot of `kind` in ribbons: see the module docs.
pub fn knot(kind: KnotKind, params: &KnotParams) -> Result<Knot, KnotError> {
    let (w, c) = (params.width, params.clearance);
    if !(w > 0.0 && w.is_finite()) {
        return Err(KnotError::Width(w));
    }
    if !(c > 0.0 && c <= 0.25 * w) {
        return Err(KnotError::ClearanceRange {
            clearance: c,
            max: 0.25 * w,
        });
    }
    let lay = layout(kind, w, c)?;
    let lengths: Vec<f64> = lay
        .curves
        .iter()
        .map(|c| crate::ribbon::polyline_length(c))
        .collect();
    let (across, rows) = match params.resolution {
        KnotResolution::Across(n) => {
            if n < 2 {
                return Err(KnotError::Across(n));
            }
            (n, lengths.iter().map(|&l| rows_for(l, w, n)).collect())
        }
        KnotResolution::Vertices(n) => resolution_for(&lengths, w, n),
    };
    let mut mesh = TriMesh::default();
    let mut rest = Vec::new();
    let mut ropes = Vec::new();
    let mut max_strain = 0.0f64;
    for (r, curve) in lay.curves.iter().enumerate() {
        let rb = ribbon_with_hints(curve, w, across, rows[r], &lay.hints[r])
            .map_err(|e| KnotError::Ribbon { rope: r, source: e })?;
        let first = mesh.append(&rb.mesh);
        rest.extend(
            rb.rest
                .iter()
                .map(|p| *p + DVec3::new(0.0, 3.0 * w * r as f64, 0.0)),
        );
        let cl = &rb.centreline;
        let n = cl.len();
        ropes.push(Rope {
            first_vertex: first,
            across,
            along: rb.along,
            length: rb.length,
            ends: [cl[0], cl[n - 1]],
            end_directions: [
                (cl[0] - cl[1]).normalize(),
                (cl[n - 1] - cl[n - 2]).normalize(),
            ],
            max_strain: rb.max_strain,
        });
        max_strain = max_strain.max(rb.max_strain);
    }
    let altitude = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, cc] = t.map(|i| mesh.positions[i as usize]);
            let area2 = (b - a).cross(cc - a).length();
            let longest = (b - a)
                .length()
                .max((cc - b).length())
                .max((a - cc).length());
            area2 / longest
        })
        .fold(f64::INFINITY, f64::min);
    if altitude < c {
        return Err(KnotError::TooFine {
            altitude,
            clearance: c,
        });
    }
    let probe = 4.0 * c;
    let clearance = match min_clearance(&mesh.positions, &mesh.triangles, probe) {
        Some(found) if found.distance < c => {
            return Err(KnotError::Clearance {
                found: found.distance,
                required: c,
                vertices: found.vertices,
            })
        }
        Some(found) => found.distance,
        None => probe,
    };
    let centrelines: Vec<Vec<DVec3>> = ropes.iter().map(|r| rope_centreline(&mesh, r)).collect();
    Ok(Knot {
        kind,
        mesh,
        rest,
        ropes,
        max_strain,
        clearance,
        crossings: planar_crossings(&centrelines),
    })
}

/// The centreline of `rope` in `mesh`: the mean of each row of vertices.
pub fn rope_centreline(mesh: &TriMesh, rope: &Rope) -> Vec<DVec3> {
    (0..rope.along)
        .map(|i| {
            let first = rope.first_vertex as usize + i * rope.across;
            let row = &mesh.positions[first..first + rope.across];
            row.iter().copied().sum::<DVec3>() / rope.across as f64
        })
        .collect()
}
