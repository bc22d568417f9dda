//! k-d tree (a BSP tree with axis-aligned planes), built by binned SAH with
//! an empty-space bonus (Wald & Havran, "On building fast kd-trees for ray
//! tracing, and on doing that in O(N log N)", 2006; binning as in Hunt et
//! al. 2006), each primitive that crosses a split plane clipped to the two
//! sides (Wald & Havran's split clipping, after Havran's "perfect
//! splits"), and traversed front to back (pbrt-v4's `KdTreeAggregate`).

use crate::bvh::each_prim;
use crate::{AccelStats, BuildConfig, Clip, Leaf, RayCounter};
use raymesh_geometry::{cull_bound, Aabb, Ray, Vec3, Vec3A};
use rayon::prelude::*;
use std::hint::select_unpredictable;
use std::ops::Range;

/// Deepest a k-d tree may grow; also the traversal stack size.
const MAX_DEPTH: usize = 64;
/// Cost discount for a split that cuts off empty space.
const EMPTY_BONUS: f32 = 0.2;
/// Splits that do not lower the cost, tolerated along one path.
const MAX_BAD_REFINES: u32 = 3;

/// An 8-byte node. `a` holds the split position's bits (interior) or the
/// first primitive's offset (leaf); `b`'s low two bits hold the axis (0–2)
/// or 3 for a leaf, its upper 30 bits the above child's index (interior;
/// the below child is the next node) or the primitive count (leaf).
///
/// A side that holds no primitive has no node (Wald & Havran's empty-space
/// cuts make many: more than half the leaves of bunny00's tree were
/// empty). Above index 0 (the root, no one's child) says the above side is
/// empty; an above index one past the node's own (where the below child
/// would lie) says the below side is. A ray then never loads a node to
/// learn that it holds nothing, nor pushes one on its stack.
#[derive(Clone, Copy, Debug, PartialEq)]
struct KdNode {
    a: u32,
    b: u32,
}

/// The most nodes, and references in one leaf, a node's 30 bits can name.
/// A tree past them (hundreds of millions of triangles) stops with a
/// message rather than wrapping into wrong children.
const MAX_INDEX: u32 = 1 << 30;
/// What a tree of more references than a `u32` offset reaches says.
const TOO_MANY_REFS: &str = "a k-d tree of 2^32 references or more";

impl KdNode {
    fn leaf(offset: u32, count: u32) -> Self {
        assert!(
            count < MAX_INDEX,
            "a k-d tree leaf of 2^30 references or more"
        );
        Self {
            a: offset,
            b: (count << 2) | 3,
        }
    }
    fn interior(axis: usize, split: f32, above: u32) -> Self {
        assert!(above < MAX_INDEX, "a k-d tree of 2^30 nodes or more");
        Self {
            a: split.to_bits(),
            b: (above << 2) | axis as u32,
        }
    }
    #[inline(always)]
    fn is_leaf(self) -> bool {
        self.b & 3 == 3
    }
    #[inline(always)]
    fn axis(self) -> usize {
        (self.b & 3) as usize
    }
    #[inline(always)]
    fn split(self) -> f32 {
        f32::from_bits(self.a)
    }
    #[inline(always)]
    fn upper(self) -> u32 {
        self.b >> 2
    }
    /// An interior node's children, `at` being its own index: below and
    /// above, [`NO_NODE`] for an empty side.
    #[inline(always)]
    fn children(self, at: usize) -> (usize, usize) {
        let up = self.upper() as usize;
        (
            if up == at + 1 { NO_NODE } else { at + 1 },
            if up == 0 { NO_NODE } else { up },
        )
    }
}

/// What [`KdNode::children`] gives for an empty side.
const NO_NODE: usize = usize::MAX;

/// A k-d tree over primitive boxes. A primitive that crosses a split plane
/// goes to each side its part reaches (its box's side, or its shape's when
/// the build clips it: [`Self::build_clipped`]); one that touches the plane
/// goes to both, so a hit on the plane is found from either.
#[derive(Clone, Debug)]
pub struct KdTree {
    bounds: Aabb,
    nodes: Vec<KdNode>,
    /// The leaves' references, leaf after leaf: a leaf's primitives are
    /// `prims[start..start + count]`. Empty once an owner has stored its
    /// primitives in this order, a reference per slot
    /// ([`Self::take_leaf_order`]): a leaf then names its slots
    /// `start..start + count` directly (`slots`).
    prims: Vec<u32>,
    /// Whether the order was taken and leaves name slots.
    slots: bool,
}

/// Nodes with at least this many primitive references build their two
/// subtrees as separate rayon tasks.
const PAR_SUBTREE: usize = 4096;

/// A primitive's reference in a node: its index, and the box of its part
/// inside the node (its own box at the root, then cut at each plane it
/// crosses on the way down; see [`Clip`]).
#[derive(Clone, Copy, Debug)]
struct Ref {
    id: u32,
    b: Aabb,
}

/// What every node of one build reads.
struct Builder<'a> {
    config: &'a BuildConfig,
    /// Cuts a reference crossing a split plane into its two sides' parts.
    clip: &'a Clip<'a>,
    max_depth: usize,
    /// [`PAR_SUBTREE`], or more to build on one thread (tests compare both).
    par_subtree: usize,
    /// Primitives a leaf tests for the cost of one ([`Self::tests`]).
    block: u32,
}

/// Nodes and leaf primitive lists of a subtree built on one thread; child
/// and primitive indices are relative to these vectors.
#[derive(Default)]
struct Local {
    nodes: Vec<KdNode>,
    prims: Vec<u32>,
}

/// A subtree as the parallel recursion returns it, flattened once at the end.
enum Subtree {
    Flat(Local),
    /// A split plane (axis, position) whose two sides were built in
    /// parallel, below and above; `None` for an empty side.
    Split(usize, f32, Option<Box<Subtree>>, Option<Box<Subtree>>),
}

/// Per bin and axis, how many boxes start in it and how many end in it.
type BinCounts = (Vec<[u32; 3]>, Vec<[u32; 3]>);

/// A node's split plane, and the count of splits that did not pay along
/// the path down to it.
#[derive(Clone, Copy)]
struct Plane {
    axis: usize,
    pos: f32,
    bad: u32,
}

impl Plane {
    /// The boxes of the two sides of `bounds`, below and above.
    fn sides(self, bounds: Aabb) -> (Aabb, Aabb) {
        let (mut lo, mut hi) = (bounds, bounds);
        lo.max[self.axis] = self.pos;
        hi.min[self.axis] = self.pos;
        (lo, hi)
    }
}

/// What one thread's sequential build reuses from node to node, so that a
/// node allocates nothing: with both threads allocating and freeing a list
/// a node, the allocator took 14% of a 2-thread build at 10M triangles
/// (perf), part of it waiting on the other thread's arena lock.
struct Scratch {
    /// The reference lists of the nodes being built, as a stack: a node's
    /// list, then (above it) the above side's, then its descendants'.
    ids: Vec<Ref>,
    bins: BinCounts,
}

/// Appends `tree` to `out` in the order a one-thread build makes (below
/// subtree right after its parent, then the above subtree), shifting its
/// child and primitive indices.
fn place(tree: Subtree, out: &mut Local) {
    match tree {
        Subtree::Flat(local) => {
            let (node_base, prim_base) = (out.nodes.len() as u32, out.prims.len() as u32);
            out.nodes.extend(local.nodes.into_iter().map(|n| {
                if n.is_leaf() {
                    KdNode {
                        a: n.a.checked_add(prim_base).expect(TOO_MANY_REFS),
                        b: n.b,
                    }
                } else if n.upper() == 0 {
                    n
                } else {
                    let above = n.upper().checked_add(node_base).unwrap_or(MAX_INDEX);
                    KdNode::interior(n.axis(), n.split(), above)
                }
            }));
            out.prims.extend_from_slice(&local.prims);
        }
        Subtree::Split(axis, split, below, above) => {
            let here = out.nodes.len();
            out.nodes.push(KdNode::interior(axis, split, 0));
            if let Some(b) = below {
                place(*b, out);
            }
            // With no below child, the above one lands right after this
            // node: the mark of an empty below side.
            let above_index = if above.is_some() {
                out.nodes.len() as u32
            } else {
                0
            };
            out.nodes[here] = KdNode::interior(axis, split, above_index);
            if let Some(a) = above {
                place(*a, out);
            }
        }
    }
}

impl KdTree {
    /// Builds the tree over primitive `i`'s box `boxes[i]`, knowing the
    /// primitives only by their boxes: a box that crosses a split plane is
    /// cut at it ([`Aabb::split`]).
    ///
    /// Large nodes build their two sides in parallel on the current rayon
    /// pool; the tree is the same whatever the number of threads.
    #[must_use]
    pub fn build(boxes: &[Aabb], config: &BuildConfig) -> Self {
        Self::build_clipped(
            boxes,
            &|_, within, axis, pos| within.split(axis, pos),
            config,
        )
    }

    /// [`Self::build`], with `clip` cutting a primitive that crosses a
    /// split plane into the parts on each side (see [`Clip`]): a triangle
    /// then goes only to the sides its own shape reaches, not every side
    /// its box does, for fewer references and fewer triangles tested a
    /// ray ([`raymesh_geometry::clip_triangle`]; Wald & Havran 2006, §4.3).
    #[must_use]
    pub fn build_clipped(boxes: &[Aabb], clip: &Clip<'_>, config: &BuildConfig) -> Self {
        Self::build_split_at(boxes, clip, config, PAR_SUBTREE)
    }

    fn build_split_at(
        boxes: &[Aabb],
        clip: &Clip<'_>,
        config: &BuildConfig,
        par_subtree: usize,
    ) -> Self {
        let bounds = boxes
            .par_iter()
            .fold(|| Aabb::EMPTY, |a, b| a.union(*b))
            .reduce(|| Aabb::EMPTY, Aabb::union);
        let n = boxes.len();
        let b = Builder {
            config,
            clip,
            // Havran's rule of thumb, 8 + 1.3 log2 N, within the stack.
            max_depth: ((8.0 + 1.3 * (n.max(1) as f64).log2()).round() as usize).min(MAX_DEPTH - 1),
            par_subtree,
            block: config.leaf_block.unwrap_or(1).clamp(1, 64) as u32,
        };
        let mut out = Local::default();
        if n > 0 {
            let refs = (0..n as u32)
                .into_par_iter()
                .map(|id| Ref {
                    id,
                    b: boxes[id as usize],
                })
                .collect();
            place(b.subtree(bounds, refs, 0, 0), &mut out);
        }
        Self {
            bounds,
            nodes: out.nodes,
            prims: out.prims,
            slots: false,
        }
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub(crate) fn stats(&self) -> AccelStats {
        let root_area = self.bounds.half_area() as f64;
        let (mut leaves, mut depth, mut sah) = (0usize, 0usize, 0.0f64);
        if !self.nodes.is_empty() {
            let mut stack = vec![(0usize, self.bounds, 1usize)];
            while let Some((i, b, d)) = stack.pop() {
                let n = self.nodes[i];
                let rel = if root_area > 0.0 {
                    b.half_area() as f64 / root_area
                } else {
                    1.0
                };
                if n.is_leaf() {
                    leaves += 1;
                    depth = depth.max(d);
                    sah += rel * n.upper() as f64;
                } else {
                    sah += rel;
                    let (mut lo, mut hi) = (b, b);
                    lo.max[n.axis()] = n.split();
                    hi.min[n.axis()] = n.split();
                    let (below, above) = n.children(i);
                    for (c, side) in [(below, lo), (above, hi)] {
                        if c != NO_NODE {
                            stack.push((c, side, d + 1));
                        }
                    }
                }
            }
        }
        AccelStats {
            nodes: self.nodes.len(),
            leaves,
            depth,
            bytes: self.nodes.len() * std::mem::size_of::<KdNode>() + self.prims.len() * 4,
            sah_cost: sah,
            ..AccelStats::default()
        }
    }

    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        self.traverse_ranges(ray, counter, &mut each_prim(&self.prims, ray, leaf));
    }

    /// The leaves' references in leaf order, for an owner to store its
    /// primitives by (a primitive in several leaves several times), so
    /// that each leaf's primitives lie together and are tested as blocks
    /// of consecutive slots, not gathered by index. `None` once taken.
    pub(crate) fn leaf_order(&self) -> Option<&[u32]> {
        (!self.prims.is_empty()).then_some(&self.prims[..])
    }

    /// Hands over [`Self::leaf_order`] once the owner has stored its
    /// primitives by it: from then on a leaf names its slots
    /// ([`Self::traverse_ranges`]), and the tree has no lists
    /// ([`Self::names_slots`]).
    pub(crate) fn take_leaf_order(&mut self) -> Vec<u32> {
        self.slots = true;
        std::mem::take(&mut self.prims)
    }

    /// Whether the leaves name slots ([`Self::take_leaf_order`]): then
    /// they have no lists ([`Self::traverse_lists`]).
    pub(crate) fn names_slots(&self) -> bool {
        self.slots
    }

    /// Front-to-back traversal calling `list(ids)` with each nonempty
    /// leaf's primitives; it returns the ray's new upper bound (below
    /// `tmin` stops), so that a caller can test a leaf's primitives
    /// together ([`crate::Primitives::intersect_ids`]). For a tree whose
    /// leaves name primitives, not slots ([`Self::names_slots`]).
    ///
    /// Kept as small as this: the walks of the grid's and the k-d tree's
    /// lists share one AVX2 function (`Scene::lists_avx2`), near the size
    /// past which LLVM no longer inlines their leaf test into it (a loop
    /// here that made lists of slots for the other trees took it past:
    /// every intrinsic of the kernel a call; `scripts/check-kernels-inlined.sh`).
    #[inline]
    pub(crate) fn traverse_lists<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        list: &mut impl FnMut(&[u32]) -> f32,
    ) {
        debug_assert!(!self.slots, "the leaves name slots: no lists");
        let prims = &self.prims;
        self.traverse_ranges(ray, counter, &mut |start, count| {
            list(&prims[start as usize..(start + count) as usize])
        });
    }

    /// Front-to-back traversal calling `range(start, count)` with each
    /// nonempty leaf: its references `start..start + count` in
    /// [`Self::leaf_order`] (its slots once the owner stores its
    /// primitives so). `range` returns the ray's new upper bound (below
    /// `tmin` stops).
    #[inline]
    pub(crate) fn traverse_ranges<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        range: &mut impl FnMut(u32, u32) -> f32,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let Some((t0, t1)) = self.bounds.intersect_ray(ray, ray.tmax()) else {
            return;
        };
        // Arrays, not `Vec3`s: `Vec3`'s `Index` is a `match` on the axis,
        // which changes from node to node and mispredicted.
        let (o, d, inv) = (
            ray.origin().to_array(),
            ray.dir().to_array(),
            ray.inv_dir().to_array(),
        );
        let mut tmax = ray.tmax();
        let mut stack = [(0u32, 0.0f32, 0.0f32); MAX_DEPTH];
        let mut sp = 0usize;
        let (mut node, mut n0, mut n1) = (0usize, t0, t1);
        loop {
            if node != NO_NODE && n0 <= cull_bound(tmax) {
                counter.node();
                let n = self.nodes[node];
                if !n.is_leaf() {
                    let axis = n.axis();
                    let split = n.split();
                    let (below, above) = n.children(node);
                    // The below child shares this node's cache line or
                    // the next; the above one lies far off, and is visited
                    // next or popped later: start fetching it now.
                    crate::simd::prefetch_at(&self.nodes, above);
                    if d[axis] == 0.0 {
                        // Parallel to the plane: one side holds the whole ray.
                        node = if o[axis] <= split { below } else { above };
                        continue;
                    }
                    let t = (split - o[axis]) * inv[axis];
                    // Pad the crossing so that rounding never skips a side.
                    let pad = t.abs() * 1e-6 + f32::MIN_POSITIVE;
                    // Which side the ray meets first: a conditional move,
                    // as the axis changes from node to node.
                    let fwd = d[axis] > 0.0;
                    let first = select_unpredictable(fwd, below, above);
                    let second = select_unpredictable(fwd, above, below);
                    if t - pad > n1 {
                        node = first;
                    } else if t + pad < n0 {
                        node = second;
                    } else if first == NO_NODE {
                        node = second;
                        n0 = (t - pad).max(n0);
                    } else {
                        if second != NO_NODE {
                            stack[sp] = (second as u32, (t - pad).max(n0), n1);
                            sp += 1;
                        }
                        node = first;
                        n1 = (t + pad).min(n1);
                    }
                    continue;
                }
                let count = n.upper();
                if count != 0 {
                    for _ in 0..count {
                        counter.prim();
                    }
                    tmax = range(n.a, count);
                    if tmax < ray.tmin() {
                        return;
                    }
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            let (i, a, b) = stack[sp];
            (node, n0, n1) = (i as usize, a, b);
        }
    }
}

impl Builder<'_> {
    /// The plane to split a node over `ids` (the box `bounds`) at, or
    /// `None` for a leaf. `bins` is scratch space for the binning.
    fn plan(
        &self,
        bounds: Aabb,
        ids: &[Ref],
        depth: usize,
        bad: u32,
        bins: &mut BinCounts,
    ) -> Option<Plane> {
        let n = ids.len();
        if n <= 1 || depth >= self.max_depth {
            return None;
        }
        let (cost, axis, pos) = self.best_split(bounds, ids, bins)?;
        let mut bad = bad;
        if cost >= self.tests(n as u32) {
            bad += 1;
            if bad > MAX_BAD_REFINES || n <= self.config.max_leaf_for(self.block as usize) / 2 {
                return None;
            }
        }
        Some(Plane { axis, pos, bad })
    }

    /// Splits the reference list `ids[range]` by the plane `axis`, `split`:
    /// the below side is compacted in place at the start of the range, in
    /// order, and the above side appended to `ids`, in order. Returns the
    /// below side's length. A reference whose box crosses the plane is
    /// clipped ([`Builder::clip`]) and goes to each side its part reaches,
    /// with the box of that part; one that only touches the plane goes
    /// both ways (`<=`, `>=`), so plane hits are found from either side.
    /// One pass reads each reference once for both sides, and no list is
    /// allocated: the one-thread build keeps its nodes' lists on one stack
    /// (see [`Scratch`]).
    fn partition_in(
        &self,
        ids: &mut Vec<Ref>,
        range: Range<usize>,
        axis: usize,
        split: f32,
    ) -> usize {
        ids.reserve(range.len());
        let mut kept = range.start;
        for k in range.clone() {
            let r = ids[k];
            let (below, above) = if r.b.min[axis] < split && split < r.b.max[axis] {
                let (lo, hi) = (self.clip)(r.id, r.b, axis, split);
                (
                    (!lo.is_empty()).then_some(lo),
                    (!hi.is_empty()).then_some(hi),
                )
            } else {
                (
                    (r.b.min[axis] <= split).then_some(r.b),
                    (r.b.max[axis] >= split).then_some(r.b),
                )
            };
            if let Some(b) = above {
                ids.push(Ref { id: r.id, b });
            }
            if let Some(b) = below {
                ids[kept] = Ref { id: r.id, b };
                kept += 1;
            }
        }
        kept - range.start
    }

    /// The two sides of `ids` ([`Self::partition_in`]) as two lists, the
    /// below one in `ids`' own allocation.
    fn partition(&self, mut ids: Vec<Ref>, axis: usize, split: f32) -> (Vec<Ref>, Vec<Ref>) {
        let n = ids.len();
        let kept = self.partition_in(&mut ids, 0..n, axis, split);
        let above = ids.split_off(n);
        ids.truncate(kept);
        (ids, above)
    }

    /// Builds the subtree over `ids`, its two sides in parallel when large.
    fn subtree(&self, bounds: Aabb, ids: Vec<Ref>, depth: usize, bad: u32) -> Subtree {
        let n = ids.len();
        let mut local = Local::default();
        if n < self.par_subtree {
            let mut scratch = Scratch {
                ids,
                bins: BinCounts::default(),
            };
            self.build(&mut local, &mut scratch, bounds, 0..n, depth, bad);
            return Subtree::Flat(local);
        }
        let Some(p) = self.plan(bounds, &ids, depth, bad, &mut BinCounts::default()) else {
            Self::make_leaf(&mut local, &ids);
            return Subtree::Flat(local);
        };
        let (below, above) = self.partition(ids, p.axis, p.pos);
        if below.len() == n && above.len() == n || below.is_empty() && above.is_empty() {
            Self::make_leaf(&mut local, &below);
            return Subtree::Flat(local);
        }
        let (lo, hi) = p.sides(bounds);
        let side = |b: Aabb, ids: Vec<Ref>| {
            (!ids.is_empty()).then(|| Box::new(self.subtree(b, ids, depth + 1, p.bad)))
        };
        let (b, a) = rayon::join(|| side(lo, below), || side(hi, above));
        Subtree::Split(p.axis, p.pos, b, a)
    }

    /// Builds the subtree over the references `s.ids[range]` into `out`,
    /// on this thread. Lists of the nodes below are pushed on `s.ids` past
    /// its length and popped before returning.
    fn build(
        &self,
        out: &mut Local,
        s: &mut Scratch,
        bounds: Aabb,
        range: Range<usize>,
        depth: usize,
        bad: u32,
    ) {
        let (n, top) = (range.len(), s.ids.len());
        let Some(p) = self.plan(bounds, &s.ids[range.clone()], depth, bad, &mut s.bins) else {
            Self::make_leaf(out, &s.ids[range]);
            return;
        };
        let kept = self.partition_in(&mut s.ids, range.clone(), p.axis, p.pos);
        let above = top..s.ids.len();
        if kept == n && above.len() == n || kept == 0 && above.is_empty() {
            // No progress, or every part clipped away (a degenerate
            // primitive): one leaf.
            Self::make_leaf(out, &s.ids[above]);
        } else {
            // An empty side gets no node (see [`KdNode`]).
            let (lo, hi) = p.sides(bounds);
            let here = out.nodes.len();
            out.nodes.push(KdNode::interior(p.axis, p.pos, 0));
            if kept > 0 {
                let below = range.start..range.start + kept;
                self.build(out, s, lo, below, depth + 1, p.bad);
            }
            // With no below child, the above one lands right after this
            // node: the mark of an empty below side.
            let above_index = if above.is_empty() {
                0
            } else {
                out.nodes.len() as u32
            };
            out.nodes[here] = KdNode::interior(p.axis, p.pos, above_index);
            if !above.is_empty() {
                self.build(out, s, hi, above, depth + 1, p.bad);
            }
        }
        s.ids.truncate(top);
    }

    fn make_leaf(out: &mut Local, ids: &[Ref]) {
        let offset = u32::try_from(out.prims.len()).expect(TOO_MANY_REFS);
        out.nodes.push(KdNode::leaf(offset, ids.len() as u32));
        out.prims.extend(ids.iter().map(|r| r.id));
    }

    /// One pass over the boxes of `ids` counts every axis: in how many
    /// boxes start, and end, in each of `nb` bins from `origin` (`scale`
    /// bins a unit), the last bin holding those at the far end, into `bins`.
    fn bin(&self, ids: &[Ref], origin: Vec3, scale: Vec3, nb: usize, bins: &mut BinCounts) {
        let (mins, maxs) = bins;
        for v in [&mut *mins, &mut *maxs] {
            v.clear();
            v.resize(nb + 1, [0; 3]);
        }
        // Clamped in floats (a NaN to 0), then truncated, the three axes
        // at once: the BVH builders' binning (`truncate3`).
        let simd = crate::simd::simd_enabled();
        let (origin, scale) = (Vec3A::from(origin), Vec3A::from(scale));
        let bin =
            |p: Vec3| crate::simd::truncate3((Vec3A::from(p) - origin) * scale, nb as f32, simd);
        for r in ids {
            let (lo, hi) = (bin(r.b.min), bin(r.b.max));
            for axis in 0..3 {
                mins[(lo >> (8 * axis) & 0xff) as usize][axis] += 1;
                maxs[(hi >> (8 * axis) & 0xff) as usize][axis] += 1;
            }
        }
    }

    /// What a leaf of `n` primitives costs to test, in tests of one:
    /// blocks of [`BuildConfig::leaf_block`] when its primitives are
    /// tested together.
    #[inline(always)]
    fn tests(&self, n: u32) -> f32 {
        n.div_ceil(self.block) as f32
    }

    /// Cheapest plane among the bin boundaries of every axis, as (cost, axis, position).
    fn best_split(
        &self,
        bounds: Aabb,
        ids: &[Ref],
        bins: &mut BinCounts,
    ) -> Option<(f32, usize, f32)> {
        // Small nodes need few candidate planes: twice their size is plenty.
        // At most 255: a box's bin on each axis is packed into a byte.
        let nb = self.config.bins.min(2 * ids.len()).clamp(2, 255);
        let ext = bounds.extent();
        let area = bounds.half_area();
        if !(area > 0.0) {
            return None;
        }
        let mut best: Option<(f32, usize, f32)> = None;
        let scale = Vec3::select(
            ext.cmpgt(Vec3::ZERO),
            Vec3::splat(nb as f32) / ext,
            Vec3::ZERO,
        );
        self.bin(ids, bounds.min, scale, nb, bins);
        let (mins, maxs) = (&bins.0, &bins.1);
        for axis in 0..3 {
            if !(ext[axis] > 0.0) {
                continue;
            }
            let (o1, o2) = ((axis + 1) % 3, (axis + 2) % 3);
            let cross = ext[o1] * ext[o2];
            let perim = ext[o1] + ext[o2];
            let (mut n_below, mut n_above) = (0u32, ids.len() as u32);
            for k in 1..nb {
                n_below += mins[k - 1][axis];
                n_above -= maxs[k - 1][axis];
                let pos = bounds.min[axis] + k as f32 * ext[axis] / nb as f32;
                let (wb, wa) = (pos - bounds.min[axis], bounds.max[axis] - pos);
                let (ab, aa) = (cross + wb * perim, cross + wa * perim);
                let bonus = if n_below == 0 || n_above == 0 {
                    1.0 - EMPTY_BONUS
                } else {
                    1.0
                };
                // Compared before the division by the node's area, which
                // is the same for every candidate.
                let cost = bonus * (ab * self.tests(n_below) + aa * self.tests(n_above));
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, pos));
                }
            }
        }
        best.map(|(c, axis, pos)| (self.config.traversal_cost + c / area, axis, pos))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel recursion lays the tree out node for node as the
    /// one-thread build does, whether rayon runs one thread or several.
    #[test]
    fn parallel_build_is_identical_to_sequential() {
        let b = crate::test_util::clustered_boxes(20_000);
        let config = BuildConfig::default();
        let clip = |_, within: Aabb, axis, pos| within.split(axis, pos);
        let seq = KdTree::build_split_at(&b, &clip, &config, usize::MAX);
        assert!(
            seq.nodes.len() > 1000,
            "a real tree: {} nodes",
            seq.nodes.len()
        );
        for threads in [1, 3] {
            let pool = crate::test_util::pool(threads);
            for split_at in [2, 64, PAR_SUBTREE] {
                let par = pool.install(|| KdTree::build_split_at(&b, &clip, &config, split_at));
                assert_eq!(par.nodes, seq.nodes, "split at {split_at}");
                assert_eq!(par.prims, seq.prims);
                assert_eq!(par.bounds, seq.bounds);
            }
        }
    }

    /// The binning counts, per bin and axis, the boxes that start and end
    /// in each bin, whatever the number of boxes and of bins; boxes past
    /// either end land in the end bins.
    #[test]
    fn binning_counts_each_box_once() {
        let config = BuildConfig::default();
        let clip = |_, within: Aabb, axis, pos| within.split(axis, pos);
        let b = Builder {
            config: &config,
            clip: &clip,
            max_depth: MAX_DEPTH - 1,
            par_subtree: PAR_SUBTREE,
            block: 1,
        };
        let boxes = crate::test_util::clustered_boxes(101);
        let bounds = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        let mut bins = BinCounts::default();
        for n in [0, 1, 2, 7, 100, 101] {
            let ids: Vec<Ref> = boxes[..n]
                .iter()
                .enumerate()
                .map(|(i, &b)| Ref { id: i as u32, b })
                .collect();
            for nb in [2, 16, 255] {
                // A box a little inside the bounds, so that some boxes
                // fall outside it at each end.
                let origin = bounds.min + bounds.extent() * 0.1;
                let scale = Vec3::splat(nb as f32) / (bounds.extent() * 0.8);
                b.bin(&ids, origin, scale, nb, &mut bins);
                let mut want = [vec![[0u32; 3]; nb + 1], vec![[0u32; 3]; nb + 1]];
                let at = |x: f32, axis: usize| {
                    let k = ((x - origin[axis]) * scale[axis]).clamp(0.0, nb as f32);
                    k as usize
                };
                for r in &ids {
                    for axis in 0..3 {
                        want[0][at(r.b.min[axis], axis)][axis] += 1;
                        want[1][at(r.b.max[axis], axis)][axis] += 1;
                    }
                }
                assert_eq!(bins.0, want[0], "starts, {n} boxes, {nb} bins");
                assert_eq!(bins.1, want[1], "ends, {n} boxes, {nb} bins");
            }
        }
    }

    /// Diagonal slivers, whose boxes overlap most of the scene: known by
    /// their boxes, no split pays and the tree stays shallow; clipped at
    /// each plane, a triangle goes only to the cells its shape reaches,
    /// and the tree's SAH cost falls six times over (47.6 against 294, for
    /// 12,105 references against 1,662), each triangle still in some leaf.
    #[test]
    fn clipped_triangles_make_a_cheaper_tree() {
        let tris: Vec<[Vec3; 3]> = (0..400)
            .map(|i| {
                let x = i as f32 * 0.25;
                [
                    Vec3::new(x, 0.0, 0.0),
                    Vec3::new(x + 0.1, 0.0, 0.0),
                    Vec3::new(x + 30.0, 30.0, 30.0),
                ]
            })
            .collect();
        let boxes: Vec<Aabb> = tris.iter().map(|t| Aabb::from_points(*t)).collect();
        let config = BuildConfig::default();
        let by_box = KdTree::build(&boxes, &config);
        let clip = |i: u32, within, axis, pos| {
            raymesh_geometry::clip_triangle(tris[i as usize], within, axis, pos)
        };
        let clipped = KdTree::build_clipped(&boxes, &clip, &config);
        let (c, b) = (clipped.stats().sah_cost, by_box.stats().sah_cost);
        assert!(2.0 * c < b, "SAH cost {c} clipped against {b} by box");
        let mut named = vec![false; tris.len()];
        for &p in &clipped.prims {
            named[p as usize] = true;
        }
        assert!(named.iter().all(|&n| n), "a triangle in no leaf");
    }

    /// An empty side of a split has no node: no leaf is empty, though the
    /// clusters leave most of the space empty, and every node is reached
    /// from the root once.
    #[test]
    fn empty_sides_have_no_node() {
        let b = crate::test_util::clustered_boxes(5_000);
        let t = KdTree::build(&b, &BuildConfig::default());
        let mut reached = vec![0u32; t.nodes.len()];
        let mut stack = vec![0usize];
        let mut one_sided = 0;
        while let Some(i) = stack.pop() {
            reached[i] += 1;
            let n = t.nodes[i];
            if n.is_leaf() {
                assert!(n.upper() > 0, "an empty leaf at {i}");
            } else {
                let (below, above) = n.children(i);
                one_sided += usize::from(below == NO_NODE || above == NO_NODE);
                assert!(below != NO_NODE || above != NO_NODE, "no child at {i}");
                stack.extend([below, above].into_iter().filter(|&c| c != NO_NODE));
            }
        }
        assert!(
            reached.iter().all(|&r| r == 1),
            "a node reached twice or never"
        );
        assert!(
            one_sided > 100,
            "{one_sided} one-sided nodes: no empty space cut"
        );
    }

    /// Counting leaves in blocks ([`BuildConfig::leaf_block`]) makes fewer,
    /// fuller leaves, and still names every primitive.
    #[test]
    fn leaf_blocks_make_fuller_leaves() {
        let b = crate::test_util::clustered_boxes(20_000);
        let one = KdTree::build(&b, &BuildConfig::default());
        let config = BuildConfig {
            leaf_block: Some(2),
            ..BuildConfig::default()
        };
        let two = KdTree::build(&b, &config);
        let (s1, s2) = (one.stats(), two.stats());
        assert!(
            s2.leaves < s1.leaves,
            "{} leaves against {}",
            s2.leaves,
            s1.leaves
        );
        let fill = |t: &KdTree, leaves: usize| t.prims.len() as f64 / leaves as f64;
        assert!(fill(&two, s2.leaves) > fill(&one, s1.leaves));
        let mut named = vec![false; b.len()];
        for &p in &two.prims {
            named[p as usize] = true;
        }
        assert!(named.iter().all(|&n| n), "a primitive in no leaf");
    }

    /// Once its leaf order is taken, the tree walks the same leaves in the
    /// same order, naming slots: each leaf's slots, read through the order
    /// taken, are the primitives the tree named before, in
    /// [`KdTree::traverse_ranges`] and in [`KdTree::traverse`] (stopping
    /// where the bound falls below `tmin`), and they are the lists
    /// [`KdTree::traverse_lists`] gave.
    #[test]
    fn slots_name_what_the_order_named() {
        let b = crate::test_util::clustered_boxes(3_000);
        let config = BuildConfig {
            leaf_block: Some(8),
            ..BuildConfig::default()
        };
        let named = KdTree::build(&b, &config);
        let mut slots = named.clone();
        let order = slots.take_leaf_order();
        assert_eq!(order, named.prims);
        assert!(slots.names_slots() && !named.names_slots());
        assert!(slots.leaf_order().is_none() && named.leaf_order().is_some());
        assert!(
            order.len() > b.len(),
            "no primitive in two leaves: the test would not see slots and ids differ"
        );
        let mut next = crate::test_util::xorshift(7);
        let mut reached = 0;
        for k in 0..2_000 {
            let p = |f: &mut dyn FnMut() -> f32| Vec3::new(f(), f(), f());
            // From anywhere around the clusters toward one of the boxes.
            let o = p(&mut next) * 22.0 - Vec3::ONE;
            let d = b[(next() * (b.len() - 1) as f32) as usize].centroid() - o;
            let ray = Ray::new(o, d, 0.0, f32::INFINITY);
            // Every fifth ray stops after its third primitive.
            let stop_after = if k % 5 == 0 { 3 } else { usize::MAX };
            let ranges = |t: &KdTree| {
                let mut out = vec![];
                t.traverse_ranges(&ray, &mut crate::NoStats, &mut |s, n| {
                    out.extend((s..s + n).map(|i| order[i as usize]));
                    ray.tmax()
                });
                out
            };
            let each = |t: &KdTree| {
                let mut out = vec![];
                t.traverse(&ray, &mut crate::NoStats, &mut |i| {
                    out.push(i);
                    if out.len() >= stop_after {
                        f32::NEG_INFINITY
                    } else {
                        ray.tmax()
                    }
                });
                out
            };
            let mut lists = vec![];
            named.traverse_lists(&ray, &mut crate::NoStats, &mut |ids| {
                lists.extend_from_slice(ids);
                ray.tmax()
            });
            let leaves = ranges(&named);
            assert_eq!(leaves, ranges(&slots), "ray {k}: leaves");
            assert_eq!(leaves, lists, "ray {k}: lists");
            let by_slot: Vec<u32> = each(&slots).iter().map(|&i| order[i as usize]).collect();
            assert_eq!(each(&named), by_slot, "ray {k}: one by one");
            reached += usize::from(!leaves.is_empty());
        }
        assert!(reached > 1_500, "{reached} rays reached a leaf");
    }
}
