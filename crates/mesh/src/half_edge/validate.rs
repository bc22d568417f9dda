//! Every invariant of the half-edge mesh, checked (for tests and after edits).

use super::HalfEdgeMesh;
use crate::handle::{Face, HalfEdge, Vertex};

impl HalfEdgeMesh {
    /// Checks every invariant; the error says which one failed where. With
    /// deleted elements pending, checks the mesh they would leave: every
    /// live element must refer only to live ones.
    pub fn validate(&self) -> Result<(), String> {
        if self.has_garbage() {
            let mut m = self.clone();
            m.garbage_collect();
            return m
                .validate()
                .map_err(|e| format!("after dropping deleted elements: {e}"));
        }
        let (nv, nh, nf) = (self.num_vertices(), self.num_halfedges(), self.num_faces());
        if self.v_half.len() != nv || self.h_face.len() != nh || nh % 2 != 0 {
            return Err("array lengths disagree".into());
        }
        for h in 0..nh {
            let h = HalfEdge::new(h);
            let (to, next, face) = (self.to_vertex(h), self.next_halfedge(h), self.face(h));
            if to.idx() >= nv {
                return Err(format!(
                    "half-edge {} points to vertex {} of {nv}",
                    h.0, to.0
                ));
            }
            if to == self.from_vertex(h) {
                return Err(format!("half-edge {} is a loop at vertex {}", h.0, to.0));
            }
            if next.idx() >= nh {
                return Err(format!("half-edge {} has next {}", h.0, next.0));
            }
            if self.from_vertex(next) != to {
                return Err(format!(
                    "half-edge {} ends at {} but its next starts at {}",
                    h.0,
                    to.0,
                    self.from_vertex(next).0
                ));
            }
            if face != self.face(next) {
                return Err(format!(
                    "half-edge {} and its next lie in different faces",
                    h.0
                ));
            }
            if face.is_valid() && face.idx() >= nf {
                return Err(format!("half-edge {} has face {}", h.0, face.0));
            }
            if !face.is_valid() && !self.face(h.twin()).is_valid() {
                return Err(format!("edge {} has no face on either side", h.edge().0));
            }
        }
        let mut on_face = vec![0usize; nf];
        for h in 0..nh {
            let f = self.face(HalfEdge::new(h));
            if f.is_valid() {
                on_face[f.idx()] += 1;
            }
        }
        for f in 0..nf {
            let f = Face::new(f);
            let h0 = self.face_halfedge(f);
            if !h0.is_valid() || h0.idx() >= nh || self.face(h0) != f {
                return Err(format!("face {} has a bad half-edge", f.0));
            }
            let n = self.face_halfedges(f).take(nh + 1).count();
            if n > nh || n != on_face[f.idx()] || n < 3 {
                return Err(format!(
                    "face {} loop has {n} half-edges, {} name it",
                    f.0,
                    on_face[f.idx()]
                ));
            }
        }
        // Each vertex: its half-edge starts there, is a boundary one if any
        // is, and turning around reaches every outgoing half-edge (one fan).
        let mut out_count = vec![0usize; nv];
        let mut has_boundary = vec![false; nv];
        for h in 0..nh {
            let h = HalfEdge::new(h);
            let v = self.from_vertex(h);
            out_count[v.idx()] += 1;
            has_boundary[v.idx()] |= self.is_boundary_halfedge(h);
        }
        for v in 0..nv {
            let vv = Vertex::new(v);
            let h = self.vertex_halfedge(vv);
            if !h.is_valid() {
                if out_count[v] != 0 {
                    return Err(format!("vertex {v} has edges but no half-edge"));
                }
                continue;
            }
            if self.from_vertex(h) != vv {
                return Err(format!(
                    "vertex {v}'s half-edge starts at {}",
                    self.from_vertex(h).0
                ));
            }
            if has_boundary[v] && !self.is_boundary_halfedge(h) {
                return Err(format!(
                    "boundary vertex {v} does not point at its boundary half-edge"
                ));
            }
            let around = self.outgoing_halfedges(vv).take(out_count[v] + 1).count();
            if around != out_count[v] {
                return Err(format!(
                    "vertex {v} is not manifold: {around} of {} half-edges around it",
                    out_count[v]
                ));
            }
        }
        if let Some(p) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(format!("vertex {p} is not finite"));
        }
        Ok(())
    }
}
