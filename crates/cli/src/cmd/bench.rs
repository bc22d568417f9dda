//! `raymesh bench MESH... [--accel LIST|all] [--workloads LIST] [--size N]
//! [--threads LIST] [--repeat R] [--json] [--spatial-splits [FRACTION]]
//! [--packets | --stream] [--peers LIST [-- ARGS...]]`: BENCH.md's
//! workloads through every chosen structure, one table per mesh (or JSON
//! lines); with `--peers`, the same rays through raymesh and its peers
//! (Embree, obvhs, bvh, parry3d) side by side, run by `raymesh-peers`.

use crate::cmd::raycast::{count, tracer};
use crate::cmd::{thread_pool, MAX_THREADS};
use crate::npy::HitRecord;
use crate::workload::{make_rays_framing, parse_frame, Workload};
use anyhow::{bail, Context, Result};
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
    /// Structures, comma-separated, or `all` (every structure but brute and
    /// aabb, which test every triangle) [default: bvh,bvh4,grid,kdtree; with
    /// --peers, bvh].
    #[arg(long)]
    pub accel: Option<String>,
    /// Workloads, comma-separated (BENCH.md).
    #[arg(long, default_value = "primary,random,diffuse,shadow")]
    pub workloads: String,
    /// Image width and height of the workloads (random: the square root of the ray count).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub size: u32,
    /// Thread counts, comma-separated, each 1 to 1024 (default: 1 and all cores).
    #[arg(long, allow_negative_numbers = true)]
    pub threads: Option<String>,
    /// Timed repeats; the best is reported.
    #[arg(long, allow_negative_numbers = true, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
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
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "0.25",
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
    /// Compare with peers instead, in one run on the same rays: `embree`,
    /// `obvhs`, `bvh`, `parry3d`, comma-separated, or `all` (every one
    /// built in). Runs `raymesh-peers` (crates/bench, which keeps the
    /// peers' dependencies out of raymesh; found beside this executable,
    /// or named by the RAYMESH_PEERS environment variable) with this
    /// command's meshes, --accel, --workloads, --size, --threads, --repeat,
    /// --packets, --stream and --json, and the arguments after `--` (e.g.
    /// `-- --interleave --markdown --chart peers.png`; `raymesh-peers
    /// --help` lists them).
    #[arg(long, value_name = "LIST")]
    pub peers: Option<String>,
    /// With --peers: more arguments for `raymesh-peers`, after `--`.
    #[arg(last = true, value_name = "PEER_ARGS", requires = "peers")]
    pub peer_args: Vec<String>,
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

/// The thread counts `--threads` names, or 1 and all cores.
fn thread_counts(arg: Option<&str>) -> Result<Vec<usize>> {
    let all = thread_pool(None)?.current_num_threads();
    let threads: Vec<usize> = match arg {
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
    if let Some(&n) = threads.iter().find(|&&n| n > MAX_THREADS) {
        bail!("--threads {n}: at most {MAX_THREADS} worker threads (this machine has {all})");
    }
    Ok(threads)
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    if let Some(peers) = &args.peers {
        return run_peers(args, peers);
    }
    let accel = args.accel.as_deref().unwrap_or("bvh,bvh4,grid,kdtree");
    let accels: Vec<AccelKind> = if accel == "all" {
        AccelKind::ALL
            .into_iter()
            .filter(|k| !matches!(k, AccelKind::Brute | AccelKind::Aabb))
            .collect()
    } else {
        parse_list(accel)?
    };
    let workloads: Vec<Workload> = parse_list(&args.workloads)?;
    let config = BuildConfig {
        spatial_splits: args.spatial_splits.unwrap_or(0.0),
        optimize: args.optimize,
        ..BuildConfig::default()
    };
    let frame = args.frame.as_deref().map(parse_frame).transpose()?;
    let threads = thread_counts(args.threads.as_deref())?;
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

/// `--peers`: hands the run to `raymesh-peers` with this command's
/// settings, and fails as it fails. The peers are a separate binary so
/// that raymesh itself never links Embree or the other crates (STYLE.md).
fn run_peers(args: &Args, peers: &str) -> Result<()> {
    // What `raymesh-peers` has no form of is refused rather than dropped.
    for (given, flag) in [
        (args.frame.is_some(), "--frame"),
        (args.spatial_splits.is_some(), "--spatial-splits"),
        (args.optimize, "--optimize"),
    ] {
        if given {
            bail!(
                "{flag} does not go with --peers: raymesh-peers has no such setting \
                 (its --quality high builds raymesh and Embree with spatial splits: \
                 give it after `--`)"
            );
        }
    }
    let exe = peers_executable()?;
    let threads = thread_counts(args.threads.as_deref())?
        .iter()
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let mut cmd = std::process::Command::new(&exe);
    cmd.args(&args.meshes)
        .args(["--peers", peers])
        .args(["--accel", args.accel.as_deref().unwrap_or("bvh")])
        .args(["--workloads", &args.workloads])
        .args(["--size", &args.size.to_string()])
        .args(["--threads", &threads])
        .args(["--repeat", &args.repeat.to_string()]);
    for (given, flag) in [
        (args.packets, "--packets"),
        (args.stream, "--stream"),
        (args.json, "--json"),
    ] {
        if given {
            cmd.arg(flag);
        }
    }
    cmd.args(&args.peer_args);
    let status = cmd
        .status()
        .with_context(|| format!("could not run {}", exe.display()))?;
    if !status.success() {
        bail!("{} failed ({status})", exe.display());
    }
    Ok(())
}

/// The `raymesh-peers` executable: `RAYMESH_PEERS` when set, else the one
/// beside this executable (where cargo builds both), with how to build it
/// when there is none.
fn peers_executable() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("RAYMESH_PEERS") {
        let p = PathBuf::from(p);
        if !p.is_file() {
            bail!("RAYMESH_PEERS names {}, which is not a file", p.display());
        }
        return Ok(p);
    }
    let name = format!("raymesh-peers{}", std::env::consts::EXE_SUFFIX);
    let exe = std::env::current_exe().context("could not find the raymesh executable")?;
    let beside = exe.with_file_name(&name);
    if beside.is_file() {
        return Ok(beside);
    }
    bail!(
        "--peers runs {name}, which is not beside {} (nor named by RAYMESH_PEERS); build it \
         first, with Embree (Debian's libembree-dev) or without: \
         `cargo build --release -p raymesh-bench --features embree --bin raymesh-peers`",
        exe.display()
    )
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
