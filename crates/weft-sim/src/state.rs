//! The engine's resumable state: what a checkpoint holds (`acm-spec.md` §5).
//!
//! At a window boundary everything that influences later bits is here: the
//! tick and window index, every vertex's `x`, `v` and `tau` in input order, and
//! the whole active-layer set with depths and hysteresis counters, keyed by
//! input ids. Scripts are pure functions of time and the engine's caches only
//! ever skip work whose result is zero, so neither needs saving. The layout
//! never mentions partitions, threads or ranks: a run resumes on any of them.

use serde::{Deserialize, Serialize};
use weft_core::StencilKey;

use crate::clock::Tick;
use crate::engine::RunTotals;
use crate::layers::LayerState;

/// The state of an engine at a window boundary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EngineState {
    pub tick: Tick,
    pub window_index: u64,
    /// Positions, velocities (bit patterns of `f64`, input order).
    pub x: Vec<[f64; 3]>,
    pub v: Vec<[f64; 3]>,
    pub tau: Vec<Tick>,
    /// The active-layer set in key order.
    pub layers: Vec<(StencilKey, LayerState)>,
    /// Run counters (for summaries; they do not influence the simulation).
    pub totals: RunTotals,
}
