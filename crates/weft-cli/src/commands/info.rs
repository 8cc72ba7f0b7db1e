//! `weft info SCENE.toml [--set ...] [--json]`: what a scene builds into —
//! objects, vertices, triangles, hinges, masses, initial strain, the internal
//! and layer steps, and an estimate of the memory a window needs.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use serde::Serialize;
use weft_io::scene::load_scene;
use weft_io::scene::memory::estimated_bytes;

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
}

/// What `weft info` reports.
#[derive(Debug, Serialize)]
pub struct SceneInfo {
    pub scene: String,
    pub objects: Vec<ObjectInfo>,
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
}

/// Builds the scene and collects its figures.
pub fn scene_info(scene: &weft_io::scene::Scene) -> anyhow::Result<SceneInfo> {
    let w = weft_par::build_world(&scene.world)?;
    let objects = w
        .objects
        .iter()
        .map(|o| ObjectInfo {
            name: o.name.clone(),
            kind: if o.is_cloth { "cloth" } else { "obstacle" },
            vertices: o.vertices.len(),
            triangles: o.triangles.len(),
            mass: if o.is_cloth {
                o.vertices.clone().map(|i| w.mass[i as usize]).sum()
            } else {
                0.0
            },
        })
        .collect();
    let max_initial_strain = w
        .internal
        .stretch
        .iter()
        .map(|e| e.max_principal_strain(&e.verts.map(|i| w.x[i as usize])))
        .fold(0.0f64, f64::max);
    let steps = w.lattice.steps_per_window;
    let window = w.lattice.window();
    let end = w.lattice.window_end_at_or_after(scene.end_time);
    Ok(SceneInfo {
        scene: scene.name.clone(),
        objects,
        vertices: w.num_vertices(),
        triangles: w.triangles.len(),
        hinges: w.internal.hinges.len(),
        internal_stencils: w.internal.num_stencils(),
        partitions: w.partitioning.count,
        partition_method: w.partitioning.method.into(),
        cut_edges: w
            .topology
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
    })
}

pub fn run(a: InfoArgs) -> anyhow::Result<ExitCode> {
    let scene = load_scene(&a.scene, &a.overrides)?;
    let i = scene_info(&scene)?;
    if a.json {
        println!("{}", serde_json::to_string(&i)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!("scene {}", i.scene);
    for o in &i.objects {
        println!(
            "  {:<10} {:<8} {:>8} vertices {:>8} triangles  mass {:.4} kg",
            o.name, o.kind, o.vertices, o.triangles, o.mass
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
        "internal step    {:.4e} s (omega_max {:.4e} rad/s), {} steps per window = {:.4e} s, {} windows to the end",
        i.internal_step, i.omega_max, i.steps_per_window, i.window_seconds, i.windows_to_end
    );
    println!(
        "contact          eta_1 {:.3e} m, floor {:.3e} m, k_1 {:.4e} N/m, h_1 {:.4e} s",
        i.contact_thickness, i.separation_floor, i.layer1_stiffness, i.layer1_step
    );
    println!(
        "memory           about {:.1} MB before contact (contacts add breakpoints)",
        i.estimated_bytes as f64 / 1e6
    );
    Ok(ExitCode::SUCCESS)
}
