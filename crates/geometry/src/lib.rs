//! Geometry kernel of raymesh: rays, axis-aligned boxes, and the ray tests for
//! triangles and spheres.
//!
//! Conventions (as in glam): column vectors, right-handed, `f32` storage. A ray
//! is `origin + t * dir` for `t` in `[tmin, tmax]`; `t` is in units of `dir`,
//! which need not be normalized. Every kernel here is exact in the sense the
//! acceleration structures need: the same inputs give the same bits, whatever
//! structure calls them.

mod aabb;
mod float;
mod octahedral;
mod ray;
mod sphere;
mod triangle;

pub use aabb::{cull_bound, Aabb, CULL_SLACK};
pub use float::{
    exit_reciprocal, gamma, max_nan_second, min_nan_second, next_down, next_up, unit_vector,
    ROBUST_EXIT,
};
pub use glam::{BVec4A, DVec3, Mat3, Mat3A, Mat4, Quat, Vec2, Vec3, Vec3A, Vec4};
pub use octahedral::{decode_unit, encode_unit, ZERO_UNIT};
pub use ray::{Ray, RayLanes8, Rays8};
pub use sphere::{intersect_sphere, Sphere, SphereHit};
pub use triangle::{
    clip_triangle, hit_f64, intersect_triangle, needs_f64, triangle_area2, triangle_hit_bounds,
    triangle_is_degenerate, triangle_normal, TriHit, Triangle,
};
