//! The ray workloads of `../shared/BENCH.md`, defined from a mesh's box:
//! `primary` (pinhole camera), `random`, `diffuse` (cosine-weighted bounce
//! from primary hits) and `shadow` (toward a point light, any-hit).
//! Rays are generated with a fixed-seed SplitMix64, written out here so the
//! same workload comes out bit for bit on every machine and crate version.

use raymesh_accel::{Aabb, Ray, Surface};
use raymesh_geometry::{unit_vector, Vec3};
use std::str::FromStr;

/// A named workload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Workload {
    /// One ray per pixel of a `size × size` pinhole image.
    Primary,
    /// `size²` rays from a sphere around the mesh toward points in its box.
    Random,
    /// One cosine-weighted bounce per primary hit.
    Diffuse,
    /// One shadow ray per primary hit toward a point light (any-hit).
    Shadow,
}

impl Workload {
    /// Every workload, in BENCH.md's order.
    pub const ALL: [Workload; 4] = [Self::Primary, Self::Random, Self::Diffuse, Self::Shadow];

    /// The name BENCH.md uses.
    pub fn name(self) -> &'static str {
        match self {
            Self::Primary => "primary",
            Self::Random => "random",
            Self::Diffuse => "diffuse",
            Self::Shadow => "shadow",
        }
    }
}

impl FromStr for Workload {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|w| w.name() == s)
            .ok_or_else(|| {
                format!("unknown workload '{s}'; expected primary, random, diffuse or shadow")
            })
    }
}

/// SplitMix64 (Steele, Lea & Flood 2014): tiny, fast, and fixed forever.
pub struct SplitMix(u64);

impl SplitMix {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Uniform direction on the unit sphere.
fn unit_sphere(rng: &mut SplitMix) -> Vec3 {
    let z = 1.0 - 2.0 * rng.next_f32();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * rng.next_f32();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// BENCH.md's camera: eye, and the direction of pixel `(x, y)`.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    width: u32,
    height: u32,
    tan_half: f32,
}

impl Camera {
    /// A pinhole camera looking from `eye` at `target`.
    pub fn look_at(
        eye: Vec3,
        target: Vec3,
        up: Vec3,
        vfov_deg: f32,
        width: u32,
        height: u32,
    ) -> Self {
        // (`unit_vector`: `normalize` overflowed past 1e19 units.)
        let forward = unit_vector(target - eye);
        let right = unit_vector(forward.cross(up));
        let up = right.cross(forward);
        Self {
            eye,
            forward,
            right,
            up,
            width,
            height,
            tan_half: (vfov_deg.to_radians() * 0.5).tan(),
        }
    }

    /// BENCH.md's primary camera for a box: target its centre, eye at
    /// `c + normalize(1, 0.6, 1.6) d`, up +Y, 40° vertical field of view.
    pub fn framing(b: &Aabb, width: u32, height: u32) -> Self {
        // (A box of one point still gets a camera; a box of any size, as
        // small as 1e-19, is framed on its own diagonal: at least 1e-6
        // had put the camera over a mesh of 1e-15 as over a speck.)
        let d = b.diagonal();
        let (c, d) = (b.centroid(), if d > 0.0 { d } else { 1e-6 });
        let eye = c + Vec3::new(1.0, 0.6, 1.6).normalize() * d;
        Self::look_at(eye, c, Vec3::Y, 40.0, width, height)
    }

    /// Unit direction through the point `(x, y)` of the image (pixel units,
    /// row 0 at the top; `x + 0.5` is a pixel centre).
    pub fn dir(&self, x: f32, y: f32) -> Vec3 {
        let aspect = self.width as f32 / self.height as f32;
        let sx = (2.0 * x / self.width as f32 - 1.0) * self.tan_half * aspect;
        let sy = (1.0 - 2.0 * y / self.height as f32) * self.tan_half;
        (self.forward + sx * self.right + sy * self.up).normalize()
    }

    /// The camera's up vector.
    pub fn up(&self) -> Vec3 {
        self.up
    }
}

/// Makes the rays of a workload for a scene whose box is `b`. `size` is the
/// image width and height (primary, diffuse, shadow) or its square root
/// (random). Rays are `[ox, oy, oz, tmin, dx, dy, dz, tmax]`.
pub fn make_rays(w: Workload, scene: &dyn Surface, size: u32, seed: u64) -> Vec<[f32; 8]> {
    make_rays_framing(w, scene, scene.bounds(), size, seed)
}

/// A packed ray `[ox, oy, oz, tmin, dx, dy, dz, tmax]` (the rows
/// [`make_rays`] returns and BENCH.md's `.npy` files hold) as a [`Ray`].
pub fn unpack_ray(r: [f32; 8]) -> Ray {
    row_ray(&r)
}

/// [`unpack_ray`], inlined into its caller: a loop that collects rays
/// then makes each where it stores it (`unpack_ray`, a call, returns each
/// through memory; `raymesh-peers --stream` spent 10% of its samples
/// copying them).
#[inline]
pub fn row_ray(r: &[f32; 8]) -> Ray {
    Ray::from_row(r)
}

/// Reads a `--frame` box: six numbers `minx,miny,minz,maxx,maxy,maxz`,
/// finite, min ≤ max on each axis.
pub fn parse_frame(text: &str) -> anyhow::Result<Aabb> {
    let bad = || {
        anyhow::anyhow!(
            "--frame {text:?}: expected six finite numbers, min ≤ max on each axis: minx,miny,minz,maxx,maxy,maxz"
        )
    };
    let v: Vec<f32> = text
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|_| bad()))
        .collect::<anyhow::Result<_>>()?;
    if v.len() != 6 {
        return Err(bad());
    }
    let (lo, hi) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
    if !(lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()) {
        return Err(bad());
    }
    Ok(Aabb::new(lo, hi))
}

/// [`make_rays`] with the camera framing box `b` instead of the scene's
/// box (random rays then start around `b` and aim at points in it): to aim
/// a workload at one part of a scene, such as the teapot in a stadium.
pub fn make_rays_framing(
    w: Workload,
    scene: &dyn Surface,
    b: Aabb,
    size: u32,
    seed: u64,
) -> Vec<[f32; 8]> {
    if b.is_empty() || scene.bounds().is_empty() {
        return Vec::new();
    }
    let (c, d) = (b.centroid(), b.diagonal());
    let pack = |o: Vec3, dir: Vec3, tmax: f32| [o.x, o.y, o.z, 0.0, dir.x, dir.y, dir.z, tmax];
    let mut rng = SplitMix::new(seed);
    let cam = Camera::framing(&b, size, size);
    let cam = &cam;
    let primary = || {
        (0..size * size).map(move |i| {
            let (x, y) = (i % size, i / size);
            (cam.eye, cam.dir(x as f32 + 0.5, y as f32 + 0.5))
        })
    };
    match w {
        Workload::Primary => primary()
            .map(|(o, dir)| pack(o, dir, f32::INFINITY))
            .collect(),
        Workload::Random => (0..size * size)
            .map(|_| {
                let o = c + unit_sphere(&mut rng) * 0.75 * d;
                let p = b.min
                    + (b.max - b.min) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                pack(o, unit_vector(p - o), f32::INFINITY)
            })
            .collect(),
        Workload::Diffuse | Workload::Shadow => {
            let light = cam.eye + 0.5 * d * cam.up();
            let mut out = Vec::new();
            for (o, dir) in primary() {
                let Some(h) = scene.intersect(&Ray::infinite(o, dir)) else {
                    continue;
                };
                let n = if h.normal.dot(dir) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                let p = o + h.t * dir + 1e-4 * d * n;
                if w == Workload::Shadow {
                    let to = light - p;
                    // Past 1e19 units `length` overflows: then in f64.
                    let dist = match to.length() {
                        d if d.is_finite() && d >= f32::MIN_POSITIVE => d,
                        _ => to.as_dvec3().length() as f32,
                    };
                    out.push(pack(p, to / dist, dist));
                } else {
                    // Cosine-weighted about n (Malley's method).
                    let (r, phi) = (
                        rng.next_f32().sqrt(),
                        std::f32::consts::TAU * rng.next_f32(),
                    );
                    let (x, y) = (r * phi.cos(), r * phi.sin());
                    let z = (1.0 - x * x - y * y).max(0.0).sqrt();
                    let (t1, t2) = n.any_orthonormal_pair();
                    out.push(pack(
                        p,
                        (x * t1 + y * t2 + z * n).normalize(),
                        f32::INFINITY,
                    ));
                }
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use raymesh_accel::{AccelKind, Scene, TriangleMesh};

    /// A tetrahedron of size `s`.
    fn tet(s: f32) -> Scene<TriangleMesh> {
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.1, 0.0],
            [0.2, 1.0, 0.0],
            [0.3, 0.2, 1.0],
        ]
        .map(|v| Vec3::from_array(v) * s)
        .to_vec();
        let triangles = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        Scene::build(
            TriangleMesh {
                positions,
                triangles,
            },
            AccelKind::Brute,
        )
    }

    /// The workloads frame a scene of any size alike: the same number of
    /// rays hit a tetrahedron 1e-19 and 1e30 units across as a unit one.
    /// (The camera had been put 1e-6 from any smaller scene, and past 1e19
    /// its `normalize` overflowed: no ray hit.)
    #[test]
    fn workloads_hit_alike_at_any_scale() {
        let hits = |s: f32, w: Workload| {
            let scene = tet(s);
            make_rays(w, &scene, 24, 7)
                .iter()
                .filter(|r| scene.intersect(&unpack_ray(**r)).is_some())
                .count()
        };
        for w in [Workload::Primary, Workload::Random] {
            let unit = hits(1.0, w);
            assert!(unit > 100, "{unit}");
            for s in [1e30f32, 1e20, 1e-15, 1e-19] {
                assert_eq!(hits(s, w), unit, "{w:?} at {s}");
            }
        }
    }
}
