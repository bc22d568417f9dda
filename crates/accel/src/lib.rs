//! Acceleration structures for ray queries, interchangeable behind one small
//! interface and exact: each returns what brute force returns.
//!
//! - [`Primitives`] is what a structure indexes: anything with per-primitive
//!   bounds and a ray test (triangles, spheres, a mix of both).
//! - [`Accel`] is the structure, chosen by [`AccelKind`] in one factory,
//!   [`Accel::build`]. Structures never see primitives while traversing:
//!   builders get boxes and centroids, traversals call a leaf closure.
//! - [`Scene`] ties primitives and a structure together and answers the
//!   [`Surface`] questions: bounds, closest hit, any hit.
//!
//! Exactness: the closest hit is the least `(t, prim)` pair, and every
//! structure culls a node only when its entry distance is strictly beyond
//! the best `t` found, so ties resolve the same way everywhere and the
//! result is bit-identical to brute force.
//!
//! ```
//! use raymesh_accel::{AccelKind, Ray, Scene, Surface, TriangleMesh, Vec3};
//!
//! let mesh = TriangleMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]);
//! let scene = Scene::from_mesh(&mesh, AccelKind::FASTEST_BVH);
//! let ray = Ray::new(Vec3::new(0.25, 0.25, 1.0), -Vec3::Z, 0.0, f32::INFINITY);
//! let hit = scene.intersect(&ray).expect("a hit");
//! assert_eq!(hit.prim, 0);
//! assert!((hit.t - 1.0).abs() < 1e-6 && (hit.u - 0.25).abs() < 1e-6);
//! // Every structure answers with the same bits.
//! for kind in AccelKind::ALL {
//!     let h = Scene::from_mesh(&mesh, kind).intersect(&ray).expect("a hit");
//!     assert_eq!([h.t, h.u, h.v].map(f32::to_bits), [hit.t, hit.u, hit.v].map(f32::to_bits));
//! }
//! ```

mod accel;
mod brute;
pub mod bvh;
mod grid;
mod instance;
mod kdtree;
#[cfg(all(target_arch = "aarch64", target_feature = "neon"))]
mod neon;
mod packet;
mod pages;
mod prims;
mod scene;
mod simd;
mod stats;
#[cfg(test)]
mod test_util;

pub use accel::{Accel, AccelKind, BuildConfig};
pub use brute::{BoundedList, BruteForce};
pub use bvh::{Bvh, Bvh4, Bvh8, BvhBuilder, Clip};
pub use grid::Grid;
pub use instance::{Instance, Instances, PACKET_INSTANCES};
pub use kdtree::KdTree;
pub use packet::{Packet8, LANES};
pub use prims::{
    BlockHits, PrimHit, Primitives, Shape, Shapes, Spheres, TriangleMesh, Triangles, BLOCK,
};
pub use raymesh_geometry::{Aabb, Ray, Rays8, Vec3};
pub use scene::{BareHit, Hit, Scene, Surface};
pub use simd::{set_avx512_enabled, set_simd_enabled, Avx2, BlockRay};
pub use stats::{AccelStats, CountStats, NoStats, RayCounter};

/// Leaf callback of a traversal: tests primitive `prim` and returns the
/// ray's new upper bound (the best hit's `t`, or `-inf` to stop at once).
pub(crate) trait Leaf: FnMut(u32) -> f32 {}
impl<F: FnMut(u32) -> f32> Leaf for F {}

/// Calls `leaf` on each primitive of `prims` in order until it returns a
/// bound below the ray's `tmin`; returns the last bound (the ray's `tmax`
/// for none). The one-by-one leaf loop of every traversal.
#[inline(always)]
pub(crate) fn test_each(
    prims: impl IntoIterator<Item = u32>,
    ray: &Ray,
    leaf: &mut impl Leaf,
) -> f32 {
    let mut tmax = ray.tmax();
    for p in prims {
        tmax = leaf(p);
        if tmax < ray.tmin() {
            break;
        }
    }
    tmax
}

/// A list callback for traversals that hand out lists of primitives:
/// [`test_each`] over the list.
#[inline(always)]
pub(crate) fn each_id<'a>(ray: &'a Ray, leaf: &'a mut impl Leaf) -> impl FnMut(&[u32]) -> f32 + 'a {
    move |ids| test_each(ids.iter().copied(), ray, leaf)
}
