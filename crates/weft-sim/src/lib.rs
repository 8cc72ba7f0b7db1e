//! # weft-sim — the ACM engine
//!
//! Asynchronous Contact Mechanics (`acm-spec.md`): an asynchronous variational
//! integrator whose forces each tick on their own integer clock, nested penalty
//! layers as a contact barrier, and speculative collision windows with rollback.
//!
//! | module | responsibility |
//! |---|---|
//! | [`clock`] | integer time: ticks, the lattice, windows |
//! | [`materials`] | stretch, bend, damping, lumped masses, stable step |
//! | [`internal`] | internal stencils stored partition by partition, ordered per-vertex folds |
//! | [`partition`] | the partitioner trait, the contiguous fallback, a world's partition layout |
//! | [`kinematics`] | scripted motion of obstacles and pinned vertices |
//! | [`layers`] | the penalty-layer schedule, active-layer set, penalty and friction kicks |
//! | [`trace`] | timeline spans per stage and task, Chrome-trace JSON |
//! | [`trajectory`] | per-window breakpoint storage under a memory budget |
//! | [`balance`] | narrow-phase tasks by partition pair, profiled costs, the locality-aware assignment |
//! | [`broad`] | 26-DOP BVH broad phase with stencil-level filtering |
//! | [`dormancy`] | which active stencils a penalty batch may skip (asleep until a tick or a velocity change) |
//! | [`engine`] | the window / detect / rollback / commit loop |
//! | [`diagnostics`] | per-window statistics |
//! | [`executor`] | the `Executor` trait and the `Serial` executor |
//! | [`world`] | building a validated world from a spec |
//! | [`hash`] | the state hash |
//! | [`state`] | the resumable state a checkpoint holds |
//! | [`failpoint`] | deterministic crash points for resume tests |

pub mod balance;
pub mod broad;
pub mod clock;
pub mod config;
pub mod cpu;
pub mod diagnostics;
pub mod dormancy;
pub mod engine;
pub mod error;
pub mod executor;
pub mod failpoint;
pub mod hash;
pub mod internal;
pub mod islands;
pub mod kinematics;
pub mod layers;
pub mod materials;
pub mod partition;
pub mod share;
pub mod state;
pub mod trace;
pub mod trajectory;
pub mod world;

/// Numbers for unit tests: uniform in `[0, 1)` from a xorshift64 seeded
/// with `seed` (the same sequence on every machine).
#[cfg(test)]
pub(crate) fn uniform_numbers(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    }
}

pub use config::{ContactConfig, LimitsConfig, TimeConfig};
pub use diagnostics::{CommittedWindow, PenaltyWork, WindowStats, WindowTiming};
pub use engine::{Engine, NarrowLoad, RunTotals};
pub use error::SimError;
pub use executor::{CommError, Executor, Message, Serial, Traffic};
pub use state::EngineState;
pub use world::{ObjectKind, ObjectSpec, PinSpec, World, WorldSpec};
