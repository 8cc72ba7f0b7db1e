//! Kinematic objects: scripted motion of obstacles and pinned cloth vertices
//! (`acm-spec.md` §2.2).
//!
//! A script moves a set of vertices (inverse mass 0) along a motion that is a
//! pure function of time, `P(t)`. Their velocity changes only at the ticks of
//! the script clock (the internal clock): at tick `t` the velocity is set to the
//! chord `(P(t + h) - x(t)) / h`, so trajectories stay piecewise linear (exact for
//! collision detection), continuous, and never drift away from the script.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A motion of a rigid vertex set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Motion {
    /// Does not move.
    Fixed,
    /// Moves with a constant velocity (m/s).
    Translate { velocity: DVec3 },
    /// Rotates about the axis through `center` along `axis` (normalized on
    /// construction) with angular velocity `omega(t)` (rad/s) interpolated
    /// linearly between `profile` points `(t, omega)` and held constant outside.
    Rotate {
        center: DVec3,
        axis: DVec3,
        profile: Vec<(f64, f64)>,
    },
}

impl Motion {
    /// Angle turned by time `t` (∫₀ᵗ omega), exact for the piecewise-linear profile.
    pub fn angle(profile: &[(f64, f64)], t: f64) -> f64 {
        if profile.is_empty() || t <= 0.0 {
            return 0.0;
        }
        let omega_at = |s: f64| -> f64 {
            if s <= profile[0].0 {
                return profile[0].1;
            }
            for w in profile.windows(2) {
                let ((t0, w0), (t1, w1)) = (w[0], w[1]);
                if s <= t1 {
                    return if t1 > t0 {
                        w0 + (w1 - w0) * (s - t0) / (t1 - t0)
                    } else {
                        w1
                    };
                }
            }
            profile[profile.len() - 1].1
        };
        // Integrate piecewise: breakpoints of omega inside (0, t), trapezoids are exact.
        let mut knots: Vec<f64> = vec![0.0];
        knots.extend(profile.iter().map(|p| p.0).filter(|&s| s > 0.0 && s < t));
        knots.push(t);
        knots
            .windows(2)
            .map(|k| 0.5 * (omega_at(k[0]) + omega_at(k[1])) * (k[1] - k[0]))
            .sum()
    }

    /// Position at time `t` of the point that is at `x0` at time 0.
    pub fn position(&self, x0: DVec3, t: f64) -> DVec3 {
        match self {
            Motion::Fixed => x0,
            Motion::Translate { velocity } => x0 + *velocity * t,
            Motion::Rotate {
                center,
                axis,
                profile,
            } => {
                let theta = Self::angle(profile, t);
                rotate(x0 - *center, *axis, theta) + *center
            }
        }
    }
}

/// Rodrigues' rotation of `r` by `theta` about unit `axis` (libm for determinism).
pub fn rotate(r: DVec3, axis: DVec3, theta: f64) -> DVec3 {
    let (s, c) = (libm::sin(theta), libm::cos(theta));
    r * c + axis.cross(r) * s + axis * (axis.dot(r) * (1.0 - c))
}

/// A motion applied to a set of vertices (input ids).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Script {
    pub name: String,
    pub vertices: Vec<u32>,
    /// Positions of `vertices` at time 0.
    pub rest: Vec<DVec3>,
    pub motion: Motion,
}

impl Script {
    /// The velocity of the chord from `x_now` (at `t`) to the script's position at `t + h`.
    pub fn chord_velocity(&self, k: usize, x_now: DVec3, t: f64, h: f64) -> DVec3 {
        (self.motion.position(self.rest[k], t + h) - x_now) / h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_integrates_piecewise_linear_profile() {
        let p = [(1.0, 0.0), (3.0, 2.0)];
        assert_eq!(Motion::angle(&p, 1.0), 0.0);
        assert!((Motion::angle(&p, 3.0) - 2.0).abs() < 1e-15);
        assert!((Motion::angle(&p, 4.0) - 4.0).abs() < 1e-15);
        assert!((Motion::angle(&p, 2.0) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn rotation_keeps_distance_to_axis() {
        let m = Motion::Rotate {
            center: DVec3::new(1.0, 0.0, 0.0),
            axis: DVec3::Z,
            profile: vec![(0.0, 1.0)],
        };
        let p = m.position(DVec3::new(2.0, 0.0, 0.5), std::f64::consts::FRAC_PI_2);
        assert!((p - DVec3::new(1.0, 1.0, 0.5)).length() < 1e-12);
    }
}
