//! The one factory: a structure chosen by name, behind one enum.

use crate::{
    bvh::{BvhBuilder, Clip},
    AccelStats, BoundedList, BruteForce, Bvh, Bvh4, Bvh8, Grid, KdTree, Leaf, RayCounter,
};
use raymesh_geometry::{Aabb, Ray};
use std::fmt;
use std::str::FromStr;

/// The most primitives for which [`Accel::build_bvh_gathering`] gathers
/// beside the wide collapse: the gathered copy (40 bytes a triangle for
/// [`crate::Triangles`]) then adds at most about 10 MB to the build's peak.
/// `raymesh-peers --peers none`, best of 40 builds, 5 alternations, two
/// threads: the pig 1.558 -> 1.462 ms, the dragon 1.782 -> 1.690 ms,
/// polygon_mesh 2.986 -> 2.859 ms, bunny00 6.905 -> 6.700 ms (medians; one
/// thread unchanged).
pub(crate) const GATHER_BESIDE_MAX: usize = 1 << 18;

/// Which structure to build.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AccelKind {
    /// Every primitive tested in order (the lecture's TriangleMesh loop).
    Brute,
    /// One box around everything, tested first (the lecture's BoundedSurface).
    Aabb,
    /// BVH split at the object median on rotating axes (the lecture's builder).
    BvhMedian,
    /// BVH by binned SAH (Wald 2007).
    BvhBinned,
    /// BVH by full-sweep SAH (MacDonald & Booth 1990).
    BvhSweep,
    /// 4-wide BVH collapsed from the binned SAH tree.
    Bvh4,
    /// 8-wide BVH collapsed from the binned SAH tree, tested with AVX2.
    Bvh8,
    /// Uniform grid with 3D-DDA traversal (Amanatides & Woo 1987).
    Grid,
    /// k-d tree by binned SAH with empty-space cut-off (Wald & Havran 2006).
    KdTree,
}

impl AccelKind {
    /// Every kind, in the order tools list them.
    pub const ALL: [AccelKind; 9] = [
        Self::Brute,
        Self::Aabb,
        Self::BvhMedian,
        Self::BvhBinned,
        Self::BvhSweep,
        Self::Bvh4,
        Self::Bvh8,
        Self::Grid,
        Self::KdTree,
    ];

    /// What `bvh` names: our fastest BVH. The 8-wide tree with AVX2 node
    /// and triangle kernels beat binned SAH's binary tree on 15 of 16
    /// workload × thread × query figures per mesh (bunny00 and
    /// ChineseDragon, `raymesh-peers --size 512 --threads 1,2`, same run),
    /// by 1.1–1.6× (binned SAH stays the fastest to build).
    pub const FASTEST_BVH: AccelKind = Self::Bvh8;

    /// Whether this is a bounding volume hierarchy, which a reinsertion
    /// pass can rearrange ([`BuildConfig::optimize`]; the other kinds
    /// ignore it).
    #[must_use]
    pub fn is_bvh(self) -> bool {
        matches!(
            self,
            Self::BvhMedian | Self::BvhBinned | Self::BvhSweep | Self::Bvh4 | Self::Bvh8
        )
    }

    /// Whether the build takes spatial splits
    /// ([`BuildConfig::spatial_splits`]; the binned SAH builder and the
    /// wide trees collapsed from it; the other kinds ignore them).
    #[must_use]
    pub fn takes_spatial_splits(self) -> bool {
        matches!(self, Self::BvhBinned | Self::Bvh4 | Self::Bvh8)
    }

    /// The name tools use (`--accel NAME`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Brute => "brute",
            Self::Aabb => "aabb",
            Self::BvhMedian => "bvh-median",
            Self::BvhBinned => "bvh-binned",
            Self::BvhSweep => "bvh-sweep",
            Self::Bvh4 => "bvh4",
            Self::Bvh8 => "bvh8",
            Self::Grid => "grid",
            Self::KdTree => "kdtree",
        }
    }
}

impl fmt::Display for AccelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for AccelKind {
    type Err = String;

    /// Parses a name; `bvh` means [`AccelKind::FASTEST_BVH`].
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "bvh" {
            return Ok(Self::FASTEST_BVH);
        }
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|k| k.name()).collect();
                format!(
                    "unknown structure '{s}'; expected bvh, {}",
                    names.join(", ")
                )
            })
    }
}

/// Build settings shared by the structures; each field says what it trades.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildConfig {
    /// Most primitives a BVH or k-d leaf may hold. Larger leaves make
    /// shallower, smaller trees at the price of more primitive tests.
    /// `None` ([`Self::max_leaf_for`]): 8, or two of the leaf's SIMD
    /// blocks ([`Self::leaf_block`]) where that is more, which makes it 16
    /// for the binned and sweep BVHs over triangles: their leaves of 9 to
    /// 16 triangles take two 8-wide block tests, and the fewer levels
    /// traced random and diffuse rays 3-10% faster on the four meshes of
    /// `../shared/meshes` with more than 10,000 triangles, for at most 6%
    /// lost on some coherent ones (docs/measurements.md, *Binary BVH leaves*).
    pub max_leaf: Option<usize>,
    /// Cost of one traversal step relative to one primitive test, for SAH
    /// builders. Higher values make leaves larger.
    pub traversal_cost: f32,
    /// Grid cells per primitive (λ in Cleary & Wyvill's `λ N` rule). More cells
    /// mean fewer tests per cell and more cells stepped through per ray.
    pub grid_density: f32,
    /// The fewest primitives a grid cell lists for it to get a grid of its
    /// own (a two-level grid, [`Grid`]); 0: one level. Lower values split
    /// more cells, for fewer primitives tested a ray where the triangles
    /// crowd together, and more cells stepped through, more memory and a
    /// longer build.
    pub grid_subgrid_min: usize,
    /// How many times the mean of the cells that list anything a cell
    /// must list, too, for a grid of its own. A cell a few times as full
    /// as the others costs a ray a few more tests, which the walk through
    /// a second level costs as well: on 10M triangles of terrain (cells of
    /// 39 triangles on average), the 85,000 cells of 64 or more given
    /// grids of their own traced no faster, for 31% more memory and
    /// builds twice as long; the bunny in a stadium's cells hold
    /// hundreds of times the mean.
    pub grid_subgrid_ratio: f32,
    /// Bins per axis of the binned SAH builders. More bins find better splits
    /// for a slower build.
    pub bins: usize,
    /// Primitives a binary BVH's or k-d tree's leaf tests for the cost of
    /// one. The SAH builders count a leaf's (and a split side's)
    /// primitives in blocks of this many, as Embree's binned builder does
    /// for its SIMD leaves, so that a leaf of up to a block costs one
    /// test. `None`: a `Scene` over primitives whose leaves it tests as
    /// blocks (triangles) picks its SIMD block width for the binned and
    /// sweep BVHs and the k-d tree (whose leaves it stores as runs of
    /// rows, a triangle copied into each leaf it reaches); everything
    /// else counts one by one, including the binary tree a wide BVH is
    /// collapsed from (the collapse weighs blocks itself, and a finer
    /// tree gives it more to choose from).
    pub leaf_block: Option<usize>,
    /// Spatial splits (SBVH, Stich et al. 2009) for the binned SAH BVHs
    /// (`bvh-binned`, `bvh4`, `bvh8`): how many references spatial splits
    /// may add, as a fraction of the primitives (0.25: up to 25% more).
    /// 0, the default, turns them off. They cut the nodes where long or
    /// diagonal primitives make children overlap, for fewer nodes and
    /// primitives tested a ray, at the price of a slower build and the
    /// duplicated references' memory.
    pub spatial_splits: f32,
    /// Reinsertion optimization (Bittner, Hapala & Havran 2013) of the
    /// binary BVH after its build (`bvh-median`, `bvh-binned`,
    /// `bvh-sweep`, and the binary tree `bvh4` and `bvh8` are collapsed
    /// from): subtrees are moved to where they lower the SAH cost. Off by
    /// default: it pays on trees a top-down build left poor (the median
    /// split's: half the nodes a ray on the teapot in a stadium), hardly
    /// on the binned SAH trees of scanned meshes (under 0.3% in SAH), for
    /// 1.2-2.3 times the build there and up to 10 times on meshes of
    /// long overlapping slivers (docs/measurements.md, *Reinsertion*).
    pub optimize: bool,
}

impl Default for BuildConfig {
    fn default() -> Self {
        Self {
            max_leaf: None,
            traversal_cost: 3.0,
            // 2, not 3: with a cell's triangles tested together, 2 traced
            // as fast on bunny00, the dragon and a 2M-triangle sphere (±5%,
            // every workload) with 5-7 bytes a triangle less; 1 lost 6% on
            // bunny00's diffuse rays (`raycast --accel grid --stats`).
            grid_density: 2.0,
            grid_subgrid_min: 64,
            grid_subgrid_ratio: 4.0,
            bins: 32,
            leaf_block: None,
            spatial_splits: 0.0,
            optimize: false,
        }
    }
}

impl BuildConfig {
    /// [`Self::max_leaf`] resolved for leaves tested in blocks of `block`
    /// primitives: as given, or 8, or two blocks where that is more.
    #[must_use]
    pub fn max_leaf_for(&self, block: usize) -> usize {
        self.max_leaf.unwrap_or(8.max(2 * block))
    }
}

/// A built acceleration structure.
#[derive(Clone, Debug)]
pub enum Accel {
    /// See [`BruteForce`].
    Brute(BruteForce),
    /// See [`BoundedList`].
    Aabb(BoundedList),
    /// See [`Bvh`]; the kind says which builder made it.
    Bvh(Bvh, AccelKind),
    /// See [`Bvh4`].
    Bvh4(Bvh4),
    /// See [`Bvh8`].
    Bvh8(Bvh8),
    /// See [`Grid`].
    Grid(Grid),
    /// See [`KdTree`].
    KdTree(KdTree),
}

impl Accel {
    /// Builds the structure of the given kind over primitives' boxes.
    /// Spatial splits, if `config` asks for them, cut the boxes themselves
    /// ([`Aabb::split`]).
    #[must_use]
    pub fn build(kind: AccelKind, boxes: &[Aabb], config: &BuildConfig) -> Self {
        let bounds = |i: u32| boxes[i as usize];
        if let Some(bvh) = Self::build_bvh_by(kind, boxes.len(), &bounds, config) {
            return bvh;
        }
        match kind {
            AccelKind::Brute => Self::Brute(BruteForce::new(boxes)),
            AccelKind::Aabb => Self::Aabb(BoundedList::new(boxes)),
            AccelKind::Grid => Self::Grid(Grid::build(boxes, config)),
            AccelKind::KdTree => Self::KdTree(KdTree::build(boxes, config)),
            _ => unreachable!("{kind} is a BVH"),
        }
    }

    /// For the BVH kinds, [`Self::build`] over `n` primitives whose boxes
    /// `bounds(i)` gives, with no array of boxes in between (24 bytes a
    /// primitive less at the peak); `None` for the other kinds.
    #[must_use]
    pub fn build_bvh_by(
        kind: AccelKind,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        config: &BuildConfig,
    ) -> Option<Self> {
        let clip = |i: u32, within: Aabb, axis: usize, pos: f32| {
            let _ = i;
            within.split(axis, pos)
        };
        Self::build_bvh_clipped(kind, n, bounds, &clip, config)
    }

    /// [`Self::build_bvh_by`], with `clip` cutting primitives at the
    /// planes of spatial splits when `config` asks for them (see
    /// [`BuildConfig::spatial_splits`] and [`Clip`]).
    #[must_use]
    pub fn build_bvh_clipped(
        kind: AccelKind,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        clip: &Clip<'_>,
        config: &BuildConfig,
    ) -> Option<Self> {
        let opt = |bvh: Bvh| {
            if config.optimize {
                bvh.optimized()
            } else {
                bvh
            }
        };
        let binned = || binned_tree(n, bounds, clip, config);
        Some(match kind {
            AccelKind::BvhMedian => {
                Self::Bvh(opt(BvhBuilder::Median.build_by(n, bounds, config)), kind)
            }
            AccelKind::BvhBinned => Self::Bvh(binned(), kind),
            AccelKind::BvhSweep => {
                Self::Bvh(opt(BvhBuilder::SweepSah.build_by(n, bounds, config)), kind)
            }
            AccelKind::Bvh4 => Self::Bvh4(Bvh4::from_binary(binned())),
            AccelKind::Bvh8 => Self::Bvh8(Bvh8::from_binary(binned())),
            _ => return None,
        })
    }

    /// [`Self::build_bvh_clipped`], then `gather(order)` on the leaf order
    /// of the structure built, which is returned beside it; the structure
    /// keeps no leaf order (`gather` had it).
    ///
    /// For the wide BVHs over at most [`GATHER_BESIDE_MAX`] primitives,
    /// `gather` runs beside the collapse of the binary tree into wide
    /// nodes (the leaf order is the binary tree's): on meshes of tens of
    /// thousands of triangles each is a parallel phase of a few hundred
    /// microseconds, too short for two threads to share well, and each
    /// waited for the other. Larger meshes gather after the collapse, when
    /// the binary tree is gone, so that what `gather` makes never lies in
    /// memory beside it (the builds' peak).
    pub(crate) fn build_bvh_gathering<T: Send>(
        kind: AccelKind,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        clip: &Clip<'_>,
        config: &BuildConfig,
        gather: impl FnOnce(&[u32]) -> T + Send,
    ) -> Option<(Self, T)> {
        let beside = n <= GATHER_BESIDE_MAX;
        Self::build_gathering(kind, n, bounds, clip, config, beside, gather)
    }

    /// [`Self::build_bvh_gathering`], gathering beside the wide collapse
    /// where `beside`, whatever the size.
    fn build_gathering<T: Send>(
        kind: AccelKind,
        n: usize,
        bounds: &(dyn Fn(u32) -> Aabb + Sync),
        clip: &Clip<'_>,
        config: &BuildConfig,
        beside: bool,
        gather: impl FnOnce(&[u32]) -> T + Send,
    ) -> Option<(Self, T)> {
        if beside && matches!(kind, AccelKind::Bvh4 | AccelKind::Bvh8) {
            let mut bin = binned_tree(n, bounds, clip, config);
            let order = bin.take_prim_ids();
            let collapse = || match kind {
                AccelKind::Bvh4 => Self::Bvh4(Bvh4::from_binary(bin)),
                _ => Self::Bvh8(Bvh8::from_binary(bin)),
            };
            return Some(rayon::join(collapse, || gather(&order)));
        }
        let mut accel = Self::build_bvh_clipped(kind, n, bounds, clip, config)?;
        let order = accel.take_leaf_order().expect("a BVH has a leaf order");
        let t = gather(&order);
        Some((accel, t))
    }

    /// Which kind this is.
    #[must_use]
    pub fn kind(&self) -> AccelKind {
        match self {
            Self::Brute(_) => AccelKind::Brute,
            Self::Aabb(_) => AccelKind::Aabb,
            Self::Bvh(_, k) => *k,
            Self::Bvh4(_) => AccelKind::Bvh4,
            Self::Bvh8(_) => AccelKind::Bvh8,
            Self::Grid(_) => AccelKind::Grid,
            Self::KdTree(_) => AccelKind::KdTree,
        }
    }

    /// Bounds of everything the structure holds.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        match self {
            Self::Brute(b) => b.bounds(),
            Self::Aabb(b) => b.bounds(),
            Self::Bvh(b, _) => b.bounds(),
            Self::Bvh4(b) => b.bounds(),
            Self::Bvh8(b) => b.bounds(),
            Self::Grid(g) => g.bounds(),
            Self::KdTree(k) => k.bounds(),
        }
    }

    /// Size figures (build time left zero: [`crate::Scene`] measures it).
    #[must_use]
    pub fn stats(&self) -> AccelStats {
        let mut s = match self {
            Self::Brute(b) => b.stats(),
            Self::Aabb(b) => b.stats(),
            Self::Bvh(b, _) => b.stats(),
            Self::Bvh4(b) => b.stats(),
            Self::Bvh8(b) => b.stats(),
            Self::Grid(g) => g.stats(),
            Self::KdTree(k) => k.stats(),
        };
        s.name = self.kind().name();
        s
    }

    /// A BVH's primitive permutation (leaf slot → primitive), or a k-d
    /// tree's references leaf after leaf (a primitive in several leaves
    /// several times), which an owner may store its primitives by; `None`
    /// for other structures, and for a k-d tree whose order was taken.
    pub(crate) fn leaf_order(&self) -> Option<&[u32]> {
        match self {
            Self::Bvh(b, _) => Some(b.prim_ids()),
            Self::Bvh4(b) => Some(b.prim_ids()),
            Self::Bvh8(b) => Some(b.prim_ids()),
            Self::KdTree(k) => k.leaf_order(),
            _ => None,
        }
    }

    /// Hands over [`Self::leaf_order`] once the owner has reordered its
    /// primitives by it: from then on leaves name primitives by slot.
    pub(crate) fn take_leaf_order(&mut self) -> Option<Vec<u32>> {
        match self {
            Self::Bvh(b, _) => Some(b.take_prim_ids()),
            Self::Bvh4(b) => Some(b.take_prim_ids()),
            Self::Bvh8(b) => Some(b.take_prim_ids()),
            Self::KdTree(k) => Some(k.take_leaf_order()),
            _ => None,
        }
    }

    /// For the structures whose leaves are lists of primitive indices
    /// (the k-d tree, unless its leaves name slots, and the grid): calls
    /// `list` with each list of candidate primitives front to back, as
    /// far as the bound it returns lets the traversal go, and returns
    /// `true`. Calls nothing and returns `false` for the others.
    #[inline]
    pub(crate) fn traverse_lists<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        list: &mut impl FnMut(&[u32]) -> f32,
    ) -> bool {
        match self {
            Self::Grid(g) if ray.is_valid() => g.traverse_lists(ray, counter, list),
            Self::KdTree(k) if k.names_slots() => return false,
            Self::KdTree(k) if ray.is_valid() => k.traverse_lists(ray, counter, list),
            Self::Grid(_) | Self::KdTree(_) => {}
            _ => return false,
        }
        true
    }

    /// For each ray of `rays`, the primitives [`Self::traverse`] reaches
    /// with a leaf that never lowers its bound, as bits: from the root
    /// alone where a wide BVH answers so ([`crate::bvh::WideBvh::root_leaves_each`]),
    /// else `fallback(ray)` (other structures and deeper walks).
    pub(crate) fn root_leaves_each(
        &self,
        rays: &[Ray],
        fallback: impl Fn(&Ray) -> u64,
    ) -> Vec<u64> {
        match self {
            Self::Bvh4(b) => b.root_leaves_each(rays, fallback),
            Self::Bvh8(b) => b.root_leaves_each(rays, fallback),
            _ => rays.iter().map(fallback).collect(),
        }
    }

    /// Calls `leaf` for candidate primitives front to back, as far as the
    /// bound it returns lets the traversal go.
    #[inline]
    pub(crate) fn traverse<C: RayCounter>(&self, ray: &Ray, counter: &mut C, leaf: &mut impl Leaf) {
        if !ray.is_valid() {
            return;
        }
        match self {
            Self::Brute(b) => b.traverse(ray, counter, leaf),
            Self::Aabb(b) => b.traverse(ray, counter, leaf),
            Self::Bvh(b, _) => b.traverse(ray, counter, leaf),
            Self::Bvh4(b) => b.traverse(ray, counter, leaf),
            Self::Bvh8(b) => b.traverse(ray, counter, leaf),
            Self::Grid(g) => g.traverse(ray, counter, leaf),
            Self::KdTree(k) => k.traverse(ray, counter, leaf),
        }
    }
}

/// The binary tree that [`AccelKind::BvhBinned`] is and the wide BVHs
/// collapse: binned SAH (with spatial splits where `config` asks), then
/// reinsertion where it asks for that.
fn binned_tree(
    n: usize,
    bounds: &(dyn Fn(u32) -> Aabb + Sync),
    clip: &Clip<'_>,
    config: &BuildConfig,
) -> Bvh {
    let bvh = BvhBuilder::BinnedSah.build_spatial(n, bounds, clip, config);
    if config.optimize {
        bvh.optimized()
    } else {
        bvh
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use raymesh_geometry::Vec3;

    /// Where a wide BVH answers from its root, it names the primitives the
    /// walk reaches (and the fallback, the walk here, answers the rest),
    /// on trees of 1 to 70 boxes (one level deep or more; ids past 63),
    /// for rays from outside and inside, axis-parallel,
    /// grazing, with `tmax` short of the boxes, and invalid.
    #[test]
    fn root_leaves_are_what_the_walk_reaches() {
        let mut next = crate::test_util::xorshift(0x1357_9bdf);
        let (mut answered, mut deeper) = (0, 0);
        for n in [1usize, 2, 3, 5, 8, 9, 16, 40, 66, 70] {
            let boxes: Vec<Aabb> = (0..n)
                .map(|i| {
                    let mut p = Vec3::new(next(), next(), next()) * 6.0 - 3.0;
                    if n == 66 {
                        // Ids past 63 apart from the rest, so that a leaf
                        // of the root may hold them.
                        p.x = if i >= 64 {
                            p.x * 0.1 - 3.0
                        } else {
                            p.x * 0.5 + 2.0
                        };
                    }
                    // Flat boxes too, and one spanning the rest (a floor).
                    let e = if i == 0 {
                        Vec3::new(12.0, 0.0, 12.0)
                    } else {
                        Vec3::new(next(), next(), next())
                    };
                    Aabb::new(p - e * 0.5, p + e * 0.5)
                })
                .collect();
            // Large leaves too, so that more roots have only leaves.
            let configs = [
                BuildConfig::default(),
                BuildConfig {
                    max_leaf: Some(80),
                    traversal_cost: 1000.0,
                    ..BuildConfig::default()
                },
            ];
            for (kind, config) in [AccelKind::Bvh8, AccelKind::Bvh4]
                .into_iter()
                .flat_map(|k| configs.iter().map(move |c| (k, c)))
            {
                let top = Accel::build(kind, &boxes, config);
                let mut rays = Vec::new();
                for i in 0..400 {
                    let o = Vec3::new(next(), next(), next()) * 16.0 - 8.0;
                    let d = match i % 5 {
                        0 => Vec3::Y * (next() - 0.5),
                        1 => Vec3::new(next() - 0.5, 1e-7, next() - 0.5),
                        _ => Vec3::new(next(), next(), next()) - 0.5,
                    };
                    let tmax = if i % 7 == 0 { next() } else { f32::INFINITY };
                    let ray = if i % 53 == 0 {
                        Ray::new(Vec3::NAN, d, 0.0, tmax)
                    } else {
                        Ray::new(o, d, 0.0, tmax)
                    };
                    rays.push(ray);
                }
                let walk = |ray: &Ray| {
                    let mut walked = 0u64;
                    top.traverse(ray, &mut crate::NoStats, &mut |k| {
                        // An id past 63 sets every bit: no answer from the
                        // root may leave it out.
                        walked |= 1u64.checked_shl(k).unwrap_or(u64::MAX);
                        ray.tmax()
                    });
                    walked
                };
                let fell_back = std::cell::Cell::new(0);
                let masks = top.root_leaves_each(&rays, |r| {
                    fell_back.set(fell_back.get() + 1);
                    walk(r)
                });
                for (ray, m) in rays.iter().zip(masks) {
                    assert_eq!(m, walk(ray), "{kind} over {n}: {ray:?}");
                }
                answered += rays.len() - fell_back.get();
                deeper += fell_back.get();
            }
        }
        assert!(
            answered > 2000 && deeper > 100,
            "{answered} answered, {deeper} deeper"
        );
    }

    /// Gathering beside the collapse or after it gives the same structure,
    /// bit for bit, and hands `gather` the same leaf order, for every
    /// structure the gathering build makes (the wide BVHs, with and without
    /// spatial splits, and the others, which always gather after).
    #[test]
    fn gathering_beside_the_collapse_changes_nothing() {
        // Boxes of a scattered, overlapping set of slivers and cubes.
        let boxes: Vec<Aabb> = (0..3000u32)
            .map(|i| {
                let h =
                    |k: u32| (i.wrapping_mul(2_654_435_761).rotate_left(k) % 1000) as f32 / 100.0;
                let lo = Vec3::new(h(0), h(7), h(13));
                Aabb::new(
                    lo,
                    lo + Vec3::new(h(19) / 40.0, h(23) / 400.0, h(29) / 20.0),
                )
            })
            .collect();
        let bounds = |i: u32| boxes[i as usize];
        let clip = |i: u32, within: Aabb, axis: usize, pos: f32| {
            let _ = i;
            within.split(axis, pos)
        };
        let split = BuildConfig {
            spatial_splits: 0.25,
            ..BuildConfig::default()
        };
        for config in [BuildConfig::default(), split] {
            for kind in [
                AccelKind::Bvh8,
                AccelKind::Bvh4,
                AccelKind::BvhBinned,
                AccelKind::Grid,
            ] {
                let run = |beside| {
                    let gather = |order: &[u32]| order.to_vec();
                    Accel::build_gathering(
                        kind,
                        boxes.len(),
                        &bounds,
                        &clip,
                        &config,
                        beside,
                        gather,
                    )
                    .map(|(accel, order)| (format!("{accel:?}"), order))
                };
                let (a, b) = (run(true), run(false));
                assert_eq!(a.is_some(), kind != AccelKind::Grid, "{kind}");
                if let (Some((a, ao)), Some((b, bo))) = (a, b) {
                    assert!(ao.len() >= boxes.len(), "{kind}");
                    assert_eq!(ao, bo, "{kind}");
                    assert_eq!(a, b, "{kind}");
                }
            }
        }
    }
}
