//! The internal step: `omega_max` of the assembled rest system and the damping limit.
//!
//! `omega_max² = λ_max(M^-1 K)` with `K` the Hessian of the assembled stretch + bend
//! energy at the rest shape. It equals `λ_max` of the symmetric `D K D`,
//! `D = M^-1/2`, which [`ElasticModel::max_frequency`] finds by Lanczos iteration (three vectors,
//! no reorthogonalisation; Ritz values approach `λ_max` from below and converge much
//! faster than plain power iteration for the clustered top of a cloth spectrum) with
//! Hessian-vector products by central differences of the assembled gradient.
//! On an executor with threads or ranks, each product is assembled range by
//! range of vertices (`VertexRanges`) with the serial assembly's bits, one
//! range per thread of every rank; over ranks each rank assembles its block
//! of ranges and the blocks are all-gathered (`ranges_on_ranks`).
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

use super::assembly::gather;
use super::{ElasticModel, HingeElement, Material, StretchElement};
use crate::executor::{place_in_blocks, CommError, Executor, Serial};
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
        (self.max_frequency_on(&Serial, rest, masses)).expect("one memory has no peer")
    }
    /// [`ElasticModel::max_frequency`] with the assembly spread over
    /// `exec`'s ranks and threads (the same bits on any number).
    /// **Collective over ranks**: every rank calls it with the same model.
    pub fn max_frequency_on<E: Executor>(
        &self,
        exec: &E,
        rest: &[DVec3],
        masses: &[f64],
    ) -> Result<f64, CommError> {
        model_max_frequency(exec, rest, masses, self)
    }
    /// `gamma_max = λ_max(M^-1 C)` (1/s) of the damping operator at the rest
    /// shape, for [`damping_step_limit`].
    pub fn max_damping_rate(&self, rest: &[DVec3], masses: &[f64]) -> f64 {
        (self.max_damping_rate_on(&Serial, rest, masses)).expect("one memory has no peer")
    }
    /// [`ElasticModel::max_damping_rate`] spread over `exec`'s ranks and
    /// threads (the same bits). **Collective over ranks.**
    pub fn max_damping_rate_on<E: Executor>(
        &self,
        exec: &E,
        rest: &[DVec3],
        masses: &[f64],
    ) -> Result<f64, CommError> {
        model_max_damping_rate(exec, rest, masses, self)
    }
    /// Gershgorin upper bound of `omega_max` (rad/s).
    pub fn gershgorin_bound(&self, rest: &[DVec3], masses: &[f64]) -> f64 {
        let ranges = VertexRanges::new(self, rest.len(), 1);
        (model_gershgorin_bound(&Serial, &ranges, rest, masses, self))
            .expect("one memory has no peer")
    }
}

/// Contiguous ranges of vertices, one task each, with the elements that
/// touch each range, in element order (stretch elements, then hinges).
///
/// The serial assembly (`ElasticModel::add_gradient`) adds each vertex's
/// contributions in element order, the stretch elements first. A range's
/// task walks its elements in that same order and adds only to its own
/// vertices, so every vertex gets the same additions in the same order:
/// the same bits on any number of ranges. An element on the border of two
/// ranges is evaluated once in each.
struct VertexRanges {
    /// `bounds[k]..bounds[k + 1]` is range `k`'s vertices.
    bounds: Vec<usize>,
    stretch: Vec<Vec<u32>>,
    hinges: Vec<Vec<u32>>,
}

impl VertexRanges {
    /// At most `tasks` ranges of `n` vertices, cut where the element corners
    /// (the work) are shared about equally.
    fn new(model: &ElasticModel, n: usize, tasks: usize) -> Self {
        let corners = (model.stretch.iter().map(|e| &e.verts[..]))
            .chain(model.hinges.iter().map(|e| &e.verts[..]));
        let mut weight = vec![0u64; n];
        for verts in corners {
            for &v in verts {
                weight[v as usize] += 1;
            }
        }
        let total: u64 = weight.iter().sum();
        let tasks = tasks.clamp(1, n.max(1)) as u64;
        let mut bounds = vec![0];
        let mut done = 0u64;
        for (v, &w) in weight.iter().enumerate() {
            done += w;
            let cut = bounds.len() as u64;
            if cut < tasks && done * tasks >= total * cut && v + 1 < n {
                bounds.push(v + 1);
            }
        }
        bounds.push(n);
        let range_of = |v: u32| bounds.partition_point(|&b| b <= v as usize) - 1;
        let mut stretch = vec![Vec::new(); bounds.len() - 1];
        let mut hinges = vec![Vec::new(); bounds.len() - 1];
        let list = |lists: &mut Vec<Vec<u32>>, j: usize, verts: &[u32]| {
            let mut seen = [usize::MAX; 4];
            for (c, &v) in verts.iter().enumerate() {
                let k = range_of(v);
                if !seen[..c].contains(&k) {
                    lists[k].push(j as u32);
                }
                seen[c] = k;
            }
        };
        for (j, (e, _)) in model.stretch_iter().enumerate() {
            list(&mut stretch, j, &e.verts);
        }
        for (j, (e, _)) in model.hinge_iter().enumerate() {
            list(&mut hinges, j, &e.verts);
        }
        Self {
            bounds,
            stretch,
            hinges,
        }
    }

    /// Range `k`'s stretch elements and its hinges, each with its material,
    /// in element order.
    fn elements<'s, 'm: 's>(
        &'s self,
        k: usize,
        model: &ElasticModel<'m>,
    ) -> (
        impl Iterator<Item = (&'m StretchElement, &'m Material)> + 's,
        impl Iterator<Item = (&'m HingeElement, &'m Material)> + 's,
    ) {
        let model = *model;
        let s = (self.stretch[k].iter()).map(move |&j| model.stretch_at(j as usize));
        let h = (self.hinges[k].iter()).map(move |&j| model.hinge_at(j as usize));
        (s, h)
    }

    /// `out += f(element)` per corner, range by range, each range adding to
    /// its own vertices only (see the type's doc: the serial bits).
    fn assemble<E: Executor>(
        &self,
        exec: &E,
        model: &ElasticModel,
        out: &mut [DVec3],
        stretch: impl Fn(&StretchElement, &Material) -> [DVec3; 3] + Sync,
        hinge: impl Fn(&HingeElement, &Material) -> [DVec3; 4] + Sync,
    ) -> Result<(), CommError> {
        ranges_on_ranks(exec, out, &self.bounds, &|k, own| {
            self.add_range(k, model, own, &stretch, &hinge)
        })
    }

    /// Range `k`'s part of `out += f(element)` per corner: `own` holds the
    /// range's vertices.
    fn add_range(
        &self,
        k: usize,
        model: &ElasticModel,
        own: &mut [DVec3],
        stretch: impl Fn(&StretchElement, &Material) -> [DVec3; 3],
        hinge: impl Fn(&HingeElement, &Material) -> [DVec3; 4],
    ) {
        let start = self.bounds[k];
        let mut add = |v: u32, g: DVec3| {
            if let Some(o) = (v as usize).checked_sub(start).and_then(|j| own.get_mut(j)) {
                *o += g;
            }
        };
        let (s, h) = self.elements(k, model);
        for (e, m) in s {
            let g = stretch(e, m);
            for c in 0..3 {
                add(e.verts[c], g[c]);
            }
        }
        for (e, m) in h {
            let g = hinge(e, m);
            for c in 0..4 {
                add(e.verts[c], g[c]);
            }
        }
    }

    /// `out[i] = (g(xp)_i − g(xm)_i) · scale[i]` with `g` the assembled
    /// gradient: a Hessian-vector product by central differences. Each range
    /// assembles both gradients of its own vertices and writes its part of
    /// `out`, so ranks gather `out` only: one all-gather a product.
    fn gradient_difference<E: Executor>(
        &self,
        exec: &E,
        model: &ElasticModel,
        (xp, xm): (&[DVec3], &[DVec3]),
        scale: &[f64],
        out: &mut [DVec3],
    ) -> Result<(), CommError> {
        ranges_on_ranks(exec, out, &self.bounds, &|k, own| {
            let (mut gp, mut gm) = (vec![DVec3::ZERO; own.len()], vec![DVec3::ZERO; own.len()]);
            for (x, g) in [(xp, &mut gp), (xm, &mut gm)] {
                self.add_range(
                    k,
                    model,
                    g,
                    |e, m| e.gradient(&gather(x, e.verts), m),
                    |e, m| e.gradient(&gather(x, e.verts), m.bending_stiffness),
                );
            }
            let scale = &scale[self.bounds[k]..];
            for (j, o) in own.iter_mut().enumerate() {
                *o = (gp[j] - gm[j]) * scale[j];
            }
        })
    }

    /// [`ElasticModel::add_damping_force`], range by range (one range:
    /// that function itself).
    fn add_damping_force<E: Executor>(
        &self,
        exec: &E,
        model: &ElasticModel,
        x: &[DVec3],
        v: &[DVec3],
        force: &mut [DVec3],
    ) -> Result<(), CommError> {
        if self.bounds.len() <= 2 {
            model.add_damping_force(x, v, force);
            return Ok(());
        }
        self.assemble(
            exec,
            model,
            force,
            |e, m| e.damping_force(&gather(x, e.verts), &gather(v, e.verts), m),
            |e, m| e.damping_force(&gather(x, e.verts), &gather(v, e.verts), m),
        )
    }
}

/// `task` on chunk `k` of `data` (cut at `bounds`), on the rank that holds
/// it and there on its threads; then every rank holds every chunk, as
/// [`Executor::for_each_chunk`] leaves them on one memory. Ranks hold
/// contiguous blocks of chunks ([`place_in_blocks`]: the ranges are cut
/// where the work is shared equally), and each rank's block is
/// all-gathered with its exact bits. Every rank must start from the same
/// `data` and `bounds`. **Collective over ranks.**
///
/// Why: every rank builds the world, and the step's two Lanczos estimates
/// were most of a run's start, the same on every rank (measured at 50k over
/// 32 ranks: about 20 s of CPU each, against 1.1 s for a window).
fn ranges_on_ranks<E: Executor>(
    exec: &E,
    data: &mut [DVec3],
    bounds: &[usize],
    task: &(dyn Fn(usize, &mut [DVec3]) + Sync),
) -> Result<(), CommError> {
    let ranks = exec.ranks();
    if ranks < 2 {
        exec.for_each_chunk(data, bounds, task);
        return Ok(());
    }
    let owner = place_in_blocks(bounds.len() - 1, ranks);
    let me = exec.rank() as u32;
    exec.for_each_chunk(data, bounds, &|k, own| {
        if owner[k] == me {
            task(k, own);
        }
    });
    let block = |r: u32| {
        let (first, end) = (
            owner.partition_point(|&o| o < r),
            owner.partition_point(|&o| o <= r),
        );
        bounds[first]..bounds[end]
    };
    let all = exec.all_gather_vectors(&data[block(me)])?;
    if all.len() != ranks {
        return Err(CommError(format!(
            "rank {me}: {} blocks of the internal step's estimate gathered from {ranks} ranks",
            all.len()
        )));
    }
    for (r, part) in (0..ranks as u32).zip(all) {
        let place = block(r);
        if part.len() != place.len() {
            return Err(CommError(format!(
                "rank {me}: rank {r} sent {} vectors of the internal step's estimate, not {}",
                part.len(),
                place.len()
            )));
        }
        if r != me {
            data[place].copy_from_slice(&part);
        }
    }
    Ok(())
}

/// The ranges of vertices a step estimate on `exec` assembles: one per
/// thread of every rank. Over ranks, as many per rank as the most threads
/// of any rank (one all-gather): a rank's thread count may come from its
/// own host (`--threads 0`), and every rank must cut the same ranges. (The
/// ranks' blocks would mostly agree anyway, as the cuts at multiples of a
/// rank's share of the work are the same for any number of ranges per
/// rank, but not where fewer vertices than ranges clamp the count.)
fn ranges_for<E: Executor>(
    exec: &E,
    model: &ElasticModel,
    n: usize,
) -> Result<VertexRanges, CommError> {
    let threads = largest_over_ranks(exec, exec.threads_per_rank() as f64, "thread counts")?;
    Ok(VertexRanges::new(model, n, exec.ranks() * threads as usize))
}

/// **Collective over ranks** (one all-gather, none on one rank): the
/// largest of every rank's `value` (NaN ignored, as `f64::max` does; exact
/// in any order). `what` names the values in an error.
fn largest_over_ranks<E: Executor>(exec: &E, value: f64, what: &str) -> Result<f64, CommError> {
    if exec.ranks() < 2 {
        return Ok(value);
    }
    let me = exec.rank();
    let all = exec.all_gather_vectors(&[DVec3::new(value, 0.0, 0.0)])?;
    if all.len() != exec.ranks() {
        return Err(CommError(format!(
            "rank {me}: {what} gathered from {} of {} ranks",
            all.len(),
            exec.ranks()
        )));
    }
    let mut largest = value;
    for (r, got) in all.iter().enumerate() {
        let [one] = got[..] else {
            return Err(CommError(format!(
                "rank {me}: rank {r} sent {} of the {what}, not one",
                got.len()
            )));
        };
        largest = largest.max(one.x);
    }
    Ok(largest)
}

fn model_max_frequency<E: Executor>(
    exec: &E,
    rest: &[DVec3],
    masses: &[f64],
    model: &ElasticModel,
) -> Result<f64, CommError> {
    let d = inv_sqrt_masses(masses);
    let ell = length_scale(rest, model);
    if !ell.is_finite() {
        return Ok(0.0);
    }
    let n = rest.len();
    let ranges = ranges_for(exec, model, n)?;
    let (mut xp, mut xm) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
    let (mut gp, mut gm) = match ranges.bounds.len() {
        ..=2 => (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]),
        _ => (Vec::new(), Vec::new()),
    };
    let mut scale = vec![0.0; n];
    let lambda = lanczos_max(&d, |u, out| {
        // Physical direction D u, scaled so the largest displacement is FD_REL · ell.
        let umax = u
            .iter()
            .zip(&d)
            .fold(0.0f64, |a, (ui, di)| a.max(ui.abs().max_element() * di));
        if umax == 0.0 {
            out.fill(DVec3::ZERO);
            return Ok(());
        }
        let s = FD_REL * ell / umax;
        for i in 0..n {
            xp[i] = rest[i] + u[i] * (d[i] * s);
            xm[i] = rest[i] - u[i] * (d[i] * s);
            scale[i] = d[i] / (2.0 * s);
        }
        if ranges.bounds.len() > 2 {
            return ranges.gradient_difference(exec, model, (&xp, &xm), &scale, out);
        }
        // One range: the serial assembly, whose walk over the element
        // slices is faster.
        gp.fill(DVec3::ZERO);
        gm.fill(DVec3::ZERO);
        model.add_gradient(&xp, &mut gp);
        model.add_gradient(&xm, &mut gm);
        for i in 0..n {
            out[i] = (gp[i] - gm[i]) * scale[i];
        }
        Ok(())
    })?;
    // Safety check: Lanczos Ritz values lie below λ_max <= Gershgorin; a value that
    // is not finite or above the bound (finite-difference trouble) is replaced by
    // the bound, which is always safe.
    let bound = model_gershgorin_bound(exec, &ranges, rest, masses, model)?;
    Ok(
        if lambda.is_finite() && lambda.max(0.0).sqrt() <= bound * (1.0 + 1e-6) {
            lambda.max(0.0).sqrt()
        } else {
            bound
        },
    )
}

fn model_max_damping_rate<E: Executor>(
    exec: &E,
    rest: &[DVec3],
    masses: &[f64],
    model: &ElasticModel,
) -> Result<f64, CommError> {
    let d = inv_sqrt_masses(masses);
    let n = rest.len();
    let ranges = ranges_for(exec, model, n)?;
    let mut v = vec![DVec3::ZERO; n];
    let mut f = vec![DVec3::ZERO; n];
    let gamma = lanczos_max(&d, |u, out| {
        for i in 0..n {
            v[i] = u[i] * d[i];
        }
        f.fill(DVec3::ZERO);
        ranges.add_damping_force(exec, model, rest, &v, &mut f)?;
        for i in 0..n {
            out[i] = f[i] * (-d[i]);
        }
        Ok(())
    })?;
    Ok(gamma.max(0.0))
}

/// Central-difference Hessian of one element's gradient, accumulated as absolute
/// row sums `Σ_j |H_ij| d_i d_j` into `rows` (3 per vertex, of the vertices
/// from `first` on that `rows` holds).
fn add_abs_rows<const N: usize>(
    verts: [u32; N],
    rest: &[DVec3],
    d: &[f64],
    (rows, first): (&mut [f64], usize),
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
                let Some(row) = (verts[i] as usize).checked_sub(first).map(|r| 3 * r) else {
                    continue;
                };
                if row >= rows.len() {
                    continue;
                }
                let di = d[verts[i] as usize];
                let col = (gp[i] - gm[i]) * (di * dj / (2.0 * h));
                for a in 0..3 {
                    rows[row + a] += col[a].abs();
                }
            }
        }
    }
}

/// `sqrt(max_row Σ |D K D|)` with the assembled `K` bounded element by element
/// (finite-difference element Hessians), range by range of vertices (each
/// row's sum in element order, as one range has it; the largest row is
/// the same whatever order the ranges come in). Over ranks each rank sums
/// the rows of its block of ranges (as [`ranges_on_ranks`] places them)
/// and the ranks' largest rows are gathered: the largest of all, exactly.
/// **Collective over ranks.**
fn model_gershgorin_bound<E: Executor>(
    exec: &E,
    ranges: &VertexRanges,
    rest: &[DVec3],
    masses: &[f64],
    model: &ElasticModel,
) -> Result<f64, CommError> {
    let d = inv_sqrt_masses(masses);
    let mut rows = vec![0.0; 3 * rest.len()];
    let row_bounds: Vec<usize> = ranges.bounds.iter().map(|b| 3 * b).collect();
    let owner = place_in_blocks(ranges.bounds.len() - 1, exec.ranks());
    let me = exec.rank() as u32;
    exec.for_each_chunk(&mut rows, &row_bounds, &|k, own| {
        if owner[k] != me {
            return;
        }
        let first = ranges.bounds[k];
        let (s, h) = ranges.elements(k, model);
        for (e, m) in s {
            add_abs_rows(e.verts, rest, &d, (&mut *own, first), |x| e.gradient(x, m));
        }
        for (e, m) in h {
            let k_b = m.bending_stiffness;
            add_abs_rows(e.verts, rest, &d, (&mut *own, first), |x| {
                e.gradient(x, k_b)
            });
        }
    });
    // Rows not summed here are 0, below every sum of absolute values.
    let mine = rows.iter().fold(0.0f64, |a, &r| a.max(r));
    Ok(largest_over_ranks(exec, mine, "largest rows of the step's bound")?.sqrt())
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
fn lanczos_max(
    mask: &[f64],
    mut apply: impl FnMut(&[DVec3], &mut [DVec3]) -> Result<(), CommError>,
) -> Result<f64, CommError> {
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
        return Ok(0.0);
    }
    q.iter_mut().for_each(|v| *v /= norm);
    let mut q_prev = vec![DVec3::ZERO; n];
    let mut w = vec![DVec3::ZERO; n];
    let mut alpha: Vec<f64> = Vec::new();
    let mut beta: Vec<f64> = Vec::new();
    let steps = MAX_LANCZOS_STEPS.min(3 * mask.iter().filter(|&&m| m != 0.0).count());
    let mut last = f64::NEG_INFINITY;
    for j in 0..steps {
        apply(&q, &mut w)?;
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
                return Ok(theta);
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
    Ok(last)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::internal::KeyOrdered;
    use weft_core::Topology;
    use weft_testkit::Rng;

    /// An `nx × ny` grid, jittered and curved, its vertices numbered in a
    /// random order when `shuffled` (elements then span many ranges): its
    /// rest positions and its elements, of one damped material.
    fn mesh(rng: &mut Rng, (nx, ny): (usize, usize), shuffled: bool) -> (Vec<DVec3>, KeyOrdered) {
        let n = nx * ny;
        let mut order: Vec<u32> = (0..n as u32).collect();
        if shuffled {
            for i in (1..n).rev() {
                order.swap(i, rng.below(i as u64 + 1) as usize);
            }
        }
        let mut rest = vec![DVec3::ZERO; n];
        for j in 0..ny {
            for i in 0..nx {
                let p = DVec3::new(0.01 * i as f64, 0.01 * j as f64, 0.0) + rng.vec(0.002);
                rest[order[j * nx + i] as usize] = p;
            }
        }
        let id = |i: usize, j: usize| order[j * nx + i];
        let mut triangles = Vec::new();
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        let topo = Topology::build(n, &triangles).unwrap();
        let at = |v: &[u32]| v.iter().map(|&i| rest[i as usize]).collect::<Vec<_>>();
        let stretch: Vec<_> = (triangles.iter())
            .map(|t| StretchElement::new(*t, at(t).try_into().unwrap()).unwrap())
            .collect();
        let hinges: Vec<_> = (topo.hinges.iter())
            .map(|h| {
                let v = [h.edge[0], h.edge[1], h.wings[0], h.wings[1]];
                HingeElement::new(v, at(&v).try_into().unwrap()).unwrap()
            })
            .collect();
        let elements = KeyOrdered {
            stretch_material: vec![0; stretch.len()],
            hinge_material: vec![0; hinges.len()],
            stretch,
            hinges,
            materials: vec![Material {
                stretch_damping: 2e-5,
                bend_damping: 3e-9,
                ..Material::plate(0.15, 2.0e6, 0.3, 4.0e-4)
            }],
        };
        (rest, elements)
    }

    fn bits(v: &[DVec3]) -> Vec<[u64; 3]> {
        v.iter().map(|p| p.to_array().map(f64::to_bits)).collect()
    }

    /// Range by range, the gradient's central difference, the damping force and the Gershgorin
    /// bound have the serial assembly's bits, on any number of ranges, with
    /// the vertices numbered along the grid or at random.
    #[test]
    fn ranges_assemble_the_serial_bits() {
        let mut rng = Rng(0x5eed_0a55);
        for (case, shuffled) in [(0, false), (1, true), (2, true)] {
            let size = [(9, 7), (6, 11), (13, 5)][case];
            let (rest, elements) = mesh(&mut rng, size, shuffled);
            let (model, rest) = (elements.model(), &rest[..]);
            let n = rest.len();
            let x: Vec<DVec3> = rest.iter().map(|p| *p + rng.vec(1e-3)).collect();
            let v: Vec<DVec3> = (0..n).map(|_| rng.vec(0.5)).collect();
            let (mut grad, mut force) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
            model.add_gradient(&x, &mut grad);
            model.add_damping_force(&x, &v, &mut force);
            // A central difference of the gradient between x and rest.
            let scale: Vec<f64> = (0..n).map(|_| rng.uniform(0.5, 2.0)).collect();
            let mut at_rest = vec![DVec3::ZERO; n];
            model.add_gradient(rest, &mut at_rest);
            let difference: Vec<DVec3> =
                (0..n).map(|i| (grad[i] - at_rest[i]) * scale[i]).collect();
            let masses = vec![1e-4; n];
            let bound = model.gershgorin_bound(rest, &masses);
            for tasks in [1, 2, 3, 5, 8, 64] {
                let what = format!("case {case}, {tasks} ranges");
                let ranges = VertexRanges::new(&model, n, tasks);
                let b = &ranges.bounds;
                // As many ranges as tasks where each holds several
                // vertices; at most as many always.
                assert!(b.len() - 1 <= tasks, "{what}: {b:?}");
                assert!(tasks > 8 || b.len() - 1 == tasks, "{what}: {b:?}");
                assert!(b[0] == 0 && b[b.len() - 1] == n, "{what}: {b:?}");
                assert!(b.windows(2).all(|w| w[0] < w[1]), "{what}: {b:?}");
                let mut g = vec![DVec3::ZERO; n];
                (ranges.gradient_difference(&Serial, &model, (&x, rest), &scale, &mut g)).unwrap();
                assert_eq!(bits(&g), bits(&difference), "{what}: gradient difference");
                let mut f = vec![DVec3::ZERO; n];
                ranges
                    .add_damping_force(&Serial, &model, &x, &v, &mut f)
                    .unwrap();
                assert_eq!(bits(&f), bits(&force), "{what}: damping force");
                let on_ranges =
                    model_gershgorin_bound(&Serial, &ranges, rest, &masses, &model).unwrap();
                assert_eq!(on_ranges.to_bits(), bound.to_bits(), "{what}: Gershgorin");
            }
        }
    }

    /// An executor that runs everything in order on the calling thread but
    /// says it has `0` threads: the step estimates cut that many ranges.
    struct Pretend(usize);

    impl Executor for Pretend {
        fn for_each_chunk<T: Send>(
            &self,
            data: &mut [T],
            bounds: &[usize],
            task: &(dyn Fn(usize, &mut [T]) + Sync),
        ) {
            Serial.for_each_chunk(data, bounds, task)
        }
        fn map<R: Send>(&self, n: usize, f: &(dyn Fn(usize) -> R + Sync)) -> Vec<R> {
            Serial.map(n, f)
        }
        fn name(&self) -> String {
            format!("pretend {}", self.0)
        }
        fn threads_per_rank(&self) -> usize {
            self.0
        }
    }

    /// The largest frequency and damping rate, Lanczos over range-by-range
    /// products, have the bits of one range's.
    #[test]
    fn step_estimates_have_the_same_bits_on_any_number_of_ranges() {
        let mut rng = Rng(0x0e6a);
        let (rest, elements) = mesh(&mut rng, (10, 8), true);
        let (model, rest) = (elements.model(), &rest[..]);
        let masses: Vec<f64> = (0..rest.len()).map(|_| rng.uniform(1e-5, 1e-4)).collect();
        let omega = model.max_frequency(rest, &masses);
        let gamma = model.max_damping_rate(rest, &masses);
        assert!(omega > 0.0 && gamma > 0.0);
        for tasks in [2, 3, 7] {
            let exec = Pretend(tasks);
            let o = model.max_frequency_on(&exec, rest, &masses).unwrap();
            let g = model.max_damping_rate_on(&exec, rest, &masses).unwrap();
            assert_eq!(
                o.to_bits(),
                omega.to_bits(),
                "{tasks} ranges: {o} vs {omega}"
            );
            assert_eq!(
                g.to_bits(),
                gamma.to_bits(),
                "{tasks} ranges: {g} vs {gamma}"
            );
        }
    }
}
