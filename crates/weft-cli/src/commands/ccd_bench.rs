//! `weft ccd-bench PATH... [--json]`: the engine's narrow-phase predicate on
//! the public CCD benchmarks (either format, found by walking each PATH).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use weft_geom::ccd::benchmark::{load_benchmark, run_benchmark};

#[derive(Debug, Args)]
pub struct CcdBenchArgs {
    /// Folders to search for benchmark queries.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Minimum separation eta (m); the benchmarks' ground truth is for 0.
    #[arg(long, default_value_t = 0.0)]
    pub eta: f64,
    /// Print the report as one JSON object on the last line.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: CcdBenchArgs) -> anyhow::Result<ExitCode> {
    let mut folders = Vec::new();
    for p in &a.paths {
        let found = load_benchmark(p).with_context(|| format!("loading {}", p.display()))?;
        if found.is_empty() {
            anyhow::bail!("{}: no CCD benchmark queries found", p.display());
        }
        folders.extend(found);
    }
    let report = run_benchmark(&folders, a.eta);
    print!("{}", report.to_table());
    if a.json {
        // One compact object: the totals at the top level, then the groups.
        let t = &report.total;
        let j = serde_json::json!({
            "queries": t.queries,
            "false_negatives": t.false_negatives,
            "false_positives": t.false_positives,
            "ns_per_query": t.ns_per_query,
            "median_ns": t.median_ns,
            "max_ns": t.max_ns,
            "eta": report.eta,
            "vertex_face": report.vertex_face,
            "edge_edge": report.edge_edge,
            "folders": report.folders,
        });
        println!("{j}");
    }
    Ok(if report.total.false_negatives > 0 {
        ExitCode::from(3)
    } else {
        ExitCode::SUCCESS
    })
}
