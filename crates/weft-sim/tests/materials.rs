//! Material model tests: finite-difference gradients, invariances and momentum,
//! damping, physical calibration (uniaxial stretch, bent strip), the assembled
//! stable-step bound against a dense eigen-solve, masses, and error messages.

use glam::{DQuat, DVec3};
use std::f64::consts::PI;
use weft_core::Topology;
use weft_sim::materials::{
    damping_step_limit, dihedral_angle, lumped_masses, stable_step, HingeElement, Material,
    MaterialError, StretchElement,
};
use weft_testkit::{assert_gradient, check_gradient, Rng};

// ---------------------------------------------------------------- helpers

/// A random rotation.
fn random_rotation(rng: &mut Rng) -> DQuat {
    let axis = rng.vec(1.0).normalize();
    DQuat::from_axis_angle(axis, rng.uniform(-3.0, 3.0))
}

/// A cotton-like material with the plate-calibrated hinge stiffness.
fn cloth() -> Material {
    Material::plate(0.15, 2.0e6, 0.3, 4.0e-4)
}

fn tri(x: &[DVec3]) -> [DVec3; 3] {
    [x[0], x[1], x[2]]
}

fn quad(x: &[DVec3]) -> [DVec3; 4] {
    [x[0], x[1], x[2], x[3]]
}

fn max_norm(v: &[DVec3]) -> f64 {
    v.iter().fold(0.0f64, |a, g| a.max(g.length()))
}

fn momentum_residuals(x: &[DVec3], g: &[DVec3]) -> (f64, f64) {
    let lin: DVec3 = g.iter().copied().sum();
    let ang: DVec3 = x.iter().zip(g).map(|(p, f)| p.cross(*f)).sum();
    (lin.length(), ang.length())
}

/// A triangulated flat grid of `nx × ny` vertices over `[0, lx] × [0, ly]`
/// (right triangles, every cell split along the same diagonal).
fn grid(nx: usize, ny: usize, lx: f64, ly: f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut x = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            x.push(DVec3::new(
                lx * i as f64 / (nx - 1) as f64,
                ly * j as f64 / (ny - 1) as f64,
                0.0,
            ));
        }
    }
    let id = |i: usize, j: usize| (j * nx + i) as u32;
    let mut t = Vec::new();
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (x, t)
}

/// Owned element sets of a mesh with one material (the engine's key-ordered
/// copy of its elements has exactly these fields).
type Model = weft_sim::internal::KeyOrdered;

fn build_model(rest: &[DVec3], triangles: &[[u32; 3]], m: Material) -> Model {
    let topo = Topology::build(rest.len(), triangles).unwrap();
    let stretch: Vec<StretchElement> = triangles
        .iter()
        .map(|t| StretchElement::new(*t, t.map(|i| rest[i as usize])).unwrap())
        .collect();
    let hinges: Vec<HingeElement> = topo
        .hinges
        .iter()
        .map(|h| {
            let v = [h.edge[0], h.edge[1], h.wings[0], h.wings[1]];
            HingeElement::new(v, v.map(|i| rest[i as usize])).unwrap()
        })
        .collect();
    Model {
        stretch_material: vec![0; stretch.len()],
        hinge_material: vec![0; hinges.len()],
        stretch,
        hinges,
        materials: vec![m],
    }
}

/// The assembled elastic gradient of `model` at `x`.
fn gradient(model: &Model, x: &[DVec3]) -> Vec<DVec3> {
    let mut g = vec![DVec3::ZERO; x.len()];
    model.model().add_gradient(x, &mut g);
    g
}

// ---------------------------------------------------------------- stretch

/// Random rest triangles and deformed shapes (stretched, compressed, rotated,
/// rest != initial); gradient against central differences.
#[test]
fn stretch_gradient_matches_finite_differences() {
    let m = cloth();
    let mut rng = Rng(1);
    for _ in 0..200 {
        let rest = [rng.vec(0.01), rng.vec(0.01), rng.vec(0.01)];
        let Ok(e) = StretchElement::new([0, 1, 2], rest) else {
            continue;
        };
        // Stretch/compress by 0.5..1.6 along random axes, rotate, translate, jitter.
        let scale = DVec3::new(
            rng.uniform(0.5, 1.6),
            rng.uniform(0.5, 1.6),
            rng.uniform(0.5, 1.6),
        );
        let q = random_rotation(&mut rng);
        let shift = rng.vec(1.0);
        let x: Vec<DVec3> = rest
            .iter()
            .map(|p| q * (*p * scale) + shift + rng.vec(0.001))
            .collect();
        let g = e.gradient(&tri(&x), &m);
        assert_gradient(|y| e.energy(&tri(y), &m), &x, &g, 1e-8, 1e-5);
    }
}

/// Very thin (sliver) rest triangles, still above the rejection threshold.
#[test]
fn stretch_gradient_of_thin_triangles() {
    let m = cloth();
    let mut rng = Rng(2);
    for &thin in &[1e-3, 1e-5, 1e-7] {
        let rest = [
            DVec3::ZERO,
            DVec3::new(0.01, 0.0, 0.0),
            DVec3::new(0.004, 0.01 * thin, 0.0),
        ];
        let e = StretchElement::new([0, 1, 2], rest).unwrap();
        for _ in 0..10 {
            let x: Vec<DVec3> = rest
                .iter()
                .map(|p| *p * 1.05 + rng.vec(0.01 * thin))
                .collect();
            let g = e.gradient(&tri(&x), &m);
            assert_gradient(|y| e.energy(&tri(y), &m), &x, &g, 1e-4 * 0.01 * thin, 1e-4);
        }
    }
}

#[test]
fn stretch_rest_state_has_zero_energy_and_gradient() {
    let m = cloth();
    let rest = [
        DVec3::new(0.1, 0.2, 0.3),
        DVec3::new(0.13, 0.2, 0.31),
        DVec3::new(0.1, 0.24, 0.29),
    ];
    let e = StretchElement::new([4, 5, 6], rest).unwrap();
    assert!(
        (e.rest_area() - 0.5 * (rest[1] - rest[0]).cross(rest[2] - rest[0]).length()).abs() < 1e-18
    );
    let q = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let x = rest.map(|p| q * p + DVec3::new(5.0, -1.0, 2.0));
    assert!(e.energy(&x, &m) < 1e-12 * m.youngs_modulus * m.thickness * e.rest_area());
    let g = e.gradient(&x, &m);
    let f_scale = m.youngs_modulus * m.thickness * 0.03;
    assert!(max_norm(&g) < 1e-12 * f_scale, "{g:?}");
}

// ---------------------------------------------------------------- bend

/// A hinge with edge along x, wing 2 at +y and wing 3 rotated by `angle` about the
/// edge, so the signed dihedral angle is `angle` (in (-pi, pi]).
fn hinge_at(angle: f64) -> [DVec3; 4] {
    let x0 = DVec3::new(-0.004, 0.0, 0.0);
    let x1 = DVec3::new(0.006, 0.0, 0.0);
    let x2 = DVec3::new(0.001, 0.008, 0.0);
    // Wing B lies at -y when flat; the fold rotates it about the edge.
    let b = DVec3::new(0.002, -0.007, 0.0);
    let rot = DQuat::from_axis_angle(DVec3::X, angle);
    [x0, x1, x2, rot * b]
}

#[test]
fn dihedral_angle_is_signed_and_exact() {
    // Angle difference modulo 2 pi (pi and -pi are the same fold).
    let diff = |a: f64, b: f64| ((a - b + PI).rem_euclid(2.0 * PI) - PI).abs();
    for a in [
        0.0,
        1e-9,
        -1e-9,
        0.3,
        -0.3,
        1.5,
        -2.9,
        PI - 1e-4,
        -PI + 1e-4,
        PI,
    ] {
        let x = hinge_at(a);
        let theta = dihedral_angle(&x);
        assert!(diff(theta, a) < 1e-12, "angle {a}: got {theta}");
        assert!((-PI..=PI).contains(&theta));
        // Rigid motion does not change it.
        let q = DQuat::from_axis_angle(DVec3::new(0.3, -1.0, 0.2).normalize(), 2.0);
        let y = x.map(|p| q * p + DVec3::splat(3.0));
        assert!(diff(dihedral_angle(&y), a) < 1e-11);
    }
}

fn check_hinge_gradient(rest: [DVec3; 4], x: [DVec3; 4], k_b: f64, tol: f64) {
    let e = HingeElement::new([0, 1, 2, 3], rest).unwrap();
    let g = e.gradient(&x, k_b);
    assert_gradient(|y| e.energy(&quad(y), k_b), &x, &g, 1e-9, tol);
}

/// Random hinges, including nearly flat (theta ≈ 0) and folded (theta ≈ ±pi)
/// shapes, rest angles on both sides of the atan2 branch cut, rest != initial.
#[test]
fn bend_gradient_matches_finite_differences() {
    let k_b = cloth().bending_stiffness;
    let mut rng = Rng(3);
    for _ in 0..200 {
        let rest = [rng.vec(0.01), rng.vec(0.01), rng.vec(0.01), rng.vec(0.01)];
        if HingeElement::new([0, 1, 2, 3], rest).is_err() {
            continue;
        }
        let x = rest.map(|p| p + rng.vec(0.003));
        check_hinge_gradient(rest, x, k_b, 1e-5);
    }
    // Nearly flat and nearly folded, with rest angles 0, ±pi-ish and random.
    for &(a, rest_a) in &[
        (1e-7, 0.0),
        (-1e-7, 0.3),
        (0.0, -0.2),
        (PI - 3e-6, 0.0),
        (-PI + 3e-6, 0.5),
        (PI - 1e-4, -PI + 1e-4), // across the branch cut: wrapped difference ≈ 2e-4
        (-3.13, 3.12),
        (2.0, -2.5),
    ] {
        let q = random_rotation(&mut rng);
        let x = hinge_at(a).map(|p| q * p + rng.vec(1e-5) * 1e-3);
        check_hinge_gradient(hinge_at(rest_a), x, k_b, 1e-5);
    }
}

/// The wrapped angle difference keeps a hinge folded through ±pi smooth.
#[test]
fn bend_energy_is_continuous_across_the_branch_cut() {
    let e = HingeElement::new([0, 1, 2, 3], hinge_at(3.0)).unwrap();
    let k = 1.0;
    let a = e.energy(&hinge_at(PI - 1e-9), k);
    let b = e.energy(&hinge_at(-PI + 1e-9), k);
    assert!((a - b).abs() < 1e-6 * a, "{a} vs {b}");
    let w = e.weight();
    let d = PI - 3.0;
    assert!((a - k * w * d * d).abs() < 1e-6 * a);
}

/// Thin wings (nearly collinear with the edge) still have exact gradients.
#[test]
fn bend_gradient_of_thin_wings() {
    let k_b = 1e-3;
    for &thin in &[1e-3, 1e-5] {
        let rest = [
            DVec3::ZERO,
            DVec3::new(0.01, 0.0, 0.0),
            DVec3::new(0.004, 0.01 * thin, 0.0),
            DVec3::new(0.006, -0.01 * thin, 0.0),
        ];
        let e = HingeElement::new([0, 1, 2, 3], rest).unwrap();
        let mut x = rest;
        x[2].z += 0.3 * 0.01 * thin;
        x[3].z += 0.1 * 0.01 * thin;
        let g = e.gradient(&x, k_b);
        assert_gradient(
            |y| e.energy(&quad(y), k_b),
            &x,
            &g,
            1e-5 * 0.01 * thin,
            1e-4,
        );
    }
}

// ---------------------------------------------------------------- invariance, momentum

#[test]
fn energies_are_rigid_invariant_and_gradients_conserve_momentum() {
    let m = cloth();
    let mut rng = Rng(4);
    for _ in 0..100 {
        let rest: Vec<DVec3> = (0..4).map(|_| rng.vec(0.01)).collect();
        let x: Vec<DVec3> = rest.iter().map(|p| *p * 1.1 + rng.vec(0.002)).collect();
        let q = random_rotation(&mut rng);
        let t = rng.vec(10.0);
        let y: Vec<DVec3> = x.iter().map(|p| q * *p + t).collect();
        if let Ok(s) = StretchElement::new([0, 1, 2], tri(&rest)) {
            let (e0, e1) = (s.energy(&tri(&x), &m), s.energy(&tri(&y), &m));
            assert!((e0 - e1).abs() <= 1e-9 * e0.abs(), "{e0} {e1}");
            let g = s.gradient(&tri(&x), &m);
            let (lin, ang) = momentum_residuals(&x[..3], &g);
            let scale = max_norm(&g);
            assert!(lin <= 1e-13 * scale, "linear {lin} vs {scale}");
            assert!(ang <= 1e-13 * scale * 0.02, "angular {ang} vs {scale}");
            // Rotated gradient = rotation of the gradient.
            let gy = s.gradient(&tri(&y), &m);
            for k in 0..3 {
                assert!((gy[k] - q * g[k]).length() <= 1e-9 * scale);
            }
        }
        if let Ok(h) = HingeElement::new([0, 1, 2, 3], quad(&rest)) {
            let k_b = m.bending_stiffness;
            let (e0, e1) = (h.energy(&quad(&x), k_b), h.energy(&quad(&y), k_b));
            assert!((e0 - e1).abs() <= 1e-9 * e0.abs() + 1e-25, "{e0} {e1}");
            let g = h.gradient(&quad(&x), k_b);
            let (lin, ang) = momentum_residuals(&x, &g);
            let scale = max_norm(&g);
            assert!(lin <= 1e-12 * scale, "linear {lin} vs {scale}");
            assert!(ang <= 1e-12 * scale * 0.02, "angular {ang} vs {scale}");
        }
    }
}

// ---------------------------------------------------------------- damping

fn damped() -> Material {
    Material {
        stretch_damping: 1e-4,
        bend_damping: 1e-4 * cloth().bending_stiffness,
        ..cloth()
    }
}

#[test]
fn damping_vanishes_for_rigid_motion_and_conserves_momentum() {
    let m = damped();
    let mut rng = Rng(5);
    for _ in 0..100 {
        let rest: Vec<DVec3> = (0..4).map(|_| rng.vec(0.01)).collect();
        let x: Vec<DVec3> = rest.iter().map(|p| *p * 1.05 + rng.vec(0.002)).collect();
        let c = x.iter().copied().sum::<DVec3>() / 4.0;
        let omega = rng.vec(5.0);
        let vt = rng.vec(1.0);
        let rigid: Vec<DVec3> = x.iter().map(|p| omega.cross(*p - c) + vt).collect();
        let random: Vec<DVec3> = (0..4).map(|_| rng.vec(1.0)).collect();
        if let Ok(s) = StretchElement::new([0, 1, 2], tri(&rest)) {
            let f = s.damping_force(&tri(&x), &tri(&random), &m);
            let scale = max_norm(&f);
            assert!(scale > 0.0);
            let (lin, ang) = momentum_residuals(&x[..3], &f);
            assert!(
                lin <= 1e-13 * scale && ang <= 1e-13 * scale * 0.02,
                "{lin} {ang}"
            );
            let dissipation: f64 = (0..3).map(|k| f[k].dot(random[k])).sum();
            assert!(dissipation <= 0.0, "damping must dissipate: {dissipation}");
            let fr = s.damping_force(&tri(&x), &tri(&rigid), &m);
            assert!(max_norm(&fr) <= 1e-12 * scale, "{fr:?} vs {scale}");
        }
        if let Ok(h) = HingeElement::new([0, 1, 2, 3], quad(&rest)) {
            let f = h.damping_force(&quad(&x), &quad(&random), &m);
            let scale = max_norm(&f);
            let (lin, ang) = momentum_residuals(&x, &f);
            assert!(
                lin <= 1e-12 * scale && ang <= 1e-12 * scale * 0.02,
                "{lin} {ang}"
            );
            let dissipation: f64 = (0..4).map(|k| f[k].dot(random[k])).sum();
            assert!(dissipation <= 0.0);
            let fr = h.damping_force(&quad(&x), &quad(&rigid), &m);
            assert!(max_norm(&fr) <= 1e-10 * scale, "{fr:?} vs {scale}");
        }
    }
}

/// At rest the damping operators are `stretch_damping · K_stretch` and
/// `bend_damping / k_b · K_bend` (stiffness-proportional), as documented.
#[test]
fn damping_is_stiffness_proportional_at_rest() {
    let m = damped();
    let (x, t) = grid(4, 3, 0.03, 0.02);
    let mut rest = x.clone();
    for (i, p) in rest.iter_mut().enumerate() {
        p.z = 0.002 * ((i * 7 % 5) as f64 - 2.0); // curved rest: bending is loaded
    }
    let model = build_model(&rest, &t, m);
    let mut rng = Rng(6);
    let v: Vec<DVec3> = rest.iter().map(|_| rng.vec(1.0)).collect();
    let mut f = vec![DVec3::ZERO; rest.len()];
    model.model().add_damping_force(&rest, &v, &mut f);
    // K v by central differences, stretch and bend share alpha = 1e-4 here.
    let eps = 1e-8;
    let xp: Vec<DVec3> = rest.iter().zip(&v).map(|(p, d)| *p + *d * eps).collect();
    let xm: Vec<DVec3> = rest.iter().zip(&v).map(|(p, d)| *p - *d * eps).collect();
    let (gp, gm) = (gradient(&model, &xp), gradient(&model, &xm));
    let scale = max_norm(&f);
    for i in 0..rest.len() {
        let kv = (gp[i] - gm[i]) / (2.0 * eps);
        assert!(
            (f[i] + kv * 1e-4).length() <= 1e-5 * scale,
            "vertex {i}: {:?} vs {:?}",
            f[i],
            -kv * 1e-4
        );
    }
}

// ---------------------------------------------------------------- physics

/// Uniaxial stretch of an irregularly meshed strip with free lateral contraction
/// recovers E and nu: `sigma_xx = E eps_xx`, `eps_yy = -nu eps_xx` (small strain).
#[test]
fn uniaxial_stretch_recovers_youngs_modulus_and_poisson_ratio() {
    for nu in [0.0, 0.3, 0.45, -0.2] {
        let m = Material {
            poisson_ratio: nu,
            ..cloth()
        };
        let (lx, ly) = (0.5, 0.1);
        let (mut rest, t) = grid(11, 4, lx, ly);
        // Jitter interior vertices so the mesh is irregular.
        let mut rng = Rng(7);
        for p in rest.iter_mut() {
            if p.x > 0.0 && p.x < lx && p.y > 0.0 && p.y < ly {
                p.x += rng.uniform(-0.01, 0.01);
                p.y += rng.uniform(-0.005, 0.005);
            }
        }
        let model = build_model(&rest, &t, m);
        let ex = 1e-4;
        // dU/d(eps_x) and dU/d(eps_y) from the assembled gradient.
        let derivs = |ey: f64| {
            let x: Vec<DVec3> = rest
                .iter()
                .map(|p| DVec3::new(p.x * (1.0 + ex), p.y * (1.0 + ey), 0.0))
                .collect();
            let g = gradient(&model, &x);
            let dx: f64 = g.iter().zip(&rest).map(|(g, p)| g.x * p.x).sum();
            let dy: f64 = g.iter().zip(&rest).map(|(g, p)| g.y * p.y).sum();
            (dx, dy)
        };
        // Secant iteration for the free lateral strain (dU/d(eps_y) = 0).
        let (mut a, mut b) = (0.0, -0.5 * ex);
        let (mut fa, mut fb) = (derivs(a).1, derivs(b).1);
        for _ in 0..50 {
            if fb == fa {
                break;
            }
            let c = b - fb * (b - a) / (fb - fa);
            (a, fa) = (b, fb);
            b = c;
            fb = derivs(b).1;
        }
        let ey = b;
        let force = derivs(ey).0 / lx; // end force = dU/d(Delta L)
        let e_meas = force / (ly * m.thickness) / ex;
        let nu_meas = -ey / ex;
        assert!(
            (e_meas / m.youngs_modulus - 1.0).abs() < 0.01,
            "E: {e_meas} vs {}",
            m.youngs_modulus
        );
        assert!(
            (nu_meas - nu).abs() < 0.01 * nu.abs().max(0.01),
            "nu {nu_meas} vs {nu}"
        );
    }
}

/// A flat strip of regular mesh rolled onto a cylinder of radius R (vertices on
/// the cylinder, hinge angles from the exact geometry) folds along the edge lines
/// parallel to the axis; each fold line `s` apart carries `theta = s/R`, so the
/// energy per area of the interior fold strips is `3 k_b / R²`
/// (see `materials` module docs), which equals the Kirchhoff plate value
/// `D / (2 R²)` for `k_b = D/6`. Holds to round-off; tolerance 1e-9.
#[test]
fn bent_strip_matches_plate_bending_energy() {
    let m = cloth();
    let d = m.plate_stiffness();
    assert!((m.default_bending_stiffness() - d / 6.0).abs() <= 1e-15 * d);
    let radius = 0.05;
    // (flat rest, triangles, fold-line spacing)
    let mut meshes = Vec::new();
    {
        // Right-triangle grid, axis along y: fold lines x = const.
        let (nx, ny, lx, ly) = (13, 6, 0.12, 0.05);
        let (x, t) = grid(nx, ny, lx, ly);
        meshes.push((x, t, lx / (nx - 1) as f64));
    }
    {
        // Equilateral mesh with columns along y (edges along the axis).
        let (cols, rows, a) = (11usize, 8usize, 0.01);
        let s = a * 3f64.sqrt() / 2.0;
        let mut x = Vec::new();
        for i in 0..cols {
            for j in 0..rows {
                let shift = if i % 2 == 1 { 0.5 * a } else { 0.0 };
                x.push(DVec3::new(i as f64 * s, j as f64 * a + shift, 0.0));
            }
        }
        let id = |i: usize, j: usize| (i * rows + j) as u32;
        let mut t = Vec::new();
        for i in 0..cols - 1 {
            for j in 0..rows - 1 {
                if i % 2 == 0 {
                    t.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                    t.push([id(i, j + 1), id(i + 1, j), id(i + 1, j + 1)]);
                } else {
                    t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                    t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
                }
            }
        }
        meshes.push((x, t, s));
    }
    for (k, (rest, t, s)) in meshes.into_iter().enumerate() {
        let model = build_model(&rest, &t, m);
        let bent: Vec<DVec3> = rest
            .iter()
            .map(|p| {
                let phi = p.x / radius;
                DVec3::new(radius * phi.sin(), p.y, radius * (1.0 - phi.cos()))
            })
            .collect();
        let energy: f64 = model
            .hinges
            .iter()
            .map(|h| h.energy(&h.verts.map(|i| bent[i as usize]), m.bending_stiffness))
            .sum();
        // Area of the interior fold strips: each axial hinge of length l owns l·s.
        let axial_length: f64 = model
            .hinges
            .iter()
            .map(|h| rest[h.verts[1] as usize] - rest[h.verts[0] as usize])
            .filter(|e| e.x.abs() < 1e-12)
            .map(|e| e.length())
            .sum();
        assert!(axial_length > 0.0);
        let area = axial_length * s;
        let discrete = 3.0 * m.bending_stiffness / (radius * radius) * area;
        let plate = d / (2.0 * radius * radius) * area;
        assert!(
            (energy / discrete - 1.0).abs() < 1e-9,
            "mesh {k}: {energy} vs 3 k_b/R² A = {discrete}"
        );
        assert!(
            (energy / plate - 1.0).abs() < 1e-9,
            "mesh {k}: {energy} vs {plate}"
        );
    }
}

#[test]
fn lumped_masses_sum_to_density_times_area() {
    let (x, t) = grid(5, 4, 0.4, 0.3);
    let density: Vec<f64> = (0..t.len()).map(|i| 0.1 + 0.01 * i as f64).collect();
    let m = lumped_masses(x.len() + 1, &t, &x, &density);
    let expected: f64 = t
        .iter()
        .zip(&density)
        .map(|(t, rho)| {
            rho * 0.5
                * (x[t[1] as usize] - x[t[0] as usize])
                    .cross(x[t[2] as usize] - x[t[0] as usize])
                    .length()
        })
        .sum();
    let total: f64 = m.iter().sum();
    assert!((total - expected).abs() <= 1e-14 * expected);
    assert_eq!(m[x.len()], 0.0, "a vertex in no triangle has no mass");
    // Uniform density: corner 4 (one triangle) vs interior vertex 6 (six triangles).
    let m = lumped_masses(x.len(), &t, &x, &vec![0.2; t.len()]);
    let tri_area = 0.5 * 0.1 * 0.1;
    assert!((m[4] - 0.2 * tri_area / 3.0).abs() < 1e-15);
    assert!((m[6] - 6.0 * 0.2 * tri_area / 3.0).abs() < 1e-15);
}

// ---------------------------------------------------------------- stable step

/// Eigenvalues of a dense symmetric matrix by cyclic Jacobi rotations.
fn jacobi_eigenvalues(mut a: Vec<Vec<f64>>) -> Vec<f64> {
    let n = a.len();
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let diag: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum();
        if off <= 1e-30 * diag {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
            }
        }
    }
    (0..n).map(|i| a[i][i]).collect()
}

/// Dense `M^-1/2 K M^-1/2` of the assembled rest system by central differences.
fn dense_scaled_stiffness(model: &Model, rest: &[DVec3], mass: &[f64]) -> Vec<Vec<f64>> {
    let n = 3 * rest.len();
    let mut k = vec![vec![0.0; n]; n];
    let h = 1e-7;
    for col in 0..n {
        let (mut xp, mut xm) = (rest.to_vec(), rest.to_vec());
        xp[col / 3][col % 3] += h;
        xm[col / 3][col % 3] -= h;
        let (gp, gm) = (gradient(model, &xp), gradient(model, &xm));
        for row in 0..n {
            k[row][col] = (gp[row / 3][row % 3] - gm[row / 3][row % 3])
                / (2.0 * h)
                / (mass[row / 3] * mass[col / 3]).sqrt();
        }
    }
    // Symmetrize the finite-difference noise.
    for i in 0..n {
        for j in 0..i {
            let s = 0.5 * (k[i][j] + k[j][i]);
            k[i][j] = s;
            k[j][i] = s;
        }
    }
    k
}

/// `max_frequency` (Lanczos on the assembled system) against a dense Jacobi
/// eigen-solve on small meshes: within 3 %, never more than 2 % below; the
/// Gershgorin bound is above.
#[test]
fn max_frequency_matches_dense_eigenvalues() {
    let mut rng = Rng(8);
    for (nx, ny, curved, kb_scale) in [
        (3, 3, false, 1.0),
        (3, 3, true, 1.0),
        (4, 5, true, 1.0),
        (5, 4, true, 1e4), // bending-dominated
    ] {
        let m = Material {
            bending_stiffness: cloth().bending_stiffness * kb_scale,
            ..cloth()
        };
        let (mut rest, t) = grid(nx, ny, 0.02 * (nx - 1) as f64, 0.015 * (ny - 1) as f64);
        for p in rest.iter_mut() {
            p.x += rng.uniform(-0.002, 0.002);
            p.y += rng.uniform(-0.002, 0.002);
            if curved {
                p.z = 0.003 * rng.uniform(-1.0, 1.0);
            }
        }
        let model = build_model(&rest, &t, m);
        let mass = lumped_masses(rest.len(), &t, &rest, &vec![m.area_density; t.len()]);
        let exact = jacobi_eigenvalues(dense_scaled_stiffness(&model, &rest, &mass))
            .into_iter()
            .fold(0.0f64, f64::max)
            .sqrt();
        let view = model.model();
        let omega = view.max_frequency(&rest, &mass);
        let bound = view.gershgorin_bound(&rest, &mass);
        assert!(
            (omega / exact - 1.0).abs() < 0.03 && omega >= 0.98 * exact,
            "{nx}x{ny}: omega {omega} vs dense {exact}"
        );
        assert!(
            bound >= exact * (1.0 - 1e-6),
            "Gershgorin {bound} below {exact}"
        );
        let h = stable_step(omega, 0.5);
        assert!((h - 1.0 / omega).abs() <= 1e-15 * h);
    }
}

/// Explicit leapfrog with Jacobi-semantics damping on the linearised rest system
/// stays bounded just below `damping_step_limit` and blows up just above it.
#[test]
fn damping_step_limit_separates_stable_from_unstable() {
    let alpha = 2e-5;
    let m = Material {
        stretch_damping: alpha,
        bend_damping: alpha * cloth().bending_stiffness,
        ..cloth()
    };
    let (rest, t) = grid(3, 3, 0.02, 0.02);
    let model = build_model(&rest, &t, m);
    let mass = lumped_masses(rest.len(), &t, &rest, &vec![m.area_density; t.len()]);
    let view = model.model();
    let omega = view.max_frequency(&rest, &mass);
    let gamma = view.max_damping_rate(&rest, &mass);
    // Stiffness-proportional: gamma = alpha omega².
    assert!(
        (gamma / (alpha * omega * omega) - 1.0).abs() < 1e-3,
        "{gamma}"
    );
    let limit = damping_step_limit(omega, gamma);
    assert!(limit < 2.0 / omega);

    // Linear dynamics in scaled coordinates: A = M^-1/2 K M^-1/2, C = alpha A.
    let a = dense_scaled_stiffness(&model, &rest, &mass);
    let n = a.len();
    let run = |h: f64| {
        let mut rng = Rng(9);
        let mut x: Vec<f64> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let mut v = vec![0.0; n];
        let mut peak: f64 = 0.0;
        for _ in 0..4000 {
            let ax: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|j| a[i][j] * x[j]).sum())
                .collect();
            let av: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|j| a[i][j] * v[j]).sum())
                .collect();
            for i in 0..n {
                v[i] -= h * (ax[i] + alpha * av[i]);
                x[i] += h * v[i];
            }
            peak = peak.max(x.iter().fold(0.0f64, |m, xi| m.max(xi.abs())));
        }
        peak
    };
    assert!(run(0.97 * limit) < 1e3, "unstable below the limit");
    assert!(
        run(1.03 * limit) > 1e6,
        "stable above the limit: the limit is too low"
    );
}

#[test]
fn a_model_without_elements_has_no_frequency() {
    let model = Model {
        stretch: vec![],
        stretch_material: vec![],
        hinges: vec![],
        hinge_material: vec![],
        materials: vec![cloth()],
    };
    let omega = model.model().max_frequency(&[DVec3::ZERO; 3], &[1.0; 3]);
    assert_eq!(omega, 0.0);
    assert_eq!(stable_step(omega, 0.3), f64::INFINITY);
}

// ---------------------------------------------------------------- errors

#[test]
fn invalid_materials_are_rejected_with_the_parameter_named() {
    assert!(cloth().validate().is_ok());
    let cases: [(Material, &str); 6] = [
        (
            Material {
                poisson_ratio: 0.5,
                ..cloth()
            },
            "poisson_ratio",
        ),
        (
            Material {
                poisson_ratio: -1.0,
                ..cloth()
            },
            "poisson_ratio",
        ),
        (
            Material {
                youngs_modulus: 0.0,
                ..cloth()
            },
            "youngs_modulus",
        ),
        (
            Material {
                thickness: f64::NAN,
                ..cloth()
            },
            "thickness",
        ),
        (
            Material {
                area_density: -1.0,
                ..cloth()
            },
            "density", // the scene key, not the field name
        ),
        (
            Material {
                stretch_damping: -1e-3,
                ..cloth()
            },
            "stretch_damping",
        ),
    ];
    for (m, name) in cases {
        let err = m.validate().unwrap_err();
        assert!(
            matches!(err, MaterialError::InvalidParameter { parameter, .. } if parameter == name)
        );
        assert!(err.to_string().contains(name), "{err}");
        assert!(!err.to_string().contains("area_density"), "{err}");
    }
    let (lambda, mu) = cloth().lame();
    let (e, nu) = (cloth().youngs_modulus, cloth().poisson_ratio);
    assert!((mu - e / (2.0 * (1.0 + nu))).abs() < 1e-9);
    assert!((lambda - e * nu / (1.0 - nu * nu)).abs() < 1e-9);
}

#[test]
fn degenerate_rest_shapes_are_rejected_with_the_element_named() {
    let collinear = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
    let err = StretchElement::new([7, 8, 9], collinear).unwrap_err();
    assert!(err.to_string().contains("#7, #8, #9"), "{err}");
    // Messages name the vertices of the object, not the input ids.
    assert!(err.clone().in_object(7).to_string().contains("#0, #1, #2"));
    let nan = [DVec3::ZERO, DVec3::X, DVec3::new(f64::NAN, 1.0, 0.0)];
    assert!(StretchElement::new([0, 1, 2], nan).is_err());
    let sliver = [DVec3::ZERO, DVec3::X, DVec3::new(0.5, 1e-12, 0.0)];
    assert!(StretchElement::new([0, 1, 2], sliver).is_err());

    let flat_wing = [
        DVec3::ZERO,
        DVec3::X,
        DVec3::X * 0.5,
        DVec3::new(0.5, -1.0, 0.0),
    ];
    let err = HingeElement::new([3, 4, 5, 6], flat_wing).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("#3–#4") && msg.contains("wing"), "{msg}");
    assert!(err.in_object(3).to_string().contains("#0–#1"));
    let no_edge = [DVec3::ZERO, DVec3::ZERO, DVec3::Y, -DVec3::Y];
    assert!(HingeElement::new([0, 1, 2, 3], no_edge).is_err());
}

/// A deliberately wrong gradient must fail the shared checker (the tests above
/// can fail).
#[test]
fn gradient_checker_catches_a_wrong_bend_gradient() {
    let rest = hinge_at(0.2);
    let e = HingeElement::new([0, 1, 2, 3], rest).unwrap();
    let x = hinge_at(0.5);
    let mut g = e.gradient(&x, 1.0);
    g[0] *= 1.01;
    let r = check_gradient(|y| e.energy(&quad(y), 1.0), &x, &g, 1e-9);
    assert!(r.max_rel_error > 1e-3);
}
