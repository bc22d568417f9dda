//! The two flat structures: brute force, and one box around it.

use crate::{AccelStats, Leaf, RayCounter};
use raymesh_geometry::{Aabb, Ray};

/// Tests every primitive in index order: the reference every other
/// structure must agree with.
#[derive(Clone, Debug)]
pub struct BruteForce {
    len: u32,
    bounds: Aabb,
}

impl BruteForce {
    /// A list of the primitives with these boxes.
    #[must_use]
    pub fn new(boxes: &[Aabb]) -> Self {
        Self {
            len: boxes.len() as u32,
            bounds: boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b)),
        }
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub(crate) fn stats(&self) -> AccelStats {
        AccelStats {
            depth: 1,
            sah_cost: self.len as f64,
            ..AccelStats::default()
        }
    }

    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        scan(0..self.len, ray, counter, leaf);
    }
}

/// Offers primitives `range` in order, stopping once the bound drops below `tmin`.
#[inline(always)]
fn scan<C: RayCounter>(
    range: std::ops::Range<u32>,
    ray: &Ray,
    counter: &mut C,
    leaf: &mut impl Leaf,
) {
    for i in range {
        counter.prim();
        if leaf(i) < ray.tmin() {
            return;
        }
    }
}

/// Brute force behind one bounding box (the lecture's BoundedSurface): a ray
/// that misses the box tests nothing.
#[derive(Clone, Debug)]
pub struct BoundedList(BruteForce);

impl BoundedList {
    /// The box around the given primitive boxes.
    #[must_use]
    pub fn new(boxes: &[Aabb]) -> Self {
        Self(BruteForce::new(boxes))
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.0.bounds
    }

    pub(crate) fn stats(&self) -> AccelStats {
        AccelStats {
            nodes: 1,
            leaves: 1,
            depth: 1,
            bytes: std::mem::size_of::<Aabb>(),
            sah_cost: 1.0 + self.0.len as f64,
            ..AccelStats::default()
        }
    }

    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        counter.node();
        if self.0.bounds.intersect_ray(ray, ray.tmax()).is_some() {
            self.0.traverse(ray, counter, leaf);
        }
    }
}
