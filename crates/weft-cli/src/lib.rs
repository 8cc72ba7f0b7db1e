//! # weft-cli — the `weft` command-line tool
//!
//! `main` only calls [`run`], so every command is callable from tests.
//! Errors are printed as `error: …` on standard error with exit code 1
//! (2 for command-line usage errors).

pub mod commands;

use std::ffi::OsString;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// weft — cloth and thin shells that never miss a collision.
#[derive(Debug, Parser)]
#[command(name = "weft", version, about, long_about = None, term_width = 100, max_term_width = 100)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate a scene and write frames, stats and a summary.
    Run(commands::run::RunArgs),
    /// Measure the engine's throughput and parallel efficiency on a scene.
    Bench(commands::bench::BenchArgs),
    /// Run the exact continuous proximity test on CCD benchmark folders.
    CcdBench(commands::ccd_bench::CcdBenchArgs),
    /// Report intersecting triangles in frame files.
    Check(commands::check::CheckArgs),
    /// Scene statistics, start-up warnings, and whether `weft run` would start (exit 1 if not).
    Info(commands::info::InfoArgs),
    /// Render a run folder to PNG frames and an MP4 or GIF preview.
    Render(commands::render::RenderArgs),
    /// Plot a run's energy, momentum, contacts and wall time to PNG charts.
    Plot(commands::plot::PlotArgs),
}

/// Parses `args` (program name first) and runs the command.
pub fn run<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let result = match cli.command {
        Command::Run(a) => commands::run::run(a),
        Command::Bench(a) => commands::bench::run(a),
        Command::CcdBench(a) => commands::ccd_bench::run(a),
        Command::Check(a) => commands::check::run(a),
        Command::Info(a) => commands::info::run(a),
        Command::Render(a) => commands::render::run(a),
        Command::Plot(a) => commands::plot::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
