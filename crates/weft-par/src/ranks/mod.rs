//! The world spread over ranks with separate memory: the distributed code
//! paths the `Ranks` and MPI executors share, here on threads with channels.
//!
//! | module | what |
//! |---|---|
//! | [`mod@plan`] | partition placement, owned / ghost vertices, boundary and interior partitions, who sends what |
//! | [`mod@internal`] | internal-force ticks over ranks: ghost exchange overlapped with interior work, slot exchange, ordered folds |

pub mod internal;
pub mod plan;

pub use internal::{run_ticks, Traffic};
pub use plan::{place_partitions, plan, RankPlan};
