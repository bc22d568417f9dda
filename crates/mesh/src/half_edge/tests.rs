//! Half-edge mesh tests: real meshes, repairs, walks, subdivision.

use super::*;
use crate::io::read_mesh;
use crate::IndexedMesh;
use proptest::prelude::*;
use std::collections::HashMap;
use std::path::PathBuf;

fn data(name: &str) -> IndexedMesh {
    read_mesh(
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data")
            .join(name),
    )
    .unwrap()
}

fn build(m: &IndexedMesh) -> (HalfEdgeMesh, RepairReport) {
    let (h, r) = HalfEdgeMesh::build(m, BuildOptions::default()).unwrap();
    h.validate().unwrap_or_else(|e| panic!("invalid: {e}"));
    (h, r)
}

#[test]
fn fixtures_build_clean_with_the_right_topology() {
    // name, V, E, F, boundary loops, components, χ, genus
    for (name, v, e, f, b, c, chi, g) in [
        ("tetrahedron.off", 4, 6, 4, 0, 1, 2, 0),
        ("cube_quad.off", 8, 12, 6, 0, 1, 2, 0),
        ("sphere.ply", 162, 480, 320, 0, 1, 2, 0),
        ("double-torus-example.off", 231, 453, 220, 0, 1, -2, 2),
        ("mesh_with_border.off", 548, 1561, 1014, 1, 1, 1, 0),
    ] {
        let (h, r) = build(&data(name));
        assert!(r.is_clean(), "{name}: {r:?}");
        let got = (
            h.num_vertices(),
            h.num_edges(),
            h.num_faces(),
            h.boundary_loops().len(),
            h.components().0,
            h.euler_characteristic(),
            h.genus(),
        );
        assert_eq!(got, (v, e, f, b, c, chi, g), "{name}");
    }
}

#[test]
fn round_trip_keeps_faces_in_order() {
    for name in ["cube_quad.off", "elephant-with-holes.off", "sphere.ply"] {
        let m = data(name);
        let (h, r) = build(&m);
        if r.is_clean() {
            assert_eq!(h.to_indexed(), m, "{name}");
        }
        assert_eq!(h.num_faces(), m.num_faces());
    }
}

#[test]
fn walks_are_counter_clockwise_and_complete() {
    // A fan of 6 triangles around vertex 0 in the z = 0 plane, CCW seen from +z.
    let mut p = vec![Vec3::ZERO];
    for i in 0..6 {
        let a = i as f32 * std::f32::consts::TAU / 6.0;
        p.push(Vec3::new(a.cos(), a.sin(), 0.0));
    }
    let tris: Vec<[u32; 3]> = (0..6).map(|i| [0, 1 + i, 1 + (i + 1) % 6]).collect();
    let (h, _) = build(&IndexedMesh::from_triangles(p.clone(), &tris).unwrap());
    let ring: Vec<u32> = h.vertex_vertices(Vertex(0)).map(|v| v.0).collect();
    assert_eq!(ring.len(), 6);
    for w in ring.windows(2) {
        let (a, b) = (p[w[0] as usize], p[w[1] as usize]);
        assert!(a.cross(b).z > 0.0, "not counter-clockwise: {ring:?}");
    }
    assert_eq!(h.valence(Vertex(0)), 6);
    assert_eq!(h.vertex_faces(Vertex(0)).count(), 6);
    assert!(!h.is_boundary_vertex(Vertex(0)));
    // A boundary vertex: 3 edges, 2 faces, starts at its boundary half-edge.
    assert!(h.is_boundary_vertex(Vertex(1)));
    assert_eq!(h.valence(Vertex(1)), 3);
    assert_eq!(h.vertex_faces(Vertex(1)).count(), 2);
    let ring1: Vec<u32> = h.vertex_vertices(Vertex(1)).map(|v| v.0).collect();
    assert_eq!(ring1.len(), 3);
    // Faces: vertices in input order, three neighbours for an inner triangle.
    assert_eq!(
        h.face_vertices(Face(2)).map(|v| v.0).collect::<Vec<_>>(),
        vec![0, 3, 4]
    );
    assert_eq!(h.face_faces(Face(2)).count(), 2);
    assert_eq!(h.boundary_loops().len(), 1);
    assert_eq!(h.boundary_loops()[0].len(), 6);
}

#[test]
fn repairs_keep_every_face_and_report_them() {
    let p = |n: usize| {
        (0..n)
            .map(|i| Vec3::new(i as f32, (i * i % 7) as f32, (i % 3) as f32))
            .collect::<Vec<_>>()
    };
    // Bowtie: two triangles sharing only vertex 0.
    let (h, r) = build(&IndexedMesh::from_triangles(p(5), &[[0, 1, 2], [0, 3, 4]]).unwrap());
    assert_eq!(
        (r.non_manifold_vertices, r.added_vertices, h.num_faces()),
        (1, 1, 2)
    );
    // Three triangles on edge 0-1.
    let (h, r) =
        build(&IndexedMesh::from_triangles(p(5), &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap());
    assert_eq!((r.non_manifold_edges, h.num_faces()), (1, 3));
    assert!(r.added_edges >= 1);
    // Two triangles running the same way along 0-1.
    let (h, r) = build(&IndexedMesh::from_triangles(p(4), &[[0, 1, 2], [0, 1, 3]]).unwrap());
    assert_eq!((r.inconsistent_edges, h.num_faces()), (1, 2));
    // A repeated face, and a face naming a vertex twice.
    let (h, r) =
        build(&IndexedMesh::from_triangles(p(4), &[[0, 1, 2], [1, 2, 0], [0, 0, 3]]).unwrap());
    assert_eq!(r.repeated_faces, vec![1]);
    assert_eq!(r.degenerate_faces, vec![2]);
    assert_eq!(h.num_faces(), 3);
    // A closed pillow (one triangle, both ways round) beside a triangle:
    // every edge has two faces, and the second face repeats the first.
    let (h, r) = build(
        &IndexedMesh::from_triangles(p(6), &[[3, 4, 5], [0, 1, 2], [2, 1, 0], [1, 0, 2]]).unwrap(),
    );
    assert_eq!(r.repeated_faces, vec![2, 3]);
    assert_eq!(h.num_faces(), 4);
    let (_, r) =
        build(&IndexedMesh::from_triangles(p(6), &[[3, 4, 5], [0, 1, 2], [2, 1, 0]]).unwrap());
    assert_eq!(r.repeated_faces, vec![2]);
    assert_eq!(r.non_manifold_edges + r.inconsistent_edges, 0);
    // Strict mode names the faces.
    let m = IndexedMesh::from_triangles(p(5), &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap();
    let e = HalfEdgeMesh::build(&m, BuildOptions { strict: true })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("1 non-manifold edges") && e.contains("faces 0, 1, 2"),
        "{e}"
    );
}

#[test]
fn loop_and_catmull_clark_counts_and_validity() {
    let (h, _) = build(&data("sphere.ply"));
    let l = h.loop_subdivide().unwrap();
    assert_eq!(l.num_vertices(), 162 + 480);
    assert_eq!(l.num_faces(), 4 * 320);
    let (h2, r) = build(&l);
    assert!(r.is_clean());
    assert_eq!((h2.euler_characteristic(), h2.genus()), (2, 0));
    // Loop's limit surface of a convex mesh lies inside its hull: the radius shrinks.
    let max_r = |m: &IndexedMesh| {
        m.positions
            .iter()
            .map(|p| p.length())
            .fold(0.0f32, f32::max)
    };
    assert!(max_r(&l) <= max_r(&data("sphere.ply")) + 1e-6);
    // An open mesh keeps one boundary loop, twice as long.
    let (b, _) = build(&data("mesh_with_border.off"));
    let (b2, _) = build(&b.loop_subdivide().unwrap());
    assert_eq!(b2.boundary_loops().len(), 1);
    assert_eq!(
        b2.boundary_loops()[0].len(),
        2 * b.boundary_loops()[0].len()
    );
    // Quads refuse Loop; Catmull–Clark makes quads.
    let (c, _) = build(&data("cube_quad.off"));
    assert!(c.loop_subdivide().is_none());
    let cc = c.catmull_clark();
    assert_eq!((cc.num_vertices(), cc.num_faces()), (26, 24));
    assert!(cc.faces().all(|f| f.len() == 4));
    let (c2, r) = build(&cc);
    assert!(r.is_clean());
    assert_eq!(c2.euler_characteristic(), 2);
    // Cube corners move inward, towards the sphere the limit resembles.
    assert!(cc.positions[0].length() < 3f32.sqrt());
}

#[test]
fn normals_point_out_of_a_closed_mesh() {
    let (h, _) = build(&data("sphere.ply"));
    for (v, n) in h.vertex_normals().iter().enumerate() {
        let p = h.position(Vertex::new(v)).normalize();
        assert!(n.dot(p) > 0.95, "vertex {v}: {n} vs {p}");
    }
}

/// The half-edge mesh's normals (gathered around vertices, with a fast
/// arctangent) match the indexed mesh's (scattered from faces, with `acos`)
/// on closed and open meshes, quads, holes and degenerate triangles.
/// A mixed open mesh: a quad and a triangle sharing an edge, and a
/// pentagon apart.
fn mixed_polygons() -> IndexedMesh {
    let mut m = IndexedMesh::new();
    m.positions = vec![
        Vec3::ZERO,
        Vec3::X,
        Vec3::new(1.0, 1.0, 0.2),
        Vec3::Y,
        Vec3::new(0.5, -1.0, 0.3),
        Vec3::new(2.0, 0.0, 0.0),
        Vec3::new(3.0, 0.0, 0.1),
        Vec3::new(3.0, 1.0, 0.0),
        Vec3::new(2.5, 1.5, 0.0),
        Vec3::new(2.0, 1.0, 0.0),
    ];
    for f in [&[0u32, 1, 2, 3][..], &[0, 4, 1], &[5, 6, 7, 8, 9]] {
        m.push_face_unchecked(f);
    }
    m
}

#[test]
fn normals_match_the_indexed_meshs() {
    for name in [
        "sphere.ply",
        "mesh_with_border.off",
        "cube_quad.off",
        "elephant-with-holes.off",
        "degtri_sliding.off",
        "double-torus-example.off",
    ] {
        let (h, _) = build(&data(name));
        let flat = crate::normals::vertex_normals(&h.to_indexed());
        let gathered = h.vertex_normals();
        assert_eq!(flat.len(), gathered.len());
        for (v, (a, b)) in flat.iter().zip(&gathered).enumerate() {
            // The fast arctangent is within 2e-5 rad of `acos`; on the
            // sphere's regular triangles the two agree more closely.
            let tol = if name == "sphere.ply" { 1e-5 } else { 1e-4 };
            assert!((*a - *b).length() < tol, "{name} vertex {v}: {a} vs {b}");
        }
    }
    let m = mixed_polygons();
    let (h, _) = build(&m);
    let flat = crate::normals::vertex_normals(&m);
    for (v, (a, b)) in flat.iter().zip(h.vertex_normals()).enumerate() {
        assert!((*a - b).length() < 1e-4, "vertex {v}: {a} vs {b}");
    }
}

/// Deleted faces add nothing: normals after deleting faces equal those
/// after collecting the garbage.
#[test]
fn normals_skip_deleted_faces() {
    let (mut h, _) = build(&data("sphere.ply"));
    for f in (0..h.num_faces()).step_by(7) {
        h.delete_face(Face::new(f));
    }
    // A deleted face has no half-edges left to walk (they joined other loops).
    assert_eq!(h.face_halfedges(Face::new(0)).count(), 0);
    assert_eq!(h.face_normal(Face::new(0)), Vec3::ZERO);
    let live = (0..h.num_faces())
        .filter(|&f| !h.is_deleted_face(Face::new(f)))
        .count();
    assert_eq!(h.to_indexed().num_faces(), live);
    let before = h.vertex_normals();
    let kept: Vec<Vec3> = (0..h.num_vertices())
        .filter(|&v| !h.is_deleted_vertex(Vertex::new(v)))
        .map(|v| before[v])
        .collect();
    h.garbage_collect();
    let after = h.vertex_normals();
    assert_eq!(kept.len(), after.len());
    for (a, b) in kept.iter().zip(&after) {
        assert!((*a - *b).length() < 1e-6, "{a} vs {b}");
    }
}

#[test]
fn memory_is_within_96_bytes_per_vertex_on_a_closed_triangle_mesh() {
    let (h, _) = build(&data("sphere.ply"));
    let per_vertex = h.memory_bytes() as f64 / h.num_vertices() as f64;
    assert!(per_vertex <= 96.0, "{per_vertex}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any soup of triangles over few vertices (so non-manifold edges,
    /// fans, flips, repeats and degenerate faces abound) builds into a valid
    /// mesh that keeps every face and converts back face for face.
    #[test]
    fn any_soup_builds_valid_and_keeps_every_face(tris in proptest::collection::vec((0u32..7, 0u32..7, 0u32..7), 0..25)) {
        let p: Vec<Vec3> = (0..7).map(|i| Vec3::new(i as f32, (i * 3 % 5) as f32, (i % 2) as f32)).collect();
        let tris: Vec<[u32; 3]> = tris.into_iter().map(|(a, b, c)| [a, b, c]).collect();
        let m = IndexedMesh::from_triangles(p, &tris).unwrap();
        let (h, r) = HalfEdgeMesh::build(&m, BuildOptions::default()).unwrap();
        prop_assert!(h.validate().is_ok(), "{:?} -> {:?}", tris, h.validate());
        prop_assert_eq!(h.num_faces(), tris.len());
        let back = h.to_indexed();
        // Same faces, up to the vertices that repairs duplicated (same positions).
        for (f, t) in back.faces().zip(&tris) {
            let pos = |i: u32| back.positions[i as usize];
            prop_assert_eq!([pos(f[0]), pos(f[1]), pos(f[2])], [m.positions[t[0] as usize], m.positions[t[1] as usize], m.positions[t[2] as usize]]);
        }
        if r.is_clean() {
            prop_assert_eq!(&back, &m);
        }
        // The builder finds repeats from its edge pairing where it can:
        // the same faces as comparing vertex sets.
        prop_assert_eq!(&r.repeated_faces, &super::build::repeated_faces(&m), "{:?}", tris);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    /// Few triangles, some repeated with either winding and in any
    /// rotation (closed pillows, which leave every edge with two faces):
    /// the repeats found from the edge pairing are exactly the faces whose
    /// vertex set an earlier face has.
    #[test]
    fn repeats_found_from_the_pairing_match_vertex_sets(
        tris in proptest::collection::vec((0u32..9, 0u32..9, 0u32..9), 1..5),
        copies in proptest::collection::vec((0usize..5, any::<bool>(), 0usize..3, 0usize..6), 0..4),
    ) {
        let p: Vec<Vec3> = (0..9).map(|i| Vec3::new(i as f32, (i * 3 % 5) as f32, (i % 2) as f32)).collect();
        let mut all: Vec<[u32; 3]> = tris.into_iter().map(|(a, b, c)| [a, b, c]).collect();
        for (i, flip, rot, at) in copies {
            let mut t = all[i % all.len()];
            if flip {
                t.swap(1, 2);
            }
            t.rotate_left(rot);
            all.insert(at.min(all.len()), t);
        }
        let m = IndexedMesh::from_triangles(p, &all).unwrap();
        let (h, r) = HalfEdgeMesh::build(&m, BuildOptions::default()).unwrap();
        prop_assert!(h.validate().is_ok());
        prop_assert_eq!(&r.repeated_faces, &super::build::repeated_faces(&m), "{:?}", all);
    }
}

/// Whether `b` is a rotation of `a`.
fn same_cycle(a: &[u32], b: &[u32]) -> bool {
    a.len() == b.len()
        && (a.is_empty()
            || (0..a.len()).any(|k| a.iter().cycle().skip(k).take(a.len()).eq(b.iter())))
}

#[test]
fn winged_edge_and_compact_agree_with_half_edge() {
    use crate::{CompactMesh, WingedEdgeMesh};
    for name in [
        "sphere.ply",
        "mesh_with_border.off",
        "elephant-with-holes.off",
        "double-torus-example.off",
        "cube_quad.off",
    ] {
        let (h, _) = build(&data(name));
        let w = WingedEdgeMesh::from_half_edge(&h);
        let c = CompactMesh::from_half_edge(&h);
        assert_eq!(c.is_some(), h.is_triangle_mesh(), "{name}");
        for v in h.vertices() {
            let ring: Vec<u32> = h.vertex_vertices(v).map(|x| x.0).collect();
            let wring: Vec<u32> = w.vertices_of_vertex(v).map(|x| x.0).collect();
            assert_eq!(ring, wring, "{name}: winged-edge ring of {}", v.0);
            if let Some(c) = &c {
                let cring: Vec<u32> = c.vertex_vertices(v).map(|x| x.0).collect();
                assert!(
                    same_cycle(&ring, &cring),
                    "{name}: compact ring of {}: {ring:?} vs {cring:?}",
                    v.0
                );
            }
        }
        for f in h.faces() {
            let fv: Vec<u32> = h.face_vertices(f).map(|x| x.0).collect();
            let wv: Vec<u32> = w.vertices_of_face(f).map(|x| x.0).collect();
            assert!(same_cycle(&fv, &wv), "{name}: face {}", f.0);
            assert_eq!(h.face_faces(f).count(), w.faces_of_face(f).count());
        }
        // Back to indexed form: the same faces (up to where each face starts).
        let (hi, wi) = (h.to_indexed(), w.to_indexed());
        assert_eq!(hi.positions, wi.positions);
        for (a, b) in hi.faces().zip(wi.faces()) {
            assert!(same_cycle(a, b), "{name}: winged-edge face {a:?} vs {b:?}");
        }
        if let Some(c) = &c {
            assert_eq!(c.to_indexed(), hi, "{name}: compact");
        }
        let per_vertex = |bytes: usize| bytes as f64 / h.num_vertices() as f64;
        assert!(per_vertex(w.memory_bytes()) > per_vertex(h.memory_bytes()));
        if let Some(c) = &c {
            assert!(per_vertex(c.memory_bytes()) < per_vertex(h.memory_bytes()));
            // Issue 3's bound, with 12-byte positions.
            assert!(per_vertex(c.memory_bytes()) <= 56.0, "{name}");
        }
    }
}

#[derive(Clone, Debug)]
enum Op {
    Flip(usize),
    Split(usize, f32),
    SplitFace(usize),
    Collapse(usize),
    Collect,
    DeleteFace(usize),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        3 => any::<usize>().prop_map(Op::Flip),
        2 => (any::<usize>(), 0.1f32..0.9).prop_map(|(e, t)| Op::Split(e, t)),
        1 => any::<usize>().prop_map(Op::SplitFace),
        3 => any::<usize>().prop_map(Op::Collapse),
        1 => Just(Op::Collect),
    ]
}

/// Applies one edit; returns whether it changed the mesh.
fn apply(m: &mut HalfEdgeMesh, op: &Op) -> bool {
    if m.num_edges() == 0 && !matches!(op, Op::Collect) {
        return false;
    }
    match *op {
        Op::Flip(e) => m.flip(Edge::new(e % m.num_edges())),
        Op::Split(e, t) => {
            let e = Edge::new(e % m.num_edges());
            if m.is_deleted_edge(e) {
                return false;
            }
            let (a, b) = (
                m.position(m.to_vertex(e.halfedge(0))),
                m.position(m.to_vertex(e.halfedge(1))),
            );
            m.split(e, a.lerp(b, t)).is_some()
        }
        Op::SplitFace(f) => {
            if m.num_faces() == 0 {
                return false;
            }
            let f = Face::new(f % m.num_faces());
            if m.is_deleted_face(f) {
                return false;
            }
            let corners: Vec<Vec3> = m.face_vertices(f).map(|v| m.position(v)).collect();
            let centre = corners.iter().copied().sum::<Vec3>() / corners.len() as f32;
            m.split_face(f, centre).is_some()
        }
        Op::Collapse(h) => m.collapse(HalfEdge::new(h % m.num_halfedges())),
        Op::Collect => {
            m.garbage_collect();
            true
        }
        Op::DeleteFace(f) => {
            if m.num_faces() == 0 {
                return false;
            }
            let f = Face::new(f % m.num_faces());
            let live = !m.is_deleted_face(f);
            m.delete_face(f);
            live
        }
    }
}

/// Cases of the edit property test; raise with `RAYMESH_PROPTEST_CASES`.
fn edit_cases() -> u32 {
    std::env::var("RAYMESH_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: edit_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    /// Random flips, splits and collapses on real meshes, closed and open:
    /// the mesh validates after every step, and its Euler characteristic
    /// and boundary never change (each edit is a local, topology-keeping move).
    #[test]
    fn random_edits_keep_the_mesh_valid(mesh in 0usize..3, ops in proptest::collection::vec(op(), 1..60)) {
        let name = ["sphere.ply", "mesh_with_border.off", "tetrahedron.off"][mesh];
        let (mut m, _) = build(&data(name));
        let chi = m.euler_characteristic();
        let loops = m.boundary_loops().len();
        for (i, o) in ops.iter().enumerate() {
            apply(&mut m, o);
            prop_assert!(m.validate().is_ok(), "{name}: step {i} {o:?}: {:?}", m.validate());
            let mut g = m.clone();
            g.garbage_collect();
            prop_assert_eq!(g.euler_characteristic(), chi, "{} after step {} {:?}", name, i, o);
            prop_assert_eq!(g.boundary_loops().len(), loops);
        }
    }
}

fn op_with_deletes() -> impl Strategy<Value = Op> {
    prop_oneof![4 => op(), 1 => any::<usize>().prop_map(Op::DeleteFace)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: edit_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    /// Edits mixed with face deletions keep the mesh valid, and each
    /// deletion removes exactly one face.
    #[test]
    fn random_edits_with_deletions_keep_the_mesh_valid(mesh in 0usize..3, ops in proptest::collection::vec(op_with_deletes(), 1..60)) {
        let name = ["sphere.ply", "mesh_with_border.off", "cube_quad.off"][mesh];
        let (mut m, _) = build(&data(name));
        for (i, o) in ops.iter().enumerate() {
            let live = |m: &HalfEdgeMesh| m.faces().filter(|&f| !m.is_deleted_face(f)).count();
            let before = live(&m);
            let changed = apply(&mut m, o);
            prop_assert!(m.validate().is_ok(), "{name}: step {i} {o:?}: {:?}", m.validate());
            if let Op::DeleteFace(_) = o {
                prop_assert_eq!(live(&m), before - changed as usize);
            }
        }
        m.garbage_collect();
        prop_assert!(m.validate().is_ok());
        prop_assert_eq!(m.to_indexed().num_faces(), m.num_faces());
    }
}

#[test]
fn deleting_faces_by_hand() {
    // Deleting both faces of a square leaves nothing; deleting one leaves a triangle.
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    let (mut m, _) = build(&IndexedMesh::from_triangles(p, &[[0, 1, 2], [0, 2, 3]]).unwrap());
    m.delete_face(Face(1));
    m.validate().unwrap();
    m.garbage_collect();
    assert_eq!((m.num_vertices(), m.num_edges(), m.num_faces()), (3, 3, 1));
    assert_eq!(m.boundary_loops().len(), 1);
    m.delete_face(Face(0));
    m.garbage_collect();
    assert_eq!((m.num_vertices(), m.num_edges(), m.num_faces()), (0, 0, 0));
    // A hole in a closed mesh: one boundary loop of the face's size.
    let (mut s, _) = build(&data("sphere.ply"));
    s.delete_face(Face(7));
    s.garbage_collect();
    s.validate().unwrap();
    assert_eq!(
        (
            s.num_faces(),
            s.boundary_loops().len(),
            s.boundary_loops()[0].len()
        ),
        (319, 1, 3)
    );
    assert_eq!(s.euler_characteristic(), 1);
}

#[test]
fn flip_split_collapse_by_hand() {
    // Two triangles forming a square: flip the diagonal, then split it, then collapse it back.
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    let (mut m, _) = build(&IndexedMesh::from_triangles(p, &[[0, 1, 2], [0, 2, 3]]).unwrap());
    let diag = m.edges().find(|&e| !m.is_boundary_edge(e)).unwrap();
    assert!(m.flip(diag));
    m.validate().unwrap();
    let ends = [
        m.to_vertex(diag.halfedge(0)).0,
        m.to_vertex(diag.halfedge(1)).0,
    ];
    assert!(ends.contains(&1) && ends.contains(&3), "{ends:?}");
    let v = m.split(diag, Vec3::new(0.5, 0.5, 0.0)).unwrap();
    m.validate().unwrap();
    assert_eq!((m.num_vertices(), m.num_faces(), m.valence(v)), (5, 4, 4));
    // The centre joins two boundary vertices by interior edges only: collapsing
    // it onto a corner would join two boundaries through the interior.
    let out: Vec<HalfEdge> = m.outgoing_halfedges(v).collect();
    assert!(out.iter().all(|&h| !m.is_boundary_halfedge(h)));
    let collapsed = out.iter().any(|&h| m.collapse(h));
    assert!(collapsed);
    m.validate().unwrap();
    m.garbage_collect();
    m.validate().unwrap();
    assert_eq!((m.num_vertices(), m.num_faces()), (4, 2));
    // A boundary edge of a single triangle cannot be flipped or collapsed.
    let (mut t, _) = build(
        &IndexedMesh::from_triangles(vec![Vec3::ZERO, Vec3::X, Vec3::Y], &[[0, 1, 2]]).unwrap(),
    );
    assert!(!t.flip(Edge(0)));
    assert!(!t.collapse(HalfEdge(0)));
}

/// `find_halfedge` names each half-edge by its two vertices, and finds
/// none between vertices no edge joins, nor from a deleted vertex.
#[test]
fn find_halfedge_finds_each_half_edge_by_its_vertices() {
    for name in [
        "elephant-with-holes.off",
        "mesh_with_border.off",
        "cube_quad.off",
    ] {
        let (mut h, _) = build(&data(name));
        for i in 0..h.num_halfedges() {
            let he = HalfEdge::new(i);
            let (a, b) = (h.from_vertex(he), h.to_vertex(he));
            assert_eq!(h.find_halfedge(a, b), Some(he), "{name}: half-edge {i}");
        }
        // Every pair of vertices of one face that no edge joins: a
        // quad's diagonals, and around each vertex its neighbours'
        // other neighbours.
        let v0 = Vertex::new(0);
        let ring: Vec<Vertex> = h.vertex_vertices(v0).collect();
        for w in (0..h.num_vertices()).map(Vertex::new) {
            let joined = ring.contains(&w);
            assert_eq!(
                h.find_halfedge(v0, w).is_some(),
                joined,
                "{name}: 0 -> {w:?}"
            );
            assert_eq!(
                h.find_halfedge(w, v0).is_some(),
                joined,
                "{name}: {w:?} -> 0"
            );
        }
        // A collapsed-away vertex has no half-edges left (the cube's
        // quads take no collapse).
        let Some(he) = (0..h.num_halfedges())
            .map(HalfEdge::new)
            .find(|&he| h.is_collapse_ok(he))
        else {
            assert_eq!(name, "cube_quad.off");
            continue;
        };
        let gone = h.from_vertex(he);
        assert!(h.collapse(he));
        assert!(h.is_deleted_vertex(gone));
        for w in (0..h.num_vertices()).map(Vertex::new) {
            assert_eq!(h.find_halfedge(gone, w), None, "{name}: deleted {gone:?}");
        }
    }
}

/// A face split by hand: one triangle becomes three around the new
/// vertex, which sees the three corners; a quad is refused unchanged.
#[test]
fn split_face_makes_three_triangles_around_the_new_vertex() {
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    let (mut m, _) = build(&IndexedMesh::from_triangles(p, &[[0, 1, 2], [0, 2, 3]]).unwrap());
    let chi = m.euler_characteristic();
    let v = m.split_face(Face(0), Vec3::new(0.7, 0.3, 0.0)).unwrap();
    m.validate().unwrap();
    assert_eq!(v, Vertex(4));
    assert_eq!((m.num_vertices(), m.num_edges(), m.num_faces()), (5, 8, 4));
    assert_eq!(m.euler_characteristic(), chi);
    let mut ring: Vec<u32> = m.vertex_vertices(v).map(|w| w.0).collect();
    ring.sort_unstable();
    assert_eq!(ring, [0, 1, 2]);
    assert!(!m.is_boundary_vertex(v));
    // Every face a triangle of the new vertex but the untouched one, each
    // wound as the split face was (counter-clockwise seen from +z).
    for f in m.faces() {
        let c: Vec<Vec3> = m.face_vertices(f).map(|w| m.position(w)).collect();
        assert_eq!(c.len(), 3);
        assert!((c[1] - c[0]).cross(c[2] - c[0]).z > 0.0, "face {f:?}");
    }
    let out = m.to_indexed();
    assert_eq!(out.num_faces(), 4);
    // A deleted face and a quad are refused, the mesh unchanged.
    m.delete_face(Face(1));
    let before = m.clone();
    assert_eq!(m.split_face(Face(1), Vec3::ZERO), None);
    assert_eq!(m, before);
    let (mut q, _) = build(&data("cube_quad.off"));
    let before = q.clone();
    assert_eq!(q.split_face(Face(0), Vec3::ZERO), None);
    assert_eq!(q, before);
}

/// Moving vertices changes positions and normals, never the connectivity.
#[test]
fn moved_vertices_keep_their_connectivity() {
    let (mut m, _) = build(&data("sphere.ply"));
    let before = m.clone();
    let v = Vertex(3);
    m.set_position(v, Vec3::new(5.0, 6.0, 7.0));
    assert_eq!(m.position(v), Vec3::new(5.0, 6.0, 7.0));
    for p in m.positions_mut() {
        *p *= 2.0;
    }
    assert_eq!(m.position(v), Vec3::new(10.0, 12.0, 14.0));
    assert_eq!(m.position(Vertex(0)), before.position(Vertex(0)) * 2.0);
    m.validate().unwrap();
    assert_eq!(
        m.to_indexed().faces().count(),
        before.to_indexed().faces().count()
    );
    for w in (0..m.num_vertices()).map(Vertex::new) {
        assert!(m.vertex_vertices(w).eq(before.vertex_vertices(w)));
    }
    // The moved vertex's neighbours' normals turn towards it.
    let (n0, n1) = (before.vertex_normals(), m.vertex_normals());
    assert!(m
        .vertex_vertices(v)
        .any(|w| (n0[w.idx()] - n1[w.idx()]).length() > 1e-3));
}

/// A subdivision step written straight into a half-edge mesh (`direct`)
/// against the same step's indexed mesh (`indexed`) and the half-edge
/// mesh built from it: valid, written out as the indexed mesh face for
/// face, with the built mesh's positions, edge count, one-rings (as
/// sets), boundary vertices and boundary loops (as lengths).
fn assert_same_step(direct: &HalfEdgeMesh, indexed: &IndexedMesh, what: &str) {
    direct.validate().unwrap();
    let (rebuilt, report) = build(indexed);
    assert!(report.is_clean(), "{what}");
    assert_eq!(&direct.to_indexed(), indexed, "{what}");
    assert_eq!(direct.positions(), rebuilt.positions(), "{what}");
    assert_eq!(
        (direct.num_edges(), direct.num_halfedges()),
        (rebuilt.num_edges(), rebuilt.num_halfedges()),
        "{what}"
    );
    for v in direct.vertices() {
        let mut a: Vec<u32> = direct.vertex_vertices(v).map(|w| w.0).collect();
        let mut b: Vec<u32> = rebuilt.vertex_vertices(v).map(|w| w.0).collect();
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "{what}: vertex {v:?}");
        assert_eq!(
            direct.is_boundary_vertex(v),
            rebuilt.is_boundary_vertex(v),
            "{what}"
        );
    }
    let loops = |m: &HalfEdgeMesh| {
        let mut l: Vec<usize> = m.boundary_loops().iter().map(Vec::len).collect();
        l.sort_unstable();
        l
    };
    assert_eq!(loops(direct), loops(&rebuilt), "{what}");
}

/// The Loop step written straight into a half-edge mesh is the mesh that
/// building from the indexed step gives: the same positions and faces
/// (corners in the same order), valid, with the same one-rings and
/// boundaries, over closed and open meshes, a mesh with an isolated
/// vertex, three levels in a row, and a mesh with deleted faces.
#[test]
fn loop_subdivided_is_the_rebuilt_loop_step() {
    let same = |h: &HalfEdgeMesh, what: &str| {
        let direct = h.loop_subdivided().unwrap();
        let mut g = h.clone();
        g.garbage_collect();
        assert_same_step(&direct, &g.loop_subdivide().unwrap(), what);
        direct
    };
    for name in [
        "sphere.ply",
        "mesh_with_border.off",
        "tetrahedron.off",
        "elephant-with-holes.off",
        "degtri_sliding.off",
    ] {
        let (mut h, _) = build(&data(name));
        for level in 0..3 {
            h = same(&h, &format!("{name}, level {level}"));
        }
    }
    // Three levels chained straight and three through indexed meshes:
    // the same surface, though after the first level the two number their
    // vertices otherwise (each level numbers its new vertices by the last
    // one's edges, which the two number differently) and round Loop's
    // vertex rule a little otherwise (each sums a vertex's neighbours
    // from where its ring starts). So vertices are named by how they were
    // made: the input's by index, each edge's new one by its two ends'
    // names; faces are compared as their corners' names, and positions
    // by name, within rounding.
    fn step_names(
        h: &HalfEdgeMesh,
        names: &[u64],
        intern: &mut HashMap<(u64, u64), u64>,
    ) -> Vec<u64> {
        let mut out = names.to_vec();
        for e in h.edges() {
            let (a, b) = (
                names[h.to_vertex(e.halfedge(0)).idx()],
                names[h.to_vertex(e.halfedge(1)).idx()],
            );
            let fresh = (1u64 << 32) + intern.len() as u64;
            out.push(*intern.entry((a.min(b), a.max(b))).or_insert(fresh));
        }
        out
    }
    let named = |m: &IndexedMesh, names: &[u64]| {
        let mut faces: Vec<[u64; 3]> = m
            .faces()
            .map(|f| {
                let c = [
                    names[f[0] as usize],
                    names[f[1] as usize],
                    names[f[2] as usize],
                ];
                let i = (0..3).min_by_key(|&i| c[i]).unwrap();
                [c[i], c[(i + 1) % 3], c[(i + 2) % 3]]
            })
            .collect();
        faces.sort_unstable();
        let at: HashMap<u64, Vec3> = names
            .iter()
            .copied()
            .zip(m.positions.iter().copied())
            .collect();
        (faces, at)
    };
    for name in ["elephant-with-holes.off", "sphere.ply"] {
        let mut intern = HashMap::new();
        let (mut chained, _) = build(&data(name));
        let mut rebuilt = chained.clone();
        let mut names_c: Vec<u64> = (0..chained.num_vertices() as u64).collect();
        let mut names_r = names_c.clone();
        for _ in 0..3 {
            names_c = step_names(&chained, &names_c, &mut intern);
            names_r = step_names(&rebuilt, &names_r, &mut intern);
            chained = chained.loop_subdivided().unwrap();
            rebuilt = build(&rebuilt.loop_subdivide().unwrap()).0;
        }
        let (fc, pc) = named(&chained.to_indexed(), &names_c);
        let (fr, pr) = named(&rebuilt.to_indexed(), &names_r);
        assert_eq!(fc, fr, "{name}");
        assert_eq!(pc.len(), pr.len(), "{name}");
        let mut differ = 0;
        for (k, p) in &pc {
            let q = pr[k];
            assert!(
                (*p - q).length() <= 1e-5 * (1.0 + q.length()),
                "{name}: {p} vs {q}"
            );
            differ += usize::from(*p != q);
        }
        // Rounding apart, they are the same numbers.
        assert!(differ < pc.len() / 2, "{name}: {differ} of {}", pc.len());
    }
    // An isolated vertex stays one.
    let mut m = data("tetrahedron.off");
    m.positions.push(Vec3::splat(9.0));
    let (h, _) = build(&m);
    let d = same(&h, "tetrahedron and a lone vertex");
    assert!(!d.vertex_halfedge(Vertex(4)).is_valid());
    // Deleted faces are left out, as after garbage collection (two holes
    // apart: holes that touch at a vertex would make the rebuild split it).
    let (mut h, _) = build(&data("sphere.ply"));
    for f in [0, 200] {
        h.delete_face(Face::new(f));
    }
    let d = same(&h, "sphere with deleted faces");
    assert_eq!(d.num_faces(), 4 * 318);
    assert_eq!(d.boundary_loops().len(), 2);
    // Quads refuse it, as `loop_subdivide`.
    let (c, _) = build(&data("cube_quad.off"));
    assert!(c.loop_subdivided().is_none());
}

/// The Catmull–Clark step written straight into a half-edge mesh is the
/// mesh that building from the indexed step gives, as for Loop: on
/// quads, triangles, a mixed open mesh, over two levels, and with
/// deleted faces.
#[test]
fn catmull_clark_subdivided_is_the_rebuilt_step() {
    let same = |h: &HalfEdgeMesh, what: &str| {
        let direct = h.catmull_clark_subdivided();
        let mut g = h.clone();
        g.garbage_collect();
        assert_same_step(&direct, &g.catmull_clark(), what);
        direct
    };
    let mut mixed = mixed_polygons();
    mixed.positions.push(Vec3::splat(7.0));
    for (name, mesh) in [
        ("cube_quad.off", data("cube_quad.off")),
        ("mesh_with_border.off", data("mesh_with_border.off")),
        ("tetrahedron.off", data("tetrahedron.off")),
        ("a quad, a triangle, a pentagon and a lone vertex", mixed),
    ] {
        let (mut h, _) = build(&mesh);
        for level in 0..2 {
            h = same(&h, &format!("{name}, level {level}"));
        }
        assert!(h.faces().all(|f| h.face_degree(f) == 4), "{name}");
    }
    let (mut h, _) = build(&data("sphere.ply"));
    for f in [0, 200] {
        h.delete_face(Face::new(f));
    }
    let d = same(&h, "sphere with deleted faces");
    assert_eq!(d.num_faces(), 3 * 318);
}

/// Subdividing a mesh with deleted faces subdivides what is left: the
/// same as after garbage collection, for both schemes and both outputs.
#[test]
fn subdivision_skips_deleted_faces() {
    let (mut h, _) = build(&data("sphere.ply"));
    for f in [3, 150, 299] {
        h.delete_face(Face::new(f));
    }
    let mut g = h.clone();
    g.garbage_collect();
    assert_eq!(h.loop_subdivide(), g.loop_subdivide());
    assert_eq!(h.loop_subdivide().unwrap().num_faces(), 4 * 317);
    assert_eq!(h.catmull_clark(), g.catmull_clark());
    assert_eq!(h.catmull_clark().num_faces(), 3 * 317);
    assert_eq!(h.loop_subdivided(), g.loop_subdivided());
    assert_eq!(h.catmull_clark_subdivided(), g.catmull_clark_subdivided());
}
