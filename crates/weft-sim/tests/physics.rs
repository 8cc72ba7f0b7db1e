//! Physical validation of the whole engine against theory.
//!
//! * **Cantilever**: a strip clamped at one end sags under gravity. Its static
//!   tip deflection is compared (a) tightly with an independent linear static
//!   solve of the same discrete model (discrete-shells hinges, lumped masses,
//!   written here from the spec, not from the engine's code) and (b) with
//!   Kirchhoff beam/plate theory `δ = q L⁴ / (8 D)`, `D = 6 k_b`, within a
//!   band that accounts for what the coarse right-triangle grid does (see
//!   [`cantilever_sags_as_plate_theory_says`]).
//! * **Incline**: a cloth patch on a tilted box sticks when `tan θ < mu` and
//!   slides with `a = g (sin θ − mu cos θ)` when `tan θ > mu` (and `g sin θ`
//!   without friction).
//!
//! Static equilibria are reached by *kinetic damping* (dynamic relaxation):
//! between windows, whenever the kinetic energy has dropped since the last
//! window, every dynamic velocity is set to zero. That only removes energy; the
//! state it converges to is a zero-velocity state the engine keeps still, i.e. a
//! static equilibrium of the engine's own forces — and the tests check that by
//! running on without resets afterwards. (The material damping alone cannot do
//! it in reasonable time: its explicit stability limit caps the damping ratio of
//! the fundamental at ~0.3 % here.)
//!
//! Every test prints measured vs expected numbers (`--nocapture`).

use glam::DVec3;
use weft_core::TriMesh;
use weft_geom::shapes::{cuboid, grid};
use weft_sim::kinematics::{rotate, Motion};
use weft_sim::materials::Material;
use weft_sim::{
    ContactConfig, Engine, LimitsConfig, ObjectKind, ObjectSpec, PinSpec, Serial, TimeConfig,
    World, WorldSpec,
};

const G: f64 = 9.81;

// ---------------------------------------------------------------- helpers

fn spec(
    objects: Vec<ObjectSpec>,
    pins: Vec<PinSpec>,
    contact: ContactConfig,
    spw: u64,
) -> WorldSpec {
    WorldSpec {
        objects,
        pins,
        gravity: DVec3::new(0.0, -G, 0.0),
        contact,
        time: TimeConfig {
            internal_step: None,
            beta: 0.3,
            steps_per_window: spw,
        },
        limits: LimitsConfig::default(),
        partitions: 1,
        workers: 1,
    }
}

fn cloth(name: &str, mesh: TriMesh, material: Material) -> ObjectSpec {
    ObjectSpec {
        friction: None,
        name: name.into(),
        mesh,
        kind: ObjectKind::Cloth {
            material,
            rest: None,
            velocity: vec![],
        },
    }
}

/// Stiffness-proportional damping `alpha` (stretch_damping = alpha,
/// bend_damping = alpha k_b) at `fraction` of its explicit stability limit
/// `h γ + h² ω² / 2 ≤ 2` with `γ = alpha ω_max²` (materials/step.rs).
fn damping_alpha(world: &World, fraction: f64) -> f64 {
    let (h, om) = (world.lattice.h_el(), world.omega_max);
    fraction * (2.0 - 0.5 * h * h * om * om) / (h * om * om)
}

/// Zeroes every dynamic velocity (kinetic damping). Valid between windows,
/// when every vertex is synchronized (`tau == tick`).
fn zero_velocities(engine: &mut Engine) {
    let w = &mut engine.world;
    for i in 0..w.v.len() {
        if w.inv_mass[i] > 0.0 {
            w.v[i] = DVec3::ZERO;
        }
    }
}

/// Runs `windows` windows of dynamic relaxation: after a window whose kinetic
/// energy is below the previous one's (a kinetic-energy peak has passed), all
/// dynamic velocities are zeroed.
fn relax(engine: &mut Engine, windows: usize) {
    let mut ke_prev = 0.0;
    for _ in 0..windows {
        let s = engine.step_window().expect("window").stats;
        if s.kinetic_energy < ke_prev {
            zero_velocities(engine);
            ke_prev = 0.0;
        } else {
            ke_prev = s.kinetic_energy;
        }
    }
}

// ---------------------------------------------------------------- cantilever

/// A clamped strip: free length `lf` in `n` segments of `dx = lf / n` along x,
/// plus one clamped segment (columns 0 and 1 pinned: the clamped edge is column
/// 1), width `width` along z, in the xz plane at y = 0.
struct Strip {
    mesh: TriMesh,
    nu: usize,
    nv: usize,
    pins: Vec<u32>,
}

fn strip(n: usize, lf: f64, width: f64) -> Strip {
    let dx = lf / n as f64;
    let nu = n + 2;
    let nv = (width / dx).round() as usize + 1;
    let l = dx * (nu - 1) as f64;
    let mesh = grid(
        DVec3::new(0.5 * l, 0.0, 0.0),
        DVec3::X,
        DVec3::Z,
        [l, width],
        [nu, nv],
    );
    let pins = (0..nv)
        .flat_map(|j| [(j * nu) as u32, (j * nu + 1) as u32])
        .collect();
    Strip { mesh, nu, nv, pins }
}

/// Signed dihedral angle of the hinge (edge x0-x1, wings x2, x3), written from
/// `acm-spec.md` §2.1 (not the engine's code).
fn hinge_angle(x: &[DVec3; 4]) -> f64 {
    let e = x[1] - x[0];
    let na = e.cross(x[2] - x[0]);
    let nb = (x[3] - x[0]).cross(e);
    na.cross(nb).dot(e / e.length()).atan2(na.dot(nb))
}

/// Independent linear static solve of the discrete model for the vertical
/// displacement of a flat mesh in the xz plane under gravity: energy
/// `Σ_hinges k_b · 3|e|²/A · θ²` linearized about the flat rest state
/// (`K = Σ 2 k_b w ∇θ ∇θᵀ` on the y components; the membrane carries no
/// first-order transverse stiffness), loads `-m_i g` with masses lumped as a
/// third of each incident triangle's area times `rho`. Returns the y
/// displacement of every vertex (0 at `fixed`).
fn linear_sag(mesh: &TriMesh, fixed: &[u32], rho: f64, kb: f64) -> Vec<f64> {
    let p = &mesh.positions;
    let n = p.len();
    let mut mass = vec![0.0; n];
    // Edge -> (edge start, edge end, opposite vertex) of each incident triangle.
    let mut edges: std::collections::BTreeMap<(u32, u32), Vec<[u32; 3]>> = Default::default();
    for t in &mesh.triangles {
        let area = 0.5
            * (p[t[1] as usize] - p[t[0] as usize])
                .cross(p[t[2] as usize] - p[t[0] as usize])
                .length();
        for k in 0..3 {
            mass[t[k] as usize] += rho * area / 3.0;
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push([a, b, c]);
        }
    }
    let mut free = vec![usize::MAX; n];
    let mut nf = 0;
    for i in 0..n {
        if !fixed.contains(&(i as u32)) {
            free[i] = nf;
            nf += 1;
        }
    }
    let mut k = vec![vec![0.0; nf + 1]; nf];
    for tris in edges.values().filter(|t| t.len() == 2) {
        let v = [tris[0][0], tris[0][1], tris[0][2], tris[1][2]];
        let x = v.map(|i| p[i as usize]);
        let e = x[1] - x[0];
        let area = 0.5 * (e.cross(x[2] - x[0]).length() + (x[3] - x[0]).cross(e).length());
        let w = 3.0 * e.length_squared() / area;
        // dθ/dy_j by central differences (θ is smooth at the flat state).
        let eps = 1e-7 * e.length();
        let g: Vec<f64> = (0..4)
            .map(|j| {
                let (mut xp, mut xm) = (x, x);
                xp[j].y += eps;
                xm[j].y -= eps;
                (hinge_angle(&xp) - hinge_angle(&xm)) / (2.0 * eps)
            })
            .collect();
        for a in 0..4 {
            let fa = free[v[a] as usize];
            if fa == usize::MAX {
                continue;
            }
            for b in 0..4 {
                let fb = free[v[b] as usize];
                if fb != usize::MAX {
                    k[fa][fb] += 2.0 * kb * w * g[a] * g[b];
                }
            }
        }
    }
    for i in 0..n {
        if free[i] != usize::MAX {
            k[free[i]][nf] = -mass[i] * G;
        }
    }
    // Gaussian elimination with partial pivoting (K is SPD; pivoting is cheap insurance).
    for c in 0..nf {
        let piv = (c..nf)
            .max_by(|&a, &b| k[a][c].abs().total_cmp(&k[b][c].abs()))
            .unwrap();
        k.swap(c, piv);
        for r in c + 1..nf {
            let f = k[r][c] / k[c][c];
            if f != 0.0 {
                for col in c..=nf {
                    k[r][col] -= f * k[c][col];
                }
            }
        }
    }
    let mut u = vec![0.0; nf];
    for c in (0..nf).rev() {
        let s: f64 = (c + 1..nf).map(|j| k[c][j] * u[j]).sum();
        u[c] = (k[c][nf] - s) / k[c][c];
    }
    (0..n)
        .map(|i| {
            if free[i] == usize::MAX {
                0.0
            } else {
                u[free[i]]
            }
        })
        .collect()
}

/// Mean of `-y` over the free-end column of a strip (tip deflection).
fn tip_deflection(y: impl Fn(usize) -> f64, s: &Strip) -> f64 {
    -(0..s.nv).map(|j| y(j * s.nu + s.nu - 1)).sum::<f64>() / s.nv as f64
}

struct CantileverResult {
    engine_tip: f64,
    reference_tip: f64,
    max_drift: f64,
}

/// Relaxes the clamped strip to equilibrium in the engine and returns its tip
/// deflection next to the linear reference.
fn cantilever(n: usize, lf: f64, width: f64, rho: f64, kb: f64) -> CantileverResult {
    let st = strip(n, lf, width);
    let mut material = Material {
        area_density: rho,
        youngs_modulus: 2.0e5,
        poisson_ratio: 0.3,
        thickness: 4.0e-4,
        bending_stiffness: kb,
        stretch_damping: 0.0,
        bend_damping: 0.0,
    };
    let pins = || {
        vec![PinSpec {
            name: "clamp".into(),
            object: 0,
            vertices: st.pins.clone(),
            motion: Motion::Fixed,
        }]
    };
    let build = |m: Material| {
        World::build(&spec(
            vec![cloth("strip", st.mesh.clone(), m)],
            pins(),
            ContactConfig::default(),
            100,
        ))
        .expect("world")
    };
    // Material damping (half its stability limit) kills the high modes; kinetic
    // damping takes care of the fundamental.
    let alpha = damping_alpha(&build(material), 0.5);
    material.stretch_damping = alpha;
    material.bend_damping = alpha * kb;
    let world = build(material);
    let h = world.lattice.h_el();
    let window = h * 100.0;
    let mut engine = Engine::new(world, Serial).expect("engine");
    // ~1.2 s of relaxation (about 8 periods of the fundamental), then 0.1 s free.
    relax(&mut engine, (1.2 / window).ceil() as usize);
    let tip_relaxed = tip_deflection(|i| engine.world.x[i].y, &st);
    let mut max_drift: f64 = 0.0;
    for _ in 0..(0.1 / window).ceil() as usize {
        engine.step_window().expect("window");
        let tip = tip_deflection(|i| engine.world.x[i].y, &st);
        max_drift = max_drift.max((tip - tip_relaxed).abs());
    }
    let engine_tip = tip_deflection(|i| engine.world.x[i].y, &st);
    let u = linear_sag(&st.mesh, &st.pins, rho, kb);
    let reference_tip = tip_deflection(|i| u[i], &st);
    println!(
        "cantilever n={n}: h_el={h:.3e} s, omega_max={:.0} rad/s, alpha={alpha:.2e} s, \
         t={:.2} s, rollbacks={}",
        engine.world.omega_max,
        engine.world.time(),
        engine.totals.rollbacks
    );
    CantileverResult {
        engine_tip,
        reference_tip,
        max_drift,
    }
}

/// A strip (free length 0.2 m, width 0.04 m) clamped at one end sags under its
/// weight; k_b is chosen so that continuum theory predicts δ = 3 % of L.
///
/// **Expected values.** Kirchhoff beam/plate theory per unit width,
/// `δ = q L⁴ / (8 D)` with `q = rho g` and `D = 6 k_b` (the discrete-shells
/// calibration of materials/mod.rs). For a 1-D chain of hinges with this
/// stiffness the discrete answer is exactly `δ (1 + 1/N)²` (hinge n from the tip
/// carries the moment `q (n dx)² / 2`), i.e. +21 % at N = 10, +10 % at N = 20.
/// The right-triangle grid is softer still: with free side edges it bends
/// through a zig-zag twist mode (the z-edge hinges of alternate columns pick up
/// `±κ_xz dz`), so the independent linear solve of the discrete model gives
/// δ/δ_theory = 1.413 (N = 10), 1.320 (N = 20), 1.276 (N = 40): it converges
/// like 1/N, but to ≈ 1.23, not 1 — an effective `D ≈ 6 k_b / 1.23` for a free
/// strip on this mesh (the `k_b = D/6` calibration is for cylindrical bending,
/// which a free strip on this mesh does not keep). So a 10 % band around plate
/// theory cannot hold on any affordable mesh of this kind.
///
/// **What is asserted.**
/// 1. The engine's equilibrium matches the linear reference of the same
///    discrete model within 1 % (measured: ~0.1–0.3 %; the residue is geometric
///    nonlinearity at 3 % deflection and the last relaxation wiggle).
/// 2. The equilibrium is static: over 0.1 s without kinetic damping the tip
///    moves by < 0.5 % of δ.
/// 3. Against plate theory: the ratio lies in [1.0, 1.5] at N = 10 and [1.0,
///    1.4] at N = 20 and decreases with refinement (discretization error of a
///    coarse mesh, see above). The linear reference at N = 40 and its 1/N
///    (Richardson) extrapolation pin the mesh factor at 1.15–1.30.
#[test]
fn cantilever_sags_as_plate_theory_says() {
    let (lf, width, rho) = (0.2f64, 0.04f64, 0.15f64);
    let q = rho * G;
    let delta_theory = 0.03 * lf;
    let d = q * lf.powi(4) / (8.0 * delta_theory);
    let kb = d / 6.0;
    println!("cantilever: q={q:.4} N/m², D=6 k_b={d:.4e} N·m, k_b={kb:.4e} J, δ_theory={delta_theory:.4e} m");
    let mut ratios = Vec::new();
    for &(n, band) in &[(10usize, 1.5), (20, 1.4)] {
        let r = cantilever(n, lf, width, rho, kb);
        let chain = (1.0 + 1.0 / n as f64).powi(2);
        let ratio = r.engine_tip / delta_theory;
        let rel = r.engine_tip / r.reference_tip - 1.0;
        println!(
            "cantilever n={n}: engine δ={:.5e} m, linear reference δ={:.5e} m (rel diff {:+.3}%), \
             theory δ={delta_theory:.5e} m: engine/theory={ratio:.4} (1-D chain would give {chain:.4}), \
             drift over 0.1 s={:.2e} m",
            r.engine_tip,
            r.reference_tip,
            100.0 * rel,
            r.max_drift
        );
        assert!(
            rel.abs() < 0.01,
            "n={n}: engine equilibrium {:.5e} vs discrete reference {:.5e}",
            r.engine_tip,
            r.reference_tip
        );
        assert!(
            r.max_drift < 0.005 * delta_theory,
            "n={n}: not static, drift {:.3e}",
            r.max_drift
        );
        assert!(
            (1.0..band).contains(&ratio),
            "n={n}: engine/theory = {ratio:.4} outside [1, {band}]"
        );
        ratios.push(ratio);
    }
    assert!(
        ratios[1] < ratios[0],
        "no convergence toward theory: {ratios:?}"
    );
    // Mesh factor from the (cheap) reference alone at N = 20, 40.
    let st20 = strip(20, lf, width);
    let st40 = strip(40, lf, width);
    let u20 = linear_sag(&st20.mesh, &st20.pins, rho, kb);
    let r20 = tip_deflection(|i| u20[i], &st20) / delta_theory;
    let u40 = linear_sag(&st40.mesh, &st40.pins, rho, kb);
    let r40 = tip_deflection(|i| u40[i], &st40) / delta_theory;
    let extrapolated = 2.0 * r40 - r20;
    println!("cantilever reference: δ/theory = {r20:.4} (N=20), {r40:.4} (N=40), 1/N-extrapolated {extrapolated:.4}");
    assert!(
        r40 < r20 && (1.15..1.30).contains(&extrapolated),
        "mesh factor {extrapolated:.4}"
    );
}

// ---------------------------------------------------------------- incline

struct SlideResult {
    /// Down-slope displacement of the centre of mass over the measured span (m).
    displacement: f64,
    /// Fitted down-slope acceleration (m/s²) from the positions, and from the velocities.
    accel_pos: f64,
    accel_vel: f64,
    /// Measured span (s) and internal step (s).
    span: f64,
    h_el: f64,
    /// Largest |down-slope velocity| of the centre of mass over the span (m/s).
    max_speed: f64,
    /// Smallest separation of any contact stencil over the run (m) and the floor.
    min_separation: f64,
    eta_inf: f64,
    max_depth: u32,
    rollbacks: u64,
}

/// Least-squares fit of `y = c0 + c1 t + c2 t²`; returns `c2`.
fn quadratic_coefficient(t: &[f64], y: &[f64]) -> f64 {
    // Normal equations on centred time for conditioning.
    let tm = t.iter().sum::<f64>() / t.len() as f64;
    let mut a = [[0.0; 4]; 3];
    for (&ti, &yi) in t.iter().zip(y) {
        let s = ti - tm;
        let b = [1.0, s, s * s];
        for r in 0..3 {
            for c in 0..3 {
                a[r][c] += b[r] * b[c];
            }
            a[r][3] += b[r] * yi;
        }
    }
    for c in 0..3 {
        for r in c + 1..3 {
            let f = a[r][c] / a[c][c];
            for k in c..4 {
                a[r][k] -= f * a[c][k];
            }
        }
    }
    a[2][3] / a[2][2]
}

/// Least-squares slope of `y(t)`.
fn linear_slope(t: &[f64], y: &[f64]) -> f64 {
    let n = t.len() as f64;
    let (tm, ym) = (t.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let num: f64 = t.iter().zip(y).map(|(a, b)| (a - tm) * (b - ym)).sum();
    let den: f64 = t.iter().map(|a| (a - tm) * (a - tm)).sum();
    num / den
}

/// A 4 cm, 5×5 cloth patch on a fixed box whose top face is tilted by `theta`
/// about z (rising toward +x), placed parallel to the slope at 1.2 `eta_1`
/// above it, with friction `mu`. It first settles (kinetic damping, `settle`
/// seconds, which also removes the normal bounce: penalty contact has no
/// normal damping), then runs freely for `span` seconds; the down-slope
/// position and velocity of its centre of mass are recorded at every window.
fn slide(theta: f64, mu: f64, settle: f64, span: f64) -> SlideResult {
    slide_with(theta, mu, [None, None], settle, span)
}

/// The incline's surface before tilting: the top face (y = 0) of a box, two
/// big triangles under the patch, or (`fine`) a triangulated sheet with a
/// 7 mm spacing, so that every patch vertex also meets the sheet's vertices
/// under the patch's faces: several friction stencils per vertex and batch.
fn incline_mesh(fine: bool) -> TriMesh {
    if fine {
        grid(
            DVec3::new(-0.25, 0.0, 0.0),
            DVec3::X,
            DVec3::Z,
            [0.7, 0.2],
            [101, 29],
        )
    } else {
        cuboid(DVec3::new(-0.6, -0.05, -0.1), DVec3::new(0.1, 0.0, 0.1))
    }
}

/// [`slide`] with the patch's and the incline's own friction coefficients
/// (`None`: the scene's `mu`).
fn slide_with(theta: f64, mu: f64, own: [Option<f64>; 2], settle: f64, span: f64) -> SlideResult {
    slide_on(incline_mesh(false), theta, mu, own, settle, span)
}

fn slide_on(
    mut bx: TriMesh,
    theta: f64,
    mu: f64,
    own: [Option<f64>; 2],
    settle: f64,
    span: f64,
) -> SlideResult {
    let eta = 1.0e-3;
    let tilt = |p: DVec3| rotate(p, DVec3::Z, theta);
    bx.positions.iter_mut().for_each(|p| *p = tilt(*p));
    let mut patch = grid(
        DVec3::new(0.0, 1.2 * eta, 0.0),
        DVec3::X,
        DVec3::Z,
        [0.04, 0.04],
        [5, 5],
    );
    patch.positions.iter_mut().for_each(|p| *p = tilt(*p));
    let material = Material::plate(0.15, 1.0e5, 0.3, 4.0e-4);
    let contact = ContactConfig {
        thickness: eta,
        friction: mu,
        ..Default::default()
    };
    let mut patch = cloth("patch", patch, material);
    patch.friction = own[0];
    let objects = vec![
        patch,
        ObjectSpec {
            friction: own[1],
            name: "incline".into(),
            mesh: bx,
            kind: ObjectKind::Obstacle {
                motion: Motion::Fixed,
            },
        },
    ];
    let world = World::build(&spec(objects, vec![], contact, 50)).expect("world");
    assert_eq!(world.schedule.eta_1, eta);
    let h_el = world.lattice.h_el();
    let window = 50.0 * h_el;
    let eta_inf = world.schedule.eta_inf;
    let mut engine = Engine::new(world, Serial).expect("engine");
    let patch_vertices = 0..25usize;
    let down = -tilt(DVec3::X); // unit down-slope direction
    let com = |e: &Engine| {
        let w = &e.world;
        let m: f64 = patch_vertices.clone().map(|i| w.mass[i]).sum();
        let x: DVec3 = patch_vertices.clone().map(|i| w.x[i] * w.mass[i]).sum();
        let v: DVec3 = patch_vertices.clone().map(|i| w.v[i] * w.mass[i]).sum();
        (x.dot(down) / m, v.dot(down) / m)
    };
    relax(&mut engine, (settle / window).ceil() as usize);
    zero_velocities(&mut engine);
    let mut min_separation = f64::INFINITY;
    let t0 = engine.world.time();
    let (s0, _) = com(&engine);
    let (mut ts, mut ss, mut vs) = (vec![0.0], vec![0.0], vec![0.0]);
    for _ in 0..(span / window).ceil() as usize {
        let stats = engine.step_window().expect("window").stats;
        min_separation = min_separation.min(stats.min_separation.unwrap_or(f64::INFINITY));
        let (s, v) = com(&engine);
        ts.push(engine.world.time() - t0);
        ss.push(s - s0);
        vs.push(v);
    }
    SlideResult {
        displacement: *ss.last().unwrap(),
        accel_pos: 2.0 * quadratic_coefficient(&ts, &ss),
        accel_vel: linear_slope(&ts, &vs),
        span: *ts.last().unwrap(),
        h_el,
        max_speed: vs.iter().fold(0.0f64, |a, v| a.max(v.abs())),
        min_separation,
        eta_inf,
        max_depth: engine.totals.max_depth,
        rollbacks: engine.totals.rollbacks,
    }
}

fn print_slide(label: &str, deg: f64, mu: f64, r: &SlideResult) {
    println!(
        "{label}: theta={deg}°, mu={mu}: down-slope displacement {:.4e} m over {:.3} s, \
         a(fit x)={:.5} m/s², a(fit v)={:.5} m/s², max |v|={:.3e} m/s, h_el={:.3e} s, \
         min separation {:.3e} m (floor {:.1e}), max depth {}, rollbacks {}",
        r.displacement,
        r.span,
        r.accel_pos,
        r.accel_vel,
        r.max_speed,
        r.h_el,
        r.min_separation,
        r.eta_inf,
        r.max_depth,
        r.rollbacks
    );
    assert!(
        r.min_separation > r.eta_inf,
        "{label}: separation below the floor"
    );
}

/// `tan θ < mu`: the patch sticks.
///
/// **Expected**: no sliding. The friction kick reads the velocities at the
/// start of its batch (Jacobi semantics, `acm-spec.md` §3), so it cancels the
/// down-slope velocity of the *previous* internal step while gravity adds
/// `g sin θ h_el` in the same batch: a sticking patch creeps at the lag speed
/// `g sin θ h_el` (≈ 0.36 mm/s at 15°), i.e. `g sin θ h_el T` over `T`.
/// Measured at 15°, mu = 0.5: 9.45e-5 m vs 9.0e-5 m predicted over 0.25 s,
/// peak speed 1.3× the lag speed. Close to the threshold (25°, tan θ = 0.93 mu)
/// the normal impulse per kick fluctuates with the residual normal oscillation
/// of the penalty contact and the patch micro-slips: 3.7e-4 m over 0.25 s,
/// still with no mean acceleration.
///
/// **Asserted**: no fitted down-slope acceleration above 1 % of `g sin θ`
/// (friction under-applied by 3 % would give 3.5 % at 25°); displacement below
/// 0.5 % of the frictionless `g sin θ T² / 2` (measured 0.12 %, 0.28 %); and at
/// 15°, speed below twice the lag speed and displacement below twice the lag
/// creep.
#[test]
fn incline_sticks_when_tan_theta_below_mu() {
    for &(deg, mu) in &[(15.0f64, 0.5f64), (25.0, 0.5)] {
        let th = deg.to_radians();
        assert!(th.tan() < mu);
        let r = slide(th, mu, 0.05, 0.25);
        print_slide("stick", deg, mu, &r);
        let lag_speed = G * th.sin() * r.h_el;
        let lag_creep = lag_speed * r.span;
        let free = 0.5 * G * th.sin() * r.span * r.span;
        println!(
            "stick: theta={deg}°: displacement {:.4e} m = {:.3}% of frictionless {free:.4e} m \
             (lag creep g sinθ h T = {lag_creep:.4e} m); max |v| {:.3e} m/s (lag speed {lag_speed:.3e} m/s); \
             fitted a {:.2e} m/s² = {:.3}% of g sinθ",
            r.displacement,
            100.0 * r.displacement / free,
            r.max_speed,
            r.accel_pos,
            100.0 * r.accel_pos / (G * th.sin())
        );
        assert!(
            r.accel_pos.abs() < 0.01 * G * th.sin(),
            "theta={deg}: accelerating, a = {:.3e}",
            r.accel_pos
        );
        assert!(
            r.displacement.abs() < 0.005 * free,
            "theta={deg}: displacement {:.3e} m",
            r.displacement
        );
        if deg < 20.0 {
            assert!(
                r.max_speed < 2.0 * lag_speed,
                "theta={deg}: slipping, |v| = {:.3e}",
                r.max_speed
            );
            assert!(
                r.displacement.abs() < 2.0 * lag_creep,
                "theta={deg}: creep {:.3e} m",
                r.displacement
            );
        }
    }
}

/// Per-object friction: a frictionless scene whose patch (0.5) and incline
/// (0.08) carry their own coefficients slides with their geometric mean,
/// `mu = 0.2`: `a = g (sin θ − 0.2 cos θ)`.
#[test]
fn incline_uses_the_geometric_mean_of_the_objects_friction() {
    let th = 30f64.to_radians();
    let r = slide_with(th, 0.0, [Some(0.5), Some(0.08)], 0.05, 0.25);
    let expected = G * (th.sin() - 0.2 * th.cos());
    for a in [r.accel_pos, r.accel_vel] {
        assert!(
            (a / expected - 1.0).abs() < 0.01,
            "a = {a:.5} vs {expected:.5}"
        );
    }
}

/// `tan θ > mu`: the patch slides with `a = g (sin θ − mu cos θ)`; with
/// `mu = 0`, `a = g sin θ`.
///
/// **Expected** from Coulomb's law for a body on an incline. The penalty
/// contact carries the weight's normal component on average and friction is
/// capped at `mu` times each kick's normal impulse, so the average friction
/// force is exactly `mu m g cos θ` while sliding: the acceleration is fitted by
/// least squares to the centre of mass's down-slope position (quadratic) and
/// velocity (linear) over ~0.25 s after the patch settled. Measured: within
/// 0.01 % of theory in every case.
///
/// **Tolerance** 1 %: room for the residual normal oscillation and for the
/// patch crossing the box face's diagonal (where its weight is shared by more
/// stencils), an order of magnitude above what is measured and still far below
/// the effect of friction mis-scaled by a few percent.
#[test]
fn incline_slides_when_tan_theta_above_mu() {
    for &(deg, mu) in &[(30.0f64, 0.2f64), (35.0, 0.5), (30.0, 0.0)] {
        let th = deg.to_radians();
        assert!(th.tan() > mu);
        let r = slide(th, mu, 0.05, 0.25);
        print_slide("slide", deg, mu, &r);
        let expected = G * (th.sin() - mu * th.cos());
        for (what, a) in [("position fit", r.accel_pos), ("velocity fit", r.accel_vel)] {
            let rel = a / expected - 1.0;
            println!("slide: theta={deg}°, mu={mu}: {what} a={a:.5} m/s² vs g(sinθ − mu cosθ)={expected:.5} m/s² ({:+.3}%)", 100.0 * rel);
            assert!(
                rel.abs() < 0.01,
                "theta={deg}, mu={mu}: {what} a={a:.5} vs {expected:.5}"
            );
        }
    }
}

/// On a finely triangulated incline each patch vertex takes friction from
/// several stencils in one batch (its own vertex–face contact, and the
/// sheet's vertices under its faces). Those sliding contacts share the
/// load, so their Coulomb friction must add up: the patch slides with
/// `a = g (sin θ − mu cos θ)` as on the box, within the same 1 %. (A clamp
/// of each vertex's summed friction to its largest single stencil impulse
/// under-applies friction here.)
#[test]
fn incline_of_a_fine_mesh_slides_with_coulomb_friction() {
    let (deg, mu) = (30.0f64, 0.2f64);
    let th = deg.to_radians();
    let r = slide_on(incline_mesh(true), th, mu, [None, None], 0.05, 0.25);
    print_slide("fine slide", deg, mu, &r);
    let expected = G * (th.sin() - mu * th.cos());
    for (what, a) in [("position fit", r.accel_pos), ("velocity fit", r.accel_vel)] {
        let rel = a / expected - 1.0;
        println!(
            "fine slide: {what} a={a:.5} m/s² vs {expected:.5} m/s² ({:+.3}%)",
            100.0 * rel
        );
        assert!(rel.abs() < 0.01, "{what}: a={a:.5} vs {expected:.5}");
    }
}
