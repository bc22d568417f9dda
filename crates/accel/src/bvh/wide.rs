//! Wide BVHs collapsed from a binary one: each node holds its `W`
//! children's boxes as structure-of-arrays (whole cache lines), so one node
//! visit tests `W` boxes together, and a ray makes far fewer dependent
//! memory reads than in the binary tree (Wald, Benthin & Boulos, "Getting
//! rid of packets", 2008; Dammertz et al., "Shallow bounding volume
//! hierarchies", 2008). `Bvh4` tests its boxes in plain loops the compiler
//! vectorizes; `Bvh8` uses the AVX kernel of [`crate::simd`] where the CPU
//! has AVX2, and the same plain loops elsewhere.

use super::{each_prim, Bvh};
use crate::packet::{self, Frustum, Packet8, PacketLeaf, LANES};
use crate::prims::BLOCK;
use crate::simd::{self, Avx2};
use crate::{AccelStats, Leaf, RayCounter};
use raymesh_geometry::{
    cull_bound, exit_reciprocal, max_nan_second as max_ns, min_nan_second as min_ns, Aabb, Ray,
    Vec3,
};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// `W` children: boxes by axis and lane, and for each child either a node
/// index (`count == 0`) or a leaf's first primitive slot and count. An
/// empty slot has an empty box (`min = +inf`, `max = -inf`), which no ray
/// hits. 128 bytes for `W = 4`, 256 for `W = 8`: whole cache lines.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct WideNode<const W: usize> {
    min: [[f32; W]; 3],
    max: [[f32; W]; 3],
    child: [u32; W],
    count: [u32; W],
}

/// A node of [`Bvh4`].
pub type Node4 = WideNode<4>;
/// A node of [`Bvh8`].
pub type Node8 = WideNode<8>;

const _: () = assert!(std::mem::size_of::<Node4>() == 128);
const _: () = assert!(std::mem::size_of::<Node8>() == 256);

impl<const W: usize> WideNode<W> {
    const EMPTY: Self = Self {
        min: [[f32::INFINITY; W]; 3],
        max: [[f32::NEG_INFINITY; W]; 3],
        child: [u32::MAX; W],
        count: [0; W],
    };

    /// A node with every slot empty.
    #[cfg(all(
        test,
        any(
            target_arch = "x86_64",
            all(target_arch = "aarch64", target_feature = "neon")
        )
    ))]
    pub(crate) fn empty() -> Self {
        Self::EMPTY
    }

    /// Pointers to the three rows of lower bounds (x, y, z), `W` floats each.
    #[cfg(target_arch = "x86_64")]
    pub(crate) fn min_rows(&self) -> [*const f32; 3] {
        [
            self.min[0].as_ptr(),
            self.min[1].as_ptr(),
            self.min[2].as_ptr(),
        ]
    }

    /// Pointers to the three rows of upper bounds (x, y, z), `W` floats each.
    #[cfg(target_arch = "x86_64")]
    pub(crate) fn max_rows(&self) -> [*const f32; 3] {
        [
            self.max[0].as_ptr(),
            self.max[1].as_ptr(),
            self.max[2].as_ptr(),
        ]
    }

    /// The row of bounds that starts `offset` floats into an 8-wide node
    /// ([`BoxRay::near`]'s offsets, whatever `W`): lower bounds of axis
    /// `offset / 8` below 24, upper bounds of axis `offset / 8 - 3` from
    /// there.
    #[inline(always)]
    pub(crate) fn plane_row(&self, offset: usize) -> &[f32; W] {
        let r = offset / 8;
        if r < 3 {
            &self.min[r]
        } else {
            &self.max[(r - 3).min(2)]
        }
    }

    pub(crate) fn set_box(&mut self, i: usize, b: Aabb) {
        for a in 0..3 {
            self.min[a][i] = b.min[a];
            self.max[a][i] = b.max[a];
        }
    }

    /// A node whose first children have `boxes` (at most `W`; the rest
    /// empty) and point nowhere: for testing and benchmarking the node
    /// test on its own ([`Self::slab`]).
    ///
    /// # Panics
    /// If more than `W` boxes are given.
    #[must_use]
    pub fn from_boxes(boxes: &[Aabb]) -> Self {
        assert!(boxes.len() <= W, "a {W}-wide node holds at most {W} boxes");
        let mut n = Self::EMPTY;
        for (i, b) in boxes.iter().enumerate() {
            n.set_box(i, *b);
            n.child[i] = 0;
            n.count[i] = 1;
        }
        n
    }

    /// One traversal step: the slab test of all `W` child boxes against a
    /// ray, clipped to `[ray's tmin, tmax]`. Returns a bit per child the ray
    /// enters and each child's entry distance. Uses the AVX2 kernel for
    /// 8-wide nodes and the SSE one for 4-wide nodes where the CPU has
    /// AVX2 (the NEON ones on aarch64) and [`crate::set_simd_enabled`]
    /// allows it, the portable loop otherwise (bit-identical results).
    #[must_use]
    pub fn slab(&self, ray: &BoxRay, tmax: f32) -> (u32, [f32; W]) {
        let mut t = [0.0f32; W];
        let bound = cull_bound(tmax);
        #[cfg(target_arch = "x86_64")]
        if (W == 8 || W == 4) && simd::has_avx2() {
            let mask = simd::with_avx2(|| simd::slab_wide(self, ray, bound, &mut t));
            return (mask, t);
        }
        #[cfg(all(target_arch = "aarch64", target_feature = "neon"))]
        if (W == 8 || W == 4) && simd::simd_enabled() {
            return (crate::neon::slab_wide(self, ray, bound, &mut t), t);
        }
        (slab_scalar(self, ray, bound, &mut t), t)
    }

    /// The rows of lower (`upper == false`) or upper bounds, by axis.
    #[cfg(test)]
    pub(crate) fn rows(&self, upper: bool) -> [[f32; W]; 3] {
        if upper {
            self.max
        } else {
            self.min
        }
    }

    /// [`crate::packet::frustum`] of this node's boxes, with the AVX
    /// kernel for 8-wide nodes where the CPU has it (the same bits).
    #[inline(always)]
    pub(crate) fn frustum(&self, f: &Frustum, neg: [bool; 3], bound: f32) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if W == 8 && simd::has_avx2() {
            return simd::frustum8(self, f, neg, bound);
        }
        packet::frustum(f, neg, &self.min, &self.max, bound)
    }

    /// [`Self::frustum`] for a packet walk's node, bounded by the
    /// greatest `bound` of the active `lanes`: with the walk's AVX2 proof
    /// `avx`, both in AVX2 with no CPU check (the fold over the lanes, a
    /// branch and a dependent `max` a lane, and the node test's two
    /// checks took 5-8% of a closest-hit packet walk's samples).
    #[inline(always)]
    pub(crate) fn frustum_in(
        &self,
        avx: Option<Avx2>,
        f: &Frustum,
        neg: [bool; 3],
        bound: &[f32; LANES],
        lanes: u32,
    ) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if let (Some(avx), 8) = (avx, W) {
            let b = simd::masked_max8(avx, bound, lanes);
            return simd::frustum8_in(avx, self, f, neg, b);
        }
        let _ = avx;
        self.frustum(f, neg, packet::masked_max(bound, lanes))
    }

    fn child_box(&self, i: usize) -> Aabb {
        Aabb::new(
            Vec3::new(self.min[0][i], self.min[1][i], self.min[2][i]),
            Vec3::new(self.max[0][i], self.max[1][i], self.max[2][i]),
        )
    }

    fn is_used(&self, i: usize) -> bool {
        self.child[i] != u32::MAX
    }
}

/// [`WideBvh::root_leaves_each`]'s loop over the rays: `test(box_ray,
/// tmax)` is the root's slab test (generic, so that an AVX2 kernel inlines into
/// the loop; through `&dyn Fn` it stayed a call), `bits` each child's
/// primitives, `deeper` the children that make a ray take `fallback`.
#[inline(always)]
fn root_masks<const W: usize>(
    rays: &[Ray],
    bits: &[u64; W],
    deeper: u32,
    fallback: &impl Fn(&Ray) -> u64,
    mut test: impl FnMut(&BoxRay, f32) -> u32,
) -> Vec<u64> {
    rays.iter()
        .map(|ray| {
            if !ray.is_valid() {
                return 0;
            }
            let mut entered = test(&BoxRay::new(ray), ray.tmax());
            if entered & deeper != 0 {
                return fallback(ray);
            }
            let mut m = 0u64;
            while entered != 0 {
                m |= bits[entered.trailing_zeros() as usize % W];
                entered &= entered - 1;
            }
            m
        })
        .collect()
}

/// A `W`-wide BVH sharing its binary source's leaves and permutation.
#[derive(Clone, Debug, Default)]
pub struct WideBvh<const W: usize> {
    nodes: Vec<WideNode<W>>,
    prim_ids: Vec<u32>,
    bounds: Aabb,
}

/// 4-wide BVH: four boxes per node, tested together.
pub type Bvh4 = WideBvh<4>;
/// 8-wide BVH: eight boxes per node, tested with one AVX instruction per
/// step where the CPU has AVX2 (see [`WideNode::slab`]).
pub type Bvh8 = WideBvh<8>;

impl<const W: usize> WideBvh<W> {
    /// Collapses a binary BVH into `W`-wide nodes, choosing which binary
    /// nodes become wide nodes, which become slots and which small subtrees
    /// become one wide leaf by dynamic programming over the SAH cost of the
    /// wide tree (Ylitie, Karras & Laine, "Efficient incoherent ray
    /// traversal on GPUs through compressed wide BVHs", HPG 2017). Nodes end
    /// up fuller and fewer than by greedily opening the largest child.
    #[must_use]
    pub fn from_binary(mut bin: Bvh) -> Self {
        const { assert!(W >= 2 && W <= 8, "W choices of 4 bits fill 32 bits") };
        let mut out = Self {
            nodes: Vec::new(),
            prim_ids: std::mem::take(&mut bin.prim_ids),
            bounds: bin.bounds(),
        };
        if bin.pairs.is_empty() {
            return out;
        }
        // Read the binary nodes where they lie (no copy of them): the
        // collapse's peak is the binary tree, its plan (8 bytes a node)
        // and the wide tree.
        let plan = Plan::<W>::new(&bin);
        let root = bin.node(0);
        if plan.choice(0)[0] == 0 {
            let (first, count) = leaf_range(&bin, 0).expect("a leaf choice has a range");
            let mut n = WideNode::<W>::EMPTY;
            n.set_box(0, root.bounds());
            n.child[0] = first;
            n.count[0] = count;
            out.nodes.push(n);
        } else {
            // The plan knows how many wide nodes each subtree makes, so
            // subtrees fill their own parts of the final array in
            // parallel: the same nodes, in the same (depth-first) order,
            // as one walk makes, with no array grown or copied.
            out.nodes = (0..plan.wide_nodes(0))
                .into_par_iter()
                .map(|_| WideNode::<W>::EMPTY)
                .collect();
            emit(&plan, 0, 0, &mut out.nodes);
        }
        out
    }

    /// The primitive permutation (see [`Bvh::prim_ids`]).
    #[must_use]
    pub fn prim_ids(&self) -> &[u32] {
        &self.prim_ids
    }

    pub(crate) fn take_prim_ids(&mut self) -> Vec<u32> {
        std::mem::take(&mut self.prim_ids)
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub(crate) fn stats(&self) -> AccelStats {
        let root_area = self.bounds.half_area() as f64;
        let rel = |b: Aabb| {
            if root_area > 0.0 {
                b.half_area() as f64 / root_area
            } else {
                1.0
            }
        };
        let (mut leaves, mut depth, mut sah) = (
            0usize,
            0usize,
            if self.nodes.is_empty() { 0.0 } else { 1.0 },
        );
        // The root's test, then one per inner child entered.
        let (mut node_tests, mut leaf_tests) = (sah, 0.0);
        let mut stack = if self.nodes.is_empty() {
            vec![]
        } else {
            vec![(0usize, 1usize)]
        };
        while let Some((i, d)) = stack.pop() {
            let n = &self.nodes[i];
            for k in (0..W).filter(|&k| n.is_used(k)) {
                if n.count[k] > 0 {
                    leaves += 1;
                    depth = depth.max(d);
                    sah += rel(n.child_box(k)) * n.count[k] as f64;
                    leaf_tests += rel(n.child_box(k)) * n.count[k].div_ceil(BLOCK as u32) as f64;
                } else {
                    sah += rel(n.child_box(k));
                    node_tests += rel(n.child_box(k));
                    stack.push((n.child[k] as usize, d + 1));
                }
            }
        }
        AccelStats {
            nodes: self.nodes.len(),
            leaves,
            depth,
            bytes: self.nodes.len() * std::mem::size_of::<WideNode<W>>() + self.prim_ids.len() * 4,
            sah_cost: sah,
            node_tests: Some(node_tests),
            leaf_tests: Some(leaf_tests),
            ..AccelStats::default()
        }
    }

    /// For each ray of `rays`, the primitives it reaches, as bits, where
    /// the tree is one level deep for it: what [`Self::traverse`] calls its
    /// leaf for, with a leaf that never lowers the ray's bound, when every
    /// child of the root that the ray enters is a leaf and every primitive
    /// there has an id below 64; `fallback(ray)` otherwise (the walk must
    /// go deeper). The root's test is the walk's own (`Self::slab`, the
    /// same bound), without the walk's set-up: a scene of a few instances
    /// asks this of every ray of a stream (`Instances`' stream masks).
    ///
    /// The root's children are read once for the stream (each leaf's bits,
    /// or that it is not one), and the rays' tests run in one AVX2 context
    /// where there is one: read per ray and dispatched per ray, they were
    /// 4.5% of a render of bunny00.
    pub(crate) fn root_leaves_each(
        &self,
        rays: &[Ray],
        fallback: impl Fn(&Ray) -> u64,
    ) -> Vec<u64> {
        let Some(root) = self.nodes.first() else {
            return vec![0; rays.len()];
        };
        // Each child's primitives as bits, and the children a ray must
        // not enter for the root to answer.
        let mut bits = [0u64; W];
        let mut deeper = 0u32;
        for c in 0..W {
            if !root.is_used(c) {
                continue;
            }
            if root.count[c] == 0 {
                deeper |= 1 << c;
                continue;
            }
            for slot in root.child[c]..root.child[c] + root.count[c] {
                match self.prim_ids.get(slot as usize) {
                    Some(&id) if id < 64 => bits[c] |= 1 << id,
                    None if self.prim_ids.is_empty() && slot < 64 => bits[c] |= 1 << slot,
                    _ => deeper |= 1 << c,
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        if W == 8 {
            if let Some(avx) = simd::Avx2::detect() {
                return avx.run(|| {
                    let mut t = [0.0f32; W];
                    root_masks(rays, &bits, deeper, &fallback, |r, tmax| {
                        simd::slab8(root, r, cull_bound(tmax), &mut t)
                    })
                });
            }
        }
        root_masks(rays, &bits, deeper, &fallback, |r, tmax| {
            root.slab(r, tmax).0
        })
    }

    /// Front-to-back traversal calling `leaf` per primitive (see
    /// [`Self::traverse_blocks`]).
    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        self.traverse_blocks(ray, counter, &mut each_prim(&self.prim_ids, ray, leaf));
    }

    /// Front-to-back traversal: the children a ray enters are pushed
    /// farthest first, so the nearest comes off the stack next. Each leaf
    /// reached calls `block(first, count)` with its slots in the primitive
    /// permutation, which returns the ray's new upper bound (`-inf` stops).
    /// Uses the AVX2 kernel for 8-wide nodes when the CPU has it.
    #[inline]
    pub(crate) fn traverse_blocks<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        self.traverse_blocks_in::<true, C>(ray, counter, block, &|_| {});
    }

    /// [`Self::traverse_blocks`] (or, not `ORDERED`,
    /// [`Self::traverse_blocks_unordered`]) of an 8-wide tree with the AVX2
    /// node test, or of a 4-wide one with the SSE node test
    /// ([`simd::slab_wide`]), for callers that run under [`Avx2::run`] already: the
    /// walk inlines into their AVX2 region, where the leaf test's ray
    /// constants are computed too, with no call between (bunny00, random
    /// rays: 1,144 -> 1,093 instructions a ray for closest hits, 1,008 ->
    /// 982 for any-hit queries, callgrind).
    ///
    /// Calls `prefetch_leaf(first)` for each leaf the walk pushes for
    /// later, as it prefetches the nodes it pushes: for triangles in leaf
    /// order, the block's group of rows
    /// ([`crate::Primitives::prefetch_block`]). Closest hits gain (random
    /// rays, one thread: bunny00 +2–5%, a 2M-triangle sphere +0–8%);
    /// any-hit queries, which leave most pushed leaves unvisited, lost
    /// 1–3% on bunny00's shadow rays and pass a no-op.
    ///
    /// Returns false, part way, where the ray has more items pending than
    /// the stack holds inline (a ray that enters most children at several
    /// levels of a deep tree): the caller then walks the ray again by
    /// [`Self::traverse_blocks`], whose stack spills to the heap. Moving
    /// items to and from the heap is a call, and any call in the walk's
    /// loop made the compiler keep the ray's constants in memory around
    /// it: without them, 1,035 -> 1,026 instructions a closest hit and
    /// 893 -> 881 an any-hit query (bunny00 random rays, callgrind).
    #[inline(always)]
    #[must_use]
    pub(crate) fn traverse_blocks_avx2<const ORDERED: bool, C: RayCounter>(
        &self,
        _avx: Avx2,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
    ) -> bool {
        const { assert!(W == 8 || W == 4, "the AVX2 walk is for 4- and 8-wide trees") };
        if self.nodes.is_empty() {
            return true;
        }
        // The proof stands for the CPU check of `slab8`'s kernel.
        #[cfg(target_arch = "x86_64")]
        let test = simd::slab_wide;
        #[cfg(not(target_arch = "x86_64"))]
        let test = slab_scalar;
        self.traverse_with::<ORDERED, false, C>(ray, counter, block, prefetch_leaf, test)
    }

    /// [`Self::traverse_blocks`] without ordering the children a ray
    /// enters, for any-hit queries, which stop at the first hit wherever
    /// it is: sorting costs more than it saves them (+10–25% on random
    /// any-hit rays). The bound `block` returns only ends the walk (when
    /// below the ray's `tmin`): children pushed before are visited
    /// whatever their entry, as an any-hit query, whose bound changes only
    /// to stop, needs.
    #[inline]
    pub(crate) fn traverse_blocks_unordered<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        self.traverse_blocks_in::<false, C>(ray, counter, block, &|_| {});
    }

    #[inline(always)]
    fn traverse_blocks_in<const ORDERED: bool, C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if (W == 8 || W == 4) && simd::has_avx2() {
            return simd::with_avx2(|| {
                self.traverse_with::<ORDERED, true, C>(
                    ray,
                    counter,
                    block,
                    prefetch_leaf,
                    simd::slab_wide,
                );
            });
        }
        #[cfg(all(target_arch = "aarch64", target_feature = "neon"))]
        if (W == 8 || W == 4) && simd::simd_enabled() {
            let test = crate::neon::slab_wide;
            if !self.traverse_with::<ORDERED, false, C>(ray, counter, block, prefetch_leaf, test) {
                self.walk_spilling::<ORDERED, C>(ray, counter, block, prefetch_leaf, test);
            }
            return;
        }
        // A closure, not the function itself: passed as a function item,
        // it became a call per node (LLVM did not inline its `Fn` shim;
        // bunny00 random rays, bvh4: 1,571 -> 1,437 instructions a ray).
        let test =
            |n: &WideNode<W>, r: &BoxRay, bound, t: &mut [f32; W]| slab_scalar(n, r, bound, t);
        // As the AVX2 walk: the stack inline, and a ray that would spill it
        // walks again by the spilling walk, a cold function of its own (in
        // this one, the walk inlined `block` no more: +9% instructions).
        // bunny00 random rays, bvh4, callgrind: 1,405 -> 1,350 instructions
        // a closest hit, 1,221 -> 1,181 an any-hit query.
        if !self.traverse_with::<ORDERED, false, C>(ray, counter, block, prefetch_leaf, test) {
            self.walk_spilling::<ORDERED, C>(ray, counter, block, prefetch_leaf, test);
        }
    }

    /// [`Self::traverse_with`] with a stack that spills, for the rays the
    /// inline stack could not hold, from the start again (with counts on,
    /// the first try's visits count too).
    #[cold]
    #[inline(never)]
    fn walk_spilling<const ORDERED: bool, C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &BoxRay, f32, &mut [f32; W]) -> u32,
    ) {
        self.traverse_with::<ORDERED, true, C>(ray, counter, block, prefetch_leaf, test);
    }

    /// The traversal loop, generic over the node test (`test(node, ray,
    /// bound, entries) -> hit mask`); `ORDERED` visits entered children
    /// nearest first. The nodes are read through a local slice, so that
    /// each visit checks its index once. Without `SPILL` the stack stays
    /// inline, and a ray that would spill it stops: the walk returns
    /// false (see [`Self::traverse_blocks_avx2`]); else true.
    #[inline(always)]
    fn traverse_with<const ORDERED: bool, const SPILL: bool, C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &BoxRay, f32, &mut [f32; W]) -> u32,
    ) -> bool {
        let nodes: &[WideNode<W>] = &self.nodes;
        let r = BoxRay::new(ray);
        let tmin = ray.tmin();
        // The bound boxes are culled against, `cull_bound` of the best
        // hit's `t`: kept up to date at each leaf rather than recomputed at
        // every node and pop.
        let mut bound = cull_bound(ray.tmax());
        // After a spill the inline part must take a whole node's pushes,
        // or the walk would spill forever.
        const { assert!(W <= INLINE) };
        let mut items = [Entry::NONE; INLINE];
        let mut stack = WalkStack::new(&mut items);
        // The item being visited: the nearest child entered goes straight
        // here instead of through the stack (one push and pop fewer per
        // node), the others onto the stack farthest first.
        let mut cur = Entry {
            child: 0,
            count: 0,
            entry: tmin,
        };
        loop {
            // Nodes, in an inner loop of their own that makes no call (the
            // stack's inline part has room for a node's pushes, and pops
            // come from it). (With a growing `Vec` push in the loop, every
            // node reloaded the node test's ray constants from memory: +6%
            // instructions a ray on bunny00.) In the AVX2 one-ray walks,
            // whose leaf kernel inlines into the same loop, LLVM still
            // broadcasts the ten ray constants from stack slots and reloads
            // the six row offsets at every node (55 instructions from the
            // loop's head to the mask); kept in registers (31 or 37, the
            // ray form re-read after each leaf through `black_box`, or this
            // loop as an AVX2 function of its own), rays ran slower:
            // 0.79-0.97x (docs/measurements.md, stop 62's bullet).
            let mut emptied = false;
            while cur.count == 0 {
                if !stack.has_room(W - 1) {
                    break;
                }
                counter.node();
                let i = cur.child as usize;
                let mut t = [0.0f32; W];
                let n = &nodes[i];
                let mask = test(n, &r, bound, &mut t);
                match enter::<ORDERED, W>(nodes, n, mask, &t, &mut stack, prefetch_leaf) {
                    Some(e) => cur = e,
                    None => {
                        if let Some(e) = stack.pop_inline::<ORDERED>(bound) {
                            cur = e;
                            continue;
                        }
                        emptied = true;
                        break;
                    }
                }
            }
            if !emptied {
                if cur.count == 0 {
                    // A node, but too little room inline for its pushes.
                    if !SPILL {
                        return false;
                    }
                    stack.spill();
                    continue;
                }
                // A leaf.
                for _ in 0..cur.count {
                    counter.prim();
                }
                let tmax = block(cur.child, cur.count);
                if tmax < tmin {
                    return true;
                }
                bound = cull_bound(tmax);
            }
            let next = if SPILL {
                stack.pop::<ORDERED>(bound)
            } else {
                stack.pop_inline::<ORDERED>(bound)
            };
            let Some(e) = next else {
                return true;
            };
            cur = e;
        }
    }
}

/// Rays a wide stream traversal ([`WideBvh::traverse_stream`]) keeps in
/// flight over a tree of fewer than [`LARGE_TREE_BYTES`] of nodes, and
/// over a larger one. More rays hide longer waits on memory (each ray's
/// next node or leaf is prefetched a round ahead, so more rays mean more
/// fetches under way at once), but the branch predictor then sees more
/// rays' branches interleaved and each ray's state leaves registers.
/// Pinned, random rays, Mrays/s with two / four: bunny00 (0.7 MB of
/// nodes) 3.59–3.98 / 3.29–3.52 (one by one 3.41–3.78), a 600K-triangle
/// sphere (4.7 MB) 1.80–1.95 / 1.89–2.16, a 2M-triangle one (16 MB)
/// 1.44–1.51 / 1.50–1.73. Twelve over large trees, `raymesh-ab --stream`
/// on 262K random rays (closest / any-hit, against four): the 2M-triangle
/// sphere 1.14 / 1.23 (`bvh4` 1.29 / 1.31; 16 lanes 1.01 / 1.05 against
/// 8, 12 lanes 1.05 / 1.08 against 8), 600K 1.09 / 1.11, 250K (2 MB,
/// against two) 1.20 / 1.21. Over small trees two stay: on bunny00 four
/// lanes ran 0.98 / 1.00 of two on random rays and 0.93 / 0.93 on
/// diffuse ones, eight 0.95 / 1.01 and 0.86 / 0.93.
const STREAM_LANES: [usize; 2] = [2, 12];

/// Bytes of nodes from which a wide stream keeps more rays in flight:
/// past about the core's L2, node fetches start to miss it. Twelve lanes
/// against two on random rays: a 100K-triangle sphere (0.76 MB of nodes)
/// 1.07 / 1.03, a 250K one (2 MB) 1.20 / 1.21 (bunny00, 0.66 MB: above).
const LARGE_TREE_BYTES: usize = 1 << 20;

/// Bytes of nodes below which an 8-wide tree's streams trace the rays
/// they would interleave one after another instead, on a CPU with AVX2
/// ([`WideBvh::node_bytes`]; `Scene::stream_each`): half the core's L2
/// ([`l2_bytes`]). The tree then sits well within the L2 with room for
/// leaves, its nodes come from there without the waits interleaving
/// hides, and the one-ray walk, compiled in one AVX2 region with the
/// leaf test inlined, takes less work a ray.
///
/// Measured on two cores. A Zen 3 (512 KiB of L2: this was 256 KiB for
/// every CPU then), `raymesh-ab --stream --workload random --size 512
/// --query closest` (262K rays, pinned, against f5aaeec): the pig (143
/// KiB of nodes) 1.08, the dragon (178 KiB) 1.09, the elephant (38 KiB)
/// 1.07, 12K-, 20K- and 30K-triangle spheres (94, 157, 236 KiB) 1.04,
/// 1.06, 1.03; past it one by one lost: polygon_mesh (295 KiB) 1.00, a
/// 45K-triangle sphere (357 KiB) 1.00, 60K (472 KiB) 0.97, bunny00 (680
/// KiB) 0.98, 100K (777 KiB) 0.93; any hits, one by one, the meshes
/// 1.01–1.04, the spheres 0.97–0.99. A Zen 4 (1 MiB of L2; stop 78,
/// `raymesh-ab --stream --workload random --size 512 --query
/// closest,any-hit`, interleaved against one by one): the pig 0.86 /
/// 0.88, a 30K-triangle sphere (236 KiB) 0.89 / 0.90, 60K (472 KiB) 0.95
/// / 1.00, bunny00 (680 KiB) 0.96 / 1.01, 100K (777 KiB) 1.01 / 1.01, 150K
/// (1.2 MiB) 1.12 / 1.21, 250K (2 MiB) 1.28 / 1.29. Interleaving starts
/// to pay past about three quarters of the L2 on both; half leaves a
/// margin. (`bvh4`'s one-ray walk, without the AVX2 region, lost 2–3%
/// one by one on the pig and the dragon.)
#[cfg(target_arch = "x86_64")]
pub(crate) fn small_tree_bytes() -> usize {
    l2_bytes() / 2
}

/// The L2 cache of the CPU's first core in bytes, as Linux reports it
/// (`/sys/devices/system/cpu/cpu0/cache/index*/`: the level-2 data or
/// unified cache), read once; 512 KiB where it reports none (another
/// system, or an odd value), the size the first threshold was measured
/// on.
#[cfg(target_arch = "x86_64")]
fn l2_bytes() -> usize {
    static L2: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *L2.get_or_init(|| read_l2_bytes().unwrap_or(512 << 10))
}

#[cfg(target_arch = "x86_64")]
fn read_l2_bytes() -> Option<usize> {
    let dir = std::path::Path::new("/sys/devices/system/cpu/cpu0/cache");
    (0..8).find_map(|i| {
        let index = dir.join(format!("index{i}"));
        let read = |name: &str| std::fs::read_to_string(index.join(name)).ok();
        if read("level")?.trim() != "2" || read("type")?.trim() == "Instruction" {
            return None;
        }
        parse_cache_size(&read("size")?)
    })
}

/// A cache size as Linux writes it (`1024K`, `2M`, or bytes), within 64
/// KiB and 8 MiB (a core's L2 on today's x86-64 CPUs is 256 KiB to 2
/// MiB; a larger figure is likely a shared cache a virtual machine
/// reports as L2, and would keep large trees from interleaving), or
/// `None`.
#[cfg(any(target_arch = "x86_64", test))]
fn parse_cache_size(s: &str) -> Option<usize> {
    let s = s.trim();
    let (digits, unit) = match s.strip_suffix(['K', 'k']) {
        Some(d) => (d, 1 << 10),
        None => match s.strip_suffix(['M', 'm']) {
            Some(d) => (d, 1 << 20),
            None => (s, 1),
        },
    };
    let bytes = digits.parse::<usize>().ok()?.checked_mul(unit)?;
    (64 << 10..=8 << 20).contains(&bytes).then_some(bytes)
}

/// One ray of a wide stream traversal in flight: its node test, its
/// interval, the item it visits next, its stack, and its index in the
/// stream.
struct WideLane<'a> {
    ray: BoxRay,
    tmin: f32,
    tmax: f32,
    cur: Entry,
    index: usize,
    stack: WalkStack<'a>,
}

impl WideLane<'_> {
    /// The next item on the lane's stack within its bound (any item,
    /// without `CULL`: see [`WalkStack::pop_inline`]), made current; false
    /// when none is left.
    #[inline(always)]
    fn pop<const CULL: bool>(&mut self) -> bool {
        match self.stack.pop::<CULL>(cull_bound(self.tmax)) {
            Some(e) => {
                self.cur = e;
                true
            }
            None => false,
        }
    }
}

impl<const W: usize> WideBvh<W> {
    /// Traverses every ray of `rays` as [`Self::traverse_blocks`] (or, not
    /// `ORDERED`, [`Self::traverse_blocks_unordered`]) does each: the same
    /// nodes tested with the same arithmetic, the same leaves offered in
    /// the same order. `leaf(ray, first, count, tmax)` tests a leaf for
    /// `rays[ray]` within `tmax` and returns the ray's new bound; below
    /// the ray's `tmin` ends it. Invalid rays are skipped.
    ///
    /// A few rays ([`STREAM_LANES`]) are in flight at once, a step taking one
    /// of them a node or a leaf further, round robin, and a ray that ends
    /// makes room for the next. Each step prefetches the node its ray
    /// visits next, which the ray reaches only after the other rays'
    /// steps: one ray's walk is a chain of dependent loads, and
    /// incoherent rays spend most of their time waiting on it; interleaved,
    /// the fetch of each ray's next node overlaps the others' work (the
    /// same idea as the binary BVH's stream, [`super::Bvh::traverse_stream`]).
    pub(crate) fn traverse_stream<const ORDERED: bool>(
        &self,
        rays: &[Ray],
        leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
        prefetch_leaf: impl Fn(u32),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if (W == 8 || W == 4) && simd::has_avx2() {
            return simd::with_avx2(|| {
                self.stream_sized::<ORDERED>(rays, leaf, &prefetch_leaf, |n, r, bound, t| {
                    simd::slab_wide(n, r, bound, t)
                });
            });
        }
        #[cfg(all(target_arch = "aarch64", target_feature = "neon"))]
        if (W == 8 || W == 4) && simd::simd_enabled() {
            let test = crate::neon::slab_wide;
            return self.stream_sized::<ORDERED>(rays, leaf, &prefetch_leaf, test);
        }
        self.stream_sized::<ORDERED>(rays, leaf, &prefetch_leaf, |n, r, bound, t| {
            slab_scalar(n, r, bound, t)
        });
    }

    /// The bytes of the tree's nodes (which [`STREAM_LANES`] and
    /// `small_tree_bytes` weigh).
    pub(crate) fn node_bytes(&self) -> usize {
        std::mem::size_of_val(self.nodes.as_slice())
    }

    /// [`Self::stream_with`] with as many rays in flight as the tree's
    /// size calls for ([`STREAM_LANES`]).
    #[inline(always)]
    fn stream_sized<const ORDERED: bool>(
        &self,
        rays: &[Ray],
        leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &BoxRay, f32, &mut [f32; W]) -> u32,
    ) {
        if self.node_bytes() >= LARGE_TREE_BYTES {
            self.stream_with::<ORDERED, { STREAM_LANES[1] }>(rays, leaf, prefetch_leaf, test);
        } else {
            self.stream_with::<ORDERED, { STREAM_LANES[0] }>(rays, leaf, prefetch_leaf, test);
        }
    }

    /// The loop of [`Self::traverse_stream`], generic over the node test.
    #[inline(always)]
    fn stream_with<const ORDERED: bool, const K: usize>(
        &self,
        rays: &[Ray],
        leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &BoxRay, f32, &mut [f32; W]) -> u32,
    ) {
        const { assert!(W <= INLINE) };
        let nodes: &[WideNode<W>] = &self.nodes;
        let mut next = 0;
        // Starts the next valid ray on `lane`; false when none is left.
        let start = |lane: &mut WideLane| {
            while let Some(ray) = rays.get(next) {
                next += 1;
                if ray.is_valid() {
                    lane.ray = BoxRay::new(ray);
                    (lane.tmin, lane.tmax, lane.index) = (ray.tmin(), ray.tmax(), next - 1);
                    lane.cur = Entry {
                        child: 0,
                        count: 0,
                        entry: ray.tmin(),
                    };
                    lane.stack.clear();
                    return true;
                }
            }
            false
        };
        let mut items = [[Entry::NONE; INLINE]; K];
        let mut lanes: [WideLane; K] = items.each_mut().map(|items| WideLane {
            ray: BoxRay::default(),
            tmin: 0.0,
            tmax: 0.0,
            cur: Entry::NONE,
            index: 0,
            stack: WalkStack::new(items),
        });
        super::round_robin(&mut lanes, start, |l| {
            let live = if l.cur.count == 0 {
                if !l.stack.has_room(W - 1) {
                    l.stack.spill();
                }
                let node = &nodes[l.cur.child as usize];
                let mut t = [0.0f32; W];
                let mask = test(node, &l.ray, cull_bound(l.tmax), &mut t);
                match enter::<ORDERED, W>(nodes, node, mask, &t, &mut l.stack, &|_| {}) {
                    Some(e) => {
                        l.cur = e;
                        true
                    }
                    None => l.pop::<ORDERED>(),
                }
            } else {
                l.tmax = leaf(l.index, l.cur.child, l.cur.count, l.tmax);
                l.tmax >= l.tmin && l.pop::<ORDERED>()
            };
            if live {
                if l.cur.count == 0 {
                    simd::prefetch(&nodes[l.cur.child as usize]);
                } else {
                    prefetch_leaf(l.cur.child);
                }
            }
            live
        });
    }
}

/// Rays that walk the tree together in [`WideBvh::occluded_group`]: a
/// bit each in a `u32` mask. (The group walk runs with the AVX2 node test
/// only: x86-64.)
#[cfg(target_arch = "x86_64")]
pub(crate) const GROUP: usize = 32;

/// What a group's node test needs of its rays (each ray's [`BoxRay`]),
/// by rows, a lane a ray, for rays of one octant: they share the rows
/// of a node they meet first and last (`near`, `far`).
#[derive(Clone, Debug)]
#[cfg(target_arch = "x86_64")]
pub(crate) struct GroupRays {
    pub(crate) origin: [[f32; GROUP]; 3],
    pub(crate) inv_dir: [[f32; GROUP]; 3],
    pub(crate) inv_exit: [[f32; GROUP]; 3],
    pub(crate) tmin: [f32; GROUP],
    /// Each ray's culling bound (`cull_bound` of its `tmax`).
    pub(crate) bound: [f32; GROUP],
    pub(crate) near: [usize; 3],
    pub(crate) far: [usize; 3],
}

#[cfg(target_arch = "x86_64")]
impl GroupRays {
    /// The rays `rays` (at most [`GROUP`], all in one octant).
    #[cfg(test)]
    pub(crate) fn new<'r>(rays: impl ExactSizeIterator<Item = &'r Ray>) -> Self {
        assert!(rays.len() <= GROUP);
        let mut g = Self::of_octant(0);
        for (i, ray) in rays.enumerate() {
            if i == 0 {
                g = Self::of_octant(ray.octant());
            }
            assert!(
                ray.octant() == g.octant(),
                "a group's rays share their octant"
            );
            g.set(i, ray);
        }
        g
    }

    /// A group of no rays (every lane's interval empty) whose rays are to
    /// go in the octant `octant` ([`Ray::octant`]), lane by lane
    /// ([`Self::set`]).
    #[inline(always)]
    pub(crate) fn of_octant(octant: usize) -> Self {
        let (near, far) = BoxRay::octant_rows(octant);
        Self {
            origin: [[0.0; GROUP]; 3],
            inv_dir: [[0.0; GROUP]; 3],
            inv_exit: [[0.0; GROUP]; 3],
            tmin: [f32::INFINITY; GROUP],
            bound: [f32::NEG_INFINITY; GROUP],
            near,
            far,
        }
    }

    /// Makes the group's rays go in the octant `octant` (its lanes then
    /// set anew by [`Self::set`]): for a group's rows reused by the next.
    #[inline(always)]
    pub(crate) fn set_octant(&mut self, octant: usize) {
        (self.near, self.far) = BoxRay::octant_rows(octant);
    }

    /// The octant of the group's rays, from the rows they meet first (a
    /// backward axis's is the upper bounds', past the three lower rows).
    #[cfg(test)]
    fn octant(&self) -> usize {
        (0..3).map(|a| usize::from(self.near[a] >= 24) << a).sum()
    }

    /// Puts `ray`, which must lie in the group's octant (checked in debug
    /// builds only: the caller's octant sort puts it there), in lane `i`
    /// (below [`GROUP`]): what its node test needs ([`BoxRay::new`]'s) by
    /// rows, and its culling bound. Without `new`'s check and its `BoxRay`
    /// a ray: the group streams 1.00–1.03 times as fast (`raymesh-ab
    /// --stream`, pig, bunny00 and the dragon, primary, shadow and diffuse
    /// rays). Streams fill a group eight rays at a time in AVX2
    /// (`simd::set_group_rays`, the same bits), this for the rest.
    #[inline(always)]
    pub(crate) fn set(&mut self, i: usize, ray: &Ray) {
        debug_assert_eq!(BoxRay::octant_rows(ray.octant()).0, self.near);
        let (o, inv) = (ray.origin().to_array(), ray.inv_dir().to_array());
        for a in 0..3 {
            self.origin[a][i] = o[a];
            self.inv_dir[a][i] = inv[a];
            self.inv_exit[a][i] = exit_reciprocal(inv[a]);
        }
        self.tmin[i] = ray.tmin();
        self.bound[i] = cull_bound(ray.tmax());
    }

    /// Ray `i`'s node-test form.
    #[cfg(test)]
    fn ray(&self, i: usize) -> BoxRay {
        BoxRay {
            origin: std::array::from_fn(|a| self.origin[a][i]),
            inv_dir: std::array::from_fn(|a| self.inv_dir[a][i]),
            inv_exit: std::array::from_fn(|a| self.inv_exit[a][i]),
            tmin: self.tmin[i],
            near: self.near,
            far: self.far,
        }
    }
}

/// For each of a node's children, the rays of `mask` (bits of `g`) that
/// enter its box: each ray by the one-ray node test ([`slab_scalar`]),
/// so each enters exactly the children it enters alone. What the AVX2
/// kernel (`simd::group_slab8`) must give, which a test checks.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn group_slab_scalar<const W: usize>(
    n: &WideNode<W>,
    g: &GroupRays,
    mask: u32,
) -> [u32; W] {
    group_slab_entry_scalar(n, g, mask).0
}

/// [`group_slab_scalar`], and for each child the least entry distance
/// among the rays that enter it (infinity where none does), each ray's
/// as its one-ray node test gives it, taken in increasing ray order as
/// `min_ps` takes them (`a < b ? a : b`): what `simd::group_slab8_entry`
/// must give, which a test checks.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn group_slab_entry_scalar<const W: usize>(
    n: &WideNode<W>,
    g: &GroupRays,
    mut mask: u32,
) -> ([u32; W], [f32; W]) {
    let mut entered = [0u32; W];
    let mut least = [f32::INFINITY; W];
    let mut t = [0.0f32; W];
    while mask != 0 {
        let i = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        let mut hits = slab_scalar(n, &g.ray(i), g.bound[i], &mut t);
        while hits != 0 {
            let k = hits.trailing_zeros() as usize;
            hits &= hits - 1;
            entered[k] |= 1 << i;
            least[k] = if least[k] < t[k] { least[k] } else { t[k] };
        }
    }
    (entered, least)
}

/// The slots of a node that some ray of a group entered (`entered`: the
/// rays that entered each slot), a bit each: the group walks visit them
/// by their bits (a loop over all the slots with a branch each cost the
/// closest-hit walk 5–11%). What the AVX2 kernels give beside the masks
/// (`simd::group_slab8`), which a test checks.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn entered_slots<const W: usize>(entered: &[u32; W]) -> u32 {
    let mut any = 0u32;
    for (k, e) in entered.iter().enumerate() {
        any |= u32::from(*e != 0) << k;
    }
    any
}

/// The leaves of a group's closest-hit walk ([`WideBvh::intersect_group`]).
///
/// A trait and not a closure, as [`PacketLeaf`] is, so that the leaf's
/// `#[inline(always)]` inlines it into the walk's AVX2 code.
#[cfg(target_arch = "x86_64")]
pub(crate) trait GroupLeaf {
    /// Tests ray `i` of the group against the leaf `first..first + count`:
    /// its new `tmax` when it found a nearer hit there.
    fn visit(&mut self, i: usize, first: u32, count: u32) -> Option<f32>;
    /// Starts fetching the leaf whose first slot is `first` (a hint).
    fn prefetch(&self, first: u32);
}

/// A group walk's stack item: a node or leaf (`child`, `count` as a
/// node's slot holds them), the rays of the group that entered it, and
/// the least of their entry distances.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub(crate) struct GroupEntry {
    child: u32,
    count: u32,
    mask: u32,
    entry: f32,
}

#[cfg(target_arch = "x86_64")]
impl<const W: usize> WideBvh<W> {
    /// Which rays of a group (`g`'s first `len`, at most [`GROUP`], in one
    /// octant) hit anything: a bit each in the returned mask, set when
    /// `leaf(i, first, count)`, which tests ray `i` against a leaf,
    /// returned true. [`Self::occluded_group_by`] with the leaf tested
    /// ray by ray (`prefetch_leaf` as there).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn occluded_group(
        &self,
        g: &GroupRays,
        len: usize,
        stack: &mut Vec<(u32, u32, u32)>,
        shared: &mut (u64, u64),
        leaves: &mut (u64, u64),
        leaf: &mut impl FnMut(usize, u32, u32) -> bool,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &GroupRays, u32) -> ([u32; W], u32),
    ) -> u32 {
        let mut each = |mut m: u32, first: u32, count: u32| {
            let mut hit = 0u32;
            while m != 0 {
                let i = m.trailing_zeros() as usize;
                m &= m - 1;
                if leaf(i, first, count) {
                    hit |= 1 << i;
                }
            }
            hit
        };
        self.occluded_group_by(
            g,
            len,
            stack,
            shared,
            leaves,
            &mut each,
            prefetch_leaf,
            test,
        )
    }

    /// Which rays of a group (`g`'s first `len`, at most [`GROUP`], in one
    /// octant) hit anything: a bit each in the returned mask, set where
    /// `leaf(rays, first, count)`, which tests the rays `rays` (a bit
    /// each) against a leaf, returned the ray's bit.
    ///
    /// The rays walk the tree as one, each stack item a node or leaf with
    /// the mask of the rays that entered it: a node's boxes are tested
    /// against each of its rays (`test(node, g, mask)`: per child, the
    /// rays that enter it, by each ray's one-ray node test, and a bit for
    /// each child some ray entered), a leaf
    /// against each of its rays not yet occluded, and a ray leaves the
    /// walk at its first hit. Each ray meets every leaf its one-ray
    /// any-hit walk would until it hits, so whether it hits is the
    /// one-ray answer. A node that several rays enter is fetched once for
    /// them all. Embree walks its occlusion streams' rays so, in groups of
    /// up to 32 of one octant (`bvh_intersector_stream.cpp`).
    ///
    /// Each child pushed but the one popped next starts fetching at once,
    /// as in the one-ray walk: a node's lines, or a leaf's block through
    /// `prefetch_leaf(first)`. Where the tree is past the caches this
    /// pays: any-hit streams of diffuse and shadow rays over meshes of 1.2
    /// and 2 million triangles ran 1.04-1.12 times as fast, those over
    /// bunny00, the dragon and the pig 1.00-1.03 (`raymesh-ab MESH --accel
    /// bvh8 --workload W --size 512 --stream --rounds 3`, each build the
    /// other's baseline).
    ///
    /// `stack` is scratch space, whatever it holds overwritten and grown
    /// where the walk needs more (kept by the caller for the next group);
    /// `shared` counts on the node visits and the rays they took, and
    /// `leaves` on the leaf visits and theirs, for the caller's choice of
    /// walk.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn occluded_group_by(
        &self,
        g: &GroupRays,
        len: usize,
        stack: &mut Vec<(u32, u32, u32)>,
        shared: &mut (u64, u64),
        leaves: &mut (u64, u64),
        leaf: &mut impl FnMut(u32, u32, u32) -> u32,
        prefetch_leaf: &impl Fn(u32),
        test: impl Fn(&WideNode<W>, &GroupRays, u32) -> ([u32; W], u32),
    ) -> u32 {
        assert!(len <= GROUP);
        let nodes: &[WideNode<W>] = &self.nodes;
        if nodes.is_empty() || len == 0 {
            return 0;
        }
        // Rays still looking for a hit.
        let start = u32::MAX >> (GROUP - len);
        let mut alive = start;
        // The stack as a slice with a top of its own, grown where a node's
        // pushes would not fit: each push through the `Vec` checked its
        // capacity and stored its length.
        let mut items = scratch(stack, 8 * W, (0, 0, 0));
        items[0] = (0, 0, alive);
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (child, count, mask) = items[top];
            let m = mask & alive;
            if m == 0 {
                continue;
            }
            if count > 0 {
                leaves.0 += 1;
                leaves.1 += u64::from(m.count_ones());
                alive &= !(leaf(m, child, count) & m);
                if alive == 0 {
                    break;
                }
                continue;
            }
            let n = &nodes[child as usize];
            shared.0 += 1;
            shared.1 += u64::from(m.count_ones());
            let (entered, mut any) = test(n, g, m);
            if top + W > items.len() {
                let more = 2 * items.len();
                items = scratch(stack, more, (0, 0, 0));
            }
            // The last slot comes off the stack first, as in the one-ray
            // any-hit walk; the others start fetching now.
            while any != 0 {
                let k = any.trailing_zeros() as usize;
                any &= any - 1;
                if any != 0 {
                    fetch_child(nodes, n.child[k], n.count[k], prefetch_leaf);
                }
                items[top] = (n.child[k], n.count[k], entered[k]);
                top += 1;
            }
        }
        start & !alive
    }

    /// Each ray's closest hit, for a group (`g`'s first `len` rays, at
    /// most [`GROUP`], in one octant): [`GroupLeaf::visit`]`(i, first,
    /// count)` tests ray `i` against a leaf and returns its new `tmax`
    /// when it found a nearer hit there (the leaf keeps the hits), which
    /// lowers the ray's culling bound in `g`.
    ///
    /// The rays walk the tree as one, as in [`Self::occluded_group`]; a
    /// node's entered children are visited nearest first by the least
    /// entry distance among their rays (`test(node, g, mask)` gives the
    /// rays that enter each child, that distance, and a bit for each
    /// child some ray entered), and a popped item
    /// drops the rays whose culling bound has since fallen below it (each
    /// such ray's own entry lies beyond its bound, so its one-ray walk
    /// would not enter there either). Every ray meets every leaf that
    /// could hold a hit nearer than its closest so far, so, as ties go to
    /// the least index whatever the order, each gets its one-ray closest
    /// hit. Embree walks only occlusion streams in groups; closest hits
    /// share fewer nodes, and the caller measures whether they pay. The
    /// entered children but the nearest start fetching when pushed, as in
    /// [`Self::occluded_group_by`] (leaves through
    /// [`GroupLeaf::prefetch`]): diffuse streams' closest hits over the
    /// same meshes of millions of triangles 0.97-1.05 times as fast
    /// (1.04 on two of the three), over bunny00, the dragon and the pig
    /// 1.00-1.01.
    ///
    /// `reaching(entry, bounds)` gives the rays whose bound reaches an
    /// entry distance, a bit each (`entry <= bounds[i]`, as the test-only
    /// `reaching` finds them). `stack` is scratch space, as for
    /// [`Self::occluded_group`].
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn intersect_group(
        &self,
        g: &mut GroupRays,
        len: usize,
        stack: &mut Vec<GroupEntry>,
        shared: &mut (u64, u64),
        leaf: &mut impl GroupLeaf,
        test: impl Fn(&WideNode<W>, &GroupRays, u32) -> ([u32; W], [f32; W], u32),
        reaching: impl Fn(f32, &[f32; GROUP]) -> u32,
    ) {
        assert!(len <= GROUP);
        let nodes: &[WideNode<W>] = &self.nodes;
        if nodes.is_empty() || len == 0 {
            return;
        }
        // A slice with a top of its own, as in `occluded_group`.
        let none = GroupEntry {
            child: 0,
            count: 0,
            mask: 0,
            entry: 0.0,
        };
        let mut items = scratch(stack, 8 * W, none);
        items[0] = GroupEntry {
            child: 0,
            count: 0,
            mask: u32::MAX >> (GROUP - len),
            entry: f32::NEG_INFINITY,
        };
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let item = items[top];
            // The rays whose bound still reaches the item.
            let mut m = item.mask & reaching(item.entry, &g.bound);
            if m == 0 {
                continue;
            }
            if item.count > 0 {
                while m != 0 {
                    let i = m.trailing_zeros() as usize;
                    m &= m - 1;
                    if let Some(t) = leaf.visit(i, item.child, item.count) {
                        g.bound[i] = cull_bound(t);
                    }
                }
                continue;
            }
            let n = &nodes[item.child as usize];
            shared.0 += 1;
            shared.1 += u64::from(m.count_ones());
            let (entered, entry, mut any) = test(n, g, m);
            // The entered children, farthest first (the nearest is pushed
            // last and popped next).
            let mut order = [0usize; W];
            let mut h = 0;
            while any != 0 {
                let k = any.trailing_zeros() as usize;
                any &= any - 1;
                let mut j = h;
                while j > 0 && entry[order[j - 1]] < entry[k] {
                    order[j] = order[j - 1];
                    j -= 1;
                }
                order[j] = k;
                h += 1;
            }
            if top + W > items.len() {
                let more = 2 * items.len();
                items = scratch(stack, more, none);
            }
            // Fetching starts now for all but the nearest, which is
            // popped next.
            for &k in &order[..h.saturating_sub(1)] {
                fetch_child(nodes, n.child[k], n.count[k], &|f| leaf.prefetch(f));
            }
            for &k in &order[..h] {
                items[top] = GroupEntry {
                    child: n.child[k],
                    count: n.count[k],
                    mask: entered[k],
                    entry: entry[k],
                };
                top += 1;
            }
        }
    }
}

/// A group walk's stack `stack` as a slice of at least `least` items (what
/// it held kept, new items `fill`): the walks push through the slice with
/// a top of their own, and grow it here where a node's pushes would not
/// fit.
#[cfg(target_arch = "x86_64")]
fn scratch<T: Copy>(stack: &mut Vec<T>, least: usize, fill: T) -> &mut [T] {
    if stack.len() < least {
        stack.resize(least, fill);
    }
    stack.as_mut_slice()
}

/// The rays of a group whose culling bound reaches the entry distance
/// `entry` (`entry <= bounds[i]`, false where either is NaN), a bit each:
/// what a group's closest-hit walk drops rays by at each pop, and what
/// the AVX2 kernel (`simd::reaching8`) must give, which a test checks.
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) fn reaching(entry: f32, bounds: &[f32; GROUP]) -> u32 {
    let mut reach = 0u32;
    for (i, b) in bounds.iter().enumerate() {
        reach |= u32::from(entry <= *b) << i;
    }
    reach
}

/// Starts fetching a child that a walk pushes to visit later: a node's
/// lines (`count` 0), or a leaf's block through `prefetch_leaf(first)`.
/// A hint: no result depends on it.
#[inline(always)]
fn fetch_child<const W: usize>(
    nodes: &[WideNode<W>],
    child: u32,
    count: u32,
    prefetch_leaf: &impl Fn(u32),
) {
    if count == 0 {
        simd::prefetch(&nodes[child as usize]);
    } else {
        prefetch_leaf(child);
    }
}

/// A node's entered children (`mask`, entry distances `t`): all but the
/// nearest pushed onto `stack`, farthest first (in slot order, unless
/// `ORDERED`), nodes among them prefetched; returns the nearest, or `None`
/// when the ray enters none. The caller has made room for `W - 1` pushes.
#[inline(always)]
fn enter<const ORDERED: bool, const W: usize>(
    nodes: &[WideNode<W>],
    n: &WideNode<W>,
    mut mask: u32,
    t: &[f32; W],
    stack: &mut WalkStack<'_>,
    prefetch_leaf: &impl Fn(u32),
) -> Option<Entry> {
    // The lowest child left in `mask`, taken out of it.
    let take = |mask: &mut u32| {
        let k = mask.trailing_zeros() as usize;
        *mask &= *mask - 1;
        Entry {
            child: n.child[k],
            count: n.count[k],
            // Unordered walks never read it (see `WalkStack::pop_inline`).
            entry: if ORDERED { t[k] } else { 0.0 },
        }
    };
    // Pushes a child for later, starting its fetch.
    let mut push = |item: Entry| {
        fetch_child(nodes, item.child, item.count, prefetch_leaf);
        stack.push(item);
    };
    if mask == 0 {
        return None;
    }
    let first = take(&mut mask);
    if mask == 0 {
        // One child entered: no sorting.
        return Some(first);
    }
    // The first two in the sort's order below: farther first, the later
    // slot nearer on a tie (or unordered).
    let second = take(&mut mask);
    let (far, near) = if ORDERED && first.entry < second.entry {
        (second, first)
    } else {
        (first, second)
    };
    if mask == 0 {
        // Two children entered, the commonest case after one: that
        // comparison instead of the sort.
        push(far);
        return Some(near);
    }
    if !ORDERED {
        // Slot order: each pushed as the next is taken, the last kept.
        // Gathered in an array and copied onto the stack as the sort below
        // is, each item was read back by an 8-byte load over the two
        // 4-byte stores that made it, which the CPU cannot forward from
        // stores still on their way to the cache. `raymesh-ab --accel bvh8
        // --size 512` against the copy, medians of pairs, any-hit queries
        // on the pig, bunny00, the dragon and polygon_mesh: random rays
        // 1.03-1.05, primary 0.98-1.05, shadow 0.97-1.02.
        push(far);
        let mut last = near;
        while mask != 0 {
            let item = take(&mut mask);
            push(last);
            last = item;
        }
        return Some(last);
    }
    let third = take(&mut mask);
    if mask == 0 {
        // Three entered: the third inserted by two compare-exchanges in
        // registers (the insertion below's order, ties to the later slot
        // nearer), not through the array, whose items, stored field by
        // field, the sort and the pushes copied by wider loads than the
        // stores that made them.
        let (mid, near) = if near.entry < third.entry {
            (third, near)
        } else {
            (near, third)
        };
        let (far, mid) = if far.entry < mid.entry {
            (mid, far)
        } else {
            (far, mid)
        };
        push(far);
        push(mid);
        return Some(near);
    }
    // Four or more: sorted by entry, farthest first, by insertion into
    // an array (sorting 64-bit keys instead, each written and read whole,
    // cost closest hits 1-3.5%).
    let mut hits = [Entry::NONE; W];
    (hits[0], hits[1]) = (far, near);
    let mut h = 2;
    let mut insert = |item: Entry| {
        let mut j = h;
        while j > 0 && hits[j - 1].entry < item.entry {
            hits[j] = hits[j - 1];
            j -= 1;
        }
        hits[j] = item;
        h += 1;
    };
    insert(third);
    while mask != 0 {
        insert(take(&mut mask));
    }
    for &item in &hits[..h - 1] {
        push(item);
    }
    Some(hits[h - 1])
}

impl<const W: usize> WideBvh<W> {
    /// Packet traversal: the eight rays of `p` walk the tree together,
    /// each node's boxes tested against every lane still active. Children
    /// that some lane enters are visited nearest first (by the least entry
    /// distance among their lanes), each with the lanes that enter it; a
    /// lane drops out of a subtree when its entry lies beyond its own
    /// `tmax`. Each leaf reached calls
    /// [`PacketLeaf::visit`]`(avx, first, count, lanes, tmax)`, which tests
    /// the lanes in `lanes` and lowers their `tmax`. Without
    /// `ORDERED` (any-hit queries, which stop a lane at its first hit
    /// wherever it lies) the children go in slot order, unsorted, as the
    /// one-ray any-hit walk's do (`raymesh-peers --packets`, any hits:
    /// bunny00 primary +2%, shadow +4%, the pig +2% and +7%).
    #[inline]
    pub(crate) fn traverse_packet<const ORDERED: bool>(
        &self,
        p: &Packet8,
        tmax: &mut [f32; LANES],
        leaf: &mut impl PacketLeaf,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(avx) = simd::Avx2::detect() {
            return simd::packet_walk_avx2::<W, ORDERED>(avx, self, p, tmax, leaf);
        }
        // A closure, as for the one-ray walk's portable test.
        let test =
            |p: &Packet8, near, far, bound: &[f32; LANES]| packet::slab_lanes(p, near, far, bound);
        let le = |a: &[f32; LANES], b: &[f32; LANES]| {
            packet::lane_mask(&std::array::from_fn(|i| a[i] <= b[i]))
        };
        self.packet_loop::<ORDERED>(p, tmax, leaf, None, test, le);
    }

    /// The packet walk, generic over each child's test of the packet's
    /// lanes (`test(packet, near planes, far planes, bounds)`, as
    /// [`packet::slab_lanes`]) and over the lanes' comparison of entries
    /// with bounds (`le`, as [`packet::le_mask`]), so that the AVX2 walk
    /// makes no CPU check per child or step.
    ///
    /// Children pushed start fetching at once (leaves through
    /// [`PacketLeaf::prefetch`]), in any-hit walks always and in
    /// closest-hit ones over trees of [`LARGE_TREE_BYTES`] or more: over a
    /// 2M-triangle sphere and terrain, `--packets` primary rays ran
    /// 1.05-1.10 (closest) and 1.09-1.24 (any-hit) times as fast, and
    /// streams' shadow rays (closest hits, whose coherent runs take this
    /// walk) 1.06-1.16; bunny00 and the dragon 0.98-1.04 (`raymesh-ab MESH
    /// --accel bvh8 --workload W --size 512 --packets|--stream --rounds
    /// 3`, each build the other's baseline; closest-hit walks over them
    /// lost 1-2% with the fetches, so they make none there).
    #[inline(always)]
    pub(crate) fn packet_loop<const ORDERED: bool>(
        &self,
        p: &Packet8,
        tmax: &mut [f32; LANES],
        leaf: &mut impl PacketLeaf,
        avx: Option<Avx2>,
        test: impl Fn(&Packet8, [f32; 3], [f32; 3], &[f32; LANES]) -> (u32, [f32; LANES]),
        le: impl Fn(&[f32; LANES], &[f32; LANES]) -> u32,
    ) {
        let mut stack = Stack::new(PacketEntry::NONE);
        let mut cur = PacketEntry {
            child: 0,
            count: 0,
            lanes: (1 << LANES) - 1,
            entry: p.tmin,
        };
        // A child pushed starts fetching now: its node's lines, or its
        // leaf's block. Any-hit walks always; closest-hit ones over trees
        // past the L2 cache, since over smaller ones they lost 1-2%.
        let fetch = !ORDERED || self.node_bytes() >= LARGE_TREE_BYTES;
        let prefetch_item = |leaf: &mut _, child: u32, count: u32| {
            if fetch {
                fetch_child(&self.nodes, child, count, &|f| {
                    PacketLeaf::prefetch(leaf, f)
                });
            }
        };
        loop {
            let bound: [f32; LANES] = std::array::from_fn(|i| cull_bound(tmax[i]));
            let lanes = cur.lanes & le(&cur.entry, &bound);
            if lanes != 0 {
                if cur.count > 0 {
                    leaf.visit(avx, cur.child, cur.count, lanes, tmax);
                } else {
                    let n = &self.nodes[cur.child as usize];
                    // The children some lane may enter, by one interval
                    // test for the packet; then each lane's own test.
                    let keep = match &p.frustum {
                        Some(f) => n.frustum_in(avx, f, p.neg(), &bound, lanes),
                        None => u32::MAX,
                    };
                    // Each axis's near and far row, chosen once a node (the
                    // octant is the packet's) rather than for each child.
                    let neg = p.neg();
                    let rows = |a: usize| {
                        if neg[a] {
                            (&n.max[a], &n.min[a])
                        } else {
                            (&n.min[a], &n.max[a])
                        }
                    };
                    let (r0, r1, r2) = (rows(0), rows(1), rows(2));
                    // Entered children, farthest first (ordered).
                    let mut hits = [(0.0f32, PacketEntry::NONE); W];
                    let mut h = 0;
                    // Empty slots have empty boxes, which no lane enters.
                    let mut kept = keep & ((1u64 << W) - 1) as u32;
                    while kept != 0 {
                        let c = kept.trailing_zeros() as usize;
                        kept &= kept - 1;
                        let near = [r0.0[c], r1.0[c], r2.0[c]];
                        let far = [r0.1[c], r1.1[c], r2.1[c]];
                        let (m, entry) = test(p, near, far, &bound);
                        let m = m & lanes;
                        if m == 0 {
                            continue;
                        }
                        let item = PacketEntry {
                            child: n.child[c],
                            count: n.count[c],
                            lanes: m,
                            entry,
                        };
                        if !ORDERED {
                            // Straight onto the stack, in slot order: the
                            // last pushed is visited next, as the ordered
                            // walk visits its last item (no array a node to
                            // clear and copy from). Ordered, items pushed
                            // this way and then sorted on the stack ran
                            // 0.95-0.98x as fast.
                            prefetch_item(leaf, item.child, item.count);
                            stack.push(item);
                            continue;
                        }
                        // Ordered by the first lane that enters: cheaper than
                        // the least entry, and as good for a coherent packet.
                        let key = entry[m.trailing_zeros() as usize];
                        let mut j = h;
                        while j > 0 && hits[j - 1].0 < key {
                            hits[j] = hits[j - 1];
                            j -= 1;
                        }
                        hits[j] = (key, item);
                        h += 1;
                    }
                    if h > 0 {
                        for (_, item) in &hits[..h - 1] {
                            prefetch_item(leaf, item.child, item.count);
                            stack.push(*item);
                        }
                        cur = hits[h - 1].1;
                        continue;
                    }
                }
            }
            let Some(e) = stack.pop() else { return };
            cur = e;
        }
    }
}

/// A packet traversal's stack item: a node (`count == 0`) or a leaf, the
/// lanes that enter its box, and their entry distances.
#[derive(Clone, Copy, Debug)]
pub(super) struct PacketEntry {
    pub(super) child: u32,
    pub(super) count: u32,
    pub(super) lanes: u32,
    pub(super) entry: [f32; LANES],
}

impl PacketEntry {
    pub(super) const NONE: Self = Self {
        child: 0,
        count: 0,
        lanes: 0,
        entry: [0.0; LANES],
    };
}

/// Cost of one wide node test, relative to the node's box area (the SAH's
/// traversal cost).
const NODE_COST: f32 = 1.0;
/// Cost of one block test of up to [`BLOCK`] primitives of a leaf,
/// relative to its box area: a triangle block reads and computes about
/// twice what a node test does.
const BLOCK_COST: f32 = 1.5;

/// The collapse's choices for each binary node `n`, filled bottom-up by
/// [`Plan::cost`] (each word written by the one parallel task that plans
/// `n`). The low 32 bits hold `W` choices of 4 bits. Choice 0: 0 when `n`
/// becomes one wide leaf, else `n` becomes a wide node whose slots are
/// `k` slots of its left subtree and `W - k` of its right. Choice `s - 1`,
/// for `s` in `2..=W`, when `n`'s subtree fills at most `s` slots of its
/// parent: 0 for `s - 1` slots, else `k` of its left subtree and `s - k`
/// of its right. The high 32 bits count the wide nodes that `n`'s subtree
/// makes when `n` is a wide node ([`Plan::wide_nodes`]), so that the
/// collapse knows where each subtree's nodes go before it writes them.
struct Plan<'a, const W: usize> {
    bin: &'a Bvh,
    choice: Vec<AtomicU64>,
}

/// What [`Plan::cost`] gives a binary node's parent of its subtree.
#[derive(Clone, Copy, Debug)]
struct Planned<const W: usize> {
    /// The least cost of the subtree filling at most `s` slots of its
    /// parent, for each `s` in `1..=W` (index `s - 1`); it never grows
    /// with `s`.
    cost: [f32; W],
    /// The fewest slots past which more never lower the cost (a pair of
    /// binary leaves has one each), `W` where the costs are NaN.
    useful: usize,
    /// The subtree's primitives as one wide leaf's range, when they can
    /// be one (as [`leaf_range`]).
    range: Option<(u32, u32)>,
    /// For each `s`, the wide nodes the collapse makes of the subtree so
    /// spread.
    wide: [u32; W],
}

/// `x` as an integer that orders as [`f32::total_cmp`] orders floats.
#[inline(always)]
fn total_key(x: f32) -> i32 {
    let b = x.to_bits() as i32;
    b ^ (((b >> 31) as u32) >> 1) as i32
}

/// Binary tree levels whose two subtrees are planned in parallel rayon
/// tasks (up to 2^8 tasks; below, one task walks its whole subtree).
const PAR_LEVELS: usize = 8;

const _: () = assert!(BLOCK <= u8::MAX as usize);

impl<'a, const W: usize> Plan<'a, W> {
    /// The collapse's plan of the (non-empty) binary tree `bin`: every
    /// node's choices and wide-node count, from [`Self::cost`] at the root.
    fn new(bin: &'a Bvh) -> Self {
        let plan = Self {
            bin,
            choice: (0..bin.pairs.len() * 2)
                .into_par_iter()
                .map(|_| AtomicU64::new(0))
                .collect(),
        };
        plan.cost(0, 0);
        plan
    }

    /// The choices made for binary node `n`.
    fn choice(&self, n: u32) -> [u8; W] {
        let word = self.choice[n as usize].load(Ordering::Relaxed);
        std::array::from_fn(|i| (word >> (4 * i) & 0xf) as u8)
    }

    /// How many wide nodes the collapse makes of binary node `n`'s subtree
    /// when `n` becomes a wide node (0 when it becomes a leaf).
    fn wide_nodes(&self, n: u32) -> u32 {
        (self.choice[n as usize].load(Ordering::Relaxed) >> 32) as u32
    }

    /// The least SAH cost (unscaled by the root's area) of binary node
    /// `n`'s subtree filling at most `s` slots of its parent, for each `s`
    /// in `1..=W`, with what its parent's plan needs of it (see
    /// [`Planned`]); records the choices and [`Self::wide_nodes`]. `level`
    /// is `n`'s depth, for the parallel split.
    fn cost(&self, n: u32, level: usize) -> Planned<W> {
        let node = *self.bin.node(n);
        let area = node.bounds().half_area();
        let leaf_cost = |(_, c): (u32, u32)| area * BLOCK_COST * c.div_ceil(BLOCK as u32) as f32;
        if node.is_leaf() {
            let range = (node.index, node.count);
            let c = leaf_cost(range);
            return Planned {
                cost: [c; W],
                useful: if c.is_nan() { W } else { 1 },
                range: Some(range),
                wide: [0; W],
            };
        }
        let (l, r) = if level < PAR_LEVELS {
            rayon::join(
                || self.cost(node.index, level + 1),
                || self.cost(node.index + 1, level + 1),
            )
        } else {
            (
                self.cost(node.index, level + 1),
                self.cost(node.index + 1, level + 1),
            )
        };
        let range = l.range.zip(r.range).and_then(|(a, b)| merge_ranges(a, b));
        let leaf = range.map_or(f32::INFINITY, leaf_cost);
        // Slots past a subtree's `useful` ones cost the same as its last
        // useful one, so more of them are never better: the most slots
        // worth giving the two subtrees together.
        let top = W.min(l.useful + r.useful);
        // The best split of `s` slots between the two subtrees, for each
        // `s` in `2..=top` (index `s - 1`): the first cheapest `k` of the
        // left's slots, in `total_cmp`'s order (a NaN sum, from infinite
        // boxes, ranks by its sign), compared as integers.
        let mut best = [(0.0f32, 0usize); W];
        for (s, best) in best.iter_mut().enumerate().take(top).skip(1) {
            let s = s + 1;
            let (lo, hi) = (s.saturating_sub(r.useful).max(1), l.useful.min(s - 1));
            let sum = |k: usize| l.cost[k - 1] + r.cost[s - k - 1];
            *best = (sum(lo), lo);
            let mut key = total_key(best.0);
            for k in lo + 1..=hi {
                let v = sum(k);
                let kv = total_key(v);
                if kv < key {
                    (*best, key) = ((v, k), kv);
                }
            }
        }
        let mut c = [0.0; W];
        let mut choice = [0u8; 8];
        let (inner, k) = best[top - 1];
        let inner = inner + area * NODE_COST;
        // A leaf only where the subtree makes one (NaN costs, from
        // infinite boxes, choose it too).
        (c[0], choice[0]) = if range.is_some() && !(inner < leaf) {
            (leaf, 0)
        } else {
            (inner, k as u8)
        };
        // Each `s` takes its best split only where that costs less than
        // `s - 1` slots: `c` never grows, and its last fall is where its
        // useful slots end. Past `top` slots, each costs what `top` do
        // (choice 0).
        let mut useful = 1;
        for s in 2..=top {
            let (spread, k) = best[s - 1];
            (c[s - 1], choice[s - 1]) = if spread < c[s - 2] {
                useful = s;
                (spread, k as u8)
            } else {
                (c[s - 2], 0)
            };
        }
        let last = c[top - 1];
        c[top..].fill(last);
        // NaN costs (then all of `c`) never equal one another: every slot
        // counts as useful, as in a subtree whose cost falls to the last.
        if c[W - 1].is_nan() {
            useful = W;
        }
        // The wide nodes the collapse makes below each way of filling the
        // parent's slots, following the choices as `slots` does: `n` as a
        // wide node of its own (its `k` slots on the left, `W - k` on the
        // right, as `children` splits them), or `n`'s subtree spread over
        // `s` slots. Counted here from the children's counts, not by
        // walking each node's slots (which took 43% more instructions).
        let wide = match choice[0] as usize {
            0 => 0,
            k => 1 + l.wide[k - 1] + r.wide[W - k - 1],
        };
        let mut cnt = [wide; W];
        for s in 2..=top {
            cnt[s - 1] = match choice[s - 1] as usize {
                0 => cnt[s - 2],
                k => l.wide[k - 1] + r.wide[s - k - 1],
            };
        }
        let last = cnt[top - 1];
        cnt[top..].fill(last);
        let packed = (0..W).fold(0u64, |w, i| w | u64::from(choice[i]) << (4 * i));
        self.choice[n as usize].store(packed | u64::from(wide) << 32, Ordering::Relaxed);
        Planned {
            cost: c,
            useful,
            range,
            wide: cnt,
        }
    }

    /// The binary nodes that fill the slots of the wide node made of `n`.
    fn children(&self, n: u32, out: &mut Slots<W>) {
        let k = self.choice(n)[0] as usize;
        let first = self.bin.node(n).index;
        self.slots(first, k, out);
        self.slots(first + 1, W - k, out);
    }

    /// The binary nodes that fill at most `s` slots with `n`'s subtree.
    fn slots(&self, n: u32, s: usize, out: &mut Slots<W>) {
        let choice = self.choice(n);
        let mut s = s;
        while s > 1 && choice[s - 1] == 0 {
            s -= 1;
        }
        if s == 1 {
            out.ids[out.len] = n;
            out.len += 1;
        } else {
            let k = choice[s - 1] as usize;
            let first = self.bin.node(n).index;
            self.slots(first, k, out);
            self.slots(first + 1, s - k, out);
        }
    }
}

/// Wide nodes at least this many make a subtree that [`emit`] hands to a
/// rayon task of its own (fewer in tests, so that small trees take the
/// parallel path).
const PAR_EMIT: u32 = if cfg!(test) { 16 } else { 1024 };

/// Writes the wide node of binary node `at` (which the plan makes a node)
/// to `out[0]` and those below it, depth first, to the rest of `out`
/// (`out.len()` is [`Plan::wide_nodes`] of `at`); `index` is `out[0]`'s
/// index in the whole array.
fn emit<const W: usize>(plan: &Plan<'_, W>, at: u32, index: u32, out: &mut [WideNode<W>]) {
    let (node, mut rest) = out.split_first_mut().expect("room for the node");
    let mut kids = Slots::<W>::default();
    plan.children(at, &mut kids);
    let mut next = index + 1;
    let mut subtrees: [(u32, u32, &mut [WideNode<W>]); W] =
        std::array::from_fn(|_| (0, 0, &mut [][..]));
    let mut n = 0;
    for (i, &k) in kids.ids[..kids.len].iter().enumerate() {
        node.set_box(i, plan.bin.node(k).bounds());
        if plan.choice(k)[0] == 0 {
            let (first, count) = leaf_range(plan.bin, k).expect("a leaf choice has a range");
            node.child[i] = first;
            node.count[i] = count;
        } else {
            let size = plan.wide_nodes(k);
            let (mine, others) = std::mem::take(&mut rest).split_at_mut(size as usize);
            rest = others;
            node.child[i] = next;
            subtrees[n] = (k, next, mine);
            n += 1;
            next += size;
        }
    }
    let subtrees = subtrees.into_iter().take(n);
    if next - index - 1 < PAR_EMIT {
        for (k, at, part) in subtrees {
            emit(plan, k, at, part);
        }
        return;
    }
    rayon::scope(|scope| {
        for (k, at, part) in subtrees {
            if part.len() >= PAR_EMIT as usize {
                scope.spawn(move |_| emit(plan, k, at, part));
            } else {
                emit(plan, k, at, part);
            }
        }
    });
}

/// The binary nodes that fill a wide node's slots, in order.
#[derive(Clone, Copy, Debug)]
struct Slots<const W: usize> {
    ids: [u32; W],
    len: usize,
}

impl<const W: usize> Default for Slots<W> {
    fn default() -> Self {
        Self {
            ids: [0; W],
            len: 0,
        }
    }
}

/// Two subtrees' slot ranges as one wide leaf's, when they are adjacent
/// and hold at most [`BLOCK`] primitives together.
fn merge_ranges(a: (u32, u32), b: (u32, u32)) -> Option<(u32, u32)> {
    let (first, count) = (a.0.min(b.0), a.1 + b.1);
    let contiguous = a.0 + a.1 == b.0 || b.0 + b.1 == a.0;
    (contiguous && count as usize <= BLOCK).then_some((first, count))
}

/// The slots of binary node `k` as one wide leaf `(first, count)`: its own
/// when it is a leaf, and those of its whole subtree when they are at most
/// [`BLOCK`] and contiguous (as the builders lay them out): a wide leaf of
/// up to [`BLOCK`] triangles is one SIMD block test. [`Plan::cost`] finds
/// the same ranges bottom-up; the collapse asks again only for the slots
/// the plan made leaves (at most `BLOCK - 1` levels each), rather than
/// keeping a range for every binary node.
fn leaf_range(bin: &Bvh, k: u32) -> Option<(u32, u32)> {
    // A subtree of at most BLOCK primitives is at most BLOCK - 1 levels
    // deep (each leaf holds one or more), so the search stops there.
    range_within(bin, k, BLOCK)
}

fn range_within(bin: &Bvh, k: u32, levels: usize) -> Option<(u32, u32)> {
    let n = bin.node(k);
    if n.is_leaf() {
        return Some((n.index, n.count));
    }
    if levels == 0 {
        return None;
    }
    let a = range_within(bin, n.index, levels - 1)?;
    let b = range_within(bin, n.index + 1, levels - 1)?;
    merge_ranges(a, b)
}

/// What a node test needs of a ray: origin, reciprocal direction, the
/// rows of a node's bounds it meets first and last, and `tmin`, by axis;
/// computed once per ray, before the traversal.
#[derive(Clone, Copy, Debug, Default)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub struct BoxRay {
    pub(crate) origin: [f32; 3],
    pub(crate) inv_dir: [f32; 3],
    /// The [`exit_reciprocal`]s of `inv_dir`, for exit distances.
    pub(crate) inv_exit: [f32; 3],
    pub(crate) tmin: f32,
    /// For each axis `a`, where the row of a node's bounds that holds the
    /// plane the ray meets first starts, in floats from the node's start:
    /// `8 * a` (lower bounds) or `8 * (3 + a)` (upper), as the rows of an
    /// 8-wide [`WideNode`] lie. Chosen once per ray, so that the AVX node
    /// test loads its planes by offset instead of choosing each with a
    /// conditional move at every node; kept as offsets, so that reloading
    /// them after a leaf test takes no arithmetic.
    pub(crate) near: [usize; 3],
    /// For each axis, the start of the other row: the plane the ray
    /// leaves by.
    pub(crate) far: [usize; 3],
}

impl BoxRay {
    /// The node-test form of `ray`. Inlined: as a call, it stored every
    /// field for the walk to load back (49 instructions a ray).
    #[must_use]
    #[inline(always)]
    pub fn new(ray: &Ray) -> Self {
        let (near, far) = Self::octant_rows(ray.octant());
        Self {
            origin: ray.origin().to_array(),
            inv_dir: ray.inv_dir().to_array(),
            inv_exit: ray.inv_dir().to_array().map(exit_reciprocal),
            tmin: ray.tmin(),
            near,
            far,
        }
    }

    /// What a ray's direction octant ([`Ray::octant`]) decides of its node
    /// test, by axis: the rows of a node's bounds it meets first and last
    /// ([`Self::near`], [`Self::far`]), upper bounds first on an axis it
    /// runs backwards on.
    #[inline(always)]
    pub(crate) fn octant_rows(oct: usize) -> ([usize; 3], [usize; 3]) {
        (
            [0, 1, 2].map(|a| 8 * (a + 3 * ((oct >> a) & 1))),
            [0, 1, 2].map(|a| 8 * (a + 3 * (!oct >> a & 1))),
        )
    }
}

/// The slab test of a node's `W` boxes in plain loops (the compiler
/// vectorizes them for the target's baseline SIMD): writes each child's
/// entry distance and returns a bit per child the ray enters before
/// `bound`. The arithmetic of [`Aabb::slab`] but for the order of its
/// maxima and minima, and the same operations in the same order as the
/// AVX and NEON kernels, one ray's or a group's (which tests check bit
/// for bit).
///
/// The entry is the greatest of the three axes' entries and `tmin`, a NaN
/// among them (a ray along a plane it starts on: `0 * inf`) passed over,
/// as [`Aabb::slab`] takes it; the exit likewise. [`Aabb::slab`] nests the
/// three maxima, each waiting on the next; here two run side by side, x
/// with y and z with `tmin`, and a third takes the greater, one step fewer
/// on the chain of dependent steps from a node's load to its children
/// (`raymesh-ab --accel bvh8 --size 512` against the nested maxima, one
/// ray at a time: 1.01–1.07 on the pig, the dragon, bunny00 and
/// polygon_mesh, random, diffuse, primary and shadow rays; shadow rays
/// 1.03–1.07). `max_ns(a, b)` passes over a NaN `a` but not
/// a NaN `b`: where y's entry is NaN (a ray with no y component, starting
/// on a box's y plane), the pair gives NaN and the entry leaves out x's
/// too, and so the exit: such a ray may enter a box the nested test would
/// not let it into, never the reverse. The test stays conservative, the
/// hits are the same, and every other ray gets the nested test's results
/// (but for the sign of a zero entry).
#[inline(always)]
pub(crate) fn slab_scalar<const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    slab_scalar_with::<true, W>(n, r, bound, t)
}

/// [`slab_scalar`], its maxima and minima side by side (`BALANCED`) or
/// nested as [`Aabb::slab`] nests them (what the tests check the side by
/// side ones against).
#[inline(always)]
fn slab_scalar_with<const BALANCED: bool, const W: usize>(
    n: &WideNode<W>,
    r: &BoxRay,
    bound: f32,
    t: &mut [f32; W],
) -> u32 {
    let (mut lo, mut hi) = ([[0.0f32; W]; 3], [[0.0f32; W]; 3]);
    for a in 0..3 {
        let (near, far) = (n.plane_row(r.near[a]), n.plane_row(r.far[a]));
        for i in 0..W {
            lo[a][i] = (near[i] - r.origin[a]) * r.inv_dir[a];
            hi[a][i] = (far[i] - r.origin[a]) * r.inv_exit[a];
        }
    }
    let mut mask = 0u32;
    for i in 0..W {
        // NaN-ignoring max/min: see Aabb::slab.
        let (e, x) = if BALANCED {
            (
                max_ns(max_ns(lo[0][i], lo[1][i]), max_ns(lo[2][i], r.tmin)),
                min_ns(min_ns(hi[0][i], hi[1][i]), min_ns(hi[2][i], bound)),
            )
        } else {
            (
                max_ns(lo[0][i], max_ns(lo[1][i], max_ns(lo[2][i], r.tmin))),
                min_ns(hi[0][i], min_ns(hi[1][i], min_ns(hi[2][i], bound))),
            )
        };
        t[i] = e;
        mask |= u32::from(e <= x) << i;
    }
    mask
}

/// A traversal stack item: a node (`count == 0`) or a leaf, and the ray's
/// entry distance into its box.
#[derive(Clone, Copy, Debug)]
struct Entry {
    child: u32,
    count: u32,
    entry: f32,
}

impl Entry {
    const NONE: Self = Self {
        child: 0,
        count: 0,
        entry: 0.0,
    };
}

/// Items kept inline; a tree deep enough to need more (each level adds at
/// most `W - 1`) spills to the heap instead of failing. 32 rather than 64:
/// the array is set up for every ray, and short rays feel it (shadow
/// any-hit rays +5–12% on bunny00 and the dragon, alternated runs); 16
/// rather than 32 likewise (`raymesh-ab --accel bvh8` against 19da489,
/// one ray at a time: shadow rays 1.00–1.03 on the pig, bunny00 and the
/// dragon, random rays 0.995–1.007; a 2M-triangle sphere's random rays
/// 1.02–1.03, the teapot in a stadium's 1.01; random streams over a
/// 600K-triangle sphere 1.02–1.03; packets of primary and shadow rays
/// 0.995–1.02), the rays that would need more being few even over deep
/// trees.
const INLINE: usize = 16;

/// The wide walk's stack: an inline array (cheap to set up per ray) over
/// a `Vec` that takes the older items when it fills. The node loop only
/// pushes onto and pops from the inline part, which makes no call; the
/// walk moves items between the two parts outside that loop.
///
/// The array is the caller's, borrowed, not a field: held in the struct,
/// it shared one allocation with `len`, and the compiler, unable to tell
/// a store to `items[len]` from a store to `len`, kept `len` in memory (a
/// load and a store at every push; callgrind, bunny00 random rays, 1,019
/// -> 1,015 instructions a ray, and `raymesh-ab --accel bvh8` closest
/// hits 1.01-1.02 on bunny00 and the dragon, both builds as baseline).
struct WalkStack<'a> {
    /// The newest items.
    items: &'a mut [Entry; INLINE],
    /// Items in `items`.
    len: usize,
    /// Older items, oldest first.
    spill: Vec<Entry>,
}

impl<'a> WalkStack<'a> {
    #[inline(always)]
    fn new(items: &'a mut [Entry; INLINE]) -> Self {
        Self {
            items,
            len: 0,
            spill: Vec::new(),
        }
    }

    /// Empties the stack.
    #[inline(always)]
    fn clear(&mut self) {
        self.len = 0;
        self.spill.clear();
    }

    /// Whether `n` more items fit inline.
    #[inline(always)]
    fn has_room(&self, n: usize) -> bool {
        self.len + n <= INLINE
    }

    /// Pushes `e` inline; the caller has made room ([`Self::has_room`]).
    #[inline(always)]
    fn push(&mut self, e: Entry) {
        self.items[self.len] = e;
        self.len += 1;
    }

    /// The newest inline item with an entry within `bound` (those beyond
    /// it are dropped: the ray no longer reaches them; one equal to it
    /// stays, since ties go by index), or `None` when the inline part runs
    /// out, whatever the spill holds. Without `CULL`, the newest item,
    /// whatever its entry: for unordered (any-hit) walks, whose bound
    /// never changes but to end the walk, so that nothing pushed is ever
    /// beyond it; they skip storing and comparing entries (bunny00 random
    /// any-hit: 953 -> 915 instructions a ray).
    #[inline(always)]
    fn pop_inline<const CULL: bool>(&mut self, bound: f32) -> Option<Entry> {
        while self.len > 0 {
            self.len -= 1;
            let e = self.items[self.len];
            if !CULL || e.entry <= bound {
                return Some(e);
            }
        }
        None
    }

    /// [`Self::pop_inline`], refilling the inline part from the spill when
    /// it runs out: `None` only when the whole stack is empty.
    #[inline(always)]
    fn pop<const CULL: bool>(&mut self, bound: f32) -> Option<Entry> {
        loop {
            if let Some(e) = self.pop_inline::<CULL>(bound) {
                return Some(e);
            }
            if self.spill.is_empty() {
                return None;
            }
            self.refill();
        }
    }

    /// Moves the inline items to the spill.
    ///
    /// The moves are out of line (cold) and are handed the fields they
    /// touch, not `self`: a call given `&mut self` takes the stack's
    /// address, which can put `len` back in memory (see [`WalkStack`];
    /// measured only together with the borrowed array).
    #[inline(always)]
    fn spill(&mut self) {
        spill_items(&self.items[..self.len], &mut self.spill);
        self.len = 0;
    }

    /// Moves the newest spilled items (as many as fit) back inline.
    #[inline(always)]
    fn refill(&mut self) {
        self.len = refill_items(self.items, &mut self.spill);
    }
}

/// [`WalkStack::spill`]'s move: `items` onto the end of `spill`.
#[cold]
#[inline(never)]
fn spill_items(items: &[Entry], spill: &mut Vec<Entry>) {
    spill.extend_from_slice(items);
}

/// [`WalkStack::refill`]'s move: the newest items of `spill` (as many as
/// fit) to the start of `items`; returns how many.
#[cold]
#[inline(never)]
fn refill_items(items: &mut [Entry; INLINE], spill: &mut Vec<Entry>) -> usize {
    let k = spill.len().min(INLINE);
    let from = spill.len() - k;
    items[..k].copy_from_slice(&spill[from..]);
    spill.truncate(from);
    k
}

/// A traversal stack: a small inline array (cheap to set up per ray) that
/// spills to a `Vec` on degenerate trees, so no depth bound is needed.
pub(super) struct Stack<T> {
    /// The first [`INLINE`] items.
    items: [T; INLINE],
    /// Items on the stack, inline and spilled.
    len: usize,
    /// Items past the first [`INLINE`], in push order.
    spill: Vec<T>,
}

impl<T: Copy> Stack<T> {
    /// An empty stack; `none` fills the inline array.
    #[inline(always)]
    pub(super) fn new(none: T) -> Self {
        Self {
            items: [none; INLINE],
            len: 0,
            spill: Vec::new(),
        }
    }

    #[inline(always)]
    pub(super) fn push(&mut self, e: T) {
        if self.len < INLINE {
            self.items[self.len] = e;
        } else {
            self.spill.push(e);
        }
        self.len += 1;
    }

    /// `len` counts every item, so a pop from the inline array (nearly
    /// all of them) decides by `len` alone, without reading the spill.
    #[inline(always)]
    pub(super) fn pop(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        if self.len < INLINE {
            Some(self.items[self.len])
        } else {
            self.spill.pop()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NoStats;
    use proptest::prelude::*;

    /// Linux's cache sizes read as bytes; anything else, or a size no L2
    /// has, is none (and the walk then assumes 512 KiB).
    #[test]
    fn cache_sizes_parse_as_linux_writes_them() {
        assert_eq!(parse_cache_size("1024K\n"), Some(1 << 20));
        assert_eq!(parse_cache_size("512K"), Some(512 << 10));
        assert_eq!(parse_cache_size("2M"), Some(2 << 20));
        assert_eq!(parse_cache_size("262144"), Some(256 << 10));
        // The range's ends: 64 KiB and 8 MiB are taken, past them not.
        assert_eq!(parse_cache_size("64K"), Some(64 << 10));
        assert_eq!(parse_cache_size("8M"), Some(8 << 20));
        assert_eq!(parse_cache_size("8193K"), None);
        for bad in [
            "",
            "K",
            "12x",
            "-1K",
            "32K",
            "1G",
            "16M",
            "99999999999999999999K",
        ] {
            assert_eq!(parse_cache_size(bad), None, "{bad:?}");
        }
    }

    /// `stats`' expected node and leaf tests are what random lines give:
    /// for lines uniform in space (isotropic, uniform over each
    /// direction's plane), the chance of meeting a box, given that they
    /// meet the root's, is the ratio of the two boxes' areas (Crofton's
    /// formula), which both figures are built on. Each line that meets the
    /// root box counts the inner nodes whose boxes it meets (the binary
    /// tree) or the root plus every inner child box (the 8-wide one), and
    /// each leaf box it meets in blocks; the averages of 40,000 such lines
    /// must stand within 2% of the figures (they stood within 0.6%; the
    /// 8-wide tree's figures without the root's test are 18% off).
    #[test]
    fn expected_tests_are_what_random_lines_meet() {
        // Small boxes over a sphere, as a mesh's triangles lie: lines
        // that meet the root box mostly meet several leaves.
        let mut next = crate::test_util::xorshift(0x2545_f491);
        let boxes: Vec<Aabb> = (0..3000)
            .map(|_| {
                let p = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize_or_zero();
                Aabb::new(p - Vec3::splat(0.03), p + Vec3::splat(0.03))
            })
            .collect();
        let config = crate::BuildConfig::default();
        let bin = crate::BvhBuilder::BinnedSah.build(&boxes, &config);
        let wide = Bvh8::from_binary(bin.clone());
        let root = bin.bounds();
        let (center, r) = (root.centroid(), 0.5 * root.extent().length());
        let mut next = crate::test_util::xorshift(0x9e37_79b9);
        // A line through `p` along `d`, as the slab test's interval over
        // the whole line: whether it meets `b`.
        let meets = |b: Aabb, p: Vec3, d: Vec3| {
            let oct =
                usize::from(d.x < 0.0) | usize::from(d.y < 0.0) << 1 | usize::from(d.z < 0.0) << 2;
            let (t0, t1) = b.slab(p, d.recip(), oct, f32::NEG_INFINITY, f32::INFINITY);
            t0 <= t1
        };
        // The binary tree's nodes but the root's unused sibling.
        let bin_nodes: Vec<_> = bin
            .nodes()
            .into_iter()
            .enumerate()
            .filter(|(i, _)| *i != 1)
            .map(|(_, n)| n)
            .collect();
        let (mut lines, mut bin_counts, mut wide_counts) = (0usize, (0.0, 0.0), (0.0, 0.0));
        let blocks = |count: u32| f64::from(count.div_ceil(BLOCK as u32));
        while lines < 40_000 {
            // A direction uniform on the sphere, and a point uniform on a
            // square of the plane through the center across it, wide
            // enough to hold the root box's shadow.
            let z = 2.0 * next() - 1.0;
            let phi = std::f32::consts::TAU * next();
            let d = Vec3::new(
                (1.0 - z * z).max(0.0).sqrt() * phi.cos(),
                (1.0 - z * z).max(0.0).sqrt() * phi.sin(),
                z,
            );
            let (u, v) = d.any_orthonormal_pair();
            let p = center + u * ((2.0 * next() - 1.0) * r) + v * ((2.0 * next() - 1.0) * r);
            if !meets(root, p, d) {
                continue;
            }
            lines += 1;
            for n in &bin_nodes {
                if meets(n.bounds(), p, d) {
                    if n.is_leaf() {
                        bin_counts.1 += blocks(n.count);
                    } else {
                        bin_counts.0 += 1.0;
                    }
                }
            }
            wide_counts.0 += 1.0;
            for n in &wide.nodes {
                for k in (0..8).filter(|&k| n.is_used(k) && meets(n.child_box(k), p, d)) {
                    if n.count[k] > 0 {
                        wide_counts.1 += blocks(n.count[k]);
                    } else {
                        wide_counts.0 += 1.0;
                    }
                }
            }
        }
        let lines = lines as f64;
        for (name, stats, (nodes, leaves)) in [
            ("binary", bin.stats(), bin_counts),
            ("8-wide", wide.stats(), wide_counts),
        ] {
            let (want_n, want_l) = (stats.node_tests.unwrap(), stats.leaf_tests.unwrap());
            let (got_n, got_l) = (nodes / lines, leaves / lines);
            assert!(
                (got_n / want_n - 1.0).abs() < 0.02,
                "{name}: node tests {got_n} by lines, {want_n} by areas"
            );
            assert!(
                (got_l / want_l - 1.0).abs() < 0.02,
                "{name}: leaf tests {got_l} by lines, {want_l} by areas"
            );
            assert!(
                want_n > 2.0 && want_l > 0.0,
                "{name}: {want_n} node tests, {want_l} leaf tests"
            );
        }
    }

    /// Pops give back every push in reverse order, across the spill.
    #[test]
    fn stack_is_lifo_across_the_spill() {
        let mut st = Stack::new(0usize);
        for round in 0..2 {
            for i in 0..3 * INLINE {
                st.push(i);
            }
            for i in (0..3 * INLINE).rev() {
                assert_eq!(st.pop(), Some(i), "round {round}");
            }
            assert_eq!(st.pop(), None);
        }
    }

    /// A chain of `depth` `W`-wide nodes along +x, each holding `W - 1`
    /// leaves (slot `8 * level + k`) and the next node in a box the ray
    /// enters before any of them, so that the walk takes the node and
    /// pushes the leaves at every level: `W - 1` items a level on the stack.
    fn leafy_chain_w<const W: usize>(depth: usize) -> WideBvh<W> {
        let mut nodes = vec![WideNode::<W>::EMPTY; depth];
        for (level, n) in nodes.iter_mut().enumerate() {
            let x = 10.0 * level as f32;
            for k in 0..W - 1 {
                let lo = Vec3::new(x + k as f32, -1.0, -1.0);
                n.set_box(k, Aabb::new(lo, lo + Vec3::new(0.5, 2.0, 2.0)));
                n.child[k] = (8 * level + k) as u32;
                n.count[k] = 1;
            }
            if level + 1 < depth {
                let b = Aabb::new(Vec3::new(-1.0, -1.0, -1.0), Vec3::new(1e4, 1.0, 1.0));
                n.set_box(W - 1, b);
                n.child[W - 1] = level as u32 + 1;
            }
        }
        WideBvh {
            nodes,
            prim_ids: (0..8 * depth as u32).collect(),
            bounds: Aabb::new(Vec3::splat(-1.0), Vec3::new(1e4, 1.0, 1.0)),
        }
    }

    /// [`leafy_chain_w`] of 8-wide nodes.
    fn leafy_chain(depth: usize) -> Bvh8 {
        leafy_chain_w::<8>(depth)
    }

    /// A walk that needs many times the stack's inline room (`W - 1` items
    /// a level, 40 levels, 8- and 4-wide) still reaches every leaf once,
    /// ordered or not, and front to back when ordered: its inline part
    /// spills and refills correctly, and a walk that keeps its stack
    /// inline hands the ray to one that spills.
    #[test]
    fn deep_walk_spills_and_reaches_every_leaf_once() {
        deep_walk_reaches_every_leaf_once(&leafy_chain_w::<8>(40));
        // The 4-wide walk keeps its stack inline and walks a ray again,
        // with a stack that spills, where it would not fit.
        deep_walk_reaches_every_leaf_once(&leafy_chain_w::<4>(40));
    }

    fn deep_walk_reaches_every_leaf_once<const W: usize>(bvh: &WideBvh<W>) {
        let depth = bvh.nodes.len();
        assert!(
            (W - 1) * depth > 3 * INLINE,
            "the walk must spill several times"
        );
        let ray = Ray::new(Vec3::new(-2.0, 0.1, 0.2), Vec3::X, 0.0, f32::INFINITY);
        for ordered in [true, false] {
            let mut seen = Vec::new();
            let mut block = |first: u32, count: u32| {
                assert_eq!(count, 1);
                seen.push(first);
                f32::INFINITY
            };
            if ordered {
                bvh.traverse_blocks(&ray, &mut NoStats, &mut block);
            } else {
                bvh.traverse_blocks_unordered(&ray, &mut NoStats, &mut block);
            }
            let leaves = |l: usize| (0..W - 1).map(move |k| (8 * l + k) as u32);
            let mut sorted = seen.clone();
            sorted.sort_unstable();
            let all: Vec<u32> = (0..depth).flat_map(leaves).collect();
            assert_eq!(sorted, all, "W {W}, ordered: {ordered}");
            if ordered {
                // Every leaf's box lies past the next node's entry, so the
                // walk reaches the last level first and comes back: the
                // leaves in decreasing level, front to back within one.
                let expect: Vec<u32> = (0..depth).rev().flat_map(leaves).collect();
                assert_eq!(seen, expect, "W {W}");
            }
        }
    }

    /// A group's occlusion walk over 40 levels of seven leaves each
    /// (more items pending than its stack first holds, so that it grows)
    /// offers every ray every leaf once, and a ray that hits leaves; its
    /// closest-hit walk offers every ray every leaf once.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn deep_group_walk_grows_its_stack() {
        let bvh = leafy_chain(40);
        let rays: Vec<Ray> = (0..5)
            .map(|i| {
                let o = Vec3::new(-2.0, 0.1 * i as f32, 0.2);
                Ray::new(o, Vec3::new(1.0, 0.001, 0.0), 0.0, f32::INFINITY)
            })
            .collect();
        let g = GroupRays::new(rays.iter());
        let test = |n: &Node8, g: &GroupRays, m: u32| {
            let e = group_slab_scalar(n, g, m);
            (e, entered_slots(&e))
        };
        let leaves: Vec<u32> = (0..40)
            .flat_map(|l| (0..7).map(move |k| 8 * l + k))
            .collect();
        for hit_at in [None, Some(77)] {
            let mut stack = Vec::new();
            let mut seen = vec![Vec::new(); rays.len()];
            let found = bvh.occluded_group(
                &g,
                rays.len(),
                &mut stack,
                &mut (0, 0),
                &mut (0, 0),
                &mut |i, first, count| {
                    assert_eq!(count, 1);
                    seen[i].push(first);
                    // Ray 3 hits at leaf 77.
                    i == 3 && Some(first) == hit_at
                },
                &|_| {},
                test,
            );
            assert!(
                stack.len() > 8 * 8,
                "the stack did not grow: {}",
                stack.len()
            );
            assert_eq!(found, if hit_at.is_some() { 1 << 3 } else { 0 });
            for (i, s) in seen.iter_mut().enumerate() {
                if i == 3 && hit_at.is_some() {
                    assert_eq!(s.last(), Some(&77), "ray {i} went on after its hit");
                }
                if i != 3 || hit_at.is_none() {
                    s.sort_unstable();
                    assert_eq!(*s, leaves, "ray {i}");
                }
            }
        }
        // The closest-hit walk too, where no leaf holds a hit.
        struct Seen(Vec<Vec<u32>>);
        impl GroupLeaf for Seen {
            fn visit(&mut self, i: usize, first: u32, count: u32) -> Option<f32> {
                assert_eq!(count, 1);
                self.0[i].push(first);
                None
            }
            fn prefetch(&self, _: u32) {}
        }
        let mut g = g;
        let mut seen = Seen(vec![Vec::new(); rays.len()]);
        let mut stack = Vec::new();
        let test = |n: &Node8, g: &GroupRays, m: u32| {
            let (e, least) = group_slab_entry_scalar(n, g, m);
            (e, least, entered_slots(&e))
        };
        bvh.intersect_group(
            &mut g,
            rays.len(),
            &mut stack,
            &mut (0, 0),
            &mut seen,
            test,
            reaching,
        );
        assert!(
            stack.len() > 8 * 8,
            "the stack did not grow: {}",
            stack.len()
        );
        for (i, s) in seen.0.iter_mut().enumerate() {
            s.sort_unstable();
            assert_eq!(*s, leaves, "ray {i}, closest");
        }
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// `enter` pushes a node's entered children, all but the one it
        /// returns, in the order of a stable sort of the slots by entry,
        /// farthest first (so that on a tie the later slot is nearer), and
        /// returns the nearest; unordered, in slot order. Whatever the
        /// stack held before stays below, untouched. Entries drawn from a
        /// few values, so that ties are common.
        #[test]
        fn enter_sorts_the_entered_children(
            mask in 0u32..256,
            t in proptest::array::uniform8(prop_oneof![
                (0u8..4).prop_map(f32::from),
                -1.0f32..10.0,
            ]),
            below in 0usize..8,
            ordered in any::<bool>(),
        ) {
            let mut n = Node8::empty();
            for k in 0..8 {
                n.child[k] = 100 + k as u32;
                n.count[k] = 1;
            }
            let mut items = [Entry::NONE; INLINE];
            let mut stack = WalkStack::new(&mut items);
            let old = |i: usize| Entry { child: i as u32, count: 9, entry: -(i as f32) };
            for i in 0..below {
                stack.push(old(i));
            }
            let got = if ordered {
                enter::<true, 8>(&[], &n, mask, &t, &mut stack, &|_| {})
            } else {
                enter::<false, 8>(&[], &n, mask, &t, &mut stack, &|_| {})
            };
            let mut want: Vec<usize> = (0..8).filter(|k| mask >> k & 1 != 0).collect();
            if ordered {
                want.sort_by(|&a, &b| t[b].partial_cmp(&t[a]).expect("no NaN"));
            }
            prop_assert_eq!(got.map(|e| e.child), want.last().map(|&k| 100 + k as u32));
            let pushed = want.len().saturating_sub(1);
            prop_assert_eq!(stack.len, below + pushed);
            for i in 0..below {
                prop_assert_eq!(stack.items[i].child, old(i).child);
            }
            for (j, &k) in want[..pushed].iter().enumerate() {
                let e = stack.items[below + j];
                prop_assert_eq!((e.child, e.count), (100 + k as u32, 1));
                if ordered {
                    prop_assert_eq!(e.entry.to_bits(), t[k].to_bits());
                }
            }
        }
    }

    /// The AVX2 walk, whose stack stays inline, visits the leaves the
    /// spilling walk visits, in the same order, where they fit, and stops
    /// (returning false) where they would not: 7 items a level, 2 levels
    /// fit inline, 40 do not.
    #[test]
    fn avx_walk_stops_where_the_stack_would_spill() {
        let Some(avx) = Avx2::detect() else {
            return;
        };
        let ray = Ray::new(Vec3::new(-2.0, 0.1, 0.2), Vec3::X, 0.0, f32::INFINITY);
        for (depth, fits) in [(1, true), (2, true), (3, false), (40, false)] {
            assert_eq!(7 * depth <= INLINE, fits);
            let bvh = leafy_chain(depth);
            for ordered in [true, false] {
                let walk = |avx_walk: bool| {
                    let mut seen = Vec::new();
                    let mut block = |first: u32, _count: u32| {
                        seen.push(first);
                        f32::INFINITY
                    };
                    let done = match (avx_walk, ordered) {
                        (true, true) => avx.run(|| {
                            bvh.traverse_blocks_avx2::<true, _>(
                                avx,
                                &ray,
                                &mut NoStats,
                                &mut block,
                                &|_| {},
                            )
                        }),
                        (true, false) => avx.run(|| {
                            bvh.traverse_blocks_avx2::<false, _>(
                                avx,
                                &ray,
                                &mut NoStats,
                                &mut block,
                                &|_| {},
                            )
                        }),
                        (false, true) => {
                            bvh.traverse_blocks(&ray, &mut NoStats, &mut block);
                            true
                        }
                        (false, false) => {
                            bvh.traverse_blocks_unordered(&ray, &mut NoStats, &mut block);
                            true
                        }
                    };
                    (done, seen)
                };
                let (done, seen) = walk(true);
                let (_, want) = walk(false);
                assert_eq!(done, fits, "depth {depth}, ordered: {ordered}");
                if fits {
                    assert_eq!(seen, want, "depth {depth}, ordered: {ordered}");
                }
            }
        }
    }

    /// A stream walks each of its rays as the one-ray walk does: the same
    /// leaves in the same order, ordered or not, across the stack's
    /// spills (the deep chain), with more rays than lanes in flight, an
    /// invalid ray skipped, a ray ended early by its leaf, and one whose
    /// leaves lower its bound (which only the ordered walks cull by).
    #[test]
    fn stream_walks_each_ray_as_alone() {
        let bvh = leafy_chain(40);
        let ray = |y: f32, tmax: f32| Ray::new(Vec3::new(-2.0, y, 0.2), Vec3::X, 0.0, tmax);
        let mut rays = vec![
            ray(0.1, f32::INFINITY),
            ray(-0.3, f32::INFINITY),
            Ray::new(Vec3::ZERO, Vec3::ZERO, 0.0, 1.0),
            ray(0.5, 150.0),
            ray(0.9, f32::INFINITY),
            ray(5.0, f32::INFINITY),
            ray(-0.7, f32::INFINITY),
        ];
        // Twice as many rays as the most lanes, some ending early, so
        // that every lane count starts rays while others are in flight.
        rays.extend((0..2 * STREAM_LANES[1]).map(|k| {
            let tmax = if k % 3 == 0 {
                40.0 + 15.0 * k as f32
            } else {
                f32::INFINITY
            };
            ray(-0.95 + 1.9 * k as f32 / (2 * STREAM_LANES[1]) as f32, tmax)
        }));
        // The fourth ray ends at a leaf of level 10 (as an any-hit query
        // would), the fifth finds `t = 250` in every leaf below level 30,
        // and the others find nothing.
        let answer = |i: usize, first: u32| {
            if i == 3 && first == 8 * 10 {
                f32::NEG_INFINITY
            } else if i == 4 && first < 8 * 30 {
                250.0
            } else {
                f32::INFINITY
            }
        };
        for ordered in [true, false] {
            let mut got = vec![Vec::new(); rays.len()];
            let mut leaf = |i: usize, first: u32, count: u32, _tmax: f32| {
                assert_eq!(count, 1);
                got[i].push(first);
                answer(i, first)
            };
            if ordered {
                bvh.traverse_stream::<true>(&rays, &mut leaf, |_| {});
            } else {
                bvh.traverse_stream::<false>(&rays, &mut leaf, |_| {});
            }
            // The other lane count (the tree is too small to take it), and
            // one lane, in plain Rust.
            for k in [STREAM_LANES[1], 1] {
                let mut again = vec![Vec::new(); rays.len()];
                let mut leaf = |i: usize, first: u32, _count: u32, _tmax: f32| {
                    again[i].push(first);
                    answer(i, first)
                };
                let test =
                    |n: &Node8, r: &BoxRay, bound, t: &mut [f32; 8]| slab_scalar(n, r, bound, t);
                match (ordered, k) {
                    (true, 1) => bvh.stream_with::<true, 1>(&rays, &mut leaf, &|_| {}, test),
                    (false, 1) => bvh.stream_with::<false, 1>(&rays, &mut leaf, &|_| {}, test),
                    (true, _) => bvh.stream_with::<true, { STREAM_LANES[1] }>(
                        &rays,
                        &mut leaf,
                        &|_| {},
                        test,
                    ),
                    (false, _) => bvh.stream_with::<false, { STREAM_LANES[1] }>(
                        &rays,
                        &mut leaf,
                        &|_| {},
                        test,
                    ),
                }
                assert_eq!(again, got, "{k} lanes, ordered: {ordered}");
            }
            for (i, r) in rays.iter().enumerate() {
                let mut want = Vec::new();
                let mut block = |first: u32, _count: u32| {
                    want.push(first);
                    answer(i, first)
                };
                if ordered {
                    bvh.traverse_blocks(r, &mut NoStats, &mut block);
                } else {
                    bvh.traverse_blocks_unordered(r, &mut NoStats, &mut block);
                }
                assert_eq!(got[i], want, "ray {i}, ordered: {ordered}");
            }
            assert!(got[2].is_empty() && got[5].is_empty());
            assert!(got[0].len() == 280 && got[3].len() < 280);
            // The fifth ray's bound culls what the ordered walks pushed;
            // the unordered ones, for any-hit queries, cull nothing.
            assert_eq!(got[4].len() < 280, ordered);
        }
    }

    /// A leaf's new bound culls the stacked items beyond it, across the
    /// spill: with every leaf answering `t = 35`, only the last level's
    /// nearest leaf (reached first) and the leaves entered before 35 are
    /// tested.
    #[test]
    fn deep_walk_culls_across_the_spill() {
        let depth = 40;
        let bvh = leafy_chain(depth);
        let ray = Ray::new(Vec3::new(-2.0, 0.1, 0.2), Vec3::X, 0.0, f32::INFINITY);
        let mut seen = Vec::new();
        bvh.traverse_blocks(&ray, &mut NoStats, &mut |first, _| {
            seen.push(first);
            35.0
        });
        // Leaf (level, k) is entered at t = 10 * level + k + 2.
        let mut expect = vec![(8 * (depth - 1)) as u32];
        for l in (0..depth).rev() {
            for k in 0..7 {
                if 10 * l + k + 2 <= 35 && !(l == depth - 1 && k == 0) {
                    expect.push((8 * l + k) as u32);
                }
            }
        }
        assert_eq!(seen, expect);
    }

    /// The wide node of binary node `at` and those below it, made by one
    /// depth-first walk that appends each node as it comes: the layout
    /// [`emit`] must give.
    fn walk<const W: usize>(plan: &Plan<'_, W>, at: u32, out: &mut Vec<WideNode<W>>) -> u32 {
        let me = out.len();
        out.push(WideNode::EMPTY);
        let mut kids = Slots::<W>::default();
        plan.children(at, &mut kids);
        let mut node = WideNode::<W>::EMPTY;
        for (i, &k) in kids.ids[..kids.len].iter().enumerate() {
            node.set_box(i, plan.bin.node(k).bounds());
            if plan.choice(k)[0] == 0 {
                (node.child[i], node.count[i]) = leaf_range(plan.bin, k).unwrap();
            } else {
                node.child[i] = walk(plan, k, out);
            }
        }
        out[me] = node;
        me as u32
    }

    fn check_emit<const W: usize>(n: usize, threads: usize) {
        let boxes = crate::test_util::clustered_boxes(n);
        let bin = crate::BvhBuilder::BinnedSah.build(&boxes, &crate::BuildConfig::default());
        let wide =
            crate::test_util::pool(threads).install(|| WideBvh::<W>::from_binary(bin.clone()));
        let plan = Plan::<W>::new(&bin);
        if plan.choice(0)[0] == 0 {
            // One leaf: no wide node to emit.
            assert_eq!(wide.nodes.len(), 1);
            return;
        }
        let mut want = Vec::new();
        walk(&plan, 0, &mut want);
        assert_eq!(plan.wide_nodes(0) as usize, want.len(), "n {n}");
        assert!(wide.nodes == want, "n {n}, {threads} threads");
    }

    /// The collapse writes subtrees of at least [`PAR_EMIT`] wide nodes in
    /// parallel, each into the part of the array its size gives: the
    /// nodes, and their order, are those of one depth-first walk.
    #[test]
    fn parallel_emission_matches_one_walk() {
        for n in [3, 40, 1000, 30_000] {
            if n > 1000 && cfg!(debug_assertions) {
                continue;
            }
            for threads in [1, 3] {
                check_emit::<8>(n, threads);
                check_emit::<4>(n, threads);
            }
        }
        let boxes = crate::test_util::clustered_boxes(30_000);
        let bin = crate::BvhBuilder::BinnedSah.build(&boxes, &crate::BuildConfig::default());
        let wide = Bvh8::from_binary(bin);
        assert!(
            wide.nodes.len() as u32 > 2 * PAR_EMIT,
            "the parallel path ran"
        );
    }

    /// [`Plan::cost`] as it was first written (each child's useful slots
    /// found by comparing its costs, each split's minimum by `min_by` over
    /// `total_cmp`), one thread: the oracle the planner is held to.
    fn cost_by_closures<const W: usize>(
        plan: &Plan<'_, W>,
        n: u32,
    ) -> ([f32; W], Option<(u32, u32)>, [u32; W]) {
        let node = *plan.bin.node(n);
        let area = node.bounds().half_area();
        let leaf_cost = |(_, c): (u32, u32)| area * BLOCK_COST * c.div_ceil(BLOCK as u32) as f32;
        if node.is_leaf() {
            let range = (node.index, node.count);
            return ([leaf_cost(range); W], Some(range), [0; W]);
        }
        let (l, lr, lcnt) = cost_by_closures(plan, node.index);
        let (r, rr, rcnt) = cost_by_closures(plan, node.index + 1);
        let range = lr.zip(rr).and_then(|(a, b)| merge_ranges(a, b));
        let leaf = range.map_or(f32::INFINITY, leaf_cost);
        // Slots past a subtree's `useful` ones cost the same as its last
        // useful one (a pair of binary leaves has one each), so more of
        // them are never better.
        let useful = |c: &[f32; W]| (1..W).find(|&s| c[s..].iter().all(|&x| x == c[s - 1]));
        let (lu, ru) = (useful(&l).unwrap_or(W), useful(&r).unwrap_or(W));
        // The best split of `s` slots between the two subtrees.
        let split = |s: usize| {
            (s.saturating_sub(ru).max(1)..=lu.min(s - 1))
                .map(|k| (l[k - 1] + r[s - k - 1], k))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("two slots or more")
        };
        let mut c = [0.0; W];
        let mut choice = [0u8; 8];
        let (inner, k) = split(W.min(lu + ru));
        let inner = inner + area * NODE_COST;
        // A leaf only where the subtree makes one (NaN costs, from
        // infinite boxes, choose it too).
        (c[0], choice[0]) = if range.is_some() && !(inner < leaf) {
            (leaf, 0)
        } else {
            (inner, k as u8)
        };
        for s in 2..=W {
            if s > lu + ru {
                c[s - 1] = c[s - 2];
                continue;
            }
            let (spread, k) = split(s);
            (c[s - 1], choice[s - 1]) = if spread < c[s - 2] {
                (spread, k as u8)
            } else {
                (c[s - 2], 0)
            };
        }
        // The wide nodes the collapse makes below each way of filling the
        // parent's slots, following the choices as `slots` does: `n` as a
        // wide node of its own (its `k` slots on the left, `W - k` on the
        // right, as `children` splits them), or `n`'s subtree spread over
        // `s` slots. Counted here from the children's counts, not by
        // walking each node's slots (which took 43% more instructions).
        let wide = match choice[0] as usize {
            0 => 0,
            k => 1 + lcnt[k - 1] + rcnt[W - k - 1],
        };
        let mut cnt = [wide; W];
        for s in 2..=W {
            cnt[s - 1] = match choice[s - 1] as usize {
                0 => cnt[s - 2],
                k => lcnt[k - 1] + rcnt[s - k - 1],
            };
        }
        let packed = (0..W).fold(0u64, |w, i| w | u64::from(choice[i]) << (4 * i));
        plan.choice[n as usize].store(packed | u64::from(wide) << 32, Ordering::Relaxed);
        (c, range, cnt)
    }

    /// The planner makes the choices, costs and wide-node counts of the
    /// first version, bit for bit, on trees where ties and NaN costs
    /// decide: spread and clustered boxes, piles of identical boxes, flat
    /// boxes (zero areas: every cost 0), and boxes with NaN and infinite
    /// corners, from binary trees of small and block-weighed leaves.
    #[test]
    fn plan_matches_the_first_planner() {
        let mut next = crate::test_util::xorshift(0x1234_5677);
        let mut sets: Vec<Vec<Aabb>> = vec![
            crate::test_util::clustered_boxes(6_000),
            (0..3_000)
                .map(|_| {
                    let p = Vec3::new(next(), next(), next()) * 10.0;
                    Aabb::new(p, p + Vec3::new(next(), next(), next()))
                })
                .collect(),
            vec![Aabb::new(Vec3::ZERO, Vec3::ONE); 300],
            (0..500)
                .map(|i| {
                    let p = Vec3::new(i as f32 * 0.1, next(), 0.0);
                    Aabb::new(p, p + Vec3::new(0.1, 0.0, 0.0))
                })
                .collect(),
        ];
        let mut odd = crate::test_util::clustered_boxes(3_000);
        for (i, b) in odd.iter_mut().enumerate() {
            match i % 37 {
                // Infinite and flat: its area is NaN (infinity times 0).
                0 => (b.max.x, b.max.y) = (f32::INFINITY, b.min.y),
                3 => b.max.x = f32::INFINITY,
                5 => b.min.y = f32::NEG_INFINITY,
                11 => b.min.z = f32::NAN,
                _ => {}
            }
        }
        sets.push(odd);
        // Boxes infinite on x and flat on y, apart from finite ones: the
        // first's nodes have NaN areas (infinity times 0), so NaN costs.
        sets.push(
            (0..1_000)
                .map(|i| {
                    let p = Vec3::new(i as f32, 0.0, (i % 5) as f32 + 100.0 * (i % 2) as f32);
                    let far = Vec3::new(f32::INFINITY, 0.0, p.z + 1.0);
                    Aabb::new(p, if i % 2 == 0 { far } else { p + Vec3::ONE })
                })
                .collect(),
        );
        let (mut planned, mut nan_costs) = (0, 0);
        for boxes in &sets {
            for leaf_block in [None, Some(8)] {
                let config = crate::BuildConfig {
                    leaf_block,
                    ..Default::default()
                };
                let bin = crate::BvhBuilder::BinnedSah.build(boxes, &config);
                plans_agree::<8>(&bin);
                plans_agree::<4>(&bin);
                planned += bin.pairs.len();
                nan_costs += (0..bin.pairs.len() as u32 * 2)
                    .filter(|&k| bin.node(k).bounds().half_area().is_nan())
                    .count();
            }
        }
        assert!(planned > 5_000, "{planned} pairs planned");
        assert!(nan_costs > 0, "some nodes' costs are NaN");

        // A leaf of NaN cost beside a node of two full leaves, which
        // cannot join it in one wide leaf: the root's split of its slots
        // follows from how many the NaN leaf counts as useful.
        use crate::bvh::{Node, NodePair};
        let node = |b: Aabb, index, count| Node {
            index,
            count,
            ..Node::new(b)
        };
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 1.0));
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let bin = Bvh {
            pairs: vec![
                NodePair([node(flat.union(unit), 2, 0), Node::new(Aabb::EMPTY)]),
                NodePair([node(flat, 0, 1), node(unit, 4, 0)]),
                NodePair([node(unit, 1, 8), node(unit, 9, 8)]),
            ]
            .into(),
            prim_ids: (0..17).collect(),
            depth: 3,
            parts: false,
        };
        plans_agree::<8>(&bin);
    }

    /// Asserts that [`Plan::new`] and [`cost_by_closures`] plan `bin` alike.
    fn plans_agree<const W: usize>(bin: &Bvh) {
        let plan = Plan::<W>::new(bin);
        let first = Plan::<W> {
            bin,
            choice: (0..bin.pairs.len() * 2)
                .map(|_| AtomicU64::new(0))
                .collect(),
        };
        let (want, want_range, want_wide) = cost_by_closures(&first, 0);
        let got = crate::test_util::pool(1).install(|| plan.cost(0, 0));
        assert_eq!(got.cost.map(f32::to_bits), want.map(f32::to_bits));
        assert_eq!((got.range, got.wide), (want_range, want_wide));
        for (a, b) in plan.choice.iter().zip(&first.choice) {
            assert_eq!(a.load(Ordering::Relaxed), b.load(Ordering::Relaxed));
        }
    }

    /// The stack gives items back last in, first out, past its inline
    /// part too.
    #[test]
    fn stack_spills_and_keeps_order() {
        let mut stack = Stack::new(Entry::NONE);
        let n = 3 * INLINE as u32 + 5;
        for i in 0..n {
            stack.push(Entry {
                child: i,
                count: 0,
                entry: i as f32,
            });
        }
        for i in (0..n).rev() {
            assert_eq!(stack.pop().map(|e| e.child), Some(i));
        }
        assert!(stack.pop().is_none());
    }

    /// Numbers uniform in `[-2, 2)` from a seed (an LCG: the same in every
    /// run and on every machine).
    fn uniform(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 40) as f32 / (1u64 << 24) as f32 * 4.0 - 2.0
        }
    }

    /// `n` boxes with corners from `f`.
    fn random_boxes(f: &mut impl FnMut() -> f32, n: usize) -> Vec<Aabb> {
        (0..n)
            .map(|_| {
                let p = Vec3::new(f(), f(), f());
                Aabb::new(p, p + Vec3::new(f().abs(), f().abs(), f().abs()))
            })
            .collect()
    }

    /// Every node test pads a box's exit as `(far - origin) ×
    /// exit_reciprocal(inv_dir)`, bit for bit: a ray whose `tmin` is that
    /// exit still enters the box, and one starting an ulp later does not.
    /// (Only the entry mask shows an exit, and random boxes almost never
    /// put an entry within an ulp of one: the other tests would not see
    /// a kernel rounding its exit otherwise.)
    #[test]
    fn node_tests_exit_at_the_padded_reciprocal() {
        use crate::bvh::{Node, NodePair, PairRay, PlaneRay};
        use raymesh_geometry::next_up;
        let mut f = uniform(7);
        let mut checked = 0;
        for _ in 0..2000 {
            let boxes = random_boxes(&mut f, 8);
            let node = Node8::from_boxes(&boxes);
            let o = Vec3::new(f(), f(), f()) * 3.0;
            for (i, b) in boxes.iter().enumerate() {
                // Toward a point of the box, on no axis exactly parallel.
                let target = b.min + (b.max - b.min) * Vec3::new(f(), f(), f()).abs() * 0.5;
                let away = |x: f32| if x.abs() < 0.01 { 0.01 } else { x };
                let to = target - o;
                let d = Vec3::new(away(to.x), away(to.y), away(to.z));
                let inv = Ray::new(o, d, 0.0, f32::INFINITY).inv_dir();
                let (mut entry, mut exit) = (f32::NEG_INFINITY, f32::INFINITY);
                for a in 0..3 {
                    let (near, far) = if d[a] < 0.0 {
                        (b.max[a], b.min[a])
                    } else {
                        (b.min[a], b.max[a])
                    };
                    entry = entry.max((near - o[a]) * inv[a]);
                    exit = exit.min((far - o[a]) * exit_reciprocal(inv[a]));
                }
                if !(entry <= exit && exit > 0.0 && exit.is_finite()) {
                    continue;
                }
                checked += 1;
                for (tmin, enters) in [(exit, true), (next_up(exit), false)] {
                    let ray = Ray::new(o, d, tmin, f32::INFINITY);
                    let what = format!("box {i}, tmin {tmin} (exit {exit})");
                    let (e, x) = b.slab(o, ray.inv_dir(), ray.octant(), tmin, f32::INFINITY);
                    assert_eq!(x.to_bits(), exit.to_bits(), "Aabb::slab, {what}");
                    assert_eq!(e <= x, enters, "Aabb::slab, {what}");
                    for simd in [true, false] {
                        crate::set_simd_enabled(simd);
                        let (mask, _) = node.slab(&BoxRay::new(&ray), f32::INFINITY);
                        let node4 = Node4::from_boxes(&boxes[i..i + 1]);
                        let mask4 = node4.slab(&BoxRay::new(&ray), f32::INFINITY).0;
                        crate::set_simd_enabled(true);
                        assert_eq!(mask >> i & 1 == 1, enters, "8-wide, simd {simd}, {what}");
                        assert_eq!(mask4 & 1 == 1, enters, "4-wide, simd {simd}, {what}");
                    }
                    let pair = NodePair([Node::new(*b), Node::new(*b)]);
                    let (l0, l1) = PlaneRay::new(&ray).slab(&pair.0[0], f32::INFINITY);
                    assert_eq!(l0 <= l1, enters, "binary walk, {what}");
                    let pr = PairRay::new(&ray);
                    assert_eq!(
                        super::super::pair_slab_scalar(&pair, &pr, f32::INFINITY).0 == 3,
                        enters,
                        "pair, {what}"
                    );
                    #[cfg(target_arch = "x86_64")]
                    if crate::simd::has_avx2() {
                        let got = crate::simd::pair_slab(&pair, &pr, f32::INFINITY).0;
                        assert_eq!(got == 3, enters, "AVX pair, {what}");
                    }
                    let rays = [ray; crate::LANES];
                    let packet = crate::Packet8::new(&rays).expect("one octant");
                    for simd in [true, false] {
                        crate::set_simd_enabled(simd);
                        let (m, _) = crate::packet::slab(
                            &packet,
                            b.min.to_array(),
                            b.max.to_array(),
                            &[f32::INFINITY; crate::LANES],
                        );
                        crate::set_simd_enabled(true);
                        assert_eq!(m == 0xff, enters, "packet, simd {simd}, {what}");
                        assert!(m == 0 || m == 0xff, "packet lanes agree, {what}");
                    }
                }
            }
        }
        assert!(checked > 10_000, "only {checked} boxes the rays cross");
    }

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The node test's maxima side by side give the nested maxima's
        /// entries and masks wherever y's reciprocals are finite, and
        /// never fewer boxes elsewhere; on any boxes without NaN (empty
        /// slots too), rays of hard directions (zero, tiny, huge
        /// components), and any `tmin` and bound (NaN and infinite too).
        #[test]
        fn side_by_side_maxima_match_the_nested_ones(
            corners in proptest::collection::vec(
                proptest::array::uniform6(
                    crate::test_util::hard_coord().prop_filter("no NaN", |x| !x.is_nan()),
                ),
                8,
            ),
            used in 0u32..256,
            o in proptest::array::uniform3(
                crate::test_util::hard_coord().prop_filter("finite", |x| x.is_finite()),
            ),
            d in proptest::array::uniform3(prop_oneof![
                3 => crate::test_util::hard_coord().prop_filter("finite", |x| x.is_finite()),
                1 => Just(1e-39f32),
                1 => Just(-f32::from_bits(1)),
            ]),
            tmin in crate::test_util::hard_coord(),
            bound in crate::test_util::hard_coord(),
        ) {
            let ray = Ray::new(Vec3::from_array(o), Vec3::from_array(d), 0.0, f32::INFINITY);
            prop_assume!(ray.is_valid());
            let mut node = Node8::empty();
            for (i, c) in corners.iter().enumerate() {
                let (a, b) = (Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5]));
                if used >> i & 1 != 0 {
                    node.set_box(i, Aabb::new(a.min(b), a.max(b)));
                }
            }
            let mut r = BoxRay::new(&ray);
            r.tmin = tmin;
            let (mut tb, mut tn) = ([0.0f32; 8], [0.0f32; 8]);
            let side = slab_scalar(&node, &r, bound, &mut tb);
            let nested = slab_scalar_with::<false, 8>(&node, &r, bound, &mut tn);
            if r.inv_dir[1].is_finite() && r.inv_exit[1].is_finite() {
                prop_assert_eq!(side, nested);
                for i in 0..8 {
                    // The same value (a zero's sign may differ) or both NaN.
                    prop_assert!(tb[i] == tn[i] || tb[i].is_nan() && tn[i].is_nan());
                }
            } else {
                prop_assert_eq!(nested & !side, 0, "never fewer boxes");
            }
        }
    }

    /// A ray along x in the plane of a box's lower y bound, which meets
    /// the box's x slab beyond its bound: the nested maxima keep it out,
    /// the side by side ones pass over x with y's NaN and let it in (more
    /// than needed, never less); off the plane, or with a y component,
    /// they agree.
    #[test]
    fn a_ray_on_a_y_plane_may_enter_more() {
        let node = Node8::from_boxes(&[Aabb::new(Vec3::ZERO, Vec3::ONE)]);
        let mut t = [0.0f32; 8];
        let along = Ray::new(Vec3::new(-1.0, 0.0, 0.5), Vec3::X, 0.0, f32::INFINITY);
        let r = BoxRay::new(&along);
        assert_eq!(slab_scalar_with::<false, 8>(&node, &r, 0.5, &mut t), 0);
        assert_eq!(slab_scalar(&node, &r, 0.5, &mut t), 1);
        assert_eq!(slab_scalar(&node, &r, 2.0, &mut t), 1);
        for (o, d) in [
            (Vec3::new(-1.0, 0.25, 0.5), Vec3::X),
            (Vec3::new(-1.0, 0.0, 0.5), Vec3::new(1.0, 1e-3, 0.0)),
            (Vec3::new(0.5, -1.0, 0.0), Vec3::Y),
        ] {
            let r = BoxRay::new(&Ray::new(o, d, 0.0, f32::INFINITY));
            for bound in [0.5, 2.0] {
                let nested = slab_scalar_with::<false, 8>(&node, &r, bound, &mut t);
                assert_eq!(slab_scalar(&node, &r, bound, &mut t), nested, "{o} {d}");
            }
        }
    }

    /// The public node test agrees with the one-box slab test on every
    /// child, with the SIMD kernels on and off, empty slots never entered.
    #[test]
    fn node_slab_matches_the_box_slab_test() {
        let mut f = uniform(1);
        for _ in 0..500 {
            let boxes = random_boxes(&mut f, 6);
            let node = Node8::from_boxes(&boxes);
            let mut d = Vec3::new(f(), f(), f());
            if f() > 1.0 {
                d.x = 0.0; // axis-parallel rays too
            }
            let ray = Ray::new(Vec3::new(f(), f(), f()) * 3.0, d, 0.0, f32::INFINITY);
            let tmax = f().abs() * 4.0;
            for simd in [true, false] {
                crate::set_simd_enabled(simd);
                let (mask, t) = node.slab(&BoxRay::new(&ray), tmax);
                crate::set_simd_enabled(true);
                for (i, b) in boxes.iter().enumerate() {
                    let want = b.intersect_ray(&ray, tmax);
                    assert_eq!(mask >> i & 1 == 1, want.is_some(), "box {i}, simd {simd}");
                    if let Some((entry, _)) = want {
                        assert_eq!(t[i].to_bits(), entry.to_bits(), "box {i}, simd {simd}");
                    }
                }
                assert_eq!(mask >> 6, 0, "empty slots are never entered");
            }
        }
    }
}
