//! Axis-aligned bounding boxes and the slab test.

use crate::float::{exit_reciprocal, max_nan_second, min_nan_second};
use crate::Ray;
use glam::Vec3;

/// An axis-aligned box `[min, max]`. The empty box has `min = +inf`,
/// `max = -inf`, so that growing it by any point gives that point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// Relative slack added to a ray's upper bound before it culls boxes
/// ([`cull_bound`]; public for SIMD kernels that compute the same bound
/// for several rays at once).
pub const CULL_SLACK: f32 = 1e-5;

/// The bound a traversal culls boxes against, given the best hit's `t`:
/// a few ulps above it, because a primitive's `t` and its box's entry are
/// rounded independently, and a box whose entry rounds just above a tied
/// hit must still be visited for the tie to resolve exactly.
#[inline(always)]
#[must_use]
pub fn cull_bound(t: f32) -> f32 {
    t + t.abs() * CULL_SLACK
}

impl Aabb {
    /// The empty box, identity of `union`.
    pub const EMPTY: Self = Self {
        min: Vec3::INFINITY,
        max: Vec3::NEG_INFINITY,
    };

    /// The box with the given corners (not reordered).
    #[inline]
    #[must_use]
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    /// The smallest box holding one point.
    #[inline]
    #[must_use]
    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }

    /// The smallest box holding every point of the iterator.
    #[must_use]
    pub fn from_points<I: IntoIterator<Item = Vec3>>(points: I) -> Self {
        points.into_iter().fold(Self::EMPTY, Self::grow)
    }

    /// Whether the box holds no point (`min > max` on some axis).
    #[inline]
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// The box grown to hold `p`.
    #[inline]
    #[must_use]
    pub fn grow(self, p: Vec3) -> Self {
        Self {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The smallest box holding both boxes.
    #[inline]
    #[must_use]
    pub fn union(self, other: Self) -> Self {
        Self {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// The overlap of both boxes (possibly empty).
    #[inline]
    #[must_use]
    pub fn intersection(self, other: Self) -> Self {
        Self {
            min: self.min.max(other.min),
            max: self.max.min(other.max),
        }
    }

    /// `max - min`, zero for the empty box.
    #[inline]
    #[must_use]
    pub fn extent(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    /// Centre of the box.
    #[inline]
    #[must_use]
    pub fn centroid(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// The parts of the box on each side of the plane `axis = pos`: the box
    /// cut to `[min, pos]` and to `[pos, max]` on that axis (empty on a side
    /// the box does not reach). The spatial-split builder clips primitives
    /// it knows only by their boxes this way; a NaN `pos` cuts nothing.
    #[inline]
    #[must_use]
    pub fn split(self, axis: usize, pos: f32) -> (Self, Self) {
        let (mut left, mut right) = (self, self);
        left.max[axis] = min_nan_second(pos, left.max[axis]);
        right.min[axis] = max_nan_second(pos, right.min[axis]);
        (left, right)
    }

    /// Surface area; zero for the empty box. SAH builders use it (MacDonald & Booth 1990).
    #[inline]
    #[must_use]
    pub fn surface_area(&self) -> f32 {
        2.0 * self.half_area()
    }

    /// Half the surface area, `xy + yz + zx`: all a SAH comparison needs.
    #[inline]
    #[must_use]
    pub fn half_area(&self) -> f32 {
        let e = self.extent();
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Length of the diagonal (zero for the empty box). Worked out again
    /// in `f64` where `f32`'s squared length leaves its normal range: it
    /// overflowed for boxes past about 1e19 across (infinity) and
    /// underflowed below 1e-19 (zero), and the cameras framed on it missed
    /// the scene.
    #[inline]
    #[must_use]
    pub fn diagonal(&self) -> f32 {
        let e = self.extent();
        let l2 = e.length_squared();
        if (l2.is_normal() && l2 < f32::INFINITY) || e == Vec3::ZERO {
            l2.sqrt()
        } else {
            e.as_dvec3().length() as f32
        }
    }

    /// Axis (0, 1, 2) of the largest extent; ties go to the lower axis.
    #[inline]
    #[must_use]
    pub fn longest_axis(&self) -> usize {
        let e = self.extent();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }

    /// Whether `p` lies in the closed box.
    #[inline]
    #[must_use]
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Whether the closed boxes share a point.
    #[inline]
    #[must_use]
    pub fn overlaps(&self, other: &Self) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }

    /// Slab test (Kay & Kajiya 1986): the entry and exit distances of the ray
    /// within `[ray.tmin, min(tmax, ray.tmax)]` (the bound padded by
    /// [`cull_bound`]), or `None` when it misses.
    ///
    /// Directions with a zero component give `±inf` reciprocals, so the slab
    /// of that axis yields `±inf` (no constraint) when the origin is inside it
    /// and an empty interval when outside; the `0 * inf = NaN` that arises for
    /// an origin exactly on the slab's face is dropped by the NaN-ignoring
    /// `max`/`min` (the ray lies in the face: inside the closed box). Negative
    /// directions swap the slab's faces by sign. Rays that start inside report
    /// an entry of `tmin`. The exit is padded by `1 + 2γ(3)` (computed with
    /// [`exit_reciprocal`]) so that no hit inside the box is lost to
    /// rounding (Ize 2013). Invalid rays (NaN
    /// input) have an empty interval and never hit.
    #[inline]
    #[must_use]
    pub fn intersect_ray(&self, ray: &Ray, tmax: f32) -> Option<(f32, f32)> {
        let tmax = cull_bound(tmax.min(ray.tmax()));
        let (t0, t1) = self.slab(ray.origin(), ray.inv_dir(), ray.octant(), ray.tmin(), tmax);
        (t0 <= t1).then_some((t0, t1))
    }

    /// The slab test's raw interval `(entry, exit)`; it is a miss when
    /// `entry > exit`. `octant` is `ray.octant()`, passed in so a traversal
    /// computes it once. This is the form hot loops call.
    #[inline(always)]
    #[must_use]
    pub fn slab(
        &self,
        origin: Vec3,
        inv_dir: Vec3,
        octant: usize,
        tmin: f32,
        tmax: f32,
    ) -> (f32, f32) {
        let (near, far) = self.near_far(octant);
        let tn = (near - origin) * inv_dir;
        let inv_exit = Vec3::new(
            exit_reciprocal(inv_dir.x),
            exit_reciprocal(inv_dir.y),
            exit_reciprocal(inv_dir.z),
        );
        let tf = (far - origin) * inv_exit;
        // `max_nan_second`/`min_nan_second` keep the accumulator when the
        // slab's value is NaN: a NaN slab constrains nothing. Each is one
        // maxss/minss, unlike f32::max, which adds NaN fix-ups.
        let entry = max_nan_second(tn.x, max_nan_second(tn.y, max_nan_second(tn.z, tmin)));
        let exit = min_nan_second(tf.x, min_nan_second(tf.y, min_nan_second(tf.z, tmax)));
        (entry, exit)
    }

    /// Near and far corners for a ray in the given octant.
    #[inline(always)]
    fn near_far(&self, octant: usize) -> (Vec3, Vec3) {
        let sx = octant & 1 != 0;
        let sy = octant & 2 != 0;
        let sz = octant & 4 != 0;
        let pick = |neg: bool, a: f32, b: f32| if neg { (b, a) } else { (a, b) };
        let (nx, fx) = pick(sx, self.min.x, self.max.x);
        let (ny, fy) = pick(sy, self.min.y, self.max.y);
        let (nz, fz) = pick(sz, self.min.z, self.max.z);
        (Vec3::new(nx, ny, nz), Vec3::new(fx, fy, fz))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn unit() -> Aabb {
        Aabb::new(Vec3::ZERO, Vec3::ONE)
    }

    #[test]
    fn empty_box_basics() {
        assert!(Aabb::EMPTY.is_empty());
        assert_eq!(Aabb::EMPTY.surface_area(), 0.0);
        let b = Aabb::EMPTY.grow(Vec3::ONE);
        assert_eq!(b, Aabb::from_point(Vec3::ONE));
        assert_eq!(Aabb::EMPTY.union(unit()), unit());
        let r = Ray::infinite(Vec3::splat(-1.0), Vec3::ONE);
        assert!(Aabb::EMPTY.intersect_ray(&r, f32::INFINITY).is_none());
    }

    #[test]
    fn measures() {
        let b = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(b.surface_area(), 22.0);
        assert_eq!(b.longest_axis(), 2);
        assert_eq!(b.centroid(), Vec3::new(0.5, 1.0, 1.5));
        assert!(b.contains(Vec3::new(1.0, 2.0, 3.0)));
        assert!(!b.contains(Vec3::new(1.0, 2.0, 3.1)));
    }

    #[test]
    fn axis_parallel_and_negative_directions() {
        let b = unit();
        // +x through the middle.
        let r = Ray::infinite(Vec3::new(-1.0, 0.5, 0.5), Vec3::X);
        let (t0, t1) = b.intersect_ray(&r, f32::INFINITY).unwrap();
        assert_eq!(t0, 1.0);
        assert!((t1 - 2.0).abs() < 1e-5);
        // -x from the other side.
        let r = Ray::infinite(Vec3::new(2.0, 0.5, 0.5), -Vec3::X);
        let (t0, _) = b.intersect_ray(&r, f32::INFINITY).unwrap();
        assert_eq!(t0, 1.0);
        // Parallel to x, outside the y slab.
        let r = Ray::infinite(Vec3::new(-1.0, 1.5, 0.5), Vec3::X);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_none());
        // Parallel, origin exactly on the face y = 1: inside the closed box.
        let r = Ray::infinite(Vec3::new(-1.0, 1.0, 0.5), Vec3::X);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_some());
        // Negative zero direction components.
        let r = Ray::infinite(Vec3::new(0.5, 0.5, 3.0), Vec3::new(-0.0, -0.0, -1.0));
        assert!(b.intersect_ray(&r, f32::INFINITY).is_some());
    }

    #[test]
    fn origin_inside_and_interval_clipping() {
        let b = unit();
        let r = Ray::new(
            Vec3::splat(0.5),
            Vec3::new(0.3, -0.2, 1.0),
            0.0,
            f32::INFINITY,
        );
        let (t0, t1) = b.intersect_ray(&r, f32::INFINITY).unwrap();
        assert_eq!(t0, 0.0);
        assert!(t1 > 0.0);
        // Box entirely behind the ray.
        let r = Ray::infinite(Vec3::splat(2.0), Vec3::ONE);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_none());
        // Box beyond tmax.
        let r = Ray::new(Vec3::new(-5.0, 0.5, 0.5), Vec3::X, 0.0, 1.0);
        assert!(b.intersect_ray(&r, r.tmax()).is_none());
    }

    #[test]
    fn flat_boxes() {
        let b = Aabb::new(Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 1.0, 1.0));
        let r = Ray::infinite(Vec3::new(0.5, 0.5, 0.0), Vec3::Z);
        let (t0, t1) = b.intersect_ray(&r, f32::INFINITY).unwrap();
        assert_eq!(t0, 1.0);
        assert!(t1 >= 1.0);
        // A ray inside the plane of a flat box, parallel to it.
        let r = Ray::infinite(Vec3::new(-1.0, 0.5, 1.0), Vec3::X);
        assert!(b.intersect_ray(&r, f32::INFINITY).is_some());
    }

    #[test]
    fn nan_rays_never_hit() {
        let b = Aabb::new(Vec3::splat(-1e30), Vec3::splat(1e30));
        for o in [Vec3::new(f32::NAN, 0.0, 0.0), Vec3::splat(f32::NAN)] {
            let r = Ray::infinite(o, Vec3::X);
            assert!(b.intersect_ray(&r, f32::INFINITY).is_none());
        }
        let r = Ray::infinite(Vec3::ZERO, Vec3::new(f32::NAN, 1.0, 0.0));
        assert!(b.intersect_ray(&r, f32::INFINITY).is_none());
    }

    #[test]
    fn diagonal_at_any_scale() {
        for s in [1.0f32, 1e20, 1e37, 1e-20, 1e-37] {
            let b = Aabb::new(Vec3::ZERO, Vec3::new(3.0, 4.0, 12.0) * s);
            assert!(
                (b.diagonal() / s - 13.0).abs() < 1e-5,
                "{} at {s}",
                b.diagonal()
            );
        }
        assert_eq!(Aabb::EMPTY.diagonal(), 0.0);
    }

    /// Reference slab test in f64 with explicit parallel-ray handling.
    fn reference(b: &Aabb, o: Vec3, d: Vec3) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let (lo, hi, o, d) = (b.min[a] as f64, b.max[a] as f64, o[a] as f64, d[a] as f64);
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let (mut n, mut f) = ((lo - o) / d, (hi - o) / d);
            if n > f {
                std::mem::swap(&mut n, &mut f);
            }
            t0 = t0.max(n);
            t1 = t1.min(f);
        }
        (t0 <= t1).then_some((t0, t1))
    }

    fn coord() -> impl Strategy<Value = f32> + Clone {
        prop_oneof![(-4i32..=4).prop_map(|i| i as f32 * 0.5), -3.0f32..3.0]
    }
    fn dcomp() -> impl Strategy<Value = f32> + Clone {
        prop_oneof![
            Just(0.0f32),
            Just(-0.0f32),
            (-2i32..=2).prop_map(|i| i as f32),
            -1.0f32..1.0
        ]
    }
    fn vec(s: impl Strategy<Value = f32> + Clone) -> impl Strategy<Value = Vec3> {
        (s.clone(), s.clone(), s).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]
        /// The slab test agrees with an f64 reference, except within rounding
        /// of the boundary, where it must err towards a hit.
        #[test]
        fn slab_matches_reference(a in vec(coord()), b in vec(coord()), o in vec(coord()), d in vec(dcomp())) {
            prop_assume!(d != Vec3::ZERO);
            let bx = Aabb::from_point(a).grow(b);
            let r = Ray::infinite(o, d);
            let got = bx.intersect_ray(&r, f32::INFINITY);
            match reference(&bx, o, d) {
                Some((t0, t1)) => {
                    let (g0, g1) = got.expect("reference hits, slab test missed");
                    prop_assert!((g0 as f64 - t0).abs() <= 1e-5 * (1.0 + t0.abs()));
                    prop_assert!(g1 as f64 >= t1 - 1e-5 * (1.0 + t1.abs()) || t1.is_infinite());
                }
                None => {
                    // A reported hit must be a near miss, i.e. grazing within rounding.
                    if let Some((g0, g1)) = got {
                        prop_assert!(g1 - g0 <= 1e-4 * (1.0 + g0.abs()), "{g0} {g1}");
                    }
                }
            }
        }
    }
}
