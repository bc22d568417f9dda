//! Typed `u32` handles for mesh elements, with `u32::MAX` as "none".
//! Half-edges come in twin pairs: `h ^ 1` is the twin, `h >> 1` the edge
//! (as pmp-library does), so neither is stored.

macro_rules! handle {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub u32);

        impl $name {
            /// The handle that names nothing.
            pub const INVALID: Self = Self(u32::MAX);

            /// The handle of index `i`.
            #[inline(always)]
            #[must_use]
            pub const fn new(i: usize) -> Self {
                Self(i as u32)
            }

            /// The index, for indexing arrays.
            #[inline(always)]
            #[must_use]
            pub const fn idx(self) -> usize {
                self.0 as usize
            }

            /// Whether the handle names something.
            #[inline(always)]
            #[must_use]
            pub const fn is_valid(self) -> bool {
                self.0 != u32::MAX
            }
        }
    };
}

handle!(
    /// A vertex.
    Vertex
);
handle!(
    /// A directed half of an edge; its twin is `h ^ 1`.
    HalfEdge
);
handle!(
    /// An undirected edge: half-edges `2e` and `2e + 1`.
    Edge
);
handle!(
    /// A face.
    Face
);

impl HalfEdge {
    /// The opposite half-edge of the same edge.
    #[inline(always)]
    #[must_use]
    pub const fn twin(self) -> Self {
        Self(self.0 ^ 1)
    }

    /// The edge this half-edge belongs to.
    #[inline(always)]
    #[must_use]
    pub const fn edge(self) -> Edge {
        Edge(self.0 >> 1)
    }
}

impl Edge {
    /// Half-edge `i` (0 or 1) of the edge.
    #[inline(always)]
    #[must_use]
    pub const fn halfedge(self, i: u32) -> HalfEdge {
        HalfEdge((self.0 << 1) | (i & 1))
    }
}
