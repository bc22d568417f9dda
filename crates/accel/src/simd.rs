//! SIMD kernels (wide BVH nodes, triangle blocks), chosen at run time.
//!
//! The only `unsafe` of the crate lives here: calls to `std::arch`
//! intrinsics, each behind a check that the CPU has the instructions.
//! Every kernel has a safe fallback in plain Rust (the caller's loops, which
//! the compiler vectorizes for the target's baseline), and a test below
//! compares the two bit for bit on random and degenerate input. The
//! kernels perform the same IEEE operations in the same order as the
//! fallback, without fused multiply-adds, so their results are identical.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use crate::bvh::{BoxRay, Bvh, NodePair, PairRay, WideNode};
#[cfg(target_arch = "x86_64")]
use crate::packet::PacketLeaf;
#[cfg(target_arch = "x86_64")]
use crate::BlockHits;
use raymesh_geometry::Ray;

use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};

/// Whether the SIMD kernels may be used (see [`set_simd_enabled`]).
static SIMD_ENABLED: AtomicBool = AtomicBool::new(true);

/// Turns the SIMD kernels on or off for the whole process (on by default;
/// they are used only where the CPU supports them). Off, every structure
/// runs its portable fallback, which gives bit-identical results: for
/// measuring what the kernels buy, and for testing the fallbacks on
/// machines that have the instructions.
pub fn set_simd_enabled(on: bool) {
    SIMD_ENABLED.store(on, Ordering::SeqCst);
    LEVEL.store(UNKNOWN, Ordering::SeqCst);
}

/// What [`Avx2::detect`] finds, kept in one byte: [`UNKNOWN`] until the
/// first query after start-up or after a switch ([`set_simd_enabled`],
/// [`set_avx512_enabled`]), then [`NO_AVX2`], [`AVX2`] or [`AVX512`]. One
/// load a query, where reading the two switches and the CPU's feature
/// cache took five loads and as many branches (bunny00's random rays
/// through `bvh8`, callgrind: 1,007 -> 999 instructions a closest hit).
static LEVEL: AtomicU8 = AtomicU8::new(UNKNOWN);
const UNKNOWN: u8 = 0;
const NO_AVX2: u8 = 1;
const AVX2: u8 = 2;
const AVX512: u8 = 3;

/// [`LEVEL`] worked out from the switches and the CPU, and stored. A
/// switch thrown while this runs may reset [`LEVEL`] before the store
/// here, which would then keep the old switches' level: so the switches
/// are read again after the store (all in one order, `SeqCst`), and the
/// level worked out again until it stands.
#[cold]
#[inline(never)]
fn find_level() -> u8 {
    let work_out = || {
        if !(SIMD_ENABLED.load(Ordering::SeqCst) && cpu_has_avx2()) {
            NO_AVX2
        } else if AVX512_ENABLED.load(Ordering::SeqCst)
            && cpu_has_avx512vl()
            && !avx512_off_by_env()
        {
            AVX512
        } else {
            AVX2
        }
    };
    loop {
        let level = work_out();
        LEVEL.store(level, Ordering::SeqCst);
        if work_out() == level {
            return level;
        }
    }
}

/// [`LEVEL`], worked out on first use.
#[inline(always)]
fn level() -> u8 {
    match LEVEL.load(Ordering::Relaxed) {
        UNKNOWN => find_level(),
        l => l,
    }
}

/// Whether the SIMD kernels are enabled (a loop reads it once, before it
/// starts: an atomic load is not hoisted out of a loop).
#[inline(always)]
#[must_use]
pub(crate) fn simd_enabled() -> bool {
    SIMD_ENABLED.load(Ordering::Relaxed)
}

/// Whether the SIMD kernels are enabled and this CPU has AVX2.
#[inline(always)]
#[must_use]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn has_avx2() -> bool {
    level() >= AVX2
}

/// Whether this CPU has AVX2, and POPCNT, which every CPU with AVX2 has
/// and the AVX2 builds use (detected once, then a cached load).
#[inline(always)]
#[must_use]
fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Runs `f` compiled with AVX2 enabled, so that the kernels it inlines use
/// 256-bit instructions. Panics if the CPU lacks AVX2 (callers check
/// [`has_avx2`] first; the check here keeps this function safe).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    assert!(cpu_has_avx2(), "with_avx2 called on a CPU without AVX2");
    // SAFETY: the CPU supports AVX2 and POPCNT, checked just above.
    unsafe { run_avx2(f) }
}

/// Compiled with POPCNT too: a group walk counts the rays of each node
/// visit, which as shifts and masks took 15 instructions a node.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn run_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt,avx512f,avx512vl")]
unsafe fn run_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// Whether [`Avx2::detect`] may hand out proofs that run code compiled
/// for AVX-512 ([`Avx2::run_wide`]) where the CPU has it.
static AVX512_ENABLED: AtomicBool = AtomicBool::new(true);

/// Turns the AVX-512 builds of the 8-wide BVH walks off or on for the
/// whole process (on by default; used only where the CPU has AVX-512F
/// and AVX-512VL). They run the AVX2 walks' instructions with twice the
/// vector registers, and give the same results, bit for bit: off, the
/// AVX2 builds run, for measuring what the registers buy and for testing
/// the AVX2 builds on machines with AVX-512.
pub fn set_avx512_enabled(on: bool) {
    AVX512_ENABLED.store(on, Ordering::SeqCst);
    LEVEL.store(UNKNOWN, Ordering::SeqCst);
}

/// Whether this CPU has AVX-512F and AVX-512VL (detected once, then a
/// cached load). Always false in a build with `--cfg raymesh_no_avx512`
/// (see [`Avx2::wide`]).
#[inline(always)]
#[must_use]
fn cpu_has_avx512vl() -> bool {
    #[cfg(all(target_arch = "x86_64", not(raymesh_no_avx512)))]
    {
        std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl")
    }
    #[cfg(not(all(target_arch = "x86_64", not(raymesh_no_avx512))))]
    {
        false
    }
}

/// Whether the environment turns the AVX-512 builds off:
/// `RAYMESH_AVX512=off` (or `0`), read where the SIMD level is worked out
/// (at the first query, and again after each switch). The same as
/// [`set_avx512_enabled`]`(false)` for programs that do not call it: a
/// profile-guided build's training runs its binaries once with and once
/// without, so that both builds of the walks are trained on a CPU with
/// AVX-512 (`scripts/pgo-build.sh`).
fn avx512_off_by_env() -> bool {
    std::env::var_os("RAYMESH_AVX512").is_some_and(|v| v == "off" || v == "0")
}

/// `avx.run_wide(f)` where the proof `avx` allows AVX-512, else
/// `avx.run(f)`: the closure expression `f` written out once for each,
/// so that each build inlines its own copy. One closure handed to both
/// was inlined into neither, and its kernels became calls (bvh8 ran 3 to
/// 6 times slower).
macro_rules! avx_run {
    ($avx:expr, $f:expr) => {{
        let avx: $crate::simd::Avx2 = $avx;
        if avx.wide() {
            avx.run_wide($f)
        } else {
            avx.run($f)
        }
    }};
}
pub(crate) use avx_run;

/// Asks the CPU to start loading the cache lines of `x`: a hint, with no
/// effect on any result. Traversals use it for the nodes they will visit
/// after the next one (+8% on random rays at 4.8M triangles). Not
/// switched off by [`set_simd_enabled`]: the flag, read through the GOT
/// before every cache line, cost 13 instructions a ray on bunny00
/// (callgrind), and a hint changes no result.
#[inline(always)]
pub(crate) fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = std::ptr::from_ref(x).cast::<i8>();
        for line in (0..std::mem::size_of::<T>()).step_by(64) {
            // SAFETY: SSE is part of x86_64, and a prefetch never faults
            // nor reads anything into the program: any address is fine.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(line)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// [`prefetch`] of `v[i]`'s first cache line, with no bounds check: an
/// index out of range only prefetches a line nobody reads.
#[inline(always)]
pub(crate) fn prefetch_at<T>(v: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = v.as_ptr().wrapping_add(i).cast::<i8>();
        // SAFETY: SSE is part of x86_64, and a prefetch never faults nor
        // reads anything into the program: any address is fine.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (v, i);
}

/// Each of the first three lanes of `f` clamped to `[0, last]` (a NaN to
/// 0) and truncated to an integer, packed into the three low bytes of a
/// `u32` (`last` is below 256): a centroid's bin on each axis in the
/// binned BVH builders, which do it for every primitive of every node.
/// On x86-64 one SSE2 conversion does the three lanes and two packs put
/// them in one register, where Rust's `as` conversion checks each lane
/// for NaN and overflow (a third of the binning loop's instructions);
/// elsewhere, and when `simd` is false (the caller's reading of
/// [`simd_enabled`]), the same in plain Rust.
#[inline(always)]
pub(crate) fn truncate3(f: raymesh_geometry::Vec3A, last: f32, simd: bool) -> u32 {
    debug_assert!(last < 256.0);
    // `max_keep` returns its second operand, 0, when `f` is NaN (SSE's
    // `maxps` everywhere; glam's `max` would return NaN on aarch64).
    let f = crate::bvh::min_keep(
        crate::bvh::max_keep(f, raymesh_geometry::Vec3A::ZERO),
        raymesh_geometry::Vec3A::splat(last),
    );
    #[cfg(target_arch = "x86_64")]
    if simd {
        return truncate3_sse2(f);
    }
    let _ = simd;
    truncate3_scalar(f)
}

/// [`truncate3`]'s conversion and packing in SSE2, of lanes already
/// clamped to `[0, last]`, `last` below 256.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn truncate3_sse2(f: raymesh_geometry::Vec3A) -> u32 {
    use std::arch::x86_64::{
        __m128, _mm_cvtsi128_si32, _mm_cvttps_epi32, _mm_packs_epi32, _mm_packus_epi16,
    };
    // SAFETY: SSE2 is part of x86-64, so every x86-64 CPU has it. Lanes
    // of 0..=255 pass both saturating packs unchanged.
    let bytes = unsafe {
        let k = _mm_cvttps_epi32(__m128::from(f));
        let w = _mm_packs_epi32(k, k);
        _mm_cvtsi128_si32(_mm_packus_epi16(w, w))
    };
    bytes as u32 & 0x00ff_ffff
}

/// [`truncate3`]'s conversion lane by lane, of lanes already clamped.
#[inline(always)]
fn truncate3_scalar(f: raymesh_geometry::Vec3A) -> u32 {
    let k = |x: f32| x as u32;
    k(f.x) | k(f.y) << 8 | k(f.z) << 16
}

/// The node test of a `W`-wide node for the one-ray walks that run in an
/// AVX2 region ([`crate::bvh::WideBvh::traverse_blocks_avx2`]):
/// [`slab8`] for 8-wide nodes, [`slab4`] for 4-wide ones (the branch is
/// on a constant). The same result as `bvh::wide::slab_scalar`, bit for
/// bit. Panics unless `W` is 4 or 8.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn slab_wide<const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    if W == 8 {
        slab8(n, r, bound, t)
    } else {
        slab4(n, r, bound, t)
    }
}

/// The slab test of a 4-wide node's boxes in SSE (part of every x86-64
/// CPU, so no check is needed): the same result as
/// `bvh::wide::slab_scalar` (entry distances in `t`, a bit per child
/// entered before `bound`), bit for bit, with the operations of
/// [`slab8`] on 4 lanes. The plain loops of `slab_scalar` took `bvh4`'s
/// node test as scalar code. Panics unless `W == 4`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn slab4<const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    assert!(W == 4);
    // SAFETY: every array read or written holds W == 4 floats (a 4-wide
    // node is 32 floats, and `slab4_sse` reads no further), and SSE is
    // part of x86-64.
    unsafe { slab4_sse(std::ptr::from_ref(n).cast(), r, bound, t.as_mut_ptr()) }
}

/// # Safety
/// `node` must point to a whole 4-wide node (32 floats: 6 rows of 4
/// bounds, then the child and count rows) and `t` to 4 writable floats.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn slab4_sse(node: *const f32, r: &BoxRay, bound: f32, t: *mut f32) -> u32 {
    use std::arch::x86_64::*;
    let mut lo = [_mm_setzero_ps(); 3];
    let mut hi = [_mm_setzero_ps(); 3];
    for a in 0..3 {
        // `BoxRay`'s offsets count 8 floats a row (an 8-wide node's); a
        // 4-wide node's rows are 4 apart. Masked to multiples of 4 below
        // 32: a row can never leave the node.
        let (near, far) = ((r.near[a] >> 1) & 0x1c, (r.far[a] >> 1) & 0x1c);
        let o = _mm_set1_ps(r.origin[a]);
        let inv = _mm_set1_ps(r.inv_dir[a]);
        let inv_exit = _mm_set1_ps(r.inv_exit[a]);
        // SAFETY: rows at most 28 floats into a node of 32 (the contract).
        unsafe {
            lo[a] = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(node.add(near)), o), inv);
            hi[a] = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(node.add(far)), o), inv_exit);
        }
    }
    // `max_ps(a, b)`: `a > b ? a : b`, as in `slab8_avx`.
    let e = _mm_max_ps(
        _mm_max_ps(lo[0], lo[1]),
        _mm_max_ps(lo[2], _mm_set1_ps(r.tmin)),
    );
    let x = _mm_min_ps(
        _mm_min_ps(hi[0], hi[1]),
        _mm_min_ps(hi[2], _mm_set1_ps(bound)),
    );
    // SAFETY: `t` holds 4 floats (the contract).
    unsafe { _mm_storeu_ps(t, e) };
    _mm_movemask_ps(_mm_cmple_ps(e, x)) as u32
}

/// The slab test of an 8-wide node's boxes in AVX: the same result as
/// `bvh::wide::slab_scalar` (entry distances in `t`, a bit per child
/// entered before `bound`). Panics unless `W == 8` or without AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn slab8<const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    assert!(W == 8);
    debug_assert!(cpu_has_avx2());
    // SAFETY: every array read or written holds W == 8 floats, and the
    // callers run this only on CPUs with AVX2 (inside `with_avx2`).
    unsafe { slab8_avx(std::ptr::from_ref(n).cast(), r, bound, t.as_mut_ptr()) }
}

/// # Safety
/// The CPU must have AVX; `node` must point to a whole 8-wide node (64
/// floats: 6 rows of bounds, then the child and count rows) and `t` to 8
/// writable floats.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn slab8_avx(node: *const f32, r: &BoxRay, bound: f32, t: *mut f32) -> u32 {
    use std::arch::x86_64::*;
    let mut lo = [_mm256_setzero_ps(); 3];
    let mut hi = [_mm256_setzero_ps(); 3];
    for a in 0..3 {
        // Row starts masked to multiples of 8 below 64: a row can never
        // leave the node.
        let (near, far) = (r.near[a] & 0x38, r.far[a] & 0x38);
        let o = _mm256_set1_ps(r.origin[a]);
        let inv = _mm256_set1_ps(r.inv_dir[a]);
        let inv_exit = _mm256_set1_ps(r.inv_exit[a]);
        lo[a] = _mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(node.add(near)), o), inv);
        hi[a] = _mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(node.add(far)), o), inv_exit);
    }
    // `max_ps(a, b)` is `a > b ? a : b`, returning `b` when either is NaN:
    // exactly `max_nan_second(a, b)`, in the fallback's order (two side
    // by side, then the greater of theirs: see `bvh::slab_scalar`).
    let e = _mm256_max_ps(
        _mm256_max_ps(lo[0], lo[1]),
        _mm256_max_ps(lo[2], _mm256_set1_ps(r.tmin)),
    );
    let x = _mm256_min_ps(
        _mm256_min_ps(hi[0], hi[1]),
        _mm256_min_ps(hi[2], _mm256_set1_ps(bound)),
    );
    _mm256_storeu_ps(t, e);
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(e, x)) as u32
}

/// Puts the rays `rays[group[k]]` in lanes `k` of `g`, as
/// [`crate::bvh::GroupRays::set`] puts each (the same bits): eight rays
/// at a time in AVX2, the rest one by one. Each eight are read as three
/// runs of four floats a ray (origin, reciprocal and `tmin`, `tmax`, at
/// their `#[repr(C)]` offsets in [`Ray`]) and transposed into the rows in
/// registers: a group's rows took eleven scalar stores a ray, each to
/// another cache line, and the pass was 6% of a primary occlusion
/// stream's time. Panics unless `group.len() <= GROUP` and every index
/// lies in `rays`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn set_group_rays(
    _avx: Avx2,
    g: &mut crate::bvh::GroupRays,
    rays: &[Ray],
    group: &[usize],
) {
    const _: () = assert!(std::mem::size_of::<Ray>() >= 4 * (RAY_TMAX + 4));
    assert!(group.len() <= crate::bvh::GROUP);
    let full = group.len() / 8 * 8;
    // SAFETY: `full <= GROUP` (asserted), and the CPU has AVX2 (the
    // `Avx2` proof).
    unsafe { set_group_rays_avx(g, rays, &group[..full]) };
    for (k, &i) in group.iter().enumerate().skip(full) {
        g.set(k, &rays[i]);
    }
}

/// Lanes `0..group.len()` of `g` (a multiple of 8) from `rays[group[k]]`,
/// eight at a time.
///
/// # Safety
/// The CPU must have AVX2; `group.len() <= GROUP`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn set_group_rays_avx(g: &mut crate::bvh::GroupRays, rays: &[Ray], group: &[usize]) {
    for (c, eight) in group.chunks_exact(8).enumerate() {
        let mut at = [std::ptr::null::<f32>(); 8];
        for (p, &i) in at.iter_mut().zip(eight) {
            *p = std::ptr::from_ref(&rays[i]).cast();
        }
        // SAFETY: each pointer comes from a reference to a whole `Ray`,
        // whose floats 0..4, 6..10 and 10..14 the kernel reads (the
        // struct holds them: the assertion in `set_group_rays`); lanes
        // `8c..8c + 8` lie in each row (`group.len() <= GROUP`).
        unsafe { set_group_rays8_avx(g, 8 * c, at) };
    }
}

/// Float offsets in a `#[repr(C)]` [`Ray`] (its doc comment, and a test
/// of `raymesh-geometry`, fix them): the origin, the reciprocal direction
/// (with `tmin` right after it) and `tmax`.
#[cfg(target_arch = "x86_64")]
const RAY_ORIGIN: usize = 0;
#[cfg(target_arch = "x86_64")]
const RAY_INV_DIR: usize = 6;
#[cfg(target_arch = "x86_64")]
const RAY_TMAX: usize = 10;

/// Lanes `lane0..lane0 + 8` of `g`'s rows from the rays at `rays`.
///
/// # Safety
/// The CPU must have AVX2; each pointer must point to a whole [`Ray`];
/// `lane0 + 8 <= GROUP`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn set_group_rays8_avx(g: &mut crate::bvh::GroupRays, lane0: usize, rays: [*const f32; 8]) {
    use std::arch::x86_64::*;
    let [ox, oy, oz, _] = ray_columns4(&rays, RAY_ORIGIN);
    let [ix, iy, iz, tmin] = ray_columns4(&rays, RAY_INV_DIR);
    let [tmax, _, _, _] = ray_columns4(&rays, RAY_TMAX);
    let exit = _mm256_set1_ps(raymesh_geometry::ROBUST_EXIT);
    let (o, inv) = ([ox, oy, oz], [ix, iy, iz]);
    for a in 0..3 {
        _mm256_storeu_ps(g.origin[a][lane0..lane0 + 8].as_mut_ptr(), o[a]);
        _mm256_storeu_ps(g.inv_dir[a][lane0..lane0 + 8].as_mut_ptr(), inv[a]);
        // `exit_reciprocal`: the same product.
        let inv_exit = _mm256_mul_ps(inv[a], exit);
        _mm256_storeu_ps(g.inv_exit[a][lane0..lane0 + 8].as_mut_ptr(), inv_exit);
    }
    _mm256_storeu_ps(g.tmin[lane0..lane0 + 8].as_mut_ptr(), tmin);
    // `cull_bound`: `t + |t| × CULL_SLACK`, the same operations in the
    // same order (the absolute value by clearing the sign bit, as
    // `f32::abs` does).
    let abs = _mm256_andnot_ps(_mm256_set1_ps(-0.0), tmax);
    let slack = _mm256_set1_ps(raymesh_geometry::CULL_SLACK);
    let bound = _mm256_add_ps(tmax, _mm256_mul_ps(abs, slack));
    _mm256_storeu_ps(g.bound[lane0..lane0 + 8].as_mut_ptr(), bound);
}

/// Floats `at..at + 4` of eight rays, by columns: column `c` holds float
/// `at + c` of the rays in lane order. Each ray's four floats are one
/// load (ray `j` in the low half of row `j`, ray `j + 4` in its high
/// half), transposed within the halves.
///
/// # Safety
/// The CPU must have AVX2; each pointer must point to `at + 4` readable
/// floats.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn ray_columns4(rays: &[*const f32; 8], at: usize) -> [std::arch::x86_64::__m256; 4] {
    use std::arch::x86_64::*;
    let mut r = [_mm256_setzero_ps(); 4];
    for j in 0..4 {
        let lo = _mm_loadu_ps(rays[j].add(at));
        let hi = _mm_loadu_ps(rays[j + 4].add(at));
        r[j] = _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(lo), hi);
    }
    let (l01, l23) = (
        _mm256_unpacklo_ps(r[0], r[1]),
        _mm256_unpacklo_ps(r[2], r[3]),
    );
    let (h01, h23) = (
        _mm256_unpackhi_ps(r[0], r[1]),
        _mm256_unpackhi_ps(r[2], r[3]),
    );
    [
        _mm256_shuffle_ps::<0x44>(l01, l23),
        _mm256_shuffle_ps::<0xEE>(l01, l23),
        _mm256_shuffle_ps::<0x44>(h01, h23),
        _mm256_shuffle_ps::<0xEE>(h01, h23),
    ]
}

/// `bvh::group_slab_scalar` (the test-only fallback) of an 8-wide node
/// in AVX2: the node's six rows loaded once, each ray's slab test as
/// `slab8_avx`'s (the same operations in the same order, so the same
/// bits), and each ray's hits added to the children's ray masks in one
/// vector step; and a bit for each child some ray entered, taken from
/// the masks in one vector step too (`bvh::entered_slots` of them, which
/// as a loop over the eight compiled to 31 instructions a node visit).
/// Panics unless `W == 8`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn group_slab8<const W: usize>(
    avx: Avx2,
    n: &WideNode<W>,
    g: &crate::bvh::GroupRays,
    mask: u32,
) -> ([u32; W], u32) {
    let (entered, _, slots) = group_slab8_with::<false, W>(avx, n, g, mask);
    (entered, slots)
}

/// [`group_slab8`] that also gives, for each child, the least entry
/// distance among the rays that enter it (infinity where none does), as
/// `bvh::group_slab_entry_scalar` (the test-only fallback) does: what a
/// group's closest-hit walk orders children by and drops rays by.
/// Panics unless `W == 8`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn group_slab8_entry<const W: usize>(
    avx: Avx2,
    n: &WideNode<W>,
    g: &crate::bvh::GroupRays,
    mask: u32,
) -> ([u32; W], [f32; W], u32) {
    group_slab8_with::<true, W>(avx, n, g, mask)
}

/// [`group_slab8_entry`], the entries computed only with `ENTRY`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn group_slab8_with<const ENTRY: bool, const W: usize>(
    _avx: Avx2,
    n: &WideNode<W>,
    g: &crate::bvh::GroupRays,
    mask: u32,
) -> ([u32; W], [f32; W], u32) {
    assert!(W == 8);
    let mut out = [0u32; W];
    let mut entry = [0.0f32; W];
    // SAFETY: the node holds W == 8 floats a row (64 in all), `out` 8
    // words and `entry` 8 floats; the CPU has AVX2 (the `Avx2` proof).
    let slots = unsafe {
        let node = std::ptr::from_ref(n).cast();
        group_slab8_avx::<ENTRY>(node, g, mask, out.as_mut_ptr(), entry.as_mut_ptr())
    };
    (out, entry, slots)
}

/// Returns a bit for each child that some ray entered (a nonzero mask
/// in `out`).
///
/// # Safety
/// The CPU must have AVX2; `node` must point to a whole 8-wide node (64
/// floats), `out` to 8 writable words and `entry` to 8 writable floats
/// (written only with `ENTRY`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn group_slab8_avx<const ENTRY: bool>(
    node: *const f32,
    g: &crate::bvh::GroupRays,
    mut mask: u32,
    out: *mut u32,
    entry: *mut f32,
) -> u32 {
    use std::arch::x86_64::*;
    let mut near = [_mm256_setzero_ps(); 3];
    let mut far = [_mm256_setzero_ps(); 3];
    for a in 0..3 {
        near[a] = _mm256_loadu_ps(node.add(g.near[a] & 0x38));
        far[a] = _mm256_loadu_ps(node.add(g.far[a] & 0x38));
    }
    let mut acc = _mm256_setzero_si256();
    let inf = _mm256_set1_ps(f32::INFINITY);
    let mut least = inf;
    while mask != 0 {
        let i = mask.trailing_zeros() as usize & (crate::bvh::GROUP - 1);
        mask &= mask - 1;
        let mut lo = [_mm256_setzero_ps(); 3];
        let mut hi = [_mm256_setzero_ps(); 3];
        for a in 0..3 {
            let o = _mm256_set1_ps(g.origin[a][i]);
            lo[a] = _mm256_mul_ps(_mm256_sub_ps(near[a], o), _mm256_set1_ps(g.inv_dir[a][i]));
            hi[a] = _mm256_mul_ps(_mm256_sub_ps(far[a], o), _mm256_set1_ps(g.inv_exit[a][i]));
        }
        let e = _mm256_max_ps(
            _mm256_max_ps(lo[0], lo[1]),
            _mm256_max_ps(lo[2], _mm256_set1_ps(g.tmin[i])),
        );
        let x = _mm256_min_ps(
            _mm256_min_ps(hi[0], hi[1]),
            _mm256_min_ps(hi[2], _mm256_set1_ps(g.bound[i])),
        );
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(e, x);
        if ENTRY {
            // `e` where the ray enters (never NaN there: `e <= x` held),
            // infinity elsewhere; `min_ps` of two numbers is exact.
            least = _mm256_min_ps(least, _mm256_blendv_ps(inf, e, hit));
        }
        let hit = _mm256_castps_si256(hit);
        acc = _mm256_or_si256(acc, _mm256_and_si256(hit, _mm256_set1_epi32(1 << i)));
    }
    _mm256_storeu_si256(out.cast(), acc);
    if ENTRY {
        _mm256_storeu_ps(entry, least);
    }
    let none = _mm256_cmpeq_epi32(acc, _mm256_setzero_si256());
    _mm256_movemask_ps(_mm256_castsi256_ps(none)) as u32 ^ 0xff
}

/// [`Bvh::traverse_stream`]'s loop compiled with AVX2 and its pair test
/// (`pair_slab_avx`) inlined. A closure handed to [`with_avx2`] would do
/// the same only if the compiler inlined it there, which it declines for
/// a loop this size (the kernel then became a call per node, 40% slower
/// than the one-ray walk); a `#[target_feature]` function inlines the
/// `#[inline(always)]` loop for certain. Panics without AVX2.
#[cfg(target_arch = "x86_64")]
pub(crate) fn stream_loop_avx2(
    bvh: &Bvh,
    rays: &[Ray],
    leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
) {
    assert!(cpu_has_avx2());
    // SAFETY: the CPU has AVX2 (asserted); the function has no other
    // requirement.
    unsafe { stream_loop_avx2_impl(bvh, rays, leaf) }
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn stream_loop_avx2_impl(
    bvh: &Bvh,
    rays: &[Ray],
    leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
) {
    // SAFETY (of each call): this function runs only on CPUs with AVX2.
    bvh.stream_loop::<{ crate::bvh::STREAM_LANES }>(rays, leaf, |p, r, b| unsafe {
        pair_slab_avx(p, r, b)
    });
}

/// [`crate::bvh::WideBvh`]'s packet walk compiled with AVX2, its box
/// tests and its leaves ([`PacketLeaf::visit`], `#[inline(always)]`)
/// inlined, as [`stream_loop_avx2`]'s: handed to [`Avx2::run`] as a
/// closure, the walk with its leaf inlined was left a function of its
/// own, compiled without AVX2 (closest hits 6 times slower).
#[cfg(target_arch = "x86_64")]
pub(crate) fn packet_walk_avx2<const W: usize, const ORDERED: bool>(
    avx: Avx2,
    bvh: &crate::bvh::WideBvh<W>,
    p: &crate::Packet8,
    tmax: &mut [f32; crate::LANES],
    leaf: &mut impl PacketLeaf,
) {
    // SAFETY: the proof exists, so `detect` (its only maker) found AVX2 on
    // this CPU; the function has no other requirement.
    unsafe { packet_walk_avx2_impl::<W, ORDERED>(avx, bvh, p, tmax, leaf) }
}

/// [`crate::bvh::WideBvh::intersect_group`] over an 8-wide BVH compiled
/// with AVX2, its node test ([`group_slab8_entry`]) and its leaves
/// ([`crate::bvh::GroupLeaf::visit`], `#[inline(always)]`) inlined, as
/// [`packet_walk_avx2`]'s are (handed to [`Avx2::run`] as a closure, the
/// walk was left a function compiled without AVX2, its kernels calls:
/// five times slower).
#[cfg(target_arch = "x86_64")]
pub(crate) fn intersect_group_avx2(
    avx: Avx2,
    bvh: &crate::bvh::Bvh8,
    g: &mut crate::bvh::GroupRays,
    len: usize,
    stack: &mut Vec<crate::bvh::GroupEntry>,
    shared: &mut (u64, u64),
    leaf: &mut impl crate::bvh::GroupLeaf,
) {
    // SAFETY: the proof exists, so `detect` (its only maker) found AVX2
    // and POPCNT on this CPU; the function has no other requirement.
    unsafe { intersect_group_avx2_impl(avx, bvh, g, len, stack, shared, leaf) }
}

/// # Safety
/// The CPU must have AVX2 and POPCNT.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn intersect_group_avx2_impl(
    avx: Avx2,
    bvh: &crate::bvh::Bvh8,
    g: &mut crate::bvh::GroupRays,
    len: usize,
    stack: &mut Vec<crate::bvh::GroupEntry>,
    shared: &mut (u64, u64),
    leaf: &mut impl crate::bvh::GroupLeaf,
) {
    bvh.intersect_group(
        g,
        len,
        stack,
        shared,
        leaf,
        |n, g, m| group_slab8_entry(avx, n, g, m),
        |entry, bounds| reaching8(avx, entry, bounds),
    );
}

/// `bvh::reaching` (the test-only fallback) in AVX2: the rays of a group
/// whose bound reaches `entry`, a bit each, by four compares and masks
/// (the loop over the 32 bounds compiled to 54 instructions a pop of the
/// closest-hit group walk).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn reaching8(_avx: Avx2, entry: f32, bounds: &[f32; crate::bvh::GROUP]) -> u32 {
    const { assert!(crate::bvh::GROUP == 32) };
    // SAFETY: `bounds` holds 32 floats, four rows of eight; the CPU has
    // AVX2 (the `Avx2` proof).
    unsafe { reaching8_avx(entry, bounds) }
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn reaching8_avx(entry: f32, bounds: &[f32; crate::bvh::GROUP]) -> u32 {
    use std::arch::x86_64::*;
    let e = _mm256_set1_ps(entry);
    let mut reach = 0u32;
    for (k, row) in bounds.chunks_exact(8).enumerate() {
        // `entry <= bound`, false where either is NaN, as the scalar `<=`.
        let le = _mm256_cmp_ps::<_CMP_LE_OQ>(e, _mm256_loadu_ps(row.as_ptr()));
        reach |= (_mm256_movemask_ps(le) as u32) << (8 * k);
    }
    reach
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn packet_walk_avx2_impl<const W: usize, const ORDERED: bool>(
    avx: Avx2,
    bvh: &crate::bvh::WideBvh<W>,
    p: &crate::Packet8,
    tmax: &mut [f32; crate::LANES],
    leaf: &mut impl PacketLeaf,
) {
    bvh.packet_loop::<ORDERED>(
        p,
        tmax,
        leaf,
        Some(avx),
        |p, near, far, bound| crate::packet::slab_avx(avx, p, near, far, bound),
        |a, b| le_mask8(avx, a, b),
    );
}

/// [`Bvh`]'s packet walk compiled with AVX2, as [`packet_walk_avx2`].
#[cfg(target_arch = "x86_64")]
pub(crate) fn packet_walk_binary_avx2(
    avx: Avx2,
    bvh: &Bvh,
    p: &crate::Packet8,
    tmax: &mut [f32; crate::LANES],
    leaf: &mut impl PacketLeaf,
) {
    // SAFETY: as `packet_walk_avx2`'s.
    unsafe { packet_walk_binary_avx2_impl(avx, bvh, p, tmax, leaf) }
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn packet_walk_binary_avx2_impl(
    avx: Avx2,
    bvh: &Bvh,
    p: &crate::Packet8,
    tmax: &mut [f32; crate::LANES],
    leaf: &mut impl PacketLeaf,
) {
    bvh.packet_loop(p, tmax, leaf, Some(avx));
}

/// [`crate::packet::triangle`] with the lanes' test in AVX2
/// ([`packet_lanes_avx`]). Panics without AVX2.
#[cfg(target_arch = "x86_64")]
pub(crate) fn packet_triangle(
    p: &crate::Packet8,
    corners: [raymesh_geometry::Vec3; 3],
    lanes: u32,
    tmax: &[f32; crate::LANES],
    out: &mut [crate::PrimHit; crate::LANES],
) -> u32 {
    assert!(cpu_has_avx2());
    // SAFETY: the CPU has AVX2 (asserted); the function has no other
    // requirement.
    unsafe { packet_triangle_impl(p, corners, lanes, tmax, out) }
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn packet_triangle_impl(
    p: &crate::Packet8,
    corners: [raymesh_geometry::Vec3; 3],
    lanes: u32,
    tmax: &[f32; crate::LANES],
    out: &mut [crate::PrimHit; crate::LANES],
) -> u32 {
    // SAFETY (of the call): this function runs only on CPUs with AVX2.
    crate::packet::triangle_lanes(p, corners, lanes, tmax, out, |p, c, t| unsafe {
        packet_lanes_avx(p, c, t)
    })
}

/// The lanes [`raymesh_geometry::needs_f64`] redoes in f64 for their
/// range, from `det` and `t_scaled`: where `|det| + |t_scaled|` is not
/// below infinity (NaN included), and, outside the sign bits of
/// `outside`, where either is below the least normal float. The same
/// `f32` operations as the scalar test's, so the same lanes. (The zero
/// edge functions' lanes the callers add themselves.)
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn range_redo(
    det: std::arch::x86_64::__m256,
    t_scaled: std::arch::x86_64::__m256,
    outside: std::arch::x86_64::__m256,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let abs = _mm256_castsi256_ps(_mm256_set1_epi32(i32::MAX));
    let (ad, at) = (_mm256_and_ps(det, abs), _mm256_and_ps(t_scaled, abs));
    let least = _mm256_set1_ps(f32::MIN_POSITIVE);
    let big = _mm256_cmp_ps::<_CMP_NLT_UQ>(_mm256_add_ps(ad, at), _mm256_set1_ps(f32::INFINITY));
    // (`min` gives `at` where either is NaN, a lane `big` holds already.)
    let small = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_min_ps(ad, at), least);
    _mm256_or_ps(big, _mm256_andnot_ps(outside, small))
}

/// [`crate::packet::lanes_portable`] in AVX2, one ray a lane: the same
/// operations in the same order (no fused multiply-add), so the same
/// masks and, for the lanes hit, the same bits of `t`, `u`, `v` (when no
/// lane is inside the triangle it stops before working them out). The portable loop, compiled
/// with AVX2, built its masks from arrays of `bool`s lane by lane.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn packet_lanes_avx(
    p: &crate::Packet8,
    c: [[f32; 3]; 3],
    tmax: &[f32; crate::LANES],
) -> (u32, u32, BlockHits) {
    use std::arch::x86_64::*;
    // Macros, not closures, so that the intrinsics inline wherever this
    // function does (in closures they stayed calls).
    macro_rules! ld {
        ($a:expr) => {
            _mm256_loadu_ps($a.as_ptr())
        };
    }
    let (o0, o1, o2) = (ld!(p.porigin[0]), ld!(p.porigin[1]), ld!(p.porigin[2]));
    let (s0, s1, s2) = (ld!(p.shear[0]), ld!(p.shear[1]), ld!(p.shear[2]));
    // Corner `q` relative to each lane's origin, sheared to 2D; its
    // relative `z` unsheared.
    macro_rules! corner {
        ($q:expr) => {{
            let x = _mm256_sub_ps(_mm256_set1_ps($q[0]), o0);
            let y = _mm256_sub_ps(_mm256_set1_ps($q[1]), o1);
            let z = _mm256_sub_ps(_mm256_set1_ps($q[2]), o2);
            (
                _mm256_sub_ps(x, _mm256_mul_ps(s0, z)),
                _mm256_sub_ps(y, _mm256_mul_ps(s1, z)),
                z,
            )
        }};
    }
    let (ax, ay, az) = corner!(c[0]);
    let (bx, by, bz) = corner!(c[1]);
    let (cx, cy, cz) = corner!(c[2]);
    let u = _mm256_sub_ps(_mm256_mul_ps(cx, by), _mm256_mul_ps(cy, bx));
    let v = _mm256_sub_ps(_mm256_mul_ps(ax, cy), _mm256_mul_ps(ay, cx));
    let w = _mm256_sub_ps(_mm256_mul_ps(bx, ay), _mm256_mul_ps(by, ax));
    let zero = _mm256_setzero_ps();
    let redo = _mm256_or_ps(
        _mm256_or_ps(
            _mm256_cmp_ps::<_CMP_EQ_OQ>(u, zero),
            _mm256_cmp_ps::<_CMP_EQ_OQ>(v, zero),
        ),
        _mm256_cmp_ps::<_CMP_EQ_OQ>(w, zero),
    );
    let outside = _mm256_and_ps(
        _mm256_or_ps(
            _mm256_or_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(u, zero),
                _mm256_cmp_ps::<_CMP_LT_OQ>(v, zero),
            ),
            _mm256_cmp_ps::<_CMP_LT_OQ>(w, zero),
        ),
        _mm256_or_ps(
            _mm256_or_ps(
                _mm256_cmp_ps::<_CMP_GT_OQ>(u, zero),
                _mm256_cmp_ps::<_CMP_GT_OQ>(v, zero),
            ),
            _mm256_cmp_ps::<_CMP_GT_OQ>(w, zero),
        ),
    );
    // Every lane outside (the most of a leaf's triangles, for most
    // packets): no lane can hit, so neither the division nor the hits are
    // worked out; lanes to redo stay so. (A lane outside by these
    // comparisons is outside whatever `needs_f64` says of its range:
    // strict comparisons are false for NaN, and an edge function that
    // overflowed to an infinity keeps its sign. The scalar test's `f64`
    // redo finds it outside too.)
    if _mm256_movemask_ps(outside) == 0xff {
        return (0, _mm256_movemask_ps(redo) as u32, BlockHits::default());
    }
    let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
    let t_scaled = _mm256_add_ps(
        _mm256_add_ps(
            _mm256_mul_ps(u, _mm256_mul_ps(s2, az)),
            _mm256_mul_ps(v, _mm256_mul_ps(s2, bz)),
        ),
        _mm256_mul_ps(w, _mm256_mul_ps(s2, cz)),
    );
    let redo = _mm256_or_ps(redo, range_redo(det, t_scaled, outside));
    let inv_det = _mm256_div_ps(_mm256_set1_ps(1.0), det);
    let t = _mm256_mul_ps(t_scaled, inv_det);
    // Inside, `det` neither 0 nor NaN (an ordered compare), `t` in the
    // lane's interval (NaN fails both).
    let ok = _mm256_andnot_ps(
        outside,
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_NEQ_OQ>(det, zero),
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(t, ld!(p.tmin)),
                _mm256_cmp_ps::<_CMP_LE_OQ>(t, ld!(tmax)),
            ),
        ),
    );
    // The registers as they are: `__m256` and `[f32; 8]` have the same
    // size, and every bit pattern is a valid float.
    macro_rules! lanes {
        ($x:expr) => {
            std::mem::transmute::<__m256, [f32; 8]>($x)
        };
    }
    (
        _mm256_movemask_ps(ok) as u32,
        _mm256_movemask_ps(redo) as u32,
        BlockHits {
            t: lanes!(t),
            u: lanes!(_mm256_mul_ps(v, inv_det)),
            v: lanes!(_mm256_mul_ps(w, inv_det)),
        },
    )
}

/// The slab test of a binary BVH node's two children (one cache line) in
/// AVX, one child a 128-bit half: the same entry distances and hits as
/// [`crate::bvh::pair_slab_scalar`] (two [`raymesh_geometry::Aabb::slab`]s),
/// bit for bit. Returns a bit per child entered (1 left, 2 right) and the
/// two entry distances. Panics without AVX2. The stream loop calls the
/// kernel unchecked (its AVX2 context is checked once); tests call this.
#[cfg(all(target_arch = "x86_64", test))]
#[inline(always)]
pub(crate) fn pair_slab(pair: &NodePair, r: &PairRay, bound: f32) -> (u32, f32, f32) {
    assert!(cpu_has_avx2());
    // SAFETY: a node pair is 16 floats, 64-byte aligned; the ray's rows are
    // 8 floats, 32-byte aligned; the CPU has AVX2 (asserted).
    unsafe { pair_slab_avx(pair, r, bound) }
}

/// # Safety
/// The CPU must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn pair_slab_avx(pair: &NodePair, r: &PairRay, bound: f32) -> (u32, f32, f32) {
    use std::arch::x86_64::*;
    let p = std::ptr::from_ref(pair).cast::<f32>();
    // Each node is min xyz, count, max xyz, index.
    let (left, right) = (_mm256_load_ps(p), _mm256_load_ps(p.add(8)));
    // Lanes 3 and 7 hold a node's count and index, whose bits read as
    // floats are subnormal: zeroed, or every step's arithmetic on them
    // takes the CPU's slow path for subnormal operands.
    let axes = _mm256_castsi256_ps(_mm256_setr_epi32(-1, -1, -1, 0, -1, -1, -1, 0));
    let min = _mm256_and_ps(_mm256_permute2f128_ps::<0x20>(left, right), axes);
    let max = _mm256_and_ps(_mm256_permute2f128_ps::<0x31>(left, right), axes);
    let neg = _mm256_load_ps(r.neg.as_ptr().cast());
    let (near, far) = (
        _mm256_blendv_ps(min, max, neg),
        _mm256_blendv_ps(max, min, neg),
    );
    let o = _mm256_load_ps(r.origin.as_ptr());
    let inv = _mm256_load_ps(r.inv_dir.as_ptr());
    let tn = _mm256_mul_ps(_mm256_sub_ps(near, o), inv);
    let tf = _mm256_mul_ps(_mm256_sub_ps(far, o), _mm256_load_ps(r.inv_exit.as_ptr()));
    // z, then y, then x, into the accumulator: the scalar nesting.
    // max_ps(a, b) is max_nan_second(a, b); min_ps likewise.
    let mut e = _mm256_set1_ps(r.tmin);
    let mut x = _mm256_set1_ps(bound);
    e = _mm256_max_ps(_mm256_permute_ps::<0b1010_1010>(tn), e);
    x = _mm256_min_ps(_mm256_permute_ps::<0b1010_1010>(tf), x);
    e = _mm256_max_ps(_mm256_permute_ps::<0b0101_0101>(tn), e);
    x = _mm256_min_ps(_mm256_permute_ps::<0b0101_0101>(tf), x);
    e = _mm256_max_ps(_mm256_permute_ps::<0>(tn), e);
    x = _mm256_min_ps(_mm256_permute_ps::<0>(tf), x);
    let m = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(e, x)) as u32;
    (
        (m & 1) | (m >> 3 & 2),
        _mm256_cvtss_f32(e),
        _mm_cvtss_f32(_mm256_extractf128_ps::<1>(e)),
    )
}

/// The slab test of one box against the eight rays of a packet in AVX
/// (one ray a lane, the box's `near` and `far` planes shared; `rows` the
/// lanes' origins, reciprocal directions and their
/// [`raymesh_geometry::exit_reciprocal`]s, by axis), on a CPU
/// with AVX2 (the `Avx2` proof): the same entry distances and mask as
/// [`crate::packet::slab_lanes`], bit for bit (`packet.rs`'s tests compare
/// them).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn packet_slab8(
    _avx: Avx2,
    rows: [&[[f32; 8]; 3]; 3],
    tmin: &[f32; 8],
    near: [f32; 3],
    far: [f32; 3],
    bound: &[f32; 8],
) -> (u32, [f32; 8]) {
    let mut e = [0.0f32; 8];
    // SAFETY: every pointer addresses 8 floats (the array types say so),
    // and the CPU has AVX2 (the `Avx2` proof).
    let mask = unsafe { packet_slab8_avx(rows, tmin, near, far, bound, &mut e) };
    (mask, e)
}

/// # Safety
/// The CPU must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn packet_slab8_avx(
    [origin, inv_dir, inv_exit]: [&[[f32; 8]; 3]; 3],
    tmin: &[f32; 8],
    near: [f32; 3],
    far: [f32; 3],
    bound: &[f32; 8],
    out: &mut [f32; 8],
) -> u32 {
    use std::arch::x86_64::*;
    let mut lo = [_mm256_setzero_ps(); 3];
    let mut hi = [_mm256_setzero_ps(); 3];
    for a in 0..3 {
        let o = _mm256_loadu_ps(origin[a].as_ptr());
        let inv = _mm256_loadu_ps(inv_dir[a].as_ptr());
        let inv_exit = _mm256_loadu_ps(inv_exit[a].as_ptr());
        lo[a] = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(near[a]), o), inv);
        hi[a] = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(far[a]), o), inv_exit);
    }
    // max_ps(a, b) is max_nan_second(a, b); min_ps likewise: side by side
    // as the portable loop takes them.
    let e = _mm256_max_ps(
        _mm256_max_ps(lo[0], lo[1]),
        _mm256_max_ps(lo[2], _mm256_loadu_ps(tmin.as_ptr())),
    );
    let x = _mm256_min_ps(
        _mm256_min_ps(hi[0], hi[1]),
        _mm256_min_ps(hi[2], _mm256_loadu_ps(bound.as_ptr())),
    );
    _mm256_storeu_ps(out.as_mut_ptr(), e);
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(e, x)) as u32
}

/// [`crate::packet::frustum`] of an 8-wide node's boxes in AVX, one box a
/// lane: the same operations in the same order, so the same bits
/// (`packet.rs`'s tests compare them). Panics without AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn frustum8<const W: usize>(
    n: &WideNode<W>,
    f: &crate::packet::Frustum,
    neg: [bool; 3],
    bound: f32,
) -> u32 {
    assert!(W == 8 && cpu_has_avx2());
    // SAFETY: every row holds W == 8 floats, and the CPU has AVX2
    // (both asserted).
    unsafe { frustum8_avx(f, neg, n.min_rows(), n.max_rows(), bound) }
}

/// [`frustum8`] inside an AVX2 walk: the `Avx2` proof stands for the CPU
/// check (two checks a node visit, with a branch each, before).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn frustum8_in<const W: usize>(
    _avx: Avx2,
    n: &WideNode<W>,
    f: &crate::packet::Frustum,
    neg: [bool; 3],
    bound: f32,
) -> u32 {
    // Decided at compile time for each width.
    assert!(W == 8, "frustum8_in takes 8-wide nodes");
    debug_assert!(cpu_has_avx2());
    // SAFETY: every row holds W == 8 floats (asserted), and the CPU has
    // AVX2 (the proof).
    unsafe { frustum8_avx(f, neg, n.min_rows(), n.max_rows(), bound) }
}

/// The greatest of the lanes of `v` whose bits are set in `lanes`
/// (`-inf` for none), in AVX: a blend and a reduction instead of a
/// branch and a dependent `max` a lane. For lanes that are not NaN, the
/// value of [`crate::packet::masked_max`]'s fold (the greatest is the
/// greatest in any order; zeros of either sign compare equal).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn masked_max8(_avx: Avx2, v: &[f32; 8], lanes: u32) -> f32 {
    debug_assert!(cpu_has_avx2());
    // SAFETY: `v` holds 8 floats, and the CPU has AVX2 (the proof).
    unsafe { masked_max8_avx(v, lanes) }
}

/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn masked_max8_avx(v: &[f32; 8], lanes: u32) -> f32 {
    use std::arch::x86_64::*;
    let bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    let on = _mm256_cmpeq_epi32(
        _mm256_and_si256(_mm256_set1_epi32(lanes as i32), bits),
        bits,
    );
    let x = _mm256_blendv_ps(
        _mm256_set1_ps(f32::NEG_INFINITY),
        _mm256_loadu_ps(v.as_ptr()),
        _mm256_castsi256_ps(on),
    );
    let m = _mm_max_ps(_mm256_castps256_ps128(x), _mm256_extractf128_ps::<1>(x));
    let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
    _mm_cvtss_f32(_mm_max_ss(m, _mm_movehdup_ps(m)))
}

/// # Safety
/// The CPU must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn frustum8_avx(
    f: &crate::packet::Frustum,
    neg: [bool; 3],
    min: [*const f32; 3],
    max: [*const f32; 3],
    bound: f32,
) -> u32 {
    use std::arch::x86_64::*;
    let mut e = _mm256_set1_ps(f.tmin);
    let mut x = _mm256_set1_ps(bound);
    for a in (0..3).rev() {
        let (near, far) = if neg[a] {
            (max[a], min[a])
        } else {
            (min[a], max[a])
        };
        let (i0, i1) = (_mm256_set1_ps(f.inv[a][0]), _mm256_set1_ps(f.inv[a][1]));
        let (x0, x1) = (
            _mm256_set1_ps(f.inv_exit[a][0]),
            _mm256_set1_ps(f.inv_exit[a][1]),
        );
        let d = _mm256_sub_ps(_mm256_loadu_ps(near), _mm256_set1_ps(f.near_origin[a]));
        let lo = _mm256_min_ps(_mm256_mul_ps(d, i0), _mm256_mul_ps(d, i1));
        let d = _mm256_sub_ps(_mm256_loadu_ps(far), _mm256_set1_ps(f.far_origin[a]));
        let hi = _mm256_max_ps(_mm256_mul_ps(d, x0), _mm256_mul_ps(d, x1));
        e = _mm256_max_ps(lo, e);
        x = _mm256_min_ps(hi, x);
    }
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(e, x)) as u32
}

/// A bit per lane where `a <= b` (false for NaN), in AVX: what
/// [`crate::packet::le_mask`]'s portable loop gives. The `Avx2` proof
/// stands for the CPU check (a feature check per call was 2% of a packet
/// walk's instructions).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn le_mask8(_avx: Avx2, a: &[f32; 8], b: &[f32; 8]) -> u32 {
    debug_assert!(cpu_has_avx2());
    // SAFETY: both arrays hold 8 floats, and the CPU has AVX2 (the proof).
    unsafe { le_mask8_avx(a, b) }
}

/// # Safety
/// The CPU must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn le_mask8_avx(a: &[f32; 8], b: &[f32; 8]) -> u32 {
    use std::arch::x86_64::*;
    let (a, b) = (_mm256_loadu_ps(a.as_ptr()), _mm256_loadu_ps(b.as_ptr()));
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(a, b)) as u32
}

/// Floats of one group of [`GROUP_SLOTS`] triangles in the corner rows'
/// layout (see [`crate::Triangles`]): their 9 rows (corner × axis) of 8
/// lanes, one after another, then a tenth row of the triangles' indices
/// (which the kernels never read: a block's loads stop at row 8).
pub(crate) const GROUP: usize = 10 * GROUP_SLOTS;

/// Triangles a group of the rows' layout holds (one lane each).
pub(crate) const GROUP_SLOTS: usize = 8;

/// Where a block of `count` (at most 8) triangles from slot `first` lies
/// in the grouped rows: the float offset of its first lane in row 0, and
/// the offset from each load to the second one that a block straddling
/// two groups takes its last lanes from (0 when it lies in one group).
///
/// In group `g` (slots `8g..8g + 8`), row `r` lane `l` is float
/// `80g + 8r + l`. A block's lanes from `first` run on from its row
/// into the next row's first lanes; those of the next group sit exactly
/// 72 floats (a group less one row) further on, in the same row.
#[inline(always)]
pub(crate) fn block_at(first: usize, count: usize) -> (usize, usize) {
    let (g, l) = (first / GROUP_SLOTS, first % GROUP_SLOTS);
    let span = if l + count > GROUP_SLOTS {
        GROUP - GROUP_SLOTS
    } else {
        0
    };
    (g * GROUP + l, span)
}

/// Floats past a block's offset ([`block_at`]) that its loads read: the
/// last row's (offset 64), its second load (`span`) and 8 lanes.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn block_reach(span: usize) -> usize {
    8 * GROUP_SLOTS + span + 8
}

/// The watertight ray–triangle test of
/// [`raymesh_geometry::intersect_triangle`] on up to 8 triangles at once:
/// slots `first..first + count` of rows grouped as [`crate::Triangles`]
/// lays them out ([`block_at`]); lanes past `count` are ignored. Returns
/// the mask of lanes hit (their `t`, `u`, `v` written to `out`) and the
/// mask of lanes left for the scalar test's f64 path, which is empty: the
/// kernel redoes in f64 itself the lanes the scalar test would
/// ([`raymesh_geometry::needs_f64`]; the NEON kernel leaves them to the
/// caller). Panics
/// if a row would be read past `data` or the CPU lacks AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn triangles8(
    data: &[f32],
    first: usize,
    count: usize,
    ray: &Ray,
    tmax: f32,
) -> (u32, u32, BlockHits) {
    let (at, span) = block_at(first, count);
    assert!(at + block_reach(span) <= data.len());
    assert!(cpu_has_avx2());
    // SAFETY: every load (a row offset of at most 64, plus `span`, then 8
    // lanes) lies inside `data` (asserted), and the CPU has AVX2 (asserted).
    let (hit, out) =
        unsafe { triangles8_avx(data.as_ptr().add(at), first % GROUP_SLOTS, span, ray, tmax) };
    active_lanes(hit, count, out)
}

/// [`triangles8`] of up to 8 triangles named by index, as a k-d tree's
/// leaf or a grid's cell names them (lane `k` is triangle `ids[k]` of
/// the `len` whose grouped rows are `data`; repeats allowed, ids past the
/// eighth ignored): each of the kernel's 9 rows built in a register from
/// the triangles' coordinates, eight scalar loads inserted lane by lane.
/// The lanes past the list repeat the first triangle and are masked off.
///
/// What it replaced, measured (`raymesh-ab --accel kdtree|grid`, bunny00
/// and the dragon, pinned): the rows copied a coordinate at a time into a
/// block on the stack, which the kernel, a call, then loaded, each
/// 32-byte load waiting on the eight 4-byte stores it could not be
/// forwarded from: 1.01-1.06x on primary rays, 0.98-1.04x on random ones,
/// 0.96-1.08x (mostly 1.04-1.05x) on diffuse and shadow rays (the block
/// first zeroed, its zero lanes degenerate triangles that sent
/// every block of fewer than 8 down the kernel's f64 branch: 0.99-1.09x
/// before that). Each row gathered by an AVX2 gather (`vgatherdps`)
/// instead: the k-d tree 1.00-1.01x, the grid 0.95-1.00x (Zen 3).
///
/// Returns `None` where an id is out of range, or the rows do not hold
/// `len` triangles' groups (the caller's scalar test then panics or
/// answers); panics if the CPU lacks AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn triangles8_list(
    data: &[f32],
    len: usize,
    ids: &[u32],
    ray: &Ray,
    tmax: f32,
) -> Option<(u32, u32, BlockHits)> {
    let ids = &ids[..ids.len().min(GROUP_SLOTS)];
    let slots = list_slots(data, len, ids)?;
    assert!(cpu_has_avx2());
    // SAFETY: each slot is an id's lane in row 0 of its group, which lies
    // in `data` (checked), and the rows read are at most 64 floats on
    // (`kernel_row`), within the group; the CPU has AVX2 (asserted).
    let (hit, out) = unsafe { triangles8_list_avx(data.as_ptr(), &slots, ray, tmax) };
    Some(active_lanes(hit, ids.len(), out))
}

/// [`triangles8_list`] inside a traversal compiled for AVX2 (the `Avx2`
/// proof), with the ray's constants made once a ray ([`BlockRay`]): the
/// kernel then inlines into the walk (a grid's or a k-d tree's) with
/// nothing redone per block, where [`triangles8_list`] is a call that
/// works out the ray's shear again each time. The same results, bit for
/// bit.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn triangles8_list_pre(
    _avx: Avx2,
    data: &[f32],
    len: usize,
    ids: &[u32],
    tr: &BlockRay,
    tmax: f32,
) -> Option<(u32, u32, BlockHits)> {
    let ids = &ids[..ids.len().min(GROUP_SLOTS)];
    let slots = list_slots(data, len, ids)?;
    // SAFETY: as in `triangles8_list`: each slot is an id's lane in row 0
    // of its group, within `data` (checked by `list_slots`), and a
    // `BlockRay`'s row offsets are at most 64 (its axes come from
    // `kernel_axes`, or are zero by default); the CPU has AVX2 (the
    // `Avx2` proof).
    let (hit, out) = unsafe {
        let block = list_rows(data.as_ptr(), &slots, tr.axes);
        triangles8_loaded(&block, tr.shear, tr.origin, tr.tmin, tmax)
    };
    Some(active_lanes(hit, ids.len(), out))
}

/// Each listed triangle's lane in row 0 of its group (`ids` not empty, at
/// most 8; lanes past them repeat the first), or `None` where an id is out
/// of range or the rows do not hold `len` triangles' groups.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn list_slots(data: &[f32], len: usize, ids: &[u32]) -> Option<[usize; 8]> {
    let &first = ids.first()?;
    if len.div_ceil(GROUP_SLOTS) * GROUP > data.len() || ids.iter().any(|&i| i as usize >= len) {
        return None;
    }
    Some(std::array::from_fn(|k| {
        let i = *ids.get(k).unwrap_or(&first) as usize;
        (i / GROUP_SLOTS) * GROUP + i % GROUP_SLOTS
    }))
}

/// The kernel's 9 rows of the triangles at `slots` (see
/// [`triangles8_list`]), row `r` read at `kernel_row(r, axes)`, one float
/// a lane.
///
/// # Safety
/// The CPU must have AVX2; for each lane `k`, `rows.add(slots[k] + o)`
/// must address a readable float for every row offset `o` of at most 64.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn list_rows(
    rows: *const f32,
    slots: &[usize; 8],
    axes: [usize; 3],
) -> [std::arch::x86_64::__m256; 9] {
    use std::arch::x86_64::*;
    // SAFETY: as this function's contract.
    unsafe {
        macro_rules! row {
            ($r:expr) => {{
                let p = rows.add(kernel_row($r, axes));
                _mm256_setr_ps(
                    *p.add(slots[0]),
                    *p.add(slots[1]),
                    *p.add(slots[2]),
                    *p.add(slots[3]),
                    *p.add(slots[4]),
                    *p.add(slots[5]),
                    *p.add(slots[6]),
                    *p.add(slots[7]),
                )
            }};
        }
        [
            row!(0),
            row!(1),
            row!(2),
            row!(3),
            row!(4),
            row!(5),
            row!(6),
            row!(7),
            row!(8),
        ]
    }
}

/// The rows and the kernel of [`triangles8_list`].
///
/// # Safety
/// The CPU must have AVX2; for each lane `k`, `rows.add(slots[k] + o)`
/// must address a readable float for every row offset `o` of at most 64
/// (a row's offset, [`kernel_row`], is at most 64).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn triangles8_list_avx(
    rows: *const f32,
    slots: &[usize; 8],
    ray: &Ray,
    tmax: f32,
) -> (u32, BlockHits) {
    let (s, k) = ray.shear();
    let o = ray.permute(ray.origin());
    let axes = kernel_axes(k);
    // SAFETY: as this function's contract.
    unsafe {
        let block = list_rows(rows, slots, axes);
        triangles8_loaded(&block, s.to_array(), o.to_array(), ray.tmin(), tmax)
    }
}

/// The kernel's hit mask restricted to the block's `count` lanes, with
/// the empty mask of lanes to redo that callers share with the NEON
/// kernel (the AVX2 one redoes its own: see [`triangles8_core`]).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn active_lanes(hit: u32, count: usize, out: BlockHits) -> (u32, u32, BlockHits) {
    let active = if count >= 8 {
        0xff
    } else {
        (1u32 << count) - 1
    };
    (hit & active, 0, out)
}

/// Proof that the CPU has AVX2 (and POPCNT) and the kernels are enabled
/// ([`crate::set_simd_enabled`]), checked once where it is made: methods
/// that take one skip the check. Code compiled for AVX2 (a traversal
/// under `with_avx2`) inlines the kernels they call.
#[derive(Clone, Copy, Debug)]
pub struct Avx2 {
    /// Whether the CPU has AVX-512F and AVX-512VL too (and they are
    /// enabled): then [`Self::run_wide`] may run.
    wide: bool,
}

impl Avx2 {
    /// The proof, where the CPU has AVX2 and the kernels are enabled.
    #[inline(always)]
    #[must_use]
    pub fn detect() -> Option<Self> {
        match level() {
            AVX2 => Some(Self { wide: false }),
            AVX512 => Some(Self { wide: true }),
            _ => None,
        }
    }

    /// Whether [`Self::run_wide`] may run: the CPU has AVX-512F and
    /// AVX-512VL. Built with `--cfg raymesh_no_avx512`, a constant false,
    /// so that the AVX-512 builds of the walks are not compiled at all:
    /// what a profile-guided build made on a CPU without AVX-512 does
    /// (`scripts/pgo-build.sh`). Its training cannot run them, and LLVM
    /// compiles code the profile never saw as cold, for size: their walks'
    /// closures stayed out of line, every intrinsic a call to a function
    /// compiled for no AVX, and the binary would have traced several times
    /// slower on a CPU with AVX-512 than on the one it was built on.
    #[inline(always)]
    pub(crate) fn wide(self) -> bool {
        !cfg!(raymesh_no_avx512) && self.wide
    }

    /// [`Self::run`] compiled for AVX-512F and AVX-512VL as well: the same
    /// instructions on the same 256-bit lanes (and so the same results,
    /// bit for bit), but 32 vector registers instead of 16, so that a
    /// walk keeps more of its ray's constants in registers instead of
    /// reloading them at every node. Call through [`avx_run`], which
    /// checks [`Self::wide`]. Panics if the proof does not allow it.
    #[inline(always)]
    pub(crate) fn run_wide<R>(self, f: impl FnOnce() -> R) -> R {
        assert!(self.wide, "run_wide without AVX-512");
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: `detect`, the proof's only maker, found AVX2,
            // POPCNT, AVX-512F and AVX-512VL on this CPU (`wide`, asserted).
            unsafe { run_avx512(f) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            f()
        }
    }

    /// Runs `f` compiled with AVX2 enabled (as [`with_avx2`] does, without
    /// checking the CPU again), so that the kernels and walks it inlines
    /// use 256-bit instructions and keep the ray's constants in registers.
    /// (No proof is made on other CPUs.)
    #[inline(always)]
    pub(crate) fn run<R>(self, f: impl FnOnce() -> R) -> R {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: the proof exists, so `detect` (its only maker) found
            // AVX2 and POPCNT on this CPU.
            unsafe { run_avx2(f) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            f()
        }
    }
}

/// What the triangle kernel needs of a ray, computed once per ray instead
/// of once per block: the shear constants, the origin with its axes
/// permuted, `tmin`, and the offset in a group of the first corner's row
/// of each permuted axis (`k[a]`, at `8 * k[a]`); the kernel's 9 rows
/// (corner `c`, permuted axis `a`: row `3 * c + k[a]`) are those plus a
/// constant each (`kernel_row`), which the loads take as their
/// displacement. The same for any triangles: the grouped layout
/// ([`crate::Triangles`]) places rows alike whatever their number.
#[derive(Clone, Copy, Debug, Default)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub struct BlockRay {
    shear: [f32; 3],
    origin: [f32; 3],
    tmin: f32,
    axes: [usize; 3],
}

impl BlockRay {
    /// The kernel's constants for `ray`.
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> Self {
        let (s, k) = ray.shear();
        Self {
            shear: s.to_array(),
            origin: ray.permute(ray.origin()).to_array(),
            tmin: ray.tmin(),
            axes: kernel_axes(k),
        }
    }
}

/// A bound on the values [`BlockRay::axis_class`] takes.
#[cfg(target_arch = "x86_64")]
pub(crate) const AXIS_CLASSES: usize = 16;

impl BlockRay {
    /// Which rows of a block the kernel reads for this ray, as a number
    /// below [`AXIS_CLASSES`]: rays with the same number read the same
    /// rows ([`triangles8_rays`]). (The first two axes' rows name the
    /// permutation: 9 values for the rows `kernel_axes` gives.)
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) fn axis_class(&self) -> usize {
        ((self.axes[0] / GROUP_SLOTS) * 3 + self.axes[1] / GROUP_SLOTS) % AXIS_CLASSES
    }

    /// [`Self::new`] of lane `i` of the packet `p`, from its rows: the same
    /// constants, with no `Ray` of the lane made.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    #[inline(always)]
    pub(crate) fn lane(p: &crate::Packet8, i: usize) -> Self {
        Self {
            shear: [p.shear[0][i], p.shear[1][i], p.shear[2][i]],
            origin: [p.porigin[0][i], p.porigin[1][i], p.porigin[2][i]],
            tmin: p.tmin[i],
            axes: p.block_axes,
        }
    }
}

/// The offsets [`BlockRay::new`] gives a ray of axis order `k`: of the
/// first corner's row of each permuted axis, each at most 16 (`k[a]`
/// taken as at most 2, which a permutation's entries are).
#[inline(always)]
pub(crate) fn kernel_axes(k: [usize; 3]) -> [usize; 3] {
    k.map(|a| a.min(2) * GROUP_SLOTS)
}

/// The offset in a group of the row the kernel reads as its row `r`
/// (corner `r / 3`, axis `k[r % 3]` of the ray's permutation), from the
/// ray's [`kernel_axes`]: at most 64, row 8's. `r` is a constant where
/// the kernel is unrolled, so the corner's part folds into each load's
/// displacement, and the kernel keeps three offsets live instead of nine.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn kernel_row(r: usize, axes: [usize; 3]) -> usize {
    axes[r % 3] + 3 * (r / 3) * GROUP_SLOTS
}

/// [`triangles8`] inside an AVX2 traversal: the ray's constants come
/// precomputed ([`BlockRay`]) and the AVX2 check is the `Avx2` proof, so
/// that the kernel inlines into the traversal's loop with nothing redone
/// per block. The same results, bit for bit.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn triangles8_pre(
    _avx: Avx2,
    data: &[f32],
    first: usize,
    count: usize,
    tr: &BlockRay,
    tmax: f32,
) -> (u32, u32, BlockHits) {
    let (at, span) = block_at(first, count);
    assert!(at + block_reach(span) <= data.len());
    // SAFETY: every row offset is at most 64 (a `BlockRay`'s axes come
    // from `kernel_axes`, or are zero by default), so each of the two loads of
    // 8 lanes a row stays inside `data` (asserted); the CPU has AVX2 (the
    // `Avx2` proof).
    let (hit, out) = unsafe {
        triangles8_core(
            data.as_ptr().add(at),
            |r| kernel_row(r, tr.axes),
            first % GROUP_SLOTS,
            span,
            tr.shear,
            tr.origin,
            tr.tmin,
            tmax,
        )
    };
    active_lanes(hit, count, out)
}

/// [`triangles8_pre`] of each lane in `lanes` of the packet `p`, in
/// increasing order, against one block, whose rows are loaded once for
/// all of them (the lanes share an axis order, so they read the same
/// rows): lane `i` is tested with the bound `tmax[i]` and its results go
/// to `each(i, hit, redo, hits)`, `redo` as [`triangles8_pre`]'s (empty).
/// A packet's leaf reached by few of its lanes is tested so: lane by lane
/// each test reloaded the nine rows, two loads and a blend each.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn triangles8_lanes(
    _avx: Avx2,
    data: &[f32],
    first: usize,
    count: usize,
    p: &crate::Packet8,
    lanes: u32,
    tmax: &[f32; 8],
    mut each: impl FnMut(usize, u32, u32, BlockHits),
) {
    let (at, span) = block_at(first, count);
    assert!(at + block_reach(span) <= data.len());
    // SAFETY: the packet's row offsets come from `kernel_axes`, each row
    // at most 64, so each of the two loads of 8 lanes a row stays inside
    // `data` (asserted); the CPU has AVX2 (the `Avx2` proof).
    let block = unsafe {
        load_block8(
            data.as_ptr().add(at),
            |r| kernel_row(r, p.block_axes),
            first % GROUP_SLOTS,
            span,
        )
    };
    // Every lane's origin the same, bit for bit (a camera's rays): the
    // rows relative to it, the kernel's first nine operations, are the
    // same for every lane, so made once, in place of the block's (one set
    // of nine rows live across the loop either way).
    // SAFETY: the CPU has AVX2 (the `Avx2` proof).
    let shared = unsafe { same_origin(p) };
    let rows = if shared {
        let o = [p.porigin[0][0], p.porigin[1][0], p.porigin[2][0]];
        // SAFETY: the CPU has AVX2 (the `Avx2` proof).
        unsafe { relative8(&block, o) }
    } else {
        block
    };
    let mut m = lanes;
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        let ray = BlockRay::lane(p, i);
        // SAFETY: the CPU has AVX2 (the `Avx2` proof).
        let (hit, out) = unsafe {
            if shared {
                triangles8_relative(&rows, ray.shear, ray.tmin, tmax[i])
            } else {
                triangles8_loaded(&rows, ray.shear, ray.origin, ray.tmin, tmax[i])
            }
        };
        let (hit, redo, out) = active_lanes(hit, count, out);
        each(i, hit, redo, out);
    }
}

/// Whether every lane of `p` has the same origin, bit for bit (as a
/// pinhole camera's rays do): three integer comparisons of the origin's
/// rows with their first lane (a float comparison would take `-0.0` for
/// `0.0`, whose differences with a corner can differ in sign).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn same_origin(p: &crate::Packet8) -> bool {
    use std::arch::x86_64::*;
    macro_rules! row {
        ($a:expr) => {{
            let r = _mm256_loadu_si256(p.porigin[$a].as_ptr().cast());
            _mm256_cmpeq_epi32(r, _mm256_set1_epi32(p.porigin[$a][0].to_bits() as i32))
        }};
    }
    let eq = _mm256_and_si256(_mm256_and_si256(row!(0), row!(1)), row!(2));
    _mm256_movemask_epi8(eq) == -1
}

/// The eight lanes of the packet `p` against each triangle of slots
/// `first..first + count` of rows grouped as [`crate::Triangles`] lays
/// them out, in turn: one [`packet_lanes_avx`] test a triangle, its nine
/// coordinates read straight from the rows in the packet's axis order
/// (`p.block_axes`), inside the walk's AVX2 code. Triangle `s` is tested
/// against the lanes' bounds as the hits before left `tmax`; where it
/// hits a lane of `live` or leaves one to redo, `each(s, hit, redo,
/// hits, tmax)` takes the masks (within `live`; `hit` without `redo`)
/// and the lanes' `t`, `u`, `v`, may lower `tmax`, and returns the lanes
/// it has ended, which are tested no further (the loop stops when none
/// is left). The same masks and bits as
/// [`crate::packet::triangle_lanes`] of the triangle's corners.
///
/// A packet's leaf reached by many of its lanes is tested so: the
/// triangle-by-triangle test it replaces ([`crate::packet::triangle_run`])
/// made a call a triangle and gathered each triangle's corners through
/// the stack.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn packet_tris(
    _avx: Avx2,
    data: &[f32],
    first: usize,
    count: usize,
    p: &crate::Packet8,
    live: u32,
    tmax: &mut [f32; 8],
    mut each: impl FnMut(usize, u32, u32, &BlockHits, &mut [f32; 8]) -> u32,
) {
    if count == 0 {
        return;
    }
    let end = first + count;
    // The last slot's group ends within `data`: every read below is of a
    // slot's group, at a row offset of at most 64 (row 8) plus its lane.
    assert!((end - 1) / GROUP_SLOTS * GROUP + GROUP <= data.len());
    let axes = p.block_axes;
    assert!(axes.iter().all(|&a| a <= 2 * GROUP_SLOTS));
    let mut live = live;
    for s in first..end {
        let base = s / GROUP_SLOTS * GROUP + s % GROUP_SLOTS;
        // Corner `c`'s coordinate on the packet's `a`-th axis: row `3c +
        // k[a]` of the slot's group (`axes[a]` is `8 k[a]`).
        macro_rules! at {
            ($c:expr, $a:expr) => {
                // SAFETY: `base` lies in the slot's group, `axes[a]` is at
                // most 16 and the corner's rows at most 48 further, so
                // the float lies in that group, inside `data` (asserted).
                unsafe { *data.get_unchecked(base + axes[$a] + 3 * $c * GROUP_SLOTS) }
            };
        }
        let c = [
            [at!(0, 0), at!(0, 1), at!(0, 2)],
            [at!(1, 0), at!(1, 1), at!(1, 2)],
            [at!(2, 0), at!(2, 1), at!(2, 2)],
        ];
        // SAFETY: the CPU has AVX2 (the `Avx2` proof).
        let (ok, redo, hits) = unsafe { packet_lanes_avx(p, c, tmax) };
        let (redo, hit) = (redo & live, ok & live & !redo);
        if hit | redo != 0 {
            live &= !each(s, hit, redo, &hits, tmax);
            if live == 0 {
                return;
            }
        }
    }
}

/// [`triangles8_pre`] of each ray `i` in `rays` (a bit each), with the
/// constants `pre[i]` and the bound `tmax(i)`, against one block: its
/// rows loaded once for all the rays that share an axis order (those of
/// `classes[c]`, the group's rays of [`BlockRay::axis_class`] `c`),
/// which read the same rows, and each ray's hit mask and hits handed to
/// `each(i, hit, hits)`, a class at a time. A group's leaf that several
/// of its rays reach is tested so: ray by ray, each test found the
/// block's place, and loaded and blended its nine rows, again. The same
/// results as [`triangles8_pre`] ray by ray, bit for bit (nothing is
/// left to redo).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn triangles8_rays(
    _avx: Avx2,
    data: &[f32],
    first: usize,
    count: usize,
    rays: u32,
    pre: &[BlockRay; crate::bvh::GROUP],
    classes: &[u32; AXIS_CLASSES],
    tmax: impl Fn(usize) -> f32,
    mut each: impl FnMut(usize, u32, BlockHits),
) {
    let (at, span) = block_at(first, count);
    assert!(at + block_reach(span) <= data.len());
    let mut left = rays;
    while left != 0 {
        let first_ray = left.trailing_zeros() as usize % crate::bvh::GROUP;
        let axes = pre[first_ray].axes;
        // The first ray at least, whatever `classes` says.
        let m = left & classes[pre[first_ray].axis_class()] | 1 << first_ray;
        left &= !m;
        // SAFETY: every row offset is at most 64 (a `BlockRay`'s axes come
        // from `kernel_axes`, or are zero by default), so each of the two
        // loads of 8 lanes a row stays inside `data` (asserted); the CPU
        // has AVX2 (the `Avx2` proof).
        let block = unsafe {
            load_block8(
                data.as_ptr().add(at),
                |r| kernel_row(r, axes),
                first % GROUP_SLOTS,
                span,
            )
        };
        let mut m = m;
        while m != 0 {
            let i = m.trailing_zeros() as usize % crate::bvh::GROUP;
            m &= m - 1;
            let p = &pre[i];
            debug_assert_eq!(p.axes, axes, "`classes` joins rays of one axis order");
            // SAFETY: the CPU has AVX2 (the `Avx2` proof).
            let (hit, out) =
                unsafe { triangles8_loaded(&block, p.shear, p.origin, p.tmin, tmax(i)) };
            let (hit, _, out) = active_lanes(hit, count, out);
            each(i, hit, out);
        }
    }
}

/// # Safety
/// The CPU must have AVX2; for each row offset `o` of at most 64,
/// `rows.add(o)` and `rows.add(o + span)` must address 8 readable floats.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn triangles8_avx(
    rows: *const f32,
    lane: usize,
    span: usize,
    ray: &Ray,
    tmax: f32,
) -> (u32, BlockHits) {
    let (s, k) = ray.shear();
    let o = ray.permute(ray.origin());
    // SAFETY: as this function's contract.
    unsafe {
        triangles8_core(
            rows,
            |r| kernel_row(r, kernel_axes(k)),
            lane,
            span,
            s.to_array(),
            o.to_array(),
            ray.tmin(),
            tmax,
        )
    }
}

/// The kernel itself, inlined into its caller: called from code compiled
/// for AVX2 (`triangles8_avx`, or a traversal under `with_avx2`) its
/// intrinsics inline too. Returns the mask of lanes hit and their hits.
/// The lanes the scalar test redoes in f64 ([`raymesh_geometry::needs_f64`]:
/// an edge function of exactly zero, values out of `f32`'s range) are
/// redone in f64 inside it, as the scalar test redoes them, so that
/// nothing is left to redo (and the walks it inlines into make no call
/// for it).
///
/// The ray comes as its shear constants, its origin with the axes
/// permuted, and `tmin`; row `r` of the 9 (corner `r / 3`, permuted axis
/// `r % 3`) starts `row(r)` floats after `rows`. The block's first slot
/// is lane `lane` of its group: its lanes from `8 - lane` on come from
/// the load `span` floats further (the next group's, see [`block_at`]).
///
/// # Safety
/// The CPU must have AVX2; `rows.add(row(r))` and
/// `rows.add(row(r) + span)` must address 8 readable floats for each row
/// `r` in `0..9`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn triangles8_core(
    rows: *const f32,
    row: impl Fn(usize) -> usize,
    lane: usize,
    span: usize,
    shear: [f32; 3],
    origin: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> (u32, BlockHits) {
    // SAFETY: as this function's contract.
    unsafe {
        let block = load_block8(rows, row, lane, span);
        triangles8_loaded(&block, shear, origin, tmin, tmax)
    }
}

/// The 9 rows of 8 lanes [`triangles8_core`] reads (its `rows`, `row`,
/// `lane` and `span`), loaded: row `r` is corner `r / 3`'s permuted axis
/// `r % 3`.
///
/// # Safety
/// As [`triangles8_core`]'s.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn load_block8(
    rows: *const f32,
    row: impl Fn(usize) -> usize,
    lane: usize,
    span: usize,
) -> [std::arch::x86_64::__m256; 9] {
    use std::arch::x86_64::*;
    // Lanes from `8 - lane` on: the next group's.
    let next = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
        _mm256_set1_epi32(7 - lane as i32),
    ));
    // Row `r`'s 8 lanes (a macro, not a closure, so that the intrinsics
    // inline wherever this function does).
    macro_rules! load {
        ($r:expr) => {{
            let p = rows.add(row($r));
            _mm256_blendv_ps(_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(span)), next)
        }};
    }
    [
        load!(0),
        load!(1),
        load!(2),
        load!(3),
        load!(4),
        load!(5),
        load!(6),
        load!(7),
        load!(8),
    ]
}

/// The arithmetic of [`triangles8_core`] on a block's rows already loaded
/// ([`load_block8`]): a packet's leaf loads a block once and runs each
/// lane's ray through this.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn triangles8_loaded(
    block: &[std::arch::x86_64::__m256; 9],
    shear: [f32; 3],
    origin: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> (u32, BlockHits) {
    // SAFETY: as this function's contract.
    unsafe { triangles8_relative(&relative8(block, origin), shear, tmin, tmax) }
}

/// A block's rows ([`load_block8`]) relative to a ray origin (permuted as
/// the rows are): each corner's coordinates less the origin's, the first
/// step of [`triangles8_loaded`]. Rays that share their origin, as a
/// camera's do, share these.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn relative8(
    block: &[std::arch::x86_64::__m256; 9],
    origin: [f32; 3],
) -> [std::arch::x86_64::__m256; 9] {
    use std::arch::x86_64::*;
    // Written out, not through closures, whose intrinsics would stay
    // calls where this inlines.
    let (ox, oy, oz) = (
        _mm256_set1_ps(origin[0]),
        _mm256_set1_ps(origin[1]),
        _mm256_set1_ps(origin[2]),
    );
    [
        _mm256_sub_ps(block[0], ox),
        _mm256_sub_ps(block[1], oy),
        _mm256_sub_ps(block[2], oz),
        _mm256_sub_ps(block[3], ox),
        _mm256_sub_ps(block[4], oy),
        _mm256_sub_ps(block[5], oz),
        _mm256_sub_ps(block[6], ox),
        _mm256_sub_ps(block[7], oy),
        _mm256_sub_ps(block[8], oz),
    ]
}

/// [`triangles8_loaded`] of rows already made relative to the ray's
/// origin ([`relative8`]).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn triangles8_relative(
    rel: &[std::arch::x86_64::__m256; 9],
    shear: [f32; 3],
    tmin: f32,
    tmax: f32,
) -> (u32, BlockHits) {
    use std::arch::x86_64::*;
    let (sx, sy, sz) = (
        _mm256_set1_ps(shear[0]),
        _mm256_set1_ps(shear[1]),
        _mm256_set1_ps(shear[2]),
    );
    // Corner `c` relative to the ray origin and sheared to 2D, in the
    // scalar test's order of operations (a macro, not a closure, so that
    // the intrinsics inline wherever this function does).
    macro_rules! shear {
        ($c:expr) => {{
            let (x, y, z) = (rel[3 * $c], rel[3 * $c + 1], rel[3 * $c + 2]);
            (
                _mm256_sub_ps(x, _mm256_mul_ps(sx, z)),
                _mm256_sub_ps(y, _mm256_mul_ps(sy, z)),
                _mm256_mul_ps(sz, z),
            )
        }};
    }
    let (ax, ay, az) = shear!(0);
    let (bx, by, bz) = shear!(1);
    let (cx, cy, cz) = shear!(2);
    let u = _mm256_sub_ps(_mm256_mul_ps(cx, by), _mm256_mul_ps(cy, bx));
    let v = _mm256_sub_ps(_mm256_mul_ps(ax, cy), _mm256_mul_ps(ay, cx));
    let w = _mm256_sub_ps(_mm256_mul_ps(bx, ay), _mm256_mul_ps(by, ax));
    // `off`: lanes that miss whatever their `t`, in their sign bits: the
    // edge functions are of both signs where `u`'s sign bit differs from
    // `v`'s or `w`'s (three operations where the scalar test's comparisons
    // take eleven). Right for every lane but those with an edge function
    // of zero or NaN, which the f64 redo below takes. Its check that the
    // plane is not edge-on (`det` neither 0 nor NaN) needs none either:
    // the sum of three nonzero edge functions of one sign is never zero,
    // and a NaN is redone.
    let off = _mm256_or_ps(_mm256_xor_ps(u, v), _mm256_xor_ps(u, w));
    let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
    let t_scaled = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(u, az), _mm256_mul_ps(v, bz)),
        _mm256_mul_ps(w, cz),
    );
    // The lanes the scalar test redoes in f64 (`needs_f64`): an edge
    // function of exactly zero (a ray through an edge or a vertex, or past
    // a sliver), or values out of `f32`'s range (huge or tiny scenes).
    let zero = _mm256_setzero_ps();
    let redo = _mm256_or_ps(
        _mm256_or_ps(
            _mm256_cmp_ps::<_CMP_EQ_OQ>(u, zero),
            _mm256_or_ps(
                _mm256_cmp_ps::<_CMP_EQ_OQ>(v, zero),
                _mm256_cmp_ps::<_CMP_EQ_OQ>(w, zero),
            ),
        ),
        range_redo(det, t_scaled, off),
    );
    // The registers as they are: `__m256` and `[f32; 8]` have the same
    // size, and every bit pattern is a valid float.
    let lanes = |x: __m256| std::mem::transmute::<__m256, [f32; 8]>(x);
    // The hits in f32: `t` in the interval (NaN fails) where nothing else
    // rules the lane out. (`movemask` reads the sign bits only: `off`'s
    // are the ones that matter, the comparisons' lanes are all ones or
    // all zeros.) A macro, written out on both sides of the branch below,
    // so that the common side holds none of the sheared corners past it.
    macro_rules! in_f32 {
        () => {{
            let inv_det = _mm256_div_ps(_mm256_set1_ps(1.0), det);
            let t = _mm256_mul_ps(t_scaled, inv_det);
            let hit = _mm256_movemask_ps(_mm256_andnot_ps(
                off,
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(tmin)),
                    _mm256_cmp_ps::<_CMP_LE_OQ>(t, _mm256_set1_ps(tmax)),
                ),
            )) as u32;
            (
                hit,
                BlockHits {
                    t: lanes(t),
                    u: lanes(_mm256_mul_ps(v, inv_det)),
                    v: lanes(_mm256_mul_ps(w, inv_det)),
                },
            )
        }};
    }
    let mut m = _mm256_movemask_ps(redo) as u32;
    if m == 0 {
        return in_f32!();
    }
    let (mut hit, mut out) = in_f32!();
    {
        // Those lanes redone here with the scalar test's own f64 path
        // (`raymesh_geometry::hit_f64`), lane by lane, and not by a call: a
        // call anywhere in a walk's loop makes the walk keep the ray's
        // constants in memory around it (bunny00 random rays, bvh8: 29
        // instructions a ray). One loop for every lane, not four lanes
        // at a time in AVX2: the walks this kernel inlines into must stay
        // small enough for LLVM to inline them whole into their AVX2
        // regions (with the f64 path unrolled over two halves they did
        // not, and every intrinsic became a call).
        let (ax, ay, bx, by, cx, cy) = (
            lanes(ax),
            lanes(ay),
            lanes(bx),
            lanes(by),
            lanes(cx),
            lanes(cy),
        );
        // Each corner's relative `z`, unsheared (`az` is `shear[2]` times
        // it in f32, which may have overflowed).
        let z = |c: usize| lanes(rel[3 * c + 2]);
        let z = [z(0), z(1), z(2)];
        let sz = f64::from(shear[2]);
        let d = f64::from;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            let (ax, ay, bx, by, cx, cy) =
                (d(ax[i]), d(ay[i]), d(bx[i]), d(by[i]), d(cx[i]), d(cy[i]));
            match raymesh_geometry::hit_f64(
                tmin,
                tmax,
                [cx * by - cy * bx, ax * cy - ay * cx, bx * ay - by * ax],
                z.map(|z| sz * d(z[i])),
            ) {
                Some(h) => {
                    (out.t[i], out.u[i], out.v[i]) = (h.t, h.u, h.v);
                    hit |= 1 << i;
                }
                None => hit &= !(1 << i),
            }
        }
    }
    (hit, out)
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::bvh::Node;
    use crate::test_util::{
        bits, hard_coord, hard_vec3, lanes_match, lattice, node_kernel_matches,
    };
    use proptest::prelude::*;
    use raymesh_geometry::{Aabb, Ray, Vec3};

    proptest! {
        #![proptest_config(crate::test_util::config(2000))]
        /// `set_group_rays` (eight lanes at a time in AVX2, the rest one
        /// by one) fills a group's rows with the bits `GroupRays::set`
        /// gives each ray: groups of every length up to 32, rays picked in
        /// any order (repeats too), with zeros of both signs, infinities,
        /// NaN, huge and tiny values and empty intervals. (Directions
        /// positive, one octant: `set` checks a group's octant in debug
        /// builds, and the kernel moves bits whatever their signs.)
        #[test]
        fn group_rays_by_eights_are_the_rays_one_by_one(
            rays in prop::collection::vec(
                (hard_vec3(), hard_vec3(), hard_coord(), hard_coord()), 1..48),
            picks in prop::collection::vec(any::<prop::sample::Index>(), 0..=crate::bvh::GROUP),
        ) {
            let Some(avx) = Avx2::detect() else { return Ok(()) };
            let rays: Vec<Ray> = rays
                .into_iter()
                .map(|(o, d, tmin, tmax)| Ray::new(o, d.abs(), tmin, tmax))
                .collect();
            let group: Vec<usize> = picks.iter().map(|p| p.index(rays.len())).collect();
            let mut fast = crate::bvh::GroupRays::of_octant(0);
            set_group_rays(avx, &mut fast, &rays, &group);
            let mut slow = crate::bvh::GroupRays::of_octant(0);
            for (k, &i) in group.iter().enumerate() {
                slow.set(k, &rays[i]);
            }
            let bits = |g: &crate::bvh::GroupRays, k: usize| -> Vec<u32> {
                (0..3)
                    .flat_map(|a| [g.origin[a][k], g.inv_dir[a][k], g.inv_exit[a][k]])
                    .chain([g.tmin[k], g.bound[k]])
                    .map(crate::test_util::bits)
                    .collect()
            };
            for k in 0..group.len() {
                prop_assert_eq!(bits(&fast, k), bits(&slow, k), "lane {} of {}", k, group.len());
            }
        }
    }

    /// `RAYMESH_AVX512=off` (or `0`) turns the AVX-512 builds off, as
    /// `set_avx512_enabled(false)` does; any other value or none leaves
    /// them to the CPU. (Other tests in this process may see the variable
    /// set meanwhile: they then run the AVX2 builds, whose results are the
    /// same, bit for bit.)
    #[test]
    fn the_environment_turns_avx512_off() {
        for (value, off) in [
            ("off", true),
            ("0", true),
            ("on", false),
            ("1", false),
            ("", false),
        ] {
            std::env::set_var("RAYMESH_AVX512", value);
            assert_eq!(avx512_off_by_env(), off, "RAYMESH_AVX512={value:?}");
            if off {
                // Worked out again after a switch, from the variable too.
                set_avx512_enabled(true);
                assert!(
                    Avx2::detect().is_none_or(|a| !a.wide()),
                    "RAYMESH_AVX512={value:?}"
                );
            }
        }
        std::env::remove_var("RAYMESH_AVX512");
        assert!(!avx512_off_by_env());
        set_avx512_enabled(true);
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The AVX kernel and the plain loops give the same bits.
        #[test]
        fn avx_slab_matches_fallback(
            corners in proptest::collection::vec((hard_vec3(), hard_vec3()), 8),
            used in 0u32..256,
            o in hard_vec3(), d in hard_vec3(),
            tmin in hard_coord(), bound in hard_coord(),
        ) {
            prop_assume!(cpu_has_avx2());
            let avx = |n: &WideNode<8>, r: &BoxRay, bound, t: &mut [f32; 8]| {
                with_avx2(|| slab8(n, r, bound, t))
            };
            node_kernel_matches(avx, &corners, used, (o, d, tmin, bound))?;
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The SSE kernel of 4-wide nodes and the plain loops give the
        /// same bits, on every CPU (SSE is part of x86-64), and so does the
        /// dispatch the AVX2 walks call.
        #[test]
        fn sse_slab_matches_fallback(
            corners in proptest::collection::vec((hard_vec3(), hard_vec3()), 4),
            used in 0u32..16,
            o in hard_vec3(), d in hard_vec3(),
            tmin in hard_coord(), bound in hard_coord(),
        ) {
            node_kernel_matches(slab4::<4>, &corners, used, (o, d, tmin, bound))?;
            node_kernel_matches(slab_wide::<4>, &corners, used, (o, d, tmin, bound))?;
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The AVX reduction gives the fold's greatest active lane, for
        /// every mask (none: `-inf`), on bounds that are not NaN (a packet
        /// walk's never are: its rays are valid, its hits' `t` ordered).
        #[test]
        fn avx_masked_max_matches_fallback(
            v in proptest::array::uniform8(hard_coord().prop_filter("not NaN", |x| !x.is_nan())),
            lanes in 0u32..256,
        ) {
            let Some(avx) = Avx2::detect() else { return Ok(()) };
            let want = crate::packet::masked_max(&v, lanes);
            let got = avx.run(|| masked_max8(avx, &v, lanes));
            // Zeros of either sign compare equal, as the walk's tests
            // compare them.
            prop_assert!(got == want, "{v:?} {lanes:#b}: {got} against {want}");
            if lanes == 0 {
                prop_assert_eq!(got, f32::NEG_INFINITY);
            }
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(2000))]
        /// The group kernel gives each ray of the group the children the
        /// plain loops give it (each ray's one-ray test), and each child
        /// the least entry distance of the rays that enter it, on any
        /// boxes (empty ones too) and rays (invalid ones, infinite and NaN
        /// bounds too), for any subset of the group.
        #[test]
        fn avx_group_slab_matches_fallback(
            corners in proptest::collection::vec((hard_vec3(), hard_vec3()), 8),
            used in 0u32..256,
            octant in hard_vec3(),
            rays in proptest::collection::vec(
                (hard_vec3(), hard_vec3(), hard_coord(), hard_coord()), 1..=32),
            mask in any::<u32>(),
        ) {
            prop_assume!(cpu_has_avx2());
            let mut node = WideNode::<8>::empty();
            for (i, (a, b)) in corners.iter().enumerate() {
                if used >> i & 1 != 0 {
                    node.set_box(i, Aabb::new(a.min(*b), a.max(*b)));
                }
            }
            // Directions in the octant of `octant`, as a group's are.
            let made: Vec<Ray> = rays
                .iter()
                .map(|&(o, d, _, _)| Ray::new(o, d.abs().copysign(octant), 0.0, f32::INFINITY))
                .collect();
            let mut g = crate::bvh::GroupRays::new(made.iter());
            for (i, &(_, _, tmin, bound)) in rays.iter().enumerate() {
                (g.tmin[i], g.bound[i]) = (tmin, bound);
            }
            let mask = mask & (u32::MAX >> (32 - rays.len()));
            let avx = Avx2::detect().expect("AVX2, checked");
            let want = crate::bvh::group_slab_scalar(&node, &g, mask);
            let want_slots = crate::bvh::entered_slots(&want);
            prop_assert_eq!(group_slab8(avx, &node, &g, mask), (want, want_slots));
            // With each child's least entry distance, bit for bit.
            let (entered, least, slots) = group_slab8_entry(avx, &node, &g, mask);
            let (want_entered, want_least) = crate::bvh::group_slab_entry_scalar(&node, &g, mask);
            prop_assert_eq!(entered, want_entered);
            prop_assert_eq!(least.map(bits), want_least.map(bits));
            prop_assert_eq!(slots, want_slots);
        }

        /// The rays a group's bounds keep at a pop, the kernel's as the
        /// scalar loop's: NaN, infinite and equal bounds and entries too.
        #[test]
        fn avx_reaching_matches_fallback(
            bounds in proptest::collection::vec(hard_coord(), 32),
            entry in hard_coord(),
            pick in 0usize..33,
        ) {
            prop_assume!(cpu_has_avx2());
            let bounds: [f32; 32] = bounds.try_into().expect("32 bounds");
            // An entry equal to one of the bounds half the time.
            let entry = if pick < 32 { bounds[pick] } else { entry };
            let avx = Avx2::detect().expect("AVX2, checked");
            prop_assert_eq!(reaching8(avx, entry, &bounds), crate::bvh::reaching(entry, &bounds));
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The pair kernel gives the bits of two scalar slab tests, in
        /// every octant, on any boxes (empty ones too), whatever the count
        /// and index fields hold (their bits read as floats are subnormal,
        /// normal or NaN; the kernel must ignore them).
        #[test]
        fn avx_pair_slab_matches_scalar(
            a in hard_vec3(), b in hard_vec3(), c in hard_vec3(), d in hard_vec3(),
            o in hard_vec3(), dir in hard_vec3(),
            tmin in hard_coord(), bound in hard_coord(),
            fields in proptest::array::uniform4(any::<u32>()),
        ) {
            prop_assume!(cpu_has_avx2());
            let mut pair = NodePair([Node::new(Aabb::new(a, b)), Node::new(Aabb::new(c, d))]);
            (pair.0[0].count, pair.0[0].index) = (fields[0], fields[1]);
            (pair.0[1].count, pair.0[1].index) = (fields[2], fields[3]);
            let ray = Ray::new(o, dir, tmin.min(0.0), f32::INFINITY);
            let mut r = PairRay::new(&ray);
            r.set_tmin(tmin);
            let (ma, la, ra) = pair_slab(&pair, &r, bound);
            let (mb, lb, rb) = crate::bvh::pair_slab_scalar(&pair, &r, bound);
            prop_assert_eq!(ma, mb);
            prop_assert_eq!(bits(la), bits(lb));
            prop_assert_eq!(bits(ra), bits(rb));
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(2000))]
        /// The SSE2 bin truncation gives the plain conversion's bins, and
        /// both give the clamped floor of each lane, NaN in bin 0.
        #[test]
        fn sse2_bins_match_scalar(
            x in prop_oneof![hard_coord(), -2.0f32..70.0, Just(f32::NAN)],
            y in prop_oneof![hard_coord(), -2.0f32..70.0, Just(f32::NAN)],
            z in prop_oneof![hard_coord(), -2.0f32..70.0, Just(f32::NAN)],
            nb in 2usize..=64,
        ) {
            let last = (nb - 1) as f32;
            let f = raymesh_geometry::Vec3A::new(x, y, z);
            let [a, b, c] = [x, y, z].map(|v| {
                let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, last) };
                v.floor() as u32
            });
            let want = a | b << 8 | c << 16;
            let clamped = f.max(raymesh_geometry::Vec3A::ZERO)
                .min(raymesh_geometry::Vec3A::splat(last));
            prop_assert_eq!(truncate3_sse2(clamped), want);
            prop_assert_eq!(truncate3_scalar(clamped), want);
            prop_assert_eq!(truncate3(f, last, true), want);
            prop_assert_eq!(truncate3(f, last, false), want);
        }
    }

    /// A triangle whose edge function `u` is zero in f32 and negative in
    /// f64, where `v` and `w` are positive: the f32 test alone would call
    /// it a hit, the scalar test (redoing the three in f64) a miss. The
    /// ray runs along +z through the origin; the sheared corners are the
    /// corners' x and y. `(1 + 2^-12)^2` rounds to `1 + 2^-11` in f32.
    fn f64_only_miss() -> [Vec3; 3] {
        let (e, e2) = (2f32.powi(-12), 2f32.powi(-11));
        [
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0 + e, 0.0),
            Vec3::new(-(1.0 + e), -(1.0 + e2), 0.0),
        ]
    }

    /// The block kernels redo a zero edge function in f64 as the scalar
    /// test does, whichever of the three it is and in whichever lane: the
    /// same miss where f32 alone would hit, among triangles it hits.
    #[test]
    fn zero_edge_functions_are_redone_in_f64() {
        use crate::{Primitives, Triangles};
        let ray = Ray::new(Vec3::new(0.0, 0.0, -1.0), Vec3::Z, 0.0, f32::INFINITY);
        let [a, b, c] = f64_only_miss();
        let hit = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        for turn in 0..3 {
            // Turning the corners makes the zero edge function `v`, then `w`.
            let mut tri = [a, b, c];
            tri.rotate_left(turn);
            assert!(
                raymesh_geometry::intersect_triangle(&ray, f32::INFINITY, tri[0], tri[1], tri[2])
                    .is_none(),
                "the scalar test misses turn {turn}"
            );
            for lane in 0..8 {
                let mut corners = vec![hit; 12];
                corners[2 + lane] = tri;
                let tris = Triangles::from_corners(&corners);
                let want = |k: usize| {
                    let [p, q, r] = corners[2 + k];
                    raymesh_geometry::intersect_triangle(&ray, f32::INFINITY, p, q, r)
                };
                let (mask, out) = tris.intersect_block(2, 8, &ray, f32::INFINITY);
                lanes_match(mask, &out, want).expect("intersect_block");
                assert_eq!(mask, 0xff & !(1 << lane), "turn {turn}, lane {lane}");
                if let Some(avx) = Avx2::detect() {
                    let pre = tris.block_ray(&ray);
                    let (mask, out) =
                        tris.intersect_block_pre(avx, &pre, 2, 8, &ray, f32::INFINITY);
                    lanes_match(mask, &out, want).expect("intersect_block_pre");
                }
                let ids: Vec<u32> = (2..10).collect();
                let (mask, out) = tris.intersect_ids(&ids, &ray, f32::INFINITY);
                lanes_match(mask, &out, want).expect("intersect_ids");
                if let Some(avx) = Avx2::detect() {
                    let pre = tris.block_ray(&ray);
                    let (mask, out) = tris.intersect_ids_pre(avx, &pre, &ids, &ray, f32::INFINITY);
                    lanes_match(mask, &out, want).expect("intersect_ids_pre");
                }
            }
        }
    }

    /// A `BlockRay` holds nothing of the triangles it was made with (the
    /// grouped rows lie alike for any number of triangles): made over one
    /// triangle, it finds the hits in a block of another set's.
    #[test]
    fn block_ray_serves_any_triangles() {
        use crate::{Primitives, Triangles};
        let Some(avx) = Avx2::detect() else { return };
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let one = Triangles::from_corners(&[tri]);
        let many = Triangles::from_corners(&[tri; 20]);
        let ray = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z, 0.0, f32::INFINITY);
        let pre = one.block_ray(&ray);
        for first in [0, 5, 12] {
            let (mask, hits) = many.intersect_block_pre(avx, &pre, first, 8, &ray, f32::INFINITY);
            assert_eq!((mask, hits.t), (0xff, [1.0; 8]), "block from {first}");
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The AVX triangle block gives what the scalar test gives, lane by
        /// lane: the same hits and the same bits of `t`, `u`, `v`.
        #[test]
        fn avx_triangles_match_scalar(
            tris in proptest::collection::vec(
                prop_oneof![(hard_vec3(), hard_vec3(), hard_vec3()), (lattice(), lattice(), lattice())], 32),
            first in 0usize..24, count in 0usize..9, extra in 0usize..9,
            o in prop_oneof![hard_vec3(), lattice()], d in prop_oneof![hard_vec3(), lattice()],
            tmin in prop_oneof![Just(0.0f32), hard_coord()], tmax in hard_coord(),
        ) {
            prop_assume!(cpu_has_avx2());
            // A block anywhere in the rows: in one group or straddling two
            // (from any lane), up to their very end (where its lanes past
            // `count` read the padding group).
            let len = (first + count + extra).min(tris.len());
            let corners: Vec<[Vec3; 3]> = tris[..len].iter().map(|&(a, b, c)| [a, b, c]).collect();
            let tris = crate::Triangles::from_corners(&corners);
            let ray = Ray::new(o, d, tmin, f32::INFINITY);
            let want = |k: usize| {
                (k < count).then(|| {
                    let [a, b, c] = corners[first + k];
                    raymesh_geometry::intersect_triangle(&ray, tmax, a, b, c)
                })?
            };
            let (mask, out) = crate::Primitives::intersect_block(
                &tris, first as u32, count as u32, &ray, tmax,
            );
            lanes_match(mask, &out, want)?;
            // The form the 8-wide walk inlines, its constants made once.
            let avx = Avx2::detect().expect("AVX2, kernels on");
            let pre = crate::Primitives::block_ray(&tris, &ray);
            let (mask, out) = crate::Primitives::intersect_block_pre(
                &tris, avx, &pre, first as u32, count as u32, &ray, tmax,
            );
            lanes_match(mask, &out, want)?;
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(2000))]
        /// A packet's block test ([`crate::Primitives::intersect_block_lanes`],
        /// the block's rows loaded once for every lane) gives each lane what
        /// the scalar test gives its ray with its own bound, bit for bit,
        /// and reports exactly the lanes asked for, in increasing order.
        #[test]
        fn packet_block_lanes_match_scalar(
            tris in proptest::collection::vec(
                prop_oneof![(hard_vec3(), hard_vec3(), hard_vec3()), (lattice(), lattice(), lattice())], 32),
            first in 0usize..24, count in 0usize..9,
            origins in proptest::collection::vec(prop_oneof![hard_vec3(), lattice()], 8),
            d in prop_oneof![hard_vec3(), lattice()],
            tmin in prop_oneof![Just(0.0f32), hard_coord()],
            tmax in proptest::collection::vec(hard_coord(), 8),
            lanes in 0u32..256,
        ) {
            prop_assume!(cpu_has_avx2());
            let len = (first + count).min(tris.len());
            let corners: Vec<[Vec3; 3]> = tris[..len].iter().map(|&(a, b, c)| [a, b, c]).collect();
            let tris = crate::Triangles::from_corners(&corners);
            // One direction: the eight rays share its octant and axis order.
            let rays: [Ray; 8] =
                std::array::from_fn(|i| Ray::new(origins[i], d, tmin, f32::INFINITY));
            let Some(p) = crate::Packet8::new(&rays) else { return Ok(()) };
            let tmax: [f32; 8] = tmax.try_into().expect("8 bounds");
            let count = count.min(len - first.min(len));
            let first = first.min(len);
            let avx = Avx2::detect().expect("AVX2, kernels on");
            let mut seen = Vec::new();
            let mut lane_results = Vec::new();
            crate::Primitives::intersect_block_lanes(
                &tris, avx, first as u32, count as u32, &p, lanes, &tmax,
                |i, mask, out| {
                    seen.push(i);
                    lane_results.push((i, mask, out));
                },
            );
            let asked: Vec<usize> = (0..8).filter(|i| lanes >> i & 1 != 0).collect();
            prop_assert_eq!(&seen, &asked);
            for (i, mask, out) in lane_results {
                lanes_match(mask, &out, |k| {
                    (k < count).then(|| {
                        let [a, b, c] = corners[first + k];
                        raymesh_geometry::intersect_triangle(&rays[i], tmax[i], a, b, c)
                    })?
                })?;
            }
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(2000))]
        /// A block tested for several rays of a group at once, its rows
        /// loaded once for each axis order among them, gives each ray
        /// asked for, once, what the scalar test gives it with its own
        /// bound, bit for bit: rays of any directions (so of several axis
        /// orders in one call), any subset of up to 32.
        #[test]
        fn block_for_several_rays_matches_scalar(
            tris in proptest::collection::vec(
                prop_oneof![(hard_vec3(), hard_vec3(), hard_vec3()), (lattice(), lattice(), lattice())], 32),
            first in 0usize..24, count in 0usize..9,
            rays in proptest::collection::vec(
                (prop_oneof![hard_vec3(), lattice()], prop_oneof![hard_vec3(), lattice()],
                 prop_oneof![Just(0.0f32), hard_coord()], hard_coord()), 1..=32),
            asked in any::<u32>(),
        ) {
            prop_assume!(cpu_has_avx2());
            let len = (first + count).min(tris.len());
            let corners: Vec<[Vec3; 3]> = tris[..len].iter().map(|&(a, b, c)| [a, b, c]).collect();
            let tris = crate::Triangles::from_corners(&corners);
            let made: Vec<(Ray, f32)> = rays
                .iter()
                .map(|&(o, d, tmin, tmax)| (Ray::new(o, d, tmin, f32::INFINITY), tmax))
                .collect();
            let mut pre = [BlockRay::default(); crate::bvh::GROUP];
            let mut classes = [0u32; AXIS_CLASSES];
            for (k, (r, _)) in made.iter().enumerate() {
                pre[k] = BlockRay::new(r);
                classes[pre[k].axis_class()] |= 1 << k;
            }
            let asked = asked & (u32::MAX >> (32 - made.len()));
            let count = count.min(len - first.min(len));
            let first = first.min(len);
            let avx = Avx2::detect().expect("AVX2, kernels on");
            let mut results = Vec::new();
            crate::Primitives::intersect_block_rays(
                &tris, avx, first as u32, count as u32, asked, &pre,
                |i| &made[i].0, |i| made[i].1, &classes,
                |i, mask, out| results.push((i, mask, out)),
            );
            let mut seen: Vec<usize> = results.iter().map(|&(i, _, _)| i).collect();
            seen.sort_unstable();
            let want: Vec<usize> = (0..made.len()).filter(|i| asked >> i & 1 != 0).collect();
            prop_assert_eq!(&seen, &want);
            for (i, mask, out) in results {
                let (ray, tmax) = &made[i];
                lanes_match(mask, &out, |k| {
                    (k < count).then(|| {
                        let [a, b, c] = corners[first + k];
                        raymesh_geometry::intersect_triangle(ray, *tmax, a, b, c)
                    })?
                })?;
            }
        }

        /// Triangles named by a list (a k-d tree's leaf, a grid cell;
        /// repeats allowed) gathered into a block give what the scalar
        /// test gives each, lane by lane, bit for bit: by
        /// `intersect_ids`, and by its AVX2 form with the ray's
        /// constants made before (`intersect_ids_pre`, the walks' own).
        #[test]
        fn gathered_triangles_match_scalar(
            tris in proptest::collection::vec(
                prop_oneof![(hard_vec3(), hard_vec3(), hard_vec3()), (lattice(), lattice(), lattice())], 12),
            ids in proptest::collection::vec(0u32..12, 0..=8),
            o in prop_oneof![hard_vec3(), lattice()], d in prop_oneof![hard_vec3(), lattice()],
            tmin in prop_oneof![Just(0.0f32), hard_coord()], tmax in hard_coord(),
        ) {
            let corners: Vec<[Vec3; 3]> = tris.iter().map(|&(a, b, c)| [a, b, c]).collect();
            let tris = crate::Triangles::from_corners(&corners);
            let ray = Ray::new(o, d, tmin, f32::INFINITY);
            let want = |k: usize| {
                let [a, b, c] = corners[*ids.get(k)? as usize];
                raymesh_geometry::intersect_triangle(&ray, tmax, a, b, c)
            };
            let (mask, out) = crate::Primitives::intersect_ids(&tris, &ids, &ray, tmax);
            lanes_match(mask, &out, want)?;
            if let Some(avx) = Avx2::detect() {
                let pre = crate::Primitives::block_ray(&tris, &ray);
                let (mask, out) =
                    crate::Primitives::intersect_ids_pre(&tris, avx, &pre, &ids, &ray, tmax);
                lanes_match(mask, &out, want)?;
            }
        }
    }
}
