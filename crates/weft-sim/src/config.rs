//! User-facing engine settings and their defaults (SI units).

use serde::{Deserialize, Serialize};

/// Contact settings (`acm-spec.md` §3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContactConfig {
    /// Outer contact thickness `eta_1` (m). Clamped to half the smallest cloth
    /// triangle altitude so a flat rest mesh has no pair inside layer 1.
    pub thickness: f64,
    /// Separation floor as a fraction of `eta_1` (`eta_inf = floor · eta_1`).
    pub floor_fraction: f64,
    /// Stiffness of layer 1 (N/m); `None` = automatic `m_min (0.1 / h_1)^2 / 2`.
    pub stiffness: Option<f64>,
    /// `h_1 = h_el / 2^j`.
    pub layer1_step_shift: u32,
    /// Layers activated per detection of a stencil (L).
    pub layers_per_detection: u32,
    /// Calm windows before the innermost layer of a stencil is retired.
    pub retire_after_windows: u32,
    /// Activate layers before a window for the stencils its extrapolated
    /// motion brings into them (`engine/predict.rs`): fewer rollbacks, the
    /// same trajectory (policy independence, `acm-spec.md` §4). On in
    /// `Default` and in scenes (`contact.predict`).
    #[serde(default)]
    pub predict: bool,
    /// Keep the far stencils (two dynamic vertices, certified outside
    /// `eta_1`) out of the contact islands, promoting one into them when it
    /// may come within `eta_1` (`engine/events/far.rs`): smaller islands,
    /// whose units spread over the ranks, and the same trajectory.
    /// `Some(on)` always or never (`contact.split_islands`); `None`, the
    /// default: from 4 ranks and from 8 threads per rank on (`Engine::new`).
    #[serde(default)]
    pub split_islands: Option<bool>,
    /// Coulomb friction coefficient (0 = off).
    pub friction: f64,
    /// Rollbacks of one window before the run stops with a diagnostic.
    pub max_rollbacks: u32,
}

impl Default for ContactConfig {
    fn default() -> Self {
        Self {
            thickness: 1e-3,
            floor_fraction: 0.1,
            stiffness: None,
            layer1_step_shift: 0,
            layers_per_detection: 5,
            retire_after_windows: 3,
            predict: true,
            split_islands: None,
            friction: 0.0,
            max_rollbacks: 1000,
        }
    }
}

/// Time settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimeConfig {
    /// Internal step (s); `None` = `beta · 2 / omega_max` of the assembled rest system.
    pub internal_step: Option<f64>,
    /// Safety factor of the automatic step (≤ 0.5).
    pub beta: f64,
    /// Internal steps per collision window.
    pub steps_per_window: u64,
}

impl Default for TimeConfig {
    fn default() -> Self {
        Self {
            internal_step: None,
            beta: 0.3,
            steps_per_window: 100,
        }
    }
}

/// Engine limits.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LimitsConfig {
    /// Memory for one window's trajectories (bytes).
    pub trajectory_budget_bytes: usize,
}

impl Default for LimitsConfig {
    fn default() -> Self {
        Self {
            trajectory_budget_bytes: 4 << 30,
        }
    }
}
