//! Stop requests: SIGINT, SIGTERM, SIGUSR1 and the `--stop-after` deadline all
//! set one flag the engine polls between event batches; the run then saves a
//! checkpoint of the last committed window and exits cleanly. A second SIGINT
//! or SIGTERM while it does so ends the process at once (status 130 / 143).

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};

/// The reason given when the `--stop-after` deadline passed.
pub const STOP_AFTER: &str = "stop-after";

const REASONS: [&str; 5] = ["", "SIGINT", "SIGTERM", "SIGUSR1", STOP_AFTER];
const DEADLINE: usize = 4;

/// Why a run should stop, shared with the engine.
#[derive(Clone, Debug, Default)]
pub struct StopRequest {
    pub flag: Arc<AtomicBool>,
    reason: Arc<AtomicUsize>,
}

impl StopRequest {
    /// A request nobody but [`StopRequest::deadline`] and tests set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the flag on SIGINT, SIGTERM and SIGUSR1.
    pub fn on_signals(self) -> std::io::Result<Self> {
        for (sig, code, reason) in [(SIGINT, 130, 1), (SIGTERM, 143, 2), (SIGUSR1, 0, 3)] {
            if code != 0 {
                // Registered first, so it sees the flag as the previous
                // signal left it: only a repeated signal exits at once.
                signal_hook::flag::register_conditional_shutdown(sig, code, self.flag.clone())?;
            }
            signal_hook::flag::register_usize(sig, self.reason.clone(), reason)?;
            signal_hook::flag::register(sig, self.flag.clone())?;
        }
        Ok(self)
    }

    /// Sets the flag once `after` has passed.
    pub fn deadline(self, after: Duration) -> Self {
        let (flag, reason) = (self.flag.clone(), self.reason.clone());
        std::thread::spawn(move || {
            std::thread::sleep(after);
            let _ = reason.compare_exchange(0, DEADLINE, Ordering::SeqCst, Ordering::SeqCst);
            flag.store(true, Ordering::SeqCst);
        });
        self
    }

    /// Whether a stop was requested.
    pub fn requested(&self) -> bool {
        self.flag.load(Ordering::SeqCst)
    }

    /// The first reason given (`SIGINT`, `SIGTERM`, `SIGUSR1` or `stop-after`).
    pub fn reason(&self) -> Option<&'static str> {
        let r = self.reason.load(Ordering::SeqCst);
        (r > 0).then(|| REASONS[r.min(REASONS.len() - 1)])
    }
}

/// Parses a duration such as `90`, `45s`, `30m`, `2h`, `1h30m` or `1d`
/// (a bare number is seconds).
pub fn parse_duration(text: &str) -> Result<Duration, String> {
    let t = text.trim();
    let bad = || format!("'{text}' is not a duration (examples: 3600, 45s, 30m, 2h, 1h30m, 1d)");
    if t.is_empty() {
        return Err(bad());
    }
    if let Ok(s) = t.parse::<f64>() {
        return if s.is_finite() && s >= 0.0 {
            Ok(Duration::from_secs_f64(s))
        } else {
            Err(bad())
        };
    }
    let mut total = 0.0f64;
    let mut number = String::new();
    for c in t.chars() {
        if c.is_ascii_digit() || c == '.' {
            number.push(c);
            continue;
        }
        let unit = match c {
            's' => 1.0,
            'm' => 60.0,
            'h' => 3600.0,
            'd' => 86400.0,
            _ => return Err(bad()),
        };
        let n: f64 = number.parse().map_err(|_| bad())?;
        total += n * unit;
        number.clear();
    }
    if !number.is_empty() || !total.is_finite() {
        return Err(bad());
    }
    Ok(Duration::from_secs_f64(total))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations() {
        assert_eq!(parse_duration("90").unwrap(), Duration::from_secs(90));
        assert_eq!(parse_duration("45s").unwrap(), Duration::from_secs(45));
        assert_eq!(parse_duration("1h30m").unwrap(), Duration::from_secs(5400));
        assert_eq!(parse_duration("0.5m").unwrap(), Duration::from_secs(30));
        assert_eq!(parse_duration("1d").unwrap(), Duration::from_secs(86400));
        for bad in ["", "m", "1x", "3h5", "-4", "nan"] {
            assert!(parse_duration(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn deadline_sets_the_flag_with_its_reason() {
        let s = StopRequest::new().deadline(Duration::from_millis(1));
        for _ in 0..2000 {
            if s.requested() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(s.requested());
        assert_eq!(s.reason(), Some("stop-after"));
    }
}
