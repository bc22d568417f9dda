//! Reinsertion optimization of a built binary BVH: subtrees are taken out
//! and put back where they cost least, as in Bittner, Hapala & Havran,
//! "Fast Insertion-Based Optimization of Bounding Volume Hierarchies"
//! (2013), with the subtree moves and area-ordered batches of Meister &
//! Bittner, "Parallel Reinsertion for Bounding Volume Hierarchy
//! Optimization" (2018), here one move after another.
//!
//! A top-down builder decides each split once, looking only at the
//! primitives below it; reinsertion revisits those decisions with the
//! whole tree in view. Moving a subtree keeps every leaf as it is, so the
//! SAH cost changes only by the interior nodes' areas: each move is
//! chosen to lower their sum (the original place is always a candidate,
//! so no move raises it).

use super::{Bvh, Node, NodePair, SHALLOW, STACK_SIZE};
use raymesh_geometry::Aabb;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// No node: the root's parent, a leaf's children.
const NONE: u32 = u32::MAX;

/// How many reinsertion rounds [`optimize`] runs at most, and the share of
/// the nodes each one moves.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Rounds {
    /// Rounds at most; the optimizer stops earlier once a round lowers the
    /// interior area by less than [`Rounds::min_gain`].
    pub(crate) max: usize,
    /// Share of the nodes a round takes out and reinserts, the largest
    /// first.
    pub(crate) batch: f32,
    /// Relative drop of the interior area below which a round is the last.
    pub(crate) min_gain: f64,
}

impl Default for Rounds {
    fn default() -> Self {
        Self {
            max: 10,
            batch: 0.05,
            min_gain: 1e-3,
        }
    }
}

/// The tree with parent links, which moves need and the flat layout lacks.
struct Tree {
    bounds: Vec<Aabb>,
    parent: Vec<u32>,
    /// Children of an interior node; `[NONE, NONE]` for a leaf.
    kids: Vec<[u32; 2]>,
    /// `(first, count)` of a leaf's slots in the old permutation.
    leaf: Vec<(u32, u32)>,
    /// Levels of the subtree below each node (1 for a leaf).
    height: Vec<u32>,
    root: u32,
    /// Deepest a leaf may go: moves that would put one deeper are not
    /// made (see [`optimize`]).
    limit: u32,
}

/// The search frontier: the ancestors' growth so far (as a [`key`]), the
/// node, and its depth (the root at 1), least growth first.
type Frontier = BinaryHeap<Reverse<(u64, u32, u32)>>;

/// Half-area as `f64`, for sums over many nodes.
fn area(b: &Aabb) -> f64 {
    f64::from(b.half_area())
}

/// A non-negative finite `f64` as a key that sorts like it.
fn key(x: f64) -> u64 {
    x.max(0.0).to_bits()
}

impl Tree {
    fn from_bvh(bvh: &Bvh, limit: u32) -> Self {
        let nodes = bvh.nodes();
        let n = nodes.len();
        let mut t = Self {
            bounds: nodes.iter().map(Node::bounds).collect(),
            parent: vec![NONE; n],
            kids: vec![[NONE; 2]; n],
            leaf: vec![(0, 0); n],
            height: vec![1; n],
            root: 0,
            limit,
        };
        for (i, node) in nodes.iter().enumerate() {
            if i == 1 {
                continue;
            }
            if node.is_leaf() {
                t.leaf[i] = (node.index, node.count);
            } else {
                let c = node.index;
                t.kids[i] = [c, c + 1];
                t.parent[c as usize] = i as u32;
                t.parent[c as usize + 1] = i as u32;
            }
        }
        // Boxes become exactly the union of their children's (a spatial
        // split's children may be tighter than their parent), so that a
        // refit can stop at the first box a move leaves unchanged.
        for i in t.postorder() {
            if !t.is_leaf(i) {
                t.bounds[i as usize] = t.union_of_kids(i);
                t.height[i as usize] = t.height_of_kids(i);
            }
        }
        t
    }

    fn is_leaf(&self, i: u32) -> bool {
        self.kids[i as usize][0] == NONE
    }

    fn union_of_kids(&self, i: u32) -> Aabb {
        let [a, b] = self.kids[i as usize];
        self.bounds[a as usize].union(self.bounds[b as usize])
    }

    fn height_of_kids(&self, i: u32) -> u32 {
        let [a, b] = self.kids[i as usize];
        1 + self.height[a as usize].max(self.height[b as usize])
    }

    /// The nodes reachable from the root, children before parents.
    fn postorder(&self) -> Vec<u32> {
        let mut order = self.preorder();
        order.reverse();
        order
    }

    /// The nodes reachable from the root, parents before children.
    fn preorder(&self) -> Vec<u32> {
        let mut order = Vec::with_capacity(self.bounds.len());
        let mut stack = vec![self.root];
        while let Some(i) = stack.pop() {
            order.push(i);
            if !self.is_leaf(i) {
                stack.extend(self.kids[i as usize]);
            }
        }
        order
    }

    /// Sum of the interior nodes' half-areas: the part of the SAH cost
    /// that moving subtrees changes.
    fn interior_area(&self) -> f64 {
        self.preorder()
            .into_iter()
            .filter(|&i| !self.is_leaf(i))
            .map(|i| area(&self.bounds[i as usize]))
            .sum()
    }

    /// Recomputes boxes and heights from `i` up, stopping at the first
    /// node where neither changes (above it nothing does).
    fn refit(&mut self, mut i: u32) {
        while i != NONE {
            let (b, h) = (self.union_of_kids(i), self.height_of_kids(i));
            if b == self.bounds[i as usize] && h == self.height[i as usize] {
                return;
            }
            (self.bounds[i as usize], self.height[i as usize]) = (b, h);
            i = self.parent[i as usize];
        }
    }

    /// Puts `new` where `old` hangs (as a child of `old`'s parent, or as
    /// the root).
    fn replace(&mut self, old: u32, new: u32) {
        let g = self.parent[old as usize];
        self.parent[new as usize] = g;
        if g == NONE {
            self.root = new;
        } else {
            let k = &mut self.kids[g as usize];
            let side = usize::from(k[1] == old);
            k[side] = new;
        }
    }

    /// Takes the subtree at `n` (not the root) out: its parent node is
    /// freed, its sibling takes the parent's place. Returns the parent,
    /// the sibling, and which child of the parent `n` was.
    fn remove(&mut self, n: u32) -> (u32, u32, usize) {
        let p = self.parent[n as usize];
        let [a, b] = self.kids[p as usize];
        let (sibling, side) = if a == n { (b, 0) } else { (a, 1) };
        self.replace(p, sibling);
        self.parent[n as usize] = NONE;
        self.parent[p as usize] = NONE;
        let g = self.parent[sibling as usize];
        self.refit(g);
        (p, sibling, side)
    }

    /// The interior area the detached subtree `n` adds hung beside `x`:
    /// the new parent's area and what every ancestor of `x` grows.
    fn cost_beside(&self, n: u32, x: u32) -> f64 {
        let nb = self.bounds[n as usize];
        let mut cost = area(&self.bounds[x as usize].union(nb));
        let mut q = self.parent[x as usize];
        while q != NONE {
            let qb = self.bounds[q as usize];
            cost += area(&qb.union(nb)) - area(&qb);
            q = self.parent[q as usize];
        }
        cost
    }

    /// The node beside which the detached subtree `n` costs less than
    /// beside `stay` (where it was), if any: best-first search over the
    /// tree for the least [`Self::cost_beside`], bounded below by the
    /// ancestors' growth so far plus `n`'s own area (Bittner et al.).
    /// Staying wins ties, so that equal trees do not churn. A node that
    /// would put a leaf (of `n`'s or of its own subtree) deeper than the
    /// limit is passed over.
    fn best_sibling(&self, n: u32, stay: u32, heap: &mut Frontier) -> u32 {
        let nb = self.bounds[n as usize];
        let own = area(&nb);
        let tall = self.height[n as usize];
        let mut best = (stay, self.cost_beside(n, stay));
        heap.clear();
        heap.push(Reverse((key(0.0), self.root, 1)));
        while let Some(Reverse((k, x, depth))) = heap.pop() {
            let induced = f64::from_bits(k);
            if induced + own >= best.1 {
                break;
            }
            let xb = self.bounds[x as usize];
            let joined = area(&xb.union(nb));
            let fits = depth + tall.max(self.height[x as usize]) <= self.limit;
            if fits && induced + joined < best.1 {
                best = (x, induced + joined);
            }
            if !self.is_leaf(x) {
                let below = induced + joined - area(&xb);
                if below + own < best.1 {
                    for c in self.kids[x as usize] {
                        heap.push(Reverse((key(below), c, depth + 1)));
                    }
                }
            }
        }
        best.0
    }

    /// Hangs the detached subtree `n` beside `x`, under the free node `p`,
    /// as its child `side`.
    fn insert(&mut self, n: u32, x: u32, p: u32, side: usize) {
        self.replace(x, p);
        let mut kids = [x, n];
        if side == 0 {
            kids.swap(0, 1);
        }
        self.kids[p as usize] = kids;
        self.parent[x as usize] = p;
        self.parent[n as usize] = p;
        self.bounds[p as usize] = self.bounds[x as usize].union(self.bounds[n as usize]);
        self.height[p as usize] = self.height_of_kids(p);
        let g = self.parent[p as usize];
        self.refit(g);
    }

    /// One round: the largest `batch` share of the nodes, each taken out
    /// and put back at its best place.
    fn round(&mut self, batch: f32, heap: &mut Frontier) {
        let mut order: Vec<u32> = self.preorder();
        order.retain(|&i| i != self.root);
        let take = ((order.len() as f32 * batch).ceil() as usize).min(order.len());
        let by_area = |i: &u32| Reverse((key(area(&self.bounds[*i as usize])), *i));
        if take < order.len() {
            order.select_nth_unstable_by_key(take, by_area);
            order.truncate(take);
        }
        order.sort_unstable_by_key(by_area);
        for n in order {
            if self.parent[n as usize] == NONE {
                continue;
            }
            let (p, stay, side) = self.remove(n);
            let x = self.best_sibling(n, stay, heap);
            self.insert(n, x, p, side);
        }
    }

    /// The depth of the deepest leaf (the root at 1).
    fn depth(&self) -> usize {
        self.height[self.root as usize] as usize
    }

    /// The flat layout again: sibling pairs in depth-first order, and the
    /// permutation in leaf order, so that every subtree's primitives are
    /// again one run of slots (the wide collapse merges such runs).
    fn flatten(&self, old_ids: &[u32], parts: bool) -> Bvh {
        let empty = Node::new(Aabb::EMPTY);
        let mut pairs = vec![NodePair([empty; 2])];
        let mut prim_ids = Vec::with_capacity(old_ids.len());
        // (tree node, where its flat node goes)
        let mut stack = vec![(self.root, 0u32)];
        while let Some((i, at)) = stack.pop() {
            let mut node = Node::new(self.bounds[i as usize]);
            if self.is_leaf(i) {
                let (first, count) = self.leaf[i as usize];
                node.index = prim_ids.len() as u32;
                node.count = count;
                prim_ids.extend_from_slice(&old_ids[first as usize..(first + count) as usize]);
            } else {
                let pair = pairs.len() as u32;
                pairs.push(NodePair([empty; 2]));
                node.index = 2 * pair;
                let [l, r] = self.kids[i as usize];
                stack.push((r, 2 * pair + 1));
                stack.push((l, 2 * pair));
            }
            pairs[(at >> 1) as usize].0[(at & 1) as usize] = node;
        }
        Bvh {
            pairs: pairs.into(),
            prim_ids,
            depth: self.depth() as u32,
            parts,
        }
    }
}

/// Optimizes `bvh` by reinsertion (see the module's doc) and returns the
/// better tree, or `bvh` itself where there is nothing to gain (fewer
/// than three nodes, or a root box of no or infinite area) or no
/// permutation to rewrite (an owner took it: [`Bvh::take_prim_ids`]).
///
/// No move puts a leaf deeper than [`SHALLOW`] levels, or than the tree
/// already was if it was deeper: past them the binary walk sets up a
/// longer stack for every ray, and on the teapot in a stadium the depth
/// went from 27 to 39 levels unchecked, for the same nodes a ray within
/// 0.2%.
pub(crate) fn optimize(bvh: Bvh, rounds: Rounds) -> Bvh {
    let root_area = f64::from(bvh.bounds().half_area());
    let measurable = root_area > 0.0 && root_area.is_finite();
    if bvh.pairs.len() < 2 || bvh.prim_ids.is_empty() || !measurable {
        return bvh;
    }
    let limit = bvh.depth().clamp(SHALLOW, STACK_SIZE);
    optimize_within(bvh, rounds, limit)
}

/// [`optimize`] with no leaf deeper than `limit` levels (at least the
/// tree's depth) after any move.
fn optimize_within(bvh: Bvh, rounds: Rounds, limit: usize) -> Bvh {
    let limit = limit.max(bvh.depth()) as u32;
    let mut tree = Tree::from_bvh(&bvh, limit);
    let mut heap = BinaryHeap::new();
    let mut cost = tree.interior_area();
    if !cost.is_finite() {
        return bvh;
    }
    for _ in 0..rounds.max {
        tree.round(rounds.batch, &mut heap);
        let now = tree.interior_area();
        let gain = (cost - now) / cost;
        cost = now;
        if gain < rounds.min_gain {
            break;
        }
    }
    debug_assert!(tree.depth() <= limit as usize);
    tree.flatten(&bvh.prim_ids, bvh.parts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{clustered_boxes, xorshift};
    use crate::{BuildConfig, BvhBuilder};
    use raymesh_geometry::Vec3;

    /// Each leaf's primitives, as sorted lists, sorted: what reinsertion
    /// must keep.
    fn leaves(bvh: &Bvh) -> Vec<Vec<u32>> {
        let mut out: Vec<Vec<u32>> = bvh
            .nodes()
            .iter()
            .enumerate()
            .filter(|(i, n)| *i != 1 && n.is_leaf())
            .map(|(_, n)| {
                let mut ids = bvh.prim_ids[n.index as usize..(n.index + n.count) as usize].to_vec();
                ids.sort_unstable();
                ids
            })
            .collect();
        out.sort();
        out
    }

    /// `n` boxes of very mixed sizes: small ones in clusters, a few long
    /// slivers across them (the builders' top splits then overlap).
    fn mixed_boxes(n: usize) -> Vec<Aabb> {
        let mut next = xorshift(0x1234_5679);
        let mut boxes = clustered_boxes(n);
        for (i, b) in boxes.iter_mut().enumerate().filter(|(i, _)| i % 17 == 0) {
            let axis = i % 3;
            let p = Vec3::new(next(), next(), next()) * 20.0;
            let mut q = p + Vec3::splat(0.1);
            q[axis] += 15.0;
            *b = Aabb::new(p, q);
        }
        boxes
    }

    /// The optimized tree is valid (every primitive in one leaf, children
    /// inside parents, depth as recorded), keeps every leaf as it was, and
    /// costs no more, for every builder, with and without spatial splits.
    #[test]
    fn keeps_the_leaves_and_never_costs_more() {
        let clip = |_: u32, within: Aabb, axis: usize, pos: f32| within.split(axis, pos);
        for boxes in [clustered_boxes(2000), mixed_boxes(3000)] {
            for (builder, splits) in [
                (BvhBuilder::Median, 0.0),
                (BvhBuilder::BinnedSah, 0.0),
                (BvhBuilder::SweepSah, 0.0),
                (BvhBuilder::BinnedSah, 0.5),
            ] {
                let config = BuildConfig {
                    spatial_splits: splits,
                    ..BuildConfig::default()
                };
                let bounds = |i: u32| boxes[i as usize];
                let bvh = builder.build_spatial(boxes.len(), &bounds, &clip, &config);
                let before = bvh.stats().sah_cost;
                let kept = leaves(&bvh);
                let opt = bvh.optimized();
                let what = format!("{builder:?}, spatial splits {splits}");
                opt.validate(&boxes)
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_eq!(leaves(&opt), kept, "{what}");
                let after = opt.stats().sah_cost;
                assert!(
                    after <= before * (1.0 + 1e-6),
                    "{what}: {before} -> {after}"
                );
            }
        }
    }

    /// Where the top-down build chose badly, reinsertion finds better:
    /// the lecture's median split on mixed boxes loses a tenth of its
    /// SAH cost, the binned SAH tree a few percent.
    #[test]
    fn lowers_the_cost_of_poor_trees() {
        let boxes = mixed_boxes(4000);
        let config = BuildConfig::default();
        for (builder, most) in [(BvhBuilder::Median, 0.9), (BvhBuilder::BinnedSah, 0.99)] {
            let bvh = builder.build(&boxes, &config);
            let before = bvh.stats().sah_cost;
            let after = bvh.optimized().stats().sah_cost;
            assert!(after < most * before, "{builder:?}: {before} -> {after}");
        }
    }

    /// No move takes a leaf past the depth limit; without the limit the
    /// same tree does go deeper (so the check can fail).
    #[test]
    fn moves_keep_within_the_depth_limit() {
        let boxes = mixed_boxes(4000);
        let bvh = BvhBuilder::Median.build(&boxes, &BuildConfig::default());
        let depth = bvh.depth();
        let limit = depth + 2;
        let free = optimize_within(bvh.clone(), Rounds::default(), STACK_SIZE);
        assert!(free.depth() > limit, "{depth} -> {}", free.depth());
        let kept = optimize_within(bvh.clone(), Rounds::default(), limit);
        kept.validate(&boxes).expect("valid");
        assert!(kept.depth() <= limit, "{depth} -> {}", kept.depth());
        let (before, after) = (bvh.stats().sah_cost, kept.stats().sah_cost);
        assert!(after < 0.95 * before, "{before} -> {after}");
    }

    /// Nothing to move, or no area to measure moves by: the tree comes
    /// back as it was.
    #[test]
    fn small_flat_and_broken_trees_come_back_unchanged() {
        let config = BuildConfig::default();
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let flat = |i: u32| {
            Aabb::new(
                Vec3::new(i as f32, 0.0, 0.0),
                Vec3::new(i as f32 + 0.5, 1.0, 0.0),
            )
        };
        let huge = Aabb::new(Vec3::splat(-3e38), Vec3::splat(3e38));
        let nan = Aabb::new(Vec3::splat(f32::NAN), Vec3::ONE);
        let cases: Vec<Vec<Aabb>> = vec![
            vec![],
            vec![unit],
            vec![unit; 20],
            vec![
                huge, unit, unit, huge, unit, unit, unit, unit, unit, unit, unit,
            ],
        ];
        for boxes in &cases {
            let bvh = BvhBuilder::BinnedSah.build(boxes, &config);
            let opt = bvh.clone().optimized();
            assert_eq!(opt.nodes(), bvh.nodes(), "{} boxes", boxes.len());
            assert_eq!(opt.prim_ids(), bvh.prim_ids());
            opt.validate(boxes).expect("valid");
        }
        // Boxes of no area in one plane: still a valid tree. With NaN
        // corners (broken input, which no ray hits): every primitive still
        // in exactly one leaf, as the builders promise for such boxes.
        let planar: Vec<Aabb> = (0..500).map(flat).collect();
        let stacked: Vec<Aabb> = (0..300).map(|i| flat(i % 7)).collect();
        for boxes in [planar.clone(), stacked] {
            let opt = BvhBuilder::BinnedSah.build(&boxes, &config).optimized();
            opt.validate(&boxes).expect("valid");
        }
        let mut broken = planar;
        broken.extend([nan; 20]);
        let opt = BvhBuilder::BinnedSah.build(&broken, &config).optimized();
        let mut ids = opt.prim_ids().to_vec();
        ids.sort_unstable();
        assert!(ids.iter().copied().eq(0..broken.len() as u32));
    }
}
