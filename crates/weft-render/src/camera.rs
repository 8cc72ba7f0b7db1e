//! A perspective look-at camera and its automatic fit to a bounding box.

use glam::DVec3;

/// A perspective camera looking from `eye` at `target`, with `up` giving the
/// roll and `fov_y_degrees` the vertical field of view. Pixels are square, so
/// the horizontal field of view follows from the image aspect ratio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: DVec3,
    pub target: DVec3,
    pub up: DVec3,
    pub fov_y_degrees: f64,
}

/// The orthonormal camera frame: `right`, `up`, `forward` (view space is
/// x right, y up, z forward, so visible points have positive z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Frame {
    pub eye: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    pub forward: DVec3,
    /// `1 / tan(fov_y / 2)`.
    pub focal: f64,
}

impl Frame {
    /// View-space coordinates of world point `p`.
    pub fn view_of(&self, p: DVec3) -> DVec3 {
        let d = p - self.eye;
        DVec3::new(d.dot(self.right), d.dot(self.up), d.dot(self.forward))
    }
}

impl Camera {
    /// Vertical field of view of fitted cameras (degrees).
    pub const DEFAULT_FOV_Y_DEGREES: f64 = 35.0;
    /// Direction of fitted cameras around the `up` axis (degrees).
    pub const FIT_AZIMUTH_DEGREES: f64 = 30.0;
    /// Height of fitted cameras above the horizontal plane (degrees).
    pub const FIT_ELEVATION_DEGREES: f64 = 25.0;
    /// Fitted boxes fill at most `1 / FIT_MARGIN` of the field of view.
    pub const FIT_MARGIN: f64 = 1.1;

    /// Checks that the camera defines a view: finite values, `eye` distinct
    /// from `target`, `up` not parallel to the view direction, and a field of
    /// view strictly between 0° and 180°.
    pub fn validate(&self) -> Result<(), String> {
        let finite = self.eye.is_finite()
            && self.target.is_finite()
            && self.up.is_finite()
            && self.fov_y_degrees.is_finite();
        if !finite {
            return Err(format!("camera has a non-finite value: {self:?}"));
        }
        let forward = self.target - self.eye;
        if forward.length() == 0.0 {
            return Err("camera eye and target coincide".into());
        }
        if forward.normalize().cross(self.up).length() < 1e-9 * self.up.length().max(1e-300) {
            return Err("camera up vector is zero or parallel to the view direction".into());
        }
        if !(self.fov_y_degrees > 0.0 && self.fov_y_degrees < 180.0) {
            return Err(format!(
                "field of view {} degrees; expected a value in (0, 180)",
                self.fov_y_degrees
            ));
        }
        Ok(())
    }

    /// The camera frame.
    ///
    /// # Panics
    /// If [`Camera::validate`] fails.
    pub(crate) fn frame(&self) -> Frame {
        if let Err(e) = self.validate() {
            panic!("invalid camera: {e}");
        }
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        Frame {
            eye: self.eye,
            right,
            up,
            forward,
            focal: 1.0 / (0.5 * self.fov_y_degrees.to_radians()).tan(),
        }
    }

    /// A camera that sees the whole box `[min, max]` in an image of the given
    /// `aspect` (width / height): [`Camera::fit_points`] on the box's eight
    /// corners. A degenerate box (one point) is treated as a unit cube.
    pub fn fit(min: DVec3, max: DVec3, aspect: f64, up: DVec3, fov_y_degrees: f64) -> Camera {
        let (mut lo, mut hi) = (min, max);
        if !((hi - lo).length() > 0.0 && (hi - lo).is_finite()) {
            let c = if (lo + hi).is_finite() {
                0.5 * (lo + hi)
            } else {
                DVec3::ZERO
            };
            (lo, hi) = (c - 0.5, c + 0.5);
        }
        let corners: Vec<DVec3> = (0..8)
            .map(|k| {
                DVec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        fit_cloud(&corners, aspect, up, fov_y_degrees)
    }

    /// A camera that sees all finite `points` in an image of the given
    /// `aspect` (width / height). It looks from azimuth
    /// [`Camera::FIT_AZIMUTH_DEGREES`] and elevation
    /// [`Camera::FIT_ELEVATION_DEGREES`] relative to `up` (for `up = +y` the
    /// azimuth turns from `+z` towards `+x`) at the middle of the points'
    /// extent across the view, from the nearest distance at which every point
    /// projects inside both fields of view shrunk by [`Camera::FIT_MARGIN`].
    /// (A bounding sphere would be simpler but frames flat scenes, such as a
    /// cloth above the ground, far too loosely.) `None` when no point is
    /// finite; coincident points are treated as a unit cube around them; a
    /// zero or non-finite `up` is replaced by `+y`.
    pub fn fit_points<'a>(
        points: impl IntoIterator<Item = &'a DVec3>,
        aspect: f64,
        up: DVec3,
        fov_y_degrees: f64,
    ) -> Option<Camera> {
        let pts: Vec<DVec3> = points
            .into_iter()
            .filter(|p| p.is_finite())
            .copied()
            .collect();
        let (lo, hi) = bounds(&pts)?;
        if lo == hi {
            return Some(Camera::fit(lo, hi, aspect, up, fov_y_degrees));
        }
        Some(fit_cloud(&pts, aspect, up, fov_y_degrees))
    }
}

/// [`Camera::fit_points`] for a non-empty set of finite, not all coincident
/// points.
fn fit_cloud(points: &[DVec3], aspect: f64, up: DVec3, fov_y_degrees: f64) -> Camera {
    let up = if up.is_finite() && up.length() > 0.0 {
        up.normalize()
    } else {
        DVec3::Y
    };
    // A horizontal reference axis: +z unless `up` is close to it.
    let reference = if up.dot(DVec3::Z).abs() < 0.9 {
        DVec3::Z
    } else {
        DVec3::X
    };
    let front = (reference - reference.dot(up) * up).normalize();
    let side = up.cross(front);
    let (az, el) = (
        Camera::FIT_AZIMUTH_DEGREES.to_radians(),
        Camera::FIT_ELEVATION_DEGREES.to_radians(),
    );
    let dir = el.cos() * (az.cos() * front + az.sin() * side) + el.sin() * up;
    // The camera frame for this direction (as in `Camera::frame`).
    let forward = -dir;
    let right = forward.cross(up).normalize();
    let cam_up = right.cross(forward);
    let (lo, hi) = bounds(points).unwrap_or((DVec3::ZERO, DVec3::ONE));
    let center = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    // Aim at the middle of the extent across the view, so the picture is
    // centred even when the box's centre is not.
    let extent = |axis: DVec3| {
        points.iter().fold((f64::MAX, f64::MIN), |(a, b), p| {
            let t = (*p - center).dot(axis);
            (a.min(t), b.max(t))
        })
    };
    let (r0, r1) = extent(right);
    let (u0, u1) = extent(cam_up);
    let target = center + 0.5 * (r0 + r1) * right + 0.5 * (u0 + u1) * cam_up;
    let tan_y = (0.5 * fov_y_degrees.to_radians()).tan() / Camera::FIT_MARGIN;
    let tan_x = tan_y * aspect.max(1e-6);
    // Point o (relative to the target) at eye distance d has view depth
    // d + o.forward and must satisfy |o.right| <= tan_x * depth, likewise for
    // up; the eye also stays a little outside the points' bounding sphere.
    let mut distance = 0.0f64;
    for p in points {
        let o = *p - target;
        let depth_offset = o.dot(forward);
        distance = distance
            .max(o.dot(right).abs() / tan_x - depth_offset)
            .max(o.dot(cam_up).abs() / tan_y - depth_offset)
            .max(0.1 * radius - depth_offset);
    }
    Camera {
        eye: target + distance * dir,
        target,
        up,
        fov_y_degrees,
    }
}

/// The bounding box of the finite points, if any.
pub(crate) fn bounds<'a>(points: impl IntoIterator<Item = &'a DVec3>) -> Option<(DVec3, DVec3)> {
    let mut it = points.into_iter().filter(|p| p.is_finite());
    let first = *it.next()?;
    Some(it.fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fitted_camera_looks_at_the_centre_from_above() {
        let c = Camera::fit(
            DVec3::splat(-1.0),
            DVec3::splat(1.0),
            4.0 / 3.0,
            DVec3::Y,
            35.0,
        );
        assert!(c.validate().is_ok());
        assert!(c.target.length() < 1e-12, "{:?}", c.target);
        let d = c.eye - c.target;
        assert!(d.y > 0.0 && d.x > 0.0 && d.z > d.x);
        let elevation = (d.y / d.length()).asin().to_degrees();
        assert!((elevation - 25.0).abs() < 1e-9);
        // Every corner projects inside the field of view, the widest one
        // close to its edge.
        let f = c.frame();
        let tan = (17.5f64).to_radians().tan();
        let mut widest = 0.0f64;
        for k in 0..8 {
            let p = DVec3::new(
                if k & 1 == 0 { -1.0 } else { 1.0 },
                if k & 2 == 0 { -1.0 } else { 1.0 },
                if k & 4 == 0 { -1.0 } else { 1.0 },
            );
            let v = f.view_of(p);
            assert!(v.z > 0.0);
            widest = widest
                .max((v.x / v.z / (4.0 / 3.0)).abs())
                .max((v.y / v.z).abs());
        }
        assert!(widest <= tan / Camera::FIT_MARGIN + 1e-12, "{widest}");
        assert!(widest > 0.99 * tan / Camera::FIT_MARGIN, "{widest}");
    }

    #[test]
    fn invalid_cameras_are_rejected() {
        let ok = Camera {
            eye: DVec3::new(0.0, 0.0, 5.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_degrees: 40.0,
        };
        assert!(ok.validate().is_ok());
        assert!(Camera {
            target: ok.eye,
            ..ok
        }
        .validate()
        .is_err());
        assert!(Camera { up: DVec3::Z, ..ok }.validate().is_err());
        assert!(Camera {
            fov_y_degrees: 180.0,
            ..ok
        }
        .validate()
        .is_err());
        assert!(Camera {
            eye: DVec3::NAN,
            ..ok
        }
        .validate()
        .is_err());
    }
}
