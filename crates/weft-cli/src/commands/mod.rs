//! One module per subcommand.

pub mod ccd_bench;
pub mod check;
pub mod run;
