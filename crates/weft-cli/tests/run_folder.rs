//! What `weft run --out DIR` may do to DIR: a folder that holds something
//! other than a weft run is refused unless `--overwrite` is given; even then,
//! and when replacing an earlier run, only the files a run wrote are removed
//! (the manifest says which), so a user's own files survive; and an `--out`
//! that is a file is called a file.

use std::path::Path;
use std::process::Output;

mod common;
use common::{small_crumple, stderr, summary};

/// Replaces the folder's run with one that writes PLY frames only and no
/// checkpoint on a schedule (so one killed early has none).
const NO_SCHEDULE: [&str; 6] = [
    "--overwrite",
    "--no-preview",
    "--set",
    "output.checkpoint_every=0",
    "--set",
    "output.checkpoint_minutes=0",
];

fn run(out: &Path, extra: &[&str], failpoint: Option<&str>) -> Output {
    small_crumple(out, extra, failpoint)
        .arg("--quiet")
        .output()
        .expect("weft runs")
}

/// Every file under `dir`, relative to it, with its bytes.
fn tree(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut files = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.file_type().unwrap().is_dir() {
                stack.push(e.path());
            } else {
                let rel = e.path().strip_prefix(dir).unwrap().display().to_string();
                files.insert(rel, std::fs::read(e.path()).unwrap());
            }
        }
    }
    files
}

#[test]
fn a_folder_holding_other_files_is_refused_without_overwrite() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("notes.txt"), "my notes").unwrap();
    std::fs::write(dir.path().join("stats.jsonl"), "my own stats\n").unwrap();
    std::fs::create_dir(dir.path().join("render")).unwrap();
    std::fs::write(dir.path().join("render/frame_00000.png"), "mine").unwrap();
    let before = tree(dir.path());

    let o = run(dir.path(), &["--no-preview"], None);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("is not empty and holds no weft run") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(tree(dir.path()), before, "nothing touched");

    // Asked for, it writes there; what is not a run's output stays.
    let s = summary(&run(dir.path(), &["--overwrite", "--no-preview"], None));
    assert_eq!(s["complete"], true);
    assert_eq!(
        std::fs::read_to_string(dir.path().join("notes.txt")).unwrap(),
        "my notes"
    );
    assert_eq!(
        std::fs::read(dir.path().join("render/frame_00000.png")).unwrap(),
        b"mine",
        "no preview was made: render/ is as it was"
    );
}

/// `--overwrite` over an earlier run removes what that run wrote — frames in
/// every format it wrote, the VTK index, the preview and its PNG frames, the
/// checkpoint — and nothing else.
#[test]
fn overwrite_removes_only_the_files_the_earlier_run_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    // The earlier run: PLY and VTK frames and a preview.
    let formats = "output.formats=[\"ply\",\"vtk\"]";
    let first = summary(&run(
        out,
        &["--set", formats, "--set", "time.end=0.1"],
        None,
    ));
    assert!(out.join("frames.pvd").is_file() && out.join("render").is_dir());
    assert!(out.join("preview.mp4").is_file() || out.join("preview.gif").is_file());
    // The user's files, beside it and among its frames.
    std::fs::write(out.join("notes.txt"), "my notes").unwrap();
    std::fs::write(out.join("frames/README"), "about these frames").unwrap();

    // Without --overwrite: refused, naming both ways on.
    let o = run(out, &["--no-preview"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("already holds a run"), "{}", stderr(&o));

    // Replaced by a run that stops before its first checkpoint (PLY only,
    // no checkpoints on a schedule, killed in window 2).
    let o = run(out, &NO_SCHEDULE, Some("mid-window@2"));
    assert_eq!(o.status.code(), Some(weft_sim::failpoint::EXIT_CODE));
    let files = tree(out);
    let names: Vec<&str> = files.keys().map(String::as_str).collect();
    for kept in ["notes.txt", "frames/README"] {
        assert!(names.contains(&kept), "{kept} was removed: {names:?}");
    }
    for gone in [
        "frames.pvd",
        "preview.mp4",
        "preview.gif",
        "checkpoint.wckp",
    ] {
        assert!(!names.contains(&gone), "{gone} of the earlier run is left");
    }
    assert!(
        !names
            .iter()
            .any(|n| n.starts_with("frames-vtk") || n.starts_with("render")),
        "frames of the earlier run are left: {names:?}"
    );
    let frames = names.iter().filter(|n| n.ends_with(".ply")).count();
    assert!(
        frames < first["frames"].as_u64().unwrap() as usize,
        "only this run's frames: {names:?}"
    );
    // So the folder is not mistaken for the earlier run's checkpoint.
    let o = common::resume(out, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no checkpoint"), "{}", stderr(&o));
    let o = run(out, &["--no-preview"], None);
    assert!(
        stderr(&o).contains("ended before its first checkpoint")
            && !stderr(&o).contains("--resume"),
        "no round in circles: {}",
        stderr(&o)
    );
}

/// `--overwrite` into a folder that holds an earlier run's outputs but no
/// manifest (it was lost, or removed by hand): the files named as a run's
/// outputs are removed first — the fixed names and frames in every frame
/// folder — so no stale checkpoint or frame passes for the new run's. What
/// is not named as a run's output stays.
#[test]
fn overwrite_without_a_manifest_removes_the_files_named_as_a_runs() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    for folder in ["frames", "frames-obj", "frames-vtk"] {
        std::fs::create_dir(out.join(folder)).unwrap();
    }
    let stale = [
        "checkpoint.wckp",
        "frames.pvd",
        "preview.gif",
        "frames/frame_00500.ply",
        "frames-obj/frame_00000.obj",
        "frames-vtk/frame_00003.vtu",
    ];
    for f in stale {
        std::fs::write(out.join(f), "stale").unwrap();
    }
    std::fs::write(out.join("notes.txt"), "my notes").unwrap();
    std::fs::write(out.join("frames/README"), "about these frames").unwrap();

    // A run that stops before its first checkpoint, writing PLY frames only.
    let o = run(out, &NO_SCHEDULE, Some("mid-window@2"));
    assert_eq!(o.status.code(), Some(weft_sim::failpoint::EXIT_CODE));
    let files = tree(out);
    for f in stale {
        assert!(!files.contains_key(f), "{f} of the earlier run is left");
    }
    assert_eq!(files["notes.txt"], b"my notes");
    assert_eq!(files["frames/README"], b"about these frames");
    assert!(
        files.contains_key("frames/frame_00000.ply"),
        "the new run's frame"
    );
}

#[test]
fn an_out_that_is_a_file_is_called_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("afile");
    std::fs::write(&file, "data").unwrap();
    let o = run(&file, &["--no-preview"], None);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("afile is a file, not a folder"), "{err}");
    assert_eq!(std::fs::read(&file).unwrap(), b"data");
}
