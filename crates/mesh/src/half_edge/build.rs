//! Building a half-edge mesh from indexed polygons, repairing what real
//! files get wrong instead of dropping faces, and converting back.

use super::HalfEdgeMesh;
use crate::handle::{Face, HalfEdge, Vertex};
use crate::{ErrorKind, IndexedMesh, Location, MeshError};

/// How to build.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildOptions {
    /// Fail on any non-manifold or inconsistent input instead of repairing it.
    pub strict: bool,
}

/// What the builder found and changed. Every face is kept: problems are
/// repaired by splitting vertices and edges.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RepairReport {
    /// Edges with more than two faces (each extra face got its own copy of the edge).
    pub non_manifold_edges: usize,
    /// Edges whose two faces run the same way (the edge was split in two).
    pub inconsistent_edges: usize,
    /// Vertices where several fans of faces meet (split into one vertex per fan).
    pub non_manifold_vertices: usize,
    /// Vertices added by splitting (fans and repeated corners).
    pub added_vertices: usize,
    /// Edges added by splitting.
    pub added_edges: usize,
    /// Faces with the same vertex set as an earlier face.
    pub repeated_faces: Vec<u32>,
    /// Faces that name one vertex twice (the repeat got its own vertex).
    pub degenerate_faces: Vec<u32>,
    /// Faces touching a non-manifold or inconsistent edge or vertex.
    pub affected_faces: Vec<u32>,
}

impl RepairReport {
    /// Whether the input needed no repair.
    #[must_use]
    pub fn is_clean(&self) -> bool {
        self.non_manifold_edges == 0
            && self.inconsistent_edges == 0
            && self.non_manifold_vertices == 0
            && self.repeated_faces.is_empty()
            && self.degenerate_faces.is_empty()
    }
}

/// Disjoint sets over half-edges (union by index, path halving).
fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

fn list(faces: &[u32]) -> String {
    let shown: Vec<String> = faces.iter().take(10).map(u32::to_string).collect();
    let more = if faces.len() > 10 {
        format!(" and {} more", faces.len() - 10)
    } else {
        String::new()
    };
    format!("{}{more}", shown.join(", "))
}

impl HalfEdgeMesh {
    /// Builds from indexed polygons, repairing non-manifold input.
    pub fn from_indexed(mesh: &IndexedMesh) -> Self {
        Self::build(mesh, BuildOptions::default())
            .expect("repairing builds never fail")
            .0
    }

    /// Builds from indexed polygons; see [`RepairReport`] for what is repaired,
    /// and [`BuildOptions::strict`] to refuse instead.
    pub fn build(
        mesh: &IndexedMesh,
        opts: BuildOptions,
    ) -> Result<(Self, RepairReport), MeshError> {
        let mut report = RepairReport::default();
        let mut positions = mesh.positions.clone();
        // Corners, face by face; a face's corner c is the half-edge from corner c to c + 1.
        let nf = mesh.num_faces();
        let mut corner_v: Vec<u32> = Vec::with_capacity(mesh.indices().len());
        let mut face_start: Vec<u32> = Vec::with_capacity(nf + 1);
        let mut seen: std::collections::HashMap<Vec<u32>, u32> = std::collections::HashMap::new();
        for (f, face) in mesh.faces().enumerate() {
            face_start.push(corner_v.len() as u32);
            let start = corner_v.len();
            for &v in face {
                if corner_v[start..].contains(&v) {
                    // A repeated corner gets a vertex of its own, so the face stays.
                    if report.degenerate_faces.last() != Some(&(f as u32)) {
                        report.degenerate_faces.push(f as u32);
                    }
                    positions.push(positions[v as usize]);
                    report.added_vertices += 1;
                    corner_v.push((positions.len() - 1) as u32);
                } else {
                    corner_v.push(v);
                }
            }
            let mut key = face.to_vec();
            key.sort_unstable();
            if let Some(_first) = seen.insert(key, f as u32) {
                report.repeated_faces.push(f as u32);
            }
        }
        face_start.push(corner_v.len() as u32);
        let nc = corner_v.len();
        let nv = positions.len();
        let mut corner_face = vec![0u32; nc];
        let mut corner_next = vec![0u32; nc];
        for f in 0..nf {
            let (s, e) = (face_start[f] as usize, face_start[f + 1] as usize);
            for c in s..e {
                corner_face[c] = f as u32;
                corner_next[c] = if c + 1 == e { s as u32 } else { c as u32 + 1 };
            }
        }
        let head = |c: usize| corner_v[corner_next[c] as usize];
        // Outgoing corners of each vertex (CSR).
        let mut out_start = vec![0u32; nv + 1];
        for &v in &corner_v {
            out_start[v as usize + 1] += 1;
        }
        for i in 0..nv {
            out_start[i + 1] += out_start[i];
        }
        let mut fill = out_start.clone();
        let mut out = vec![0u32; nc];
        for (c, &v) in corner_v.iter().enumerate() {
            out[fill[v as usize] as usize] = c as u32;
            fill[v as usize] += 1;
        }
        let outgoing =
            |v: u32| &out[out_start[v as usize] as usize..out_start[v as usize + 1] as usize];

        // Pair each corner a→b with an unpaired b→a. Each vertex pair is
        // counted once, at its lowest corner.
        const NONE: u32 = u32::MAX;
        let mut pair = vec![NONE; nc];
        let mut bad_face = vec![false; nf];
        let mut cut = 0usize;
        for c in 0..nc {
            let (a, b) = (corner_v[c], head(c));
            let same = outgoing(a)
                .iter()
                .filter(|&&d| head(d as usize) == b)
                .count();
            let opposite = outgoing(b)
                .iter()
                .copied()
                .filter(|&d| head(d as usize) == a);
            let first = outgoing(a)
                .iter()
                .filter(|&&d| head(d as usize) == b)
                .chain(outgoing(b).iter().filter(|&&d| head(d as usize) == a))
                .all(|&d| d as usize >= c);
            let total = same + opposite.clone().count();
            if total > 2 {
                report.non_manifold_edges += first as usize;
                bad_face[corner_face[c] as usize] = true;
            } else if same > 1 {
                report.inconsistent_edges += first as usize;
                bad_face[corner_face[c] as usize] = true;
            }
            if pair[c] == NONE {
                if let Some(d) = opposite.clone().find(|&d| pair[d as usize] == NONE) {
                    pair[c] = d;
                    pair[d as usize] = c as u32;
                } else if total > 1 {
                    cut += 1;
                }
            }
        }

        // Half-edges: a paired corner pair is one edge; an unpaired corner gets a boundary twin.
        let mut corner_he = vec![HalfEdge::INVALID; nc];
        let mut m = HalfEdgeMesh {
            positions,
            ..Self::default()
        };
        for c in 0..nc {
            if corner_he[c].is_valid() {
                continue;
            }
            let h = HalfEdge::new(m.h_to.len());
            corner_he[c] = h;
            m.h_to.push(Vertex(head(c)));
            m.h_face.push(Face(corner_face[c]));
            m.h_next.push(HalfEdge::INVALID);
            let d = pair[c];
            if d != NONE {
                corner_he[d as usize] = h.twin();
                m.h_to.push(Vertex(corner_v[c]));
                m.h_face.push(Face(corner_face[d as usize]));
            } else {
                m.h_to.push(Vertex(corner_v[c]));
                m.h_face.push(Face::INVALID);
            }
            m.h_next.push(HalfEdge::INVALID);
        }
        report.added_edges = cut;
        for c in 0..nc {
            m.h_next[corner_he[c].idx()] = corner_he[corner_next[c] as usize];
        }
        m.f_half = (0..nf).map(|f| corner_he[face_start[f] as usize]).collect();

        // Fans: outgoing face half-edges h ~ twin(prev(h)) when that has a face.
        let nh = m.h_to.len();
        let mut parent: Vec<u32> = (0..nh as u32).collect();
        for c in 0..nc {
            let h = corner_he[c];
            let t = m.prev_halfedge(h).twin();
            if !m.is_boundary_halfedge(t) {
                let (x, y) = (find(&mut parent, h.0), find(&mut parent, t.0));
                if x != y {
                    parent[x.max(y) as usize] = x.min(y);
                }
            }
        }
        for v in 0..nv as u32 {
            let mut fans: Vec<u32> = Vec::new();
            for &c in outgoing(v) {
                let r = find(&mut parent, corner_he[c as usize].0);
                if !fans.contains(&r) {
                    fans.push(r);
                }
            }
            if fans.len() <= 1 {
                continue;
            }
            report.non_manifold_vertices += 1;
            for &fan in &fans[1..] {
                let nv2 = Vertex::new(m.positions.len());
                m.positions.push(m.positions[v as usize]);
                report.added_vertices += 1;
                for &c in outgoing(v) {
                    let h = corner_he[c as usize];
                    if find(&mut parent, h.0) == fan {
                        m.h_to[h.twin().idx()] = nv2;
                        let p = m.prev_halfedge(h);
                        m.h_to[p.idx()] = nv2;
                        bad_face[corner_face[c as usize] as usize] = true;
                    }
                }
            }
        }

        // Boundary loops, and each vertex's half-edge (its boundary one if any).
        let nv = m.positions.len();
        m.v_half = vec![HalfEdge::INVALID; nv];
        let mut boundary_out = vec![HalfEdge::INVALID; nv];
        for h in 0..nh {
            let h = HalfEdge::new(h);
            let from = m.from_vertex(h);
            if m.is_boundary_halfedge(h) {
                boundary_out[from.idx()] = h;
            }
            if !m.v_half[from.idx()].is_valid() {
                m.v_half[from.idx()] = h;
            }
        }
        for h in 0..nh {
            let h = HalfEdge::new(h);
            if m.is_boundary_halfedge(h) {
                m.h_next[h.idx()] = boundary_out[m.to_vertex(h).idx()];
            }
        }
        for v in 0..nv {
            if boundary_out[v].is_valid() {
                m.v_half[v] = boundary_out[v];
            }
        }
        report.affected_faces = (0..nf as u32).filter(|&f| bad_face[f as usize]).collect();

        if opts.strict && !report.is_clean() {
            let mut what = Vec::new();
            if report.non_manifold_edges + report.inconsistent_edges + report.non_manifold_vertices
                > 0
            {
                what.push(format!(
                    "{} non-manifold edges, {} inconsistently oriented edges, {} non-manifold vertices (faces {})",
                    report.non_manifold_edges,
                    report.inconsistent_edges,
                    report.non_manifold_vertices,
                    list(&report.affected_faces)
                ));
            }
            if !report.repeated_faces.is_empty() {
                what.push(format!("repeated faces {}", list(&report.repeated_faces)));
            }
            if !report.degenerate_faces.is_empty() {
                what.push(format!(
                    "faces naming a vertex twice {}",
                    list(&report.degenerate_faces)
                ));
            }
            return Err(MeshError::new(
                Location::File,
                ErrorKind::Syntax(format!("not a manifold mesh: {}", what.join("; "))),
            ));
        }
        Ok((m, report))
    }

    /// The indexed polygon mesh with the same vertices and faces, in order.
    #[must_use]
    pub fn to_indexed(&self) -> IndexedMesh {
        let mut out =
            IndexedMesh::with_capacity(self.num_vertices(), self.num_faces(), self.num_halfedges());
        out.positions = self.positions.clone();
        let mut face = Vec::new();
        for f in self.faces() {
            face.clear();
            face.extend(self.face_vertices(f).map(|v| v.0));
            out.push_face_unchecked(&face);
        }
        out
    }
}
