//! `weft run` under a batch system: distinct exit statuses (0 complete, 75
//! stopped with a checkpoint), a progress log when standard error is a file,
//! a preview of the frames so far at `--stop-after`, absurd sizes refused up
//! front, and frames never faster than windows.

use std::path::Path;
use std::process::Command;

mod common;
use common::{repo, small_crumple, stderr, stopped_summary, summary, weft};

fn crumple(out: &Path, extra: &[&str]) -> Command {
    small_crumple(out, extra, None)
}

fn lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// A run stopped by `--stop-after` exits 75 (a job script requeues on it)
/// and still gets its preview, of the frames written so far.
#[test]
fn stop_after_exits_75_with_a_preview_of_the_frames_so_far() {
    let dir = tempfile::tempdir().unwrap();
    // (to 0.6 s: a run of far more than the one second it is stopped after)
    let o = crumple(
        dir.path(),
        &["--set", "time.end=0.6", "--stop-after", "1", "--quiet"],
    )
    .output()
    .unwrap();
    let s = stopped_summary(&o);
    assert_eq!(s["stopped_by"], "stop-after");
    let preview = ["preview.mp4", "preview.gif"]
        .iter()
        .any(|p| dir.path().join(p).is_file());
    assert!(preview, "no preview: {}", stderr(&o));
    let frames = lines(&dir.path().join("frames.jsonl")).len();
    let pngs = std::fs::read_dir(dir.path().join("render"))
        .unwrap()
        .count();
    assert!(frames >= 1);
    assert_eq!(pngs, frames, "one picture per frame so far");
}

/// On a file (a batch job's log), progress comes as whole lines, one per
/// `WEFT_PROGRESS_INTERVAL` (30 s when unset: none in a run of seconds).
#[test]
fn progress_is_logged_in_lines_when_stderr_is_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let o = crumple(dir.path(), &["--no-preview"])
        .env("WEFT_PROGRESS_INTERVAL", "0")
        .output()
        .unwrap();
    let s = summary(&o);
    let err = stderr(&o);
    let log: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("weft: progress "))
        .collect();
    assert_eq!(
        log.len() as u64,
        s["windows"].as_u64().unwrap(),
        "a line per window at interval 0:\n{err}"
    );
    let last = log.last().unwrap();
    for part in [
        "t = ",
        "/0.2200 s (100.0%)",
        "windows/s",
        "rollbacks",
        "ETA",
    ] {
        assert!(last.contains(part), "{part}: {last}");
    }
    assert!(!err.contains('\r'), "no terminal redraws in a log");

    let o = crumple(dir.path(), &["--no-preview", "--overwrite"])
        .env_remove("WEFT_PROGRESS_INTERVAL")
        .output()
        .unwrap();
    summary(&o);
    assert!(!stderr(&o).contains("weft: progress"), "{}", stderr(&o));

    let o = crumple(dir.path(), &["--no-preview", "--overwrite"])
        .env("WEFT_PROGRESS_INTERVAL", "soon")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("WEFT_PROGRESS_INTERVAL: 'soon' is not a duration"),
        "{}",
        stderr(&o)
    );
}

/// 10^10 vertices are refused before anything is built, with the memory
/// they would need, by `weft run` and `weft info` alike.
#[test]
fn absurd_sizes_are_refused_up_front_with_the_memory_they_need() {
    let dir = tempfile::tempdir().unwrap();
    let drape = repo().join("scenes/drape.toml");
    for args in [
        vec!["run", "--out", dir.path().to_str().unwrap()],
        vec!["info"],
    ] {
        let o = weft()
            .args(&args[..1])
            .arg(&drape)
            .args(&args[1..])
            .args(["--set", "size=1e10"])
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        for part in [
            "grid.resolution",
            "size = 10000000000",
            "10000000000 vertices",
            "of memory",
        ] {
            assert!(err.contains(part), "{args:?}: {part}: {err}");
        }
    }
}

/// Frames are committed states, which exist only at window boundaries: a
/// frame rate above the window rate writes one frame per window (not the
/// same state several times over), and says so once.
#[test]
fn a_frame_rate_above_the_window_rate_is_clamped_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    let o = crumple(
        dir.path(),
        &["--set", "output.frame_rate=100000", "--no-preview"],
    )
    .output()
    .unwrap();
    let s = summary(&o);
    let err = stderr(&o);
    assert_eq!(err.matches("is above the window rate").count(), 1, "{err}");
    let frames = lines(&dir.path().join("frames.jsonl"));
    assert_eq!(frames.len() as u64, s["windows"].as_u64().unwrap() + 1);
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f["window"], k as u64, "frame {k} is window {k}'s state");
    }
}

/// Every committed window's line and every frame's line reach their files
/// at once (not when a buffer fills or a checkpoint flushes it), so a run in
/// progress can be watched, plotted and rendered.
#[test]
fn a_run_in_progress_shows_each_window_and_frame_as_it_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = crumple(
        dir.path(),
        &[
            "--set",
            "time.end=5",
            // No checkpoint, which would flush too.
            "--set",
            "output.checkpoint_every=0",
            "--set",
            "output.checkpoint_minutes=0",
            "--quiet",
            "--no-preview",
        ],
    )
    .stdout(std::process::Stdio::null())
    .stderr(std::process::Stdio::null())
    .spawn()
    .unwrap();
    let whole_lines = |name: &str| -> Vec<serde_json::Value> {
        let text = std::fs::read_to_string(dir.path().join(name)).unwrap_or_default();
        let whole = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
        whole
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    };
    let started = std::time::Instant::now();
    let (stats, frames) = loop {
        // Frames first: a frame's window has its stats line before it.
        let frames = whole_lines("frames.jsonl");
        let stats = whole_lines("stats.jsonl");
        if frames.len() >= 3 {
            break (stats, frames);
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before its lines were seen"
        );
        assert!(
            started.elapsed().as_secs() < 120,
            "no lines after 2 minutes"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    child.kill().unwrap();
    child.wait().unwrap();
    // Seen as they came (a buffer of 8 kB would have held back a hundred
    // frame lines), with every window up to the last frame's.
    assert!(frames.len() < 20, "{} frame lines at once", frames.len());
    let last = frames.last().unwrap()["window"].as_u64().unwrap();
    assert!(
        stats.len() as u64 >= last,
        "{} stats lines, frame of window {last}",
        stats.len()
    );
    for f in &frames {
        let file = dir.path().join(f["file"].as_str().unwrap());
        assert!(
            file.is_file(),
            "{} is listed before it exists",
            file.display()
        );
    }
}
