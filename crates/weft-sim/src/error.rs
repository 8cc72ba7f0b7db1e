//! Errors of the engine. Each names what went wrong and where, and says what to do.

use thiserror::Error;
use weft_core::{MeshError, StencilKey};

use crate::materials::MaterialError;

/// Where a primitive is, for messages: object name and object-local index.
#[derive(Clone, Debug, PartialEq)]
pub struct Place {
    pub object: String,
    pub local: u32,
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} #{}", self.object, self.local)
    }
}

/// Everything that stops a simulation.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum SimError {
    #[error("object '{object}': invalid mesh: {source}")]
    Mesh {
        object: String,
        #[source]
        source: MeshError,
    },
    #[error("object '{object}': {source}")]
    Material {
        object: String,
        #[source]
        source: MaterialError,
    },
    #[error("invalid setting: {0}")]
    Config(String),
    #[error(
        "initial state: {kind} stencil {key:?} (vertices {places}) is {distance:.3e} m apart, \
         closer than the separation floor eta_inf = {floor:.3e} m; move the objects apart"
    )]
    InitialContact {
        kind: &'static str,
        key: StencilKey,
        places: String,
        distance: f64,
        floor: f64,
    },
    #[error(
        "initial state: triangles {a} and {b} intersect; weft cannot start from \
         intersecting geometry — move the objects apart"
    )]
    InitialIntersection { a: Place, b: Place },
    #[error(
        "window starting at t = {time:.6} s needed more than {cap} rollbacks; the last stencil \
         detected was {kind} {key:?} (vertices {places}) near {position:?} at depth {depth}. \
         The window's start state was kept for a reproduction. Lower the internal step or \
         the window length, or raise contact.max_rollbacks"
    )]
    RollbackCap {
        time: f64,
        cap: u32,
        kind: &'static str,
        key: StencilKey,
        places: String,
        position: [f64; 3],
        depth: u32,
    },
    #[error(
        "window starting at t = {time:.6} s needs {breakpoints} trajectory breakpoints, more than \
         the memory budget of {budget_bytes} bytes; shorten the window (time.steps_per_window) \
         or raise limits.trajectory_budget_bytes"
    )]
    TrajectoryBudget {
        time: f64,
        breakpoints: usize,
        budget_bytes: usize,
    },
    #[error(
        "vertex {place} reached a non-finite position or velocity at t = {time:.6} s; the \
         simulation became unstable — lower the internal step (time.beta or time.internal_step)"
    )]
    NonFinite { place: Place, time: f64 },
    /// The run was asked to stop (a signal or a deadline); the engine is back
    /// at the start of the window it was in, which is the last committed state.
    #[error("interrupted in the window starting at t = {time:.6} s")]
    Interrupted { time: f64 },
    /// The ranks sharing the run lost contact.
    #[error("the ranks lost contact: {0}")]
    Ranks(#[from] crate::executor::CommError),
    /// A saved state does not fit this world.
    #[error("the saved state does not fit this scene: {0}")]
    StateMismatch(String),
}
