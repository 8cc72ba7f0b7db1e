//! Checkpoints and resume, end to end through the `weft` binary: a run
//! stopped anywhere — at deterministic crash points (mid-window, mid-rollback,
//! between a checkpoint's temporary write and its rename), by a real SIGKILL,
//! by SIGTERM or by `--stop-after` — and resumed gives the same `state_hash`,
//! the same `stats.jsonl` and `frames.jsonl` bytes and the same frame files as
//! a run that never stopped. Corrupt and mismatched checkpoints are refused.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

mod common;
use common::{resume, small_crumple, stderr, stopped_summary, summary, weft};

/// The small `crumple`, writing PLY and VTK frames.
const FORMATS: &[&str] = &["--set", "output.formats=[\"ply\",\"vtk\"]"];

/// The small `crumple` with [`FORMATS`], then `extra`, quiet and without a
/// preview.
fn crumple(out: &Path, failpoint: Option<&str>, extra: &[&str]) -> Command {
    let mut c = small_crumple(out, &[FORMATS, extra].concat(), failpoint);
    c.args(["--quiet", "--no-preview"]);
    c
}

fn fresh_run(out: &Path, failpoint: Option<&str>, extra: &[&str]) -> Output {
    crumple(out, failpoint, extra).output().expect("weft runs")
}

/// Every file whose bytes a resume must reproduce.
fn deterministic_files(out: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    for name in ["stats.jsonl", "frames.jsonl", "frames.pvd", "objects.json"] {
        files.insert(name.to_string(), std::fs::read(out.join(name)).unwrap());
    }
    for dir in ["frames", "frames-vtk"] {
        for e in std::fs::read_dir(out.join(dir)).unwrap() {
            let e = e.unwrap();
            let name = format!("{dir}/{}", e.file_name().to_string_lossy());
            files.insert(name, std::fs::read(e.path()).unwrap());
        }
    }
    files
}

struct Reference {
    _dir: tempfile::TempDir,
    hash: String,
    files: BTreeMap<String, Vec<u8>>,
    /// Rollbacks per committed window.
    rollbacks: Vec<u64>,
}

/// The uninterrupted run, once per test binary.
fn reference() -> &'static Reference {
    static R: OnceLock<Reference> = OnceLock::new();
    R.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let s = summary(&fresh_run(dir.path(), None, &[]));
        assert_eq!(s["complete"], true);
        let files = deterministic_files(dir.path());
        let rollbacks: Vec<u64> = String::from_utf8_lossy(&files["stats.jsonl"])
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                v["rollbacks"].as_u64().unwrap()
            })
            .collect();
        assert!(
            rollbacks.iter().sum::<u64>() >= 3,
            "the fixture needs rollbacks after its first checkpoint: {rollbacks:?}"
        );
        Reference {
            hash: s["state_hash"].as_str().unwrap().to_string(),
            files,
            rollbacks,
            _dir: dir,
        }
    })
}

fn assert_same_as_reference(out: &Path, s: &serde_json::Value) {
    let r = reference();
    assert_eq!(s["complete"], true);
    assert_eq!(s["state_hash"].as_str().unwrap(), r.hash);
    let files = deterministic_files(out);
    assert_eq!(
        files.keys().collect::<Vec<_>>(),
        r.files.keys().collect::<Vec<_>>(),
        "the same files"
    );
    for (name, bytes) in &files {
        assert!(
            bytes == &r.files[name],
            "{name} differs from the uninterrupted run"
        );
    }
}

fn crash_and_resume(failpoint: &str) {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(dir.path(), Some(failpoint), &[]);
    assert_eq!(
        o.status.code(),
        Some(weft_sim::failpoint::EXIT_CODE),
        "{failpoint} was not reached: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

#[test]
fn resume_after_a_crash_mid_window() {
    crash_and_resume("mid-window@7");
}

#[test]
fn resume_after_a_crash_mid_rollback() {
    // The first rollback in a window after the first checkpoint (window 3).
    let r = reference();
    let w = (4..r.rollbacks.len())
        .find(|&w| r.rollbacks[w] > 0)
        .expect("a rollback after window 3");
    let before: u64 = r.rollbacks[..w].iter().sum();
    crash_and_resume(&format!("mid-rollback@{}", before + 1));
}

#[test]
fn resume_after_a_crash_between_checkpoint_write_and_rename() {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(dir.path(), Some("checkpoint-rename@2"), &[]);
    assert_eq!(o.status.code(), Some(weft_sim::failpoint::EXIT_CODE));
    // The first checkpoint survived; the second is only a temporary file.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["last_checkpoint"]["window"], 3);
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
    let stale = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp")
        })
        .count();
    assert_eq!(stale, 0, "the resume removes the abandoned temporary file");
}

/// A stop request that lands mid-window after rollbacks added layers: the
/// checkpoint holds the committed layers, not the ones the window's rollbacks
/// added, so the resumed window repeats its rollbacks and the stats agree.
#[test]
fn an_interrupt_after_a_rollback_resumes_identically() {
    let r = reference();
    let w = (4..r.rollbacks.len())
        .find(|&w| r.rollbacks[w] > 0)
        .expect("a rollback after window 3");
    let before: u64 = r.rollbacks[..w].iter().sum();
    let dir = tempfile::tempdir().unwrap();
    let point = format!("interrupt-after-rollback@{}", before + 1);
    let s = stopped_summary(&fresh_run(dir.path(), Some(&point), &[]));
    assert_eq!(s["windows"], w as u64, "stopped in window {w}");
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

fn manifest(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap()
}

/// A write that fails mid-run (`write:…` failpoints: "No space left on
/// device", as a full disk says) ends the run `failed` with the error, every
/// line file holding whole lines only, and the manifest naming the last good
/// checkpoint; the resume from it ends as the uninterrupted run does.
fn fail_a_write_and_resume(failpoint: &str) {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(dir.path(), Some(failpoint), &[]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{failpoint}: {err}");
    assert_eq!(
        err.matches("No space left on device").count(),
        1,
        "{failpoint}: the error, once: {err}"
    );
    assert!(
        err.contains("--resume"),
        "{failpoint}: says how to go on: {err}"
    );
    let m = manifest(dir.path());
    assert_eq!(m["status"], "failed", "{failpoint}");
    assert!(
        m["error"]
            .as_str()
            .unwrap()
            .contains("No space left on device"),
        "{failpoint}: {m}"
    );
    assert_eq!(m["last_checkpoint"]["window"], 3, "{failpoint}: {m}");
    for name in ["stats.jsonl", "timing.jsonl", "frames.jsonl"] {
        let text = std::fs::read_to_string(dir.path().join(name)).unwrap();
        assert!(
            text.is_empty() || text.ends_with('\n'),
            "{failpoint}: {name} torn"
        );
        for line in text.lines() {
            serde_json::from_str::<serde_json::Value>(line)
                .unwrap_or_else(|e| panic!("{failpoint}: {name}: {e}: {line}"));
        }
    }
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
    assert_eq!(manifest(dir.path())["status"], "complete");
}

#[test]
fn a_line_write_that_fails_half_way_is_cut_and_the_run_resumes() {
    // Window 5's line: after the first checkpoint (window 3).
    fail_a_write_and_resume("write:stats.jsonl@5");
}

#[test]
fn a_frame_write_that_fails_leaves_a_resumable_run() {
    // The first frame of a window after the first checkpoint.
    let frames = String::from_utf8_lossy(&reference().files["frames.jsonl"]).into_owned();
    let frame = frames
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|r| r["window"].as_u64().unwrap() > 3)
        .expect("a frame after window 3")["frame"]
        .as_u64()
        .unwrap();
    fail_a_write_and_resume(&format!("write:frame@{frame}"));
}

#[test]
fn a_checkpoint_write_that_fails_leaves_the_previous_one() {
    fail_a_write_and_resume("write:checkpoint@2");
}

/// The half-written line a failed write leaves is cut at once, so `weft
/// plot` reads the stats of the failed run.
#[test]
fn the_stats_of_a_failed_run_can_be_plotted() {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(dir.path(), Some("write:stats.jsonl@5"), &[]);
    assert_eq!(o.status.code(), Some(1));
    let stats = std::fs::read_to_string(dir.path().join("stats.jsonl")).unwrap();
    assert_eq!(stats.lines().count(), 4, "windows 1 to 4, whole");
    let plots = tempfile::tempdir().unwrap();
    let p = weft()
        .arg("plot")
        .arg(dir.path())
        .arg("--out")
        .arg(plots.path())
        .output()
        .unwrap();
    assert!(p.status.success(), "{}", stderr(&p));
}

/// `output.checkpoint_minutes`: a checkpoint also once that much wall time
/// has passed since the last one (here 6 ms, with the window count off); a
/// crash resumes from the last of them, to the same bytes.
#[test]
fn checkpoints_by_wall_time_resume_identically() {
    let dir = tempfile::tempdir().unwrap();
    let by_time = [
        "--set",
        "output.checkpoint_every=0",
        "--set",
        "output.checkpoint_minutes=0.0001",
    ];
    let o = fresh_run(dir.path(), Some("mid-window@7"), &by_time);
    assert_eq!(
        o.status.code(),
        Some(weft_sim::failpoint::EXIT_CODE),
        "{}",
        stderr(&o)
    );
    // With the window count off, any checkpoint before the crash in window
    // 7 came by wall time (one per window unless a window takes < 6 ms).
    let window = manifest(dir.path())["last_checkpoint"]["window"].clone();
    assert!(
        window.as_u64().is_some_and(|w| (1..=7).contains(&w)),
        "a checkpoint by wall time: {window}"
    );
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

/// A run killed before its first checkpoint cannot be resumed: the refusal
/// gives the command that starts it again over the folder (`--overwrite`),
/// and that command works.
#[test]
fn a_run_killed_before_its_first_checkpoint_is_started_again_with_overwrite() {
    let dir = tempfile::tempdir().unwrap();
    let no_schedule = [
        "--set",
        "output.checkpoint_every=0",
        "--set",
        "output.checkpoint_minutes=0",
    ];
    let o = fresh_run(dir.path(), Some("mid-window@7"), &no_schedule);
    assert_eq!(o.status.code(), Some(weft_sim::failpoint::EXIT_CODE));
    let o = resume(dir.path(), &[]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no checkpoint"), "{err}");
    let command = err
        .split('`')
        .nth(1)
        .unwrap_or_else(|| panic!("a command in backquotes: {err}"));
    assert!(command.contains("--overwrite"), "{command}");
    let weft_binary = env!("CARGO_BIN_EXE_weft");
    let command = command.replacen("weft ", &format!("'{weft_binary}' "), 1);
    let o = Command::new("sh")
        .arg("-c")
        .arg(format!("{command} --quiet --no-preview"))
        .env_remove("WEFT_FAILPOINT")
        .output()
        .unwrap();
    let s = summary(&o);
    assert_eq!(s["complete"], true);
    assert_eq!(s["state_hash"].as_str().unwrap(), reference().hash);
}

fn wait_for_checkpoint(out: &Path, child: &mut std::process::Child, window: u64) {
    let start = Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(out.join("manifest.json")) {
            if let Ok(m) = serde_json::from_str::<serde_json::Value>(&text) {
                if m["last_checkpoint"]["window"]
                    .as_u64()
                    .is_some_and(|w| w >= window)
                {
                    return;
                }
            }
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before checkpointing window {window}"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoint");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn spawn_run(out: &Path) -> std::process::Child {
    crumple(out, None, &[])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("weft starts")
}

#[test]
fn resume_after_sigkill() {
    let _ = reference();
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(dir.path());
    wait_for_checkpoint(dir.path(), &mut child, 3);
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    assert!(!status.success());
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

#[test]
fn sigterm_checkpoints_and_exits_cleanly() {
    let _ = reference();
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(dir.path());
    wait_for_checkpoint(dir.path(), &mut child, 3);
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let o = child.wait_with_output().unwrap();
    if o.status.success() {
        // The signal came after the last window: nothing left to resume.
        assert_same_as_reference(dir.path(), &summary(&o));
        return;
    }
    let s = stopped_summary(&o);
    assert_eq!(s["stopped_by"], "SIGTERM");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["status"], "stopped");
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

#[test]
fn stop_after_checkpoints_and_resume_finishes_identically() {
    let dir = tempfile::tempdir().unwrap();
    let s = stopped_summary(&fresh_run(dir.path(), None, &["--stop-after", "0"]));
    assert_eq!(s["stopped_by"], "stop-after");
    // Resumed twice: a resume may itself be stopped and resumed.
    stopped_summary(&resume(dir.path(), &["--stop-after", "0"]));
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["status"], "complete");
    assert_eq!(m["segments"].as_array().unwrap().len(), 3);
}

#[test]
fn a_resume_removes_the_temporaries_of_writes_a_kill_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    stopped_summary(&fresh_run(dir.path(), None, &["--stop-after", "0"]));
    // What a process killed between writing and renaming leaves behind.
    for (folder, name) in [
        ("", ".checkpoint.wckp.4242.7.tmp"),
        ("frames", ".frame_00002.ply.4242.8.tmp"),
        ("frames-vtk", ".frame_00002.vtu.4242.9.tmp"),
    ] {
        let d = dir.path().join(folder);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(name), b"half a file").unwrap();
    }
    let s = summary(&resume(dir.path(), &[]));
    assert_same_as_reference(dir.path(), &s);
}

/// A finished fixture run to damage.
fn finished_copy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    summary(&fresh_run(dir.path(), None, &["--set", "time.end=0.05"]));
    dir
}

#[test]
fn corrupt_and_mismatched_checkpoints_are_refused() {
    let dir = finished_copy();
    let ck = dir.path().join("checkpoint.wckp");
    let good = std::fs::read(&ck).unwrap();

    // A flipped byte in the payload.
    let mut bad = good.clone();
    let last = bad.len() - 1;
    bad[last] ^= 0x40;
    std::fs::write(&ck, &bad).unwrap();
    let o = resume(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("corrupt") && stderr(&o).contains("checksum"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read(&ck).unwrap(),
        bad,
        "a refused checkpoint is left as it was"
    );

    // Truncated.
    std::fs::write(&ck, &good[..good.len() / 2]).unwrap();
    let o = resume(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));

    // Not a checkpoint at all.
    std::fs::write(&ck, b"hello").unwrap();
    let o = resume(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("not a weft checkpoint"),
        "{}",
        stderr(&o)
    );

    // A different scene (an override other than time.end).
    std::fs::write(&ck, &good).unwrap();
    let o = resume(dir.path(), &["--set", "contact.friction=0.1"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("different scene"), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"));

    // Extending the end time is allowed, and continues from the checkpoint.
    let s = summary(&resume(dir.path(), &["--set", "time.end=0.07"]));
    assert_eq!(s["complete"], true);
    assert!(s["simulated_seconds"].as_f64().unwrap() >= 0.07);
}

#[test]
fn refusals_without_a_checkpoint_or_over_an_existing_run() {
    let dir = tempfile::tempdir().unwrap();
    let o = resume(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("manifest.json"), "{}", stderr(&o));

    let dir = finished_copy();
    let o = fresh_run(dir.path(), None, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("already holds a run"), "{}", stderr(&o));
    let before = std::fs::read(dir.path().join("stats.jsonl")).unwrap();
    assert!(!before.is_empty(), "nothing already written is lost");

    std::fs::remove_file(dir.path().join("checkpoint.wckp")).unwrap();
    let o = resume(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no checkpoint"), "{}", stderr(&o));
}

/// An engine error that the manifest cannot record either is reported as
/// itself, with its own advice and a note about the manifest: not "remove the
/// cause, then --resume", since a resume would hit the rollback cap again.
#[test]
fn an_engine_error_the_manifest_cannot_record_keeps_its_own_advice() {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(
        dir.path(),
        Some("write:manifest:failed@1"),
        &["--set", "contact.max_rollbacks=0"],
    );
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains("rollbacks") && err.contains("raise contact.max_rollbacks"),
        "{err}"
    );
    assert!(
        err.contains("recording that in the manifest failed too")
            && err.contains("manifest.json: No space left on device"),
        "{err}"
    );
    assert!(
        !err.contains("remove the cause") && !err.contains("--resume"),
        "{err}"
    );
    assert_eq!(manifest(dir.path())["status"], "running");
}

/// Hitting the rollback cap stops the run with an error naming the stencil,
/// keeps a reproduction bundle and checkpoints the last committed window.
#[test]
fn the_rollback_cap_leaves_a_checkpoint_and_a_reproduction() {
    let dir = tempfile::tempdir().unwrap();
    let o = fresh_run(dir.path(), None, &["--set", "contact.max_rollbacks=0"]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains("rollbacks") && err.contains("stencil"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    for f in [
        "repro/window_start.ply",
        "repro/window_start.json",
        "checkpoint.wckp",
    ] {
        assert!(dir.path().join(f).is_file(), "{f} missing");
    }
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["status"], "failed");
    assert!(m["error"].as_str().unwrap().contains("rollbacks"));
    // The checkpoint is the start of the window that could not commit: the
    // first window of the reference run with a rollback.
    let first = reference().rollbacks.iter().position(|&r| r > 0).unwrap();
    assert_eq!(m["last_checkpoint"]["window"], first as u64);
    let repro: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("repro/window_start.json")).unwrap())
            .unwrap();
    assert_eq!(repro["window"], first as u64);
}
