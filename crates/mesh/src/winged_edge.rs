//! The winged-edge mesh exactly as the lecture draws it: per edge its head
//! and tail vertices, left and right faces, and the previous and next edges
//! on each side; one edge per vertex and per face (Baumgart 1975).

use crate::handle::{Edge, Face, Vertex};
use crate::HalfEdgeMesh;
use raymesh_geometry::Vec3;

/// One edge, oriented tail → head; `left` is the face on its left (the one
/// whose boundary runs tail → head), `right` the other (none on a boundary).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WingedEdge {
    /// Vertex the edge points to.
    pub head: Vertex,
    /// Vertex the edge starts from.
    pub tail: Vertex,
    /// Face on the left.
    pub left: Face,
    /// Face on the right.
    pub right: Face,
    /// Previous edge around the left face.
    pub lprev: Edge,
    /// Next edge around the left face.
    pub lnext: Edge,
    /// Previous edge around the right face.
    pub rprev: Edge,
    /// Next edge around the right face.
    pub rnext: Edge,
}

/// A winged-edge mesh: 32 bytes per edge, one edge per vertex and face.
#[derive(Clone, Debug, Default)]
pub struct WingedEdgeMesh {
    positions: Vec<Vec3>,
    edges: Vec<WingedEdge>,
    v_edge: Vec<Edge>,
    f_edge: Vec<Edge>,
}

impl WingedEdgeMesh {
    /// The winged-edge form of a half-edge mesh (same vertex, edge and face numbers).
    #[must_use]
    pub fn from_half_edge(m: &HalfEdgeMesh) -> Self {
        let edges = m
            .edges()
            .map(|e| {
                let (h0, h1) = (e.halfedge(0), e.halfedge(1));
                WingedEdge {
                    head: m.to_vertex(h0),
                    tail: m.to_vertex(h1),
                    left: m.face(h0),
                    right: m.face(h1),
                    lprev: m.prev_halfedge(h0).edge(),
                    lnext: m.next_halfedge(h0).edge(),
                    rprev: m.prev_halfedge(h1).edge(),
                    rnext: m.next_halfedge(h1).edge(),
                }
            })
            .collect();
        let v_edge = m
            .vertices()
            .map(|v| {
                let h = m.vertex_halfedge(v);
                if h.is_valid() {
                    h.edge()
                } else {
                    Edge::INVALID
                }
            })
            .collect();
        let f_edge = m.faces().map(|f| m.face_halfedge(f).edge()).collect();
        Self {
            positions: m.positions().to_vec(),
            edges,
            v_edge,
            f_edge,
        }
    }

    /// An edge's record.
    #[inline(always)]
    #[must_use]
    pub fn edge(&self, e: Edge) -> &WingedEdge {
        &self.edges[e.idx()]
    }

    /// Number of edges.
    #[must_use]
    pub fn num_edges(&self) -> usize {
        self.edges.len()
    }

    /// Position of a vertex.
    #[must_use]
    pub fn position(&self, v: Vertex) -> Vec3 {
        self.positions[v.idx()]
    }

    /// The lecture's EdgesOfVertex: from the vertex's edge, step to `lprev`
    /// when the vertex is the edge's tail and to `rprev` when it is its
    /// head, until the first edge comes round (counter-clockwise).
    pub fn edges_of_vertex(&self, v: Vertex) -> impl Iterator<Item = Edge> + '_ {
        self.cycle(self.v_edge[v.idx()], move |w| {
            if w.tail == v {
                w.lprev
            } else {
                w.rprev
            }
        })
    }

    /// Neighbouring vertices, in the order of [`Self::edges_of_vertex`].
    pub fn vertices_of_vertex(&self, v: Vertex) -> impl Iterator<Item = Vertex> + '_ {
        self.edges_of_vertex(v).map(move |e| {
            let w = self.edge(e);
            if w.tail == v {
                w.head
            } else {
                w.tail
            }
        })
    }

    /// Edges of a face in its winding order: `lnext` where the face is on
    /// the edge's left, `rnext` where it is on its right.
    pub fn edges_of_face(&self, f: Face) -> impl Iterator<Item = Edge> + '_ {
        self.cycle(self.f_edge[f.idx()], move |w| {
            if w.left == f {
                w.lnext
            } else {
                w.rnext
            }
        })
    }

    /// Edges from `start`, stepping by `step` until `start` comes round.
    fn cycle<'a>(
        &'a self,
        start: Edge,
        step: impl Fn(&WingedEdge) -> Edge + 'a,
    ) -> impl Iterator<Item = Edge> + 'a {
        let mut cur = start;
        std::iter::from_fn(move || {
            if !cur.is_valid() {
                return None;
            }
            let e = cur;
            let n = step(self.edge(e));
            cur = if n == start { Edge::INVALID } else { n };
            Some(e)
        })
    }

    /// Vertices of a face in its winding order (each edge's start as the face sees it).
    pub fn vertices_of_face(&self, f: Face) -> impl Iterator<Item = Vertex> + '_ {
        self.edges_of_face(f).map(move |e| {
            let w = self.edge(e);
            if w.left == f {
                w.tail
            } else {
                w.head
            }
        })
    }

    /// Faces across the edges of a face (boundary edges skipped).
    pub fn faces_of_face(&self, f: Face) -> impl Iterator<Item = Face> + '_ {
        self.edges_of_face(f)
            .map(move |e| {
                let w = self.edge(e);
                if w.left == f {
                    w.right
                } else {
                    w.left
                }
            })
            .filter(|g| g.is_valid())
    }

    /// The indexed polygon mesh with the same vertices and faces.
    #[must_use]
    pub fn to_indexed(&self) -> crate::IndexedMesh {
        let mut out = crate::IndexedMesh::with_capacity(
            self.positions.len(),
            self.f_edge.len(),
            2 * self.edges.len(),
        );
        out.positions = self.positions.clone();
        let mut face = Vec::new();
        for f in 0..self.f_edge.len() {
            face.clear();
            face.extend(self.vertices_of_face(Face::new(f)).map(|v| v.0));
            out.push_face_unchecked(&face);
        }
        out
    }

    /// Bytes of the structure's arrays (positions included).
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        self.positions.len() * 12
            + self.edges.len() * std::mem::size_of::<WingedEdge>()
            + self.v_edge.len() * 4
            + self.f_edge.len() * 4
    }
}
