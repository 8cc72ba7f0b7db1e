//! What the end-to-end tests of the `weft` binary share.

#![allow(dead_code)] // each test file uses its own part

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository root (scenes live in `scenes/`).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The `weft` binary, with no failpoint inherited from the caller.
pub fn weft() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_weft"));
    c.env_remove("WEFT_FAILPOINT");
    c
}

/// A small `crumple`: contact and rollbacks within a few windows, seconds to
/// run, a checkpoint every 3 windows and frames at 60 per second.
pub const SMALL_CRUMPLE: &[&str] = &[
    "--set",
    "size=150",
    "--set",
    "time.end=0.22",
    "--set",
    "time.steps_per_window=25",
    "--set",
    "output.checkpoint_every=3",
    "--set",
    "output.frame_rate=60",
];

/// `weft run scenes/crumple.toml --out OUT` with [`SMALL_CRUMPLE`], then
/// `extra`, with `WEFT_FAILPOINT=failpoint` when one is given: the run the
/// end-to-end tests start.
pub fn small_crumple(out: &Path, extra: &[&str], failpoint: Option<&str>) -> Command {
    let mut c = weft();
    c.arg("run")
        .arg(repo().join("scenes/crumple.toml"))
        .arg("--out")
        .arg(out)
        .args(SMALL_CRUMPLE)
        .args(extra);
    if let Some(f) = failpoint {
        c.env("WEFT_FAILPOINT", f);
    }
    c
}

/// A finished command's standard error as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `weft run --resume out EXTRA… --quiet --no-preview`.
pub fn resume(out: &Path, extra: &[&str]) -> Output {
    weft()
        .arg("run")
        .arg("--resume")
        .arg(out)
        .args(extra)
        .args(["--quiet", "--no-preview"])
        .output()
        .expect("weft runs")
}

/// The JSON summary (last line) of a run that reached its end (exit 0).
pub fn summary(o: &Output) -> serde_json::Value {
    summary_with_status(o, 0)
}

/// Exit status of a run stopped early with a checkpoint (`weft run --help`).
pub const STOPPED: i32 = 75;

/// The JSON summary of a run stopped early with a checkpoint (exit 75).
pub fn stopped_summary(o: &Output) -> serde_json::Value {
    let s = summary_with_status(o, STOPPED);
    assert_eq!(s["complete"], false, "{s}");
    s
}

fn summary_with_status(o: &Output, code: i32) -> serde_json::Value {
    assert_eq!(
        o.status.code(),
        Some(code),
        "weft exited with {:?}, not {code}:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    let text = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(text.lines().last().expect("a summary line")).expect("JSON summary")
}
