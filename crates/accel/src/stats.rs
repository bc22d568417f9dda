//! Statistics: per structure (what it costs to keep) and per ray (what it
//! cost to trace), the latter compiled away when not asked for.

/// Figures of a built structure.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AccelStats {
    /// Structure name, as [`crate::AccelKind`] spells it.
    pub name: &'static str,
    /// Build time in milliseconds.
    pub build_ms: f64,
    /// Nodes (BVH and k-d tree), cells (grid), 1 for a bounded list, 0 for brute force.
    pub nodes: usize,
    /// Leaves (or non-empty cells).
    pub leaves: usize,
    /// Longest root-to-leaf path (1 for a flat structure).
    pub depth: usize,
    /// Bytes the structure occupies, the primitives' own buffers apart.
    pub bytes: usize,
    /// Surface area heuristic cost with unit traversal and intersection
    /// costs (MacDonald & Booth 1990): the expected work of a random ray
    /// that hits the root box, in primitive tests.
    pub sah_cost: f64,
    /// Node tests a random ray that hits the root box is expected to make,
    /// by the same area ratios as [`Self::sah_cost`]: one for each node it
    /// enters (a wide node's children tested at once; a binary node's
    /// pair of children). `None` for structures other than BVHs.
    pub node_tests: Option<f64>,
    /// Leaf tests such a ray is expected to make: each leaf it enters
    /// counted in blocks of up to [`crate::BLOCK`] primitives, as
    /// triangles are tested ([`crate::Primitives::intersect_block`]), or
    /// one primitive at a time for primitives that have no block test.
    /// With [`Self::node_tests`], the SAH that Embree's builder minimizes
    /// (unit costs, leaves in blocks), for comparing trees whose leaves
    /// are tested in blocks of different widths, where `sah_cost` counts
    /// every primitive. `None` for structures other than BVHs.
    pub leaf_tests: Option<f64>,
}

/// Counts what one ray costs. Traversals are generic over it, so that
/// [`NoStats`] compiles to nothing on the normal path.
pub trait RayCounter {
    /// One node (or grid cell) visited.
    fn node(&mut self);
    /// One primitive tested.
    fn prim(&mut self);
}

/// Counts nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoStats;

impl RayCounter for NoStats {
    #[inline(always)]
    fn node(&mut self) {}
    #[inline(always)]
    fn prim(&mut self) {}
}

/// Counts nodes visited and primitives tested.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CountStats {
    /// Nodes (or cells) visited.
    pub nodes: u64,
    /// Primitives tested.
    pub prims: u64,
}

impl RayCounter for CountStats {
    #[inline(always)]
    fn node(&mut self) {
        self.nodes += 1;
    }
    #[inline(always)]
    fn prim(&mut self) {
        self.prims += 1;
    }
}
