//! Diagnostics of committed windows.

use serde::{Deserialize, Serialize};

/// What happened in one committed window (one line of the stats file).
///
/// Only what the simulation determines, so a resumed run, or one on another
/// executor, writes the same bytes; how the window ran (wall-clock and CPU
/// times, the penalty stage's work) is its [`WindowTiming`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WindowStats {
    /// Index of the window (0-based).
    pub window: u64,
    /// Simulated time at the window's end (s).
    pub time: f64,
    /// Tick at the window's end.
    pub tick: u64,
    /// Internal-clock batches run in the committed pass.
    pub internal_events: u64,
    /// Internal stencil evaluations in the committed pass.
    pub internal_stencil_evaluations: u64,
    /// Penalty-layer stencil evaluations (one per stencil per layer tick).
    pub layer_events: u64,
    /// Penalty evaluations that kicked (stencil inside its layer).
    pub layer_kicks: u64,
    /// Contact islands of the committed pass (`crate::islands`) and the
    /// layer events of the largest one (its share of `layer_events` is what
    /// bounds running islands in parallel).
    #[serde(default)]
    pub islands: u64,
    #[serde(default)]
    pub largest_island_layer_events: u64,
    /// Rollbacks of this window.
    pub rollbacks: u32,
    /// Active stencils at commit (after retirement) and their depth histogram
    /// (`depth_histogram[i]` = stencils of depth `i + 1`).
    pub active_stencils: u64,
    pub depth_histogram: Vec<u64>,
    pub max_depth: u32,
    /// Candidate stencils of the committed pass's broad phase.
    pub candidates: u64,
    /// Stencils the narrow phase reported, summed over all passes.
    pub confirmed: u64,
    /// Layers retired at commit.
    pub retired_layers: u64,
    /// Layers activated before the window by prediction
    /// (`contact.predict`), and by the detections of its rollbacks.
    #[serde(default)]
    pub predicted_layers: u64,
    #[serde(default)]
    pub detected_layers: u64,
    /// Of the predicted layers, those of stencils certified to stay outside
    /// their first predicted layer over the committed pass (never reached;
    /// a conservative count: an uncertain one counts as reached).
    #[serde(default)]
    pub predicted_unreached: u64,
    /// Trajectory breakpoints of the committed pass.
    pub breakpoints: u64,
    /// The breakpoints the committed pass's narrow phase walked: summed over
    /// its candidate stencils' four vertices (divided by `4 · candidates`,
    /// the trajectory length of a queried vertex, what the narrow phase's
    /// cost per query follows).
    #[serde(default)]
    pub queried_breakpoints: u64,
    /// Time intervals the window's certificates (narrow phase and commit,
    /// all passes) certified, and those of them certified by the
    /// trajectories' block bounds alone, without walking a segment
    /// (`weft_geom::ccd::bounds`).
    #[serde(default)]
    pub certified_intervals: u64,
    #[serde(default)]
    pub block_certified_intervals: u64,
    /// Smallest stencil distance seen at layer events and at the window end (m);
    /// `null` when no stencil was near.
    pub min_separation: Option<f64>,
    pub kinetic_energy: f64,
    /// Elastic + gravity + penalty energy at the window end (J).
    pub potential_energy: f64,
    /// The penalty (contact) part of `potential_energy` (J).
    pub contact_energy: f64,
    pub linear_momentum: [f64; 3],
    pub angular_momentum: [f64; 3],
}

/// A committed window as [`crate::Engine::step_window`] returns it: what the
/// simulation computed (a line of the stats file, the same bytes on any
/// executor, rank and partition count) and how this run computed it (a line
/// of the timing file).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CommittedWindow {
    pub stats: WindowStats,
    pub timing: WindowTiming,
}

/// Counts of how a committed pass's penalty stage ran rather than of what
/// it computed: they follow from whether the far stencils were kept out of
/// the islands (`contact.split_islands`; unset, on from 4 ranks and from 8
/// threads per rank), which never changes the motion. So
/// they go to the timing file, and the stats file is the same on any
/// executor, rank and partition count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PenaltyWork {
    /// The far stencils were kept out of the islands.
    pub split: bool,
    /// Exact distance evaluations at penalty batches (one serves every
    /// firing layer of its stencil); the other layer events were skipped:
    /// asleep, or certainly outside every firing layer by a distance bound.
    pub layer_evaluations: u64,
    /// Split: far stencils kept out of the islands when the pass started,
    /// those promoted into them during it, and the island units that ran a
    /// segment again after a promotion.
    pub far_stencils: u64,
    pub far_promoted: u64,
    pub island_reruns: u64,
    /// Split: the layer events of the largest unit of islands at the pass's
    /// end (what bounds running them in parallel, as
    /// `largest_island_layer_events` does whole).
    pub largest_unit_layer_events: u64,
}

/// Wall-clock time of one committed window (one line of the timing file),
/// and how its penalty stage ran.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WindowTiming {
    pub window: u64,
    /// Wall-clock seconds spent on the window (all passes).
    pub wall_seconds: f64,
    /// Wall-clock seconds per stage, summed over all passes.
    pub stage_seconds: StageSeconds,
    #[serde(default)]
    pub penalty_work: PenaltyWork,
}

/// The stages of one window pass, each with its wall-clock time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageSeconds {
    /// Event batches (internal forces, penalty layers, scripts) and trajectories.
    pub events: f64,
    /// The internal-force part of `events`: positions at the tick, stencil
    /// evaluation, and the per-vertex folds and new velocities of internal
    /// ticks.
    #[serde(default)]
    pub internal: f64,
    /// Broad phase (DOPs, BVH, stencil filtering).
    pub broad: f64,
    /// The layer prediction before the first pass (`contact.predict`):
    /// accelerations, its own broad phase, sampled distances.
    #[serde(default)]
    pub predict: f64,
    /// Narrow phase (continuous proximity tests).
    pub narrow: f64,
    /// Commit: layer retirement and diagnostics.
    pub commit: f64,
    /// The same stages' CPU seconds on this rank, polling for peers left
    /// out (`crate::cpu`; `internal` is not split out).
    #[serde(default)]
    pub cpu: StageCpu,
    /// The bytes this rank sent to its peers in each stage (over ranks).
    #[serde(default)]
    pub sent: StageSent,
}

/// One figure per stage of a rank's window (CPU seconds in
/// [`StageSeconds::cpu`], bytes sent in [`StageSeconds::sent`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PerStage {
    pub events: f64,
    pub broad: f64,
    pub narrow: f64,
    pub commit: f64,
    pub predict: f64,
}

/// CPU seconds per stage of one rank (see [`StageSeconds::cpu`]).
pub type StageCpu = PerStage;

/// Bytes sent per stage of one rank (see [`StageSeconds::sent`]).
pub type StageSent = PerStage;

impl std::ops::AddAssign for PerStage {
    fn add_assign(&mut self, o: Self) {
        self.events += o.events;
        self.broad += o.broad;
        self.narrow += o.narrow;
        self.commit += o.commit;
        self.predict += o.predict;
    }
}
