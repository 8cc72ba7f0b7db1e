//! Start-up warnings: what a scene builds into that can be simulated but is
//! probably not what its author meant. `weft run` prints them once, on rank 0
//! and not with `--quiet`, before the engine starts; `weft info` prints them
//! too and lists them in its JSON.

use std::ops::RangeInclusive;

use weft_core::mesh::bounding_box;
use weft_io::scene::Scene;
use weft_sim::world::min_altitude;
use weft_sim::World;

/// Cloth sizes (bounding-box diagonal, m) outside this range are probably
/// modelled in other units: a garment, a flag or a ribbon is millimetres to
/// metres across.
pub const PLAUSIBLE_CLOTH_SIZE: RangeInclusive<f64> = 5e-3..=5.0;

/// The warnings for `scene`, whose world is `world`: what loading noted
/// (mesh warnings), a clamped contact thickness, implausible cloth sizes.
pub fn warnings(scene: &Scene, world: &World) -> Vec<String> {
    let mut out = scene.warnings.clone();
    out.extend(clamped_thickness(scene, world));
    for o in world.objects.iter().filter(|o| o.is_cloth) {
        let (lo, hi) = bounding_box(&world.x[o.vertices.start as usize..o.vertices.end as usize]);
        let size = (hi - lo).length();
        if !PLAUSIBLE_CLOTH_SIZE.contains(&size) {
            out.push(format!(
                "cloth '{}' is {size:.3e} m across (its bounding-box diagonal), implausibly {} \
                 for a cloth: weft's units are metres; if the mesh was modelled in other units, \
                 rescale it with transform.scale (0.01 for centimetres, 0.001 for millimetres)",
                o.name,
                if size > *PLAUSIBLE_CLOTH_SIZE.end() {
                    "large"
                } else {
                    "small"
                }
            ));
        }
    }
    out
}

/// The world clamps `contact.thickness` to half the smallest altitude of a
/// cloth triangle (a thicker layer would reach across a triangle).
fn clamped_thickness(scene: &Scene, world: &World) -> Option<String> {
    let asked = scene.world.contact.thickness;
    let used = world.schedule.eta_1;
    if used >= asked {
        return None;
    }
    let thinnest = world
        .objects
        .iter()
        .filter(|o| o.is_cloth)
        .flat_map(|o| o.triangles.clone().map(move |t| (o, t)))
        .map(|(o, t)| {
            let corners = world.triangles[t as usize].map(|i| world.x[i as usize]);
            (min_altitude(corners), o, t - o.triangles.start)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0));
    let place = thinnest.map_or(String::new(), |(altitude, o, t)| {
        format!(
            " (the thinnest is triangle {t} of cloth '{}', 0-based, {altitude:.3e} m high)",
            o.name
        )
    });
    Some(format!(
        "contact.thickness = {asked:.3e} m is more than half the smallest altitude of a cloth \
         triangle{place}; using {used:.3e} m. To keep {asked:.3e} m, remesh the cloth without \
         triangles thinner than {:.3e} m",
        2.0 * asked
    ))
}

/// Prints `warnings` to standard error, one line each.
pub fn print(warnings: &[String]) {
    for w in warnings {
        eprintln!("weft: warning: {w}");
    }
}
