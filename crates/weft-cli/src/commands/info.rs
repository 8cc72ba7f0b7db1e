//! `weft info SCENE.toml [--set ...] [--json]`: what a scene builds into —
//! objects (with their bounding boxes, edge lengths and smallest altitudes),
//! pins, vertices, triangles, hinges, masses, initial strain, the internal and
//! layer steps, an estimate of the memory a window needs, the start-up
//! warnings, and whether `weft run` would start: the engine's own check of the
//! start state (contact closer than the separation floor, intersections),
//! with a non-zero exit status when it would refuse.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use serde::Serialize;
use weft_core::mesh::bounding_box;
use weft_io::scene::load_scene;
use weft_io::scene::memory::estimated_bytes;
use weft_sim::world::min_altitude;
use weft_sim::{Engine, Serial, World};

use super::startup;

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// Override a scene value: `--set key.path=value` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One object of the scene.
#[derive(Debug, Serialize)]
pub struct ObjectInfo {
    pub name: String,
    pub kind: &'static str,
    pub vertices: usize,
    pub triangles: usize,
    /// Total mass (kg); 0 for obstacles (kinematic).
    pub mass: f64,
    /// Smallest and largest start coordinates (m), `[min, max]`.
    pub bounding_box: [[f64; 3]; 2],
    /// Shortest and longest triangle edge (m), `[min, max]`.
    pub edge_length: [f64; 2],
    /// Smallest triangle altitude (m); for a cloth, twice the largest
    /// contact thickness it allows.
    pub min_altitude: f64,
}

/// One pin of the scene.
#[derive(Debug, Serialize)]
pub struct PinInfo {
    pub name: String,
    pub object: String,
    /// How many of the object's vertices it holds.
    pub vertices: usize,
}

/// What `weft info` reports.
#[derive(Debug, Serialize)]
pub struct SceneInfo {
    pub scene: String,
    pub objects: Vec<ObjectInfo>,
    pub pins: Vec<PinInfo>,
    pub vertices: usize,
    pub triangles: usize,
    pub hinges: usize,
    pub internal_stencils: usize,
    /// Partitions of the cloth triangles and how they were made.
    pub partitions: usize,
    pub partition_method: String,
    /// Interior edges whose two triangles lie in different partitions.
    pub cut_edges: usize,
    /// Largest |principal Green strain| of the start shape against the rest shape.
    pub max_initial_strain: f64,
    pub omega_max: f64,
    pub internal_step: f64,
    pub steps_per_window: u64,
    pub window_seconds: f64,
    pub windows_to_end: u64,
    pub contact_thickness: f64,
    pub separation_floor: f64,
    pub layer1_stiffness: f64,
    pub layer1_step: f64,
    /// Bytes for state, forces and one window of internal-clock breakpoints
    /// (see [`estimated_bytes`]; contacts add more).
    pub estimated_bytes: u64,
    /// What `weft run` warns about at start-up.
    pub warnings: Vec<String>,
    /// Why `weft run` would refuse the start state (the engine's own check:
    /// contact closer than the separation floor, intersecting triangles), or
    /// `None` when it would start.
    pub start_refused: Option<String>,
}

/// An object's figures.
fn object_info(w: &World, o: &weft_sim::world::ObjectInfo) -> ObjectInfo {
    let (lo, hi) = bounding_box(&w.x[o.vertices.start as usize..o.vertices.end as usize]);
    let mut edge_length = [f64::INFINITY, 0.0f64];
    let mut altitude = f64::INFINITY;
    for t in o.triangles.clone() {
        let p = w.triangles[t as usize].map(|i| w.x[i as usize]);
        for k in 0..3 {
            let e = (p[(k + 1) % 3] - p[k]).length();
            edge_length = [edge_length[0].min(e), edge_length[1].max(e)];
        }
        altitude = altitude.min(min_altitude(p));
    }
    ObjectInfo {
        name: o.name.clone(),
        kind: if o.is_cloth { "cloth" } else { "obstacle" },
        vertices: o.vertices.len(),
        triangles: o.triangles.len(),
        mass: if o.is_cloth {
            o.vertices.clone().map(|i| w.mass[i as usize]).sum()
        } else {
            0.0
        },
        bounding_box: [lo.to_array(), hi.to_array()],
        edge_length,
        min_altitude: altitude,
    }
}

/// Builds the scene, collects its figures and runs the engine's start-state
/// check on it.
pub fn scene_info(scene: &weft_io::scene::Scene) -> anyhow::Result<SceneInfo> {
    // The internal step's estimate, most of the build, on every core.
    let pool = weft_par::Threads::new(0).context("cannot start the worker threads")?;
    let w = pool.install(|| weft_par::build_world_on(&scene.world, &pool))?;
    let objects = w.objects.iter().map(|o| object_info(&w, o)).collect();
    let pins = scene
        .world
        .pins
        .iter()
        .map(|p| PinInfo {
            name: p.name.clone(),
            object: scene.world.objects[p.object].name.clone(),
            vertices: p.vertices.len(),
        })
        .collect();
    let warnings = startup::warnings(scene, &w);
    let max_initial_strain = w
        .internal
        .stretch
        .iter()
        .map(|e| e.max_principal_strain(&e.verts.map(|i| w.x[i as usize])))
        .fold(0.0f64, f64::max);
    // A built world keeps only the faces around each vertex: the edges'
    // faces are derived again for the cut.
    let topology = weft_core::Topology::build(w.num_vertices(), &w.triangles)?;
    let steps = w.lattice.steps_per_window;
    let window = w.lattice.window();
    let end = w.lattice.window_end_at_or_after(scene.end_time);
    let mut info = SceneInfo {
        scene: scene.name.clone(),
        objects,
        pins,
        vertices: w.num_vertices(),
        triangles: w.triangles.len(),
        hinges: w.internal.hinges.len(),
        internal_stencils: w.internal.num_stencils(),
        partitions: w.partitioning.count,
        partition_method: w.partitioning.method.into(),
        cut_edges: topology
            .edge_faces
            .iter()
            .filter(|&&[a, b]| {
                let p = &w.partitioning.of_triangle;
                b != weft_core::NONE
                    && p[a as usize] != weft_core::NONE
                    && p[b as usize] != p[a as usize]
            })
            .count(),
        max_initial_strain,
        omega_max: w.omega_max,
        internal_step: w.lattice.h_el(),
        steps_per_window: steps,
        window_seconds: w.lattice.seconds(window),
        windows_to_end: end / window,
        contact_thickness: w.schedule.eta_1,
        separation_floor: w.schedule.eta_inf,
        layer1_stiffness: w.schedule.k_1,
        layer1_step: w.lattice.seconds(w.schedule.h_1),
        estimated_bytes: estimated_bytes(
            w.num_vertices() as u64,
            w.internal.stretch.len() as u64,
            w.internal.hinges.len() as u64,
            steps,
        ),
        warnings,
        start_refused: None,
    };
    // The check `weft run` makes before its first window (Engine::new).
    info.start_refused = Engine::new(w, Serial).err().map(|e| e.to_string());
    Ok(info)
}

pub fn run(a: InfoArgs) -> anyhow::Result<ExitCode> {
    let scene = load_scene(&a.scene, &a.overrides)?;
    let i = scene_info(&scene)?;
    startup::print(&i.warnings);
    // `weft run` would refuse: the same status as its error.
    let status = match &i.start_refused {
        None => ExitCode::SUCCESS,
        Some(_) => ExitCode::from(1),
    };
    if a.json {
        println!("{}", serde_json::to_string(&i)?);
        return Ok(status);
    }
    print_text(&i);
    Ok(status)
}

fn print_text(i: &SceneInfo) {
    let v = |a: [f64; 3]| format!("({:.4}, {:.4}, {:.4})", a[0], a[1], a[2]);
    println!("scene {}", i.scene);
    for o in &i.objects {
        println!(
            "  {:<10} {:<8} {:>8} vertices {:>8} triangles  mass {:.4} kg",
            o.name, o.kind, o.vertices, o.triangles, o.mass
        );
        println!(
            "  {:<10} box {} to {} m, edges {:.3e} to {:.3e} m, smallest altitude {:.3e} m",
            "",
            v(o.bounding_box[0]),
            v(o.bounding_box[1]),
            o.edge_length[0],
            o.edge_length[1],
            o.min_altitude
        );
    }
    for p in &i.pins {
        println!(
            "  pin {:<10} holds {} vertices of '{}'",
            p.name, p.vertices, p.object
        );
    }
    println!(
        "total        {} vertices, {} triangles, {} hinges, {} internal stencils",
        i.vertices, i.triangles, i.hinges, i.internal_stencils
    );
    println!(
        "partitions       {} ({}), {} interior edges cut",
        i.partitions, i.partition_method, i.cut_edges
    );
    println!(
        "initial strain   max |principal Green strain| {:.3e}",
        i.max_initial_strain
    );
    println!(
        "internal step    {:.4e} s (highest natural frequency {:.4e} rad/s), {} steps per window = {:.4e} s, {} windows to the end",
        i.internal_step, i.omega_max, i.steps_per_window, i.window_seconds, i.windows_to_end
    );
    println!(
        "contact          thickness {:.3e} m, separation floor {:.3e} m, layer-1 stiffness {:.4e} N/m and step {:.4e} s",
        i.contact_thickness, i.separation_floor, i.layer1_stiffness, i.layer1_step
    );
    println!(
        "memory           about {:.1} MB before contact (contacts add breakpoints)",
        i.estimated_bytes as f64 / 1e6
    );
    match &i.start_refused {
        None => println!(
            "start state      ok: nothing closer than the separation floor, no intersection"
        ),
        Some(e) => println!("start state      weft run would refuse it: {e}"),
    }
}
