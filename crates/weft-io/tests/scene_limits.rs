//! Scenes too large for the machine are refused while loading, before a
//! generator allocates anything: the message names the key, the vertex and
//! triangle counts and the bytes the run would need. And the `[output]` keys
//! a run reads for its schedule are checked.

use std::path::{Path, PathBuf};

use weft_io::scene::load_scene;

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name)
}

fn refusal(name: &str, overrides: &[&str]) -> String {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    match load_scene(&scene(name), &o) {
        Ok(s) => panic!(
            "{name} {overrides:?} loaded ({} objects)",
            s.world.objects.len()
        ),
        Err(e) => e.to_string(),
    }
}

fn assert_has(msg: &str, fragments: &[&str]) {
    for f in fragments {
        assert!(msg.contains(f), "message lacks '{f}': {msg}");
    }
}

/// 10^10 vertices need tens of terabytes: more than any machine these tests
/// run on. Were the mesh allocated first, the process would abort instead.
#[test]
fn absurd_sizes_are_refused_before_anything_is_allocated() {
    let e = refusal("drape.toml", &["size=1e10"]);
    assert_has(
        &e,
        &[
            "drape.toml",
            "cloth[0] 'cloth'.grid.resolution",
            "scaled by size = 10000000000 to [100000, 100000]",
            "10000000000 vertices",
            "bytes) of memory",
            "TB",
        ],
    );
    let e = refusal("drape.toml", &["cloth.0.grid.resolution=[100000, 100000]"]);
    assert_has(
        &e,
        &["grid.resolution: resolution [100000, 100000] makes 10000000000 vertices"],
    );
    // Beyond what usize products hold.
    let e = refusal(
        "drape.toml",
        &["cloth.0.grid.resolution=[10000000000, 10000000000]"],
    );
    assert_has(&e, &["grid.resolution", "of memory"]);
    let e = refusal("twister.toml", &["size=1e10"]);
    assert_has(
        &e,
        &["'sleeve'.tube.resolution", "scaled by size", "of memory"],
    );
    let e = refusal(
        "twister.toml",
        &["obstacle.0.cylinder.segments=100000000000"],
    );
    assert_has(
        &e,
        &["'rod'.cylinder", "segments = 100000000000", "of memory"],
    );
    let e = refusal("reef-knot.toml", &["size=1e10"]);
    assert_has(&e, &["'ropes'.ribbon", "scaled by size", "of memory"]);
    let e = refusal(
        "reef-knot.toml",
        &["size=0", "cloth.0.ribbon.across=100000000000"],
    );
    assert_has(
        &e,
        &["'ropes'.ribbon", "across = 100000000000", "of memory"],
    );
}

#[test]
fn size_may_be_written_as_a_whole_float() {
    let a = load_scene(&scene("drape.toml"), &["size=400".into()]).unwrap();
    let b = load_scene(&scene("drape.toml"), &["size=4e2".into()]).unwrap();
    assert_eq!(
        a.world.objects[0].mesh.num_vertices(),
        b.world.objects[0].mesh.num_vertices()
    );
    assert_has(
        &refusal("drape.toml", &["size=400.5"]),
        &["size", "whole number"],
    );
    assert_has(&refusal("drape.toml", &["size=-4"]), &["size", "negative"]);
}

#[test]
fn checkpoint_minutes_is_read_and_checked() {
    let s = load_scene(&scene("drape.toml"), &[]).unwrap();
    assert_eq!(s.output.checkpoint_minutes, 10.0, "the default");
    let s = load_scene(
        &scene("drape.toml"),
        &["output.checkpoint_minutes=0.5".into()],
    )
    .unwrap();
    assert_eq!(s.output.checkpoint_minutes, 0.5);
    for bad in ["-1", "nan", "inf"] {
        let e = refusal("drape.toml", &[&format!("output.checkpoint_minutes={bad}")]);
        assert_has(
            &e,
            &[
                "output.checkpoint_minutes",
                "non-negative number of minutes",
            ],
        );
    }
}
