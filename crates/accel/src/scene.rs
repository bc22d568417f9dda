//! Primitives plus a structure: the lecture's Surface interface.

#[cfg(target_arch = "x86_64")]
use crate::bvh::GroupLeaf;
use crate::bvh::WideBvh;
use crate::simd::avx_run;
#[cfg(target_arch = "x86_64")]
use crate::simd::{BlockRay, AXIS_CLASSES};
use crate::{
    packet::{Packet8, PacketLeaf, LANES},
    prims::BLOCK,
    Accel, AccelKind, AccelStats, Avx2, BlockHits, BuildConfig, Bvh, Bvh4, Bvh8, Clip, CountStats,
    Grid, KdTree, NoStats, PrimHit, Primitives, RayCounter, TriangleMesh, Triangles,
};
use raymesh_geometry::{Aabb, Ray, Rays8, Vec3};
use rayon::prelude::*;
use std::time::Instant;

/// The closest hit of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Index of the primitive hit.
    pub prim: u32,
    /// Instance hit, in an instanced scene ([`crate::Instances`]); 0 otherwise.
    pub instance: u32,
    /// First surface coordinate (weight of a triangle's 2nd corner).
    pub u: f32,
    /// Second surface coordinate (weight of a triangle's 3rd corner).
    pub v: f32,
    /// Unit geometric normal, as the primitive defines it (not flipped toward the ray).
    pub normal: Vec3,
}

/// A hit without its normal: what a ray-casting record holds
/// (`../shared/BENCH.md`'s `t, prim, u, v`). [`Scene::intersect_bare`]
/// and [`Scene::any_hit_bare`] make one without computing the normal a
/// [`Hit`] carries (the triangle's corners read again, a cross product
/// and a square root).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BareHit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Index of the primitive hit.
    pub prim: u32,
    /// First surface coordinate (weight of a triangle's 2nd corner).
    pub u: f32,
    /// Second surface coordinate (weight of a triangle's 3rd corner).
    pub v: f32,
}

impl From<Hit> for BareHit {
    fn from(h: Hit) -> Self {
        Self {
            t: h.t,
            prim: h.prim,
            u: h.u,
            v: h.v,
        }
    }
}

/// What anything a ray can hit answers: the lecture's Surface.
pub trait Surface: Send + Sync {
    /// Bounds of the whole surface.
    fn bounds(&self) -> Aabb;
    /// The closest hit within the ray's interval: least `t`, ties to the least primitive index.
    fn intersect(&self, ray: &Ray) -> Option<Hit>;
    /// Whether anything is hit within the ray's interval (for shadow rays).
    fn occluded(&self, ray: &Ray) -> bool;
    /// The closest hits of eight rays: [`Surface::intersect`] of each.
    /// Structures that trace coherent rays together as a packet (a
    /// [`Scene`] over a wide BVH) override it, with the same results.
    fn intersect8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        rays.each_ref().map(|r| self.intersect(r))
    }
    /// Whether each of eight rays hits anything: [`Surface::occluded`] of
    /// each. A [`Scene`] over a BVH traces coherent rays (shadow rays of
    /// neighbouring pixels toward one light) together, with the same
    /// answers.
    fn occluded8(&self, rays: &[Ray; LANES]) -> [bool; LANES] {
        rays.each_ref().map(|r| self.occluded(r))
    }
    /// The closest hits of many rays: `out[i]` is [`Surface::intersect`]
    /// of `rays[i]`. Structures that trace a stream together (a [`Scene`]
    /// over a BVH: packets of its coherent runs, groups or
    /// interleaving for the rest; [`crate::Instances`] over such scenes)
    /// override it, with the same hits. Panics unless `out` has one entry
    /// per ray.
    fn intersect_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (o, r) in out.iter_mut().zip(rays) {
            *o = self.intersect(r);
        }
    }
    /// Whether each of many rays hits anything: `out[i]` is
    /// [`Surface::occluded`] of `rays[i]` (a renderer's shadow rays
    /// toward one light), overridden as [`Surface::intersect_stream`] is.
    /// Panics unless `out` has one entry per ray.
    fn occluded_stream(&self, rays: &[Ray], out: &mut [bool]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (o, r) in out.iter_mut().zip(rays) {
            *o = self.occluded(r);
        }
    }
    /// [`Surface::intersect`], adding the nodes visited and primitives
    /// tested to `stats` (heat maps use it).
    fn intersect_count(&self, ray: &Ray, stats: &mut CountStats) -> Option<Hit> {
        let _ = stats;
        self.intersect(ray)
    }
}

/// Primitives and the structure built over them.
#[derive(Clone, Debug)]
pub struct Scene<P> {
    prims: P,
    accel: Accel,
    bounds: Aabb,
    build_ms: f64,
    /// Whether the primitives are stored in the structure's leaf order
    /// (a BVH's, or a k-d tree's: [`Accel::leaf_order`]).
    leaf_order: bool,
    /// When they are, and their type does not keep the index the user
    /// gave each ([`Primitives::STORES_INDEX`]): that index for each
    /// stored primitive (what hits report).
    original: Option<Vec<u32>>,
}

/// A structure of `kind` other than a BVH over `n` primitives (the box of
/// primitive `i` is `bounds(i)`), with the union of their boxes.
fn build_not_bvh(
    kind: AccelKind,
    n: usize,
    bounds: &(dyn Fn(u32) -> Aabb + Sync),
    clip: &Clip<'_>,
    config: &BuildConfig,
) -> (Accel, Aabb) {
    if kind == AccelKind::Grid {
        // The grid asks for the boxes in each pass instead of keeping them.
        let (grid, b) = Grid::build_by(n, bounds, Some(clip), config);
        return (Accel::Grid(grid), b);
    }
    let boxes: Vec<Aabb> = (0..n as u32).into_par_iter().map(bounds).collect();
    let b = boxes
        .par_iter()
        .copied()
        .reduce(|| Aabb::EMPTY, Aabb::union);
    let accel = if kind == AccelKind::KdTree {
        Accel::KdTree(KdTree::build_clipped(&boxes, clip, config))
    } else {
        Accel::build(kind, &boxes, config)
    };
    (accel, b)
}

impl<P: Primitives> Scene<P> {
    /// Builds the structure of `kind` with default settings.
    #[must_use]
    pub fn build(prims: P, kind: AccelKind) -> Self {
        Self::build_with(prims, kind, &BuildConfig::default())
    }

    /// Builds the structure of `kind` with the given settings; the build
    /// time counts the boxes' computation and, for a BVH, putting the
    /// primitives in leaf order (when their type can be reordered).
    #[must_use]
    pub fn build_with(prims: P, kind: AccelKind, config: &BuildConfig) -> Self {
        let start = Instant::now();
        let config = &leaf_blocks::<P>(kind, config);
        let n = prims.len();
        // A BVH's root box is the union of the primitives' boxes: the
        // scene's box, with no array of boxes made.
        let clip = |i, within, axis, pos| prims.clip(i, within, axis, pos);
        let bounds_of = |i| prims.bounds(i);
        let built = Accel::build_bvh_clipped(kind, n, &bounds_of, &clip, config);
        let (mut accel, bounds) = match built {
            Some(a) => {
                let b = a.bounds();
                (a, b)
            }
            None => build_not_bvh(kind, n, &bounds_of, &clip, config),
        };
        let mut prims = prims;
        let mut leaf_order = false;
        let mut original = None;
        // A k-d tree's order repeats the primitives its planes cut: worth
        // the copies where a leaf's primitives are tested together.
        let by_leaves = !matches!(accel, Accel::KdTree(_)) || P::BLOCK_TEST;
        if let Some(order) = accel.leaf_order().filter(|_| by_leaves) {
            if prims.reorder(order) {
                leaf_order = true;
                // Taken from the structure either way: primitives that
                // keep their indices need it no more.
                original = accel.take_leaf_order().filter(|_| !P::STORES_INDEX);
            }
        }
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        Self {
            prims,
            accel,
            bounds,
            build_ms,
            leaf_order,
            original,
        }
    }

    /// The primitives, in storage order (see [`Self::original_index`]).
    #[must_use]
    pub fn prims(&self) -> &P {
        &self.prims
    }

    /// The index the user gave the primitive stored at `k`.
    #[inline]
    #[must_use]
    pub fn original_index(&self, k: u32) -> u32 {
        if P::STORES_INDEX {
            return self.prims.stored_index(k);
        }
        self.original.as_ref().map_or(k, |o| o[k as usize])
    }

    /// The structure.
    #[must_use]
    pub fn accel(&self) -> &Accel {
        &self.accel
    }

    /// The structure's figures, with its build time.
    #[must_use]
    pub fn stats(&self) -> AccelStats {
        let s = self.accel.stats();
        // The accelerator counts leaves in blocks; primitives without a
        // block test take one test each, which it cannot count.
        let leaf_tests = s.leaf_tests.filter(|_| P::BLOCK_TEST);
        AccelStats {
            build_ms: self.build_ms,
            bytes: s.bytes + self.original.as_ref().map_or(0, |o| o.len() * 4),
            leaf_tests,
            ..s
        }
    }

    /// The BVH, when the primitives are stored in its leaf order: then a
    /// leaf is a block of consecutive primitives, tested at once with
    /// [`Primitives::intersect_block`].
    fn wide_blocks(&self) -> Option<WideRef<'_>> {
        if !self.leaf_order {
            return None;
        }
        match &self.accel {
            Accel::Bvh(b, _) => Some(WideRef::W2(b)),
            Accel::Bvh4(b) => Some(WideRef::W4(b)),
            Accel::Bvh8(b) => Some(WideRef::W8(b)),
            _ => None,
        }
    }

    /// The k-d tree, when the primitives are stored in its leaf order
    /// ([`KdTree::leaf_order`]): then a leaf is a run of consecutive
    /// slots, tested a block at a time as a BVH's leaves are.
    fn kd_slots(&self) -> Option<&KdTree> {
        match &self.accel {
            Accel::KdTree(k) if k.names_slots() => Some(k),
            _ => None,
        }
    }

    /// Closest hit, counting nodes visited and primitives tested.
    pub fn intersect_counted<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        self.closest(ray, counter)
            .hit()
            .map(|(prim, h)| self.hit(prim, ray, h))
    }

    /// [`Surface::intersect`] without the normal: the same hit, for callers
    /// that record hits rather than shade them (`raymesh raycast`).
    pub fn intersect_bare(&self, ray: &Ray) -> Option<BareHit> {
        self.closest(ray, &mut NoStats)
            .hit()
            .map(|(prim, h)| self.bare(prim, h))
    }

    /// [`Self::any_hit`] without the normal: the same hit.
    pub fn any_hit_bare(&self, ray: &Ray) -> Option<BareHit> {
        self.first_hit(ray, &mut NoStats)
            .hit()
            .map(|(prim, h)| self.bare(prim, h))
    }

    /// [`Self::intersect_bare`] of the ray in row `r`, laid out `[ox, oy,
    /// oz, tmin, dx, dy, dz, tmax]` (BENCH.md's rays, as `raymesh rays`
    /// writes them and numpy arrays hold them): the hit of
    /// [`Ray::from_row`], bit for bit, with the ray made inside the
    /// query.
    ///
    /// For callers that hold rays as rows rather than as [`Ray`]s (as
    /// Embree takes its `RTCRay`). Over an 8-wide BVH on a CPU with AVX2
    /// the ray's constants (reciprocal, shear, axes) are then computed in
    /// the walk's SIMD region, compiled for AVX2 or AVX-512, from the row
    /// where it lies, instead of in the caller's code (compiled for
    /// baseline x86-64) and handed over through memory, where a load
    /// wider than the stores that wrote it waits for them to reach the
    /// cache. `raymesh-ab --rows` (rows made into `Ray`s inline in the
    /// timed loop, against this), pig: primary rays 1.03 (closest) and
    /// 1.07 (occlusion), random 1.01 and 1.06 (docs/measurements.md, stop 74).
    pub fn intersect_bare_row(&self, r: &[f32; 8]) -> Option<BareHit> {
        self.closest_row(r)
            .hit()
            .map(|(prim, h)| self.bare(prim, h))
    }

    /// [`Self::closest`] of the ray in row `r`: one instance of the walk
    /// for [`Self::intersect_bare_row`] and the packets' rays that make
    /// no packet ([`Self::packet8_soa`]).
    #[inline(always)]
    fn closest_row(&self, r: &[f32; 8]) -> PackedHit {
        self.closest_made(|| Ray::from_row(r), &mut NoStats)
    }

    /// [`Self::any_hit_bare`] of the ray in row `r`, made inside the
    /// query, as [`Self::intersect_bare_row`]: the same hit.
    pub fn any_hit_bare_row(&self, r: &[f32; 8]) -> Option<BareHit> {
        self.first_hit_row(r)
            .hit()
            .map(|(prim, h)| self.bare(prim, h))
    }

    /// [`Self::occluded`] of the ray in row `r`, made inside the query, as
    /// [`Self::intersect_bare_row`].
    pub fn occluded_row(&self, r: &[f32; 8]) -> bool {
        self.first_hit_row(r).hit().is_some()
    }

    /// [`Self::first_hit`] of the ray in row `r`: one instance of the walk
    /// for [`Self::any_hit_bare_row`], [`Self::occluded_row`] and the
    /// packets' rays that make no packet ([`Self::packet8_soa`]).
    #[inline(always)]
    fn first_hit_row(&self, r: &[f32; 8]) -> PackedHit {
        self.first_hit_made(|| Ray::from_row(r), &mut NoStats)
    }

    /// The closest hit's primitive (in storage order) and hit, packed
    /// ([`PackedHit`]).
    #[inline(always)]
    fn closest<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> PackedHit {
        self.closest_made(|| *ray, counter)
    }

    /// [`Self::closest`] of the ray `make` makes: in the 8-wide walk's
    /// SIMD region where there is one (see [`Self::intersect_bare_row`];
    /// a copy of a ray already made costs nothing there, the copy never
    /// made), else before the walk. Each call site's `make` is a type of
    /// its own, so each instantiates the walk once, as the walk's kernel
    /// needs to be inlined (see [`Self::closest_avx2`]).
    #[inline(always)]
    fn closest_made<C: RayCounter>(&self, make: impl Fn() -> Ray, counter: &mut C) -> PackedHit {
        if let (Some(WideRef::W8(bvh)), Some(avx)) = (self.wide_blocks(), Avx2::detect()) {
            return self.closest_avx2(bvh, avx, make, counter);
        }
        let ray = &make();
        if let (Some(WideRef::W4(bvh)), Some(avx)) = (self.wide_blocks(), Avx2::detect()) {
            return self.wide4_avx2::<false, C>(bvh, avx, ray, counter);
        }
        if let (Accel::Grid(_) | Accel::KdTree(_), Some(avx)) = (&self.accel, Avx2::detect()) {
            return self.lists_avx2::<false, C>(avx, ray, counter);
        }
        self.closest_general(ray, counter)
    }

    /// [`Self::intersect_counted`] on every path but [`Self::closest_avx2`]'s:
    /// a function of its own, so that each compiles as if the other were
    /// not there (sharing one function, the k-d tree's walk took 4% more
    /// instructions).
    #[inline(never)]
    fn closest_general<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> PackedHit {
        let mut best: Option<(u32, PrimHit)> = None;
        let mut tmax = ray.tmax();
        // The binary BVH apart, with the leaves it pushes prefetched (as
        // `closest_avx2` does for 8-wide trees): passing the prefetch
        // through `WideRef::traverse_blocks` for every width instead cost
        // the binary walk 37 instructions a ray and 1% (bunny00 random).
        if let Some(WideRef::W2(bvh)) = self.wide_blocks() {
            if !ray.is_valid() {
                return PackedHit::NONE;
            }
            if let Some(avx) = Avx2::detect() {
                // Each leaf in an AVX2 region of its own, the block test
                // inlined there and its ray constants computed once for
                // the ray; the walk itself stays portable code (compiled
                // for AVX2 with the kernel inlined, it took more
                // instructions: its plane indices spilled).
                let pre = self.prims.block_ray(ray);
                bvh.traverse_blocks_prefetching(
                    ray,
                    counter,
                    &mut |first, count| {
                        avx.run(|| {
                            self.leaf_closest_by(first, count, &mut tmax, &mut best, |s, n, t| {
                                self.prims.intersect_block_pre(avx, &pre, s, n, ray, t)
                            })
                        });
                        tmax
                    },
                    &|first| self.prims.prefetch_block(first),
                );
            } else {
                bvh.traverse_blocks_prefetching(
                    ray,
                    counter,
                    &mut |first, count| {
                        self.leaf_closest(ray, first, count, &mut tmax, &mut best);
                        tmax
                    },
                    &|first| self.prims.prefetch_block(first),
                );
            }
        } else if let Some(wide) = self.wide_blocks() {
            wide.traverse_blocks(ray, counter, &mut |first, count| {
                self.leaf_closest(ray, first, count, &mut tmax, &mut best);
                tmax
            });
        } else if let Some(kd) = self.kd_slots() {
            if ray.is_valid() {
                kd.traverse_ranges(ray, counter, &mut |first, count| {
                    self.leaf_closest(ray, first, count, &mut tmax, &mut best);
                    tmax
                });
            }
        } else if !self.accel.traverse_lists(ray, counter, &mut |ids| {
            self.list_closest(ray, ids, &mut tmax, &mut best);
            tmax
        }) {
            self.accel.traverse(ray, counter, &mut |prim| {
                if let Some(h) = self.prims.intersect(prim, ray, tmax) {
                    self.offer(&mut best, &mut tmax, prim, h);
                }
                tmax
            });
        }
        PackedHit::found(best)
    }

    /// The closest hit over an 8-wide BVH on a CPU with AVX2 (the `Avx2`
    /// proof), for [`Self::intersect_counted`]. The walk runs compiled for
    /// AVX2 (under [`Avx2::run`], [`Bvh8::traverse_blocks_avx2`]), so the
    /// block test ([`Primitives::intersect_block_pre`]) inlines into it,
    /// with the ray's constants computed once, in the same AVX2 region.
    /// Where the CPU has AVX-512F and AVX-512VL, the same walk compiled
    /// for them runs instead ([`avx_run`]): the same instructions on the
    /// same lanes, with 32 vector registers, which keep more of the ray's
    /// constants out of memory (`raymesh-ab --accel bvh8` on bunny00 and
    /// the dragon, each build as the other's baseline: closest hits 1–8%
    /// faster, any-hit queries 2–9%). The ray is `make`'s, made inside
    /// the region (see [`Self::closest_made`]); an invalid one misses
    /// there.
    ///
    /// The kernel inlines only while everything between `with_avx2` and
    /// it is `#[inline(always)]` or a closure called from one place: the
    /// binary walk, instantiated for two stack sizes, calls its leaf
    /// closure from two, and there every intrinsic became a call (2.5
    /// times slower). A `bvh8` that slows down that much after an
    /// unrelated change is worth checking for that first.
    #[inline(always)]
    fn closest_avx2<const W: usize, C: RayCounter>(
        &self,
        bvh: &WideBvh<W>,
        avx: Avx2,
        make: impl Fn() -> Ray,
        counter: &mut C,
    ) -> PackedHit {
        let result = avx_run!(avx, || {
            let ray = &make();
            if !ray.is_valid() {
                return PackedHit::NONE;
            }
            let mut best = None;
            let mut tmax = ray.tmax();
            let pre = self.prims.block_ray(ray);
            let done = bvh.traverse_blocks_avx2::<true, C>(
                avx,
                ray,
                counter,
                &mut |first, count| {
                    self.leaf_closest_by(first, count, &mut tmax, &mut best, |s, n, t| {
                        self.prims.intersect_block_pre(avx, &pre, s, n, ray, t)
                    });
                    tmax
                },
                &|first| self.prims.prefetch_block(first),
            );
            PackedHit::new(done, best)
        });
        // A ray the inline stack could not hold walks again, from the start
        // (with counts on, the first try's visits count too).
        if result.is_undone() {
            return self.closest_general(&make(), counter);
        }
        result
    }

    /// [`Self::closest_avx2`] (or, `ANY`, [`Self::any_avx2`]) over a
    /// 4-wide BVH (its node test in SSE, [`crate::simd::slab4`]), the ray
    /// made before: a function of its own for each query, so that the
    /// 8-wide walk's code does not change with it (as
    /// [`Self::lists_avx2`]). Before, `bvh4` walked in portable code, its
    /// node test scalar and each leaf a call.
    #[inline(never)]
    fn wide4_avx2<const ANY: bool, C: RayCounter>(
        &self,
        bvh: &Bvh4,
        avx: Avx2,
        ray: &Ray,
        counter: &mut C,
    ) -> PackedHit {
        if ANY {
            self.any_avx2(bvh, avx, || *ray, counter)
        } else {
            self.closest_avx2(bvh, avx, || *ray, counter)
        }
    }

    /// The closest hit (or, `ANY`, the first hit found) over a grid or a
    /// k-d tree on a CPU with AVX2 (the `Avx2` proof): the walk runs
    /// compiled for AVX2, so that the test of a cell's or a leaf's listed
    /// triangles ([`Primitives::intersect_ids_pre`]) inlines into it, with
    /// the ray's constants made once a ray; from portable code it was a
    /// call a block, which worked out the ray's shear again each time. A
    /// function of its own (as [`Self::closest_general`]), and each walk
    /// in an AVX2 region of its own: one region for both was too large
    /// for LLVM to inline into the functions that set the region up, and
    /// every intrinsic became a call.
    #[inline(never)]
    fn lists_avx2<const ANY: bool, C: RayCounter>(
        &self,
        avx: Avx2,
        ray: &Ray,
        counter: &mut C,
    ) -> PackedHit {
        if !ray.is_valid() {
            return PackedHit::NONE;
        }
        if let Some(kd) = self.kd_slots() {
            return self.kd_blocks_avx2::<ANY, C>(kd, avx, ray, counter);
        }
        // The region around one walk (a macro: the walks' `traverse_lists`
        // are methods of different types).
        macro_rules! region {
            ($walk:expr) => {
                avx_run!(avx, || {
                    let mut best = None;
                    let mut tmax = ray.tmax();
                    let pre = self.prims.block_ray(ray);
                    let test = |b: &[u32], t| self.prims.intersect_ids_pre(avx, &pre, b, ray, t);
                    $walk.traverse_lists(ray, counter, &mut |ids| {
                        if ANY {
                            best = self.list_any_by(ids, ray.tmax(), test);
                            if best.is_some() {
                                f32::NEG_INFINITY
                            } else {
                                ray.tmax()
                            }
                        } else {
                            self.list_closest_by(ids, &mut tmax, &mut best, test);
                            tmax
                        }
                    });
                    PackedHit::found(best)
                })
            };
        }
        match &self.accel {
            Accel::Grid(g) if g.two_level() => region!(crate::grid::Levels::<true>(g)),
            Accel::Grid(g) => region!(crate::grid::Levels::<false>(g)),
            Accel::KdTree(k) => region!(k),
            _ if ANY => self.any_general(ray, counter),
            _ => self.closest_general(ray, counter),
        }
    }

    /// [`Self::lists_avx2`] over a k-d tree whose leaves are runs of slots
    /// ([`Self::kd_slots`]): the walk in an AVX2 region, each leaf tested
    /// a block of consecutive slots at a time with the block kernel
    /// ([`Primitives::intersect_block_pre`]), as a BVH's leaves are, with
    /// no gather by index. A function of its own, as each walk's region
    /// is (see [`Self::lists_avx2`]). The ray must be valid.
    #[inline(never)]
    fn kd_blocks_avx2<const ANY: bool, C: RayCounter>(
        &self,
        kd: &KdTree,
        avx: Avx2,
        ray: &Ray,
        counter: &mut C,
    ) -> PackedHit {
        avx_run!(avx, || {
            let pre = self.prims.block_ray(ray);
            let test = |s, n, t| self.prims.intersect_block_pre(avx, &pre, s, n, ray, t);
            let mut best = None;
            let mut tmax = ray.tmax();
            kd.traverse_ranges(ray, counter, &mut |first, count| {
                if ANY {
                    best = self.leaf_any_by(first, count, ray.tmax(), test);
                    if best.is_some() {
                        f32::NEG_INFINITY
                    } else {
                        ray.tmax()
                    }
                } else {
                    self.leaf_closest_by(first, count, &mut tmax, &mut best, test);
                    tmax
                }
            });
            PackedHit::found(best)
        })
    }

    /// [`Self::closest_avx2`] for any-hit queries, for
    /// [`Self::any_hit_counted`].
    #[inline(always)]
    fn any_avx2<const W: usize, C: RayCounter>(
        &self,
        bvh: &WideBvh<W>,
        avx: Avx2,
        make: impl Fn() -> Ray,
        counter: &mut C,
    ) -> PackedHit {
        let result = avx_run!(avx, || {
            let ray = &make();
            if !ray.is_valid() {
                return PackedHit::NONE;
            }
            let mut found = None;
            let pre = self.prims.block_ray(ray);
            let done = bvh.traverse_blocks_avx2::<false, C>(
                avx,
                ray,
                counter,
                &mut |first, count| {
                    found = self.leaf_any_by(first, count, ray.tmax(), |s, n, t| {
                        self.prims.intersect_block_pre(avx, &pre, s, n, ray, t)
                    });
                    if found.is_some() {
                        f32::NEG_INFINITY
                    } else {
                        ray.tmax()
                    }
                },
                &|_| {},
            );
            PackedHit::new(done, found)
        });
        if result.is_undone() {
            return self.any_general(&make(), counter);
        }
        result
    }

    /// Takes hit `h` of primitive `prim` (with `h.t <= tmax`) as the
    /// closest so far unless it ties the current one at a greater index
    /// than the user gave it: ties go to the least index.
    #[inline(always)]
    fn offer(&self, best: &mut Option<(u32, PrimHit)>, tmax: &mut f32, prim: u32, h: PrimHit) {
        if h.t < *tmax || best.is_none_or(|(b, _)| self.tie_goes_to(prim, b)) {
            *tmax = h.t;
            *best = Some((prim, h));
        }
    }

    /// Whether stored primitive `prim`, hit at the same distance as the
    /// best so far, `best`, was given the lesser index. Out of the leaf
    /// loops: ties are rare, and the two index lookups inlined into every
    /// leaf test cost primary rays' closest hits 2–4%.
    #[cold]
    #[inline(never)]
    fn tie_goes_to(&self, prim: u32, best: u32) -> bool {
        self.original_index(prim) < self.original_index(best)
    }

    /// Tests the leaf of slots `first..first + count` (primitives in leaf
    /// order) for the closest hit within `tmax`, a block at a time, and
    /// offers each hit in slot order against the bound the ones before it
    /// left: what testing one by one gives.
    #[inline(always)]
    fn leaf_closest(
        &self,
        ray: &Ray,
        first: u32,
        count: u32,
        tmax: &mut f32,
        best: &mut Option<(u32, PrimHit)>,
    ) {
        self.leaf_closest_by(first, count, tmax, best, |s, n, t| {
            self.prims.intersect_block(s, n, ray, t)
        });
    }

    /// [`Self::leaf_closest`] with the block test `test(first, count,
    /// tmax)`: [`Primitives::intersect_block`] or its AVX2 form.
    #[inline(always)]
    fn leaf_closest_by(
        &self,
        first: u32,
        count: u32,
        tmax: &mut f32,
        best: &mut Option<(u32, PrimHit)>,
        test: impl Fn(u32, u32, f32) -> (u32, BlockHits),
    ) {
        // A plain loop: `step_by` cost 14 instructions a leaf, and wide
        // leaves are one block.
        let (mut start, end) = (first, first + count);
        while start < end {
            let n = (end - start).min(BLOCK as u32);
            let (mut mask, hits) = test(start, n, *tmax);
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if hits.t[k] <= *tmax {
                    self.offer(best, tmax, start + k as u32, hits.get(k));
                }
            }
            start += BLOCK as u32;
        }
    }

    /// The first hit in the leaf of slots `first..first + count` within
    /// the ray's interval: the least slot of the first block hit.
    #[inline(always)]
    fn leaf_any(&self, ray: &Ray, first: u32, count: u32) -> Option<(u32, PrimHit)> {
        self.leaf_any_by(first, count, ray.tmax(), |s, n, t| {
            self.prims.intersect_block(s, n, ray, t)
        })
    }

    /// [`Self::leaf_any`] with the block test `test(first, count, tmax)`.
    #[inline(always)]
    fn leaf_any_by(
        &self,
        first: u32,
        count: u32,
        tmax: f32,
        test: impl Fn(u32, u32, f32) -> (u32, BlockHits),
    ) -> Option<(u32, PrimHit)> {
        let (mut start, end) = (first, first + count);
        while start < end {
            let n = (end - start).min(BLOCK as u32);
            let (mask, hits) = test(start, n, tmax);
            if mask != 0 {
                let k = mask.trailing_zeros();
                return Some((start + k, hits.get(k as usize)));
            }
            start += BLOCK as u32;
        }
        None
    }

    /// [`Self::leaf_closest`] for a list of primitives (a grid cell's
    /// untested primitives, a k-d tree's leaf over primitives it names): a
    /// block of [`BLOCK`] at a time ([`Primitives::intersect_ids`]), each
    /// hit offered in list order.
    #[inline(always)]
    fn list_closest(
        &self,
        ray: &Ray,
        ids: &[u32],
        tmax: &mut f32,
        best: &mut Option<(u32, PrimHit)>,
    ) {
        self.list_closest_by(ids, tmax, best, |b, t| self.prims.intersect_ids(b, ray, t));
    }

    /// [`Self::list_closest`] with the block test `test(ids, tmax)`:
    /// [`Primitives::intersect_ids`] or its AVX2 form.
    #[inline(always)]
    fn list_closest_by(
        &self,
        ids: &[u32],
        tmax: &mut f32,
        best: &mut Option<(u32, PrimHit)>,
        test: impl Fn(&[u32], f32) -> (u32, BlockHits),
    ) {
        for block in ids.chunks(BLOCK) {
            let (mut mask, hits) = test(block, *tmax);
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if hits.t[k] <= *tmax {
                    self.offer(best, tmax, block[k], hits.get(k));
                }
            }
        }
    }

    /// [`Self::leaf_any`] for a list of primitives: the first in the list
    /// hit within the ray's interval.
    #[inline(always)]
    fn list_any(&self, ray: &Ray, ids: &[u32]) -> Option<(u32, PrimHit)> {
        self.list_any_by(ids, ray.tmax(), |b, t| self.prims.intersect_ids(b, ray, t))
    }

    /// [`Self::list_any`] with the block test `test(ids, tmax)`.
    #[inline(always)]
    fn list_any_by(
        &self,
        ids: &[u32],
        tmax: f32,
        test: impl Fn(&[u32], f32) -> (u32, BlockHits),
    ) -> Option<(u32, PrimHit)> {
        ids.chunks(BLOCK).find_map(|block| {
            let (mask, hits) = test(block, tmax);
            (mask != 0).then(|| {
                let k = mask.trailing_zeros() as usize;
                (block[k], hits.get(k))
            })
        })
    }

    /// Any hit, counting nodes visited and primitives tested.
    pub fn occluded_counted<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> bool {
        // The primitive and its hit only: no `Hit` made, no normal computed.
        self.first_hit(ray, counter).hit().is_some()
    }

    /// The first hit the traversal finds (not necessarily the closest).
    pub fn any_hit(&self, ray: &Ray) -> Option<Hit> {
        self.any_hit_counted(ray, &mut NoStats)
    }

    /// [`Self::any_hit`], counting nodes visited and primitives tested.
    pub fn any_hit_counted<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        self.first_hit(ray, counter)
            .hit()
            .map(|(prim, h)| self.hit(prim, ray, h))
    }

    /// The primitive (in storage order) and hit of [`Self::any_hit_counted`],
    /// packed ([`PackedHit`]).
    #[inline(always)]
    fn first_hit<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> PackedHit {
        self.first_hit_made(|| *ray, counter)
    }

    /// [`Self::first_hit`] of the ray `make` makes, as
    /// [`Self::closest_made`].
    #[inline(always)]
    fn first_hit_made<C: RayCounter>(&self, make: impl Fn() -> Ray, counter: &mut C) -> PackedHit {
        match (self.wide_blocks(), Avx2::detect()) {
            (Some(WideRef::W8(bvh)), Some(avx)) => self.any_avx2(bvh, avx, make, counter),
            (Some(WideRef::W4(bvh)), Some(avx)) => {
                self.wide4_avx2::<true, C>(bvh, avx, &make(), counter)
            }
            (Some(WideRef::W2(bvh)), Some(avx)) => self.any_binary_avx2(bvh, avx, &make(), counter),
            (None, Some(avx)) if matches!(self.accel, Accel::Grid(_) | Accel::KdTree(_)) => {
                self.lists_avx2::<true, C>(avx, &make(), counter)
            }
            _ => self.any_general(&make(), counter),
        }
    }

    /// [`Self::any_hit_counted`] over a binary BVH on a CPU with AVX2:
    /// each leaf tested in an AVX2 region of its own, the block test
    /// inlined there with its ray constants computed once a ray, as
    /// [`Self::closest_general`] tests a binary BVH's leaves for closest
    /// hits. A function of its own, so that the other walks' code does
    /// not change with it.
    #[inline(never)]
    fn any_binary_avx2<C: RayCounter>(
        &self,
        bvh: &crate::Bvh,
        avx: Avx2,
        ray: &Ray,
        counter: &mut C,
    ) -> PackedHit {
        if !ray.is_valid() {
            return PackedHit::NONE;
        }
        let mut found = None;
        let pre = self.prims.block_ray(ray);
        bvh.traverse_blocks(ray, counter, &mut |first, count| {
            found = avx.run(|| {
                self.leaf_any_by(first, count, ray.tmax(), |s, n, t| {
                    self.prims.intersect_block_pre(avx, &pre, s, n, ray, t)
                })
            });
            if found.is_some() {
                f32::NEG_INFINITY
            } else {
                ray.tmax()
            }
        });
        PackedHit::found(found)
    }

    /// [`Self::any_hit_counted`] on every path but [`Self::any_avx2`]'s and
    /// [`Self::any_binary_avx2`]'s,
    /// apart for the same reason as [`Self::closest_general`].
    #[inline(never)]
    fn any_general<C: RayCounter>(&self, ray: &Ray, counter: &mut C) -> PackedHit {
        let mut found: Option<(u32, PrimHit)> = None;
        if let Some(wide) = self.wide_blocks() {
            let mut block = |first: u32, count: u32| {
                found = self.leaf_any(ray, first, count);
                if found.is_some() {
                    f32::NEG_INFINITY
                } else {
                    ray.tmax()
                }
            };
            wide.traverse_blocks_unordered(ray, counter, &mut block);
        } else if let Some(kd) = self.kd_slots() {
            if ray.is_valid() {
                kd.traverse_ranges(ray, counter, &mut |first, count| {
                    found = self.leaf_any(ray, first, count);
                    if found.is_some() {
                        f32::NEG_INFINITY
                    } else {
                        ray.tmax()
                    }
                });
            }
        } else if !self.accel.traverse_lists(ray, counter, &mut |ids| {
            found = self.list_any(ray, ids);
            if found.is_some() {
                f32::NEG_INFINITY
            } else {
                ray.tmax()
            }
        }) {
            self.accel
                .traverse(ray, counter, &mut |prim| match self.prims.intersect(
                    prim,
                    ray,
                    ray.tmax(),
                ) {
                    Some(h) => {
                        found = Some((prim, h));
                        f32::NEG_INFINITY
                    }
                    None => ray.tmax(),
                });
        }
        PackedHit::found(found)
    }

    /// [`Self::bare`] of each lane's hit, if any. A loop: `array::map`
    /// stayed a call into `try_map` compiled apart (4% of `raymesh raycast
    /// --packets`' time on the pig's primary rays).
    #[inline(always)]
    fn bare8(&self, best: [Option<(u32, PrimHit)>; LANES]) -> [Option<BareHit>; LANES] {
        let mut out = [None; LANES];
        for (o, b) in out.iter_mut().zip(best) {
            *o = b.map(|(prim, h)| self.bare(prim, h));
        }
        out
    }

    /// The [`BareHit`] of hit `h` of primitive `prim` (in storage order).
    #[inline]
    fn bare(&self, prim: u32, h: PrimHit) -> BareHit {
        bare_at(self.original_index(prim), h)
    }

    fn hit(&self, prim: u32, ray: &Ray, h: PrimHit) -> Hit {
        self.hit_at(prim, self.original_index(prim), ray, h)
    }

    /// [`Self::hit`] with the primitive's index as given already looked up.
    fn hit_at(&self, prim: u32, index: u32, ray: &Ray, h: PrimHit) -> Hit {
        Hit {
            t: h.t,
            prim: index,
            instance: 0,
            u: h.u,
            v: h.v,
            normal: self.prims.normal(prim, ray, &h),
        }
    }

    /// The closest hits of eight rays, bit for bit what
    /// [`Self::intersect_counted`] gives each. Rays that share their
    /// direction's octant and dominant axis (a camera's neighbouring
    /// pixels) walk a BVH together as one [`Packet8`]: each node and leaf
    /// is fetched once for the eight, its box tested against the eight
    /// rays at once. Other rays, and other structures, are traced one by
    /// one.
    pub fn intersect8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        let best = self.packet8::<false>(rays);
        std::array::from_fn(|i| best[i].map(|(prim, h)| self.hit(prim, &rays[i], h)))
    }

    /// [`Self::intersect8`] without the normals: the same hits.
    pub fn intersect8_bare(&self, rays: &[Ray; LANES]) -> [Option<BareHit>; LANES] {
        self.bare8(self.packet8::<false>(rays))
    }

    /// Any hit of each of eight rays (shadow rays from neighbouring
    /// pixels toward one light): whether [`Self::any_hit`] of each finds
    /// one, and then a hit of that ray within its interval, though not
    /// necessarily the one [`Self::any_hit`] finds first (the packet
    /// visits the nodes in another order). Coherent rays walk a BVH
    /// together as a [`Packet8`] (a wide BVH's children in slot order, a
    /// binary one's nearest first), and each lane drops out at its first
    /// hit; other rays, and other structures, are traced one by one.
    pub fn any_hit8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        let found = self.packet8::<true>(rays);
        std::array::from_fn(|i| found[i].map(|(prim, h)| self.hit(prim, &rays[i], h)))
    }

    /// [`Self::any_hit8`] without the normals: the same hits.
    pub fn any_hit8_bare(&self, rays: &[Ray; LANES]) -> [Option<BareHit>; LANES] {
        self.bare8(self.packet8::<true>(rays))
    }

    /// Whether each of eight rays hits anything: [`Self::any_hit8`]'s
    /// answer without a hit made.
    pub fn occluded8(&self, rays: &[Ray; LANES]) -> [bool; LANES] {
        self.packet8::<true>(rays).map(|f| f.is_some())
    }

    /// [`Self::intersect8`] of eight rays given as rows ([`Rays8`], the
    /// layout of Embree's `RTCRay8`): the same hits as
    /// [`Self::intersect8`] of each lane's [`Rays8::ray`], with the rays'
    /// constants made for the eight lanes at once ([`Rays8::lanes`]).
    pub fn intersect8_soa(&self, rays: &Rays8) -> [Option<Hit>; LANES] {
        let best = self.packet8_soa::<false>(rays);
        std::array::from_fn(|i| best[i].map(|(prim, h)| self.hit(prim, &rays.ray(i), h)))
    }

    /// [`Self::intersect8_soa`] without the normals: the same hits.
    pub fn intersect8_soa_bare(&self, rays: &Rays8) -> [Option<BareHit>; LANES] {
        self.bare8(self.packet8_soa::<false>(rays))
    }

    /// [`Self::any_hit8_bare`] of eight rays given as rows ([`Rays8`]), as
    /// [`Self::intersect8_soa`].
    pub fn any_hit8_soa_bare(&self, rays: &Rays8) -> [Option<BareHit>; LANES] {
        self.bare8(self.packet8_soa::<true>(rays))
    }

    /// [`Self::occluded8`] of eight rays given as rows ([`Rays8`]), as
    /// [`Self::intersect8_soa`].
    pub fn occluded8_soa(&self, rays: &Rays8) -> [bool; LANES] {
        self.packet8_soa::<true>(rays).map(|f| f.is_some())
    }

    /// The primitives (in storage order) and hits of [`Self::intersect8`],
    /// or with `ANY` of [`Self::any_hit8`].
    fn packet8<const ANY: bool>(&self, rays: &[Ray; LANES]) -> [Option<(u32, PrimHit)>; LANES] {
        // Checked, then built in place (see `Packet8::build`).
        let (Some(wide), true) = (self.wide_blocks(), Packet8::coherent(rays)) else {
            return self.one_by_one::<ANY>(rays);
        };
        self.walk_packet::<ANY>(wide, &Packet8::build(rays))
    }

    /// [`Self::packet8`] of rays given as rows: a packet made from the
    /// rows ([`Rays8::lanes`]) when they make one, else each lane alone,
    /// through the row queries' walks ([`Self::closest_row`],
    /// [`Self::first_hit_row`]), which make its ray inside them. (Each
    /// lane's `Ray` made first and handed to the `&Ray` walk, `raymesh
    /// raycast --packets` on bunny00's 4M random rays, one thread,
    /// pinned, took 938–940 ms against 894–923.)
    fn packet8_soa<const ANY: bool>(&self, rays: &Rays8) -> [Option<(u32, PrimHit)>; LANES] {
        if let Some(wide) = self.wide_blocks() {
            if let Some(lanes) = &rays.lanes() {
                return self.walk_packet::<ANY>(wide, &Packet8::from_lanes(rays, lanes));
            }
        }
        std::array::from_fn(|i| {
            let row = rays.row(i);
            if ANY {
                self.first_hit_row(&row).hit()
            } else {
                self.closest_row(&row).hit()
            }
        })
    }

    /// [`Self::packet8`] of rays that make no packet: each ray alone.
    fn one_by_one<const ANY: bool>(&self, rays: &[Ray; LANES]) -> [Option<(u32, PrimHit)>; LANES] {
        rays.each_ref().map(|r| {
            if ANY {
                self.first_hit(r, &mut NoStats).hit()
            } else {
                self.closest(r, &mut NoStats).hit()
            }
        })
    }

    /// The packet walk of [`Self::packet8`] over the BVH `wide`.
    #[inline(always)]
    fn walk_packet<const ANY: bool>(
        &self,
        wide: WideRef<'_>,
        p: &Packet8,
    ) -> [Option<(u32, PrimHit)>; LANES] {
        let mut tmax: [f32; LANES] = *p.tmax();
        let mut leaf = WalkLeaf::<P, ANY> {
            scene: self,
            p,
            best: [None; LANES],
        };
        match wide {
            WideRef::W4(b) if ANY => b.traverse_packet::<false>(p, &mut tmax, &mut leaf),
            WideRef::W4(b) => b.traverse_packet::<true>(p, &mut tmax, &mut leaf),
            WideRef::W8(b) if ANY => b.traverse_packet::<false>(p, &mut tmax, &mut leaf),
            WideRef::W8(b) => b.traverse_packet::<true>(p, &mut tmax, &mut leaf),
            WideRef::W2(b) => b.traverse_packet(p, &mut tmax, &mut leaf),
        }
        leaf.best
    }

    /// A packet's leaf (`first..first + count`) tested a block at a time
    /// for the lanes in `lanes` of `p`, each block against every lane
    /// still in it ([`Primitives::intersect_block_lanes`]): each lane's
    /// blocks in the order, and with the bounds, that [`Self::leaf_lanes`]
    /// tests them, so the same hits. Closest hits lower the lane's
    /// `tmax`; with `ANY`, a lane's first hit ends it (`tmax` to `-inf`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn leaf_blocks<const ANY: bool>(
        &self,
        avx: Avx2,
        p: &Packet8,
        (first, count, lanes): (u32, u32, u32),
        tmax: &mut [f32; LANES],
        best: &mut [Option<(u32, PrimHit)>; LANES],
    ) {
        let (mut start, end) = (first, first + count);
        let mut live = lanes;
        while start < end && live != 0 {
            let n = (end - start).min(BLOCK as u32);
            // Any hit: each lane's own bound, as `leaf_any_by` takes it.
            let bound = if ANY { *p.tmax() } else { *tmax };
            let mut ended = 0;
            self.prims.intersect_block_lanes(
                avx,
                start,
                n,
                p,
                live,
                &bound,
                |i, mut mask, hits| {
                    if !ANY {
                        while mask != 0 {
                            let k = mask.trailing_zeros() as usize;
                            mask &= mask - 1;
                            if hits.t[k] <= tmax[i] {
                                self.offer(
                                    &mut best[i],
                                    &mut tmax[i],
                                    start + k as u32,
                                    hits.get(k),
                                );
                            }
                        }
                    } else if mask != 0 {
                        let k = mask.trailing_zeros();
                        best[i] = Some((start + k, hits.get(k as usize)));
                        tmax[i] = f32::NEG_INFINITY;
                        ended |= 1 << i;
                    }
                },
            );
            live &= !ended;
            start += BLOCK as u32;
        }
    }

    /// A packet's leaf (`first..first + count`) tested lane by lane for
    /// the lanes in `lanes` of `p`, each lane's ray by the portable block
    /// test ([`Primitives::intersect_block`]), as each ray alone would be:
    /// the leaf where the walk has no AVX2 (with it: `Self::leaf_blocks`).
    /// Closest hits lower the lane's `tmax`; with `ANY`, a lane's first
    /// hit ends it (`tmax` to `-inf`).
    #[inline(always)]
    fn leaf_lanes<const ANY: bool>(
        &self,
        p: &Packet8,
        (first, count, lanes): (u32, u32, u32),
        tmax: &mut [f32; LANES],
        best: &mut [Option<(u32, PrimHit)>; LANES],
    ) {
        let mut m = lanes;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            let ray = p.ray(i);
            let test = |s, n, t| self.prims.intersect_block(s, n, ray, t);
            if !ANY {
                self.leaf_closest_by(first, count, &mut tmax[i], &mut best[i], test);
            } else if let Some(f) = self.leaf_any_by(first, count, p.tmax()[i], test) {
                best[i] = Some(f);
                tmax[i] = f32::NEG_INFINITY;
            }
        }
    }

    /// The closest hits of many rays: `out[i]` is [`Self::intersect`] of
    /// `rays[i]`, bit for bit.
    ///
    /// Over a BVH in leaf order, the rays walk the tree a few at a time,
    /// interleaved. Over a binary BVH each step is without branches on the
    /// rays' data: about 1.3 times the speed of tracing one by one on
    /// incoherent rays (random directions) on bunny00. Over a wide BVH each
    /// step prefetches what its ray visits next, twelve rays in flight over
    /// trees of 1 MiB of nodes or more: 1.7–2.4 times on random rays over
    /// meshes far larger than the caches (250,000 triangles and up), level
    /// or slower on smaller ones: on a CPU with AVX2, an 8-wide tree whose
    /// nodes take less than half the core's L2 (256 KiB, some 30,000
    /// triangles, on a 512 KiB L2; 512 KiB on a 1 MiB one) traces such rays
    /// one by one instead (random rays 1.03–1.09 times as fast on the pig,
    /// the dragon, the elephant and small spheres on a Zen 3, 1.05–1.16 on
    /// a Zen 4; see `bvh::small_tree_bytes`). Both were slower on coherent
    /// rays (a camera's, or shadow rays toward one light) over small
    /// meshes, whose branches the one-by-one walk predicts well: over a
    /// wide BVH each run of eight rays that makes a packet ([`Packet8`])
    /// walks the tree as one instead, with each ray's one-by-one hit
    /// (`raymesh-peers bunny00.off ChineseDragon-10kv.off --stream --size
    /// 512`, one thread: primary rays 8.4 -> 15.5 and 8.1 -> 16.0 Mrays/s,
    /// shadow rays 7.0 -> 11.5 and 5.5 -> 10.1; random and diffuse rays,
    /// which make no packets, level: the runs are checked first, and a
    /// stream with no packet goes to the interleaved walk whole), and over
    /// a binary BVH too since a renderer's streams showed it missing
    /// (`--accel bvh-binned`, bunny00: primary rays 5.26 -> 12.24, shadow
    /// rays 3.77 -> 9.47; diffuse level). Over an 8-wide BVH on a CPU with
    /// AVX2, a stream with no packet walks in groups of up to 32 rays of
    /// one octant instead (`Bvh8::intersect_group`), each node fetched and
    /// tested once for all the group's rays that enter it, unless its rays
    /// start scattered (random rays) or its first groups share too few
    /// nodes, which leave it interleaved: diffuse rays 1.16–1.32 times as
    /// fast as interleaved on bunny00, the dragon, the pig and
    /// polygon_mesh, 1.07 on a 600K-triangle sphere (`raymesh-peers
    /// --stream --workloads diffuse --size 512 --accel bvh8`, one thread,
    /// against e280670).
    /// See `raymesh raycast --stream`. Other structures trace one by one.
    pub fn intersect_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        let best = self.stream(rays, false, true);
        for ((o, r), b) in out.iter_mut().zip(rays).zip(best) {
            *o = b.map(|(prim, index, h)| self.hit_at(prim, index, r, h));
        }
    }

    /// [`Self::any_hit`] of many rays, bit for bit: interleaved, as
    /// [`Self::intersect_stream`] traces rays that make no packet, or over
    /// an 8-wide BVH on a CPU with AVX2 in groups, as
    /// [`Self::occluded_stream`] walks them (each ray meets the leaves its
    /// one-ray walk meets, in the same order, so it finds the same hit).
    /// No packets: a packet's lane may find another hit than its ray alone.
    pub fn any_hit_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        let found = self.stream(rays, true, false);
        for ((o, r), f) in out.iter_mut().zip(rays).zip(found) {
            *o = f.map(|(prim, index, h)| self.hit_at(prim, index, r, h));
        }
    }

    /// Whether each ray hits anything: `out[i]` is [`Self::occluded`] of
    /// `rays[i]` (shadow rays, which need no hit). Over an 8-wide BVH on a
    /// CPU with AVX2 the rays walk it in groups of up to 32 of one octant,
    /// each node fetched and tested once for all the group's rays that
    /// enter it and each ray leaving at its first hit (as Embree walks its
    /// occlusion streams; whether a ray hits is the one-ray answer),
    /// unless the first groups share too few nodes (`GROUP_MIN_SHARE`),
    /// which leaves the rest interleaved; over other BVHs each run of
    /// eight rays that makes a packet walks the tree as one (each lane
    /// stopping at its first hit), as [`Self::intersect_stream`] traces
    /// closest hits, and the rest are interleaved. `raymesh-peers
    /// bunny00.off ChineseDragon-10kv.off pig.stl sphere.ply --workloads
    /// random,diffuse --stream --size 512 --accel bvh8` (the last from
    /// `raymesh generate sphere --triangles 600000`), one thread, against
    /// interleaving (81aa57f): diffuse rays 1.28–1.60 times as fast.
    /// Coherent runs (a camera's rays, shadow rays toward one light)
    /// walked as packets until groups overtook them with 01f9a19: in
    /// groups, primary rays 1.03–1.09 and shadow rays 1.10–1.20 times as
    /// fast over bunny00, the dragon, the pig and polygon_mesh (402eeab,
    /// two alternations), and 1.2–1.5 times over meshes of millions of
    /// triangles, whose packets' lanes part before the leaves (0863f27).
    /// Where a hit is wanted too, [`Self::any_hit_stream`] gives the
    /// one-ray hits (in groups too).
    pub fn occluded_stream(&self, rays: &[Ray], out: &mut [bool]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        #[cfg(target_arch = "x86_64")]
        if let (Some(WideRef::W8(bvh)), Some(avx)) = (self.wide_blocks(), Avx2::detect()) {
            self.occluded_in_groups(bvh, avx, rays, out, GroupPolicy::ANY_HIT);
            return;
        }
        for (o, f) in out.iter_mut().zip(self.stream(rays, true, true)) {
            *o = f.is_some();
        }
    }

    /// [`Self::occluded_stream`] over an 8-wide BVH on a CPU with AVX2: the
    /// whole stream by [`Self::first_hits_in_groups`] with `policy`.
    #[cfg(target_arch = "x86_64")]
    fn occluded_in_groups(
        &self,
        bvh: &Bvh8,
        avx: Avx2,
        rays: &[Ray],
        out: &mut [bool],
        policy: GroupPolicy,
    ) {
        out.fill(false);
        let all: Vec<usize> = (0..rays.len()).collect();
        self.first_hits_in_groups(bvh, avx, rays, &all, true, policy, &mut |i, _| {
            out[i] = true;
        });
    }

    /// Calls `found(i, (prim, index, hit))` for each ray `rays[i]`, `i` in
    /// `which`, that hits anything, with its one-ray hit: with `any_hit`,
    /// [`Self::any_hit`]'s (the same leaves in the same order, the first
    /// hit of the first leaf with one), else [`Self::intersect`]'s closest
    /// (least `t`, ties to the least index, whatever the order). The rays
    /// are sorted by their direction's octant (a counting sort), each
    /// octant's in groups of [`crate::bvh::GROUP`] that walk the tree
    /// together ([`Bvh8::occluded_group`], [`Bvh8::intersect_group`]).
    /// Once `policy.probe` rays have walked so, if their groups' node
    /// visits took fewer than `policy.min_share` rays each on average, the
    /// remaining rays are interleaved instead ([`Self::stream_each`]); so
    /// are all of them, without a group, where they start scattered
    /// ([`Self::scattered`] with `policy.scatter`).
    #[cfg(target_arch = "x86_64")]
    #[inline(never)]
    #[allow(clippy::too_many_arguments)]
    fn first_hits_in_groups(
        &self,
        bvh: &Bvh8,
        avx: Avx2,
        rays: &[Ray],
        which: &[usize],
        any_hit: bool,
        policy: GroupPolicy,
        found: &mut impl FnMut(usize, (u32, u32, PrimHit)),
    ) {
        use crate::bvh::{GroupRays, GROUP};
        if self.scattered(which.iter().map(|&i| rays[i].origin()), policy.scatter) {
            return self.interleave(rays, which, any_hit, found);
        }
        // A counting sort by octant, reading each ray once (its first touch
        // of the stream: the reads were a good part of this function's
        // time). Invalid rays go in too: with `tmin` infinite and the bound
        // `-inf` (or NaN) they enter no box, as alone.
        let octant: Vec<u8> = which.iter().map(|&i| rays[i].octant() as u8).collect();
        let mut starts = [0usize; 9];
        let order = match octant.first() {
            // One octant (a camera's rays, mostly, or shadow rays toward
            // one light): the order as given. Counting such a stream
            // added one to the same counter in memory for every ray, each
            // add waiting on the one before (a sixth of this function's
            // time on primary rays).
            Some(&o) if octant.iter().all(|&x| x == o) => {
                starts[usize::from(o) + 1..].fill(which.len());
                which.to_vec()
            }
            _ => {
                for &o in &octant {
                    starts[usize::from(o) + 1] += 1;
                }
                for o in 0..8 {
                    starts[o + 1] += starts[o];
                }
                let mut at = starts;
                let mut order = vec![0usize; which.len()];
                for (&i, &o) in which.iter().zip(&octant) {
                    order[at[usize::from(o)]] = i;
                    at[usize::from(o)] += 1;
                }
                order
            }
        };
        // The groups, as ranges of `order` and their octant: each octant's
        // rays in runs of at most GROUP, one octant after another.
        let groups: Vec<(usize, usize, usize)> = (0..8)
            .flat_map(|o| {
                (starts[o]..starts[o + 1])
                    .step_by(GROUP)
                    .map(move |a| (a, (a + GROUP).min(starts[o + 1]), o))
            })
            .collect();
        let mut stack = Vec::with_capacity(256);
        let mut entries = Vec::with_capacity(256);
        // Node visits and the rays they took, over the groups so far, and
        // (occlusion) leaf visits and theirs.
        let mut shared = (0u64, 0u64);
        let mut leaves = (0u64, 0u64);
        let mut handed = None;
        // Each ray's node-test rows and leaf-test constants, made once
        // for the walk, in place (made by `array::from_fn`, the constants
        // went through a call and a copy that waited on the call's
        // narrower stores: half of this function's time on primary rays).
        // One set of rows for all the groups, each group's rays put over
        // the last's: a walk reads only its own rays' lanes (`len` of
        // them, and the bits of their masks), so what lies past them is
        // never read, and the rows need no clearing (made anew for each
        // group, 3 KiB of zeros a group cost primary occlusion streams a
        // few percent).
        let mut g = GroupRays::of_octant(0);
        let mut pre = [BlockRay::default(); GROUP];
        for &(a, b, octant) in &groups {
            let few = (shared.1 as f64) < f64::from(policy.min_share) * shared.0 as f64;
            if a >= policy.probe && few {
                handed = Some(a);
                break;
            }
            let group = &order[a..b];
            let ray = |i: usize| &rays[group[i]];
            g.set_octant(octant);
            // With any hits, where the leaf visits so far took several
            // rays each (camera and shadow rays), a block's rows are
            // loaded once for the rays that reach it together; elsewhere
            // (diffuse and random rays, a leaf mostly reached by one or
            // two) ray by ray, which has fewer loops to mispredict.
            let coherent =
                any_hit && leaves.0 > 0 && leaves.1 as f64 >= SHARED_LEAF_RAYS * leaves.0 as f64;
            // The node-test rows eight rays at a time (AVX2 transposes:
            // ray by ray, they were eleven scalar stores a ray to as many
            // cache lines; primary occlusion streams 1.02-1.04x), then the
            // leaf constants ray by ray and, for the coherent walk, the
            // group's rays of each axis order, which read the same rows of
            // a block (a pass of their own cost a loop more a ray: primary
            // and shadow occlusion streams 1.01-1.02x without it).
            crate::simd::set_group_rays(avx, &mut g, rays, group);
            let mut classes = [0u32; AXIS_CLASSES];
            for ((k, p), &i) in pre.iter_mut().enumerate().zip(group) {
                let r = &rays[i];
                *p = self.prims.block_ray(r);
                if coherent {
                    classes[p.axis_class()] |= 1 << k;
                }
            }
            if any_hit {
                // Two walks, each with one copy of the kernel: with two in
                // one, the leaf closure was no longer inlined and every
                // intrinsic became a call (0.08-0.13x).
                if coherent {
                    avx_run!(avx, || bvh.occluded_group_by(
                        &g,
                        group.len(),
                        &mut stack,
                        &mut shared,
                        &mut leaves,
                        &mut |rays, first, count| {
                            // The leaf's blocks in order, each tested for
                            // the rays that hit none before it (as
                            // `leaf_any_by` tests them ray by ray): a ray's
                            // first hit is the least slot of the first
                            // block it hits.
                            let mut hit = 0u32;
                            let (mut start, end) = (first, first + count);
                            while start < end && rays & !hit != 0 {
                                let n = (end - start).min(BLOCK as u32);
                                let rest = rays & !hit;
                                let tmax = |i: usize| ray(i).tmax();
                                let each = |i: usize, mask: u32, got: BlockHits| {
                                    if mask != 0 {
                                        let k = mask.trailing_zeros();
                                        let prim = start + k;
                                        let h = got.get(k as usize);
                                        found(group[i], (prim, self.original_index(prim), h));
                                        hit |= 1 << i;
                                    }
                                };
                                self.prims.intersect_block_rays(
                                    avx, start, n, rest, &pre, ray, tmax, &classes, each,
                                );
                                start += BLOCK as u32;
                            }
                            hit
                        },
                        &|first| self.prims.prefetch_block(first),
                        |n, g, m| crate::simd::group_slab8(avx, n, g, m),
                    ));
                } else {
                    avx_run!(avx, || bvh.occluded_group(
                        &g,
                        group.len(),
                        &mut stack,
                        &mut shared,
                        &mut leaves,
                        &mut |i, first, count| {
                            let r = ray(i);
                            let hit = self.leaf_any_by(first, count, r.tmax(), |s, n, t| {
                                self.prims.intersect_block_pre(avx, &pre[i], s, n, r, t)
                            });
                            if let Some((prim, h)) = hit {
                                found(group[i], (prim, self.original_index(prim), h));
                            }
                            hit.is_some()
                        },
                        &|first| self.prims.prefetch_block(first),
                        |n, g, m| crate::simd::group_slab8(avx, n, g, m),
                    ));
                }
                continue;
            }
            let mut leaf = ClosestInGroup {
                scene: self,
                avx,
                rays,
                group,
                pre: &pre,
                tmax: std::array::from_fn(|i| if i < group.len() { ray(i).tmax() } else { 0.0 }),
                best: [None; GROUP],
            };
            let len = group.len();
            let e = &mut entries;
            crate::simd::intersect_group_avx2(avx, bvh, &mut g, len, e, &mut shared, &mut leaf);
            for (&i, b) in group.iter().zip(leaf.best) {
                if let Some((prim, h)) = b {
                    found(i, (prim, self.original_index(prim), h));
                }
            }
        }
        if let Some(done) = handed {
            self.interleave(rays, &order[done..], any_hit, found);
        }
    }

    /// Calls `found(i, hit)` for each ray `rays[i]`, `i` in `which`, that
    /// hits anything, with its one-ray hit (closest, or with `any_hit` the
    /// one-ray any hit), the rays interleaved ([`Self::stream_each`]): in
    /// place where `which` is every ray in order, else a copy of them in
    /// `which`'s order.
    #[cfg(target_arch = "x86_64")]
    fn interleave(
        &self,
        rays: &[Ray],
        which: &[usize],
        any_hit: bool,
        found: &mut impl FnMut(usize, (u32, u32, PrimHit)),
    ) {
        let whole = which.len() == rays.len() && which.iter().enumerate().all(|(k, &i)| k == i);
        let each = if whole {
            self.stream_each(rays, any_hit)
        } else {
            let others: Vec<Ray> = which.iter().map(|&i| rays[i]).collect();
            self.stream_each(&others, any_hit)
        };
        for (i, f) in which.iter().zip(each) {
            if let Some(f) = f {
                found(*i, f);
            }
        }
    }

    /// Whether a stream's rays, whose origins are `origins` in the stream's
    /// order, start far from their neighbours: the first [`SCATTER_PROBE`],
    /// on average more than `fraction` of the scene box's diagonal from
    /// the one before (non-finite distances left out).
    /// Groups gather rays near each other in the stream, and rays that
    /// start so far apart share few nodes (random rays, whose origins lie
    /// anywhere on a sphere around the scene): such streams are
    /// interleaved without walking any group to find out.
    #[cfg(target_arch = "x86_64")]
    fn scattered(&self, mut origins: impl Iterator<Item = Vec3>, fraction: f32) -> bool {
        if fraction == f32::INFINITY {
            // No distance is that far (occlusion streams ask so).
            return false;
        }
        let diagonal = self.bounds.diagonal();
        let Some(mut last) = origins.next() else {
            return false;
        };
        let (mut apart, mut n) = (0.0f32, 0usize);
        for o in origins.take(SCATTER_PROBE - 1) {
            let d = o.distance(last);
            if d.is_finite() {
                apart += d;
            }
            (last, n) = (o, n + 1);
        }
        n > 0 && diagonal.is_finite() && apart > fraction * diagonal * n as f32
    }

    /// [`Self::intersect_stream`] (or, with `any_hit`,
    /// [`Self::any_hit_stream`]) without the normals: the same hits.
    pub fn stream_bare(&self, rays: &[Ray], any_hit: bool, out: &mut [Option<BareHit>]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (o, b) in out.iter_mut().zip(self.stream(rays, any_hit, !any_hit)) {
            *o = b.map(|(_, index, h)| bare_at(index, h));
        }
    }

    /// The primitives (in storage order), their indices as given
    /// ([`Self::original_index`]) and hits of [`Self::intersect_stream`],
    /// or with `any_hit` of [`Self::any_hit_stream`].
    ///
    /// With `packets`, each run of eight rays (from the stream's start)
    /// that makes a packet ([`Packet8`]: one octant and axis order, as a
    /// camera's neighbouring pixels or shadow rays toward one light do)
    /// walks the BVH as one; the other rays are interleaved as before.
    /// A packet gives each ray its one-by-one closest hit bit for bit, but
    /// with `any_hit` only whether it hits (a lane may find another hit
    /// than the ray alone): [`Self::occluded_stream`]'s answer.
    fn stream(
        &self,
        rays: &[Ray],
        any_hit: bool,
        packets: bool,
    ) -> Vec<Option<(u32, u32, PrimHit)>> {
        // One-ray any hits (no packets, whose lanes may find others) in
        // groups where the groups pay, as occlusion streams walk.
        #[cfg(target_arch = "x86_64")]
        if any_hit && !packets {
            if let (Some(WideRef::W8(bvh)), Some(avx)) = (self.wide_blocks(), Avx2::detect()) {
                return self.stream_in_groups(bvh, avx, rays, true);
            }
        }
        let wide = match self.wide_blocks() {
            Some(w) if packets => w,
            _ => return self.stream_each(rays, any_hit),
        };
        // Which runs make packets, found first.
        let coherent: Vec<bool> = rays
            .chunks(LANES)
            .map(|c| <&[Ray; LANES]>::try_from(c).is_ok_and(Packet8::coherent))
            .collect();
        if !coherent.contains(&true) {
            // Closest hits of a stream with no packet (diffuse rays) over
            // an 8-wide BVH on a CPU with AVX2 walk in groups where the
            // groups pay. (The few other rays of a stream with packets,
            // where neighbouring rays' octants differ, stay interleaved: in
            // groups, a camera's rays ran 2.5-5% slower.)
            #[cfg(target_arch = "x86_64")]
            if let (WideRef::W8(bvh), Some(avx), false) = (wide, Avx2::detect(), any_hit) {
                return self.stream_in_groups(bvh, avx, rays, false);
            }
            // No output or list of the other rays made for nothing.
            return self.stream_each(rays, any_hit);
        }
        let mut out = vec![None; rays.len()];
        let mut rest: Vec<usize> = Vec::new();
        for ((c, chunk), packet) in rays.chunks(LANES).enumerate().zip(coherent) {
            match <&[Ray; LANES]>::try_from(chunk) {
                Ok(eight) if packet => {
                    let packet = Packet8::build(eight);
                    let best = if any_hit {
                        self.walk_packet::<true>(wide, &packet)
                    } else {
                        self.walk_packet::<false>(wide, &packet)
                    };
                    for (o, b) in out[c * LANES..][..LANES].iter_mut().zip(best) {
                        *o = b.map(|(prim, h)| (prim, self.original_index(prim), h));
                    }
                }
                _ => rest.extend(c * LANES..c * LANES + chunk.len()),
            }
        }
        if !rest.is_empty() {
            let others: Vec<Ray> = rest.iter().map(|&i| rays[i]).collect();
            for (&i, found) in rest.iter().zip(self.stream_each(&others, any_hit)) {
                out[i] = found;
            }
        }
        out
    }

    /// [`Self::stream`] of rays that make no packets, over an 8-wide BVH
    /// on a CPU with AVX2, with `any_hit` (the one-ray any hits) or
    /// without: [`Self::first_hits_in_groups`] with the policy for the
    /// query, or where the rays start scattered, [`Self::stream_each`]
    /// (checked here too: handed over by `first_hits_in_groups`, through
    /// a list and a copy of the hits, random rays' closest hits ran 3-4%
    /// slower).
    #[cfg(target_arch = "x86_64")]
    fn stream_in_groups(
        &self,
        bvh: &Bvh8,
        avx: Avx2,
        rays: &[Ray],
        any_hit: bool,
    ) -> Vec<Option<(u32, u32, PrimHit)>> {
        if self.scattered(rays.iter().map(Ray::origin), SCATTER_FRACTION) {
            return self.stream_each(rays, any_hit);
        }
        let policy = GroupPolicy {
            // Checked above.
            scatter: f32::INFINITY,
            ..if any_hit {
                GroupPolicy::ANY_HIT
            } else {
                GroupPolicy::CLOSEST
            }
        };
        let mut out = vec![None; rays.len()];
        let all: Vec<usize> = (0..rays.len()).collect();
        self.first_hits_in_groups(bvh, avx, rays, &all, any_hit, policy, &mut |i, f| {
            out[i] = Some(f);
        });
        out
    }

    /// [`Self::stream`] with every ray interleaved with the others (over a
    /// BVH) or traced alone (over the other structures, and over an 8-wide
    /// BVH whose nodes take less than half the core's L2 on a CPU with
    /// AVX2, `bvh::small_tree_bytes`, where that is faster).
    fn stream_each(&self, rays: &[Ray], any_hit: bool) -> Vec<Option<(u32, u32, PrimHit)>> {
        let one_by_one = || {
            rays.iter()
                .map(|r| {
                    let found = if any_hit {
                        self.first_hit(r, &mut NoStats)
                    } else {
                        self.closest(r, &mut NoStats)
                    }
                    .hit();
                    found.map(|(prim, h)| (prim, self.original_index(prim), h))
                })
                .collect()
        };
        let Some(wide) = self.wide_blocks() else {
            return one_by_one();
        };
        #[cfg(target_arch = "x86_64")]
        if let (WideRef::W8(b), Some(_)) = (wide, Avx2::detect()) {
            if b.node_bytes() < crate::bvh::small_tree_bytes() {
                return one_by_one();
            }
        }
        let mut found: Vec<Option<(u32, PrimHit)>> = vec![None; rays.len()];
        // Each hit's index as given, looked up when the hit is found: the
        // block's rows, with triangles' indices among them, were just
        // read. Looked up after the stream, 1,024 rays later, they had
        // left the cache (a 600K-triangle sphere's random rays, closest
        // hits, `raymesh-ab --stream` against that: 1.035 and 1.047).
        let mut index = vec![0u32; rays.len()];
        // A leaf of ray `i`: its first hit, which ends an any-hit query, or
        // its closest so far.
        let mut leaf = |i: usize, first, count, mut tmax| {
            if any_hit {
                found[i] = self.leaf_any(&rays[i], first, count);
                if let Some((prim, _)) = found[i] {
                    index[i] = self.original_index(prim);
                    return f32::NEG_INFINITY;
                }
            } else {
                let before = found[i].map(|(prim, _)| prim);
                self.leaf_closest(&rays[i], first, count, &mut tmax, &mut found[i]);
                if let Some((prim, _)) = found[i].filter(|&(prim, _)| Some(prim) != before) {
                    index[i] = self.original_index(prim);
                }
            }
            tmax
        };
        let prefetch = |first| self.prims.prefetch_block(first);
        match (wide, any_hit) {
            (WideRef::W2(b), _) => b.traverse_stream(rays, &mut leaf),
            (WideRef::W4(b), false) => b.traverse_stream::<true>(rays, &mut leaf, prefetch),
            (WideRef::W4(b), true) => b.traverse_stream::<false>(rays, &mut leaf, prefetch),
            (WideRef::W8(b), false) => b.traverse_stream::<true>(rays, &mut leaf, prefetch),
            (WideRef::W8(b), true) => b.traverse_stream::<false>(rays, &mut leaf, prefetch),
        }
        found
            .into_iter()
            .zip(index)
            .map(|(f, index)| f.map(|(prim, h)| (prim, index, h)))
            .collect()
    }

    /// Closest hit and what it cost.
    pub fn intersect_stats(&self, ray: &Ray) -> (Option<Hit>, CountStats) {
        let mut c = CountStats::default();
        (self.intersect_counted(ray, &mut c), c)
    }
}

/// The leaves of a group's closest-hit walk
/// ([`crate::bvh::WideBvh::intersect_group`]): ray `i` of the group is
/// `rays[group[i]]`, with its leaf-test constants `pre[i]`, its closest
/// hit so far `best[i]` and its `tmax[i]`.
#[cfg(target_arch = "x86_64")]
struct ClosestInGroup<'a, P: Primitives> {
    scene: &'a Scene<P>,
    avx: Avx2,
    rays: &'a [Ray],
    group: &'a [usize],
    pre: &'a [BlockRay; crate::bvh::GROUP],
    tmax: [f32; crate::bvh::GROUP],
    best: [Option<(u32, PrimHit)>; crate::bvh::GROUP],
}

#[cfg(target_arch = "x86_64")]
impl<P: Primitives> GroupLeaf for ClosestInGroup<'_, P> {
    #[inline(always)]
    fn visit(&mut self, i: usize, first: u32, count: u32) -> Option<f32> {
        let (scene, avx, pre) = (self.scene, self.avx, &self.pre[i]);
        let r = &self.rays[self.group[i]];
        let before = self.tmax[i];
        scene.leaf_closest_by(
            first,
            count,
            &mut self.tmax[i],
            &mut self.best[i],
            |s, n, t| scene.prims.intersect_block_pre(avx, pre, s, n, r, t),
        );
        (self.tmax[i] != before).then_some(self.tmax[i])
    }
    #[inline(always)]
    fn prefetch(&self, first: u32) {
        self.scene.prims.prefetch_block(first);
    }
}

/// What a query's walk found, as two integers, which a function returns
/// in two registers: the best hit (its primitive in storage order, and
/// the hit), no hit, or a walk left undone (an AVX2 walk whose inline
/// stack would have spilled). As the `Option<(u32, PrimHit)>` it stands
/// for (20 bytes; a 16-byte struct fares the same), each walk's result
/// went back through memory, stored field by field and loaded as wider
/// words, loads the CPU cannot forward from those stores: they waited for
/// the stores to reach the cache. `perf record -e cpu-clock` put 6% of
/// the samples of rays that miss the pig's box (in `raymesh-peers`) on
/// one such load. Returned packed, `raymesh-ab --accel bvh8 --size 512`
/// against the build before (medians of pairs, closest / any-hit): rays
/// that miss the pig's box 1.42 / 1.44, its primary rays 1.13 / 1.19,
/// bunny00's 1.07 / 1.12.
///
/// Without a hit, `t` is NaN, which no hit's `t` is (it passed `tmin <= t
/// <= tmax`), and the primitive 0 (no hit) or 1 (undone).
#[derive(Clone, Copy)]
struct PackedHit(u64, u64);

impl PackedHit {
    /// No hit.
    const NONE: Self = Self(0x7fc0_0000 << 32, 0);

    /// A walk left undone.
    const UNDONE: Self = Self(0x7fc0_0000 << 32 | 1, 0);

    /// `best`, a finished walk's result.
    #[inline(always)]
    fn found(best: Option<(u32, PrimHit)>) -> Self {
        match best {
            // A hit's `t` is never NaN (see [`Primitives::intersect`]).
            Some((prim, h)) => Self(
                u64::from(prim) | u64::from(h.t.to_bits()) << 32,
                u64::from(h.u.to_bits()) | u64::from(h.v.to_bits()) << 32,
            ),
            None => Self::NONE,
        }
    }

    /// `best`, or, unless `done`, a walk to do again.
    #[inline(always)]
    fn new(done: bool, best: Option<(u32, PrimHit)>) -> Self {
        if done {
            Self::found(best)
        } else {
            Self::UNDONE
        }
    }

    /// Whether the walk was left undone.
    #[inline(always)]
    fn is_undone(self) -> bool {
        self.0 == Self::UNDONE.0
    }

    /// The primitive and hit of a finished walk, if it found one.
    #[inline(always)]
    fn hit(self) -> Option<(u32, PrimHit)> {
        debug_assert!(!self.is_undone());
        let t = f32::from_bits((self.0 >> 32) as u32);
        (!t.is_nan()).then(|| {
            let h = PrimHit {
                t,
                u: f32::from_bits(self.1 as u32),
                v: f32::from_bits((self.1 >> 32) as u32),
            };
            (self.0 as u32, h)
        })
    }
}

/// The [`BareHit`] of hit `h` of the primitive given index `index`.
#[inline]
fn bare_at(index: u32, h: PrimHit) -> BareHit {
    BareHit {
        t: h.t,
        prim: index,
        u: h.u,
        v: h.v,
    }
}

/// `config` with [`BuildConfig::leaf_block`] resolved, over primitives
/// whose leaves are tested as blocks: the SIMD block width for the
/// SAH-built binary BVHs (a leaf of up to a block costs one test), and
/// [`KD_LEAF_BLOCK`] for the k-d tree; as given otherwise.
fn leaf_blocks<P: Primitives>(kind: AccelKind, config: &BuildConfig) -> BuildConfig {
    let block = match kind {
        AccelKind::BvhBinned | AccelKind::BvhSweep => Some(BLOCK),
        AccelKind::KdTree => Some(KD_LEAF_BLOCK),
        _ => None,
    };
    BuildConfig {
        leaf_block: config.leaf_block.or(block.filter(|_| P::BLOCK_TEST)),
        ..*config
    }
}

/// Triangles a k-d tree leaf tests for the cost of one, in its SAH: a
/// whole block. The scene stores the triangles in the tree's leaf order
/// (a triangle once in each leaf it reaches, [`KdTree::leaf_order`]), so
/// a leaf's triangles are a run of rows, tested [`BLOCK`] at a time by
/// the block kernel as a BVH's leaves are. (They were gathered by index
/// into blocks, a cost per triangle, and 2 was the best count then.)
/// `raymesh-ab MESH --accel kdtree --workload W --size 256 --rounds 2
/// --chunk 16384 --set leaf_block=B` against the gathering build, pinned,
/// medians of pairs, closest / any-hit: bunny00's random rays with 2 in
/// the new layout 1.07 / 1.09, with 4 1.19 / 1.18, with 8 1.29 / 1.25;
/// with 8 on the four meshes of `../shared/meshes` with more than 10,000
/// triangles, all four workloads, 1.17–1.36 / 1.22–1.41 and, in a second
/// run, 1.16–1.31 / 1.20–1.39, the same hits (occlusion too);
/// a traversal cost of 6 instead of 3 beside it gained nothing (0.97–1.46
/// / 1.06–1.38 on the same 16). The copies cost memory: bunny00 60.9 →
/// 77.1 bytes a triangle (124 with 2), its build 89 → 57 ms.
const KD_LEAF_BLOCK: usize = BLOCK;

/// The fewest rays a node visit must take on average, over an occlusion
/// stream's first groups ([`Scene::occluded_stream`]), for its other rays
/// to walk in groups too rather than interleaved. Rays a visit took in
/// groups of 32, at 256² (bunny00; a 600K-triangle sphere): random 1.76;
/// 1.61, diffuse 4.29; 3.46, shadow 10.4; 7.3, primary 12.1; 8.5. In
/// groups, random rays ran 0.96 and 0.57 times as fast as interleaved
/// (the sphere's tree, past the caches, is where interleaving's
/// prefetches pay), diffuse rays 1.43 and 1.27 times; the threshold was
/// 2.5 then, and scattered streams (random rays) were interleaved at
/// once. Since the groups' set-up costs less (01f9a19), random rays in
/// groups run 1.10–1.46 times as fast as interleaved where they share
/// 1.95 rays a visit or more (the pig 2.23, the dragon 2.06,
/// polygon_mesh 1.95; a teapot in a stadium, whose stadium ends many
/// rays near the root, 3.56) and 0.53–0.64 times where they share 1.64
/// or fewer (the 600K sphere 1.64, a 2M sphere 1.51, a 1M terrain 1.48);
/// bunny00, 1.84, about level. So occlusion streams are probed whatever
/// their origins, at 1.75 (`raymesh-peers --stream --workloads random
/// --size 512 --accel bvh8`, two alternations: the first four 1.11–1.46
/// times as fast as at 402eeab, bunny00 0.98, the large meshes 0.95–0.96,
/// what their probes cost).
#[cfg(target_arch = "x86_64")]
const GROUP_MIN_SHARE: f32 = 1.75;

/// [`GROUP_MIN_SHARE`] for closest hits ([`Scene::intersect_stream`]),
/// which need more sharing for a gain: rays a node visit took in groups,
/// diffuse rays at 256² (bunny00, the dragon, the pig, polygon_mesh, a
/// 600K-triangle sphere), 4.4, 5.9, 7.1, 4.4 and 3.5, where groups ran
/// 1.12, 1.26, 1.13, 1.08 and 0.98 times as fast as interleaving (at
/// 512²; 1.21, 1.32, 1.16, 1.17 and 1.07 since 7113358); random rays
/// 1.7–2.4, where groups ran 0.5–0.8 times as fast.
#[cfg(target_arch = "x86_64")]
const CLOSEST_MIN_SHARE: f32 = 3.0;

/// Rays of a stream that walk in groups before [`GROUP_MIN_SHARE`] (or
/// [`CLOSEST_MIN_SHARE`]) decides for the others: two groups.
#[cfg(target_arch = "x86_64")]
const GROUP_PROBE: usize = 64;

/// Rays whose origins [`Scene::scattered`] compares.
#[cfg(target_arch = "x86_64")]
const SCATTER_PROBE: usize = 64;

/// How far apart, as a fraction of the scene box's diagonal, neighbouring
/// rays of a closest-hit stream start on average for [`Scene::scattered`]
/// to leave the stream interleaved (occlusion streams are always probed:
/// [`GROUP_MIN_SHARE`]). BENCH.md's random rays start about a diagonal
/// apart; a camera's diffuse bounces from neighbouring pixels, a few
/// thousandths except across silhouettes.
#[cfg(target_arch = "x86_64")]
const SCATTER_FRACTION: f32 = 0.0625;

/// When [`Scene::first_hits_in_groups`] walks rays in groups and when it
/// interleaves them: see there.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
struct GroupPolicy {
    min_share: f32,
    probe: usize,
    scatter: f32,
}

/// Rays a leaf visit of an occlusion stream's groups took on average
/// (over the groups before) from which the next group's leaves load each
/// block once for all the rays that reach it together
/// (`Primitives::intersect_block_rays`) rather than ray by ray. On the
/// 256² workloads of the dragon and the pig the visits took 4.6-4.7 rays
/// (primary), 4.4 (shadow), 1.9-2.2 (diffuse) and 1.0 (random); with
/// one ray or two a visit, the loops over the rays and their axis orders
/// cost more than the loads they save.
#[cfg(target_arch = "x86_64")]
const SHARED_LEAF_RAYS: f64 = 3.0;

#[cfg(target_arch = "x86_64")]
impl GroupPolicy {
    /// Any hits and occlusion.
    const ANY_HIT: Self = Self {
        min_share: GROUP_MIN_SHARE,
        probe: GROUP_PROBE,
        // Occlusion streams are never taken as scattered (see
        // GROUP_MIN_SHARE); `stream_in_groups` checks `any_hit_stream`'s
        // itself, whose groups gain less (random rays probed as occlusion
        // streams are, the one-ray leaf order kept: the pig 1.11, the
        // dragon 1.06, bunny00 0.93, the 600K sphere 0.94 times as fast
        // as interleaved, `raymesh-ab --stream`).
        scatter: f32::INFINITY,
    };
    /// Closest hits.
    const CLOSEST: Self = Self {
        min_share: CLOSEST_MIN_SHARE,
        probe: GROUP_PROBE,
        scatter: SCATTER_FRACTION,
    };
}

impl Scene<Triangles> {
    /// The fastest scene over an indexed mesh: its triangles as
    /// [`Triangles`] rows, with the structure of `kind` (default settings).
    #[must_use]
    pub fn from_mesh(mesh: &TriangleMesh, kind: AccelKind) -> Self {
        Self::from_mesh_with(mesh, kind, &BuildConfig::default())
    }

    /// [`Self::from_mesh`] with the given settings. A BVH is built from the
    /// mesh's own boxes and the rows are then gathered straight in its leaf
    /// order, so the rows never coexist with the builder's references and
    /// no copy in the mesh's order is made and permuted: the same scene as
    /// `Scene::build_with(Triangles::from_mesh(mesh), ..)`, with a lower
    /// memory peak and less work. For the wide BVHs over at most 2^18
    /// triangles the rows are gathered while the binary tree collapses
    /// into wide nodes (10 MB at most beside it, two short phases that
    /// then share the threads); larger meshes gather after the collapse.
    /// The other structures (the k-d tree, the grid) are built from the
    /// mesh's boxes too, and the rows gathered after the build, in the
    /// k-d tree's leaf order (a triangle once in each leaf it reaches) or
    /// the mesh's (the k-d builder's references, which carry boxes, are
    /// gone by then: a 1M-triangle terrain's k-d build peaked at 164 MiB
    /// instead of 200 in `raymesh scale`). The build time counts the
    /// gathering.
    #[must_use]
    pub fn from_mesh_with(mesh: &TriangleMesh, kind: AccelKind, config: &BuildConfig) -> Self {
        let start = Instant::now();
        let config = &leaf_blocks::<Triangles>(kind, config);
        let clip = |i, within, axis, pos| mesh.clip(i, within, axis, pos);
        // The rows keep each triangle's index: the order is not kept.
        let gather = |order: &[u32]| Triangles::from_mesh_in_order(mesh, order);
        let bounds_of = |i| mesh.bounds(i);
        let built = Accel::build_bvh_gathering(kind, mesh.len(), &bounds_of, &clip, config, gather);
        let (accel, prims, bounds) = match built {
            Some((accel, prims)) => {
                let bounds = accel.bounds();
                (accel, prims, bounds)
            }
            None => {
                // The other structures built first, from the mesh's own
                // boxes, then the rows gathered: they never coexist with
                // the k-d builder's references.
                let (mut accel, bounds) =
                    build_not_bvh(kind, mesh.len(), &bounds_of, &clip, config);
                // A k-d tree's leaves become runs of rows, in its order
                // (a triangle its planes cut once in each leaf it reaches).
                let prims = match accel.leaf_order() {
                    Some(order) => {
                        let prims = Triangles::from_mesh_in_order(mesh, order);
                        accel.take_leaf_order();
                        prims
                    }
                    None => Triangles::from_mesh(mesh),
                };
                (accel, prims, bounds)
            }
        };
        // A BVH's leaves are blocks of the rows, and a k-d tree's where
        // it gave its order; the grid's lists name the triangles by index.
        let leaf_order = match &accel {
            Accel::KdTree(k) => k.names_slots(),
            a => a.leaf_order().is_some(),
        };
        Self {
            prims,
            accel,
            bounds,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
            leaf_order,
            original: None,
        }
    }
}

impl<P: Primitives> Surface for Scene<P> {
    fn bounds(&self) -> Aabb {
        self.bounds
    }
    #[inline]
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.intersect_counted(ray, &mut NoStats)
    }
    #[inline]
    fn occluded(&self, ray: &Ray) -> bool {
        self.occluded_counted(ray, &mut NoStats)
    }
    fn intersect8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        Scene::intersect8(self, rays)
    }
    fn occluded8(&self, rays: &[Ray; LANES]) -> [bool; LANES] {
        Scene::occluded8(self, rays)
    }
    fn intersect_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        Scene::intersect_stream(self, rays, out);
    }
    fn occluded_stream(&self, rays: &[Ray], out: &mut [bool]) {
        Scene::occluded_stream(self, rays, out);
    }
    fn intersect_count(&self, ray: &Ray, stats: &mut CountStats) -> Option<Hit> {
        self.intersect_counted(ray, stats)
    }
}

/// The leaf of [`Scene::walk_packet`]'s walk: the scene, the packet and
/// each lane's hit so far. With `ANY`, a lane that has one is done, its
/// bound set to -inf, which every later box and triangle test of the lane
/// fails.
struct WalkLeaf<'a, 'r, P, const ANY: bool> {
    scene: &'a Scene<P>,
    p: &'a Packet8<'r>,
    best: [Option<(u32, PrimHit)>; LANES],
}

impl<P: Primitives, const ANY: bool> PacketLeaf for WalkLeaf<'_, '_, P, ANY> {
    #[inline(always)]
    fn prefetch(&self, first: u32) {
        self.scene.prims.prefetch_block(first);
    }
    #[inline(always)]
    fn visit(
        &mut self,
        avx: Option<Avx2>,
        first: u32,
        count: u32,
        lanes: u32,
        tmax: &mut [f32; LANES],
    ) {
        let (scene, p, best) = (self.scene, self.p, &mut self.best);
        // A leaf tested lane by lane takes one block test per lane and
        // block; triangle by triangle, one packet test per primitive.
        // Fine meshes make leaves that few lanes reach: then the first,
        // up to twice as many block tests as triangles (a block test is
        // the cheaper: `raymesh-ab --packets`, primary rays, against
        // as many: bunny00 +0-1%, the dragon +4-5%, the pig +5-7%,
        // polygon_mesh +3-5%, bunny00's shadow rays +9%; three times:
        // the dragon -4%).
        if lanes.count_ones() * count.div_ceil(BLOCK as u32) < 2 * count {
            // Inside the walk's AVX2 code, each block loaded once for the
            // lanes and tested with each lane's constants.
            #[cfg(target_arch = "x86_64")]
            if let Some(avx) = avx {
                scene.leaf_blocks::<ANY>(avx, p, (first, count, lanes), tmax, best);
                return;
            }
            let _ = avx;
            scene.leaf_lanes::<ANY>(p, (first, count, lanes), tmax, best);
            return;
        }
        let mut offer = |i: usize, prim, h, tmax: &mut [f32; LANES]| {
            if !ANY {
                scene.offer(&mut best[i], &mut tmax[i], prim, h);
            } else if best[i].is_none() {
                best[i] = Some((prim, h));
                tmax[i] = f32::NEG_INFINITY;
            }
        };
        #[cfg(target_arch = "x86_64")]
        if let Some(avx) = avx {
            scene
                .prims
                .intersect_packet_tris(avx, first, count, p, lanes, ANY, tmax, &mut offer);
            return;
        }
        scene
            .prims
            .intersect_packet_run(first, count, p, lanes, tmax, &mut offer);
    }
}

/// A BVH of any width, for the block traversal.
#[derive(Clone, Copy)]
enum WideRef<'a> {
    W2(&'a Bvh),
    W4(&'a Bvh4),
    W8(&'a Bvh8),
}

impl WideRef<'_> {
    #[inline(always)]
    fn traverse_blocks<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        self.traverse_blocks_in(true, ray, counter, block);
    }

    /// [`Self::traverse_blocks`] for any-hit queries: the wide trees skip
    /// ordering the children they enter.
    fn traverse_blocks_unordered<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        self.traverse_blocks_in(false, ray, counter, block);
    }

    #[inline(always)]
    fn traverse_blocks_in<C: RayCounter>(
        &self,
        ordered: bool,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        if !ray.is_valid() {
            return;
        }
        match (self, ordered) {
            (Self::W2(b), _) => b.traverse_blocks(ray, counter, block),
            (Self::W4(b), true) => b.traverse_blocks(ray, counter, block),
            (Self::W4(b), false) => b.traverse_blocks_unordered(ray, counter, block),
            (Self::W8(b), true) => b.traverse_blocks(ray, counter, block),
            (Self::W8(b), false) => b.traverse_blocks_unordered(ray, counter, block),
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::test_util::xorshift;
    use crate::Spheres;
    use raymesh_geometry::Sphere;

    /// A packed walk result gives back the primitive and hit it was made
    /// from, bit for bit, over the values a hit may hold (any index, a
    /// `t` of zero, minus zero, a subnormal, the largest float or
    /// infinity); no hit stays no hit; and only an undone walk reads as
    /// undone, whatever the primitive of a hit.
    #[test]
    fn packed_hits_unpack_to_what_they_were_made_from() {
        let bits =
            |x: Option<(u32, PrimHit)>| x.map(|(p, h)| (p, [h.t, h.u, h.v].map(f32::to_bits)));
        let ts = [
            0.0,
            -0.0,
            f32::from_bits(1),
            0.5,
            f32::MAX,
            f32::INFINITY,
            -3.0,
        ];
        let uvs = [0.0, -0.0, 0.25, 1.0, f32::from_bits(0xffff_ffff)];
        for prim in [0, 1, 2, 0x7fc0_0000, u32::MAX - 1, u32::MAX] {
            for (i, &t) in ts.iter().enumerate() {
                let (u, v) = (uvs[i % uvs.len()], uvs[(i + 2) % uvs.len()]);
                let hit = Some((prim, PrimHit { t, u, v }));
                let packed = PackedHit::found(hit);
                assert!(!packed.is_undone());
                assert!(!PackedHit::new(true, hit).is_undone());
                assert_eq!(bits(packed.hit()), bits(hit), "prim {prim} t {t}");
                assert_eq!(bits(PackedHit::new(true, hit).hit()), bits(hit));
                assert!(PackedHit::new(false, hit).is_undone());
            }
        }
        assert_eq!(bits(PackedHit::found(None).hit()), None);
        assert!(!PackedHit::found(None).is_undone());
        assert!(PackedHit::new(false, None).is_undone());
        assert!(PackedHit::UNDONE.is_undone() && !PackedHit::NONE.is_undone());
    }

    /// A closed-ish cloud of small triangles around the unit cube, and
    /// rays of every kind an occlusion stream meets: random (from inside
    /// and outside the cloud), from points on triangles (as diffuse and
    /// shadow rays start), camera runs that make packets, short ones, and
    /// invalid ones.
    fn cloud_and_rays() -> (TriangleMesh, Vec<Ray>) {
        let mut f = xorshift(17);
        let mut v = move || Vec3::new(f(), f(), f()) * 2.0 - Vec3::ONE;
        let mut positions = Vec::new();
        for _ in 0..3000 {
            let c = v();
            positions.extend([c, c + v() * 0.08, c + v() * 0.08]);
        }
        let triangles = (0..3000).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        let mut rays = Vec::new();
        for i in 0..600 {
            let d = v();
            rays.push(Ray::new(
                v() * 1.5,
                d,
                0.0,
                if i % 4 == 3 { 0.3 } else { f32::INFINITY },
            ));
            let p = positions[(i * 7) % positions.len()];
            rays.push(Ray::new(p, v(), 1e-4, f32::INFINITY));
            if i % 40 == 0 {
                let o = Vec3::new(-3.0, 0.1 * v().y, 0.1 * v().z);
                for k in 0..16 {
                    let j = Vec3::new(0.0, k as f32 * 0.01, (k % 4) as f32 * 0.01);
                    rays.push(Ray::infinite(o, Vec3::new(1.0, 0.02, 0.03) + j));
                }
            }
        }
        rays.push(Ray::infinite(Vec3::NAN, Vec3::X));
        rays.push(Ray::infinite(Vec3::ZERO, Vec3::ZERO));
        (TriangleMesh::new(positions, triangles), rays)
    }

    /// A k-d tree over triangles stores them in its leaf order, a
    /// triangle once in each leaf that holds it (so its leaves are tested
    /// as blocks of rows), whether the scene is made from the mesh or from
    /// rows given whole, and the hits are brute force's, with the indices
    /// the user gave; over an indexed mesh or spheres, which have no block
    /// test, the tree keeps its lists instead of copies.
    #[test]
    fn kd_trees_over_triangles_test_their_leaves_as_blocks() {
        let (m, rays) = cloud_and_rays();
        let brute = Scene::build(m.clone(), AccelKind::Brute);
        let check = |kd: &dyn Fn() -> bool, len: usize, hit: &dyn Fn(&Ray) -> Option<BareHit>| {
            assert!(kd(), "the k-d tree's leaves are not runs of slots");
            assert!(len > m.len(), "{len} stored for {} triangles", m.len());
            for r in &rays {
                let (want, got) = (brute.intersect_bare(r), hit(r));
                assert_eq!(
                    want.map(|h| (h.prim, h.t.to_bits())),
                    got.map(|h| (h.prim, h.t.to_bits()))
                );
            }
        };
        let a = Scene::from_mesh(&m, AccelKind::KdTree);
        check(&|| a.kd_slots().is_some(), a.prims().len(), &|r| {
            a.intersect_bare(r)
        });
        let b = Scene::build(Triangles::from_mesh(&m), AccelKind::KdTree);
        check(&|| b.kd_slots().is_some(), b.prims().len(), &|r| {
            b.intersect_bare(r)
        });
        // An indexed mesh and spheres: no block test.
        let c = Scene::build(m.clone(), AccelKind::KdTree);
        assert!(c.kd_slots().is_none());
        assert_eq!(c.prims().len(), m.len());
        let spheres = Spheres(
            (0..m.len() as u32)
                .map(|i| Sphere::new(m.corners(i)[0], 0.01))
                .collect(),
        );
        let d = Scene::build(spheres, AccelKind::KdTree);
        assert!(d.kd_slots().is_none());
        assert_eq!(d.prims().len(), m.len());
    }

    /// Occlusion streams, and streams in groups for any and closest hits,
    /// give each ray's one-ray answer whichever way their rays go: all in
    /// groups, all interleaved after a probe of none, the switch after the
    /// usual probe, all interleaved as scattered, and the default
    /// policies, over streams of several lengths.
    #[test]
    fn stream_groups_give_the_one_ray_answers() {
        let Some(avx) = Avx2::detect() else { return };
        let (m, rays) = cloud_and_rays();
        let s = Scene::from_mesh(&m, AccelKind::Bvh8);
        let Some(WideRef::W8(bvh)) = s.wide_blocks() else {
            panic!("an 8-wide BVH in leaf order");
        };
        let want: Vec<bool> = rays.iter().map(|r| s.occluded(r)).collect();
        assert!(want.iter().any(|&w| w) && want.iter().any(|&w| !w));
        let policy = |min_share, probe, scatter| GroupPolicy {
            min_share,
            probe,
            scatter,
        };
        let never = f32::INFINITY;
        for policy in [
            policy(0.0, 0, never),
            policy(never, 0, never),
            policy(never, GROUP_PROBE, never),
            policy(0.0, 0, 0.0),
            GroupPolicy::ANY_HIT,
            GroupPolicy::CLOSEST,
        ] {
            for n in [rays.len(), 1000, 97, 33, 8, 1, 0] {
                let mut got = vec![true; n];
                s.occluded_in_groups(bvh, avx, &rays[..n], &mut got, policy);
                for i in 0..n {
                    assert_eq!(got[i], want[i], "ray {i} of {n}, {policy:?}: {:?}", rays[i]);
                }
                // And the hits: each ray's one-ray any hit and closest hit,
                // bit for bit.
                let all: Vec<usize> = (0..n).collect();
                for any_hit in [true, false] {
                    let mut hits = vec![None; n];
                    s.first_hits_in_groups(
                        bvh,
                        avx,
                        &rays[..n],
                        &all,
                        any_hit,
                        policy,
                        &mut |i, f| {
                            hits[i] = Some(f);
                        },
                    );
                    for i in 0..n {
                        let bits = |t: f32, u: f32, v: f32| [t.to_bits(), u.to_bits(), v.to_bits()];
                        let got = hits[i].map(|(_, index, h)| (index, bits(h.t, h.u, h.v)));
                        let one = if any_hit {
                            s.any_hit(&rays[i])
                        } else {
                            s.intersect(&rays[i])
                        };
                        let one = one.map(|h| (h.prim, bits(h.t, h.u, h.v)));
                        assert_eq!(got, one, "any hit {any_hit}, ray {i} of {n}, {policy:?}");
                    }
                }
            }
        }
    }
}
