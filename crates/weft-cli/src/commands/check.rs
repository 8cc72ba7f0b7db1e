//! `weft check FRAME...`: exact triangle–triangle intersection report of frame
//! files (PLY or OBJ); exits non-zero when non-adjacent triangles intersect.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

#[derive(Debug, Args)]
pub struct CheckArgs {
    /// Frame files, or folders whose .ply / .obj files are checked in name order.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
}

/// Expands folders into their frame files, sorted by name.
pub fn frame_files(paths: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut in_dir: Vec<PathBuf> = std::fs::read_dir(p)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| {
                    f.extension().is_some_and(|x| {
                        x.eq_ignore_ascii_case("ply") || x.eq_ignore_ascii_case("obj")
                    })
                })
                .collect();
            in_dir.sort();
            files.extend(in_dir);
        } else {
            files.push(p.clone());
        }
    }
    Ok(files)
}

pub fn run(a: CheckArgs) -> anyhow::Result<ExitCode> {
    let files = frame_files(&a.paths)?;
    if files.is_empty() {
        anyhow::bail!("no frame files found");
    }
    let mut bad = 0usize;
    for f in &files {
        let m = weft_io::read_mesh(f)?.mesh;
        let hits = weft_geom::intersections::mesh_self_intersections(&m.positions, &m.triangles);
        if hits.is_empty() {
            println!("{}: ok ({} triangles)", f.display(), m.num_triangles());
        } else {
            bad += 1;
            let shown: Vec<String> = hits
                .iter()
                .take(5)
                .map(|(a, b)| format!("{a}×{b}"))
                .collect();
            println!(
                "{}: {} intersecting triangle pairs (first: {})",
                f.display(),
                hits.len(),
                shown.join(", ")
            );
        }
    }
    println!("{} frames checked, {} with intersections", files.len(), bad);
    Ok(if bad == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
