//! The progress of `weft run` on standard error: on a terminal, a line
//! redrawn in place at most five times a second (simulated / end time,
//! windows per second, rollbacks, active contacts, ETA); elsewhere (a batch
//! job's log) one line every 30 seconds, or every `WEFT_PROGRESS_INTERVAL`
//! (a duration: `10`, `5m`). Nothing with `--quiet`.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// Time between the lines of a log (standard error not a terminal).
pub const LOG_INTERVAL: Duration = Duration::from_secs(30);
/// Sets the log interval (for tests and impatient users).
pub const LOG_INTERVAL_VARIABLE: &str = "WEFT_PROGRESS_INTERVAL";

/// How progress is shown.
enum Mode {
    Off,
    /// Redrawn in place on a terminal.
    Line,
    /// One line per interval, for a log file.
    Log(Duration),
}

pub struct Progress {
    mode: Mode,
    started: Instant,
    last_draw: Option<Instant>,
    /// (simulated time, windows) when this process started.
    origin: (f64, u64),
    end_time: f64,
}

/// What the line shows.
pub struct Snapshot {
    pub time: f64,
    pub windows: u64,
    pub rollbacks: u64,
    pub active: u64,
    pub depth: u32,
}

impl Progress {
    /// Progress from simulated time `start_time` after `start_windows`
    /// windows to `end_time`, logged every `log_interval` when standard
    /// error is not a terminal.
    pub fn new(
        quiet: bool,
        log_interval: Duration,
        start_time: f64,
        start_windows: u64,
        end_time: f64,
    ) -> Self {
        let mode = if quiet {
            Mode::Off
        } else if std::io::stderr().is_terminal() {
            Mode::Line
        } else {
            Mode::Log(log_interval)
        };
        Self {
            mode,
            started: Instant::now(),
            last_draw: None,
            origin: (start_time, start_windows),
            end_time,
        }
    }

    pub fn update(&mut self, s: &Snapshot) {
        let (interval, at_once) = match self.mode {
            Mode::Off => return,
            Mode::Line => (Duration::from_millis(200), true),
            // The first log line after one interval, not at the start.
            Mode::Log(every) => (every, false),
        };
        let due = match self.last_draw {
            Some(t) => t.elapsed() >= interval,
            None => at_once || self.started.elapsed() >= interval,
        };
        if !due {
            return;
        }
        self.last_draw = Some(Instant::now());
        let wall = self.started.elapsed().as_secs_f64().max(1e-9);
        let rate = (s.windows - self.origin.1) as f64 / wall;
        let sim_rate = (s.time - self.origin.0) / wall;
        let frac = (s.time / self.end_time).clamp(0.0, 1.0);
        let eta = if sim_rate > 0.0 {
            format_eta((self.end_time - s.time).max(0.0) / sim_rate)
        } else {
            "--".into()
        };
        let mut err = std::io::stderr().lock();
        if let Mode::Log(_) = self.mode {
            let _ = writeln!(
                err,
                "weft: progress t = {:.4}/{:.4} s ({:.1}%), {:.2} windows/s, {} rollbacks, \
                 {} active (depth {}), ETA {eta}",
                s.time,
                self.end_time,
                100.0 * frac,
                rate,
                s.rollbacks,
                s.active,
                s.depth
            );
            return;
        }
        let width = 24;
        let filled = (frac * width as f64).round() as usize;
        let line = format!(
            "[{}{}] {:.4}/{:.4} s  {:.2} win/s  rollbacks {}  active {} (depth {})  ETA {}",
            "#".repeat(filled),
            "-".repeat(width - filled),
            s.time,
            self.end_time,
            rate,
            s.rollbacks,
            s.active,
            s.depth,
            eta
        );
        let _ = write!(err, "\r\x1b[2K{line}");
        let _ = err.flush();
    }

    /// Clears the terminal line so the next output starts clean.
    pub fn finish(&mut self) {
        if matches!(self.mode, Mode::Line) && self.last_draw.is_some() {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[2K");
            let _ = err.flush();
        }
    }
}

/// The log interval: `WEFT_PROGRESS_INTERVAL` if set, else 30 s. One that
/// cannot be read is an error, not a silent 30 s.
pub fn log_interval() -> anyhow::Result<Duration> {
    match std::env::var(LOG_INTERVAL_VARIABLE) {
        Ok(text) => super::signals::parse_duration(&text)
            .map_err(|e| anyhow::anyhow!("{LOG_INTERVAL_VARIABLE}: {e}")),
        Err(_) => Ok(LOG_INTERVAL),
    }
}

fn format_eta(seconds: f64) -> String {
    let s = seconds.round() as u64;
    match s {
        0..=59 => format!("{s}s"),
        60..=3599 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, (s % 3600) / 60),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn eta_format() {
        assert_eq!(super::format_eta(5.2), "5s");
        assert_eq!(super::format_eta(125.0), "2m05s");
        assert_eq!(super::format_eta(7300.0), "2h01m");
    }
}
