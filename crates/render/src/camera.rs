//! A pinhole camera.

use raymesh_geometry::{Ray, Vec3};

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
    /// Returns `None` when the frame is degenerate (eye = target, or up parallel to the view).
    #[must_use]
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, vfov_deg: f32, aspect: f32) -> Option<Self> {
        let forward = (target - eye).try_normalize()?;
        let right = forward.cross(up).try_normalize()?;
        let up = right.cross(forward);
        (vfov_deg > 0.0 && vfov_deg < 180.0 && aspect > 0.0).then(|| Self {
            eye,
            forward,
            right,
            up,
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
