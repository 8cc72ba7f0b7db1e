//! `weft plot DIR_OR_STATS`: PNG charts of a run's diagnostics; see
//! [`weft_render::plot_stats`].

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A run folder, or a stats.jsonl file (timing.jsonl beside it is used too).
    pub input: PathBuf,
    /// Output folder [default: DIR/plots, beside the stats file for a file].
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: PlotArgs) -> anyhow::Result<ExitCode> {
    let out = match &args.out {
        Some(o) => o.clone(),
        None if args.input.is_dir() => args.input.join("plots"),
        None => args
            .input
            .parent()
            .map_or_else(|| PathBuf::from("plots"), |p| p.join("plots")),
    };
    let report = weft_render::plot_stats(&args.input, &out)
        .with_context(|| format!("cannot plot {}", args.input.display()))?;
    for f in &report.files {
        println!("wrote {}", f.display());
    }
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    Ok(ExitCode::SUCCESS)
}
