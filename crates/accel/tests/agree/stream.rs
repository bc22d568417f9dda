//! Rays traced as a stream ([`Scene::intersect_stream`],
//! [`Scene::any_hit_stream`]) give, ray by ray, what each ray traced alone
//! gives: the same primitive and the same bits of `t`, `u`, `v` and the
//! normal; [`Scene::occluded_stream`] gives each ray's
//! [`Surface::occluded`]. Incoherent rays (random origins and directions,
//! rays from inside the box, rays at vertices and edges, short and invalid
//! rays) over random soups, spheres and mixes, real meshes and the hard
//! cases, in streams of every length around the number of rays in flight;
//! runs of coherent rays among them, which streams walk as packets.

use proptest::prelude::*;
use raymesh_accel::*;
use raymesh_geometry::Sphere;

use crate::common;
use common::{
    bare_bits, bare_of, hit_bits as key, load, point, soup, tri_mesh, uniform, unit_grid,
    worth_checking,
};

/// The BVHs take streams; the others trace one by one.
const KINDS: [AccelKind; 7] = [
    AccelKind::BvhBinned,
    AccelKind::BvhMedian,
    AccelKind::BvhSweep,
    AccelKind::Bvh4,
    AccelKind::Bvh8,
    AccelKind::Grid,
    AccelKind::Brute,
];

/// Checks both stream queries against one-by-one tracing, over the whole
/// ray list and over its first few rays (streams shorter than the lanes in
/// flight); returns how many rays hit.
fn check<P: Primitives>(s: &Scene<P>, rays: &[Ray], what: &str) -> usize {
    let mut hits = 0;
    for n in [rays.len(), rays.len().min(3), rays.len().min(1), 0] {
        let rays = &rays[..n];
        let mut got = vec![None; n];
        s.intersect_stream(rays, &mut got);
        let mut any = vec![None; n];
        s.any_hit_stream(rays, &mut any);
        let mut occluded = vec![false; n];
        s.occluded_stream(rays, &mut occluded);
        let (mut bare, mut bare_any) = (vec![None; n], vec![None; n]);
        s.stream_bare(rays, false, &mut bare);
        s.stream_bare(rays, true, &mut bare_any);
        for (i, r) in rays.iter().enumerate() {
            assert_eq!(key(got[i]), key(s.intersect(r)), "{what}: ray {i}: {r:?}");
            assert_eq!(
                key(any[i]),
                key(s.any_hit(r)),
                "{what}: any hit, ray {i}: {r:?}"
            );
            assert_eq!(
                occluded[i],
                s.occluded(r),
                "{what}: occluded, ray {i}: {r:?}"
            );
            assert_eq!(bare_bits(bare[i]), bare_of(got[i]), "{what}: bare, ray {i}");
            assert_eq!(
                bare_bits(bare_any[i]),
                bare_of(any[i]),
                "{what}: bare any hit, ray {i}"
            );
        }
        hits = hits.max(got.iter().filter(|h| h.is_some()).count());
    }
    hits
}

/// Every kind over an indexed mesh, over its corner rows in leaf order
/// (what `raymesh raycast` traces), and over rows in the mesh's order.
fn check_mesh(m: &TriangleMesh, rays: &[Ray]) -> usize {
    let mut hits = 0;
    for kind in KINDS {
        if !worth_checking(kind, m.triangles.len()) {
            continue;
        }
        hits = hits.max(check(
            &Scene::from_mesh(m, kind),
            rays,
            &format!("{kind} rows"),
        ));
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
    for kind in [AccelKind::BvhBinned, AccelKind::Bvh8] {
        let s = Scene::from_mesh_with(m, kind, &spatial);
        check(&s, rays, &format!("{kind} rows, spatial splits"));
    }
    hits
}

/// Incoherent rays for a mesh: from random points of a box twice the
/// mesh's (inside it too) in random directions, some with short
/// intervals; at its vertices and edge midpoints; and a few invalid.
fn incoherent_rays(m: &TriangleMesh, n: usize, seed: u64) -> Vec<Ray> {
    let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
    let (c, d) = (b.centroid(), b.diagonal());
    let mut u = uniform(seed);
    let mut v3 = move || Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5);
    let mut rays = Vec::new();
    for i in 0..n {
        let o = c + v3() * 2.0 * d;
        let tmax = if i % 5 == 4 { d * 0.3 } else { f32::INFINITY };
        rays.push(Ray::new(o, v3(), 0.0, tmax));
        if m.len() > 0 && i % 3 == 0 {
            let [a, bb, _] = m.corners((i % m.len()) as u32);
            rays.push(Ray::infinite(o, a - o));
            rays.push(Ray::infinite(o, (a + bb) * 0.5 - o));
        }
    }
    rays.push(Ray::infinite(Vec3::NAN, Vec3::X));
    rays.push(Ray::new(c, Vec3::Y, 2.0, 1.0));
    rays.push(Ray::infinite(c, Vec3::ZERO));
    rays
}

/// Runs of camera-like rays (eight and more from near one point, in one
/// octant with one dominant axis, aimed across the mesh's box: the closest
/// hits' streams walk such runs of eight as packets) mixed with
/// incoherent rays, so that runs start on and off a multiple of eight,
/// end mid-run, and share a stream with rays traced as before.
fn mixed_rays(m: &TriangleMesh, seed: u64) -> Vec<Ray> {
    let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
    let (c, d) = (b.centroid(), b.diagonal().max(1e-3));
    let mut u = uniform(seed);
    let incoherent = incoherent_rays(m, 40, seed ^ 0x9e37);
    let mut rays = Vec::new();
    for run in 0..12 {
        // A direction with every component away from zero, in the run's
        // octant; the lanes stray from it by less than its smallest one.
        let sign = |bit: u32| if run >> bit & 1 == 0 { 1.0 } else { -1.0 };
        let base = Vec3::new(sign(0), 0.5 * sign(1), 0.3 * sign(2));
        let o = c - base * d;
        for _ in 0..8 + run % 5 {
            let jitter = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5) * 0.1;
            let tmax = if run % 4 == 3 {
                d * (0.8 + u())
            } else {
                f32::INFINITY
            };
            rays.push(Ray::new(o + jitter * d, base + jitter, 0.0, tmax));
        }
        rays.extend_from_slice(&incoherent[run * 3..run * 3 + run % 4]);
    }
    rays
}

proptest! {
    #![proptest_config(ProptestConfig { cases: common::cases(64), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn coherent_runs_in_streams(tris in proptest::collection::vec((point(), point(), point()), 1..150),
                                seed in any::<u64>()) {
        let m = tri_mesh(&soup(tris));
        let rays = mixed_rays(&m, seed);
        check_mesh(&m, &rays);
    }

    #[test]
    fn random_soups(tris in proptest::collection::vec((point(), point(), point()), 0..150),
                    seed in any::<u64>()) {
        let m = tri_mesh(&soup(tris));
        let rays = incoherent_rays(&m, 60, seed);
        check_mesh(&m, &rays);
    }

    #[test]
    fn spheres_and_mixes(spheres in proptest::collection::vec((point(), 0.05f32..0.8), 0..30),
                         tris in proptest::collection::vec((point(), point(), point()), 0..30),
                         seed in any::<u64>()) {
        let sph: Vec<Sphere> = spheres.iter().map(|&(c, r)| Sphere::new(c, r)).collect();
        let tris = soup(tris);
        let rays = incoherent_rays(&tri_mesh(&tris), 60, seed);
        for kind in KINDS {
            check(&Scene::build(Spheres(sph.clone()), kind), &rays, "spheres");
            let mut mix: Vec<Shape> = sph.iter().copied().map(Shape::Sphere).collect();
            mix.extend(tris.iter().copied().map(Shape::Triangle));
            check(&Scene::build(Shapes(mix), kind), &rays, "mix");
        }
    }
}

/// Real meshes: most rays hit, and every stream answer is the one-by-one
/// answer.
#[test]
fn real_meshes() {
    for name in [
        "elephant-with-holes.off",
        "sphere.ply",
        "double-torus-example.off",
        "degtri_sliding.off",
        "mesh_with_border.off",
    ] {
        let m = load(name);
        let rays = incoherent_rays(&m, 700, name.len() as u64);
        let hits = check_mesh(&m, &rays);
        assert!(hits > rays.len() / 10, "{name}: only {hits} hits");
        let rays = mixed_rays(&m, name.len() as u64);
        let hits = check_mesh(&m, &rays);
        assert!(hits > rays.len() / 4, "{name}: only {hits} hits in runs");
    }
}

/// Axis-parallel rays through vertices and along shared edges, grazing
/// rays from inside the box, huge coordinates, one triangle, none.
#[test]
fn hard_cases() {
    let grid = unit_grid();
    let mut rays = Vec::new();
    for i in 0..9 {
        let f = i as f32;
        rays.push(Ray::infinite(Vec3::new(f, 2.0, 5.0), Vec3::NEG_Z));
        rays.push(Ray::infinite(Vec3::new(f * 0.5, f * 0.5, -3.0), Vec3::Z));
        rays.push(Ray::infinite(
            Vec3::new(0.5, f, 0.0),
            Vec3::new(1.0, 0.0, 1e-7),
        ));
        rays.push(Ray::infinite(Vec3::new(-1.0, f, 0.0), Vec3::X));
        rays.push(Ray::new(Vec3::new(f, 3.0, 1.0), Vec3::NEG_Z, 0.0, 1.0));
    }
    let hits = check_mesh(&tri_mesh(&grid), &rays);
    assert!(hits > rays.len() / 4, "only {hits} hits");
    let huge: Vec<[Vec3; 3]> = grid.iter().map(|t| t.map(|p| p * 1e30)).collect();
    let rays_huge: Vec<Ray> = rays
        .iter()
        .map(|r| Ray::infinite(r.origin() * 1e30, r.dir()))
        .collect();
    check_mesh(&tri_mesh(&huge), &rays_huge);
    check_mesh(&tri_mesh(&grid[..1]), &rays);
    check_mesh(&TriangleMesh::default(), &rays);
}

/// A bumpy `n` × `n` height field (`2 n²` triangles) over the unit square.
fn height_field(n: usize) -> TriangleMesh {
    let mut u = uniform(99);
    let heights: Vec<f32> = (0..(n + 1) * (n + 1)).map(|_| u() * 0.02).collect();
    let p = |i: usize, j: usize| {
        let (x, z) = (i as f32 / n as f32, j as f32 / n as f32);
        Vec3::new(
            x,
            (x * 9.0).sin() * (z * 7.0).cos() * 0.2 + heights[i * (n + 1) + j],
            z,
        )
    };
    let mut tris = Vec::with_capacity(2 * n * n);
    for i in 0..n {
        for j in 0..n {
            tris.push([p(i, j), p(i + 1, j), p(i, j + 1)]);
            tris.push([p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    tri_mesh(&tris)
}

/// A mesh whose 8-wide tree has between 256 KiB and 1 MiB of nodes,
/// over which its streams interleave two rays at a time, or on a CPU
/// with AVX2 and an L2 of more than twice its nodes trace one ray after
/// another (as they do over the smaller trees of the meshes above): a
/// 150 × 150 height field (45,000 triangles), traced by incoherent rays.
#[test]
fn middle_trees() {
    let m = height_field(150);
    let rays = incoherent_rays(&m, 2000, 4);
    let s = Scene::from_mesh(&m, AccelKind::Bvh8);
    let bytes = s.stats().nodes * 256;
    assert!(
        (1 << 18..1 << 20).contains(&bytes),
        "{bytes} bytes of nodes"
    );
    let hits = check(&s, &rays, "bvh8 middle");
    assert!(hits > rays.len() / 10, "only {hits} hits");
}

/// A mesh whose wide trees pass 1 MiB of nodes, over which the wide
/// streams keep more rays in flight than over the small meshes above: a
/// bumpy 300 × 300 height field (180,000 triangles), traced by incoherent
/// rays and by rays through its vertices.
#[test]
fn large_trees() {
    let m = height_field(300);
    let rays = incoherent_rays(&m, 2000, 5);
    for (kind, node_bytes) in [(AccelKind::Bvh8, 256), (AccelKind::Bvh4, 128)] {
        let s = Scene::from_mesh(&m, kind);
        let bytes = s.stats().nodes * node_bytes;
        assert!(bytes > 1 << 20, "{kind}: only {bytes} bytes of nodes");
        let hits = check(&s, &rays, &format!("{kind} large"));
        assert!(hits > rays.len() / 10, "{kind}: only {hits} hits");
    }
}

/// Camera rays looking along a diagonal (so that a group's rays come in
/// several axis orders, each reading other rows of a block) and shadow
/// rays from their hits toward a point light (their intervals of many
/// lengths), a few hundred of each in one stream: coherent occlusion,
/// whose leaves several rays of a group reach together and which
/// therefore test each block once for all of them (over `bvh8` on a CPU
/// with AVX2). Every answer is the one-by-one answer.
#[test]
fn coherent_occlusion_shares_leaf_tests() {
    for (name, m) in [
        ("elephant-with-holes.off", load("elephant-with-holes.off")),
        ("sphere.ply", load("sphere.ply")),
        ("height field", height_field(60)),
    ] {
        let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
        let (c, d) = (b.centroid(), b.diagonal().max(1e-3));
        let s = Scene::from_mesh(&m, AccelKind::Bvh8);
        for (k, eye_dir) in [Vec3::new(1.0, 0.9, 1.1), Vec3::new(-0.6, 0.7, 0.65)]
            .into_iter()
            .enumerate()
        {
            let eye = c + eye_dir * (0.8 * d);
            let forward = (c - eye).normalize();
            let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
            let up = right.cross(forward);
            // 40 × 40 rays over about 33° each way, row by row.
            let mut camera = Vec::new();
            for j in 0..40 {
                for i in 0..40 {
                    let (x, y) = (i as f32 / 39.0 - 0.5, j as f32 / 39.0 - 0.5);
                    let dir = forward + right * (0.6 * x) + up * (0.6 * y);
                    // Every third ray stops somewhere around the mesh.
                    let tmax = if (i + j) % 3 == 0 {
                        d * (1.1 + 0.05 * (i % 9) as f32)
                    } else {
                        f32::INFINITY
                    };
                    camera.push(Ray::new(eye, dir.normalize(), 0.0, tmax));
                }
            }
            let light = c + Vec3::new(0.2, 1.0, -0.4) * d;
            let shadow: Vec<Ray> = camera
                .iter()
                .filter_map(|r| s.intersect(r).map(|h| r.at(h.t)))
                .enumerate()
                .map(|(i, p)| Ray::new(p, light - p, 1e-3, 0.2 + 0.1 * (i % 9) as f32))
                .collect();
            let what = format!("{name}, camera {k}");
            let hits = check(&s, &camera, &what);
            assert!(hits > camera.len() / 20, "{what}: only {hits} hits");
            assert!(shadow.len() > 100, "{what}: {} shadow rays", shadow.len());
            check(&s, &shadow, &format!("{what}, shadow rays"));
        }
    }
}

/// Streams find a degenerate triangle where one ray at a time does, with
/// a blocker across each ray that hits it short of its segment
/// (`common::degenerate_with_blockers`).
#[test]
fn degenerate_triangles_with_blockers() {
    let (m, rays) = common::degenerate_with_blockers(2000, false);
    assert!(check_mesh(&m, &rays) > 0);
}
