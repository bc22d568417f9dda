//! Writing images: linear RGB to 8-bit sRGB PNG, and the heat-map palette.

use raymesh_geometry::Vec3;
use std::path::Path;

/// The sRGB transfer function (IEC 61966-2-1) of a linear value in `[0, 1]`.
fn srgb(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// 8-bit sRGB bytes of linear RGB pixels (NaN and negatives become 0).
#[must_use]
pub fn to_srgb8(pixels: &[Vec3]) -> Vec<u8> {
    pixels
        .iter()
        .flat_map(|p| [srgb(p.x), srgb(p.y), srgb(p.z)])
        .collect()
}

/// A perceptually ordered palette (dark blue, purple, orange, yellow, like
/// matplotlib's "inferno") at `t` in `[0, 1]`, as linear RGB.
#[must_use]
pub fn heat_color(t: f32) -> Vec3 {
    const STOPS: [[f32; 3]; 6] = [
        [0.0, 0.0, 0.016],
        [0.04, 0.005, 0.18],
        [0.3, 0.02, 0.25],
        [0.75, 0.1, 0.07],
        [0.98, 0.45, 0.0],
        [0.98, 0.96, 0.55],
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * (STOPS.len() - 1) as f32;
    let i = (t as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    Vec3::from_array(STOPS[i]).lerp(Vec3::from_array(STOPS[i + 1]), f)
}

/// Writes 8-bit sRGB pixels as a PNG.
pub fn save_png(
    path: &Path,
    width: u32,
    height: u32,
    srgb8: &[u8],
) -> Result<(), image::ImageError> {
    image::save_buffer(path, srgb8, width, height, image::ColorType::Rgb8)
}
