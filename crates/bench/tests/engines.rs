//! The engines of the side-by-side benchmark (`raymesh_bench::engines`),
//! wired as `raymesh-peers` wires them: every Rust peer answers as raymesh
//! does, and raymesh's own modes (streams, packets, each structure as an
//! engine) give its one-ray answers exactly.

use raymesh::workload::{make_rays, Workload};
use raymesh_accel::{AccelKind, BuildConfig, Scene, Surface, TriangleMesh};
use raymesh_bench::engines::{
    build, moller_trumbore, structure_engine, structure_of, Answer, Runner, OPT_IN_PEERS,
    RUST_PEERS,
};
use raymesh_geometry::Vec3;

/// Every Rust peer, wired as the benchmark wires it, answers as raymesh
/// does on real meshes: the same triangle or the same `t` (their
/// Möller–Trumbore tests are not watertight, so a ray through an edge
/// may differ; allow one ray in a thousand), on one and two threads, with
/// rays clipped to `[tmin, tmax]` windows.
#[test]
fn peers_agree_with_raymesh() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data");
    for file in ["elephant-with-holes.off", "double-torus-example.off"] {
        let mesh = raymesh_mesh::io::read_mesh(format!("{dir}/{file}")).expect("test mesh");
        let tris = mesh.triangles();
        let reference = build(
            "raymesh",
            AccelKind::FASTEST_BVH,
            &BuildConfig::default(),
            &mesh.positions,
            &tris,
        );
        let scene = Scene::build(
            TriangleMesh::new(mesh.positions.clone(), tris.clone()),
            AccelKind::FASTEST_BVH,
        );
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let run = Runner {
                pool: &pool,
                repeat: 1,
                packets: false,
                stream: false,
            };
            // raymesh's stream mode (over a binary and an 8-wide BVH,
            // where it interleaves rays) gives its one-ray answers
            // exactly.
            let binary = build(
                "raymesh",
                AccelKind::BvhBinned,
                &BuildConfig::default(),
                &mesh.positions,
                &tris,
            );
            let stream = Runner {
                stream: true,
                ..run
            };
            for w in [Workload::Primary, Workload::Random, Workload::Shadow] {
                let rays = make_rays(w, &scene, 48, 3);
                for (engine, what) in [(&binary, "binary"), (&reference, "wide")] {
                    for any in [false, true] {
                        let (_, want) = engine.trace(&rays, any, &run);
                        let (_, got) = engine.trace(&rays, any, &stream);
                        assert_eq!(got, want, "{file}: {w:?} as a {what} stream, any {any}");
                    }
                }
            }
            // raymesh's packet mode gives its one-ray answers exactly,
            // camera rays (coherent packets) included.
            let packets = Runner {
                packets: true,
                ..run
            };
            for w in [Workload::Primary, Workload::Random, Workload::Shadow] {
                let rays = make_rays(w, &scene, 48, 3);
                for any in [false, true] {
                    let (_, want) = reference.trace(&rays, any, &run);
                    let (_, got) = reference.trace(&rays, any, &packets);
                    assert_eq!(
                        got, want,
                        "{file}: {w:?} in packets, any {any}, {threads} threads"
                    );
                }
            }
            for w in [Workload::Random, Workload::Diffuse, Workload::Shadow] {
                let mut rays = make_rays(w, &scene, 48, 3);
                // Clip every other random ray to a window around the
                // mesh's middle, so that tmin and tmax matter.
                if w == Workload::Random {
                    let c = scene.bounds().centroid();
                    for r in rays.iter_mut().step_by(2) {
                        let (o, d) = (Vec3::new(r[0], r[1], r[2]), Vec3::new(r[4], r[5], r[6]));
                        let mid = (c - o).dot(d) / d.length_squared();
                        (r[3], r[7]) = (0.9 * mid, 1.1 * mid);
                    }
                }
                for any in [false, true] {
                    let (_, want) = reference.trace(&rays, any, &run);
                    let hits = want.iter().filter(|a| a.is_some()).count();
                    if w == Workload::Random {
                        assert!(hits > rays.len() / 10, "{file}: too few hits to test");
                    }
                    // raymesh through its other entry point (each `Ray`
                    // made by the caller), and over each of its
                    // structures as an engine of its own, gives the
                    // same answers exactly; the Rust peers the same
                    // triangles.
                    let ours = AccelKind::ALL.map(structure_engine);
                    for name in OPT_IN_PEERS.into_iter().chain(ours).chain(RUST_PEERS) {
                        let peer = pool.install(|| {
                            build(
                                name,
                                AccelKind::FASTEST_BVH,
                                &BuildConfig::default(),
                                &mesh.positions,
                                &tris,
                            )
                        });
                        assert_eq!(peer.name(), name);
                        let (_, got) = peer.trace(&rays, any, &run);
                        if let Some(kind) = structure_of(name) {
                            assert_eq!(peer.accel(), Some(kind), "{name}");
                            assert_eq!(got, want, "{name} on {file}, {w:?}, any-hit {any}");
                            continue;
                        }
                        if OPT_IN_PEERS.contains(&name) {
                            assert_eq!(got, want, "{name} on {file}, {w:?}, any-hit {any}");
                            continue;
                        }
                        // The same triangle, and t within 1e-4 relative.
                        let same = |a: &Answer, b: &Answer| match (a, b) {
                            (Some((ta, pa)), Some((tb, pb))) => {
                                pa == pb && (ta - tb).abs() <= 1e-4 * ta.abs().max(tb.abs())
                            }
                            _ => a == b,
                        };
                        let differ = got.iter().zip(&want).filter(|(a, b)| !same(a, b)).count();
                        assert!(
                            differ * 1000 <= rays.len(),
                            "{name} on {file}, {w:?}, any-hit {any}, {threads} threads: \
                             {differ} of {} rays differ",
                            rays.len()
                        );
                    }
                }
            }
        }
    }
}

/// The two-sided test finds hits from both sides, inside `[tmin, tmax]` only.
#[test]
fn moller_trumbore_is_two_sided_and_bounded() {
    let p = [
        nalgebra::Point3::new(0.0, 0.0, 0.0),
        nalgebra::Point3::new(1.0, 0.0, 0.0),
        nalgebra::Point3::new(0.0, 1.0, 0.0),
    ];
    let (o, d) = (Vec3::new(0.25, 0.25, 1.0), Vec3::new(0.0, 0.0, -1.0));
    assert_eq!(moller_trumbore(o, d, &p, 0.0, f32::INFINITY), 1.0);
    assert_eq!(
        moller_trumbore(-o + Vec3::new(0.5, 0.5, 0.0), -d, &p, 0.0, 9.0),
        1.0
    );
    assert!(moller_trumbore(o, d, &p, 0.0, 0.5).is_infinite());
    assert!(moller_trumbore(o, d, &p, 1.5, 9.0).is_infinite());
    assert!(moller_trumbore(Vec3::new(2.0, 2.0, 1.0), d, &p, 0.0, 9.0).is_infinite());
}
