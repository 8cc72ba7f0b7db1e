//! Nested penalty layers: the contact barrier (`acm-spec.md` §3).
//!
//! For every stencil with distance `d`, layer `l = 1, 2, ...` has
//!
//! ```text
//! V_l   = k_l (eta_l - d)^2 / 2        if d < eta_l, else 0
//! eta_l = eta_inf + (eta_1 - eta_inf) l^(-1/4)
//! k_l   = k_1 l^3
//! h_l   = h_1 l^(-3/2)   (ticks, rounded down: every layer has the same omega h)
//! ```
//!
//! The sum over layers diverges as `d → eta_inf`, so a finite-energy motion can
//! only enter finitely many layers. The active-layer set of a stencil is always a
//! prefix `1..=depth`; it only grows within a window and shrinks at commits, one
//! innermost layer at a time after `hysteresis` calm windows.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use weft_core::{StencilKey, NONE};
use weft_geom::distance::Closest;

use crate::clock::Tick;

/// The layer schedule of one simulation.
///
/// ```
/// use weft_sim::layers::LayerSchedule;
/// let s = LayerSchedule { eta_1: 1e-3, eta_inf: 1e-4, k_1: 10.0, h_1: 1 << 20 };
/// assert_eq!(s.eta(1), 1e-3);
/// assert!(s.eta(16) < s.eta(2) && s.eta(16) > s.eta_inf); // nested, above the floor
/// assert_eq!(s.k(2), 80.0);                                // k_l = k_1 l^3
/// assert_eq!(s.step(4), (1 << 20) / 8);                    // h_l = h_1 l^(-3/2)
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerSchedule {
    /// Outer contact thickness `eta_1` (m).
    pub eta_1: f64,
    /// Separation floor `eta_inf` (m), `0 ≤ eta_inf < eta_1`.
    pub eta_inf: f64,
    /// Stiffness of layer 1 (N/m).
    pub k_1: f64,
    /// Step of layer 1 in ticks.
    pub h_1: Tick,
}

impl LayerSchedule {
    /// `eta_l`.
    pub fn eta(&self, l: u32) -> f64 {
        if l == 0 {
            return f64::INFINITY;
        }
        self.eta_inf + (self.eta_1 - self.eta_inf) * libm::pow(l as f64, -0.25)
    }

    /// `k_l`.
    pub fn k(&self, l: u32) -> f64 {
        let l = l as f64;
        self.k_1 * l * l * l
    }

    /// `h_l` in ticks (at least 1).
    pub fn step(&self, l: u32) -> Tick {
        let h = (self.h_1 as f64 * libm::pow(l as f64, -1.5)).floor();
        (h as Tick).max(1)
    }

    /// The deepest layer whose step `h_1 l^(-3/2)` is at least one tick, so
    /// that [`LayerSchedule::step`] is exact rounding down (deeper layers
    /// would round up to one tick: a larger `omega h`, unstable). A stencil
    /// never gets a deeper layer (the engine stops with an error).
    pub fn resolved_depth(&self) -> u32 {
        resolved_depth(self.h_1)
    }

    /// Energy of layer `l` at distance `d`.
    pub fn energy(&self, l: u32, d: f64) -> f64 {
        let gap = self.eta(l) - d;
        if gap > 0.0 {
            0.5 * self.k(l) * gap * gap
        } else {
            0.0
        }
    }

    /// Energy of layers `1..=depth` at distance `d`. `eta_l` falls with `l`,
    /// so the sum stops at the first layer `d` is outside: the same value
    /// as summing every layer (the rest add zeros), without their `pow`s.
    pub fn energy_through(&self, depth: u32, d: f64) -> f64 {
        let mut sum = 0.0;
        for l in 1..=depth {
            let gap = self.eta(l) - d;
            if !(gap > 0.0) {
                break;
            }
            sum += 0.5 * self.k(l) * gap * gap;
        }
        sum
    }
}

/// The deepest layer `l` whose step `h_1 l^(-3/2)` (the formula of
/// [`LayerSchedule::step`]) is at least one tick, for layer 1's step `h_1`
/// in ticks (0 when not even layer 1 is resolved): `l ≤ h_1^(2/3)`, found
/// by doubling and bisection on the same floating-point formula.
pub fn resolved_depth(h_1: Tick) -> u32 {
    let exact = |l: u32| h_1 as f64 * libm::pow(l as f64, -1.5) >= 1.0;
    if !exact(1) {
        return 0;
    }
    let mut lo = 1u32;
    while lo < u32::MAX / 2 && exact(lo * 2) {
        lo *= 2;
    }
    let mut hi = lo * 2;
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if exact(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The active layers of one stencil.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayerState {
    /// Active layers are `1..=depth`.
    pub depth: u32,
    /// Consecutive committed windows in which the stencil stayed certified
    /// outside `eta_depth` (the retirement hysteresis counter).
    pub calm_windows: u32,
}

/// Every stencil's active layers, ordered by global key (the fold order).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActiveLayers {
    pub stencils: BTreeMap<StencilKey, LayerState>,
}

impl ActiveLayers {
    /// Depth of `key` (0 when inactive).
    pub fn depth(&self, key: &StencilKey) -> u32 {
        self.stencils.get(key).map_or(0, |s| s.depth)
    }

    /// The depth of each of `keys` (ascending, as the broad phase gives
    /// candidates), by one merge walk with the map instead of a search per
    /// key: the layer predictor and the narrow phase ask for tens of
    /// thousands of candidates a pass, and the searches were a third of
    /// the predictor's decisions.
    pub fn depths_of(&self, keys: &[StencilKey]) -> Vec<u32> {
        debug_assert!(keys.windows(2).all(|p| p[0] <= p[1]), "keys in order");
        let Some(first) = keys.first() else {
            return Vec::new();
        };
        let mut active = self.stencils.range(first..).peekable();
        keys.iter()
            .map(|key| {
                while active.next_if(|(k, _)| *k < key).is_some() {}
                match active.peek() {
                    Some((k, s)) if *k == key => s.depth,
                    _ => 0,
                }
            })
            .collect()
    }

    /// The deepest active layer.
    pub fn max_depth(&self) -> u32 {
        self.stencils.values().map(|s| s.depth).max().unwrap_or(0)
    }

    /// Activates `extra` more layers of `key` (layers depth+1 ..= depth+extra)
    /// and resets its calm counter.
    pub fn deepen(&mut self, key: StencilKey, extra: u32) {
        let s = self.stencils.entry(key).or_insert(LayerState {
            depth: 0,
            calm_windows: 0,
        });
        s.depth += extra;
        s.calm_windows = 0;
    }

    /// Histogram: entry `i` = number of stencils with depth `i + 1`.
    pub fn depth_histogram(&self) -> Vec<u64> {
        let mut h = vec![0u64; self.max_depth() as usize];
        for s in self.stencils.values() {
            h[s.depth as usize - 1] += 1;
        }
        h
    }
}

/// The impulses of one penalty-layer event on its stencil's four vertices.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct PenaltyImpulse {
    /// Normal impulse on each vertex (N·s).
    pub normal: [DVec3; 4],
    /// Friction impulse on each vertex (N·s).
    pub friction: [DVec3; 4],
    /// The tangential impulse that on its own would stop the stencil's
    /// relative sliding, as a multiple of the one applied (≥ 1; exactly 1
    /// when the kick stops the sliding, 0 without friction). A batch's
    /// friction clamp ([`FrictionClamp`]) reads it.
    pub stop_ratio: f64,
    /// Energy of the layer at the event (J), for diagnostics.
    pub energy: f64,
}

/// The kick of a layer with thickness `eta`, stiffness `k` and step `h`
/// seconds (layer `l`: `eta_l`, `k_l`, `h_l`) on a stencil with closest-point
/// data `c` (positions at the event) and velocities `v` at the start of the
/// batch (Jacobi semantics for friction); `w` are inverse masses. `None` when
/// the stencil is outside the layer (zero kick — it must leave no trace).
///
/// Normal: the layer force is `-dV/dx_j = k (eta - d) c_j n`, so the impulse is
/// `h k (eta - d) c_j n`. Friction (Coulomb, Bridson et al. 2002 style): the
/// relative velocity `v_rel = Σ c_j v_j` has tangential part `v_t`; the
/// tangential impulse `I_t = -min(mu J_n, |v_t| / Σ c_j² w_j) v_t/|v_t|`
/// (at most what stops the relative sliding) is distributed as `c_j I_t`.
/// Both parts sum to zero over the stencil (Σ c_j = 0): linear momentum is
/// conserved; friction does not conserve angular momentum. Kicks of one
/// batch read the same velocities, so their friction is clamped together
/// afterwards ([`FrictionClamp`]), one factor per stencil.
pub fn penalty_kick(
    eta: f64,
    k: f64,
    h: f64,
    c: &Closest,
    v: &[DVec3; 4],
    w: &[f64; 4],
    mu: f64,
) -> Option<PenaltyImpulse> {
    let gap = eta - c.d;
    if gap <= 0.0 || gap.is_nan() {
        return None;
    }
    let jn = h * k * gap;
    let normal = c.coeff.map(|cj| c.n * (jn * cj));
    let mut friction = [DVec3::ZERO; 4];
    let mut stop_ratio = 0.0;
    if mu > 0.0 {
        let mut v_rel = DVec3::ZERO;
        let mut m_inv = 0.0;
        for j in 0..4 {
            v_rel += v[j] * c.coeff[j];
            m_inv += c.coeff[j] * c.coeff[j] * w[j];
        }
        let v_t = v_rel - c.n * v_rel.dot(c.n);
        let speed = v_t.length();
        if speed > 0.0 && m_inv > 0.0 {
            let stop = speed / m_inv;
            let magnitude = (mu * jn).min(stop);
            let it = v_t * (-magnitude / speed);
            friction = c.coeff.map(|cj| it * cj);
            stop_ratio = stop / magnitude;
        }
    }
    Some(PenaltyImpulse {
        normal,
        friction,
        stop_ratio,
        energy: 0.5 * k * gap * gap,
    })
}

/// The friction clamp of one batch (`acm-spec.md` §3: the summed tangential
/// impulses of a batch never reverse a vertex's sliding), acting on whole
/// stencil impulses so that every kick still conserves linear momentum.
///
/// A kick's friction at most stops its own stencil's relative sliding, but
/// the kicks of one batch all read the velocities at its start (Jacobi), so
/// several stencils at one vertex could together overshoot. The rule: the
/// friction vertex `i` receives in a batch, `Σ_k |f_ki|` over its stencils
/// `k`, may not exceed `L_i = max_k |f_ki| · stop_ratio_k`, the impulse the
/// most demanding single stencil at `i` would need to stop its sliding there.
/// A vertex over its limit gets the factor `s_i = L_i / Σ_k |f_ki|`; each
/// stencil's friction is scaled by the smallest factor among its dynamic
/// vertices, as a whole. Then
///
/// * every kick's friction still sums to zero over its stencil (linear
///   momentum is conserved whatever the clamp does);
/// * vertex `i` receives at most `Σ_k s_k |f_ki| ≤ s_i Σ_k |f_ki| ≤ L_i`;
/// * a vertex in one stencil is never clamped (`|f| ≤ |f| · stop_ratio`), and
///   sliding contacts sharing a load keep their full Coulomb friction as long
///   as its sum stays below what stops the vertex.
///
/// The sums are folded in the batch's (layer, key) order, so the factors are
/// the same bits wherever the batch runs.
#[derive(Clone, Debug, Default)]
pub struct FrictionClamp {
    /// Per vertex: `Σ_k |f_ki|` and `L_i` of the batch so far (0 when none).
    sum: Vec<f64>,
    limit: Vec<f64>,
}

impl FrictionClamp {
    /// Scratch for `n` vertices.
    pub fn new(n: usize) -> Self {
        Self {
            sum: vec![0.0; n],
            limit: vec![0.0; n],
        }
    }

    /// Adds the friction of a kick on stencil vertices `v` (first pass over
    /// the batch, in fold order); `NONE` marks a kinematic vertex, which no
    /// kick moves.
    pub fn add(&mut self, v: &[u32; 4], kick: &PenaltyImpulse) {
        for j in 0..4 {
            let i = v[j] as usize;
            let f = kick.friction[j].length();
            if v[j] != NONE && f > 0.0 {
                self.sum[i] += f;
                self.limit[i] = self.limit[i].max(f * kick.stop_ratio);
            }
        }
    }

    /// The factor (in `(0, 1]`) by which the whole friction impulse of a kick
    /// added before is scaled (second pass).
    pub fn scale(&self, v: &[u32; 4], kick: &PenaltyImpulse) -> f64 {
        let mut s = 1.0f64;
        for j in 0..4 {
            let i = v[j] as usize;
            if v[j] != NONE && kick.friction[j] != DVec3::ZERO && self.sum[i] > self.limit[i] {
                s = s.min(self.limit[i] / self.sum[i]);
            }
        }
        s
    }

    /// Forgets the batch's sums at stencil vertices `v` (after the second pass).
    pub fn clear(&mut self, v: &[u32; 4]) {
        for &i in v.iter().filter(|&&i| i != NONE) {
            self.sum[i as usize] = 0.0;
            self.limit[i as usize] = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule() -> LayerSchedule {
        LayerSchedule {
            eta_1: 1e-3,
            eta_inf: 1e-4,
            k_1: 10.0,
            h_1: 1 << 20,
        }
    }

    /// One merge walk gives what a search per key gives, for sorted keys
    /// with repeats, active and not, before, among and after the active.
    #[test]
    fn depths_of_sorted_keys_match_a_search_each() {
        use weft_core::StencilKey;
        let key = |a: u32| StencilKey::edge_edge([a, a + 1], [a + 2, a + 3]);
        let mut layers = ActiveLayers::default();
        for a in (10..200).step_by(7) {
            layers.deepen(key(a), 1 + a % 5);
        }
        let mut keys: Vec<StencilKey> = (0..260).step_by(3).map(key).collect();
        keys.extend((10..200).step_by(14).map(key));
        keys.sort();
        let want: Vec<u32> = keys.iter().map(|k| layers.depth(k)).collect();
        assert!(want.iter().filter(|&&d| d > 0).count() > 10);
        assert_eq!(layers.depths_of(&keys), want);
        assert!(layers.depths_of(&[]).is_empty());
        assert_eq!(
            ActiveLayers::default().depths_of(&keys),
            vec![0; keys.len()]
        );
    }

    /// `energy_through` stops at the first layer the distance is outside;
    /// it must equal the sum over every layer, bit for bit, at distances
    /// on, between and beyond the layers' `eta_l`.
    #[test]
    fn energy_through_equals_the_sum_over_every_layer() {
        let s = schedule();
        for depth in [0u32, 1, 2, 7, 40, 300] {
            let mut ds = vec![0.0, 5e-5, 1e-4, 2e-3, s.eta_1];
            for l in 1..=depth.min(60) {
                let eta = s.eta(l);
                ds.extend([
                    eta,
                    eta * (1.0 - 1e-12),
                    eta * (1.0 + 1e-12),
                    0.5 * (eta + s.eta(l + 1)),
                ]);
            }
            for d in ds {
                let every: f64 = (1..=depth).map(|l| s.energy(l, d)).fold(0.0, |a, e| a + e);
                let sum = s.energy_through(depth, d);
                assert_eq!(sum.to_bits(), every.to_bits(), "depth {depth} d {d}");
            }
        }
    }

    #[test]
    fn schedule_is_nested_and_barrier_like() {
        let s = schedule();
        assert_eq!(s.eta(1), 1e-3);
        for l in 1..50 {
            assert!(s.eta(l + 1) < s.eta(l));
            assert!(s.eta(l) > s.eta_inf);
            assert!(s.step(l + 1) <= s.step(l));
            // omega h = sqrt(k_l) h_l is the same for every layer, up to the
            // rounding of h_l down to whole ticks (which only lowers it).
            let wh = (s.k(l)).sqrt() * s.step(l) as f64;
            let wh1 = (s.k(1)).sqrt() * s.step(1) as f64;
            let rel = wh / wh1 - 1.0;
            assert!(
                rel <= 1e-12 && rel > -1.0 / s.step(l) as f64,
                "layer {l}: {rel:e}"
            );
        }
    }

    #[test]
    fn kick_is_zero_outside_and_momentum_free_inside() {
        let s = schedule();
        let c = Closest {
            d: 2e-3,
            n: DVec3::Z,
            coeff: [1.0, -0.2, -0.3, -0.5],
        };
        let v = [DVec3::X, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
        assert!(penalty_kick(s.eta(1), s.k(1), 1e-3, &c, &v, &[1.0; 4], 0.5).is_none());
        let c = Closest { d: 5e-4, ..c };
        let k = penalty_kick(s.eta(1), s.k(1), 1e-3, &c, &v, &[1.0; 4], 0.5).unwrap();
        let total: DVec3 = k.normal.iter().chain(&k.friction).copied().sum();
        assert!(total.length() < 1e-18);
        assert!(k.normal[0].z > 0.0, "pushes the vertex out along n");
        assert!(k.friction[0].x < 0.0, "friction opposes sliding");
    }

    /// Random batches of kicks on a few shared vertices: after the clamp
    /// every kick still sums to zero over its stencil, no vertex receives
    /// more than its limit, and a vertex in one stencil is left alone.
    #[test]
    fn friction_clamp_scales_whole_stencils_and_respects_each_limit() {
        let mut rnd = crate::uniform_numbers(0x9e37_79b9_7f4a_7c15);
        let n = 6;
        let w = [1.0, 2.0, 0.5, 0.0, 1.5, 3.0]; // vertex 3 is kinematic
        let mut clamped = 0;
        for _ in 0..500 {
            let mut clamp = FrictionClamp::new(n);
            let kicks: Vec<([u32; 4], PenaltyImpulse)> = (0..1 + (rnd() * 5.0) as usize)
                .map(|_| {
                    let mut v = [0u32; 4];
                    for j in 0..4 {
                        v[j] = (rnd() * n as f64) as u32 % n as u32;
                    }
                    let c = Closest {
                        d: 1e-4 * rnd(),
                        n: DVec3::Z,
                        coeff: [1.0, -0.3, -0.3, -0.4],
                    };
                    // Slow sliding: the kicks mostly stop it (and overshoot
                    // together where they share a vertex); fast: Coulomb.
                    let speed = if rnd() < 0.5 { 1e-3 } else { 1.0 };
                    let vel = [0; 4].map(|_| DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.0) * speed);
                    let inv = v.map(|i| w[i as usize]);
                    let k = penalty_kick(1e-3, 1e4 * rnd(), 1e-3, &c, &vel, &inv, 2.0 * rnd());
                    (v, k.unwrap())
                })
                .collect();
            // The clamp's view: kinematic vertices marked NONE.
            let dynamic = |v: &[u32; 4]| v.map(|i| if w[i as usize] > 0.0 { i } else { NONE });
            for (v, k) in &kicks {
                clamp.add(&dynamic(v), k);
            }
            let mut got = vec![DVec3::ZERO; n];
            let mut limit = vec![0.0f64; n];
            let mut count = vec![0; n];
            for (v, k) in &kicks {
                let s = clamp.scale(&dynamic(v), k);
                assert!(s > 0.0 && s <= 1.0);
                clamped += usize::from(s < 1.0);
                let total: DVec3 = k.friction.iter().map(|f| *f * s).sum();
                assert!(total.length() <= 1e-12 * k.friction[0].length().max(1e-300));
                for j in 0..4 {
                    let i = v[j] as usize;
                    if w[i] > 0.0 && k.friction[j] != DVec3::ZERO {
                        got[i] += k.friction[j] * s;
                        limit[i] = limit[i].max(k.friction[j].length() * k.stop_ratio);
                        count[i] += 1;
                    }
                }
            }
            for i in 0..n {
                assert!(got[i].length() <= limit[i] * (1.0 + 1e-12), "vertex {i}");
            }
            for (v, k) in &kicks {
                let alone = v.iter().all(|&i| count[i as usize] <= 1);
                if alone {
                    assert_eq!(clamp.scale(&dynamic(v), k), 1.0);
                }
                clamp.clear(&dynamic(v));
            }
            assert!(clamp.sum.iter().chain(&clamp.limit).all(|&x| x == 0.0));
        }
        assert!(
            clamped > 50,
            "the clamp must act in some batches: {clamped}"
        );
    }

    #[test]
    fn resolved_depth_is_the_last_layer_with_a_step_of_a_tick() {
        for h_1 in [0u64, 1, 2, 7, 8, 1000, 1024, 1 << 17, 1 << 20] {
            let d = resolved_depth(h_1);
            let s = LayerSchedule { h_1, ..schedule() };
            let exact = |l: u32| h_1 as f64 * libm::pow(l as f64, -1.5) >= 1.0;
            if d > 0 {
                assert!(exact(d) && s.step(d) >= 1, "h_1 = {h_1}");
            }
            assert!(!exact(d + 1), "h_1 = {h_1}: {d}");
            let approx = (h_1 as f64).powf(2.0 / 3.0);
            assert!(
                (d as f64 - approx).abs() <= 1.0,
                "h_1 = {h_1}: {d} vs {approx}"
            );
        }
    }
}
