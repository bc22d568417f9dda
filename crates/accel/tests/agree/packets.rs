//! Eight rays traced together ([`Scene::intersect8`]) give, lane by lane,
//! what each ray traced alone gives: the same primitive and the same bits
//! of `t`, `u`, `v`. Coherent packets (which take the packet traversal)
//! and mixed ones (traced one by one), over random soups, real meshes,
//! spheres, instances and the hard cases.

use proptest::prelude::*;
use raymesh_accel::*;
use raymesh_geometry::{intersect_triangle, Mat4, Sphere};

use crate::common;
use common::{
    bare_bits, bare_of, hit_bits as key, load, point, soup, tri_mesh, unit_grid, worth_checking,
};

/// The structures: the wide BVHs take packets, the others fall back.
const KINDS: [AccelKind; 5] = [
    AccelKind::Bvh8,
    AccelKind::Bvh4,
    AccelKind::BvhBinned,
    AccelKind::Grid,
    AccelKind::Brute,
];

/// Checks `intersect8` against `intersect` on each packet of `rays` (in
/// eights, the last padded by repeating); returns how many packets were
/// coherent enough to trace together.
fn check(s: &dyn Surface, rays: &[Ray], what: &str) -> usize {
    let mut coherent = 0;
    for chunk in rays.chunks(LANES) {
        let packet: [Ray; LANES] = std::array::from_fn(|i| chunk[i % chunk.len()]);
        coherent += usize::from(Packet8::new(&packet).is_some());
        let got = s.intersect8(&packet);
        let occluded = s.occluded8(&packet);
        for (i, r) in packet.iter().enumerate() {
            assert_eq!(key(got[i]), key(s.intersect(r)), "{what}: lane {i}: {r:?}");
            assert_eq!(
                occluded[i],
                s.occluded(r),
                "{what}: occluded, lane {i}: {r:?}"
            );
        }
    }
    coherent
}

/// Checks `intersect_stream` and `occluded_stream` against `intersect`
/// and `occluded` of each ray, over `rays` whole and over each of its
/// halves; returns how many rays hit anything.
fn check_streams(s: &dyn Surface, rays: &[Ray], what: &str) -> usize {
    let half = rays.len() / 2;
    let mut hits = 0;
    for part in [rays, &rays[..half], &rays[half..]] {
        let mut got = vec![None; part.len()];
        let mut occluded = vec![true; part.len()];
        s.intersect_stream(part, &mut got);
        s.occluded_stream(part, &mut occluded);
        for (i, r) in part.iter().enumerate() {
            let want = s.intersect(r);
            assert_eq!(key(got[i]), key(want), "{what}: stream, ray {i}: {r:?}");
            assert_eq!(
                occluded[i],
                s.occluded(r),
                "{what}: occluded stream, ray {i}"
            );
            hits += usize::from(want.is_some());
        }
    }
    hits
}

/// Checks `any_hit8` on each packet of `rays` over a scene of `m`'s
/// triangles: a lane has a hit exactly when its ray is occluded, and the
/// hit is its triangle's own (the same bits of `t`, `u`, `v` as the
/// watertight test of that triangle alone), whichever one the packet
/// found first; `any_hit8_bare` and `occluded8` say the same, and so do
/// `any_hit8_soa_bare` and `occluded8_soa` of the rays as rows.
fn check_any<P: Primitives>(s: &Scene<P>, m: &TriangleMesh, rays: &[Ray], what: &str) {
    for chunk in rays.chunks(LANES) {
        let packet: [Ray; LANES] = std::array::from_fn(|i| chunk[i % chunk.len()]);
        let (full, bare) = (s.any_hit8(&packet), s.any_hit8_bare(&packet));
        let occluded = s.occluded8(&packet);
        // The same rays as rows: the same packet, so the same hits.
        let rows = Rays8::from_rays(&packet);
        let (rows_bare, rows_occluded) = (s.any_hit8_soa_bare(&rows), s.occluded8_soa(&rows));
        for (i, r) in packet.iter().enumerate() {
            let what = format!("{what}: any hit, lane {i}: {r:?}");
            assert_eq!(bare_bits(rows_bare[i]), bare_bits(bare[i]), "{what}: rows");
            assert_eq!(rows_occluded[i], occluded[i], "{what}: rows");
            assert_eq!(full[i].is_some(), s.occluded(r), "{what}");
            assert_eq!(occluded[i], s.occluded(r), "{what}");
            assert_eq!(bare_bits(bare[i]), bare_of(full[i]), "{what}");
            if let Some(h) = full[i] {
                let [a, b, c] = m.corners(h.prim);
                let own = intersect_triangle(r, r.tmax(), a, b, c)
                    .unwrap_or_else(|| panic!("{what}: {h:?} is no hit of its triangle"));
                let bits = |t: f32, u: f32, v: f32| [t, u, v].map(f32::to_bits);
                assert_eq!(bits(h.t, h.u, h.v), bits(own.t, own.u, own.v), "{what}");
            }
        }
    }
}

/// Checks `intersect8_bare` against `intersect8` on each packet of `rays`,
/// and the forms that take the rays as rows (`intersect8_soa` and
/// `intersect8_soa_bare`) against those.
fn check_bare<P: Primitives>(s: &Scene<P>, rays: &[Ray], what: &str) {
    for chunk in rays.chunks(LANES) {
        let packet: [Ray; LANES] = std::array::from_fn(|i| chunk[i % chunk.len()]);
        let (bare, full) = (s.intersect8_bare(&packet), s.intersect8(&packet));
        // The same rays as rows ([`Rays8`]).
        let rows = Rays8::from_rays(&packet);
        let (rows_bare, rows_full) = (s.intersect8_soa_bare(&rows), s.intersect8_soa(&rows));
        for i in 0..LANES {
            assert_eq!(
                bare_bits(bare[i]),
                bare_of(full[i]),
                "{what}: bare, lane {i}"
            );
            assert_eq!(key(rows_full[i]), key(full[i]), "{what}: rows, lane {i}");
            assert_eq!(
                bare_bits(rows_bare[i]),
                bare_bits(bare[i]),
                "{what}: rows, bare, lane {i}"
            );
        }
    }
}

/// Every kind over an indexed mesh, over its corner rows in leaf order
/// (the renderer's scenes), and over the rows in the mesh's order; returns
/// how many of the packets were coherent (the rays' property: each kind
/// counts the same).
fn check_mesh(m: &TriangleMesh, rays: &[Ray]) -> usize {
    let mut coherent = 0;
    for kind in KINDS {
        if !worth_checking(kind, m.triangles.len()) {
            continue;
        }
        let rows = Scene::from_mesh(m, kind);
        coherent = check(&rows, rays, &format!("{kind} rows"));
        check_bare(&rows, rays, &format!("{kind} rows"));
        check_any(&rows, m, rays, &format!("{kind} rows"));
        check_any(
            &Scene::build(m.clone(), kind),
            m,
            rays,
            &format!("{kind} mesh"),
        );
        check(
            &Scene::build(m.clone(), kind),
            rays,
            &format!("{kind} mesh"),
        );
        let rows = Triangles::from_mesh(m);
        check(
            &Scene::build(rows, kind),
            rays,
            &format!("{kind} built rows"),
        );
    }
    // With spatial splits: leaves holding parts of triangles.
    let spatial = BuildConfig {
        spatial_splits: 1.0,
        ..BuildConfig::default()
    };
    for kind in [AccelKind::Bvh8, AccelKind::Bvh4, AccelKind::BvhBinned] {
        let s = Scene::from_mesh_with(m, kind, &spatial);
        check(&s, rays, &format!("{kind} rows, spatial splits"));
        check_any(&s, m, rays, &format!("{kind} rows, spatial splits"));
    }
    coherent
}

/// Camera-like packets: eight rays from `o` toward points around `aim`,
/// and eight toward the given targets (vertices, edge points) from `o`.
fn camera_rays(o: Vec3, aims: &[Vec3], spread: f32, targets: &[Vec3]) -> Vec<Ray> {
    let mut rays = Vec::new();
    for (k, aim) in aims.iter().enumerate() {
        for i in 0..LANES {
            let j = Vec3::new((i % 4) as f32, (i / 4) as f32, (k % 3) as f32) * spread;
            let tmax = if k % 4 == 3 { 1.0 } else { f32::INFINITY };
            rays.push(Ray::new(o, *aim + j - o, 0.0, tmax));
        }
    }
    for t in targets {
        rays.push(Ray::infinite(o, *t - o));
    }
    rays
}

/// A soup's triangles (shared edge and duplicate added), and points to
/// aim at: the first eight's corners, edge midpoints and centroids.
fn soup_and_targets(tris: Vec<(Vec3, Vec3, Vec3)>) -> (Vec<[Vec3; 3]>, Vec<Vec3>) {
    let t = soup(tris);
    let targets = t
        .iter()
        .take(8)
        .flat_map(|&[a, b, c]| [a, b, c, (a + b) * 0.5, (a + b + c) / 3.0])
        .collect();
    (t, targets)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: common::cases(64), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_soups(tris in proptest::collection::vec((point(), point(), point()), 0..120),
                    origin in point(),
                    aims in proptest::collection::vec(point(), 6),
                    spread in prop_oneof![Just(0.0f32), 0.001f32..0.3]) {
        let (tris, targets) = soup_and_targets(tris);
        let rays = camera_rays(origin * 3.0 + Vec3::Z * 4.0, &aims, spread, &targets);
        check_mesh(&tri_mesh(&tris), &rays);
    }

    #[test]
    fn spheres_and_mixes(spheres in proptest::collection::vec((point(), 0.05f32..0.8), 0..30),
                         tris in proptest::collection::vec((point(), point(), point()), 0..30),
                         origin in point(),
                         aims in proptest::collection::vec(point(), 4)) {
        let sph: Vec<Sphere> = spheres.iter().map(|&(c, r)| Sphere::new(c, r)).collect();
        let (tris, targets) = soup_and_targets(tris);
        let rays = camera_rays(origin * 3.0 + Vec3::Z * 4.0, &aims, 0.05, &targets);
        for kind in KINDS {
            let spheres = Scene::build(Spheres(sph.clone()), kind);
            check(&spheres, &rays, "spheres");
            // The row forms too: shapes with no packet test of their own
            // ask the packet for each lane's ray, made from the rows.
            check_bare(&spheres, &rays, "spheres");
            let mut mix: Vec<Shape> = sph.iter().copied().map(Shape::Sphere).collect();
            mix.extend(tris.iter().copied().map(Shape::Triangle));
            let mix = Scene::build(Shapes(mix), kind);
            check(&mix, &rays, "mix");
            check_bare(&mix, &rays, "mix");
        }
    }
}

/// A camera's packets over real meshes: nearly all of them coherent, so
/// the packet traversal is what is checked.
#[test]
fn real_meshes_through_a_camera() {
    for name in [
        "elephant-with-holes.off",
        "sphere.ply",
        "mesh_with_border.off",
        "degtri_sliding.off",
    ] {
        let m = load(name);
        let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
        let (c, d) = (b.centroid(), b.diagonal());
        let eye = c + Vec3::new(0.3, 0.4, 1.0).normalize() * 1.5 * d;
        // A 64 × 32 image in 4 × 2 tiles, through the whole box.
        let (w, h) = (64, 32);
        let mut rays = Vec::new();
        for ty in 0..h / 2 {
            for tx in 0..w / 4 {
                for i in 0..LANES {
                    let (x, y) = (tx * 4 + i % 4, ty * 2 + i / 4);
                    let p = b.min
                        + (b.max - b.min)
                            * Vec3::new(x as f32 / w as f32, y as f32 / h as f32, 0.5);
                    rays.push(Ray::infinite(eye, p - eye));
                }
            }
        }
        // Exactly through vertices, from the eye.
        rays.extend(
            m.positions
                .iter()
                .take(64)
                .map(|&p| Ray::infinite(eye, p - eye)),
        );
        let packets = rays.len().div_ceil(LANES);
        let coherent = check_mesh(&m, &rays);
        assert!(
            coherent * 10 >= packets * 8,
            "{name}: only {coherent} of {packets} packets were coherent"
        );
    }
}

/// Instances trace packets too, transformed into each object's space:
/// packets that straddle instances (so lanes list different ones), and
/// an instance placed twice in the same spot (ties go to the least
/// instance).
#[test]
fn instances() {
    let m = load("elephant-with-holes.off");
    let size = m
        .positions
        .iter()
        .fold(Aabb::EMPTY, |a, p| a.grow(*p))
        .diagonal();
    let objects = vec![
        Scene::from_mesh(&m, AccelKind::Bvh8),
        Scene::from_mesh(&m, AccelKind::BvhBinned),
    ];
    let place = |k: u32| {
        Mat4::from_translation(Vec3::new(k as f32 * 2.0 * size, 0.0, 0.0))
            * Mat4::from_rotation_y(k as f32 * 0.3)
    };
    let mut instances: Vec<Instance> = (0..6)
        .map(|k| Instance {
            object: k % 2,
            transform: place(k),
        })
        .collect();
    instances.push(Instance {
        object: 1,
        transform: place(0),
    });
    let top = |kind| Instances::build(objects.clone(), &instances, kind).unwrap();
    let s = top(AccelKind::BvhBinned);
    let b = s.bounds();
    let eye = b.centroid() + Vec3::new(0.0, 0.3, 2.0) * b.diagonal();
    let aims: Vec<Vec3> = (0..60)
        .map(|i| {
            let f = Vec3::new((i % 20) as f32 / 20.0, (i / 20) as f32 / 3.0 + 0.2, 0.5);
            b.min + (b.max - b.min) * f
        })
        .collect();
    let rays = camera_rays(eye, &aims, 0.1 * size, &[]);
    // Packets whose lanes end on different instances, or some on none.
    let mut straddling = 0;
    for packet in rays.chunks_exact(LANES) {
        let hit: Vec<_> = packet
            .iter()
            .map(|r| s.intersect(r).map(|h| h.instance))
            .collect();
        straddling += usize::from(hit.iter().any(|h| *h != hit[0]));
    }
    assert!(
        straddling > 3,
        "only {straddling} packets straddle instances"
    );
    // Top structures whose leaves hold one instance each, or several.
    for kind in [
        AccelKind::BvhBinned,
        AccelKind::Bvh8,
        AccelKind::Bvh4,
        AccelKind::Grid,
        AccelKind::KdTree,
        AccelKind::Brute,
    ] {
        let what = format!("instances under {kind}");
        check(&top(kind), &rays, &what);
        let hits = check_streams(&top(kind), &rays, &what);
        assert!(hits >= 40, "{what}: only {hits} hits");
    }
    // More instances than packets and streams list (each ray by itself).
    let many: Vec<Instance> = (0..PACKET_INSTANCES as u32 + 6)
        .map(|k| Instance {
            object: k % 2,
            transform: place(k % 7),
        })
        .collect();
    let crowd = Instances::build(objects.clone(), &many, AccelKind::Bvh8).unwrap();
    check(&crowd, &rays, "70 instances");
    let hits = check_streams(&crowd, &rays, "70 instances");
    assert!(hits >= 40, "70 instances: only {hits} hits");
}

/// Hard cases: axis-parallel packets, rays starting inside boxes, rays
/// along shared edges, huge coordinates, an empty scene, invalid lanes.
#[test]
fn hard_cases() {
    let grid = unit_grid();
    let m = tri_mesh(&grid);
    let mut rays = Vec::new();
    // Axis-parallel, through vertices and along shared edges.
    for i in 0..LANES {
        rays.push(Ray::infinite(Vec3::new(i as f32, 2.0, 5.0), Vec3::NEG_Z));
    }
    for i in 0..LANES {
        rays.push(Ray::infinite(
            Vec3::new(i as f32 * 0.5 + 0.5, i as f32 * 0.5 + 0.5, -3.0),
            Vec3::Z,
        ));
    }
    // Grazing the plane, from inside the box.
    for i in 0..LANES {
        rays.push(Ray::infinite(
            Vec3::new(0.5, i as f32, 0.0),
            Vec3::new(1.0, 0.0, 1e-7),
        ));
    }
    // One invalid lane among valid ones (traced one by one).
    for i in 0..LANES {
        let o = if i == 3 {
            Vec3::NAN
        } else {
            Vec3::new(3.3, 2.2, 4.0)
        };
        rays.push(Ray::infinite(o, Vec3::new(0.01 * i as f32, 0.0, -1.0)));
    }
    let coherent = check_mesh(&m, &rays);
    assert!(coherent > 0, "no packet was traced together");
    let huge: Vec<[Vec3; 3]> = grid.iter().map(|t| t.map(|p| p * 1e30)).collect();
    let rays_huge: Vec<Ray> = rays
        .iter()
        .map(|r| Ray::infinite(r.origin() * 1e30, r.dir()))
        .collect();
    check_mesh(&tri_mesh(&huge), &rays_huge);
    check_mesh(&TriangleMesh::default(), &rays);
}

/// Packets find a degenerate triangle where one ray at a time does, with
/// a blocker across each ray that hits it short of its segment
/// (`common::degenerate_with_blockers`, coherent rays: eight from one eye
/// toward neighbouring points of the segment).
#[test]
fn degenerate_triangles_with_blockers() {
    let (m, rays) = common::degenerate_with_blockers(2000, true);
    assert!(check_mesh(&m, &rays) > 0);
}
