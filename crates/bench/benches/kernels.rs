//! criterion micro-benchmarks of the hot kernels: a ray's set-up, the slab test of one box,
//! one traversal step (an 8-wide node's boxes at once), the watertight
//! triangle test (one, and a leaf block of eight), each with the SIMD
//! kernels on and off; and one whole closest-hit query on a real mesh.
//!
//! `cargo bench -p raymesh-bench --bench kernels`

use criterion::{criterion_group, criterion_main, Criterion};
use raymesh::workload::SplitMix;
use raymesh_accel::bvh::{BoxRay, Node8};
use raymesh_accel::{
    set_simd_enabled, Aabb, AccelKind, Primitives, Ray, Scene, Surface, TriangleMesh, Triangles,
    Vec3,
};
use raymesh_geometry::intersect_triangle;
use std::hint::black_box;

/// A fixed pseudo-random stream (the workloads' SplitMix64), so every run
/// measures the same input.
struct Rng(SplitMix);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(SplitMix::new(seed))
    }
    fn v(&mut self) -> Vec3 {
        Vec3::new(self.0.next_f32(), self.0.next_f32(), self.0.next_f32())
    }
}

/// 256 rays from a sphere around the unit cube toward points inside it.
fn rays(rng: &mut Rng) -> Vec<Ray> {
    (0..256)
        .map(|_| {
            let o = (rng.v() - 0.5).normalize_or_zero() * 2.0 + 0.5;
            Ray::infinite(o, rng.v() - o)
        })
        .collect()
}

fn kernels(c: &mut Criterion) {
    let mut rng = Rng::new(7);
    let rays = rays(&mut rng);
    let boxes: Vec<Aabb> = (0..8)
        .map(|_| {
            let p = rng.v();
            Aabb::new(p, p + rng.v() * 0.4)
        })
        .collect();
    let node = Node8::from_boxes(&boxes);
    let box_rays: Vec<BoxRay> = rays.iter().map(BoxRay::new).collect();
    let corners: Vec<[Vec3; 3]> = (0..8).map(|_| [rng.v(), rng.v(), rng.v()]).collect();
    let tm = TriangleMesh::new(
        corners.iter().flatten().copied().collect(),
        (0..8u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    );
    let block = Triangles::from_mesh(&tm);

    // What a query pays before any node: the reciprocal and the shear.
    let packed: Vec<(Vec3, Vec3)> = rays.iter().map(|r| (r.origin(), r.dir())).collect();
    c.bench_function("Ray::new (256 rays)", |b| {
        b.iter(|| {
            for &(o, d) in &packed {
                black_box(Ray::new(black_box(o), black_box(d), 0.0, f32::INFINITY));
            }
        })
    });

    c.bench_function("slab test, one box (256 rays)", |b| {
        b.iter(|| {
            let mut hits = 0;
            for r in &rays {
                hits += usize::from(
                    black_box(&boxes[0])
                        .intersect_ray(r, f32::INFINITY)
                        .is_some(),
                );
            }
            hits
        });
    });
    for simd in [true, false] {
        set_simd_enabled(simd);
        let tag = if simd { "simd" } else { "scalar" };
        c.bench_function(
            &format!("traversal step, 8-wide node, {tag} (256 rays)"),
            |b| {
                b.iter(|| {
                    let mut mask = 0;
                    for r in &box_rays {
                        mask ^= black_box(&node).slab(r, f32::INFINITY).0;
                    }
                    mask
                });
            },
        );
        c.bench_function(&format!("triangle block of 8, {tag} (256 rays)"), |b| {
            b.iter(|| {
                let mut mask = 0;
                for r in &rays {
                    mask ^= black_box(&block).intersect_block(0, 8, r, f32::INFINITY).0;
                }
                mask
            });
        });
    }
    set_simd_enabled(true);
    c.bench_function("triangle test, one (256 rays)", |b| {
        let [p0, p1, p2] = corners[0];
        b.iter(|| {
            let mut hits = 0;
            for r in &rays {
                hits += usize::from(
                    intersect_triangle(r, f32::INFINITY, black_box(p0), p1, p2).is_some(),
                );
            }
            hits
        });
    });

    // One whole query: bunny00 with the fastest BVH, when the shared meshes are there.
    let bunny = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/meshes/bunny00.off"
    );
    if let Ok(mesh) = raymesh_mesh::io::read_mesh(bunny) {
        let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
        let scene = Scene::from_mesh(&tm, AccelKind::FASTEST_BVH);
        let b = scene.bounds();
        let mut rng = Rng::new(11);
        let queries: Vec<Ray> = (0..256)
            .map(|_| {
                let o = b.centroid() + (rng.v() - 0.5).normalize_or_zero() * b.diagonal();
                let p = b.min + rng.v() * b.extent();
                Ray::infinite(o, p - o)
            })
            .collect();
        c.bench_function("closest hit, bunny00, bvh (256 random rays)", |bch| {
            bch.iter(|| {
                let mut hits = 0;
                for r in &queries {
                    hits += usize::from(scene.intersect(r).is_some());
                }
                hits
            });
        });
    }
}

criterion_group!(benches, kernels);
criterion_main!(benches);
