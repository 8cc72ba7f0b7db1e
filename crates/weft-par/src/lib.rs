//! # weft-par — parallel execution
//!
//! Executors that run the engine's stages (see [`weft_sim::Executor`]) on more
//! than one core. The engine hands an executor per-partition tasks that write
//! disjoint output chunks and independent maps whose results come back in
//! index order; every per-vertex sum is an ordered fold done afterwards. So a
//! run gives the same bits on [`Threads`] with any thread count as on
//! [`weft_sim::Serial`].
//!
//! | module | what |
//! |---|---|
//! | [`metis`] | [`Metis`]: METIS partitions of the cloth's triangle dual graph |
//! | [`ranks`] | the world over ranks with separate memory: placement, halo plans, internal forces by message passing |
//! | [`threads`] | [`Threads`]: a rayon thread pool of its own |

pub mod metis;
pub mod ranks;
pub mod threads;

pub use metis::{build_world, build_world_on, Metis};
pub use ranks::Ranks;
pub use threads::Threads;
