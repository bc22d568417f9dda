//! The half-edge mesh for polygon meshes.
//!
//! Per half-edge: its head vertex, the next half-edge of its face (or of
//! its boundary loop) and its face (none on a boundary); the twin and the
//! edge are implicit (`h ^ 1`, `h >> 1`), and the previous half-edge is not
//! stored (it is found by walking the face: two steps on a triangle). Per
//! vertex: one outgoing half-edge, a boundary one when the vertex is on a
//! boundary, so walks around it are complete. Per face: one half-edge.
//! That is 12 bytes per half-edge and 16 per vertex with its position,
//! about 96 bytes per vertex on a triangle mesh (the lecture counts 120).

mod build;
mod edit;
mod query;
mod subdivide;
mod validate;

pub use build::{BuildOptions, RepairReport};

use crate::handle::{Edge, Face, HalfEdge, Vertex};
use raymesh_geometry::Vec3;

/// A half-edge mesh (see the module docs for the layout).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HalfEdgeMesh {
    pub(crate) positions: Vec<Vec3>,
    /// Outgoing half-edge of each vertex (boundary one on a boundary; none if isolated).
    pub(crate) v_half: Vec<HalfEdge>,
    /// Head vertex and next half-edge (around the face or boundary loop)
    /// of each half-edge, side by side: a walk around a vertex reads both
    /// from one cache line (the twin's `next` sits beside `to`).
    pub(crate) h_link: Vec<Link>,
    /// Face of each half-edge (none on a boundary).
    pub(crate) h_face: Vec<Face>,
    /// One half-edge of each face.
    pub(crate) f_half: Vec<HalfEdge>,
    /// Deleted elements since the last garbage collection; allocated only
    /// once an edit deletes something.
    pub(crate) garbage: Option<Box<edit::Garbage>>,
}

/// A half-edge's head vertex and the next half-edge around its face.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Link {
    pub(crate) to: Vertex,
    pub(crate) next: HalfEdge,
}

impl HalfEdgeMesh {
    /// Number of vertices.
    #[inline]
    #[must_use]
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of edges.
    #[inline]
    #[must_use]
    pub fn num_edges(&self) -> usize {
        self.h_link.len() / 2
    }

    /// Number of half-edges.
    #[inline]
    #[must_use]
    pub fn num_halfedges(&self) -> usize {
        self.h_link.len()
    }

    /// Number of faces.
    #[inline]
    #[must_use]
    pub fn num_faces(&self) -> usize {
        self.f_half.len()
    }

    /// Position of a vertex.
    #[inline(always)]
    #[must_use]
    pub fn position(&self, v: Vertex) -> Vec3 {
        self.positions[v.idx()]
    }

    /// All positions.
    #[must_use]
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Moves vertex `v` to `p` (smoothing, deformation, placing the vertex
    /// an edit made): the connectivity stays as it is. Panics if `v` is
    /// not a vertex of the mesh.
    #[inline]
    pub fn set_position(&mut self, v: Vertex, p: Vec3) {
        self.positions[v.idx()] = p;
    }

    /// All positions, to move many vertices at once (a slice: the vertex
    /// count is the connectivity's, and stays).
    #[must_use]
    pub fn positions_mut(&mut self) -> &mut [Vec3] {
        &mut self.positions
    }

    /// The vertex a half-edge points to.
    #[inline(always)]
    #[must_use]
    pub fn to_vertex(&self, h: HalfEdge) -> Vertex {
        self.h_link[h.idx()].to
    }

    /// The vertex a half-edge starts from.
    #[inline(always)]
    #[must_use]
    pub fn from_vertex(&self, h: HalfEdge) -> Vertex {
        self.h_link[h.twin().idx()].to
    }

    /// The next half-edge around the face (or boundary loop).
    #[inline(always)]
    #[must_use]
    pub fn next_halfedge(&self, h: HalfEdge) -> HalfEdge {
        self.h_link[h.idx()].next
    }

    /// The previous half-edge around the face (or boundary loop). Not
    /// stored: found by walking the face (two steps on a triangle), or, for
    /// a boundary half-edge, by turning clockwise around its start vertex
    /// (the vertex's valence in steps, not the loop's length).
    #[inline]
    #[must_use]
    pub fn prev_halfedge(&self, h: HalfEdge) -> HalfEdge {
        if self.is_boundary_halfedge(h) {
            // Clockwise around from(h): o -> next(twin(o)); stop before h comes round.
            let mut o = h;
            loop {
                let t = o.twin();
                let n = self.next_halfedge(t);
                if n == h {
                    return t;
                }
                o = n;
            }
        }
        let mut p = h;
        loop {
            let n = self.next_halfedge(p);
            if n == h {
                return p;
            }
            p = n;
        }
    }

    /// The face of a half-edge (invalid on a boundary).
    #[inline(always)]
    #[must_use]
    pub fn face(&self, h: HalfEdge) -> Face {
        self.h_face[h.idx()]
    }

    /// One outgoing half-edge of a vertex (a boundary one if the vertex is on
    /// a boundary; invalid if it is isolated).
    #[inline(always)]
    #[must_use]
    pub fn vertex_halfedge(&self, v: Vertex) -> HalfEdge {
        self.v_half[v.idx()]
    }

    /// One half-edge of a face.
    #[inline(always)]
    #[must_use]
    pub fn face_halfedge(&self, f: Face) -> HalfEdge {
        self.f_half[f.idx()]
    }

    /// Whether the half-edge has no face.
    #[inline(always)]
    #[must_use]
    pub fn is_boundary_halfedge(&self, h: HalfEdge) -> bool {
        !self.face(h).is_valid()
    }

    /// Whether either side of the edge has no face.
    #[inline]
    #[must_use]
    pub fn is_boundary_edge(&self, e: Edge) -> bool {
        self.is_boundary_halfedge(e.halfedge(0)) || self.is_boundary_halfedge(e.halfedge(1))
    }

    /// Whether the vertex is on a boundary (or isolated).
    #[inline]
    #[must_use]
    pub fn is_boundary_vertex(&self, v: Vertex) -> bool {
        let h = self.vertex_halfedge(v);
        !h.is_valid() || self.is_boundary_halfedge(h)
    }

    /// Bytes of the structure's arrays (positions included).
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        self.positions.len() * 12
            + self.v_half.len() * 4
            + self.h_link.len() * 12
            + self.f_half.len() * 4
            + self.garbage.as_ref().map_or(0, |g| g.bytes())
    }

    /// Vertices, in order.
    pub fn vertices(&self) -> impl ExactSizeIterator<Item = Vertex> {
        (0..self.num_vertices()).map(Vertex::new)
    }

    /// Faces, in order.
    pub fn faces(&self) -> impl ExactSizeIterator<Item = Face> {
        (0..self.num_faces()).map(Face::new)
    }

    /// Edges, in order.
    pub fn edges(&self) -> impl ExactSizeIterator<Item = Edge> {
        (0..self.num_edges()).map(Edge::new)
    }
}

#[cfg(test)]
mod tests;
