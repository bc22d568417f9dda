//! A pinhole camera.

use raymesh_geometry::{unit_vector, Ray, Rays8, Vec3};

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
        // (`unit_vector`: `try_normalize` gave up on an eye more than 1e19
        // units from its target, or less than 1e-19.)
        let forward = Some(unit_vector(target - eye)).filter(|f| *f != Vec3::ZERO)?;
        let right = Some(unit_vector(forward.cross(up))).filter(|r| *r != Vec3::ZERO)?;
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
