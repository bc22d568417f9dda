//! Support code of the `raymesh` tool that the benchmark crate shares: the
//! numpy ray and hit files of `../shared/BENCH.md`, its ray workloads, and
//! how tables print rates.

pub mod npy;
pub mod workload;

/// A rate for a table: two decimals, or three significant digits when it
/// is below 0.1 (a grid on the teapot in a stadium runs at 0.0016 Mrays/s,
/// which two decimals would print as 0.00).
pub fn rate(x: f64) -> String {
    if x > 0.0 && x < 0.1 {
        let digits = (2 - x.log10().floor() as i32).clamp(0, 9) as usize;
        format!("{x:.digits$}")
    } else {
        format!("{x:.2}")
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn small_rates_keep_three_significant_digits() {
        assert_eq!(super::rate(5.26), "5.26");
        assert_eq!(super::rate(0.25), "0.25");
        assert_eq!(super::rate(0.0016), "0.00160");
        assert_eq!(super::rate(0.04), "0.0400");
        assert_eq!(super::rate(0.0), "0.00");
    }
}

/// The README's Rust examples, run as doctests so that they keep up with
/// the library.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;
