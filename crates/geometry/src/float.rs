//! Floating-point error bounds (pbrt-v4, "Floating-Point Arithmetic", §6.8).

/// Half an ulp of 1.0: the relative rounding error of one `f32` operation.
pub const MACHINE_EPSILON: f32 = f32::EPSILON * 0.5;

/// Bound on the relative error of `n` chained floating-point operations,
/// `n ε / (1 - n ε)` (Higham); used to pad intervals so they stay conservative.
#[inline]
#[must_use]
pub const fn gamma(n: i32) -> f32 {
    (n as f32 * MACHINE_EPSILON) / (1.0 - n as f32 * MACHINE_EPSILON)
}

/// `1 + 2 γ(3)`: scaling a slab test's exit distance by it keeps the test
/// conservative under rounding (Ize, "Robust BVH Ray Traversal", JCGT 2013).
pub const ROBUST_EXIT: f32 = 1.0 + 2.0 * gamma(3);

/// The reciprocal direction component a slab test computes exit distances
/// with: `inv_dir × ROBUST_EXIT`, once a ray, so that each exit is
/// `(far - origin) × exit_reciprocal(inv_dir)`, padded without a
/// multiplication of its own (one fewer a plane in every node test).
///
/// The padding still bounds the rounding (Ize 2013): entry and exit share
/// the rounded reciprocal, whose error scales both alike; past it the exit
/// is rounded three times (the difference, the padded reciprocal, the
/// product) as it was (the difference, the product, the padding), and the
/// entry twice.
#[inline(always)]
#[must_use]
pub fn exit_reciprocal(inv_dir: f32) -> f32 {
    inv_dir * ROBUST_EXIT
}

/// `a` if `a > b`, else `b`: returns `b` when `a` is NaN, in one `maxss`
/// (unlike `f32::max`, which adds NaN fix-ups). Slab tests pass the
/// accumulator as `b`, so a NaN slab constrains nothing.
#[inline(always)]
#[must_use]
pub fn max_nan_second(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `a` if `a < b`, else `b`: returns `b` when `a` is NaN, in one `minss`.
#[inline(always)]
#[must_use]
pub fn min_nan_second(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// The next representable `f32` above `x` (identity on +inf and NaN).
#[inline]
#[must_use]
pub fn next_up(x: f32) -> f32 {
    if x.is_nan() || x == f32::INFINITY {
        return x;
    }
    if x == 0.0 {
        return f32::from_bits(1);
    }
    let bits = x.to_bits();
    f32::from_bits(if x > 0.0 { bits + 1 } else { bits - 1 })
}

/// The next representable `f32` below `x` (identity on -inf and NaN).
#[inline]
#[must_use]
pub fn next_down(x: f32) -> f32 {
    -next_up(-x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_up_down_step_one_ulp() {
        assert!(next_up(1.0) > 1.0);
        assert_eq!(next_down(next_up(1.0)), 1.0);
        assert!(next_up(0.0) > 0.0);
        assert!(next_down(0.0) < 0.0);
        assert_eq!(next_up(f32::INFINITY), f32::INFINITY);
        assert!(next_up(-1.0) > -1.0);
    }

    #[test]
    fn nan_second_keeps_the_accumulator() {
        assert_eq!(max_nan_second(f32::NAN, 1.0), 1.0);
        assert_eq!(min_nan_second(f32::NAN, 1.0), 1.0);
        assert_eq!(max_nan_second(2.0, 1.0), 2.0);
        assert_eq!(min_nan_second(0.5, 1.0), 0.5);
    }

    #[test]
    fn gamma_grows_with_n() {
        assert!(gamma(3) > gamma(2));
        assert!(gamma(1) > 0.0 && gamma(1) < 1e-7);
    }
}

/// `v` scaled to unit length, zero for a zero (or non-finite) vector, for
/// any finite `v`: glam's `normalize_or_zero` where its squared length is
/// a normal `f32` (the same bits), in `f64` where it is not (vectors
/// longer than about 1e19, whose squared length overflows, or shorter
/// than about 1e-19, whose squared length underflows or loses its
/// digits: `f32` gave zero, NaN or a vector not of unit length).
#[inline]
#[must_use]
pub fn unit_vector(v: glam::Vec3) -> glam::Vec3 {
    if v.length_squared().is_normal() {
        return v.normalize_or_zero();
    }
    v.as_dvec3().normalize_or_zero().as_vec3()
}

#[cfg(test)]
mod unit_tests {
    use super::unit_vector;
    use glam::Vec3;

    #[test]
    fn unit_vectors_at_any_scale() {
        let v = Vec3::new(3.0, -4.0, 12.0);
        for s in [1.0f32, 1e20, 1e37, 1e-20, 1e-37] {
            let u = unit_vector(v * s);
            assert!((u - v / 13.0).length() < 1e-6, "{u} at {s}");
        }
        assert_eq!(unit_vector(v), v.normalize());
        assert_eq!(unit_vector(Vec3::ZERO), Vec3::ZERO);
        assert_eq!(unit_vector(Vec3::new(f32::NAN, 0.0, 1.0)), Vec3::ZERO);
    }
}
