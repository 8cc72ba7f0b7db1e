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
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let t = Instant::now();
        for _ in 0..reps {
            f.evaluate(&Serial, &bounds, &world.x, &world.v, &mut out, None);
            for i in 0..world.x.len() {
                sum += f.fold(i, &out);
            }
        }
        best = best.min(t.elapsed().as_secs_f64());
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
}
