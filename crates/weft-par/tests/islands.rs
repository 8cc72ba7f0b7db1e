//! Contact islands reproduce the global schedule bit for bit: on random
//! small scenes (cloths falling at random tilts and speeds onto a sphere and
//! onto each other, friction on or off, two layer-1 steps) the islands run
//! in parallel on two threads end every window in the same positions,
//! velocities, clocks and layers as every active stencil run as one island
//! (one batch per tick over all of them, `Engine::run_as_one_island`), with
//! the same counts of layer evaluations, kicks and breakpoints; with every
//! island alone and with the small ones packed (`Engine::set_island_packing`).

use glam::DVec3;
use weft_geom::shapes::{grid, sphere};
use weft_par::Threads;
use weft_sim::kinematics::Motion;
use weft_sim::materials::Material;
use weft_sim::{
    CommittedWindow, ContactConfig, Engine, Executor, LimitsConfig, ObjectKind, ObjectSpec, Serial,
    TimeConfig, World, WorldSpec,
};
use weft_testkit::Rng;

fn scene(rng: &mut Rng, case: usize) -> WorldSpec {
    let mut objects = vec![ObjectSpec {
        friction: None,
        name: "ball".into(),
        mesh: sphere(DVec3::ZERO, 0.03, 2),
        kind: ObjectKind::Obstacle {
            motion: Motion::Fixed,
        },
    }];
    // Four small cloths over the ball, two side by side in each of two
    // layers: they touch the ball and each other apart and together.
    for k in 0..4 {
        let eu = (DVec3::X + rng.vec(0.15)).normalize();
        let ev = (DVec3::Z + rng.vec(0.15)).cross(eu).normalize();
        let side = if k % 2 == 0 { -0.014 } else { 0.014 };
        let centre = DVec3::new(
            side + rng.uniform(-0.003, 0.003),
            rng.uniform(-0.01, 0.01),
            0.0,
        ) + DVec3::Z * (0.042 + 0.02 * (k / 2) as f64);
        let mesh = grid(centre, eu, ev, [0.024, 0.024], [5, 5]);
        let n = mesh.num_vertices();
        objects.push(ObjectSpec {
            friction: None,
            name: format!("cloth{k}"),
            mesh,
            kind: ObjectKind::Cloth {
                material: Material::plate(0.15, 2.0e5, 0.3, 4.0e-4),
                rest: None,
                velocity: vec![rng.vec(0.5) - DVec3::Z; n],
            },
        });
    }
    WorldSpec {
        objects,
        pins: vec![],
        gravity: DVec3::new(0.0, 0.0, -9.81),
        contact: ContactConfig {
            thickness: 1e-3,
            friction: if case % 2 == 0 { 0.0 } else { 0.4 },
            layer1_step_shift: (case / 2) as u32,
            ..Default::default()
        },
        time: TimeConfig {
            internal_step: None,
            beta: 0.3,
            steps_per_window: 20,
        },
        limits: LimitsConfig::default(),
        partitions: 4,
        workers: 1,
    }
}

/// The world run as one island on `Serial` (one batch per tick over every
/// stencil: the global schedule), and on `exec`.
fn global_and<E: Executor>(world: World, exec: E) -> (Engine<Serial>, Engine<E>) {
    let mut global = Engine::new(world.clone(), Serial).unwrap();
    global.run_as_one_island(true);
    (global, Engine::new(world, exec).unwrap())
}

/// The two engines hold the same positions, velocities, clocks and layers.
fn assert_same_state<A: Executor, B: Executor>(a: &Engine<A>, b: &Engine<B>, what: &str) {
    assert_eq!(a.world.x, b.world.x, "{what}: positions");
    assert_eq!(a.world.v, b.world.v, "{what}: velocities");
    assert_eq!(a.world.tau, b.world.tau, "{what}: clocks");
    assert_eq!(a.world.layers, b.world.layers, "{what}: layers");
}

/// The four random scenes, 30 windows each, under the global schedule and
/// on 2 threads with `configure(case, engine)` applied: the same state at
/// every window end; `each(global's window, the other's, what)` per window.
fn against_the_global_schedule(
    configure: impl Fn(usize, &mut Engine<Threads>),
    mut each: impl FnMut(&CommittedWindow, &CommittedWindow, &str),
) {
    let mut rng = Rng(0x1514);
    for case in 0..4 {
        let spec = scene(&mut rng, case);
        let world = weft_par::build_world(&spec).unwrap();
        let (mut global, mut other) = global_and(world, Threads::new(2).unwrap());
        configure(case, &mut other);
        for w in 0..30 {
            let a = global.step_window().unwrap();
            let b = other.step_window().unwrap();
            let what = format!("case {case}, window {w}");
            assert_same_state(&global, &other, &what);
            each(&a, &b, &what);
        }
    }
}

#[test]
fn islands_on_threads_give_the_bits_of_the_global_schedule() {
    let (mut most_islands, mut kicks) = (0u64, 0u64);
    // Every island alone, or the small ones packed in threes.
    let pack = |case: usize, e: &mut Engine<Threads>| e.set_island_packing([1, 3][case % 2]);
    against_the_global_schedule(pack, |a, b, what| {
        let counts = |w: &CommittedWindow| {
            (
                w.stats.layer_events,
                w.timing.penalty_work.layer_evaluations,
                w.stats.layer_kicks,
                w.stats.breakpoints,
                w.stats.rollbacks,
            )
        };
        assert_eq!(counts(a), counts(b), "{what}: counts");
        let (a, b) = (&a.stats, &b.stats);
        assert_eq!(a.min_separation, b.min_separation, "{what}");
        assert!(a.islands <= 1, "{what}: one island");
        most_islands = most_islands.max(b.islands);
        kicks += b.layer_kicks;
    });
    println!("up to {most_islands} islands in a window, {kicks} kicks");
    assert!(
        most_islands >= 4,
        "the scenes must make several islands: {most_islands}"
    );
    assert!(kicks > 1000, "too little contact: {kicks} kicks");
}

/// With the far stencils kept out of the islands (`split_far_stencils`)
/// and promoted into them when they may come within `eta_1`, every window
/// ends in the global schedule's bits, on the scenes above (cloths falling
/// onto a ball and onto each other, where a thousand far stencils are
/// promoted). The reruns after a speed broke a cap are held on `crumple`
/// (`determinism.rs`, `split_islands_keep_the_bits_on_every_executor`).
#[test]
fn far_stencils_split_the_islands_with_the_bits_of_the_global_schedule() {
    let (mut far, mut promoted) = (0u64, 0u64);
    let split = |_: usize, e: &mut Engine<Threads>| e.split_far_stencils(true);
    against_the_global_schedule(split, |_, b, _| {
        far += b.timing.penalty_work.far_stencils;
        promoted += b.timing.penalty_work.far_promoted;
    });
    println!("{far} far stencils at pass starts, {promoted} promoted");
    assert!(
        far > 2000 && promoted > 500,
        "{far} far, {promoted} promoted"
    );
}

/// A paddle moving up at `speed` strikes a cloth at rest, which flies into
/// a second cloth hovering just above it: the two cloths' stencils are far
/// (certified outside `eta_1` while both rest), until the paddle's kicks
/// break their speed caps in the middle of a segment.
fn paddle(speed: f64, gap: f64) -> WorldSpec {
    let flat = |z: f64, size: f64| grid(DVec3::Z * z, DVec3::X, DVec3::Y, [size, size], [6, 6]);
    let cloth = |name: &str, z: f64| ObjectSpec {
        friction: None,
        name: name.into(),
        mesh: flat(z, 0.024),
        kind: ObjectKind::Cloth {
            material: Material::plate(0.15, 2.0e5, 0.3, 4.0e-4),
            rest: None,
            velocity: vec![DVec3::ZERO; 36],
        },
    };
    WorldSpec {
        objects: vec![
            ObjectSpec {
                friction: None,
                name: "paddle".into(),
                mesh: flat(-0.004, 0.04),
                kind: ObjectKind::Obstacle {
                    motion: Motion::Translate {
                        velocity: DVec3::Z * speed,
                        until: None,
                    },
                },
            },
            cloth("struck", 0.0),
            cloth("hovering", 1e-3 + gap),
        ],
        pins: vec![],
        gravity: DVec3::ZERO,
        contact: ContactConfig {
            thickness: 1e-3,
            ..Default::default()
        },
        time: TimeConfig {
            internal_step: None,
            beta: 0.3,
            steps_per_window: 20,
        },
        limits: LimitsConfig::default(),
        partitions: 2,
        workers: 1,
    }
}

/// The speed caps hold the far stencils' certificates within a segment:
/// a cloth struck by a paddle flies into another that rested just above
/// it, inside the segment whose kicks launched it. The islands must report
/// the broken caps, the check after the segment promote the stencils and
/// the segment run again — or the first kicks between the cloths are lost
/// (without the reports this fails).
#[test]
fn a_cloth_launched_within_a_segment_promotes_its_far_stencils() {
    let mut reruns = 0;
    for (speed, gap) in [(2.0, 5e-5), (4.0, 1e-4), (8.0, 2e-4)] {
        let world = weft_par::build_world(&paddle(speed, gap)).unwrap();
        let (mut global, mut split) = global_and(world, Serial);
        split.split_far_stencils(true);
        for w in 0..20 {
            let a = global.step_window().unwrap();
            let b = split.step_window().unwrap();
            let what = format!("paddle at {speed} m/s, gap {gap}, window {w}");
            assert_same_state(&global, &split, &what);
            assert_eq!(a.stats.rollbacks, b.stats.rollbacks, "{what}: rollbacks");
            reruns += b.timing.penalty_work.island_reruns;
        }
    }
    assert!(reruns > 0, "no segment ran again");
}

/// A checkpointed layer on kinematic vertices only (no broad phase makes
/// one; a hand-edited checkpoint can) is refused by `restore`, not left to
/// fail when the islands are built.
#[test]
fn restore_refuses_a_layer_of_kinematic_vertices_only() {
    let spec = scene(&mut Rng(3), 0);
    let world = weft_par::build_world(&spec).unwrap();
    let mut engine = Engine::new(world, Serial).unwrap();
    let mut state = engine.state();
    let ball = weft_sim::layers::LayerState {
        depth: 1,
        calm_windows: 0,
    };
    state
        .layers
        .push((weft_core::StencilKey::vertex_face(0, [1, 2, 3]), ball));
    let err = engine.restore(state).unwrap_err().to_string();
    assert!(err.contains("only pinned or scripted vertices"), "{err}");
}
