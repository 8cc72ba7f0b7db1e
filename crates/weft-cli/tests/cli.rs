//! End-to-end tests of the `weft` binary and its library entry points.

use std::path::{Path, PathBuf};
use std::process::Command;

use weft_cli::commands::run::simulate;
use weft_core::StencilKey;
use weft_geom::distance::stencil_closest;
use weft_geom::intersections::mesh_self_intersections;
use weft_io::scene::load_scene;
use weft_sim::{Engine, Serial, World};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn scene(name: &str) -> PathBuf {
    repo().join("scenes").join(name)
}

fn weft(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_weft"))
        .args(args)
        .output()
        .expect("weft runs")
}

fn last_json(stdout: &[u8]) -> serde_json::Value {
    let text = String::from_utf8_lossy(stdout);
    let line = text.lines().last().expect("some output");
    serde_json::from_str(line).unwrap_or_else(|e| panic!("last line is not JSON ({e}): {line}"))
}

/// `crumple` is the shared contact-heavy fixture: the same bits for any
/// chunking of the mesh into partitions, and enough contact to mean it.
#[test]
fn crumple_hash_is_independent_of_partitioning() {
    let mut hashes = Vec::new();
    for partitions in [1, 4, 16] {
        let s = load_scene(
            &scene("crumple.toml"),
            &["time.end=0.23".into(), format!("partitions={partitions}")],
        )
        .unwrap();
        let out = tempfile::tempdir().unwrap();
        let summary = simulate(&s, out.path(), true).unwrap();
        println!(
            "P = {partitions}: {} rollbacks, depth {}, peak active {}, hash {}",
            summary.rollbacks, summary.max_depth, summary.max_active_stencils, summary.state_hash
        );
        // 7 rollbacks measured (prediction gives most layers before they
        // are asked for: 14 before the resting margin and twice the closing
        // energy, 20 and more before its margin and energy count).
        assert!(summary.rollbacks >= 4, "{} rollbacks", summary.rollbacks);
        assert!(summary.max_depth >= 5, "depth {}", summary.max_depth);
        assert!(
            summary.max_active_stencils >= 300,
            "peak active stencils {}",
            summary.max_active_stencils
        );
        hashes.push(summary.state_hash);
    }
    assert!(
        hashes.windows(2).all(|w| w[0] == w[1]),
        "hashes differ: {hashes:?}"
    );
}

#[test]
fn run_writes_frames_stats_and_a_json_summary_without_intersections() {
    let out = tempfile::tempdir().unwrap();
    let o = weft(&[
        "run",
        scene("drape.toml").to_str().unwrap(),
        "--out",
        out.path().to_str().unwrap(),
        "--set",
        "size=400",
        "--set",
        "time.end=0.3",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = last_json(&o.stdout);
    for key in ["state_hash", "windows", "rollbacks", "wall_seconds"] {
        assert!(j.get(key).is_some(), "summary lacks {key}: {j}");
    }
    assert!(
        j["rollbacks"].as_u64().unwrap() >= 1,
        "the cloth must reach the sphere: {j}"
    );
    let stats = std::fs::read_to_string(out.path().join("stats.jsonl")).unwrap();
    assert_eq!(stats.lines().count() as u64, j["windows"].as_u64().unwrap());
    let frames = out.path().join("frames");
    let n = std::fs::read_dir(&frames).unwrap().count();
    assert!(n >= 9, "{n} frames");
    // Every frame is free of intersections (exact test), as `weft check` says.
    let c = weft(&["check", frames.to_str().unwrap()]);
    assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stdout));
}

#[test]
fn ccd_bench_reports_zero_false_negatives_as_json() {
    let data = repo().join("../shared/data/ccd");
    assert!(
        data.is_dir(),
        "the shared CCD data is missing: expected it at {}",
        data.display()
    );
    let o = weft(&["ccd-bench", data.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = last_json(&o.stdout);
    let total = &j;
    assert_eq!(total["false_negatives"], 0, "{total}");
    assert!(total["queries"].as_u64().unwrap() >= 8000, "{total}");
    for key in [
        "queries",
        "false_negatives",
        "false_positives",
        "ns_per_query",
    ] {
        assert!(
            total.get(key).is_some() || j.get(key).is_some(),
            "no {key}: {j}"
        );
    }
}

/// Bad scene input: a clear message naming the file, line or key; exit 1; no panic.
#[test]
fn bad_scenes_are_refused_with_clear_messages() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(scene("crumple.toml")).unwrap();
    let cases: Vec<(&str, String, Vec<&str>, &str)> = vec![
        (
            "unknown key",
            base.replace("[time]", "[time]\nsteps = 3"),
            vec![],
            "unknown field `steps`",
        ),
        (
            "wrong type",
            base.replace("end = 0.6", "end = \"soon\""),
            vec![],
            "line",
        ),
        (
            "bad value",
            base.replace("end = 0.6", "end = -1.0"),
            vec![],
            "time.end",
        ),
        (
            "missing mesh",
            base.replace("grid = {", "mesh = \"nowhere.obj\"\n#"),
            vec![],
            "nowhere.obj",
        ),
        (
            "bad version",
            base.replace("version = 1", "version = 7"),
            vec![],
            "version",
        ),
        (
            "unknown override",
            base.clone(),
            vec!["--set", "time.ending=3"],
            "ending",
        ),
        (
            "malformed override",
            base.clone(),
            vec!["--set", "time.end"],
            "key.path=value",
        ),
        ("bad toml", format!("{base}\n[[[nonsense"), vec![], "line"),
    ];
    for (what, text, extra, needle) in cases {
        let path = dir.path().join(format!("{}.toml", what.replace(' ', "_")));
        std::fs::write(&path, text).unwrap();
        let out = dir.path().join("out");
        let mut args = vec![
            "run",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(extra);
        let o = weft(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{what}: {err}");
        assert!(
            err.contains(needle),
            "{what}: message lacks '{needle}': {err}"
        );
        assert!(!err.contains("panicked"), "{what}: {err}");
    }
}

/// An error whose text already shows its cause (the engine's material error:
/// `object '…': {source}`) is printed once, not once more as the cause.
#[test]
fn an_error_is_printed_exactly_once() {
    let out = tempfile::tempdir().unwrap();
    let o = weft(&[
        "run",
        scene("crumple.toml").to_str().unwrap(),
        "--out",
        out.path().to_str().unwrap(),
        "--set",
        "size=150",
        "--set",
        "cloth.0.material.poisson_ratio=0.7",
        "--quiet",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "one line: {err}");
    assert_eq!(err.matches("poisson_ratio").count(), 1, "{err}");
}

/// Bad mesh files behind a scene: malformed, non-manifold, degenerate, NaN,
/// out-of-range indices — each refused with the file, the line or element and
/// the problem; exit 1; no panic.
#[test]
fn bad_meshes_are_refused_naming_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    let square = "v 0 0.3 0\nv 0.2 0.3 0\nv 0.2 0.3 0.2\nv 0 0.3 0.2\n";
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "malformed face",
            format!("{square}f 1 2\n"),
            vec!["bad.obj:5", "at least 3"],
        ),
        (
            "index out of range",
            format!("{square}f 1 2 9\n"),
            vec!["bad.obj:5", "9"],
        ),
        (
            "not a number",
            "v 0 zero 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n".into(),
            vec!["bad.obj:1"],
        ),
        (
            "NaN coordinate",
            format!("{square}v nan 0 0\nf 1 2 3\nf 1 3 5\n"),
            vec!["bad.obj:5", "vertex 5", "non-finite"],
        ),
        (
            "degenerate triangle",
            "v 0 0.3 0\nv 0.1 0.3 0\nv 0.2 0.3 0\nf 1 2 3\n".into(),
            vec!["bad.obj:4", "area"],
        ),
        (
            "non-manifold edge",
            format!("{square}v 0.1 0.5 0.1\nf 1 2 3\nf 1 3 4\nf 1 3 5\n"),
            vec!["bad.obj", "non-manifold", "edge"],
        ),
    ];
    for (what, obj, needles) in cases {
        std::fs::write(dir.path().join("bad.obj"), obj).unwrap();
        let scene_text = "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"bad.obj\"\n[cloth.material]\n\
                          density = 0.2\nyoungs_modulus = 1e5\npoisson_ratio = 0.3\nthickness = 1e-3\n";
        let path = dir.path().join("scene.toml");
        std::fs::write(&path, scene_text).unwrap();
        let o = weft(&[
            "run",
            path.to_str().unwrap(),
            "--out",
            dir.path().join("o").to_str().unwrap(),
            "--quiet",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{what}: {err}");
        for needle in needles {
            assert!(
                err.contains(needle),
                "{what}: message lacks '{needle}': {err}"
            );
        }
        assert!(!err.contains("panicked"), "{what}: {err}");
        let c = weft(&["check", dir.path().join("bad.obj").to_str().unwrap()]);
        assert_ne!(c.status.code(), Some(0), "check refuses it too ({what})");
        assert!(!String::from_utf8_lossy(&c.stderr).contains("panicked"));
    }
}

/// A mesh validation error is printed once, in the file's own numbering: the
/// 0-based text of the underlying `MeshError` is not appended as a cause.
#[test]
fn check_prints_a_mesh_error_once_in_the_files_numbering() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.obj");
    // Line 6 is a face that repeats a vertex.
    std::fs::write(
        &bad,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 2\n",
    )
    .unwrap();
    let c = weft(&["check", bad.to_str().unwrap()]);
    assert_eq!(c.status.code(), Some(1));
    let err = String::from_utf8_lossy(&c.stderr);
    let line = err
        .lines()
        .find(|l| l.starts_with("error:"))
        .expect("an error line");
    assert!(
        line.contains("bad.obj:6: the face on line 6 (v 2, v 4, v 2) repeats a vertex"),
        "{err}"
    );
    assert_eq!(line.matches("repeats a vertex").count(), 1, "{err}");
    assert!(!line.contains("0-based"), "{err}");
}

/// Initially intersecting geometry is refused, naming the triangles.
#[test]
fn intersecting_initial_state_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(scene("drape.toml")).unwrap();
    let text = base.replace("center = [0.0, 0.45, 0.0]", "center = [0.0, 0.1, 0.0]");
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, text).unwrap();
    let o = weft(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        dir.path().join("o").to_str().unwrap(),
        "--set",
        "size=200",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("initial state"), "{err}");
    assert!(
        err.contains("cloth #") && err.contains("sphere #"),
        "names the primitives: {err}"
    );
}

/// `crumple` never lets anything pass: at every committed window end, by brute
/// force over every stencil of the world, each stencil is at least
/// `eta_(depth+1)` apart (what the narrow phase certified), no stencil is
/// below the floor, and no two triangles intersect (exact test).
#[test]
fn crumple_keeps_every_stencil_outside_its_next_layer() {
    let s = load_scene(&scene("crumple.toml"), &["time.end=0.2".into()]).unwrap();
    let mut e = Engine::new(World::build(&s.world).unwrap(), Serial).unwrap();
    let (tris, inv_mass) = (e.world.triangles.clone(), e.world.inv_mass.clone());
    let edges = weft_core::Topology::build(e.world.num_vertices(), &tris)
        .unwrap()
        .edges;
    let dynamic = |k: &StencilKey| k.v.iter().any(|&i| inv_mass[i as usize] > 0.0);
    let mut stencils = Vec::new();
    for v in 0..e.world.num_vertices() as u32 {
        for t in &tris {
            let k = StencilKey::vertex_face(v, *t);
            if !k.shares_vertex() && dynamic(&k) {
                stencils.push(k);
            }
        }
    }
    for (a, ea) in edges.iter().enumerate() {
        for eb in &edges[a + 1..] {
            let k = StencilKey::edge_edge(*ea, *eb);
            if !k.shares_vertex() && dynamic(&k) {
                stencils.push(k);
            }
        }
    }
    let (mut rollbacks, mut depth, mut closest) = (0, 0, f64::INFINITY);
    while e.world.time() < s.end_time {
        let st = e.step_window().unwrap().stats;
        rollbacks += st.rollbacks;
        depth = depth.max(st.max_depth);
        let w = &e.world;
        // Rounding slack of the distance itself (coordinates below ~1 m).
        let slack = 1e-12;
        for k in &stencils {
            let d = stencil_closest(k.kind, &k.v.map(|i| w.x[i as usize])).d;
            closest = closest.min(d);
            let next = w.schedule.eta(w.layers.depth(k) + 1);
            assert!(
                d >= next - slack && d > w.schedule.eta_inf,
                "window {}: stencil {k:?} at {d:e}, inside eta_(depth+1) = {next:e}",
                st.window
            );
        }
        let hits: Vec<_> = mesh_self_intersections(&w.x, &tris)
            .into_iter()
            .filter(|&(a, b)| {
                [a, b]
                    .iter()
                    .any(|&f| tris[f as usize].iter().any(|&i| inv_mass[i as usize] > 0.0))
            })
            .collect();
        assert!(
            hits.is_empty(),
            "window {}: intersecting triangles {hits:?}",
            st.window
        );
    }
    println!(
        "crumple to 0.2 s: {rollbacks} rollbacks, depth {depth}, closest stencil {closest:e} m"
    );
    // Measured: 4 rollbacks, depth 18 (prediction gives most layers before
    // the detection asks; the detection still had to ask).
    assert!(
        rollbacks >= 2 && depth >= 5,
        "too little contact to mean anything"
    );
}

/// `weft info` builds the scene and reports its figures without simulating.
#[test]
fn info_reports_scene_figures() {
    let o = weft(&["info", scene("crumple.toml").to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = last_json(&o.stdout);
    assert_eq!(j["vertices"], 584, "{j}");
    assert_eq!(j["triangles"], 1070, "{j}");
    assert_eq!(j["objects"][0]["vertices"], 576, "{j}");
    // 0.5 m × 0.5 m at 0.2 kg/m².
    let mass = j["objects"][0]["mass"].as_f64().unwrap();
    assert!((mass - 0.05).abs() < 1e-12, "cloth mass {mass}");
    // The start shape is the wave A sin(3 pi s) sin(2 pi t) (A = 3 cm, side
    // L = 0.5 m) over a flat rest shape: the steepest slope 3 pi A / L gives a
    // Green strain of about slope^2 / 2 (the mesh samples it slightly lower).
    let strain = j["max_initial_strain"].as_f64().unwrap();
    let slope = 3.0 * std::f64::consts::PI * 0.03 / 0.5;
    let expected = 0.5 * slope * slope;
    assert!(
        strain < expected && strain > 0.95 * expected,
        "initial strain {strain}, continuum {expected}"
    );
    assert!(j["internal_step"].as_f64().unwrap() > 0.0);
    let text = weft(&[
        "info",
        scene("drape.toml").to_str().unwrap(),
        "--set",
        "size=400",
    ]);
    assert!(text.status.success());
    let out = String::from_utf8_lossy(&text.stdout);
    assert!(
        out.contains("cloth") && out.contains("sphere") && out.contains("internal step"),
        "{out}"
    );
}

/// A reader that goes away (`weft info … | head -1`) ends weft quietly.
#[test]
fn a_closed_pipe_is_not_a_panic() {
    use std::io::Read;
    let mut child = Command::new(env!("CARGO_BIN_EXE_weft"))
        .args(["info", scene("drape.toml").to_str().unwrap()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // close the read end before weft writes
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    child.wait().unwrap();
    assert!(!err.contains("panicked"), "{err}");
}
