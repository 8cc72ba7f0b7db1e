//! `weft run SCENE.toml --out DIR`: simulate and write
//!
//! * `DIR/frames/frame_NNNNN.ply` (or `.obj`): one file per output frame holding
//!   **all objects** (cloth and obstacles) concatenated in input order, with
//!   per-vertex velocities in PLY. Frame k is the committed state at the first
//!   window boundary at or after `k / frame_rate` (its time is in `frames.jsonl`);
//!   frames come only from committed windows.
//! * `DIR/stats.jsonl`: one JSON line per committed window (deterministic:
//!   a resumed run writes the same bytes).
//! * `DIR/timing.jsonl`: one JSON line per committed window with its wall-clock
//!   time, in total and per stage.
//! * `DIR/frames.jsonl`: one line per frame: index, file, time, window.
//! * standard output, last line: one JSON object with `state_hash`, `windows`,
//!   `rollbacks`, `wall_seconds` and more.
//!
//! When the rollback cap is hit, the window's start state is kept in
//! `DIR/repro/` (positions and velocities as PLY, active layers as JSON).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use serde::Serialize;
use weft_io::scene::{load_scene, FrameFormat, Scene};
use weft_sim::{Engine, Serial, SimError, World};

#[derive(Debug, Args)]
pub struct RunArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Override a scene value: `--set key.path=value` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Print nothing but the final JSON line.
    #[arg(long)]
    pub quiet: bool,
}

/// The summary printed as the last line.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub scene: String,
    pub state_hash: String,
    pub windows: u64,
    pub rollbacks: u64,
    pub wall_seconds: f64,
    pub simulated_seconds: f64,
    pub frames: u64,
    pub max_depth: u32,
    pub max_active_stencils: u64,
    pub narrow_queries: u64,
    pub vertices: usize,
    pub triangles: usize,
    pub internal_step: f64,
    pub eta_1: f64,
}

#[derive(Serialize)]
struct FrameRecord<'a> {
    frame: u64,
    file: &'a str,
    time: f64,
    window: u64,
}

pub fn run(a: RunArgs) -> anyhow::Result<ExitCode> {
    let scene = load_scene(&a.scene, &a.overrides)?;
    let summary = simulate(&scene, &a.out, a.quiet)?;
    println!("{}", serde_json::to_string(&summary)?);
    Ok(ExitCode::SUCCESS)
}

/// The folder (under the output folder) that frames of `format` go to.
pub fn frames_folder(format: FrameFormat) -> &'static str {
    match format {
        FrameFormat::Ply => "frames",
        FrameFormat::Obj => "frames-obj",
        FrameFormat::Vtk => "frames-vtk",
    }
}

/// Writes frame `k` in `format`; returns its path relative to `out`.
fn write_frame(out: &Path, k: u64, world: &World, format: FrameFormat) -> anyhow::Result<String> {
    let rel = format!(
        "{}/frame_{k:05}.{}",
        frames_folder(format),
        format.extension()
    );
    let path = out.join(&rel);
    match format {
        FrameFormat::Ply => weft_io::write_ply(&path, &world.x, &world.triangles, Some(&world.v))?,
        FrameFormat::Obj => weft_io::write_obj(&path, &world.x, &world.triangles)?,
        FrameFormat::Vtk => anyhow::bail!("VTK output is not built yet"),
    }
    Ok(rel)
}

/// Runs `scene` to its end time, writing outputs under `out`.
pub fn simulate(scene: &Scene, out: &Path, quiet: bool) -> anyhow::Result<RunSummary> {
    let started = Instant::now();
    for &f in &scene.output.formats {
        let dir = out.join(frames_folder(f));
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let world = World::build(&scene.world)?;
    let mut engine = Engine::new(world, Serial)?;
    let w = &engine.world;
    if !quiet {
        eprintln!(
            "weft: {} — {} vertices, {} triangles, h_el = {:.3e} s, window = {} steps, eta_1 = {:.3e} m",
            scene.name,
            w.num_vertices(),
            w.triangles.len(),
            w.lattice.h_el(),
            w.lattice.steps_per_window,
            w.schedule.eta_1
        );
    }
    let end_tick = w.lattice.window_end_at_or_after(scene.end_time);
    let frame_dt = 1.0 / scene.output.frame_rate;
    let mut stats_file = BufWriter::new(File::create(out.join("stats.jsonl"))?);
    let mut frames_file = BufWriter::new(File::create(out.join("frames.jsonl"))?);
    let mut timing_file = BufWriter::new(File::create(out.join("timing.jsonl"))?);
    let mut frame = 0u64;
    let mut emit = |engine: &Engine<Serial>, frame: &mut u64| -> anyhow::Result<()> {
        let w = &engine.world;
        let mut name = String::new();
        for &f in &scene.output.formats {
            let rel = write_frame(out, *frame, w, f)?;
            if name.is_empty() {
                name = rel;
            }
        }
        let rec = FrameRecord {
            frame: *frame,
            file: &name,
            time: w.time(),
            window: w.window_index,
        };
        writeln!(frames_file, "{}", serde_json::to_string(&rec)?)?;
        *frame += 1;
        Ok(())
    };
    emit(&engine, &mut frame)?;
    let mut last_report = Instant::now();
    while engine.world.tick < end_tick {
        let stats = match engine.step_window() {
            Ok(s) => s,
            Err(e) => {
                if matches!(e, SimError::RollbackCap { .. }) {
                    let _ = save_repro(out, &engine.world);
                }
                stats_file.flush()?;
                frames_file.flush()?;
                return Err(e.into());
            }
        };
        writeln!(stats_file, "{}", serde_json::to_string(&stats)?)?;
        writeln!(timing_file, "{}", serde_json::to_string(&stats.timing())?)?;
        while engine.world.time() + 1e-12 >= frame as f64 * frame_dt {
            emit(&engine, &mut frame)?;
        }
        if !quiet && last_report.elapsed().as_secs_f64() > 2.0 {
            last_report = Instant::now();
            eprintln!(
                "t = {:.4}/{:.4} s  windows {}  rollbacks {}  active {}  depth {}",
                engine.world.time(),
                scene.end_time,
                engine.totals.windows,
                engine.totals.rollbacks,
                stats.active_stencils,
                stats.max_depth
            );
        }
    }
    stats_file.flush()?;
    frames_file.flush()?;
    timing_file.flush()?;
    let w = &engine.world;
    Ok(RunSummary {
        scene: scene.name.clone(),
        state_hash: engine.state_hash(),
        windows: engine.totals.windows,
        rollbacks: engine.totals.rollbacks,
        wall_seconds: started.elapsed().as_secs_f64(),
        simulated_seconds: w.time(),
        frames: frame,
        max_depth: engine.totals.max_depth,
        max_active_stencils: engine.totals.max_active_stencils,
        narrow_queries: engine.totals.narrow_queries,
        vertices: w.num_vertices(),
        triangles: w.triangles.len(),
        internal_step: w.lattice.h_el(),
        eta_1: w.schedule.eta_1,
    })
}

/// Keeps the state of the window that could not commit, for a reproduction.
fn save_repro(out: &Path, world: &World) -> anyhow::Result<()> {
    let dir = out.join("repro");
    std::fs::create_dir_all(&dir)?;
    weft_io::write_ply(
        &dir.join("window_start.ply"),
        &world.x,
        &world.triangles,
        Some(&world.v),
    )?;
    let layers: Vec<_> = world
        .layers
        .stencils
        .iter()
        .map(|(k, s)| serde_json::json!({"key": k, "depth": s.depth, "calm_windows": s.calm_windows}))
        .collect();
    let info = serde_json::json!({
        "tick": world.tick,
        "time": world.time(),
        "window": world.window_index,
        "layers": layers,
    });
    weft_io::write_atomic(&dir.join("window_start.json"), info.to_string().as_bytes())?;
    Ok(())
}
