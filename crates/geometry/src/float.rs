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
    fn gamma_grows_with_n() {
        assert!(gamma(3) > gamma(2));
        assert!(gamma(1) > 0.0 && gamma(1) < 1e-7);
    }
}
