//! Policy independence (`acm-spec.md` §4): the positions, velocities and
//! clocks do not depend on when layers are activated or retired — predicted
//! ahead of a window (`contact.predict`), added `layers_per_detection` at a
//! time, retired after `retire_after_windows` calm windows — while the
//! rollback counts do.
//!
//! Why it holds: a layer kicks only inside its `eta_l`, and a committed
//! window keeps every stencil outside its first inactive layer, so every
//! committed trajectory is that of "every layer always active". This test
//! also guards the engine: any place where an inactive, sleeping or skipped
//! layer changed the physics (a breakpoint, a fold order, a friction clamp,
//! an island's schedule) would break it.

use std::path::Path;

use weft_io::scene::load_scene;
use weft_par::ranks::in_process;
use weft_par::Threads;
use weft_sim::{Engine, Executor, Serial};

/// One activation and retirement policy.
#[derive(Clone, Copy, Debug)]
struct Policy {
    predict: bool,
    layers_per_detection: u32,
    retire_after_windows: u32,
}

/// Every value of each knob the issue names, in six runs.
const POLICIES: [Policy; 6] = [
    Policy {
        predict: true,
        layers_per_detection: 5,
        retire_after_windows: 3,
    },
    Policy {
        predict: false,
        layers_per_detection: 5,
        retire_after_windows: 3,
    },
    Policy {
        predict: false,
        layers_per_detection: 1,
        retire_after_windows: 1,
    },
    Policy {
        predict: true,
        layers_per_detection: 1,
        retire_after_windows: 10,
    },
    Policy {
        predict: true,
        layers_per_detection: 2,
        retire_after_windows: 1,
    },
    Policy {
        predict: false,
        layers_per_detection: 2,
        retire_after_windows: 10,
    },
];

/// What a run leaves at each window end.
struct Run {
    /// Per window: the bits of x, v (per coordinate) and tau.
    windows: Vec<Vec<u64>>,
    rollbacks: u64,
    predicted_layers: u64,
    peak_active: u64,
}

fn run(scene: &str, overrides: &[&str], policy: Policy) -> Run {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(scene);
    let mut set: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    set.push(format!("contact.predict={}", policy.predict));
    set.push(format!(
        "contact.layers_per_detection={}",
        policy.layers_per_detection
    ));
    set.push(format!(
        "contact.retire_after_windows={}",
        policy.retire_after_windows
    ));
    let scene = load_scene(&path, &set).unwrap();
    let world = weft_par::build_world(&scene.world).unwrap();
    let mut e = Engine::new(world, Serial).unwrap();
    let end = e.world.lattice.window_end_at_or_after(scene.end_time);
    let mut windows = Vec::new();
    let mut predicted_layers = 0;
    while e.world.tick < end {
        let stats = e.step_window().unwrap().stats;
        predicted_layers += stats.predicted_layers;
        let w = &e.world;
        let bits = (w.x.iter().chain(&w.v))
            .flat_map(|p| p.to_array().map(f64::to_bits))
            .chain(w.tau.iter().copied())
            .collect();
        windows.push(bits);
    }
    Run {
        windows,
        rollbacks: e.totals.rollbacks,
        predicted_layers,
        peak_active: e.totals.max_active_stencils,
    }
}

/// Runs `scene` under every policy and compares every window end with the
/// first policy's, bit for bit.
fn same_trajectory_under_every_policy(scene: &str, overrides: &[&str]) {
    let reference = run(scene, overrides, POLICIES[0]);
    assert!(
        reference.peak_active > 0 && reference.rollbacks + reference.predicted_layers > 0,
        "{scene}: no contact to test with"
    );
    let mut rollbacks = vec![reference.rollbacks];
    for policy in &POLICIES[1..] {
        let r = run(scene, overrides, *policy);
        assert_eq!(
            r.windows.len(),
            reference.windows.len(),
            "{scene}: {policy:?}"
        );
        for (k, (a, b)) in r.windows.iter().zip(&reference.windows).enumerate() {
            if let Some(at) = a.iter().zip(b).position(|(a, b)| a != b) {
                panic!(
                    "{scene}: {policy:?} differs from {:?} at the end of window {k} \
                     (word {at} of x, v, tau)",
                    POLICIES[0]
                );
            }
        }
        if policy.predict {
            assert!(
                r.predicted_layers > 0,
                "{scene}: {policy:?} predicted nothing"
            );
        }
        rollbacks.push(r.rollbacks);
    }
    println!("{scene}: rollbacks per policy {rollbacks:?}");
    let distinct = {
        let mut r = rollbacks.clone();
        r.sort_unstable();
        r.dedup();
        r.len()
    };
    assert!(
        distinct >= 3,
        "{scene}: the policies should change the rollbacks: {rollbacks:?}"
    );
}

#[test]
fn crumple() {
    same_trajectory_under_every_policy(
        "crumple.toml",
        &["size=300", "time.end=0.2", "time.steps_per_window=25"],
    );
}

#[test]
fn twister() {
    same_trajectory_under_every_policy(
        "twister.toml",
        &[
            "size=300",
            "time.end=0.015",
            "time.steps_per_window=10",
            "obstacle.0.motion.omega=[[0.0, 0.0], [0.25, 6.283185307179586]]",
        ],
    );
}

#[test]
fn reef_knot() {
    same_trajectory_under_every_policy("reef-knot.toml", &["size=400", "time.end=0.3"]);
}

/// The policy keys are left out of the scene fingerprint (a run resumes,
/// and a bench starts from a checkpoint, under another policy); a key that
/// changes the physics is not.
#[test]
fn policy_keys_are_not_part_of_the_scene_fingerprint() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
    let print = |set: &[&str]| {
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        load_scene(&path, &set).unwrap().fingerprint
    };
    let base = print(&[]);
    assert_eq!(
        print(&[
            "contact.predict=true",
            "contact.layers_per_detection=2",
            "contact.retire_after_windows=7",
        ]),
        base
    );
    assert_ne!(print(&["contact.friction=0.1"]), base);
}

/// With prediction on, the layer set too (hence the state hash) is the same
/// on every executor: the predictor decides from state every rank holds.
#[test]
fn prediction_is_the_same_on_threads_and_ranks() {
    fn hash<E: Executor>(exec: E) -> (String, u64) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/crumple.toml");
        let set: Vec<String> = [
            "size=300",
            "time.end=0.2",
            "time.steps_per_window=25",
            "partitions=6",
            "contact.predict=true",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let scene = load_scene(&path, &set).unwrap();
        let world = weft_par::build_world(&scene.world).unwrap();
        let mut e = Engine::new(world, exec).unwrap();
        let end = e.world.lattice.window_end_at_or_after(scene.end_time);
        let mut predicted = 0;
        while e.world.tick < end {
            predicted += e.step_window().unwrap().stats.predicted_layers;
        }
        (e.state_hash(), predicted)
    }
    let reference = hash(Serial);
    assert!(reference.1 > 0, "nothing predicted");
    assert_eq!(hash(Threads::new(2).unwrap()), reference, "2 threads");
    for ranks in [2, 3] {
        let outcomes = in_process(ranks, |_| Threads::new(1).unwrap(), hash);
        for (rank, o) in outcomes.iter().enumerate() {
            assert_eq!(*o, reference, "rank {rank} of {ranks}");
        }
    }
}
