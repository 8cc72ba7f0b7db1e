//! One module per subcommand.

pub mod bench;
pub mod ccd_bench;
pub mod check;
pub mod info;
pub mod plot;
pub mod render;
pub mod run;
pub mod startup;
