//! `weft run SCENE.toml --out DIR`: simulate and write
//!
//! * `DIR/frames/frame_NNNNN.ply` (and `frames-obj/…obj`, `frames-vtk/…vtu`
//!   with `DIR/frames.pvd`, as the scene's `output.formats` ask): one file per
//!   output frame holding **all objects** (cloth and obstacles) concatenated in
//!   input order, with per-vertex velocities in PLY and VTK. Frame k is the
//!   committed state at the first window boundary at or after `k / frame_rate`
//!   (its time is in `frames.jsonl`); frames come only from committed windows.
//! * `DIR/objects.json`: each object's name, vertex and triangle ranges.
//! * `DIR/stats.jsonl`: one JSON line per committed window (deterministic:
//!   a resumed run writes the same bytes).
//! * `DIR/timing.jsonl`: one JSON line per committed window with its wall-clock
//!   time, in total and per stage.
//! * `DIR/checkpoint.wckp`: the last checkpoint (every `output.checkpoint_every`
//!   windows or `output.checkpoint_minutes` of wall time, whichever comes
//!   first, at `--stop-after`, on SIGINT / SIGTERM / SIGUSR1, at the rollback
//!   cap and at the end); `weft run --resume DIR` continues from it.
//! * `DIR/manifest.json`: scene, overrides, version, command lines, machine,
//!   status and the last good checkpoint.
//! * `DIR/preview.mp4` or `DIR/preview.gif` and `DIR/render/`: a preview of a
//!   run that completed or was stopped by `--stop-after` (skip with
//!   `--no-preview`).
//! * standard output, last line: one JSON object with `state_hash`, `windows`,
//!   `rollbacks`, `wall_seconds`, `complete` and more.
//!
//! When the rollback cap is hit, the window's start state is kept in
//! `DIR/repro/` (positions and velocities as PLY, active layers as JSON) and
//! checkpointed.

mod faults;
pub mod folder;
mod line_file;
pub mod manifest;
#[cfg(feature = "mpi")]
pub mod mpi_launch;
pub mod outputs;
pub mod progress;
pub mod signals;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Args;
use serde::Serialize;
use weft_io::checkpoint::{read_checkpoint, write_checkpoint, Checkpoint};
use weft_io::scene::{load_scene, OutputSettings, Scene};
use weft_par::Threads;
use weft_sim::{Engine, Executor, Serial, SimError, World};

use manifest::{CheckpointRef, Machine, Manifest, SceneRef, Segment};
use outputs::RunOutputs;
use progress::Progress;
use signals::StopRequest;

/// The checkpoint file in a run folder.
pub const CHECKPOINT_FILE: &str = "checkpoint.wckp";

/// Exit status of a run stopped early with a checkpoint (`--stop-after`,
/// SIGINT, SIGTERM, SIGUSR1): `EX_TEMPFAIL` of `sysexits.h`, "try again
/// later", which job scripts can test to requeue.
pub const EXIT_STOPPED: u8 = 75;

/// The exit statuses, for `weft run --help`.
pub const EXIT_STATUS_HELP: &str = "\
Exit status:
  0         the run reached its end time
  1         an error: bad input, or a failure during the run (DIR/manifest.json then says
            \"failed\", with the error; after a failed write, `--resume DIR` continues from the
            last checkpoint once the cause is removed)
  2         a command-line usage error
  75        stopped early with a checkpoint by --stop-after, SIGINT, SIGTERM or SIGUSR1:
            continue with `weft run --resume DIR` (a job script can requeue on 75)
  130, 143  a second SIGINT or SIGTERM ended the process at once

When standard error is not a terminal, a progress line is logged every 30 s
(WEFT_PROGRESS_INTERVAL=DURATION sets the interval: 10, 5m).";

/// The exit status of a run that ended as `summary` says.
pub fn exit_status(summary: &RunSummary) -> ExitCode {
    match summary.complete {
        true => ExitCode::SUCCESS,
        false => ExitCode::from(EXIT_STOPPED),
    }
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// The scene file (TOML); not given with --resume.
    #[arg(required_unless_present = "resume")]
    pub scene: Option<PathBuf>,
    /// Output folder (created if missing).
    #[arg(long, required_unless_present = "resume", conflicts_with = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the run in DIR from its last checkpoint (only time.end and the
    /// layer policies contact.predict, .layers_per_detection and
    /// .retire_after_windows may be changed with --set).
    #[arg(long, value_name = "DIR", conflicts_with = "scene")]
    pub resume: Option<PathBuf>,
    /// Override a scene value: `--set key.path=value` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Checkpoint and exit (status 75) after this much wall time (3600, 45m,
    /// 1h30m).
    #[arg(long, value_name = "DURATION", value_parser = signals::parse_duration)]
    pub stop_after: Option<Duration>,
    /// Write into an --out folder that is not empty: the files an earlier run
    /// there wrote (its manifest says which; without one, the files named as
    /// a run's outputs) are removed first; other files stay.
    #[arg(long)]
    pub overwrite: bool,
    /// Do not render a preview when the run completes or stops at
    /// --stop-after.
    #[arg(long)]
    pub no_preview: bool,
    /// Worker threads (0: one per logical core). The results are the same
    /// bits for any count.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub threads: usize,
    /// Ranks simulated in this process: threads with memory of their own that
    /// exchange every result as messages — MPI's code paths without MPI. Each
    /// rank gets --threads threads (0: the cores shared out). Same bits for any
    /// count. Under mpirun (feature `mpi`) the ranks are MPI's instead.
    #[arg(long, default_value_t = 1, value_name = "R", value_parser = clap::value_parser!(u32).range(1..=256))]
    pub ranks: u32,
    /// Print nothing but the final JSON line.
    #[arg(long)]
    pub quiet: bool,
    /// Write a timeline of the run to FILE (Chrome-trace JSON; open it in
    /// Perfetto or chrome://tracing): one track per thread, spans per stage and
    /// per task. At most 400,000 spans are kept.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Trace only windows A to B-1 (indices counted from the start of the run).
    #[arg(long, value_name = "A..B", requires = "trace", value_parser = parse_window_range)]
    pub trace_windows: Option<std::ops::Range<u64>>,
}

/// Parses `A..B` (`A..` for "from A on") into a range of window indices.
fn parse_window_range(s: &str) -> Result<std::ops::Range<u64>, String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("'{s}' is not a range A..B of window indices"))?;
    let num = |x: &str, default: u64| -> Result<u64, String> {
        if x.trim().is_empty() {
            return Ok(default);
        }
        x.trim()
            .parse()
            .map_err(|_| format!("'{x}' in '{s}' is not a window index"))
    };
    let (a, b) = (num(a, 0)?, num(b, u64::MAX)?);
    if a >= b {
        return Err(format!("the range '{s}' holds no window"));
    }
    Ok(a..b)
}

/// The summary printed as the last line.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub scene: String,
    pub state_hash: String,
    /// Whether the run reached its end time (false: stopped with a checkpoint).
    pub complete: bool,
    /// A signal name or `stop-after` when the run stopped early.
    pub stopped_by: Option<String>,
    /// The last checkpoint written, if any.
    pub checkpoint: Option<PathBuf>,
    pub windows: u64,
    pub rollbacks: u64,
    /// Wall-clock seconds of this process, and over the run and its resumes.
    pub wall_seconds: f64,
    pub total_wall_seconds: f64,
    pub simulated_seconds: f64,
    pub frames: u64,
    pub max_depth: u32,
    pub max_active_stencils: u64,
    pub narrow_queries: u64,
    /// What ran the engine (rank 0's executor over ranks), and how many
    /// ranks shared the run.
    pub executor: String,
    pub ranks: usize,
    pub vertices: usize,
    pub triangles: usize,
    pub internal_step: f64,
    pub eta_1: f64,
}

/// One run of a scene into an output folder.
#[derive(Clone)]
pub struct RunJob<'a> {
    pub scene: &'a Scene,
    pub out: &'a Path,
    pub quiet: bool,
    /// Continue from `out`'s checkpoint instead of starting fresh.
    pub resume: bool,
    pub stop: StopRequest,
    /// Render `out/preview.*` when the run completes.
    pub preview: bool,
    pub command_line: Vec<String>,
    /// Record timeline spans during these windows (see `weft_sim::trace`).
    pub trace_windows: Option<std::ops::Range<u64>>,
    /// Time between progress lines when standard error is not a terminal.
    pub progress_interval: Duration,
}

pub fn run(a: RunArgs) -> anyhow::Result<ExitCode> {
    #[cfg(feature = "mpi")]
    if mpi_launch::launched() {
        return mpi_launch::run(a);
    }
    let (scene, out, resume) = prepare(&a)?;
    let job = new_job(&a, &scene, &out, resume)?;
    let result = if a.ranks > 1 {
        on_simulated_ranks(&a, job)
    } else {
        let threads = Threads::new(a.threads).context("cannot start the worker threads")?;
        if threads.threads() == 1 {
            execute(job, Serial)
        } else {
            let exec = threads.clone();
            threads.install(move || execute(job, exec))
        }
    };
    // The timeline is written whatever the outcome: a failed run's is the
    // one worth reading.
    if let Some(path) = &a.trace {
        write_trace(path, &scene.name, a.quiet)?;
    }
    let summary = result?;
    println!("{}", serde_json::to_string(&summary)?);
    Ok(exit_status(&summary))
}

/// Runs `job` on `a.ranks` ranks simulated in this process; returns rank 0's
/// summary (every rank ends in the same state), or the first error — rank
/// 0's first, as a peer's error is then only that it lost rank 0.
fn on_simulated_ranks(a: &RunArgs, job: RunJob<'_>) -> anyhow::Result<RunSummary> {
    let ranks = a.ranks as usize;
    let per_rank = match a.threads {
        0 => (std::thread::available_parallelism().map_or(1, |n| n.get()) / ranks).max(1),
        n => n,
    };
    let pools = (0..ranks)
        .map(|_| Threads::new(per_rank))
        .collect::<Result<Vec<_>, _>>()
        .context("cannot start the worker threads")?;
    let results = weft_par::ranks::in_process(
        ranks,
        |r| pools[r].clone(),
        |exec| {
            let pool = exec.local().clone();
            let job = job.clone();
            pool.install(move || execute(job, exec))
        },
    );
    let mut first_error = None;
    let mut summary = None;
    for r in results {
        match r {
            Ok(s) => {
                summary.get_or_insert(s);
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    match (first_error, summary) {
        (Some(e), _) => Err(e),
        (None, Some(s)) => Ok(s),
        (None, None) => bail!("no rank ran"),
    }
}

/// The scene, the output folder, and whether the run resumes: what `a` asks
/// for, checked.
fn prepare(a: &RunArgs) -> anyhow::Result<(Scene, PathBuf, bool)> {
    Ok(match &a.resume {
        Some(dir) => {
            let m = Manifest::read(dir)?;
            let mut overrides = m.overrides.clone();
            overrides.extend(a.overrides.iter().cloned());
            (load_scene(&m.scene.path, &overrides)?, dir.clone(), true)
        }
        None => {
            let (Some(scene), Some(out)) = (&a.scene, &a.out) else {
                bail!("give a scene and --out DIR, or --resume DIR");
            };
            folder::check_fresh_out(out, a.overwrite)?;
            (load_scene(scene, &a.overrides)?, out.clone(), false)
        }
    })
}

/// The job `a` asks for, with stop requests wired to the signals.
fn new_job<'a>(
    a: &RunArgs,
    scene: &'a Scene,
    out: &'a Path,
    resume: bool,
) -> anyhow::Result<RunJob<'a>> {
    let mut stop = StopRequest::new()
        .on_signals()
        .context("cannot install the signal handlers")?;
    if let Some(d) = a.stop_after {
        stop = stop.deadline(d);
    }
    Ok(RunJob {
        scene,
        out,
        quiet: a.quiet,
        resume,
        stop,
        preview: !a.no_preview,
        command_line: std::env::args().collect(),
        trace_windows: a
            .trace
            .as_ref()
            .map(|_| a.trace_windows.clone().unwrap_or(0..u64::MAX)),
        progress_interval: progress::log_interval()?,
    })
}

/// Runs `scene` to its end time from the start, writing outputs under `out`
/// (no signal handling, no preview).
pub fn simulate(scene: &Scene, out: &Path, quiet: bool) -> anyhow::Result<RunSummary> {
    let job = RunJob {
        scene,
        out,
        quiet,
        resume: false,
        stop: StopRequest::new(),
        preview: false,
        command_line: Vec::new(),
        trace_windows: None,
        progress_interval: progress::LOG_INTERVAL,
    };
    execute(job, Serial)
}

/// Writes the recorded spans to `path` as Chrome-trace JSON.
pub(crate) fn write_trace(path: &Path, scene: &str, quiet: bool) -> anyhow::Result<()> {
    weft_sim::trace::set_recording(false);
    let (spans, tracks, dropped) = weft_sim::trace::take();
    let mut text = Vec::new();
    weft_sim::trace::write_chrome_json(
        &mut text,
        0,
        &format!("weft {scene}"),
        &spans,
        &tracks,
        dropped,
    )?;
    weft_io::atomic::write_atomic(path, &text)
        .with_context(|| format!("cannot write the trace {}", path.display()))?;
    if !quiet {
        eprintln!(
            "weft: trace of {} spans on {} threads written to {}{}",
            spans.len(),
            tracks.len(),
            path.display(),
            if dropped > 0 {
                format!(" ({dropped} more spans over the cap were not kept)")
            } else {
                String::new()
            }
        );
    }
    Ok(())
}

/// Hash of the scene text with overrides (end time excluded) and of the world
/// it builds: what a checkpoint must match to be resumed.
pub(crate) fn scene_hash(scene: &Scene, world: &World) -> String {
    let text = format!(
        "{}:{}",
        scene.fingerprint,
        weft_sim::hash::world_fingerprint(world)
    );
    format!("{:032x}", xxhash_rust::xxh3::xxh3_128(text.as_bytes()))
}

/// What a job starts from: the world its scene builds, the scene hash, and on
/// resume the checkpoint (checked against that hash).
pub(crate) struct Prepared {
    world: World,
    hash: String,
    checkpoint: Option<Checkpoint>,
}

impl Prepared {
    /// Builds `scene`'s world for `workers` = ranks × threads (the
    /// automatic partition count depends on it, the results do not), with
    /// the internal step estimated on `exec`'s threads and ranks (the same
    /// bits on any number; collective over ranks) and, when `resume`, reads
    /// `out`'s checkpoint.
    pub(crate) fn new<E: Executor>(
        scene: &Scene,
        out: &Path,
        resume: bool,
        workers: usize,
        exec: &E,
    ) -> anyhow::Result<Self> {
        let mut spec = scene.world.clone();
        spec.workers = workers;
        let world = weft_par::build_world_on(&spec, exec)?;
        let hash = scene_hash(scene, &world);
        let checkpoint = match resume {
            true => Some(read_resumable(out, &hash)?),
            false => None,
        };
        Ok(Self {
            world,
            hash,
            checkpoint,
        })
    }
}

/// Runs a job: see the module documentation for what it writes.
pub fn execute<E: Executor>(job: RunJob<'_>, exec: E) -> anyhow::Result<RunSummary> {
    let workers = exec.ranks() * exec.threads_per_rank();
    let prepared = Prepared::new(job.scene, job.out, job.resume, workers, &exec)?;
    execute_prepared(job, prepared, exec)
}

/// [`execute`] from a [`Prepared`] start.
///
/// On an executor spread over ranks every rank calls this with the same job:
/// every rank steps the same windows (the engine's collectives keep them in
/// step) and only rank 0 writes — outputs, checkpoints, manifest, progress.
/// The ranks agree at every window boundary whether to stop, so a signal or
/// deadline that reached only some of them stops all at the same window.
pub(crate) fn execute_prepared<E: Executor>(
    job: RunJob<'_>,
    prepared: Prepared,
    exec: E,
) -> anyhow::Result<RunSummary> {
    let started = Instant::now();
    let (scene, out) = (job.scene, job.out);
    let leader = exec.rank() == 0;
    let spread = exec.ranks() > 1;
    if leader {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    }
    let Prepared {
        world,
        hash,
        checkpoint,
    } = prepared;
    if leader && !job.quiet {
        super::startup::print(&super::startup::warnings(scene, &world));
    }
    let mut engine = Engine::new(world, exec)?;
    let (frame_dt, frame_note) = frame_interval(scene, &engine.world);
    let machine = Machine::this();
    let mut prior_wall = 0.0;
    let mut writer = None;
    if let Some(ck) = checkpoint {
        let path = out.join(CHECKPOINT_FILE);
        engine
            .restore(ck.engine)
            .with_context(|| format!("{}", path.display()))?;
        prior_wall = ck.wall_seconds;
        if leader {
            folder::remove_abandoned_temporaries(out);
            let outputs = RunOutputs::resume(out, &scene.output.formats, frame_dt, &ck.cursors)?;
            let mut m = Manifest::read(out)?;
            m.overrides = scene.overrides.clone();
            m.end_time = scene.end_time;
            m.segments.push(Segment {
                started: manifest::now_utc(),
                command_line: job.command_line.clone(),
                from_window: engine.world.window_index,
                machine,
            });
            writer = Some((outputs, m));
        }
    } else if leader {
        // Only now that the scene is good: what --overwrite replaces.
        folder::remove_previous_run(out)?;
        let outputs = RunOutputs::create(out, &scene.output.formats, frame_dt)?;
        write_objects(out, &engine.world)?;
        let m = Manifest {
            weft_version: env!("CARGO_PKG_VERSION").into(),
            scene: SceneRef {
                path: std::fs::canonicalize(&scene.path).unwrap_or_else(|_| scene.path.clone()),
                name: scene.name.clone(),
                hash: hash.clone(),
            },
            overrides: scene.overrides.clone(),
            end_time: scene.end_time,
            frame_folders: scene
                .output
                .formats
                .iter()
                .map(|&f| outputs::frames_folder(f).to_string())
                .collect(),
            status: String::new(),
            stopped_by: None,
            error: None,
            last_checkpoint: None,
            segments: vec![Segment {
                started: manifest::now_utc(),
                command_line: job.command_line.clone(),
                from_window: 0,
                machine,
            }],
            updated: String::new(),
        };
        writer = Some((outputs, m));
    }
    if let Some((_, manifest)) = &mut writer {
        manifest.status = "running".into();
        manifest.stopped_by = None;
        manifest.error = None;
        manifest.write(out)?;
    }
    // On one memory the engine stops mid-window on a request; over ranks
    // they agree at window boundaries instead (a rank alone cannot stop).
    if !spread {
        engine.set_interrupt(job.stop.flag.clone());
    }
    let quiet = job.quiet || !leader;

    let w = &engine.world;
    if !quiet {
        eprintln!(
            "weft: {} — {} vertices, {} triangles, h_el = {:.3e} s, window = {} steps, eta_1 = {:.3e} m, {}{}",
            scene.name,
            w.num_vertices(),
            w.triangles.len(),
            w.lattice.h_el(),
            w.lattice.steps_per_window,
            w.schedule.eta_1,
            engine.executor().name(),
            if job.resume {
                format!(", resumed at t = {:.6} s (window {})", w.time(), w.window_index)
            } else {
                String::new()
            }
        );
    }
    if let (false, Some(note)) = (quiet, frame_note) {
        eprintln!("weft: note: {note}");
    }
    let end_tick = w.lattice.window_end_at_or_after(scene.end_time);
    let mut progress = Progress::new(
        quiet,
        job.progress_interval,
        w.time(),
        engine.totals.windows,
        scene.end_time,
    );
    let mut saver = Saver {
        out,
        hash: &hash,
        scene_name: &scene.name,
        written: 0,
        prior_wall,
        started,
        last_written: Instant::now(),
    };
    // Every error from here on leaves the manifest `failed`, naming it.
    let ended = step_to_end(
        &mut engine,
        &job,
        end_tick,
        &mut writer,
        &mut saver,
        &mut progress,
    );
    progress.finish();
    let stopped_by = match ended {
        Ok(stopped_by) => stopped_by,
        Err(e) => return Err(record_failure(e, &engine, &mut writer, &mut saver)),
    };
    let complete = stopped_by.is_none();
    let frames = writer
        .as_ref()
        .map_or(0, |(outputs, _)| outputs.frames_written());
    if !quiet {
        if let Some(why) = stopped_by {
            eprintln!(
                "weft: stopped by {why} at t = {:.6} s (window {}); continue with `weft run --resume {}`",
                engine.world.time(),
                engine.world.window_index,
                out.display()
            );
        }
    }
    // A run stopped by --stop-after has time left for a preview of the
    // frames so far; one stopped by a signal is asked to end now.
    let previewed = complete || stopped_by == Some(signals::STOP_AFTER);
    if previewed && job.preview && leader {
        preview(out, job.quiet, scene_camera(scene));
    }
    let w = &engine.world;
    let wall = started.elapsed().as_secs_f64();
    Ok(RunSummary {
        scene: scene.name.clone(),
        state_hash: engine.state_hash(),
        complete,
        stopped_by: stopped_by.map(String::from),
        checkpoint: Some(out.join(CHECKPOINT_FILE)),
        windows: engine.totals.windows,
        rollbacks: engine.totals.rollbacks,
        wall_seconds: wall,
        total_wall_seconds: prior_wall + wall,
        simulated_seconds: w.time(),
        frames,
        max_depth: engine.totals.max_depth,
        max_active_stencils: engine.totals.max_active_stencils,
        narrow_queries: engine.totals.narrow_queries,
        executor: engine.executor().name(),
        ranks: engine.executor().ranks(),
        vertices: w.num_vertices(),
        triangles: w.triangles.len(),
        internal_step: w.lattice.h_el(),
        eta_1: w.schedule.eta_1,
    })
}

/// Steps `engine` to `end_tick` or to a stop request, writing every
/// committed window's outputs and the checkpoints, then a last checkpoint;
/// returns what stopped the run early, if anything.
fn step_to_end<E: Executor>(
    engine: &mut Engine<E>,
    job: &RunJob<'_>,
    end_tick: u64,
    writer: &mut Option<(RunOutputs, Manifest)>,
    saver: &mut Saver<'_>,
    progress: &mut Progress,
) -> anyhow::Result<Option<&'static str>> {
    let out = job.out;
    let mut stopped_by = None;
    if let Some((outputs, _)) = writer {
        outputs.frames_due(&engine.world)?;
    }
    while engine.world.tick < end_tick {
        if let Some(range) = &job.trace_windows {
            weft_sim::trace::set_recording(range.contains(&engine.world.window_index));
        }
        let window = match engine.step_window() {
            Ok(w) => w,
            Err(SimError::Interrupted { .. }) => {
                stopped_by = Some(job.stop.reason().unwrap_or("interrupt"));
                break;
            }
            Err(e) => return Err(e.into()),
        };
        if let Some((outputs, manifest)) = writer {
            outputs.record_window(&window)?;
            outputs.frames_due(&engine.world)?;
            progress.update(&progress::Snapshot {
                time: engine.world.time(),
                windows: engine.totals.windows,
                rollbacks: engine.totals.rollbacks,
                active: window.stats.active_stencils,
                depth: window.stats.max_depth,
            });
            if saver.due(&job.scene.output, engine.world.window_index)
                && engine.world.tick < end_tick
            {
                manifest.last_checkpoint = Some(saver.save(engine, outputs)?);
                manifest.write(out)?;
            }
        }
        let stop = job.stop.requested();
        if engine.executor().any_rank(stop)? {
            // A rank that was not asked itself names the request it joined.
            stopped_by = Some(
                job.stop
                    .reason()
                    .unwrap_or("a stop request on another rank"),
            );
            break;
        }
    }
    if let Some((outputs, manifest)) = writer {
        // Also at the end: a completed run can be extended with --resume.
        manifest.last_checkpoint = Some(saver.save(engine, outputs)?);
        manifest.status = if stopped_by.is_none() {
            "complete"
        } else {
            "stopped"
        }
        .into();
        manifest.stopped_by = stopped_by.map(String::from);
        manifest.write(out)?;
    }
    Ok(stopped_by)
}

/// Records in the manifest that the run failed with `e` and returns the error
/// to report: an engine error as it is (its own advice, its type kept; with a
/// note when the manifest could not record it), any other failure with how to
/// go on from the last checkpoint. At the rollback cap the engine is back at
/// the window start (the last commit): that state is kept for a reproduction
/// and checkpointed. Any other failure (an engine error, a write that failed)
/// checkpoints nothing: the outputs may lag the engine, and the last good
/// checkpoint stays the one to resume from.
fn record_failure<E: Executor>(
    e: anyhow::Error,
    engine: &Engine<E>,
    writer: &mut Option<(RunOutputs, Manifest)>,
    saver: &mut Saver<'_>,
) -> anyhow::Error {
    let Some((outputs, manifest)) = writer else {
        return e;
    };
    let out = saver.out;
    let engine_error = e.downcast_ref::<SimError>();
    if matches!(engine_error, Some(SimError::RollbackCap { .. })) {
        let _ = save_repro(out, &engine.world);
        if let Ok(r) = saver.save(engine, outputs) {
            manifest.last_checkpoint = Some(r);
        }
    }
    manifest.status = "failed".into();
    manifest.error = Some(crate::error_text(&e));
    // The manifest's write error names the file.
    let recorded = manifest.write(out).map_err(|m| {
        format!(
            "the run failed, and recording that in the manifest failed too ({})",
            crate::error_text(&m)
        )
    });
    if engine_error.is_some() {
        // The simulation's own error says what to change (a resume would
        // meet it again), and it keeps its type: under MPI every rank has
        // the same one and exits with it instead of aborting the job.
        return match recorded {
            Ok(()) => e,
            Err(note) => e.context(note),
        };
    }
    // Not the simulation's fault: say how to go on.
    let resume = match &manifest.last_checkpoint {
        Some(ck) => format!(
            "the run can go on from its last checkpoint (window {}, t = {:.6} s): remove the \
             cause, then `weft run --resume {}`",
            ck.window,
            ck.time,
            out.display()
        ),
        None => format!(
            "the run failed before its first checkpoint: remove the cause, then start it \
             again: `{}`",
            manifest.restart_command(out)
        ),
    };
    let manifest_note = match recorded {
        Ok(()) => String::new(),
        Err(note) => format!("; {note}"),
    };
    anyhow::anyhow!("{}{manifest_note}\n  {resume}", crate::error_text(&e))
}

/// Simulated seconds between frames: `1 / output.frame_rate`, but at least one
/// window, as frames are committed states and those exist only at window
/// boundaries (a faster rate wrote the same state several times over). When
/// the scene asks for more, also the note that says so.
fn frame_interval(scene: &Scene, world: &World) -> (f64, Option<String>) {
    let asked = 1.0 / scene.output.frame_rate;
    let window = world.lattice.seconds(world.lattice.window());
    // Within rounding of the window (100 frames/s of 0.01 s windows) is no news.
    if asked >= window * (1.0 - 1e-9) {
        return (asked.max(window), None);
    }
    let note = format!(
        "output.frame_rate = {} frames/s is above the window rate ({:.6} windows/s of {:.4e} s): \
         frames are committed states, taken at window boundaries, so one frame per window is \
         written instead; lower output.frame_rate, or shorten the window (time.window or \
         time.steps_per_window)",
        scene.output.frame_rate,
        1.0 / window,
        window
    );
    (window, Some(note))
}

/// The checkpoint in run folder `out`, if it can be resumed by a scene whose
/// hash is `hash`.
fn read_resumable(out: &Path, hash: &str) -> anyhow::Result<Checkpoint> {
    let path = out.join(CHECKPOINT_FILE);
    if !path.exists() {
        let restart = Manifest::read(out).map_or_else(
            |_| format!("weft run SCENE --out {} --overwrite", out.display()),
            |m| m.restart_command(out),
        );
        bail!(
            "{} has no checkpoint to resume from ({} is missing): the run ended before its \
             first checkpoint, so there is nothing to continue; start it again, replacing \
             it: `{restart}`",
            out.display(),
            path.display()
        );
    }
    let ck = read_checkpoint(&path)?;
    if ck.scene_hash != hash {
        bail!(
            "{}: the checkpoint was made from a different scene (scene hash {} there, {} now); \
             the scene file, a mesh it reads or an override changed — only time.end and the \
             layer policies (contact.predict, .layers_per_detection, .retire_after_windows) \
             may change on resume",
            path.display(),
            ck.scene_hash,
            hash
        );
    }
    Ok(ck)
}

/// Writes checkpoints of one process.
struct Saver<'a> {
    out: &'a Path,
    hash: &'a str,
    scene_name: &'a str,
    /// Checkpoints written so far (numbers the `checkpoint-rename` failpoint).
    written: u64,
    prior_wall: f64,
    started: Instant,
    /// When the last checkpoint was written (the start, before the first).
    last_written: Instant,
}

impl Saver<'_> {
    /// Whether a checkpoint is due after committing window `window` (its
    /// index counted from the start of the run): every `checkpoint_every`
    /// windows, and once `checkpoint_minutes` of wall time have passed
    /// since the last one.
    fn due(&self, output: &OutputSettings, window: u64) -> bool {
        let every = output.checkpoint_every;
        let minutes = output.checkpoint_minutes;
        (every > 0 && window % every == 0)
            || (minutes > 0.0 && self.last_written.elapsed().as_secs_f64() >= minutes * 60.0)
    }

    /// Checkpoints the engine's committed state with where each output
    /// file stands ([`RunOutputs::cursors`] makes their lines durable first).
    fn save<E: Executor>(
        &mut self,
        engine: &Engine<E>,
        outputs: &RunOutputs,
    ) -> anyhow::Result<CheckpointRef> {
        let ck = Checkpoint {
            weft_version: env!("CARGO_PKG_VERSION").into(),
            scene_name: self.scene_name.into(),
            scene_hash: self.hash.into(),
            engine: engine.state(),
            cursors: outputs.cursors()?,
            wall_seconds: self.prior_wall + self.started.elapsed().as_secs_f64(),
        };
        self.written += 1;
        let n = self.written;
        let path = self.out.join(CHECKPOINT_FILE);
        faults::injected("write:checkpoint", n)
            .with_context(|| format!("cannot write the checkpoint {}", path.display()))?;
        write_checkpoint(&path, &ck, || {
            weft_sim::failpoint::hit("checkpoint-rename", n)
        })?;
        self.last_written = Instant::now();
        let w = &engine.world;
        Ok(CheckpointRef {
            file: CHECKPOINT_FILE.into(),
            window: w.window_index,
            tick: w.tick,
            time: w.time(),
            written: manifest::now_utc(),
        })
    }
}

/// `objects.json`: names and ranges of the objects in the frame files.
fn write_objects(out: &Path, world: &World) -> anyhow::Result<()> {
    let objects: Vec<_> = world
        .objects
        .iter()
        .map(|o| {
            serde_json::json!({
                "name": o.name,
                "vertices": [o.vertices.start, o.vertices.end],
                "triangles": [o.triangles.start, o.triangles.end],
                "cloth": o.is_cloth,
            })
        })
        .collect();
    let text = serde_json::to_string_pretty(&serde_json::json!({ "objects": objects }))? + "\n";
    weft_io::write_atomic(&out.join("objects.json"), text.as_bytes())?;
    Ok(())
}

/// The scene's `[camera]` as a render camera.
pub fn scene_camera(scene: &Scene) -> Option<weft_render::Camera> {
    scene.camera.as_ref().map(|c| weft_render::Camera {
        eye: glam::DVec3::from_array(c.eye),
        target: glam::DVec3::from_array(c.target),
        up: glam::DVec3::from_array(c.up),
        fov_y_degrees: c.fov_degrees,
    })
}

/// The `[camera]` of the scene a run folder was made from, if its manifest
/// and scene can still be read.
pub fn camera_of_run(dir: &Path) -> Option<weft_render::Camera> {
    let m = Manifest::read(dir).ok()?;
    let scene = load_scene(&m.scene.path, &m.overrides).ok()?;
    scene_camera(&scene)
}

/// Renders the preview of the frames so far; a failure is reported, not fatal
/// (the simulation's outputs are already written).
fn preview(out: &Path, quiet: bool, camera: Option<weft_render::Camera>) {
    let opts = weft_render::RenderOptions {
        width: 480,
        height: 360,
        camera,
        ..Default::default()
    };
    match weft_render::render_run(out, &opts) {
        Ok(r) if !quiet => {
            for w in &r.warnings {
                eprintln!("weft: preview: {w}");
            }
            if let Some(p) = &r.preview {
                eprintln!(
                    "weft: preview {} ({} frames in {:.1} s)",
                    p.display(),
                    r.frames.len(),
                    r.seconds
                );
            }
        }
        Ok(_) => {}
        Err(e) => eprintln!("weft: warning: no preview: {e}"),
    }
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
