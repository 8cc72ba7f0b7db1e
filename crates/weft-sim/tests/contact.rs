//! Contact-guarantee and bad-input tests (`acm-spec.md` §3–§4).
//!
//! * every committed window end is checked by brute force over **all** stencils
//!   of the world ([`check_window_end`]): each is farther than
//!   `eta_(depth+1)` of its active depth (what the narrow phase certified) and
//!   than the floor `eta_inf`, and no two triangles intersect;
//! * fast impacts (no tunnelling), a sheet dropped on a pinned sheet, cloth
//!   resting on a sphere;
//! * the broad phase against a brute-force, densely time-sampled search;
//! * bad input: every class is refused with an error naming the problem;
//! * the penalty kick is `-h dV_l/dx` (finite differences).

use std::collections::BTreeSet;

use glam::DVec3;
use weft_core::{MeshError, StencilKey, StencilKind, TriMesh};
use weft_geom::ccd::Trajectory;
use weft_geom::distance::stencil_closest;
use weft_geom::intersections::mesh_self_intersections;
use weft_geom::shapes::{cuboid, grid, sphere};
use weft_sim::broad::BroadPhase;
use weft_sim::kinematics::{Keyframes, Motion};
use weft_sim::layers::{penalty_kick, LayerSchedule};
use weft_sim::materials::{damping_step_limit, Material, MaterialError};
use weft_sim::trajectory::Trajectories;
use weft_sim::{
    CommittedWindow, ContactConfig, Engine, LimitsConfig, ObjectKind, ObjectSpec, PinSpec, Serial,
    SimError, TimeConfig, World, WorldSpec,
};
use weft_testkit::{assert_gradient, Rng};

// ---------------------------------------------------------------- helpers

/// A cotton-like material with the plate-calibrated hinge stiffness.
fn cloth_material() -> Material {
    Material::plate(0.15, 2.0e5, 0.3, 4.0e-4)
}

fn cloth(name: &str, mesh: TriMesh, velocity: DVec3) -> ObjectSpec {
    let n = mesh.num_vertices();
    ObjectSpec {
        friction: None,
        name: name.into(),
        mesh,
        kind: ObjectKind::Cloth {
            material: cloth_material(),
            rest: None,
            velocity: vec![velocity; n],
        },
    }
}

fn obstacle(name: &str, mesh: TriMesh) -> ObjectSpec {
    ObjectSpec {
        friction: None,
        name: name.into(),
        mesh,
        kind: ObjectKind::Obstacle {
            motion: Motion::Fixed,
        },
    }
}

fn spec(objects: Vec<ObjectSpec>, gravity: DVec3, steps_per_window: u64) -> WorldSpec {
    WorldSpec {
        objects,
        pins: vec![],
        gravity,
        contact: ContactConfig {
            thickness: 1e-3,
            friction: 0.0,
            ..Default::default()
        },
        time: TimeConfig {
            internal_step: None,
            beta: 0.3,
            steps_per_window,
        },
        limits: LimitsConfig::default(),
        partitions: 1,
        workers: 1,
    }
}

fn engine(spec: &WorldSpec) -> Engine<Serial> {
    let world = World::build(spec).expect("world builds");
    Engine::new(world, Serial).expect("valid initial state")
}

/// Every edge of `triangles` (sorted vertex pairs).
fn edges_of(triangles: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let mut set = BTreeSet::new();
    for t in triangles {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            set.insert([a.min(b), a.max(b)]);
        }
    }
    set.into_iter().collect()
}

/// Every contact stencil of a mesh: VF (vertex, triangle not containing it) and
/// EE (edges without a shared vertex), without the all-kinematic ones.
fn all_stencils(triangles: &[[u32; 3]], inv_mass: &[f64]) -> Vec<StencilKey> {
    let dynamic = |k: &StencilKey| k.v.iter().any(|&i| inv_mass[i as usize] > 0.0);
    let mut out = Vec::new();
    for v in 0..inv_mass.len() as u32 {
        for t in triangles {
            if t.contains(&v) {
                continue;
            }
            let k = StencilKey::vertex_face(v, *t);
            if dynamic(&k) {
                out.push(k);
            }
        }
    }
    let edges = edges_of(triangles);
    for (i, a) in edges.iter().enumerate() {
        for b in &edges[i + 1..] {
            if a.iter().any(|v| b.contains(v)) {
                continue;
            }
            let k = StencilKey::edge_edge(*a, *b);
            if dynamic(&k) {
                out.push(k);
            }
        }
    }
    out
}

/// Distance from `p` to the segment `[a, b]` (reference, independent of
/// `weft_geom::distance`).
fn ref_point_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let e = b - a;
    let ee = e.dot(e);
    let t = if ee > 0.0 {
        ((p - a).dot(e) / ee).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + e * t)).length()
}

/// Reference vertex–triangle distance: the face-interior projection when it
/// lies inside, else the nearest edge. Every candidate is the length of a real
/// pair of points, so it never underestimates beyond rounding.
fn ref_vertex_face(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let mut d = ref_point_segment(p, a, b)
        .min(ref_point_segment(p, b, c))
        .min(ref_point_segment(p, c, a));
    let n = (b - a).cross(c - a);
    let nn = n.dot(n);
    if nn > 0.0 {
        let q = p - n * ((p - a).dot(n) / nn);
        let wa = (b - q).cross(c - q).dot(n) / nn;
        let wb = (c - q).cross(a - q).dot(n) / nn;
        let wc = 1.0 - wa - wb;
        if wa >= 0.0 && wb >= 0.0 && wc >= 0.0 {
            d = d.min((p - (a * wa + b * wb + c * wc)).length());
        }
    }
    d
}

/// Reference segment–segment distance: endpoint candidates, and the clamped
/// solution of the normal equations refined by alternating projections,
/// evaluated as the length of a real pair of points (an upper bound that is
/// tight up to rounding; it never takes the infinite lines' distance).
fn ref_edge_edge(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> f64 {
    let mut d = ref_point_segment(p0, q0, q1)
        .min(ref_point_segment(p1, q0, q1))
        .min(ref_point_segment(q0, p0, p1))
        .min(ref_point_segment(q1, p0, p1));
    let (e, f, r) = (p1 - p0, q1 - q0, p0 - q0);
    let (ee, ff, ef, er, fr) = (e.dot(e), f.dot(f), e.dot(f), e.dot(r), f.dot(r));
    let den = ee * ff - ef * ef;
    if ee > 0.0 && ff > 0.0 && den > 0.0 {
        let mut s = ((ef * fr - ff * er) / den).clamp(0.0, 1.0);
        let mut t = ((ee * fr - ef * er) / den).clamp(0.0, 1.0);
        for _ in 0..4 {
            d = d.min(((p0 + e * s) - (q0 + f * t)).length());
            t = ((p0 + e * s - q0).dot(f) / ff).clamp(0.0, 1.0);
            s = ((q0 + f * t - p0).dot(e) / ee).clamp(0.0, 1.0);
        }
        d = d.min(((p0 + e * s) - (q0 + f * t)).length());
    }
    d
}

fn ref_distance(kind: StencilKind, x: &[DVec3; 4]) -> f64 {
    match kind {
        StencilKind::VertexFace => ref_vertex_face(x[0], x[1], x[2], x[3]),
        StencilKind::EdgeEdge => ref_edge_edge(x[0], x[1], x[2], x[3]),
    }
}

/// What [`check_window_end`] measured.
#[derive(Clone, Copy, Debug)]
struct EndCheck {
    /// Smallest stencil distance at the window end (m).
    min_distance: f64,
    /// Smallest `d - eta_(depth+1)` over all stencils (m).
    min_margin: f64,
    /// Stencils checked.
    stencils: usize,
    /// Stencils where `stencil_closest` is more than 1e-9 m (and 1e-6
    /// relative) below the reference distance (see
    /// `edge_edge_distance_of_parallel_edges_is_not_underestimated`).
    closest_underestimates: usize,
}

/// Brute-force invariants of a committed window end, over every stencil:
///
/// * `d >= eta_(depth+1)` with `depth` the stencil's active depth after the
///   commit — the narrow phase certified `d > eta_(depth+1)` over the whole
///   window T1 included (and retirement only drops layer `l` after certifying
///   `d > eta_l`);
/// * `d >= eta_inf` (the floor);
/// * no two triangles intersect, except pairs of all-kinematic triangles.
///
/// Tolerance: the certificate is about the exact distance of the stored
/// (exact) positions; `stencil_closest` computes it in floating point with an
/// error of a few ulps of the coordinates' magnitude `M` (differences of
/// coordinates, a handful of products and one square root). `TOL = 1024 u M`
/// bounds that generously and is ~1e-13 m here, nine orders of magnitude below
/// the layer gaps being checked (1e-4 m).
fn check_window_end(engine: &Engine<Serial>) -> EndCheck {
    check_state(engine, true)
}

/// [`check_window_end`]; with `layer_invariant = false` (the initial state,
/// which only has to be above the floor) the `eta_(depth+1)` check is skipped.
fn check_state(engine: &Engine<Serial>, layer_invariant: bool) -> EndCheck {
    let w = &engine.world;
    let s = &w.schedule;
    let m = w.x.iter().fold(0.0f64, |a, p| a.max(p.abs().max_element()));
    let tol = 1024.0 * f64::EPSILON * 0.5 * m.max(1e-3);
    // The active-layer set is well formed.
    for (key, st) in &w.layers.stencils {
        assert!(st.depth >= 1, "active stencil {key:?} with depth 0");
        assert!(
            !key.shares_vertex(),
            "active stencil {key:?} shares a vertex"
        );
        assert!(
            key.v.iter().any(|&i| w.inv_mass[i as usize] > 0.0),
            "active stencil {key:?} is all-kinematic"
        );
    }
    let mut out = EndCheck {
        min_distance: f64::INFINITY,
        min_margin: f64::INFINITY,
        stencils: 0,
        closest_underestimates: 0,
    };
    for key in all_stencils(&w.triangles, &w.inv_mass) {
        let x = key.v.map(|i| w.x[i as usize]);
        let d = ref_distance(key.kind, &x);
        let dc = stencil_closest(key.kind, &x).d;
        if dc < d * (1.0 - 1e-6) - 1e-9 {
            out.closest_underestimates += 1;
        }
        let depth = w.layers.depth(&key);
        let eta_next = s.eta(depth + 1);
        out.stencils += 1;
        out.min_distance = out.min_distance.min(d);
        out.min_margin = out.min_margin.min(d - eta_next);
        assert!(
            d >= s.eta_inf - tol,
            "window {} (tick {}): {key:?} at distance {d:e} is below the floor eta_inf = {:e}; x = {x:?}",
            w.window_index,
            w.tick,
            s.eta_inf
        );
        assert!(
            !layer_invariant || d >= eta_next - tol,
            "window {} (tick {}): {key:?} at depth {depth} is at distance {d:e} <= eta_{} = {eta_next:e} \
             (the narrow phase should have reported it); x = {x:?}",
            w.window_index,
            w.tick,
            depth + 1
        );
    }
    let kinematic_tri = |f: u32| {
        w.triangles[f as usize]
            .iter()
            .all(|&i| w.inv_mass[i as usize] == 0.0)
    };
    let hits: Vec<(u32, u32)> = mesh_self_intersections(&w.x, &w.triangles)
        .into_iter()
        .filter(|&(a, b)| !(kinematic_tri(a) && kinematic_tri(b)))
        .collect();
    assert!(
        hits.is_empty(),
        "window {} (tick {}): intersecting triangles {:?}",
        w.window_index,
        w.tick,
        hits.iter()
            .map(|&(a, b)| (
                w.triangle_place(a).to_string(),
                w.triangle_place(b).to_string()
            ))
            .collect::<Vec<_>>()
    );
    out
}

/// Totals over a checked run.
#[derive(Clone, Copy, Debug, Default)]
struct RunSummary {
    windows: usize,
    rollbacks: u64,
    max_depth: u32,
    /// Smallest `min_separation` the engine reported.
    min_separation: f64,
    /// Smallest brute-force distance at a window end.
    min_end_distance: f64,
    /// Smallest `d - eta_(depth+1)` at a window end.
    min_margin: f64,
    /// Largest number of stencils at one window end whose `stencil_closest`
    /// distance is below the reference.
    closest_underestimates: usize,
}

/// Runs `windows` windows, checking the invariants at the start and after
/// every commit; `each` sees the engine after each window's check.
fn run_checked(
    engine: &mut Engine<Serial>,
    windows: usize,
    mut each: impl FnMut(&Engine<Serial>, &CommittedWindow),
) -> RunSummary {
    // The initial state only has to be above the floor (not outside
    // eta_(depth+1)); the summary covers committed window ends only.
    check_state(engine, false);
    let mut sum = RunSummary {
        min_separation: f64::INFINITY,
        min_end_distance: f64::INFINITY,
        min_margin: f64::INFINITY,
        ..Default::default()
    };
    for _ in 0..windows {
        let window = engine.step_window().expect("window commits");
        let stats = &window.stats;
        // The statistics are the engine's energies at the window end
        // (potential = elastic + gravity + contact), bit for bit.
        let (kinetic, elastic_gravity, contact) = engine.energies();
        assert_eq!(
            (
                stats.kinetic_energy,
                stats.potential_energy,
                stats.contact_energy
            ),
            (kinetic, elastic_gravity + contact, contact),
            "window {}: the statistics' energies",
            stats.window
        );
        let c = check_window_end(engine);
        let floor = engine.world.schedule.eta_inf;
        if let Some(ms) = stats.min_separation {
            assert!(
                ms > floor,
                "window {}: the engine saw a separation {ms:e} below the floor {floor:e} \
                 (brute force at the window end: smallest reference distance {:e}, {} stencils \
                 whose stencil_closest distance is below the reference)",
                stats.window,
                c.min_distance,
                c.closest_underestimates
            );
            sum.min_separation = sum.min_separation.min(ms);
        }
        sum.windows += 1;
        sum.rollbacks += stats.rollbacks as u64;
        sum.max_depth = sum.max_depth.max(stats.max_depth);
        sum.min_end_distance = sum.min_end_distance.min(c.min_distance);
        sum.min_margin = sum.min_margin.min(c.min_margin);
        sum.closest_underestimates = sum.closest_underestimates.max(c.closest_underestimates);
        each(engine, &window);
    }
    sum
}

fn print_summary(name: &str, e: &Engine<Serial>, s: &RunSummary) {
    let sch = &e.world.schedule;
    println!(
        "{name}: {} windows ({:.3e} s, h_el {:.3e} s), rollbacks {}, max depth {}, \
         eta_1 {:.3e}, eta_inf {:.3e}, min separation (engine) {:.4e}, \
         min end distance {:.4e}, min margin over eta_(depth+1) {:.4e}, narrow queries {}, \
         stencil_closest underestimates (max per window end) {}",
        s.windows,
        e.world.time(),
        e.world.lattice.h_el(),
        s.rollbacks,
        s.max_depth,
        sch.eta_1,
        sch.eta_inf,
        s.min_separation,
        s.min_end_distance,
        s.min_margin,
        e.totals.narrow_queries,
        s.closest_underestimates,
    );
}

fn object_vertices(e: &Engine<Serial>, object: usize) -> std::ops::Range<usize> {
    let r = &e.world.objects[object].vertices;
    r.start as usize..r.end as usize
}

// ------------------------------------------------- 2. no tunnelling

/// A large fixed triangle in the plane z = 0 (normal +z).
fn big_triangle() -> TriMesh {
    TriMesh::new(
        vec![
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        vec![[0, 1, 2]],
    )
}

/// A small cloth triangle (1 cm) `height` above the origin, slightly tilted.
fn small_triangle(height: f64) -> TriMesh {
    TriMesh::new(
        vec![
            DVec3::new(-0.005, -0.003, height),
            DVec3::new(0.005, -0.003, height + 0.0007),
            DVec3::new(0.0, 0.006, height + 0.0003),
        ],
        vec![[0, 1, 2]],
    )
}

fn bullet_scene(target: TriMesh, projectile: TriMesh, speed: f64) -> WorldSpec {
    spec(
        vec![
            obstacle("target", target),
            cloth("bullet", projectile, DVec3::new(0.0, 0.0, -speed)),
        ],
        DVec3::ZERO,
        20,
    )
}

/// Fires `projectile` down at a target whose top surface is z = `top`; checks
/// the invariants at every window end, that the projectile never goes below
/// the surface, and that it ends up stopped or bouncing back.
fn fire(name: &str, target: TriMesh, top: f64, projectile: TriMesh, speed: f64) {
    let spec = bullet_scene(target, projectile, speed);
    let mut e = engine(&spec);
    let cloth = object_vertices(&e, 1);
    let mut touched = false;
    let mut windows = 0;
    let sum = run_checked(&mut e, 40, |e, _| {
        windows += 1;
        for i in cloth.clone() {
            assert!(
                e.world.x[i].z > top,
                "{name}: vertex {i} went through the target: z = {}",
                e.world.x[i].z
            );
        }
        if e.world.layers.max_depth() > 0 {
            touched = true;
        }
    });
    print_summary(name, &e, &sum);
    let vz: f64 = cloth.clone().map(|i| e.world.v[i].z).sum::<f64>() / cloth.len() as f64;
    let zmin = cloth
        .clone()
        .map(|i| e.world.x[i].z)
        .fold(f64::INFINITY, f64::min);
    println!(
        "{name}: final mean vz {vz:.3} m/s (fired at {:.1}), lowest z {zmin:.4e}",
        -speed
    );
    assert!(
        touched && sum.rollbacks >= 1 && sum.max_depth >= 1,
        "{name}: no contact happened"
    );
    assert!(zmin > top, "{name}: ended on the far side");
    assert!(
        vz > -0.1 * speed,
        "{name}: still moving into the target at {vz} m/s after {} windows",
        sum.windows
    );
}

/// A 2 cm square sheet of `n` × `n` vertices, 1 cm above the origin, in the
/// xy plane (the cloth of the input-checking tests).
fn small_sheet(n: usize) -> TriMesh {
    grid(
        DVec3::new(0.0, 0.0, 0.01),
        DVec3::X,
        DVec3::Y,
        [0.02, 0.02],
        [n, n],
    )
}

#[test]
fn triangle_fired_at_100_m_s_bounces_off_a_fixed_triangle() {
    fire(
        "triangle->triangle",
        big_triangle(),
        0.0,
        small_triangle(0.004),
        100.0,
    );
}

/// A 3x3-vertex cloth (8 triangles, 1 cm), tilted, 1.5–6 mm above a box
/// whose top face is z = 0.
fn grid_bullet() -> (TriMesh, TriMesh) {
    let mut g = grid(
        DVec3::new(0.003, -0.002, 0.003),
        DVec3::new(1.0, 0.0, 0.2).normalize(),
        DVec3::new(0.0, 1.0, -0.1).normalize(),
        [0.01, 0.01],
        [3, 3],
    );
    for p in &mut g.positions {
        p.z += 0.0015;
    }
    let target = cuboid(DVec3::new(-0.1, -0.1, -0.05), DVec3::new(0.1, 0.1, 0.0));
    (target, g)
}

/// A 100 m/s impact with the default 5 layers per detection: the first
/// contact window needs a depth of about 100, and its speculative passes
/// with too few layers push the cloth through and blow up. A blown-up pass
/// is a detection like any other (the stencils near the blow-up get more
/// layers, bounded by the rollback cap), so the run must go on to the end:
/// every window commits with every invariant held, nothing goes through the
/// box, and the cloth bounces.
#[test]
fn grid_fired_at_100_m_s_with_default_layers_never_tunnels() {
    let (target, g) = grid_bullet();
    let spec = bullet_scene(target, g, 100.0);
    let mut e = engine(&spec);
    let cloth = object_vertices(&e, 1);
    let sum = run_checked(&mut e, 15, |e, _| {
        for i in cloth.clone() {
            assert!(e.world.x[i].z > 0.0, "vertex {i} went through the box");
        }
    });
    print_summary("grid->box (L = 5)", &e, &sum);
    let vz: f64 = cloth.clone().map(|i| e.world.v[i].z).sum::<f64>() / cloth.len() as f64;
    println!("grid->box (L = 5): final mean vz {vz:.2} m/s");
    assert!(sum.max_depth >= 20, "depth {}", sum.max_depth);
    assert!(vz > 50.0, "did not bounce: vz = {vz}");
}

/// The 100 m/s impact with prediction on and off: with it, a detected (or
/// predicted) stencil gets as many layers as its closing kinetic energy
/// needs, at least 5, so the impact takes fewer rollbacks than 5 layers per
/// detection; the layers differ, the motion does not (policy independence:
/// positions, velocities and clocks equal bit for bit after every window).
#[test]
fn a_fast_impact_gets_its_layers_from_its_closing_energy() {
    let (target, g) = grid_bullet();
    let run = |predict: bool| {
        let mut spec = bullet_scene(target.clone(), g.clone(), 100.0);
        spec.contact.predict = predict;
        let mut e = engine(&spec);
        let mut states = Vec::new();
        let sum = run_checked(&mut e, 15, |e, _| {
            states.push((e.world.x.clone(), e.world.v.clone(), e.world.tau.clone()))
        });
        print_summary(&format!("grid->box (predict {predict})"), &e, &sum);
        (sum.rollbacks, sum.max_depth, states)
    };
    let (rollbacks_on, depth_on, on) = run(true);
    let (rollbacks_off, depth_off, off) = run(false);
    assert!(depth_on >= 20 && depth_off >= 20, "{depth_on} {depth_off}");
    // Measured: 7 against 27 (prediction alone, 5 layers a time: 25).
    assert!(
        2 * rollbacks_on <= rollbacks_off,
        "{rollbacks_on} rollbacks with the energy count, {rollbacks_off} without"
    );
    assert!(on == off, "the layer policy changed the motion");
}

/// The same impact with room for only 4 rollbacks and 5 layers per
/// detection (prediction off: with it, the energy count gives the impact
/// its layers in fewer rollbacks, see
/// `a_fast_impact_gets_its_layers_from_its_closing_energy`): its passes
/// blow up, and past the cap the error names the stencil, says that passes
/// blew up and advises more layers per detection — not a smaller internal
/// step — with the world back at the window start.
#[test]
fn blown_up_passes_past_the_rollback_cap_name_the_stencil() {
    let (target, g) = grid_bullet();
    let mut spec = bullet_scene(target, g, 100.0);
    spec.contact.max_rollbacks = 4;
    spec.contact.predict = false;
    let mut e = engine(&spec);
    for _ in 0..5 {
        let x = e.world.x.clone();
        match e.step_window() {
            Ok(_) => continue,
            Err(err) => {
                let msg = err.to_string();
                println!("{msg}");
                let SimError::RollbackCap { blown_up, pair, .. } = err else {
                    panic!("wrong error: {msg}")
                };
                assert!(blown_up >= 1, "{msg}");
                assert!(pair.contains("bullet #"), "{pair}");
                assert!(msg.contains("blew up") && msg.contains("contact.layers_per_detection"));
                assert_eq!(e.world.x, x, "x is not the window start state");
                return;
            }
        }
    }
    panic!("4 rollbacks were enough for a 100 m/s impact with 5 layers per detection");
}

/// The same 100 m/s impact as `grid_fired_at_100_m_s_with_default_layers_never_tunnels`, with
/// 20 layers per detection instead of 5: it commits every window (the first
/// one at depth ~100), bounces and keeps every invariant, with fewer
/// rollbacks than the default.
#[test]
fn grid_fired_at_100_m_s_with_20_layers_per_detection_bounces() {
    let (target, g) = grid_bullet();
    let mut spec = bullet_scene(target, g, 100.0);
    spec.contact.layers_per_detection = 20;
    let mut e = engine(&spec);
    let cloth = object_vertices(&e, 1);
    let sum = run_checked(&mut e, 15, |e, _| {
        for i in cloth.clone() {
            assert!(e.world.x[i].z > 0.0, "vertex {i} went through the box");
        }
    });
    print_summary("grid->box (L = 20)", &e, &sum);
    let vz: f64 = cloth.clone().map(|i| e.world.v[i].z).sum::<f64>() / cloth.len() as f64;
    println!("grid->box (L = 20): final mean vz {vz:.2} m/s");
    assert!(sum.rollbacks >= 1 && sum.max_depth >= 1);
    assert!(vz > 50.0, "did not bounce: vz = {vz}");
}

/// Height of the surface of `mesh` (a graph over xy) under `p`, if any.
fn height_under(x: &[DVec3], triangles: &[[u32; 3]], p: DVec3) -> Option<f64> {
    for t in triangles {
        let [a, b, c] = t.map(|i| x[i as usize]);
        let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if det.abs() < 1e-18 {
            continue;
        }
        let u = ((p.x - a.x) * (c.y - a.y) - (c.x - a.x) * (p.y - a.y)) / det;
        let v = ((b.x - a.x) * (p.y - a.y) - (p.x - a.x) * (b.y - a.y)) / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
            return Some(a.z + u * (b.z - a.z) + v * (c.z - a.z));
        }
    }
    None
}

#[test]
fn sheet_dropped_at_12_m_s_on_a_pinned_sheet_does_not_cross() {
    // Lower sheet: 6x6 vertices, 10 cm, border pinned. Upper sheet: 5x5
    // vertices, 7 cm, rotated, 3 mm above, falling at 12 m/s.
    let lower = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [0.10, 0.10], [6, 6]);
    let rot = 0.3f64;
    let upper = grid(
        DVec3::new(0.004, -0.003, 0.003),
        DVec3::new(rot.cos(), rot.sin(), 0.0),
        DVec3::new(-rot.sin(), rot.cos(), 0.0),
        [0.07, 0.07],
        [5, 5],
    );
    let border: Vec<u32> = (0..36u32)
        .filter(|&i| {
            let (u, v) = (i % 6, i / 6);
            u == 0 || v == 0 || u == 5 || v == 5
        })
        .collect();
    let mut s = spec(
        vec![
            cloth("lower", lower, DVec3::ZERO),
            cloth("upper", upper, DVec3::new(0.0, 0.0, -12.0)),
        ],
        DVec3::ZERO,
        10,
    );
    s.pins.push(PinSpec {
        name: "border".into(),
        object: 0,
        vertices: border,
        motion: Motion::Fixed,
    });
    let mut e = engine(&s);
    let low = object_vertices(&e, 0);
    let up = object_vertices(&e, 1);
    let low_tris: Vec<[u32; 3]> = e.world.triangles
        [e.world.objects[0].triangles.start as usize..e.world.objects[0].triangles.end as usize]
        .to_vec();
    let mut checked_heights = 0usize;
    let sum = run_checked(&mut e, 12, |e, st| {
        println!(
            "  window {} rollbacks {} depth {} wall {:.2}s kicks {} cand {}",
            st.stats.window,
            st.stats.rollbacks,
            st.stats.max_depth,
            st.timing.wall_seconds,
            st.stats.layer_kicks,
            st.stats.candidates
        );
        for i in up.clone() {
            let p = e.world.x[i];
            if let Some(h) = height_under(&e.world.x, &low_tris, p) {
                checked_heights += 1;
                assert!(
                    p.z > h,
                    "upper vertex {i} crossed the lower sheet: z = {} below surface {h}",
                    p.z
                );
            }
        }
    });
    print_summary("sheet->pinned sheet", &e, &sum);
    let vz: f64 = up.clone().map(|i| e.world.v[i].z).sum::<f64>() / up.len() as f64;
    let low_min = low
        .clone()
        .map(|i| e.world.x[i].z)
        .fold(f64::INFINITY, f64::min);
    println!(
        "sheet->pinned sheet: final mean vz of the upper sheet {vz:.3} m/s, lowest lower-sheet z {low_min:.4e}, {checked_heights} height checks"
    );
    assert!(
        sum.rollbacks >= 1 && sum.max_depth >= 1,
        "no contact happened"
    );
    assert!(checked_heights > 0);
}

#[test]
fn cloth_resting_on_a_sphere_stays_outside_for_40_windows() {
    let r = 0.1;
    let ball = sphere(DVec3::ZERO, r, 2);
    let sheet = grid(
        DVec3::new(0.003, 0.002, r + 0.003),
        DVec3::X,
        DVec3::Y,
        [0.16, 0.16],
        [9, 9],
    );
    let s = spec(
        vec![
            obstacle("ball", ball.clone()),
            cloth("sheet", sheet, DVec3::new(0.0, 0.0, -0.5)),
        ],
        DVec3::new(0.0, 0.0, -9.81),
        50,
    );
    let mut e = engine(&s);
    let sheet_v = object_vertices(&e, 1);
    // Outside the convex tessellated ball: in front of some face plane.
    let faces: Vec<(DVec3, DVec3)> = ball
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| ball.positions[i as usize]);
            (a, (b - a).cross(c - a).normalize())
        })
        .collect();
    let mut depth_seen = 0;
    let sum = run_checked(&mut e, 40, |e, st| {
        depth_seen = depth_seen.max(st.stats.max_depth);
        for i in sheet_v.clone() {
            let p = e.world.x[i];
            let out = faces
                .iter()
                .map(|(a, n)| (p - *a).dot(*n))
                .fold(f64::NEG_INFINITY, f64::max);
            assert!(out > 0.0, "sheet vertex {i} is inside the ball: {p:?}");
        }
    });
    print_summary("cloth on sphere", &e, &sum);
    let zc: f64 = sheet_v.clone().map(|i| e.world.x[i].z).sum::<f64>() / sheet_v.len() as f64;
    println!(
        "cloth on sphere: mean sheet z {zc:.4}, active stencils {}",
        e.world.layers.stencils.len()
    );
    assert!(sum.rollbacks >= 1 && depth_seen >= 1, "no contact happened");
    assert!(zc > 0.0, "the sheet slid off the top of the ball");
}

/// Regression (failed on the committed `edge_edge`, passes with the working
/// tree's fix): `weft_geom::distance::edge_edge` underestimated the distance
/// of nearly parallel segments. With `|m|^2 <= 1e-8 |e|^2 |f|^2` the interior
/// candidate (infinite lines' distance `|r.m|/|m|`, with ill-conditioned
/// `s, t` that land in [0, 1]) was compared with the endpoint candidates and
/// "the smaller wins" — but the lines' distance is always the smaller, and for
/// parallel lines it is meaningless. Segments 5e-4 m apart came out as
/// 3.4e-7 m (6% of random parallel pairs underestimated); two coplanar
/// diagonals of one grid, 4 cm apart, as exactly 0.
#[test]
fn edge_edge_distance_of_parallel_edges_is_not_underestimated() {
    use weft_geom::distance::edge_edge;
    // Two parallel diagonals of one grid, 2.8 cm apart (closest: p1, q0 4 cm).
    let (p0, p1) = (DVec3::new(-0.06, -0.06, 0.0), DVec3::new(-0.04, -0.04, 0.0));
    let (q0, q1) = (
        DVec3::new(0.0, -0.04, 0.0),
        DVec3::new(0.019999999999999993, -0.02, 0.0),
    );
    let reference = ref_edge_edge(p0, p1, q0, q1);
    let got = edge_edge(p0, p1, q0, q1);
    println!(
        "coplanar parallel diagonals: edge_edge d = {:e}, reference {reference:e}, {got:?}",
        got.d
    );
    let mut rng = Rng(7);
    let (mut bad, mut worst) = (0usize, f64::INFINITY);
    let n = 20000;
    for _ in 0..n {
        let a = rng.vec(0.1);
        let dir = rng.vec(1.0).normalize() * rng.uniform(0.005, 0.03);
        let nrm = rng.vec(1.0).cross(dir).normalize();
        let off = dir.cross(nrm).normalize() * 5e-4;
        let shift = dir * rng.uniform(-0.5, 0.5);
        let c = edge_edge(a, a + dir, a + off + shift, a + off + shift + dir);
        let r = ref_edge_edge(a, a + dir, a + off + shift, a + off + shift + dir);
        assert!((r - 5e-4).abs() < 1e-12, "reference {r}");
        if c.d < 0.999 * r {
            bad += 1;
            worst = worst.min(c.d);
        }
    }
    println!("parallel segments 5e-4 m apart: {bad} of {n} underestimated, smallest d {worst:e}");
    assert!(
        (got.d - reference).abs() <= 1e-9,
        "edge_edge says {:e} for segments {reference:e} apart",
        got.d
    );
    assert_eq!(
        bad, 0,
        "{bad} of {n} parallel pairs underestimated (smallest {worst:e} for 5e-4)"
    );
}

/// Regression, the consequence of the one above at setup: two cloth triangles
/// with parallel edges 0.5 mm apart (eta_inf = 0.1 mm) were refused as an
/// initial contact "2.576e-5 m apart".
#[test]
fn parallel_edges_half_a_millimetre_apart_are_not_refused_as_initial_contact() {
    let p0 = DVec3::new(
        0.08015890527807326,
        0.08710534787499227,
        0.04142264763834752,
    );
    let p1 = DVec3::new(0.09708641219086754, 0.07686795372958617, 0.0502282036927804);
    let q0 = DVec3::new(
        0.07386917481825331,
        0.09100605154435297,
        0.03866821187568923,
    );
    let q1 = DVec3::new(
        0.09079668173104759,
        0.08076865739894687,
        0.047473767930122104,
    );
    let gap = ref_edge_edge(p0, p1, q0, q1);
    assert!((gap - 5e-4).abs() < 1e-9, "construction: {gap}");
    // Third corners 1 cm away on opposite sides, in the plane of the edges.
    let dir = (p1 - p0).normalize();
    let r = q0 - p0;
    let side = (r - dir * r.dot(dir)).normalize();
    let a = TriMesh::new(vec![p0, p1, (p0 + p1) * 0.5 - side * 0.01], vec![[0, 1, 2]]);
    let b = TriMesh::new(vec![q0, q1, (q0 + q1) * 0.5 + side * 0.01], vec![[0, 1, 2]]);
    let s = two_objects_spec(cloth("a", a, DVec3::ZERO), cloth("b", b, DVec3::ZERO));
    let world = World::build(&s).unwrap();
    let floor = world.schedule.eta_inf;
    // Brute force: every stencil is farther than the floor.
    let min = all_stencils(&world.triangles, &world.inv_mass)
        .iter()
        .map(|k| ref_distance(k.kind, &k.v.map(|i| world.x[i as usize])))
        .fold(f64::INFINITY, f64::min);
    assert!(
        min > 4.9e-4 && min > floor,
        "construction: min distance {min}"
    );
    if let Err(e) = Engine::new(world, Serial) {
        panic!("a valid scene (closest stencil {min:e} m apart, floor {floor:e}) was refused: {e}");
    }
}

/// Regression, the same bug inside a run: two identical 5x5 sheets stacked
/// 0.5 mm apart (inside eta_1 = 1 mm, above the floor 0.1 mm). Before the
/// `edge_edge` fix window 0 committed with `WindowStats::min_separation =
/// Some(0.0)`: layer events computed d = 0 for separated inter-sheet EE
/// stencils (and kicked with it), while the brute-force check at every window
/// end was clean.
#[test]
fn stacked_parallel_sheets_never_report_a_separation_below_the_floor() {
    let lower = grid(
        DVec3::new(0.01, 0.02, 0.3),
        DVec3::X,
        DVec3::Y,
        [0.07, 0.07],
        [5, 5],
    );
    let mut upper = lower.clone();
    for p in &mut upper.positions {
        p.z += 5e-4;
    }
    let s = two_objects_spec(
        cloth("lower", lower, DVec3::ZERO),
        cloth("upper", upper, DVec3::ZERO),
    );
    let mut e = engine(&s);
    let sum = run_checked(&mut e, 3, |_, CommittedWindow { stats: st, .. }| {
        println!(
            "  window {}: rollbacks {} depth {} min separation {:?}",
            st.window, st.rollbacks, st.max_depth, st.min_separation
        );
    });
    print_summary("stacked sheets", &e, &sum);
}

/// A `TrajectoryBudget` error in the middle of a window leaves the world at
/// the window start, like `RollbackCap` (it once left some `x`, `tau`
/// advanced, and a second `step_window` underflowed `t - tau`), and a
/// second `step_window` fails the same way without a panic.
#[test]
fn trajectory_budget_error_keeps_the_window_start_state() {
    let mut s = bullet_scene(big_triangle(), small_triangle(0.004), 1.0);
    // 6 start points + 3 dynamic vertices per internal step: fails at step 6.
    s.limits.trajectory_budget_bytes = (6 + 3 * 5 + 1) * 32;
    let mut e = Engine::new(World::build(&s).unwrap(), Serial).unwrap();
    let (x, v, tau, tick) = (
        e.world.x.clone(),
        e.world.v.clone(),
        e.world.tau.clone(),
        e.world.tick,
    );
    let err = e.step_window().expect_err("budget too small");
    assert!(matches!(err, SimError::TrajectoryBudget { .. }), "{err}");
    println!(
        "{err}; tau after the error: {:?}, tick {}",
        e.world.tau, e.world.tick
    );
    let retry =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| e.step_window().map(|_| ())));
    match &retry {
        Err(_) => println!("retrying step_window panicked"),
        Ok(r) => println!("retry: {:?}", r.as_ref().err()),
    }
    assert_eq!(
        (e.world.tick, &e.world.tau),
        (tick, &tau),
        "tau is not the window start state"
    );
    assert_eq!(e.world.x, x, "x is not the window start state");
    assert_eq!(e.world.v, v, "v is not the window start state");
    assert!(
        retry.is_ok(),
        "step_window panicked after a TrajectoryBudget error"
    );
}

// ------------------------------------------------- 3. broad phase vs brute force

/// One random scene for the broad-phase comparison.
struct BroadScene {
    triangles: Vec<[u32; 3]>,
    inv_mass: Vec<f64>,
    /// Per vertex: (tick relative to t0, position), strictly increasing ticks,
    /// the first at 0 and the last at the window end.
    paths: Vec<Vec<(u64, DVec3)>>,
}

const T0: u64 = 3 << 30;
const WINDOW: u64 = 1 << 24;

fn random_paths(rng: &mut Rng, x: &[DVec3], step: f64) -> Vec<Vec<(u64, DVec3)>> {
    x.iter()
        .map(|&p0| {
            let k = rng.below(5) as usize; // 0..4 interior breakpoints
            let mut ticks: Vec<u64> = (0..k).map(|_| 1 + rng.below(WINDOW - 1)).collect();
            ticks.sort_unstable();
            ticks.dedup();
            let mut path = vec![(0, p0)];
            let mut p = p0;
            let vel = rng.vec(step);
            for t in ticks.into_iter().chain([WINDOW]) {
                p += vel + rng.vec(step);
                path.push((t, p));
            }
            path
        })
        .collect()
}

fn soup_scene(rng: &mut Rng, eta: f64) -> BroadScene {
    let ntri = 10;
    let mut x = Vec::new();
    let mut triangles = Vec::new();
    for f in 0..ntri {
        let c = rng.vec(4.0 * eta);
        let base = x.len() as u32;
        for _ in 0..3 {
            x.push(c + rng.vec(3.0 * eta));
        }
        triangles.push([base, base + 1, base + 2]);
        // Some triangles share an edge or a vertex with the previous one.
        if f > 0 && rng.below(3) == 0 {
            let prev = triangles[f - 1];
            let q = x.len() as u32;
            x.push(c + rng.vec(3.0 * eta));
            triangles.push([prev[0], prev[1], q]);
        }
    }
    let inv_mass = (0..x.len())
        .map(|_| if rng.below(4) == 0 { 0.0 } else { 1.0 })
        .collect();
    let paths = random_paths(rng, &x, eta);
    BroadScene {
        triangles,
        inv_mass,
        paths,
    }
}

fn grid_scene(rng: &mut Rng, eta: f64) -> BroadScene {
    // Two 4x4 grids with spacing ~3 eta, one above the other, folded and
    // perturbed; boundary and corner vertices included.
    let a = grid(
        DVec3::ZERO,
        DVec3::X,
        DVec3::Y,
        [9.0 * eta, 9.0 * eta],
        [4, 4],
    );
    let b = grid(
        DVec3::new(0.5 * eta, 0.3 * eta, 1.2 * eta),
        DVec3::new(1.0, 0.2, 0.0).normalize(),
        DVec3::new(-0.2, 1.0, 0.3).normalize(),
        [9.0 * eta, 9.0 * eta],
        [4, 4],
    );
    let mut m = TriMesh::default();
    m.append(&a);
    m.append(&b);
    let x: Vec<DVec3> = m
        .positions
        .iter()
        .map(|&p| p + rng.vec(0.4 * eta))
        .collect();
    let inv_mass = (0..x.len())
        .map(|i| if i < 4 && rng.below(2) == 0 { 0.0 } else { 1.0 })
        .collect();
    let paths = random_paths(rng, &x, 0.7 * eta);
    BroadScene {
        triangles: m.triangles,
        inv_mass,
        paths,
    }
}

fn position_at(path: &[(u64, DVec3)], t: f64) -> DVec3 {
    let k = path.partition_point(|&(s, _)| (s as f64) <= t);
    if k == 0 {
        return path[0].1;
    }
    if k >= path.len() {
        return path[path.len() - 1].1;
    }
    let (ta, pa) = path[k - 1];
    let (tb, pb) = path[k];
    let a = (t - ta as f64) / (tb - ta) as f64;
    pa + (pb - pa) * a
}

/// Smallest sampled distance of a stencil over the window: at every breakpoint
/// of its vertices and `per_segment` uniform samples between consecutive ones.
/// Sampling can only under-report closeness.
fn sampled_min_distance(scene: &BroadScene, key: &StencilKey, per_segment: usize) -> f64 {
    let mut times: Vec<u64> = key
        .v
        .iter()
        .flat_map(|&i| scene.paths[i as usize].iter().map(|&(t, _)| t))
        .collect();
    times.sort_unstable();
    times.dedup();
    let mut best = f64::INFINITY;
    for w in times.windows(2) {
        for s in 0..per_segment {
            let t = w[0] as f64 + (w[1] - w[0]) as f64 * s as f64 / per_segment as f64;
            let x = key.v.map(|i| position_at(&scene.paths[i as usize], t));
            best = best.min(stencil_closest(key.kind, &x).d);
        }
    }
    let x = key
        .v
        .map(|i| position_at(&scene.paths[i as usize], WINDOW as f64));
    best.min(stencil_closest(key.kind, &x).d)
}

#[test]
fn broad_phase_finds_every_stencil_a_brute_force_search_finds() {
    let eta = 1e-3;
    let mut rng = Rng(0x5EED_CAFE);
    let (mut total_brute, mut total_cand, mut scenes) = (0usize, 0usize, 0usize);
    for round in 0..40 {
        let scene = if round % 2 == 0 {
            soup_scene(&mut rng, eta)
        } else {
            grid_scene(&mut rng, eta)
        };
        let n = scene.inv_mass.len();
        let x0: Vec<DVec3> = scene.paths.iter().map(|p| p[0].1).collect();
        let mut traj = Trajectories::new(n, usize::MAX);
        traj.begin(T0, &x0);
        for (i, path) in scene.paths.iter().enumerate() {
            for &(t, p) in &path[1..] {
                traj.record(i, T0 + t, p).expect("budget");
            }
        }
        // The recorded trajectories are the paths (ticks relative to T0).
        for (i, path) in scene.paths.iter().enumerate() {
            let tr: Trajectory<'_> = traj.of(i);
            assert_eq!(tr.times.len(), path.len());
            for (k, &(t, p)) in path.iter().enumerate() {
                assert_eq!(tr.times[k], t as f64);
                assert_eq!(tr.points[k], p);
            }
        }
        let mut broad = BroadPhase::default();
        let cand = broad.candidates(&scene.triangles, &scene.inv_mass, &traj, 0.5 * eta);
        let cand_set: BTreeSet<StencilKey> = cand.iter().copied().collect();
        assert_eq!(cand_set.len(), cand.len(), "duplicate candidates");
        for k in &cand {
            assert!(!k.shares_vertex(), "candidate {k:?} shares a vertex");
            assert!(
                k.v.iter().any(|&i| scene.inv_mass[i as usize] > 0.0),
                "candidate {k:?} is all-kinematic"
            );
        }
        let all = all_stencils(&scene.triangles, &scene.inv_mass);
        let mut brute = 0;
        let mut missed = Vec::new();
        for key in &all {
            let d = sampled_min_distance(&scene, key, 48);
            if d <= eta {
                brute += 1;
                if !cand_set.contains(key) {
                    missed.push((*key, d));
                }
            }
        }
        assert!(
            missed.is_empty(),
            "round {round}: the broad phase missed {} of {brute} stencils that come within eta_1 = {eta}: {:?}",
            missed.len(),
            &missed[..missed.len().min(10)]
        );
        // Every candidate is a real stencil of the mesh.
        let all_set: BTreeSet<StencilKey> = all.iter().copied().collect();
        assert!(
            cand.iter().all(|k| all_set.contains(k)),
            "candidate outside the stencil set"
        );
        total_brute += brute;
        total_cand += cand.len();
        scenes += 1;
    }
    println!(
        "broad phase: {scenes} scenes, {total_brute} stencils within eta_1 (sampled), {total_cand} candidates, \
         false-positive ratio {:.3}",
        (total_cand - total_brute.min(total_cand)) as f64 / total_cand.max(1) as f64
    );
    assert!(
        total_brute > 100,
        "the scenes are too sparse to test anything"
    );
}

/// A stencil whose primitives come within eta_1 only between breakpoints, at a
/// sliver of the window, along a direction that is none of the 13 DOP axes.
#[test]
fn broad_phase_finds_a_brief_oblique_near_miss() {
    let eta = 1e-3;
    for (case, gap) in [(0, 0.999 * eta), (1, eta * (1.0 - 1e-9)), (2, 0.0)] {
        // Edge A along an oblique direction, fixed; edge B sweeps across it.
        let dir = DVec3::new(1.0, 2.0, 3.0).normalize();
        let perp = dir.cross(DVec3::new(0.3, -0.7, 0.2)).normalize();
        let side = dir.cross(perp);
        let x = vec![
            -dir * 0.01,
            dir * 0.01,
            DVec3::ZERO, // apex of the fixed triangle
            perp * gap - side * 0.01 + dir * 0.02,
            perp * gap + side * 0.01 - dir * 0.02,
            perp * 0.5 + dir * 0.03,
        ];
        let triangles = vec![[0, 1, 2], [3, 4, 5]];
        // Move the apex away so only the edges come close; triangle B sweeps
        // along `side` from far away to far away, passing edge A at `gap`.
        let mut x = x;
        x[2] = -perp * 0.01;
        let n = x.len();
        let inv_mass = vec![1.0; n];
        let sweep = side * 0.5;
        let mut traj = Trajectories::new(n, usize::MAX);
        let x0: Vec<DVec3> = x
            .iter()
            .enumerate()
            .map(|(i, &p)| if i >= 3 { p - sweep } else { p })
            .collect();
        traj.begin(T0, &x0);
        for i in 0..n {
            let p = if i >= 3 { x[i] + sweep } else { x[i] };
            traj.record(i, T0 + WINDOW, p).unwrap();
        }
        let key = StencilKey::edge_edge([0, 1], [3, 4]);
        let mid = key.v.map(|i| x[i as usize]);
        let d_mid = stencil_closest(StencilKind::EdgeEdge, &mid).d;
        assert!(d_mid <= eta, "case {case}: construction: d = {d_mid}");
        let cand = BroadPhase::default().candidates(&triangles, &inv_mass, &traj, 0.5 * eta);
        assert!(
            cand.contains(&key),
            "case {case}: EE stencil passing at {d_mid:e} <= eta_1 not a candidate: {cand:?}"
        );
    }
}

// ------------------------------------------------- 4. bad input

fn two_objects_spec(a: ObjectSpec, b: ObjectSpec) -> WorldSpec {
    spec(vec![a, b], DVec3::ZERO, 10)
}

#[test]
fn initially_intersecting_triangles_are_refused_by_name() {
    // A small vertical cloth triangle piercing the middle of a large obstacle
    // triangle: no VF or EE stencil is close, only the faces intersect.
    let pierce = TriMesh::new(
        vec![
            DVec3::new(-0.01, 0.0, -0.005),
            DVec3::new(0.01, 0.0, -0.005),
            DVec3::new(0.0, 0.0, 0.006),
        ],
        vec![[0, 1, 2]],
    );
    let mut ground = big_triangle();
    // Put the obstacle triangle second in a 2-triangle mesh to check indices.
    ground.positions.push(DVec3::new(3.0, 3.0, 1.0));
    ground.triangles.insert(0, [1, 3, 2]);
    let s = two_objects_spec(
        cloth("flag", pierce, DVec3::ZERO),
        obstacle("floor", ground),
    );
    let world = World::build(&s).expect("builds");
    match Engine::new(world, Serial) {
        Err(SimError::InitialIntersection { a, b }) => {
            let mut names = [(a.object.clone(), a.local), (b.object.clone(), b.local)];
            names.sort();
            assert_eq!(names, [("flag".to_string(), 0), ("floor".to_string(), 1)]);
            let msg = SimError::InitialIntersection { a, b }.to_string();
            println!("{msg}");
            assert!(
                msg.contains("flag #0") && msg.contains("floor #1") && msg.contains("intersect")
            );
        }
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("intersecting triangles accepted"),
    }
}

#[test]
fn primitives_closer_than_the_floor_are_refused_by_name() {
    // A cloth triangle whose vertex 1 is 2e-5 m above an obstacle face
    // (eta_inf = 0.1 * 1e-3 = 1e-4).
    let t = TriMesh::new(
        vec![
            DVec3::new(0.0, 0.0, 0.01),
            DVec3::new(0.001, 0.002, 2e-5),
            DVec3::new(0.01, 0.0, 0.01),
        ],
        vec![[0, 1, 2]],
    );
    let s = two_objects_spec(
        obstacle("floor", big_triangle()),
        cloth("cloth", t, DVec3::ZERO),
    );
    let world = World::build(&s).expect("builds");
    match Engine::new(world, Serial) {
        Err(e @ SimError::InitialContact { .. }) => {
            let msg = e.to_string();
            println!("{msg}");
            let SimError::InitialContact {
                kind,
                key,
                pair,
                distance,
                floor,
            } = e
            else {
                unreachable!()
            };
            assert_eq!(kind, "vertex-face");
            assert_eq!(key, StencilKey::vertex_face(4, [0, 1, 2]));
            assert_eq!(pair, "vertex cloth #1 and triangle floor #0, #1, #2");
            assert!((distance - 2e-5).abs() < 1e-12 && floor == 1e-4);
            assert!(
                msg.contains(&pair) && msg.contains("contact.floor"),
                "{msg}"
            );
            assert!(
                !msg.contains("StencilKey") && !msg.contains("eta_inf"),
                "{msg}"
            );
        }
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("contact closer than the floor accepted"),
    }
    // Edge-edge: two crossing cloth edges 5e-5 apart.
    let a = TriMesh::new(
        vec![
            DVec3::new(-0.01, 0.0, 0.0),
            DVec3::new(0.01, 0.0, 0.0),
            DVec3::new(0.0, -0.01, -0.01),
        ],
        vec![[0, 1, 2]],
    );
    let b = TriMesh::new(
        vec![
            DVec3::new(0.0, -0.01, 5e-5),
            DVec3::new(0.0, 0.01, 5e-5),
            DVec3::new(0.0, 0.0, 0.02),
        ],
        vec![[0, 1, 2]],
    );
    let s = two_objects_spec(cloth("a", a, DVec3::ZERO), cloth("b", b, DVec3::ZERO));
    match Engine::new(World::build(&s).unwrap(), Serial) {
        Err(SimError::InitialContact {
            kind, key, pair, ..
        }) => {
            println!("EE: {kind} {key:?} {pair}");
            assert_eq!(kind, "edge-edge");
            assert_eq!(key, StencilKey::edge_edge([0, 1], [3, 4]));
            assert_eq!(pair, "edge a #0–#1 and edge b #0–#1");
        }
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("EE contact closer than the floor accepted"),
    }
}

#[test]
fn rollback_cap_names_the_stencil_and_keeps_the_window_start() {
    let mut s = bullet_scene(big_triangle(), small_triangle(0.004), 100.0);
    s.contact.max_rollbacks = 1;
    // 5 layers per detection: with prediction's energy count one rollback
    // gives this impact all the layers it needs.
    s.contact.predict = false;
    let world = World::build(&s).unwrap();
    let mut e = Engine::new(world, Serial).unwrap();
    for w in 0..40 {
        let (x, v, tau, tick) = (
            e.world.x.clone(),
            e.world.v.clone(),
            e.world.tau.clone(),
            e.world.tick,
        );
        let layers = e.world.layers.clone();
        match e.step_window() {
            Ok(CommittedWindow { stats: st, .. }) => {
                assert!(st.rollbacks <= 1, "window {w}: {} rollbacks", st.rollbacks)
            }
            Err(err) => {
                let msg = err.to_string();
                println!("window {w}: {msg}");
                let SimError::RollbackCap {
                    cap,
                    key,
                    pair,
                    depth,
                    kind,
                    ..
                } = err
                else {
                    panic!("wrong error: {msg}")
                };
                assert_eq!(cap, 1);
                // The stencil involves the bullet (vertices 3..6) and the target.
                assert!(key.v.iter().any(|&i| i >= 3), "{key:?}");
                assert!(pair.contains("bullet #"), "{pair}");
                assert!(msg.contains(&pair) && !msg.contains("StencilKey"), "{msg}");
                assert!(depth >= 2, "the error names the depth reached: {depth}");
                assert_eq!(
                    e.world.layers, layers,
                    "the active layers are the committed ones (a checkpoint of this state \
                     resumes bit-identically)"
                );
                assert!(msg.contains("max_rollbacks"), "{msg}");
                assert!(kind == "vertex-face" || kind == "edge-edge");
                assert_eq!(e.world.x, x, "x is not the window start state");
                assert_eq!(e.world.v, v, "v is not the window start state");
                assert_eq!(e.world.tau, tau, "tau is not the window start state");
                assert_eq!(e.world.tick, tick);
                return;
            }
        }
    }
    panic!("a 100 m/s impact never needed more than one rollback");
}

#[test]
fn too_small_trajectory_budget_is_reported() {
    let mut s = bullet_scene(big_triangle(), small_triangle(0.004), 1.0);
    // 6 vertices: the start points alone fill 6 breakpoints of 32 bytes.
    s.limits.trajectory_budget_bytes = 7 * 32;
    let world = World::build(&s).unwrap();
    let mut e = Engine::new(world, Serial).unwrap();
    match e.step_window() {
        Err(err @ SimError::TrajectoryBudget { .. }) => {
            let msg = err.to_string();
            println!("{msg}");
            let SimError::TrajectoryBudget {
                breakpoints,
                budget_bytes,
                ..
            } = err
            else {
                unreachable!()
            };
            assert_eq!(budget_bytes, 224);
            assert!(breakpoints * 32 > budget_bytes);
            assert!(msg.contains("trajectory_budget_bytes"));
        }
        Err(err) => panic!("wrong error: {err}"),
        Ok(_) => panic!("a budget of 7 breakpoints was enough for a window"),
    }
}

/// A budget error can stop a window in the middle of a penalty-only batch
/// (its breakpoints are recorded one vertex at a time). Whatever batch it
/// stops, no impulse of it may survive: after the budget is raised, the
/// same engine steps on to exactly the bits of an engine that never hit the
/// budget. Every budget between the first contact window's start points
/// and its full trajectory is tried, so some stop a penalty-only batch with
/// touched vertices still to apply (with friction on, so a stale friction
/// impulse would show too).
#[test]
fn a_budget_error_leaves_no_stale_impulse_behind() {
    let (target, g) = grid_bullet();
    let mut s = bullet_scene(target, g, 0.5);
    s.contact.friction = 0.5;
    // Layer 1 on an 8× finer clock: penalty-only batches between internal
    // ticks, from the first tick of a window on.
    s.contact.layer1_step_shift = 3;
    s.objects[1] = {
        let mut o = s.objects[1].clone();
        if let ObjectKind::Cloth { velocity, .. } = &mut o.kind {
            for (k, v) in velocity.iter_mut().enumerate() {
                v.x += 0.3 * k as f64; // sliding: friction acts
            }
        }
        o
    };
    let windows = 8;
    let mut reference = engine(&s);
    let mut needed = 0;
    let mut kicked = 0;
    let mut states = Vec::new();
    for _ in 0..windows {
        let st = reference.step_window().unwrap().stats;
        kicked += st.layer_kicks;
        println!(
            "window {}: depth {:?}, {} breakpoints, {} rollbacks, {} layer events",
            st.window, st.depth_histogram, st.breakpoints, st.rollbacks, st.layer_events
        );
        needed = needed.max(st.breakpoints as usize);
        states.push((reference.world.x.clone(), reference.world.v.clone()));
    }
    // Contact: layers kicked (with layer prediction on, none needs a rollback).
    assert!(kicked > 0, "no contact");
    let (mut stopped, mut tried) = (0, 0);
    for budget in (7..needed).step_by(1.max(needed / 400)) {
        let mut e = engine(&s);
        e.set_trajectory_budget(budget * 32);
        let mut hit = false;
        for (w, state) in states.iter().enumerate() {
            match e.step_window() {
                Ok(_) => {}
                Err(SimError::TrajectoryBudget { .. }) => {
                    hit = true;
                    e.set_trajectory_budget(usize::MAX);
                    e.step_window().unwrap();
                }
                Err(other) => panic!("budget {budget}: {other}"),
            }
            assert_eq!(
                (&e.world.x, &e.world.v),
                (&state.0, &state.1),
                "budget {budget} breakpoints: window {w} differs from the unlimited run"
            );
        }
        tried += 1;
        stopped += usize::from(hit);
    }
    println!("{stopped} of {tried} budgets stopped a window; at most {needed} breakpoints");
    assert!(stopped > 50, "{stopped} budgets stopped a window");
}

fn build_err(s: &WorldSpec) -> SimError {
    match World::build(s) {
        Err(e) => e,
        Ok(_) => panic!("bad input accepted"),
    }
}

#[test]
fn non_finite_initial_velocity_is_refused() {
    let g = small_sheet(3);
    let mut c = cloth("shirt", g, DVec3::ZERO);
    if let ObjectKind::Cloth { velocity, .. } = &mut c.kind {
        velocity[4] = DVec3::new(0.0, f64::NAN, 0.0);
    }
    let s = two_objects_spec(obstacle("floor", big_triangle()), c);
    let e = build_err(&s);
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, SimError::Config(_)), "{e:?}");
    assert!(
        msg.contains("shirt") && msg.contains("vertex 4") && msg.contains("not finite"),
        "{msg}"
    );
    // Infinity as well.
    let mut c = cloth("shirt", small_sheet(3), DVec3::ZERO);
    if let ObjectKind::Cloth { velocity, .. } = &mut c.kind {
        velocity[0].x = f64::INFINITY;
    }
    let msg = build_err(&two_objects_spec(obstacle("floor", big_triangle()), c)).to_string();
    assert!(
        msg.contains("vertex 0") && msg.contains("not finite"),
        "{msg}"
    );
}

/// A cloth thrown faster than contact can act on (across the whole scene in
/// one internal step) is refused by name, not left to roll back for hours;
/// one just slow enough to cross the scene in a step still starts.
#[test]
fn unresolvable_initial_speed_is_refused() {
    let with_speed = |speed: f64| {
        let mut c = cloth("shirt", small_sheet(3), DVec3::ZERO);
        if let ObjectKind::Cloth { velocity, .. } = &mut c.kind {
            velocity[7] = DVec3::new(0.0, -speed, 0.0);
        }
        two_objects_spec(obstacle("floor", big_triangle()), c)
    };
    let e = build_err(&with_speed(1e307));
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, SimError::Config(_)), "{e:?}");
    assert!(
        msg.contains("shirt") && msg.contains("vertex 7") && msg.contains("1.000e307 m/s"),
        "{msg}"
    );
    // The limit: the scene's extent (at least 1 m) per internal step.
    let w = World::build(&with_speed(0.0)).expect("a resting cloth starts");
    let h = w.lattice.h_el();
    let (lo, hi) =
        w.x.iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
    let across = (hi - lo).length().max(1.0);
    assert!(World::build(&with_speed(0.99 * across / h)).is_ok());
    assert!(World::build(&with_speed(1.01 * across / h)).is_err());
}

#[test]
fn non_finite_positions_are_refused_as_mesh_errors() {
    for (obj, vertex) in [(0usize, 1usize), (1, 5)] {
        let mut objects = vec![
            obstacle("floor", big_triangle()),
            cloth("shirt", small_sheet(3), DVec3::ZERO),
        ];
        objects[obj].mesh.positions[vertex].z = if obj == 0 {
            f64::NAN
        } else {
            f64::NEG_INFINITY
        };
        let e = build_err(&spec(objects, DVec3::ZERO, 10));
        let msg = e.to_string();
        println!("{msg}");
        match e {
            SimError::Mesh {
                object,
                source:
                    MeshError::NonFiniteCoordinate {
                        vertex: v, axis, ..
                    },
            } => {
                assert_eq!(object, ["floor", "shirt"][obj]);
                assert_eq!((v, axis), (vertex, 'z'));
            }
            other => panic!("wrong error: {other:?}"),
        }
    }
    // A non-finite rest shape.
    let g = small_sheet(3);
    let mut rest = g.positions.clone();
    rest[2].x = f64::NAN;
    let c = ObjectSpec {
        friction: None,
        name: "shirt".into(),
        mesh: g,
        kind: ObjectKind::Cloth {
            material: cloth_material(),
            rest: Some(rest),
            velocity: vec![],
        },
    };
    let msg = build_err(&spec(vec![c], DVec3::ZERO, 10)).to_string();
    println!("{msg}");
    assert!(
        msg.contains("shirt") && msg.contains("vertex 2") && msg.contains("not finite"),
        "{msg}"
    );
}

#[test]
fn non_finite_gravity_is_refused_or_stops_cleanly() {
    let g = small_sheet(3);
    let s = spec(
        vec![cloth("shirt", g, DVec3::ZERO)],
        DVec3::new(0.0, 0.0, f64::NAN),
        10,
    );
    match World::build(&s) {
        Err(e) => println!("gravity NaN refused at build: {e}"),
        Ok(world) => {
            let mut e = Engine::new(world, Serial).expect("no contact");
            match e.step_window() {
                Err(err @ SimError::NonFinite { .. }) => {
                    println!(
                        "gravity NaN accepted by World::build, stopped at the first window: {err}"
                    )
                }
                Err(err) => panic!("wrong error: {err}"),
                Ok(_) => panic!("a NaN gravity ran a window without an error"),
            }
        }
    }
}

#[test]
fn pin_with_an_out_of_range_vertex_is_refused() {
    let g = small_sheet(3);
    let mut s = spec(vec![cloth("shirt", g, DVec3::ZERO)], DVec3::ZERO, 10);
    s.pins.push(PinSpec {
        name: "clip".into(),
        object: 0,
        vertices: vec![0, 9],
        motion: Motion::Fixed,
    });
    let e = build_err(&s);
    let msg = e.to_string();
    println!("{msg}");
    assert!(matches!(e, SimError::Config(_)));
    assert!(
        msg.contains("clip")
            && msg.contains("vertex 9")
            && msg.contains("shirt")
            && msg.contains("out of range"),
        "{msg}"
    );
    // A pin on an object that does not exist, and on an obstacle.
    s.pins[0].vertices = vec![0];
    s.pins[0].object = 3;
    let msg = build_err(&s).to_string();
    assert!(msg.contains("clip") && msg.contains('3'), "{msg}");
    s.objects.push(obstacle("floor", big_triangle()));
    s.pins[0].object = 1;
    let msg = build_err(&s).to_string();
    assert!(msg.contains("clip") && msg.contains("floor"), "{msg}");
}

#[test]
fn degenerate_cloth_triangle_is_refused() {
    // Triangle 1 has collinear corners.
    let m = TriMesh::new(
        vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.01, 0.0, 0.0),
            DVec3::new(0.0, 0.01, 0.0),
            DVec3::new(0.02, 0.0, 0.0),
        ],
        vec![[0, 1, 2], [1, 3, 0]],
    );
    let e = build_err(&spec(vec![cloth("rag", m, DVec3::ZERO)], DVec3::ZERO, 10));
    let msg = e.to_string();
    println!("{msg}");
    match e {
        SimError::Mesh {
            object,
            source: MeshError::DegenerateTriangle { triangle, .. },
        } => assert_eq!((object.as_str(), triangle), ("rag", 1)),
        other => panic!("wrong error: {other:?}"),
    }
    // A valid mesh whose rest shape has a zero-area triangle: triangle 3 is
    // (2, 5, 4); the rest position of vertex 5 (which keeps mass from
    // triangle (4, 5, 8)) goes to the midpoint of edge (2, 4).
    let g = small_sheet(3);
    assert_eq!(g.triangles[3], [2, 5, 4]);
    let mut rest = g.positions.clone();
    rest[5] = (rest[2] + rest[4]) * 0.5;
    let c = ObjectSpec {
        friction: None,
        name: "rag".into(),
        mesh: g.clone(),
        kind: ObjectKind::Cloth {
            material: cloth_material(),
            rest: Some(rest),
            velocity: vec![],
        },
    };
    let e = build_err(&spec(vec![c], DVec3::ZERO, 10));
    let msg = e.to_string();
    println!("{msg}");
    assert!(
        matches!(&e, SimError::Material { object, .. } if object == "rag"),
        "wrong error for a degenerate rest triangle: {e:?}"
    );
    // A degenerate rest triangle whose corner has no other triangle (corner
    // vertex 2 of triangle 2 = (1, 2, 4)): the message must still be about the
    // degenerate triangle, not claim the vertex "belongs to no triangle".
    assert_eq!(g.triangles[2], [1, 2, 4]);
    let mut rest = g.positions.clone();
    rest[2] = (rest[1] + rest[4]) * 0.5;
    let c = ObjectSpec {
        friction: None,
        name: "rag".into(),
        mesh: g,
        kind: ObjectKind::Cloth {
            material: cloth_material(),
            rest: Some(rest),
            velocity: vec![],
        },
    };
    let e = build_err(&spec(vec![c], DVec3::ZERO, 10));
    let msg = e.to_string();
    println!("{msg}");
    assert!(msg.contains("rag"), "{msg}");
    assert!(
        !msg.contains("belongs to no triangle"),
        "misleading diagnosis of a zero-area rest triangle: {msg}"
    );
}

#[test]
fn poisson_ratio_of_one_half_or_more_is_refused() {
    for nu in [0.5, 0.7, f64::NAN] {
        let g = small_sheet(3);
        let mut c = cloth("rubber", g, DVec3::ZERO);
        if let ObjectKind::Cloth { material, .. } = &mut c.kind {
            material.poisson_ratio = nu;
        }
        let e = build_err(&spec(vec![c], DVec3::ZERO, 10));
        let msg = e.to_string();
        println!("{msg}");
        match e {
            SimError::Material {
                object,
                source: MaterialError::InvalidParameter { parameter, .. },
            } => assert_eq!((object.as_str(), parameter), ("rubber", "poisson_ratio")),
            other => panic!("wrong error: {other:?}"),
        }
        assert!(msg.contains("poisson_ratio") && msg.contains("0.5"));
    }
}

/// Two 3×3 cloths side by side; the second ("damped") carries `damping`
/// times the stiffness-proportional damping at the first one's rest limit.
fn two_cloths_damped(damping: [f64; 2]) -> WorldSpec {
    let sheet = |x: f64| {
        grid(
            DVec3::new(x, 0.0, 0.01),
            DVec3::X,
            DVec3::Y,
            [0.02, 0.02],
            [5, 5],
        )
    };
    let mut damped = cloth("damped", sheet(0.05), DVec3::ZERO);
    if let ObjectKind::Cloth { material, .. } = &mut damped.kind {
        material.stretch_damping = damping[0];
        material.bend_damping = damping[1];
    }
    spec(
        vec![cloth("plain", sheet(0.0), DVec3::ZERO), damped],
        DVec3::ZERO,
        10,
    )
}

/// A derived internal step respects the damping's explicit stability limit
/// too: strong damping shortens the step (to half the damped limit) instead
/// of refusing the scene; light damping leaves `beta · 2 / omega_max`.
#[test]
fn derived_internal_step_respects_the_damping_limit() {
    let calm = World::build(&two_cloths_damped([0.0, 0.0])).unwrap();
    assert_eq!(calm.damping_rate, 0.0);
    assert_eq!(calm.lattice.h_el(), 0.3 * 2.0 / calm.omega_max);
    let w = World::build(&two_cloths_damped([1e-3, 1e-9])).unwrap();
    let limit = damping_step_limit(w.omega_max, w.damping_rate);
    println!(
        "h_el {:.4e} s, damped limit {limit:.4e} s, undamped limit {:.4e} s",
        w.lattice.h_el(),
        2.0 / w.omega_max
    );
    assert!(
        0.5 * limit < 0.3 * 2.0 / w.omega_max,
        "the damping must bind"
    );
    assert_eq!(w.lattice.h_el(), 0.5 * limit);
    let light = World::build(&two_cloths_damped([1e-6, 1e-12])).unwrap();
    assert!(light.damping_rate > 0.0);
    assert_eq!(light.lattice.h_el(), 0.3 * 2.0 / light.omega_max);
}

/// A given internal step above the damping limit is refused, naming the
/// cloth, its damping at fault and the largest values that pass at that
/// step — which do pass, while 2 % more does not.
#[test]
fn given_step_with_too_much_damping_names_the_cloth_and_the_values_that_pass() {
    let probe = World::build(&two_cloths_damped([0.0, 0.0])).unwrap();
    let mut s = two_cloths_damped([1e-3, 1e-9]);
    s.time.internal_step = Some(0.9 / probe.omega_max);
    let msg = build_err(&s).to_string();
    println!("{msg}");
    assert!(msg.contains("cloth 'damped'"), "{msg}");
    assert!(msg.contains("mostly its stretch_damping"), "{msg}");
    assert!(!msg.contains("plain"), "{msg}");
    let value = |key: &str| -> f64 {
        let at = msg.find("largest values that pass are").unwrap();
        let rest = &msg[at..];
        let from = rest.find(&format!("{key} = ")).unwrap() + key.len() + 3;
        rest[from..].split(' ').next().unwrap().parse().unwrap()
    };
    let (stretch, bend) = (value("stretch_damping"), value("bend_damping"));
    assert!(stretch > 0.0 && stretch < 1e-3 && bend > 0.0 && bend < 1e-9);
    let mut ok = s.clone();
    ok.objects[1] = two_cloths_damped([stretch, bend]).objects[1].clone();
    World::build(&ok).expect("the suggested values pass");
    let mut over = s.clone();
    over.objects[1] = two_cloths_damped([1.02 * stretch, 1.02 * bend]).objects[1].clone();
    assert!(build_err(&over).to_string().contains("cloth 'damped'"));
}

/// A user-set contact stiffness is checked against the layer stability
/// bound `omega_1 h_1 ≤ 0.1`: the automatic value (the bound) and anything
/// below it build; above it the scene is refused with both numbers.
#[test]
fn contact_stiffness_above_the_layer_stability_bound_is_refused() {
    let sheet = small_sheet(5);
    let mut s = spec(vec![cloth("sheet", sheet, DVec3::ZERO)], DVec3::ZERO, 10);
    let auto = World::build(&s).unwrap().schedule.k_1;
    s.contact.stiffness = Some(auto);
    assert_eq!(World::build(&s).unwrap().schedule.k_1, auto);
    s.contact.stiffness = Some(0.5 * auto);
    assert_eq!(World::build(&s).unwrap().schedule.k_1, 0.5 * auto);
    s.contact.stiffness = Some(4.0 * auto);
    let msg = build_err(&s).to_string();
    println!("{msg}");
    assert!(
        msg.contains("contact.stiffness") && msg.contains("0.200"),
        "{msg}"
    );
    assert!(msg.contains(&format!("{auto:.4e}")), "{msg}");
    // A layer-1 step 4× shorter allows 16× the stiffness.
    s.contact.layer1_step_shift = 2;
    s.contact.stiffness = Some(16.0 * auto);
    World::build(&s).expect("stiffer layer on a shorter step");
}

/// `layer1_step_shift` beyond what the tick lattice resolves (fewer than 100
/// layer steps of at least one tick) is refused, naming the largest shift
/// that works — not silently capped.
#[test]
fn layer1_step_shift_beyond_the_tick_lattice_is_refused() {
    let sheet = small_sheet(5);
    let mut s = spec(vec![cloth("sheet", sheet, DVec3::ZERO)], DVec3::ZERO, 10);
    s.contact.layer1_step_shift = 10;
    let w = World::build(&s).expect("shift 10 resolves 101 layers");
    assert_eq!(w.schedule.h_1, 1 << 10);
    assert!(w.schedule.resolved_depth() >= 100);
    for shift in [11, 16, 20, 21, 64, u32::MAX] {
        s.contact.layer1_step_shift = shift;
        let msg = build_err(&s).to_string();
        assert!(
            msg.contains(&format!("layer1_step_shift = {shift}")) && msg.contains("at most 10"),
            "{msg}"
        );
    }
}

/// A stencil is never given a layer deeper than the lattice resolves (its
/// step would round up to a tick and be unstable), but it does get every
/// layer down to that depth. With layer 1 on a 1,024-tick step (101 layers
/// resolved) and 102 layers per detection, a grid fired at 100 m/s onto a box
/// gets 101 layers at its first detection, which stop it: no error. With a
/// barrier too soft (10^-8 of the automatic stiffness) for 101 layers to stop
/// the grid, a stencil already at layer 101 is reported again: an error
/// naming the stencil and the depth, with the state of the window start.
/// (One internal step per window: a layer-101 stencil ticks about every
/// tick, 2^20 times per step.)
#[test]
fn a_layer_deeper_than_the_lattice_resolves_is_an_error() {
    let (target, g) = grid_bullet();
    let mut spec = bullet_scene(target, g, 100.0);
    spec.contact.layer1_step_shift = 10;
    spec.contact.layers_per_detection = 102;
    spec.time.steps_per_window = 1;
    let mut e = engine(&spec);
    assert_eq!(e.world.schedule.resolved_depth(), 101);
    let mut windows = 0;
    while e.world.layers.max_depth() == 0 {
        e.step_window().expect("101 layers stop the grid");
        windows += 1;
        assert!(windows < 50, "the impact was never detected");
    }
    assert_eq!(e.world.layers.max_depth(), 101);

    spec.contact.stiffness = Some(1e-8 * e.world.schedule.k_1);
    let mut e = engine(&spec);
    for _ in 0..50 {
        let x = e.world.x.clone();
        match e.step_window() {
            Ok(_) => {}
            Err(err @ SimError::LayerTooDeep { .. }) => {
                let msg = err.to_string();
                println!("{msg}");
                assert!(
                    msg.contains("layer 102") && msg.contains("101 layers"),
                    "{msg}"
                );
                assert!(msg.contains("bullet #") && msg.contains("layer1_step_shift"));
                assert_eq!(e.world.x, x);
                return;
            }
            Err(other) => panic!("wrong error: {other}"),
        }
    }
    panic!("the stencil at the deepest resolved layer was never reported again");
}

/// An engine of `s` with its skips, and one evaluating every layer event.
fn with_and_without_skips(s: &WorldSpec) -> (Engine<Serial>, Engine<Serial>) {
    let fast = engine(s);
    let mut full = engine(s);
    full.evaluate_every_layer_event(true);
    (fast, full)
}

/// Steps both a window and asserts the same positions, velocities, clocks,
/// layers, layer events and kicks.
fn same_window(
    fast: &mut Engine<Serial>,
    full: &mut Engine<Serial>,
    what: &str,
) -> (CommittedWindow, CommittedWindow) {
    let a = fast.step_window().unwrap();
    let b = full.step_window().unwrap();
    assert_eq!(fast.world.x, full.world.x, "{what}: positions");
    assert_eq!(fast.world.v, full.world.v, "{what}: velocities");
    assert_eq!(fast.world.tau, full.world.tau, "{what}: clocks");
    assert_eq!(fast.world.layers, full.world.layers, "{what}: layers");
    let counts = |w: &CommittedWindow| (w.stats.layer_events, w.stats.layer_kicks);
    assert_eq!(counts(&a), counts(&b), "{what}: layer events and kicks");
    (a, b)
}

/// Asleep stencils and layer events skipped by a distance bound kick zero,
/// so skipping them leaves the same bits: on random scenes (two small
/// cloths falling at random tilts and speeds onto a sphere and onto each
/// other, friction on or off) the engine with every layer event evaluated
/// exactly and the engine with its skips end every window in the same
/// positions, velocities, clocks and layers — while the skips did skip.
#[test]
fn skipped_layer_events_give_the_bits_of_full_evaluation() {
    let mut rng = Rng(0x5eed);
    let (mut events, mut evaluations, mut kicks) = (0u64, 0u64, 0u64);
    for case in 0..4 {
        let mut objects = vec![obstacle("ball", sphere(DVec3::ZERO, 0.03, 2))];
        for k in 0..2 {
            let tilt = rng.vec(0.15);
            let eu = (DVec3::X + tilt).normalize();
            let ev = (DVec3::Z + rng.vec(0.15)).cross(eu).normalize();
            let centre = DVec3::new(rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01), 0.0)
                + DVec3::Z * (0.045 + 0.02 * k as f64);
            let g = grid(centre, eu, ev, [0.04, 0.04], [6, 6]);
            objects.push(cloth(&format!("cloth{k}"), g, rng.vec(0.5) - DVec3::Z));
        }
        let mut s = spec(objects, DVec3::new(0.0, 0.0, -9.81), 20);
        s.contact.friction = if case % 2 == 0 { 0.0 } else { 0.4 };
        s.contact.layer1_step_shift = (case / 2) as u32;
        let (mut fast, mut full) = with_and_without_skips(&s);
        for w in 0..25 {
            let (a, b) = same_window(&mut fast, &mut full, &format!("case {case}, window {w}"));
            assert!(b.timing.penalty_work.layer_evaluations <= b.stats.layer_events);
            events += a.stats.layer_events;
            evaluations += a.timing.penalty_work.layer_evaluations;
            kicks += a.stats.layer_kicks;
        }
    }
    println!("{events} layer events, {evaluations} evaluated exactly, {kicks} kicks");
    assert!(kicks > 1000, "too little contact: {kicks} kicks");
    assert!(
        2 * evaluations < events,
        "the skips must skip: {evaluations} of {events}"
    );
}

/// A kinematic obstacle's speed caps are kept once for every island
/// (`weft_sim::dormancy::SharedCaps`): when it speeds up, every island
/// watching it must wake its stencils of it. A plate rises slowly under a
/// cloth at rest, so the stencils between them sleep under the plate's
/// slow speed, then it speeds up tenfold at an internal tick: with its
/// skips the engine must end every window with the bits of evaluating
/// every event (without the wake, the sleeping stencils miss their first
/// kicks and this fails).
#[test]
fn a_kinematic_obstacle_that_speeds_up_wakes_the_stencils_asleep_against_it() {
    let mut kicks = 0u64;
    for (slow, fast_at) in [(0.02, 3.0), (0.05, 5.0), (0.1, 7.0)] {
        let plate = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [0.06, 0.06], [6, 6]);
        let sheet = grid(DVec3::Z * 2.5e-3, DVec3::X, DVec3::Y, [0.04, 0.04], [6, 6]);
        let still = vec![
            obstacle("plate", plate.clone()),
            cloth("sheet", sheet.clone(), DVec3::ZERO),
        ];
        let probe = engine(&spec(still, DVec3::ZERO, 20));
        // Frames one window apart, half a window off the windows (a
        // speed-up at a window's start would meet islands built afresh),
        // the speed-up after `fast_at` frames.
        let window = 20.0 * probe.world.lattice.h_el();
        let rise = |k: usize| {
            let windows = k as f64;
            let z = if windows <= fast_at {
                slow * window * windows
            } else {
                slow * window * (fast_at + 10.0 * (windows - fast_at))
            };
            plate.positions.iter().map(|&p| p + DVec3::Z * z).collect()
        };
        let script = Keyframes {
            frame_rate: 1.0 / window,
            start: 0.5 * window,
            frames: (0..40).map(rise).collect(),
        };
        let mut moving = obstacle("plate", plate.clone());
        moving.kind = ObjectKind::Obstacle {
            motion: Motion::Sequence(script),
        };
        let s = spec(
            vec![moving, cloth("sheet", sheet, DVec3::ZERO)],
            DVec3::ZERO,
            20,
        );
        let (mut fast, mut full) = with_and_without_skips(&s);
        for w in 0..16 {
            let what = format!("slow {slow} m/s, faster after {fast_at} windows, window {w}");
            let (a, _) = same_window(&mut fast, &mut full, &what);
            kicks += a.stats.layer_kicks;
        }
    }
    assert!(kicks > 100, "too little contact: {kicks} kicks");
}

/// An island skipped while nothing of it is awake keeps the global
/// schedule's bits and counts. A sheet bounces on a plate (its stencils with
/// the plate asleep in flight, its island skipped at most internal ticks
/// while gravity slows it and speeds it up again); beside it a sheet carried
/// by a rising plate stays in contact, so the one island of the global
/// schedule is visited, and every vertex observed, at nearly every internal
/// tick.
/// Every island alone ends each window in the global schedule's positions,
/// velocities and layers with its counts of layer events, exact evaluations
/// and kicks: a skipped island must leave every speed cap as a visit would
/// (`dormancy::changes_cap`), or its later certificates get other lengths.
#[test]
fn an_island_skipped_in_flight_keeps_the_bits_and_counts_of_the_global_schedule() {
    let plate = |x: f64| grid(DVec3::X * x, DVec3::X, DVec3::Y, [0.06, 0.06], [6, 6]);
    let sheet = |x: f64, z: f64| {
        grid(
            DVec3::new(x, 0.0, z),
            DVec3::X,
            DVec3::Y,
            [0.04, 0.04],
            [6, 6],
        )
    };
    let mut s = spec(
        vec![
            ObjectSpec {
                kind: ObjectKind::Obstacle {
                    motion: Motion::Translate {
                        velocity: DVec3::Z * 0.02,
                        until: None,
                    },
                },
                ..obstacle("lifting plate", plate(0.0))
            },
            cloth("carried", sheet(0.0, 0.95e-3), DVec3::Z * 0.02),
            obstacle("launch plate", plate(0.2)),
            cloth("thrown", sheet(0.2, 3e-3), DVec3::Z * -0.3),
        ],
        DVec3::new(0.0, 0.0, -9.81),
        20,
    );
    // (the thrown sheet's stencils stay active through its flight)
    s.contact.retire_after_windows = 1000;
    let (mut islands, mut global) = (engine(&s), engine(&s));
    islands.set_island_packing(1);
    global.run_as_one_island(true);
    let (mut evaluations, mut most_islands) = (0u64, 0u64);
    for w in 0..120 {
        let a = islands.step_window().unwrap();
        let b = global.step_window().unwrap();
        let what = format!("window {w}");
        assert_eq!(islands.world.x, global.world.x, "{what}: positions");
        assert_eq!(islands.world.v, global.world.v, "{what}: velocities");
        assert_eq!(islands.world.layers, global.world.layers, "{what}: layers");
        let counts = |w: &CommittedWindow| {
            (
                w.stats.layer_events,
                w.timing.penalty_work.layer_evaluations,
                w.stats.layer_kicks,
            )
        };
        assert_eq!(counts(&a), counts(&b), "{what}: counts");
        evaluations += a.timing.penalty_work.layer_evaluations;
        most_islands = most_islands.max(a.stats.islands);
    }
    println!("{evaluations} evaluations, up to {most_islands} islands");
    assert!(most_islands >= 2, "the sheets must make two islands");
}

// ------------------------------------------------- 5. penalty kick = -h dV/dx

#[test]
fn penalty_kick_is_minus_h_times_the_layer_energy_gradient() {
    let schedule = LayerSchedule {
        eta_1: 1e-3,
        eta_inf: 1e-4,
        k_1: 37.0,
        h_1: 1 << 20,
    };
    let h = 2.5e-5;
    let cases: Vec<(StencilKind, [DVec3; 4])> = vec![
        // VF, closest point in the face interior.
        (
            StencilKind::VertexFace,
            [
                DVec3::new(0.002, 0.003, 3e-4),
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(0.01, 0.001, 0.0002),
                DVec3::new(0.001, 0.01, -0.0001),
            ],
        ),
        // VF, closest point on an edge of the face.
        (
            StencilKind::VertexFace,
            [
                DVec3::new(0.005, -2e-4, 2e-4),
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(0.01, 0.0, 0.0),
                DVec3::new(0.0, 0.01, 0.0),
            ],
        ),
        // EE, crossing edges.
        (
            StencilKind::EdgeEdge,
            [
                DVec3::new(-0.01, 0.001, 4e-4),
                DVec3::new(0.01, -0.002, 3e-4),
                DVec3::new(0.001, -0.01, 0.0),
                DVec3::new(-0.002, 0.01, -1e-4),
            ],
        ),
        // EE, endpoint of one edge against the interior of the other.
        (
            StencilKind::EdgeEdge,
            [
                DVec3::new(0.0, 0.0, 5e-4),
                DVec3::new(0.0, 0.0, 0.02),
                DVec3::new(-0.01, 0.001, 0.0),
                DVec3::new(0.01, -0.001, 0.0),
            ],
        ),
    ];
    let v = [DVec3::ZERO; 4];
    let w = [1.0; 4];
    let mut checked = 0;
    for (kind, x) in &cases {
        let d = stencil_closest(*kind, x).d;
        for l in 1..=12u32 {
            let c = stencil_closest(*kind, x);
            let kick = penalty_kick(schedule.eta(l), schedule.k(l), h, &c, &v, &w, 0.0);
            if d >= schedule.eta(l) {
                assert!(kick.is_none(), "{kind:?} l={l}: a kick outside the layer");
                continue;
            }
            let k = kick.expect("inside the layer");
            let grad: Vec<DVec3> = k.normal.iter().map(|j| -*j / h).collect();
            let energy = |y: &[DVec3]| {
                let y = [y[0], y[1], y[2], y[3]];
                schedule.energy(l, stencil_closest(*kind, &y).d)
            };
            assert_gradient(energy, x, &grad, 1e-9, 1e-5);
            assert!((k.energy - schedule.energy(l, d)).abs() <= 1e-12 * k.energy);
            let total: DVec3 = k.normal.iter().copied().sum();
            assert!(total.length() <= 1e-12 * k.normal[0].length(), "momentum");
            checked += 1;
        }
        // At exactly eta_l the kick is zero.
        let c = stencil_closest(*kind, x);
        let at = LayerSchedule {
            eta_1: c.d,
            eta_inf: 0.0,
            ..schedule.clone()
        };
        assert!(penalty_kick(at.eta(1), at.k(1), h, &c, &v, &w, 0.0).is_none());
    }
    println!("penalty kick: {checked} (stencil, layer) pairs checked against finite differences");
    assert!(checked >= 12);
}
