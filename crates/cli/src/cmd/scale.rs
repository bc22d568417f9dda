//! `raymesh scale [--sizes LIST] [--accel LIST] [--threads LIST] [--size N]
//! [--repeat R] [--chart FILE.svg] [--json]`: how build and trace scale
//! with the triangle count, on synthetic terrains of the given sizes
//! (millions of triangles), with a log-log chart.

use crate::cmd::raycast::{count, trace};
use crate::cmd::thread_pool;
use crate::npy::HitRecord;
use crate::workload::{make_rays, Workload};
use anyhow::{bail, Context, Result};
use raymesh_accel::{AccelKind, Primitives, Scene, TriangleMesh};
use raymesh_mesh::synthetic;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `raymesh scale`.
#[derive(clap::Args)]
pub struct Args {
    /// Terrain sizes in millions of triangles, comma-separated (e.g. 0.1,1,10,100).
    #[arg(long, allow_negative_numbers = true, default_value = "0.01,0.1,1")]
    pub sizes: String,
    /// Structures, comma-separated.
    #[arg(long, default_value = "bvh8")]
    pub accel: String,
    /// Thread counts, comma-separated, each 1 to 1024 (default: 1 and all cores).
    #[arg(long, allow_negative_numbers = true)]
    pub threads: Option<String>,
    /// Width and height of the primary-ray image traced at every size.
    #[arg(long, allow_negative_numbers = true, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub size: u32,
    /// Timed repeats of each build and each trace; the best is reported.
    #[arg(long, allow_negative_numbers = true, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// Write a log-log chart (SVG) of build speed, trace speed and cost per
    /// ray against the triangle count. Overwritten if it exists.
    #[arg(long)]
    pub chart: Option<PathBuf>,
    /// Print JSON lines instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One measured row: a size, a structure and a thread count.
#[derive(Clone, Debug, Serialize)]
struct Row {
    triangles: usize,
    accel: &'static str,
    threads: usize,
    build_ms: f64,
    build_mtris_per_s: f64,
    /// Build time on 1 thread over build time on `threads` (when 1 was measured).
    build_speedup: Option<f64>,
    rays: usize,
    mrays_per_s: f64,
    nodes_per_ray: f64,
    triangles_per_ray: f64,
    /// The structure plus the corner copy it traces, per triangle.
    bytes_per_triangle: f64,
    /// The process's peak resident memory during the row (Linux), MiB:
    /// the mesh, the build and the trace. Where the kernel refuses to
    /// reset the peak, it is the peak since the process started.
    peak_rss_mib: Option<f64>,
}

/// Resets the process's peak resident set to its current size (Linux 4.0+:
/// writing 5 to `/proc/self/clear_refs`), so that [`peak_rss_mib`]
/// measures from here. Elsewhere, or if refused, it does nothing.
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// The process's peak resident set (`VmHWM`), in MiB; `None` off Linux.
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

fn parse_list<T: std::str::FromStr>(s: &str, what: &str) -> Result<Vec<T>> {
    s.split(',')
        .map(|x| {
            x.trim()
                .parse::<T>()
                .map_err(|_| anyhow::anyhow!("{what}: cannot read {x:?} in {s:?}"))
        })
        .collect()
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    let sizes: Vec<f64> = parse_list(&args.sizes, "--sizes")?;
    let max = (u32::MAX / 4) as f64 / 1e6;
    if let Some(bad) = sizes.iter().find(|&&s| !(s > 0.0 && s <= max)) {
        bail!("--sizes: {bad} is not within (0, {max:.0}] million triangles");
    }
    let accels: Vec<AccelKind> = args
        .accel
        .split(',')
        .map(|x| x.trim().parse::<AccelKind>().map_err(anyhow::Error::msg))
        .collect::<Result<_>>()?;
    let all = thread_pool(None)?.current_num_threads();
    let threads: Vec<usize> = match &args.threads {
        Some(t) => parse_list(t, "--threads")?,
        None if all > 1 => vec![1, all],
        None => vec![1],
    };
    if threads.contains(&0) {
        bail!("--threads: thread counts must be at least 1");
    }
    if let Some(chart) = &args.chart {
        if chart.extension().and_then(|e| e.to_str()) != Some("svg") {
            bail!("{}: the chart is an SVG file (.svg)", chart.display());
        }
        crate::cmd::check_output(chart, &[])?;
    }
    let pools: Vec<rayon::ThreadPool> = threads
        .iter()
        .map(|&t| thread_pool(Some(t)))
        .collect::<Result<_>>()?;
    if !args.json {
        println!(
            "{:>11} {:<10} {:>3} {:>10} {:>8} {:>7} {:>8} {:>7} {:>7} {:>6} {:>8}",
            "triangles",
            "structure",
            "thr",
            "build ms",
            "Mtris/s",
            "speedup",
            "Mrays/s",
            "nodes/r",
            "tris/r",
            "B/tri",
            "peak MiB"
        );
    }
    let mut rows = Vec::new();
    for &millions in &sizes {
        let n = (millions * 1e6).round().max(1.0) as usize;
        let step = crate::cmd::stage(format!("making a terrain of {n} triangles"));
        // Made afresh for every build (untimed), so that no spare copy
        // sits in memory beside the one a build consumes.
        let make = || {
            let terrain = synthetic::terrain(n);
            TriangleMesh::new(terrain.positions, terrain.triangles)
        };
        // The first mesh serves the first build; later ones are made anew.
        let mut spare = Some(make());
        let ntri = spare.as_ref().map_or(0, TriangleMesh::len);
        step.finish_and_clear();
        let mut rays: Vec<[f32; 8]> = Vec::new();
        for &accel in &accels {
            let mut one_thread_ms = None;
            for (pool, &t) in pools.iter().zip(&threads) {
                let step = crate::cmd::stage(format!(
                    "{ntri} triangles: building and tracing {} on {t} threads",
                    accel.name()
                ));
                let mut best = f64::INFINITY;
                let mut scene = None;
                reset_peak_rss();
                for _ in 0..args.repeat {
                    // The last build goes before the next: one at a time in memory.
                    drop(scene.take());
                    let mesh = spare.take().unwrap_or_else(make);
                    let start = Instant::now();
                    let s = pool.install(|| Scene::from_mesh(&mesh, accel));
                    best = best.min(start.elapsed().as_secs_f64() * 1e3);
                    // The scene holds its own corner copy: the mesh goes.
                    drop(mesh);
                    scene = Some(s);
                }
                let scene = scene.expect("at least one repeat");
                if t == 1 {
                    one_thread_ms = Some(best);
                }
                if rays.is_empty() {
                    rays = make_rays(Workload::Primary, &scene, args.size, 1);
                }
                let mut hits = vec![HitRecord::MISS; rays.len()];
                let mut trace_ms = f64::INFINITY;
                for _ in 0..args.repeat {
                    let start = Instant::now();
                    pool.install(|| trace(&scene, &rays, false, &mut hits));
                    trace_ms = trace_ms.min(start.elapsed().as_secs_f64() * 1e3);
                }
                let (nodes_per_ray, triangles_per_ray) =
                    pool.install(|| count(&scene, &rays, false));
                let row = Row {
                    triangles: ntri,
                    accel: accel.name(),
                    threads: t,
                    build_ms: best,
                    build_mtris_per_s: ntri as f64 / best / 1e3,
                    build_speedup: one_thread_ms.filter(|_| t != 1).map(|one| one / best),
                    rays: rays.len(),
                    mrays_per_s: rays.len() as f64 / trace_ms.max(1e-9) / 1e3,
                    nodes_per_ray,
                    triangles_per_ray,
                    bytes_per_triangle: (scene.stats().bytes + scene.prims().bytes()) as f64
                        / ntri.max(1) as f64,
                    peak_rss_mib: peak_rss_mib(),
                };
                drop(scene);
                step.finish_and_clear();
                print_row(&row, args.json)?;
                rows.push(row);
            }
        }
    }
    if let Some(path) = &args.chart {
        chart(path, &rows)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn print_row(r: &Row, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(r)?);
    } else {
        println!(
            "{:>11} {:<10} {:>3} {:>10.1} {:>8.2} {:>7} {:>8} {:>7.1} {:>7.1} {:>6.1} {:>8}",
            r.triangles,
            r.accel,
            r.threads,
            r.build_ms,
            r.build_mtris_per_s,
            r.build_speedup
                .map_or_else(|| "-".to_string(), |s| format!("{s:.2}×")),
            crate::cmd::rate(r.mrays_per_s),
            r.nodes_per_ray,
            r.triangles_per_ray,
            r.bytes_per_triangle,
            r.peak_rss_mib
                .map_or_else(|| "-".to_string(), |m| format!("{m:.0}")),
        );
    }
    Ok(())
}

/// Three log-log panels against the triangle count: build Mtris/s and
/// trace Mrays/s per structure and thread count, and cost per ray (nodes
/// visited plus triangles tested) per structure.
fn chart(path: &Path, rows: &[Row]) -> Result<()> {
    use plotters::prelude::*;
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = SVGBackend::new(path, (1500, 480)).into_drawing_area();
        root.fill(&WHITE)?;
        let panels = root.split_evenly((1, 3));
        type Metric = fn(&Row) -> f64;
        let metrics: [(&str, Metric, bool, SeriesLabelPosition); 3] = [
            (
                "build, Mtris/s (log-log)",
                |r| r.build_mtris_per_s,
                true,
                SeriesLabelPosition::LowerRight,
            ),
            (
                "primary rays, Mrays/s (log-log)",
                |r| r.mrays_per_s,
                true,
                SeriesLabelPosition::LowerLeft,
            ),
            (
                "cost per ray: nodes + triangles (log-log)",
                |r| r.nodes_per_ray + r.triangles_per_ray,
                false,
                SeriesLabelPosition::UpperLeft,
            ),
        ];
        let xs = rows.iter().map(|r| r.triangles as f64);
        let (xmin, xmax) = xs.fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
        let xr = (xmin / 1.5).max(1.0)..(xmax * 1.5).max(2.0);
        for (panel, (title, metric, per_thread, legend)) in panels.iter().zip(metrics) {
            let ys = rows.iter().map(metric).filter(|y| *y > 0.0);
            let (ymin, ymax) = ys.fold((f64::INFINITY, 0.0f64), |(a, b), y| (a.min(y), b.max(y)));
            if !(ymax > 0.0) {
                continue;
            }
            let mut chart = ChartBuilder::on(panel)
                .caption(title, ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(xr.clone().log_scale(), (ymin / 1.5..ymax * 1.5).log_scale())?;
            chart
                .configure_mesh()
                .x_desc("triangles")
                .x_label_formatter(&|x| format!("{x:.0e}"))
                .y_label_formatter(&|y| {
                    if *y >= 10.0 {
                        format!("{y:.0}")
                    } else if *y >= 1.0 {
                        format!("{y:.1}")
                    } else {
                        format!("{y:.2}")
                    }
                })
                .draw()?;
            // One series per structure (and thread count, for speeds).
            let mut keys: Vec<(&str, usize)> = Vec::new();
            for r in rows {
                let k = (r.accel, if per_thread { r.threads } else { 0 });
                if !keys.contains(&k) {
                    keys.push(k);
                }
            }
            for (i, &(accel, threads)) in keys.iter().enumerate() {
                let color = Palette99::pick(i).to_rgba();
                let points: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| r.accel == accel && (!per_thread || r.threads == threads))
                    .map(|r| (r.triangles as f64, metric(r)))
                    .filter(|p| p.1 > 0.0)
                    .collect();
                let label = if per_thread {
                    format!("{accel}, {threads} thr")
                } else {
                    accel.to_string()
                };
                chart
                    .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))?
                    .label(label)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
                chart.draw_series(
                    points
                        .into_iter()
                        .map(|p| Circle::new(p, 3, color.filled())),
                )?;
            }
            if !per_thread {
                // What growth with log N looks like: c · log2 N through the
                // first structure's smallest size.
                if let Some(first) = rows.iter().find(|r| r.accel == keys[0].0) {
                    let c = metric(first) / (first.triangles as f64).log2();
                    let xs = [xr.start, xmin, xmax, xr.end];
                    chart
                        .draw_series(LineSeries::new(
                            xs.map(|x| (x, c * x.log2())),
                            BLACK.mix(0.4).stroke_width(1),
                        ))?
                        .label("∝ log N (through the first point)")
                        .legend(|(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.4))
                        });
                }
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .position(legend)
                .draw()?;
        }
        root.present()?;
        Ok(())
    };
    draw()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("{}: cannot write the chart", path.display()))
}
