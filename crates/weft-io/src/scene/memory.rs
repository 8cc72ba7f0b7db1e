//! The memory a scene needs, estimated from its element counts, and the
//! refusal of a scene that cannot fit — given before a generator allocates
//! its mesh, so an absurd `size` or resolution is an error naming the key, the
//! counts and the bytes, never an allocation failure.

use std::path::Path;

use weft_sim::trajectory::{BYTES_PER_BREAKPOINT, STAGED_BYTES_PER_VERTEX};

use super::{invalid, SceneError};

/// Bytes of a world's state, internal forces and one window of internal-clock
/// breakpoints: `vertices` vertices, `stretch` stretch elements (cloth
/// triangles) and `hinges` hinges, windows of `steps_per_window` internal
/// steps. Contacts add more (about `W / h_1 · Σ l^1.5` breakpoints per vertex
/// in a contact of depth D). What `weft info` reports.
pub fn estimated_bytes(vertices: u64, stretch: u64, hinges: u64, steps_per_window: u64) -> u64 {
    let e = Estimate::new(vertices, stretch, hinges, steps_per_window);
    u64::try_from(e.mesh + e.trajectories).unwrap_or(u64::MAX)
}

/// [`estimated_bytes`] by term.
struct Estimate {
    /// The state and internal forces: what the mesh needs whatever the window.
    mesh: u128,
    /// One window of internal-clock breakpoints: `vertices ×
    /// (steps_per_window + 2)` of them.
    trajectories: u128,
}

impl Estimate {
    fn new(vertices: u64, stretch: u64, hinges: u64, steps_per_window: u64) -> Self {
        let (n, stretch, hinges) = (vertices as u128, stretch as u128, hinges as u128);
        // x, v and tau (3 f64 each), mass, flags and clock per vertex, and
        // the internal ticks' staged breakpoints.
        let state = n * (3 * 24 + 8 + 16 + STAGED_BYTES_PER_VERTEX as u128);
        // An output slot (a 3-vector) per element corner: 3 per stretch
        // element, 4 per hinge; 48 bytes of rest data per element.
        let forces = (3 * stretch + 4 * hinges) * 24 + (stretch + hinges) * 48;
        let trajectories = n * (steps_per_window as u128 + 2) * BYTES_PER_BREAKPOINT as u128;
        Self {
            mesh: state + forces,
            trajectories,
        }
    }
}

/// `bytes` (saturated to `u64`) as [`human_bytes`] writes it.
fn human_u128(bytes: u128) -> String {
    human_bytes(u64::try_from(bytes).unwrap_or(u64::MAX))
}

/// The most memory a scene may ask for.
#[derive(Clone, Debug)]
pub struct MemoryLimit {
    pub bytes: u64,
    /// What the limit is, for messages ("this machine's physical memory, 16 GB").
    pub what: String,
}

/// Used where the physical memory cannot be read.
const UNKNOWN_MACHINE_CAP: u64 = 1 << 40;

impl MemoryLimit {
    /// This machine's physical memory (`MemTotal` of `/proc/meminfo`), or
    /// 1 TiB where that cannot be read.
    pub fn this_machine() -> Self {
        let total = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|text| {
                let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
                let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
                kib.checked_mul(1024)
            });
        match total {
            Some(bytes) => Self {
                bytes,
                what: format!("this machine's physical memory, {}", human_bytes(bytes)),
            },
            None => Self {
                bytes: UNKNOWN_MACHINE_CAP,
                what: format!(
                    "{} (this machine's memory could not be read)",
                    human_bytes(UNKNOWN_MACHINE_CAP)
                ),
            },
        }
    }
}

/// `bytes` in decimal units, as `weft info` prints memory (`12.3 GB`).
pub fn human_bytes(bytes: u64) -> String {
    let units = ["bytes", "kB", "MB", "GB", "TB", "PB", "EB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1000.0 && unit + 1 < units.len() {
        value /= 1000.0;
        unit += 1;
    }
    match unit {
        0 => format!("{bytes} bytes"),
        _ => format!("{value:.1} {}", units[unit]),
    }
}

/// The objects of a scene admitted so far, against a [`MemoryLimit`].
pub(crate) struct MemoryBudget {
    limit: MemoryLimit,
    steps_per_window: u64,
    vertices: f64,
    stretch: f64,
    hinges: f64,
}

impl MemoryBudget {
    pub(crate) fn new(limit: MemoryLimit, steps_per_window: u64) -> Self {
        Self {
            limit,
            steps_per_window,
            vertices: 0.0,
            stretch: 0.0,
            hinges: 0.0,
        }
    }

    /// Admits an object of `vertices` vertices and `triangles` triangles
    /// (counted in f64, so that absurd counts cannot overflow) that `key`
    /// makes as `source` says ("resolution [10, 10]"), or refuses it when the
    /// scene with it would need more than the limit. A cloth's triangles are
    /// stretch elements, with at most 3/2 hinges each.
    pub(crate) fn admit(
        &mut self,
        path: &Path,
        key: &str,
        source: &str,
        vertices: f64,
        triangles: f64,
        cloth: bool,
    ) -> Result<(), SceneError> {
        let (stretch, hinges) = match cloth {
            true => (triangles, 1.5 * triangles),
            false => (0.0, 0.0),
        };
        // `as u64` saturates: a count beyond u64 is refused all the same.
        let estimate = Estimate::new(
            (self.vertices + vertices) as u64,
            (self.stretch + stretch) as u64,
            (self.hinges + hinges) as u64,
            self.steps_per_window,
        );
        let need = u64::try_from(estimate.mesh + estimate.trajectories).unwrap_or(u64::MAX);
        if need > self.limit.bytes {
            let rest = if self.vertices > 0.0 {
                " with the objects before it"
            } else {
                ""
            };
            let (mesh, window) = (human_u128(estimate.mesh), human_u128(estimate.trajectories));
            let spw = self.steps_per_window;
            // What to lower: the mesh when it alone does not fit; else the
            // window's breakpoints are what push it over.
            let advice = if estimate.mesh > self.limit.bytes as u128 {
                format!("the state and internal forces alone need {mesh}: lower it")
            } else {
                format!(
                    "the state and internal forces need {mesh}, one window's trajectory \
                     breakpoints ({spw} internal steps) {window}: shorten the window \
                     (time.steps_per_window or time.window), or lower it"
                )
            };
            return Err(invalid(
                path,
                key,
                format!(
                    "{source} makes {vertices:.0} vertices and {triangles:.0} triangles: the \
                     run would need at least {} ({need} bytes) of memory{rest} for windows of \
                     {spw} internal steps, more than {}; {advice}",
                    human_bytes(need),
                    self.limit.what
                ),
            ));
        }
        self.vertices += vertices;
        self.stretch += stretch;
        self.hinges += hinges;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_read_as_people_write_them() {
        assert_eq!(human_bytes(999), "999 bytes");
        assert_eq!(human_bytes(12_345_678), "12.3 MB");
        assert_eq!(human_bytes(40_000_000_000_000), "40.0 TB");
    }

    #[test]
    fn a_budget_counts_every_object_admitted() {
        let limit = MemoryLimit {
            bytes: estimated_bytes(1000, 0, 0, 100),
            what: "the test limit".into(),
        };
        let mut b = MemoryBudget::new(limit, 100);
        let p = Path::new("s.toml");
        b.admit(p, "a", "a", 600.0, 0.0, false).unwrap();
        let e = b.admit(p, "b", "b's resolution", 600.0, 0.0, false);
        let e = e.unwrap_err().to_string();
        assert!(
            e.contains("s.toml: b: b's resolution makes 600 vertices")
                && e.contains("with the objects before it")
                && e.contains("more than the test limit"),
            "{e}"
        );
        b.admit(p, "c", "c", 400.0, 0.0, false).unwrap();
    }

    /// The refusal says which term to lower: the mesh when it alone does not
    /// fit, else the window whose breakpoints push it over.
    #[test]
    fn a_refusal_names_the_term_that_does_not_fit() {
        let p = Path::new("s.toml");
        let limit = MemoryLimit {
            bytes: estimated_bytes(1000, 2000, 3000, 100),
            what: "the test limit".into(),
        };
        // Too many vertices even for one-step windows.
        let e = MemoryBudget::new(limit.clone(), 1)
            .admit(p, "k", "k", 1e6, 2e6, true)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the state and internal forces alone need") && e.ends_with("lower it"),
            "{e}"
        );
        assert!(!e.contains("steps_per_window"), "{e}");
        // The same mesh fits with windows of 100 steps, not of 10^6.
        MemoryBudget::new(limit.clone(), 100)
            .admit(p, "k", "k", 1000.0, 2000.0, true)
            .unwrap();
        let e = MemoryBudget::new(limit, 1_000_000)
            .admit(p, "k", "k", 1000.0, 2000.0, true)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("one window's trajectory breakpoints (1000000 internal steps) 39.0 GB")
                && e.contains("shorten the window (time.steps_per_window or time.window)"),
            "{e}"
        );
    }
}
