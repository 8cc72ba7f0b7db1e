//! `weft bench [SCENE] [--size N] [--checkpoint FILE] [--make-checkpoint]
//! [--windows N] [--threads 1,2,...] [--repeats N] [--json]`: the engine's
//! throughput on a scene at the published discretization (windows of 1/3000 s
//! of 140 internal steps), starting from a checkpoint in a contact-heavy state.
//!
//! For each thread count and each repeat the engine is built afresh, restored
//! from the checkpoint and stepped `--windows` windows; the report holds the
//! median over the repeats of the wall time per window (in total and per
//! stage), internal stencil evaluations per core-second, narrow-phase queries
//! per second, and the parallel efficiency T(1) / (n T(n)); the rollbacks per
//! window, the state hash after the run (checked equal for every run and
//! thread count), the process's peak memory per vertex and the machine's
//! processor topology.
//!
//! Over ranks (`--ranks R,...` simulates them in this process; under
//! `mpirun` they are MPI's) it also reports each rank's stage times, the
//! messages and bytes each rank sends per window, and the narrow phase's load
//! imbalance (max / mean of the measured per-rank seconds) as placed by the
//! balancer and as it would be with every task on its home rank.

pub mod machine;
pub mod project;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Args;
use serde::Serialize;
use weft_io::checkpoint::read_checkpoint;
use weft_io::scene::load_scene;
use weft_par::Threads;
use weft_sim::diagnostics::{PerStage, StageCpu, StageSent};
use weft_sim::{CommittedWindow, Engine, EngineState, Executor, NarrowLoad, Serial, World};

use super::run::{execute, scene_hash, signals::StopRequest, RunJob, CHECKPOINT_FILE};
use machine::Topology;

/// The published discretization (Ni et al.): windows of 1/3000 s ...
const PUBLISHED_WINDOW: f64 = 1.0 / 3000.0;
/// ... of 140 internal steps each.
const PUBLISHED_STEPS: u64 = 140;

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// The scene file (TOML).
    #[arg(default_value = "scenes/twister.toml")]
    pub scene: PathBuf,
    /// Override a scene value: `--set key.path=value` (repeatable). Applied after
    /// the published discretization (`time.window=1/3000`, `time.steps_per_window=140`),
    /// so `--set` can replace it.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// About N cloth vertices (`--set size=N`).
    #[arg(long, value_name = "N")]
    pub size: Option<u64>,
    /// The checkpoint to start from [default: bench/SCENE-SIZE.wckp]. It must
    /// come from the same scene, size and overrides.
    #[arg(long, value_name = "FILE")]
    pub checkpoint: Option<PathBuf>,
    /// Make the checkpoint first: run the scene from the start to --warmup in the
    /// folder CHECKPOINT.warmup/ (CHECKPOINT without its extension) and copy its checkpoint.
    #[arg(long)]
    pub make_checkpoint: bool,
    /// Simulated seconds the --make-checkpoint run covers (rounded up to a whole
    /// window); by the default the twister's sleeve has shrunk onto the rod and
    /// grips it (about 1,000 active stencils at --size 2000).
    #[arg(long, value_name = "SECONDS", default_value_t = 0.01)]
    pub warmup: f64,
    /// Windows per run.
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub windows: u64,
    /// Thread counts to run, comma separated (1: the serial executor)
    /// [default: 1 and one per available logical CPU].
    #[arg(long, value_name = "N,...", value_delimiter = ',')]
    pub threads: Vec<usize>,
    /// Rank counts to run, comma separated: ranks simulated in this process,
    /// each with the listed thread counts [default: 1]. Under mpirun the rank
    /// count is MPI's; do not give this option then.
    #[arg(long, value_name = "R,...", value_delimiter = ',')]
    pub ranks: Vec<usize>,
    /// Runs per thread count; the report holds their median.
    #[arg(long, value_name = "N", default_value_t = 5)]
    pub repeats: usize,
    /// Also print the report as one JSON object on the last line.
    #[arg(long)]
    pub json: bool,
    /// Write a timeline (Chrome-trace JSON, as `weft run --trace`) of the last
    /// run of the largest thread count.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Project the time per window to these rank counts (a model, not a
    /// measurement: `bench/project.rs`): replays the simulated ranks'
    /// communication steps of `--ranks` (1 and two or more counts above it,
    /// `--threads 1`) under a LogGP network.
    #[arg(long, value_name = "R,...", value_delimiter = ',')]
    pub project: Vec<usize>,
    /// The projection's network latency L, microseconds (the three network
    /// defaults: an InfiniBand HDR cluster).
    #[arg(long, value_name = "US", default_value_t = 1.0)]
    pub latency_us: f64,
    /// The projection's CPU overhead o per message, microseconds.
    #[arg(long, value_name = "US", default_value_t = 0.3)]
    pub overhead_us: f64,
    /// The projection's bandwidth per rank, GB/s.
    #[arg(long, value_name = "GB/S", default_value_t = 25.0)]
    pub bandwidth_gbs: f64,
    /// How the projection's collectives travel: `dissemination`, Bruck's
    /// `⌈log2 R⌉` rounds, as weft's transports run them, or `linear`, each
    /// rank's part to every other rank (Open MPI 4.1's nonblocking ones).
    #[arg(long, value_enum, default_value = "dissemination")]
    pub collectives: project::Collectives,
}

/// The totals of one run of `--windows` windows.
#[derive(Clone, Debug, Default)]
struct Sample {
    /// This rank's wall and stage seconds, and what it sent.
    own: RankSample,
    internal_evaluations: u64,
    /// Internal stencil evaluations over all passes (rolled-back ones too).
    internal_evaluations_all_passes: u64,
    /// Internal ticks over all passes (rolled-back ones too).
    internal_ticks_all_passes: u64,
    layer_events: u64,
    /// Exact distance evaluations at penalty batches (the other layer
    /// events were skipped by a certificate or a distance bound).
    layer_evaluations: u64,
    /// Contact islands summed over windows, and the layer events of each
    /// window's largest island.
    islands: u64,
    largest_island_layer_events: u64,
    /// Far stencils at the pass starts, promoted, and unit reruns, summed
    /// over windows (`contact.split_islands`).
    far: [u64; 4],
    /// Vertices that moved to another rank with their unit in a merge
    /// (`contact.split_islands` over ranks; the same count on every rank).
    moved_between_ranks: u64,
    /// Windows whose islands were split (`contact.split_islands`; unset,
    /// from 4 ranks and from 8 threads per rank on).
    split_windows: u64,
    rollbacks: u64,
    /// Layers activated by prediction and by detection, and the predicted
    /// ones never reached, summed over windows.
    predicted_layers: u64,
    detected_layers: u64,
    predicted_unreached: u64,
    /// Committed passes' candidates and the breakpoints their vertices had.
    candidates: u64,
    queried_breakpoints: u64,
    /// Intervals certified, and those certified by block bounds alone.
    certified_intervals: u64,
    block_certified_intervals: u64,
    /// Narrow-phase queries over all passes (rolled-back ones included).
    narrow_queries: u64,
    active_stencils: u64,
    max_depth: u32,
    /// Stencils per contact island after the last window.
    island_sizes: Vec<u64>,
    state_hash: String,
    /// Each rank's own figures (one entry on one rank).
    ranks: Vec<RankSample>,
    /// Measured narrow-phase seconds per rank, balanced and home-only.
    narrow_load: NarrowLoad,
    /// Simulated ranks recording their steps (`--project`): each rank's
    /// communication steps of the windows run.
    steps: Vec<Vec<weft_par::ranks::SyncStep>>,
}

/// One rank's totals over a run.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
struct RankSample {
    wall: f64,
    events: f64,
    broad: f64,
    narrow: f64,
    commit: f64,
    /// The layer prediction (before each window's first pass).
    #[serde(default)]
    predict: f64,
    /// The internal-force part of `events`.
    internal: f64,
    /// CPU seconds of this rank's work per stage, and over the whole run
    /// (`weft_sim::cpu`; polling for peers left out), and the polling.
    cpu: StageCpu,
    cpu_total: f64,
    cpu_polling: f64,
    /// Bytes this rank sent per stage.
    sent: StageSent,
    /// This rank's process's peak resident memory (VmHWM), bytes.
    peak_rss: Option<u64>,
    messages: u64,
    bytes: u64,
    /// Collectives and point-to-point exchanges this rank took part in.
    collectives: u64,
    exchanges: u64,
}

/// One rank's figures per window (median run).
#[derive(Clone, Debug, Serialize)]
pub struct RankFigures {
    pub rank: usize,
    pub stage_seconds_per_window: StageTimes,
    /// CPU seconds of the rank's work per window, per stage and in all
    /// (polling for peers left out), and the polling left out.
    pub cpu_seconds_per_window: StageCpu,
    pub cpu_total_seconds_per_window: f64,
    pub cpu_polling_seconds_per_window: f64,
    /// The peak resident memory of the rank's process (simulated ranks
    /// share one process, hence one figure).
    pub peak_rss_bytes: Option<u64>,
    pub messages_per_window: f64,
    pub bytes_per_window: f64,
    /// The bytes sent per window, per stage.
    pub sent_bytes_per_window: StageSent,
    /// Communication rounds per window, and both together per internal tick
    /// of every pass (rolled-back ones included).
    pub collectives_per_window: f64,
    pub exchanges_per_window: f64,
    pub rounds_per_internal_tick: f64,
}

/// Seconds per window, median over the repeats.
#[derive(Clone, Debug, Serialize)]
pub struct StageTimes {
    pub events: f64,
    pub broad: f64,
    pub narrow: f64,
    pub commit: f64,
    /// The layer prediction before each window's first pass.
    pub predict: f64,
    /// The internal-force part of `events`.
    pub internal: f64,
    /// Wall time outside the five stages (snapshots, restores, statistics).
    pub other: f64,
}

/// The figures of one rank count and thread count.
#[derive(Clone, Debug, Serialize)]
pub struct ThreadResult {
    pub ranks: usize,
    /// Threads per rank.
    pub threads: usize,
    pub executor: String,
    /// Median wall-clock seconds per window, and each run's.
    pub wall_seconds_per_window: f64,
    pub runs_wall_seconds_per_window: Vec<f64>,
    pub stage_seconds_per_window: StageTimes,
    /// Committed-pass internal stencil evaluations / (wall seconds · threads).
    pub internal_evaluations_per_core_second: f64,
    /// The same over the events stage's time only.
    pub internal_evaluations_per_events_core_second: f64,
    /// The internal-force stage alone: evaluations over all passes / (its
    /// wall seconds · threads).
    pub internal_stage_evaluations_per_core_second: f64,
    /// Narrow-phase queries (all passes) / narrow-stage seconds.
    pub narrow_queries_per_second: f64,
    /// T(1) / T(n) and T(1) / (n · T(n)) from the medians, n = ranks ·
    /// threads (null without a 1-rank 1-thread run).
    pub speedup: Option<f64>,
    pub parallel_efficiency: Option<f64>,
    /// Over ranks: each rank's figures (the median run's), and the narrow
    /// phase's load imbalance, max / mean of the per-rank measured seconds,
    /// as the balancer placed the tasks and with each on its home rank.
    pub per_rank: Vec<RankFigures>,
    /// Counted scaling: the ranks' work CPU per window in all; its ratio to
    /// one process's (the 1-rank 1-thread run: redundancy); the largest
    /// rank's (the critical path); and T1 / critical path, the most this
    /// rank count could speed the work up with a free network.
    pub cpu_sum_seconds_per_window: f64,
    pub redundancy: Option<f64>,
    pub critical_path_seconds_per_window: f64,
    pub speedup_bound: Option<f64>,
    pub narrow_imbalance: Option<f64>,
    pub narrow_imbalance_home_only: Option<f64>,
    /// Over ranks with the units spread (`contact.split_islands`): the
    /// vertices per window that moved to another rank with their unit.
    pub moved_between_ranks_per_window: f64,
    /// The share of the windows whose islands were split (the median
    /// run's).
    pub split_window_share: f64,
}

/// What `weft bench` reports.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub scene: String,
    pub scene_path: PathBuf,
    pub overrides: Vec<String>,
    pub scene_hash: String,
    pub checkpoint: PathBuf,
    pub vertices: usize,
    pub cloth_vertices: usize,
    pub triangles: usize,
    pub internal_stencils: usize,
    pub partitions: usize,
    pub window_seconds: f64,
    pub steps_per_window: u64,
    pub internal_step: f64,
    /// Wall seconds this process (rank 0 under `mpirun`) took to build the
    /// world, most of it the internal step's estimate, which the
    /// `build_workers` (ranks, threads per rank) shared. Not in the windows'
    /// times: every run of a bench starts from the one world.
    pub build_seconds: f64,
    pub build_workers: [usize; 2],
    /// Simulated time, window index and active (penalty) stencils at the checkpoint.
    pub start_time: f64,
    pub start_window: u64,
    pub start_active_stencils: usize,
    pub windows: u64,
    pub repeats: usize,
    /// Per window of the benchmark (the same in every run).
    pub rollbacks_per_window: f64,
    /// Layers activated per window by prediction (`contact.predict`) and by
    /// detection (rollbacks), and the predicted ones never reached.
    pub predicted_layers_per_window: f64,
    pub detected_layers_per_window: f64,
    pub predicted_unreached_per_window: f64,
    /// Breakpoints per vertex of a committed pass's narrow-phase query: the
    /// trajectory length the narrow phase's cost follows.
    pub breakpoints_per_queried_vertex: Option<f64>,
    /// Of the time intervals the certificates (narrow phase and commit)
    /// certified, the share certified by the trajectories' block bounds
    /// alone, no segment walked (`None` when none was certified).
    pub block_certified_share: Option<f64>,
    pub narrow_queries_per_window: f64,
    pub internal_evaluations_per_window: f64,
    pub layer_events_per_window: f64,
    /// Of the layer events, those evaluated exactly (per window).
    pub layer_evaluations_per_window: f64,
    /// Contact islands per window, and the largest island's share of the
    /// layer events (what bounds running islands in parallel).
    pub islands_per_window: f64,
    /// Per window: far stencils at the pass start, promoted, unit reruns.
    pub far_per_window: [f64; 3],
    /// The largest unit's share of the layer events (split islands).
    pub largest_unit_share: Option<f64>,
    pub largest_island_share: Option<f64>,
    /// Active stencils and their deepest layer after the last window.
    pub end_active_stencils: u64,
    pub end_max_depth: u32,
    /// The contact islands of the active stencils after the last window, by
    /// size: entry `k` counts the islands of `2^k ..= 2^(k+1) - 1` stencils;
    /// and the largest island's stencils.
    pub end_island_sizes: Vec<u64>,
    pub end_largest_island: u64,
    /// State hash after the last window, and whether every run agreed on it.
    pub state_hash: String,
    pub deterministic: bool,
    /// Peak resident memory of the process while benchmarking (VmHWM), in
    /// bytes and per vertex; null where the system does not tell.
    pub peak_rss_bytes: Option<u64>,
    pub peak_bytes_per_vertex: Option<f64>,
    pub machine: Topology,
    pub results: Vec<ThreadResult>,
    /// `--project`: the modelled times per window.
    pub projection: Option<ProjectionReport>,
}

/// What `--project` reports: a model, not a measurement.
#[derive(Clone, Debug, Serialize)]
pub struct ProjectionReport {
    pub network: project::Network,
    /// One process's work CPU per window (T1 of the efficiencies).
    pub one_process_seconds_per_window: Option<f64>,
    /// Each measured rank count: the replay of its steps (seconds per
    /// window) and its counted critical path.
    pub replayed: Vec<(usize, f64, f64)>,
    /// Each measured rank count: summed over the intervals between its
    /// collectives, the busiest rank's work and the mean rank's (seconds
    /// per window; `project::between_collectives`).
    pub between_collectives: Vec<(usize, f64, f64)>,
    /// The fit summed over the intervals (seconds per window): the work
    /// that does not shrink with the ranks (Σ a) and the work shared (Σ b,
    /// the busiest rank's is Σ b / R).
    pub fit: (f64, f64),
    /// The fit and the imbalance at the largest measured count, by the
    /// site of the collective ending each interval (seconds per window;
    /// `project::by_site`), largest Σ a first.
    pub by_site: Vec<project::SiteShare>,
    /// Each asked rank count: the model's seconds per window (and its
    /// parts), and T1 / (R · T(R)).
    pub projected: Vec<(project::Projected, Option<f64>)>,
}

/// How the ranks of a bench run are made.
#[derive(Clone, Copy)]
enum Launch<'a> {
    /// In this process: one memory, or ranks simulated on threads.
    Local,
    /// This process is one MPI rank.
    #[cfg(feature = "mpi")]
    Mpi(&'a weft_par::ranks::MpiTransport),
    #[cfg(not(feature = "mpi"))]
    #[allow(dead_code)]
    Never(std::marker::PhantomData<&'a ()>),
}

pub fn run(a: BenchArgs) -> anyhow::Result<ExitCode> {
    #[cfg(feature = "mpi")]
    if super::run::mpi_launch::launched() {
        use weft_par::ranks::Transport;
        let transport = weft_par::ranks::MpiTransport::init()
            .map_err(|e| anyhow::anyhow!("cannot start MPI: {e}"))?;
        let rank = transport.rank();
        return match bench(&a, Launch::Mpi(&transport)) {
            Ok(code) => Ok(code),
            // The ranks may be at different points: end them all.
            Err(e) if transport.size() > 1 => {
                eprintln!("error: on rank {rank}: {}", crate::error_text(&e));
                transport.abort(1)
            }
            Err(e) => Err(e),
        };
    }
    bench(&a, Launch::Local)
}

fn bench(a: &BenchArgs, launch: Launch<'_>) -> anyhow::Result<ExitCode> {
    let (leader, mpi_ranks) = match launch {
        Launch::Local => (true, None),
        #[cfg(feature = "mpi")]
        Launch::Mpi(t) => {
            use weft_par::ranks::Transport;
            (t.rank() == 0, Some(t.size()))
        }
        #[cfg(not(feature = "mpi"))]
        Launch::Never(_) => unreachable!(),
    };
    if a.windows == 0 {
        bail!("--windows must be at least 1");
    }
    if a.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let threads = thread_counts(&a.threads)?;
    let projecting = !a.project.is_empty();
    if projecting {
        if mpi_ranks.is_some() {
            bail!("--project replays ranks simulated in this process (--ranks), not MPI's");
        }
        if a.ranks.iter().filter(|&&r| r > 1).count() < 2 || !a.ranks.contains(&1) {
            bail!("--project needs --ranks with 1 and two or more counts above 1, e.g. --ranks 1,2,4,8");
        }
        if threads != [1] {
            bail!("--project needs --threads 1 (a rank's work is its thread's CPU)");
        }
        if a.project.contains(&0) {
            bail!("--project: rank counts must be at least 1");
        }
        for (name, v) in [
            ("--latency-us", a.latency_us),
            ("--overhead-us", a.overhead_us),
            ("--bandwidth-gbs", a.bandwidth_gbs),
        ] {
            if !(v.is_finite() && v >= 0.0) || (name == "--bandwidth-gbs" && v == 0.0) {
                bail!("{name} must be a finite number above 0 (got {v})");
            }
        }
    }
    let rank_list = match mpi_ranks {
        Some(_) if !a.ranks.is_empty() => {
            bail!("--ranks simulates ranks in one process; under mpirun the ranks are MPI's")
        }
        Some(_) if a.make_checkpoint => bail!(
            "make the checkpoint without mpirun first (--make-checkpoint), then bench under mpirun"
        ),
        Some(n) => vec![n],
        None => rank_counts(&a.ranks)?,
    };
    let mut overrides = vec![
        format!("time.window={PUBLISHED_WINDOW}"),
        format!("time.steps_per_window={PUBLISHED_STEPS}"),
    ];
    if let Some(n) = a.size {
        overrides.push(format!("size={n}"));
    }
    overrides.extend(a.overrides.iter().cloned());
    let mut scene = load_scene(&a.scene, &overrides)?;
    // One world for every run: partitioned for the most workers asked for
    // (the results do not depend on it).
    scene.world.workers = rank_list.iter().max().copied().unwrap_or(1)
        * a.threads.iter().max().copied().unwrap_or(1).max(1);
    let build_pool = Threads::new(threads.iter().max().copied().unwrap_or(1).max(1))
        .context("cannot start the worker threads")?;
    let build_threads = build_pool.threads();
    let build_clock = std::time::Instant::now();
    let world = match launch {
        Launch::Local => {
            build_pool.install(|| weft_par::build_world_on(&scene.world, &build_pool))?
        }
        // Every rank builds the world; the internal step's estimate is
        // spread over them (collective).
        #[cfg(feature = "mpi")]
        Launch::Mpi(t) => {
            let ranks = weft_par::Ranks::new(t, build_pool.clone());
            build_pool.install(|| weft_par::build_world_on(&scene.world, &ranks))?
        }
        #[cfg(not(feature = "mpi"))]
        Launch::Never(_) => unreachable!(),
    };
    let build_seconds = build_clock.elapsed().as_secs_f64();
    drop(build_pool);
    let hash = scene_hash(&scene, &world);
    // The world holds the meshes now: the scene's copies are not kept
    // through the runs, whose peak memory is measured.
    scene.world.objects = Vec::new();
    let checkpoint = a.checkpoint.clone().unwrap_or_else(|| {
        let size = a.size.map_or("default".to_string(), |n| n.to_string());
        PathBuf::from("bench").join(format!("{}-{size}.wckp", scene.name))
    });

    if a.make_checkpoint {
        make_checkpoint(a, &overrides, &checkpoint, threads.iter().copied().max())?;
    } else if !checkpoint.exists() {
        bail!(
            "no checkpoint at {}; make one with\n  {} --make-checkpoint",
            checkpoint.display(),
            command_line()
        );
    }
    let ck = read_checkpoint(&checkpoint)
        .with_context(|| format!("reading the checkpoint {}", checkpoint.display()))?;
    if ck.scene_hash != hash {
        bail!(
            "{}: the checkpoint was made from another scene, size or overrides (scene `{}`, \
             scene hash {}); this bench runs `{}` with {} (scene hash {}). Make a matching one \
             with --make-checkpoint",
            checkpoint.display(),
            ck.scene_name,
            ck.scene_hash,
            scene.name,
            overrides.join(" "),
            hash
        );
    }
    let start = ck.engine;
    let lattice = &world.lattice;
    let mut report = BenchReport {
        scene: scene.name.clone(),
        scene_path: scene.path.clone(),
        overrides: overrides.clone(),
        scene_hash: hash,
        checkpoint: checkpoint.clone(),
        vertices: world.num_vertices(),
        cloth_vertices: world
            .objects
            .iter()
            .filter(|o| o.is_cloth)
            .map(|o| o.vertices.len())
            .sum(),
        triangles: world.triangles.len(),
        internal_stencils: world.internal.num_stencils(),
        partitions: world.partitioning.count,
        window_seconds: lattice.seconds(lattice.window()),
        steps_per_window: lattice.steps_per_window,
        internal_step: lattice.h_el(),
        build_seconds,
        build_workers: [mpi_ranks.unwrap_or(1), build_threads],
        start_time: lattice.seconds(start.tick),
        start_window: start.window_index,
        start_active_stencils: start.layers.len(),
        windows: a.windows,
        repeats: a.repeats,
        rollbacks_per_window: 0.0,
        predicted_layers_per_window: 0.0,
        detected_layers_per_window: 0.0,
        predicted_unreached_per_window: 0.0,
        breakpoints_per_queried_vertex: None,
        block_certified_share: None,
        narrow_queries_per_window: 0.0,
        internal_evaluations_per_window: 0.0,
        layer_events_per_window: 0.0,
        layer_evaluations_per_window: 0.0,
        islands_per_window: 0.0,
        far_per_window: [0.0; 3],
        largest_unit_share: None,
        largest_island_share: None,
        end_active_stencils: 0,
        end_max_depth: 0,
        end_island_sizes: Vec::new(),
        end_largest_island: 0,
        state_hash: String::new(),
        deterministic: true,
        peak_rss_bytes: None,
        peak_bytes_per_vertex: None,
        machine: Topology::this(),
        results: Vec::new(),
        projection: None,
    };
    let say = |text: String| {
        if leader {
            eprintln!("{text}");
        }
    };
    say(format!(
        "weft bench: {} — {} vertices, {} steps of {:.4e} s per window, from t = {:.6} s \
         ({} active stencils); {} windows × {} runs per thread count",
        report.scene,
        report.vertices,
        report.steps_per_window,
        report.internal_step,
        report.start_time,
        report.start_active_stencils,
        a.windows,
        a.repeats
    ));

    // The peak from here on: the benchmark runs, not the checkpoint's making.
    machine::reset_peak_rss();
    let mut all: Vec<((usize, usize), Vec<Sample>)> = Vec::new();
    let last = (rank_list.last().copied(), threads.last().copied());
    // Each run gets a copy of the world and the start; the last one gets
    // them, so that no run's peak holds a copy it does not use.
    let mut inputs = Some((world, start));
    for &ranks in &rank_list {
        for &n in &threads {
            let mut samples = Vec::with_capacity(a.repeats);
            for r in 0..a.repeats {
                let final_run = (Some(ranks), Some(n)) == last && r + 1 == a.repeats;
                weft_sim::trace::set_recording(a.trace.is_some() && final_run);
                let (world, start) = if final_run {
                    inputs.take().expect("the inputs, until the last run")
                } else {
                    let (world, start) = inputs.as_ref().expect("the inputs");
                    (world.clone(), start.clone())
                };
                let s = run_once(launch, ranks, n, world, start, a.windows, projecting)
                    .with_context(|| format!("{ranks} rank(s) × {n} thread(s), run {}", r + 1))?;
                say(format!(
                    "weft bench: {ranks} rank(s) × {n} thread(s), run {}/{}: {:.4} s per window",
                    r + 1,
                    a.repeats,
                    s.own.wall / a.windows as f64
                ));
                samples.push(s);
            }
            all.push(((ranks, n), samples));
        }
    }
    if !leader {
        return Ok(ExitCode::SUCCESS);
    }
    if let Some(path) = &a.trace {
        super::run::write_trace(path, &report.scene, false)?;
    }
    report.peak_rss_bytes = machine::peak_rss_bytes();
    report.peak_bytes_per_vertex = report
        .peak_rss_bytes
        .map(|b| b as f64 / report.vertices as f64);
    summarize(&mut report, &all);
    if projecting {
        let net = project::Network {
            latency: a.latency_us * 1e-6,
            overhead: a.overhead_us * 1e-6,
            seconds_per_byte: 1.0 / (a.bandwidth_gbs * 1e9),
            collectives: a.collectives,
        };
        report.projection = Some(projection(&report, &all, &a.project, net)?);
    }

    print!("{}", table(&report));
    if a.json {
        println!("{}", serde_json::to_string(&report)?);
    }
    if !report.deterministic {
        let hashes: Vec<String> = all
            .iter()
            .flat_map(|((r, n), s)| s.iter().map(move |s| format!("{r}×{n}: {}", s.state_hash)))
            .collect();
        bail!(
            "the runs ended in different states (ranks×threads: state hash): {}",
            hashes.join(", ")
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The thread counts to run: as given (each at least 1, no repeats), or 1 and
/// one per available logical CPU.
fn thread_counts(given: &[usize]) -> anyhow::Result<Vec<usize>> {
    if given.is_empty() {
        let all = std::thread::available_parallelism().map_or(1, |n| n.get());
        return Ok(if all > 1 { vec![1, all] } else { vec![1] });
    }
    distinct_counts(
        given,
        "--threads",
        "thread counts must be at least 1",
        1..=usize::MAX,
    )
}

/// The rank counts to run: as given (1 to 256, no repeats), or 1.
fn rank_counts(given: &[usize]) -> anyhow::Result<Vec<usize>> {
    if given.is_empty() {
        return Ok(vec![1]);
    }
    distinct_counts(given, "--ranks", "rank counts must be 1 to 256", 1..=256)
}

/// `given` checked: every count in `allowed` (else `option: rule (got n)`),
/// none listed twice.
fn distinct_counts(
    given: &[usize],
    option: &str,
    rule: &str,
    allowed: std::ops::RangeInclusive<usize>,
) -> anyhow::Result<Vec<usize>> {
    let mut seen = Vec::new();
    for &n in given {
        if !allowed.contains(&n) {
            bail!("{option}: {rule} (got {n})");
        }
        if seen.contains(&n) {
            bail!("{option}: {n} is listed twice");
        }
        seen.push(n);
    }
    Ok(seen)
}

/// One run of `windows` windows on `ranks` ranks of `threads` threads each;
/// the sample is rank 0's, with every rank's own figures in `ranks`.
fn run_once(
    launch: Launch<'_>,
    ranks: usize,
    threads: usize,
    world: World,
    start: EngineState,
    windows: u64,
    record_steps: bool,
) -> anyhow::Result<Sample> {
    let pool = || Threads::new(threads).context("cannot start the worker threads");
    match launch {
        Launch::Local if ranks == 1 => {
            if threads == 1 {
                measure(world, Serial, start, windows)
            } else {
                let exec = pool()?;
                exec.clone()
                    .install(move || measure(world, exec, start, windows))
            }
        }
        Launch::Local => {
            let pools = (0..ranks).map(|_| pool()).collect::<Result<Vec<_>, _>>()?;
            let results = weft_par::ranks::in_process(
                ranks,
                |r| pools[r].clone(),
                |exec| {
                    let (world, start) = (world.clone(), start.clone());
                    exec.local().clone().install(move || {
                        // On the thread that runs the rank's work: its CPU
                        // clock is the rank's.
                        let sink = weft_par::ranks::StepSink::default();
                        if record_steps {
                            exec.transport().record_steps(sink.clone());
                        }
                        let mut s = measure(world, exec, start, windows)?;
                        let steps = std::mem::take(&mut *sink.lock().expect("the step sink"));
                        s.steps = vec![windows_steps(steps, s.own.collectives)];
                        Ok(s)
                    })
                },
            );
            let mut samples = results.into_iter().collect::<anyhow::Result<Vec<_>>>()?;
            if let Some(s) = samples
                .iter()
                .find(|s| s.state_hash != samples[0].state_hash)
            {
                bail!(
                    "ranks ended in different states: {} and {}",
                    samples[0].state_hash,
                    s.state_hash
                );
            }
            let every: Vec<RankSample> = samples.iter().flat_map(|s| s.ranks.clone()).collect();
            let steps: Vec<_> = samples.iter_mut().flat_map(|s| s.steps.drain(..)).collect();
            let mut first = samples.swap_remove(0);
            first.ranks = every;
            first.steps = if record_steps { steps } else { Vec::new() };
            Ok(first)
        }
        #[cfg(feature = "mpi")]
        Launch::Mpi(t) => {
            use weft_par::ranks::Transport;
            let local = pool()?;
            let exec = weft_par::Ranks::new(t, local.clone());
            let mut s = local.install(move || measure(world, exec, start, windows))?;
            // Collective: every rank's own figures to every rank.
            let mine = postcard::to_allocvec(&s.own)?;
            let parts = t.all_gather(mine).map_err(|e| anyhow::anyhow!("{e}"))?;
            s.ranks = parts
                .iter()
                .map(|p| postcard::from_bytes(p))
                .collect::<Result<_, _>>()?;
            Ok(s)
        }
        #[cfg(not(feature = "mpi"))]
        Launch::Never(_) => unreachable!(),
    }
}

/// A rank's recorded steps less those before the windows ran (the engine's
/// set-up and restore): all up to the collective that precedes the
/// windows' `collectives`.
fn windows_steps(
    steps: Vec<weft_par::ranks::SyncStep>,
    collectives: u64,
) -> Vec<weft_par::ranks::SyncStep> {
    let total = steps.iter().filter(|s| s.collective).count() as u64;
    let mut before = total.saturating_sub(collectives);
    let cut = steps
        .iter()
        .position(|s| {
            if before == 0 {
                return true;
            }
            if s.collective {
                before -= 1;
            }
            false
        })
        .unwrap_or(steps.len());
    steps[cut..].to_vec()
}

/// `--project`: replays each simulated rank count's steps (the median run's)
/// and projects the asked rank counts from them.
fn projection(
    r: &BenchReport,
    all: &[((usize, usize), Vec<Sample>)],
    targets: &[usize],
    net: project::Network,
) -> anyhow::Result<ProjectionReport> {
    let windows = r.windows as f64;
    let mut measured = Vec::new();
    let mut replayed = Vec::new();
    let mut between = Vec::new();
    for ((ranks, _), samples) in all.iter().filter(|((ranks, _), _)| *ranks > 1) {
        let walls: Vec<f64> = samples.iter().map(|s| s.own.wall).collect();
        let mid = median(&walls);
        let s = samples
            .iter()
            .min_by(|a, b| {
                (a.own.wall - mid)
                    .abs()
                    .total_cmp(&(b.own.wall - mid).abs())
            })
            .expect("a sample");
        let seconds =
            project::replay(&s.steps, &net).map_err(|e| anyhow::anyhow!("{ranks} ranks: {e}"))?;
        let critical = r
            .results
            .iter()
            .find(|t| t.ranks == *ranks)
            .map_or(0.0, |t| t.critical_path_seconds_per_window);
        replayed.push((*ranks, seconds / windows, critical));
        let iv = project::intervals(&s.steps).map_err(|e| anyhow::anyhow!("{ranks} ranks: {e}"))?;
        let (most, mean) = project::between_collectives(&iv);
        between.push((*ranks, most / windows, mean / windows));
        measured.push((*ranks, iv));
    }
    let one = r.results.iter().find(|t| t.ranks == 1);
    let t1 = one.map(|t| t.cpu_sum_seconds_per_window);
    let projected = project::project(&measured, targets, &net)
        .map_err(|e| anyhow::anyhow!(e))?
        .into_iter()
        .map(|mut p| {
            // The intervals span the whole run: per window (the model is
            // linear in the work, so scaling after the fit is the same).
            p.work /= windows;
            p.collectives /= windows;
            p.point_to_point /= windows;
            p.seconds /= windows;
            if let (1, Some(one)) = (p.ranks, one) {
                // One rank is one process, measured: the model is of runs
                // over ranks (`project.rs`).
                let wall = one.wall_seconds_per_window;
                p = project::Projected {
                    ranks: 1,
                    seconds: wall,
                    work: wall,
                    collectives: 0.0,
                    point_to_point: 0.0,
                    measured: true,
                };
            }
            let e = t1.map(|t1| t1 / (p.ranks as f64 * p.seconds));
            (p, e)
        })
        .collect();
    // (After `project`, which refuses measured counts whose collective
    // schedules differ: the fit reads the same interval of each.)
    let fit = (project::fitted(&measured).iter()).fold((0.0, 0.0), |f, m| {
        (f.0 + m.0 / windows, f.1 + m.1 / windows)
    });
    let by_site = (project::by_site(&measured).into_iter())
        .map(|mut s| {
            s.fit = (s.fit.0 / windows, s.fit.1 / windows);
            s.most /= windows;
            s.mean /= windows;
            s
        })
        .collect();
    Ok(ProjectionReport {
        network: net,
        one_process_seconds_per_window: t1,
        replayed,
        between_collectives: between,
        fit,
        by_site,
        projected,
    })
}

/// The command line of this process, for a message that suggests a variant.
fn command_line() -> String {
    std::env::args()
        .map(|a| {
            if !a.is_empty()
                && a.bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b"-_=./,:+".contains(&b))
            {
                a
            } else {
                format!("'{}'", a.replace('\'', r"'\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Runs the bench's scene from the start to `--warmup` with `weft run`'s
/// machinery and keeps its last checkpoint at `path`.
fn make_checkpoint(
    a: &BenchArgs,
    overrides: &[String],
    path: &Path,
    threads: Option<usize>,
) -> anyhow::Result<()> {
    if !(a.warmup.is_finite() && a.warmup > 0.0) {
        bail!(
            "--warmup must be a positive number of seconds (got {})",
            a.warmup
        );
    }
    let mut warm = overrides.to_vec();
    warm.push(format!("time.end={}", a.warmup));
    let scene = load_scene(&a.scene, &warm)?;
    let out = path.with_extension("warmup");
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    eprintln!(
        "weft bench: making the checkpoint: {} from t = 0 to {} s in {}",
        scene.name,
        a.warmup,
        out.display()
    );
    let job = RunJob {
        scene: &scene,
        out: &out,
        quiet: false,
        resume: false,
        stop: StopRequest::new(),
        preview: false,
        command_line: std::env::args().collect(),
        trace_windows: None,
        progress_interval: super::run::progress::log_interval()?,
    };
    let n = threads.unwrap_or(1);
    let summary = if n <= 1 {
        execute(job, Serial)?
    } else {
        execute(
            job,
            Threads::new(n).context("cannot start the worker threads")?,
        )?
    };
    let made = out.join(CHECKPOINT_FILE);
    let bytes = std::fs::read(&made).with_context(|| format!("reading {}", made.display()))?;
    weft_io::write_atomic(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
    let ck = read_checkpoint(path)?;
    eprintln!(
        "weft bench: checkpoint {} at t = {:.6} s (window {}): {} active stencils (peak {} on \
         the way, {} rollbacks, {:.1} s); the run folder stays in {}",
        path.display(),
        summary.simulated_seconds,
        ck.engine.window_index,
        ck.engine.layers.len(),
        summary.max_active_stencils,
        summary.rollbacks,
        summary.wall_seconds,
        out.display()
    );
    Ok(())
}

/// Restores `start` into a fresh engine over `world` and steps `windows` windows.
fn measure<E: Executor>(
    world: World,
    exec: E,
    start: EngineState,
    windows: u64,
) -> anyhow::Result<Sample> {
    let mut engine = Engine::new(world, exec)?;
    engine.restore(start)?;
    let queries_before = engine.totals.narrow_queries;
    let traffic_before = engine.executor().traffic();
    let cpu_before = engine.executor().work_cpu_seconds();
    let moved_before = engine.moved_between_ranks;
    let mut s = Sample::default();
    let clock = Instant::now();
    for _ in 0..windows {
        let CommittedWindow { stats: w, timing } = engine.step_window()?;
        s.own.events += timing.stage_seconds.events;
        s.own.broad += timing.stage_seconds.broad;
        s.own.narrow += timing.stage_seconds.narrow;
        s.own.commit += timing.stage_seconds.commit;
        s.own.predict += timing.stage_seconds.predict;
        s.own.cpu += timing.stage_seconds.cpu;
        s.own.sent += timing.stage_seconds.sent;
        s.predicted_layers += w.predicted_layers;
        s.detected_layers += w.detected_layers;
        s.predicted_unreached += w.predicted_unreached;
        s.candidates += w.candidates;
        s.queried_breakpoints += w.queried_breakpoints;
        s.certified_intervals += w.certified_intervals;
        s.block_certified_intervals += w.block_certified_intervals;
        s.own.internal += timing.stage_seconds.internal;
        // Every pass runs the window's internal ticks (a pass cut short by a
        // blow-up, which is rolled back, would count a little high).
        s.internal_evaluations_all_passes +=
            w.internal_stencil_evaluations * (u64::from(w.rollbacks) + 1);
        s.internal_ticks_all_passes += w.internal_events * (u64::from(w.rollbacks) + 1);
        s.internal_evaluations += w.internal_stencil_evaluations;
        s.layer_events += w.layer_events;
        s.layer_evaluations += timing.penalty_work.layer_evaluations;
        s.islands += w.islands;
        s.largest_island_layer_events += w.largest_island_layer_events;
        s.far[0] += timing.penalty_work.far_stencils;
        s.far[1] += timing.penalty_work.far_promoted;
        s.far[2] += timing.penalty_work.island_reruns;
        s.far[3] += timing.penalty_work.largest_unit_layer_events;
        s.split_windows += u64::from(timing.penalty_work.split);
        s.rollbacks += u64::from(w.rollbacks);
        s.active_stencils = w.active_stencils;
        s.max_depth = w.max_depth;
    }
    s.own.wall = clock.elapsed().as_secs_f64();
    s.narrow_queries = engine.totals.narrow_queries - queries_before;
    s.moved_between_ranks = engine.moved_between_ranks - moved_before;
    s.state_hash = engine.state_hash();
    let w = &engine.world;
    let islands = weft_sim::islands::Islands::build(w.layers.stencils.keys(), &w.inv_mass);
    s.island_sizes = (0..islands.len())
        .map(|k| islands.stencils_of(k).len() as u64)
        .collect();
    let traffic = engine.executor().traffic();
    s.own.messages = traffic.messages - traffic_before.messages;
    s.own.bytes = traffic.bytes - traffic_before.bytes;
    s.own.collectives = traffic.collectives - traffic_before.collectives;
    s.own.exchanges = traffic.exchanges - traffic_before.exchanges;
    s.own.cpu_total = engine.executor().work_cpu_seconds() - cpu_before;
    s.own.cpu_polling = (traffic.wait_cpu_ns - traffic_before.wait_cpu_ns) as f64 * 1e-9;
    s.own.peak_rss = machine::peak_rss_bytes();
    s.ranks = vec![s.own.clone()];
    s.narrow_load = engine.narrow_load.clone();
    Ok(s)
}

/// The median (the mean of the middle two for an even count).
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Fills the report's figures from the samples of each thread count.
fn summarize(r: &mut BenchReport, all: &[((usize, usize), Vec<Sample>)]) {
    let first = &all[0].1[0];
    let windows = r.windows as f64;
    r.rollbacks_per_window = first.rollbacks as f64 / windows;
    r.predicted_layers_per_window = first.predicted_layers as f64 / windows;
    r.detected_layers_per_window = first.detected_layers as f64 / windows;
    r.predicted_unreached_per_window = first.predicted_unreached as f64 / windows;
    r.breakpoints_per_queried_vertex = (first.candidates > 0)
        .then(|| first.queried_breakpoints as f64 / (4 * first.candidates) as f64);
    r.block_certified_share = (first.certified_intervals > 0)
        .then(|| first.block_certified_intervals as f64 / first.certified_intervals as f64);
    r.narrow_queries_per_window = first.narrow_queries as f64 / windows;
    r.internal_evaluations_per_window = first.internal_evaluations as f64 / windows;
    r.layer_events_per_window = first.layer_events as f64 / windows;
    r.layer_evaluations_per_window = first.layer_evaluations as f64 / windows;
    r.islands_per_window = first.islands as f64 / windows;
    r.far_per_window = [0, 1, 2].map(|k| first.far[k] as f64 / windows);
    r.largest_unit_share = (first.layer_events > 0 && first.far[0] > 0)
        .then(|| first.far[3] as f64 / first.layer_events as f64);
    r.largest_island_share = (first.layer_events > 0)
        .then(|| first.largest_island_layer_events as f64 / first.layer_events as f64);
    r.end_active_stencils = first.active_stencils;
    r.end_max_depth = first.max_depth;
    for &size in &first.island_sizes {
        let bucket = size.ilog2() as usize;
        if r.end_island_sizes.len() <= bucket {
            r.end_island_sizes.resize(bucket + 1, 0);
        }
        r.end_island_sizes[bucket] += 1;
    }
    r.end_largest_island = first.island_sizes.iter().copied().max().unwrap_or(0);
    r.state_hash = first.state_hash.clone();
    r.deterministic = all.iter().flat_map(|(_, s)| s).all(|s| {
        s.state_hash == first.state_hash
            && s.rollbacks == first.rollbacks
            && s.narrow_queries == first.narrow_queries
            && s.internal_evaluations == first.internal_evaluations
    });
    for &((ranks, threads), ref samples) in all {
        // Cores at work: every rank's threads.
        let n = ranks * threads;
        let med = |f: &dyn Fn(&Sample) -> f64| median(&samples.iter().map(f).collect::<Vec<_>>());
        let runs: Vec<f64> = samples.iter().map(|s| s.own.wall / windows).collect();
        let wall = median(&runs);
        // Per window, the median over the runs of a figure of one rank.
        let of_rank = |of: &dyn Fn(&Sample) -> &RankSample, f: &dyn Fn(&RankSample) -> f64| {
            med(&|s| f(of(s)) / windows)
        };
        let stages = |of: &dyn Fn(&Sample) -> &RankSample| StageTimes {
            events: of_rank(of, &|x| x.events),
            broad: of_rank(of, &|x| x.broad),
            narrow: of_rank(of, &|x| x.narrow),
            commit: of_rank(of, &|x| x.commit),
            predict: of_rank(of, &|x| x.predict),
            internal: of_rank(of, &|x| x.internal),
            other: of_rank(of, &|x| {
                x.wall - x.events - x.broad - x.narrow - x.commit - x.predict
            }),
        };
        // Per window, rank `k`'s median per-stage figures `f` (CPU or bytes).
        let per_stage = |k: usize, f: &dyn Fn(&RankSample) -> &PerStage| PerStage {
            events: of_rank(&|s| &s.ranks[k], &|x| f(x).events),
            broad: of_rank(&|s| &s.ranks[k], &|x| f(x).broad),
            narrow: of_rank(&|s| &s.ranks[k], &|x| f(x).narrow),
            commit: of_rank(&|s| &s.ranks[k], &|x| f(x).commit),
            predict: of_rank(&|s| &s.ranks[k], &|x| f(x).predict),
        };
        let evals = first.internal_evaluations as f64;
        let per_rank: Vec<RankFigures> = (0..ranks)
            .map(|k| RankFigures {
                rank: k,
                stage_seconds_per_window: stages(&|s| &s.ranks[k]),
                cpu_seconds_per_window: per_stage(k, &|x| &x.cpu),
                cpu_total_seconds_per_window: of_rank(&|s| &s.ranks[k], &|x| x.cpu_total),
                cpu_polling_seconds_per_window: of_rank(&|s| &s.ranks[k], &|x| x.cpu_polling),
                peak_rss_bytes: samples.iter().filter_map(|s| s.ranks[k].peak_rss).max(),
                messages_per_window: of_rank(&|s| &s.ranks[k], &|x| x.messages as f64),
                bytes_per_window: of_rank(&|s| &s.ranks[k], &|x| x.bytes as f64),
                sent_bytes_per_window: per_stage(k, &|x| &x.sent),
                collectives_per_window: of_rank(&|s| &s.ranks[k], &|x| x.collectives as f64),
                exchanges_per_window: of_rank(&|s| &s.ranks[k], &|x| x.exchanges as f64),
                rounds_per_internal_tick: med(&|s| {
                    let x = &s.ranks[k];
                    (x.collectives + x.exchanges) as f64 / s.internal_ticks_all_passes.max(1) as f64
                }),
            })
            .collect();
        let cpu_sum: f64 = per_rank
            .iter()
            .map(|k| k.cpu_total_seconds_per_window)
            .sum();
        let critical_path = (per_rank.iter())
            .map(|k| k.cpu_total_seconds_per_window)
            .fold(0.0, f64::max);
        let imbalance = |f: &dyn Fn(&NarrowLoad) -> &[f64]| {
            let v: Vec<f64> = samples
                .iter()
                .filter_map(|s| NarrowLoad::imbalance(f(&s.narrow_load)))
                .collect();
            (ranks > 1 && !v.is_empty()).then(|| median(&v))
        };
        r.results.push(ThreadResult {
            ranks,
            threads,
            executor: match (ranks, threads) {
                (1, 1) => "serial".into(),
                (1, t) => format!("threads({t})"),
                (r, t) => format!("ranks({r}) × threads({t})"),
            },
            wall_seconds_per_window: wall,
            runs_wall_seconds_per_window: runs.clone(),
            stage_seconds_per_window: stages(&|s| &s.own),
            internal_evaluations_per_core_second: med(&|s| evals / (s.own.wall * n as f64)),
            internal_evaluations_per_events_core_second: med(&|s| {
                evals / (s.own.events * n as f64)
            }),
            internal_stage_evaluations_per_core_second: med(&|s| {
                s.internal_evaluations_all_passes as f64 / (s.own.internal * n as f64)
            }),
            narrow_queries_per_second: med(&|s| s.narrow_queries as f64 / s.own.narrow),
            speedup: None,
            parallel_efficiency: None,
            cpu_sum_seconds_per_window: cpu_sum,
            redundancy: None,
            critical_path_seconds_per_window: critical_path,
            speedup_bound: None,
            per_rank,
            narrow_imbalance: imbalance(&|l| &l.balanced),
            narrow_imbalance_home_only: imbalance(&|l| &l.home_only),
            moved_between_ranks_per_window: med(&|s| s.moved_between_ranks as f64 / windows),
            split_window_share: med(&|s| s.split_windows as f64 / windows),
        });
    }
    if let Some(t1) = r
        .results
        .iter()
        .find(|t| t.threads == 1 && t.ranks == 1)
        .map(|t| t.wall_seconds_per_window)
    {
        for t in &mut r.results {
            let speedup = t1 / t.wall_seconds_per_window;
            t.speedup = Some(speedup);
            t.parallel_efficiency = Some(speedup / (t.ranks * t.threads) as f64);
        }
    }
    // Counted scaling against one process's work CPU.
    if let Some(cpu1) = (r.results.iter())
        .find(|t| t.threads == 1 && t.ranks == 1)
        .map(|t| t.cpu_sum_seconds_per_window)
        .filter(|&c| c > 0.0)
    {
        for t in &mut r.results {
            t.redundancy = Some(t.cpu_sum_seconds_per_window / cpu1);
            t.speedup_bound = (t.critical_path_seconds_per_window > 0.0)
                .then(|| cpu1 / t.critical_path_seconds_per_window);
        }
    }
}

/// The human-readable report.
fn table(r: &BenchReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let ms = |x: f64| format!("{:.2}", x * 1e3);
    let _ = writeln!(
        s,
        "scene       {} ({}), {} vertices ({} cloth), {} triangles, {} internal stencils, {} partitions",
        r.scene,
        r.scene_path.display(),
        r.vertices,
        r.cloth_vertices,
        r.triangles,
        r.internal_stencils,
        r.partitions
    );
    let _ = writeln!(
        s,
        "time        windows of {:.6e} s = {} internal steps of {:.4e} s",
        r.window_seconds, r.steps_per_window, r.internal_step
    );
    let _ = writeln!(
        s,
        "build       the world in {:.2} s, its internal step estimated on {} rank(s) × {} thread(s)",
        r.build_seconds, r.build_workers[0], r.build_workers[1]
    );
    let _ = writeln!(
        s,
        "start       {}: t = {:.6} s (window {}), {} active stencils",
        r.checkpoint.display(),
        r.start_time,
        r.start_window,
        r.start_active_stencils
    );
    let _ = writeln!(
        s,
        "runs        {} windows per run, median of {} runs per thread count",
        r.windows, r.repeats
    );
    let _ = writeln!(s, "machine     {}", r.machine.describe());
    let _ = writeln!(
        s,
        "per window  {:.2} rollbacks, {:.0} narrow-phase queries ({} breakpoints per queried \
         vertex; {} of certified intervals by block bounds alone), {:.4e} internal stencil \
         evaluations, {:.4e} penalty-layer evaluations ({:.4e} exact distances)",
        r.rollbacks_per_window,
        r.narrow_queries_per_window,
        r.breakpoints_per_queried_vertex
            .map_or("—".into(), |b| format!("{b:.1}")),
        r.block_certified_share
            .map_or("—".into(), |b| format!("{:.0} %", 100.0 * b)),
        r.internal_evaluations_per_window,
        r.layer_events_per_window,
        r.layer_evaluations_per_window
    );
    let _ = writeln!(
        s,
        "layers      per window {:.0} activated by prediction ({:.0} never reached), {:.0} by \
         detection",
        r.predicted_layers_per_window,
        r.predicted_unreached_per_window,
        r.detected_layers_per_window
    );
    let _ = writeln!(
        s,
        "islands     {:.1} contact islands per window; the largest holds {} of the layer events; \
         at the end, islands of 1, 2-3, 4-7, ... stencils: {:?} (largest {})",
        r.islands_per_window,
        r.largest_island_share
            .map_or("none".to_string(), |f| format!("{:.1} %", 100.0 * f)),
        r.end_island_sizes,
        r.end_largest_island
    );
    if r.far_per_window[0] > 0.0 {
        let _ = writeln!(
            s,
            "far         per window {:.0} far stencils kept out of the islands, {:.0} promoted \
             into them, {:.1} units run again; the largest unit holds {} of the layer events \
             (contact.split_islands)",
            r.far_per_window[0],
            r.far_per_window[1],
            r.far_per_window[2],
            r.largest_unit_share
                .map_or("none".to_string(), |f| format!("{:.1} %", 100.0 * f))
        );
    }
    let _ = writeln!(
        s,
        "end         {} active stencils, depth {}, state hash {} ({})",
        r.end_active_stencils,
        r.end_max_depth,
        r.state_hash,
        if r.deterministic {
            "the same in every run"
        } else {
            "RUNS DIFFER"
        }
    );
    let _ = writeln!(
        s,
        "memory      {}",
        match (r.peak_rss_bytes, r.peak_bytes_per_vertex) {
            (Some(b), Some(v)) => format!(
                "process peak {:.1} MB = {:.0} bytes per vertex (VmHWM)",
                b as f64 / 1e6,
                v
            ),
            _ => "unknown (no /proc/self/status)".into(),
        }
    );
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "{:>5} {:>7} {:>10} {:>8} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8} {:>12} {:>15} {:>12} {:>8} {:>10}",
        "ranks",
        "threads",
        "ms/window",
        "events",
        "internal",
        "broad",
        "narrow",
        "commit",
        "predict",
        "other",
        "evals/core·s",
        "internal/core·s",
        "queries/s",
        "speedup",
        "efficiency"
    );
    for t in &r.results {
        let st = &t.stage_seconds_per_window;
        let _ = writeln!(
            s,
            "{:>5} {:>7} {:>10} {:>8} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8} {:>12.4e} {:>15.4e} {:>12.4e} {:>8} {:>10}",
            t.ranks,
            t.threads,
            ms(t.wall_seconds_per_window),
            ms(st.events),
            ms(st.internal),
            ms(st.broad),
            ms(st.narrow),
            ms(st.commit),
            ms(st.predict),
            ms(st.other),
            t.internal_evaluations_per_core_second,
            t.internal_stage_evaluations_per_core_second,
            t.narrow_queries_per_second,
            t.speedup.map_or("—".into(), |x| format!("{x:.2}")),
            t.parallel_efficiency
                .map_or("—".into(), |x| format!("{:.0} %", 100.0 * x)),
        );
    }
    let ratio = |x: Option<f64>| x.map_or("—".into(), |x| format!("{x:.2}"));
    let _ = writeln!(
        s,
        "\ncounted (work CPU per window, polling for peers left out; T1 = one process's):"
    );
    for t in &r.results {
        let _ = writeln!(
            s,
            "  {:>3} ranks × {:>2} threads: Σ cpu {} ms, redundancy {}, critical path {} ms, \
             speed-up bound T1 / critical path {}",
            t.ranks,
            t.threads,
            ms(t.cpu_sum_seconds_per_window),
            ratio(t.redundancy),
            ms(t.critical_path_seconds_per_window),
            ratio(t.speedup_bound)
        );
    }
    for t in r.results.iter().filter(|t| t.ranks > 1) {
        let _ = writeln!(
            s,
            "\n{} ranks × {} threads: narrow-phase imbalance (max / mean) {} with the balancer, \
             {} with every task on its home rank",
            t.ranks,
            t.threads,
            ratio(t.narrow_imbalance),
            ratio(t.narrow_imbalance_home_only)
        );
        let _ = writeln!(
            s,
            "  islands split (far stencils kept out, units spread over the ranks) in {:.0} % of \
             the windows",
            100.0 * t.split_window_share
        );
        if t.moved_between_ranks_per_window > 0.0 {
            let _ = writeln!(
                s,
                "  units spread: {:.0} vertices per window moved to another rank with their unit",
                t.moved_between_ranks_per_window
            );
        }
        for k in &t.per_rank {
            let st = &k.stage_seconds_per_window;
            let _ = writeln!(
                s,
                "  rank {:>3}: events {} internal {} broad {} narrow {} commit {} predict {} other {} ms; \
                 {:.0} messages, {:.3} MB sent, {:.0} collectives and {:.0} exchanges per \
                 window ({:.2} per internal tick)",
                k.rank,
                ms(st.events),
                ms(st.internal),
                ms(st.broad),
                ms(st.narrow),
                ms(st.commit),
                ms(st.predict),
                ms(st.other),
                k.messages_per_window,
                k.bytes_per_window / 1e6,
                k.collectives_per_window,
                k.exchanges_per_window,
                k.rounds_per_internal_tick
            );
            let c = &k.cpu_seconds_per_window;
            let _ = writeln!(
                s,
                "            cpu: events {} broad {} narrow {} commit {} predict {}, in all {} ms \
                 per window ({} ms polling for peers left out); peak memory {}",
                ms(c.events),
                ms(c.broad),
                ms(c.narrow),
                ms(c.commit),
                ms(c.predict),
                ms(k.cpu_total_seconds_per_window),
                ms(k.cpu_polling_seconds_per_window),
                k.peak_rss_bytes
                    .map_or("unknown".into(), |b| format!("{:.1} MB", b as f64 / 1e6)),
            );
            let b = &k.sent_bytes_per_window;
            let _ = writeln!(
                s,
                "            sent: events {:.3} broad {:.3} narrow {:.3} commit {:.3} predict {:.3} MB \
                 per window",
                b.events / 1e6,
                b.broad / 1e6,
                b.narrow / 1e6,
                b.commit / 1e6,
                b.predict / 1e6,
            );
        }
    }
    if let Some(p) = &r.projection {
        let _ = writeln!(
            s,
            "\nprojection — a model, not a measurement (LogGP: L = {:.2} µs, o = {:.2} µs, \
             {:.1} GB/s; {} collectives; bench/project.rs):",
            p.network.latency * 1e6,
            p.network.overhead * 1e6,
            1e-9 / p.network.seconds_per_byte,
            clap::ValueEnum::to_possible_value(&p.network.collectives)
                .expect("no variant is skipped")
                .get_name()
        );
        for ((ranks, replay, critical), (_, most, mean)) in
            p.replayed.iter().zip(&p.between_collectives)
        {
            let _ = writeln!(
                s,
                "  replay of the {ranks} simulated ranks: {} ms per window (counted critical path {} ms); \
                 between collectives the busiest rank's work sums to {} ms, the mean rank's to {} ms \
                 (imbalance {})",
                ms(*replay),
                ms(*critical),
                ms(*most),
                ms(*mean),
                ratio((*mean > 0.0).then(|| most / mean))
            );
        }
        let _ = writeln!(
            s,
            "  the fit, a + b / R per interval, summed: {} ms a window that does not shrink with \
             the ranks (Σ a), {} ms shared (Σ b)",
            ms(p.fit.0),
            ms(p.fit.1)
        );
        if let Some(largest) = p.replayed.iter().map(|r| r.0).max() {
            let _ = writeln!(
                s,
                "  by the site of the collective ending each interval (ms a window; imbalance at \
                 {largest} ranks):\n  {:<34} {:>9} {:>8} {:>8} {:>9}",
                "site", "intervals", "Σ a", "Σ b", "imbalance"
            );
            for site in &p.by_site {
                let name = if site.site.is_empty() {
                    "(outside every site)"
                } else {
                    site.site
                };
                let _ = writeln!(
                    s,
                    "  {:<34} {:>9.0} {:>8} {:>8} {:>9}",
                    name,
                    site.intervals as f64 / r.windows as f64,
                    ms(site.fit.0),
                    ms(site.fit.1),
                    ratio((site.mean > 0.0).then(|| site.most / site.mean))
                );
            }
        }
        let _ = writeln!(
            s,
            "  ranks  ms/window  work  all-gathers  point-to-point  efficiency (T1 = {} ms)",
            p.one_process_seconds_per_window.map_or("—".into(), ms)
        );
        for (q, e) in &p.projected {
            let _ = writeln!(
                s,
                "  {:>5} {:>10} {:>5} {:>12} {:>15} {:>11}{}",
                q.ranks,
                ms(q.seconds),
                ms(q.work),
                ms(q.collectives),
                ms(q.point_to_point),
                e.map_or("—".into(), |e| format!("{:.0} %", 100.0 * e)),
                if q.measured {
                    "  (measured: one process, not modelled)"
                } else {
                    ""
                }
            );
        }
    }
    let _ = writeln!(
        s,
        "\nTimes are milliseconds per window (median); internal is the internal-force part of \
         events. evals/core·s: committed-pass internal stencil evaluations per wall second per \
         thread (the whole pipeline); internal/core·s: internal stencil evaluations (all \
         passes) per second of the internal-force stage per thread; queries/s: narrow-phase \
         queries (all passes) per narrow-stage second; efficiency: T(1) / (n · T(n)) with n = \
         ranks · threads, T(1) on the serial executor."
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(&[7.0]), 7.0);
    }

    #[test]
    fn rank_lists() {
        assert_eq!(rank_counts(&[]).unwrap(), vec![1]);
        assert_eq!(rank_counts(&[1, 3]).unwrap(), vec![1, 3]);
        assert!(rank_counts(&[0]).is_err());
        assert!(rank_counts(&[2, 2]).is_err());
    }

    #[test]
    fn thread_lists() {
        assert_eq!(thread_counts(&[1, 2]).unwrap(), vec![1, 2]);
        assert!(thread_counts(&[0]).is_err());
        assert!(thread_counts(&[2, 2]).is_err());
        assert!(!thread_counts(&[]).unwrap().is_empty());
    }
}
