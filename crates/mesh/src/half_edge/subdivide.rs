//! Subdivision: Loop for triangle meshes, Catmull–Clark for polygon meshes.
//! Each level returns a new indexed mesh (or a half-edge mesh,
//! written straight from the old one's connectivity): old vertices first
//! (moved), then one vertex per edge (and, for Catmull–Clark, one per
//! face).

use super::{HalfEdgeMesh, Link};
use crate::handle::{Face, HalfEdge, Vertex};
use crate::IndexedMesh;
use raymesh_geometry::Vec3;

/// The first half of old half-edge `h` in a subdivided mesh: `h` from x
/// to y (edge e, side s) becomes x→m, its first half, and m→y, its
/// second, where m is edge e's new vertex: half-edges 4e (x→m) and 4e + 2
/// (m→y) for side 0, 4e + 3 (y→m) and 4e + 1 (m→x) for side 1, so that
/// each half's twin is its `^ 1`. The subdivided meshes number the old
/// edges' halves so, then their new inner edges.
fn first_half(h: HalfEdge) -> HalfEdge {
    HalfEdge::new(4 * h.edge().idx() + 3 * (h.idx() & 1))
}

/// The second half of old half-edge `h` (see [`first_half`]).
fn second_half(h: HalfEdge) -> HalfEdge {
    HalfEdge::new(4 * h.edge().idx() + 2 - (h.idx() & 1))
}

impl HalfEdgeMesh {
    /// A copy with its deleted elements collected, if it has any: what the
    /// subdivisions work on then (a deleted face's half-edges may belong
    /// to other loops).
    fn collected(&self) -> Option<HalfEdgeMesh> {
        self.garbage.as_ref()?;
        let mut m = self.clone();
        m.garbage_collect();
        Some(m)
    }

    /// What both subdivisions written straight into a half-edge mesh
    /// share: a mesh of `positions` (the old vertices, the edges' new ones,
    /// then any others) with room for `inner` new edges inside the old
    /// faces and for `faces` faces, each old half-edge's two halves
    /// written (their heads, and their links along boundaries), and the
    /// outgoing half-edges of the old vertices (the first half of theirs)
    /// and of the edges' new vertices (a second half; on a boundary, the
    /// boundary's). The inner edges, the faces and the outgoing half-edges
    /// of any further vertices are the caller's to write.
    fn halved(&self, positions: Vec<Vec3>, inner: usize, faces: usize) -> HalfEdgeMesh {
        let (nv, ne) = (self.num_vertices(), self.num_edges());
        let nh = 4 * ne + 2 * inner;
        let none = Link {
            to: Vertex::INVALID,
            next: HalfEdge::INVALID,
        };
        let mut m = HalfEdgeMesh {
            v_half: Vec::with_capacity(positions.len()),
            positions,
            h_link: vec![none; nh],
            h_face: vec![Face::INVALID; nh],
            f_half: vec![HalfEdge::INVALID; faces],
            garbage: None,
        };
        for h in (0..self.num_halfedges()).map(HalfEdge::new) {
            let (f1, s1) = (first_half(h), second_half(h));
            m.h_link[f1.idx()].to = Vertex::new(nv + h.edge().idx());
            m.h_link[s1.idx()].to = self.to_vertex(h);
            if self.is_boundary_halfedge(h) {
                m.h_link[f1.idx()].next = s1;
                m.h_link[s1.idx()].next = first_half(self.next_halfedge(h));
            }
        }
        for v in self.vertices() {
            let h = self.vertex_halfedge(v);
            m.v_half.push(if h.is_valid() {
                first_half(h)
            } else {
                HalfEdge::INVALID
            });
        }
        for e in self.edges() {
            let h = e.halfedge(0);
            let b = if self.is_boundary_halfedge(h.twin()) {
                h.twin()
            } else {
                h
            };
            m.v_half.push(second_half(b));
        }
        m
    }

    /// Whether every face is a triangle.
    #[must_use]
    pub fn is_triangle_mesh(&self) -> bool {
        self.num_halfedges() - self.boundary_halfedge_count() == 3 * self.num_faces()
    }

    pub(crate) fn boundary_halfedge_count(&self) -> usize {
        self.h_face.iter().filter(|f| !f.is_valid()).count()
    }

    /// The cubic B-spline rule both schemes use on a boundary: `3/4` of the
    /// vertex and `1/8` of each neighbour along the boundary.
    fn boundary_vertex_point(&self, v: Vertex) -> Vec3 {
        let h = self.vertex_halfedge(v);
        let (a, b) = (self.to_vertex(h), self.from_vertex(self.prev_halfedge(h)));
        0.75 * self.position(v) + 0.125 * (self.position(a) + self.position(b))
    }

    /// One level of Loop subdivision (Loop, "Smooth subdivision surfaces
    /// based on triangles", 1987), with Loop's weights
    /// `β = (5/8 - (3/8 + cos(2π/n)/4)²) / n` and the boundary rules
    /// `3/4, 1/8, 1/8` (vertices) and `1/2, 1/2` (edges). `None` if a
    /// face is not a triangle. A mesh with deleted elements is subdivided
    /// as if they were collected.
    #[must_use]
    pub fn loop_subdivide(&self) -> Option<IndexedMesh> {
        if let Some(m) = self.collected() {
            return m.loop_subdivide();
        }
        if !self.is_triangle_mesh() {
            return None;
        }
        let nv = self.num_vertices();
        let mut out = IndexedMesh::with_capacity(0, 4 * self.num_faces(), 12 * self.num_faces());
        out.positions = self.loop_positions();
        let ev = |h: HalfEdge| (nv + h.edge().idx()) as u32;
        for f in self.faces() {
            let h0 = self.face_halfedge(f);
            let h1 = self.next_halfedge(h0);
            let h2 = self.next_halfedge(h1);
            let (a, b, c) = (
                self.from_vertex(h0).0,
                self.from_vertex(h1).0,
                self.from_vertex(h2).0,
            );
            let (ab, bc, ca) = (ev(h0), ev(h1), ev(h2));
            out.push_face_unchecked(&[a, ab, ca]);
            out.push_face_unchecked(&[b, bc, ab]);
            out.push_face_unchecked(&[c, ca, bc]);
            out.push_face_unchecked(&[ab, bc, ca]);
        }
        Some(out)
    }

    /// [`Self::loop_subdivide`] as a half-edge mesh, its connectivity
    /// written straight from this one's: each edge's two halves, three
    /// edges inside each triangle, four triangles for each, every link
    /// known from where it came from. The same mesh as
    /// `HalfEdgeMesh::from_indexed(&self.loop_subdivide()?)` (the same
    /// positions, vertices and faces in the same order; its edges numbered
    /// otherwise), without pairing the new corners again, which took
    /// about 85% of that (bunny00). Levels of subdivision chain without
    /// indexed meshes between them. `None` if a face is not a triangle; a
    /// mesh with deleted elements is subdivided as if they were collected.
    #[must_use]
    pub fn loop_subdivided(&self) -> Option<HalfEdgeMesh> {
        if let Some(m) = self.collected() {
            return m.loop_subdivided();
        }
        if !self.is_triangle_mesh() {
            return None;
        }
        let (nv, ne, nf) = (self.num_vertices(), self.num_edges(), self.num_faces());
        let (first, second) = (first_half, second_half);
        let mid = |h: HalfEdge| Vertex::new(nv + h.edge().idx());
        // Face f's three inside edges, 2 ne + 3 f + k: even half-edges in
        // its corner triangles, odd ones (their twins) in the middle one.
        let inner = |f: usize, k: usize| HalfEdge::new(2 * (2 * ne + 3 * f + k));
        let mut m = self.halved(self.loop_positions(), 3 * nf, 4 * nf);
        for f in 0..nf {
            let h0 = self.face_halfedge(Face::new(f));
            let h1 = self.next_halfedge(h0);
            let h2 = self.next_halfedge(h1);
            // Corners a (h0's start), b, c and midpoints ab, bc, ca: inner
            // k = 0 runs ab→ca, 1 bc→ab, 2 ca→bc.
            let (i0, i1, i2) = (inner(f, 0), inner(f, 1), inner(f, 2));
            let (ab, bc, ca) = (mid(h0), mid(h1), mid(h2));
            for (i, from, to) in [(i0, ab, ca), (i1, bc, ab), (i2, ca, bc)] {
                m.h_link[i.idx()].to = to;
                m.h_link[i.twin().idx()].to = from;
            }
            let faces = [
                [first(h0), i0, second(h2)],
                [first(h1), i1, second(h0)],
                [first(h2), i2, second(h1)],
                [i1.twin(), i2.twin(), i0.twin()],
            ];
            for (k, t) in faces.into_iter().enumerate() {
                let face = Face::new(4 * f + k);
                for j in 0..3 {
                    m.h_link[t[j].idx()].next = t[(j + 1) % 3];
                    m.h_face[t[j].idx()] = face;
                }
                m.f_half[face.idx()] = t[0];
            }
        }
        Some(m)
    }

    /// The positions of one Loop step: every vertex moved by Loop's rule
    /// (or the boundary rule), then a new vertex on each edge, in edge
    /// order.
    fn loop_positions(&self) -> Vec<Vec3> {
        let (nv, ne) = (self.num_vertices(), self.num_edges());
        let mut out = Vec::with_capacity(nv + ne);
        for v in self.vertices() {
            let p = self.position(v);
            let h = self.vertex_halfedge(v);
            let q = if !h.is_valid() {
                p
            } else if self.is_boundary_halfedge(h) {
                self.boundary_vertex_point(v)
            } else {
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                for w in self.vertex_vertices(v) {
                    sum += self.position(w);
                    n += 1;
                }
                let c = 0.375 + 0.25 * (std::f32::consts::TAU / n as f32).cos();
                let beta = (0.625 - c * c) / n as f32;
                (1.0 - n as f32 * beta) * p + beta * sum
            };
            out.push(q);
        }
        for e in self.edges() {
            let (h, t) = (e.halfedge(0), e.halfedge(1));
            let (a, b) = (
                self.position(self.to_vertex(h)),
                self.position(self.to_vertex(t)),
            );
            let q = if self.is_boundary_edge(e) {
                0.5 * (a + b)
            } else {
                let c = self.position(self.to_vertex(self.next_halfedge(h)));
                let d = self.position(self.to_vertex(self.next_halfedge(t)));
                0.375 * (a + b) + 0.125 * (c + d)
            };
            out.push(q);
        }
        out
    }

    /// One level of Catmull–Clark subdivision (Catmull & Clark, "Recursively
    /// generated B-spline surfaces on arbitrary topological meshes", 1978):
    /// every face becomes quads; boundaries follow the cubic B-spline rules.
    ///
    /// A mesh with deleted elements is subdivided as if they were
    /// collected (a deleted face's half-edges may belong to other loops).
    #[must_use]
    pub fn catmull_clark(&self) -> IndexedMesh {
        if let Some(m) = self.collected() {
            return m.catmull_clark();
        }
        let (nv, ne) = (self.num_vertices(), self.num_edges());
        let mut out = IndexedMesh::with_capacity(0, self.num_halfedges(), 4 * self.num_halfedges());
        out.positions = self.catmull_clark_positions();
        for f in self.faces() {
            let c = (nv + ne + f.idx()) as u32;
            for h in self.face_halfedges(f) {
                // The quad at h's start vertex: vertex, edge(h), face, edge(prev(h)).
                let p = self.prev_halfedge(h);
                out.push_face_unchecked(&[
                    self.from_vertex(h).0,
                    (nv + h.edge().idx()) as u32,
                    c,
                    (nv + p.edge().idx()) as u32,
                ]);
            }
        }
        out
    }

    /// [`Self::catmull_clark`] as a half-edge mesh, its connectivity
    /// written straight from this one's, as [`Self::loop_subdivided`]
    /// writes Loop's: each edge's two halves, an edge from each side's
    /// midpoint to the face's new vertex, a quad at each corner. The same
    /// mesh as `HalfEdgeMesh::from_indexed(&self.catmull_clark())` (the
    /// same positions, vertices and faces in the same order; its edges
    /// numbered otherwise). A mesh with deleted elements is subdivided as
    /// if they were collected.
    #[must_use]
    pub fn catmull_clark_subdivided(&self) -> HalfEdgeMesh {
        if let Some(m) = self.collected() {
            return m.catmull_clark_subdivided();
        }
        let (nv, ne, nf, nh) = (
            self.num_vertices(),
            self.num_edges(),
            self.num_faces(),
            self.num_halfedges(),
        );
        let (first, second) = (first_half, second_half);
        let mid = |h: HalfEdge| Vertex::new(nv + h.edge().idx());
        // Corner k of the new mesh: the k-th face half-edge, face by face,
        // each face's from its first half-edge on; its quad is face k and
        // its inner edge 2 ne + k, whose even half runs from the side's
        // midpoint to the face's new vertex.
        let mut corner = vec![u32::MAX; nh];
        let mut first_corner = Vec::with_capacity(nf + 1);
        let mut k = 0u32;
        for f in self.faces() {
            first_corner.push(k);
            for h in self.face_halfedges(f) {
                corner[h.idx()] = k;
                k += 1;
            }
        }
        let nc = k as usize;
        let inner = |h: HalfEdge| HalfEdge::new(2 * (2 * ne + corner[h.idx()] as usize));
        let mut m = self.halved(self.catmull_clark_positions(), nc, nc);
        for f in self.faces() {
            let c = Vertex::new(nv + ne + f.idx());
            for h in self.face_halfedges(f) {
                let i = inner(h);
                m.h_link[i.idx()].to = c;
                m.h_link[i.twin().idx()].to = mid(h);
                let p = self.prev_halfedge(h);
                let quad = [first(h), i, inner(p).twin(), second(p)];
                let face = Face::new(corner[h.idx()] as usize);
                for j in 0..4 {
                    m.h_link[quad[j].idx()].next = quad[(j + 1) % 4];
                    m.h_face[quad[j].idx()] = face;
                }
                m.f_half[face.idx()] = quad[0];
            }
        }
        // Each face's new vertex leaves by its first corner's inner edge.
        for &k in &first_corner {
            m.v_half
                .push(HalfEdge::new(2 * (2 * ne + k as usize)).twin());
        }
        m
    }

    /// The positions of one Catmull–Clark step: the old vertices moved,
    /// then a vertex on each edge, then one in each face.
    fn catmull_clark_positions(&self) -> Vec<Vec3> {
        let (nv, ne, nf) = (self.num_vertices(), self.num_edges(), self.num_faces());
        let mut out = Vec::with_capacity(nv + ne + nf);
        let face_pts: Vec<Vec3> = self
            .faces()
            .map(|f| {
                let (mut s, mut n) = (Vec3::ZERO, 0.0);
                for v in self.face_vertices(f) {
                    s += self.position(v);
                    n += 1.0;
                }
                s / n
            })
            .collect();
        let fp = |f: Face| face_pts[f.idx()];
        for v in self.vertices() {
            let p = self.position(v);
            let h = self.vertex_halfedge(v);
            let q = if !h.is_valid() {
                p
            } else if self.is_boundary_halfedge(h) {
                self.boundary_vertex_point(v)
            } else {
                let (mut f_sum, mut r_sum, mut n) = (Vec3::ZERO, Vec3::ZERO, 0.0f32);
                for o in self.outgoing_halfedges(v) {
                    f_sum += fp(self.face(o));
                    r_sum += 0.5 * (p + self.position(self.to_vertex(o)));
                    n += 1.0;
                }
                (f_sum / n + 2.0 * r_sum / n + (n - 3.0) * p) / n
            };
            out.push(q);
        }
        for e in self.edges() {
            let (h, t) = (e.halfedge(0), e.halfedge(1));
            let (a, b) = (
                self.position(self.to_vertex(h)),
                self.position(self.to_vertex(t)),
            );
            let q = if self.is_boundary_edge(e) {
                0.5 * (a + b)
            } else {
                0.25 * (a + b + fp(self.face(h)) + fp(self.face(t)))
            };
            out.push(q);
        }
        out.extend_from_slice(&face_pts);
        out
    }
}
