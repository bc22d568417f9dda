//! `raymesh bench MESH... [--accel LIST|all] [--workloads LIST] [--size N]
//! [--threads LIST] [--repeat R] [--json] [--spatial-splits [FRACTION]]
//! [--packets | --stream]`: BENCH.md's workloads through every chosen
//! structure, one table per mesh (or JSON lines).

use crate::cmd::raycast::{count, tracer};
use crate::cmd::thread_pool;
use crate::npy::HitRecord;
use crate::workload::{make_rays_framing, parse_frame, Workload};
use anyhow::{bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use raymesh_accel::{AccelKind, BuildConfig, Scene, Surface, TriangleMesh};
use raymesh_mesh::io::read_mesh;
use serde::Serialize;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `raymesh bench`.
#[derive(clap::Args)]
pub struct Args {
    /// Mesh files.
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
    /// Structures, comma-separated, or `all` (every structure but brute and aabb, which test every triangle).
    #[arg(long, default_value = "bvh,bvh4,grid,kdtree")]
    pub accel: String,
    /// Workloads, comma-separated (BENCH.md).
    #[arg(long, default_value = "primary,random,diffuse,shadow")]
    pub workloads: String,
    /// Image width and height of the workloads (random: the square root of the ray count).
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub size: u32,
    /// Thread counts, comma-separated, each 1 to 1024 (default: 1 and all cores).
    #[arg(long)]
    pub threads: Option<String>,
    /// Timed repeats; the best is reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// Aim the workloads at this box instead of each mesh's whole box:
    /// `minx,miny,minz,maxx,maxy,maxz` (as `raymesh rays --frame`).
    #[arg(long, allow_hyphen_values = true)]
    pub frame: Option<String>,
    /// Print JSON lines instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Spatial splits for bvh-binned, bvh4 and bvh8 (as `raycast
    /// --spatial-splits`): up to FRACTION more references than triangles,
    /// 0.25 when given alone.
    #[arg(long, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "0.25",
          value_parser = crate::cmd::parse_fraction)]
    pub spatial_splits: Option<f32>,
    /// Reinsertion optimization of every BVH's binary tree (as `raycast
    /// --optimize`).
    #[arg(long)]
    pub optimize: bool,
    /// Trace eight consecutive rays at a time as packets (as `raycast
    /// --packets`): for a camera's rays and shadow rays toward one light.
    #[arg(long, conflicts_with = "stream")]
    pub packets: bool,
    /// Trace each task's rays as a stream, several walking the tree at once
    /// (as `raycast --stream`): for incoherent rays over meshes larger than
    /// the caches.
    #[arg(long)]
    pub stream: bool,
}

/// One measured row.
#[derive(Serialize)]
struct Row {
    mesh: String,
    triangles: usize,
    accel: &'static str,
    workload: &'static str,
    rays: usize,
    threads: usize,
    build_ms_1_thread: f64,
    build_ms_all_threads: f64,
    bytes_per_triangle: f64,
    nodes: usize,
    depth: usize,
    sah_cost: f64,
    closest_mrays_per_s: f64,
    any_hit_mrays_per_s: f64,
    nodes_per_ray: f64,
    triangles_per_ray: f64,
    spatial_splits: f32,
    optimize: bool,
    packets: bool,
    stream: bool,
}

fn parse_list<T: std::str::FromStr<Err = String>>(s: &str) -> Result<Vec<T>> {
    s.split(',')
        .map(|x| x.trim().parse::<T>().map_err(anyhow::Error::msg))
        .collect()
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    let accels: Vec<AccelKind> = if args.accel == "all" {
        AccelKind::ALL
            .into_iter()
            .filter(|k| !matches!(k, AccelKind::Brute | AccelKind::Aabb))
            .collect()
    } else {
        parse_list(&args.accel)?
    };
    let workloads: Vec<Workload> = parse_list(&args.workloads)?;
    let config = BuildConfig {
        spatial_splits: args.spatial_splits.unwrap_or(0.0),
        optimize: args.optimize,
        ..BuildConfig::default()
    };
    let frame = args.frame.as_deref().map(parse_frame).transpose()?;
    let all = thread_pool(None)?.current_num_threads();
    let threads: Vec<usize> = match &args.threads {
        Some(t) => t
            .split(',')
            .map(|x| {
                x.trim()
                    .parse::<usize>()
                    .map_err(|_| anyhow::anyhow!("--threads: '{x}' is not a thread count"))
            })
            .collect::<Result<_>>()?,
        None if all > 1 => vec![1, all],
        None => vec![1],
    };
    if threads.contains(&0) {
        bail!("--threads: thread counts must be at least 1");
    }
    let pools: Vec<rayon::ThreadPool> = threads
        .iter()
        .map(|&t| thread_pool(Some(t)))
        .collect::<Result<_>>()?;
    let one = thread_pool(Some(1))?;
    let steps = (args.meshes.len() * accels.len() * workloads.len()) as u64;
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(steps);
        b.set_style(
            ProgressStyle::with_template("{spinner} bench [{bar:30}] {pos}/{len} {msg}")?
                .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    for path in &args.meshes {
        let mesh = read_mesh(path)?;
        let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
        let ntri = tm.triangles.len();
        let reference = Scene::build(tm.clone(), AccelKind::FASTEST_BVH);
        let rays: Vec<(Workload, Vec<[f32; 8]>)> = workloads
            .iter()
            .map(|&w| {
                let r = make_rays_framing(
                    w,
                    &reference,
                    frame.unwrap_or(reference.bounds()),
                    args.size,
                    1,
                );
                (w, r)
            })
            .collect();
        let trace_with = tracer(args.packets, args.stream);
        let mut rows = Vec::new();
        for &accel in &accels {
            let build = |pool: &rayon::ThreadPool| {
                pool.install(|| {
                    let t = Instant::now();
                    let s = Scene::from_mesh_with(&tm, accel, &config);
                    (t.elapsed().as_secs_f64() * 1e3, s)
                })
            };
            let (build_1, scene) = build(&one);
            let (build_all, _) = build(pools.last().expect("a pool"));
            let st = scene.stats();
            for (w, rs) in &rays {
                bar.set_message(format!("{} {} {}", path.display(), accel, w.name()));
                let (nodes_per_ray, tris_per_ray) =
                    one.install(|| count(&scene, rs, w.name() == "shadow"));
                let mut hits = vec![HitRecord::MISS; rs.len()];
                for (pool, &t) in pools.iter().zip(&threads) {
                    let mut time = |any: bool| {
                        let mut best = f64::INFINITY;
                        for _ in 0..args.repeat {
                            let s = Instant::now();
                            pool.install(|| trace_with(&scene, rs, any, &mut hits));
                            best = best.min(s.elapsed().as_secs_f64());
                        }
                        rs.len() as f64 / best / 1e6
                    };
                    let closest = time(false);
                    let any = time(true);
                    rows.push(Row {
                        mesh: path.display().to_string(),
                        triangles: ntri,
                        accel: st.name,
                        workload: w.name(),
                        rays: rs.len(),
                        threads: t,
                        build_ms_1_thread: build_1,
                        build_ms_all_threads: build_all,
                        bytes_per_triangle: (st.bytes + scene.prims().bytes()) as f64
                            / ntri.max(1) as f64,
                        nodes: st.nodes,
                        depth: st.depth,
                        sah_cost: st.sah_cost,
                        closest_mrays_per_s: closest,
                        any_hit_mrays_per_s: any,
                        nodes_per_ray,
                        triangles_per_ray: tris_per_ray,
                        // What this structure's build took: the others
                        // ignore these settings.
                        spatial_splits: if accel.takes_spatial_splits() {
                            config.spatial_splits
                        } else {
                            0.0
                        },
                        optimize: config.optimize && accel.is_bvh(),
                        packets: args.packets,
                        stream: args.stream,
                    });
                }
                bar.inc(1);
            }
        }
        bar.suspend(|| print_rows(&rows, args.json, path, ntri))?;
    }
    bar.finish_and_clear();
    Ok(())
}

fn print_rows(rows: &[Row], json: bool, path: &std::path::Path, ntri: usize) -> Result<()> {
    if json {
        for r in rows {
            println!("{}", serde_json::to_string(r)?);
        }
        return Ok(());
    }
    let mode = match rows.first() {
        Some(r) if r.packets => ", rays traced as packets of 8",
        Some(r) if r.stream => ", rays traced as streams",
        _ => "",
    };
    println!("\n{} ({ntri} triangles{mode})", path.display());
    println!(
        "{:<11} {:<8} {:>3} {:>9} {:>9} {:>7} {:>8} {:>6} {:>6} {:>9} {:>9} {:>8} {:>8}",
        "structure",
        "workload",
        "thr",
        "build1 ms",
        "buildN ms",
        "B/tri",
        "nodes",
        "depth",
        "SAH",
        "closest",
        "any-hit",
        "nodes/r",
        "tris/r"
    );
    for r in rows {
        println!(
            "{:<11} {:<8} {:>3} {:>9.1} {:>9.1} {:>7.1} {:>8} {:>6} {:>6.1} {:>9} {:>9} {:>8.1} {:>8.1}",
            r.accel,
            r.workload,
            r.threads,
            r.build_ms_1_thread,
            r.build_ms_all_threads,
            r.bytes_per_triangle,
            r.nodes,
            r.depth,
            r.sah_cost,
            crate::cmd::rate(r.closest_mrays_per_s),
            crate::cmd::rate(r.any_hit_mrays_per_s),
            r.nodes_per_ray,
            r.triangles_per_ray
        );
    }
    println!("(Mrays/s; closest and any-hit are the best of the repeats; nodes/r and tris/r are per ray, counted in a separate pass)");
    Ok(())
}
