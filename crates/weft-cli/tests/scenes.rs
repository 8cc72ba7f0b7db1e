//! The bundled scenes at small sizes: every frame free of intersecting
//! triangles (exact test; obstacle–obstacle pairs aside) and stats showing
//! real contact — at least one rollback, a layer depth of 2 or more, and
//! active stencils in at least 30 % of the windows.

use std::path::{Path, PathBuf};

use glam::DVec3;
use weft_cli::commands::run::simulate;
use weft_core::StencilKind;
use weft_geom::distance::stencil_closest;
use weft_geom::intersections::mesh_self_intersections;
use weft_io::scene::{load_scene, Scene};
use weft_sim::kinematics::Motion;
use weft_sim::ObjectKind;

fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name)
}

/// The PLY frames of the run folder `dir`, in order.
fn ply_frames(dir: &Path) -> Vec<PathBuf> {
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "ply"))
        .collect();
    frames.sort();
    frames
}

/// What a small run of a scene showed.
struct Outcome {
    scene: Scene,
    windows: usize,
    /// The last frame's positions (all objects, input order) and its time.
    last_frame: Vec<DVec3>,
    last_time: f64,
}

/// Runs `name` with `overrides`, checks every frame and the contact stats,
/// and returns what the caller may check further.
fn run_and_check(name: &str, overrides: &[&str]) -> Outcome {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let scene = load_scene(&scene_path(name), &o).unwrap_or_else(|e| panic!("{name}: {e}"));
    // Obstacle triangles, by object (frames hold every object in order).
    let mut obstacle = Vec::new();
    for obj in &scene.world.objects {
        let is_obstacle = matches!(obj.kind, ObjectKind::Obstacle { .. });
        obstacle.extend(std::iter::repeat_n(is_obstacle, obj.mesh.num_triangles()));
    }
    let out = tempfile::tempdir().unwrap();
    let summary = simulate(&scene, out.path(), true).unwrap_or_else(|e| panic!("{name}: {e:#}"));

    let frames = ply_frames(out.path());
    assert!(frames.len() >= 3, "{name}: {} frames", frames.len());
    let mut last_frame = Vec::new();
    for f in &frames {
        let m = weft_io::read_mesh(f).unwrap().mesh;
        assert_eq!(m.num_triangles(), obstacle.len(), "{}", f.display());
        let hits: Vec<(u32, u32)> = mesh_self_intersections(&m.positions, &m.triangles)
            .into_iter()
            .filter(|&(a, b)| !(obstacle[a as usize] && obstacle[b as usize]))
            .collect();
        assert!(
            hits.is_empty(),
            "{name}: {}: intersecting triangles {:?}",
            f.display(),
            &hits[..hits.len().min(10)]
        );
        last_frame = m.positions;
    }
    let frame_times = std::fs::read_to_string(out.path().join("frames.jsonl")).unwrap();
    let last: serde_json::Value =
        serde_json::from_str(frame_times.lines().last().unwrap()).unwrap();
    let last_time = last["time"].as_f64().unwrap();

    let stats = std::fs::read_to_string(out.path().join("stats.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = stats
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let field = |r: &serde_json::Value, k: &str| {
        r[k].as_u64()
            .unwrap_or_else(|| panic!("{name}: stats line lacks {k}: {r}"))
    };
    let windows = rows.len();
    let rollbacks: u64 = rows.iter().map(|r| field(r, "rollbacks")).sum();
    let depth = rows
        .iter()
        .map(|r| field(r, "max_depth"))
        .max()
        .unwrap_or(0);
    let in_contact = rows
        .iter()
        .filter(|r| field(r, "active_stencils") > 0)
        .count();
    println!(
        "{name} {overrides:?}: {} vertices, {windows} windows, {rollbacks} rollbacks, \
         max depth {depth}, contact in {in_contact} windows ({:.0} %), {:.1} s",
        summary.vertices,
        100.0 * in_contact as f64 / windows as f64,
        summary.wall_seconds
    );
    assert_eq!(windows as u64, summary.windows);
    assert!(rollbacks >= 1, "{name}: no rollback in {windows} windows");
    assert!(depth >= 2, "{name}: max layer depth {depth}");
    assert!(
        in_contact as f64 >= 0.3 * windows as f64,
        "{name}: active stencils in only {in_contact} of {windows} windows"
    );
    Outcome {
        scene,
        windows,
        last_frame,
        last_time,
    }
}

#[test]
fn drape_small() {
    run_and_check("drape.toml", &["size=300", "time.end=0.25"]);
}

#[test]
fn crumple_small() {
    run_and_check("crumple.toml", &["time.end=0.2"]);
}

/// The upper cloth comes down on the lower one draped over the sphere: by the
/// end the two cloths are within the contact thickness of each other (and,
/// by the frame checks, never pass through each other).
#[test]
fn two_cloths_small() {
    let r = run_and_check("two-cloths.toml", &["size=300", "time.end=0.2"]);
    let objects = &r.scene.world.objects;
    assert_eq!(objects[0].name, "lower");
    assert_eq!(objects[1].name, "upper");
    let n_lower = objects[0].mesh.num_vertices() as u32;
    let x = &r.last_frame;
    // The two cloths' triangles and edges in global (frame) vertex ids.
    let lower: Vec<[u32; 3]> = objects[0].mesh.triangles.clone();
    let upper: Vec<[u32; 3]> = objects[1]
        .mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| i + n_lower))
        .collect();
    let edges = |tris: &[[u32; 3]]| {
        let mut e: Vec<[u32; 2]> = tris
            .iter()
            .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        e.sort_unstable();
        e.dedup();
        e
    };
    let vertices = |tris: &[[u32; 3]]| {
        let mut v: Vec<u32> = tris.iter().flatten().copied().collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let at = |i: u32| x[i as usize];
    let mut closest = f64::INFINITY;
    for (verts, faces) in [(vertices(&upper), &lower), (vertices(&lower), &upper)] {
        for t in faces.iter() {
            for &p in &verts {
                let q = [at(p), at(t[0]), at(t[1]), at(t[2])];
                closest = closest.min(stencil_closest(StencilKind::VertexFace, &q).d);
            }
        }
    }
    for a in edges(&lower) {
        for b in edges(&upper) {
            let q = [at(a[0]), at(a[1]), at(b[0]), at(b[1])];
            closest = closest.min(stencil_closest(StencilKind::EdgeEdge, &q).d);
        }
    }
    let eta = r.scene.world.contact.thickness;
    println!(
        "two-cloths: upper to lower {closest:e} m after {} windows",
        r.windows
    );
    assert!(
        closest < eta,
        "the cloths never meet: closest {closest:e} m"
    );
}

/// With the twist started at t = 0 (the documented override), the gripped
/// middle of the sleeve turns with the rod while its held ends stay.
#[test]
fn twister_small() {
    let r = run_and_check(
        "twister.toml",
        &[
            "size=300",
            "time.end=0.15",
            "obstacle.0.motion.omega=[[0.0, 0.0], [0.25, 6.283185307179586]]",
        ],
    );
    let objects = &r.scene.world.objects;
    let (sleeve, rod) = (&objects[0], &objects[1]);
    let ObjectKind::Obstacle {
        motion: Motion::Rotate { profile, .. },
    } = &rod.kind
    else {
        panic!("the rod rotates")
    };
    let rod_angle = Motion::angle(profile, r.last_time);
    // Mean turn about the x axis of the sleeve vertices over the rod's middle
    // half, and of the held end rings.
    let turn = |select: &dyn Fn(f64) -> bool| {
        let (mut sum, mut n) = (0.0, 0);
        for (p0, p) in sleeve.mesh.positions.iter().zip(&r.last_frame) {
            if select(p0.x) {
                let a = p.z.atan2(p.y) - p0.z.atan2(p0.y);
                sum += (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                n += 1;
            }
        }
        assert!(n > 0);
        sum / n as f64
    };
    let middle = turn(&|x| x.abs() < 0.1);
    let ends = turn(&|x| x.abs() > 0.399);
    println!("twister: rod turned {rod_angle:.3} rad, sleeve middle {middle:.3}, ends {ends:.3}");
    assert!(rod_angle > 0.15, "rod turned only {rod_angle}");
    assert!(
        (middle - rod_angle).abs() < 0.2 * rod_angle,
        "the sleeve slips: middle {middle}, rod {rod_angle}"
    );
    assert!(ends.abs() < 1e-9, "held ends turned {ends}");
}

/// Every bundled scene builds at `size` = 300, 2,000 and 10,000 and would
/// start: its world (METIS partitions, masses, the internal step derived
/// from both the stiffness and the damping limit, the layer schedule) and
/// its initial state are valid, and the step is within both explicit
/// stability limits of its rest system.
#[test]
fn every_bundled_scene_builds_at_every_size() {
    let mut names: Vec<String> = std::fs::read_dir(scene_path(""))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert!(names.len() >= 6, "{names:?}");
    for name in &names {
        for size in [300, 2000, 10_000] {
            let what = format!("{name} at size={size}");
            let scene = load_scene(&scene_path(name), &[format!("size={size}")])
                .unwrap_or_else(|e| panic!("{what}: {e}"));
            let world =
                weft_par::build_world(&scene.world).unwrap_or_else(|e| panic!("{what}: {e}"));
            let (h, omega, gamma) = (world.lattice.h_el(), world.omega_max, world.damping_rate);
            println!("{what}: h_el {h:.3e} s, omega_max {omega:.3e}, damping rate {gamma:.3e}");
            assert!(h <= 2.0 / omega, "{what}: step {h:e} above 2 / omega_max");
            assert!(
                h <= weft_sim::materials::damping_step_limit(omega, gamma),
                "{what}: step {h:e} above the damping limit"
            );
            weft_sim::Engine::new(world, weft_sim::Serial)
                .unwrap_or_else(|e| panic!("{what}: {e}"));
        }
    }
}

/// `crumple` (the bundled scene, to 0.3 s: the cloth has landed and folds
/// onto itself, layers 20 deep) writes every frame byte for byte as the
/// build before the trajectories' block bounds did (XXH3-128 of its CLI
/// run's frames, in order): a narrow phase that certifies differently may
/// change the layers, never the trajectory (acm-spec §4).
#[test]
fn crumple_frames_are_those_of_the_build_before_block_bounds() {
    const FRAMES_DIGEST: &str = "2b2e0e5849d271943c8879527ee43bea";
    let o = vec!["time.end=0.3".to_string()];
    let scene = load_scene(&scene_path("crumple.toml"), &o).unwrap();
    let out = tempfile::tempdir().unwrap();
    simulate(&scene, out.path(), true).unwrap();
    let frames = ply_frames(out.path());
    assert_eq!(frames.len(), 10);
    let mut digest = xxhash_rust::xxh3::Xxh3::new();
    for f in &frames {
        digest.update(&std::fs::read(f).unwrap());
    }
    assert_eq!(
        format!("{:032x}", digest.digest128()),
        FRAMES_DIGEST,
        "the frames changed"
    );
}
