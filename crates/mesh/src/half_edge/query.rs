//! Walks around vertices and faces, and whole-mesh properties.

use super::HalfEdgeMesh;
use crate::handle::{Edge, Face, HalfEdge, Vertex};
use raymesh_geometry::Vec3;

/// Half-edges visited by repeatedly stepping from a start until it comes
/// round again: around a vertex (see [`HalfEdgeMesh::outgoing_halfedges`])
/// or a face (see [`HalfEdgeMesh::face_halfedges`]).
pub struct Circulator<'a> {
    mesh: &'a HalfEdgeMesh,
    step: fn(&HalfEdgeMesh, HalfEdge) -> HalfEdge,
    start: HalfEdge,
    cur: HalfEdge,
}

impl Iterator for Circulator<'_> {
    type Item = HalfEdge;
    #[inline]
    fn next(&mut self) -> Option<HalfEdge> {
        let h = self.cur;
        if !h.is_valid() {
            return None;
        }
        let n = (self.step)(self.mesh, h);
        self.cur = if n == self.start {
            HalfEdge::INVALID
        } else {
            n
        };
        Some(h)
    }
}

impl HalfEdgeMesh {
    /// The next outgoing half-edge counter-clockwise around its start vertex.
    #[inline]
    #[must_use]
    pub fn ccw_rotated(&self, h: HalfEdge) -> HalfEdge {
        self.prev_halfedge(h).twin()
    }

    /// The next outgoing half-edge clockwise around its start vertex.
    #[inline(always)]
    #[must_use]
    pub fn cw_rotated(&self, h: HalfEdge) -> HalfEdge {
        self.next_halfedge(h.twin())
    }

    /// Outgoing half-edges of `v`, counter-clockwise, starting with its
    /// boundary half-edge when it has one.
    #[must_use]
    pub fn outgoing_halfedges(&self, v: Vertex) -> Circulator<'_> {
        let h = self.vertex_halfedge(v);
        Circulator {
            mesh: self,
            step: Self::ccw_rotated,
            start: h,
            cur: h,
        }
    }

    /// Neighbouring vertices of `v`, counter-clockwise.
    pub fn vertex_vertices(&self, v: Vertex) -> impl Iterator<Item = Vertex> + '_ {
        self.outgoing_halfedges(v).map(|h| self.to_vertex(h))
    }

    /// Neighbouring vertices of `v`, clockwise: one load per step, where
    /// counter-clockwise needs the previous half-edge. Boundary vertices
    /// turn fully too (boundary loops are linked), starting at the boundary.
    pub fn vertex_vertices_cw(&self, v: Vertex) -> impl Iterator<Item = Vertex> + '_ {
        let h = self.vertex_halfedge(v);
        Circulator {
            mesh: self,
            step: Self::cw_rotated,
            start: h,
            cur: h,
        }
        .map(|h| self.to_vertex(h))
    }

    /// Faces around `v`, counter-clockwise.
    pub fn vertex_faces(&self, v: Vertex) -> impl Iterator<Item = Face> + '_ {
        self.outgoing_halfedges(v)
            .map(|h| self.face(h))
            .filter(|f| f.is_valid())
    }

    /// Edges around `v`, counter-clockwise.
    pub fn vertex_edges(&self, v: Vertex) -> impl Iterator<Item = Edge> + '_ {
        self.outgoing_halfedges(v).map(HalfEdge::edge)
    }

    /// Number of edges at `v`.
    #[must_use]
    pub fn valence(&self, v: Vertex) -> usize {
        self.outgoing_halfedges(v).count()
    }

    /// The half-edge from `from` to `to`, if an edge joins them (the first
    /// met counter-clockwise around `from`), as OpenMesh's
    /// `find_halfedge`: how an edge is named by its two vertices, to flip,
    /// split or collapse it. `None` for a deleted or isolated `from`.
    /// Panics if `from` is not a vertex of the mesh.
    #[must_use]
    pub fn find_halfedge(&self, from: Vertex, to: Vertex) -> Option<HalfEdge> {
        self.outgoing_halfedges(from)
            .find(|&h| self.to_vertex(h) == to)
    }

    /// Half-edges of face `f`, in its winding order.
    #[must_use]
    pub fn face_halfedges(&self, f: Face) -> Circulator<'_> {
        let h = self.face_halfedge(f);
        Circulator {
            mesh: self,
            step: Self::next_halfedge,
            start: h,
            cur: h,
        }
    }

    /// Vertices of face `f`, in its winding order, starting where it started in the input.
    pub fn face_vertices(&self, f: Face) -> impl Iterator<Item = Vertex> + '_ {
        self.face_halfedges(f).map(|h| self.from_vertex(h))
    }

    /// Faces across the edges of `f` (boundary edges have none and are skipped).
    pub fn face_faces(&self, f: Face) -> impl Iterator<Item = Face> + '_ {
        self.face_halfedges(f)
            .map(|h| self.face(h.twin()))
            .filter(|f| f.is_valid())
    }

    /// Number of vertices of face `f`.
    #[must_use]
    pub fn face_degree(&self, f: Face) -> usize {
        self.face_halfedges(f).count()
    }

    /// Every boundary loop, as its half-edges in order.
    #[must_use]
    pub fn boundary_loops(&self) -> Vec<Vec<HalfEdge>> {
        let mut seen = vec![false; self.num_halfedges()];
        let mut loops = Vec::new();
        for h in 0..self.num_halfedges() {
            let h = HalfEdge::new(h);
            if seen[h.idx()] || !self.is_boundary_halfedge(h) {
                continue;
            }
            let mut l = Vec::new();
            let mut c = h;
            while !seen[c.idx()] {
                seen[c.idx()] = true;
                l.push(c);
                c = self.next_halfedge(c);
            }
            loops.push(l);
        }
        loops
    }

    /// Connected components (isolated vertices count as one each) and each vertex's component.
    #[must_use]
    pub fn components(&self) -> (usize, Vec<u32>) {
        let mut label = vec![u32::MAX; self.num_vertices()];
        let mut count = 0u32;
        let mut stack = Vec::new();
        for v in self.vertices() {
            if label[v.idx()] != u32::MAX {
                continue;
            }
            label[v.idx()] = count;
            stack.push(v);
            while let Some(u) = stack.pop() {
                for w in self.vertex_vertices(u) {
                    if label[w.idx()] == u32::MAX {
                        label[w.idx()] = count;
                        stack.push(w);
                    }
                }
            }
            count += 1;
        }
        (count as usize, label)
    }

    /// Euler characteristic `V - E + F`.
    #[must_use]
    pub fn euler_characteristic(&self) -> i64 {
        self.num_vertices() as i64 - self.num_edges() as i64 + self.num_faces() as i64
    }

    /// Total genus of an orientable mesh, from `χ = 2c - 2g - b` over its
    /// `c` components and `b` boundary loops.
    #[must_use]
    pub fn genus(&self) -> i64 {
        let c = self.components().0 as i64;
        let b = self.boundary_loops().len() as i64;
        (2 * c - b - self.euler_characteristic()) / 2
    }

    /// Unit normal of face `f` (Newell's method), zero when degenerate.
    #[must_use]
    pub fn face_normal(&self, f: Face) -> Vec3 {
        let mut n = Vec3::ZERO;
        for h in self.face_halfedges(f) {
            let a = self.position(self.from_vertex(h));
            let b = self.position(self.to_vertex(h));
            n += Vec3::new(
                (a.y - b.y) * (a.z + b.z),
                (a.z - b.z) * (a.x + b.x),
                (a.x - b.x) * (a.y + b.y),
            );
        }
        n.normalize_or_zero()
    }

    /// Angle-weighted unit vertex normals (Thürmer & Wüthrich 1998): each
    /// face adds its normal times its corner angle. Gathered vertex by
    /// vertex, in parallel, turning clockwise around each vertex (one load a
    /// step), so that each normal is written once and no two threads write
    /// one place. A triangle's normal and the sine part of its angle come
    /// from one cross product; other polygons use their Newell normal.
    /// Isolated and deleted vertices, and vertices of degenerate faces
    /// only, get a zero normal.
    #[must_use]
    pub fn vertex_normals(&self) -> Vec<Vec3> {
        use crate::normals::fast_angle;
        use rayon::prelude::*;
        // Loop-invariant facts that save a load per corner: every face a
        // triangle, no boundary half-edge.
        let boundary = self.boundary_halfedge_count();
        let clean = self.garbage.is_none();
        let all_triangles = clean && self.num_halfedges() - boundary == 3 * self.num_faces();
        // Then no corner needs its face.
        let closed_triangles = all_triangles && boundary == 0;
        let polygons = (!all_triangles).then(|| {
            (0..self.num_faces())
                .into_par_iter()
                .map(|f| {
                    let f = Face::new(f);
                    // A deleted face's half-edges may belong to other loops now.
                    if self.is_deleted_face(f) {
                        Vec3::ZERO
                    } else {
                        self.face_normal(f)
                    }
                })
                .collect::<Vec<_>>()
        });
        // Corners wait in batches of eight (structure of arrays) before
        // their angles are taken: the arctangents of a batch are
        // independent, so the processor overlaps them where one corner at a
        // time would wait on each division in turn.
        const BATCH: usize = 8;
        #[derive(Clone, Copy)]
        struct Batch {
            /// |e_out × e_in| and e_out · e_in: the angle's sine and cosine parts.
            sin: [f32; BATCH],
            cos: [f32; BATCH],
            /// Each corner adds `dir * angle / div`: a triangle's cross
            /// product over its length, or a polygon's unit normal over 1.
            div: [f32; BATCH],
            dir: [Vec3; BATCH],
            n: usize,
        }
        impl Batch {
            const EMPTY: Self = Self {
                sin: [0.0; BATCH],
                cos: [1.0; BATCH],
                div: [1.0; BATCH],
                dir: [Vec3::ZERO; BATCH],
                n: 0,
            };
            fn flush(&mut self, sum: &mut Vec3) {
                let mut w = [0.0f32; BATCH];
                for i in 0..BATCH {
                    w[i] = fast_angle(self.sin[i], self.cos[i]) / self.div[i];
                }
                for i in 0..self.n {
                    *sum += self.dir[i] * w[i];
                }
                // Only the count: the lanes past it keep an earlier
                // corner's values (or `EMPTY`'s), whose weights the next
                // flush computes with the others and leaves out. Resetting
                // all 200 bytes here, and building a batch per vertex, was
                // a `memcpy` a vertex: 16% of the time on the pig, one
                // thread (`perf record -e cpu-clock`).
                self.n = 0;
            }
            fn push(&mut self, sum: &mut Vec3, sin: f32, cos: f32, div: f32, dir: Vec3) {
                let i = self.n;
                (self.sin[i], self.cos[i], self.div[i], self.dir[i]) = (sin, cos, div, dir);
                self.n += 1;
                if self.n == BATCH {
                    self.flush(sum);
                }
            }
        }
        let normal = |batch: &mut Batch, v: usize| {
            let h0 = self.v_half[v];
            if !h0.is_valid() {
                return Vec3::ZERO;
            }
            let p = self.positions[v];
            let (mut sum, mut prev) = (Vec3::ZERO, h0);
            let mut e_in = self.position(self.to_vertex(h0)) - p;
            loop {
                // The face left of `h` has its corner at `v` between
                // `prev`'s head (coming in) and `h`'s head (going out).
                let h = self.cw_rotated(prev);
                let link = self.h_link[h.idx()];
                let e_out = self.position(link.to) - p;
                let f = if closed_triangles {
                    Face::new(0)
                } else {
                    self.h_face[h.idx()]
                };
                if f.is_valid() {
                    let cross = e_out.cross(e_in);
                    let len = cross.length();
                    let dot = e_out.dot(e_in);
                    let triangle =
                        all_triangles || self.h_link[link.next.idx()].next == prev.twin();
                    if triangle && len > 0.0 {
                        batch.push(&mut sum, len, dot, len, cross);
                    } else if !triangle {
                        let n = polygons.as_ref().map_or(Vec3::ZERO, |n| n[f.idx()]);
                        batch.push(&mut sum, len, dot, 1.0, n);
                    }
                }
                if h == h0 {
                    break;
                }
                (prev, e_in) = (h, e_out);
            }
            batch.flush(&mut sum);
            sum.normalize_or_zero()
        };
        (0..self.num_vertices())
            .into_par_iter()
            .with_min_len(4096)
            // One batch per rayon task, reused from vertex to vertex.
            .map_init(|| Batch::EMPTY, normal)
            .collect()
    }
}
