//! The internal step: `omega_max` of the assembled rest system and the damping limit.
//!
//! `omega_max² = λ_max(M^-1 K)` with `K` the Hessian of the assembled stretch + bend
//! energy at the rest shape. It equals `λ_max` of the symmetric `D K D`,
//! `D = M^-1/2`, which [`ElasticModel::max_frequency`] finds by Lanczos iteration (three vectors,
//! no reorthogonalisation; Ritz values approach `λ_max` from below and converge much
//! faster than plain power iteration for the clustered top of a cloth spectrum) with
//! Hessian-vector products by central differences of the assembled gradient.
//! [`ElasticModel::gershgorin_bound`] gives the rigorous upper bound
//! `sqrt(max_row Σ_e Σ_col |K^e| d_i d_j)` from finite-difference element Hessians
//! (typically 5–15 % above `omega_max` on cloth grids); it is the safety check: a
//! Lanczos result that is not finite or lies above it is replaced by it.
//!
//! Every vertex is treated as free: pinning vertices removes rows and columns of
//! `D K D`, which can only lower `λ_max` (Cauchy interlacing), so the result is
//! also a bound for pinned cloth. Vertices of zero mass (in no triangle) are left out.
//!
//! # Damping limit
//!
//! The AVI kick reads damping with the velocities at the start of the batch:
//! `v+ = v - h M^-1 (K x + C v)`, `x+ = x + h v+`. For a mode with `M^-1 K = ω²`,
//! `M^-1 C = γ` the amplification matrix has determinant `1 - hγ` and trace
//! `2 - h²ω² - hγ`; it is stable iff `h γ + h² ω² / 2 <= 2`. [`damping_step_limit`]
//! solves this for `h` with `ω = omega_max` and `γ = gamma_max = λ_max(M^-1 C)`
//! ([`ElasticModel::max_damping_rate`], Lanczos on the exactly linear damping operator). This is
//! exact when `C = alpha K` (`bend_damping = stretch_damping · k_b`, where both
//! operators share their modes); otherwise it pairs the stiffest mode with the most
//! damped one, which is the worst case whenever those coincide (the usual case:
//! both are the shortest-wavelength membrane modes).

use super::ElasticModel;
use glam::DVec3;

/// Most Lanczos steps.
const MAX_LANCZOS_STEPS: usize = 400;
/// Convergence test interval and relative tolerance on the top Ritz value.
const CHECK_EVERY: usize = 10;
const RITZ_TOL: f64 = 1e-9;
/// Finite-difference step relative to the shortest rest edge.
const FD_REL: f64 = 1e-5;

/// `beta · 2 / omega_max` (infinite for `omega_max == 0`).
#[inline]
pub fn stable_step(omega_max: f64, beta: f64) -> f64 {
    if omega_max > 0.0 {
        beta * 2.0 / omega_max
    } else {
        f64::INFINITY
    }
}

/// Largest explicit step stable with stiffness `omega_max` and damping rate
/// `gamma_max` (1/s): the root of `h γ + h² ω²/2 = 2`, i.e.
/// `4 / (γ + sqrt(γ² + 4 ω²))`; `2/omega_max` without damping.
#[inline]
pub fn damping_step_limit(omega_max: f64, gamma_max: f64) -> f64 {
    let den = gamma_max + (gamma_max * gamma_max + 4.0 * omega_max * omega_max).sqrt();
    if den > 0.0 {
        4.0 / den
    } else {
        f64::INFINITY
    }
}

/// `1/sqrt(m)` per vertex, 0 for massless (or non-finite mass) vertices.
fn inv_sqrt_masses(masses: &[f64]) -> Vec<f64> {
    masses
        .iter()
        .map(|&m| {
            if m > 0.0 && m.is_finite() {
                1.0 / m.sqrt()
            } else {
                0.0
            }
        })
        .collect()
}

/// Shortest first rest edge over all elements (the finite-difference length scale).
fn length_scale(rest: &[DVec3], model: &ElasticModel) -> f64 {
    let s = model
        .stretch
        .iter()
        .map(|e| (rest[e.verts[1] as usize] - rest[e.verts[0] as usize]).length());
    let h = model
        .hinges
        .iter()
        .map(|e| (rest[e.verts[1] as usize] - rest[e.verts[0] as usize]).length());
    s.chain(h).fold(f64::INFINITY, f64::min)
}

impl ElasticModel<'_> {
    /// `omega_max = sqrt(λ_max(M^-1 K))` (rad/s) of the assembled rest system
    /// (0 without elements). Use with [`stable_step`].
    pub fn max_frequency(&self, rest: &[DVec3], masses: &[f64]) -> f64 {
        model_max_frequency(rest, masses, self)
    }
    /// `gamma_max = λ_max(M^-1 C)` (1/s) of the damping operator at the rest
    /// shape, for [`damping_step_limit`].
    pub fn max_damping_rate(&self, rest: &[DVec3], masses: &[f64]) -> f64 {
        model_max_damping_rate(rest, masses, self)
    }
    /// Gershgorin upper bound of `omega_max` (rad/s).
    pub fn gershgorin_bound(&self, rest: &[DVec3], masses: &[f64]) -> f64 {
        model_gershgorin_bound(rest, masses, self)
    }
}

fn model_max_frequency(rest: &[DVec3], masses: &[f64], model: &ElasticModel) -> f64 {
    let d = inv_sqrt_masses(masses);
    let ell = length_scale(rest, model);
    if !ell.is_finite() {
        return 0.0;
    }
    let n = rest.len();
    let (mut xp, mut xm) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
    let (mut gp, mut gm) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
    let lambda = lanczos_max(&d, |u, out| {
        // Physical direction D u, scaled so the largest displacement is FD_REL · ell.
        let umax = u
            .iter()
            .zip(&d)
            .fold(0.0f64, |a, (ui, di)| a.max(ui.abs().max_element() * di));
        if umax == 0.0 {
            out.fill(DVec3::ZERO);
            return;
        }
        let s = FD_REL * ell / umax;
        for i in 0..n {
            xp[i] = rest[i] + u[i] * (d[i] * s);
            xm[i] = rest[i] - u[i] * (d[i] * s);
        }
        gp.fill(DVec3::ZERO);
        gm.fill(DVec3::ZERO);
        model.add_gradient(&xp, &mut gp);
        model.add_gradient(&xm, &mut gm);
        for i in 0..n {
            out[i] = (gp[i] - gm[i]) * (d[i] / (2.0 * s));
        }
    });
    // Safety check: Lanczos Ritz values lie below λ_max <= Gershgorin; a value that
    // is not finite or above the bound (finite-difference trouble) is replaced by
    // the bound, which is always safe.
    let bound = model_gershgorin_bound(rest, masses, model);
    if lambda.is_finite() && lambda.max(0.0).sqrt() <= bound * (1.0 + 1e-6) {
        lambda.max(0.0).sqrt()
    } else {
        bound
    }
}

fn model_max_damping_rate(rest: &[DVec3], masses: &[f64], model: &ElasticModel) -> f64 {
    let d = inv_sqrt_masses(masses);
    let n = rest.len();
    let mut v = vec![DVec3::ZERO; n];
    let mut f = vec![DVec3::ZERO; n];
    let gamma = lanczos_max(&d, |u, out| {
        for i in 0..n {
            v[i] = u[i] * d[i];
        }
        f.fill(DVec3::ZERO);
        model.add_damping_force(rest, &v, &mut f);
        for i in 0..n {
            out[i] = f[i] * (-d[i]);
        }
    });
    gamma.max(0.0)
}

/// Central-difference Hessian of one element's gradient, accumulated as absolute
/// row sums `Σ_j |H_ij| d_i d_j` into `rows` (3 per vertex).
fn add_abs_rows<const N: usize>(
    verts: [u32; N],
    rest: &[DVec3],
    d: &[f64],
    rows: &mut [f64],
    grad: impl Fn(&[DVec3; N]) -> [DVec3; N],
) {
    let x0 = verts.map(|i| rest[i as usize]);
    let ell = (x0[1] - x0[0]).length();
    let h = FD_REL * ell;
    for j in 0..N {
        let dj = d[verts[j] as usize];
        for b in 0..3 {
            let (mut xp, mut xm) = (x0, x0);
            xp[j][b] += h;
            xm[j][b] -= h;
            let (gp, gm) = (grad(&xp), grad(&xm));
            for i in 0..N {
                let di = d[verts[i] as usize];
                let col = (gp[i] - gm[i]) * (di * dj / (2.0 * h));
                for a in 0..3 {
                    rows[3 * verts[i] as usize + a] += col[a].abs();
                }
            }
        }
    }
}

/// `sqrt(max_row Σ |D K D|)` with the assembled `K` bounded element by element
/// (finite-difference element Hessians).
fn model_gershgorin_bound(rest: &[DVec3], masses: &[f64], model: &ElasticModel) -> f64 {
    let d = inv_sqrt_masses(masses);
    let mut rows = vec![0.0; 3 * rest.len()];
    for (e, m) in model.stretch_iter() {
        add_abs_rows(e.verts, rest, &d, &mut rows, |x| e.gradient(x, m));
    }
    for (e, m) in model.hinge_iter() {
        let k_b = m.bending_stiffness;
        add_abs_rows(e.verts, rest, &d, &mut rows, |x| e.gradient(x, k_b));
    }
    rows.iter().fold(0.0f64, |a, &r| a.max(r)).sqrt()
}

/// Deterministic start vector component in [-1, 1) (splitmix64 of the index).
fn start_component(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum()
}

/// Largest eigenvalue of the symmetric operator `apply` on vectors supported where
/// `mask != 0`, by Lanczos with a deterministic start vector.
fn lanczos_max(mask: &[f64], mut apply: impl FnMut(&[DVec3], &mut [DVec3])) -> f64 {
    let n = mask.len();
    let mut q: Vec<DVec3> = (0..n)
        .map(|i| {
            let b = 3 * i as u64;
            let v = DVec3::new(
                start_component(b),
                start_component(b + 1),
                start_component(b + 2),
            );
            if mask[i] != 0.0 {
                v
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    let norm = dot(&q, &q).sqrt();
    if norm == 0.0 {
        return 0.0;
    }
    q.iter_mut().for_each(|v| *v /= norm);
    let mut q_prev = vec![DVec3::ZERO; n];
    let mut w = vec![DVec3::ZERO; n];
    let mut alpha: Vec<f64> = Vec::new();
    let mut beta: Vec<f64> = Vec::new();
    let steps = MAX_LANCZOS_STEPS.min(3 * mask.iter().filter(|&&m| m != 0.0).count());
    let mut last = f64::NEG_INFINITY;
    for j in 0..steps {
        apply(&q, &mut w);
        let a = dot(&q, &w);
        let b_prev = beta.last().copied().unwrap_or(0.0);
        for i in 0..n {
            w[i] -= q[i] * a + q_prev[i] * b_prev;
        }
        let b = dot(&w, &w).sqrt();
        alpha.push(a);
        let scale = alpha.iter().fold(0.0f64, |s, x| s.max(x.abs()));
        let breakdown = b.is_nan() || b <= 1e-13 * scale;
        if breakdown || (j + 1) % CHECK_EVERY == 0 || j + 1 == steps {
            let theta = tridiagonal_max(&alpha, &beta);
            if breakdown || theta - last <= RITZ_TOL * theta.abs() || !theta.is_finite() {
                return theta;
            }
            last = theta;
        }
        beta.push(b);
        core::mem::swap(&mut q_prev, &mut q);
        for i in 0..n {
            q[i] = w[i] / b;
        }
    }
    // Only reached when `steps == 0`, which the non-zero start vector excludes.
    last
}

/// Largest eigenvalue of the symmetric tridiagonal matrix with diagonal `alpha` and
/// off-diagonal `beta` (`beta.len() == alpha.len() - 1`), by Sturm-sequence bisection.
fn tridiagonal_max(alpha: &[f64], beta: &[f64]) -> f64 {
    let k = alpha.len();
    let off = |i: usize| {
        (if i > 0 { beta[i - 1].abs() } else { 0.0 })
            + (if i + 1 < k { beta[i].abs() } else { 0.0 })
    };
    let mut lo = (0..k)
        .map(|i| alpha[i] - off(i))
        .fold(f64::INFINITY, f64::min);
    let mut hi = (0..k)
        .map(|i| alpha[i] + off(i))
        .fold(f64::NEG_INFINITY, f64::max);
    // Number of eigenvalues below x.
    let below = |x: f64| {
        let mut count = 0;
        let mut q = 1.0;
        for i in 0..k {
            let b2 = if i > 0 {
                beta[i - 1] * beta[i - 1]
            } else {
                0.0
            };
            q = alpha[i] - x - b2 / q;
            if q == 0.0 {
                q = -f64::EPSILON * (x.abs() + 1e-300);
            }
            if q < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if below(mid) == k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}
