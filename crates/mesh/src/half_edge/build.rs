//! Building a half-edge mesh from indexed polygons, repairing what real
//! files get wrong instead of dropping faces, and converting back.

use super::{HalfEdgeMesh, Link};
use crate::handle::{Face, HalfEdge, Vertex};
use crate::{ErrorKind, IndexedMesh, Location, MeshError};
use std::borrow::Cow;

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
    ///
    /// Corners are bucketed by their edge's lower vertex, so both ways of
    /// an edge meet in one short bucket; half-edges are numbered as the
    /// buckets are read, so a vertex's edges lie together, which makes
    /// walks around vertices cheaper. Beside the mesh, the build touches
    /// only 4 bytes per corner and 4 per vertex of new memory on triangle
    /// meshes, 8 more per corner on polygons (the buckets become the
    /// half-edges): first-touched pages cost more than the passes over them.
    pub fn build(
        mesh: &IndexedMesh,
        opts: BuildOptions,
    ) -> Result<(Self, RepairReport), MeshError> {
        const NONE: u32 = u32::MAX;
        let mut report = RepairReport::default();
        let mut positions = mesh.positions.clone();
        let face_start = mesh.face_starts();
        let nf = mesh.num_faces();
        // Corners, face by face: a face's corner c is the half-edge from
        // corner c's vertex to the next corner's. Borrowed from the mesh
        // unless a face names a vertex twice: the repeat gets a vertex of
        // its own, so that the face stays.
        let mut corners = Cow::Borrowed(mesh.indices());
        for f in 0..nf {
            let (s, e) = (face_start[f] as usize, face_start[f + 1] as usize);
            if !(s + 1..e).any(|i| corners[s..i].contains(&corners[i])) {
                continue;
            }
            report.degenerate_faces.push(f as u32);
            let cv = corners.to_mut();
            for i in s + 1..e {
                if cv[s..i].contains(&cv[i]) {
                    positions.push(positions[cv[i] as usize]);
                    report.added_vertices += 1;
                    cv[i] = (positions.len() - 1) as u32;
                }
            }
        }
        let cv: &[u32] = &corners;
        let nc = cv.len();
        let mut nv = positions.len();
        // Each corner's face and the next corner round it: arithmetic for
        // triangle meshes (corner 3f + i), two arrays for polygons.
        let triangles = mesh.is_triangle_mesh();
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

        // Corners bucketed by their edge's lower vertex (counting sort,
        // filled back to front so that each bucket is in corner order),
        // each with the upper vertex beside it; `up` marks the corners
        // that run from the lower vertex to the upper one.
        let mut valence = vec![0u32; nv];
        let mut bucket = vec![0u32; nv + 1];
        for c in 0..nc {
            let (a, b) = (cv[c], cv[corner_next(c)]);
            valence[a as usize] += 1;
            bucket[a.min(b) as usize] += 1;
        }
        let mut sum = 0;
        for n in &mut bucket[..nv] {
            sum += *n;
            *n = sum;
        }
        bucket[nv] = nc as u32;
        // Room for every half-edge (at most two per corner), so that the
        // half-edges can take this memory over later; untouched room costs
        // no pages.
        let mut entry = Vec::with_capacity(2 * nc);
        entry.resize(nc, [0u32; 2]);
        let mut up = vec![0u64; nc.div_ceil(64)];
        for c in (0..nc).rev() {
            let (a, b) = (cv[c], cv[corner_next(c)]);
            let k = &mut bucket[a.min(b) as usize];
            *k -= 1;
            entry[*k as usize] = [a.max(b), c as u32];
            up[*k as usize / 64] |= u64::from(a < b) << (*k % 64);
        }

        // Pair the corners of each edge: the k-th corner one way with the
        // k-th the other way, in corner order. An edge with more than two
        // corners, or two the same way, is reported; its corners left
        // without a partner become edges of their own (the cut).
        let mut corner_he = vec![NONE; nc];
        let mut boundary: Vec<u32> = Vec::new();
        let mut bad_face: Vec<bool> = Vec::new();
        let (mut ne, mut cut) = (0u32, 0usize);
        let mut ways = [Vec::new(), Vec::new()];
        for v in 0..nv {
            let (s, e) = (bucket[v] as usize, bucket[v + 1] as usize);
            // Entries already paired get NONE as their upper vertex.
            let b = &mut entry[s..e];
            let is_up = |i: usize| up[(s + i) / 64] >> ((s + i) % 64) & 1 == 1;
            for i in 0..b.len() {
                let [hi, c] = b[i];
                if hi == NONE {
                    continue;
                }
                // The common case: this corner and exactly one more, the other way.
                let mut more = (i + 1..b.len()).filter(|&j| b[j][0] == hi);
                match (more.next(), more.next()) {
                    (Some(j), None) if is_up(i) != is_up(j) => {
                        b[j][0] = NONE;
                        corner_he[c as usize] = 2 * ne;
                        corner_he[b[j][1] as usize] = 2 * ne + 1;
                        ne += 1;
                        continue;
                    }
                    (None, _) => {
                        // A boundary edge.
                        corner_he[c as usize] = 2 * ne;
                        boundary.push(c);
                        ne += 1;
                        continue;
                    }
                    _ => {}
                }
                // Several corners on one edge: sort them by direction.
                ways[0].clear();
                ways[1].clear();
                for j in i..b.len() {
                    if b[j][0] == hi {
                        b[j][0] = NONE;
                        ways[usize::from(is_up(j))].push(b[j][1]);
                    }
                }
                let (n0, n1) = (ways[0].len(), ways[1].len());
                if n0 + n1 > 2 {
                    report.non_manifold_edges += 1;
                } else {
                    report.inconsistent_edges += 1;
                }
                if bad_face.is_empty() {
                    bad_face = vec![false; nf];
                }
                for &c in ways[0].iter().chain(&ways[1]) {
                    bad_face[corner_face(c as usize) as usize] = true;
                }
                let pairs = n0.min(n1);
                for (&c, &d) in ways[0].iter().zip(&ways[1]) {
                    corner_he[c.min(d) as usize] = 2 * ne;
                    corner_he[c.max(d) as usize] = 2 * ne + 1;
                    ne += 1;
                }
                for &c in ways[0][pairs..].iter().chain(&ways[1][pairs..]) {
                    corner_he[c as usize] = 2 * ne;
                    boundary.push(c);
                    ne += 1;
                    cut += 1;
                }
            }
        }
        drop(up);
        report.added_edges = cut;

        // Half-edges: a corner's runs to the next corner's vertex; the twin
        // of a corner without a partner is a boundary half-edge, whose
        // `next` is linked once the fans are settled.
        let nh = 2 * ne as usize;
        // The half-edges and vertices' half-edges take over the buckets'
        // memory (collected in place), which saves touching fresh pages.
        let none = Link {
            to: Vertex::INVALID,
            next: HalfEdge::INVALID,
        };
        let mut h_link: Vec<Link> = entry.into_iter().map(|_| none).collect();
        h_link.resize(nh, none);
        let mut v_half: Vec<HalfEdge> = bucket.into_iter().map(|_| HalfEdge::INVALID).collect();
        v_half.truncate(nv);
        let mut h_face = vec![Face::INVALID; nh];
        for c in 0..nc {
            let (h, n) = (corner_he[c] as usize, corner_next(c));
            h_link[h] = Link {
                to: Vertex(cv[n]),
                next: HalfEdge(corner_he[n]),
            };
            h_face[h] = Face(corner_face(c));
            v_half[cv[c] as usize] = HalfEdge(corner_he[c]);
        }
        for &c in &boundary {
            h_link[corner_he[c as usize] as usize ^ 1].to = Vertex(cv[c as usize]);
        }
        let f_half: Vec<HalfEdge> = (0..nf)
            .map(|f| HalfEdge(corner_he[face_start[f] as usize]))
            .collect();
        // Fans. Around a vertex, an outgoing half-edge turns clockwise to
        // the next of its twin, counter-clockwise to the twin of its
        // previous; boundary twins have no `next` yet, which ends a turn.
        // A vertex is manifold when one fan reaches all its corners.
        let prev = |h_link: &[Link], h: usize| {
            let mut p = h;
            loop {
                let n = h_link[p].next.idx();
                if n == h {
                    return p;
                }
                p = n;
            }
        };
        let cw = |h_link: &[Link], h: usize| {
            let n = h_link[h ^ 1].next;
            n.is_valid().then(|| n.idx())
        };
        let ccw = |h_link: &[Link], h: usize| {
            let t = prev(h_link, h) ^ 1;
            h_link[t].next.is_valid().then_some(t)
        };
        // The corners one fan reaches from `h0`, `k` at most, and whether
        // the fan is closed: turning clockwise (one load a step) until back
        // at `h0` or at a boundary, then counter-clockwise from `h0` to the
        // other boundary. The two turns are inverses, so no corner is
        // counted twice.
        let fan_size = |h_link: &[Link], h0: usize, k: usize| {
            let (mut n, mut h) = (1, h0);
            while let Some(x) = cw(h_link, h) {
                if x == h0 || n > k {
                    return (n, true);
                }
                (n, h) = (n + 1, x);
            }
            h = h0;
            while let Some(x) = ccw(h_link, h) {
                if n > k {
                    break;
                }
                (n, h) = (n + 1, x);
            }
            (n, false)
        };
        // A triangle that repeats an earlier one on clean edges (at most two
        // faces each, consistently oriented) shares all three edges with
        // it, so at each of its vertices the two make a closed fan of two
        // corners: the vertex has several fans, or only those two corners.
        // Without such a vertex there is no repeat.
        let mut maybe_repeats = false;
        let several_fans: Vec<u32> = (0..nv as u32)
            .filter(|&v| {
                let k = valence[v as usize] as usize;
                if k <= 1 {
                    return false;
                }
                let (n, closed) = fan_size(&h_link, v_half[v as usize].idx(), k);
                maybe_repeats |= n != k || (k == 2 && closed);
                n != k
            })
            .collect();
        drop(valence);
        let clean_triangles = triangles
            && report.degenerate_faces.is_empty()
            && report.non_manifold_edges + report.inconsistent_edges == 0;
        report.repeated_faces = if !clean_triangles {
            repeated_faces(mesh)
        } else if maybe_repeats {
            // Here an edge has at most two faces: a triangle is repeated
            // exactly when its three edges' other faces are one earlier face.
            let other = |c: usize| h_face[corner_he[c] as usize ^ 1].0;
            (0..nf as u32)
                .filter(|&f| {
                    let g = other(3 * f as usize);
                    g < f && g == other(3 * f as usize + 1) && g == other(3 * f as usize + 2)
                })
                .collect()
        } else {
            Vec::new()
        };
        if !several_fans.is_empty() {
            // Rare: each such vertex's outgoing half-edges, in corner order,
            // labelled by fan; every fan after the first gets a new vertex.
            let mut slot = vec![NONE; nv];
            for (i, &v) in several_fans.iter().enumerate() {
                slot[v as usize] = i as u32;
            }
            let mut outs = vec![Vec::new(); several_fans.len()];
            for c in 0..nc {
                let s = slot[cv[c] as usize];
                if s != NONE {
                    outs[s as usize].push(corner_he[c] as usize);
                }
            }
            let mut fan_of = vec![NONE; nh];
            for (&v, outs) in several_fans.iter().zip(&outs) {
                let mut fans = 0u32;
                for &h0 in outs {
                    if fan_of[h0] != NONE {
                        continue;
                    }
                    fan_of[h0] = fans;
                    for clockwise in [false, true] {
                        let mut h = h0;
                        while let Some(n) = if clockwise {
                            cw(&h_link, h)
                        } else {
                            ccw(&h_link, h)
                        } {
                            if fan_of[n] != NONE {
                                break;
                            }
                            fan_of[n] = fans;
                            h = n;
                        }
                    }
                    fans += 1;
                }
                if fans <= 1 {
                    continue;
                }
                report.non_manifold_vertices += 1;
                if bad_face.is_empty() {
                    bad_face = vec![false; nf];
                }
                for &h in outs {
                    bad_face[h_face[h].idx()] = true;
                    if fan_of[h] == 0 {
                        v_half[v as usize] = HalfEdge::new(h);
                    }
                }
                for fan in 1..fans {
                    let v2 = Vertex::new(positions.len());
                    positions.push(positions[v as usize]);
                    report.added_vertices += 1;
                    v_half.push(HalfEdge::INVALID);
                    for &h in outs {
                        if fan_of[h] == fan {
                            h_link[h ^ 1].to = v2;
                            let p = prev(&h_link, h);
                            h_link[p].to = v2;
                            v_half[v2.idx()] = HalfEdge::new(h);
                        }
                    }
                }
            }
            nv = positions.len();
        }
        debug_assert_eq!(v_half.len(), nv);

        // Boundary loops: a boundary half-edge is its start vertex's
        // half-edge, and the next of the boundary half-edge that ends there.
        for &c in &boundary {
            let h = corner_he[c as usize] as usize;
            v_half[h_link[h].to.idx()] = HalfEdge::new(h ^ 1);
        }
        for &c in &boundary {
            let b = corner_he[c as usize] as usize ^ 1;
            h_link[b].next = v_half[h_link[b].to.idx()];
        }
        if !bad_face.is_empty() {
            report.affected_faces = (0..nf as u32).filter(|&f| bad_face[f as usize]).collect();
        }
        let m = HalfEdgeMesh {
            positions,
            v_half,
            h_link,
            h_face,
            f_half,
            garbage: None,
        };

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
    /// Deleted faces are left out; deleted vertices stay, unused, until
    /// [`Self::garbage_collect`] renumbers them away.
    #[must_use]
    pub fn to_indexed(&self) -> IndexedMesh {
        let mut out =
            IndexedMesh::with_capacity(self.num_vertices(), self.num_faces(), self.num_halfedges());
        out.positions = self.positions.clone();
        let mut face = Vec::new();
        for f in self.faces() {
            if self.is_deleted_face(f) {
                continue;
            }
            face.clear();
            face.extend(self.face_vertices(f).map(|v| v.0));
            out.push_face_unchecked(&face);
        }
        out
    }
}
