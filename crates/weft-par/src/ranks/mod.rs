//! The world spread over ranks with separate memory: the distributed code
//! paths the `Ranks` and MPI executors share, here on threads with channels.
//!
//! | module | what |
//! |---|---|
//! | [`mod@plan`] | partition placement, owned / ghost vertices, boundary and interior partitions, who sends what (the slot lists are the engine's `RankShare`) |
//! | [`mod@executor`] | [`Ranks`]: one rank's executor — its share of every stage, all-gathered; boundary slots point to point |
//! | [`mod@transport`] | the [`Transport`]: an all-gather collective and a point-to-point exchange overlapped with work; its in-process channels |
//! | `mpi` (feature `mpi`) | `MpiTransport`: the [`Transport`] over MPI, nonblocking collectives and `Isend`/`Irecv` polled with a back-off |
//! | [`mod@internal`] | internal-force ticks over ranks: ghost exchange overlapped with interior work, slot exchange, ordered folds |

pub mod dissemination;
pub mod executor;
pub mod internal;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod plan;
pub mod transport;

#[cfg(feature = "mpi")]
pub use self::mpi::MpiTransport;
pub use executor::{in_process, Ranks};
pub use internal::run_ticks;
pub use plan::{place_partitions, plan, RankPlan};
pub use transport::{
    ChannelTransport, HeadsAndParts, RankFailure, StepSink, SyncStep, Traffic, TrafficCounter,
    Transport,
};
