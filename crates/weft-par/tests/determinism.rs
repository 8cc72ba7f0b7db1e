//! The same bits on any executor and partitioning: `crumple` (friction and
//! damping on) run on `Serial`, on `Threads` with 1 to 4 threads and on
//! `Ranks` with 1 to 4 ranks (threads with memory of their own, talking over
//! channels), with 1, 4, 16 and 64 METIS partitions, ends in one
//! `state_hash` on every rank — with enough
//! contact to mean it (asserted: rollbacks, peak active stencils, depth, and
//! penalty stencils that couple two partitions).
//!
//! The hash is also compared with [`FIXTURE_HASH`], so the test profile
//! (debug assertions on) and `--release` (`.ci/run` runs this file in both)
//! are held to the same bits — and any change of the numerics shows up here.

use std::path::Path;

use weft_io::scene::load_scene;
use weft_par::ranks::in_process;
use weft_par::Threads;
use weft_sim::{Engine, Executor, PenaltyWork, Serial, SimError};

/// `state_hash` of the fixture below, with layer prediction on (the
/// default). The hash includes the layer set, which prediction changes.
const FIXTURE_HASH: &str = "7d6870e5fb7c0e5f63f8e3af3fdaad49";

/// `state_hash` of the fixture with `contact.predict=false`: the hash pinned
/// before prediction became the default, so the numerics stay held too.
const FIXTURE_HASH_WITHOUT_PREDICTION: &str = "8995028407ecd8365b22d59d5a36a74b";

struct Outcome {
    hash: String,
    rollbacks: u64,
    max_depth: u32,
    peak_active: u64,
    /// Active penalty stencils coupling two partitions, and all of them, at
    /// the window with the most active stencils.
    spanning_at_peak: (usize, usize),
    /// Messages this rank sent to others.
    messages: u64,
    /// Over ranks with `contact.split_islands`: vertices whose unit moved
    /// to another rank in a merge (`Engine::moved_between_ranks`).
    moved_between_ranks: u64,
    /// The bits of every vertex's position, velocity and clock at the end.
    motion: Vec<[u64; 7]>,
    /// Every window's statistics (the stats file's lines), and how its
    /// penalty stage ran (from the timing file's).
    stats: Vec<weft_sim::WindowStats>,
    work: Vec<PenaltyWork>,
}

fn run<E: Executor>(exec: E, partitions: usize) -> Outcome {
    run_with(exec, partitions, true)
}

fn run_with<E: Executor>(exec: E, partitions: usize, predict: bool) -> Outcome {
    run_set(exec, partitions, &[format!("contact.predict={predict}")])
}

/// The fixture with the scene settings `set` added.
fn run_set<E: Executor>(exec: E, partitions: usize, set: &[String]) -> Outcome {
    run_hooked(exec, partitions, set, &mut |_, _| {})
}

/// [`run_set`], calling `after` with the engine and the count of windows
/// run after every window.
fn run_hooked<E: Executor>(
    exec: E,
    partitions: usize,
    set: &[String],
    after: &mut dyn FnMut(&mut Engine<E>, u32),
) -> Outcome {
    let build = |spec: &weft_sim::WorldSpec| weft_par::build_world(spec).unwrap();
    run_built(exec, partitions, set, &build, after)
}

/// [`run_hooked`] on the world `build` makes of the fixture's scene.
fn run_built<E: Executor>(
    exec: E,
    partitions: usize,
    set: &[String],
    build: &dyn Fn(&weft_sim::WorldSpec) -> weft_sim::World,
    after: &mut dyn FnMut(&mut Engine<E>, u32),
) -> Outcome {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let mut sets = vec![
        "size=300".into(),
        "time.end=0.24".into(),
        "time.steps_per_window=25".into(),
        format!("partitions={partitions}"),
    ];
    sets.extend_from_slice(set);
    let scene = load_scene(&path, &sets).unwrap();
    let world = build(&scene.world);
    assert_eq!(world.partitioning.count, partitions);
    let mut e = Engine::new(world, exec).unwrap();
    let end = e.world.lattice.window_end_at_or_after(scene.end_time);
    let mut peak = 0;
    let mut spanning_at_peak = (0, 0);
    let (mut stats, mut work) = (Vec::new(), Vec::new());
    while e.world.tick < end {
        let w = e.step_window().unwrap();
        stats.push(w.stats);
        work.push(w.timing.penalty_work);
        let active = &e.world.layers.stencils;
        if active.len() > peak {
            peak = active.len();
            let p = &e.world.partitioning;
            spanning_at_peak = (active.keys().filter(|k| p.spans(k)).count(), active.len());
        }
        after(&mut e, stats.len() as u32);
    }
    Outcome {
        hash: e.state_hash(),
        rollbacks: e.totals.rollbacks,
        max_depth: e.totals.max_depth,
        peak_active: e.totals.max_active_stencils,
        spanning_at_peak,
        messages: e.executor().traffic().messages,
        moved_between_ranks: e.moved_between_ranks,
        motion: (0..e.world.x.len())
            .map(|i| {
                let (x, v) = (e.world.x[i], e.world.v[i]);
                [
                    x.x.to_bits(),
                    x.y.to_bits(),
                    x.z.to_bits(),
                    v.x.to_bits(),
                    v.y.to_bits(),
                    v.z.to_bits(),
                    e.world.tau[i],
                ]
            })
            .collect(),
        stats,
        work,
    }
}

/// Every window of `o` split its islands exactly when `split`, and the
/// statistics `stats.jsonl` holds are `reference`'s all the same.
fn same_stats_split_as_asked(o: &Outcome, reference: &Outcome, split: bool, label: &str) {
    for ((a, b), work) in o.stats.iter().zip(&reference.stats).zip(&o.work) {
        let window = b.window;
        assert_eq!(work.split, split, "{label}: split in {window}");
        assert_eq!(a, b, "{label}: statistics of {window}");
    }
    assert_eq!(o.stats.len(), reference.stats.len(), "{label}: windows");
}

/// Every executor at `partitions` partitions ends in the fixture's hash.
fn all_executors_agree(partitions: usize) {
    let reference = run(Serial, partitions);
    let label = format!("P = {partitions}");
    assert_eq!(reference.hash, FIXTURE_HASH, "serial, {label}");
    // (6 at every P with layer prediction on, 28 without it: the fixture
    // exercises rollbacks either way.)
    assert!(
        reference.rollbacks >= 5,
        "{label}: {} rollbacks",
        reference.rollbacks
    );
    assert!(
        reference.max_depth >= 5,
        "{label}: depth {}",
        reference.max_depth
    );
    // (479 at every P since friction is clamped per stencil, not per vertex:
    // the cloth grips and folds less than with the under-applied friction.)
    assert!(
        reference.peak_active >= 400,
        "{label}: peak {}",
        reference.peak_active
    );
    if partitions == 16 {
        let (spanning, all) = reference.spanning_at_peak;
        assert!(
            4 * spanning >= all,
            "P = 16: only {spanning} of {all} active penalty stencils span two partitions"
        );
    }
    // `contact.split_islands` unset: no split on one memory below 8
    // threads, every window split from 8 on; the same stats either way.
    assert!(reference.work.iter().all(|w| !w.split));
    for threads in [1, 2, 3, 4, 8] {
        let o = run(Threads::new(threads).unwrap(), partitions);
        assert_eq!(o.hash, FIXTURE_HASH, "threads = {threads}, {label}");
        same_stats_split_as_asked(&o, &reference, threads >= 8, &format!("{threads} threads"));
    }
    // Ranks with one thread each, and two ranks of two threads.
    let rows = [(1, 1), (2, 1), (3, 1), (4, 1), (2, 2)];
    for (ranks, threads) in rows {
        let local = |_| Threads::new(threads).unwrap();
        let outcomes = in_process(ranks, local, |exec| run(exec, partitions));
        for (rank, o) in outcomes.iter().enumerate() {
            assert_eq!(
                o.hash, FIXTURE_HASH,
                "rank {rank} of {ranks} ({threads} threads each), {label}"
            );
            assert_eq!(o.rollbacks, reference.rollbacks, "rank {rank} of {ranks}");
            // Each rank computed its share and received the others'.
            assert_eq!(o.messages > 0, ranks > 1, "rank {rank} of {ranks}");
            // (`contact.split_islands` unset: split from 4 ranks on)
            let label = format!("rank {rank} of {ranks}");
            same_stats_split_as_asked(o, &reference, ranks >= 4, &label);
        }
    }
}

#[test]
fn one_partition() {
    all_executors_agree(1);
}

#[test]
fn four_partitions() {
    all_executors_agree(4);
}

#[test]
fn sixteen_partitions() {
    all_executors_agree(16);
}

#[test]
fn sixty_four_partitions() {
    all_executors_agree(64);
}

/// Layer prediction changes the layer set (and so the state hash and the
/// rollbacks), never the motion (policy independence, `acm-spec.md` §4): the
/// fixture without it ends in the hash pinned before prediction became the
/// default, with every position, velocity and clock the same bit for bit.
#[test]
fn prediction_changes_the_layers_not_the_motion() {
    let on = run_with(Serial, 4, true);
    let off = run_with(Serial, 4, false);
    assert_eq!(on.hash, FIXTURE_HASH);
    assert_eq!(off.hash, FIXTURE_HASH_WITHOUT_PREDICTION);
    assert!(on.motion == off.motion, "prediction changed the motion");
    assert!(
        on.rollbacks < off.rollbacks,
        "{} rollbacks with prediction, {} without",
        on.rollbacks,
        off.rollbacks
    );
}

/// With `contact.split_islands` the far stencils stay out of the islands
/// and are promoted into them when they may come within `eta_1`
/// (`engine/events/far.rs`): the motion and the layers — so the fixture's
/// hash — are those of the islands built over every active stencil, on
/// `Serial`, `Threads` and `Ranks`, and every window's statistics (layer
/// evaluations, far stencils, promotions, reruns) agree on every executor:
/// the units and their promotions follow from the state, not from where
/// they run.
#[test]
fn split_islands_keep_the_bits_on_every_executor() {
    let split = ["contact.split_islands=true".to_string()];
    let reference = run_set(Serial, 4, &split);
    assert_eq!(reference.hash, FIXTURE_HASH, "serial, split");
    let whole = run(Serial, 4);
    assert!(
        whole.motion == reference.motion,
        "splitting changed the motion"
    );
    let sum = |f: &dyn Fn(&PenaltyWork) -> u64| -> u64 { reference.work.iter().map(f).sum() };
    let (far, promoted) = (sum(&|w| w.far_stencils), sum(&|w| w.far_promoted));
    println!(
        "far {far}, promoted {promoted}, reruns {}",
        sum(&|w| w.island_reruns)
    );
    assert!(
        far > 1000 && promoted > 100,
        "far {far}, promoted {promoted}"
    );
    let threads = run_set(Threads::new(2).unwrap(), 4, &split);
    assert_eq!(threads.hash, FIXTURE_HASH, "2 threads, split");
    assert_eq!(
        (threads.stats, threads.work),
        (reference.stats.clone(), reference.work.clone()),
        "2 threads, split: statistics and penalty work"
    );
    for (ranks, threads) in [(2, 1), (3, 2), (4, 1)] {
        let local = |_| Threads::new(threads).unwrap();
        let outcomes = in_process(ranks, local, |exec| run_set(exec, 4, &split));
        for (rank, o) in outcomes.iter().enumerate() {
            let label = format!("rank {rank} of {ranks} ({threads} threads), split");
            assert_eq!(o.hash, FIXTURE_HASH, "{label}");
            for (a, b) in o.stats.iter().zip(&reference.stats) {
                assert_eq!(a, b, "{label}: statistics of window {}", b.window);
            }
            assert_eq!(o.work, reference.work, "{label}: penalty work");
        }
        // The units are spread over the ranks, and promotions merged units
        // of two ranks (every rank counts every move alike).
        let moved = outcomes[0].moved_between_ranks;
        println!("{ranks} ranks: {moved} vertices moved between ranks");
        assert!(moved > 0, "{ranks} ranks: no unit moved between ranks");
        assert!(outcomes.iter().all(|o| o.moved_between_ranks == moved));
    }
}

/// A twister (a scripted rod, the sleeve's ends pinned to scripts: vertices
/// the internal stencils read but that fold nothing) over 1, 3 and 4 ranks:
/// the same state hash after its first windows. A rank keeps current only
/// the vertices it owns and those others read (`share::PassShare`); a
/// kinematic vertex a partition reads off its owner must be among them.
#[test]
fn twister_over_ranks_keeps_the_vertices_each_rank_reads() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/twister.toml");
    let scene = load_scene(
        &path,
        &[
            "size=600".into(),
            "time.steps_per_window=20".into(),
            "partitions=12".into(),
        ],
    )
    .unwrap();
    let reference = twister_hash(&scene, Serial);
    for ranks in [3, 4] {
        let hashes = in_process(ranks, |_| Serial, |exec| twister_hash(&scene, exec));
        for (rank, hash) in hashes.iter().enumerate() {
            assert_eq!(hash, &reference, "rank {rank} of {ranks}");
        }
    }
}

/// The internal step is estimated (two Lanczos iterations over the
/// assembled rest system, most of a world's build) range by range of
/// vertices on a rank's threads: a world built on 2 and 3 threads has one
/// thread's largest frequency, damping rate and step, bit for bit, and the
/// same fingerprint; the crumple fixture run from one still ends on its
/// hash.
#[test]
fn worlds_built_on_threads_have_one_threads_step() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    for (name, size) in [("crumple", 300), ("twister", 600), ("drape", 400)] {
        let sets = [format!("size={size}"), "time.steps_per_window=25".into()];
        let scene = load_scene(&dir.join(format!("{name}.toml")), &sets).unwrap();
        let serial = weft_par::build_world(&scene.world).unwrap();
        assert!(
            serial.omega_max > 0.0 && serial.damping_rate > 0.0,
            "{name}"
        );
        for threads in [2, 3] {
            let pool = Threads::new(threads).unwrap();
            let built = pool.install(|| weft_par::build_world_on(&scene.world, &pool));
            let world = built.unwrap();
            let what = format!("{name} on {threads} threads");
            assert_eq!(
                world.omega_max.to_bits(),
                serial.omega_max.to_bits(),
                "{what}"
            );
            assert_eq!(
                world.damping_rate.to_bits(),
                serial.damping_rate.to_bits(),
                "{what}"
            );
            let h = |w: &weft_sim::World| w.lattice.h_el().to_bits();
            assert_eq!(h(&world), h(&serial), "{what}: the internal step");
            let fingerprint = weft_sim::hash::world_fingerprint;
            assert_eq!(fingerprint(&world), fingerprint(&serial), "{what}");
        }
    }
    let pool = Threads::new(3).unwrap();
    let build = |spec: &weft_sim::WorldSpec| {
        (pool.install(|| weft_par::build_world_on(spec, &pool))).unwrap()
    };
    let o = run_built(Serial, 4, &[], &build, &mut |_, _| {});
    assert_eq!(
        o.hash, FIXTURE_HASH,
        "crumple from a world built on 3 threads"
    );
}

/// The state hash of `scene` after 4 windows on `exec`.
fn twister_hash<E: Executor>(scene: &weft_io::scene::Scene, exec: E) -> String {
    let world = weft_par::build_world(&scene.world).unwrap();
    let mut e = Engine::new(world, exec).unwrap();
    for _ in 0..4 {
        e.step_window().unwrap();
    }
    e.state_hash()
}

/// A digest of the positions' x bits: the state an error leaves (the window
/// start's, on every executor).
fn x_bits<E: Executor>(e: &Engine<E>) -> u64 {
    (e.world.x.iter())
        .map(|p| p.x.to_bits())
        .fold(0, u64::wrapping_add)
}

/// A vertex whose mass turns out not to be a number: its first new velocity
/// is not finite. Every executor stops at the same vertex with the same
/// error (over ranks the vertex's owner finds it; the other ranks count
/// the changed velocities before it again, and every rank stops there).
#[test]
fn a_blow_up_stops_every_executor_at_the_same_vertex() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let scene = load_scene(&path, &["size=300".into(), "partitions=8".into()]).unwrap();
    fn broken<E: Executor>(scene: &weft_io::scene::Scene, exec: E) -> (String, u64) {
        let world = weft_par::build_world(&scene.world).unwrap();
        let mut e = Engine::new(world, exec).unwrap();
        // A vertex in the middle of the cloth (owned by a middle rank).
        let k = e.world.x.len() / 2;
        e.world.inv_mass[k] = f64::NAN;
        let err = e.step_window().map(|_| ()).unwrap_err();
        // (the state the error leaves: the window start's, on every executor)
        (err.to_string(), x_bits(&e))
    }
    let reference = broken(&scene, Serial);
    assert!(reference.0.contains("non-finite"), "{}", reference.0);
    for ranks in [2, 3] {
        let outcomes = in_process(ranks, |_| Serial, |exec| broken(&scene, exec));
        for (rank, o) in outcomes.iter().enumerate() {
            assert_eq!(o, &reference, "rank {rank} of {ranks}");
        }
    }
}

/// As above, but in contact: with contact islands, the internal forces and
/// folds of the vertices outside every island run beside the islands (on
/// one memory, not over ranks), and a blow-up of such a vertex must still
/// stop the tick at that vertex, at the window's first internal tick, as
/// over ranks (which compute the whole tick at the tick). `drape` hangs
/// its corners far from the sphere: a corner's blow-up has no stencil near
/// it, so it is an error at once, naming the vertex and the tick.
#[test]
fn a_blow_up_in_contact_stops_every_executor_at_the_same_vertex() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/drape.toml");
    let scene = load_scene(&path, &["size=300".into(), "partitions=8".into()]).unwrap();
    fn broken<E: Executor>(scene: &weft_io::scene::Scene, exec: E) -> (String, u64) {
        let world = weft_par::build_world(&scene.world).unwrap();
        let mut e = Engine::new(world, exec).unwrap();
        while e.world.layers.stencils.len() < 20 {
            assert!(e.world.window_index < 400, "drape never came into contact");
            e.step_window().unwrap();
        }
        let mut touched = vec![false; e.world.x.len()];
        for key in e.world.layers.stencils.keys() {
            key.v.iter().for_each(|&i| touched[i as usize] = true);
        }
        let dynamic = |i: usize| e.world.inv_mass[i] > 0.0;
        // The vertex outside every island farthest from every stencil in
        // contact, before the last island vertex (so that a tick that
        // missed it would stop at a later vertex, or not at all).
        let x = &e.world.x;
        let near = |i: usize| {
            (0..touched.len())
                .filter(|&j| touched[j])
                .map(|j| x[i].distance(x[j]))
                .fold(f64::INFINITY, f64::min)
        };
        let last = (0..touched.len())
            .rfind(|&i| touched[i] && dynamic(i))
            .expect("a vertex in an island");
        let calm = (0..last)
            .filter(|&i| !touched[i] && dynamic(i))
            .max_by(|&a, &b| near(a).total_cmp(&near(b)))
            .expect("a vertex outside the islands");
        e.world.inv_mass[calm] = f64::NAN;
        // (A window starts on the internal clock: its first internal tick
        // is its first tick.)
        let first_tick = e.world.time();
        match e.step_window().map(|_| ()).unwrap_err() {
            err @ SimError::NonFinite { vertex, time, .. } => {
                assert_eq!(vertex as usize, calm, "{err}");
                assert!(
                    (time - first_tick).abs() < 1e-3 * e.world.lattice.h_el(),
                    "{err}"
                );
                (err.to_string(), x_bits(&e))
            }
            err => panic!("expected a non-finite vertex, got: {err}"),
        }
    }
    let reference = broken(&scene, Serial);
    assert_eq!(broken(&scene, Threads::new(2).unwrap()), reference);
    let outcomes = in_process(2, |_| Serial, |exec| broken(&scene, exec));
    for (rank, o) in outcomes.iter().enumerate() {
        assert_eq!(o, &reference, "rank {rank} of 2");
    }
}

/// Over ranks the engine places the partitions again between windows by
/// the load it measured (`engine/placement.rs`); which placement it takes
/// follows wall-clock times, so this test takes them by hand instead: a
/// different one after every window (some leave a rank without any
/// partition), on 2 and 3 ranks of 1 and 2 threads. Every rank ends in the
/// fixture's hash with every window's statistics.
#[test]
fn partitions_placed_again_between_windows_keep_the_bits() {
    let partitions = 16;
    let reference = run(Serial, partitions);
    for (ranks, threads) in [(2, 1), (3, 1), (2, 2)] {
        let local = |_| Threads::new(threads).unwrap();
        let outcomes = in_process(ranks, local, |exec| {
            // Window w: partition p on rank (p * (w + 1) + w) mod R, or
            // every third window all on rank w mod R.
            let mut place = |e: &mut Engine<_>, w: u32| {
                let home: Vec<u32> = (0..partitions as u32)
                    .map(|p| match w % 3 {
                        0 => w % ranks as u32,
                        _ => (p * (w + 1) + w) % ranks as u32,
                    })
                    .collect();
                let before = e.placements;
                e.place_partitions(home).expect("placed again");
                assert_eq!(e.placements, before + 1, "placed after window {w}");
            };
            run_hooked(exec, partitions, &[], &mut place)
        });
        for (rank, o) in outcomes.iter().enumerate() {
            let label = format!("rank {rank} of {ranks} ({threads} threads), placed by hand");
            assert_eq!(o.hash, FIXTURE_HASH, "{label}");
            // (2 and 3 ranks: the islands whole, `contact.split_islands`
            // unset)
            same_stats_split_as_asked(o, &reference, false, &label);
        }
    }
}

/// With `contact.split_islands` over ranks the twister's units are spread
/// over the ranks and its far stencils watched where their units run: a
/// promotion merges units of two ranks, and the merged unit is built where
/// it runs once its vertices' states arrived there (built before, from a
/// stale velocity, a stencil slept through a kick), from the loose
/// vertices' owners too (the rank watching a far stencil need not hold
/// them). Every window's state hash and statistics are one process's at 2,
/// 3 and 4 ranks.
#[test]
fn twister_split_over_ranks_keeps_the_bits() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/twister.toml");
    let scene = load_scene(
        &path,
        &[
            "size=600".to_string(),
            "time.steps_per_window=20".into(),
            "partitions=12".into(),
            "contact.split_islands=true".into(),
        ],
    )
    .unwrap();
    fn windows<E: Executor>(
        scene: &weft_io::scene::Scene,
        exec: E,
    ) -> (Vec<(String, weft_sim::CommittedWindow)>, u64) {
        let world = weft_par::build_world(&scene.world).unwrap();
        let mut e = Engine::new(world, exec).unwrap();
        let mut out = Vec::new();
        for _ in 0..4 {
            let mut w = e.step_window().unwrap();
            (w.timing.wall_seconds, w.timing.stage_seconds) = (0.0, Default::default());
            out.push((e.state_hash(), w));
        }
        (out, e.moved_between_ranks)
    }
    let (reference, _) = windows(&scene, Serial);
    let promoted: u64 = reference
        .iter()
        .map(|w| w.1.timing.penalty_work.far_promoted)
        .sum();
    assert!(promoted > 1000, "{promoted} promotions");
    for ranks in [2, 3, 4] {
        let outcomes = in_process(ranks, |_| Serial, |exec| windows(&scene, exec));
        for (rank, (got, moved)) in outcomes.iter().enumerate() {
            for (k, (a, b)) in got.iter().zip(&reference).enumerate() {
                assert_eq!(a.0, b.0, "rank {rank} of {ranks}: window {k}'s hash");
                assert_eq!(a.1, b.1, "rank {rank} of {ranks}: window {k}'s statistics");
            }
            assert!(
                *moved > 0,
                "rank {rank} of {ranks}: no unit moved between ranks"
            );
        }
    }
}
