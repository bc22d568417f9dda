//! NEON kernels for aarch64, where NEON is part of the base architecture
//! (no run-time check): the 8-wide node's slab test and the watertight
//! test of a block of 8 triangles, each as two halves of 4 lanes. They do
//! the portable code's arithmetic in its order, so they give its results
//! bit for bit (the tests below compare them; CI runs them under
//! `qemu-aarch64`). The plain loops they replace compile to scalar code
//! on aarch64: LLVM vectorized neither (`objdump` of the walk showed no
//! vector arithmetic). Off under [`crate::set_simd_enabled`]`(false)`, as
//! the AVX2 kernels are on x86-64.
//!
//! The kernels are safe code over the one-line wrappers of `q` below:
//! the intrinsics are `unsafe` to call from functions without
//! `#[target_feature(enable = "neon")]`, and this module compiles only
//! where the build enables NEON (`cfg(target_feature)`), which makes each
//! call sound; the loads and stores touch slices checked to hold them.
//! (As `#[target_feature]` functions, where the calls are safe, the
//! kernels' closures did not inline: half again the instructions a ray,
//! under qemu.)
#![allow(unsafe_code)]

use crate::bvh::{BoxRay, WideNode};
use crate::prims::BlockHits;
use crate::simd::{block_at, GROUP, GROUP_SLOTS};
use q::F;
use raymesh_geometry::Ray;

/// Safe wrappers of the NEON intrinsics the kernels use. SAFETY (every
/// `unsafe` block here): the module compiles only where the build enables
/// NEON, which is all these intrinsics require, but for the loads and
/// stores, whose slices are checked to hold the 4 floats they touch.
mod q {
    use core::arch::aarch64 as a;
    /// Four floats.
    pub(super) type F = a::float32x4_t;
    /// Four lane masks (all ones or all zeros).
    pub(super) type M = a::uint32x4_t;

    macro_rules! wrap {
        ($($name:ident($($x:ident: $t:ty),*) -> $r:ty = $f:ident;)*) => {$(
            #[inline(always)]
            pub(super) fn $name($($x: $t),*) -> $r {
                unsafe { a::$f($($x),*) }
            }
        )*};
    }
    wrap! {
        add(x: F, y: F) -> F = vaddq_f32;
        sub(x: F, y: F) -> F = vsubq_f32;
        mul(x: F, y: F) -> F = vmulq_f32;
        div(x: F, y: F) -> F = vdivq_f32;
        abs(x: F) -> F = vabsq_f32;
        splat(x: f32) -> F = vdupq_n_f32;
        eq(x: F, y: F) -> M = vceqq_f32;
        lt(x: F, y: F) -> M = vcltq_f32;
        le(x: F, y: F) -> M = vcleq_f32;
        gt(x: F, y: F) -> M = vcgtq_f32;
        ge(x: F, y: F) -> M = vcgeq_f32;
        and(x: M, y: M) -> M = vandq_u32;
        or(x: M, y: M) -> M = vorrq_u32;
        and_not(x: M, y: M) -> M = vbicq_u32;
        not(x: M) -> M = vmvnq_u32;
        select(m: M, x: F, y: F) -> F = vbslq_f32;
    }

    /// `[x0, x1, x2, x3]`.
    #[inline(always)]
    pub(super) fn new(x: [f32; 4]) -> F {
        unsafe { a::vld1q_f32(x.as_ptr()) }
    }

    /// Bit `i` set where lane `i` of `m` is true.
    #[inline(always)]
    pub(super) fn bits(m: M) -> u32 {
        let w = [1u32, 2, 4, 8];
        unsafe { a::vaddvq_u32(a::vandq_u32(m, a::vld1q_u32(w.as_ptr()))) }
    }

    /// Four floats of `s` from `at`: panics unless they are all in `s`.
    #[inline(always)]
    pub(super) fn load(s: &[f32], at: usize) -> F {
        let four = &s[at..at + 4];
        unsafe { a::vld1q_f32(four.as_ptr()) }
    }

    /// Stores `x` to `s[at..at + 4]`: panics unless they are all in `s`.
    #[inline(always)]
    pub(super) fn store(s: &mut [f32], at: usize, x: F) {
        let four = &mut s[at..at + 4];
        unsafe { a::vst1q_f32(four.as_mut_ptr(), x) }
    }
}

/// `a > b ? a : b` in each lane: `b` when either is NaN, as
/// [`raymesh_geometry::max_nan_second`] (NEON's `fmax` would propagate it).
#[inline(always)]
fn max_ns(a: F, b: F) -> F {
    q::select(q::gt(a, b), a, b)
}

/// `a < b ? a : b` in each lane: [`raymesh_geometry::min_nan_second`].
#[inline(always)]
fn min_ns(a: F, b: F) -> F {
    q::select(q::lt(a, b), a, b)
}

/// The slab test of an 8-wide or a 4-wide node's boxes, 4 lanes at a
/// time: the results of [`crate::bvh::slab_scalar`] bit for bit (entry
/// distances in `t`, a bit per child entered before `bound`). Panics
/// unless `W` is 4 or 8.
#[inline(always)]
pub(crate) fn slab_wide<const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    assert!(W == 8 || W == 4);
    let mut mask = 0;
    for half in (0..W).step_by(4) {
        let axis = |a: usize| {
            let (near, far) = (n.plane_row(r.near[a]), n.plane_row(r.far[a]));
            let o = q::splat(r.origin[a]);
            let inv = q::splat(r.inv_dir[a]);
            let inv_exit = q::splat(r.inv_exit[a]);
            let lo = q::mul(q::sub(q::load(near, half), o), inv);
            let hi = q::mul(q::sub(q::load(far, half), o), inv_exit);
            (lo, hi)
        };
        let (l0, h0) = axis(0);
        let (l1, h1) = axis(1);
        let (l2, h2) = axis(2);
        // Two maxima side by side, then the greater of theirs, as the
        // portable test takes them.
        let e = max_ns(max_ns(l0, l1), max_ns(l2, q::splat(r.tmin)));
        let x = min_ns(min_ns(h0, h1), min_ns(h2, q::splat(bound)));
        q::store(t, half, e);
        mask |= q::bits(q::le(e, x)) << half;
    }
    mask
}

/// The watertight test of up to 8 triangles at once, as
/// [`crate::simd::triangles8`] does it with AVX2: slots `first..first +
/// count` of rows grouped as [`crate::Triangles`] lays them out; lanes
/// past `count` are ignored. Returns the mask of lanes hit (their `t`,
/// `u`, `v` in the hits), and the mask of lanes the scalar test redoes in
/// f64 ([`raymesh_geometry::needs_f64`]: an edge function of exactly
/// zero, values out of `f32`'s range), which are not in the hit mask. The same bits as the scalar test. Panics if a
/// row would be read past `data`.
#[inline(always)]
pub(crate) fn triangles8(
    data: &[f32],
    first: usize,
    count: usize,
    ray: &Ray,
    tmax: f32,
) -> (u32, u32, BlockHits) {
    let (at, span) = block_at(first, count);
    // The two windows of a group's size the block's loads lie in: from
    // its offset, and `span` further on (the same when the block is in
    // one group); checked once, so that the loads' own checks fold away.
    let window = |from: usize| -> &[f32; GROUP] {
        data.get(from..from + GROUP)
            .and_then(|w| w.try_into().ok())
            .expect("a block's rows lie in the triangles' data")
    };
    let (win, next_win) = (window(at), window(at + span));
    let lane = first % GROUP_SLOTS;
    let (s, k) = ray.shear();
    let origin = ray.permute(ray.origin());
    let (sx, sy, sz) = (q::splat(s.x), q::splat(s.y), q::splat(s.z));
    let (ox, oy, oz) = (q::splat(origin.x), q::splat(origin.y), q::splat(origin.z));
    let zero = q::splat(0.0);
    let one = q::splat(1.0);
    let (t_lo, t_hi) = (q::splat(ray.tmin()), q::splat(tmax));
    let mut out = BlockHits::default();
    let (mut hit, mut redo) = (0, 0);
    // Each half of the block, with `half` a constant in each (a loop
    // left the loads' bounds checks in, 2 instructions a load).
    macro_rules! half {
        ($half:literal) => {{
            let half: usize = $half;
            // Lanes `half + i` from `GROUP_SLOTS - lane` on lie in the next
            // group, `span` floats further on.
            let next = q::ge(
                q::new([0.0, 1.0, 2.0, 3.0].map(|i| i + half as f32)),
                q::splat((GROUP_SLOTS - lane) as f32),
            );
            // Corner `c`'s coordinate on the ray's permuted axis `a`, row
            // `3 * c + k[a]` (macros, not closures: LLVM called the
            // closures, 9 times a block).
            macro_rules! load {
                ($c:expr, $a:literal) => {{
                    let row = (3 * $c + k[$a]).min(8) * GROUP_SLOTS + half;
                    q::select(next, q::load(next_win, row), q::load(win, row))
                }};
            }
            // Corner `c` relative to the ray origin and sheared to 2D, in the
            // scalar test's order of operations.
            macro_rules! shear {
                ($c:expr) => {{
                    let x = q::sub(load!($c, 0), ox);
                    let y = q::sub(load!($c, 1), oy);
                    let z = q::sub(load!($c, 2), oz);
                    (
                        q::sub(x, q::mul(sx, z)),
                        q::sub(y, q::mul(sy, z)),
                        q::mul(sz, z),
                    )
                }};
            }
            let (ax, ay, az) = shear!(0);
            let (bx, by, bz) = shear!(1);
            let (cx, cy, cz) = shear!(2);
            let u = q::sub(q::mul(cx, by), q::mul(cy, bx));
            let v = q::sub(q::mul(ax, cy), q::mul(ay, cx));
            let w = q::sub(q::mul(bx, ay), q::mul(by, ax));
            let flat = q::or(q::eq(u, zero), q::or(q::eq(v, zero), q::eq(w, zero)));
            let any_neg = q::or(q::lt(u, zero), q::or(q::lt(v, zero), q::lt(w, zero)));
            let any_pos = q::or(q::gt(u, zero), q::or(q::gt(v, zero), q::gt(w, zero)));
            let det = q::add(q::add(u, v), w);
            let t_scaled = q::add(q::add(q::mul(u, az), q::mul(v, bz)), q::mul(w, cz));
            let inv_det = q::div(one, det);
            let t = q::mul(t_scaled, inv_det);
            // Inside (all edge functions of one sign), a plane that is not
            // edge-on (`det` neither 0 nor NaN: `det == det` rules NaN out, as
            // `vceqq` alone does not), and `t` in the interval (NaN fails
            // every comparison).
            let edge_on = q::or(q::eq(det, zero), q::not(q::eq(det, det)));
            let ok = q::and_not(
                q::and(q::ge(t, t_lo), q::le(t, t_hi)),
                q::or(edge_on, q::and(any_neg, any_pos)),
            );
            // The lanes the scalar test redoes in f64 (`needs_f64`, the
            // same `f32` values): an edge function of zero, `|det| +
            // |t_scaled|` not below infinity (NaN included), or, inside,
            // either below the least normal float.
            let (ad, at) = (q::abs(det), q::abs(t_scaled));
            let least = q::splat(f32::MIN_POSITIVE);
            let big = q::not(q::lt(q::add(ad, at), q::splat(f32::INFINITY)));
            let small = q::or(q::lt(ad, least), q::lt(at, least));
            let redo_lanes = q::or(
                flat,
                q::or(big, q::and_not(small, q::and(any_neg, any_pos))),
            );
            hit |= q::bits(ok) << half;
            redo |= q::bits(redo_lanes) << half;
            q::store(&mut out.t, half, t);
            q::store(&mut out.u, half, q::mul(v, inv_det));
            q::store(&mut out.v, half, q::mul(w, inv_det));
        }};
    }
    half!(0);
    half!(4);
    let active = if count >= 8 {
        0xff
    } else {
        (1u32 << count) - 1
    };
    let (hit, redo) = (hit & active, redo & active);
    (hit & !redo, redo, out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{hard_coord, hard_vec3, lanes_match, lattice, node_kernel_matches};
    use crate::{Primitives, Triangles};
    use proptest::prelude::*;
    use raymesh_geometry::{intersect_triangle, Vec3};

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The NEON node test and the plain loops give the same bits, on
        /// any boxes (empty slots too) and rays (NaN, infinities, zeros),
        /// of 8-wide nodes and of 4-wide ones (the first four boxes).
        #[test]
        fn neon_slab_matches_fallback(
            corners in proptest::collection::vec((hard_vec3(), hard_vec3()), 8),
            used in 0u32..256,
            o in hard_vec3(), d in hard_vec3(),
            tmin in hard_coord(), bound in hard_coord(),
        ) {
            node_kernel_matches(slab_wide::<8>, &corners, used, (o, d, tmin, bound))?;
            node_kernel_matches(slab_wide::<4>, &corners[..4], used & 15, (o, d, tmin, bound))?;
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The NEON triangle block gives what the scalar test gives, lane
        /// by lane: the same hits and the same bits of `t`, `u`, `v`, for a
        /// block anywhere in the rows (in one group or straddling two, from
        /// any lane, up to their very end), with rays through shared edges
        /// and vertices (lattice points), which take the f64 path.
        #[test]
        fn neon_triangles_match_scalar(
            tris in proptest::collection::vec(
                prop_oneof![(hard_vec3(), hard_vec3(), hard_vec3()), (lattice(), lattice(), lattice())], 32),
            first in 0usize..24, count in 0usize..9, extra in 0usize..9,
            o in prop_oneof![hard_vec3(), lattice()], d in prop_oneof![hard_vec3(), lattice()],
            tmin in prop_oneof![Just(0.0f32), hard_coord()], tmax in hard_coord(),
        ) {
            let len = (first + count + extra).min(tris.len());
            let corners: Vec<[Vec3; 3]> = tris[..len].iter().map(|&(a, b, c)| [a, b, c]).collect();
            let tris = Triangles::from_corners(&corners);
            let ray = Ray::new(o, d, tmin, f32::INFINITY);
            let want = |k: usize| {
                (k < count).then(|| {
                    let [a, b, c] = corners[first + k];
                    intersect_triangle(&ray, tmax, a, b, c)
                })?
            };
            // Through the block test the walks call (the kernel, then the
            // f64 path for its `redo` lanes).
            let (mask, out) = tris.intersect_block(first as u32, count as u32, &ray, tmax);
            lanes_match(mask, &out, want)?;
        }
    }

    /// The kernel flags a lane for the f64 path exactly where an edge
    /// function is zero, and leaves that lane out of its hits: a ray along
    /// the shared edge of two triangles.
    #[test]
    fn shared_edge_takes_the_f64_path() {
        let corners = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
        ];
        let tris = Triangles::from_corners(&corners);
        // Through the midpoint of the shared edge from (1, 0) to (0, 1).
        let ray = Ray::new(Vec3::new(0.5, 0.5, -1.0), Vec3::Z, 0.0, f32::INFINITY);
        let (hit, redo, _) = triangles8(tris.rows(), 0, 2, &ray, f32::INFINITY);
        assert_eq!((hit, redo), (0b00, 0b11));
        let (mask, out) = tris.intersect_block(0, 2, &ray, f32::INFINITY);
        assert_ne!(mask, 0);
        for k in 0..2 {
            if mask >> k & 1 != 0 {
                assert_eq!(out.t[k], 1.0);
            }
        }
    }
}
