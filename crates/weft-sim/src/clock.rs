//! Integer time.
//!
//! Time is a `u64` count of one global quantum `q` seconds (`acm-spec.md` §2):
//! the internal step is `2^20` quanta, every other step is a whole number of
//! quanta (layer steps rounded *down*, which only makes them more stable), and
//! window boundaries are whole numbers of internal steps. "Which events fall in
//! this window", "which events coincide" and "the next event after t" are then
//! integer questions; floating time is derived only where physics needs it.

use serde::{Deserialize, Serialize};

/// A time in quanta since the start of the simulation.
pub type Tick = u64;

/// Quanta per internal step (`h_el = 2^20 q`).
pub const TICKS_PER_INTERNAL_STEP: Tick = 1 << 20;

/// The time lattice of one simulation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lattice {
    /// Seconds per tick.
    pub quantum: f64,
    /// Internal steps per collision window.
    pub steps_per_window: u64,
}

impl Lattice {
    /// A lattice whose internal step is `h_el` seconds.
    pub fn new(h_el: f64, steps_per_window: u64) -> Self {
        Self {
            quantum: h_el / TICKS_PER_INTERNAL_STEP as f64,
            steps_per_window: steps_per_window.max(1),
        }
    }

    /// The internal step in ticks.
    pub fn internal_step(&self) -> Tick {
        TICKS_PER_INTERNAL_STEP
    }

    /// The internal step in seconds.
    pub fn h_el(&self) -> f64 {
        self.seconds(TICKS_PER_INTERNAL_STEP)
    }

    /// Window length in ticks.
    pub fn window(&self) -> Tick {
        self.steps_per_window * TICKS_PER_INTERNAL_STEP
    }

    /// Ticks to seconds.
    pub fn seconds(&self, t: Tick) -> f64 {
        t as f64 * self.quantum
    }

    /// The position at tick `t` of a vertex at `x` at tick `tau` with
    /// velocity `v`: the engine's drift `x + v (t - tau) q`, written once,
    /// so every place that drifts a vertex gets the same bits.
    #[inline]
    pub fn drift(&self, x: glam::DVec3, v: glam::DVec3, tau: Tick, t: Tick) -> glam::DVec3 {
        x + v * ((t - tau) as f64 * self.quantum)
    }

    /// The last tick at or before `seconds`, rounded down to a whole window.
    pub fn window_end_at_or_before(&self, seconds: f64) -> Tick {
        let w = self.window();
        let t = (seconds / self.quantum).floor();
        let t = if t.is_finite() && t > 0.0 {
            t as Tick
        } else {
            0
        };
        t / w * w
    }

    /// The first window boundary at or after `seconds`.
    pub fn window_end_at_or_after(&self, seconds: f64) -> Tick {
        let w = self.window();
        let t = (seconds / self.quantum).ceil();
        let t = if t.is_finite() && t > 0.0 {
            t as Tick
        } else {
            0
        };
        t.div_ceil(w) * w
    }
}

/// The first multiple of `period` strictly after `t` (events are at n·period,
/// n ≥ 1).
#[inline]
pub fn next_multiple_after(t: Tick, period: Tick) -> Tick {
    (t / period + 1) * period
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_multiple() {
        assert_eq!(next_multiple_after(0, 5), 5);
        assert_eq!(next_multiple_after(4, 5), 5);
        assert_eq!(next_multiple_after(5, 5), 10);
    }

    #[test]
    fn window_rounding() {
        let l = Lattice::new(1e-3, 10);
        assert_eq!(l.window(), 10 << 20);
        assert_eq!(l.window_end_at_or_after(0.0105), 2 * l.window());
        assert_eq!(l.window_end_at_or_before(0.0105), l.window());
    }
}
