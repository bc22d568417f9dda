//! Rendering: tiles on all cores, stratified samples, shading or heat map.

use crate::World;
use raymesh_geometry::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// What each pixel shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Whitted shading.
    Shade,
    /// Nodes visited plus primitives tested by the pixel's camera rays.
    Heatmap,
}

/// Render settings beyond the scene's.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Shading or heat map.
    pub mode: Mode,
}

/// A finished image and what it took.
pub struct Rendered {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear RGB (shade) or the mean cost per camera ray in `x` (heat map), row-major, row 0 at the top.
    pub pixels: Vec<Vec3>,
    /// Rays traced (camera, shadow and reflection).
    pub rays: u64,
    /// Seconds spent rendering.
    pub seconds: f64,
}

/// Edge of a square tile in pixels.
const TILE: u32 = 32;

/// Camera rays per stream ([`World::trace_stream`]), a multiple of eight
/// so that the streams' runs of eight are those of the whole tile. Its
/// shadow and mirror rays follow each stream in turn. `raymesh render
/// [bunny00.off] --threads 1 --width 800 --height 800`, pinned, render
/// seconds for streams of 128 / 256 / 512 / 1,024 / a whole tile (4,096
/// rays at 4 samples a pixel): the demo 1.20–1.21 / 1.18–1.19 / 1.17 /
/// 1.23–1.26 / 1.24–1.25, bunny00 0.70 / 0.68 / 0.68 / 0.72 / 0.72.
const STREAM: usize = 512;

/// SplitMix64 finalizer: a hash for per-pixel sample jitter, so the image
/// is the same on every run, thread count and structure.
fn hash(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn unit(h: u64) -> f32 {
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Sample `k` of `spp` in pixel `(x, y)`: stratified on a `g × g` grid
/// (`g = ⌈√spp⌉`), jittered within its cell; one sample is the pixel centre.
fn sample(x: u32, y: u32, k: u32, spp: u32) -> (f32, f32) {
    if spp == 1 {
        return (x as f32 + 0.5, y as f32 + 0.5);
    }
    let g = (spp as f32).sqrt().ceil() as u32;
    let (cx, cy) = (k % g, k / g);
    let h = hash(((y as u64) << 40) ^ ((x as u64) << 16) ^ k as u64 ^ 0x9e37_79b9_7f4a_7c15);
    let (jx, jy) = (unit(h), unit(hash(h)));
    (
        x as f32 + (cx as f32 + jx) / g as f32,
        y as f32 + (cy as f32 + jy) / g as f32,
    )
}

/// Renders the world; `progress(done, total)` is called as tiles finish.
pub fn render(world: &World, opts: Options, progress: &(dyn Fn(u64, u64) + Sync)) -> Rendered {
    let (w, h, spp) = (world.width, world.height, world.spp);
    let tiles_x = w.div_ceil(TILE);
    let tiles = (tiles_x * h.div_ceil(TILE)) as u64;
    let done = AtomicU64::new(0);
    let start = Instant::now();
    let results: Vec<(u32, u32, Vec<Vec3>, u64)> = (0..tiles as u32)
        .into_par_iter()
        .map(|t| {
            let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
            let (x1, y1) = ((x0 + TILE).min(w), (y0 + TILE).min(h));
            let tw = x1 - x0;
            let mut out = vec![Vec3::ZERO; (tw * (y1 - y0)) as usize];
            let mut rays = 0u64;
            // Sample `k` of pixel `(x, y)` as a point of the image.
            let point = |x: u32, y: u32, k: u32| {
                let (sx, sy) = sample(x, y, k, spp);
                (sx / w as f32, sy / h as f32)
            };
            let camera = |x: u32, y: u32, k: u32| {
                let (sx, sy) = point(x, y, k);
                world.camera.ray(sx, sy)
            };
            match opts.mode {
                Mode::Shade => {
                    // The tile's camera rays in 4 × 2 pixel blocks, each
                    // pixel's samples in order (so runs of eight make
                    // packets, and each pixel sums its samples as one by
                    // one would), traced in streams of STREAM.
                    // The rays made eight at a time (`Camera::rays8`, the
                    // same rays), the last few one by one.
                    let mut pixel = Vec::with_capacity((tw * (y1 - y0) * spp) as usize);
                    let mut stream = Vec::with_capacity(pixel.capacity());
                    let (mut sx, mut sy) = ([0.0f32; 8], [0.0f32; 8]);
                    let mut held = 0;
                    for by in (y0..y1).step_by(2) {
                        for bx in (x0..x1).step_by(4) {
                            for y in by..(by + 2).min(y1) {
                                for x in bx..(bx + 4).min(x1) {
                                    let p = ((y - y0) * tw + (x - x0)) as usize;
                                    for k in 0..spp {
                                        pixel.push(p);
                                        (sx[held], sy[held]) = point(x, y, k);
                                        held += 1;
                                        if held == 8 {
                                            stream.extend(world.camera.rays8(&sx, &sy));
                                            held = 0;
                                        }
                                    }
                                }
                            }
                        }
                    }
                    for i in 0..held {
                        stream.push(world.camera.ray(sx[i], sy[i]));
                    }
                    for (ps, rs) in pixel.chunks(STREAM).zip(stream.chunks(STREAM)) {
                        for (p, c) in ps.iter().zip(world.trace_stream(rs, 0, &mut rays)) {
                            out[*p] += c;
                        }
                    }
                }
                Mode::Heatmap => {
                    for y in y0..y1 {
                        for x in x0..x1 {
                            let p = ((y - y0) * tw + (x - x0)) as usize;
                            for k in 0..spp {
                                rays += 1;
                                out[p] += Vec3::new(world.cost(&camera(x, y, k)) as f32, 0.0, 0.0);
                            }
                        }
                    }
                }
            }
            for c in &mut out {
                *c /= spp as f32;
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, tiles);
            (x0, y0, out, rays)
        })
        .collect();
    let mut pixels = vec![Vec3::ZERO; (w * h) as usize];
    let mut rays = 0;
    for (x0, y0, tile, r) in results {
        rays += r;
        let tw = (x0 + TILE).min(w) - x0;
        for (i, p) in tile.into_iter().enumerate() {
            let (x, y) = (x0 + i as u32 % tw, y0 + i as u32 / tw);
            pixels[(y * w + x) as usize] = p;
        }
    }
    Rendered {
        width: w,
        height: h,
        pixels,
        rays,
        seconds: start.elapsed().as_secs_f64(),
    }
}
