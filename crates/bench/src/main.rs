//! `raymesh-peers MESH... [--rays RAYS.npy | --workloads LIST --size N]
//! [--threads LIST] [--repeat R] [--accel A] [--markdown]`: the same rays
//! through raymesh and, built with `--features embree`, through Intel
//! Embree 3, in one run: build time, bytes, closest-hit and any-hit
//! Mrays/s per workload and thread count, ratios, and how far the hits
//! agree (same triangle, or `t` within 1e-4 relative, as
//! `../shared/BENCH.md` asks).

#[cfg(feature = "embree")]
mod embree_peer;

use anyhow::{bail, Result};
use clap::Parser;
use raymesh::npy;
use raymesh::workload::{make_rays, Workload};
use raymesh_accel::{AccelKind, Scene, Surface, TriangleMesh, Triangles};
use raymesh_mesh::io::read_mesh;
use std::path::PathBuf;
use std::time::Instant;

/// Side-by-side ray-query benchmark against Embree.
#[derive(Parser)]
struct Args {
    /// Mesh files.
    #[arg(required = true)]
    meshes: Vec<PathBuf>,
    /// Rays from a file (BENCH.md's (N, 8) float32 .npy) instead of generated workloads.
    #[arg(long)]
    rays: Option<PathBuf>,
    /// Workloads to generate (BENCH.md), comma-separated.
    #[arg(long, default_value = "primary,random,diffuse,shadow")]
    workloads: String,
    /// Image size of generated workloads.
    #[arg(long, default_value_t = 1024)]
    size: u32,
    /// Thread counts, comma-separated.
    #[arg(long, default_value = "1")]
    threads: String,
    /// Timed repeats; the best is reported.
    #[arg(long, default_value_t = 3)]
    repeat: u32,
    /// raymesh structure.
    #[arg(long, default_value = "bvh")]
    accel: AccelKind,
    /// Print a markdown table as well.
    #[arg(long)]
    markdown: bool,
}

/// Best time of `repeat` runs of `f`, in seconds, and its last result.
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

/// Traces every ray on `threads` threads (1024-ray chunks), collecting per-ray results.
fn trace_all<T: Send>(threads: usize, n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    use rayon::prelude::*;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    pool.install(|| (0..n).into_par_iter().with_min_len(1024).map(f).collect())
}

/// One measured line.
struct Line {
    mesh: String,
    workload: String,
    threads: usize,
    query: &'static str,
    raymesh: f64,
    embree: Option<f64>,
    agree: Option<f64>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let threads: Vec<usize> = args
        .threads
        .split(',')
        .map(|t| t.trim().parse())
        .collect::<Result<_, _>>()?;
    if threads.contains(&0) {
        bail!("thread counts must be at least 1");
    }
    let mut lines = Vec::new();
    for path in &args.meshes {
        let mesh = read_mesh(path)?;
        let tris = mesh.triangles();
        let tm = TriangleMesh::new(mesh.positions.clone(), tris.clone());
        let scene = Scene::build(Triangles::from_mesh(&tm), args.accel);
        let st = scene.stats();
        let rm_bytes = (st.bytes + tris.len() * 36) as f64 / tris.len().max(1) as f64;
        println!("{}: {} triangles", path.display(), tris.len());
        println!(
            "  raymesh {:<10} build {:7.1} ms (1 thread)  {:6.1} B/tri",
            st.name, st.build_ms, rm_bytes
        );
        #[cfg(feature = "embree")]
        let em = {
            let em = embree_peer::EmbreeScene::new(&mesh.positions, &tris, 1);
            println!(
                "  embree  {:<10} build {:7.1} ms (1 thread)  {:6.1} B/tri",
                "bvh",
                em.build_ms,
                em.bytes as f64 / tris.len().max(1) as f64
            );
            em
        };
        let workloads: Vec<(String, Vec<[f32; 8]>)> = match &args.rays {
            Some(file) => {
                let rays = npy::parse_rays(&std::fs::read(file)?)?;
                let raw = rays
                    .iter()
                    .map(|r| {
                        let (o, d) = (r.origin(), r.dir());
                        [o.x, o.y, o.z, r.tmin(), d.x, d.y, d.z, r.tmax()]
                    })
                    .collect();
                vec![(file.display().to_string(), raw)]
            }
            None => {
                let reference = Scene::build(tm.clone(), AccelKind::FASTEST_BVH);
                args.workloads
                    .split(',')
                    .map(|w| {
                        let w: Workload = w.trim().parse().map_err(anyhow::Error::msg)?;
                        Ok((w.name().to_string(), make_rays(w, &reference, args.size, 1)))
                    })
                    .collect::<Result<_>>()?
            }
        };
        for (name, raw) in &workloads {
            let rays: Vec<raymesh_accel::Ray> = raw
                .iter()
                .map(|r| {
                    raymesh_accel::Ray::new(
                        raymesh_accel::Vec3::new(r[0], r[1], r[2]),
                        raymesh_accel::Vec3::new(r[4], r[5], r[6]),
                        r[3],
                        r[7],
                    )
                })
                .collect();
            let n = rays.len();
            for &t in &threads {
                for any in [false, true] {
                    let (rm_s, rm_hits): (f64, Vec<Option<(f32, u32)>>) = best(args.repeat, || {
                        trace_all(t, n, |i| {
                            let r = &rays[i];
                            if any {
                                scene.occluded(r).then_some((0.0, 0))
                            } else {
                                scene.intersect(r).map(|h| (h.t, h.prim))
                            }
                        })
                    });
                    let raymesh = n as f64 / rm_s / 1e6;
                    #[allow(unused_mut)]
                    let mut line = Line {
                        mesh: path.display().to_string(),
                        workload: name.clone(),
                        threads: t,
                        query: if any { "any-hit" } else { "closest" },
                        raymesh,
                        embree: None,
                        agree: None,
                    };
                    #[cfg(feature = "embree")]
                    {
                        let (em_s, em_hits): (f64, Vec<Option<(f32, u32)>>) =
                            best(args.repeat, || {
                                trace_all(t, n, |i| {
                                    let r = &raw[i];
                                    if any {
                                        em.occluded(r).then_some((0.0, 0))
                                    } else {
                                        em.intersect(r).map(|(t, p, _, _)| (t, p))
                                    }
                                })
                            });
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
                        line.embree = Some(n as f64 / em_s / 1e6);
                        line.agree = Some(agree as f64 / n.max(1) as f64);
                    }
                    let _ = &rm_hits;
                    match (line.embree, line.agree) {
                        (Some(e), Some(a)) => println!(
                            "  {:<8} {} thr {:<8} raymesh {:6.2}  embree {:6.2} Mrays/s  ratio {:.2}  hits agree on {:.3}% of rays",
                            line.workload, line.threads, line.query, line.raymesh, e, line.raymesh / e, 100.0 * a
                        ),
                        _ => println!("  {:<8} {} thr {:<8} raymesh {:6.2} Mrays/s", line.workload, line.threads, line.query, line.raymesh),
                    }
                    lines.push(line);
                }
            }
        }
    }
    if args.markdown {
        println!("\n| mesh | workload | threads | query | raymesh Mrays/s | Embree Mrays/s | ratio | hits agree |");
        println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
        for l in &lines {
            let mesh = std::path::Path::new(&l.mesh)
                .file_name()
                .map_or(l.mesh.clone(), |f| f.to_string_lossy().into_owned());
            match (l.embree, l.agree) {
                (Some(e), Some(a)) => println!(
                    "| {mesh} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.3}% |",
                    l.workload,
                    l.threads,
                    l.query,
                    l.raymesh,
                    e,
                    l.raymesh / e,
                    100.0 * a
                ),
                _ => println!(
                    "| {mesh} | {} | {} | {} | {:.2} | | | |",
                    l.workload, l.threads, l.query, l.raymesh
                ),
            }
        }
    }
    Ok(())
}
