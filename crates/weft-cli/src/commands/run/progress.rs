//! The progress line of `weft run` on a terminal: simulated / end time,
//! windows per second, rollbacks, active contacts and an ETA, redrawn in place
//! at most five times a second. Silent when standard error is not a terminal
//! or with `--quiet`.

use std::io::{IsTerminal, Write};
use std::time::Instant;

pub struct Progress {
    enabled: bool,
    started: Instant,
    last_draw: Option<Instant>,
    /// (wall instant, simulated time, windows) when this process started.
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
    pub fn new(quiet: bool, start_time: f64, start_windows: u64, end_time: f64) -> Self {
        Self {
            enabled: !quiet && std::io::stderr().is_terminal(),
            started: Instant::now(),
            last_draw: None,
            origin: (start_time, start_windows),
            end_time,
        }
    }

    pub fn update(&mut self, s: &Snapshot) {
        if !self.enabled
            || self
                .last_draw
                .is_some_and(|t| t.elapsed().as_secs_f64() < 0.2)
        {
            return;
        }
        self.last_draw = Some(Instant::now());
        let wall = self.started.elapsed().as_secs_f64().max(1e-9);
        let rate = (s.windows - self.origin.1) as f64 / wall;
        let sim_rate = (s.time - self.origin.0) / wall;
        let frac = (s.time / self.end_time).clamp(0.0, 1.0);
        let width = 24;
        let filled = (frac * width as f64).round() as usize;
        let eta = if sim_rate > 0.0 {
            format_eta((self.end_time - s.time).max(0.0) / sim_rate)
        } else {
            "--".into()
        };
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
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r\x1b[2K{line}");
        let _ = err.flush();
    }

    /// Clears the line so the next output starts clean.
    pub fn finish(&mut self) {
        if self.enabled && self.last_draw.is_some() {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[2K");
            let _ = err.flush();
        }
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
