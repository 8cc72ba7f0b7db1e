//! Single-core throughput of the internal-force stage: stretch and bend
//! stencil evaluations per second, including the per-vertex ordered fold.
//!
//! `cargo bench -p weft-sim --bench internal`

use std::time::Instant;

use glam::DVec3;
use weft_geom::shapes::grid;
use weft_sim::materials::Material;
use weft_sim::{
    ContactConfig, LimitsConfig, ObjectKind, ObjectSpec, Serial, TimeConfig, World, WorldSpec,
};

fn main() {
    let n = 200;
    let flat = grid(DVec3::ZERO, DVec3::X, DVec3::Z, [1.0, 1.0], [n, n]);
    let mut start = flat.clone();
    for (k, p) in start.positions.iter_mut().enumerate() {
        p.y = 0.01 * ((k % n) as f64 * 0.3).sin() * ((k / n) as f64 * 0.2).cos();
    }
    let material = Material::plate(0.2, 1e5, 0.3, 1e-3);
    let spec = WorldSpec {
        objects: vec![ObjectSpec {
            friction: None,
            name: "cloth".into(),
            mesh: start,
            kind: ObjectKind::Cloth {
                material,
                rest: Some(flat.positions),
                velocity: vec![],
            },
        }],
        pins: vec![],
        gravity: DVec3::ZERO,
        contact: ContactConfig::default(),
        time: TimeConfig {
            internal_step: Some(1e-4),
            ..Default::default()
        },
        limits: LimitsConfig::default(),
        partitions: 1,
        workers: 1,
    };
    let world = World::build(&spec).expect("world");
    let f = &world.internal;
    let bounds = f.slot_bounds();
    let mut out = vec![DVec3::ZERO; f.num_slots()];
    let mut sum = DVec3::ZERO;
    let reps = 50;
    let (mut best, mut best_eval, mut best_fold) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    for _ in 0..5 {
        let (mut eval, mut fold) = (0.0, 0.0);
        for _ in 0..reps {
            let t = Instant::now();
            f.evaluate(&Serial, &bounds, &world.x, &world.v, &mut out, None);
            let between = Instant::now();
            for i in 0..world.x.len() {
                sum += f.fold(i, &out);
            }
            eval += (between - t).as_secs_f64();
            fold += between.elapsed().as_secs_f64();
        }
        best = best.min(eval + fold);
        best_eval = best_eval.min(eval);
        best_fold = best_fold.min(fold);
    }
    let evals = (f.num_stencils() * reps) as f64;
    println!(
        "internal forces: {} vertices, {} stencils ({} stretch, {} hinges)",
        world.x.len(),
        f.num_stencils(),
        f.stretch.len(),
        f.hinges.len()
    );
    println!(
        "{:.2} M stencil evaluations per core-second (evaluate + ordered fold, best of 5; checksum {:.3e})",
        evals / best / 1e6,
        sum.length()
    );
    println!(
        "per repetition: evaluate {:.3} ms, fold {:.3} ms (best of 5 each)",
        best_eval / reps as f64 * 1e3,
        best_fold / reps as f64 * 1e3
    );
}
