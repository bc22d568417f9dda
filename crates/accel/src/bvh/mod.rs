//! Bounding volume hierarchy: a flat array of 32-byte nodes with `u32`
//! indices, sibling children side by side, and a primitive permutation.
//!
//! Builders (one per file) see only primitive boxes and centroids; the tree
//! never calls them. Traversal visits the nearer child first and keeps the
//! farther on a fixed-size stack, whose depth the builders bound.

mod build;
mod optimize;
mod wide;

pub(crate) use build::{max_keep, min_keep};
pub use build::{BvhBuilder, Clip};
#[cfg(test)]
pub(crate) use wide::slab_scalar;
#[cfg(target_arch = "x86_64")]
pub(crate) use wide::small_tree_bytes;
#[cfg(all(test, target_arch = "x86_64"))]
pub(crate) use wide::{entered_slots, group_slab_entry_scalar, group_slab_scalar, reaching};
pub use wide::{BoxRay, Bvh4, Bvh8, Node4, Node8, WideBvh, WideNode};
#[cfg(target_arch = "x86_64")]
pub(crate) use wide::{GroupEntry, GroupLeaf, GroupRays, GROUP};

use crate::packet::{self, Packet8, PacketLeaf, LANES};
use crate::pages::Pages;
use crate::prims::BLOCK;
use crate::{simd, test_each, AccelStats, Leaf, RayCounter};
use raymesh_geometry::{
    cull_bound, exit_reciprocal, max_nan_second as max_ns, min_nan_second as min_ns, Aabb, Ray,
    Vec3,
};
use wide::{PacketEntry, Stack};

/// Most nodes a traversal stack can hold. Builders never make a tree deeper
/// than this: past [`build::SAH_DEPTH_LIMIT`] levels they split by count,
/// which halves the primitives per level, so depth ≤ 64 + log2(2^32) = 96.
pub(crate) const STACK_SIZE: usize = 96;

/// Levels up to which a binary traversal uses a stack of this many
/// entries rather than [`STACK_SIZE`] (see [`Bvh::traverse_blocks`]).
const SHALLOW: usize = 32;

/// A block callback for traversals that hand out leaves as slot ranges:
/// [`test_each`] over the range's primitives (through the permutation
/// `ids`, when there is one).
#[inline(always)]
pub(crate) fn each_prim<'a>(
    ids: &'a [u32],
    ray: &'a Ray,
    leaf: &'a mut impl Leaf,
) -> impl FnMut(u32, u32) -> f32 + 'a {
    move |first, count| {
        let slots = first..first + count;
        test_each(
            slots.map(|p| if ids.is_empty() { p } else { ids[p as usize] }),
            ray,
            leaf,
        )
    }
}

/// A node: its box, and either two adjacent children (`count == 0`,
/// `index` the first child) or a leaf of `count` primitives starting at
/// `index` in the permutation. 32 bytes, so two fit a cache line.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Node {
    min: [f32; 3],
    pub(crate) count: u32,
    max: [f32; 3],
    pub(crate) index: u32,
}

const _: () = assert!(std::mem::size_of::<Node>() == 32);

/// Two sibling nodes in one 64-byte cache line: a traversal that tests
/// both children of a node reads one line. The root shares its pair with
/// an unused node.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub(crate) struct NodePair(pub(crate) [Node; 2]);

impl Node {
    pub(crate) fn new(b: Aabb) -> Self {
        Self {
            min: b.min.to_array(),
            count: 0,
            max: b.max.to_array(),
            index: 0,
        }
    }

    /// The node's box.
    #[inline(always)]
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::new(Vec3::from_array(self.min), Vec3::from_array(self.max))
    }

    /// Whether this is a leaf.
    #[inline(always)]
    #[must_use]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

/// A ray prepared for the node test: for each axis, which of a node's
/// eight words ([`Node`]'s `min`, `count`, `max`, `index`) holds the plane
/// the ray meets first (`near`) and last (`far`).
///
/// Reading the planes by index instead of choosing them with `if` per
/// axis takes 12 branches a node off the traversal; they mispredicted
/// whenever a ray's octant differed from the previous ray's (9 a ray on
/// random rays, by callgrind).
#[derive(Clone, Copy, Debug, Default)]
struct PlaneRay {
    origin: [f32; 3],
    inv_dir: [f32; 3],
    /// The [`exit_reciprocal`]s of `inv_dir`, for exit distances.
    inv_exit: [f32; 3],
    near: [usize; 3],
    far: [usize; 3],
    tmin: f32,
}

impl PlaneRay {
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        let oct = ray.octant();
        let near = [0, 1, 2].map(|a| a + 4 * ((oct >> a) & 1));
        Self {
            origin: ray.origin().to_array(),
            inv_dir: ray.inv_dir().to_array(),
            inv_exit: ray.inv_dir().to_array().map(exit_reciprocal),
            near,
            far: near.map(|i| i ^ 4),
            tmin: ray.tmin(),
        }
    }

    /// [`Aabb::slab`] of the node's box: the same operations in the same
    /// order, so the same `(entry, exit)` bit for bit.
    #[inline(always)]
    fn slab(&self, n: &Node, bound: f32) -> (f32, f32) {
        let p: &[f32; 8] = bytemuck::cast_ref(n);
        let near = |a: usize| (p[self.near[a] & 7] - self.origin[a]) * self.inv_dir[a];
        let far = |a: usize| (p[self.far[a] & 7] - self.origin[a]) * self.inv_exit[a];
        let entry = max_ns(near(0), max_ns(near(1), max_ns(near(2), self.tmin)));
        let exit = min_ns(far(0), min_ns(far(1), min_ns(far(2), bound)));
        (entry, exit)
    }
}

/// A BVH: nodes (root first) and the primitive permutation leaves index into.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// Node `i` is `pairs[i / 2].0[i % 2]`; node 0 is the root, node 1 unused.
    /// On huge pages where the system has them ([`crate::pages`]).
    pairs: Pages<NodePair>,
    /// Leaf slot → primitive; empty once the owner has reordered its
    /// primitives to match (then slot `k` is primitive `k`).
    prim_ids: Vec<u32>,
    /// [`Self::depth`], recorded by the builder.
    depth: u32,
    /// Whether spatial splits built the tree: its leaves then hold parts
    /// of primitives (see [`Self::validate`]).
    parts: bool,
}

impl Bvh {
    /// The nodes, root first, then the root's unused sibling, then sibling
    /// pairs (empty for no primitives).
    #[must_use]
    pub fn nodes(&self) -> Vec<Node> {
        self.pairs.iter().flat_map(|p| p.0).collect()
    }

    /// Node `i`.
    #[inline(always)]
    fn node(&self, i: u32) -> &Node {
        &self.pairs[(i >> 1) as usize].0[(i & 1) as usize]
    }

    /// The primitive permutation: leaf `(index, count)` holds
    /// `prim_ids[index..index + count]`. A caller that reorders its
    /// primitives by it can drop this indirection.
    #[must_use]
    pub fn prim_ids(&self) -> &[u32] {
        &self.prim_ids
    }

    pub(crate) fn bounds(&self) -> Aabb {
        self.pairs.first().map_or(Aabb::EMPTY, |p| p.0[0].bounds())
    }

    /// Hands the permutation to an owner that stores its primitives in leaf
    /// order; from then on leaves name primitives by slot.
    pub(crate) fn take_prim_ids(&mut self) -> Vec<u32> {
        std::mem::take(&mut self.prim_ids)
    }

    /// This tree improved by reinsertion (see [`crate::BuildConfig::optimize`]):
    /// the same leaves, arranged for a lower SAH cost.
    #[must_use]
    pub fn optimized(self) -> Self {
        optimize::optimize(self, optimize::Rounds::default())
    }

    /// Depth of the deepest leaf (1 for a single leaf, 0 for an empty tree).
    #[must_use]
    pub fn depth(&self) -> usize {
        self.depth as usize
    }

    pub(crate) fn stats(&self) -> AccelStats {
        let nodes = &self.nodes();
        // Node 1 is the root's unused sibling.
        let used = || {
            nodes
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != 1)
                .map(|(_, n)| n)
        };
        let leaves = used().filter(|n| n.is_leaf()).count();
        let root_area = self.bounds().half_area() as f64;
        let rel = |n: &Node| {
            if root_area > 0.0 {
                n.bounds().half_area() as f64 / root_area
            } else {
                1.0
            }
        };
        // Per node: (SAH term, node tests, leaf tests). An inner node
        // entered is one test of its pair of children.
        let (sah_cost, node_tests, leaf_tests) = used()
            .map(|n| {
                let a = rel(n);
                if n.is_leaf() {
                    let blocks = n.count.div_ceil(BLOCK as u32);
                    (a * n.count as f64, 0.0, a * blocks as f64)
                } else if root_area > 0.0 {
                    (a, a, 0.0)
                } else {
                    // Flat: as `sah_cost` always counted it, leaves only.
                    (0.0, a, 0.0)
                }
            })
            .fold((0.0, 0.0, 0.0), |s, t| (s.0 + t.0, s.1 + t.1, s.2 + t.2));
        AccelStats {
            nodes: nodes.len().saturating_sub(1),
            leaves,
            depth: self.depth(),
            bytes: self.pairs.len() * std::mem::size_of::<NodePair>() + self.prim_ids.len() * 4,
            sah_cost,
            node_tests: Some(node_tests),
            leaf_tests: Some(leaf_tests),
            ..AccelStats::default()
        }
    }

    /// Checks every invariant: children inside their parent, each primitive
    /// in exactly one leaf and inside its box, indices in range. For tests.
    ///
    /// A tree built with spatial splits holds parts of primitives: each
    /// primitive must be in at least one leaf, at most once a leaf, and
    /// overlap the box of every leaf that holds it (a part's box lies
    /// inside the primitive's box).
    pub fn validate(&self, boxes: &[Aabb]) -> Result<(), String> {
        let parts = self.parts;
        if !parts && self.prim_ids.len() != boxes.len() {
            return Err(format!(
                "{} leaf slots for {} primitives without spatial splits",
                self.prim_ids.len(),
                boxes.len()
            ));
        }
        if boxes.is_empty() {
            return if self.pairs.is_empty() {
                Ok(())
            } else {
                Err("nodes without primitives".into())
            };
        }
        let nodes = self.nodes();
        let mut seen = vec![false; boxes.len()];
        let mut stack = vec![(0usize, 1usize)];
        let mut deepest = 0;
        while let Some((i, depth)) = stack.pop() {
            if depth > STACK_SIZE {
                return Err(format!("depth {depth} exceeds the traversal stack"));
            }
            let n = nodes.get(i).ok_or(format!("node {i} out of range"))?;
            let b = n.bounds();
            if n.is_leaf() {
                deepest = deepest.max(depth);
                let range = n.index as usize..(n.index + n.count) as usize;
                let leaf = self.prim_ids.get(range).ok_or("leaf range out of range")?;
                for (k, &p) in leaf.iter().enumerate() {
                    let p = p as usize;
                    let pb = *boxes.get(p).ok_or(format!("primitive {p} out of range"))?;
                    if std::mem::replace(&mut seen[p], true) && !parts {
                        return Err(format!("primitive {p} in two leaves"));
                    }
                    if parts {
                        if leaf[..k].contains(&(p as u32)) {
                            return Err(format!("primitive {p} twice in leaf {i}"));
                        }
                        // (Broken input, NaN or infinite corners, has no
                        // parts to speak of: only the count is checked.)
                        let finite = pb.min.is_finite() && pb.max.is_finite();
                        if finite && !pb.is_empty() && !b.overlaps(&pb) {
                            return Err(format!("leaf {i} holds primitive {p} but misses its box"));
                        }
                    } else if !pb.is_empty() && b.union(pb) != b {
                        return Err(format!("primitive {p} sticks out of leaf {i}"));
                    }
                }
            } else {
                let c = n.index as usize;
                if c + 1 >= nodes.len() || c <= i || !c.is_multiple_of(2) {
                    return Err(format!("node {i} has bad children {c}"));
                }
                for k in [c, c + 1] {
                    let cb = nodes[k].bounds();
                    if !cb.is_empty() && b.union(cb) != b {
                        return Err(format!("child {k} sticks out of node {i}"));
                    }
                    stack.push((k, depth + 1));
                }
            }
        }
        if deepest != self.depth() {
            return Err(format!("depth {} recorded, {deepest} walked", self.depth()));
        }
        match seen.iter().position(|s| !s) {
            Some(p) => Err(format!("primitive {p} in no leaf")),
            None => Ok(()),
        }
    }

    /// Closest-first traversal (any-hit too: the leaf returns `-inf` to
    /// stop), calling `leaf` per primitive.
    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        self.traverse_blocks(ray, counter, &mut each_prim(&self.prim_ids, ray, leaf));
    }

    /// Closest-first traversal calling `block(first, count)` for each leaf
    /// reached, with its slots in the primitive permutation; it returns the
    /// ray's new upper bound (`-inf` stops).
    ///
    /// The stack holds at most one node a level below the root, so a tree
    /// of at most [`SHALLOW`] levels (most are) walks with a stack of that
    /// many entries: set up per ray, [`STACK_SIZE`]'s 768 bytes were a
    /// `memset` call a ray (63 instructions on bunny00's random rays).
    #[inline]
    pub(crate) fn traverse_blocks<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
    ) {
        self.traverse_blocks_prefetching(ray, counter, block, &|_| {});
    }

    /// [`Self::traverse_blocks`], calling `prefetch_leaf(first)` for each
    /// leaf the walk pushes for later (the farther of two children
    /// entered), as the wide walk does
    /// ([`WideBvh::traverse_blocks_avx2`]).
    #[inline]
    pub(crate) fn traverse_blocks_prefetching<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
    ) {
        if self.depth() <= SHALLOW {
            self.walk_blocks::<SHALLOW, C>(ray, counter, block, prefetch_leaf);
        } else {
            self.walk_blocks::<STACK_SIZE, C>(ray, counter, block, prefetch_leaf);
        }
    }

    /// [`Self::traverse_blocks`] with a stack of `N` entries (`N` at least
    /// the tree's depth).
    #[inline(always)]
    fn walk_blocks<const N: usize, C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        block: &mut impl FnMut(u32, u32) -> f32,
        prefetch_leaf: &impl Fn(u32),
    ) {
        let Some(root) = self.pairs.first().map(|p| &p.0[0]) else {
            return;
        };
        let pr = PlaneRay::new(ray);
        let tmin = ray.tmin();
        let mut tmax = ray.tmax();
        let (entry, exit) = pr.slab(root, cull_bound(tmax));
        if entry > exit {
            return;
        }
        let mut stack = [(0u32, 0.0f32); N];
        let mut sp = 0usize;
        let mut node = root;
        loop {
            counter.node();
            if node.is_leaf() {
                for _ in 0..node.count {
                    counter.prim();
                }
                tmax = block(node.index, node.count);
                if tmax < tmin {
                    return;
                }
            } else {
                let pair = &self.pairs[(node.index >> 1) as usize].0;
                let (l, r) = (&pair[0], &pair[1]);
                // Start fetching both grandchild pairs while the children
                // are tested: the walk goes on to one of them next, or
                // pops one later (a leaf's index only wastes a prefetch).
                simd::prefetch_at(&self.pairs, (l.index >> 1) as usize);
                simd::prefetch_at(&self.pairs, (r.index >> 1) as usize);
                let bound = cull_bound(tmax);
                let ((l0, l1), (r0, r1)) = (pr.slab(l, bound), pr.slab(r, bound));
                let (hit_l, hit_r) = (l0 <= l1, r0 <= r1);
                if hit_l && hit_r {
                    let (near, far, far_entry) = if l0 <= r0 {
                        (l, node.index + 1, r0)
                    } else {
                        (r, node.index, l0)
                    };
                    let far_node = self.node(far);
                    if far_node.is_leaf() {
                        prefetch_leaf(far_node.index);
                    }
                    stack[sp] = (far, far_entry);
                    sp += 1;
                    node = near;
                    continue;
                } else if hit_l {
                    node = l;
                    continue;
                } else if hit_r {
                    node = r;
                    continue;
                }
            }
            // Pop the next node still in reach; equal entries stay (ties by index).
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                let (i, entry) = stack[sp];
                if entry <= cull_bound(tmax) {
                    node = self.node(i);
                    break;
                }
            }
        }
    }
}

/// Rays a stream traversal ([`Bvh::traverse_stream`]) keeps in flight:
/// enough independent walks to hide a node fetch's latency behind the
/// others' work; more only adds state. On bunny00's random rays, pinned:
/// with the AVX step 2 and 8 lanes ran within 3% of 4; with the first,
/// scalar step, 1 lane was 28% slower than 4 and 2 lanes 4% slower.
pub(crate) const STREAM_LANES: usize = 4;

/// Node index that marks the bottom of a stream lane's stack: popping it
/// ends the lane's ray.
const DONE: u32 = u32::MAX;

/// Slots of a stream lane's stack: a power of two above [`STACK_SIZE`] + 2
/// (the bottom marker, and the slot a step may write past the top), so
/// that masking an index with `STREAM_STACK - 1` keeps it in bounds
/// without a check and leaves every index the traversal uses unchanged.
const STREAM_STACK: usize = 128;
const _: () = assert!(STREAM_STACK.is_power_of_two() && STREAM_STACK >= STACK_SIZE + 2);

/// A ray prepared for the test of a node's two children at once (the AVX
/// kernel `simd::pair_slab_avx`): origin and reciprocal direction repeated
/// in both 128-bit halves, and a mask of the axes whose near plane is the
/// box's upper one. The scalar form ([`PlaneRay`]) comes along for the
/// portable path.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
pub(crate) struct PairRay {
    pub(crate) origin: [f32; 8],
    pub(crate) inv_dir: [f32; 8],
    pub(crate) inv_exit: [f32; 8],
    pub(crate) neg: [u32; 8],
    pub(crate) tmin: f32,
    plane: PlaneRay,
}

impl PairRay {
    /// The ray's node test.
    pub(crate) fn new(ray: &Ray) -> Self {
        let plane = PlaneRay::new(ray);
        // Lane `i` holds axis `i % 4`; the fourth of each half is unused.
        let axis = |i: usize| (i % 4 < 3).then_some(i % 4);
        Self {
            origin: std::array::from_fn(|i| axis(i).map_or(0.0, |a| plane.origin[a])),
            inv_dir: std::array::from_fn(|i| axis(i).map_or(0.0, |a| plane.inv_dir[a])),
            inv_exit: std::array::from_fn(|i| axis(i).map_or(0.0, |a| plane.inv_exit[a])),
            neg: std::array::from_fn(|i| {
                axis(i).map_or(0, |a| 0u32.wrapping_sub((plane.near[a] >= 4) as u32))
            }),
            tmin: plane.tmin,
            plane,
        }
    }

    /// Changes the lower end of the ray's interval (tests give the node
    /// tests `tmin`s a valid ray cannot have).
    #[cfg(all(test, target_arch = "x86_64"))]
    pub(crate) fn set_tmin(&mut self, tmin: f32) {
        self.tmin = tmin;
        self.plane.tmin = tmin;
    }
}

/// Both children's slab tests in plain Rust ([`PlaneRay::slab`] each):
/// the portable path of the AVX pair kernel, with its result (a bit
/// per child entered, 1 left and 2 right, and both entry distances).
#[inline(always)]
pub(crate) fn pair_slab_scalar(pair: &NodePair, r: &PairRay, bound: f32) -> (u32, f32, f32) {
    let (l0, l1) = r.plane.slab(&pair.0[0], bound);
    let (r0, r1) = r.plane.slab(&pair.0[1], bound);
    ((l0 <= l1) as u32 | ((r0 <= r1) as u32) << 1, l0, r0)
}

/// `if c { a } else { b }` as a conditional move, never a branch: the
/// stream walk's choices are unpredictable, and a branch mispredicts on
/// them (without the hint the compiler made branches of these selects).
#[inline(always)]
fn select_u32(c: bool, a: u32, b: u32) -> u32 {
    std::hint::select_unpredictable(c, a, b)
}

/// [`select_u32`] for floats, bit for bit.
#[inline(always)]
fn select_f32(c: bool, a: f32, b: f32) -> f32 {
    f32::from_bits(select_u32(c, a.to_bits(), b.to_bits()))
}

/// One ray of a stream traversal in flight: its node test, its bound, the
/// node it visits next with that node's entry distance, its stack, and its
/// index in the stream.
#[derive(Clone, Copy, Debug)]
struct StreamLane {
    ray: PairRay,
    tmax: f32,
    cur: u32,
    entry: f32,
    sp: usize,
    index: usize,
    /// Slot 0 is the bottom marker, never overwritten.
    stack: [(u32, f32); STREAM_STACK],
}

impl Bvh {
    /// Traverses every ray of `rays` closest-first, as
    /// [`Self::traverse_blocks`] does each: the same boxes tested with the
    /// same arithmetic, the same leaves offered in the same order (and
    /// past a shrunk bound, nodes the one-ray walk would pop unseen are
    /// visited and culled by their children's test, which cannot change a
    /// result). `leaf(ray, first, count, tmax)` tests a leaf for
    /// `rays[ray]` within `tmax` and returns the ray's new bound; below the
    /// ray's `tmin` ends it, as for any-hit queries. Invalid rays are
    /// skipped.
    ///
    /// [`STREAM_LANES`] rays are in flight at once, each step taking every
    /// one a node further, and a ray that finishes makes room for the next
    /// (Aila & Laine, "Understanding the efficiency of ray traversal on
    /// GPUs", 2009, keep lanes busy the same way). A step chooses its next
    /// node with conditional moves instead of branches and tests both
    /// children in one AVX kernel: one ray's walk is a chain of dependent
    /// loads and unpredictable branches, which incoherent rays spend most
    /// of their time waiting on; interleaved, the core overlaps the rays'
    /// chains, and no misprediction throws away the others' work.
    pub(crate) fn traverse_stream(
        &self,
        rays: &[Ray],
        leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
    ) {
        if self.pairs.is_empty() {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if simd::has_avx2() {
            return simd::stream_loop_avx2(self, rays, leaf);
        }
        self.stream_loop::<STREAM_LANES>(rays, leaf, pair_slab_scalar);
    }

    /// The loop of [`Self::traverse_stream`], `K` lanes, generic over the
    /// test of a node's two children.
    #[inline(always)]
    pub(crate) fn stream_loop<const K: usize>(
        &self,
        rays: &[Ray],
        leaf: &mut impl FnMut(usize, u32, u32, f32) -> f32,
        pair_slab: impl Fn(&NodePair, &PairRay, f32) -> (u32, f32, f32),
    ) {
        const M: usize = STREAM_STACK - 1;
        let root = &self.pairs[0].0[0];
        let mut next = 0;
        // Starts the next ray that enters the root's box on `lane`;
        // returns false when none is left.
        let start = |lane: &mut StreamLane| {
            while let Some(ray) = rays.get(next) {
                next += 1;
                if !ray.is_valid() {
                    continue;
                }
                let r = PairRay::new(ray);
                let (entry, exit) = r.plane.slab(root, cull_bound(ray.tmax()));
                if entry <= exit {
                    (lane.ray, lane.tmax, lane.index) = (r, ray.tmax(), next - 1);
                    (lane.cur, lane.entry, lane.sp) = (0, entry, 1);
                    return true;
                }
            }
            false
        };
        let mut lanes = [StreamLane {
            ray: PairRay::default(),
            tmax: 0.0,
            cur: DONE,
            entry: 0.0,
            sp: 0,
            index: 0,
            stack: [(DONE, f32::NEG_INFINITY); STREAM_STACK],
        }; K];
        round_robin(&mut lanes, start, |l| {
            let node = self.node(l.cur);
            let bound = cull_bound(l.tmax);
            if node.is_leaf() || l.entry > bound {
                if node.is_leaf() && l.entry <= bound {
                    l.tmax = leaf(l.index, node.index, node.count, l.tmax);
                    if l.tmax < l.ray.tmin {
                        l.sp = 1;
                    }
                }
                l.sp -= 1;
                (l.cur, l.entry) = l.stack[l.sp & M];
            } else {
                let (hits, l0, r0) =
                    pair_slab(&self.pairs[(node.index >> 1) as usize], &l.ray, bound);
                let (hit_l, hit_r) = (hits & 1 != 0, hits & 2 != 0);
                // The one-ray walk's order: the left child first unless
                // only the right is entered or the right strictly first.
                let right = hit_r & (!hit_l | !(l0 <= r0));
                let near = node.index + right as u32;
                // Push the farther child (kept only if both are entered);
                // pop if neither is.
                l.stack[l.sp & M] = (near ^ 1, select_f32(right, l0, r0));
                let any = hit_l | hit_r;
                let sp = l.sp + (hit_l & hit_r) as usize - !any as usize;
                let top = l.stack[sp & M];
                l.sp = sp;
                l.cur = select_u32(any, near, top.0);
                l.entry = select_f32(any, select_f32(right, r0, l0), top.1);
            }
            l.cur != DONE
        });
    }
}

/// The scheduling of a stream traversal: `start` puts the next ray on a
/// lane (false when none is left), and `step` takes a lane's ray one step
/// further (false when it has ended). Steps go round robin over the lanes
/// in flight; a lane whose ray ends starts the next, or, with none left,
/// trades places with the last lane in flight.
#[inline(always)]
pub(crate) fn round_robin<L, const K: usize>(
    lanes: &mut [L; K],
    mut start: impl FnMut(&mut L) -> bool,
    mut step: impl FnMut(&mut L) -> bool,
) {
    // Lanes `..n` are in flight.
    let mut n = 0;
    while n < K && start(&mut lanes[n]) {
        n += 1;
    }
    while n > 0 {
        let mut k = 0;
        while k < n {
            let lane = &mut lanes[k];
            if step(lane) || start(lane) {
                k += 1;
            } else {
                n -= 1;
                lanes.swap(k, n);
            }
        }
    }
}

impl Bvh {
    /// Packet traversal (see [`WideBvh::traverse_packet`], the same
    /// contract): both children's boxes are tested against every active
    /// lane; when lanes enter both, the child that the lowest such lane
    /// enters first is visited first, the other pushed with its lanes.
    #[inline]
    pub(crate) fn traverse_packet(
        &self,
        p: &Packet8,
        tmax: &mut [f32; LANES],
        leaf: &mut impl PacketLeaf,
    ) {
        if self.pairs.is_empty() {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(avx) = simd::Avx2::detect() {
            return simd::packet_walk_binary_avx2(avx, self, p, tmax, leaf);
        }
        self.packet_loop(p, tmax, leaf, None);
    }

    /// The walk of [`Self::traverse_packet`], `avx` handed to the leaves.
    /// Grandchild pairs and a pushed leaf's block start fetching as in
    /// the one-ray walk: `--packets` primary rays over a 2M-triangle
    /// sphere and terrain 1.05-1.13 times as fast (closest and any-hit),
    /// over bunny00, the dragon and the pig 0.96-1.04 (`raymesh-ab MESH
    /// --accel bvh-binned --workload primary --size 512 --packets --rounds
    /// 3`, each build the other's baseline).
    #[inline(always)]
    pub(crate) fn packet_loop(
        &self,
        p: &Packet8,
        tmax: &mut [f32; LANES],
        leaf: &mut impl PacketLeaf,
        avx: Option<simd::Avx2>,
    ) {
        let test = |n: &Node, bound: &[f32; LANES]| packet::slab(p, n.min, n.max, bound);
        let bound: [f32; LANES] = std::array::from_fn(|i| cull_bound(tmax[i]));
        let (lanes, entry) = test(self.node(0), &bound);
        let mut stack = Stack::new(PacketEntry::NONE);
        // `child` is the node's index here.
        let mut cur = PacketEntry {
            child: 0,
            count: 0,
            lanes,
            entry,
        };
        loop {
            let bound: [f32; LANES] = std::array::from_fn(|i| cull_bound(tmax[i]));
            let lanes = cur.lanes & packet::le_mask(&cur.entry, &bound);
            if lanes != 0 {
                let node = self.node(cur.child);
                if node.is_leaf() {
                    leaf.visit(avx, node.index, node.count, lanes, tmax);
                } else {
                    let pair = &self.pairs[(node.index >> 1) as usize].0;
                    // Both grandchild pairs start fetching, as in the
                    // one-ray walk (a leaf's index only wastes a prefetch).
                    simd::prefetch_at(&self.pairs, (pair[0].index >> 1) as usize);
                    simd::prefetch_at(&self.pairs, (pair[1].index >> 1) as usize);
                    let (ml, el) = test(&pair[0], &bound);
                    let (mr, er) = test(&pair[1], &bound);
                    let (ml, mr) = (ml & lanes, mr & lanes);
                    let l = PacketEntry {
                        child: node.index,
                        count: 0,
                        lanes: ml,
                        entry: el,
                    };
                    let r = PacketEntry {
                        child: node.index + 1,
                        lanes: mr,
                        entry: er,
                        ..l
                    };
                    if ml != 0 && mr != 0 {
                        let both = (ml & mr).trailing_zeros() as usize;
                        let (near, far) = if both < LANES && el[both] > er[both] {
                            (r, l)
                        } else {
                            (l, r)
                        };
                        let far_node = self.node(far.child);
                        if far_node.is_leaf() {
                            leaf.prefetch(far_node.index);
                        }
                        stack.push(far);
                        cur = near;
                        continue;
                    } else if ml != 0 {
                        cur = l;
                        continue;
                    } else if mr != 0 {
                        cur = r;
                        continue;
                    }
                }
            }
            let Some(e) = stack.pop() else { return };
            cur = e;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{hard_coord, hard_vec3};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(crate::test_util::config(4000))]
        /// The node test that reads planes by index gives the bits of
        /// `Aabb::slab`, in every octant, on any box (empty ones too) and
        /// whatever the leaf fields hold.
        #[test]
        fn plane_slab_matches_aabb_slab(
            a in hard_vec3(), b in hard_vec3(), o in hard_vec3(), d in hard_vec3(),
            tmin in hard_coord(), bound in hard_coord(), count in any::<u32>(), index in any::<u32>(),
        ) {
            let mut node = Node::new(Aabb::new(a, b));
            (node.count, node.index) = (count, index);
            let ray = Ray::new(o, d, tmin.min(0.0), f32::INFINITY);
            let mut pr = PlaneRay::new(&ray);
            pr.tmin = tmin;
            let (e, x) = pr.slab(&node, bound);
            let (e0, x0) = node.bounds().slab(ray.origin(), ray.inv_dir(), ray.octant(), tmin, bound);
            prop_assert_eq!((e.to_bits(), x.to_bits()), (e0.to_bits(), x0.to_bits()));
        }
    }
}
