//! Meshes, hit keys and generators shared by the integration tests.

use proptest::prelude::*;
use raymesh_accel::{
    Aabb, AccelKind, BareHit, Hit, Primitives, Ray, Scene, Surface, TriangleMesh, Vec3,
};
use std::path::PathBuf;

/// Cases per property: `default`, or `RAYMESH_PROPTEST_CASES` where set
/// (higher for a long run; 1 under Miri, `scripts/miri.sh`, which
/// interprets every build and ray a case makes).
#[allow(dead_code)] // not every test file has properties
pub fn cases(default: u32) -> u32 {
    std::env::var("RAYMESH_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Whether a check of packets or streams against one-by-one tracing runs
/// `kind` over a mesh of `triangles`: brute force's packets and streams
/// are its rays one by one, checked over the small meshes; over the
/// elephant's 4,463 triangles its scalar tests took three quarters of
/// the real-mesh tests of packets and streams (`agree`'s `packets::` and
/// `stream::`: 4–5 s each, and a minute each in `.ci/run`'s emulated
/// aarch64 step).
#[allow(dead_code)] // not every test file checks packets or streams
pub fn worth_checking(kind: AccelKind, triangles: usize) -> bool {
    kind != AccelKind::Brute || triangles <= 2_000
}

/// A mesh from the repository's `tests/data`, fan-triangulated.
pub fn load(name: &str) -> TriangleMesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name);
    let m = raymesh_mesh::io::read_mesh(path).unwrap();
    TriangleMesh::new(m.positions.clone(), m.triangles())
}

/// A soup of triangles as an indexed mesh, three vertices each.
#[allow(dead_code)] // not every test file makes soups
pub fn tri_mesh(tris: &[[Vec3; 3]]) -> TriangleMesh {
    let positions: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let triangles = (0..tris.len() as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    TriangleMesh::new(positions, triangles)
}

/// A hit as bits (primitive, instance, `t`, `u`, `v`, normal), so that
/// `-0.0` and `0.0` differ: what "the same hit, bit for bit" compares.
#[allow(dead_code)]
pub fn hit_bits(h: Option<Hit>) -> Option<(u32, u32, u32, u32, u32, [u32; 3])> {
    h.map(|h| {
        (
            h.prim,
            h.instance,
            h.t.to_bits(),
            h.u.to_bits(),
            h.v.to_bits(),
            h.normal.to_array().map(f32::to_bits),
        )
    })
}

/// A [`BareHit`] as bits (primitive, `t`, `u`, `v`): [`hit_bits`] for the
/// queries without the normal.
#[allow(dead_code)]
pub fn bare_bits(h: Option<BareHit>) -> Option<(u32, u32, u32, u32)> {
    h.map(|h| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()))
}

/// A [`Hit`]'s [`bare_bits`]: what a query without the normal must give.
#[allow(dead_code)]
pub fn bare_of(h: Option<Hit>) -> Option<(u32, u32, u32, u32)> {
    bare_bits(h.map(BareHit::from))
}

/// The row (`[ox, oy, oz, tmin, dx, dy, dz, tmax]`) that makes ray `r`,
/// where `r` is valid (an invalid ray keeps an empty interval, not the one
/// it was given).
#[allow(dead_code)]
pub fn row_of(r: &Ray) -> Option<[f32; 8]> {
    r.is_valid().then(|| r.row())
}

/// What the row queries answer for `row`, as bits: the closest hit, the
/// any hit and the occlusion (`Scene::intersect_bare_row`,
/// `any_hit_bare_row`, `occluded_row`).
#[allow(dead_code, clippy::type_complexity)]
pub fn row_answers<P: Primitives>(
    s: &Scene<P>,
    row: &[f32; 8],
) -> (
    Option<(u32, u32, u32, u32)>,
    Option<(u32, u32, u32, u32)>,
    bool,
) {
    (
        bare_bits(s.intersect_bare_row(row)),
        bare_bits(s.any_hit_bare_row(row)),
        s.occluded_row(row),
    )
}

/// A point of the cube `[-2, 2]³`.
#[allow(dead_code)]
pub fn point() -> impl Strategy<Value = Vec3> {
    (-2.0f32..2.0, -2.0f32..2.0, -2.0f32..2.0).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// A soup's triangles, with one sharing an edge with the first and one
/// duplicating it.
#[allow(dead_code)]
pub fn soup(tris: Vec<(Vec3, Vec3, Vec3)>) -> Vec<[Vec3; 3]> {
    let mut t: Vec<[Vec3; 3]> = tris.into_iter().map(|(a, b, c)| [a, b, c]).collect();
    if let Some(&[a, b, c]) = t.first() {
        t.push([b, a, c + Vec3::Z]); // shares an edge
        t.push([a, b, c]); // duplicate
    }
    t
}

/// 8 × 8 unit squares in the plane z = 0, two triangles each: shared
/// edges and vertices on a lattice, for rays along and through them.
#[allow(dead_code)]
pub fn unit_grid() -> Vec<[Vec3; 3]> {
    (0..64)
        .flat_map(|i| {
            let (x, y) = ((i % 8) as f32, (i / 8) as f32);
            let p = |dx: f32, dy: f32| Vec3::new(x + dx, y + dy, 0.0);
            [
                [p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)],
                [p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)],
            ]
        })
        .collect()
}

/// Uniform floats in `[0, 1)` from a fixed seed (xorshift64), for rays
/// that need no strategy.
#[allow(dead_code)]
pub fn uniform(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Rays from a sphere around the mesh toward random points in its box, and
/// rays aimed exactly at vertices and edge midpoints (zero edge functions).
#[allow(dead_code)]
pub fn sphere_rays(m: &TriangleMesh, n: usize) -> Vec<Ray> {
    let b = m.positions.iter().fold(Aabb::EMPTY, |a, p| a.grow(*p));
    let (c, d) = (b.centroid(), b.diagonal());
    let mut next = uniform(0x2545_f491_4f6c_dd1d);
    let mut out = Vec::new();
    for i in 0..n {
        let dir = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5);
        let o = c + dir.normalize_or_zero() * 0.75 * d;
        let p = b.min + (b.max - b.min) * Vec3::new(next(), next(), next());
        out.push(Ray::infinite(o, p - o));
        let [a, bb, _] = m.corners((i % m.len()) as u32);
        out.push(Ray::infinite(o, a - o));
        out.push(Ray::infinite(o, (a + bb) * 0.5 - o));
    }
    out
}

/// A brute-force closest hit, as [`bare_of`] keys.
pub type Want = Vec<Option<(u32, u32, u32, u32)>>;

/// For the tests that compare a kernel's builds (SIMD or portable, AVX2
/// or AVX-512): four meshes of `tests/data` (holes, a closed sphere,
/// quads, degenerate triangles), each with its [`sphere_rays`] and brute
/// force's closest hits for them, a tenth of the rays or more hitting.
#[allow(dead_code)]
pub fn kernel_cases() -> Vec<(&'static str, TriangleMesh, Vec<Ray>, Want)> {
    let names = [
        "elephant-with-holes.off",
        "sphere.ply",
        "cube_quad.off",
        "degtri_sliding.off",
    ];
    names
        .into_iter()
        .map(|name| {
            let m = load(name);
            let rays = sphere_rays(&m, 400);
            let brute = Scene::build(m.clone(), AccelKind::Brute);
            let want: Want = rays.iter().map(|r| bare_of(brute.intersect(r))).collect();
            assert!(want.iter().filter(|w| w.is_some()).count() > rays.len() / 10);
            (name, m, rays, want)
        })
        .collect()
}

/// A degenerate (zero-area) triangle, the segment from the origin to
/// (2, 0, 0), and `n` rays through points of it, with a blocker across
/// each ray that hits the triangle short of where it crosses the segment.
/// A ray through the segment can hit the triangle (rounding leaves it a
/// tiny triangle around the ray, see
/// `raymesh_geometry::intersect_triangle`) at a `t` outside the corners'
/// box, which it enters only at the segment; the small triangle placed
/// across the ray halfway between is hit after the degenerate one. Rays
/// from all around, or (`coherent`) from four eyes, eight at a time
/// toward neighbouring points of the segment, as packets are made.
#[allow(dead_code)]
pub fn degenerate_with_blockers(n: usize, coherent: bool) -> (TriangleMesh, Vec<Ray>) {
    let mut next = uniform(0x5eed_0dd5);
    let segment = [Vec3::ZERO, Vec3::X * 2.0, Vec3::X];
    let alone = Scene::build(tri_mesh(&[segment]), AccelKind::Brute);
    // Two look along the segment, where its corners' distances along a
    // ray spread most.
    let eyes = [
        Vec3::new(-1.0, 1.5, 2.0),
        Vec3::new(-2.0, 0.4, 0.3),
        Vec3::new(4.0, -0.3, 0.5),
        Vec3::new(0.7, 0.4, -2.5),
    ];
    let (mut tris, mut rays) = (vec![segment], Vec::with_capacity(n));
    let mut aim = 0.0;
    for i in 0..n {
        let r = if coherent {
            if i % 8 == 0 {
                aim = 1.9 * next();
            }
            let eye = eyes[(i / 8) % eyes.len()];
            let p = Vec3::new(aim + 0.1 * next(), 0.0, 0.0);
            Ray::infinite(eye, (p - eye).normalize())
        } else {
            let p = Vec3::new(2.0 * next(), 0.0, 0.0);
            let d = Vec3::new(next() * 2.0 - 1.0, next() * 2.0 - 1.0, next() * 2.0 - 1.0);
            let d = d.normalize_or(Vec3::Y);
            Ray::infinite(p - d * (0.5 + 2.0 * next()), d)
        };
        // Where the ray passes the segment's line (`y = z = 0`), by the
        // axis its direction crosses it fastest on.
        let a = if r.dir().y.abs() > r.dir().z.abs() {
            1
        } else {
            2
        };
        let cross = -r.origin()[a] / r.dir()[a];
        if let Some(h) = alone.intersect(&r) {
            if h.t < cross * 0.99 {
                let at = r.at((h.t + cross) * 0.5);
                let (e, f) = r.dir().any_orthonormal_pair();
                tris.push([
                    at + e * 0.01,
                    at - e * 0.01 + f * 0.01,
                    at - e * 0.01 - f * 0.01,
                ]);
            }
        }
        rays.push(r);
    }
    assert!(tris.len() > n / 200, "{} blockers", tris.len() - 1);
    (tri_mesh(&tris), rays)
}

/// Thin triangles hit at grazing angles, each hit that lies short of its
/// triangle's corners' box (by more than four times the traversals'
/// slack, [`raymesh_geometry::CULL_SLACK`] of `t`) with a small blocker
/// placed across the ray halfway between the hit and the box's entry: the
/// known gap of the README's exactness paragraph, made to show. `slivers`
/// triangles, each two units long and `2 / α` wide (α from 10 to 10⁴), in
/// planes flat or tilted by 10⁻³ or 2 × 10⁻³ (a box thin in one axis,
/// whose face a ray in the plane grazes), far apart; `tries` rays at
/// each, aimed at a point inside it from 0.5 to 2.5 units away, 10⁻¹ to
/// 10⁻⁶ radians off its plane. Returns the mesh (the slivers first), the kept rays, and
/// how many slivers there are.
#[allow(dead_code)]
pub fn thin_with_blockers(slivers: usize, tries: usize) -> (TriangleMesh, Vec<Ray>, usize) {
    let mut next = uniform(0x7417_0001);
    let mut rnd = move || {
        let v = Vec3::new(next(), next(), next()) * 2.0 - Vec3::ONE;
        (v, next(), next(), next())
    };
    let (mut tris, mut blockers, mut rays) = (Vec::new(), Vec::new(), Vec::new());
    for j in 0..slivers {
        let c = Vec3::new(10.0 * j as f32, 0.0, 0.0);
        let (v, s, alpha, _) = rnd();
        let tilt = 1e-3 * (j % 3) as f32;
        let e = Vec3::new(v.x, v.y, v.z * tilt).normalize_or(Vec3::X);
        let f = Vec3::new(-e.y, e.x, 0.0).normalize_or(Vec3::Y);
        let alpha = 10f32.powf(1.0 + 3.0 * alpha);
        let a = [c - e, c + e, c + e * (s * 1.8 - 0.9) + f * (2.0 / alpha)];
        tris.push(a);
        let alone = Scene::build(tri_mesh(&[a]), AccelKind::Brute);
        let n = (a[1] - a[0]).cross(a[2] - a[0]).normalize();
        let bounds = Aabb::from_points(a);
        for _ in 0..tries {
            let (w, u, v, x) = rnd();
            let (u, v) = if u + v > 1.0 {
                (1.0 - u, 1.0 - v)
            } else {
                (u, v)
            };
            let p = a[0] + (a[1] - a[0]) * u + (a[2] - a[0]) * v;
            let along = (w - n * n.dot(w)).normalize_or(e);
            let off = 10f32.powf(-1.0 - 5.0 * x) * if w.x < 0.0 { -1.0 } else { 1.0 };
            let d = (along + n * off).normalize();
            let r = Ray::infinite(p - d * (0.5 + 2.0 * (w.y * 0.5 + 0.5)), d);
            let Some(h) = alone.intersect(&r) else {
                continue;
            };
            let Some((entry, _)) = bounds.intersect_ray(&r, f32::INFINITY) else {
                continue;
            };
            if h.t * (1.0 + 4.0 * raymesh_geometry::CULL_SLACK) < entry {
                let at = r.at((h.t + entry) * 0.5);
                let (g, k) = r.dir().any_orthonormal_pair();
                let s = (entry - h.t) * 0.05;
                blockers.push([at + g * s, at - g * s + k * s, at - g * s - k * s]);
                rays.push(r);
            }
        }
    }
    tris.extend(blockers);
    (tri_mesh(&tris), rays, slivers)
}
