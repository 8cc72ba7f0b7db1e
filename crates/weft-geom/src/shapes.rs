//! Generated geometry: cloth grids and tessellated obstacles.
//!
//! Every generator returns a consistently oriented (counter-clockwise seen from
//! outside / from +normal), manifold mesh.

use std::collections::BTreeMap;

use glam::DVec3;
use weft_core::TriMesh;

/// A rectangular grid of `nu × nv` vertices spanning `[-a/2, a/2] × [-b/2, b/2]`
/// in the plane spanned by unit vectors `eu`, `ev` around `center`. Quads are
/// split along alternating diagonals (no preferred direction).
pub fn grid(center: DVec3, eu: DVec3, ev: DVec3, size: [f64; 2], res: [usize; 2]) -> TriMesh {
    let (nu, nv) = (res[0].max(2), res[1].max(2));
    let mut positions = Vec::with_capacity(nu * nv);
    for j in 0..nv {
        for i in 0..nu {
            let s = (i as f64 / (nu - 1) as f64 - 0.5) * size[0];
            let t = (j as f64 / (nv - 1) as f64 - 0.5) * size[1];
            positions.push(center + eu * s + ev * t);
        }
    }
    let id = |i: usize, j: usize| (j * nu + i) as u32;
    let mut triangles = Vec::with_capacity(2 * (nu - 1) * (nv - 1));
    for j in 0..nv - 1 {
        for i in 0..nu - 1 {
            let quad = [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
            push_quad(&mut triangles, quad, (i + j) % 2 == 0);
        }
    }
    TriMesh::new(positions, triangles)
}

/// An icosphere: the icosahedron subdivided `subdivisions` times, projected
/// onto the sphere (`10·4^n + 2` vertices).
pub fn sphere(center: DVec3, radius: f64, subdivisions: u32) -> TriMesh {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    let mut p: Vec<DVec3> = [
        (-1.0, phi, 0.0),
        (1.0, phi, 0.0),
        (-1.0, -phi, 0.0),
        (1.0, -phi, 0.0),
        (0.0, -1.0, phi),
        (0.0, 1.0, phi),
        (0.0, -1.0, -phi),
        (0.0, 1.0, -phi),
        (phi, 0.0, -1.0),
        (phi, 0.0, 1.0),
        (-phi, 0.0, -1.0),
        (-phi, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut t: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut mid: BTreeMap<(u32, u32), u32> = BTreeMap::new();
        let mut next = Vec::with_capacity(t.len() * 4);
        let mut midpoint = |a: u32, b: u32, p: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                p.push(((p[a as usize] + p[b as usize]) * 0.5).normalize());
                (p.len() - 1) as u32
            })
        };
        for &[a, b, c] in &t {
            let ab = midpoint(a, b, &mut p);
            let bc = midpoint(b, c, &mut p);
            let ca = midpoint(c, a, &mut p);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        t = next;
    }
    TriMesh::new(p.into_iter().map(|q| center + q * radius).collect(), t)
}

/// An axis-aligned box from `min` to `max` (12 triangles, outward normals).
pub fn cuboid(min: DVec3, max: DVec3) -> TriMesh {
    let c = |i: u32| {
        DVec3::new(
            if i & 1 == 0 { min.x } else { max.x },
            if i & 2 == 0 { min.y } else { max.y },
            if i & 4 == 0 { min.z } else { max.z },
        )
    };
    let positions = (0..8).map(c).collect();
    let quads = [
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
    ];
    let mut triangles = Vec::new();
    for q in quads {
        triangles.push([q[0], q[1], q[2]]);
        triangles.push([q[0], q[2], q[3]]);
    }
    TriMesh::new(positions, triangles)
}

/// A capped cylinder (rod) of `radius` from `a` to `b`: `segments` around,
/// `rings` along, closed with a fan at each end.
pub fn capped_cylinder(a: DVec3, b: DVec3, radius: f64, segments: usize, rings: usize) -> TriMesh {
    let segments = segments.max(3);
    let rings = rings.max(1);
    let axis = (b - a).normalize_or_zero();
    let helper = if axis.x.abs() < 0.9 {
        DVec3::X
    } else {
        DVec3::Y
    };
    let u = axis.cross(helper).normalize();
    let w = axis.cross(u);
    let mut positions = Vec::new();
    for r in 0..=rings {
        let c = a + (b - a) * (r as f64 / rings as f64);
        for s in 0..segments {
            let phi = std::f64::consts::TAU * s as f64 / segments as f64;
            positions.push(c + (u * libm::cos(phi) + w * libm::sin(phi)) * radius);
        }
    }
    let cap_a = positions.len() as u32;
    positions.push(a);
    let cap_b = positions.len() as u32;
    positions.push(b);
    let id = |r: usize, s: usize| (r * segments + s % segments) as u32;
    let mut triangles = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            triangles.push([id(r, s), id(r, s + 1), id(r + 1, s + 1)]);
            triangles.push([id(r, s), id(r + 1, s + 1), id(r + 1, s)]);
        }
    }
    for s in 0..segments {
        triangles.push([cap_a, id(0, s + 1), id(0, s)]);
        triangles.push([cap_b, id(rings, s), id(rings, s + 1)]);
    }
    TriMesh::new(positions, triangles)
}

/// An open tube (a sleeve: a cylinder without caps) of `radius` from `a` to
/// `b`: `res[0]` vertices around (at least 3) times `res[1]` rings along (at
/// least 2), ring by ring from `a`, each ring starting on the same side as
/// [`capped_cylinder`]'s; quads split along alternating diagonals; normals
/// point outward. Its boundary is the two end rings.
pub fn tube(a: DVec3, b: DVec3, radius: f64, res: [usize; 2]) -> TriMesh {
    let (around, along) = (res[0].max(3), res[1].max(2));
    let axis = (b - a).normalize_or_zero();
    let helper = if axis.x.abs() < 0.9 {
        DVec3::X
    } else {
        DVec3::Y
    };
    let u = axis.cross(helper).normalize();
    let w = axis.cross(u);
    let mut positions = Vec::with_capacity(around * along);
    for j in 0..along {
        let c = a + (b - a) * (j as f64 / (along - 1) as f64);
        for i in 0..around {
            let phi = std::f64::consts::TAU * i as f64 / around as f64;
            positions.push(c + (u * libm::cos(phi) + w * libm::sin(phi)) * radius);
        }
    }
    let id = |i: usize, j: usize| (j * around + i % around) as u32;
    let mut triangles = Vec::with_capacity(2 * around * (along - 1));
    for j in 0..along - 1 {
        for i in 0..around {
            let quad = [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
            push_quad(&mut triangles, quad, (i + j) % 2 == 0);
        }
    }
    TriMesh::new(positions, triangles)
}

/// Splits the quad `[a, b, c, d]` (in order around it) into two triangles
/// along `a–c` or, when `!diagonal_ac`, along `b–d`; alternating the diagonal
/// in a checkerboard keeps a grid free of a preferred shear direction.
fn push_quad(triangles: &mut Vec<[u32; 3]>, [a, b, c, d]: [u32; 4], diagonal_ac: bool) {
    if diagonal_ac {
        triangles.push([a, b, c]);
        triangles.push([a, c, d]);
    } else {
        triangles.push([a, b, d]);
        triangles.push([b, c, d]);
    }
}

/// Punches a round hole into `mesh`: removes every vertex closer than
/// `radius` to `center` and every triangle that uses one, then every vertex
/// that would join two separate fans of triangles (a "bow tie", which can
/// appear where the cut passes a grid corner), until the rim is manifold.
/// Vertices left in no triangle are dropped. Returns the new mesh (vertices
/// and triangles in their old relative order) and, per new vertex, its index
/// in `mesh`.
pub fn punch_hole(mesh: &TriMesh, center: DVec3, radius: f64) -> (TriMesh, Vec<u32>) {
    let n = mesh.num_vertices();
    let mut removed: Vec<bool> = mesh
        .positions
        .iter()
        .map(|p| (*p - center).length() < radius)
        .collect();
    loop {
        let kept: Vec<[u32; 3]> = mesh
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&i| !removed[i as usize]))
            .copied()
            .collect();
        let mut bow_ties = false;
        for (v, &d) in boundary_degree(n, &kept).iter().enumerate() {
            if d > 2 {
                removed[v] = true;
                bow_ties = true;
            }
        }
        if bow_ties {
            continue;
        }
        let mut used = vec![false; n];
        for t in &kept {
            for &i in t {
                used[i as usize] = true;
            }
        }
        let mut new_id = vec![u32::MAX; n];
        let mut old_ids = Vec::new();
        for i in 0..n {
            if used[i] {
                new_id[i] = old_ids.len() as u32;
                old_ids.push(i as u32);
            }
        }
        let positions = old_ids
            .iter()
            .map(|&i| mesh.positions[i as usize])
            .collect();
        let triangles = kept.iter().map(|t| t.map(|i| new_id[i as usize])).collect();
        return (TriMesh::new(positions, triangles), old_ids);
    }
}

/// A grid (as [`grid`]) with a round hole of `radius` centred at offsets
/// `hole` (m) from `center` along `eu`, `ev`, whose rim is a true circle:
/// the grid vertices closer than `radius` + half a grid spacing go (see
/// [`punch_hole`]), a ring of vertices is placed exactly on the circle (about
/// one per grid spacing, at least 6, the first at angle 0 from `eu` towards
/// `ev`), the gap between the ring and the cut is closed by a strip of
/// triangles (greedy shortest-diagonal stitching), and the cut's staircase
/// loop is relaxed towards its neighbours (Laplacian smoothing in the plane;
/// every other grid vertex keeps its place). Returns the mesh (grid vertices
/// first, in grid order, then the ring counter-clockwise about `eu × ev`)
/// and, per vertex, its grid index (`None` for ring vertices). Fails with a
/// message when the hole does not fit inside the sheet, catches no grid
/// vertex, or the rim cannot be stitched without slivers (altitude below a
/// tenth of the grid spacing).
pub fn grid_with_hole(
    center: DVec3,
    eu: DVec3,
    ev: DVec3,
    size: [f64; 2],
    res: [usize; 2],
    hole: [f64; 2],
    radius: f64,
) -> Result<(TriMesh, Vec<Option<u32>>), String> {
    let (nu, nv) = (res[0].max(2), res[1].max(2));
    let spacing = [size[0] / (nu - 1) as f64, size[1] / (nv - 1) as f64];
    let h = 0.5 * (spacing[0] + spacing[1]);
    let cut = radius + 0.5 * h;
    if !(radius > 0.0) {
        return Err(format!("hole radius {radius} must be positive"));
    }
    if hole[0].abs() + cut + h > 0.5 * size[0] || hole[1].abs() + cut + h > 0.5 * size[1] {
        return Err(format!(
            "a hole of radius {radius} m at {hole:?} does not fit inside the {} m × {} m grid \
             with a grid spacing to spare",
            size[0], size[1]
        ));
    }
    let c = center + eu * hole[0] + ev * hole[1];
    let full = grid(center, eu, ev, size, [nu, nv]);
    let (mut mesh, old) = punch_hole(&full, c, cut);
    if mesh.num_triangles() == full.num_triangles() {
        return Err(format!(
            "a hole of radius {radius} m catches no vertex of the {nu} × {nv} grid"
        ));
    }
    let n = mesh.num_vertices();
    let angle = |p: DVec3| {
        let d = p - c;
        let a = libm::atan2(d.dot(ev), d.dot(eu));
        if a < 0.0 {
            a + std::f64::consts::TAU
        } else {
            a
        }
    };
    // The cut's loop: the boundary piece that is not the sheet's border (the
    // one nearest the hole), ordered counter-clockwise about eu × ev (the
    // triangles' winding runs clockwise around a hole).
    let pieces = boundary_components(n, &mesh.triangles);
    let rim = pieces
        .iter()
        .min_by(|a, b| {
            let d = |p: &Vec<u32>| {
                p.iter()
                    .map(|&i| (mesh.positions[i as usize] - c).length())
                    .fold(0.0, f64::max)
            };
            d(a).total_cmp(&d(b))
        })
        .ok_or("the cut has no boundary")?;
    if pieces.len() != 2 {
        return Err(format!(
            "cutting the hole left {} boundary loops, not 2",
            pieces.len()
        ));
    }
    let mut next = vec![u32::MAX; n];
    let on_rim: std::collections::BTreeSet<u32> = rim.iter().copied().collect();
    for (a, b) in directed_boundary_edges(&mesh.triangles) {
        if on_rim.contains(&a) {
            next[a as usize] = b;
        }
    }
    let mut cw = vec![rim[0]];
    while cw.len() <= rim.len() {
        let v = next[*cw.last().expect("non-empty") as usize];
        if v == cw[0] || v == u32::MAX {
            break;
        }
        cw.push(v);
    }
    if cw.len() != rim.len() {
        return Err("the cut's rim is not a single loop".into());
    }
    let mut outer: Vec<u32> = cw.into_iter().rev().collect();
    // Start at the smallest angle; the loop must turn monotonically (the cut
    // is star-shaped about the centre), once around.
    let start = (0..outer.len())
        .min_by(|&a, &b| {
            angle(mesh.positions[outer[a] as usize])
                .total_cmp(&angle(mesh.positions[outer[b] as usize]))
        })
        .expect("non-empty");
    outer.rotate_left(start);
    let theta0 = angle(mesh.positions[outer[0] as usize]);
    let mut turned = 0.0;
    for w in outer.windows(2) {
        let mut d = angle(mesh.positions[w[1] as usize]) - angle(mesh.positions[w[0] as usize]);
        if d <= -std::f64::consts::PI {
            d += std::f64::consts::TAU;
        }
        if !(d > 0.0 && d < std::f64::consts::PI) {
            return Err("the cut's rim does not turn monotonically around the hole".into());
        }
        turned += d;
    }
    if !(turned < std::f64::consts::TAU) {
        return Err("the cut's rim turns more than once around the hole".into());
    }
    let m = outer.len();
    // The ring on the circle, first vertex at angle 0.
    let count = ((std::f64::consts::TAU * radius / h).round() as usize).max(6);
    let ring0 = n as u32;
    for j in 0..count {
        let phi = std::f64::consts::TAU * j as f64 / count as f64;
        mesh.positions
            .push(c + (eu * libm::cos(phi) + ev * libm::sin(phi)) * radius);
    }
    // Stitch from the first ring vertex at or after the loop's start, taking
    // at each step the shorter of the two possible new diagonals.
    let first = (0..count)
        .find(|&j| std::f64::consts::TAU * j as f64 / count as f64 >= theta0)
        .unwrap_or(count);
    let ring = |k: usize| ring0 + ((first + k) % count) as u32;
    let (mut a, mut b) = (0, 0);
    while a < m || b < count {
        let advance_outer = b == count
            || (a < m && {
                let pos = |v: u32| mesh.positions[v as usize];
                (pos(outer[(a + 1) % m]) - pos(ring(b))).length()
                    <= (pos(outer[a % m]) - pos(ring(b + 1))).length()
            });
        if advance_outer {
            mesh.triangles.push([outer[a], outer[(a + 1) % m], ring(b)]);
            a += 1;
        } else {
            mesh.triangles.push([outer[a % m], ring(b + 1), ring(b)]);
            b += 1;
        }
    }
    // Relax the cut's loop (the staircase left by the grid) towards its
    // neighbours: a few Jacobi sweeps of Laplacian smoothing in the plane
    // even out the stitched triangles; the ring and the rest of the grid stay.
    let mut neighbours: BTreeMap<u32, Vec<u32>> = outer.iter().map(|&v| (v, Vec::new())).collect();
    for t in &mesh.triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            if let Some(list) = neighbours.get_mut(&a) {
                if !list.contains(&b) {
                    list.push(b);
                }
            }
            if let Some(list) = neighbours.get_mut(&b) {
                if !list.contains(&a) {
                    list.push(a);
                }
            }
        }
    }
    for _ in 0..SMOOTHING_SWEEPS {
        let moved: Vec<(u32, DVec3)> = neighbours
            .iter()
            .map(|(&v, list)| {
                let sum = list
                    .iter()
                    .fold(DVec3::ZERO, |acc, &w| acc + mesh.positions[w as usize]);
                (v, sum / list.len() as f64)
            })
            .collect();
        for (v, p) in moved {
            mesh.positions[v as usize] = p;
        }
    }
    // Every stitched triangle must face the grid's way and not be a sliver.
    let normal = eu.cross(ev);
    let near_rim = |t: &&[u32; 3]| t.iter().any(|v| neighbours.contains_key(v) || *v >= ring0);
    for t in mesh.triangles.iter().filter(near_rim) {
        let [p, q, r] = t.map(|i| mesh.positions[i as usize]);
        let area2 = (q - p).cross(r - p).dot(normal);
        let longest = (q - p).length().max((r - q).length()).max((p - r).length());
        if !(area2 > MIN_ALTITUDE * h * longest) {
            return Err(format!(
                "stitching the rim of a hole of radius {radius} m to a grid of spacing {h:.3e} m \
                 gives a degenerate triangle; use a finer grid or a larger hole"
            ));
        }
    }
    let mut grid_index: Vec<Option<u32>> = old.into_iter().map(Some).collect();
    grid_index.extend(std::iter::repeat_n(None, count));
    Ok((mesh, grid_index))
}

/// Jacobi sweeps of Laplacian smoothing of the cut's loop.
const SMOOTHING_SWEEPS: usize = 8;
/// Smallest altitude of a triangle at the rim, in grid spacings (a grid
/// triangle has about 0.7).
const MIN_ALTITUDE: f64 = 0.1;

/// Boundary edges as directed in their triangle, in key order of the
/// undirected edge.
fn directed_boundary_edges(triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut uses: BTreeMap<(u32, u32), (u32, (u32, u32))> = BTreeMap::new();
    for t in triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            let entry = uses.entry((a.min(b), a.max(b))).or_insert((0, (a, b)));
            entry.0 += 1;
        }
    }
    uses.into_values()
        .filter(|&(c, _)| c == 1)
        .map(|(_, e)| e)
        .collect()
}

/// Number of boundary edges (edges of exactly one triangle) at each vertex:
/// 0 inside, 2 on a manifold boundary, more at a bow tie.
fn boundary_degree(n: usize, triangles: &[[u32; 3]]) -> Vec<u32> {
    let mut degree = vec![0u32; n];
    for (a, b) in boundary_edges(triangles) {
        degree[a as usize] += 1;
        degree[b as usize] += 1;
    }
    degree
}

/// The edges `(min, max)` used by exactly one triangle, in key order.
fn boundary_edges(triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut uses: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    for t in triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    uses.into_iter()
        .filter(|&(_, c)| c == 1)
        .map(|(e, _)| e)
        .collect()
}

/// The connected pieces of the boundary of a triangle set over `n` vertices
/// (for a manifold mesh: its boundary loops — a grid has one, a grid with a
/// hole two). Each piece lists its vertices in increasing order; pieces are
/// ordered by their smallest vertex.
pub fn boundary_components(n: usize, triangles: &[[u32; 3]]) -> Vec<Vec<u32>> {
    let edges = boundary_edges(triangles);
    // Union-find over the boundary edges.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let p = parent[parent[i as usize] as usize];
            parent[i as usize] = p;
            i = p;
        }
        i
    }
    let mut on_boundary = vec![false; n];
    for &(a, b) in &edges {
        on_boundary[a as usize] = true;
        on_boundary[b as usize] = true;
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
    let mut pieces: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for v in 0..n as u32 {
        if on_boundary[v as usize] {
            let r = root(&mut parent, v);
            pieces.entry(r).or_default().push(v);
        }
    }
    let mut out: Vec<Vec<u32>> = pieces.into_values().collect();
    out.sort_by_key(|p| p[0]);
    out
}

/// Moves `p` radially (about the line through `center` along unit `normal`)
/// so that the ring at distance `from` goes to distance `to`, the ring at
/// `band` and everything beyond it stays, and distances in between are
/// mapped linearly. Used to give a punched hole a different rest radius:
/// for `band > max(from, to) > 0` the map is monotone, so it keeps every
/// triangle of the annulus `from ≤ r` right side up.
pub fn radial_remap(
    p: DVec3,
    center: DVec3,
    normal: DVec3,
    from: f64,
    to: f64,
    band: f64,
) -> DVec3 {
    let d = p - center;
    let axial = normal * d.dot(normal);
    let radial = d - axial;
    let r = radial.length();
    if r >= band || r == 0.0 {
        return p;
    }
    let r_new = to + (r - from) * (band - to) / (band - from);
    center + axial + radial * (r_new / r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use weft_core::Topology;

    fn closed_and_outward(m: &TriMesh) {
        let topo = Topology::build(m.num_vertices(), &m.triangles).unwrap();
        assert!(topo.is_boundary_vertex.iter().all(|b| !b), "closed");
        // Signed volume positive <=> outward orientation.
        let vol: f64 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!(vol > 0.0, "outward normals, volume {vol}");
    }

    #[test]
    fn generated_obstacles_are_closed_and_outward() {
        closed_and_outward(&sphere(DVec3::ZERO, 1.0, 2));
        closed_and_outward(&cuboid(DVec3::splat(-1.0), DVec3::new(2.0, 1.0, 1.5)));
        closed_and_outward(&capped_cylinder(DVec3::ZERO, DVec3::Z, 0.1, 12, 4));
        assert_eq!(sphere(DVec3::ZERO, 1.0, 3).num_vertices(), 642);
    }

    #[test]
    fn punched_grids_are_manifold_annuli() {
        // Many resolutions, radii and offsets: the cut passes grid corners and
        // edge midpoints; every result is a valid manifold with exactly two
        // boundary loops (Euler characteristic 0) and nothing inside the hole.
        let mut cases = 0;
        for res in [[5, 5], [12, 9], [24, 24], [31, 40]] {
            for radius in [0.05, 0.11, 0.125, 0.2, 0.26] {
                for offset in [[0.0f64, 0.0f64], [0.031, -0.017], [0.125, 0.125]] {
                    let spacing = (1.0 / (res[0] - 1) as f64).max(1.25 / (res[1] - 1) as f64);
                    let reach = radius + 2.0 * spacing;
                    if offset[0].abs() + reach >= 0.5 || offset[1].abs() + reach >= 0.625 {
                        continue; // not an interior hole at this resolution
                    }
                    let g = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [1.0, 1.25], res);
                    let c = DVec3::new(offset[0], 0.0, offset[1]);
                    let (m, old) = punch_hole(&g, c, radius);
                    if m.num_triangles() == g.num_triangles() {
                        continue; // the hole caught no vertex
                    }
                    cases += 1;
                    let warnings = weft_core::validate(&m).unwrap();
                    assert!(
                        warnings.is_empty(),
                        "{res:?} {radius} {offset:?}: {warnings:?}"
                    );
                    let topo = Topology::build(m.num_vertices(), &m.triangles).unwrap();
                    let euler = m.num_vertices() as i64 - topo.edges.len() as i64
                        + m.num_triangles() as i64;
                    assert_eq!(euler, 0, "{res:?} {radius} {offset:?}");
                    assert_eq!(boundary_components(m.num_vertices(), &m.triangles).len(), 2);
                    assert_eq!(
                        boundary_degree(m.num_vertices(), &m.triangles).iter().max(),
                        Some(&2)
                    );
                    for (k, p) in m.positions.iter().enumerate() {
                        assert_eq!(*p, g.positions[old[k] as usize]);
                        assert!((*p - c).length() >= radius);
                    }
                    assert!(old.windows(2).all(|w| w[0] < w[1]));
                }
            }
        }
        assert!(cases >= 25, "{cases} cases cut something");
    }

    #[test]
    fn a_cut_that_would_leave_a_bow_tie_takes_its_vertex() {
        // A fan around vertex 0 with a star-shaped (not convex) link: the
        // ball holds link vertices 2 (45°) and 5 (180°) but neither the hub
        // nor the far-out vertices 3 and 4 between them, so the hub would
        // keep two separate fans. It goes too, and with it the whole fan.
        let deg = std::f64::consts::PI / 180.0;
        let mut p = vec![DVec3::ZERO];
        for (k, r) in [1.0, 1.0, 3.0, 3.0, 1.0, 1.0, 1.0, 1.0].iter().enumerate() {
            let a = (45 * k) as f64 * deg;
            p.push(DVec3::new(r * libm::cos(a), r * libm::sin(a), 0.0));
        }
        let t: Vec<[u32; 3]> = (0..8u32).map(|k| [0, 1 + k, 1 + (k + 1) % 8]).collect();
        let fan = TriMesh::new(p, t);
        assert!(weft_core::validate(&fan).is_ok());
        let c = DVec3::new(-0.606, 1.463, 0.0);
        let r = 1.53;
        let inside: Vec<usize> = (0..9)
            .filter(|&i| (fan.positions[i] - c).length() < r)
            .collect();
        assert_eq!(inside, vec![2, 5]);
        let (m, old) = punch_hole(&fan, c, r);
        assert_eq!(m.num_triangles(), 0);
        assert!(old.is_empty());
    }

    #[test]
    fn grids_with_round_holes_are_manifold_annuli_with_a_circular_rim() {
        let mut built = 0;
        for res in [[8, 8], [12, 9], [24, 24], [31, 40], [60, 60], [101, 101]] {
            for radius in [0.03, 0.05, 0.11, 0.2] {
                for offset in [[0.0f64, 0.0f64], [0.031, -0.017], [0.1, 0.125]] {
                    let (eu, ev) = (DVec3::X, DVec3::Z);
                    let r = grid_with_hole(DVec3::Y, eu, ev, [1.0, 1.25], res, offset, radius);
                    let Ok((m, index)) = r else {
                        continue;
                    };
                    built += 1;
                    let what = format!("{res:?} {radius} {offset:?}");
                    let warnings = weft_core::validate(&m).unwrap();
                    assert!(warnings.is_empty(), "{what}: {warnings:?}");
                    let topo = Topology::build(m.num_vertices(), &m.triangles).unwrap();
                    let euler = m.num_vertices() as i64 - topo.edges.len() as i64
                        + m.num_triangles() as i64;
                    assert_eq!(euler, 0, "{what}");
                    let loops = boundary_components(m.num_vertices(), &m.triangles);
                    assert_eq!(loops.len(), 2, "{what}");
                    // The rim loop is exactly the ring, on the circle.
                    let c = DVec3::Y + DVec3::new(offset[0], 0.0, offset[1]);
                    let ring: Vec<u32> = (0..m.num_vertices() as u32)
                        .filter(|&i| index[i as usize].is_none())
                        .collect();
                    assert!(ring.len() >= 6);
                    assert!(loops.contains(&ring), "{what}");
                    for &i in &ring {
                        let d = (m.positions[i as usize] - c).length();
                        assert!((d - radius).abs() < 1e-14, "{what}: ring at {d}");
                    }
                    // Grid vertices off the relaxed loop keep their place; all
                    // stay clear of the hole.
                    let g = grid(DVec3::Y, eu, ev, [1.0, 1.25], res);
                    let loop_vertices: Vec<u32> = topo
                        .edges
                        .iter()
                        .filter(|e| {
                            index[e[0] as usize].is_none() != index[e[1] as usize].is_none()
                        })
                        .flat_map(|e| *e)
                        .filter(|&v| index[v as usize].is_some())
                        .collect();
                    let mut moved = 0;
                    for (k, (p, i)) in m.positions.iter().zip(&index).enumerate() {
                        if let Some(i) = i {
                            assert!((*p - c).length() > radius, "{what}");
                            if *p != g.positions[*i as usize] {
                                moved += 1;
                                assert!(loop_vertices.contains(&(k as u32)), "{what}: {k} moved");
                            }
                        }
                    }
                    assert!(moved > 0);
                    // Every triangle faces the grid's way (eu × ev) and none
                    // is a sliver.
                    let up = eu.cross(ev);
                    let h = 0.5 * (1.0 / (res[0] - 1) as f64 + 1.25 / (res[1] - 1) as f64);
                    for f in 0..m.num_triangles() {
                        let [a, b, cc] = m.corners(f);
                        assert!((b - a).cross(cc - a).dot(up) > 0.0, "{what}: triangle {f}");
                        let alt = crate::shapes::tests::altitude([a, b, cc]);
                        assert!(alt > 0.1 * h, "{what}: triangle {f} altitude {alt:e}");
                    }
                }
            }
        }
        assert!(built >= 50, "{built} holes built");
        // Too small for its grid, or not inside it: clear errors.
        let e = grid_with_hole(
            DVec3::ZERO,
            DVec3::X,
            DVec3::Z,
            [1.0, 1.0],
            [5, 5],
            [0.1, 0.1],
            0.01,
        );
        assert!(e.unwrap_err().contains("catches no vertex"));
        let e = grid_with_hole(
            DVec3::ZERO,
            DVec3::X,
            DVec3::Z,
            [1.0, 1.0],
            [50, 50],
            [0.3, 0.0],
            0.2,
        );
        assert!(e.unwrap_err().contains("does not fit"));
    }

    pub(super) fn altitude(p: [DVec3; 3]) -> f64 {
        let area2 = (p[1] - p[0]).cross(p[2] - p[0]).length();
        let longest = (p[1] - p[0])
            .length()
            .max((p[2] - p[1]).length())
            .max((p[0] - p[2]).length());
        area2 / longest
    }

    #[test]
    fn boundary_components_of_a_grid_and_of_two_grids() {
        let g = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [1.0, 1.0], [4, 3]);
        let b = boundary_components(g.num_vertices(), &g.triangles);
        assert_eq!(b, vec![vec![0, 1, 2, 3, 4, 7, 8, 9, 10, 11]]);
        let mut two = g.clone();
        two.append(&grid(DVec3::Y, DVec3::X, DVec3::Z, [1.0, 1.0], [3, 3]));
        let b = boundary_components(two.num_vertices(), &two.triangles);
        assert_eq!(b.len(), 2);
        assert_eq!(b[1], vec![12, 13, 14, 15, 17, 18, 19, 20]);
    }

    #[test]
    fn radial_remap_moves_the_rim_and_keeps_the_rest() {
        let (c, n) = (DVec3::new(0.1, 0.2, 0.3), DVec3::Y);
        let at = |r: f64, phi: f64, h: f64| c + DVec3::new(r * phi.cos(), h, r * phi.sin());
        // The rim at 0.04 goes to 0.02; the band edge at 0.08 and beyond stay.
        let p = radial_remap(at(0.04, 0.7, 0.01), c, n, 0.04, 0.02, 0.08);
        assert!((p - at(0.02, 0.7, 0.01)).length() < 1e-15);
        let q = at(0.08, 2.0, 0.0);
        assert_eq!(radial_remap(q, c, n, 0.04, 0.02, 0.08), q);
        let q = at(0.3, 2.0, 0.0);
        assert_eq!(radial_remap(q, c, n, 0.04, 0.02, 0.08), q);
        // Halfway stays halfway (linear in between), direction kept.
        let p = radial_remap(at(0.06, -1.0, 0.0), c, n, 0.04, 0.02, 0.08);
        assert!((p - at(0.05, -1.0, 0.0)).length() < 1e-15);
        // A remapped punched grid keeps every triangle right side up.
        let g = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [0.6, 0.6], [40, 40]);
        let (mut m, _) = punch_hole(&g, DVec3::ZERO, 0.05);
        let normal = |m: &TriMesh, f: usize| {
            let [a, b, c] = m.corners(f);
            (b - a).cross(c - a)
        };
        let before: Vec<DVec3> = (0..m.num_triangles()).map(|f| normal(&m, f)).collect();
        for p in &mut m.positions {
            *p = radial_remap(*p, DVec3::ZERO, DVec3::Y, 0.05, 0.02, 0.1);
        }
        for (f, b) in before.iter().enumerate() {
            assert!(normal(&m, f).dot(*b) > 0.0, "triangle {f} flipped");
        }
    }

    #[test]
    fn tube_is_an_open_outward_cylinder() {
        let (a, b) = (DVec3::new(-0.4, 0.1, 0.0), DVec3::new(0.4, 0.1, 0.0));
        let m = tube(a, b, 0.05, [12, 7]);
        assert_eq!(m.num_vertices(), 84);
        assert_eq!(m.num_triangles(), 2 * 12 * 6);
        let warnings = weft_core::validate(&m).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        // Two boundary loops: the end rings (vertices 0..12 and 72..84).
        let loops = boundary_components(m.num_vertices(), &m.triangles);
        assert_eq!(
            loops,
            vec![(0..12).collect::<Vec<u32>>(), (72..84).collect()]
        );
        for (k, p) in m.positions.iter().enumerate() {
            let d = *p - DVec3::new(p.x, 0.1, 0.0);
            assert!((d.length() - 0.05).abs() < 1e-15, "vertex {k}");
            assert!((p.x - (-0.4 + 0.8 * (k / 12) as f64 / 6.0)).abs() < 1e-15);
        }
        // Outward: each triangle's normal points away from the axis.
        for f in 0..m.num_triangles() {
            let [p, q, r] = m.corners(f);
            let n = (q - p).cross(r - p);
            let centroid = (p + q + r) / 3.0;
            let out = centroid - DVec3::new(centroid.x, 0.1, 0.0);
            assert!(n.dot(out) > 0.0, "triangle {f} faces inward");
        }
        // The same first direction as the rod of the same axis.
        let rod = capped_cylinder(a, b, 0.05, 12, 6);
        assert!((rod.positions[0] - m.positions[0]).length() < 1e-15);
    }

    #[test]
    fn grid_counts() {
        let g = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [1.0, 1.0], [4, 3]);
        assert_eq!(g.num_vertices(), 12);
        assert_eq!(g.num_triangles(), 12);
        assert!(weft_core::validate(&g).is_ok());
    }
}
