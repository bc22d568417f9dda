//! Editing triangle meshes: edge flip, edge split, face split, half-edge
//! collapse (with the link condition of Dey et al. 1999 / Hoppe et al.
//! 1993), and garbage collection of what collapses delete.

use super::{HalfEdgeMesh, Link};
use crate::handle::{Edge, Face, HalfEdge, Vertex};
use raymesh_geometry::Vec3;

/// Elements deleted since the last [`HalfEdgeMesh::garbage_collect`].
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Garbage {
    vertices: Vec<bool>,
    edges: Vec<bool>,
    faces: Vec<bool>,
}

impl Garbage {
    pub(crate) fn bytes(&self) -> usize {
        self.vertices.len() + self.edges.len() + self.faces.len()
    }
}

fn mark(v: &mut Vec<bool>, i: usize, len: usize) {
    if v.len() < len {
        v.resize(len, false);
    }
    v[i] = true;
}

impl HalfEdgeMesh {
    /// Whether a vertex was deleted by an edit (until garbage collection).
    #[must_use]
    pub fn is_deleted_vertex(&self, v: Vertex) -> bool {
        self.garbage
            .as_ref()
            .is_some_and(|g| g.vertices.get(v.idx()).copied().unwrap_or(false))
    }

    /// Whether an edge was deleted by an edit.
    #[must_use]
    pub fn is_deleted_edge(&self, e: Edge) -> bool {
        self.garbage
            .as_ref()
            .is_some_and(|g| g.edges.get(e.idx()).copied().unwrap_or(false))
    }

    /// Whether a face was deleted by an edit.
    #[must_use]
    pub fn is_deleted_face(&self, f: Face) -> bool {
        self.garbage
            .as_ref()
            .is_some_and(|g| g.faces.get(f.idx()).copied().unwrap_or(false))
    }

    /// Whether edits left deleted elements behind.
    #[must_use]
    pub fn has_garbage(&self) -> bool {
        self.garbage.is_some()
    }

    fn garbage_mut(&mut self) -> &mut Garbage {
        self.garbage.get_or_insert_with(Default::default)
    }

    fn mark_vertex_deleted(&mut self, v: Vertex) {
        let n = self.num_vertices();
        mark(&mut self.garbage_mut().vertices, v.idx(), n);
    }

    fn mark_edge_deleted(&mut self, e: Edge) {
        let n = self.num_edges();
        mark(&mut self.garbage_mut().edges, e.idx(), n);
    }

    fn mark_face_deleted(&mut self, f: Face) {
        let n = self.num_faces();
        mark(&mut self.garbage_mut().faces, f.idx(), n);
    }

    fn is_triangle(&self, f: Face) -> bool {
        let h = self.face_halfedge(f);
        self.next_halfedge(self.next_halfedge(self.next_halfedge(h))) == h
    }

    /// Whether the faces on both sides of `e` are triangles (or none).
    fn triangles_around(&self, e: Edge) -> bool {
        [e.halfedge(0), e.halfedge(1)]
            .into_iter()
            .all(|h| self.is_boundary_halfedge(h) || self.is_triangle(self.face(h)))
    }

    /// Points a vertex at its boundary half-edge if it has one (after edits).
    fn adjust_outgoing(&mut self, v: Vertex) {
        let start = self.vertex_halfedge(v);
        if !start.is_valid() {
            return;
        }
        let mut h = start;
        loop {
            if self.is_boundary_halfedge(h) {
                self.v_half[v.idx()] = h;
                return;
            }
            h = self.cw_rotated(h);
            if h == start {
                return;
            }
        }
    }

    /// Whether [`Self::flip`] may turn `e`: an interior edge between two
    /// triangles whose far vertices are not already joined.
    #[must_use]
    pub fn is_flip_ok(&self, e: Edge) -> bool {
        if self.is_deleted_edge(e) || self.is_boundary_edge(e) || !self.triangles_around(e) {
            return false;
        }
        let (h0, h1) = (e.halfedge(0), e.halfedge(1));
        let (a, b) = (
            self.to_vertex(self.next_halfedge(h0)),
            self.to_vertex(self.next_halfedge(h1)),
        );
        a != b && !self.vertex_vertices(a).any(|w| w == b)
    }

    /// Turns edge `e` inside its two triangles, to join their far vertices.
    /// Returns false (and changes nothing) when [`Self::is_flip_ok`] is false.
    pub fn flip(&mut self, e: Edge) -> bool {
        if !self.is_flip_ok(e) {
            return false;
        }
        let (h0, h1) = (e.halfedge(0), e.halfedge(1));
        let (a0, a1) = (self.next_halfedge(h0), self.next_halfedge(h1));
        let (b0, b1) = (self.next_halfedge(a0), self.next_halfedge(a1));
        let (va0, vb0) = (self.to_vertex(h0), self.to_vertex(h1));
        let (va1, vb1) = (self.to_vertex(a0), self.to_vertex(a1));
        let (f0, f1) = (self.face(h0), self.face(h1));
        self.h_link[h0.idx()].to = va1;
        self.h_link[h1.idx()].to = vb1;
        // Face f0: h0 (vb1→va1), b0 (va1→vb0), a1 (vb0→vb1). Face f1: h1, b1, a0.
        self.h_link[h0.idx()].next = b0;
        self.h_link[b0.idx()].next = a1;
        self.h_link[a1.idx()].next = h0;
        self.h_link[h1.idx()].next = b1;
        self.h_link[b1.idx()].next = a0;
        self.h_link[a0.idx()].next = h1;
        self.h_face[a1.idx()] = f0;
        self.h_face[a0.idx()] = f1;
        self.f_half[f0.idx()] = h0;
        self.f_half[f1.idx()] = h1;
        if self.v_half[va0.idx()] == h1 {
            self.v_half[va0.idx()] = a0;
        }
        if self.v_half[vb0.idx()] == h0 {
            self.v_half[vb0.idx()] = a1;
        }
        true
    }

    fn new_edge(&mut self, from: Vertex, to: Vertex) -> HalfEdge {
        let h = HalfEdge::new(self.h_link.len());
        self.h_link.extend([
            Link {
                to,
                next: HalfEdge::INVALID,
            },
            Link {
                to: from,
                next: HalfEdge::INVALID,
            },
        ]);
        self.h_face.extend([Face::INVALID; 2]);
        h
    }

    fn new_face(&mut self, h: HalfEdge) -> Face {
        self.f_half.push(h);
        Face::new(self.f_half.len() - 1)
    }

    /// Splits edge `e` at a new vertex at `p`, and each triangle beside it
    /// in two. `None` (and no change) if a face beside `e` is not a triangle.
    pub fn split(&mut self, e: Edge, p: Vec3) -> Option<Vertex> {
        if self.is_deleted_edge(e) || !self.triangles_around(e) {
            return None;
        }
        let (h0, h1) = (e.halfedge(0), e.halfedge(1));
        let v1 = self.to_vertex(h0);
        let (f0, f1) = (self.face(h0), self.face(h1));
        let prev_h1 = self.prev_halfedge(h1);
        let next_h0 = self.next_halfedge(h0);
        let v = Vertex::new(self.positions.len());
        self.positions.push(p);
        self.v_half.push(HalfEdge::INVALID);
        // h0: v0→v, g: v→v1 (its twin v1→v), h1 becomes v→v0.
        self.h_link[h0.idx()].to = v;
        let g = self.new_edge(v, v1);
        let gt = g.twin();
        if f0.is_valid() {
            let (x, y) = (next_h0, self.next_halfedge(next_h0));
            let w = self.to_vertex(x);
            let n = self.new_edge(v, w);
            let f2 = self.new_face(h0);
            self.set_triangle([g, x, n.twin()], f0);
            self.set_triangle([h0, n, y], f2);
        } else {
            self.h_link[h0.idx()].next = g;
            self.h_link[g.idx()].next = next_h0;
        }
        if f1.is_valid() {
            let (z, q) = (
                self.next_halfedge(h1),
                self.next_halfedge(self.next_halfedge(h1)),
            );
            let u = self.to_vertex(z);
            let m = self.new_edge(v, u);
            let f4 = self.new_face(gt);
            self.set_triangle([h1, z, m.twin()], f1);
            self.set_triangle([gt, m, q], f4);
        } else {
            self.h_link[prev_h1.idx()].next = gt;
            self.h_link[gt.idx()].next = h1;
        }
        self.v_half[v.idx()] = if !f1.is_valid() { h1 } else { g };
        if self.v_half[v1.idx()] == h1 {
            self.v_half[v1.idx()] = gt;
        }
        if let Some(gb) = self.garbage.as_mut() {
            // Keep the marks' lengths in step with the arrays.
            gb.vertices.resize(self.positions.len(), false);
        }
        Some(v)
    }

    /// Splits triangle `f` in three at a new vertex at `p`, joined to its
    /// three corners (OpenMesh's `split(FaceHandle, Point)`, the 1-to-3
    /// split of √3 subdivision and of inserting a point into a
    /// triangulation). `f` keeps the part beside its first half-edge; the
    /// other two are new faces. `None` (and no change) if `f` is deleted
    /// or not a triangle. Panics if `f` is not a face of the mesh.
    pub fn split_face(&mut self, f: Face, p: Vec3) -> Option<Vertex> {
        if self.is_deleted_face(f) || !self.is_triangle(f) {
            return None;
        }
        let h0 = self.face_halfedge(f);
        let h1 = self.next_halfedge(h0);
        let h2 = self.next_halfedge(h1);
        let (a, b, c) = (self.to_vertex(h2), self.to_vertex(h0), self.to_vertex(h1));
        let v = Vertex::new(self.positions.len());
        self.positions.push(p);
        // Each `new_edge(v, x)` is v→x, and its twin x→v.
        let (ea, eb, ec) = (
            self.new_edge(v, a),
            self.new_edge(v, b),
            self.new_edge(v, c),
        );
        let (f1, f2) = (self.new_face(h1), self.new_face(h2));
        self.set_triangle([h0, eb.twin(), ea], f);
        self.set_triangle([h1, ec.twin(), eb], f1);
        self.set_triangle([h2, ea.twin(), ec], f2);
        // Inside the triangle: none of its half-edges is a boundary, and the
        // corners keep the outgoing half-edges they had.
        self.v_half.push(ea);
        if let Some(gb) = self.garbage.as_mut() {
            gb.vertices.resize(self.positions.len(), false);
        }
        Some(v)
    }

    fn set_triangle(&mut self, hs: [HalfEdge; 3], f: Face) {
        for i in 0..3 {
            self.h_link[hs[i].idx()].next = hs[(i + 1) % 3];
            self.h_face[hs[i].idx()] = f;
        }
        self.f_half[f.idx()] = hs[0];
    }

    /// Whether [`Self::collapse`] may merge the start of `h` into its end:
    /// the faces beside it are triangles, no triangle would be left hanging,
    /// an interior edge does not join two boundaries, and the one-rings of
    /// the two vertices share only the vertices opposite the edge (the link
    /// condition), and no second edge joins them, so the result stays a
    /// manifold without loops.
    #[must_use]
    pub fn is_collapse_ok(&self, h: HalfEdge) -> bool {
        let e = h.edge();
        if self.is_deleted_edge(e) || !self.triangles_around(e) {
            return false;
        }
        let o = h.twin();
        let (v0, v1) = (self.from_vertex(h), self.to_vertex(h));
        let side = |h: HalfEdge| -> Result<Option<Vertex>, ()> {
            if self.is_boundary_halfedge(h) {
                return Ok(None);
            }
            let h1 = self.next_halfedge(h);
            let h2 = self.next_halfedge(h1);
            if self.is_boundary_halfedge(h1.twin()) && self.is_boundary_halfedge(h2.twin()) {
                return Err(());
            }
            Ok(Some(self.to_vertex(h1)))
        };
        let (Ok(vl), Ok(vr)) = (side(h), side(o)) else {
            return false;
        };
        if vl.is_some() && vl == vr {
            return false;
        }
        if self.is_boundary_vertex(v0) && self.is_boundary_vertex(v1) && !self.is_boundary_edge(e) {
            return false;
        }
        // Another edge joining v0 and v1 would become a loop.
        if self.vertex_vertices(v0).filter(|&w| w == v1).count() > 1 {
            return false;
        }
        let ring1: Vec<Vertex> = self.vertex_vertices(v1).collect();
        !self
            .vertex_vertices(v0)
            .any(|w| w != v1 && Some(w) != vl && Some(w) != vr && ring1.contains(&w))
    }

    /// Merges the start vertex of `h` into its end, removing the edge and
    /// the triangles beside it. Returns false (and changes nothing) when
    /// [`Self::is_collapse_ok`] is false. Deleted elements stay until
    /// [`Self::garbage_collect`].
    pub fn collapse(&mut self, h: HalfEdge) -> bool {
        if !self.is_collapse_ok(h) {
            return false;
        }
        let o = h.twin();
        let (v0, v1) = (self.from_vertex(h), self.to_vertex(h));
        let (hn, hp) = (self.next_halfedge(h), self.prev_halfedge(h));
        let (on, op) = (self.next_halfedge(o), self.prev_halfedge(o));
        let (fh, fo) = (self.face(h), self.face(o));
        // What the loops' removal needs, read before anything changes.
        let loop_h = fh
            .is_valid()
            .then(|| (hn, hp, self.prev_halfedge(hn.twin())));
        let loop_o = fo
            .is_valid()
            .then(|| (on, op, self.prev_halfedge(on.twin())));
        let vl = fh.is_valid().then(|| self.to_vertex(hn));
        let vr = fo.is_valid().then(|| self.to_vertex(on));
        let incoming: Vec<HalfEdge> = self.outgoing_halfedges(v0).map(HalfEdge::twin).collect();
        for i in incoming {
            self.h_link[i.idx()].to = v1;
        }
        self.h_link[hp.idx()].next = hn;
        self.h_link[op.idx()].next = on;
        if fh.is_valid() {
            self.f_half[fh.idx()] = hn;
        }
        if fo.is_valid() {
            self.f_half[fo.idx()] = on;
        }
        if self.v_half[v1.idx()] == o {
            self.v_half[v1.idx()] = on;
        }
        self.v_half[v0.idx()] = HalfEdge::INVALID;
        self.mark_vertex_deleted(v0);
        self.mark_edge_deleted(h.edge());
        for (a, b, prev_ta) in [loop_h, loop_o].into_iter().flatten() {
            self.remove_loop(a, b, prev_ta, v1);
        }
        for v in [Some(v1), vl, vr].into_iter().flatten() {
            self.adjust_outgoing(v);
        }
        true
    }

    /// Removes the two-sided face `[a, b]` (a: v1→x, b: x→v1) left by a
    /// collapse: `b` takes the place of `twin(a)`, whose previous half-edge
    /// was `prev_ta`.
    fn remove_loop(&mut self, a: HalfEdge, b: HalfEdge, prev_ta: HalfEdge, v1: Vertex) {
        let ta = a.twin();
        let x = self.to_vertex(a);
        let (f, g) = (self.face(a), self.face(ta));
        self.h_link[prev_ta.idx()].next = b;
        self.h_link[b.idx()].next = self.next_halfedge(ta);
        self.h_face[b.idx()] = g;
        if g.is_valid() && self.f_half[g.idx()] == ta {
            self.f_half[g.idx()] = b;
        }
        if self.v_half[x.idx()] == ta {
            self.v_half[x.idx()] = b;
        }
        if self.v_half[v1.idx()] == a {
            self.v_half[v1.idx()] = b.twin();
        }
        self.mark_face_deleted(f);
        self.mark_edge_deleted(a.edge());
    }

    /// Deletes face `f`: its half-edges become boundary, edges left with no
    /// face on either side are deleted (the boundary loops relinked around
    /// them), and vertices left with no edge are deleted. Any polygon; the
    /// elements stay until [`Self::garbage_collect`]. As pmp-library and
    /// OpenMesh do, this may leave a vertex where two boundaries touch.
    pub fn delete_face(&mut self, f: Face) {
        if self.is_deleted_face(f) {
            return;
        }
        let hs: Vec<HalfEdge> = self.face_halfedges(f).collect();
        let vs: Vec<Vertex> = hs.iter().map(|&h| self.to_vertex(h)).collect();
        for &h in &hs {
            self.h_face[h.idx()] = Face::INVALID;
        }
        self.mark_face_deleted(f);
        // Its half-edges join other loops now: walks of the deleted face end at once.
        self.f_half[f.idx()] = HalfEdge::INVALID;
        let dead: Vec<Edge> = hs
            .iter()
            .filter(|h| self.is_boundary_halfedge(h.twin()))
            .map(|h| h.edge())
            .collect();
        for e in dead {
            // h0 runs v1 → v0, h1 runs v0 → v1.
            let (h0, h1) = (e.halfedge(0), e.halfedge(1));
            let (v0, v1) = (self.to_vertex(h0), self.to_vertex(h1));
            let (next0, next1) = (self.next_halfedge(h0), self.next_halfedge(h1));
            let (prev0, prev1) = (self.prev_halfedge(h0), self.prev_halfedge(h1));
            self.h_link[prev0.idx()].next = next1;
            self.h_link[prev1.idx()].next = next0;
            self.mark_edge_deleted(e);
            if self.v_half[v0.idx()] == h1 {
                if next0 == h1 {
                    self.v_half[v0.idx()] = HalfEdge::INVALID;
                    self.mark_vertex_deleted(v0);
                } else {
                    self.v_half[v0.idx()] = next0;
                }
            }
            if self.v_half[v1.idx()] == h0 {
                if next1 == h0 {
                    self.v_half[v1.idx()] = HalfEdge::INVALID;
                    self.mark_vertex_deleted(v1);
                } else {
                    self.v_half[v1.idx()] = next1;
                }
            }
        }
        for v in vs {
            if !self.is_deleted_vertex(v) {
                self.adjust_outgoing(v);
            }
        }
    }

    /// Drops deleted elements, renumbering the rest in order.
    pub fn garbage_collect(&mut self) {
        let Some(g) = self.garbage.take() else { return };
        let keep = |marks: &Vec<bool>, n: usize| -> Vec<u32> {
            let mut next = 0u32;
            (0..n)
                .map(|i| {
                    if marks.get(i).copied().unwrap_or(false) {
                        u32::MAX
                    } else {
                        next += 1;
                        next - 1
                    }
                })
                .collect()
        };
        let vmap = keep(&g.vertices, self.num_vertices());
        let emap = keep(&g.edges, self.num_edges());
        let fmap = keep(&g.faces, self.num_faces());
        let hmap = |h: HalfEdge| {
            if h.is_valid() && emap[h.idx() >> 1] != u32::MAX {
                HalfEdge((emap[h.idx() >> 1] << 1) | (h.0 & 1))
            } else {
                HalfEdge::INVALID
            }
        };
        let vm = |v: Vertex| {
            if v.is_valid() {
                Vertex(vmap[v.idx()])
            } else {
                v
            }
        };
        let fm = |f: Face| if f.is_valid() { Face(fmap[f.idx()]) } else { f };
        let mut m = HalfEdgeMesh::default();
        for v in 0..self.num_vertices() {
            if vmap[v] != u32::MAX {
                m.positions.push(self.positions[v]);
                m.v_half.push(hmap(self.v_half[v]));
            }
        }
        for h in 0..self.num_halfedges() {
            if emap[h >> 1] != u32::MAX {
                m.h_link.push(Link {
                    to: vm(self.h_link[h].to),
                    next: hmap(self.h_link[h].next),
                });
                m.h_face.push(fm(self.h_face[h]));
            }
        }
        for f in 0..self.num_faces() {
            if fmap[f] != u32::MAX {
                m.f_half.push(hmap(self.f_half[f]));
            }
        }
        *self = m;
    }
}
