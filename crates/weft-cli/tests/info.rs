//! `weft info` on someone else's mesh: each object's bounding box, edge
//! lengths and smallest altitude, what each pin holds, the start-up warnings
//! (also printed once by `weft run`), and the engine's verdict on the start
//! state, with the exit status `weft run` would have.

mod common;

use std::path::Path;
use std::process::Output;

use common::weft;

/// `weft ARGS…` in `dir`.
fn weft_in(dir: &Path, args: &[&str]) -> Output {
    weft()
        .current_dir(dir)
        .args(args)
        .output()
        .expect("weft runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn info_json(o: &Output) -> serde_json::Value {
    let out = text(&o.stdout);
    serde_json::from_str(out.lines().last().expect("a JSON line"))
        .unwrap_or_else(|e| panic!("not JSON ({e}): {out}"))
}

/// Two cloths crossing each other: the upright one passes through the flat
/// one, its vertices clear of it (no contact, an intersection).
const CROSSING: &str = r#"version = 1
[time]
end = 0.05
[[cloth]]
name = "flat"
grid = { size = [0.2, 0.2], resolution = [4, 4], center = [0.0, 0.5, 0.0] }
[[cloth]]
name = "upright"
grid = { size = [0.2, 0.2], resolution = [4, 4], center = [0.01, 0.5, 0.0], plane = "xy" }
"#;

/// What used to happen: `weft info` reported the crossing cloths as fine and
/// only `weft run` refused them.
#[test]
fn info_says_what_run_would_refuse_and_exits_as_run_does() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("cross.toml"), CROSSING).unwrap();
    let o = weft_in(dir.path(), &["info", "cross.toml"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(
        out.contains("start state      weft run would refuse it: ")
            && out.contains("flat #6 and upright #6 intersect"),
        "{out}"
    );
    let o = weft_in(dir.path(), &["info", "cross.toml", "--json"]);
    assert_eq!(o.status.code(), Some(1));
    let refused = info_json(&o)["start_refused"].as_str().unwrap().to_string();
    // The same words as `weft run`'s error.
    let run = weft_in(
        dir.path(),
        &["run", "cross.toml", "--out", "out", "--no-preview"],
    );
    assert_eq!(run.status.code(), Some(1));
    assert!(
        text(&run.stderr).contains(&refused),
        "{}",
        text(&run.stderr)
    );
    // Moved apart, both start.
    let apart = ["--set", "cloth.1.grid.center=[0.01, 0.8, 0.0]"];
    let o = weft_in(
        dir.path(),
        &[&["info", "cross.toml", "--json"][..], &apart].concat(),
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(info_json(&o)["start_refused"].is_null());
    let o = weft_in(dir.path(), &[&["info", "cross.toml"][..], &apart].concat());
    assert!(text(&o.stdout).contains("start state      ok"));
}

#[test]
fn info_reports_each_objects_extent_edges_altitude_and_pins() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("s.toml"),
        r#"version = 1
[[cloth]]
name = "sheet"
grid = { size = [0.4, 0.2], resolution = [5, 3], center = [0.0, 0.5, 0.0] }
transform = { scale = [2.0, 1.0, 1.0] }
[[obstacle]]
name = "floor"
box = { min = [-1.0, -0.1, -1.0], max = [1.0, 0.0, 1.0] }
[[pin]]
name = "left"
object = "sheet"
relative = true
box_min = [0.0, 0.0, 0.0]
box_max = [0.0, 1.0, 1.0]
"#,
    )
    .unwrap();
    let o = weft_in(dir.path(), &["info", "s.toml", "--json"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let j = info_json(&o);
    let sheet = &j["objects"][0];
    // 0.8 m × 0.2 m after the transform, on a 0.2 m × 0.1 m grid.
    assert_eq!(
        sheet["bounding_box"],
        serde_json::json!([[-0.4, 0.5, -0.1], [0.4, 0.5, 0.1]])
    );
    let edges = sheet["edge_length"].as_array().unwrap();
    let (short, long) = (edges[0].as_f64().unwrap(), edges[1].as_f64().unwrap());
    assert!((short - 0.1).abs() < 1e-12, "{short}");
    assert!((long - 0.05f64.sqrt()).abs() < 1e-12, "{long}");
    // The right triangles' altitude onto the hypotenuse: 0.2 · 0.1 / √0.05.
    let altitude = sheet["min_altitude"].as_f64().unwrap();
    assert!(
        (altitude - 0.02 / 0.05f64.sqrt()).abs() < 1e-12,
        "{altitude}"
    );
    assert_eq!(
        j["objects"][1]["bounding_box"],
        serde_json::json!([[-1.0, -0.1, -1.0], [1.0, 0.0, 1.0]])
    );
    assert_eq!(
        j["pins"],
        serde_json::json!([{ "name": "left", "object": "sheet", "vertices": 3 }])
    );
    assert_eq!(j["warnings"], serde_json::json!([]));
    let o = weft_in(dir.path(), &["info", "s.toml"]);
    let out = text(&o.stdout);
    assert!(
        out.contains("box (-0.4000, 0.5000, -0.1000) to (0.4000, 0.5000, 0.1000) m")
            && out.contains("pin left       holds 3 vertices of 'sheet'"),
        "{out}"
    );
}

/// A 14 m ribbon with a contact thickness its triangles cannot hold.
const LONG_RIBBON: &str = r#"version = 1
[time]
end = 0.01
[contact]
thickness = 0.2
[[cloth]]
name = "ribbon"
grid = { size = [14.0, 0.2], resolution = [8, 3], center = [0.0, 0.5, 0.0] }
"#;

fn count(haystack: &str, needle: &str) -> usize {
    haystack.matches(needle).count()
}

/// What used to happen: both went unsaid; the thickness was silently clamped
/// and the 14 m cloth simulated as if it were meant.
#[test]
fn run_and_info_warn_once_about_a_clamped_thickness_and_an_implausible_size() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("long.toml"), LONG_RIBBON).unwrap();
    let clamp = "weft: warning: contact.thickness = 2.000e-1 m is more than half the smallest \
                 altitude of a cloth triangle";
    let size = "weft: warning: cloth 'ribbon' is 1.400e1 m across";
    let o = weft_in(dir.path(), &["info", "long.toml", "--json"]);
    assert!(o.status.success());
    let err = text(&o.stderr);
    assert_eq!((count(&err, clamp), count(&err, size)), (1, 1), "{err}");
    let j = info_json(&o);
    let used = j["contact_thickness"].as_f64().unwrap();
    assert!(err.contains(&format!("using {used:.3e} m")), "{err}");
    assert!(used < 0.2 && used > 0.04, "{used}");
    assert_eq!(j["warnings"].as_array().unwrap().len(), 2);
    // `weft run`, also over two ranks: once, from rank 0.
    for ranks in ["1", "2"] {
        let out = format!("out{ranks}");
        let o = weft_in(
            dir.path(),
            &[
                "run",
                "long.toml",
                "--out",
                &out,
                "--no-preview",
                "--ranks",
                ranks,
            ],
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        let err = text(&o.stderr);
        assert_eq!((count(&err, clamp), count(&err, size)), (1, 1), "{err}");
    }
    let o = weft_in(
        dir.path(),
        &[
            "run",
            "long.toml",
            "--out",
            "quiet",
            "--no-preview",
            "--quiet",
        ],
    );
    assert!(o.status.success());
    assert!(!text(&o.stderr).contains("warning"), "{}", text(&o.stderr));
    // At 1.4 m and with a thickness the triangles hold, nothing to say.
    let o = weft_in(
        dir.path(),
        &[
            "info",
            "long.toml",
            "--set",
            "cloth.0.grid.size=[1.4, 0.2]",
            "--set",
            "contact.thickness=1e-3",
        ],
    );
    assert!(o.status.success());
    assert!(!text(&o.stderr).contains("warning"), "{}", text(&o.stderr));
}

/// Third-party meshes: the square and the skirt import, build and start as
/// a cloth (the sphere as an obstacle under it). The cylinder has an unwelded
/// seam: what used to happen was "... stencil ... is 0.000e0 m apart ...; move
/// the objects apart" from `weft run`.
#[test]
fn the_shared_meshes_import_and_start_or_say_to_weld() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes");
    assert!(
        data.is_dir(),
        "shared test data not found at {}; this test needs it",
        data.display()
    );
    let dir = tempfile::tempdir().unwrap();
    let scene = |mesh: &str| {
        std::fs::write(
            dir.path().join("s.toml"),
            format!(
                "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"{}\"\n\
                 transform = {{ translate = [0.0, 3.0, 0.0] }}\n\
                 [[obstacle]]\nname = \"ball\"\nmesh = \"{}\"\n",
                data.join(mesh).display(),
                data.join("sphere1K.obj").display()
            ),
        )
        .unwrap();
        weft_in(dir.path(), &["info", "s.toml", "--json"])
    };
    for mesh in ["square2K.obj", "skirt4K.obj"] {
        let o = scene(mesh);
        assert!(o.status.success(), "{mesh}: {}", text(&o.stderr));
        let j = info_json(&o);
        assert!(j["start_refused"].is_null(), "{mesh}: {j}");
        assert!(j["objects"][0]["min_altitude"].as_f64().unwrap() > 0.0);
    }
    let o = scene("cylinder3K.obj");
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(
        err.contains("cylinder3K.obj: 128 vertices lie exactly on other vertices")
            && err.contains("(v 1 = v 1088; v 2 = v 1087;")
            && err.contains("weld the mesh (128 coincident vertices)")
            && !err.contains("move the objects apart"),
        "{err}"
    );
}
