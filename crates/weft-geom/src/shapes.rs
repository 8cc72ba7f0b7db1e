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
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            } else {
                triangles.push([a, b, d]);
                triangles.push([b, c, d]);
            }
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
    fn grid_counts() {
        let g = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [1.0, 1.0], [4, 3]);
        assert_eq!(g.num_vertices(), 12);
        assert_eq!(g.num_triangles(), 12);
        assert!(weft_core::validate(&g).is_ok());
    }
}
