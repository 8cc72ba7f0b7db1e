//! The event loop's numerics: it is exactly leapfrog when every force shares
//! one step, and with contact it conserves momentum and energy.

use glam::DVec3;
use weft_geom::shapes::grid;
use weft_sim::materials::Material;
use weft_sim::{
    ContactConfig, Engine, LimitsConfig, ObjectKind, ObjectSpec, Serial, TimeConfig, World,
    WorldSpec,
};

fn material() -> Material {
    Material::plate(0.2, 1e5, 0.3, 1e-3)
}

fn spec(objects: Vec<ObjectSpec>, gravity: DVec3, steps_per_window: u64, beta: f64) -> WorldSpec {
    WorldSpec {
        objects,
        pins: vec![],
        gravity,
        contact: ContactConfig {
            thickness: 2e-3,
            ..Default::default()
        },
        time: TimeConfig {
            internal_step: None,
            beta,
            steps_per_window,
        },
        limits: LimitsConfig::default(),
        partitions: 1,
        workers: 1,
    }
}

/// With one common step for every force (no contact), the asynchronous event
/// loop is leapfrog: drift x += h v, then kick v -= h M⁻¹ ∇V(x). The reference
/// below does exactly that with the assembled gradient, and the two must agree
/// to the last bit.
#[test]
fn event_loop_without_contact_is_leapfrog_bitwise() {
    let flat = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [0.2, 0.1], [9, 5]);
    let mut start = flat.clone();
    for (k, p) in start.positions.iter_mut().enumerate() {
        // Stretched 3 % and slightly wavy: stretch and bend both act.
        *p *= 1.03;
        p.y = 0.004 * ((k % 9) as f64 * 0.7).sin();
    }
    let velocity: Vec<DVec3> = (0..start.num_vertices())
        .map(|k| DVec3::new(0.01 * (k as f64).cos(), 0.2, -0.05))
        .collect();
    let obj = ObjectSpec {
        friction: None,
        name: "sheet".into(),
        mesh: start,
        kind: ObjectKind::Cloth {
            material: material(),
            rest: Some(flat.positions),
            velocity,
        },
    };
    let gravity = DVec3::new(0.0, -9.81, 0.0);
    let world = World::build(&spec(vec![obj], gravity, 20, 0.3)).unwrap();
    let mut engine = Engine::new(world, Serial).unwrap();

    // Reference leapfrog on a copy of the initial state.
    let w0 = engine.world.clone();
    let model = w0.internal.model();
    let h = w0.lattice.h_el();
    let (mut x, mut v) = (w0.x.clone(), w0.v.clone());
    let windows = 3;
    for _ in 0..windows {
        let stats = engine.step_window().unwrap().stats;
        assert_eq!(stats.rollbacks, 0, "this test must not see contact");
        assert_eq!(stats.layer_events, 0);
    }
    // Kicks at ticks n·h for n ≥ 1; the kick at the last window end belongs
    // to the next window, so the run ends with a drift.
    let steps = windows * 20;
    for n in 1..=steps {
        for i in 0..x.len() {
            x[i] += v[i] * h;
        }
        if n == steps {
            break;
        }
        let mut g = vec![DVec3::ZERO; x.len()];
        model.add_gradient(&x, &mut g);
        for i in 0..x.len() {
            let gi = g[i] - gravity * w0.mass[i];
            v[i] += gi * -h * w0.inv_mass[i];
        }
    }
    let moved = (x[0] - w0.x[0]).length();
    assert!(moved > 1e-3, "the sheet must move ({moved})");
    for i in 0..x.len() {
        assert_eq!(engine.world.x[i], x[i], "position of vertex {i}");
        assert_eq!(engine.world.v[i], v[i], "velocity of vertex {i}");
    }
}

/// A strip bent into a U (a half circle of radius 1 cm and two parallel arms)
/// whose arms swing towards each other and slap together, while the whole
/// strip drifts and spins; no gravity, damping, friction or kinematics.
fn folding_strip() -> WorldSpec {
    let flat = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [0.24, 0.08], [19, 7]);
    let r = 0.012;
    let arc = std::f64::consts::FRAC_PI_2 * r;
    let u_shape = |s: f64| -> DVec3 {
        if s.abs() <= arc {
            let phi = s / r;
            DVec3::new(r * phi.sin(), -r * phi.cos(), 0.0)
        } else {
            DVec3::new(r * s.signum(), s.abs() - arc, 0.0)
        }
    };
    let mut start = flat.clone();
    for p in &mut start.positions {
        let z = p.z;
        *p = u_shape(p.x) + DVec3::new(0.0, 0.0, z);
    }
    let (drift, spin) = (DVec3::new(0.3, 0.1, -0.2), DVec3::new(0.0, 1.5, 0.0));
    let velocity = flat
        .positions
        .iter()
        .zip(&start.positions)
        .map(|(f, p)| {
            // Each arm swings inwards, faster towards its tip.
            let lever = ((f.x.abs() - arc) / 0.1).clamp(0.0, 1.0);
            DVec3::new(-f.x.signum() * 2.5 * lever, 0.0, 0.0) + drift + spin.cross(*p)
        })
        .collect();
    let obj = ObjectSpec {
        friction: None,
        name: "strip".into(),
        mesh: start,
        kind: ObjectKind::Cloth {
            material: material(),
            rest: Some(flat.positions),
            velocity,
        },
    };
    spec(vec![obj], DVec3::ZERO, 50, 0.1)
}

#[test]
fn folding_onto_itself_conserves_momentum_and_energy() {
    let world = World::build(&folding_strip()).unwrap();
    let mut engine = Engine::new(world, Serial).unwrap();
    let (p0, l0) = engine.momenta();
    let w = &engine.world;
    let (mut scale_p, mut scale_l) = (0.0, 0.0);
    for i in 0..w.x.len() {
        scale_p += w.mass[i] * w.v[i].length();
        scale_l += w.mass[i] * w.x[i].cross(w.v[i]).length();
    }
    let mut rollbacks = 0;
    let mut max_depth = 0;
    let mut energies = Vec::new();
    let mut contact_started = false;
    // Windows in which a penalty layer kicked (with layer prediction on, a
    // contact need not cost a rollback, so rollbacks do not count contacts).
    let mut kicking_windows = 0;
    for _ in 0..120 {
        let s = engine.step_window().unwrap().stats;
        rollbacks += s.rollbacks;
        max_depth = max_depth.max(s.max_depth);
        contact_started |= s.layer_kicks > 0;
        kicking_windows += u32::from(s.layer_kicks > 0);
        // Energy is compared between contacts (no stencil inside a layer at
        // the window end): inside a contact the staggered velocities of the
        // layer clocks make the instantaneous sum oscillate by O(omega h).
        if contact_started && s.contact_energy == 0.0 {
            energies.push(s.kinetic_energy + s.potential_energy);
        }
        let (p, l) = engine.momenta();
        let (ep, el) = ((p - p0).length() / scale_p, (l - l0).length() / scale_l);
        assert!(
            ep < 1e-10,
            "linear momentum drifted by {ep:.2e} (relative) in window {}",
            s.window
        );
        assert!(
            el < 1e-10,
            "angular momentum drifted by {el:.2e} (relative) in window {}",
            s.window
        );
    }
    println!(
        "rollbacks {rollbacks}, windows with kicks {kicking_windows}, max depth {max_depth}, \
         contact-free windows after contact {}",
        energies.len()
    );
    assert!(
        energies.len() >= 20,
        "too few contact-free windows to judge the energy"
    );
    assert!(
        kicking_windows >= 10,
        "the fold must make contact repeatedly: {kicking_windows} windows with kicks"
    );
    assert!(max_depth >= 3, "layer depth {max_depth} < 3");
    let e0 = energies[0];
    let worst = energies
        .iter()
        .map(|e| (e / e0 - 1.0).abs())
        .fold(0.0, f64::max);
    let q = energies.len() / 4;
    let mean = |s: &[f64]| s.iter().sum::<f64>() / s.len() as f64;
    let trend = (mean(&energies[energies.len() - q..]) - mean(&energies[..q])) / e0;
    println!("energy: worst deviation {worst:.3e}, trend {trend:.3e}");
    assert!(
        worst < 0.01,
        "energy deviates by {worst:.3e} after first contact"
    );
    assert!(
        trend.abs() < 0.005,
        "energy trend {trend:.3e} between first and last quarter"
    );
}

/// The slapping strip of [`folding_onto_itself_conserves_momentum_and_energy`]
/// with friction on (and damping, which is momentum preserving too): every
/// friction impulse of a penalty kick sums to zero over its stencil, and the
/// clamp that keeps a batch's summed friction from overshooting scales whole
/// stencil impulses, so linear momentum stays constant to round-off. Angular
/// momentum is not conserved by friction (`acm-spec.md` §3). The frictionless
/// run of the same scene must end elsewhere: friction really acted.
#[test]
fn folding_with_friction_conserves_linear_momentum() {
    let run = |mu: f64| {
        let mut s = folding_strip();
        s.contact.friction = mu;
        let world = World::build(&s).unwrap();
        let mut engine = Engine::new(world, Serial).unwrap();
        let (p0, _) = engine.momenta();
        let w = &engine.world;
        let scale_p: f64 = (0..w.x.len()).map(|i| w.mass[i] * w.v[i].length()).sum();
        let (mut rollbacks, mut kicks) = (0, 0);
        for _ in 0..60 {
            let s = engine.step_window().unwrap().stats;
            rollbacks += s.rollbacks;
            kicks += s.layer_kicks;
            let (p, _) = engine.momenta();
            let ep = (p - p0).length() / scale_p;
            assert!(
                ep < 1e-10,
                "mu = {mu}: linear momentum drifted by {ep:.2e} (relative) in window {}",
                s.window
            );
        }
        println!("mu = {mu}: {rollbacks} rollbacks, {kicks} layer kicks");
        // Layer prediction takes most rollbacks away; the kicks are the contact.
        assert!(kicks > 1000, "the fold must make contact");
        engine.world.v.clone()
    };
    let sliding = run(0.0);
    let gripping = run(0.8);
    let changed = sliding
        .iter()
        .zip(&gripping)
        .filter(|(a, b)| (**a - **b).length() > 1e-3)
        .count();
    assert!(
        changed > sliding.len() / 4,
        "friction changed only {changed} of {} velocities by more than 1 mm/s",
        sliding.len()
    );
}
