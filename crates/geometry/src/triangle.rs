//! Watertight ray–triangle intersection (Woop, Benthin & Wald, JCGT 2013).

use crate::{Aabb, Ray};
use glam::Vec3;

/// A triangle given by its three corners.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    /// The corners, in winding order.
    pub v: [Vec3; 3],
}

/// Result of a ray–triangle test: distance along the ray and the barycentric
/// weights `u`, `v` of the 2nd and 3rd corner (the 1st has `1 - u - v`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriHit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Weight of the second corner.
    pub u: f32,
    /// Weight of the third corner.
    pub v: f32,
}

impl Triangle {
    /// Makes a triangle.
    #[inline]
    #[must_use]
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self { v: [a, b, c] }
    }

    /// Unnormalized geometric normal `(b - a) × (c - a)`; zero when degenerate.
    #[inline]
    #[must_use]
    pub fn normal(&self) -> Vec3 {
        (self.v[1] - self.v[0]).cross(self.v[2] - self.v[0])
    }

    /// Bounding box.
    #[inline]
    #[must_use]
    pub fn bounds(&self) -> crate::Aabb {
        crate::Aabb::from_point(self.v[0])
            .grow(self.v[1])
            .grow(self.v[2])
    }

    /// Ray test over `[ray.tmin, tmax]`; see [`intersect_triangle`].
    #[inline]
    #[must_use]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<TriHit> {
        intersect_triangle(ray, tmax, self.v[0], self.v[1], self.v[2])
    }
}

/// Whether the corners lie in line (or coincide): a zero-area triangle,
/// [`triangle_area2`] zero (its `f64` cross product of the `f32` edges
/// is zero), without the square root. The one test of degeneracy:
/// `raymesh info` counts by it and the structures grow boxes by it
/// ([`triangle_hit_bounds`]).
#[inline]
#[must_use]
pub fn triangle_is_degenerate([a, b, c]: [Vec3; 3]) -> bool {
    let a = a.as_dvec3();
    (b.as_dvec3() - a).cross(c.as_dvec3() - a) == glam::DVec3::ZERO
}

/// The box that holds every point where [`intersect_triangle`] puts a hit
/// on triangle `corners`, the box acceleration structures must give it:
/// the corners' box, grown on every axis by its largest extent for a
/// degenerate triangle ([`triangle_is_degenerate`]).
///
/// A hit's `t` is its barycentric mix of the corners' distances along the
/// ray's dominant axis, so the hit point lies within the corners' range
/// on that axis, and within that range's width, on the other two (along
/// which the ray moves no faster), of where the ray meets the triangle.
/// On a proper triangle the mix is the point's own and the hit lies in
/// the corners' box (to rounding, which traversals allow for). On a
/// degenerate one that rounding leaves a tiny triangle around the ray
/// (see [`intersect_triangle`]) the mix is rounding noise, and the hit
/// may lie anywhere in that range: outside the corners' box, which is
/// flat, so that a structure culling it there missed what brute force
/// finds (`degenerate_triangles_are_found_where_brute_force_finds_them`
/// in `raymesh-accel`'s agreement tests).
#[inline]
#[must_use]
pub fn triangle_hit_bounds(corners: [Vec3; 3]) -> Aabb {
    let [a, b, c] = corners;
    let tight = Triangle { v: corners }.bounds();
    if !triangle_is_degenerate(corners) {
        return tight;
    }
    // Plus the rounding of where the ray meets the segment, as in
    // `clip_triangle`; saturated, so that the box stays finite.
    let reach = a.abs().max(b.abs()).max(c.abs()) * (64.0 * f32::EPSILON)
        + Vec3::splat(tight.extent().max_element() + f32::MIN_POSITIVE);
    Aabb {
        min: (tight.min - reach).max(Vec3::splat(-f32::MAX)),
        max: (tight.max + reach).min(Vec3::splat(f32::MAX)),
    }
}

/// The boxes of the parts of triangle `corners` inside `within` on each
/// side of the plane `axis = pos`, as a spatial-split BVH builder needs
/// them (Stich, Friedrich & Dietrich, "Spatial splits in bounding volume
/// hierarchies", 2009): each side's box holds the corners on that side and
/// the points where the edges cross the plane, and is then cut to `within`
/// and to its side. An empty box means no part lies on that side.
///
/// Conservative, so that a BVH built from the parts misses no hit: each
/// crossing is widened by a bound on its rounding error (a few dozen ulps
/// of the larger corner coordinate, far more than its handful of `f32`
/// operations can err by), so every point of the triangle inside `within`
/// lies in the box of its side (both boxes, on the plane). A degenerate
/// triangle's hits may lie anywhere in its [`triangle_hit_bounds`]: it
/// cuts `within` itself.
#[must_use]
pub fn clip_triangle(corners: [Vec3; 3], within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
    if triangle_is_degenerate(corners) {
        return within.split(axis, pos);
    }
    /// Relative error bound of a crossing: 64 ε, where the computation
    /// (two subtractions, a division, a multiply and an add) errs by
    /// less than 8 ε of the larger corner coordinate.
    const PAD: f32 = 64.0 * f32::EPSILON;
    let (mut left, mut right) = (Aabb::EMPTY, Aabb::EMPTY);
    for i in 0..3 {
        let (a, b) = (corners[i], corners[(i + 1) % 3]);
        let (da, db) = (a[axis], b[axis]);
        if da <= pos {
            left = left.grow(a);
        }
        if da >= pos {
            right = right.grow(a);
        }
        if (da < pos && pos < db) || (db < pos && pos < da) {
            // The crossing a + (b - a) s, s = (pos - da) / (db - da) in [0, 1].
            let s = (pos - da) / (db - da);
            let x = a + (b - a) * s;
            // (Plus the least normal float, for corners among the subnormals.)
            let err = a.abs().max(b.abs()) * PAD + Vec3::splat(f32::MIN_POSITIVE);
            let (mut lo, mut hi) = (x - err, x + err);
            (lo[axis], hi[axis]) = (pos, pos);
            left = left.grow(lo).grow(hi);
            right = right.grow(lo).grow(hi);
        }
    }
    let (wl, wr) = within.split(axis, pos);
    (left.intersection(wl), right.intersection(wr))
}

/// The unit normal of triangle `a b c` (winding order, `(b - a) × (c -
/// a)` normalized), zero for a degenerate one. Worked out again in `f64`
/// where the cross product's squared length is not a normal `f32`, so
/// that it holds for any `f32` corners: in `f32` it overflows for
/// triangles about 10^9.5 across and underflows below 10^-9.5, and the
/// normal came out zero (shading such scenes black).
#[inline]
#[must_use]
pub fn triangle_normal(a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let n = (b - a).cross(c - a);
    if n.length_squared().is_normal() {
        // In range: `f32`, the bits it always gave.
        return n.normalize_or_zero();
    }
    let a = a.as_dvec3();
    (b.as_dvec3() - a)
        .cross(c.as_dvec3() - a)
        .normalize_or_zero()
        .as_vec3()
}

/// Twice the area of a triangle, computed in f64 so that tiny triangles far
/// from the origin are not reported degenerate by rounding alone.
#[must_use]
pub fn triangle_area2(a: Vec3, b: Vec3, c: Vec3) -> f64 {
    let a = a.as_dvec3();
    (b.as_dvec3() - a).cross(c.as_dvec3() - a).length()
}

/// Watertight ray–triangle test over `[ray.tmin, tmax]`, both sides counted.
///
/// The ray is sheared so that it runs along +z from the origin; the triangle's
/// edge functions are then evaluated in 2D at the origin. Edges shared by two
/// triangles are evaluated with the same operands in both, so a ray through a
/// shared edge or vertex hits at least one of them (never falls through a
/// crack). Rays in the triangle's plane never hit it, and invalid rays
/// never hit.
///
/// A degenerate (zero-area) triangle, its corners in line, is missed where
/// the shear keeps them exactly in line (an axis-aligned ray, for one).
/// Elsewhere rounding may leave them a tiny triangle around a ray that
/// passes through the segment they span, and the ray hits it, at a `t`
/// somewhere between the corners' distances along the ray rather than
/// where it crosses the segment (rays aimed at random points of a 2.2-unit
/// segment, in the test below: 8% hit it, `t` 1.3% off on average and up
/// to 33%). That hit keeps a mesh with such a triangle watertight: the
/// triangle joins the edges of the neighbours on its two sides, which
/// share no edge with each other, and without it 4% of those rays passed
/// between them (`degenerate_triangles_keep_meshes_watertight`). Such a
/// hit may lie outside the corners' box; the structures give a degenerate
/// triangle a box that holds it ([`triangle_hit_bounds`]).
///
/// Where `f32` cannot be trusted the test is redone in `f64` from the same
/// sheared corners ([`needs_f64`]): an edge function that rounds to exactly
/// zero, as the paper prescribes, and (beyond it) a determinant or scaled
/// distance that overflowed, or that fell below the normal floats for a
/// triangle the ray is inside. Corners some 10^12 units from the ray's
/// origin make the latter's cubes overflow `f32`, and corners 10^-13
/// apart make them underflow; in `f64` neither does, so huge and tiny
/// scenes get the hits they have, not misses or `t = 0`. A hit whose `t`
/// is past `f32::MAX` is no hit.
#[inline]
#[must_use]
pub fn intersect_triangle(ray: &Ray, tmax: f32, p0: Vec3, p1: Vec3, p2: Vec3) -> Option<TriHit> {
    let (s, _) = ray.shear();
    let o = ray.origin();
    let a = ray.permute(p0 - o);
    let b = ray.permute(p1 - o);
    let c = ray.permute(p2 - o);
    let ax = a.x - s.x * a.z;
    let ay = a.y - s.y * a.z;
    let bx = b.x - s.x * b.z;
    let by = b.y - s.y * b.z;
    let cx = c.x - s.x * c.z;
    let cy = c.y - s.y * c.z;

    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    // Outside by strict comparisons is outside whatever the range: they are
    // false for NaN, an edge function that overflowed to an infinity keeps
    // its sign, and the f64 redo would find the same signs.
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    let az = s.z * a.z;
    let bz = s.z * b.z;
    let cz = s.z * c.z;
    let t_scaled = u * az + v * bz + w * cz;
    if needs_f64(u, v, w, det, t_scaled, false) {
        let d = |x: f32| f64::from(x);
        let (ax, ay, bx, by, cx, cy) = (d(ax), d(ay), d(bx), d(by), d(cx), d(cy));
        let sz = d(s.z);
        return hit_f64(
            ray.tmin(),
            tmax,
            [cx * by - cy * bx, ax * cy - ay * cx, bx * ay - by * ax],
            [sz * d(a.z), sz * d(b.z), sz * d(c.z)],
        );
    }
    // Inside, all three of one sign and none zero: `det` is not zero, and
    // (from `needs_f64`) neither NaN nor infinite.
    let inv_det = 1.0 / det;
    let t = t_scaled * inv_det;
    // `!(t >= tmin)` also rejects NaN, and an invalid ray has tmin = +inf.
    if !(t >= ray.tmin() && t <= tmax) {
        return None;
    }
    Some(TriHit {
        t,
        u: v * inv_det,
        v: w * inv_det,
    })
}

/// Whether the `f32` test of [`intersect_triangle`] must be redone in
/// `f64`, from its edge functions `u`, `v`, `w`, their sum `det`, the
/// scaled distance `t_scaled` and whether the signs of the edge functions
/// put the ray `outside` the triangle: an edge function of exactly zero
/// (a ray through an edge or a vertex, where the sign decides
/// watertightness), a `det` or `t_scaled` that is infinite or NaN
/// (products past `f32::MAX`; then `outside` may be wrong too), or, for a
/// ray inside, either below the least normal float (products that
/// underflowed, so `t` or the barycentrics lost their precision, down to
/// `t = 0`). The SIMD kernels redo exactly these lanes (each with the
/// same `f32` operations), so that every kernel gives the same bits; a
/// lane outside by strict comparisons is no hit either way, which is why
/// the scalar test, having returned for those already, passes `false`.
#[inline(always)]
#[must_use]
pub fn needs_f64(u: f32, v: f32, w: f32, det: f32, t_scaled: f32, outside: bool) -> bool {
    let (ad, at) = (det.abs(), t_scaled.abs());
    // `|` rather than `||`: no branches, so that lanes vectorize.
    (u == 0.0)
        | (v == 0.0)
        | (w == 0.0)
        | !(ad + at < f32::INFINITY)
        | (!outside & ((ad < f32::MIN_POSITIVE) | (at < f32::MIN_POSITIVE)))
}

/// [`intersect_triangle`]'s test redone in `f64`: from its edge functions
/// `e` (each from the `f32` sheared corners, whose products `f64` holds
/// exactly, so that their signs are exact) and the corners' scaled
/// distances `z` (`shear.z` times each corner's relative `z`, exact too),
/// the hit within `[tmin, tmax]`, if any. An edge function of zero is of
/// neither sign. The SIMD kernels that redo lanes themselves call it too,
/// so that their hits are the scalar test's, bit for bit.
#[inline]
#[must_use]
pub fn hit_f64(tmin: f32, tmax: f32, e: [f64; 3], z: [f64; 3]) -> Option<TriHit> {
    let [u, v, w] = e;
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    // Zero only when all three are (an edge-on plane or a degenerate
    // triangle); NaN from non-finite corners.
    if !(det != 0.0) {
        return None;
    }
    let t_scaled = u * z[0] + v * z[1] + w * z[2];
    let t = (t_scaled / det) as f32;
    if !(t >= tmin && t <= tmax && t < f32::INFINITY) {
        return None;
    }
    Some(TriHit {
        t,
        u: (v / det) as f32,
        v: (w / det) as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Whether the f64 point `p` lies in `b` (closed).
    fn holds(b: Aabb, p: glam::DVec3) -> bool {
        !b.is_empty() && p.cmpge(b.min.as_dvec3()).all() && p.cmple(b.max.as_dvec3()).all()
    }

    fn clip_coord() -> impl Strategy<Value = f32> {
        prop_oneof![
            -4.0f32..4.0,
            -1e6f32..1e6,
            (-8i32..8).prop_map(|k| k as f32 * 0.5)
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]
        /// Every point of the triangle inside `within` lies in the box of
        /// its side of the plane (checked in f64 on a grid of barycentric
        /// points, the corners, and points on the edges), and each box
        /// stays inside `within` and on its side.
        #[test]
        fn clipped_boxes_hold_the_triangle(
            c in proptest::array::uniform9(clip_coord()),
            cut in proptest::array::uniform6(0.0f32..1.0),
            axis in 0usize..3, at in 0.0f32..1.0, edge_plane in any::<bool>(),
        ) {
            let corners = [
                Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5]), Vec3::new(c[6], c[7], c[8]),
            ];
            let full = Triangle { v: corners }.bounds();
            // A sub-box of the triangle's box, as a reference clipped before.
            let lerp = |lo: f32, hi: f32, f: f32| lo + (hi - lo) * f;
            let mut within = full;
            for k in 0..3 {
                let (f, g) = (cut[2 * k].min(cut[2 * k + 1]) * 0.5, 0.5 + cut[2 * k].max(cut[2 * k + 1]) * 0.5);
                within.min[k] = lerp(full.min[k], full.max[k], f);
                within.max[k] = lerp(full.min[k], full.max[k], g).max(within.min[k]);
            }
            // A plane through the box, or through a corner.
            let pos = if edge_plane { corners[1][axis] } else { lerp(within.min[axis], within.max[axis], at) };
            let (l, r) = clip_triangle(corners, within, axis, pos);
            let (wl, wr) = within.split(axis, pos);
            prop_assert!(l.is_empty() || (wl.union(l) == wl), "left {l:?} outside {wl:?}");
            prop_assert!(r.is_empty() || (wr.union(r) == wr), "right {r:?} outside {wr:?}");
            let [a, b, cc] = corners.map(|v| v.as_dvec3());
            let n = 24;
            for i in 0..=n {
                for j in 0..=n - i {
                    let (u, v) = (f64::from(i) / f64::from(n), f64::from(j) / f64::from(n));
                    let p = a + (b - a) * u + (cc - a) * v;
                    if !holds(within, p) {
                        continue;
                    }
                    let side = p[axis];
                    if side <= f64::from(pos) {
                        prop_assert!(holds(l, p), "{p:?} not in left {l:?}");
                    }
                    if side >= f64::from(pos) {
                        prop_assert!(holds(r, p), "{p:?} not in right {r:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn clip_of_a_triangle_across_a_plane() {
        // The triangle (0,0,0) (4,0,0) (0,4,0) cut at x = 1: left keeps
        // x in [0, 1] and the whole height; right has x in [1, 4] and
        // y up to 3 (where the hypotenuse crosses x = 1).
        let t = [
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(0.0, 4.0, 0.0),
        ];
        let whole = Triangle { v: t }.bounds();
        let (l, r) = clip_triangle(t, whole, 0, 1.0);
        assert_eq!((l.min.x, l.max.x, l.min.y), (0.0, 1.0, 0.0));
        assert!((l.max.y - 4.0).abs() < 1e-4);
        assert_eq!((r.min.x, r.max.x, r.min.y), (1.0, 4.0, 0.0));
        assert!((r.max.y - 3.0).abs() < 1e-4 && r.max.y >= 3.0);
        // A plane the triangle does not reach leaves one side empty.
        let (l, r) = clip_triangle(t, whole, 2, 1.0);
        assert!(r.is_empty() && l == whole);
        // The box fallback cuts the box itself.
        let (l, r) = whole.split(1, 1.0);
        assert_eq!((l.max.y, r.min.y), (1.0, 1.0));
    }

    fn tri() -> [Vec3; 3] {
        [Vec3::ZERO, Vec3::X, Vec3::Y]
    }

    #[test]
    fn hits_and_barycentrics() {
        let [a, b, c] = tri();
        let r = Ray::infinite(Vec3::new(0.25, 0.5, 1.0), -Vec3::Z);
        let h = intersect_triangle(&r, f32::INFINITY, a, b, c).unwrap();
        assert_eq!(h.t, 1.0);
        assert!((h.u - 0.25).abs() < 1e-6 && (h.v - 0.5).abs() < 1e-6);
        // Back side counts too.
        let r = Ray::infinite(Vec3::new(0.25, 0.5, -2.0), Vec3::Z * 2.0);
        assert_eq!(
            intersect_triangle(&r, f32::INFINITY, a, b, c).unwrap().t,
            1.0
        );
        // Outside.
        let r = Ray::infinite(Vec3::new(0.75, 0.75, 1.0), -Vec3::Z);
        assert!(intersect_triangle(&r, f32::INFINITY, a, b, c).is_none());
        // Behind the origin / beyond tmax.
        let r = Ray::infinite(Vec3::new(0.25, 0.25, -1.0), -Vec3::Z);
        assert!(intersect_triangle(&r, f32::INFINITY, a, b, c).is_none());
        let r = Ray::new(Vec3::new(0.25, 0.25, 2.0), -Vec3::Z, 0.0, 1.5);
        assert!(intersect_triangle(&r, r.tmax(), a, b, c).is_none());
    }

    /// An axis-aligned ray shears exactly, so a degenerate triangle's
    /// corners stay in line and it is missed (elsewhere, see
    /// `degenerate_triangles_keep_meshes_watertight`); rays in the plane
    /// and invalid rays miss.
    #[test]
    fn degenerate_and_coplanar_never_hit() {
        let r = Ray::infinite(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z);
        assert!(
            intersect_triangle(&r, f32::INFINITY, Vec3::ZERO, Vec3::X, Vec3::X * 2.0).is_none()
        );
        assert!(intersect_triangle(&r, f32::INFINITY, Vec3::X, Vec3::X, Vec3::X).is_none());
        let r = Ray::infinite(Vec3::new(-1.0, 0.2, 0.0), Vec3::X);
        let [a, b, c] = tri();
        assert!(intersect_triangle(&r, f32::INFINITY, a, b, c).is_none());
        let r = Ray::infinite(Vec3::new(f32::NAN, 0.2, 1.0), -Vec3::Z);
        assert!(intersect_triangle(&r, f32::INFINITY, a, b, c).is_none());
    }

    /// Numbers in `[0, 1]` from a xorshift generator seeded with `seed`
    /// (not zero): the same sequence on every run.
    fn uniform(seed: u32) -> impl FnMut() -> f32 {
        let mut s = seed;
        move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            f64::from(s) as f32 / u32::MAX as f32
        }
    }

    /// A segment split at a point `c` between its ends: two triangles on
    /// one side meet at `c`, one on the other side spans the whole
    /// segment, and a degenerate triangle `a`, `b`, `c` joins their edges.
    /// Rays aimed at points of the segment from all around: with the
    /// degenerate triangle none passes through; without it some do, as the
    /// edges on the two sides are different edges whose rounding need not
    /// agree. (A test that skipped degenerate triangles would fail here.)
    #[test]
    fn degenerate_triangles_keep_meshes_watertight() {
        let (a, b, c) = (
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::new(2.3, 0.0, 0.0),
            Vec3::new(1.7, 0.0, 0.0),
        );
        let near = [a, c, Vec3::new(0.5, 1.0, 0.3)];
        let far = [c, b, Vec3::new(1.5, 1.0, -0.2)];
        let under = [b, a, Vec3::new(1.0, -1.0, 0.1)];
        let line = [a, b, c];
        assert_eq!(triangle_area2(a, b, c), 0.0);
        let mut next = uniform(0x1234_5678);
        let (mut through, mut caught) = (0, 0);
        for _ in 0..20_000 {
            let p = Vec3::new(0.1 + 2.2 * next(), 0.0, 0.0);
            let o = Vec3::new(4.0 * next() - 2.0, 4.0 * next() - 2.0, 1.0 + next());
            let r = Ray::infinite(o, p - o);
            let hit = |[p0, p1, p2]: [Vec3; 3]| intersect_triangle(&r, f32::INFINITY, p0, p1, p2);
            if [near, far, under].into_iter().all(|t| hit(t).is_none()) {
                through += 1;
                if hit(line).is_some() {
                    caught += 1;
                }
            }
        }
        assert!(through > 100, "{through} rays between the neighbours");
        assert_eq!(caught, through, "rays through the mesh");
    }

    /// Every hit on a degenerate triangle lies where a traversal looks for
    /// it: the ray meets its [`triangle_hit_bounds`] no later than the
    /// bound a traversal culls against ([`crate::cull_bound`] of the
    /// hit's `t`). The corners' own box fails that on some of the same
    /// rays (the reason for the growth). Corners exactly in line (on a
    /// lattice, a whole step apart), rays from all around aimed at points
    /// of the segment. A proper triangle keeps its corners' box.
    #[test]
    fn hits_on_degenerate_triangles_lie_in_their_hit_bounds() {
        let mut next = uniform(0x2545_f491);
        let (mut hits, mut outside_corners) = (0, 0);
        for _ in 0..400 {
            let mut lattice = |scale: f32| ((next() * 16.0).floor() - 8.0) * scale;
            let a = Vec3::new(lattice(0.125), lattice(0.125), lattice(0.125));
            let step = Vec3::new(lattice(1.0), lattice(1.0), lattice(1.0)) * 0.0625;
            let (k, m) = ((next() * 4.0).floor() + 1.0, -(next() * 4.0).floor());
            let corners = [a, a + step * k, a + step * m];
            if !triangle_is_degenerate(corners) {
                continue;
            }
            let bounds = triangle_hit_bounds(corners);
            let tight = Aabb::from_point(corners[0])
                .grow(corners[1])
                .grow(corners[2]);
            assert!(bounds.min.cmple(tight.min).all() && bounds.max.cmpge(tight.max).all());
            for _ in 0..100 {
                let p = corners[2] + (corners[1] - corners[2]) * next();
                let d = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5);
                let r = Ray::infinite(p - d * (1.0 + 4.0 * next()), d);
                let [p0, p1, p2] = corners;
                let Some(h) = intersect_triangle(&r, f32::INFINITY, p0, p1, p2) else {
                    continue;
                };
                hits += 1;
                let entry = bounds.intersect_ray(&r, f32::INFINITY).map(|(t0, _)| t0);
                assert!(
                    entry.is_some_and(|t0| t0 <= crate::cull_bound(h.t)),
                    "{corners:?} {r:?}: hit at {} but the box at {entry:?}",
                    h.t
                );
                let corner_entry = tight.intersect_ray(&r, f32::INFINITY).map(|(t0, _)| t0);
                if !corner_entry.is_some_and(|t0| t0 <= crate::cull_bound(h.t)) {
                    outside_corners += 1;
                }
            }
        }
        assert!(
            hits > 500 && outside_corners > 50,
            "{hits} hits, {outside_corners} outside"
        );
        let proper = [Vec3::ZERO, Vec3::X, Vec3::Y];
        assert!(!triangle_is_degenerate(proper));
        assert_eq!(
            triangle_hit_bounds(proper),
            Aabb::from_point(Vec3::ZERO).grow(Vec3::X).grow(Vec3::Y)
        );
        // Finite however far the corners lie.
        let far = [Vec3::splat(-3e38), Vec3::splat(3e38), Vec3::ZERO];
        assert!(triangle_is_degenerate(far));
        let b = triangle_hit_bounds(far);
        assert!(b.min.is_finite() && b.max.is_finite(), "{b:?}");
        // Clipped, a degenerate triangle cuts the box it is given.
        let within = triangle_hit_bounds([Vec3::ZERO, Vec3::X * 2.0, Vec3::X]);
        assert_eq!(
            clip_triangle([Vec3::ZERO, Vec3::X * 2.0, Vec3::X], within, 1, 0.5),
            within.split(1, 0.5)
        );
    }

    /// Plain f64 Möller–Trumbore, as the reference.
    fn reference(o: Vec3, d: Vec3, [a, b, c]: [Vec3; 3]) -> Option<(f64, f64, f64)> {
        let (o, d) = (o.as_dvec3(), d.as_dvec3());
        let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
        let e1 = b - a;
        let e2 = c - a;
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let s = o - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let t = e2.dot(q) / det;
        (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t >= 0.0).then_some((t, u, v))
    }

    fn v3(r: f32) -> impl Strategy<Value = Vec3> {
        (-r..r, -r..r, -r..r).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20000))]
        /// Agrees with an f64 reference away from the edges (margin 1e-4 in
        /// barycentrics), and its t and barycentrics are close when both hit.
        #[test]
        fn matches_f64_reference(a in v3(2.0), b in v3(2.0), c in v3(2.0), o in v3(4.0), d in v3(1.0)) {
            prop_assume!(d.length() > 1e-3);
            let n = (b - a).cross(c - a);
            prop_assume!(n.length() > 1e-2);
            let r = Ray::infinite(o, d);
            let got = intersect_triangle(&r, f32::INFINITY, a, b, c);
            let want = reference(o, d, [a, b, c]);
            // Skip grazing configurations where the two may legitimately differ.
            let cosang = (n.normalize().dot(d.normalize())).abs();
            prop_assume!(cosang > 1e-2);
            match (got, want) {
                (Some(h), Some((t, u, v))) => {
                    prop_assert!((h.t as f64 - t).abs() <= 1e-3 * (1.0 + t.abs()), "{} vs {}", h.t, t);
                    prop_assert!((h.u as f64 - u).abs() <= 1e-3 && (h.v as f64 - v).abs() <= 1e-3);
                }
                (None, Some((t, u, v))) => {
                    let margin = u.min(v).min(1.0 - u - v);
                    prop_assert!(margin < 1e-4 || t < 1e-4, "missed a clear hit {t} {u} {v}");
                }
                (Some(h), None) => {
                    let margin = h.u.min(h.v).min(1.0 - h.u - h.v);
                    prop_assert!(margin.abs() < 1e-4 || h.t.abs() < 1e-4, "false hit {h:?}");
                }
                (None, None) => {}
            }
        }
    }

    /// Coordinates on a grid of 2^-10, so that scaling them by a power of
    /// two in `2^-100..=2^100` is exact.
    fn snapped(r: f32) -> impl Strategy<Value = Vec3> {
        v3(r).prop_map(|v| (v * 1024.0).round() / 1024.0)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20000))]
        /// Scaling a scene and its ray's origin by a power of two scales
        /// `t` by it and keeps the barycentrics, whatever the power: a clear
        /// hit at unit scale is the same hit at 2^-100 (where `f32`'s
        /// products of three coordinates underflow) and at 2^100 (where its
        /// products of two overflow). Before the range checks of
        /// `needs_f64`, hits from about 2^42 up were lost or put at
        /// infinity, and those from about 2^-43 down put at `t = 0`.
        #[test]
        fn hits_keep_at_any_scale(a in snapped(2.0), b in snapped(2.0), c in snapped(2.0),
                                  d in snapped(1.0), bu in 0.05f32..0.9, bv in 0.05f32..0.9,
                                  dist in 0.1f32..4.0, k in -100i32..=100) {
            prop_assume!(d.length() > 1e-2);
            // Aimed at a point inside (snapped, so it may move a little).
            let p = a + (b - a) * bu * (1.0 - bv) + (c - a) * bv;
            let o = ((p - d * dist) * 1024.0).round() / 1024.0;
            let n = (b - a).cross(c - a);
            prop_assume!(n.length() > 1e-2);
            prop_assume!(n.normalize().dot(d.normalize()).abs() > 1e-2);
            let want = reference(o, d, [a, b, c]);
            prop_assume!(want.is_some_and(|(t, u, v)| u.min(v).min(1.0 - u - v) > 1e-3 && t > 1e-3));
            let (t, u, v) = want.unwrap();
            let s = 2f32.powi(k);
            let r = Ray::infinite(o * s, d);
            let h = intersect_triangle(&r, f32::INFINITY, a * s, b * s, c * s);
            prop_assert!(h.is_some(), "lost the hit at 2^{k}");
            let h = h.unwrap();
            let ts = f64::from(h.t) / f64::from(s);
            prop_assert!((ts - t).abs() <= 1e-3 * (1.0 + t), "t {ts} against {t} at 2^{k}");
            prop_assert!((f64::from(h.u) - u).abs() <= 1e-3 && (f64::from(h.v) - v).abs() <= 1e-3);
        }
    }

    #[test]
    fn normals_of_huge_and_tiny_triangles() {
        for s in [1.0f32, 1e12, 1e30, 1e38, 1e-12, 1e-30, 1e-40] {
            let n = triangle_normal(Vec3::X * s, Vec3::Y * s, Vec3::Z * s);
            assert!((n - Vec3::ONE / 3f32.sqrt()).length() < 1e-6, "{n} at {s}");
        }
        assert_eq!(
            triangle_normal(Vec3::ZERO, Vec3::X, Vec3::X * 2.0),
            Vec3::ZERO
        );
    }

    #[test]
    fn huge_and_tiny_triangles_hit() {
        // A unit triangle at 10^15 (cubes past f32::MAX) and at 10^-15
        // (cubes below its least float), a ray down its middle.
        for s in [1e15f32, 1e30, 1e-15, 1e-30] {
            let r = Ray::infinite(Vec3::new(0.25, 0.25, 2.0) * s, -Vec3::Z);
            let h = intersect_triangle(&r, f32::INFINITY, Vec3::ZERO, Vec3::X * s, Vec3::Y * s)
                .unwrap_or_else(|| panic!("no hit at {s}"));
            assert!((h.t / s - 2.0).abs() < 1e-6, "t = {} at {s}", h.t);
            assert!((h.u - 0.25).abs() < 1e-6 && (h.v - 0.25).abs() < 1e-6);
        }
        // Beyond what `t` holds: no hit, not one at infinity.
        let r = Ray::infinite(Vec3::new(0.25, 0.25, 3e38), Vec3::new(0.0, 0.0, -1e-10));
        assert!(intersect_triangle(&r, f32::INFINITY, Vec3::ZERO, Vec3::X, Vec3::Y).is_none());
    }

    /// A ray that starts inside a closed mesh must leave it, so it must hit
    /// some triangle, also when aimed exactly at a shared vertex or at a point
    /// of a shared edge (watertightness).
    #[test]
    fn watertight_on_shared_edges_and_vertices() {
        use proptest::test_runner::{Config, TestRunner};
        // An octahedron with off-grid vertices, so that rounding is exercised.
        let v = [
            Vec3::new(1.1, 0.013, -0.07),
            Vec3::new(-0.97, 0.021, 0.05),
            Vec3::new(0.031, 1.23, 0.011),
            Vec3::new(-0.02, -1.07, 0.03),
            Vec3::new(0.04, 0.017, 0.93),
            Vec3::new(0.013, -0.029, -1.11),
        ];
        let faces = [
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        let edges: Vec<(usize, usize)> = faces
            .iter()
            .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
            .collect();
        let mut runner = TestRunner::new(Config {
            cases: 50000,
            ..Config::default()
        });
        let strat = (
            v3(0.3),
            0usize..(6 + edges.len()),
            0.0f32..1.0,
            1e-3f32..1e3,
        );
        runner
            .run(&strat, |(o, which, s, scale)| {
                let target = if which < 6 {
                    v[which]
                } else {
                    let (a, b) = edges[which - 6];
                    v[a].lerp(v[b], s)
                };
                let r = Ray::infinite(o, (target - o) * scale);
                let hit = faces.iter().any(|f| {
                    intersect_triangle(&r, f32::INFINITY, v[f[0]], v[f[1]], v[f[2]]).is_some()
                });
                prop_assert!(hit, "ray from {o:?} to {target:?} fell through");
                Ok(())
            })
            .unwrap();
    }

    #[test]
    fn area_in_f64() {
        let far = Vec3::splat(1e6);
        assert!(triangle_area2(far, far + Vec3::X * 0.5, far + Vec3::Y * 0.5) > 0.0);
        assert_eq!(triangle_area2(Vec3::ZERO, Vec3::X, Vec3::X * 2.0), 0.0);
    }
}
