//! The `ribbon` generator of `[[cloth]]`: a strip of given width along a
//! polyline or tied in a knot, resting on its flat strip (see
//! `weft_geom::ribbon` and `weft_geom::knots` for the geometry).
//!
//! ```toml
//! ribbon = { knot = "reef", width = 0.01, across = 3 }                 # a knot
//! ribbon = { points = [[0, 0, 0], [0.1, 0, 0.05]], width = 0.01 }      # a polyline
//! ```

use std::path::Path;

use glam::DVec3;
use serde::Deserialize;
use weft_core::TriMesh;
use weft_geom::knots::{self, KnotError, KnotKind, KnotParams, KnotResolution};
use weft_geom::ribbon::{self as geom, RibbonError};

use super::{invalid, SceneError};

/// `ribbon = { ... }` of a `[[cloth]]`: exactly one of `knot` or `points`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RibbonSection {
    /// A knot tied in the ribbon: "reef" (two ropes) or "bowline".
    #[serde(default)]
    pub knot: Option<String>,
    /// Or the centreline as a polyline (m), resampled by arc length.
    #[serde(default)]
    pub points: Option<Vec<[f64; 3]>>,
    /// Smooth the polyline by a cubic B-spline (the points are its control
    /// points) before resampling.
    #[serde(default)]
    pub smooth: bool,
    /// Width of the strip (m).
    pub width: f64,
    /// Vertices across the strip (at least 2); rows along follow from the
    /// spacing across. Scaled, with the rows, by the scene's `size`.
    #[serde(default = "default_across")]
    pub across: usize,
    /// Knots: the smallest distance required between non-adjacent parts at the
    /// start (m); absent = the scene's `contact.thickness`. Polylines: checked
    /// only when given.
    #[serde(default)]
    pub clearance: Option<f64>,
}

fn default_across() -> usize {
    3
}

/// A generated ribbon cloth: the start mesh and its flat rest strip (same
/// triangles), and the initial strain measured on them.
#[derive(Clone, Debug)]
pub struct RibbonCloth {
    pub mesh: TriMesh,
    pub flat: TriMesh,
    pub max_strain: f64,
}

/// Samples per control-point span of the B-spline of a smoothed polyline.
const SPLINE_SAMPLES: usize = 16;

fn points(r: &RibbonSection) -> Vec<DVec3> {
    let p: Vec<DVec3> = r
        .points
        .iter()
        .flatten()
        .map(|&q| DVec3::from_array(q))
        .collect();
    if r.smooth {
        geom::bspline(&p, SPLINE_SAMPLES)
    } else {
        p
    }
}

/// Vertices the section generates as written (no `size` scaling): what the
/// scene's `size` is measured against. 0 for a section that cannot be built
/// (building it reports why).
pub fn written_vertices(r: &RibbonSection) -> f64 {
    if !(r.width > 0.0 && r.width.is_finite()) || r.across < 2 {
        return 0.0;
    }
    let lengths = match (&r.knot, &r.points) {
        (Some(k), None) => match KnotKind::from_name(k) {
            Some(kind) => knots::rope_lengths(kind, r.width),
            None => return 0.0,
        },
        (None, Some(_)) => vec![geom::polyline_length(&points(r))],
        _ => return 0.0,
    };
    lengths
        .iter()
        .filter(|l| l.is_finite())
        .map(|&l| r.across as f64 * geom::rows_for(l, r.width, r.across) as f64)
        .sum()
}

/// Builds the ribbon of `r` for the cloth `key` of the scene at `path`.
/// `thickness` is the scene's `contact.thickness` (the knots' default
/// clearance); `target` is the vertex count the scene's `size` asks of this
/// ribbon, if any.
pub fn build(
    r: &RibbonSection,
    path: &Path,
    key: &str,
    thickness: f64,
    target: Option<usize>,
) -> Result<RibbonCloth, SceneError> {
    let k = |field: &str| format!("{key}.ribbon.{field}");
    if !(r.width > 0.0 && r.width.is_finite()) {
        return Err(invalid(
            path,
            k("width"),
            format!("must be a positive width in metres (got {})", r.width),
        ));
    }
    if r.across < 2 {
        return Err(invalid(
            path,
            k("across"),
            format!(
                "a strip needs at least 2 vertices across (got {})",
                r.across
            ),
        ));
    }
    if let Some(c) = r.clearance {
        if !(c > 0.0 && c.is_finite()) {
            return Err(invalid(
                path,
                k("clearance"),
                format!("must be a positive distance in metres (got {c})"),
            ));
        }
    }
    match (&r.knot, &r.points) {
        (Some(name), None) => {
            let kind = KnotKind::from_name(name).ok_or_else(|| {
                let known: Vec<&str> = KnotKind::ALL.iter().map(|k| k.name()).collect();
                invalid(
                    path,
                    k("knot"),
                    format!("unknown knot '{name}' (expected {})", known.join(" or ")),
                )
            })?;
            if r.smooth {
                return Err(invalid(
                    path,
                    k("smooth"),
                    "belongs to `points`, not `knot`",
                ));
            }
            let params = KnotParams {
                width: r.width,
                clearance: r.clearance.unwrap_or(thickness),
                resolution: match target {
                    Some(n) => KnotResolution::Vertices(n),
                    None => KnotResolution::Across(r.across),
                },
            };
            let knot = knots::knot(kind, &params).map_err(|e| {
                let field = match &e {
                    KnotError::Width(_) => "width",
                    KnotError::Across(_) => "across",
                    KnotError::Design(_) | KnotError::Ribbon { .. } => "knot",
                    _ => "clearance",
                };
                let hint = if r.clearance.is_none() && field == "clearance" {
                    " (the clearance defaults to contact.thickness)"
                } else {
                    ""
                };
                invalid(path, k(field), format!("{e}{hint}"))
            })?;
            let flat = TriMesh::new(knot.rest, knot.mesh.triangles.clone());
            Ok(RibbonCloth {
                max_strain: knot.max_strain,
                mesh: knot.mesh,
                flat,
            })
        }
        (None, Some(_)) => {
            let p = points(r);
            let length = geom::polyline_length(&p);
            let (across, rows) = match target {
                Some(n) => {
                    let (a, rows) = geom::resolution_for(&[length], r.width, n);
                    (a, rows[0])
                }
                None => (r.across, geom::rows_for(length, r.width, r.across)),
            };
            let rb = geom::ribbon(&p, r.width, across, rows).map_err(|e| {
                let field = match e {
                    RibbonError::Width(_) => "width",
                    RibbonError::Across(_) => "across",
                    _ => "points",
                };
                invalid(path, k(field), e.to_string())
            })?;
            if let Some(c) = r.clearance {
                if let Some(found) = geom::min_clearance(&rb.mesh.positions, &rb.mesh.triangles, c)
                {
                    return Err(invalid(
                        path,
                        k("clearance"),
                        format!(
                            "the strip comes within {:.4e} m of itself (vertices {:?}), closer than the clearance {c:.4e} m",
                            found.distance, found.vertices
                        ),
                    ));
                }
            }
            let flat = TriMesh::new(rb.rest, rb.mesh.triangles.clone());
            Ok(RibbonCloth {
                max_strain: rb.max_strain,
                mesh: rb.mesh,
                flat,
            })
        }
        (Some(_), Some(_)) => Err(invalid(
            path,
            format!("{key}.ribbon"),
            "give `knot` or `points`, not both",
        )),
        (None, None) => Err(invalid(
            path,
            format!("{key}.ribbon"),
            "give a `knot` (\"reef\" or \"bowline\") or the centreline `points`",
        )),
    }
}
