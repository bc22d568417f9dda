//! BVH builders: the lecture's median split, binned SAH and full-sweep SAH.
//! They share one top-down recursion and differ only in how a node's
//! primitives are split.

mod spatial;

pub use spatial::Clip;

use super::{Bvh, Node, NodePair};
use crate::pages::PagesMut;
use crate::BuildConfig;
use raymesh_geometry::{Aabb, Mat3A, Vec3, Vec3A, Vec4};
use rayon::prelude::*;

/// Depth past which every builder splits by count (halving the node), so
/// that no tree outgrows the traversal stack whatever the input.
pub(crate) const SAH_DEPTH_LIMIT: usize = 64;

/// Leaf size of the median builder (the lecture splits down to a few primitives).
const MEDIAN_LEAF: usize = 4;

/// How a BVH is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhBuilder {
    /// Split at the centroid median on rotating axes x, y, z, x, … (the
    /// lecture's top-down builder): fast and balanced, blind to geometry.
    Median,
    /// Binned SAH (Wald, "On fast construction of SAH-based bounding volume
    /// hierarchies", 2007): centroids are counted into bins per axis and the
    /// cheapest bin boundary wins. O(N) per level.
    BinnedSah,
    /// Full-sweep SAH (MacDonald & Booth 1990): every centroid position on
    /// every axis is a candidate. Best trees; the centroids are sorted once
    /// on each axis, and each split partitions the three orders, so a
    /// level costs O(N).
    SweepSah,
}

/// Nodes with at least this many primitives build their two subtrees as
/// separate rayon tasks; smaller ones build on the thread they are on.
/// At 2048 (`raymesh-peers --peers none --build-repeat 40`, best of the
/// builds, five alternations, two threads, Zen 5) the dragon built in
/// 0.955 of the time (1.50 ms against 1.57), the pig in the same (1.24),
/// bunny00 and polygon_mesh within their noise (6.0–8.0 ms, 2.5–3.0):
/// not worth a change.
const PAR_SUBTREE: usize = 4096;

/// Nodes with at least twice this many primitives bin and bound their
/// primitives in parallel chunks of this many. At 16K, the root of a mesh
/// of 16K to 32K triangles (the pig, the dragon) was binned and
/// partitioned on one thread while the other waited; at 8K
/// (`raymesh-peers --peers none`, best of 40 builds, 5 alternations,
/// medians, two threads) the pig builds in 0.952 of the time, the dragon
/// 0.982, polygon_mesh 0.966, bunny00 0.985; one thread 0.995-1.008.
const PAR_CHUNK: usize = 8 * 1024;

/// A primitive as the builders move it: its box and its index, 32 bytes.
/// Builders partition these in place, so that every pass over a node
/// reads memory in order (as Embree's builders do with their `PrimRef`s)
/// rather than chasing indices into the box array.
///
/// The box's corners are two SSE registers' worth (`Vec4`, 16-byte
/// aligned), the index kept bit for bit in the lower corner's fourth lane,
/// so that each corner loads as one `Vec3A` in one aligned move (three
/// moves and shuffles a corner as `Vec3`s) and a copy is two aligned
/// moves (at 28 bytes it was two overlapping ones, and the partition's
/// next load of a reference it had just moved stalled on store
/// forwarding). The fourth lanes never reach a result, and [`Self::corners`]
/// zeroes the index's: read as a float, an index below 2^23 is a
/// denormal, and arithmetic on denormals is slow (left in, it made a
/// 2M-triangle build take 900-1060 ms instead of 770-820).
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct PrimRef {
    lo: Vec4,
    hi: Vec4,
}

const _: () = assert!(std::mem::size_of::<PrimRef>() == 32);

impl PrimRef {
    /// Primitive `id` with box `b`.
    #[inline(always)]
    fn new(b: Aabb, id: u32) -> Self {
        Self {
            lo: b.min.extend(f32::from_bits(id)),
            hi: b.max.extend(0.0),
        }
    }

    /// The references of primitives `0..n`, primitive `i` with box
    /// `bounds(i)`, made in parallel, in [`PagesMut`]: there are many, and
    /// every one is written once (see [`crate::pages`]).
    fn all(n: usize, bounds: &(dyn Fn(u32) -> Aabb + Sync)) -> PagesMut<Self> {
        PagesMut::from_fn_par(n, 1, |i| Self::new(bounds(i as u32), i as u32))
    }

    /// [`Self::all`] as a vector, for builders that add references.
    fn all_vec(n: usize, bounds: &(dyn Fn(u32) -> Aabb + Sync)) -> Vec<Self> {
        (0..n as u32)
            .into_par_iter()
            .map(|i| Self::new(bounds(i), i))
            .collect()
    }

    /// The primitive's index.
    #[inline(always)]
    fn id(&self) -> u32 {
        self.lo.w.to_bits()
    }

    /// The box's corners in SSE lanes (the fourth lanes 0).
    #[inline(always)]
    fn corners(&self) -> (Vec3A, Vec3A) {
        let xyz = raymesh_geometry::BVec4A::new(true, true, true, false);
        (
            Vec3A::from_vec4(Vec4::select(xyz, self.lo, Vec4::ZERO)),
            Vec3A::from_vec4(self.hi),
        )
    }

    #[inline(always)]
    fn min(&self) -> Vec3 {
        self.lo.truncate()
    }

    #[inline(always)]
    fn max(&self) -> Vec3 {
        self.hi.truncate()
    }

    #[inline(always)]
    fn bounds(&self) -> Aabb {
        Aabb::new(self.min(), self.max())
    }

    #[inline(always)]
    fn centroid(&self) -> Vec3 {
        self.bounds().centroid()
    }
}

/// What every node of one build reads.
struct Ctx<'a> {
    config: &'a BuildConfig,
    builder: BvhBuilder,
    /// [`PAR_SUBTREE`], or more to build on one thread (tests compare both).
    par_subtree: usize,
    /// [`BuildConfig::leaf_block`], resolved.
    block: usize,
    /// Its base-2 logarithm, where it is a power of two.
    block_shift: Option<u32>,
    /// [`BuildConfig::max_leaf`], resolved for [`Self::block`].
    max_leaf: usize,
}

impl<'a> Ctx<'a> {
    /// What a build by `builder` with `config` reads, splitting subtrees of
    /// `par_subtree` primitives or more across rayon tasks.
    fn new(config: &'a BuildConfig, builder: BvhBuilder, par_subtree: usize) -> Self {
        let block = config.leaf_block.unwrap_or(1).max(1);
        Self {
            config,
            builder,
            par_subtree,
            block,
            block_shift: block.is_power_of_two().then(|| block.trailing_zeros()),
            max_leaf: config.max_leaf_for(block),
        }
    }
}

/// A subtree as the parallel recursion returns it, flattened once at the end.
enum Subtree<'a> {
    /// Built on one thread, laid out as a whole tree is: node 0 is the
    /// root, node 1 unused, sibling pairs from 2 on, and child indices
    /// point into `nodes` (kept in the build's [`NodePool`]); `depth` is
    /// that of its deepest leaf (the whole tree's root at depth 1).
    Flat { nodes: &'a [Node], depth: usize },
    /// A root whose two subtrees were built in parallel.
    Split(Node, Box<Subtree<'a>>, Box<Subtree<'a>>),
}

/// The nodes of a subtree being built on one thread, filled from the
/// front, in a vector of its own that the allocator reuses from one
/// subtree to the next (a few hundred kilobytes at most, warm in the
/// cache); once built they are copied to the [`NodePool`].
struct Region {
    nodes: Vec<Node>,
    /// Depth of the deepest leaf written (the root at depth 1).
    depth: usize,
}

impl Region {
    /// Room for the nodes of a subtree over `n` primitives: its root, the
    /// unused slot beside it, and a pair per split, of which there are at
    /// most `n - 1`.
    fn for_prims(n: usize) -> Self {
        Self {
            nodes: Vec::with_capacity(2 * n.max(1)),
            depth: 0,
        }
    }

    fn push(&mut self, n: Node) {
        self.nodes.push(n);
    }

    fn len(&self) -> usize {
        self.nodes.len()
    }
}

impl std::ops::Index<usize> for Region {
    type Output = Node;
    fn index(&self, i: usize) -> &Node {
        &self.nodes[i]
    }
}

impl std::ops::IndexMut<usize> for Region {
    fn index_mut(&mut self, i: usize) -> &mut Node {
        &mut self.nodes[i]
    }
}

/// The build's one buffer for the nodes of its one-thread subtrees, each
/// copied in whole as soon as it is built, one after another, wherever
/// the threads' timing puts it ([`place`] reads them in the tree's order).
///
/// One buffer, not a vector kept per subtree: freed at once, it goes back
/// to the system, where thousands of small vectors stayed in the
/// allocator's arenas as free memory the process still holds (a
/// 10M-triangle render then peaked 100 MB higher, while it gathered the
/// triangle rows). Filled densely from the front, so that a large one
/// sits on huge pages ([`PagesMut`]) with no more of it resident than the
/// nodes written: when each subtree had a fixed share of it (two slots a
/// primitive, about half of them written), huge pages made every slot
/// resident and a 10M-triangle build peaked at 1,204 MiB against 741.
struct NodePool<'a>(std::sync::Mutex<&'a mut [Node]>);

impl<'a> NodePool<'a> {
    /// Copies `region`'s nodes to the buffer's next free slots.
    fn keep(&self, region: &Region) -> Subtree<'a> {
        let mine = {
            let mut free = self
                .0
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let (mine, rest) = std::mem::take(&mut *free).split_at_mut(region.len());
            *free = rest;
            mine
        };
        mine.copy_from_slice(&region.nodes);
        Subtree::Flat {
            nodes: mine,
            depth: region.depth,
        }
    }
}

/// `a < b ? a : b` in each lane: SSE's `minps`, which returns `b` when
/// either is NaN. The builders rely on it: a NaN corner, put first, leaves
/// the box it is added to as it was. glam's `min` is `minps` on x86-64,
/// but NEON's `vminq_f32` on aarch64, which returns NaN: there a NaN
/// corner made a bin's box NaN, so rays never entered it (a spatial-split
/// build of triangles with NaN and infinite corners failed its
/// validation, run under qemu).
#[inline(always)]
pub(crate) fn min_keep(a: Vec3A, b: Vec3A) -> Vec3A {
    #[cfg(target_arch = "x86_64")]
    {
        a.min(b)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Vec3A::select(a.cmplt(b), a, b)
    }
}

/// `a > b ? a : b` in each lane: SSE's `maxps` (see [`min_keep`]).
#[inline(always)]
pub(crate) fn max_keep(a: Vec3A, b: Vec3A) -> Vec3A {
    #[cfg(target_arch = "x86_64")]
    {
        a.max(b)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        Vec3A::select(a.cmpgt(b), a, b)
    }
}

/// A bin of the binned builder: the box of its primitives (in SIMD
/// registers' layout) and their number.
#[derive(Clone, Copy, Debug)]
struct Bin {
    min: Vec3A,
    max: Vec3A,
    count: u32,
}

impl Bin {
    const EMPTY: Self = Self {
        min: Vec3A::INFINITY,
        max: Vec3A::NEG_INFINITY,
        count: 0,
    };

    /// Adds a primitive's box. The primitive's corner comes first in each
    /// `min`/`max`, so that a NaN there leaves the bin as it was
    /// ([`min_keep`] returns its second operand when either is NaN).
    #[inline(always)]
    fn add(&mut self, min: Vec3A, max: Vec3A) {
        self.min = min_keep(min, self.min);
        self.max = max_keep(max, self.max);
        self.count += 1;
    }

    #[inline(always)]
    fn merge(self, o: Self) -> Self {
        Self {
            min: min_keep(o.min, self.min),
            max: max_keep(o.max, self.max),
            count: self.count + o.count,
        }
    }

    /// Half the surface area of the box, as [`Aabb::half_area`].
    #[inline(always)]
    fn half_area(&self) -> f32 {
        let e = max_keep(self.max - self.min, Vec3A::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

/// Half the surface areas of three bins' boxes, one a lane: each
/// [`Bin::half_area`], bit for bit (the same products and sums in the same
/// order), for the three boxes at once.
#[inline(always)]
fn half_areas(bins: &[Bin; 3]) -> Vec3A {
    let e = bins.map(|b| max_keep(b.max - b.min, Vec3A::ZERO));
    let t = Mat3A::from_cols(e[0], e[1], e[2]).transpose();
    let (x, y, z) = (t.x_axis, t.y_axis, t.z_axis);
    x * y + y * z + z * x
}

/// Scratch bins of the binned builder: [`MAX_BINS`] per axis, the three
/// axes' bins, then a second set of three (see [`Ctx::bin`]).
type Bins = Vec<Bin>;

/// How [`Ctx::bin_all`] binned a node's centroids: bins per axis, and
/// the map from a centroid to its bin (`(c - min) * scale`, floored).
#[derive(Clone, Copy, Debug)]
struct Binning {
    nb: usize,
    min: Vec3,
    scale: Vec3,
}

/// The cheapest object split [`Ctx::best_object`] found: its SAH cost
/// (unscaled by the node's area), axis, first bin of the right side, and
/// how many primitives go left.
#[derive(Clone, Copy, Debug)]
struct ObjectSplit {
    cost: f32,
    axis: usize,
    boundary: usize,
    left: u32,
}

fn new_bins() -> Bins {
    vec![Bin::EMPTY; 6 * MAX_BINS]
}

impl BvhBuilder {
    /// Builds a BVH over primitive boxes; primitive `i` has box `boxes[i]`.
    ///
    /// Large nodes build their subtrees in parallel on the current rayon
    /// pool, and bin and partition their primitives in parallel chunks;
    /// the tree is the same, node for node, whatever the number of threads.
    #[must_use]
    pub fn build(self, boxes: &[Aabb], config: &BuildConfig) -> Bvh {
        self.build_split_at(boxes.len(), &|i| boxes[i as usize], config, PAR_SUBTREE)
    }

    /// [`Self::build`] over `n` primitives whose boxes `bounds(i)` gives:
    /// no array of boxes is made, which saves 24 bytes a primitive of
    /// peak memory.
    #[must_use]
    pub fn build_by(
        self,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        config: &BuildConfig,
    ) -> Bvh {
        self.build_split_at(n, bounds, config, PAR_SUBTREE)
    }

    fn build_split_at(
        self,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        config: &BuildConfig,
        par_subtree: usize,
    ) -> Bvh {
        if n == 0 {
            return Bvh::default();
        }
        assert!(n < u32::MAX as usize, "too many primitives for u32 indices");
        let mut refs = PrimRef::all(n, bounds);
        let ctx = Ctx::new(config, self, par_subtree);
        let (bounds, cbounds) = ctx.bounds_pair(&refs);
        // Zeroed by the system, so only the slots written become resident
        // (at most two a primitive are).
        let mut slots = PagesMut::<Node>::zeroed(2 * n);
        let pool = NodePool(std::sync::Mutex::new(&mut slots));
        let mut orders = if self == Self::SweepSah {
            Sorted::all(&refs)
        } else {
            Default::default()
        };
        let sorted = (self == Self::SweepSah).then(|| {
            let [x, y, z] = &mut orders;
            Sorted([x.as_mut_slice(), y, z])
        });
        let tree = ctx.subtree(&mut refs, sorted, &pool, 0, 1, bounds, cbounds);
        drop(orders);
        // The references (32 bytes a primitive) go before the tree is
        // flattened, so that they never coexist with both of its copies.
        let depth = tree.depth() as u32;
        let prim_ids = refs.par_iter().map(PrimRef::id).collect();
        drop(refs);
        let empty = NodePair([Node::new(Aabb::EMPTY); 2]);
        let mut pairs = PagesMut::from_fn_par(tree.pairs(), 1, |_| empty);
        pairs[0].0[0] = place(tree, &mut pairs[1..], 1);
        drop(slots);
        Bvh {
            pairs: pairs.into(),
            prim_ids,
            depth,
            parts: false,
        }
    }
}

impl Subtree<'_> {
    /// Sibling pairs of the whole tree once placed, the root's included.
    fn pairs(&self) -> usize {
        match self {
            Self::Flat { nodes, .. } => nodes.len() / 2,
            Self::Split(_, l, r) => l.pairs() + r.pairs(),
        }
    }

    /// Depth of the deepest leaf (the whole tree's root at depth 1).
    fn depth(&self) -> usize {
        match self {
            Self::Flat { depth, .. } => *depth,
            Self::Split(_, l, r) => l.depth().max(r.depth()),
        }
    }
}

/// Writes the sibling pairs of `tree` below its root to `out` (exactly
/// as many), in the order a one-thread build makes them (each pair, then
/// the left subtree, then the right), and returns the root with its child
/// index pointing into the whole array, of which `out[0]` is pair `base`
/// (node `i` is `pairs[i / 2].0[i % 2]`). Subtrees built in parallel are
/// placed in parallel, each into its own part of `out`.
fn place(tree: Subtree<'_>, out: &mut [NodePair], base: u32) -> Node {
    match tree {
        Subtree::Flat { nodes, .. } => {
            // Pairs start at node 2 in `nodes` and at node `2 * base` in the array.
            let shift = |mut n: Node| {
                if !n.is_leaf() {
                    n.index = n.index - 2 + 2 * base;
                }
                n
            };
            assert_eq!(out.len(), nodes.len() / 2 - 1, "one slot a pair");
            for (o, c) in out.iter_mut().zip(nodes[2..].chunks_exact(2)) {
                *o = NodePair([shift(c[0]), shift(c[1])]);
            }
            shift(nodes[0])
        }
        Subtree::Split(mut root, left, right) => {
            root.index = 2 * base;
            let (own, rest) = out.split_first_mut().expect("room for the pair");
            let (l, r) = rest.split_at_mut(left.pairs() - 1);
            let right_base = base + 1 + l.len() as u32;
            let (a, b) = rayon::join(
                || place(*left, l, base + 1),
                || place(*right, r, right_base),
            );
            *own = NodePair([a, b]);
            root
        }
    }
}

impl Ctx<'_> {
    /// What `n` primitives cost to test in a leaf: blocks of [`Self::block`].
    #[inline(always)]
    fn blocks(&self, n: usize) -> f32 {
        // A block of 2^k by a shift and a mask, not an integer division:
        // the binned builder weighs two sides at every bin boundary it
        // tries (a block of 1 weighs a wide BVH's binary tree, 8 a binary
        // BVH's triangle leaves).
        let blocks = match self.block_shift {
            Some(k) => (n >> k) + usize::from(n & ((1 << k) - 1) != 0),
            None => n.div_ceil(self.block),
        };
        blocks as f32
    }

    /// Boxes of the primitives and of their centroids, in one pass
    /// (in parallel chunks for many primitives: unions are exact, so the
    /// result does not depend on the chunking).
    fn bounds_pair(&self, ids: &[PrimRef]) -> (Aabb, Aabb) {
        // In SSE lanes (`Vec3A`), where `Aabb`'s `Vec3` takes each axis on
        // its own: the same minima and maxima (a NaN corner is skipped
        // either way: the accumulator comes second), the same centroids.
        let one = |ids: &[PrimRef]| {
            let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
            let (mut clo, mut chi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
            for r in ids {
                let (a, b) = r.corners();
                let c = (a + b) * 0.5;
                (lo, hi) = (min_keep(a, lo), max_keep(b, hi));
                (clo, chi) = (min_keep(c, clo), max_keep(c, chi));
            }
            let aabb = |lo: Vec3A, hi: Vec3A| Aabb::new(lo.into(), hi.into());
            (aabb(lo, hi), aabb(clo, chi))
        };
        if ids.len() < 2 * PAR_CHUNK {
            return one(ids);
        }
        ids.par_chunks(PAR_CHUNK).map(one).reduce(
            || (Aabb::EMPTY, Aabb::EMPTY),
            |(b1, c1), (b2, c2)| (b1.union(b2), c1.union(c2)),
        )
    }

    /// Builds the subtree over `ids` (which start at `offset` in the
    /// permutation), splitting large nodes' children across rayon tasks.
    #[allow(clippy::too_many_arguments)]
    fn subtree<'s>(
        &self,
        ids: &mut [PrimRef],
        mut sorted: Option<Sorted<'_>>,
        pool: &NodePool<'s>,
        offset: u32,
        depth: usize,
        bounds: Aabb,
        cbounds: Aabb,
    ) -> Subtree<'s> {
        if ids.len() < self.par_subtree {
            let mut nodes = Region::for_prims(ids.len());
            nodes.push(Node::new(Aabb::EMPTY));
            nodes.push(Node::new(Aabb::EMPTY));
            self.build(
                &mut nodes,
                &mut new_bins(),
                0,
                ids,
                sorted,
                offset,
                depth,
                bounds,
                cbounds,
            );
            return pool.keep(&nodes);
        }
        let mut root = Node::new(bounds);
        match self.split(
            &mut new_bins(),
            ids,
            sorted.as_mut(),
            depth,
            bounds,
            cbounds,
        ) {
            None => {
                root.index = offset;
                root.count = ids.len() as u32;
                let mut nodes = Region::for_prims(1);
                nodes.push(root);
                nodes.push(Node::new(Aabb::EMPTY));
                nodes.depth = depth;
                pool.keep(&nodes)
            }
            Some(mid) => {
                let (left, right) = ids.split_at_mut(mid);
                let (ls, rs) = Sorted::split_at(sorted, mid);
                // Each side bounds its own primitives, on its own task.
                let (l, r) = rayon::join(
                    || {
                        let (b, c) = self.bounds_pair(left);
                        self.subtree(left, ls, pool, offset, depth + 1, b, c)
                    },
                    || {
                        let (b, c) = self.bounds_pair(right);
                        let o = offset + mid as u32;
                        self.subtree(right, rs, pool, o, depth + 1, b, c)
                    },
                );
                Subtree::Split(root, Box::new(l), Box::new(r))
            }
        }
    }

    /// Where the builder splits a node: `None` for a leaf, else the number
    /// of primitives that go left (moved to the front of `ids`).
    fn split(
        &self,
        bins: &mut Bins,
        ids: &mut [PrimRef],
        sorted: Option<&mut Sorted<'_>>,
        depth: usize,
        bounds: Aabb,
        cbounds: Aabb,
    ) -> Option<usize> {
        if ids.len() <= 1 {
            None
        } else if depth >= SAH_DEPTH_LIMIT {
            let mid = self.split_by_count(ids, cbounds);
            if let Some(sorted) = sorted {
                sorted.resort(ids, mid);
            }
            Some(mid)
        } else if self.builder != BvhBuilder::Median && self.leaf_wins(ids.len()) {
            None
        } else {
            match self.builder {
                BvhBuilder::Median => {
                    (ids.len() > MEDIAN_LEAF).then(|| self.split_median(ids, (depth - 1) % 3))
                }
                BvhBuilder::BinnedSah => self.split_binned(bins, ids, bounds, cbounds),
                BvhBuilder::SweepSah => {
                    let sorted = sorted.expect("the sweep builder's orders");
                    self.split_sweep(ids, sorted, bounds, cbounds)
                }
            }
        }
    }

    /// Builds node `node` of `nodes` over `ids`, which start at `offset`
    /// in the permutation; `bounds` and `cbounds` are the boxes of the
    /// primitives and of their centroids. One thread.
    #[allow(clippy::too_many_arguments)]
    fn build(
        &self,
        nodes: &mut Region,
        bins: &mut Bins,
        node: usize,
        ids: &mut [PrimRef],
        mut sorted: Option<Sorted<'_>>,
        offset: u32,
        depth: usize,
        bounds: Aabb,
        cbounds: Aabb,
    ) {
        nodes[node] = Node::new(bounds);
        match self.split(bins, ids, sorted.as_mut(), depth, bounds, cbounds) {
            None => {
                let n = &mut nodes[node];
                n.index = offset;
                n.count = ids.len() as u32;
                nodes.depth = nodes.depth.max(depth);
            }
            Some(mid) => {
                let first = nodes.len();
                nodes[node].index = first as u32;
                nodes.push(Node::new(Aabb::EMPTY));
                nodes.push(Node::new(Aabb::EMPTY));
                let (left, right) = ids.split_at_mut(mid);
                let (ls, rs) = Sorted::split_at(sorted, mid);
                let (lb, lc) = self.bounds_pair(left);
                let (rb, rc) = self.bounds_pair(right);
                self.build(nodes, bins, first, left, ls, offset, depth + 1, lb, lc);
                let (o, d) = (offset + mid as u32, depth + 1);
                self.build(nodes, bins, first + 1, right, rs, o, d, rb, rc);
            }
        }
    }

    /// Puts the lower half of centroids on `axis` first; returns the middle.
    fn split_median(&self, ids: &mut [PrimRef], axis: usize) -> usize {
        let mid = ids.len() / 2;
        ids.select_nth_unstable_by(mid, |a, b| {
            a.centroid()[axis].total_cmp(&b.centroid()[axis])
        });
        mid
    }

    /// Median split on the longest centroid axis: the fallback that always
    /// makes progress.
    fn split_by_count(&self, ids: &mut [PrimRef], cbounds: Aabb) -> usize {
        self.split_median(ids, cbounds.longest_axis())
    }

    /// Whether an SAH builder makes a leaf of `n` primitives whatever their
    /// boxes: a split costs at least the traversal step, so where a leaf
    /// of `n` costs no more and may hold them, [`Self::decide`] takes the
    /// leaf. Binning such a node only to find that out is skipped: a wide
    /// BVH's binary tree, which weighs primitives one by one against a
    /// step of 3, makes a leaf of every node of 2 or 3 primitives.
    #[inline(always)]
    fn leaf_wins(&self, n: usize) -> bool {
        n <= self.max_leaf && self.blocks(n) <= self.config.traversal_cost
    }

    /// Whether no split of the `ids` of a node with box `bounds` can cost
    /// less than their leaf, so that [`Self::decide`] would make a leaf
    /// whatever the bins: checked before binning them, since many nodes
    /// of a few primitives end up leaves after binning (12,682 of
    /// bunny00's 30,297 binned nodes did; this bound spares 5,553 of
    /// them). A side's box holds each of
    /// its primitives' boxes, so its area times its count is at least the
    /// sum of their areas, and a side's weight in blocks at least its count
    /// over the block: any split costs at least the traversal step plus
    /// the sum of all the primitives' areas over the block, relative to
    /// the node's area. Only where that bound passes the leaf's cost by a
    /// margin far above the rounding of either sum (1e-4, relative), so
    /// the trees are the ones binning every node makes.
    #[inline(always)]
    fn leaf_certain(&self, ids: &[PrimRef], bounds: Aabb) -> bool {
        if ids.len() > self.max_leaf {
            return false;
        }
        let area = bounds.half_area();
        let room = self.blocks(ids.len()) - self.config.traversal_cost;
        if !(area.is_finite() && area > 0.0 && room > 0.0) {
            return false;
        }
        let sum: f32 = ids
            .iter()
            .map(|r| {
                let (min, max) = r.corners();
                Bin { min, max, count: 1 }.half_area()
            })
            .sum();
        sum / self.block as f32 >= room * area * (1.0 + 1e-4)
    }

    /// Leaf or split, given the best split's SAH cost (relative to the node's area).
    fn decide(
        &self,
        ids: &mut [PrimRef],
        cbounds: Aabb,
        best: Option<(f32, usize)>,
        area: f32,
        apply: impl FnOnce(&mut [PrimRef]) -> usize,
    ) -> Option<usize> {
        let n = ids.len();
        let leaf_cost = self.blocks(n);
        match best {
            Some((cost, _)) if area > 0.0 => {
                let split_cost = self.config.traversal_cost + cost / area;
                if split_cost < leaf_cost || n > self.max_leaf {
                    Some(apply(ids))
                } else {
                    None
                }
            }
            _ if n > self.max_leaf => Some(self.split_by_count(ids, cbounds)),
            _ => None,
        }
    }

    /// Binned SAH: one pass bins the centroids on all three axes at once,
    /// then the cheapest bin boundary wins.
    fn split_binned(
        &self,
        bins: &mut Bins,
        ids: &mut [PrimRef],
        bounds: Aabb,
        cb: Aabb,
    ) -> Option<usize> {
        if self.leaf_certain(ids, bounds) {
            return None;
        }
        self.split_binned_all(bins, ids, bounds, cb)
    }

    /// [`Self::split_binned`] without the early leaf: bins every node.
    fn split_binned_all(
        &self,
        bins: &mut Bins,
        ids: &mut [PrimRef],
        bounds: Aabb,
        cb: Aabb,
    ) -> Option<usize> {
        let binning = self.bin_all(bins, ids, cb);
        let best = self.best_object(bins, &binning, ids.len());
        self.decide(
            ids,
            cb,
            best.map(|b| (b.cost, b.axis)),
            bounds.half_area(),
            |ids| {
                let best = best.expect("a split was found");
                let mid = self.object_partition(ids, &binning, best.axis, best.boundary);
                // The split moves exactly the primitives the bins counted.
                assert_eq!(mid, best.left as usize, "partition disagrees with the bins");
                mid
            },
        )
    }

    /// Bins the centroids of `ids` (in the centroid box `cb`) on all three
    /// axes into `bins`, in parallel chunks for many primitives.
    fn bin_all(&self, bins: &mut Bins, ids: &[PrimRef], cb: Aabb) -> Binning {
        // Small nodes need few bins: 4 + n/20, as Embree's binned builder
        // does (Wald 2007 bins every node alike). Most nodes are small, and
        // sweeping 32 bins on three axes cost them more than binning
        // their primitives.
        let nb = self.config.bins.min(4 + ids.len() / 20).clamp(2, MAX_BINS);
        let ext = cb.extent();
        let scale = Vec3::select(
            ext.cmpgt(Vec3::ZERO),
            Vec3::splat(nb as f32) / ext,
            Vec3::ZERO,
        );
        if ids.len() < 2 * PAR_CHUNK {
            self.bin(ids, cb.min, scale, nb, bins);
        } else {
            let merged = ids
                .par_chunks(PAR_CHUNK)
                .map(|chunk| {
                    let mut b = new_bins();
                    self.bin(chunk, cb.min, scale, nb, &mut b);
                    b
                })
                .reduce(new_bins, |mut a, b| {
                    // The first set: `bin` merged the second into it.
                    for (x, y) in a.iter_mut().zip(&b).take(3 * MAX_BINS) {
                        *x = x.merge(*y);
                    }
                    a
                });
            bins.copy_from_slice(&merged);
        }
        Binning {
            nb,
            min: cb.min,
            scale,
        }
    }

    /// The cheapest bin boundary of `bins` (filled by [`Self::bin_all`]
    /// over `n` primitives), if any splits them.
    fn best_object(&self, bins: &Bins, binning: &Binning, n: usize) -> Option<ObjectSplit> {
        // Weighed one by one (a wide BVH's binary tree), a side's cost is
        // its count as a float: one conversion, where `blocks` shifts,
        // masks and converts a 64-bit integer (on a 600K-triangle sphere
        // this function's instructions went from 270M to 226M).
        if self.block == 1 {
            Self::best_object_by(bins, binning, n, |c| c as f32)
        } else {
            Self::best_object_by(bins, binning, n, |c| self.blocks(c as usize))
        }
    }

    /// [`Self::best_object`], a side of `c` primitives weighing `weight(c)`.
    ///
    /// The three axes are swept together, one SIMD lane each (as Embree's
    /// binned builder does): at each bin boundary the boxes of the three
    /// axes' sides are transposed so that one multiply-add chain gives
    /// their three half areas. Per axis the same unions, areas and costs,
    /// bit for bit, as sweeping each axis on its own, and the same winner:
    /// each axis keeps its cheapest boundary (the first of equal ones),
    /// then the cheapest axis wins (the first of equal ones), which is the
    /// first cheapest of the axis-by-axis sweep. Only boundaries with
    /// primitives on both sides count (those between an axis's first and
    /// last non-empty bins); an axis whose centroids have no extent bins
    /// them all into its first bin, so it has none.
    #[inline(always)]
    fn best_object_by(
        bins: &Bins,
        binning: &Binning,
        n: usize,
        weight: impl Fn(u32) -> f32,
    ) -> Option<ObjectSplit> {
        // Most nodes are small and have few bins: their right sides' areas
        // fit a short array, which is quicker to set up.
        if binning.nb <= SMALL_BINS {
            Self::best_object_in::<SMALL_BINS>(bins, binning, n, weight)
        } else {
            Self::best_object_in::<MAX_BINS>(bins, binning, n, weight)
        }
    }

    /// [`Self::best_object_by`] for at most `CAP` bins per axis.
    #[inline(always)]
    fn best_object_in<const CAP: usize>(
        bins: &Bins,
        binning: &Binning,
        n: usize,
        weight: impl Fn(u32) -> f32,
    ) -> Option<ObjectSplit> {
        let nb = binning.nb;
        debug_assert!(nb <= CAP);
        let axis_bins: [&[Bin]; 3] = std::array::from_fn(|a| &bins[a * MAX_BINS..][..nb]);
        let n = n as u32;
        // Right sides: the bins from `b` on, for each boundary `b`.
        let mut right_area = [Vec3A::ZERO; CAP];
        let mut acc = [Bin::EMPTY; 3];
        for b in (1..nb).rev() {
            for (acc, bins) in acc.iter_mut().zip(&axis_bins) {
                *acc = acc.merge(bins[b]);
            }
            right_area[b] = half_areas(&acc);
        }
        let mut left = [Bin::EMPTY; 3];
        let mut best_cost = Vec3A::INFINITY;
        let mut best = [(0usize, 0u32); 3];
        for (b, &right_area) in (1..nb).zip(&right_area[1..nb]) {
            for (left, bins) in left.iter_mut().zip(&axis_bins) {
                *left = left.merge(bins[b - 1]);
            }
            let counts = left.map(|l| l.count);
            let weights = |c: [u32; 3]| Vec3A::new(weight(c[0]), weight(c[1]), weight(c[2]));
            let (lw, rw) = (weights(counts), weights(counts.map(|c| n - c)));
            let cost = half_areas(&left) * lw + right_area * rw;
            // A side weighs more than nothing exactly when it holds
            // primitives.
            let both_sides = lw.cmpgt(Vec3A::ZERO) & rw.cmpgt(Vec3A::ZERO);
            let better = cost.cmplt(best_cost) & both_sides;
            best_cost = Vec3A::select(better, cost, best_cost);
            let mask = better.bitmask();
            for (a, best) in best.iter_mut().enumerate() {
                if mask >> a & 1 != 0 {
                    *best = (b, counts[a]);
                }
            }
        }
        // Costs are finite or NaN, and a NaN never wins.
        let mut winner: Option<ObjectSplit> = None;
        for (axis, &(boundary, left)) in best.iter().enumerate() {
            let cost = best_cost[axis];
            if cost < winner.map_or(f32::INFINITY, |w| w.cost) {
                winner = Some(ObjectSplit {
                    cost,
                    axis,
                    boundary,
                    left,
                });
            }
        }
        winner
    }

    /// Moves the primitives of `ids` whose centroid bins below `boundary`
    /// on `axis` to the front; returns how many there are.
    fn object_partition(
        &self,
        ids: &mut [PrimRef],
        binning: &Binning,
        axis: usize,
        boundary: usize,
    ) -> usize {
        // `bin3(c)[axis] < boundary` on one axis, without the
        // float-to-integer conversion: the bin is the floor of `f`
        // (clamped to the last bin, at or past any boundary), and a
        // NaN `f` goes to bin 0, on the left, as `!(f >= b)` does.
        let (lo, s, b) = (binning.min[axis], binning.scale[axis], boundary as f32);
        // One partition loop per axis, each reading its axis's two corner
        // coordinates as fields: indexing the centroid by a variable axis
        // made the whole box, its centroid and a branchy lane choice per
        // primitive. The same centroid, `0.5 * (min + max)`, bit for bit.
        let left = |min: f32, max: f32| !((0.5 * (min + max) - lo) * s >= b);
        match axis {
            0 => par_partition(ids, |r| left(r.lo.x, r.hi.x)),
            1 => par_partition(ids, |r| left(r.lo.y, r.hi.y)),
            _ => par_partition(ids, |r| left(r.lo.z, r.hi.z)),
        }
    }

    /// Counts `ids` into the first `nb` bins of each axis of `bins` (the
    /// others untouched) and grows each bin's box by its primitives' boxes.
    ///
    /// Two things keep the loop from stalling on memory. The bins of each
    /// whole run of [`BIN_RUN`] primitives are found first, then updated,
    /// so that no bin's load waits on the arithmetic that finds the bin of
    /// a store before it. And neighbouring primitives of a mesh mostly
    /// fall in the same bins, where each update waits for the one before
    /// it to be stored: a run's even primitives update one set of bins and
    /// its odd ones a second (behind the first in `bins`), merged at the
    /// end. The primitives past the last whole run go one at a time to
    /// the first set. Unions and counts are exact, so the bins are what
    /// one set gives.
    fn bin(&self, ids: &[PrimRef], min: Vec3, scale: Vec3, nb: usize, bins: &mut Bins) {
        // The kernels' switch read once, and the loop compiled for each
        // setting: tested per primitive, it cost three instructions of the
        // fifty-odd that bin one.
        if crate::simd::simd_enabled() {
            Self::bin_with::<true>(ids, min, scale, nb, bins);
        } else {
            Self::bin_with::<false>(ids, min, scale, nb, bins);
        }
    }

    /// [`Self::bin`], converting bins with SSE2 where `SIMD`.
    #[inline(always)]
    fn bin_with<const SIMD: bool>(
        ids: &[PrimRef],
        min: Vec3,
        scale: Vec3,
        nb: usize,
        bins: &mut Bins,
    ) {
        let paired = ids.len() >= BIN_RUN;
        for axis in 0..if paired { 6 } else { 3 } {
            bins[axis * MAX_BINS..axis * MAX_BINS + nb].fill(Bin::EMPTY);
        }
        let (first, second) = bins.split_at_mut(3 * MAX_BINS);
        let mut a = axes(first);
        let mut b = axes(second);
        let bin_of = |r: &PrimRef| {
            let (lo, hi) = r.corners();
            bin3((lo + hi) * 0.5, min, scale, nb, SIMD)
        };
        // Whole runs as arrays, so that the loops carry no checks.
        let mut runs = ids.chunks_exact(BIN_RUN);
        for run in &mut runs {
            let run: &[PrimRef; BIN_RUN] = run.try_into().expect("a whole run");
            // Filled in place: `array::from_fn` built the bins in a second
            // array and copied them over.
            let mut k = [0u32; BIN_RUN];
            for (k, r) in k.iter_mut().zip(run) {
                *k = bin_of(r);
            }
            for i in (0..BIN_RUN).step_by(2) {
                add_to(&mut a, k[i], &run[i]);
                add_to(&mut b, k[i + 1], &run[i + 1]);
            }
        }
        for r in runs.remainder() {
            add_to(&mut a, bin_of(r), r);
        }
        if paired {
            for (a, b) in a.iter_mut().zip(&b) {
                for (x, y) in a[..nb].iter_mut().zip(&b[..nb]) {
                    *x = x.merge(*y);
                }
            }
        }
    }

    /// Full-sweep SAH over every centroid position on every axis, reading
    /// the node's primitives in each axis's order from `sorted`, which the
    /// split leaves in order for both children.
    fn split_sweep(
        &self,
        ids: &mut [PrimRef],
        sorted: &mut Sorted<'_>,
        bounds: Aabb,
        cbounds: Aabb,
    ) -> Option<usize> {
        let mut best = None;
        let mut right_area = vec![0.0f32; ids.len()];
        for (axis, order) in sorted.0.iter().enumerate() {
            self.sweep_axis(axis, order, &mut right_area, &mut best);
        }
        let mut swept = false;
        let split = self.decide(
            ids,
            cbounds,
            best.map(|(cst, a, _)| (cst, a)),
            bounds.half_area(),
            |ids| {
                let (_, axis, k) = best.expect("a split was found");
                sorted.split_by(axis, k);
                ids.copy_from_slice(sorted.0[axis]);
                swept = true;
                k
            },
        );
        // A split by count (no split found, or none where the node's box
        // has no area) rearranged `ids` itself.
        if let (Some(mid), false) = (split, swept) {
            sorted.resort(ids, mid);
        }
        split
    }

    /// Sweeps the primitives of a node in `axis`'s order: the SAH cost of
    /// each split into a prefix and the rest, kept in `best` as `(cost,
    /// axis, primitives left)` where lower than what `best` holds (earlier
    /// axes and positions win ties). `right_area` is scratch, as long as
    /// `order`.
    fn sweep_axis(
        &self,
        axis: usize,
        order: &[PrimRef],
        right_area: &mut [f32],
        best: &mut Option<(f32, usize, usize)>,
    ) {
        let n = order.len();
        let mut acc = Bin::EMPTY;
        for (area, r) in right_area[1..].iter_mut().zip(&order[1..]).rev() {
            let (lo, hi) = r.corners();
            acc.add(lo, hi);
            *area = acc.half_area();
        }
        let mut left = Bin::EMPTY;
        for (k, (r, &right)) in (1..).zip(order.iter().zip(&right_area[1..])) {
            let (lo, hi) = r.corners();
            left.add(lo, hi);
            let cost = left.half_area() * self.blocks(k) + right * self.blocks(n - k);
            if best.is_none_or(|(bc, _, _)| cost < bc) {
                *best = Some((cost, axis, k));
            }
        }
    }
}

/// The sweep builder's three orders of a node's primitives, by centroid
/// on x, y and z ([`sweep_key`]: `f32::total_cmp`'s order, ties broken by
/// primitive index, so that a split does not depend on the order the
/// node's primitives came in). Sorted once for the whole build; each
/// split then partitions the other two orders stably, which keeps them
/// sorted for the children: O(N) a node instead of three sorts, which
/// made the build O(N log² N). Wald and Havran build k-d trees so ("On
/// building fast kd-trees for ray tracing, and on doing that in
/// O(N log N)", 2006).
struct Sorted<'a>([&'a mut [PrimRef]; 3]);

impl<'a> Sorted<'a> {
    /// The references `refs` (primitive `i` at index `i`) in each axis's
    /// order.
    fn all(refs: &[PrimRef]) -> [Vec<PrimRef>; 3] {
        debug_assert!((0u32..).zip(refs).all(|(i, r)| r.id() == i));
        std::array::from_fn(|axis| {
            // Sorted as integer keys, each with its primitive's index in
            // its low bits: comparing references by their centroids took
            // several times as long.
            let mut keys: Vec<u64> = refs
                .par_iter()
                .map(|r| sweep_key(r.centroid()[axis], r.id()))
                .collect();
            keys.par_sort_unstable();
            keys.par_iter().map(|&k| refs[k as u32 as usize]).collect()
        })
    }

    /// The orders of the first `mid` primitives and of the rest.
    fn split_at(this: Option<Self>, mid: usize) -> (Option<Self>, Option<Self>) {
        let Some(Self([x, y, z])) = this else {
            return (None, None);
        };
        let ((x0, x1), (y0, y1), (z0, z1)) = (
            x.split_at_mut(mid),
            y.split_at_mut(mid),
            z.split_at_mut(mid),
        );
        (Some(Self([x0, y0, z0])), Some(Self([x1, y1, z1])))
    }

    /// After a sweep split at the `k`-th primitive in `axis`'s order: the
    /// other two orders partitioned stably, that split's left side first.
    fn split_by(&mut self, axis: usize, k: usize) {
        let key = |r: &PrimRef| sweep_key(r.centroid()[axis], r.id());
        let pivot = key(&self.0[axis][k]);
        let mut right = Vec::with_capacity(self.0[axis].len() - k);
        for (b, order) in self.0.iter_mut().enumerate() {
            if b != axis {
                stable_partition(order, &mut right, |r| key(r) < pivot);
            }
        }
    }

    /// After a split of `ids` that no order gives (by count): each order
    /// made again from its side of `ids` (`mid` primitives left).
    fn resort(&mut self, ids: &[PrimRef], mid: usize) {
        for (axis, order) in self.0.iter_mut().enumerate() {
            order.copy_from_slice(ids);
            let key = |r: &PrimRef| sweep_key(r.centroid()[axis], r.id());
            let (l, r) = order.split_at_mut(mid);
            l.sort_unstable_by_key(key);
            r.sort_unstable_by_key(key);
        }
    }
}

/// Moves the items of `v` for which `left` holds to its front, in their
/// order, and the others behind them, in theirs (`scratch` holds those
/// meanwhile).
fn stable_partition<T: Copy>(v: &mut [T], scratch: &mut Vec<T>, left: impl Fn(&T) -> bool) {
    scratch.clear();
    let mut k = 0;
    for i in 0..v.len() {
        let x = v[i];
        if left(&x) {
            v[k] = x;
            k += 1;
        } else {
            scratch.push(x);
        }
    }
    v[k..].copy_from_slice(scratch);
}

/// A key whose integer order is `c`'s `f32::total_cmp` order, then `id`'s.
#[inline(always)]
fn sweep_key(c: f32, id: u32) -> u64 {
    // `total_cmp`'s own mapping to a signed integer (the magnitude bits
    // flipped for negative numbers), then the sign bit flipped so that
    // the order holds unsigned.
    let bits = c.to_bits() as i32;
    let ordered = (bits ^ (((bits >> 31) as u32) >> 1) as i32) as u32 ^ 0x8000_0000;
    (u64::from(ordered) << 32) | u64::from(id)
}

/// Primitives [`Ctx::bin`] finds the bins of before it updates them.
const BIN_RUN: usize = 32;

/// The three axes' bins at the front of `bins`, as fixed-size arrays, so
/// that a bin number masked to the array (a no-op: bins are below `nb <=
/// MAX_BINS`) indexes them without bounds checks.
fn axes(bins: &mut [Bin]) -> [&mut [Bin; MAX_BINS]; 3] {
    let (x, rest) = bins.split_at_mut(MAX_BINS);
    let (y, z) = rest.split_at_mut(MAX_BINS);
    [x, y, &mut z[..MAX_BINS]].map(|b| b.try_into().expect("MAX_BINS bins per axis"))
}

/// Adds primitive `r` to bins `k` (packed as [`bin3`] packs them) of the
/// three axes `axes`.
#[inline(always)]
fn add_to(axes: &mut [&mut [Bin; MAX_BINS]; 3], k: u32, r: &PrimRef) {
    const MASK: usize = MAX_BINS - 1;
    let (lo, hi) = r.corners();
    let k = k as usize;
    axes[0][k & MASK].add(lo, hi);
    axes[1][(k >> 8) & MASK].add(lo, hi);
    axes[2][(k >> 16) & MASK].add(lo, hi);
}

/// Bins per axis up to which [`Ctx::best_object_by`] sweeps in short arrays.
const SMALL_BINS: usize = 8;

/// Most bins per axis of the binned builder (a power of two: see `bin`).
const MAX_BINS: usize = 64;
const _: () = assert!(MAX_BINS.is_power_of_two());

/// Bin of a centroid on each axis: the floor of its scaled offset,
/// clamped to the bins in floats first (a NaN lands in bin 0), so that the
/// conversion is a plain truncation of a small number rather than a
/// saturating float-to-`usize` cast (half of the binning loop's time
/// before), and on x86-64 one SSE2 truncation of the three axes (see
/// [`crate::simd::truncate3`]).
#[inline(always)]
fn bin3(c: Vec3A, min: Vec3, scale: Vec3, nb: usize, simd: bool) -> u32 {
    let f = (c - Vec3A::from(min)) * Vec3A::from(scale);
    crate::simd::truncate3(f, (nb - 1) as f32, simd)
}

/// [`partition`] for long slices, in parallel and in place: chunks of
/// [`PAR_CHUNK`] are partitioned on their own, then the elements left on
/// the wrong side of the overall boundary are swapped across it, range
/// against range. The order within each side depends only on the
/// slice's length, never on the number of threads. Before, the top
/// nodes' partitions ran on one thread while the others waited: a
/// 10M-triangle terrain built in 2.92-2.93 s on 2 threads, now 2.49-2.69 s
/// (temporary timer, `Scene::from_mesh` with `bvh-binned`, alternated).
fn par_partition<T: Send>(v: &mut [T], pred: impl Fn(&T) -> bool + Sync) -> usize {
    if v.len() < 2 * PAR_CHUNK {
        return partition(v, pred);
    }
    let counts: Vec<usize> = v
        .par_chunks_mut(PAR_CHUNK)
        .map(|c| partition(c, &pred))
        .collect();
    let mid: usize = counts.iter().sum();
    // Chunk `k` holds [start, start + count) satisfying `pred`, then the rest.
    // Misplaced: the rest below `mid`, and satisfying elements at or past it.
    let (mut wrong_lo, mut wrong_hi) = (Vec::new(), Vec::new());
    for (k, &count) in counts.iter().enumerate() {
        let start = k * PAR_CHUNK;
        let (split, end) = (start + count, (start + PAR_CHUNK).min(v.len()));
        if split < end.min(mid) {
            wrong_lo.push(split..end.min(mid));
        }
        if start.max(mid) < split {
            wrong_hi.push(start.max(mid) - mid..split - mid);
        }
    }
    let (lo, hi) = v.split_at_mut(mid);
    let pairs: Vec<(&mut [T], &mut [T])> = zip_ranges(lo, &wrong_lo, hi, &wrong_hi);
    pairs
        .into_par_iter()
        .for_each(|(a, b)| a.swap_with_slice(b));
    mid
}

/// Pieces of `a` over `ra` and of `b` over `rb` (each list sorted and
/// disjoint, both covering the same number of elements), cut so that the
/// `i`-th pieces have equal lengths (4,096 at most): what swapping the two
/// sequences element by element, in parallel, needs.
fn zip_ranges<'a, T>(
    mut a: &'a mut [T],
    ra: &[std::ops::Range<usize>],
    mut b: &'a mut [T],
    rb: &[std::ops::Range<usize>],
) -> Vec<(&'a mut [T], &'a mut [T])> {
    let (mut out, mut a_base, mut b_base) = (Vec::new(), 0, 0);
    let (mut i, mut j) = (0, 0);
    let (mut ca, mut cb) = (ra.first().cloned(), rb.first().cloned());
    while let (Some(x), Some(y)) = (ca.clone(), cb.clone()) {
        // At most a few thousand swaps a piece, so that the pieces balance.
        let len = x.len().min(y.len()).min(4096);
        let (_, rest) = std::mem::take(&mut a).split_at_mut(x.start - a_base);
        let (pa, rest) = rest.split_at_mut(len);
        a = rest;
        a_base = x.start + len;
        let (_, rest) = std::mem::take(&mut b).split_at_mut(y.start - b_base);
        let (pb, rest) = rest.split_at_mut(len);
        b = rest;
        b_base = y.start + len;
        out.push((pa, pb));
        ca = if len < x.len() {
            Some(x.start + len..x.end)
        } else {
            i += 1;
            ra.get(i).cloned()
        };
        cb = if len < y.len() {
            Some(y.start + len..y.end)
        } else {
            j += 1;
            rb.get(j).cloned()
        };
    }
    assert!(
        ca.is_none() && cb.is_none(),
        "both sides misplace as many elements"
    );
    out
}

/// Moves the elements satisfying `pred` to the front; returns how many
/// there are. Lomuto's scheme without branches: every element is swapped
/// with the first one not yet known to satisfy `pred`, and the count grows
/// by the predicate's value. It writes more than Hoare's scheme but never
/// mispredicts on a split's coin-flip predicate (Hoare's partition was a
/// fifth of the build).
fn partition<T>(v: &mut [T], pred: impl Fn(&T) -> bool) -> usize {
    let mut l = 0;
    for i in 0..v.len() {
        // v[..l] satisfy pred, v[l..i] do not.
        let p = pred(&v[i]);
        v.swap(l, i);
        l += usize::from(p);
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel recursion and parallel binning lay the tree out node
    /// for node as the one-thread build does, for every builder, whether
    /// rayon runs one thread or several.
    #[test]
    fn parallel_build_is_identical_to_sequential() {
        // Over 2 * PAR_CHUNK primitives, so that binning and bounds go
        // parallel at the top too.
        let b = crate::test_util::clustered_boxes(2 * PAR_CHUNK + 1234);
        let config = BuildConfig::default();
        for builder in [
            BvhBuilder::Median,
            BvhBuilder::BinnedSah,
            BvhBuilder::SweepSah,
        ] {
            let seq = builder.build_split_at(b.len(), &|i| b[i as usize], &config, usize::MAX);
            seq.validate(&b).unwrap();
            for threads in [1, 3] {
                let pool = crate::test_util::pool(threads);
                for split_at in [2, 64, PAR_SUBTREE] {
                    let par = pool.install(|| {
                        builder.build_split_at(b.len(), &|i| b[i as usize], &config, split_at)
                    });
                    assert_eq!(par.nodes(), seq.nodes(), "{builder:?} split at {split_at}");
                    assert_eq!(par.prim_ids(), seq.prim_ids());
                }
            }
        }
    }

    /// The parallel partition moves exactly the elements satisfying the
    /// predicate to the front, losing and repeating none, whatever the
    /// proportion on each side and however the chunks fall.
    #[test]
    fn parallel_partition_partitions() {
        for (n, modulus) in [
            (2 * PAR_CHUNK, 2),
            (3 * PAR_CHUNK + 7, 3),
            (5 * PAR_CHUNK + 1, 7),
            (4 * PAR_CHUNK + 99, 1),
        ] {
            for keep in 0..modulus.min(3) {
                // A scrambled order, so that misplaced runs cross chunks.
                let mut v: Vec<u32> = (0..n as u32)
                    .map(|i| i.wrapping_mul(2_654_435_761))
                    .collect();
                let pred = |x: &u32| (x >> 7) % modulus == keep;
                let want = v.iter().filter(|x| pred(x)).count();
                let mut sorted = v.clone();
                sorted.sort_unstable();
                let mid = par_partition(&mut v, pred);
                assert_eq!(mid, want, "{n} {modulus} {keep}");
                assert!(v[..mid].iter().all(pred) && !v[mid..].iter().any(pred));
                v.sort_unstable();
                assert_eq!(v, sorted);
            }
        }
        let mut all_false = vec![1u32; 3 * PAR_CHUNK];
        assert_eq!(par_partition(&mut all_false, |_| false), 0);
    }

    /// Boxes with NaN or infinite corners (from broken input) and huge
    /// ones build without a panic, every primitive in exactly one leaf.
    #[test]
    fn non_finite_and_huge_boxes_build() {
        let mut b = crate::test_util::clustered_boxes(3000);
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 3e38, -3e38];
        for (i, x) in bad.iter().cycle().take(600).enumerate() {
            let k = (i * 5) % b.len();
            let axis = i % 3;
            if i % 2 == 0 {
                b[k].min[axis] = *x;
            } else {
                b[k].max[axis] = *x;
            }
        }
        for builder in [
            BvhBuilder::Median,
            BvhBuilder::BinnedSah,
            BvhBuilder::SweepSah,
        ] {
            let bvh = builder.build(&b, &BuildConfig::default());
            let mut ids = bvh.prim_ids().to_vec();
            ids.sort_unstable();
            assert!(ids.iter().copied().eq(0..b.len() as u32), "{builder:?}");
        }
    }

    /// [`Ctx::bin`] (bins found a run at a time, two sets of bins from
    /// a whole run on) fills the bins that adding each
    /// primitive in turn to one set fills, bit for bit, for node sizes
    /// around the run and pairing thresholds, odd and even, and with NaN
    /// and infinite corners; and it leaves the bins past `nb` alone.
    #[test]
    fn binning_matches_one_at_a_time() {
        let mut boxes = crate::test_util::clustered_boxes(7 * BIN_RUN + 7);
        for (k, x) in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY]
            .iter()
            .enumerate()
        {
            boxes[7 * k + 3].min[k] = *x;
            boxes[11 * k + 5].max[(k + 1) % 3] = *x;
        }
        let refs: Vec<PrimRef> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| PrimRef::new(*b, i as u32))
            .collect();
        let config = BuildConfig::default();
        let ctx = Ctx::new(&config, BvhBuilder::BinnedSah, PAR_SUBTREE);
        let bits = |b: &Bin| {
            let (lo, hi) = (Vec3::from(b.min), Vec3::from(b.max));
            (
                lo.to_array().map(f32::to_bits),
                hi.to_array().map(f32::to_bits),
                b.count,
            )
        };
        let sizes = [
            1,
            2,
            BIN_RUN - 1,
            BIN_RUN,
            BIN_RUN + 1,
            2 * BIN_RUN - 1,
            2 * BIN_RUN,
        ];
        for n in sizes
            .into_iter()
            .chain([2 * BIN_RUN + 1, 3 * BIN_RUN + 5, refs.len()])
        {
            let ids = &refs[..n];
            let cb = ids.iter().fold(Aabb::EMPTY, |a, r| {
                a.union(Aabb::new(r.centroid(), r.centroid()))
            });
            for nb in [2, 5, 32, MAX_BINS] {
                let scale = Vec3::select(
                    cb.extent().cmpgt(Vec3::ZERO),
                    Vec3::splat(nb as f32) / cb.extent(),
                    Vec3::ZERO,
                );
                let mut want = new_bins();
                for axis in 0..3 {
                    for r in ids {
                        let (lo, hi) = r.corners();
                        let k = bin3((lo + hi) * 0.5, cb.min, scale, nb, false);
                        want[axis * MAX_BINS + (k >> (8 * axis) & 0xff) as usize].add(lo, hi);
                    }
                }
                let mut got = new_bins();
                // Bins past `nb` hold something that must stay as it is.
                got[..3 * MAX_BINS].fill(Bin {
                    count: 7,
                    ..Bin::EMPTY
                });
                for axis in 0..3 {
                    for b in nb..MAX_BINS {
                        want[axis * MAX_BINS + b].count = 7;
                    }
                }
                ctx.bin(ids, cb.min, scale, nb, &mut got);
                let (got, want) = (&got[..3 * MAX_BINS], &want[..3 * MAX_BINS]);
                assert!(
                    got.iter().map(bits).eq(want.iter().map(bits)),
                    "{n} primitives, {nb} bins"
                );
                assert_eq!(
                    got.iter().map(|b| b.count).sum::<u32>(),
                    3 * n as u32 + 3 * 7 * (MAX_BINS - nb) as u32
                );
            }
        }
    }

    /// The cheapest bin boundary as the builder found it before it swept
    /// the three axes together: each axis on its own, skipping axes whose
    /// centroids have no extent, over the boundaries between its first and
    /// last non-empty bins, the first cheapest winning.
    fn best_object_axis_by_axis(
        ctx: &Ctx<'_>,
        bins: &Bins,
        nb: usize,
        ext: Vec3,
        n: usize,
    ) -> Option<(u32, usize, usize, u32)> {
        let mut best: Option<(u32, usize, usize, u32)> = None;
        let mut best_cost = f32::INFINITY;
        for axis in 0..3 {
            if !(ext[axis] > 0.0) {
                continue;
            }
            let bins = &bins[axis * MAX_BINS..][..nb];
            let nonempty = |b: &Bin| b.count > 0;
            let (Some(first), Some(last)) = (
                bins.iter().position(nonempty),
                bins.iter().rposition(nonempty),
            ) else {
                continue;
            };
            for b in first + 1..=last {
                let left = bins[..b].iter().fold(Bin::EMPTY, |a, x| a.merge(*x));
                // The right side merged from the last bin down, as the
                // sweep accumulates it.
                let right = bins[b..].iter().rev().fold(Bin::EMPTY, |a, x| a.merge(*x));
                let (lc, rc) = (left.count as usize, n - left.count as usize);
                let cost = left.half_area() * ctx.blocks(lc) + right.half_area() * ctx.blocks(rc);
                if cost < best_cost {
                    best_cost = cost;
                    best = Some((cost.to_bits(), axis, b, left.count));
                }
            }
        }
        best
    }

    /// Sweeping the three axes together (one SIMD lane each) finds the
    /// split the axis-by-axis sweep finds, cost bit for bit, on nodes of
    /// every size, with primitives weighed one by one and in blocks, where
    /// centroids coincide on an axis or on all three, and where boxes have
    /// NaN or infinite corners.
    #[test]
    fn axes_swept_together_choose_as_each_alone() {
        let boxes = crate::test_util::clustered_boxes(700);
        // Centroids that coincide on y (a flat strip), and on every axis.
        let flat: Vec<Aabb> = boxes
            .iter()
            .map(|b| {
                Aabb::new(
                    Vec3::new(b.min.x, 1.0, b.min.z),
                    Vec3::new(b.max.x, 3.0, b.max.z),
                )
            })
            .collect();
        let same = vec![Aabb::new(Vec3::ZERO, Vec3::ONE); 40];
        // Corners that are NaN (skipped by the unions) or infinite (an
        // axis with an infinite extent bins everything into its first
        // bin): the first 20 boxes are clean, so small nodes still split.
        let mut odd = boxes.clone();
        for (k, x) in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY]
            .iter()
            .enumerate()
        {
            odd[7 * k + 23].min[k] = *x;
            odd[11 * k + 25].max[(k + 1) % 3] = *x;
        }
        let mut checked = 0;
        for (set, boxes) in [&boxes, &flat, &same, &odd].into_iter().enumerate() {
            let refs: Vec<PrimRef> = boxes
                .iter()
                .enumerate()
                .map(|(i, b)| PrimRef::new(*b, i as u32))
                .collect();
            for block in [None, Some(8), Some(3)] {
                for nbins in [32, 8, 2] {
                    let config = BuildConfig {
                        leaf_block: block,
                        bins: nbins,
                        ..BuildConfig::default()
                    };
                    let ctx = Ctx::new(&config, BvhBuilder::BinnedSah, PAR_SUBTREE);
                    for n in [2, 3, 5, 9, 17, 40, 100, 333, 700] {
                        let ids = &refs[(set * 13) % 7..][..n.min(refs.len() - (set * 13) % 7)];
                        let (_, cb) = ctx.bounds_pair(ids);
                        let mut bins = new_bins();
                        let binning = ctx.bin_all(&mut bins, ids, cb);
                        let got = ctx
                            .best_object(&bins, &binning, ids.len())
                            .map(|s| (s.cost.to_bits(), s.axis, s.boundary, s.left));
                        let want = best_object_axis_by_axis(
                            &ctx,
                            &bins,
                            binning.nb,
                            cb.extent(),
                            ids.len(),
                        );
                        assert_eq!(
                            got, want,
                            "set {set}, block {block:?}, {nbins} bins, {n} primitives"
                        );
                        checked += usize::from(want.is_some());
                    }
                }
            }
        }
        // The sets are not all without splits.
        assert!(checked > 100, "{checked} splits compared");
    }

    /// Where the binned builder makes a leaf without binning (its bound on
    /// any split's cost passes the leaf's), binning finds no split that
    /// pays either: the early leaf changes no tree. Nodes of 2 to 16
    /// boxes, from spread out to piled up, weighed one by one and in
    /// blocks of 2 and 8 (where leaves of up to a block win anyway), at
    /// several traversal costs.
    #[test]
    fn early_leaves_are_the_leaves_binning_makes() {
        let mut next = crate::test_util::xorshift(0x1b87_3593);
        let (mut early, mut split) = (0, 0);
        for &(block, traversal_cost) in &[
            (None, 3.0),
            (None, 1.0),
            (None, 5.5),
            (Some(2), 2.0),
            (Some(8), 1.0),
        ] {
            let config = BuildConfig {
                leaf_block: block,
                traversal_cost,
                ..BuildConfig::default()
            };
            let ctx = Ctx::new(&config, BvhBuilder::BinnedSah, PAR_SUBTREE);
            for round in 0..3000 {
                let n = 2 + round % 15;
                // Boxes of size up to `size` spread over `spread`: piled
                // up where the spread is small against the size.
                let (spread, size) = (next() * next() * 3.0, 0.05 + next() * 2.0);
                let mut refs: Vec<PrimRef> = (0..n as u32)
                    .map(|i| {
                        let p = Vec3::new(next(), next(), next()) * spread;
                        let e = Vec3::new(next(), next(), next()) * size;
                        PrimRef::new(Aabb::new(p, p + e), i)
                    })
                    .collect();
                let (bounds, cb) = ctx.bounds_pair(&refs);
                let mut bins = new_bins();
                let all = ctx.split_binned_all(&mut bins, &mut refs, bounds, cb);
                if ctx.leaf_certain(&refs, bounds) {
                    assert_eq!(
                        all, None,
                        "{n} boxes over {spread} of up to {size}: binning splits"
                    );
                    early += 1;
                } else {
                    split += usize::from(all.is_some());
                }
            }
        }
        // Both kinds of node were met.
        assert!(
            early > 300 && split > 300,
            "{early} early leaves, {split} splits"
        );
    }

    /// A leaf's cost in blocks is the ceiling of count / block, whether
    /// the block is a power of two (a shift) or not (a division).
    #[test]
    fn blocks_round_up() {
        for block in 1..=9 {
            let config = BuildConfig {
                leaf_block: Some(block),
                ..BuildConfig::default()
            };
            let ctx = Ctx::new(&config, BvhBuilder::BinnedSah, PAR_SUBTREE);
            for n in (0..100).chain([u32::MAX as usize - 1]) {
                assert_eq!(
                    ctx.blocks(n),
                    n.div_ceil(block) as f32,
                    "{n} in blocks of {block}"
                );
            }
        }
    }

    /// A leaf holds at most [`BuildConfig::max_leaf`] primitives: by
    /// default 8 when they are weighed one by one (a wide BVH's binary
    /// tree) and two blocks (16) when in blocks of 8; as given when given.
    /// Over copies of one box, where no split helps, the SAH builders make
    /// the largest leaves the limit allows, and no larger.
    #[test]
    fn leaves_hold_at_most_max_leaf() {
        let one = Aabb::new(Vec3::ZERO, Vec3::ONE);
        for (block, max_leaf, limit) in [
            (None, None, 8),
            (Some(8), None, 16),
            (Some(2), None, 8),
            (Some(8), Some(4), 4),
            (None, Some(12), 12),
        ] {
            let config = BuildConfig {
                leaf_block: block,
                max_leaf,
                ..BuildConfig::default()
            };
            assert_eq!(config.max_leaf_for(block.unwrap_or(1)), limit);
            for builder in [BvhBuilder::BinnedSah, BvhBuilder::SweepSah] {
                for n in [limit, limit + 1, 5 * limit + 3] {
                    let bvh = builder.build(&vec![one; n], &config);
                    let leaves: Vec<u32> = bvh
                        .nodes()
                        .iter()
                        .filter(|n| n.is_leaf())
                        .map(|n| n.count)
                        .collect();
                    let largest = leaves.iter().copied().max().unwrap_or(0) as usize;
                    let what = format!("{builder:?}, {n} boxes, blocks {block:?}, {max_leaf:?}");
                    assert_eq!(leaves.iter().sum::<u32>() as usize, n, "{what}");
                    assert!(largest <= limit, "{what}: a leaf of {largest}");
                    assert_eq!(leaves.len() == 1, n <= limit, "{what}: {leaves:?}");
                }
            }
        }
    }

    /// The sweep builder, which sorts once and partitions, splits every
    /// node where a sweep over the node's primitives sorted afresh on each
    /// axis splits it (the same primitives left), with copies of boxes
    /// (equal centroids, ordered by index), nodes whose box has no area or
    /// a NaN one (split by count, after which the orders are made again:
    /// a flat set with one box infinitely long, whose half without it the
    /// sweep then splits), and block sizes 1 and 8.
    #[test]
    fn sweep_splits_where_a_fresh_sort_would() {
        let mut b = crate::test_util::clustered_boxes(3000);
        for i in 0..300 {
            b[3 * i + 1] = b[3 * i];
        }
        // Forty points at one spot: no sweep split has area there.
        for k in b.iter_mut().skip(2000).take(40) {
            *k = Aabb::new(Vec3::splat(0.5), Vec3::splat(0.5));
        }
        let mut flat: Vec<Aabb> = crate::test_util::clustered_boxes(500)
            .iter()
            .map(|k| Aabb::new(k.min.with_z(0.0), k.max.with_z(0.0)))
            .collect();
        flat[7].max.x = f32::INFINITY;
        // The slots (first, count) of node `i`'s primitives.
        fn range(nodes: &[Node], i: usize) -> (usize, usize) {
            let n = &nodes[i];
            if n.is_leaf() {
                return (n.index as usize, n.count as usize);
            }
            let (lf, lc) = range(nodes, n.index as usize);
            let (rf, rc) = range(nodes, n.index as usize + 1);
            assert_eq!(lf + lc, rf, "a subtree's slots are contiguous");
            (lf, lc + rc)
        }
        for (b, leaf_block) in [(&b, None), (&b, Some(8)), (&flat, None)] {
            let config = BuildConfig {
                leaf_block,
                ..BuildConfig::default()
            };
            let bvh = BvhBuilder::SweepSah.build(b, &config);
            bvh.validate(b).unwrap();
            let ctx = Ctx::new(&config, BvhBuilder::SweepSah, PAR_SUBTREE);
            let (nodes, ids) = (bvh.nodes(), bvh.prim_ids());
            let (mut swept, mut by_count) = (0, 0);
            for (i, n) in nodes.iter().enumerate() {
                if i == 1 || n.is_leaf() {
                    continue;
                }
                let (first, count) = range(&nodes, i);
                let refs: Vec<PrimRef> = ids[first..first + count]
                    .iter()
                    .map(|&p| PrimRef::new(b[p as usize], p))
                    .collect();
                let mut best = None;
                let mut right_area = vec![0.0; count];
                let orders: Vec<Vec<PrimRef>> = (0..3)
                    .map(|axis| {
                        let mut order = refs.clone();
                        order.sort_by_key(|r| sweep_key(r.centroid()[axis], r.id()));
                        ctx.sweep_axis(axis, &order, &mut right_area, &mut best);
                        order
                    })
                    .collect();
                let (_, axis, k) = best.expect("two primitives or more");
                let (lf, lc) = range(&nodes, n.index as usize);
                let mut left = ids[lf..lf + lc].to_vec();
                left.sort_unstable();
                let mut want: Vec<u32> = orders[axis][..k].iter().map(PrimRef::id).collect();
                want.sort_unstable();
                if n.bounds().half_area() > 0.0 {
                    assert_eq!(left, want, "node {i}, block {leaf_block:?}");
                    swept += 1;
                } else {
                    assert_eq!(lc, count / 2, "split by count");
                    by_count += 1;
                }
            }
            assert!(swept > 50 && by_count > 0, "{swept} {by_count}");
        }
    }

    /// The sweep builder's integer keys order centroids as `total_cmp`
    /// does, then primitive indices: over zeros of both signs, NaNs,
    /// infinities, subnormals and ties.
    #[test]
    fn sweep_keys_order_as_total_cmp_then_index() {
        let mut values = vec![
            0.0f32,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            f32::from_bits(1),
            -f32::from_bits(1),
            1.0,
            -1.0,
            f32::MAX,
            f32::MIN,
        ];
        let mut rng = crate::test_util::xorshift(7);
        values.extend((0..200).map(|_| (rng() - 0.5) * 1e3));
        let keyed: Vec<(f32, u32)> = values
            .iter()
            .enumerate()
            .flat_map(|(i, &v)| [(v, i as u32), (v, 1000 + i as u32)])
            .collect();
        for a in &keyed {
            for b in &keyed {
                assert_eq!(
                    sweep_key(a.0, a.1).cmp(&sweep_key(b.0, b.1)),
                    a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)),
                    "{a:?} against {b:?}"
                );
            }
        }
    }
}
