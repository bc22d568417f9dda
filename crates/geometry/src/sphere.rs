//! Ray–sphere intersection, careful at grazing angles and far from the origin.

use crate::{Aabb, Ray};
use glam::Vec3;

/// A sphere by centre and radius.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre.
    pub center: Vec3,
    /// Radius (positive).
    pub radius: f32,
}

/// Result of a ray–sphere test: distance and the point's spherical
/// coordinates `u = φ / 2π`, `v = θ / π` (θ from +y), for texturing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SphereHit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Azimuth over 2π, in `[0, 1)`.
    pub u: f32,
    /// Polar angle from +y over π, in `[0, 1]`.
    pub v: f32,
}

impl Sphere {
    /// Makes a sphere.
    #[inline]
    #[must_use]
    pub fn new(center: Vec3, radius: f32) -> Self {
        Self { center, radius }
    }

    /// Bounding box.
    #[inline]
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        let r = Vec3::splat(self.radius.abs());
        Aabb::new(self.center - r, self.center + r)
    }

    /// Ray test over `[ray.tmin, tmax]`; see [`intersect_sphere`].
    #[inline]
    #[must_use]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<SphereHit> {
        intersect_sphere(ray, tmax, self.center, self.radius)
    }

    /// Outward unit normal at a point on the sphere.
    #[inline]
    #[must_use]
    pub fn normal_at(&self, p: Vec3) -> Vec3 {
        ((p - self.center) / self.radius).normalize_or_zero()
    }
}

/// Nearest intersection of the ray with the sphere within `[ray.tmin, tmax]`.
///
/// Uses the forms of Haines et al., "Precision Improvements for Ray/Sphere
/// Intersection" (Ray Tracing Gems, ch. 7): the discriminant is computed from
/// the distance between the centre and the ray's closest point, which keeps
/// its precision for small spheres far away and for grazing rays, and the two
/// roots come from the numerically stable pair `q / a`, `c / q`. In `f64`:
/// the test squares distances and the radius, which in `f32` overflow past
/// about 1e19 units and underflow below 1e-19 (a sphere 1e20 or 1e-20
/// across was missed); spheres are few in a scene, and `f64`'s arithmetic
/// costs them little.
#[must_use]
pub fn intersect_sphere(ray: &Ray, tmax: f32, center: Vec3, radius: f32) -> Option<SphereHit> {
    if !(radius > 0.0) || !center.is_finite() || !radius.is_finite() {
        return None;
    }
    let (d, center) = (ray.dir().as_dvec3(), center.as_dvec3());
    let radius = f64::from(radius);
    let f = ray.origin().as_dvec3() - center;
    let a = d.dot(d);
    let b = -f.dot(d); // half of -b in the textbook quadratic
    let l = f + (b / a) * d; // centre → closest point on the line
    let r2 = radius * radius;
    let disc = a * (r2 - l.dot(l));
    if !(disc >= 0.0) {
        return None;
    }
    let c = f.dot(f) - r2;
    let q = b + b.signum() * disc.sqrt();
    let (t0, t1) = if q == 0.0 {
        // Ray through the centre with the origin at the centre.
        let h = disc.sqrt() / a;
        (-h, h)
    } else {
        (c / q, q / a)
    };
    // Distances past f32's range are no hit.
    let (t0, t1) = (t0.min(t1) as f32, t0.max(t1) as f32);
    let t = if t0 >= ray.tmin() && t0 <= tmax && t0 < f32::INFINITY {
        t0
    } else if t1 >= ray.tmin() && t1 <= tmax && t1 < f32::INFINITY {
        t1
    } else {
        return None;
    };
    let n = (ray.origin().as_dvec3() + f64::from(t) * d - center) / radius;
    let phi = n.z.atan2(n.x) as f32;
    let u = if phi < 0.0 {
        phi / std::f32::consts::TAU + 1.0
    } else {
        phi / std::f32::consts::TAU
    };
    let v = (n.y.clamp(-1.0, 1.0) as f32).acos() / std::f32::consts::PI;
    Some(SphereHit { t, u, v })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The same hit at any scale: a unit sphere's hit, scaled by 1e30 or
    /// 1e-30 with its ray's origin (where `f32`'s squares overflow or
    /// underflow), at the scaled distance and the same point.
    #[test]
    fn hits_at_any_scale() {
        let o = Vec3::new(0.3, -0.2, -3.0);
        let d = Vec3::new(0.05, 0.02, 1.0);
        let unit = intersect_sphere(&Ray::infinite(o, d), f32::INFINITY, Vec3::ZERO, 1.0).unwrap();
        for s in [1e10f32, 1e20, 1e30, 1e-10, 1e-20, 1e-30] {
            let h = intersect_sphere(&Ray::infinite(o * s, d), f32::INFINITY, Vec3::ZERO, s)
                .unwrap_or_else(|| panic!("no hit at {s}"));
            assert!(
                (h.t / s - unit.t).abs() < 1e-5 * unit.t,
                "{} at {s}",
                h.t / s
            );
            assert!((h.u - unit.u).abs() < 1e-5 && (h.v - unit.v).abs() < 1e-5);
        }
    }

    #[test]
    fn front_and_inside() {
        let s = Sphere::new(Vec3::ZERO, 1.0);
        let r = Ray::infinite(Vec3::new(0.0, 0.0, -3.0), Vec3::Z);
        assert_eq!(s.intersect(&r, f32::INFINITY).unwrap().t, 2.0);
        let r = Ray::infinite(Vec3::ZERO, Vec3::Z);
        assert_eq!(s.intersect(&r, f32::INFINITY).unwrap().t, 1.0);
        let r = Ray::infinite(Vec3::new(0.0, 2.0, -3.0), Vec3::Z);
        assert!(s.intersect(&r, f32::INFINITY).is_none());
        let r = Ray::infinite(Vec3::new(0.0, 0.0, 3.0), Vec3::Z);
        assert!(s.intersect(&r, f32::INFINITY).is_none());
        let r = Ray::infinite(Vec3::new(f32::NAN, 0.0, -3.0), Vec3::Z);
        assert!(s.intersect(&r, f32::INFINITY).is_none());
        assert!(Sphere::new(Vec3::ZERO, 0.0)
            .intersect(&Ray::infinite(Vec3::Z * -3.0, Vec3::Z), f32::INFINITY)
            .is_none());
    }

    #[test]
    fn small_sphere_far_away() {
        // A 1 mm sphere 10 km away, hit dead centre and just inside its rim.
        let c = Vec3::new(1.0e4, 0.0, 0.0);
        let s = Sphere::new(c, 1e-3);
        let r = Ray::infinite(Vec3::ZERO, Vec3::X);
        let h = s.intersect(&r, f32::INFINITY).expect("centre hit");
        assert!((h.t - (1.0e4 - 1e-3)).abs() < 2e-3);
        let r = Ray::infinite(Vec3::new(0.0, 0.9e-3, 0.0), Vec3::X);
        assert!(s.intersect(&r, f32::INFINITY).is_some());
        let r = Ray::infinite(Vec3::new(0.0, 1.1e-3, 0.0), Vec3::X);
        assert!(s.intersect(&r, f32::INFINITY).is_none());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5000))]
        /// Hits lie on the sphere, and agree with an f64 reference away from grazing.
        #[test]
        fn matches_f64_reference(cx in -5.0f32..5.0, cy in -5.0f32..5.0, r in 0.1f32..2.0,
                                 ox in -10.0f32..10.0, oy in -10.0f32..10.0, dx in -1.0f32..1.0, dy in -1.0f32..1.0, dz in -1.0f32..1.0) {
            let d = Vec3::new(dx, dy, dz);
            prop_assume!(d.length() > 1e-2);
            let center = Vec3::new(cx, cy, 0.3);
            let o = Vec3::new(ox, oy, -4.0);
            let ray = Ray::infinite(o, d);
            let got = intersect_sphere(&ray, f32::INFINITY, center, r);
            let (od, dd, cd) = (o.as_dvec3(), d.as_dvec3(), center.as_dvec3());
            let f = od - cd;
            let (a, b, c) = (dd.dot(dd), 2.0 * f.dot(dd), f.dot(f) - (r as f64).powi(2));
            let disc = b * b - 4.0 * a * c;
            let want = if disc < 0.0 { None } else {
                let s = disc.sqrt();
                let (t0, t1) = ((-b - s) / (2.0 * a), (-b + s) / (2.0 * a));
                if t0 >= 0.0 { Some(t0) } else if t1 >= 0.0 { Some(t1) } else { None }
            };
            let grazing = disc.abs() < 1e-3 * b * b;
            match (got, want) {
                (Some(h), Some(t)) => prop_assert!((h.t as f64 - t).abs() < 1e-3 * (1.0 + t.abs())),
                (None, None) => {}
                (g, w) => prop_assert!(grazing || (w.is_some_and(|t| t < 1e-3)), "{g:?} vs {w:?}"),
            }
        }
    }
}
