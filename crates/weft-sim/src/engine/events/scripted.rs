//! A scripted vertex's polyline of a pass, replayed from its window start.
//!
//! Over ranks each vertex's breakpoints are stored by one rank, and the
//! narrow phase fetches the polylines its tasks read from there. A scripted
//! vertex of zero inverse mass needs no fetch: no kick moves it (an island
//! joins and kicks only dynamic vertices), and at each internal tick it takes
//! its script's chord from its position there ([`super::internal`]'s
//! `new_velocity`), which ignores every impulse. Its polyline therefore
//! follows from its state at the window start and its script alone, and
//! [`scripted_polyline`] computes it with the operations the pass applied, in
//! the same order: the bits its holder stored (tested below against the
//! stored polylines, window by window, rollbacks included). The twister's
//! rod is read by every rank's narrow-phase tasks, and its holder used to
//! send its polylines to each of them every pass.
//!
//! Only a pass that ran to the window end is replayed. One cut short at an
//! internal tick by a non-finite vertex applied that tick's new states to
//! the vertices before it only, so a scripted vertex's last breakpoint there
//! is either its staged position or a drift by no ticks from it, which may
//! differ in the sign of a zero; such a pass fetches as before.

use glam::DVec3;

use super::internal::new_velocity;
use super::tick_at_or_after;
use crate::clock::Tick;
use crate::world::World;

/// Whether vertex `i`'s polyline of a pass that ran to the window end can be
/// computed by [`scripted_polyline`]: it follows a script and no kick moves
/// it.
#[inline]
pub(in crate::engine) fn replayable(w: &World, i: usize) -> bool {
    w.script_of[i].is_some() && w.inv_mass[i] == 0.0
}

/// The breakpoints (times relative to `t0`, positions) of scripted vertex
/// `i` over a pass from `t0` that ran to `t1`, from its state `(x, v, tau)`
/// at `t0` (the window's snapshot): what the pass recorded for it.
///
/// The pass's steps for such a vertex, each mirrored here:
/// * its first breakpoint, the position at the window start
///   (`Trajectories::begin`);
/// * at each internal tick `b` in `[t0, t1)` (none at tick 0, as in the
///   pass, `tick_at_or_after`): its position drifted to `b`,
///   the chord velocity from there; if the velocity changes, the vertex
///   moves to `b` and stages a breakpoint (`apply_internal`), which at the
///   instant of the last one replaces its position (`push_breakpoint`);
/// * the drift to `t1` and a breakpoint there (`drift_to`), by the same
///   rule.
pub(in crate::engine) fn scripted_polyline(
    w: &World,
    i: usize,
    (mut x, mut v, mut tau): (DVec3, DVec3, Tick),
    (t0, t1): (Tick, Tick),
) -> (Vec<f64>, Vec<DVec3>) {
    debug_assert!(
        replayable(w, i),
        "vertex {i} is not a replayable scripted vertex"
    );
    let lattice = &w.lattice;
    let step = lattice.internal_step();
    let h = lattice.h_el();
    let ticks = (t1 - t0).div_ceil(step) as usize;
    let mut times = Vec::with_capacity(ticks + 2);
    let mut points = Vec::with_capacity(ticks + 2);
    times.push(0.0);
    points.push(x);
    let mut push = |t: Tick, p: DVec3| {
        let rel = (t - t0) as f64;
        if times.last() == Some(&rel) {
            *points.last_mut().expect("a first breakpoint") = p;
        } else {
            times.push(rel);
            points.push(p);
        }
    };
    let mut b = tick_at_or_after(t0, step);
    while b < t1 {
        let xt = lattice.drift(x, v, tau, b);
        let v_new = new_velocity(w, i, xt, DVec3::ZERO, lattice.seconds(b), h);
        if v_new != v {
            (x, v, tau) = (xt, v_new, b);
            push(b, xt);
        }
        b += step;
    }
    push(t1, lattice.drift(x, v, tau, t1));
    (times, points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::executor::Serial;
    use crate::kinematics::{Keyframes, Motion};
    use crate::materials::Material;
    use crate::world::{ObjectKind, ObjectSpec, PinSpec, WorldSpec};
    use crate::{ContactConfig, Engine, LimitsConfig, TimeConfig};
    use weft_geom::shapes::grid;

    /// A sheet dropped onto three scripted plates side by side (one
    /// spinning in its plane, one sliding and then stopping, one keyframed),
    /// two of its corners pinned to a script of their own. No layer
    /// prediction: the windows that meet a plate roll back.
    fn scene() -> World {
        let plate = |x: f64| {
            grid(
                DVec3::new(x, 0.0, -0.004),
                DVec3::X,
                DVec3::Y,
                [0.06, 0.06],
                [5, 5],
            )
        };
        let obstacle = |name: &str, x: f64, motion: Motion| ObjectSpec {
            name: name.into(),
            mesh: plate(x),
            kind: ObjectKind::Obstacle { motion },
            friction: None,
        };
        let keyframed = plate(0.1).positions;
        let keyframes = Keyframes {
            frame_rate: 2000.0,
            start: 3.0e-4,
            frames: (0..6)
                .map(|k| {
                    keyframed
                        .iter()
                        .map(|&p| p + DVec3::Z * (0.0015 * k as f64))
                        .collect()
                })
                .collect(),
        };
        let sheet = grid(DVec3::ZERO, DVec3::X, DVec3::Y, [0.26, 0.08], [26, 8]);
        let n = sheet.num_vertices();
        let spec = WorldSpec {
            objects: vec![
                ObjectSpec {
                    name: "sheet".into(),
                    mesh: sheet,
                    kind: ObjectKind::Cloth {
                        material: Material::plate(0.15, 2.0e5, 0.3, 4.0e-4),
                        rest: None,
                        velocity: vec![DVec3::new(0.05, 0.0, -1.0); n],
                    },
                    friction: None,
                },
                obstacle(
                    "spinning",
                    -0.1,
                    Motion::Rotate {
                        center: DVec3::new(-0.1, 0.0, 0.0),
                        axis: DVec3::Z,
                        profile: vec![(0.0, 40.0), (0.002, -25.0)],
                    },
                ),
                obstacle(
                    "sliding",
                    0.0,
                    Motion::Translate {
                        velocity: DVec3::new(0.2, 0.1, 0.0),
                        until: Some(0.001),
                    },
                ),
                obstacle("keyframed", 0.1, Motion::Sequence(keyframes)),
            ],
            pins: vec![PinSpec {
                name: "corners".into(),
                object: 0,
                vertices: vec![0, (n - 1) as u32],
                motion: Motion::Translate {
                    velocity: DVec3::new(0.0, 0.0, -0.8),
                    until: None,
                },
            }],
            gravity: DVec3::new(0.0, 0.0, -9.81),
            contact: ContactConfig {
                thickness: 1e-3,
                predict: false,
                ..Default::default()
            },
            time: TimeConfig {
                internal_step: None,
                beta: 0.3,
                steps_per_window: 8,
            },
            limits: LimitsConfig::default(),
            partitions: 1,
            workers: 1,
        };
        World::build(&spec).expect("a valid scene")
    }

    #[test]
    fn replayed_polylines_are_the_stored_ones_bit_for_bit() {
        let mut engine = Engine::new(scene(), Serial).expect("an engine");
        let scripted: Vec<usize> = (0..engine.world.num_vertices())
            .filter(|&i| replayable(&engine.world, i))
            .collect();
        assert_eq!(scripted.len(), 3 * 25 + 2, "the plates and the pins");
        let bits = |p: &[DVec3]| -> Vec<[u64; 3]> {
            p.iter().map(|q| q.to_array().map(f64::to_bits)).collect()
        };
        let (mut moved, mut rollbacks) = (0, 0);
        for _ in 0..16 {
            let w = &engine.world;
            let start: Vec<_> = (scripted.iter())
                .map(|&i| (w.x[i], w.v[i], w.tau[i]))
                .collect();
            let t0 = w.tick;
            let window = engine.step_window().expect("a window");
            rollbacks += window.stats.rollbacks;
            let t1 = engine.world.tick;
            for (&i, &s) in scripted.iter().zip(&start) {
                let (times, points) = scripted_polyline(&engine.world, i, s, (t0, t1));
                let stored = engine.traj.of(i);
                assert_eq!(times, stored.times, "vertex {i}'s times from {t0}");
                assert_eq!(bits(&points), bits(stored.points), "vertex {i} from {t0}");
                let last = *times.last().expect("a breakpoint");
                assert_eq!(engine.traj.tally(i), (times.len() as u32, last));
                moved += usize::from(times.len() > 2);
            }
        }
        // The scripts moved their vertices, and windows rolled back (their
        // last pass replayed from the same start).
        assert!(moved > 16 * 25, "{moved} polylines with a move");
        assert!(rollbacks > 0, "no window rolled back");
    }
}
