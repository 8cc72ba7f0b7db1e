//! `DIR/manifest.json`: what a run folder holds and how it was made — the
//! scene and its effective overrides, the weft version, each command line that
//! worked on it, the machine, the status and the last good checkpoint. It is
//! rewritten atomically at the start, at every checkpoint and at the end, so it
//! is always a complete JSON document.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::Context;
use serde::{Deserialize, Serialize};

pub const FILE: &str = "manifest.json";

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Manifest {
    pub weft_version: String,
    pub scene: SceneRef,
    /// Every `--set` in effect, in the order applied.
    pub overrides: Vec<String>,
    pub end_time: f64,
    /// The folders the run writes frames to (`frames`, `frames-obj`,
    /// `frames-vtk`): with the fixed names, what says which files are the
    /// run's (absent in manifests of older versions: any of them).
    #[serde(default)]
    pub frame_folders: Vec<String>,
    /// `running`, `complete`, `stopped` (resumable) or `failed`.
    pub status: String,
    /// What stopped a `stopped` run: a signal name or `stop-after`.
    #[serde(default)]
    pub stopped_by: Option<String>,
    /// The error that ended a `failed` run.
    #[serde(default)]
    pub error: Option<String>,
    pub last_checkpoint: Option<CheckpointRef>,
    /// One entry per process that worked on the folder (a run and its resumes).
    pub segments: Vec<Segment>,
    pub updated: String,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneRef {
    /// Absolute path of the scene file.
    pub path: PathBuf,
    pub name: String,
    /// Hash of the scene with its overrides (end time excluded) and of the
    /// world built from it.
    pub hash: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointRef {
    /// Relative to the run folder.
    pub file: String,
    pub window: u64,
    pub tick: u64,
    pub time: f64,
    pub written: String,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Segment {
    pub started: String,
    pub command_line: Vec<String>,
    /// The window the segment started from (0 for a fresh run).
    pub from_window: u64,
    pub machine: Machine,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Machine {
    pub hostname: String,
    pub os: String,
    pub arch: String,
    pub logical_cpus: usize,
}

impl Machine {
    pub fn this() -> Self {
        let hostname = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| std::fs::read_to_string("/etc/hostname"))
            .map(|s| s.trim().to_string())
            .ok()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .unwrap_or_else(|| "unknown".into());
        Self {
            hostname,
            os: std::env::consts::OS.into(),
            arch: std::env::consts::ARCH.into(),
            logical_cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }
}

impl Manifest {
    pub fn read(dir: &Path) -> anyhow::Result<Self> {
        let path = dir.join(FILE);
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "cannot resume from {}: it has no readable {FILE} (is it the --out folder of a weft run?)",
                dir.display()
            )
        })?;
        serde_json::from_str(&text)
            .with_context(|| format!("{}: not a valid weft run manifest", path.display()))
    }

    /// The command line that starts this run afresh in `dir`, replacing it.
    pub fn restart_command(&self, dir: &Path) -> String {
        let mut words = vec![
            "weft".to_string(),
            "run".into(),
            shell_word(&self.scene.path.to_string_lossy()),
            "--out".into(),
            shell_word(&dir.to_string_lossy()),
            "--overwrite".into(),
        ];
        for o in &self.overrides {
            words.push("--set".into());
            words.push(shell_word(o));
        }
        words.join(" ")
    }

    pub fn write(&mut self, dir: &Path) -> anyhow::Result<()> {
        self.updated = now_utc();
        let path = dir.join(FILE);
        super::faults::injected_nth(&format!("write:manifest:{}", self.status))
            .with_context(|| format!("cannot write {}", path.display()))?;
        let text = serde_json::to_string_pretty(self)? + "\n";
        weft_io::write_atomic(&path, text.as_bytes())?;
        Ok(())
    }
}

/// `word` as a POSIX shell reads it back: as is when it is plain, else in
/// single quotes.
fn shell_word(word: &str) -> String {
    let plain = !word.is_empty()
        && word
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@%".contains(c));
    if plain {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', "'\\''"))
    }
}

/// The current time as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn now_utc() -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format_utc(secs)
}

/// Seconds since the Unix epoch as an ISO 8601 UTC time (proleptic Gregorian
/// calendar; days to a civil date after Howard Hinnant's algorithm).
pub fn format_utc(secs: u64) -> String {
    let days = (secs / 86400) as i64;
    let rem = secs % 86400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        (rem % 3600) / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn shell_words_read_back_as_given() {
        assert_eq!(super::shell_word("time.end=2"), "time.end=2");
        assert_eq!(
            super::shell_word("output.formats=[\"ply\"]"),
            "'output.formats=[\"ply\"]'"
        );
        assert_eq!(super::shell_word("it's"), "'it'\\''s'");
    }

    #[test]
    fn utc_dates() {
        assert_eq!(super::format_utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(super::format_utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(super::format_utc(1_795_000_000), "2026-11-18T11:06:40Z");
    }
}
