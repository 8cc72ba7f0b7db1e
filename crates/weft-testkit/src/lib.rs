//! # weft-testkit — shared test helpers (not published)
//!
//! One finite-difference gradient checker for every energy in weft, so that all
//! gradient tests measure the same thing the same way, and one small seeded
//! random generator for randomized tests.

use glam::DVec3;

/// Result of a finite-difference gradient check.
#[derive(Clone, Copy, Debug)]
pub struct FdReport {
    /// max over components of |analytic - fd| / max(|fd|, |analytic|, scale).
    pub max_rel_error: f64,
    /// the component (vertex, axis) where it occurred.
    pub worst: (usize, usize),
}

/// Compares `grad` (dE/dx at `x`) with central differences of `energy` with
/// step `h`. Errors are relative to `max(|fd|, |analytic|, scale)`, where `scale`
/// is the typical gradient magnitude (the largest analytic component), so
/// components that are zero up to round-off do not blow the ratio up.
pub fn check_gradient(
    energy: impl Fn(&[DVec3]) -> f64,
    x: &[DVec3],
    grad: &[DVec3],
    h: f64,
) -> FdReport {
    assert_eq!(x.len(), grad.len(), "gradient length differs from x");
    let scale = grad
        .iter()
        .flat_map(|g| g.to_array())
        .fold(0.0f64, |m, c| m.max(c.abs()))
        .max(f64::MIN_POSITIVE);
    let mut y = x.to_vec();
    let mut report = FdReport {
        max_rel_error: 0.0,
        worst: (0, 0),
    };
    for i in 0..x.len() {
        for a in 0..3 {
            let orig = y[i][a];
            y[i][a] = orig + h;
            let ep = energy(&y);
            y[i][a] = orig - h;
            let em = energy(&y);
            y[i][a] = orig;
            let fd = (ep - em) / (2.0 * h);
            let an = grad[i][a];
            let err = (an - fd).abs() / fd.abs().max(an.abs()).max(1e-3 * scale);
            if err > report.max_rel_error {
                report.max_rel_error = err;
                report.worst = (i, a);
            }
        }
    }
    report
}

/// Asserts that `grad` matches central differences within `tol` (relative).
#[track_caller]
pub fn assert_gradient(
    energy: impl Fn(&[DVec3]) -> f64,
    x: &[DVec3],
    grad: &[DVec3],
    h: f64,
    tol: f64,
) {
    let r = check_gradient(energy, x, grad, h);
    assert!(
        r.max_rel_error <= tol,
        "gradient differs from finite differences: rel. error {:.3e} > {tol:.1e} at vertex {} axis {}\n x = {x:?}\n grad = {grad:?}",
        r.max_rel_error,
        r.worst.0,
        r.worst.1
    );
}

/// Deterministic splitmix64 generator for randomized tests (seeded, so a
/// failing case reproduces).
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// A vector with components uniform in `[-r, r)`.
    pub fn vec(&mut self, r: f64) -> DVec3 {
        DVec3::new(
            self.uniform(-r, r),
            self.uniform(-r, r),
            self.uniform(-r, r),
        )
    }

    /// Uniform in `0..n`.
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detects_a_wrong_gradient() {
        let e = |x: &[DVec3]| x[0].length_squared() * 0.5;
        let x = [DVec3::new(1.0, -2.0, 0.5)];
        assert_gradient(e, &x, &x, 1e-6, 1e-8);
        let wrong = [x[0] * 1.01];
        assert!(check_gradient(e, &x, &wrong, 1e-6).max_rel_error > 1e-3);
    }
}
