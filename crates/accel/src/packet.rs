//! Ray packets: eight rays traced together through a wide BVH, so that a
//! node's boxes and a leaf's triangles are fetched once for the eight and
//! tested with each ray in one SIMD lane (Wald, Slusallek, Benthin &
//! Wagner, "Interactive rendering with coherent ray tracing", 2001; Wald,
//! Boulos & Shirley, "Ray tracing deformable scenes using dynamic bounding
//! volume hierarchies", 2007). Coherent rays (a camera's neighbouring
//! pixels) visit nearly the same nodes, so the packet pays for a node once
//! where single rays pay eight times.
//!
//! Exact: a packet is made only of rays that share their direction's
//! octant and dominant axis, so every lane runs the single-ray arithmetic
//! of `bvh::wide::slab_scalar` and [`raymesh_geometry::intersect_triangle`]
//! in the same order, with no fused multiply-add; each lane culls only what
//! its own ray would cull, and the closest hit (least `t`, ties to the least
//! index) is the one the single-ray traversal returns, bit for bit. The
//! loops below are plain Rust over eight lanes, which the compiler turns
//! into AVX under [`crate::simd::with_avx2`] and into SSE elsewhere; the
//! triangle test has an AVX2 kernel of its own (`simd::packet_lanes_avx`,
//! the loop [`lanes_portable`] its fallback).

use crate::{BlockHits, PrimHit};
use raymesh_geometry::{
    exit_reciprocal, intersect_triangle, max_nan_second as max_ns, min_nan_second as min_ns,
    needs_f64, Mat4, Ray, RayLanes8, Rays8, Vec3, Vec4,
};
use std::cell::OnceCell;

/// Rays in a packet: one per SIMD lane of AVX.
pub const LANES: usize = 8;

/// What a packet walk does at a leaf ([`crate::bvh::WideBvh`]'s and
/// [`crate::Bvh`]'s `traverse_packet`): tests primitives
/// `first..first + count` for the lanes in `lanes`, lowering their bounds
/// in `tmax` (to `-inf` for a lane that is done). `avx` is the walk's
/// proof that it runs in code compiled for AVX2, where it does.
///
/// A trait and not a closure so that the leaf's `#[inline(always)]`
/// inlines it into the walk's AVX2 code: the closure stayed a call each
/// leaf, with a CPU check and a call into AVX2 code inside it.
pub(crate) trait PacketLeaf {
    /// Tests the leaf for the lanes in `lanes`.
    fn visit(
        &mut self,
        avx: Option<crate::simd::Avx2>,
        first: u32,
        count: u32,
        lanes: u32,
        tmax: &mut [f32; LANES],
    );
    /// Starts fetching the leaf whose first slot is `first` (a hint).
    fn prefetch(&self, first: u32);
}

/// Eight rays in structure-of-arrays form, with what the box and triangle
/// tests need of each, for [`crate::Scene::intersect8`]. All share their
/// direction's octant and dominant axis (see [`Packet8::new`]).
///
/// Aligned to a cache line, with the rows first, so that each row the
/// kernels load whole (32 bytes) lies in one line. Left to the compiler's
/// layout (alignment 8, two rows straddling lines), occlusion streams
/// (`Scene::occluded_stream`), whose packets live in a frame of their
/// own, ran slower: this layout made them 1.12–1.25 times as fast on
/// primary and shadow rays (`raymesh-peers bunny00.off
/// ChineseDragon-10kv.off --stream --workloads primary,shadow --size
/// 512 --accel bvh8`, one thread, two alternated runs); the other packet
/// queries are level.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
pub struct Packet8<'a> {
    /// Upper ends of the intervals, as given.
    tmax: [f32; LANES],
    /// Origins by axis.
    origin: [[f32; LANES]; 3],
    /// Reciprocal directions by axis.
    inv_dir: [[f32; LANES]; 3],
    /// Their [`exit_reciprocal`]s, which exit distances are computed with.
    inv_exit: [[f32; LANES]; 3],
    /// Lower ends of the intervals.
    pub(crate) tmin: [f32; LANES],
    /// Origins in that axis order.
    pub(crate) porigin: [[f32; LANES]; 3],
    /// Shear constants of each lane (see [`Ray::shear`]).
    pub(crate) shear: [[f32; LANES]; 3],
    /// The triangle block kernel's axis offsets for the axis order `k`
    /// (every lane's: see [`crate::BlockRay`]).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) block_axes: [usize; 3],
    /// The watertight test's axis order `(kx, ky, kz)` (every lane's).
    k: [usize; 3],
    /// Which axes run backwards (the same for every lane).
    neg: [bool; 3],
    /// The packet's bounds for [`frustum`], when every lane's reciprocal
    /// direction is finite.
    pub(crate) frustum: Option<Frustum>,
    /// Where the lanes' rays come from, for the tests that need a lane's
    /// `Ray` (the scalar test's f64 path, primitives with no packet test).
    source: Source<'a>,
}

// Every row starts at a multiple of 32 bytes (the layout's point).
const _: () = {
    use std::mem::offset_of;
    let rows = [
        offset_of!(Packet8<'static>, tmax),
        offset_of!(Packet8<'static>, origin),
        offset_of!(Packet8<'static>, inv_dir),
        offset_of!(Packet8<'static>, inv_exit),
        offset_of!(Packet8<'static>, tmin),
        offset_of!(Packet8<'static>, porigin),
        offset_of!(Packet8<'static>, shear),
    ];
    let mut i = 0;
    while i < rows.len() {
        assert!(rows[i] % 32 == 0, "a packet's rows start on 32 bytes");
        i += 1;
    }
};

/// The rays of a packet: borrowed as they were given, not copied (a copy
/// was 480 bytes moved a packet), or, for rays given as rows, made from
/// them the first time a test asks for one (most packets of triangles
/// never do: the leaf kernels take the rows).
///
/// The larger variant stays inline: a packet lives on the stack for one
/// query, where a `Box` would be an allocation a packet.
#[derive(Clone, Debug)]
#[allow(clippy::large_enum_variant)]
enum Source<'a> {
    Rays(&'a [Ray; LANES]),
    Rows(&'a Rays8, OnceCell<[Ray; LANES]>),
}

/// What the interval slab test of a whole packet needs, per axis: the
/// origin coordinate that gives the least entry into the near plane and
/// the one that gives the greatest exit from the far plane, and the least
/// and greatest reciprocal direction. Made only when every reciprocal
/// direction is finite (and, the octant being shared, of one sign), so
/// the test meets no `0 × inf`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frustum {
    pub(crate) near_origin: [f32; 3],
    pub(crate) far_origin: [f32; 3],
    pub(crate) inv: [[f32; 2]; 3],
    /// The least and greatest [`exit_reciprocal`] (those of `inv`'s ends:
    /// rounding is monotone).
    pub(crate) inv_exit: [[f32; 2]; 3],
    pub(crate) tmin: f32,
}

impl<'a> Packet8<'a> {
    /// The packet of `rays`, or `None` unless every ray is valid and all
    /// share their direction's octant and axis order (then each lane's
    /// tests are the single-ray tests; callers trace the rays one by one
    /// otherwise).
    #[must_use]
    pub fn new(rays: &'a [Ray; LANES]) -> Option<Self> {
        Self::coherent(rays).then(|| Self::build(rays))
    }

    /// Whether `rays` make a packet ([`Self::new`]): all valid, with one
    /// octant and one axis order.
    #[inline]
    pub(crate) fn coherent(rays: &[Ray; LANES]) -> bool {
        let (_, k) = rays[0].shear();
        let oct = rays[0].octant();
        // Plain loops: iterator chains and arrays filled after zeroing made
        // this about 180 instructions a ray, a fifth of a packet's trace.
        let mut same = true;
        for r in rays {
            // The axis orders compared axis by axis: compared as arrays,
            // they were stored and reloaded as one vector, a load the
            // CPU could not forward from the three stores (a stall).
            let rk = r.shear().1;
            same &= r.is_valid() & (r.octant() == oct);
            same &= (rk[0] == k[0]) & (rk[1] == k[1]) & (rk[2] == k[2]);
        }
        same
    }

    /// The packet of `rays`, which must be [`Self::coherent`]. Returned by
    /// value rather than in an `Option`, so that the caller's packet is
    /// written in place (moved out of an `Option`, its 700 bytes were
    /// copied once more), and each array filled where it lies.
    #[inline]
    pub(crate) fn build(rays: &'a [Ray; LANES]) -> Self {
        let (_, k) = rays[0].shear();
        // Each ray's fields as 4-vectors (origin and `tmin`, reciprocal
        // and `tmax`, shear), four rays' transposed at a time
        // ([`Mat4::transpose`]) and stored as whole rows: gathered lane by
        // lane (`array::from_fn`, which stayed calls), the rows were 96
        // stores of four bytes that the packet's row loads waited on.
        let (mut origin, mut inv_dir, mut shear) =
            ([[0.0f32; LANES]; 3], [[0.0; LANES]; 3], [[0.0; LANES]; 3]);
        let (mut tmin, mut tmax) = ([0.0f32; LANES], [0.0f32; LANES]);
        for h in [0, 4] {
            let quad = |f: fn(&Ray) -> Vec4| {
                Mat4::from_cols(
                    f(&rays[h]),
                    f(&rays[h + 1]),
                    f(&rays[h + 2]),
                    f(&rays[h + 3]),
                )
                .transpose()
            };
            let o = quad(|r| r.origin().extend(r.tmin()));
            let i = quad(|r| r.inv_dir().extend(r.tmax()));
            let s = quad(|r| r.shear().0.extend(0.0));
            for a in 0..3 {
                o.col(a).write_to_slice(&mut origin[a][h..h + 4]);
                i.col(a).write_to_slice(&mut inv_dir[a][h..h + 4]);
                s.col(a).write_to_slice(&mut shear[a][h..h + 4]);
            }
            o.col(3).write_to_slice(&mut tmin[h..h + 4]);
            i.col(3).write_to_slice(&mut tmax[h..h + 4]);
        }
        Self::assemble(
            Source::Rays(rays),
            &tmax,
            &origin,
            &inv_dir,
            &shear,
            &tmin,
            k,
            rays[0].octant(),
        )
    }

    /// The packet of `rays`, whose rows `lanes` are
    /// ([`raymesh_geometry::Rays8::lanes`]): taken as they are, with no
    /// transposition and nothing checked again (the same packet as
    /// [`Self::build`] of each lane's [`Rays8::ray`]).
    #[inline(always)]
    pub(crate) fn from_lanes(rays: &'a Rays8, lanes: &RayLanes8) -> Self {
        Self::assemble(
            Source::Rows(rays, OnceCell::new()),
            &rays.tmax,
            &rays.origin,
            &lanes.inv_dir,
            &lanes.shear,
            &rays.tmin,
            lanes.k,
            lanes.octant,
        )
    }

    /// The packet of `rays`, given by rows (each lane's origin, reciprocal
    /// direction, shear constants and `tmin`) with their shared axis order
    /// and octant. The rows by reference, copied once, into the packet.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn assemble(
        source: Source<'a>,
        tmax: &[f32; LANES],
        origin: &[[f32; LANES]; 3],
        inv_dir: &[[f32; LANES]; 3],
        shear: &[[f32; LANES]; 3],
        tmin: &[f32; LANES],
        k: [usize; 3],
        oct: usize,
    ) -> Self {
        let neg = [oct & 1 != 0, oct & 2 != 0, oct & 4 != 0];
        // The frustum's ends by reductions over each row's two halves as
        // 4-lane vectors (a lane at a time, they were the most of this
        // function's instructions). Origins are finite and reciprocals
        // never NaN, so the order of the comparisons does not change the
        // result.
        let (o_lo, o_hi) = (row_min(origin), row_max(origin));
        let (i_lo, i_hi) = (row_min(inv_dir), row_max(inv_dir));
        let finite = inv_dir.iter().all(|r| {
            let (a, b) = halves(r);
            (a.is_finite_mask() & b.is_finite_mask()).all()
        });
        let frustum = Frustum {
            // A ray running forward on an axis enters its near plane
            // earliest from the greatest origin, backward from the least.
            near_origin: std::array::from_fn(|a| if neg[a] { o_lo[a] } else { o_hi[a] }),
            far_origin: std::array::from_fn(|a| if neg[a] { o_hi[a] } else { o_lo[a] }),
            inv: std::array::from_fn(|a| [i_lo[a], i_hi[a]]),
            inv_exit: std::array::from_fn(|a| [exit_reciprocal(i_lo[a]), exit_reciprocal(i_hi[a])]),
            tmin: row_min(&[*tmin])[0],
        };
        Self {
            source,
            tmax: *tmax,
            origin: *origin,
            inv_dir: *inv_dir,
            inv_exit: {
                // A loop, not `map`: `array::map` stayed a call into
                // `try_map` compiled apart, whose lane-by-lane stores the
                // rows' 32-byte loads then waited on.
                let mut e = *inv_dir;
                for row in &mut e {
                    for x in row {
                        *x = exit_reciprocal(*x);
                    }
                }
                e
            },
            tmin: *tmin,
            neg,
            k,
            porigin: [origin[k[0]], origin[k[1]], origin[k[2]]],
            shear: *shear,
            block_axes: crate::simd::kernel_axes(k),
            frustum: finite.then_some(frustum),
        }
    }
}

/// A row's two halves, lanes `0..4` and `4..8`.
#[inline(always)]
fn halves(r: &[f32; LANES]) -> (Vec4, Vec4) {
    (Vec4::from_slice(&r[..4]), Vec4::from_slice(&r[4..]))
}

/// Each row's least lane: its halves' least lanes, then the least of
/// those four.
#[inline(always)]
fn row_min<const N: usize>(rows: &[[f32; LANES]; N]) -> [f32; N] {
    rows.map(|r| {
        let (a, b) = halves(&r);
        a.min(b).min_element()
    })
}

/// Each row's greatest lane, as [`row_min`].
#[inline(always)]
fn row_max<const N: usize>(rows: &[[f32; LANES]; N]) -> [f32; N] {
    rows.map(|r| {
        let (a, b) = halves(&r);
        a.max(b).max_element()
    })
}

impl Packet8<'_> {
    /// Which axes the rays run backwards on.
    #[must_use]
    pub(crate) fn neg(&self) -> [bool; 3] {
        self.neg
    }

    /// Lane `k`'s ray.
    #[must_use]
    pub fn ray(&self, k: usize) -> &Ray {
        &self.rays()[k]
    }

    /// The lanes' rays (for rays given as rows, made on the first call).
    #[must_use]
    pub(crate) fn rays(&self) -> &[Ray; LANES] {
        match &self.source {
            Source::Rays(r) => r,
            Source::Rows(rows, made) => made.get_or_init(|| std::array::from_fn(|i| rows.ray(i))),
        }
    }

    /// Each lane's upper bound, as given.
    #[must_use]
    pub(crate) fn tmax(&self) -> &[f32; LANES] {
        &self.tmax
    }
}

/// The slab test of one box (`min`, `max`) against every lane, clipped to
/// each lane's `[tmin, bound]`: a bit per lane that enters the box, and each
/// lane's entry distance. Per lane, the arithmetic of
/// `bvh::wide::slab_scalar` in its order, so the bits are the same.
/// Uses the AVX kernel where the CPU has it (bit-identical results).
#[inline(always)]
pub(crate) fn slab(
    p: &Packet8,
    min: [f32; 3],
    max: [f32; 3],
    bound: &[f32; LANES],
) -> (u32, [f32; LANES]) {
    let (near, far) = planes(p, min, max);
    #[cfg(target_arch = "x86_64")]
    if let Some(avx) = crate::simd::Avx2::detect() {
        return slab_avx(avx, p, near, far, bound);
    }
    slab_lanes(p, near, far, bound)
}

/// [`slab_lanes`] in AVX inside an AVX2 traversal (the `Avx2` proof in
/// place of a check per box): the same bits.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn slab_avx(
    avx: crate::simd::Avx2,
    p: &Packet8,
    near: [f32; 3],
    far: [f32; 3],
    bound: &[f32; LANES],
) -> (u32, [f32; LANES]) {
    crate::simd::packet_slab8(
        avx,
        [&p.origin, &p.inv_dir, &p.inv_exit],
        &p.tmin,
        near,
        far,
        bound,
    )
}

/// A box's near and far plane on each axis for the packet's octant.
#[inline(always)]
pub(crate) fn planes(p: &Packet8, min: [f32; 3], max: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let pick = |a: usize| {
        if p.neg[a] {
            (max[a], min[a])
        } else {
            (min[a], max[a])
        }
    };
    ([0, 1, 2].map(|a| pick(a).0), [0, 1, 2].map(|a| pick(a).1))
}

/// [`slab`]'s portable loop, given each axis's near and far plane.
#[inline(always)]
pub(crate) fn slab_lanes(
    p: &Packet8,
    near: [f32; 3],
    far: [f32; 3],
    bound: &[f32; LANES],
) -> (u32, [f32; LANES]) {
    let (mut lo, mut hi) = ([[0.0f32; LANES]; 3], [[0.0f32; LANES]; 3]);
    for a in 0..3 {
        for i in 0..LANES {
            lo[a][i] = (near[a] - p.origin[a][i]) * p.inv_dir[a][i];
            hi[a][i] = (far[a] - p.origin[a][i]) * p.inv_exit[a][i];
        }
    }
    // Side by side as slab_scalar takes them: max(max(lo_x, lo_y),
    // max(lo_z, tmin)).
    let e: [f32; LANES] =
        std::array::from_fn(|i| max_ns(max_ns(lo[0][i], lo[1][i]), max_ns(lo[2][i], p.tmin[i])));
    let x: [f32; LANES] =
        std::array::from_fn(|i| min_ns(min_ns(hi[0][i], hi[1][i]), min_ns(hi[2][i], bound[i])));
    (lane_mask(&std::array::from_fn(|i| e[i] <= x[i])), e)
}

/// Which of `W` boxes (rows of lower and upper bounds by axis) some lane
/// of the packet may enter before `bound` (the greatest of the lanes'
/// bounds): the slab test in interval arithmetic over the packet's
/// origins and reciprocal directions (Boulos et al., "Geometric and
/// arithmetic culling methods for entire ray packets", 2006), one test for
/// all eight rays. Conservative, exactly: IEEE rounding is monotone, so the
/// interval's ends computed with the lanes' own operations bound every
/// lane's own entry and exit, and a box left out is one no lane's own
/// test ([`slab`]) enters. The lanes' tests then run only on the boxes
/// kept.
#[inline(always)]
pub(crate) fn frustum<const W: usize>(
    f: &Frustum,
    neg: [bool; 3],
    min: &[[f32; W]; 3],
    max: &[[f32; W]; 3],
    bound: f32,
) -> u32 {
    let mut e = [f.tmin; W];
    let mut x = [bound; W];
    for a in (0..3).rev() {
        let (near, far) = if neg[a] {
            (&max[a], &min[a])
        } else {
            (&min[a], &max[a])
        };
        let [i0, i1] = f.inv[a];
        let [x0, x1] = f.inv_exit[a];
        for c in 0..W {
            let d = near[c] - f.near_origin[a];
            let lo = min_ns(d * i0, d * i1);
            let d = far[c] - f.far_origin[a];
            let hi = max_ns(d * x0, d * x1);
            e[c] = max_ns(lo, e[c]);
            x[c] = min_ns(hi, x[c]);
        }
    }
    (0..W).fold(0, |m, c| m | (u32::from(e[c] <= x[c]) << c))
}

/// The greatest of the lanes of `v` whose bits are set in `lanes`
/// (`-inf` for none): the bound a packet's interval test ([`frustum`])
/// takes for its active lanes. By selects, not a filtered loop (a branch
/// a lane: 4% of the walk's instructions).
#[inline(always)]
pub(crate) fn masked_max(v: &[f32; LANES], lanes: u32) -> f32 {
    (0..LANES).fold(f32::NEG_INFINITY, |b, i| {
        let on = lanes >> i & 1 != 0;
        max_ns(if on { v[i] } else { f32::NEG_INFINITY }, b)
    })
}

/// A bit per lane where `a <= b` (none for NaN), in AVX where the CPU
/// has it.
#[inline(always)]
pub(crate) fn le_mask(a: &[f32; LANES], b: &[f32; LANES]) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx) = crate::simd::Avx2::detect() {
        return crate::simd::le_mask8(avx, a, b);
    }
    lane_mask(&std::array::from_fn(|i| a[i] <= b[i]))
}

/// A bit per lane that is `true`.
#[inline(always)]
pub(crate) fn lane_mask(b: &[bool; LANES]) -> u32 {
    b.iter()
        .enumerate()
        .fold(0, |m, (i, &b)| m | (u32::from(b) << i))
}

/// The watertight ray–triangle test of
/// [`raymesh_geometry::intersect_triangle`] for every lane of the packet
/// against one triangle, each lane over `[tmin, tmax[lane]]`: writes the
/// hits of the lanes in `lanes` to `out` and returns their mask. Lanes
/// the scalar test redoes in f64 ([`needs_f64`]: an edge function of
/// exactly zero, values out of `f32`'s range) take the scalar test, as
/// the single-ray kernels do.
#[inline]
pub(crate) fn triangle(
    p: &Packet8,
    corners: [Vec3; 3],
    lanes: u32,
    tmax: &[f32; LANES],
    out: &mut [PrimHit; LANES],
) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::has_avx2() {
        return crate::simd::packet_triangle(p, corners, lanes, tmax, out);
    }
    triangle_lanes(p, corners, lanes, tmax, out, lanes_portable)
}

/// [`triangle`] for each primitive of `prims` in turn (corners given by
/// `corners`), calling `offer(lane, prim, hit, tmax)` for each lane hit:
/// a packet traversal's leaf where the walk has no AVX2 (with it,
/// triangles take [`crate::simd::packet_tris`]).
#[inline(always)]
pub(crate) fn triangle_run(
    p: &Packet8,
    prims: std::ops::Range<u32>,
    corners: impl Fn(u32) -> [Vec3; 3],
    lanes: u32,
    tmax: &mut [f32; LANES],
    offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
) {
    for prim in prims {
        let mut hits = [PrimHit::default(); LANES];
        let mut m = triangle_lanes(p, corners(prim), lanes, tmax, &mut hits, lanes_portable);
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            offer(k, prim, hits[k], tmax);
        }
    }
}

/// [`triangle`]'s body with the lanes' test `kernel` ([`lanes_portable`]
/// or its AVX2 form): the lanes it hits written to `out`, those the
/// scalar test would redo in f64 ([`needs_f64`]) redone by it.
#[inline(always)]
pub(crate) fn triangle_lanes(
    p: &Packet8,
    corners: [Vec3; 3],
    lanes: u32,
    tmax: &[f32; LANES],
    out: &mut [PrimHit; LANES],
    kernel: impl Fn(&Packet8, [[f32; 3]; 3], &[f32; LANES]) -> (u32, u32, BlockHits),
) -> u32 {
    let [kx, ky, kz] = p.k;
    let c = corners.map(|v| {
        let a = v.to_array();
        [a[kx], a[ky], a[kz]]
    });
    let (ok, redo, h) = kernel(p, c, tmax);
    let redo = redo & lanes;
    let mut hit = ok & lanes & !redo;
    let mut m = hit;
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        out[i] = h.get(i);
    }
    let mut m = redo;
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        let [a, b, cc] = corners;
        if let Some(h) = intersect_triangle(p.ray(i), tmax[i], a, b, cc) {
            out[i] = PrimHit::from(h);
            hit |= 1 << i;
        }
    }
    hit
}

/// The eight lanes' test of one triangle (corners `c`, axes in the
/// packet's order `k`), in plain Rust: the mask of lanes inside with `t`
/// in their interval, the mask of lanes the scalar test redoes in f64
/// ([`needs_f64`]: an edge function of zero, values out of `f32`'s
/// range), and each lane's `t`, `u`, `v`. The AVX2 kernel
/// (`simd::packet_lanes_avx`) makes the same operations in the same order.
#[inline(always)]
pub(crate) fn lanes_portable(
    p: &Packet8,
    c: [[f32; 3]; 3],
    tmax: &[f32; LANES],
) -> (u32, u32, BlockHits) {
    let mut h = BlockHits::default();
    let (mut ok, mut redo) = ([false; LANES], [false; LANES]);
    for i in 0..LANES {
        let (o, s) = (
            [p.porigin[0][i], p.porigin[1][i], p.porigin[2][i]],
            [p.shear[0][i], p.shear[1][i], p.shear[2][i]],
        );
        let rel = |q: [f32; 3]| [q[0] - o[0], q[1] - o[1], q[2] - o[2]];
        let (a, b, cc) = (rel(c[0]), rel(c[1]), rel(c[2]));
        let (ax, ay) = (a[0] - s[0] * a[2], a[1] - s[1] * a[2]);
        let (bx, by) = (b[0] - s[0] * b[2], b[1] - s[1] * b[2]);
        let (cx, cy) = (cc[0] - s[0] * cc[2], cc[1] - s[1] * cc[2]);
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        // `|` and `&`, not `||` and `&&`: no branches, so the lanes vectorize.
        let outside = ((u < 0.0) | (v < 0.0) | (w < 0.0)) & ((u > 0.0) | (v > 0.0) | (w > 0.0));
        let det = u + v + w;
        let t_scaled = u * (s[2] * a[2]) + v * (s[2] * b[2]) + w * (s[2] * cc[2]);
        redo[i] = needs_f64(u, v, w, det, t_scaled, outside);
        let inv_det = 1.0 / det;
        h.t[i] = t_scaled * inv_det;
        h.u[i] = v * inv_det;
        h.v[i] = w * inv_det;
        // `det != 0.0` alone would let NaN through; `t >= tmin` rejects NaN.
        ok[i] =
            !outside & (det != 0.0) & !det.is_nan() & (h.t[i] >= p.tmin[i]) & (h.t[i] <= tmax[i]);
    }
    (lane_mask(&ok), lane_mask(&redo), h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::{slab_scalar, BoxRay, Node8};
    use raymesh_geometry::Aabb;

    fn rng(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 40) as f32 / (1u64 << 24) as f32 * 4.0 - 2.0
        }
    }

    /// Eight rays from near one point in one octant, as a camera makes.
    fn coherent(f: &mut impl FnMut() -> f32) -> [Ray; LANES] {
        let o = Vec3::new(f(), f(), f()) * 3.0;
        let d = Vec3::new(
            1.0 + f().abs(),
            0.1 + f().abs() * 0.2,
            -0.1 - f().abs() * 0.2,
        );
        std::array::from_fn(|_| {
            let j = Vec3::new(f(), f(), f()) * 0.01;
            Ray::new(o + j, d + j, 0.0, f32::INFINITY)
        })
    }

    /// A packet of prepared rays (`Packet8::build`, which transposes
    /// them four at a time) and the packet of the same rays as rows
    /// (`Packet8::from_lanes`) hold every lane's own constants, bit for
    /// bit: its origin, reciprocals, shear, interval and exit reciprocals.
    #[test]
    fn built_packets_hold_each_lanes_constants() {
        let mut f = rng(11);
        for n in 0..300 {
            let mut rays = coherent(&mut f);
            // Finite intervals of their own on some lanes.
            if n % 2 == 1 {
                for (i, r) in rays.iter_mut().enumerate() {
                    *r = Ray::new(r.origin(), r.dir(), 0.01 * i as f32, 2.0 + f().abs());
                }
            }
            let rows = Rays8::from_rays(&rays);
            let lanes = rows.lanes().expect("one octant and axis order");
            for p in [Packet8::build(&rays), Packet8::from_lanes(&rows, &lanes)] {
                let bits = |x: f32| x.to_bits();
                for (i, r) in rays.iter().enumerate() {
                    let (s, k) = r.shear();
                    assert_eq!(p.k, k);
                    for a in 0..3 {
                        assert_eq!(bits(p.origin[a][i]), bits(r.origin()[a]));
                        assert_eq!(bits(p.porigin[a][i]), bits(r.origin()[k[a]]));
                        assert_eq!(bits(p.inv_dir[a][i]), bits(r.inv_dir()[a]));
                        assert_eq!(
                            bits(p.inv_exit[a][i]),
                            bits(exit_reciprocal(r.inv_dir()[a]))
                        );
                        assert_eq!(bits(p.shear[a][i]), bits(s[a]));
                    }
                    assert_eq!(bits(p.tmin[i]), bits(r.tmin()));
                    assert_eq!(bits(p.tmax[i]), bits(r.tmax()));
                }
            }
        }
    }

    /// Each lane's box test gives the single-ray node test's bits.
    #[test]
    fn packet_slab_matches_the_single_ray_test() {
        let mut f = rng(7);
        for _ in 0..300 {
            let rays = coherent(&mut f);
            let p = Packet8::new(&rays).expect("one octant and axis order");
            let q = Vec3::new(f(), f(), f());
            let b = Aabb::new(q, q + Vec3::new(f().abs(), f().abs(), f().abs()));
            let mut bound: [f32; LANES] = std::array::from_fn(|_| f().abs() * 8.0);
            bound[3] = f32::NAN;
            for simd in [true, false] {
                crate::set_simd_enabled(simd);
                let (mask, e) = slab(&p, b.min.to_array(), b.max.to_array(), &bound);
                let le = le_mask(&e, &bound);
                crate::set_simd_enabled(true);
                for (i, r) in rays.iter().enumerate() {
                    let mut t = [0.0f32; 8];
                    let node = Node8::from_boxes(&[b]);
                    let m = slab_scalar(&node, &BoxRay::new(r), bound[i], &mut t);
                    assert_eq!(mask >> i & 1, m & 1, "lane {i}, simd {simd}");
                    // Entries of lanes that miss matter too: pops compare them.
                    assert_eq!(e[i].to_bits(), t[0].to_bits(), "lane {i}, simd {simd}");
                    assert_eq!(le >> i & 1 == 1, e[i] <= bound[i], "lane {i}, simd {simd}");
                }
            }
        }
    }

    /// The interval test of a node keeps every box some lane enters
    /// (boxes empty, flat, huge or infinite too), with the AVX kernel and
    /// the portable loop giving the same bits, and culls most boxes no
    /// lane enters.
    #[test]
    fn frustum_keeps_every_box_a_lane_enters() {
        let mut f = rng(5);
        let (mut culled, mut missed) = (0, 0);
        for n in 0..3000 {
            let mut rays = coherent(&mut f);
            if n % 2 == 0 {
                // Different origins too.
                let d = rays[0].dir();
                rays = std::array::from_fn(|i| {
                    Ray::new(rays[i].origin() + Vec3::splat(f() * 0.3), d, f().abs(), 1e3)
                });
            }
            let p = Packet8::new(&rays).expect("one octant and axis order");
            let fr = p.frustum.expect("finite directions");
            let boxes: Vec<Aabb> = (0..8)
                .map(|k| {
                    let q = Vec3::new(f(), f(), f()) * 4.0;
                    let e = Vec3::new(f().abs(), f().abs(), f().abs()) * [0.0, 0.2, 2.0][k % 3];
                    match k {
                        6 => Aabb::EMPTY,
                        7 if n % 5 == 0 => Aabb::new(q - Vec3::splat(f32::INFINITY), q),
                        _ => Aabb::new(q, q + e),
                    }
                })
                .collect();
            let node = Node8::from_boxes(&boxes);
            let (min, max) = (node.rows(false), node.rows(true));
            let bound: [f32; LANES] = std::array::from_fn(|_| f().abs() * 6.0);
            let b = bound.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let mut kept = None;
            for simd in [true, false] {
                crate::set_simd_enabled(simd);
                let m = if simd && cfg!(target_arch = "x86_64") {
                    node.frustum(&fr, p.neg, b)
                } else {
                    frustum(&fr, p.neg, &min, &max, b)
                };
                crate::set_simd_enabled(true);
                assert!(
                    kept.is_none_or(|k| k == m),
                    "case {n}: kernel and loop differ"
                );
                kept = Some(m);
            }
            let kept = kept.unwrap_or_default();
            for (c, bx) in boxes.iter().enumerate() {
                let (lanes, _) = slab(&p, bx.min.to_array(), bx.max.to_array(), &bound);
                if lanes != 0 {
                    assert!(
                        kept >> c & 1 == 1,
                        "case {n}: box {c} entered by {lanes:b} culled"
                    );
                } else if kept >> c & 1 == 0 {
                    culled += 1;
                } else {
                    missed += 1;
                }
            }
        }
        assert!(
            culled > 4 * missed,
            "culled {culled}, kept {missed} boxes no lane enters"
        );
    }

    /// Each lane's triangle test gives the scalar test's hit, bit for bit,
    /// edge-on and corner-through cases included, and scenes scaled by
    /// 2^±50 and 2^±100 (where the scalar test redoes lanes in f64 for
    /// their range: `needs_f64`).
    #[test]
    fn packet_triangle_matches_the_scalar_test() {
        let mut f = rng(11);
        for n in 0..2000 {
            let scale = match n % 10 {
                1 => 2f32.powi(50),
                2 => 2f32.powi(-50),
                3 => 2f32.powi(100),
                4 => 2f32.powi(-100),
                _ => 1.0,
            };
            let rays = coherent(&mut f).map(|r| {
                Ray::new(
                    r.origin() * scale,
                    r.dir(),
                    r.tmin() * scale,
                    r.tmax() * scale,
                )
            });
            let p = Packet8::new(&rays).expect("one octant and axis order");
            let mut tri = [
                (Vec3::new(f(), f(), f()) + Vec3::X * 3.0) * scale,
                (Vec3::new(f(), f(), f()) + Vec3::X * 3.0) * scale,
                (Vec3::new(f(), f(), f()) + Vec3::X * 3.0) * scale,
            ];
            if n % 7 == 0 {
                // Through the first ray's origin: edge functions of zero.
                tri[0] = rays[0].origin() + rays[0].dir() * 2.0 * scale;
            }
            if n % 11 == 0 {
                tri[2] = tri[1]; // degenerate
            }
            let tmax: [f32; LANES] = std::array::from_fn(|_| f().abs() * 10.0 * scale);
            let lanes = if n % 3 == 0 { 0xff } else { 0b1010_1101 };
            for simd in [true, false] {
                crate::set_simd_enabled(simd);
                let mut out = [PrimHit::default(); LANES];
                let mask = triangle(&p, tri, lanes, &tmax, &mut out);
                crate::set_simd_enabled(true);
                for (i, r) in rays.iter().enumerate() {
                    let want = (lanes >> i & 1 == 1)
                        .then(|| intersect_triangle(r, tmax[i], tri[0], tri[1], tri[2]))
                        .flatten();
                    assert_eq!(mask >> i & 1 == 1, want.is_some(), "lane {i} of case {n}");
                    if let Some(h) = want {
                        let got = out[i];
                        assert_eq!(
                            [got.t, got.u, got.v].map(f32::to_bits),
                            [h.t, h.u, h.v].map(f32::to_bits),
                            "lane {i} of case {n}"
                        );
                    }
                }
            }
        }
    }

    /// A leaf's triangles tested one after another against a packet's
    /// lanes, as a packet walk with AVX2 tests them (`Triangles`'
    /// `intersect_packet_tris`, [`crate::simd::packet_tris`]), and as one
    /// without (`intersect_packet_run`, the portable kernel): each makes
    /// the offers that each lane's ray alone makes, triangle by triangle
    /// with the bound the hits before left (the scalar test), bit for bit;
    /// with `ends`, a lane's first hit ends it. In every axis order, at
    /// scales that send lanes down the `f64` path, with triangles through
    /// a lane's ray (edge functions of zero), degenerate and repeated
    /// ones, and leaves that start and end inside the rows' groups.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn packet_leaf_runs_match_each_lanes_scalar_tests() {
        use crate::Primitives;
        let Some(avx) = crate::simd::Avx2::detect() else {
            return;
        };
        let mut f = rng(23);
        for n in 0..600 {
            let scale = match n % 8 {
                1 => 2f32.powi(60),
                2 => 2f32.powi(-60),
                _ => 1.0,
            };
            // Directions' components permuted and flipped: every axis
            // order and octant.
            let (perm, flip) = (
                [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1]][n % 4],
                n / 4 % 8,
            );
            let rays = coherent(&mut f).map(|r| {
                let d = r.dir().to_array();
                let d = Vec3::new(d[perm[0]], d[perm[1]], d[perm[2]]);
                let s = |b: usize| if flip >> b & 1 == 1 { -1.0 } else { 1.0 };
                let d = d * Vec3::new(s(0), s(1), s(2));
                Ray::new(r.origin() * scale, d, 0.0, f32::INFINITY)
            });
            let p = Packet8::new(&rays).expect("one octant and axis order");
            let count = 1 + n % 13;
            let tris: Vec<[Vec3; 3]> = (0..count + 8)
                .map(|i| {
                    // Ahead of the lanes, about where they point.
                    let ahead = rays[i % LANES].origin() + rays[i % LANES].dir() * 3.0 * scale;
                    let mut t = [0; 3].map(|_| ahead + Vec3::new(f(), f(), f()) * scale);
                    match (n + i) % 9 {
                        0 => t[0] = rays[i % LANES].origin() + rays[i % LANES].dir() * 2.0 * scale,
                        1 => t[2] = t[1],
                        _ => {}
                    }
                    t
                })
                .collect();
            let mut tris = tris;
            if n % 5 == 0 {
                tris[count / 2] = tris[0]; // the same triangle twice
            }
            let rows = crate::Triangles::from_corners(&tris);
            let first = (n * 7) % 9;
            let count = count.min(tris.len() - first);
            let lanes = if n % 3 == 0 { 0xff } else { 0b0110_1011 };
            let bound: [f32; LANES] = std::array::from_fn(|i| {
                if i % 3 == 0 {
                    f32::INFINITY
                } else {
                    (2.0 + f().abs() * 3.0) * scale
                }
            });
            for ends in [false, true] {
                // Each lane alone: the scalar test, triangle by triangle.
                let mut want = Vec::new();
                for (k, r) in rays.iter().enumerate() {
                    let mut t = bound[k];
                    if lanes >> k & 1 == 0 {
                        continue;
                    }
                    for (s, c) in tris.iter().enumerate().skip(first).take(count) {
                        if let Some(h) = intersect_triangle(r, t, c[0], c[1], c[2]) {
                            want.push((s as u32, k, [h.t, h.u, h.v].map(f32::to_bits)));
                            t = if ends { f32::NEG_INFINITY } else { h.t };
                            if ends {
                                break;
                            }
                        }
                    }
                }
                want.sort_unstable();
                let run = |simd: bool| {
                    let mut got = Vec::new();
                    let mut tmax = bound;
                    let mut offer = |k: usize, prim: u32, h: PrimHit, tmax: &mut [f32; LANES]| {
                        got.push((prim, k, [h.t, h.u, h.v].map(f32::to_bits)));
                        tmax[k] = if ends { f32::NEG_INFINITY } else { h.t };
                    };
                    let (first, count) = (first as u32, count as u32);
                    if simd {
                        rows.intersect_packet_tris(
                            avx, first, count, &p, lanes, ends, &mut tmax, &mut offer,
                        );
                    } else {
                        rows.intersect_packet_run(first, count, &p, lanes, &mut tmax, &mut offer);
                    }
                    got.sort_unstable();
                    got
                };
                assert_eq!(run(true), want, "AVX2, case {n}, ends {ends}");
                assert_eq!(run(false), want, "portable, case {n}, ends {ends}");
            }
        }
    }

    /// The frustum holds the lanes' extremes, whichever lane holds each
    /// (the vector reductions of `build` against a plain fold), in every
    /// octant; a lane with an infinite reciprocal direction leaves none.
    #[test]
    fn frustum_holds_the_lanes_extremes() {
        let mut f = rng(5);
        for n in 0..500 {
            let mut rays = coherent(&mut f);
            let flip = Vec3::new(
                if n & 1 == 0 { 1.0 } else { -1.0 },
                if n & 2 == 0 { 1.0 } else { -1.0 },
                if n & 4 == 0 { 1.0 } else { -1.0 },
            );
            for r in &mut rays {
                *r = Ray::new(r.origin(), r.dir() * flip, f().abs(), 50.0);
            }
            let p = Packet8::new(&rays).expect("one octant and axis order");
            let fr = p.frustum.expect("finite reciprocals");
            let fold = |x: &dyn Fn(&Ray) -> f32, max: bool| {
                rays.iter()
                    .map(x)
                    .fold(if max { f32::MIN } else { f32::MAX }, |a, b| {
                        if max {
                            a.max(b)
                        } else {
                            a.min(b)
                        }
                    })
            };
            for a in 0..3 {
                let (lo, hi) = (
                    fold(&|r| r.origin()[a], false),
                    fold(&|r| r.origin()[a], true),
                );
                let neg = rays[0].dir()[a] < 0.0;
                assert_eq!(
                    fr.near_origin[a],
                    if neg { lo } else { hi },
                    "case {n} axis {a}"
                );
                assert_eq!(
                    fr.far_origin[a],
                    if neg { hi } else { lo },
                    "case {n} axis {a}"
                );
                let inv = [
                    fold(&|r| r.inv_dir()[a], false),
                    fold(&|r| r.inv_dir()[a], true),
                ];
                assert_eq!(fr.inv[a], inv, "case {n} axis {a}");
                assert_eq!(
                    fr.inv_exit[a],
                    inv.map(exit_reciprocal),
                    "case {n} axis {a}"
                );
            }
            assert_eq!(fr.tmin, fold(&|r| r.tmin(), false), "case {n}");
            // A zero z component (of the direction's sign): the same
            // octant and axis order, an infinite reciprocal.
            for r in &mut rays {
                *r = Ray::new(r.origin(), r.dir() * Vec3::new(1.0, 1.0, 0.0), 0.0, 1.0);
            }
            let p = Packet8::new(&rays).expect("one octant and axis order");
            assert!(p.frustum.is_none(), "case {n}: a zero direction component");
        }
    }

    /// Rays of different octants or axis orders, or an invalid ray, make
    /// no packet.
    #[test]
    fn mixed_rays_make_no_packet() {
        let mut f = rng(3);
        let mut rays = coherent(&mut f);
        assert!(Packet8::new(&rays).is_some());
        rays[5] = Ray::infinite(rays[5].origin(), -rays[5].dir());
        assert!(Packet8::new(&rays).is_none());
        let mut rays = coherent(&mut f);
        rays[2] = Ray::infinite(Vec3::NAN, rays[2].dir());
        assert!(Packet8::new(&rays).is_none());
        let mut rays = coherent(&mut f);
        rays[7] = Ray::infinite(rays[7].origin(), Vec3::new(0.1, 5.0, -0.1));
        assert!(Packet8::new(&rays).is_none());
    }
}
