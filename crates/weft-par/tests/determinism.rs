//! The same bits on any executor: `crumple` (friction and damping on) run on
//! `Serial` and on `Threads` with 1 to 4 threads, each with 1, 4 and 16
//! partitions, ends in one `state_hash` — with enough contact to mean it.

use std::path::Path;

use weft_io::scene::load_scene;
use weft_par::Threads;
use weft_sim::{Engine, Executor, Serial, World};

struct Outcome {
    hash: String,
    rollbacks: u64,
    max_depth: u32,
    peak_active: u64,
}

fn run<E: Executor>(exec: E, partitions: usize) -> Outcome {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let scene = load_scene(
        &path,
        &[
            "size=150".into(),
            "time.end=0.22".into(),
            "time.steps_per_window=25".into(),
            format!("partitions={partitions}"),
        ],
    )
    .unwrap();
    let mut e = Engine::new(World::build(&scene.world).unwrap(), exec).unwrap();
    let end = e.world.lattice.window_end_at_or_after(scene.end_time);
    while e.world.tick < end {
        e.step_window().unwrap();
    }
    Outcome {
        hash: e.state_hash(),
        rollbacks: e.totals.rollbacks,
        max_depth: e.totals.max_depth,
        peak_active: e.totals.max_active_stencils,
    }
}

#[test]
fn serial_and_threads_agree_for_any_thread_and_partition_count() {
    let reference = run(Serial, 1);
    assert!(
        reference.rollbacks >= 20,
        "{} rollbacks",
        reference.rollbacks
    );
    assert!(reference.max_depth >= 5, "depth {}", reference.max_depth);
    assert!(
        reference.peak_active >= 50,
        "peak {}",
        reference.peak_active
    );
    for partitions in [1, 4, 16] {
        for threads in [1, 2, 3, 4] {
            let o = run(Threads::new(threads).unwrap(), partitions);
            assert_eq!(
                o.hash, reference.hash,
                "threads = {threads}, partitions = {partitions}"
            );
        }
        assert_eq!(
            run(Serial, partitions).hash,
            reference.hash,
            "serial, P = {partitions}"
        );
    }
}
