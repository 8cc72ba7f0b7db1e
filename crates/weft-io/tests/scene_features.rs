//! Scene-file features: mesh-sequence obstacles, translation with a stop,
//! rest shapes from UVs and from a rest mesh, the window / internal-step keys,
//! the camera, punched grids and boundary pins, and what third-party meshes
//! need (unwelded meshes refused, mesh warnings kept, per-axis scale, pin
//! boxes relative to the object).

use std::path::{Path, PathBuf};

use glam::DVec3;
use weft_io::scene::{load_scene, SceneError};
use weft_sim::kinematics::Motion;
use weft_sim::{Engine, ObjectKind, Serial, World};

/// Writes `text` to `dir/name` and returns the path.
fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    if let Some(parent) = p.parent() {
        std::fs::create_dir_all(parent).unwrap();
    }
    std::fs::write(&p, text).unwrap();
    p
}

/// Loads scene `text` written to `dir/scene.toml`.
fn load(dir: &Path, text: &str, overrides: &[&str]) -> Result<weft_io::scene::Scene, SceneError> {
    let p = write(dir, "scene.toml", text);
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    load_scene(&p, &o)
}

fn err(dir: &Path, text: &str, overrides: &[&str]) -> String {
    match load(dir, text, overrides) {
        Ok(_) => panic!("the scene should be refused:\n{text}"),
        Err(e) => e.to_string(),
    }
}

fn assert_has(msg: &str, fragments: &[&str]) {
    for f in fragments {
        assert!(msg.contains(f), "message lacks '{f}': {msg}");
    }
}

const CLOTH: &str = r#"
[[cloth]]
name = "cloth"
grid = { size = [0.2, 0.2], resolution = [6, 6], center = [0.0, 0.1, 0.0] }
"#;

// ---------------------------------------------------------------- time

#[test]
fn window_and_internal_step_keys() {
    let dir = tempfile::tempdir().unwrap();
    let base = format!("version = 1\n{CLOTH}");
    // Only steps (or nothing): the internal step is derived later.
    let s = load(dir.path(), &base, &[]).unwrap();
    assert_eq!(s.world.time.internal_step, None);
    assert_eq!(s.world.time.steps_per_window, 100);
    // The published discretization: 1/3000 s windows of 140 steps.
    let s = load(
        dir.path(),
        &base,
        &["time.window=3.3333e-4", "time.steps_per_window=140"],
    )
    .unwrap();
    assert_eq!(s.world.time.steps_per_window, 140);
    assert_eq!(s.world.time.internal_step, Some(3.3333e-4 / 140.0));
    // Window alone: the default 100 steps.
    let s = load(dir.path(), &base, &["time.window=1e-2"]).unwrap();
    assert_eq!(s.world.time.steps_per_window, 100);
    assert_eq!(s.world.time.internal_step, Some(1e-4));
    // Window and internal step: steps = round(window / step).
    let s = load(
        dir.path(),
        &base,
        &["time.window=1e-2", "time.internal_step=3.3e-4"],
    )
    .unwrap();
    assert_eq!(s.world.time.steps_per_window, 30);
    assert_eq!(s.world.time.internal_step, Some(3.3e-4));
    // All three, consistent.
    let s = load(
        dir.path(),
        &base,
        &[
            "time.window=1e-2",
            "time.internal_step=1e-4",
            "time.steps_per_window=100",
        ],
    )
    .unwrap();
    assert_eq!(s.world.time.steps_per_window, 100);
    // All three, contradicting.
    let e = err(
        dir.path(),
        &base,
        &[
            "time.window=1e-2",
            "time.internal_step=1e-4",
            "time.steps_per_window=140",
        ],
    );
    assert_has(
        &e,
        &["scene.toml", "time.steps_per_window", "140", "contradicts"],
    );
    // A window shorter than half a step, a bad window, zero steps.
    let e = err(
        dir.path(),
        &base,
        &["time.window=1e-5", "time.internal_step=1e-4"],
    );
    assert_has(&e, &["time.window", "at least one"]);
    let e = err(dir.path(), &base, &["time.window=-1.0"]);
    assert_has(&e, &["time.window", "positive"]);
    let e = err(dir.path(), &base, &["time.steps_per_window=0"]);
    assert_has(&e, &["time.steps_per_window", "at least 1"]);
    let e = err(dir.path(), &base, &["time.internal_step=0.0"]);
    assert_has(&e, &["time.internal_step", "positive"]);
    // Wrong type, with the line in the file.
    let e = err(
        dir.path(),
        &format!("version = 1\n[time]\nwindow = \"short\"\n{CLOTH}"),
        &[],
    );
    assert_has(&e, &["scene.toml", "line 3", "window"]);
}

#[test]
fn an_internal_step_above_the_stability_step_is_refused_naming_both() {
    let dir = tempfile::tempdir().unwrap();
    let base = format!("version = 1\n{CLOTH}");
    let s = load(dir.path(), &base, &[]).unwrap();
    let w = World::build(&s.world).unwrap();
    let limit = 2.0 / w.omega_max;
    // Just below the limit builds; just above is refused.
    let ok = load(
        dir.path(),
        &base,
        &[&format!("time.internal_step={:e}", 0.99 * limit)],
    )
    .unwrap();
    assert!(World::build(&ok.world).is_ok());
    let above = 1.01 * limit;
    let bad = load(
        dir.path(),
        &base,
        &[&format!("time.internal_step={above:e}")],
    )
    .unwrap();
    let e = World::build(&bad.world).unwrap_err().to_string();
    assert_has(
        &e,
        &[
            "stability step",
            &format!("{above:e}"),
            &format!("{limit:e}"),
        ],
    );
    // The same through time.window / time.steps_per_window.
    let bad = load(
        dir.path(),
        &base,
        &[
            &format!("time.window={:e}", 10.0 * above),
            "time.steps_per_window=10",
        ],
    )
    .unwrap();
    let e = World::build(&bad.world).unwrap_err().to_string();
    assert_has(&e, &["stability step", "time.window"]);
}

// ---------------------------------------------------------------- motion

#[test]
fn translate_until_is_read_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "version = 1\n{CLOTH}\n[[pin]]\nname = \"end\"\nobject = \"cloth\"\nindices = [0, 5]\n\
         motion = {{ kind = \"translate\", velocity = [0.5, 0.0, 0.0], until = 0.25 }}\n"
    );
    let s = load(dir.path(), &text, &[]).unwrap();
    assert_eq!(
        s.world.pins[0].motion,
        Motion::Translate {
            velocity: DVec3::new(0.5, 0.0, 0.0),
            until: Some(0.25)
        }
    );
    // The pinned vertices stop where the script says.
    let mut e = Engine::new(World::build(&s.world).unwrap(), Serial).unwrap();
    let x0 = e.world.x[0];
    while e.world.time() < 0.4 {
        e.step_window().unwrap();
    }
    let moved = e.world.x[0] - x0;
    assert!(
        (moved - DVec3::new(0.125, 0.0, 0.0)).length() < 1e-12,
        "moved {moved:?}"
    );
    assert!(e.world.v[0].length() < 1e-9, "{:?}", e.world.v[0]);
    let s = load(dir.path(), &text, &["pin.0.motion.until=-1.0"]);
    assert_has(
        &s.unwrap_err().to_string(),
        &["pin[0] 'end'.motion.until", "non-negative"],
    );
    let e = err(
        dir.path(),
        &text,
        &[
            "pin.0.motion.kind=rotate",
            "pin.0.motion.omega=[[0.0, 1.0]]",
        ],
    );
    assert_has(&e, &["motion.until", "translate"]);
}

// ---------------------------------------------------------------- rest shapes

/// A 3 × 3 vertex OBJ sheet in the xz plane at y = `y`, with texture
/// coordinates `uv_of(i, j)` on every corner (`None`: no `vt`).
fn sheet_obj(y: f64, uv_of: Option<&dyn Fn(usize, usize) -> [f64; 2]>) -> String {
    let mut s = String::new();
    for j in 0..3 {
        for i in 0..3 {
            s += &format!("v {} {y} {}\n", 0.1 * i as f64, 0.1 * j as f64);
        }
    }
    if let Some(f) = uv_of {
        for j in 0..3 {
            for i in 0..3 {
                let [u, v] = f(i, j);
                s += &format!("vt {u} {v}\n");
            }
        }
    }
    for j in 0..2 {
        for i in 0..2 {
            let a = j * 3 + i + 1;
            let (b, c, d) = (a + 1, a + 4, a + 3);
            if uv_of.is_some() {
                s += &format!("f {a}/{a} {c}/{c} {b}/{b}\nf {a}/{a} {d}/{d} {c}/{c}\n");
            } else {
                s += &format!("f {a} {c} {b}\nf {a} {d} {c}\n");
            }
        }
    }
    s
}

fn cloth_rest(s: &weft_io::scene::Scene) -> Option<Vec<DVec3>> {
    match &s.world.objects[0].kind {
        ObjectKind::Cloth { rest, .. } => rest.clone(),
        _ => panic!("object 0 is a cloth"),
    }
}

#[test]
fn rest_shape_from_uvs() {
    let dir = tempfile::tempdir().unwrap();
    // UVs of a 0.05-unit grid, stretched 2x along u: at uv_scale = 2 the rest
    // shape is 0.2 × 0.1 m while the start shape is 0.2 × 0.2 m.
    let uv = |i: usize, j: usize| [0.1 * i as f64, 0.05 * j as f64];
    write(dir.path(), "sheet.obj", &sheet_obj(0.5, Some(&uv)));
    let text = "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"sheet.obj\"\nrest = \"uv\"\nuv_scale = 2.0\n";
    let s = load(dir.path(), text, &[]).unwrap();
    let rest = cloth_rest(&s).unwrap();
    for j in 0..3 {
        for i in 0..3 {
            let [u, v] = uv(i, j);
            assert_eq!(rest[j * 3 + i], DVec3::new(2.0 * u, 2.0 * v, 0.0));
        }
    }
    // The world builds and the rest area is the UV area times scale².
    let w = World::build(&s.world).unwrap();
    let mass: f64 = w.mass.iter().sum();
    assert!((mass - 0.2 * (0.4 * 0.2)).abs() < 1e-15, "mass {mass}");
    // Errors: no UVs, a seam, a generated cloth, a uv_scale without "uv".
    write(dir.path(), "plain.obj", &sheet_obj(0.5, None));
    let e = err(dir.path(), &text.replace("sheet.obj", "plain.obj"), &[]);
    assert_has(
        &e,
        &["cloth[0] 'c'.rest", "plain.obj", "texture coordinates"],
    );
    let mut seam = sheet_obj(0.5, Some(&uv));
    seam = seam.replacen("f 1/1 5/5 2/2", "f 1/9 5/5 2/2", 1);
    write(dir.path(), "seam.obj", &seam);
    let e = err(dir.path(), &text.replace("sheet.obj", "seam.obj"), &[]);
    assert_has(
        &e,
        &["seam.obj:", "v 1 has two texture coordinates", "seam"],
    );
    let e = err(
        dir.path(),
        &format!("version = 1\n{CLOTH}rest = \"uv\"\n"),
        &[],
    );
    assert_has(&e, &["cloth[0] 'cloth'.rest", "mesh file"]);
    let e = err(
        dir.path(),
        &format!("version = 1\n{CLOTH}uv_scale = 2.0\n"),
        &[],
    );
    assert_has(&e, &["uv_scale", "uv"]);
    let e = err(dir.path(), text, &["cloth.0.uv_scale=0.0"]);
    assert_has(&e, &["uv_scale", "positive"]);
    let e = err(dir.path(), text, &["cloth.0.rest=round"]);
    assert_has(&e, &["unknown rest shape 'round'", "uv"]);
}

#[test]
fn rest_shape_from_a_rest_mesh() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "start.obj", &sheet_obj(0.5, None));
    // The rest mesh: the same sheet, 10 % larger (a prestretched start).
    let rest_text: String = sheet_obj(0.0, None)
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(r) => {
                let c: Vec<f64> = r.split(' ').map(|x| x.parse().unwrap()).collect();
                format!("v {} {} {}\n", 1.1 * c[0], c[1], 1.1 * c[2])
            }
            None => format!("{l}\n"),
        })
        .collect();
    write(dir.path(), "rest.obj", &rest_text);
    let text =
        "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"start.obj\"\nrest_mesh = \"rest.obj\"\n\
                transform = { translate = [0.0, 0.25, 0.0] }\n";
    let s = load(dir.path(), text, &[]).unwrap();
    let rest = cloth_rest(&s).unwrap();
    // The cloth's transform applies to the rest mesh too.
    assert_eq!(rest[4], DVec3::new(1.1 * 0.1, 0.25, 1.1 * 0.1));
    assert_eq!(
        s.world.objects[0].mesh.positions[4],
        DVec3::new(0.1, 0.75, 0.1)
    );
    World::build(&s.world).unwrap();
    // Different connectivity, a missing file, and both rest keys at once.
    write(
        dir.path(),
        "flipped.obj",
        &rest_text.replacen("f 1 5 2", "f 1 2 5", 1),
    );
    let e = err(dir.path(), &text.replace("rest.obj", "flipped.obj"), &[]);
    assert_has(&e, &["cloth[0] 'c'.rest_mesh", "flipped.obj", "triangle 0"]);
    write(
        dir.path(),
        "fewer.obj",
        "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n",
    );
    let e = err(dir.path(), &text.replace("rest.obj", "fewer.obj"), &[]);
    assert_has(&e, &["rest_mesh", "fewer.obj has 3 vertices", "has 9"]);
    let e = err(dir.path(), &text.replace("rest.obj", "gone.obj"), &[]);
    assert_has(&e, &["rest_mesh", "gone.obj"]);
    assert!(load(dir.path(), &format!("{text}rest = \"initial\"\n"), &[]).is_ok());
    let e = err(dir.path(), text, &["cloth.0.rest=uv"]);
    assert_has(&e, &["rest_mesh", "not both"]);
}

// ---------------------------------------------------------------- camera

#[test]
fn camera_is_optional_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let base = format!("version = 1\n{CLOTH}");
    assert!(load(dir.path(), &base, &[]).unwrap().camera.is_none());
    let text = format!("{base}\n[camera]\neye = [1.0, 2.0, 3.0]\ntarget = [0.0, 0.5, 0.0]\n");
    let c = load(dir.path(), &text, &[]).unwrap().camera.unwrap();
    assert_eq!(c.eye, [1.0, 2.0, 3.0]);
    assert_eq!(c.target, [0.0, 0.5, 0.0]);
    assert_eq!(c.up, [0.0, 1.0, 0.0]);
    assert_eq!(c.fov_degrees, 40.0);
    let c = load(dir.path(), &text, &["camera.fov_degrees=25"])
        .unwrap()
        .camera
        .unwrap();
    assert_eq!(c.fov_degrees, 25.0);
    assert_has(
        &err(dir.path(), &text, &["camera.fov_degrees=180"]),
        &["camera.fov_degrees"],
    );
    assert_has(
        &err(dir.path(), &text, &["camera.target=[1.0, 2.0, 3.0]"]),
        &["camera.target", "differ"],
    );
    assert_has(
        &err(dir.path(), &text, &["camera.up=[-1.0, -1.5, -3.0]"]),
        &["camera.up", "parallel"],
    );
    let e = err(dir.path(), &format!("{text}zoom = 2\n"), &[]);
    assert_has(&e, &["unknown field `zoom`", "line"]);
}

// ---------------------------------------------------------------- grids with holes, boundary pins

#[test]
fn punched_grid_with_a_smaller_rest_hole_and_boundary_pins() {
    let dir = tempfile::tempdir().unwrap();
    let text = r#"
version = 1
[[cloth]]
name = "sheet"
grid = { size = [0.4, 0.4], resolution = [21, 21], center = [0.0, 0.3, 0.0], hole = { radius = 0.05, rest_radius = 0.03 } }
rest = "flat"

[[pin]]
name = "border"
object = "sheet"
boundary = "outer"
"#;
    let s = load(dir.path(), text, &[]).unwrap();
    let m = &s.world.objects[0].mesh;
    // Spacing 2 cm: the grid points closer than 5 cm + half a spacing go; a
    // ring of 2π · 5 cm / 2 cm ≈ 16 vertices lines the hole.
    let removed = (0..21 * 21)
        .filter(|k| {
            let (i, j) = ((k % 21) as f64 - 10.0, (k / 21) as f64 - 10.0);
            0.02 * (i * i + j * j).sqrt() < 0.06
        })
        .count();
    assert_eq!(m.num_vertices(), 21 * 21 - removed + 16);
    let center = DVec3::new(0.0, 0.3, 0.0);
    let on_rim: Vec<usize> = (0..m.num_vertices())
        .filter(|&k| ((m.positions[k] - center).length() - 0.05).abs() < 1e-14)
        .collect();
    assert_eq!(on_rim.len(), 16);
    assert!(m
        .positions
        .iter()
        .all(|p| (*p - center).length() >= 0.05 - 1e-14));
    // The rest shape pulls the rim in to 3 cm, linearly out to the identity
    // at 10 cm, and leaves the far field.
    let rest = cloth_rest(&s).unwrap();
    let mut in_band = 0;
    for (p, r) in m.positions.iter().zip(&rest) {
        let d = (*p - center).length();
        if d < 0.1 {
            in_band += 1;
            let want = 0.03 + (d - 0.05) * (0.1 - 0.03) / (0.1 - 0.05);
            assert!(((*r - center).length() - want).abs() < 1e-12);
            assert!((*r - center).normalize().dot((*p - center).normalize()) > 1.0 - 1e-12);
        } else {
            assert_eq!(r, p);
        }
    }
    assert!(in_band >= 30, "{in_band} vertices in the band");
    for &k in &on_rim {
        assert!(((rest[k] - center).length() - 0.03).abs() < 1e-14);
    }
    // The outer pin holds exactly the 80 border vertices, not the rim.
    let border = &s.world.pins[0].vertices;
    assert_eq!(border.len(), 80);
    for &v in border {
        let p = m.positions[v as usize];
        assert!(p.x.abs() > 0.199 || p.z.abs() > 0.199, "{p:?}");
    }
    // "all" adds the rim.
    let s = load(dir.path(), text, &["pin.0.boundary=all"]).unwrap();
    assert!(s.world.pins[0].vertices.len() > 80);
    let w = World::build(&s.world).unwrap();
    assert_eq!(w.objects[0].vertices.len(), m.num_vertices());
    // Errors: unknown boundary, a hole that misses every vertex or does not fit.
    assert_has(
        &err(dir.path(), text, &["pin.0.boundary=inner"]),
        &["pin[0] 'border'.boundary", "unknown boundary 'inner'"],
    );
    assert_has(
        &err(
            dir.path(),
            text,
            &[
                "cloth.0.grid.hole.radius=0.002",
                "cloth.0.grid.hole.center=[0.01, 0.01]",
            ],
        ),
        &["cloth[0] 'sheet'.grid.hole", "catches no vertex"],
    );
    assert_has(
        &err(dir.path(), text, &["cloth.0.grid.hole.center=[0.15, 0.0]"]),
        &["grid.hole", "inside"],
    );
    assert_has(
        &err(dir.path(), text, &["cloth.0.grid.hole.rest_radius=-1.0"]),
        &["grid.hole", "positive"],
    );
}

// ---------------------------------------------------------------- mesh sequences

/// A square plate (two triangles, 4 vertices, normal +y) of half-size `a` at
/// height `y`, as OBJ text.
fn plate_obj(a: f64, y: f64) -> String {
    format!(
        "v {} {y} {}\nv {a} {y} {}\nv {a} {y} {a}\nv {} {y} {a}\nf 1 3 2\nf 1 4 3\n",
        -a, -a, -a, -a
    )
}

#[test]
fn mesh_sequence_frames_are_read_validated_and_hit_exactly() {
    let dir = tempfile::tempdir().unwrap();
    // Frames written out of order on disk; the pattern sorts by name. The
    // heights are not representable exactly in binary, so only a reader that
    // hands the file's values through untouched matches them bit for bit.
    let heights = [0.0, 0.013, 0.041, 0.07];
    for (i, y) in heights.iter().enumerate().rev() {
        write(
            dir.path(),
            &format!("walk/f{:04}.obj", i + 1),
            &plate_obj(0.3, *y),
        );
    }
    write(dir.path(), "walk/notes.txt", "not a frame");
    let text = r#"
version = 1
[[cloth]]
name = "cloth"
grid = { size = [0.2, 0.2], resolution = [6, 6], center = [0.0, 0.5, 0.0] }

[[obstacle]]
name = "plate"
mesh_sequence = { pattern = "walk/f*.obj", frame_rate = 10.0, start = 0.05 }
transform = { scale = 2.0, translate = [0.0, 0.1, 0.0] }
"#;
    let s = load(dir.path(), text, &[]).unwrap();
    let Motion::Sequence(k) = (match &s.world.objects[1].kind {
        ObjectKind::Obstacle { motion } => motion.clone(),
        _ => panic!(),
    }) else {
        panic!("a sequence motion")
    };
    assert_eq!(k.frames.len(), 4);
    assert_eq!((k.frame_rate, k.start), (10.0, 0.05));
    // The transform applies to every frame.
    for (i, y) in heights.iter().enumerate() {
        let want = DVec3::new(-0.6, 2.0 * y + 0.1, -0.6);
        assert_eq!(k.frames[i][0], want, "frame {i}");
    }
    // Through the world's script: frame positions exactly at frame times,
    // held before the start and after the end, linear in between.
    let w = World::build(&s.world).unwrap();
    let script = w.scripts.iter().find(|s| s.name == "plate").unwrap();
    for (i, frame) in k.frames.iter().enumerate() {
        let t = 0.05 + i as f64 / 10.0;
        for (v, p) in frame.iter().enumerate() {
            assert_eq!(script.position(v, t), *p);
        }
    }
    assert_eq!(script.position(2, 0.0), k.frames[0][2]);
    assert_eq!(script.position(2, 9.0), k.frames[3][2]);
    let mid = script.position(1, 0.05 + 0.15);
    let want = (k.frames[1][1] + k.frames[2][1]) * 0.5;
    assert!((mid - want).length() < 1e-14, "{mid:?} {want:?}");
    // The same frames listed explicitly.
    let listed = text.replace(
        r#"pattern = "walk/f*.obj""#,
        r#"files = ["walk/f0001.obj", "walk/f0002.obj", "walk/f0003.obj", "walk/f0004.obj"]"#,
    );
    let s2 = load(dir.path(), &listed, &[]).unwrap();
    assert_eq!(s2.world.objects[1], s.world.objects[1]);

    // A frame with a different vertex count or different faces is named.
    write(
        dir.path(),
        "walk/f0003.obj",
        &(plate_obj(0.3, 0.041) + "v 0 0 0\n"),
    );
    let e = err(dir.path(), text, &[]);
    assert_has(
        &e,
        &[
            "obstacle[0] 'plate'.mesh_sequence.files[2]",
            "walk/f0003.obj has 5 vertices",
            "f0001.obj",
        ],
    );
    write(
        dir.path(),
        "walk/f0003.obj",
        &plate_obj(0.3, 0.041)
            .replace("f 1 4 3", "f 1 3 4")
            .replace("f 1 3 2", "f 1 2 3"),
    );
    let e = err(dir.path(), text, &[]);
    assert_has(
        &e,
        &["mesh_sequence.files[2]", "walk/f0003.obj: triangle 0"],
    );
    write(dir.path(), "walk/f0003.obj", &plate_obj(0.3, 0.041));
    // Missing files, empty patterns, bad keys.
    let e = err(dir.path(), &listed.replace("f0004", "f0009"), &[]);
    assert_has(&e, &["mesh_sequence.files[3]", "f0009.obj"]);
    let e = err(dir.path(), &text.replace("walk/f*.obj", "walk/g*.obj"), &[]);
    assert_has(&e, &["mesh_sequence.pattern", "matches no file"]);
    let e = err(dir.path(), &text.replace("walk/f*.obj", "w*/f*.obj"), &[]);
    assert_has(&e, &["mesh_sequence.pattern", "file name only"]);
    let e = err(dir.path(), text, &["obstacle.0.mesh_sequence.frame_rate=0"]);
    assert_has(&e, &["mesh_sequence.frame_rate", "positive"]);
    let e = err(
        dir.path(),
        &text.replace("start = 0.05", "start = 0.05, fps = 3"),
        &[],
    );
    assert_has(&e, &["unknown field `fps`", "line 9"]);
    let e = err(dir.path(), &text.replace("frame_rate = 10.0, ", ""), &[]);
    assert_has(&e, &["frame_rate"]);
    let e = err(
        dir.path(),
        &format!("{text}mesh = \"walk/f0001.obj\"\n"),
        &[],
    );
    assert_has(&e, &["exactly one of", "mesh_sequence"]);
    let e = err(
        dir.path(),
        &format!("{text}motion = {{ kind = \"translate\", velocity = [1.0, 0.0, 0.0] }}\n"),
        &[],
    );
    assert_has(&e, &["obstacle[0] 'plate'.motion", "frames"]);
    let e = err(
        dir.path(),
        &text.replace(r#"pattern = "walk/f*.obj", "#, ""),
        &[],
    );
    assert_has(&e, &["mesh_sequence", "files"]);
}

/// A plate that rises along a mesh sequence lifts the cloth lying on it, and
/// the plate's vertices follow the sequence.
#[test]
fn a_rising_plate_sequence_lifts_the_cloth() {
    let dir = tempfile::tempdir().unwrap();
    // Frames at 10 fps: the plate rises 6 cm between 0.1 s and 0.4 s, then stops.
    let heights = [0.0, 0.0, 0.02, 0.04, 0.06];
    for (i, y) in heights.iter().enumerate() {
        write(dir.path(), &format!("rise/{i}.obj"), &plate_obj(0.3, *y));
    }
    let text = r#"
version = 1
[time]
end = 0.6
[contact]
thickness = 2e-3
friction = 0.3
[[cloth]]
name = "cloth"
grid = { size = [0.2, 0.2], resolution = [8, 8], center = [0.0, 0.006, 0.0] }
[cloth.material]
stretch_damping = 2e-4
[[obstacle]]
name = "plate"
mesh_sequence = { pattern = "rise/*.obj", frame_rate = 10.0 }
"#;
    let s = load(dir.path(), text, &[]).unwrap();
    let mut e = Engine::new(World::build(&s.world).unwrap(), Serial).unwrap();
    let cloth = e.world.objects[0].vertices.clone();
    let plate = e.world.objects[1].vertices.clone();
    let mean_y =
        |w: &World| cloth.clone().map(|i| w.x[i as usize].y).sum::<f64>() / cloth.len() as f64;
    let (mut rollbacks, mut lowest_gap) = (0, f64::INFINITY);
    while e.world.time() < 0.6 {
        let st = e.step_window().unwrap().stats;
        rollbacks += st.rollbacks;
        let w = &e.world;
        let t = w.time();
        // The plate is where the sequence puts it (chords end on the script).
        let script = w.scripts.iter().find(|s| s.name == "plate").unwrap();
        for (k, i) in plate.clone().enumerate() {
            let d = (w.x[i as usize] - script.position(k, t)).length();
            assert!(
                d < 1e-12,
                "t = {t}: plate vertex {k} is {d:e} m off its script"
            );
        }
        let top = w.x[plate.start as usize].y;
        let low = cloth
            .clone()
            .map(|i| w.x[i as usize].y)
            .fold(f64::INFINITY, f64::min);
        lowest_gap = lowest_gap.min(low - top);
    }
    let w = &e.world;
    let top = w.x[plate.start as usize].y;
    assert!((top - 0.06).abs() < 1e-12, "plate at {top}");
    // The cloth rests on the plate, 6 cm higher than it started falling onto it.
    let y = mean_y(w);
    assert!(y > 0.06 && y < 0.06 + 0.004, "cloth mean height {y}");
    assert!(
        lowest_gap > 0.0,
        "the cloth never passes the plate: gap {lowest_gap:e}"
    );
    assert!(rollbacks >= 1, "the plate must push the cloth");
}

// ---------------------------------------------------------------- tubes

#[test]
fn tube_generator_with_a_narrower_rest_and_size_scaling() {
    let dir = tempfile::tempdir().unwrap();
    let text = r#"
version = 1
[[cloth]]
name = "sleeve"
tube = { from = [-0.4, 0.0, 0.0], to = [0.4, 0.0, 0.0], radius = 0.05, rest_radius = 0.04, resolution = [12, 9] }
rest = "flat"

[[pin]]
name = "ends"
object = "sleeve"
boundary = "all"
"#;
    let s = load(dir.path(), text, &[]).unwrap();
    let m = &s.world.objects[0].mesh;
    assert_eq!(m.num_vertices(), 12 * 9);
    let rest = cloth_rest(&s).unwrap();
    for (p, r) in m.positions.iter().zip(&rest) {
        assert!((DVec3::new(0.0, p.y, p.z).length() - 0.05).abs() < 1e-15);
        assert!((DVec3::new(0.0, r.y, r.z).length() - 0.04).abs() < 1e-15);
        assert_eq!(p.x, r.x);
    }
    // Both end rings are the boundary.
    let pins = &s.world.pins[0].vertices;
    assert_eq!(pins.len(), 24);
    assert!(pins.iter().all(|&v| m.positions[v as usize].x.abs() == 0.4));
    // `size` scales both resolutions like a grid's.
    let s = load(dir.path(), text, &["size=432"]).unwrap();
    assert_eq!(s.world.objects[0].mesh.num_vertices(), 24 * 18);
    // The start shape without `rest`: no prestress.
    let s = load(dir.path(), text, &["cloth.0.rest=initial"]).unwrap();
    assert!(cloth_rest(&s).is_none());
    assert_has(
        &err(dir.path(), text, &["cloth.0.tube.rest_radius=0.0"]),
        &["cloth[0] 'sleeve'.tube", "positive"],
    );
    assert_has(
        &err(dir.path(), text, &["cloth.0.tube.to=[-0.4, 0.0, 0.0]"]),
        &["cloth[0] 'sleeve'.tube", "distinct"],
    );
    assert_has(
        &err(
            dir.path(),
            text,
            &["cloth.0.grid={ size = [0.1, 0.1], resolution = [3, 3] }"],
        ),
        &["cloth[0] 'sleeve'", "exactly one of", "tube"],
    );
}

// ---------------------------------------------------------------- third-party meshes

/// `sheet_obj(0.5, None)` written out as a triangle soup: one vertex per
/// triangle corner, as some exporters write (8 triangles, 24 vertices on 9
/// positions).
fn soup_obj() -> String {
    let mut s = String::new();
    let p = |k: usize| (0.1 * (k % 3) as f64, 0.1 * (k / 3) as f64);
    let mut corners = 0;
    for j in 0..2 {
        for i in 0..2 {
            let a = j * 3 + i;
            for tri in [[a, a + 4, a + 1], [a, a + 3, a + 4]] {
                for k in tri {
                    let (x, z) = p(k);
                    s += &format!("v {x} 0.5 {z}\n");
                }
                s += &format!("f {} {} {}\n", corners + 1, corners + 2, corners + 3);
                corners += 3;
            }
        }
    }
    s
}

/// What used to happen: the soup loaded, and `weft run` refused it at the
/// start with "... apart, closer than the separation floor ...; move the
/// objects apart", a cure that cannot work.
#[test]
fn an_unwelded_cloth_is_refused_with_the_count_and_the_first_places() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "soup.obj", &soup_obj());
    let cloth = "version = 1\n[[cloth]]\nname = \"rag\"\nmesh = \"soup.obj\"\n";
    let e = err(dir.path(), cloth, &[]);
    // 24 vertices on 9 positions (two of them used once): welding removes 15.
    assert_has(
        &e,
        &[
            "cloth[0] 'rag'",
            "soup.obj: 15 vertices lie exactly on other vertices, at 7 places",
            "(v 1 = v 4; v 2 = v 6 = v 11 = v 15 = v 19 = v 22;",
            "weld the mesh (15 coincident vertices)",
        ],
    );
    // As an obstacle the same soup is fine: nothing there holds together.
    let obstacle =
        format!("version = 1\n{CLOTH}\n[[obstacle]]\nname = \"plate\"\nmesh = \"soup.obj\"\n");
    load(dir.path(), &obstacle, &[]).unwrap();
    // A PLY soup names its vertices 0-based, as PLY does.
    let m = weft_io::read_obj(&dir.path().join("soup.obj"))
        .unwrap()
        .mesh;
    weft_io::write_ply(
        &dir.path().join("soup.ply"),
        &m.positions,
        &m.triangles,
        None,
    )
    .unwrap();
    let e = err(dir.path(), &cloth.replace("soup.obj", "soup.ply"), &[]);
    assert_has(
        &e,
        &[
            "(vertex 0 (0-based) = vertex 3 (0-based)",
            "weld the mesh (15 coincident vertices)",
        ],
    );
}

/// A welded cloth with a stray duplicate of one of its vertices that no
/// triangle uses (a common export leftover, which validation only warns
/// about) is not an unwelded mesh: the triangles are joined. It loads, with
/// the warning about the unused vertex.
#[test]
fn an_unused_duplicate_vertex_is_not_an_unwelded_mesh() {
    let dir = tempfile::tempdir().unwrap();
    write(
        dir.path(),
        "stray.obj",
        "v 0 0.5 0\nv 0.1 0.5 0\nv 0.1 0.5 0.1\nv 0 0.5 0.1\nv 0.1 0.5 0.1\nf 1 2 3\nf 1 3 4\n",
    );
    let s = load(
        dir.path(),
        "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"stray.obj\"\n",
        &[],
    )
    .unwrap_or_else(|e| panic!("refused: {e}"));
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert_has(&s.warnings[0], &["stray.obj", "v 5"]);

    // Two used vertices on one position are still refused, and a stray
    // there does not count as a third.
    write(
        dir.path(),
        "split.obj",
        "v 0 0.5 0\nv 0.1 0.5 0\nv 0.1 0.5 0.1\nv 0 0.5 0.1\nv 0.1 0.5 0.1\nv 0 0.5 0\n\
         v 0 0.5 0\nf 1 2 3\nf 6 5 4\n",
    );
    let e = err(
        dir.path(),
        "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"split.obj\"\n",
        &[],
    );
    assert_has(
        &e,
        &[
            "split.obj: 2 vertices lie exactly on other vertices, at 2 places (v 1 = v 6; v 3 = v 5)",
            "weld the mesh (2 coincident vertices)",
        ],
    );
}

#[test]
fn mesh_warnings_are_kept_for_the_start_up_in_the_files_numbering() {
    let dir = tempfile::tempdir().unwrap();
    // The second face is flipped: both faces traverse the edge v 3 -> v 1.
    // What used to happen: nothing said so (the reader's warnings were dropped).
    write(
        dir.path(),
        "flip.obj",
        "v 0 0.5 0\nv 0.1 0.5 0\nv 0.1 0.5 0.1\nv 0 0.5 0.1\nf 1 2 3\n# flipped\nf 1 4 3\n",
    );
    let s = load(
        dir.path(),
        "version = 1\n[[cloth]]\nname = \"c\"\nmesh = \"flip.obj\"\n",
        &[],
    )
    .unwrap();
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert_has(
        &s.warnings[0],
        &[
            "cloth[0] 'c': flip.obj: 1 interior edges are inconsistently oriented",
            "from v 3 to v 1",
            "the face on line 5 and the face on line 7",
        ],
    );
    // The bundled generators make clean meshes.
    let s = load(dir.path(), &format!("version = 1\n{CLOTH}"), &[]).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
}

#[test]
fn transform_scale_takes_one_factor_or_three() {
    let dir = tempfile::tempdir().unwrap();
    let base = format!("version = 1\n{CLOTH}");
    let extent = |s: &weft_io::scene::Scene| {
        let (lo, hi) = weft_core::mesh::bounding_box(&s.world.objects[0].mesh.positions);
        hi - lo
    };
    let plain = extent(&load(dir.path(), &base, &[]).unwrap());
    let uniform = extent(&load(dir.path(), &base, &["cloth.0.transform.scale=2.0"]).unwrap());
    assert_eq!(uniform, plain * 2.0);
    let s = load(
        dir.path(),
        &base,
        &[
            "cloth.0.transform.scale=[3.0, 1.0, 0.5]",
            "cloth.0.transform.translate=[0.0, 1.0, 0.0]",
        ],
    )
    .unwrap();
    assert_eq!(extent(&s), plain * DVec3::new(3.0, 1.0, 0.5));
    // Scaled before it is moved: the grid's centre (0, 0.1, 0) lands at (0, 1.1, 0).
    let (lo, hi) = weft_core::mesh::bounding_box(&s.world.objects[0].mesh.positions);
    assert!((0.5 * (lo + hi) - DVec3::new(0.0, 1.1, 0.0)).length() < 1e-12);
    for bad in ["[1.0, 0.0, 1.0]", "-1.0", "[1.0, inf, 1.0]"] {
        let e = err(
            dir.path(),
            &base,
            &[&format!("cloth.0.transform.scale={bad}")],
        );
        assert_has(
            &e,
            &[
                "cloth[0] 'cloth'.transform.scale",
                "[sx, sy, sz] of positive numbers",
            ],
        );
    }
    let e = err(dir.path(), &base, &["cloth.0.transform.scale=[1.0, 2.0]"]);
    assert_has(&e, &["a number or an array of three numbers [sx, sy, sz]"]);
}

/// A scene whose cloth is a 0.4 m × 0.2 m grid, moved and stretched by its
/// transform, with one pin given by `pin`.
fn pinned_sheet(pin: &str) -> String {
    format!(
        r#"version = 1
[[cloth]]
name = "sheet"
grid = {{ size = [0.4, 0.2], resolution = [9, 5], center = [0.0, 0.5, 0.0] }}
transform = {{ scale = [2.0, 1.0, 1.0], translate = [1.0, 0.0, -0.3] }}

[[pin]]
name = "edge"
object = "sheet"
{pin}
"#
    )
}

fn pinned(s: &weft_io::scene::Scene) -> Vec<u32> {
    s.world.pins[0].vertices.clone()
}

#[test]
fn a_relative_pin_box_selects_what_the_equivalent_absolute_box_does() {
    let dir = tempfile::tempdir().unwrap();
    // The sheet spans x in [0.6, 1.4], y = 0.5, z in [-0.4, -0.2]: the row at
    // the largest z and the column at the smallest x.
    let relative = load(
        dir.path(),
        &pinned_sheet("box_min = [0.0, 0.0, 0.9]\nbox_max = [1.0, 1.0, 1.0]\nrelative = true"),
        &[],
    )
    .unwrap();
    let absolute = load(
        dir.path(),
        &pinned_sheet("box_min = [0.5, 0.4, -0.21]\nbox_max = [1.5, 0.6, -0.19]"),
        &[],
    )
    .unwrap();
    assert_eq!(pinned(&relative).len(), 9);
    assert_eq!(pinned(&relative), pinned(&absolute));
    // 0 and 1 are exactly the bounding box: its faces are inside.
    let column = load(
        dir.path(),
        &pinned_sheet("box_min = [0.0, 0.0, 0.0]\nbox_max = [0.0, 1.0, 1.0]\nrelative = true"),
        &[],
    )
    .unwrap();
    assert_eq!(pinned(&column), vec![0, 9, 18, 27, 36]);
}

#[test]
fn a_pin_box_that_selects_nothing_names_the_pin_and_the_object() {
    let dir = tempfile::tempdir().unwrap();
    // Millimetres instead of metres.
    let e = err(
        dir.path(),
        &pinned_sheet("box_min = [500.0, 400.0, -210.0]\nbox_max = [1500.0, 600.0, -190.0]"),
        &[],
    );
    assert_has(
        &e,
        &[
            "pin[0] 'edge'.box_min",
            "selects no vertex of cloth 'sheet'",
            "bounding box runs from [0.6",
        ],
    );
    let e = err(
        dir.path(),
        &pinned_sheet("box_min = [2.0, 0.0, 0.0]\nbox_max = [3.0, 1.0, 1.0]\nrelative = true"),
        &[],
    );
    assert_has(
        &e,
        &[
            "pin[0] 'edge'.box_min: the box from [2.19",
            "(relative = true: [2.0, 0.0, 0.0] to [3.0, 1.0, 1.0] of the bounding box)",
            "cloth 'sheet'",
        ],
    );
    let e = err(
        dir.path(),
        &pinned_sheet("indices = [0]\nrelative = true"),
        &[],
    );
    assert_has(&e, &["pin[0] 'edge'.relative", "give box_min and box_max"]);
}
