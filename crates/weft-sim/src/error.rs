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
    /// Two primitives of a stencil closer than the separation floor at the
    /// start (`distance` 0: they touch or cross).
    #[error(
        "initial state: {pair} {}; weft cannot start from touching or nearly touching \
         geometry — move the objects apart{}",
        if *distance > 0.0 {
            format!("are {distance:.3e} m apart, closer than the separation floor of {floor:.3e} m \
                     (contact.floor × the contact thickness)")
        } else {
            "touch or cross (0 m apart)".to_string()
        },
        if *distance > 0.0 { " (or lower contact.floor)" } else { "" }
    )]
    InitialContact {
        kind: &'static str,
        key: StencilKey,
        /// The two primitives, by object and object-local vertex index.
        pair: String,
        distance: f64,
        floor: f64,
    },
    #[error(
        "initial state: triangles {a} and {b} intersect; weft cannot start from \
         intersecting geometry — move the objects apart"
    )]
    InitialIntersection { a: Place, b: Place },
    #[error(
        "window starting at t = {time:.6} s needed more than {cap} rollbacks; the last \
         stencil detected was {pair} near {position:?} at layer depth {depth}{}. The window's \
         start state was kept for a reproduction. {}",
        if *blown_up > 0 {
            format!("; {blown_up} of the window's passes blew up (a non-finite position or velocity)")
        } else {
            String::new()
        },
        if *blown_up > 0 {
            "Raise contact.layers_per_detection (more layers per detection for a fast impact) \
             or contact.max_rollbacks, or lower the internal step"
        } else {
            "Lower the internal step or the window length, or raise contact.max_rollbacks"
        }
    )]
    RollbackCap {
        time: f64,
        cap: u32,
        kind: &'static str,
        key: StencilKey,
        /// The stencil's two primitives, by object and object-local vertex index.
        pair: String,
        position: [f64; 3],
        depth: u32,
        /// Passes of the window that ended in a non-finite value.
        blown_up: u32,
    },
    /// A stencil that already has every layer the tick lattice resolves was
    /// reported again: it needs layer `depth` (one past `resolved`).
    #[error(
        "window starting at t = {time:.6} s: {pair} needs layer {depth}, deeper than the \
         {resolved} layers whose steps h_l = h_1 l^(-3/2) the tick lattice resolves (at least \
         one tick each); lower contact.layer1_step_shift (each step down resolves about 1.6× \
         as many layers)"
    )]
    LayerTooDeep {
        time: f64,
        key: StencilKey,
        /// The stencil's two primitives, by object and object-local vertex index.
        pair: String,
        depth: u32,
        resolved: u32,
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
    /// A value became non-finite with no contact near it to add layers to:
    /// a real instability.
    #[error(
        "vertex {place} reached a non-finite position or velocity at t = {time:.6} s, with no \
         contact near it; the simulation became unstable — lower the internal step (time.beta \
         or time.internal_step)"
    )]
    NonFinite {
        place: Place,
        /// The vertex's global index (objects concatenated in scene order).
        vertex: u32,
        time: f64,
    },
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
