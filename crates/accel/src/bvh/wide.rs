//! A 4-wide BVH collapsed from a binary one: each node holds its four
//! children's boxes as structure-of-arrays (two cache lines), so one node
//! visit tests four boxes in loops the compiler vectorizes, and a ray makes
//! about half as many dependent memory reads as in the binary tree (Wald,
//! Benthin & Boulos, "Getting rid of packets", 2008; Dammertz et al.,
//! "Shallow bounding volume hierarchies", 2008).

use super::{Bvh, STACK_SIZE};
use crate::{AccelStats, Leaf, RayCounter};
use raymesh_geometry::{
    cull_bound, max_nan_second as max_ns, min_nan_second as min_ns, Aabb, Ray, Vec3, ROBUST_EXIT,
};

/// Children per node.
const WIDTH: usize = 4;

/// Four children: boxes by axis and lane, and for each child either a node
/// index (`count == 0`) or a leaf's first primitive slot and count. An
/// empty slot has an empty box (`min = +inf`, `max = -inf`), which no ray hits.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(64))]
pub struct Node4 {
    min: [[f32; WIDTH]; 3],
    max: [[f32; WIDTH]; 3],
    child: [u32; WIDTH],
    count: [u32; WIDTH],
}

const _: () = assert!(std::mem::size_of::<Node4>() == 128);

impl Node4 {
    const EMPTY: Self = Self {
        min: [[f32::INFINITY; WIDTH]; 3],
        max: [[f32::NEG_INFINITY; WIDTH]; 3],
        child: [u32::MAX; WIDTH],
        count: [0; WIDTH],
    };

    fn set_box(&mut self, i: usize, b: Aabb) {
        for a in 0..3 {
            self.min[a][i] = b.min[a];
            self.max[a][i] = b.max[a];
        }
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

/// A 4-wide BVH sharing its binary source's leaves and permutation.
#[derive(Clone, Debug, Default)]
pub struct Bvh4 {
    nodes: Vec<Node4>,
    prim_ids: Vec<u32>,
    bounds: Aabb,
}

impl Bvh4 {
    /// Collapses a binary BVH: each node takes the two children of its
    /// binary node and keeps opening its largest inner child (by surface
    /// area) until it has four.
    #[must_use]
    pub fn from_binary(bin: Bvh) -> Self {
        let nodes2 = bin.nodes();
        let bounds = bin.bounds();
        let mut out = Self {
            nodes: Vec::new(),
            prim_ids: bin.prim_ids,
            bounds,
        };
        if nodes2.is_empty() {
            return out;
        }
        if nodes2[0].is_leaf() {
            let mut n = Node4::EMPTY;
            n.set_box(0, nodes2[0].bounds());
            n.child[0] = nodes2[0].index;
            n.count[0] = nodes2[0].count;
            out.nodes.push(n);
        } else {
            out.collapse(&nodes2, 0);
        }
        out
    }

    fn collapse(&mut self, nodes2: &[super::Node], at: usize) -> u32 {
        let me = self.nodes.len();
        self.nodes.push(Node4::EMPTY);
        let first = nodes2[at].index as usize;
        let mut kids = vec![first, first + 1];
        while kids.len() < WIDTH {
            let open = kids
                .iter()
                .enumerate()
                .filter(|(_, &k)| !nodes2[k].is_leaf())
                .max_by(|a, b| {
                    nodes2[*a.1]
                        .bounds()
                        .half_area()
                        .total_cmp(&nodes2[*b.1].bounds().half_area())
                });
            let Some((i, &k)) = open else { break };
            let c = nodes2[k].index as usize;
            kids[i] = c;
            kids.push(c + 1);
        }
        let mut node = Node4::EMPTY;
        for (i, &k) in kids.iter().enumerate() {
            let n = &nodes2[k];
            node.set_box(i, n.bounds());
            if n.is_leaf() {
                node.child[i] = n.index;
                node.count[i] = n.count;
            } else {
                node.child[i] = self.collapse(nodes2, k);
            }
        }
        self.nodes[me] = node;
        me as u32
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
        let mut stack = if self.nodes.is_empty() {
            vec![]
        } else {
            vec![(0usize, 1usize)]
        };
        while let Some((i, d)) = stack.pop() {
            let n = &self.nodes[i];
            for k in (0..WIDTH).filter(|&k| n.is_used(k)) {
                if n.count[k] > 0 {
                    leaves += 1;
                    depth = depth.max(d);
                    sah += rel(n.child_box(k)) * n.count[k] as f64;
                } else {
                    sah += rel(n.child_box(k));
                    stack.push((n.child[k] as usize, d + 1));
                }
            }
        }
        AccelStats {
            nodes: self.nodes.len(),
            leaves,
            depth,
            bytes: self.nodes.len() * std::mem::size_of::<Node4>() + self.prim_ids.len() * 4,
            sah_cost: sah,
            ..AccelStats::default()
        }
    }

    /// Front-to-back traversal: the children a ray enters are pushed
    /// farthest first, so the nearest comes off the stack next.
    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        if self.nodes.is_empty() {
            return;
        }
        let (o, inv, oct, tmin) = (ray.origin(), ray.inv_dir(), ray.octant(), ray.tmin());
        let mut tmax = ray.tmax();
        // (child, count, entry): count 0 is a node.
        let mut stack = [(0u32, 0u32, 0.0f32); 3 * STACK_SIZE];
        let mut sp = 1usize;
        stack[0] = (0, 0, tmin);
        while sp > 0 {
            sp -= 1;
            let (child, count, entry) = stack[sp];
            if entry > cull_bound(tmax) {
                continue;
            }
            if count > 0 {
                for p in child..child + count {
                    counter.prim();
                    let id = if self.prim_ids.is_empty() {
                        p
                    } else {
                        self.prim_ids[p as usize]
                    };
                    tmax = leaf(id);
                    if tmax < tmin {
                        return;
                    }
                }
                continue;
            }
            counter.node();
            let n = &self.nodes[child as usize];
            let bound = cull_bound(tmax);
            let mut t0 = [0.0f32; WIDTH];
            let mut hit = [false; WIDTH];
            let (mut lo, mut hi) = ([[0.0f32; WIDTH]; 3], [[0.0f32; WIDTH]; 3]);
            for a in 0..3 {
                let neg = oct >> a & 1 != 0;
                let (near, far) = if neg {
                    (&n.max[a], &n.min[a])
                } else {
                    (&n.min[a], &n.max[a])
                };
                for i in 0..WIDTH {
                    lo[a][i] = (near[i] - o[a]) * inv[a];
                    hi[a][i] = (far[i] - o[a]) * inv[a] * ROBUST_EXIT;
                }
            }
            for i in 0..WIDTH {
                // NaN-ignoring max/min: see Aabb::slab.
                let e = max_ns(lo[0][i], max_ns(lo[1][i], max_ns(lo[2][i], tmin)));
                let x = min_ns(hi[0][i], min_ns(hi[1][i], min_ns(hi[2][i], bound)));
                t0[i] = e;
                hit[i] = e <= x;
            }
            // Push entered children, farthest first (insertion by entry, at most 4).
            let base = sp;
            for i in 0..WIDTH {
                if !hit[i] {
                    continue;
                }
                let item = (n.child[i], n.count[i], t0[i]);
                let mut j = sp;
                while j > base && stack[j - 1].2 < item.2 {
                    stack[j] = stack[j - 1];
                    j -= 1;
                }
                stack[j] = item;
                sp += 1;
            }
        }
    }
}
