//! Building a half-edge mesh from indexed polygons, repairing what real
//! files get wrong instead of dropping faces, and converting back.

use super::{HalfEdgeMesh, Link};
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

/// Faces with the same vertex set as an earlier face. Faces are bucketed
/// by their lowest vertex, so only faces sharing it are compared.
pub(super) fn repeated_faces(mesh: &IndexedMesh) -> Vec<u32> {
    let nv = mesh.num_vertices();
    let mut start = vec![0u32; nv + 1];
    for f in mesh.faces() {
        start[*f.iter().min().unwrap() as usize + 1] += 1;
    }
    for i in 0..nv {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut bucket = vec![0u32; mesh.num_faces()];
    for (i, f) in mesh.faces().enumerate() {
        let m = *f.iter().min().unwrap() as usize;
        bucket[fill[m] as usize] = i as u32;
        fill[m] += 1;
    }
    // Same vertex set: same size and, sorted, the same vertices. Triangles
    // (the common case) compare as arrays, without allocating.
    let same = |f: u32, g: u32| {
        let (a, b) = (mesh.face(f as usize), mesh.face(g as usize));
        if a.len() != b.len() {
            return false;
        }
        if a.len() == 3 {
            let (mut x, mut y) = ([a[0], a[1], a[2]], [b[0], b[1], b[2]]);
            x.sort_unstable();
            y.sort_unstable();
            return x == y;
        }
        let (mut x, mut y) = (a.to_vec(), b.to_vec());
        x.sort_unstable();
        y.sort_unstable();
        x == y
    };
    let mut out = Vec::new();
    for v in 0..nv {
        let b = &bucket[start[v] as usize..start[v + 1] as usize];
        for j in 1..b.len() {
            if (0..j).any(|i| same(b[i], b[j])) {
                out.push(b[j]);
            }
        }
    }
    out.sort_unstable();
    out
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
        }
        face_start.push(corner_v.len() as u32);
        let nc = corner_v.len();
        let nv = positions.len();
        // Each corner's face and the next corner round it: arithmetic for
        // triangle meshes (corner 3f + i), two arrays for polygons.
        let triangles = face_start.windows(2).all(|w| w[1] - w[0] == 3);
        let (mut faces, mut nexts) = (Vec::new(), Vec::new());
        if !triangles {
            (faces, nexts) = (vec![0u32; nc], vec![0u32; nc]);
            for f in 0..nf {
                let (s, e) = (face_start[f] as usize, face_start[f + 1] as usize);
                for c in s..e {
                    faces[c] = f as u32;
                    nexts[c] = if c + 1 == e { s as u32 } else { c as u32 + 1 };
                }
            }
        }
        let corner_face = |c: usize| {
            if triangles {
                (c / 3) as u32
            } else {
                faces[c]
            }
        };
        let corner_next = |c: usize| {
            if triangles {
                if c % 3 == 2 {
                    c - 2
                } else {
                    c + 1
                }
            } else {
                nexts[c] as usize
            }
        };
        let corner_to: Vec<u32> = (0..nc).map(|c| corner_v[corner_next(c)]).collect();
        let head = |c: usize| corner_to[c];
        // Outgoing corners of each vertex (CSR), in corner order, with
        // their head vertices alongside (`out_to`), so that scanning a
        // vertex's outgoing edges reads two short contiguous runs.
        let mut out_start = vec![0u32; nv + 1];
        for &v in &corner_v {
            out_start[v as usize + 1] += 1;
        }
        for i in 0..nv {
            out_start[i + 1] += out_start[i];
        }
        let mut fill = out_start.clone();
        let mut out = vec![0u32; nc];
        let mut out_to = vec![0u32; nc];
        for (c, &v) in corner_v.iter().enumerate() {
            let k = fill[v as usize] as usize;
            out[k] = c as u32;
            out_to[k] = corner_to[c];
            fill[v as usize] += 1;
        }
        drop(fill);
        let range = |v: u32| out_start[v as usize] as usize..out_start[v as usize + 1] as usize;
        let outgoing = |v: u32| &out[range(v)];

        // Pair each corner a→b with an unpaired b→a (the first in corner
        // order), vertex by vertex, corners in order. Each vertex pair is
        // counted once, at its lowest corner. A corner paired cleanly from
        // the other side (exactly one corner each way) has nothing left to
        // check.
        const NONE: u32 = u32::MAX;
        let mut pair = vec![NONE; nc];
        let mut clean = vec![false; nc];
        let mut bad_face = vec![false; nf];
        let mut cut = 0usize;
        for a in 0..nv as u32 {
            let ra = range(a);
            for k in ra.clone() {
                let c = out[k] as usize;
                if clean[c] {
                    continue;
                }
                let b = out_to[k];
                let same = out_to[ra.clone()].iter().filter(|&&t| t == b).count();
                let (mut opposite, mut free) = (0usize, NONE);
                let rb = range(b);
                for (&d, &t) in out[rb.clone()].iter().zip(&out_to[rb.clone()]) {
                    if t == a {
                        opposite += 1;
                        if free == NONE && pair[d as usize] == NONE {
                            free = d;
                        }
                    }
                }
                let total = same + opposite;
                if total > 2 || same > 1 {
                    let first = ra
                        .clone()
                        .filter(|&j| out_to[j] == b)
                        .chain(rb.filter(|&j| out_to[j] == a))
                        .all(|j| out[j] as usize >= c);
                    if total > 2 {
                        report.non_manifold_edges += first as usize;
                    } else {
                        report.inconsistent_edges += first as usize;
                    }
                    bad_face[corner_face(c) as usize] = true;
                }
                if pair[c] == NONE {
                    if free != NONE {
                        pair[c] = free;
                        pair[free as usize] = c as u32;
                        clean[free as usize] = total == 2 && same == 1;
                    } else if total > 1 {
                        cut += 1;
                    }
                }
            }
        }
        drop(clean);
        report.repeated_faces = if triangles
            && report.degenerate_faces.is_empty()
            && report.non_manifold_edges + report.inconsistent_edges == 0
        {
            // Two triangles with one vertex set share all three edges, and
            // here an edge has at most two faces: a triangle is repeated
            // exactly when its three corners pair with the same earlier face.
            (0..nf)
                .filter(|&f| {
                    let g = |k: usize| match pair[3 * f + k] {
                        NONE => NONE,
                        d => corner_face(d as usize),
                    };
                    g(0) < f as u32 && g(0) == g(1) && g(0) == g(2)
                })
                .map(|f| f as u32)
                .collect()
        } else {
            repeated_faces(mesh)
        };

        // Half-edges: a paired corner pair is one edge; an unpaired corner gets a boundary twin.
        let mut corner_he = vec![HalfEdge::INVALID; nc];
        let edges = (0..nc)
            .filter(|&c| pair[c] == NONE || (c as u32) < pair[c])
            .count();
        let mut m = HalfEdgeMesh {
            positions,
            h_link: Vec::with_capacity(2 * edges),
            h_face: Vec::with_capacity(2 * edges),
            ..Self::default()
        };
        for c in 0..nc {
            if corner_he[c].is_valid() {
                continue;
            }
            let h = HalfEdge::new(m.h_link.len());
            corner_he[c] = h;
            m.h_link.push(Link {
                to: Vertex(head(c)),
                next: HalfEdge::INVALID,
            });
            m.h_face.push(Face(corner_face(c)));
            let d = pair[c];
            m.h_link.push(Link {
                to: Vertex(corner_v[c]),
                next: HalfEdge::INVALID,
            });
            if d != NONE {
                corner_he[d as usize] = h.twin();
                m.h_face.push(Face(corner_face(d as usize)));
            } else {
                m.h_face.push(Face::INVALID);
            }
        }
        report.added_edges = cut;
        for c in 0..nc {
            m.h_link[corner_he[c].idx()].next = corner_he[corner_next(c)];
        }
        m.f_half = (0..nf).map(|f| corner_he[face_start[f] as usize]).collect();

        // Fans. Around a vertex, corner c turns counter-clockwise to the
        // partner of the corner before it, clockwise to the corner after its
        // partner. A vertex is manifold when one fan reaches all its corners.
        let corner_prev = |c: usize| {
            if triangles {
                return if c % 3 == 0 { c + 2 } else { c - 1 };
            }
            let f = corner_face(c) as usize;
            if c == face_start[f] as usize {
                face_start[f + 1] as usize - 1
            } else {
                c - 1
            }
        };
        let ccw = |c: usize| {
            let p = pair[corner_prev(c)];
            (p != NONE).then_some(p as usize)
        };
        let cw = |c: usize| {
            let p = pair[c];
            (p != NONE).then(|| corner_next(p as usize))
        };
        // The corners one fan reaches from `c0`, `k` at most: turning
        // counter-clockwise until back at `c0` (a closed fan) or at a
        // boundary, then clockwise from `c0` to the other boundary. The two
        // turns are inverses, so no corner is counted twice.
        let fan_size = |c0: usize, k: usize| {
            let (mut n, mut c) = (1, c0);
            while let Some(x) = ccw(c) {
                if x == c0 || n > k {
                    return n;
                }
                (n, c) = (n + 1, x);
            }
            c = c0;
            while let Some(x) = cw(c) {
                if n > k {
                    break;
                }
                (n, c) = (n + 1, x);
            }
            n
        };
        // Fan labels, made only once a vertex has several fans.
        let mut fan_of = Vec::new();
        for v in 0..nv as u32 {
            let outs = outgoing(v);
            if outs.len() <= 1 || fan_size(outs[0] as usize, outs.len()) == outs.len() {
                // One fan reaches every corner: the common case, no labels.
                continue;
            }
            if fan_of.is_empty() {
                fan_of = vec![u32::MAX; nc];
            }
            let mut fans = 0u32;
            for &c0 in outs {
                if fan_of[c0 as usize] != u32::MAX {
                    continue;
                }
                fan_of[c0 as usize] = fans;
                for clockwise in [false, true] {
                    let mut c = c0 as usize;
                    while let Some(n) = if clockwise { cw(c) } else { ccw(c) } {
                        if fan_of[n] != u32::MAX {
                            break;
                        }
                        fan_of[n] = fans;
                        c = n;
                    }
                }
                fans += 1;
            }
            if fans <= 1 {
                continue;
            }
            report.non_manifold_vertices += 1;
            for &c in outs {
                bad_face[corner_face(c as usize) as usize] = true;
            }
            for fan in 1..fans {
                let nv2 = Vertex::new(m.positions.len());
                m.positions.push(m.positions[v as usize]);
                report.added_vertices += 1;
                for &c in outs {
                    if fan_of[c as usize] == fan {
                        let h = corner_he[c as usize];
                        m.h_link[h.twin().idx()].to = nv2;
                        m.h_link[corner_he[corner_prev(c as usize)].idx()].to = nv2;
                    }
                }
            }
        }

        // Boundary loops, and each vertex's half-edge (its boundary one if any).
        let nv = m.positions.len();
        let nh = m.h_link.len();
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
                m.h_link[h.idx()].next = boundary_out[m.to_vertex(h).idx()];
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
