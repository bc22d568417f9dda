//! A pinhole camera.

use raymesh_geometry::{unit_vector, Ray, Rays8, Vec3};

/// The sine of the least angle between a camera's up vector and its
/// view ([`Camera::try_look_at`]): 1e-5, about 0.0006 degrees. Two unit
/// vectors along one line, each rounded to `f32`, leave a cross product
/// of a few 1e-8; a camera set up so close to looking along its up
/// vector has no orientation worth keeping.
pub const UP_ALONG_VIEW: f32 = 1e-5;

/// Why [`Camera::try_look_at`] cannot make a camera.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The eye or the target has an infinite or NaN coordinate.
    #[error("the eye and the target need finite coordinates")]
    NotFinite,
    /// The eye is the target: no view direction.
    #[error("the eye is the target: no direction to look in")]
    EyeAtTarget,
    /// The up vector is zero or not finite.
    #[error("up is zero or not finite")]
    NoUp,
    /// The up vector lies along the view (or its opposite).
    #[error(
        "up lies along the view (within {UP_ALONG_VIEW:e} radians of the line from the eye to the \
         target): which way is up would be rounding noise"
    )]
    UpAlongView,
    /// The vertical field of view is not within (0, 180) degrees.
    #[error("fov {0} is not within (0, 180) degrees")]
    Fov(f32),
    /// The image's width over its height is not a positive number.
    #[error("aspect ratio {0} is not a positive number")]
    Aspect(f32),
}

/// Pinhole camera: an eye, an orthonormal frame and a vertical field of view.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half: f32,
    aspect: f32,
}

impl Camera {
    /// A camera at `eye` looking at `target`; `vfov_deg` is the vertical field of view.
    /// Returns `None` when the camera cannot be made (eye = target, up
    /// along the view, fov outside (0, 180), aspect not positive);
    /// [`Self::try_look_at`] says which.
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, vfov_deg: f32, aspect: f32) -> Option<Self> {
        Self::try_look_at(eye, target, up, vfov_deg, aspect).ok()
    }

    /// [`Self::look_at`], or what makes the frame degenerate. `up` need
    /// not be a unit vector nor square with the view, but it must point
    /// somewhere else than along it: within [`UP_ALONG_VIEW`] radians of
    /// the view (or of its opposite) its cross product with the view is
    /// rounding noise, and the image would turn by whatever that noise
    /// says.
    pub fn try_look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        vfov_deg: f32,
        aspect: f32,
    ) -> Result<Self, CameraError> {
        if !(eye.is_finite() && target.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        // (`unit_vector`: `try_normalize` gave up on an eye more than 1e19
        // units from its target, or less than 1e-19; and in `f64` where
        // the difference itself leaves `f32`, an eye and a target on
        // either side of 2e38.)
        let to_target = target - eye;
        let forward = if to_target.is_finite() {
            unit_vector(to_target)
        } else {
            (target.as_dvec3() - eye.as_dvec3())
                .normalize_or_zero()
                .as_vec3()
        };
        if forward == Vec3::ZERO {
            return Err(CameraError::EyeAtTarget);
        }
        let up_dir = unit_vector(up);
        if up_dir == Vec3::ZERO {
            return Err(CameraError::NoUp);
        }
        let side = forward.cross(up_dir);
        if !(side.length() > UP_ALONG_VIEW) {
            return Err(CameraError::UpAlongView);
        }
        if !(vfov_deg > 0.0 && vfov_deg < 180.0) {
            return Err(CameraError::Fov(vfov_deg));
        }
        if !(aspect > 0.0 && aspect.is_finite()) {
            return Err(CameraError::Aspect(aspect));
        }
        let right = unit_vector(side);
        Ok(Self {
            eye,
            forward,
            right,
            up: right.cross(forward),
            tan_half: (vfov_deg.to_radians() * 0.5).tan(),
            aspect,
        })
    }

    /// The ray through image point `(sx, sy)` in `[0, 1]²` (y down).
    /// Inlined into the renderer's loop, where each ray is made in place
    /// and its divisions overlap the next ray's (called, it returned each
    /// ray through memory: 10% of a render's samples).
    #[must_use]
    #[inline]
    pub fn ray(&self, sx: f32, sy: f32) -> Ray {
        let x = (2.0 * sx - 1.0) * self.tan_half * self.aspect;
        let y = (1.0 - 2.0 * sy) * self.tan_half;
        Ray::infinite(
            self.eye,
            (self.forward + x * self.right + y * self.up).normalize(),
        )
    }

    /// The rays through eight image points (`sx[i]`, `sy[i]`), each
    /// [`Self::ray`]'s bit for bit: the directions made lane by lane in
    /// rows (the same operations in the same order, which the compiler
    /// makes a SIMD step for four or eight lanes), the rays by
    /// [`Rays8::rays`]. Neighbouring pixels' rays share their octant and
    /// axis order, so their reciprocals and shear take a division a row,
    /// not one a ray.
    #[must_use]
    #[inline]
    pub fn rays8(&self, sx: &[f32; 8], sy: &[f32; 8]) -> [Ray; 8] {
        let (f, r, u) = (self.forward, self.right, self.up);
        let mut rays = Rays8 {
            origin: self.eye.to_array().map(|e| [e; 8]),
            dir: [[0.0; 8]; 3],
            tmin: [0.0; 8],
            tmax: [f32::INFINITY; 8],
        };
        for i in 0..8 {
            let x = (2.0 * sx[i] - 1.0) * self.tan_half * self.aspect;
            let y = (1.0 - 2.0 * sy[i]) * self.tan_half;
            // `forward + x * right + y * up`, then glam's `normalize`:
            // times `1 / sqrt(dot)`, the dot product summed left to right.
            let v = [
                f.x + x * r.x + y * u.x,
                f.y + x * r.y + y * u.y,
                f.z + x * r.z + y * u.z,
            ];
            let inv = 1.0 / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            for a in 0..3 {
                rays.dir[a][i] = v[a] * inv;
            }
        }
        rays.rays()
    }

    /// Eye position.
    #[must_use]
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// Unit up vector of the frame.
    #[must_use]
    pub fn up(&self) -> Vec3 {
        self.up
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each degenerate frame is refused with its own reason; an up vector
    /// a little off the view still makes an orthonormal frame with up
    /// on the side it points to.
    #[test]
    fn degenerate_frames_say_why() {
        let (eye, target) = (Vec3::new(0.4, 2.2, 7.5), Vec3::ZERO);
        let look = |eye, target, up, fov| Camera::try_look_at(eye, target, up, fov, 1.5);
        assert_eq!(
            look(eye, eye, Vec3::Y, 40.0).err(),
            Some(CameraError::EyeAtTarget)
        );
        assert_eq!(
            look(eye, target, Vec3::ZERO, 40.0).err(),
            Some(CameraError::NoUp)
        );
        assert_eq!(
            look(Vec3::new(f32::NAN, 0.0, 0.0), target, Vec3::Y, 40.0).err(),
            Some(CameraError::NotFinite)
        );
        // An eye and a target whose difference leaves `f32`.
        let far = Vec3::new(0.0, 0.0, 3e38);
        let c = look(-far, far, Vec3::Y, 40.0).unwrap();
        assert_eq!(c.forward, Vec3::Z);
        // Along the view, either way, at any length: the rounded cross
        // product is not zero, but it is noise.
        for up in [eye, -eye * 3.0, eye * 1e-20, eye * 1e20] {
            assert_eq!(
                look(eye, target, up, 40.0).err(),
                Some(CameraError::UpAlongView),
                "{up}"
            );
        }
        for fov in [0.0, 180.0, -5.0, f32::NAN] {
            assert!(matches!(
                look(eye, target, Vec3::Y, fov),
                Err(CameraError::Fov(_))
            ));
        }
        assert!(matches!(
            Camera::try_look_at(eye, target, Vec3::Y, 40.0, 0.0),
            Err(CameraError::Aspect(_))
        ));
        // Looking nearly straight down, up 1e-3 radians off the view.
        let down = Vec3::new(0.0, 10.0, 0.01);
        let c = look(down, target, Vec3::Y, 40.0).unwrap();
        for (a, b) in [(c.forward, c.right), (c.right, c.up), (c.up, c.forward)] {
            assert!(a.dot(b).abs() < 1e-5, "{a} {b}");
        }
        for v in [c.forward, c.right, c.up] {
            assert!((v.length() - 1.0).abs() < 1e-6, "{v}");
        }
        assert!(c.up.z < 0.0 && c.forward.y < 0.0, "{c:?}");
        assert_eq!(
            Camera::look_at(eye, target, Vec3::Y, 40.0, 1.5).map(|c| c.forward),
            look(eye, target, Vec3::Y, 40.0).ok().map(|c| c.forward)
        );
    }

    /// `rays8` makes each point's `ray` bit for bit, by rows where the
    /// eight share an octant and axis order and one by one where they do
    /// not: random cameras, with points clustered (a pixel's samples and
    /// its neighbours') or spread over the image, the centre and the
    /// edges among them.
    #[test]
    fn rays8_are_each_points_ray() {
        let mut state = 0x2545_f491_u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            f64::from(state) as f32 / u32::MAX as f32
        };
        let bits = |r: &Ray| {
            let (s, k) = r.shear();
            let v = |v: Vec3| v.to_array().map(f32::to_bits);
            (
                v(r.origin()),
                v(r.dir()),
                v(r.inv_dir()),
                v(s),
                k,
                r.tmin().to_bits(),
                r.tmax().to_bits(),
            )
        };
        let (mut rows, mut single) = (0, 0);
        for _ in 0..20_000 {
            let mut v = || Vec3::new(next(), next(), next()) * 20.0 - 10.0;
            let (eye, target, up) = (v(), v(), v());
            let fov = 1.0 + 170.0 * next();
            let Some(camera) = Camera::look_at(eye, target, up, fov, 0.25 + 3.0 * next()) else {
                continue;
            };
            let spread = [1.0, 0.01, 1e-4][(next() * 3.0) as usize % 3];
            let (cx, cy) = (next(), next());
            let mut pick = |c: f32| match (next() * 16.0) as u32 {
                0 => 0.0,
                1 => 1.0,
                2 => 0.5,
                _ => (c + spread * (next() - 0.5)).clamp(0.0, 1.0),
            };
            let sx: [f32; 8] = std::array::from_fn(|_| pick(cx));
            let sy: [f32; 8] = std::array::from_fn(|_| pick(cy));
            let made = camera.rays8(&sx, &sy);
            for i in 0..8 {
                assert_eq!(
                    bits(&made[i]),
                    bits(&camera.ray(sx[i], sy[i])),
                    "{sx:?} {sy:?}"
                );
            }
            let each: [Ray; 8] = std::array::from_fn(|i| camera.ray(sx[i], sy[i]));
            if Rays8::from_rays(&each).lanes().is_some() {
                rows += 1;
            } else {
                single += 1;
            }
        }
        // Both ways exercised, each often.
        assert!(
            rows > 1000 && single > 1000,
            "{rows} by rows, {single} one by one"
        );
    }
}
