//! What structures index: primitives with bounds and a ray test.

use raymesh_geometry::{intersect_sphere, intersect_triangle, Aabb, Ray, Sphere, Vec3};

/// Hit of one primitive: distance and two surface coordinates (barycentric
/// weights of the 2nd and 3rd corner for triangles; `φ/2π`, `θ/π` for spheres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimHit {
    /// Ray parameter.
    pub t: f32,
    /// First surface coordinate.
    pub u: f32,
    /// Second surface coordinate.
    pub v: f32,
}

/// A set of primitives addressed by `u32` index: what a structure is built over.
pub trait Primitives: Send + Sync {
    /// Number of primitives.
    fn len(&self) -> usize;
    /// Whether there are none.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Bounding box of primitive `i`.
    fn bounds(&self, i: u32) -> Aabb;
    /// Ray test of primitive `i` over `[ray.tmin, tmax]` (both ends included).
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit>;
    /// Unit geometric normal of primitive `i` at a hit (not flipped toward the ray).
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3;
}

/// Triangles sharing one vertex buffer: the lecture's TriangleMesh.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Corner indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Makes a mesh; every index must be below `positions.len()`.
    #[must_use]
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        assert!(
            triangles
                .iter()
                .flatten()
                .all(|&i| (i as usize) < positions.len()),
            "triangle index out of range"
        );
        Self {
            positions,
            triangles,
        }
    }

    /// The corners of triangle `i`.
    #[inline(always)]
    #[must_use]
    pub fn corners(&self, i: u32) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[i as usize];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Bytes of the vertex and index buffers.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.positions.len() * 12 + self.triangles.len() * 12
    }
}

impl Primitives for TriangleMesh {
    #[inline]
    fn len(&self) -> usize {
        self.triangles.len()
    }
    #[inline]
    fn bounds(&self, i: u32) -> Aabb {
        let [a, b, c] = self.corners(i);
        Aabb::from_point(a).grow(b).grow(c)
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let [a, b, c] = self.corners(i);
        intersect_triangle(ray, tmax, a, b, c).map(|h| PrimHit {
            t: h.t,
            u: h.u,
            v: h.v,
        })
    }
    fn normal(&self, i: u32, _ray: &Ray, _hit: &PrimHit) -> Vec3 {
        let [a, b, c] = self.corners(i);
        (b - a).cross(c - a).normalize_or_zero()
    }
}

/// A list of spheres.
#[derive(Clone, Debug, Default)]
pub struct Spheres(pub Vec<Sphere>);

impl Primitives for Spheres {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        self.0[i as usize].bounds()
    }
    #[inline]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let s = self.0[i as usize];
        intersect_sphere(ray, tmax, s.center, s.radius).map(|h| PrimHit {
            t: h.t,
            u: h.u,
            v: h.v,
        })
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        self.0[i as usize].normal_at(ray.at(hit.t))
    }
}

/// One primitive of a mixed list.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A triangle by its corners.
    Triangle([Vec3; 3]),
    /// A sphere.
    Sphere(Sphere),
}

/// Triangles and spheres mixed in one list.
#[derive(Clone, Debug, Default)]
pub struct Shapes(pub Vec<Shape>);

impl Primitives for Shapes {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        match &self.0[i as usize] {
            Shape::Triangle([a, b, c]) => Aabb::from_point(*a).grow(*b).grow(*c),
            Shape::Sphere(s) => s.bounds(),
        }
    }
    #[inline]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        match &self.0[i as usize] {
            Shape::Triangle([a, b, c]) => {
                intersect_triangle(ray, tmax, *a, *b, *c).map(|h| PrimHit {
                    t: h.t,
                    u: h.u,
                    v: h.v,
                })
            }
            Shape::Sphere(s) => intersect_sphere(ray, tmax, s.center, s.radius).map(|h| PrimHit {
                t: h.t,
                u: h.u,
                v: h.v,
            }),
        }
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        match &self.0[i as usize] {
            Shape::Triangle([a, b, c]) => (*b - *a).cross(*c - *a).normalize_or_zero(),
            Shape::Sphere(s) => s.normal_at(ray.at(hit.t)),
        }
    }
}

impl<P: Primitives + ?Sized> Primitives for &P {
    fn len(&self) -> usize {
        (**self).len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        (**self).bounds(i)
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        (**self).intersect(i, ray, tmax)
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        (**self).normal(i, ray, hit)
    }
}
