//! Kinematic objects: scripted motion of obstacles and pinned cloth vertices
//! (`acm-spec.md` §2.2).
//!
//! A script moves a set of vertices (inverse mass 0) along a motion that is a
//! pure function of time, `P(t)`. Their velocity changes only at the ticks of
//! the script clock (the internal clock): at tick `t` the velocity is set to the
//! chord `(P(t + h) - x(t)) / h`, so trajectories stay piecewise linear (exact for
//! collision detection), continuous, and never drift away from the script.
//!
//! Rigid motions ([`Motion::Fixed`], [`Motion::Translate`], [`Motion::Rotate`])
//! map a vertex's time-0 position to its position at `t`; a
//! [`Motion::Sequence`] is per vertex: every vertex of the script has its own
//! keyframed path (an animated character read from a mesh sequence).
//! [`Script::position`] answers both.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A scripted motion of a vertex set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Motion {
    /// Does not move.
    Fixed,
    /// Moves with a constant velocity (m/s) until time `until` (s), then stays
    /// at rest; `None` = forever.
    Translate { velocity: DVec3, until: Option<f64> },
    /// Rotates about the axis through `center` along `axis` (normalized on
    /// construction) with angular velocity `omega(t)` (rad/s) interpolated
    /// linearly between `profile` points `(t, omega)` and held constant outside.
    Rotate {
        center: DVec3,
        axis: DVec3,
        profile: Vec<(f64, f64)>,
    },
    /// Per-vertex keyframes: vertex `k` of the script follows
    /// `frames[i][k]`, linear in time between frames (see [`Keyframes`]).
    Sequence(Keyframes),
}

/// Keyframed positions of a vertex set: frame `i` holds at time
/// `start + i / frame_rate`; positions are interpolated linearly in time
/// between frames, held at the first frame before `start` and at the last
/// frame after the end.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Keyframes {
    /// Frames per second (> 0).
    pub frame_rate: f64,
    /// Time of frame 0 (s).
    pub start: f64,
    /// `frames[i][k]`: position of vertex `k` in frame `i`; every frame has
    /// the same number of vertices, and there is at least one frame.
    pub frames: Vec<Vec<DVec3>>,
}

impl Keyframes {
    /// Checks the rate, the start time, the frame sizes (`vertices` each)
    /// and that every position is finite; the message says what is wrong.
    pub fn validate(&self, vertices: usize) -> Result<(), String> {
        if !(self.frame_rate > 0.0 && self.frame_rate.is_finite()) {
            return Err(format!(
                "frame rate {} must be a positive number of frames per second",
                self.frame_rate
            ));
        }
        if !self.start.is_finite() {
            return Err(format!("start time {} is not finite", self.start));
        }
        if self.frames.is_empty() {
            return Err("the sequence has no frames".into());
        }
        for (i, f) in self.frames.iter().enumerate() {
            if f.len() != vertices {
                return Err(format!(
                    "frame {i} has {} vertices, the object has {vertices}",
                    f.len()
                ));
            }
            if let Some(k) = f.iter().position(|p| !p.is_finite()) {
                return Err(format!("frame {i}: vertex {k} is not finite"));
            }
        }
        Ok(())
    }

    /// Number of vertices per frame.
    pub fn num_vertices(&self) -> usize {
        self.frames.first().map_or(0, Vec::len)
    }

    /// Time of the last frame (s).
    pub fn end(&self) -> f64 {
        self.start + (self.frames.len().saturating_sub(1)) as f64 / self.frame_rate
    }

    /// The frame interval holding time `t`: `(i, f)` with the position
    /// `frames[i] + f (frames[i + 1] - frames[i])`, `f` in `[0, 1)`. A time
    /// within the rounding error of `(t - start) · frame_rate` (a few ulps of
    /// `t`, `start` and the frame index) of a frame time gives `f == 0`, so
    /// `start + i / frame_rate` computed in floating point lands on frame `i`
    /// itself and the position is that frame's, bit for bit.
    fn locate(&self, t: f64) -> (usize, f64) {
        let last = self.frames.len().saturating_sub(1);
        let s = (t - self.start) * self.frame_rate;
        if !(s > 0.0) {
            return (0, 0.0);
        }
        let nearest = s.round();
        let tol = 4.0
            * f64::EPSILON
            * ((t.abs() + self.start.abs()) * self.frame_rate + nearest.max(1.0));
        if (s - nearest).abs() <= tol {
            return ((nearest as usize).min(last), 0.0);
        }
        let i = s.floor();
        if i >= last as f64 {
            return (last, 0.0);
        }
        (i as usize, s - i)
    }

    /// Position of vertex `k` at time `t`.
    pub fn position(&self, k: usize, t: f64) -> DVec3 {
        let (i, f) = self.locate(t);
        let a = self.frames[i][k];
        if f == 0.0 {
            return a;
        }
        let b = self.frames[i + 1][k];
        a + (b - a) * f
    }
}

impl Motion {
    /// Angle turned by time `t` (∫₀ᵗ omega), exact for the piecewise-linear profile.
    pub fn angle(profile: &[(f64, f64)], t: f64) -> f64 {
        if profile.is_empty() || t <= 0.0 {
            return 0.0;
        }
        let omega_at = |s: f64| Self::omega_at(profile, s);
        // Integrate piecewise: breakpoints of omega inside (0, t), trapezoids
        // are exact. The knots are walked in place (no list is made: every
        // kinematic vertex of a rotating script asks this at every internal
        // tick and prediction sample, on every thread at once).
        let inside = profile.iter().map(|p| p.0).filter(|&s| s > 0.0 && s < t);
        let knots = std::iter::once(0.0).chain(inside).chain(std::iter::once(t));
        let mut before: Option<f64> = None;
        knots
            .filter_map(|k| {
                let trapezoid = before.map(|b| 0.5 * (omega_at(b) + omega_at(k)) * (k - b));
                before = Some(k);
                trapezoid
            })
            .sum()
    }

    /// The angular speed of a (non-empty) piecewise-linear `profile` at
    /// time `s`: the first knot's before it, the last one's after it.
    fn omega_at(profile: &[(f64, f64)], s: f64) -> f64 {
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
    }

    /// Position at time `t` of vertex `k` of a script, which is at `x0` at
    /// time 0. Rigid motions move `x0`; a [`Motion::Sequence`] reads vertex
    /// `k`'s own keyframes (and ignores `x0`).
    pub fn position(&self, k: usize, x0: DVec3, t: f64) -> DVec3 {
        match self {
            Motion::Fixed => x0,
            Motion::Translate { velocity, until } => {
                let t = match until {
                    Some(u) => t.min(*u),
                    None => t,
                };
                x0 + *velocity * t.max(0.0)
            }
            Motion::Rotate {
                center,
                axis,
                profile,
            } => {
                let theta = Self::angle(profile, t);
                rotate(x0 - *center, *axis, theta) + *center
            }
            Motion::Sequence(frames) => frames.position(k, t),
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
    /// The scripted position `P(t)` of the script's `k`-th vertex.
    pub fn position(&self, k: usize, t: f64) -> DVec3 {
        self.motion.position(k, self.rest[k], t)
    }

    /// The velocity of the chord from `x_now` (at `t`) to the script's position at `t + h`.
    pub fn chord_velocity(&self, k: usize, x_now: DVec3, t: f64, h: f64) -> DVec3 {
        (self.position(k, t + h) - x_now) / h
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
    fn angle_walked_in_place_has_the_bits_of_the_listed_knots() {
        // The sum as it was, over the knots in a list.
        let listed = |profile: &[(f64, f64)], t: f64| -> f64 {
            if profile.is_empty() || t <= 0.0 {
                return 0.0;
            }
            let omega_at = |s: f64| Motion::omega_at(profile, s);
            let mut knots: Vec<f64> = vec![0.0];
            knots.extend(profile.iter().map(|p| p.0).filter(|&s| s > 0.0 && s < t));
            knots.push(t);
            (knots.windows(2))
                .map(|k| 0.5 * (omega_at(k[0]) + omega_at(k[1])) * (k[1] - k[0]))
                .sum()
        };
        let mut next = crate::uniform_numbers(0x2545_f491_4f6c_dd1d);
        for _ in 0..2000 {
            let knots = (next() * 6.0) as usize;
            let mut at = -0.5 + next();
            let profile: Vec<(f64, f64)> = (0..knots)
                .map(|_| {
                    at += next() * 0.7;
                    (at, next() * 20.0 - 10.0)
                })
                .collect();
            let t = next() * 4.0 - 0.5;
            let (a, b) = (Motion::angle(&profile, t), listed(&profile, t));
            assert_eq!(a.to_bits(), b.to_bits(), "{profile:?} at {t}");
        }
    }

    #[test]
    fn rotation_keeps_distance_to_axis() {
        let m = Motion::Rotate {
            center: DVec3::new(1.0, 0.0, 0.0),
            axis: DVec3::Z,
            profile: vec![(0.0, 1.0)],
        };
        let p = m.position(0, DVec3::new(2.0, 0.0, 0.5), std::f64::consts::FRAC_PI_2);
        assert!((p - DVec3::new(1.0, 1.0, 0.5)).length() < 1e-12);
    }

    #[test]
    fn translate_stops_at_until() {
        let v = DVec3::new(1.0, -2.0, 0.5);
        let x0 = DVec3::new(0.25, 1.0, -1.0);
        let m = Motion::Translate {
            velocity: v,
            until: Some(0.5),
        };
        assert_eq!(m.position(0, x0, 0.0), x0);
        assert_eq!(m.position(0, x0, 0.25), x0 + v * 0.25);
        assert_eq!(m.position(0, x0, 0.5), x0 + v * 0.5);
        assert_eq!(m.position(0, x0, 3.0), x0 + v * 0.5);
        let forever = Motion::Translate {
            velocity: v,
            until: None,
        };
        assert_eq!(forever.position(0, x0, 3.0), x0 + v * 3.0);
        // A chord that straddles `until` ends at the stop, and the next is zero.
        let s = Script {
            name: "pull".into(),
            vertices: vec![0],
            rest: vec![x0],
            motion: m,
        };
        let h = 0.1;
        let x = s.position(0, 0.45);
        let chord = s.chord_velocity(0, x, 0.45, h);
        assert!((x + chord * h - (x0 + v * 0.5)).length() < 1e-15);
        let at_rest = s.position(0, 0.55);
        assert_eq!(s.chord_velocity(0, at_rest, 0.55, h), DVec3::ZERO);
    }

    fn keyframes() -> Keyframes {
        // Two vertices, three frames at 24 fps from t = 0.5; vertex 1 moves
        // differently from vertex 0 (not a rigid motion).
        Keyframes {
            frame_rate: 24.0,
            start: 0.5,
            frames: vec![
                vec![DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0)],
                vec![DVec3::new(0.0, 0.3, 0.0), DVec3::new(1.0, 0.0, 0.7)],
                vec![DVec3::new(0.1, 0.3, 0.0), DVec3::new(0.9, -0.2, 0.7)],
            ],
        }
    }

    #[test]
    fn sequence_hits_frames_exactly_and_interpolates_linearly() {
        let kf = keyframes();
        assert!(kf.validate(2).is_ok());
        assert_eq!(kf.end(), 0.5 + 2.0 / 24.0);
        let m = Motion::Sequence(kf.clone());
        for (i, frame) in kf.frames.iter().enumerate() {
            let t = 0.5 + i as f64 / 24.0;
            for (k, &p) in frame.iter().enumerate() {
                assert_eq!(
                    m.position(k, DVec3::splat(9.0), t),
                    p,
                    "frame {i} vertex {k}"
                );
            }
        }
        // Held before the start and after the end.
        assert_eq!(m.position(1, DVec3::ZERO, 0.0), kf.frames[0][1]);
        assert_eq!(m.position(1, DVec3::ZERO, 100.0), kf.frames[2][1]);
        // A quarter of the way from frame 1 to frame 2.
        let t = 0.5 + 1.25 / 24.0;
        let want = kf.frames[1][1] + (kf.frames[2][1] - kf.frames[1][1]) * 0.25;
        assert!((m.position(1, DVec3::ZERO, t) - want).length() < 1e-14);
        // Continuous across a frame time.
        let eps = 1e-9;
        let t1 = 0.5 + 1.0 / 24.0;
        let jump = m.position(0, DVec3::ZERO, t1 + eps) - m.position(0, DVec3::ZERO, t1 - eps);
        assert!(jump.length() < 1e-6, "{jump:?}");
    }

    #[test]
    fn sequence_chords_follow_each_vertex() {
        let kf = keyframes();
        let s = Script {
            name: "walk".into(),
            vertices: vec![7, 9],
            rest: kf.frames[0].clone(),
            motion: Motion::Sequence(kf.clone()),
        };
        let h = 1.0 / 96.0;
        for k in 0..2 {
            let mut x = s.position(k, 0.0);
            let mut t = 0.0;
            for _ in 0..60 {
                x += s.chord_velocity(k, x, t, h) * h;
                t += h;
                assert!((x - s.position(k, t)).length() < 1e-14);
            }
            assert!((x - kf.frames[2][k]).length() < 1e-14);
        }
    }

    #[test]
    fn keyframes_validation_names_the_problem() {
        let mut kf = keyframes();
        assert!(kf
            .validate(3)
            .unwrap_err()
            .contains("frame 0 has 2 vertices"));
        kf.frames[2].pop();
        assert!(kf
            .validate(2)
            .unwrap_err()
            .contains("frame 2 has 1 vertices"));
        let mut kf = keyframes();
        kf.frame_rate = 0.0;
        assert!(kf.validate(2).unwrap_err().contains("frame rate"));
        let mut kf = keyframes();
        kf.frames[1][0].x = f64::NAN;
        assert!(kf.validate(2).unwrap_err().contains("not finite"));
        kf.frames.clear();
        assert!(kf.validate(2).unwrap_err().contains("no frames"));
    }
}
