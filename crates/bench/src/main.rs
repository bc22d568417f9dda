//! `raymesh-peers MESH --rays RAYS.npy [--any-hit] [--repeat R]`: the same
//! rays through raymesh's BVH and, built with `--features embree`, through
//! Intel Embree 3, on one thread, in one run: build time, bytes, Mrays/s,
//! ratios, and how far the hits agree (same triangle, or `t` within 1e-4
//! relative, as `../shared/BENCH.md` asks).

#[cfg(feature = "embree")]
mod embree_peer;

use anyhow::Result;
use clap::Parser;
use raymesh::npy;
use raymesh_accel::{AccelKind, Scene, Surface, TriangleMesh, Triangles};
use raymesh_mesh::io::read_mesh;
use std::path::PathBuf;
use std::time::Instant;

/// Side-by-side ray-query benchmark against Embree.
#[derive(Parser)]
struct Args {
    /// Mesh file.
    mesh: PathBuf,
    /// Rays (BENCH.md's (N, 8) float32 .npy).
    #[arg(long)]
    rays: PathBuf,
    /// Any-hit queries.
    #[arg(long)]
    any_hit: bool,
    /// Timed repeats; the best is reported.
    #[arg(long, default_value_t = 3)]
    repeat: u32,
    /// raymesh structure.
    #[arg(long, default_value = "bvh")]
    accel: AccelKind,
}

/// Best time of `repeat` runs of `f` over all rays, in seconds.
fn best<T>(repeat: u32, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.expect("at least one run"))
}

fn main() -> Result<()> {
    let args = Args::parse();
    let mesh = read_mesh(&args.mesh)?;
    let tris = mesh.triangles();
    let bytes = std::fs::read(&args.rays)?;
    let rays = npy::parse_rays(&bytes)?;
    let raw: Vec<[f32; 8]> = rays
        .iter()
        .map(|r| {
            let (o, d) = (r.origin(), r.dir());
            [o.x, o.y, o.z, r.tmin(), d.x, d.y, d.z, r.tmax()]
        })
        .collect();
    let n = rays.len() as f64;

    let tm = TriangleMesh::new(mesh.positions.clone(), tris.clone());
    let scene = Scene::build(Triangles::from_mesh(&tm), args.accel);
    let st = scene.stats();
    let rm_bytes = st.bytes + tris.len() * 36;
    let (rm_s, rm_hits): (f64, Vec<Option<(f32, u32)>>) = best(args.repeat, || {
        rays.iter()
            .map(|r| {
                if args.any_hit {
                    scene.occluded(r).then_some((0.0, 0))
                } else {
                    scene.intersect(r).map(|h| (h.t, h.prim))
                }
            })
            .collect()
    });
    let rm_mrays = n / rm_s / 1e6;
    println!(
        "mesh {}: {} triangles, {} rays{}, 1 thread",
        args.mesh.display(),
        tris.len(),
        rays.len(),
        if args.any_hit { ", any hit" } else { "" }
    );
    println!(
        "raymesh {:<10} build {:7.1} ms  {:6.1} B/tri  {:6.2} Mrays/s",
        st.name,
        st.build_ms,
        rm_bytes as f64 / tris.len() as f64,
        rm_mrays
    );
    #[cfg_attr(not(feature = "embree"), allow(unused_mut))]
    let mut report = serde_json::json!({
        "mesh": args.mesh.display().to_string(), "rays": rays.len(), "any_hit": args.any_hit,
        "raymesh": { "accel": st.name, "build_ms": st.build_ms, "bytes_per_triangle": rm_bytes as f64 / tris.len() as f64, "mrays_per_s": rm_mrays },
    });

    #[cfg(feature = "embree")]
    {
        let em = embree_peer::EmbreeScene::new(&mesh.positions, &tris, 1);
        let (em_s, em_hits): (f64, Vec<Option<(f32, u32)>>) = best(args.repeat, || {
            raw.iter()
                .map(|r| {
                    if args.any_hit {
                        em.occluded(r).then_some((0.0, 0))
                    } else {
                        em.intersect(r).map(|(t, p, _, _)| (t, p))
                    }
                })
                .collect()
        });
        let em_mrays = n / em_s / 1e6;
        let agree = rm_hits
            .iter()
            .zip(&em_hits)
            .filter(|(a, b)| match (a, b) {
                (None, None) => true,
                (Some((ta, pa)), Some((tb, pb))) => {
                    pa == pb || (ta - tb).abs() <= 1e-4 * ta.abs().max(tb.abs())
                }
                _ => false,
            })
            .count();
        println!(
            "embree  {:<10} build {:7.1} ms  {:6.1} B/tri  {:6.2} Mrays/s",
            "bvh",
            em.build_ms,
            em.bytes as f64 / tris.len() as f64,
            em_mrays
        );
        println!(
            "ratio raymesh/embree: speed {:.2}, build time {:.2}; hits agree on {:.3}% of rays",
            rm_mrays / em_mrays,
            st.build_ms / em.build_ms,
            100.0 * agree as f64 / n
        );
        report["embree"] = serde_json::json!({ "build_ms": em.build_ms, "bytes_per_triangle": em.bytes as f64 / tris.len() as f64, "mrays_per_s": em_mrays });
        report["speed_ratio"] = serde_json::json!(rm_mrays / em_mrays);
        report["agreement"] = serde_json::json!(agree as f64 / n);
    }
    #[cfg(not(feature = "embree"))]
    {
        let _ = (&raw, &rm_hits);
        println!("(built without --features embree: no peer measured)");
    }
    println!("{report}");
    Ok(())
}
