//! BVH builders: the lecture's median split, binned SAH and full-sweep SAH.
//! They share one top-down recursion and differ only in how a node's
//! primitives are split.

use super::{Bvh, Node, NodePair};
use crate::BuildConfig;
use raymesh_geometry::{Aabb, Vec3};

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
    /// every axis is a candidate. Best trees, O(N log N) per level.
    SweepSah,
}

struct Ctx<'a> {
    boxes: &'a [Aabb],
    centroids: Vec<Vec3>,
    config: &'a BuildConfig,
    builder: BvhBuilder,
    nodes: Vec<Node>,
    /// Scratch bins of the binned builder, `MAX_BINS` per axis, reused by every node.
    bins: Vec<(Aabb, u32)>,
}

impl BvhBuilder {
    /// Builds a BVH over primitive boxes; primitive `i` has box `boxes[i]`.
    #[must_use]
    pub fn build(self, boxes: &[Aabb], config: &BuildConfig) -> Bvh {
        let n = boxes.len();
        if n == 0 {
            return Bvh::default();
        }
        assert!(n < u32::MAX as usize, "too many primitives for u32 indices");
        let mut ids: Vec<u32> = (0..n as u32).collect();
        let mut ctx = Ctx {
            boxes,
            centroids: boxes.iter().map(Aabb::centroid).collect(),
            config,
            builder: self,
            nodes: Vec::with_capacity(2 * n / config.max_leaf.max(1) + 2),
            bins: vec![(Aabb::EMPTY, 0); 3 * MAX_BINS],
        };
        // The root, and its unused sibling: every later pair then starts at
        // an even index, i.e. in its own cache line.
        ctx.nodes.push(Node::new(Aabb::EMPTY));
        ctx.nodes.push(Node::new(Aabb::EMPTY));
        let (bounds, cbounds) = ctx.bounds_pair(&ids);
        ctx.build(0, &mut ids, 0, 1, bounds, cbounds);
        let pairs = ctx
            .nodes
            .chunks_exact(2)
            .map(|c| NodePair([c[0], c[1]]))
            .collect();
        Bvh {
            pairs,
            prim_ids: ids,
        }
    }
}

impl Ctx<'_> {
    /// Boxes of the primitives and of their centroids, in one pass.
    fn bounds_pair(&self, ids: &[u32]) -> (Aabb, Aabb) {
        ids.iter().fold((Aabb::EMPTY, Aabb::EMPTY), |(b, c), &i| {
            (
                b.union(self.boxes[i as usize]),
                c.grow(self.centroids[i as usize]),
            )
        })
    }

    /// Builds node `node` over `ids`, which start at `offset` in the
    /// permutation; `bounds` and `cbounds` are the boxes of the primitives
    /// and of their centroids.
    fn build(
        &mut self,
        node: usize,
        ids: &mut [u32],
        offset: u32,
        depth: usize,
        bounds: Aabb,
        cbounds: Aabb,
    ) {
        self.nodes[node] = Node::new(bounds);
        let split = if ids.len() <= 1 {
            None
        } else if depth >= SAH_DEPTH_LIMIT {
            Some(self.split_by_count(ids, cbounds))
        } else {
            match self.builder {
                BvhBuilder::Median => {
                    (ids.len() > MEDIAN_LEAF).then(|| self.split_median(ids, (depth - 1) % 3))
                }
                BvhBuilder::BinnedSah => self.split_binned(ids, bounds, cbounds),
                BvhBuilder::SweepSah => self.split_sweep(ids, bounds, cbounds),
            }
        };
        match split {
            None => {
                let n = &mut self.nodes[node];
                n.index = offset;
                n.count = ids.len() as u32;
            }
            Some(mid) => {
                let first = self.nodes.len();
                self.nodes[node].index = first as u32;
                self.nodes.push(Node::new(Aabb::EMPTY));
                self.nodes.push(Node::new(Aabb::EMPTY));
                let (left, right) = ids.split_at_mut(mid);
                let (lb, lc) = self.bounds_pair(left);
                let (rb, rc) = self.bounds_pair(right);
                self.build(first, left, offset, depth + 1, lb, lc);
                self.build(first + 1, right, offset + mid as u32, depth + 1, rb, rc);
            }
        }
    }

    /// Puts the lower half of centroids on `axis` first; returns the middle.
    fn split_median(&self, ids: &mut [u32], axis: usize) -> usize {
        let mid = ids.len() / 2;
        let c = &self.centroids;
        ids.select_nth_unstable_by(mid, |&a, &b| {
            c[a as usize][axis].total_cmp(&c[b as usize][axis])
        });
        mid
    }

    /// Median split on the longest centroid axis: the fallback that always
    /// makes progress.
    fn split_by_count(&self, ids: &mut [u32], cbounds: Aabb) -> usize {
        self.split_median(ids, cbounds.longest_axis())
    }

    /// Leaf or split, given the best split's SAH cost (relative to the node's area).
    fn decide(
        &self,
        ids: &mut [u32],
        cbounds: Aabb,
        best: Option<(f32, usize)>,
        area: f32,
        apply: impl FnOnce(&mut [u32]) -> usize,
    ) -> Option<usize> {
        let n = ids.len();
        let leaf_cost = n as f32;
        match best {
            Some((cost, _)) if area > 0.0 => {
                let split_cost = self.config.traversal_cost + cost / area;
                if split_cost < leaf_cost || n > self.config.max_leaf {
                    Some(apply(ids))
                } else {
                    None
                }
            }
            _ if n > self.config.max_leaf => Some(self.split_by_count(ids, cbounds)),
            _ => None,
        }
    }

    /// Binned SAH: one pass bins the centroids on all three axes at once,
    /// then the cheapest bin boundary wins.
    fn split_binned(&mut self, ids: &mut [u32], bounds: Aabb, cb: Aabb) -> Option<usize> {
        // Small nodes need few bins: twice their size is plenty.
        let nb = self.config.bins.min(2 * ids.len()).clamp(2, MAX_BINS);
        let ext = cb.extent();
        let scale = Vec3::select(
            ext.cmpgt(Vec3::ZERO),
            Vec3::splat(nb as f32) / ext,
            Vec3::ZERO,
        );
        let mut bins = std::mem::take(&mut self.bins);
        for axis in 0..3 {
            bins[axis * MAX_BINS..axis * MAX_BINS + nb].fill((Aabb::EMPTY, 0));
        }
        for &i in ids.iter() {
            let b = self.boxes[i as usize];
            let k = bin3(self.centroids[i as usize], cb.min, scale, nb);
            for axis in 0..3 {
                let bin = &mut bins[axis * MAX_BINS + k[axis]];
                bin.0 = bin.0.union(b);
                bin.1 += 1;
            }
        }
        // (cost, axis, first bin of the right side)
        let mut best: Option<(f32, usize, usize)> = None;
        let mut right_area = [0.0f32; MAX_BINS];
        for axis in 0..3 {
            if !(ext[axis] > 0.0) {
                continue;
            }
            let bins = &bins[axis * MAX_BINS..(axis + 1) * MAX_BINS];
            let mut acc = Aabb::EMPTY;
            for b in (1..nb).rev() {
                acc = acc.union(bins[b].0);
                right_area[b] = acc.half_area();
            }
            let (mut lbox, mut lcount) = (Aabb::EMPTY, 0u32);
            let mut rcount = ids.len() as u32;
            for b in 1..nb {
                lbox = lbox.union(bins[b - 1].0);
                lcount += bins[b - 1].1;
                rcount -= bins[b - 1].1;
                if lcount == 0 || rcount == 0 {
                    continue;
                }
                let cost = lbox.half_area() * lcount as f32 + right_area[b] * rcount as f32;
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, b));
                }
            }
        }
        self.bins = bins;
        let centroids = &self.centroids;
        self.decide(
            ids,
            cb,
            best.map(|(c, a, _)| (c, a)),
            bounds.half_area(),
            |ids| {
                let (_, axis, boundary) = best.expect("a split was found");
                partition(ids, |&i| {
                    bin3(centroids[i as usize], cb.min, scale, nb)[axis] < boundary
                })
            },
        )
    }

    fn split_sweep(&self, ids: &mut [u32], bounds: Aabb, cbounds: Aabb) -> Option<usize> {
        let n = ids.len();
        let c = &self.centroids;
        let mut best: Option<(f32, usize, usize)> = None;
        let mut sorted = ids.to_vec();
        let mut right_area = vec![0.0f32; n];
        for axis in 0..3 {
            sorted.sort_unstable_by(|&a, &b| {
                c[a as usize][axis]
                    .total_cmp(&c[b as usize][axis])
                    .then(a.cmp(&b))
            });
            let mut acc = Aabb::EMPTY;
            for k in (1..n).rev() {
                acc = acc.union(self.boxes[sorted[k] as usize]);
                right_area[k] = acc.half_area();
            }
            let mut lbox = Aabb::EMPTY;
            for k in 1..n {
                lbox = lbox.union(self.boxes[sorted[k - 1] as usize]);
                let cost = lbox.half_area() * k as f32 + right_area[k] * (n - k) as f32;
                if best.is_none_or(|(bc, _, _)| cost < bc) {
                    best = Some((cost, axis, k));
                }
            }
        }
        let area = bounds.half_area();
        self.decide(
            ids,
            cbounds,
            best.map(|(cst, a, _)| (cst, a)),
            area,
            |ids| {
                let (_, axis, k) = best.expect("a split was found");
                ids.sort_unstable_by(|&a, &b| {
                    c[a as usize][axis]
                        .total_cmp(&c[b as usize][axis])
                        .then(a.cmp(&b))
                });
                k
            },
        )
    }
}

/// Most bins per axis of the binned builder.
const MAX_BINS: usize = 64;

/// Bin of a centroid on each axis (`as` saturates, so NaN lands in bin 0).
#[inline(always)]
fn bin3(c: Vec3, min: Vec3, scale: Vec3, nb: usize) -> [usize; 3] {
    let f = (c - min) * scale;
    [
        (f.x as usize).min(nb - 1),
        (f.y as usize).min(nb - 1),
        (f.z as usize).min(nb - 1),
    ]
}

/// Moves the elements satisfying `pred` to the front; returns how many there are.
fn partition(ids: &mut [u32], pred: impl Fn(&u32) -> bool) -> usize {
    let mut k = 0;
    for i in 0..ids.len() {
        if pred(&ids[i]) {
            ids.swap(i, k);
            k += 1;
        }
    }
    k
}
