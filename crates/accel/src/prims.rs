//! What structures index: primitives with bounds and a ray test.

use crate::packet::{self, Packet8, LANES};
use crate::pages::{Pages, PagesMut};
use crate::simd::{block_at, Avx2, BlockRay, GROUP, GROUP_SLOTS};
use raymesh_geometry::{
    clip_triangle, intersect_sphere, intersect_triangle, triangle_hit_bounds, triangle_normal,
    Aabb, Ray, Sphere, SphereHit, TriHit, Vec3,
};
use rayon::prelude::*;

/// Hit of one primitive: distance and two surface coordinates (barycentric
/// weights of the 2nd and 3rd corner for triangles; `φ/2π`, `θ/π` for spheres).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PrimHit {
    /// Ray parameter.
    pub t: f32,
    /// First surface coordinate.
    pub u: f32,
    /// Second surface coordinate.
    pub v: f32,
}

impl From<TriHit> for PrimHit {
    /// A triangle's hit: `u` and `v` the second and third corners' weights.
    #[inline(always)]
    fn from(h: TriHit) -> Self {
        Self {
            t: h.t,
            u: h.u,
            v: h.v,
        }
    }
}

impl From<SphereHit> for PrimHit {
    /// A sphere's hit: `u` and `v` its azimuth and polar angle, scaled.
    #[inline(always)]
    fn from(h: SphereHit) -> Self {
        Self {
            t: h.t,
            u: h.u,
            v: h.v,
        }
    }
}

/// What a block test ([`Primitives::intersect_block`]) finds, lane by
/// lane, as structure-of-arrays: a SIMD kernel hands back its three result
/// registers as they are, with no array to clear first and no scatter into
/// [`PrimHit`]s. Only the lanes of the mask returned beside it hold hits.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlockHits {
    /// Ray parameter of each lane's hit.
    pub t: [f32; BLOCK],
    /// First surface coordinate of each lane's hit.
    pub u: [f32; BLOCK],
    /// Second surface coordinate of each lane's hit.
    pub v: [f32; BLOCK],
}

impl BlockHits {
    /// The hit of lane `k`.
    #[inline(always)]
    #[must_use]
    pub fn get(&self, k: usize) -> PrimHit {
        PrimHit {
            t: self.t[k],
            u: self.u[k],
            v: self.v[k],
        }
    }

    /// Writes `h` to lane `k`.
    #[inline(always)]
    pub fn set(&mut self, k: usize, h: PrimHit) {
        (self.t[k], self.u[k], self.v[k]) = (h.t, h.u, h.v);
    }
}

/// A set of primitives addressed by `u32` index: what a structure is built over.
pub trait Primitives: Send + Sync {
    /// Number of primitives.
    fn len(&self) -> usize;
    /// Whether there are none.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Bounding box of primitive `i`: a box that holds every hit point
    /// [`Self::intersect`] reports on it, which the structures cull by.
    /// For triangles, [`raymesh_geometry::triangle_hit_bounds`]: the
    /// corners' box, or more for a degenerate triangle, whose hits rounding
    /// may place off it.
    fn bounds(&self, i: u32) -> Aabb;
    /// The boxes of primitive `i`'s part inside `within` on each side of
    /// the plane `axis = pos`, for BVHs with spatial splits (see
    /// [`crate::Clip`], whose contract this is). The default cuts `within`
    /// itself, which is always valid; triangles clip their own shape.
    fn clip(&self, i: u32, within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
        let _ = i;
        within.split(axis, pos)
    }
    /// Ray test of primitive `i` over `[ray.tmin, tmax]` (both ends
    /// included): a hit's `t` lies in that interval, and so is never NaN
    /// (the queries of [`crate::Scene`] rely on it).
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit>;
    /// Tests primitives `first..first + count` (`count` at most [`BLOCK`])
    /// as [`Self::intersect`] would, each against the same `tmax`: returns
    /// a mask of the lanes hit and their hits (lane `k` is primitive
    /// `first + k`).
    /// Leaves of wide BVHs call it, so primitive types with a SIMD test
    /// (see [`Triangles`]) test a leaf at once; the default loops.
    #[inline]
    fn intersect_block(&self, first: u32, count: u32, ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        let mut out = BlockHits::default();
        let lanes = 0..(count as usize).min(BLOCK);
        let mask = intersect_each(self, |k| first + k as u32, lanes, ray, tmax, &mut out);
        (mask, out)
    }
    /// Asks the CPU to start loading what a block test of the primitives
    /// from `first` on reads: a hint for traversals that reach a leaf
    /// only after other work (a stream's), with no effect on any result.
    /// The default does nothing.
    #[inline(always)]
    fn prefetch_block(&self, first: u32) {
        let _ = first;
    }
    /// The per-ray constants of [`Self::intersect_block_pre`], computed
    /// once before a traversal (the default has none).
    #[inline(always)]
    fn block_ray(&self, ray: &Ray) -> BlockRay {
        let _ = ray;
        BlockRay::default()
    }
    /// [`Self::intersect_block`] inside a traversal compiled for AVX2
    /// (the `Avx2` proof), with `pre` = [`Self::block_ray`] of the same
    /// primitives and `ray`: the same results. Triangles inline their
    /// kernel there with nothing recomputed per block (and panic if `pre`
    /// was made for other triangles' rows); the default calls
    /// [`Self::intersect_block`].
    #[inline(always)]
    fn intersect_block_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        first: u32,
        count: u32,
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        let _ = (avx, pre);
        self.intersect_block(first, count, ray, tmax)
    }
    /// [`Self::intersect_block_pre`] of each lane in `lanes` of the
    /// packet `p`, in increasing order, against the block
    /// `first..first + count`: lane `i` with the bound `tmax[i]`, its mask
    /// and hits handed to `each(i, mask, hits)`. The same results. A
    /// packet's leaf that few of its lanes reach is tested so, a block at
    /// a time: triangles load the block's rows once for all the lanes and
    /// take each lane's constants from the packet's rows, with no `Ray` of
    /// the lane made (but where the scalar test must redo a lane, which
    /// the AVX2 kernel never leaves); the default tests each lane's ray.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn intersect_block_lanes(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        p: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        mut each: impl FnMut(usize, u32, BlockHits),
    ) {
        let mut m = lanes;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            let ray = p.ray(i);
            let pre = self.block_ray(ray);
            let (mask, hits) = self.intersect_block_pre(avx, &pre, first, count, ray, tmax[i]);
            each(i, mask, hits);
        }
    }
    /// [`Self::intersect_block_pre`] of each ray `i` in `rays` (a bit each,
    /// rays of a group: `ray(i)`, its constants `pre[i]`, its bound
    /// `tmax(i)`; `classes[c]`, the group's rays of axis order `c`, which
    /// read the same rows of a block), against the block
    /// `first..first + count`, each ray's mask and hits handed to
    /// `each(i, mask, hits)`. The same results. Triangles load the
    /// block's rows once for the rays that share an axis order; the
    /// default tests each ray.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn intersect_block_rays<'r>(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        rays: u32,
        pre: &[BlockRay; crate::bvh::GROUP],
        ray: impl Fn(usize) -> &'r Ray,
        tmax: impl Fn(usize) -> f32,
        classes: &[u32; crate::simd::AXIS_CLASSES],
        mut each: impl FnMut(usize, u32, BlockHits),
    ) {
        let _ = classes;
        let mut m = rays;
        while m != 0 {
            let i = m.trailing_zeros() as usize % crate::bvh::GROUP;
            m &= m - 1;
            let (mask, hits) =
                self.intersect_block_pre(avx, &pre[i], first, count, ray(i), tmax(i));
            each(i, mask, hits);
        }
    }
    /// Tests primitives `ids` (at most [`BLOCK`]; lane `k` is primitive
    /// `ids[k]`) as [`Self::intersect_block`] tests consecutive ones: the
    /// grid's cells (and the k-d tree's leaves, over primitives not
    /// stored in its leaf order) name their primitives by index.
    /// Triangles gather the corners into a block for the SIMD test; the
    /// default loops.
    #[inline]
    fn intersect_ids(&self, ids: &[u32], ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        let ids = &ids[..ids.len().min(BLOCK)];
        let mut out = BlockHits::default();
        let mask = intersect_each(self, |k| ids[k], 0..ids.len(), ray, tmax, &mut out);
        (mask, out)
    }
    /// [`Self::intersect_ids`] inside a traversal compiled for AVX2 (the
    /// `Avx2` proof), with `pre` = [`Self::block_ray`] of the same
    /// primitives and `ray`: the same results. Triangles inline their
    /// kernel there with nothing recomputed per block; the default calls
    /// [`Self::intersect_ids`].
    #[inline(always)]
    fn intersect_ids_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        ids: &[u32],
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        let _ = (avx, pre);
        self.intersect_ids(ids, ray, tmax)
    }
    /// Whether [`Self::intersect_block`] tests a block at once (a SIMD
    /// kernel) rather than one by one: then a binary BVH's SAH counts its
    /// leaves in blocks (see [`crate::BuildConfig::leaf_block`]).
    const BLOCK_TEST: bool = false;
    /// Whether the primitives keep the index the user gave each
    /// ([`Self::stored_index`]) through [`Self::reorder`]: then a scene
    /// keeps no permutation of its own, and a hit's index is read next
    /// to the primitive's data, which the hit's test has just loaded.
    const STORES_INDEX: bool = false;
    /// The index the user gave the primitive stored at `k`, for types
    /// that keep it ([`Self::STORES_INDEX`]); `k` for the others.
    #[inline(always)]
    fn stored_index(&self, k: u32) -> u32 {
        k
    }
    /// Tests primitive `i` against the lanes `lanes` of a packet, lane `k`
    /// over `[tmin, tmax[k]]`, as [`Self::intersect`] tests each lane's
    /// ray: writes the hit of lane `k` to `out[k]` and returns the mask of
    /// lanes hit. Packet traversals ([`crate::Scene::intersect8`]) call it;
    /// triangles test the eight lanes at once, the default loops over them.
    #[inline]
    fn intersect_packet(
        &self,
        i: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        out: &mut [PrimHit; LANES],
    ) -> u32 {
        let mut hit = 0;
        for k in (0..LANES).filter(|&k| lanes >> k & 1 != 0) {
            if let Some(h) = self.intersect(i, packet.ray(k), tmax[k]) {
                out[k] = h;
                hit |= 1 << k;
            }
        }
        hit
    }
    /// Tests primitives `first..first + count` in turn against the lanes
    /// `lanes` of a packet, each as [`Self::intersect_packet`] does, lane
    /// `k` over `[tmin, tmax[k]]` as the hits before left `tmax`: calls
    /// `offer(k, prim, hit, tmax)` for each lane a primitive hits, which
    /// may lower `tmax[k]`. A packet traversal's leaf in one call, so that
    /// triangles run it in one AVX2 region with their kernel inlined; the
    /// default loops over [`Self::intersect_packet`].
    #[inline]
    fn intersect_packet_run(
        &self,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        for prim in first..first + count {
            let mut hits = [PrimHit::default(); LANES];
            let mut m = self.intersect_packet(prim, packet, lanes, tmax, &mut hits);
            while m != 0 {
                let k = m.trailing_zeros() as usize;
                m &= m - 1;
                offer(k, prim, hits[k], tmax);
            }
        }
    }
    /// [`Self::intersect_packet_run`] inside a packet walk compiled for
    /// AVX2 (the `Avx2` proof): the same results. `ends` says that
    /// `offer` ends each lane at its first hit (an any-hit walk's leaf,
    /// whose `offer` sets the lane's `tmax` to `-inf`): a lane hit is then
    /// tested no further, and the leaf stops once every lane is hit.
    /// Triangles test each triangle's eight lanes with their kernel
    /// inlined into the walk (`simd::packet_tris`); the default calls
    /// [`Self::intersect_packet_run`].
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn intersect_packet_tris(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        ends: bool,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        let _ = (avx, ends);
        self.intersect_packet_run(first, count, packet, lanes, tmax, offer);
    }
    /// Unit geometric normal of primitive `i` at a hit (not flipped toward the ray).
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3;
    /// Puts the primitives in another order, in place: new primitive `k`
    /// is old primitive `order[k]` (`order` may name a primitive more than
    /// once, as a BVH with spatial splits does, and then holds more). A
    /// scene built over a BVH uses it to store primitives in leaf order and
    /// drop the permutation's indirection. Returns whether it did; `false`
    /// (the default, for types that cannot) keeps the indirection.
    fn reorder(&mut self, _order: &[u32]) -> bool {
        false
    }
}

/// `v` in the order `order` (`result[k] = v[order[k]]`), gathered in parallel.
fn permuted<T: Copy + Send + Sync>(v: &[T], order: &[u32]) -> Vec<T> {
    order.par_iter().map(|&i| v[i as usize]).collect()
}

/// Tests lanes `lanes` one by one with [`Primitives::intersect`], lane
/// `k` being primitive `prim(k)`: the portable path of
/// [`Primitives::intersect_block`] (consecutive primitives) and
/// [`Primitives::intersect_ids`] (a list). Returns the mask of lanes hit.
#[inline(always)]
fn intersect_each<P: Primitives + ?Sized>(
    prims: &P,
    prim: impl Fn(usize) -> u32,
    lanes: impl Iterator<Item = usize>,
    ray: &Ray,
    tmax: f32,
    out: &mut BlockHits,
) -> u32 {
    let mut mask = 0;
    for k in lanes {
        if let Some(h) = prims.intersect(prim(k), ray, tmax) {
            out.set(k, h);
            mask |= 1 << k;
        }
    }
    mask
}

/// A SIMD block test's result `(mask, redo, out)` completed: the lanes
/// in `redo`, which the scalar test redoes in f64
/// ([`raymesh_geometry::needs_f64`]), take the scalar test (lane `k` is
/// primitive `prim(k)`).
#[cfg(any(
    target_arch = "x86_64",
    all(target_arch = "aarch64", target_feature = "neon")
))]
#[inline(always)]
fn redo_lanes<P: Primitives + ?Sized>(
    prims: &P,
    prim: impl Fn(usize) -> u32,
    (mask, redo, mut out): (u32, u32, BlockHits),
    ray: &Ray,
    tmax: f32,
) -> (u32, BlockHits) {
    if redo == 0 {
        return (mask, out);
    }
    let lanes = (0..BLOCK).filter(|k| redo >> k & 1 != 0);
    let more = intersect_each(prims, prim, lanes, ray, tmax, &mut out);
    (mask | more, out)
}

/// The lanes `redo` of a packet against triangle `prim` of `tris` by the
/// scalar test (its `f64` path), as [`packet::triangle_lanes`] redoes
/// them: each hit goes to `offer`; returns the lanes hit. Out of line: it
/// is rare, and the scalar test inlined would crowd the packet walk it
/// is called from.
#[cfg(target_arch = "x86_64")]
#[cold]
#[inline(never)]
fn redo_packet_lanes(
    tris: &Triangles,
    prim: u32,
    packet: &Packet8,
    redo: u32,
    tmax: &mut [f32; LANES],
    offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
) -> u32 {
    let [a, b, c] = tris.corners(prim);
    let (mut m, mut hit) = (redo, 0);
    while m != 0 {
        let k = m.trailing_zeros() as usize;
        m &= m - 1;
        if let Some(h) = intersect_triangle(packet.ray(k), tmax[k], a, b, c) {
            offer(k, prim, PrimHit::from(h), tmax);
            hit |= 1 << k;
        }
    }
    hit
}

/// Triangles sharing one vertex buffer: the lecture's TriangleMesh.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Corner indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Makes a mesh; every index must be below `positions.len()`.
    #[must_use]
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        assert!(
            triangles
                .iter()
                .flatten()
                .all(|&i| (i as usize) < positions.len()),
            "triangle index out of range"
        );
        Self {
            positions,
            triangles,
        }
    }

    /// The corners of triangle `i`.
    #[inline(always)]
    #[must_use]
    pub fn corners(&self, i: u32) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[i as usize];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Asks the CPU to start loading what [`Self::corners`] of triangle
    /// `i` reads: its corner indices, and with `positions` the three
    /// positions they name (which waits for the indices, so a gather asks
    /// for a triangle's indices some steps before its positions). A hint
    /// with no effect on any result; an index out of range does nothing.
    #[inline(always)]
    pub(crate) fn prefetch_corners(&self, i: usize, positions: bool) {
        let Some(tri) = self.triangles.get(i) else {
            return;
        };
        if !positions {
            crate::simd::prefetch(tri);
            return;
        }
        for &v in tri {
            if let Some(p) = self.positions.get(v as usize) {
                crate::simd::prefetch(p);
            }
        }
    }

    /// Bytes of the vertex and index buffers.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.positions.len() * 12 + self.triangles.len() * 12
    }
}

impl Primitives for TriangleMesh {
    #[inline]
    fn len(&self) -> usize {
        self.triangles.len()
    }
    #[inline]
    fn bounds(&self, i: u32) -> Aabb {
        triangle_hit_bounds(self.corners(i))
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let [a, b, c] = self.corners(i);
        intersect_triangle(ray, tmax, a, b, c).map(PrimHit::from)
    }
    #[inline(always)]
    fn intersect_packet(
        &self,
        i: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        out: &mut [PrimHit; LANES],
    ) -> u32 {
        packet::triangle(packet, self.corners(i), lanes, tmax, out)
    }
    fn clip(&self, i: u32, within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
        clip_triangle(self.corners(i), within, axis, pos)
    }
    fn normal(&self, i: u32, _ray: &Ray, _hit: &PrimHit) -> Vec3 {
        let [a, b, c] = self.corners(i);
        triangle_normal(a, b, c)
    }
    fn reorder(&mut self, order: &[u32]) -> bool {
        self.triangles = permuted(&self.triangles, order);
        true
    }
}

/// Lanes of a primitive block: the most primitives
/// [`Primitives::intersect_block`] tests at once.
pub const BLOCK: usize = 8;

/// Triangles stored by their corners and the index the user gave each, 40
/// bytes a triangle, as nine rows of floats (corner × axis,
/// structure-of-arrays) and a row of indices, cut into groups of 8
/// triangles: no index buffer to chase, and once a BVH scene has put them
/// in leaf order, a leaf's triangles are consecutive lanes of each row,
/// tested together by the SIMD kernel (Wald et al., "Embree", 2014, keep
/// leaves in the same form). The fastest layout for ray queries, at the
/// price of a copy of the mesh.
///
/// A group's 9 rows of 8 lanes lie together (288 bytes), so a block test
/// reads one or two groups' consecutive cache lines. With each row
/// spanning all triangles, it read nine rows far apart: nine cache lines
/// or more in nine memory pages a block. Grouped, `bvh8` traced bunny00's
/// random rays 3.95–4.30 → 4.45–4.58 Mrays/s (one thread, pinned, four
/// alternations) for 20 more instructions a ray (the second loads and
/// blends of blocks that straddle two groups).
///
/// The index row ([`Self::index`], kept through [`Primitives::reorder`])
/// spares a scene in leaf order its own permutation from stored to given
/// indices, which a hit looked up in another array: on random rays that
/// lookup missed the cache half the time, where the index row lies
/// right after the group's last corner row, which the hit's block test
/// has just loaded, in the same cache line (groups start on one). The
/// same bytes in all (4 a triangle moved from the permutation to the
/// rows). `raymesh-ab --accel bvh8` against the
/// separate permutation, closest / any-hit: random rays one by one
/// bunny00 1.08–1.10 / 1.10–1.11, the dragon 1.05–1.06 / 1.02–1.08, UV
/// spheres of 600K triangles 1.16–1.19 / 1.19–1.22 and 2M 1.16 / 1.22; diffuse and primary
/// rays, one by one or in packets, 0.97–1.02; streams of random rays
/// (`--stream`) 250K 0.90 / 0.97, 600K 0.96 / 1.01, 2M 0.97 / 1.04: with
/// twelve rays in flight a stream hides the permutation's misses, and
/// its closest hits feel the rows' extra tenth.
#[derive(Clone, Debug, Default)]
pub struct Triangles {
    /// In the groups' floats ([`Self::data`]), triangle `i`'s coordinate
    /// `r` (`3 * corner + axis`) is `data[80 * (i / 8) + 8 * r + i % 8]`,
    /// and its index (as [`Self::index`] gives it) the bits of `data[80 *
    /// (i / 8) + 72 + i % 8]` (`f32::from_bits`: moved and copied, never
    /// computed with, a float keeps its bits); one zeroed group follows the last, so that a
    /// block's loads past its lanes never read past the end (see
    /// [`crate::simd::block_at`]). One allocation, so that one bounds
    /// check covers a block's loads. On huge pages where the system has
    /// them (see [`crate::pages`]).
    groups: Pages<Group>,
    len: usize,
}

/// One group of [`Triangles`]' rows: [`GROUP`] floats, 320 bytes, aligned
/// to a cache line, so that a group is exactly five lines and the index
/// row shares its line with the last corner row: a hit's index is read
/// from a line its block test loaded. In a `Vec<f32>` (16 bytes past a
/// line, as glibc placed large ones) its last four lanes lay in a sixth
/// line, which the test does not load. `raymesh-ab --accel bvh8`, random
/// rays on a 600K-triangle UV sphere, each build the other's baseline:
/// one by one 1.07–1.10 (closest and any-hit), streams 1.05–1.09;
/// bunny00 and the dragon, whose rows sit in the L2 cache, 0.92–1.05.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
struct Group([f32; GROUP]);

const _: () = assert!(std::mem::size_of::<Group>() == 4 * GROUP);
const _: () = assert!(std::mem::align_of::<Group>() == 64);

impl Triangles {
    /// The grouped rows, for the kernels' tests.
    #[cfg(all(test, target_arch = "aarch64", target_feature = "neon"))]
    pub(crate) fn rows(&self) -> &[f32] {
        self.data()
    }

    /// The rows as one run of floats (see the field's layout).
    #[inline(always)]
    fn data(&self) -> &[f32] {
        bytemuck::cast_slice(&self.groups)
    }
}

/// Triangles ahead of the one it gathers that an indexed mesh's gather in
/// a given order ([`Triangles::from_mesh_in_order`], a BVH's leaf order)
/// asks the CPU to fetch the positions of, and twice as far the corner
/// indices of: it reads both wherever they lie, and waited on each. A
/// 2M-triangle UV sphere on one thread, against the gather without it
/// alternated in one process, 15 rounds each, medians: in the sphere's
/// own vertex order 72 -> 62 ms in one run and 72 -> 69 in another (8
/// and 32 ahead gave the same), its vertices shuffled 104 -> 76 and 118
/// -> 82 ms. In the mesh's own order ([`Triangles::from_mesh`]) it paid
/// only with shuffled vertices (103 -> 75 ms) and cost 9% in the
/// sphere's order (54 -> 59 ms), where the indices, read in order, lead
/// the CPU to the positions on its own: not used there.
const GATHER_AHEAD: usize = 16;

/// The row of a group of [`Triangles`] that holds the triangles' indices,
/// after the nine corner rows.
const INDEX_ROW: usize = 9;
const _: () = assert!(GROUP == (INDEX_ROW + 1) * GROUP_SLOTS);

/// Where triangle `i`'s coordinate `r` (or, `r` = [`INDEX_ROW`], index)
/// lies in [`Triangles`]' data.
#[inline(always)]
fn slot_at(i: usize, r: usize) -> usize {
    (i / GROUP_SLOTS) * GROUP + r * GROUP_SLOTS + i % GROUP_SLOTS
}

impl Triangles {
    /// Triangles given by their corners.
    #[must_use]
    pub fn from_corners(corners: &[[Vec3; 3]]) -> Self {
        Self::gather(corners.len(), |i| corners[i], |i| i as u32, |_| {})
    }

    /// The corners of an indexed mesh's triangles, in the mesh's order.
    ///
    /// Gathers the rows in parallel, with no copy of the corners in
    /// between: the peak is the mesh plus the rows.
    #[must_use]
    pub fn from_mesh(mesh: &TriangleMesh) -> Self {
        // No prefetching (see `GATHER_AHEAD`): in the mesh's own order it
        // cost 9% where the vertices come in about the triangles' order.
        Self::gather(mesh.len(), |i| mesh.corners(i as u32), |i| i as u32, |_| {})
    }

    /// The corners of an indexed mesh's triangles in the order `order`
    /// (`stored[k]` is the mesh's triangle `order[k]`): a BVH's leaf order,
    /// gathered straight from the mesh, so that no copy in the mesh's order
    /// is made and then permuted.
    #[must_use]
    pub fn from_mesh_in_order(mesh: &TriangleMesh, order: &[u32]) -> Self {
        let ahead = |k: usize| {
            if let Some(&t) = order.get(k + 2 * GATHER_AHEAD) {
                mesh.prefetch_corners(t as usize, false);
            }
            if let Some(&t) = order.get(k + GATHER_AHEAD) {
                mesh.prefetch_corners(t as usize, true);
            }
        };
        Self::gather(order.len(), |k| mesh.corners(order[k]), |k| order[k], ahead)
    }

    /// `len` triangles, triangle `i`'s corners given by `corners(i)` and
    /// its index by `index(i)`, each group made in parallel and written
    /// once, in place, each task a run of whole groups: every triangle's
    /// corners are fetched once (from an indexed mesh: three indices and three
    /// positions, wherever they lie) and written to one run of memory.
    /// `ahead(i)` is called just before `corners(i)`, for prefetching what
    /// later triangles read ([`GATHER_AHEAD`]).
    fn gather(
        len: usize,
        corners: impl Fn(usize) -> [Vec3; 3] + Sync,
        index: impl Fn(usize) -> u32 + Sync,
        ahead: impl Fn(usize) + Sync,
    ) -> Self {
        /// Triangles a task fills at least: whole groups.
        const RUN: usize = 4096;
        const { assert!(RUN.is_multiple_of(GROUP_SLOTS)) };
        // Made in parallel, each group written once, in place (see
        // `PagesMut::from_fn_par`): `vec![group; n]` of a type of our own
        // is filled element by element on the calling thread before the
        // tasks start, a pass over the whole array that no other thread
        // shares (the pig's gather took 0.114 ms at one thread, 0.116 at
        // two, against 0.095 and 0.096 in parallel).
        let groups = PagesMut::from_fn_par(len.div_ceil(GROUP_SLOTS) + 1, RUN / GROUP_SLOTS, |g| {
            // A group's rows are filled in registers and stored whole:
            // each coordinate written to its slot of the array took a
            // bounds check and the slot's arithmetic (82 instructions
            // a triangle on bunny00 by callgrind). The group past the
            // last triangle (and a last group's unused lanes) stay
            // zero.
            let first = g * GROUP_SLOTS;
            let n = GROUP_SLOTS.min(len.saturating_sub(first));
            let mut rows = [[0.0f32; GROUP_SLOTS]; GROUP / GROUP_SLOTS];
            for k in 0..n {
                ahead(first + k);
                let c = corners(first + k);
                for (r, row) in rows[..INDEX_ROW].iter_mut().enumerate() {
                    row[k] = c[r / 3][r % 3];
                }
                rows[INDEX_ROW][k] = f32::from_bits(index(first + k));
            }
            let mut group = Group([0.0; GROUP]);
            group.0.copy_from_slice(rows.as_flattened());
            group
        });
        Self {
            groups: groups.into(),
            len,
        }
    }

    /// The corners of triangle `i`.
    #[inline(always)]
    #[must_use]
    pub fn corners(&self, i: u32) -> [Vec3; 3] {
        let i = i as usize;
        assert!(i < self.len);
        let data = self.data();
        let r = |k: usize| data[slot_at(i, k)];
        [
            Vec3::new(r(0), r(1), r(2)),
            Vec3::new(r(3), r(4), r(5)),
            Vec3::new(r(6), r(7), r(8)),
        ]
    }

    /// The index the user gave triangle `i` (its place in the mesh or the
    /// list it was made from), which reordering keeps.
    #[inline(always)]
    #[must_use]
    pub fn index(&self, i: u32) -> u32 {
        let i = i as usize;
        assert!(i < self.len);
        self.data()[slot_at(i, INDEX_ROW)].to_bits()
    }

    /// Bytes of the rows.
    #[must_use]
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(&*self.groups)
    }
}

impl Primitives for Triangles {
    const BLOCK_TEST: bool = true;
    const STORES_INDEX: bool = true;
    #[inline(always)]
    fn stored_index(&self, k: u32) -> u32 {
        self.index(k)
    }
    #[inline]
    fn len(&self) -> usize {
        self.len
    }
    #[inline]
    fn bounds(&self, i: u32) -> Aabb {
        triangle_hit_bounds(self.corners(i))
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let [a, b, c] = self.corners(i);
        intersect_triangle(ray, tmax, a, b, c).map(PrimHit::from)
    }
    #[inline(always)]
    fn intersect_block(&self, first: u32, count: u32, ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        let count = (count as usize).min(BLOCK);
        let first = first as usize;
        assert!(first + count <= self.len);
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has_avx2() {
            let block = crate::simd::triangles8(self.data(), first, count, ray, tmax);
            return redo_lanes(self, |k| (first + k) as u32, block, ray, tmax);
        }
        #[cfg(all(target_arch = "aarch64", target_feature = "neon"))]
        if crate::simd::simd_enabled() {
            let block = crate::neon::triangles8(self.data(), first, count, ray, tmax);
            return redo_lanes(self, |k| (first + k) as u32, block, ray, tmax);
        }
        let mut out = BlockHits::default();
        let mask = intersect_each(self, |k| (first + k) as u32, 0..count, ray, tmax, &mut out);
        (mask, out)
    }
    #[inline(always)]
    fn block_ray(&self, ray: &Ray) -> BlockRay {
        BlockRay::new(ray)
    }
    #[inline(always)]
    fn prefetch_block(&self, first: u32) {
        // The block's lanes in each of the nine rows: the group's five
        // cache lines, and the next group's first, which a block that
        // straddles two takes its last lanes from.
        let (at, _) = block_at(first as usize, 1);
        for off in [0, 16, 32, 48, 64, 79] {
            crate::simd::prefetch_at(self.data(), at + off);
        }
    }
    #[inline(always)]
    fn intersect_block_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        first: u32,
        count: u32,
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        #[cfg(target_arch = "x86_64")]
        {
            let count = (count as usize).min(BLOCK);
            let first = first as usize;
            assert!(first + count <= self.len);
            let block = crate::simd::triangles8_pre(avx, self.data(), first, count, pre, tmax);
            redo_lanes(self, |k| (first + k) as u32, block, ray, tmax)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (avx, pre);
            self.intersect_block(first, count, ray, tmax)
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect_block_rays<'r>(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        rays: u32,
        pre: &[BlockRay; crate::bvh::GROUP],
        _ray: impl Fn(usize) -> &'r Ray,
        tmax: impl Fn(usize) -> f32,
        classes: &[u32; crate::simd::AXIS_CLASSES],
        each: impl FnMut(usize, u32, BlockHits),
    ) {
        let count = (count as usize).min(BLOCK);
        let first = first as usize;
        assert!(first + count <= self.len);
        let data = self.data();
        crate::simd::triangles8_rays(avx, data, first, count, rays, pre, classes, tmax, each);
    }
    // Elsewhere the default: the portable block test of each lane's ray.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect_block_lanes(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        p: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        mut each: impl FnMut(usize, u32, BlockHits),
    ) {
        let count = (count as usize).min(BLOCK);
        let first = first as usize;
        assert!(first + count <= self.len);
        crate::simd::triangles8_lanes(
            avx,
            self.data(),
            first,
            count,
            p,
            lanes,
            tmax,
            |i, hit, redo, hits| {
                // The lane's `Ray` only for lanes to redo (which the AVX2
                // kernel never leaves): from rows, rays are made on demand.
                if redo == 0 {
                    each(i, hit, hits);
                } else {
                    let block = (hit, redo, hits);
                    let (hit, hits) =
                        redo_lanes(self, |k| (first + k) as u32, block, p.ray(i), tmax[i]);
                    each(i, hit, hits);
                }
            },
        );
    }
    #[inline(always)]
    fn intersect_ids_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        ids: &[u32],
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        let ids = &ids[..ids.len().min(BLOCK)];
        #[cfg(target_arch = "x86_64")]
        if let Some(block) =
            crate::simd::triangles8_list_pre(avx, self.data(), self.len, ids, pre, tmax)
        {
            return redo_lanes(self, |k| ids[k], block, ray, tmax);
        }
        // Ids out of range, or rows that do not hold the triangles: what
        // the plain test does with them.
        let _ = (avx, pre);
        self.intersect_ids(ids, ray, tmax)
    }
    #[inline(always)]
    fn intersect_ids(&self, ids: &[u32], ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        let ids = &ids[..ids.len().min(BLOCK)];
        #[cfg(target_arch = "x86_64")]
        if crate::simd::has_avx2() {
            // The block's rows built in registers from the listed
            // triangles' coordinates (see `triangles8_list`).
            if let Some(block) = crate::simd::triangles8_list(self.data(), self.len, ids, ray, tmax)
            {
                return redo_lanes(self, |k| ids[k], block, ray, tmax);
            }
        }
        let mut out = BlockHits::default();
        let mask = intersect_each(self, |k| ids[k], 0..ids.len(), ray, tmax, &mut out);
        (mask, out)
    }
    #[inline(always)]
    fn intersect_packet(
        &self,
        i: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        out: &mut [PrimHit; LANES],
    ) -> u32 {
        packet::triangle(packet, self.corners(i), lanes, tmax, out)
    }
    #[inline(always)]
    fn intersect_packet_run(
        &self,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        packet::triangle_run(
            packet,
            first..first + count,
            |i| self.corners(i),
            lanes,
            tmax,
            offer,
        );
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect_packet_tris(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        ends: bool,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        let (first, count) = (first as usize, count as usize);
        assert!(first + count <= self.len);
        crate::simd::packet_tris(
            avx,
            self.data(),
            first,
            count,
            packet,
            lanes,
            tmax,
            |s, hit, redo, hits, tmax| {
                let prim = s as u32;
                let mut m = hit;
                while m != 0 {
                    let k = m.trailing_zeros() as usize;
                    m &= m - 1;
                    offer(k, prim, hits.get(k), tmax);
                }
                let redone = if redo == 0 {
                    0
                } else {
                    redo_packet_lanes(self, prim, packet, redo, tmax, offer)
                };
                // Any-hit lanes end at their first hit.
                if ends {
                    hit | redone
                } else {
                    0
                }
            },
        );
    }
    fn clip(&self, i: u32, within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
        clip_triangle(self.corners(i), within, axis, pos)
    }
    fn normal(&self, i: u32, _ray: &Ray, _hit: &PrimHit) -> Vec3 {
        let [a, b, c] = self.corners(i);
        triangle_normal(a, b, c)
    }
    fn reorder(&mut self, order: &[u32]) -> bool {
        if order.len() != self.len {
            // Some triangles twice (spatial splits): new rows.
            *self = Self::gather(
                order.len(),
                |k| self.corners(order[k]),
                |k| self.index(order[k]),
                |_| {},
            );
            return true;
        }
        // One row at a time: the copy costs one row of memory, not ten.
        for r in 0..GROUP / GROUP_SLOTS {
            let data = self.data();
            let row: Vec<f32> = order
                .par_iter()
                .map(|&i| data[slot_at(i as usize, r)])
                .collect();
            self.groups.modify(|groups| {
                groups
                    .par_iter_mut()
                    .zip(row.par_chunks(GROUP_SLOTS))
                    .for_each(|(group, lanes)| {
                        group.0[r * GROUP_SLOTS..][..lanes.len()].copy_from_slice(lanes);
                    });
            });
        }
        true
    }
}

/// A list of spheres.
#[derive(Clone, Debug, Default)]
pub struct Spheres(pub Vec<Sphere>);

impl Primitives for Spheres {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        self.0[i as usize].bounds()
    }
    #[inline]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let s = self.0[i as usize];
        intersect_sphere(ray, tmax, s.center, s.radius).map(PrimHit::from)
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        self.0[i as usize].normal_at(ray.at(hit.t))
    }
    fn reorder(&mut self, order: &[u32]) -> bool {
        self.0 = permuted(&self.0, order);
        true
    }
}

/// One primitive of a mixed list.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A triangle by its corners.
    Triangle([Vec3; 3]),
    /// A sphere.
    Sphere(Sphere),
}

/// Triangles and spheres mixed in one list.
#[derive(Clone, Debug, Default)]
pub struct Shapes(pub Vec<Shape>);

impl Primitives for Shapes {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        match &self.0[i as usize] {
            Shape::Triangle(corners) => triangle_hit_bounds(*corners),
            Shape::Sphere(s) => s.bounds(),
        }
    }
    #[inline]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        match &self.0[i as usize] {
            Shape::Triangle([a, b, c]) => {
                intersect_triangle(ray, tmax, *a, *b, *c).map(PrimHit::from)
            }
            Shape::Sphere(s) => intersect_sphere(ray, tmax, s.center, s.radius).map(PrimHit::from),
        }
    }
    fn clip(&self, i: u32, within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
        match &self.0[i as usize] {
            Shape::Triangle(corners) => clip_triangle(*corners, within, axis, pos),
            Shape::Sphere(_) => within.split(axis, pos),
        }
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        match &self.0[i as usize] {
            Shape::Triangle([a, b, c]) => triangle_normal(*a, *b, *c),
            Shape::Sphere(s) => s.normal_at(ray.at(hit.t)),
        }
    }
    fn reorder(&mut self, order: &[u32]) -> bool {
        self.0 = permuted(&self.0, order);
        true
    }
}

impl<P: Primitives + ?Sized> Primitives for &P {
    const BLOCK_TEST: bool = P::BLOCK_TEST;
    const STORES_INDEX: bool = P::STORES_INDEX;
    #[inline(always)]
    fn stored_index(&self, k: u32) -> u32 {
        (**self).stored_index(k)
    }
    fn len(&self) -> usize {
        (**self).len()
    }
    fn bounds(&self, i: u32) -> Aabb {
        (**self).bounds(i)
    }
    fn clip(&self, i: u32, within: Aabb, axis: usize, pos: f32) -> (Aabb, Aabb) {
        (**self).clip(i, within, axis, pos)
    }
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        (**self).intersect(i, ray, tmax)
    }
    #[inline(always)]
    fn intersect_block(&self, first: u32, count: u32, ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        (**self).intersect_block(first, count, ray, tmax)
    }
    #[inline(always)]
    fn block_ray(&self, ray: &Ray) -> BlockRay {
        (**self).block_ray(ray)
    }
    #[inline(always)]
    fn prefetch_block(&self, first: u32) {
        (**self).prefetch_block(first);
    }
    #[inline(always)]
    fn intersect_block_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        first: u32,
        count: u32,
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        (**self).intersect_block_pre(avx, pre, first, count, ray, tmax)
    }
    #[inline(always)]
    fn intersect_block_lanes(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        p: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        each: impl FnMut(usize, u32, BlockHits),
    ) {
        (**self).intersect_block_lanes(avx, first, count, p, lanes, tmax, each);
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect_block_rays<'r>(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        rays: u32,
        pre: &[BlockRay; crate::bvh::GROUP],
        ray: impl Fn(usize) -> &'r Ray,
        tmax: impl Fn(usize) -> f32,
        classes: &[u32; crate::simd::AXIS_CLASSES],
        each: impl FnMut(usize, u32, BlockHits),
    ) {
        (**self).intersect_block_rays(avx, first, count, rays, pre, ray, tmax, classes, each);
    }
    #[inline(always)]
    fn intersect_ids(&self, ids: &[u32], ray: &Ray, tmax: f32) -> (u32, BlockHits) {
        (**self).intersect_ids(ids, ray, tmax)
    }
    #[inline(always)]
    fn intersect_ids_pre(
        &self,
        avx: Avx2,
        pre: &BlockRay,
        ids: &[u32],
        ray: &Ray,
        tmax: f32,
    ) -> (u32, BlockHits) {
        (**self).intersect_ids_pre(avx, pre, ids, ray, tmax)
    }
    #[inline(always)]
    fn intersect_packet(
        &self,
        i: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &[f32; LANES],
        out: &mut [PrimHit; LANES],
    ) -> u32 {
        (**self).intersect_packet(i, packet, lanes, tmax, out)
    }
    #[inline(always)]
    fn intersect_packet_run(
        &self,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        (**self).intersect_packet_run(first, count, packet, lanes, tmax, offer);
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect_packet_tris(
        &self,
        avx: Avx2,
        first: u32,
        count: u32,
        packet: &Packet8,
        lanes: u32,
        ends: bool,
        tmax: &mut [f32; LANES],
        offer: &mut impl FnMut(usize, u32, PrimHit, &mut [f32; LANES]),
    ) {
        (**self).intersect_packet_tris(avx, first, count, packet, lanes, ends, tmax, offer);
    }
    fn normal(&self, i: u32, ray: &Ray, hit: &PrimHit) -> Vec3 {
        (**self).normal(i, ray, hit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The grouped rows give back every triangle's corners and index,
        /// whatever the count (partial last group, none), after a
        /// reordering, and after one that repeats triangles (spatial
        /// splits) on top of it: the indices are the first list's.
        #[test]
        fn triangles_keep_their_corners(
            coords in proptest::collection::vec(-1e3f32..1e3, 0..40 * 9),
            shuffle in any::<u64>(),
        ) {
            let corners: Vec<[Vec3; 3]> = coords
                .chunks_exact(9)
                .map(|c| [0, 3, 6].map(|k| Vec3::new(c[k], c[k + 1], c[k + 2])))
                .collect();
            let n = corners.len();
            let mut tris = Triangles::from_corners(&corners);
            prop_assert_eq!(tris.len, n);
            for (i, c) in corners.iter().enumerate() {
                prop_assert_eq!(tris.corners(i as u32), *c);
                prop_assert_eq!(tris.index(i as u32), i as u32);
            }
            // A permutation from the seed (a multiplicative shuffle).
            let mut order: Vec<u32> = (0..n as u32).collect();
            let mut x = shuffle | 1;
            for i in (1..n).rev() {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                order.swap(i, (x >> 33) as usize % (i + 1));
            }
            prop_assert!(tris.reorder(&order));
            for (k, &i) in order.iter().enumerate() {
                prop_assert_eq!(tris.corners(k as u32), corners[i as usize]);
                prop_assert_eq!(tris.index(k as u32), i);
            }
            // Repeats: every slot's triangle, then the first again.
            let twice: Vec<u32> = (0..n as u32).chain((n > 0).then_some(0)).collect();
            let before = tris.clone();
            prop_assert!(tris.reorder(&twice));
            prop_assert_eq!(tris.len, twice.len());
            for (k, &i) in twice.iter().enumerate() {
                prop_assert_eq!(tris.corners(k as u32), before.corners(i));
                prop_assert_eq!(tris.index(k as u32), order[i as usize]);
            }
        }
    }

    /// Rows gathered from an indexed mesh in a given order, over several
    /// of the gather's parallel runs and a partial last group: each slot
    /// holds its triangle's corners and mesh index, and every float past
    /// the last triangle stays zero (the block kernels read whole groups).
    #[test]
    fn rows_gather_in_order_across_runs() {
        let mut next = crate::test_util::xorshift(0x0bad_5eed);
        for n in [0, 1, 8, 9, 4_096, 4_099, 9_003] {
            let positions: Vec<Vec3> = (0..n + 2)
                .map(|_| Vec3::new(next(), next(), next()) * 100.0)
                .collect();
            let triangles: Vec<[u32; 3]> = (0..n as u32).map(|i| [i, i + 1, i + 2]).collect();
            let mesh = TriangleMesh::new(positions, triangles);
            let order: Vec<u32> = (0..n as u32)
                .map(|k| (k * 7_919) % n.max(1) as u32)
                .collect();
            let rows = Triangles::from_mesh_in_order(&mesh, &order);
            assert_eq!(rows.len, n);
            for (k, &i) in order.iter().enumerate() {
                assert_eq!(rows.corners(k as u32), mesh.corners(i), "n {n}, slot {k}");
                assert_eq!(rows.index(k as u32), i, "n {n}, slot {k}");
            }
            let used: std::collections::HashSet<usize> = (0..n)
                .flat_map(|k| (0..=INDEX_ROW).map(move |r| slot_at(k, r)))
                .collect();
            for (at, &x) in rows.data().iter().enumerate() {
                assert!(used.contains(&at) || x == 0.0, "n {n}: float {at} is {x}");
            }
            // The larger ones on a map (from 64 KiB in these tests).
            if cfg!(target_os = "linux") {
                assert_eq!(rows.groups.is_mapped(), n >= 4_096, "n {n}");
            }
            // The gather's prefetch hint takes any index, in range or not.
            for i in [n, n + 2 * GATHER_AHEAD, usize::MAX] {
                mesh.prefetch_corners(i, false);
                mesh.prefetch_corners(i, true);
            }
        }
        // And a mesh whose public fields disagree (an index past the
        // positions): the hint skips what is not there.
        let broken = TriangleMesh {
            positions: vec![Vec3::ZERO],
            triangles: vec![[0, 5, u32::MAX]],
        };
        broken.prefetch_corners(0, true);
    }
}
