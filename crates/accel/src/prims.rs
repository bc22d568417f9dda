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
    /// The same primitives in another order: new primitive `k` is old
    /// primitive `order[k]`. A scene built over a BVH uses it to store
    /// primitives in leaf order and drop the permutation's indirection;
    /// `None` (the default) keeps the indirection.
    fn reordered(&self, _order: &[u32]) -> Option<Self>
    where
        Self: Sized,
    {
        None
    }
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
    fn reordered(&self, order: &[u32]) -> Option<Self> {
        Some(Self {
            positions: self.positions.clone(),
            triangles: order.iter().map(|&i| self.triangles[i as usize]).collect(),
        })
    }
}

/// Triangles stored by their corners, 36 bytes each: no index buffer to
/// chase, so a leaf's triangles are one contiguous read once a BVH scene
/// has put them in leaf order. The fastest layout for ray queries, at the
/// price of a copy of the mesh.
#[derive(Clone, Debug, Default)]
pub struct Triangles(pub Vec<[Vec3; 3]>);

impl Triangles {
    /// The corners of an indexed mesh's triangles, in the mesh's order.
    #[must_use]
    pub fn from_mesh(mesh: &TriangleMesh) -> Self {
        Self((0..mesh.len() as u32).map(|i| mesh.corners(i)).collect())
    }

    /// Bytes of the corner buffer.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.0.len() * 36
    }
}

impl Primitives for Triangles {
    #[inline]
    fn len(&self) -> usize {
        self.0.len()
    }
    #[inline]
    fn bounds(&self, i: u32) -> Aabb {
        let [a, b, c] = self.0[i as usize];
        Aabb::from_point(a).grow(b).grow(c)
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let [a, b, c] = self.0[i as usize];
        intersect_triangle(ray, tmax, a, b, c).map(|h| PrimHit {
            t: h.t,
            u: h.u,
            v: h.v,
        })
    }
    fn normal(&self, i: u32, _ray: &Ray, _hit: &PrimHit) -> Vec3 {
        let [a, b, c] = self.0[i as usize];
        (b - a).cross(c - a).normalize_or_zero()
    }
    fn reordered(&self, order: &[u32]) -> Option<Self> {
        Some(Self(order.iter().map(|&i| self.0[i as usize]).collect()))
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
    fn reordered(&self, order: &[u32]) -> Option<Self> {
        Some(Self(order.iter().map(|&i| self.0[i as usize]).collect()))
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
    fn reordered(&self, order: &[u32]) -> Option<Self> {
        Some(Self(order.iter().map(|&i| self.0[i as usize]).collect()))
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
