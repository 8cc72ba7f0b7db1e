//! [`plot_stats`]: PNG charts of a run's `stats.jsonl` (and `timing.jsonl`).

use crate::chart::{draw_chart, Chart, Panel, Series, Style, COLORS};
use crate::error::RenderError;
use crate::json_lines;
use serde::de::DeserializeOwned;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use weft_sim::{WindowStats, WindowTiming};

/// Width of the charts in pixels.
pub const CHART_WIDTH: u32 = 1000;

/// Writes PNG line charts of a run's diagnostics into `out_dir` (created if
/// missing) and returns their paths, with any warnings ([`PlotReport`]):
///
/// * `energy.png`: kinetic, potential, contact and total (kinetic +
///   potential) energy against simulated time;
/// * `momentum.png`: |linear| and |angular| momentum;
/// * `contacts.png`: active stencils, deepest active layer and rollbacks per
///   window;
/// * `time.png`: wall-clock seconds per window, in total and per stage
///   (events, broad, narrow, commit), only when `timing.jsonl` is present.
///
/// `input` is a run folder (its `stats.jsonl` and `timing.jsonl` are read) or
/// a stats file (a `timing.jsonl` beside it is read if present). A run still
/// writing them reads too: an incomplete last line is skipped, with a
/// warning. Errors name the file and, for a malformed line, the line.
pub fn plot_stats(input: &Path, out_dir: &Path) -> Result<PlotReport, RenderError> {
    let (stats_path, timing_path) = if input.is_dir() {
        (input.join("stats.jsonl"), input.join("timing.jsonl"))
    } else {
        let dir = input.parent().unwrap_or(Path::new(""));
        (input.to_path_buf(), dir.join("timing.jsonl"))
    };
    let mut warnings = Vec::new();
    let stats: Vec<WindowStats> = read_lines(&stats_path, &mut warnings)?;
    if stats.is_empty() {
        return Err(RenderError::format(
            &stats_path,
            None,
            "no windows to plot (the file has no lines)".into(),
        ));
    }
    let timing: Option<Vec<WindowTiming>> = if timing_path.is_file() {
        Some(read_lines(&timing_path, &mut warnings)?)
    } else {
        None
    };
    std::fs::create_dir_all(out_dir).map_err(|e| RenderError::io(out_dir, e))?;

    let mut charts = vec![
        ("energy.png", energy_chart(&stats)),
        ("momentum.png", momentum_chart(&stats)),
        ("contacts.png", contacts_chart(&stats)),
    ];
    if let Some(t) = &timing {
        charts.push(("time.png", time_chart(&stats, t)));
    }
    let mut files = Vec::new();
    for (name, chart) in charts {
        let path = out_dir.join(name);
        draw_chart(&chart, CHART_WIDTH).write_png(&path)?;
        files.push(path);
    }
    Ok(PlotReport { files, warnings })
}

/// The records of a JSON-lines file; a skipped incomplete last line goes to
/// `warnings`.
fn read_lines<T: DeserializeOwned>(
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<Vec<T>, RenderError> {
    let lines = json_lines::read(path, "record")?;
    if let Some(line) = lines.incomplete_last_line {
        warnings.push(json_lines::incomplete_warning(path, line));
    }
    Ok(lines.into_records())
}

/// What [`plot_stats`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotReport {
    /// The charts, in the order [`plot_stats`] lists them.
    pub files: Vec<PathBuf>,
    /// What the user should know although the plot succeeded: an incomplete
    /// last line skipped (a run still writing it).
    pub warnings: Vec<String>,
}

fn series(name: &str, k: usize, points: Vec<(f64, f64)>, style: Style) -> Series {
    Series {
        name: name.into(),
        color: COLORS[k % COLORS.len()],
        points,
        style,
    }
}

fn over_time(stats: &[WindowStats], f: impl Fn(&WindowStats) -> f64) -> Vec<(f64, f64)> {
    stats.iter().map(|s| (s.time, f(s))).collect()
}

fn energy_chart(stats: &[WindowStats]) -> Chart {
    Chart {
        title: "Energy".into(),
        x_label: "simulated time (s)".into(),
        panels: vec![Panel {
            title: "energy (J)".into(),
            series: vec![
                series(
                    "kinetic",
                    0,
                    over_time(stats, |s| s.kinetic_energy),
                    Style::Line,
                ),
                series(
                    "potential",
                    1,
                    over_time(stats, |s| s.potential_energy),
                    Style::Line,
                ),
                series(
                    "contact",
                    2,
                    over_time(stats, |s| s.contact_energy),
                    Style::Line,
                ),
                series(
                    "total",
                    3,
                    over_time(stats, |s| s.kinetic_energy + s.potential_energy),
                    Style::Line,
                ),
            ],
        }],
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn momentum_chart(stats: &[WindowStats]) -> Chart {
    Chart {
        title: "Momentum".into(),
        x_label: "simulated time (s)".into(),
        panels: vec![
            Panel {
                title: "|linear momentum| (kg m/s)".into(),
                series: vec![series(
                    "|p|",
                    0,
                    over_time(stats, |s| norm(s.linear_momentum)),
                    Style::Line,
                )],
            },
            Panel {
                title: "|angular momentum| (kg m^2/s)".into(),
                series: vec![series(
                    "|L|",
                    1,
                    over_time(stats, |s| norm(s.angular_momentum)),
                    Style::Line,
                )],
            },
        ],
    }
}

fn contacts_chart(stats: &[WindowStats]) -> Chart {
    Chart {
        title: "Contacts".into(),
        x_label: "simulated time (s)".into(),
        panels: vec![
            Panel {
                title: "active stencils".into(),
                series: vec![series(
                    "active",
                    0,
                    over_time(stats, |s| s.active_stencils as f64),
                    Style::Line,
                )],
            },
            Panel {
                title: "deepest active layer".into(),
                series: vec![series(
                    "depth",
                    2,
                    over_time(stats, |s| s.max_depth as f64),
                    Style::Line,
                )],
            },
            Panel {
                title: "rollbacks per window".into(),
                series: vec![series(
                    "rollbacks",
                    3,
                    over_time(stats, |s| s.rollbacks as f64),
                    Style::Stems,
                )],
            },
        ],
    }
}

fn time_chart(stats: &[WindowStats], timing: &[WindowTiming]) -> Chart {
    let time_of: BTreeMap<u64, f64> = stats.iter().map(|s| (s.window, s.time)).collect();
    let pick = |f: &dyn Fn(&WindowTiming) -> f64| -> Vec<(f64, f64)> {
        timing
            .iter()
            .filter_map(|t| time_of.get(&t.window).map(|&x| (x, f(t))))
            .collect()
    };
    Chart {
        title: "Wall-clock time".into(),
        x_label: "simulated time (s)".into(),
        panels: vec![Panel {
            title: "wall seconds per window".into(),
            series: vec![
                series("total", 0, pick(&|t| t.wall_seconds), Style::Line),
                series("events", 1, pick(&|t| t.stage_seconds.events), Style::Line),
                series("broad", 2, pick(&|t| t.stage_seconds.broad), Style::Line),
                series("narrow", 3, pick(&|t| t.stage_seconds.narrow), Style::Line),
                series("commit", 4, pick(&|t| t.stage_seconds.commit), Style::Line),
                series(
                    "predict",
                    5,
                    pick(&|t| t.stage_seconds.predict),
                    Style::Line,
                ),
            ],
        }],
    }
}
