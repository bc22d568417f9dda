//! Every structure returns exactly what brute force returns: the same
//! primitive and the same bits of `t`, `u`, `v` for the closest hit, and
//! the same answer for any hit. Random soups, real meshes, spheres, mixes,
//! instances, and the hard cases.

use proptest::prelude::*;
use raymesh_accel::*;
use raymesh_geometry::{Mat4, Sphere};

use crate::common;
use common::{bare_bits, bare_of, hit_bits, load, row_answers, row_of, tri_mesh};

const KINDS: [AccelKind; 8] = [
    AccelKind::Aabb,
    AccelKind::BvhMedian,
    AccelKind::BvhBinned,
    AccelKind::BvhSweep,
    AccelKind::Bvh4,
    AccelKind::Bvh8,
    AccelKind::Grid,
    AccelKind::KdTree,
];

/// The BVHs that take spatial splits, and a budget generous enough that
/// small inputs split too: their leaves then hold parts of primitives,
/// some primitives in several leaves, and must answer as brute force does.
const SPATIAL_KINDS: [AccelKind; 3] = [AccelKind::BvhBinned, AccelKind::Bvh4, AccelKind::Bvh8];
fn spatial() -> BuildConfig {
    BuildConfig {
        spatial_splits: 1.0,
        ..BuildConfig::default()
    }
}

/// The BVHs reinsertion optimizes, each once: the binary trees, and the
/// binned one with spatial splits too, and a wide one collapsed from an
/// optimized tree (its leaves are runs of the rewritten permutation).
fn optimized() -> [(AccelKind, BuildConfig); 5] {
    let opt = BuildConfig {
        optimize: true,
        ..BuildConfig::default()
    };
    let spatial_opt = BuildConfig {
        optimize: true,
        ..spatial()
    };
    [
        (AccelKind::BvhMedian, opt.clone()),
        (AccelKind::BvhBinned, opt.clone()),
        (AccelKind::BvhSweep, opt.clone()),
        (AccelKind::Bvh8, opt),
        (AccelKind::BvhBinned, spatial_opt),
    ]
}

/// The grid with a grid of its own in every cell that lists two
/// primitives or more, however full the others are (the default asks for
/// 64 and four times the mean, which small inputs seldom reach): the walk
/// through both levels on every input.
fn two_level() -> BuildConfig {
    BuildConfig {
        grid_subgrid_min: 2,
        grid_subgrid_ratio: 0.0,
        ..BuildConfig::default()
    }
}

/// Every kind with default settings, then the spatial-split kinds with
/// [`spatial`], then the [`optimized`] builds, then the [`two_level`]
/// grid, each with how to name it in a failure.
fn builds() -> impl Iterator<Item = (AccelKind, BuildConfig, &'static str)> {
    KINDS
        .into_iter()
        .map(|k| (k, BuildConfig::default(), ""))
        .chain(
            SPATIAL_KINDS
                .into_iter()
                .map(|k| (k, spatial(), " with spatial splits")),
        )
        .chain(
            optimized()
                .into_iter()
                .map(|(k, c)| (k, c, " optimized by reinsertion")),
        )
        .chain([(
            AccelKind::Grid,
            two_level(),
            " with a grid in each cell of two primitives or more",
        )])
}

/// [`hit_bits`] without the normal.
fn key(h: Option<Hit>) -> Option<(u32, u32, u32, u32, u32)> {
    hit_bits(h).map(|(prim, instance, t, u, v, _)| (prim, instance, t, u, v))
}

/// Checks every kind against brute force on every ray; returns how many rays hit.
fn check_all<P: Primitives + Clone>(prims: &P, rays: &[Ray]) -> usize {
    let brute = Scene::build(prims.clone(), AccelKind::Brute);
    let want: Vec<_> = rays.iter().map(|r| key(brute.intersect(r))).collect();
    let want_any: Vec<_> = rays.iter().map(|r| brute.occluded(r)).collect();
    for (w, a) in want.iter().zip(&want_any) {
        assert_eq!(
            w.is_some(),
            *a,
            "brute force any-hit disagrees with closest-hit"
        );
    }
    let builds = builds();
    for (kind, config, how) in builds {
        let s = Scene::build_with(prims.clone(), kind, &config);
        for (i, r) in rays.iter().enumerate() {
            let got = key(s.intersect(r));
            assert_eq!(
                got, want[i],
                "{kind}{how}: closest hit differs for ray {i}: {r:?}"
            );
            assert_eq!(
                s.occluded(r),
                want_any[i],
                "{kind}{how}: any hit differs for ray {i}: {r:?}"
            );
            // The queries without the normal find the same hits.
            assert_eq!(
                bare_bits(s.intersect_bare(r)),
                bare_of(s.intersect(r)),
                "{kind}{how}: bare closest hit differs for ray {i}: {r:?}"
            );
            assert_eq!(
                bare_bits(s.any_hit_bare(r)),
                bare_of(s.any_hit(r)),
                "{kind}{how}: bare any hit differs for ray {i}: {r:?}"
            );
            // The queries of a row make the same ray inside and find the
            // same hits (`invalid_rows_never_hit` covers invalid rows, on
            // every kind). Checked on `bvh8`, the one kind whose walk makes
            // the ray inside its SIMD region; the others make it first and
            // walk as for a `Ray` (the checks cost the agreement tests
            // half their time again under qemu in CI).
            if let Some(row) = row_of(r).filter(|_| kind == AccelKind::Bvh8) {
                assert_eq!(
                    row_answers(&s, &row),
                    (bare_of(s.intersect(r)), bare_of(s.any_hit(r)), want_any[i]),
                    "{kind}{how}: the row queries differ for ray {i}: {r:?}"
                );
            }
        }
    }
    want.iter().filter(|w| w.is_some()).count()
}

/// [`check_all`] on an indexed mesh and on its corner copy ([`Triangles`],
/// whose wide-BVH leaves take the SIMD block test), and the two agree.
fn check_mesh(m: &TriangleMesh, rays: &[Ray]) -> usize {
    let tris = Triangles::from_mesh(m);
    let a = Scene::build(m.clone(), AccelKind::Brute);
    let b = Scene::build(tris.clone(), AccelKind::Brute);
    for r in rays {
        assert_eq!(key(a.intersect(r)), key(b.intersect(r)), "{r:?}");
    }
    let hits = check_all(m, rays);
    assert_eq!(check_all(&tris, rays), hits);
    // Scenes gathered straight from the mesh in leaf order are the same
    // scenes, hit for hit, with the same structure.
    let builds = builds();
    for (kind, config, how) in builds {
        let want = Scene::build_with(tris.clone(), kind, &config);
        let got = Scene::from_mesh_with(m, kind, &config);
        let (ws, gs) = (want.stats(), got.stats());
        assert_eq!(
            (ws.nodes, ws.depth, ws.bytes),
            (gs.nodes, gs.depth, gs.bytes),
            "{kind}{how}"
        );
        for r in rays {
            assert_eq!(
                key(got.intersect(r)),
                key(want.intersect(r)),
                "{kind}{how}: {r:?}"
            );
            assert_eq!(got.occluded(r), want.occluded(r), "{kind}{how}: {r:?}");
        }
    }
    hits
}

/// Coordinates on a coarse lattice (shared edges, axis-aligned and coplanar
/// triangles, rays through vertices) or anywhere.
fn coord() -> impl Strategy<Value = f32> + Clone {
    prop_oneof![(-2i32..=2).prop_map(|i| i as f32 * 0.5), -1.0f32..1.0]
}
fn point() -> impl Strategy<Value = Vec3> + Clone {
    (coord(), coord(), coord()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}
fn dir_comp() -> impl Strategy<Value = f32> + Clone {
    prop_oneof![
        Just(0.0f32),
        Just(-0.0),
        (-1i32..=1).prop_map(|i| i as f32),
        -1.0f32..1.0
    ]
}
fn direction() -> impl Strategy<Value = Vec3> {
    (dir_comp(), dir_comp(), dir_comp()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// Rays from random origins, plus rays aimed exactly at the vertices and
/// edge midpoints of the given triangles, from outside and from inside.
fn rays_for(tris: &[[Vec3; 3]], origins: &[Vec3], dirs: &[Vec3]) -> Vec<Ray> {
    let mut rays: Vec<Ray> = origins
        .iter()
        .zip(dirs)
        .map(|(o, d)| Ray::infinite(*o * 3.0, *d))
        .collect();
    for (k, t) in tris.iter().enumerate().take(12) {
        let o = origins[k % origins.len()] * 3.0 + Vec3::new(0.1, 2.0, 0.3);
        for target in [
            t[0],
            t[1],
            t[2],
            (t[0] + t[1]) * 0.5,
            (t[0] + t[1] + t[2]) / 3.0,
        ] {
            rays.push(Ray::infinite(o, target - o));
            rays.push(Ray::new(o, target - o, 0.0, 1.0)); // ends exactly at the target
        }
    }
    rays
}

proptest! {
    #![proptest_config(ProptestConfig { cases: common::cases(300), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_triangle_soups(tris in proptest::collection::vec((point(), point(), point()), 0..80),
                             origins in proptest::collection::vec(point(), 24),
                             dirs in proptest::collection::vec(direction(), 24)) {
        let tris: Vec<[Vec3; 3]> = tris.into_iter().map(|(a, b, c)| [a, b, c]).collect();
        let rays = rays_for(&tris, &origins, &dirs);
        check_mesh(&tri_mesh(&tris), &rays);
    }

    #[test]
    fn spheres_and_mixes(spheres in proptest::collection::vec((point(), 0.05f32..0.8), 0..30),
                         tris in proptest::collection::vec((point(), point(), point()), 0..30),
                         origins in proptest::collection::vec(point(), 24),
                         dirs in proptest::collection::vec(direction(), 24)) {
        let sph: Vec<Sphere> = spheres.iter().map(|&(c, r)| Sphere::new(c, r)).collect();
        let tris: Vec<[Vec3; 3]> = tris.into_iter().map(|(a, b, c)| [a, b, c]).collect();
        let mut rays = rays_for(&tris, &origins, &dirs);
        for (k, s) in sph.iter().enumerate() {
            rays.push(Ray::infinite(s.center, dirs[k % dirs.len()])); // from inside a sphere
        }
        check_all(&Spheres(sph.clone()), &rays);
        let mut mix: Vec<Shape> = sph.into_iter().map(Shape::Sphere).collect();
        mix.extend(tris.into_iter().map(Shape::Triangle));
        check_all(&Shapes(mix), &rays);
    }
}

/// Deterministic pseudo-random numbers for the real-mesh tests.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
    fn unit(&mut self) -> Vec3 {
        Vec3::new(
            self.next() * 2.0 - 1.0,
            self.next() * 2.0 - 1.0,
            self.next() * 2.0 - 1.0,
        )
    }
}

/// Rays of BENCH.md's `random` workload plus rays at vertices, along
/// edges, from inside the box, and parallel to the axes.
fn mesh_rays(m: &TriangleMesh, n: usize, seed: u64) -> Vec<Ray> {
    let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
    let (c, d) = (b.centroid(), b.diagonal());
    let mut rng = Lcg(seed);
    let mut rays = Vec::new();
    for i in 0..n {
        let o = c + rng.unit().normalize_or_zero() * 0.75 * d;
        let p = b.min + (b.max - b.min) * Vec3::new(rng.next(), rng.next(), rng.next());
        rays.push(Ray::infinite(o, p - o));
        // At a vertex, and at an edge point, of some triangle.
        let t = m.triangles[i % m.triangles.len()];
        let (a, bb) = (m.positions[t[0] as usize], m.positions[t[1] as usize]);
        rays.push(Ray::infinite(o, a - o));
        rays.push(Ray::infinite(o, a.lerp(bb, 0.5) - o));
        // From inside the box, and along an axis.
        rays.push(Ray::infinite(p, rng.unit()));
        let axis = [Vec3::X, Vec3::NEG_Y, Vec3::Z][i % 3];
        rays.push(Ray::infinite(p - axis * d, axis));
    }
    rays
}

#[test]
fn real_meshes() {
    for name in [
        "elephant-with-holes.off",
        "sphere.ply",
        "mesh_with_border.off",
        "double-torus-example.off",
        "degtri_sliding.off",
        "cube_quad.off",
    ] {
        let m = load(name);
        let rays = mesh_rays(&m, 300, 7);
        let hits = check_mesh(&m, &rays);
        assert!(
            hits > rays.len() / 10,
            "{name}: only {hits} of {} rays hit",
            rays.len()
        );
    }
}

/// A dense mesh on a floor a hundred times its size (a teapot in a
/// stadium): the grid sizes its cells for the floor, gives the few cells
/// that hold the mesh grids of their own (two levels, with the default
/// settings), and answers as brute force does, as every structure does,
/// for rays at the mesh from near and from across the floor, at its
/// vertices and edges, from inside its box, along the axes and along the
/// floor.
#[test]
fn dense_mesh_in_a_large_scene() {
    let m = load("elephant-with-holes.off");
    let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
    let scale = 2.0 / b.extent().max_element();
    let positions: Vec<Vec3> = m
        .positions
        .iter()
        .map(|p| (*p - b.centroid()) * scale)
        .collect();
    let dense = TriangleMesh::new(positions.clone(), m.triangles.clone());
    let floor_y = positions.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
    // 20 x 20 squares of 10 units, two triangles each, the mesh standing
    // on the middle.
    let (mut all_pos, mut all_tris) = (positions, m.triangles.clone());
    for i in 0..20 {
        for k in 0..20 {
            let at =
                |x: i32, z: i32| Vec3::new((x - 10) as f32 * 10.0, floor_y, (z - 10) as f32 * 10.0);
            let v = all_pos.len() as u32;
            all_pos.extend([at(i, k), at(i + 1, k), at(i + 1, k + 1), at(i, k + 1)]);
            all_tris.extend([[v, v + 1, v + 2], [v, v + 2, v + 3]]);
        }
    }
    let scene = TriangleMesh::new(all_pos, all_tris);
    let grid = Scene::build(scene.clone(), AccelKind::Grid).stats();
    assert_eq!(grid.depth, 2, "the grid gave no cell a grid: {grid:?}");
    let mut rays = mesh_rays(&dense, 100, 11);
    let mut rng = Lcg(5);
    for _ in 0..100 {
        // From across the floor, at the mesh, and grazing the floor.
        let o = Vec3::new(
            rng.next() * 180.0 - 90.0,
            rng.next() * 5.0 + floor_y,
            rng.next() * 180.0 - 90.0,
        );
        let target = rng.unit();
        rays.push(Ray::infinite(o, target - o));
        rays.push(Ray::infinite(
            Vec3::new(o.x, floor_y, o.z),
            Vec3::new(-o.x, 0.0, -o.z),
        ));
    }
    // Every structure against brute force, and the grid gathered straight
    // from the mesh (as `raymesh raycast` builds it) too. (Not the whole
    // of `check_mesh`: this test runs under qemu in CI, and its three
    // passes over every build took 4.7 s of it natively.)
    let hits = check_all(&scene, &rays);
    assert!(
        hits > rays.len() / 2,
        "only {hits} of {} rays hit",
        rays.len()
    );
    let brute = Scene::build(scene.clone(), AccelKind::Brute);
    let from_mesh = Scene::from_mesh_with(&scene, AccelKind::Grid, &BuildConfig::default());
    assert_eq!(from_mesh.stats().depth, 2);
    for r in &rays {
        assert_eq!(
            key(from_mesh.intersect(r)),
            key(brute.intersect(r)),
            "{r:?}"
        );
        assert_eq!(from_mesh.occluded(r), brute.occluded(r), "{r:?}");
    }
}

#[test]
fn hard_cases() {
    let o = Vec3::new(0.3, 0.2, -2.0);
    let dirs = [
        Vec3::Z,
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.1, -0.05, 1.0),
        Vec3::X,
        -Vec3::Z,
    ];
    let mut rays: Vec<Ray> = dirs.iter().map(|&d| Ray::infinite(o, d)).collect();
    // NaN and infinite rays, zero direction, empty interval.
    rays.push(Ray::infinite(Vec3::NAN, Vec3::Z));
    rays.push(Ray::infinite(o, Vec3::new(f32::NAN, 0.0, 1.0)));
    rays.push(Ray::infinite(Vec3::splat(f32::INFINITY), Vec3::Z));
    rays.push(Ray::infinite(o, Vec3::new(0.0, f32::INFINITY, 1.0)));
    rays.push(Ray::infinite(o, Vec3::ZERO));
    rays.push(Ray::new(o, Vec3::Z, 5.0, 1.0));
    rays.push(Ray::new(o, Vec3::Z, 0.0, f32::NAN));

    let unit = [Vec3::ZERO, Vec3::X, Vec3::Y];
    // None; one; duplicates; all in one plane; degenerate; huge; tiny.
    assert_eq!(check_mesh(&tri_mesh(&[]), &rays), 0);
    assert!(check_mesh(&tri_mesh(&[unit]), &rays) > 0);
    assert!(
        check_all(
            &tri_mesh(&[unit, unit, unit, [Vec3::X, Vec3::Y, Vec3::ZERO]]),
            &rays
        ) > 0
    );
    let plane: Vec<[Vec3; 3]> = (0..50)
        .map(|i| {
            let x = (i % 10) as f32 * 0.1;
            let y = (i / 10) as f32 * 0.1;
            [
                Vec3::new(x, y, 0.0),
                Vec3::new(x + 0.1, y, 0.0),
                Vec3::new(x, y + 0.1, 0.0),
            ]
        })
        .collect();
    let mut plane_rays = rays.clone();
    plane_rays.push(Ray::infinite(Vec3::new(-1.0, 0.05, 0.0), Vec3::X)); // in the plane
    for i in 0..40 {
        let p = Vec3::new(i as f32 * 0.025, 0.3, 0.0);
        plane_rays.push(Ray::infinite(p + Vec3::Z, -Vec3::Z));
        plane_rays.push(Ray::infinite(
            Vec3::new(0.1 * (i % 10) as f32, 0.1 * (i / 10) as f32, 1.0),
            -Vec3::Z,
        ));
    }
    assert!(check_mesh(&tri_mesh(&plane), &plane_rays) > 0);
    let degenerate = [[Vec3::ZERO, Vec3::X, Vec3::X * 2.0], [Vec3::ONE; 3], unit];
    check_mesh(&tri_mesh(&degenerate), &rays);
    // Every ray hits, at every scale (f32's products of two coordinates
    // overflow at 1e30 and underflow at 1e-30, its products of three
    // already at 1e15 and 1e-15; the test redoes those in f64), at the
    // distance scaled too.
    for scale in [1e30f32, 1e-30, 1e15, 1e-15, 1e12, 1e-12] {
        let tris: Vec<[Vec3; 3]> = plane
            .iter()
            .map(|t| t.map(|v| v * scale + Vec3::Z * scale))
            .collect();
        let rs: Vec<Ray> = (0..40)
            .map(|i| {
                let p = Vec3::new(
                    0.1 * (i % 10) as f32 + 0.03,
                    0.1 * (i / 10) as f32 + 0.02,
                    -1.0,
                ) * scale;
                Ray::infinite(p, Vec3::Z)
            })
            .collect();
        assert_eq!(check_mesh(&tri_mesh(&tris), &rs), rs.len(), "at {scale}");
        let scene = Scene::build(tri_mesh(&tris), AccelKind::Brute);
        for r in &rs {
            let t = scene.intersect(r).map(|h| h.t / scale);
            assert!(
                t.is_some_and(|t| (t - 2.0).abs() < 1e-5),
                "{t:?} at {scale}"
            );
        }
    }
    // Rays starting exactly on split planes and cell boundaries: lattice origins.
    let grid_tris: Vec<[Vec3; 3]> = (0..64)
        .map(|i| {
            let p = Vec3::new((i % 4) as f32, ((i / 4) % 4) as f32, (i / 16) as f32);
            [p, p + Vec3::X, p + Vec3::Y]
        })
        .collect();
    let mut lattice_rays = Vec::new();
    for i in 0..64 {
        let p = Vec3::new((i % 4) as f32, ((i / 4) % 4) as f32, (i / 16) as f32);
        for d in [
            Vec3::X,
            Vec3::NEG_X,
            Vec3::Z,
            Vec3::NEG_Z,
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(-0.3, 0.7, -1.0),
        ] {
            lattice_rays.push(Ray::infinite(p + Vec3::new(0.25, 0.25, 0.0), d));
            lattice_rays.push(Ray::infinite(p, d));
        }
    }
    assert!(check_mesh(&tri_mesh(&grid_tris), &lattice_rays) > 0);
}

#[test]
fn empty_scene_never_hits() {
    for kind in AccelKind::ALL {
        let s = Scene::build(TriangleMesh::default(), kind);
        let r = Ray::infinite(Vec3::ZERO, Vec3::X);
        assert!(s.intersect(&r).is_none());
        assert!(!s.occluded(&r));
        assert!(s.bounds().is_empty());
    }
}

#[test]
fn bvh_builders_make_valid_trees() {
    let m = load("elephant-with-holes.off");
    let boxes: Vec<Aabb> = (0..m.len() as u32).map(|i| m.bounds(i)).collect();
    for b in [
        BvhBuilder::Median,
        BvhBuilder::BinnedSah,
        BvhBuilder::SweepSah,
    ] {
        let bvh = b.build(&boxes, &BuildConfig::default());
        bvh.validate(&boxes)
            .unwrap_or_else(|e| panic!("{b:?}: {e}"));
    }
    // All boxes identical: no SAH split exists, the count fallback must still terminate.
    let same = vec![Aabb::new(Vec3::ZERO, Vec3::ONE); 1000];
    for b in [
        BvhBuilder::Median,
        BvhBuilder::BinnedSah,
        BvhBuilder::SweepSah,
    ] {
        let bvh = b.build(&same, &BuildConfig::default());
        bvh.validate(&same).unwrap();
    }
}

#[test]
fn instances_agree_with_brute_top_level() {
    let m = load("sphere.ply");
    let objects = vec![
        Scene::build(m.clone(), AccelKind::BvhSweep),
        Scene::build(load("cube_quad.off"), AccelKind::Grid),
    ];
    let mut instances = Vec::new();
    for i in 0..40 {
        let f = i as f32;
        instances.push(Instance {
            object: i % 2,
            transform: Mat4::from_scale_rotation_translation(
                Vec3::splat(0.3 + 0.05 * (i % 5) as f32),
                raymesh_geometry::Quat::from_rotation_y(f * 0.7),
                Vec3::new((i % 7) as f32 - 3.0, (i / 7) as f32 - 3.0, (i % 3) as f32),
            ),
        });
    }
    let brute = Instances::build(objects.clone(), &instances, AccelKind::Brute).unwrap();
    let mut rng = Lcg(3);
    let rays: Vec<Ray> = (0..2000)
        .map(|_| {
            let o = rng.unit() * 10.0;
            Ray::infinite(o, rng.unit() * 3.0 - o * 0.2)
        })
        .collect();
    let want: Vec<_> = rays.iter().map(|r| key(brute.intersect(r))).collect();
    assert!(want.iter().filter(|w| w.is_some()).count() > 100);
    for kind in KINDS {
        let s = Instances::build(objects.clone(), &instances, kind).unwrap();
        for (i, r) in rays.iter().enumerate() {
            assert_eq!(key(s.intersect(r)), want[i], "{kind}: ray {i}");
            assert_eq!(s.occluded(r), want[i].is_some(), "{kind}: ray {i}");
        }
    }
    assert!(Instances::build(
        objects,
        &[Instance {
            object: 5,
            transform: Mat4::IDENTITY
        }],
        AccelKind::Brute
    )
    .is_err());
}

/// An object placed by the identity answers what the object alone does,
/// normal included (the ray is carried over as it is, with no new `Ray`
/// made, and the normal is not made unit again).
#[test]
fn identity_instances_are_the_object() {
    let m = load("elephant-with-holes.off");
    let rays = mesh_rays(&m, 300, 11);
    for kind in [AccelKind::Bvh8, AccelKind::Grid] {
        let alone = Scene::from_mesh(&m, kind);
        let placed = Instances::build(
            vec![alone.clone()],
            &[Instance {
                object: 0,
                transform: Mat4::IDENTITY,
            }],
            AccelKind::BvhBinned,
        )
        .unwrap();
        let bits = |h: Option<Hit>| {
            h.map(|h| {
                let n = h.normal.to_array().map(f32::to_bits);
                (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), n)
            })
        };
        let mut hits = 0;
        for r in &rays {
            let (a, b) = (alone.intersect(r), placed.intersect(r));
            assert_eq!(bits(a), bits(b), "{kind}: {r:?}");
            assert_eq!(alone.occluded(r), placed.occluded(r), "{kind}: {r:?}");
            hits += usize::from(a.is_some());
        }
        assert!(hits > rays.len() / 10);
        // Streams through the one instance give the same answers.
        let mut streamed = vec![None; rays.len()];
        let mut occluded = vec![false; rays.len()];
        placed.intersect_stream(&rays, &mut streamed);
        placed.occluded_stream(&rays, &mut occluded);
        for ((r, s), o) in rays.iter().zip(&streamed).zip(&occluded) {
            assert_eq!(bits(*s), bits(placed.intersect(r)), "{kind}: stream, {r:?}");
            assert_eq!(*o, placed.occluded(r), "{kind}: occluded stream, {r:?}");
        }
    }
}

#[test]
fn stats_are_sane() {
    let m = load("elephant-with-holes.off");
    for kind in AccelKind::ALL {
        let s = Scene::build(m.clone(), kind).stats();
        assert_eq!(s.name, kind.name());
        assert!(s.sah_cost > 0.0, "{kind}");
        if kind != AccelKind::Brute {
            assert!(s.nodes >= 1 && s.bytes > 0, "{kind}");
        }
    }
    let bvh = Scene::build(m.clone(), AccelKind::BvhSweep);
    let brute = Scene::build(m.clone(), AccelKind::Brute);
    let r = Ray::infinite(Vec3::new(0.0, 0.0, 3.0), -Vec3::Z);
    let (_, c) = bvh.intersect_stats(&r);
    let (_, cb) = brute.intersect_stats(&r);
    assert_eq!(cb.prims, m.len() as u64);
    assert!(c.prims < cb.prims && c.nodes > 0);
}

/// A ray with more pending than the 8-wide walk's inline stack holds: on
/// 300,000 copies of one triangle the 8-wide tree is 6 levels deep and a
/// ray through the triangle enters every child of every node (7 pending a
/// level, past the 32 inline), so the AVX2 walk stops and the ray walks
/// again with a stack that spills. Every path gives brute force's hit:
/// the least index at the common `t`.
#[test]
fn rays_past_the_inline_stack_get_brute_forces_hits() {
    let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let mesh = tri_mesh(&vec![tri; 300_000]);
    let tris = Triangles::from_mesh(&mesh);
    let brute = Scene::build(tris.clone(), AccelKind::Brute);
    let bvh8 = Scene::build(tris, AccelKind::Bvh8);
    assert!(bvh8.stats().depth >= 6, "{:?}", bvh8.stats());
    let rays = [
        Ray::infinite(Vec3::new(0.2, 0.2, -1.0), Vec3::Z),
        Ray::infinite(Vec3::new(0.3, 0.1, 1.0), -Vec3::Z),
        Ray::infinite(Vec3::new(0.1, 0.1, -1.0), Vec3::new(0.1, 0.2, 1.0)),
        Ray::infinite(Vec3::new(5.0, 5.0, -1.0), Vec3::Z),
    ];
    for (i, r) in rays.iter().enumerate() {
        let want = brute.intersect_bare(r);
        assert_eq!(want.is_some(), i < 3);
        assert_eq!(
            bare_bits(bvh8.intersect_bare(r)),
            bare_bits(want),
            "ray {i}"
        );
        assert_eq!(bvh8.any_hit_bare(r).is_some(), want.is_some(), "ray {i}");
        assert_eq!(bare_of(bvh8.intersect(r)), bare_bits(want), "ray {i}");
        // A row's ray, made inside the walk's region, walks again too.
        let (closest, any, occluded) = row_answers(&bvh8, &row_of(r).expect("a valid ray"));
        assert_eq!(closest, bare_bits(want), "ray {i}");
        assert_eq!(
            (any.is_some(), occluded),
            (want.is_some(), want.is_some()),
            "ray {i}"
        );
    }
}

/// Rows that make invalid rays (NaN or infinite parts, a zero direction,
/// an empty or NaN interval) miss in every structure, as the rays made
/// from them do; a row whose ray is valid hits, so the scenes can.
#[test]
fn invalid_rows_never_hit() {
    let (nan, inf) = (f32::NAN, f32::INFINITY);
    let rows: [[f32; 8]; 9] = [
        [nan, 0.2, -1.0, 0.0, 0.0, 0.0, 1.0, inf],
        [0.2, 0.2, -1.0, 0.0, nan, 0.0, 1.0, inf],
        [inf, 0.2, -1.0, 0.0, 0.0, 0.0, 1.0, inf],
        [0.2, 0.2, -1.0, 0.0, 0.0, -inf, 1.0, inf],
        [0.2, 0.2, -1.0, 0.0, 0.0, 0.0, 0.0, inf],
        [0.2, 0.2, -1.0, 5.0, 0.0, 0.0, 1.0, 1.0],
        [0.2, 0.2, -1.0, 0.0, 0.0, 0.0, 1.0, nan],
        [0.2, 0.2, -1.0, nan, 0.0, 0.0, 1.0, inf],
        [0.2, 0.2, -1.0, 0.0, 0.0, 0.0, 1.0, inf],
    ];
    let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let mesh = tri_mesh(&[tri, [Vec3::Z, Vec3::X + Vec3::Z, Vec3::Y + Vec3::Z]]);
    for (kind, config, how) in builds() {
        let s = Scene::from_mesh_with(&mesh, kind, &config);
        for (i, row) in rows.iter().enumerate() {
            let valid = i == rows.len() - 1;
            let ray = Ray::from_row(row);
            assert_eq!(ray.is_valid(), valid, "row {i}");
            let hit = s.intersect_bare_row(row);
            assert_eq!(hit.is_some(), valid, "{kind}{how}: row {i}");
            assert_eq!(
                bare_bits(hit),
                bare_of(s.intersect(&ray)),
                "{kind}{how}: row {i}"
            );
            assert_eq!(
                s.any_hit_bare_row(row).is_some(),
                valid,
                "{kind}{how}: row {i}"
            );
            assert_eq!(s.occluded_row(row), valid, "{kind}{how}: row {i}");
        }
    }
}

/// A degenerate triangle with a blocker across each ray that hits it
/// short of its segment ([`common::degenerate_with_blockers`]): a
/// structure that, having found the blocker, culled the degenerate
/// triangle's box (which the ray enters only at the segment) missed what
/// brute force finds, until the triangle's box grew to hold its hits
/// (`raymesh_geometry::triangle_hit_bounds`).
#[test]
fn degenerate_triangles_are_found_where_brute_force_finds_them() {
    let (m, rays) = common::degenerate_with_blockers(4000, false);
    check_mesh(&m, &rays);
}

/// The one known gap in the structures' agreement with brute force (the
/// README's exactness paragraph), bounded: thin triangles hit at grazing
/// angles, each with a blocker across the ray between its hit and where
/// the ray enters its corners' box ([`common::thin_with_blockers`]). A
/// structure that has found the blocker culls the thin triangle's box,
/// which the ray enters only after the blocker, while brute force keeps
/// the thin triangle's nearer (noisy) hit. Every build may answer so,
/// and no other way: where it differs from brute force, brute force's
/// hit is a sliver's, short of that sliver's box, and the build's is a
/// blocker's, in between. Any-hit queries agree everywhere (they stop
/// at a hit and cull nothing by it). On this scene's 817 rays (x86-64,
/// `--nocapture` prints the counts) the SAH trees differ on 3 to 9 (with
/// spatial splits, or reinsertion, or neither), the median-split tree,
/// the grid and the k-d tree on none here; nothing in them rules it out.
#[test]
fn thin_triangles_differ_only_in_the_known_gap() {
    let (m, rays, slivers) = common::thin_with_blockers(400, 3000);
    assert!(rays.len() > 50, "{} rays", rays.len());
    let brute = Scene::build(m.clone(), AccelKind::Brute);
    let want: Vec<_> = rays.iter().map(|r| brute.intersect_bare(r)).collect();
    let entry = |prim: u32, r: &Ray| {
        let bounds = Aabb::from_points(m.corners(prim));
        bounds.intersect_ray(r, f32::INFINITY).map(|(t, _)| t)
    };
    for (kind, config, how) in builds() {
        let s = Scene::build_with(m.clone(), kind, &config);
        let mut differ = 0;
        for (i, (r, w)) in rays.iter().zip(&want).enumerate() {
            assert_eq!(
                s.occluded(r),
                w.is_some(),
                "{kind}{how}: any hit differs for ray {i}: {r:?}"
            );
            let got = s.intersect_bare(r);
            if bare_bits(got) == bare_bits(*w) {
                continue;
            }
            differ += 1;
            let (w, g) = (w.unwrap(), got.unwrap());
            let box_entry = entry(w.prim, r).unwrap_or(f32::INFINITY);
            assert!(
                (w.prim as usize) < slivers
                    && g.prim as usize >= slivers
                    && w.t < g.t
                    && g.t < box_entry,
                "{kind}{how}: ray {i} differs outside the known gap: brute force {w:?} \
                 (its box entered at {box_entry}), got {g:?}: {r:?}"
            );
        }
        eprintln!("{kind}{how}: {differ} of {} rays in the gap", rays.len());
    }
}
