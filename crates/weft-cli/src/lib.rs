//! # weft-cli — the `weft` command-line tool
//!
//! `main` only calls [`run`], so every command is callable from tests.
//! Errors are printed once, as `error: …` ([`error_text`]) on standard error
//! with exit code 1 (2 for command-line usage errors; `weft run` documents
//! its other statuses in its `--help`).

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
    #[command(after_help = commands::run::EXIT_STATUS_HELP)]
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
            eprintln!("error: {}", error_text(&e));
            ExitCode::from(1)
        }
    }
}

/// An error and its causes on one line, `outer: cause: …`, each text once.
///
/// anyhow's `{:#}` prints every cause after its parent, but many of weft's
/// errors already show their cause in their own text (`object 'x': {source}`
/// with `#[source]`), which `{:#}` would then print twice. A cause whose text
/// the line already holds is left out.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::error_text;

    #[derive(Debug)]
    struct Leaf;
    impl std::fmt::Display for Leaf {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("the step exceeds the limit")
        }
    }
    impl std::error::Error for Leaf {}

    /// Shows its source in its own text, as `#[error("… {source}")]` does.
    #[derive(Debug)]
    struct Wrapper(Leaf);
    impl std::fmt::Display for Wrapper {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "object 'cloth': {}", self.0)
        }
    }
    impl std::error::Error for Wrapper {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    #[test]
    fn a_cause_already_in_the_text_is_printed_once() {
        let e = anyhow::Error::new(Wrapper(Leaf));
        assert_eq!(error_text(&e), "object 'cloth': the step exceeds the limit");
        // A context that does not repeat its cause keeps it.
        let e = e.context("cannot build the world");
        assert_eq!(
            error_text(&e),
            "cannot build the world: object 'cloth': the step exceeds the limit"
        );
    }
}
