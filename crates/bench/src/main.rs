//! `raymesh-peers MESH... [--rays RAYS.npy | --workloads LIST --size N]
//! [--threads LIST] [--repeat R] [--build-repeat B] [--interleave] [--accel LIST|all] [--peers LIST]
//! [--markdown] [--json] [--chart OUT.png]`: the same rays through raymesh
//! and its peers, in one run: Intel Embree 3 (built with `--features
//! embree`) and the Rust crates obvhs, bvh and parry3d. For each engine and
//! thread count it reports the build time and bytes per triangle; for each
//! workload, query and thread count, Mrays/s, raymesh's ratio to each
//! peer, and how far each engine's hits agree with Embree's (same
//! triangle, or `t` within 1e-4 relative, as `../shared/BENCH.md` asks;
//! with raymesh's when Embree is not built in). Several raymesh
//! structures (`--accel bvh8,grid,kdtree`) run side by side in the same
//! run, each as an engine of its own.

use anyhow::{bail, ensure, Context, Result};
use clap::Parser;
use raymesh::npy;
use raymesh::workload::{make_rays, Workload};
use raymesh_accel::{AccelKind, BuildConfig, Scene, TriangleMesh};
use raymesh_bench::engines::{
    structure_engine, structure_of, Answer, Engine, Runner, OPT_IN_PEERS, RUST_PEERS,
};
use raymesh_bench::{chart, thread_list, Trace};
use raymesh_mesh::io::read_mesh;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Side-by-side ray-query benchmark against Embree and the Rust BVH crates.
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
    #[arg(long, allow_negative_numbers = true, default_value_t = 1024)]
    size: u32,
    /// Thread counts, comma-separated.
    #[arg(long, allow_negative_numbers = true, default_value = "1")]
    threads: String,
    /// Timed repeats; the best is reported.
    #[arg(long, allow_negative_numbers = true, default_value_t = 3)]
    repeat: u32,
    /// Timed builds of each engine (the best is reported). By default at
    /// least R (`--repeat`), and more until the engine's builds have
    /// taken 0.25 s in all (at most 50): a build of a few milliseconds
    /// varies by a quarter from one to the next on a shared machine, and
    /// three of them do not settle the ratio.
    #[arg(long, allow_negative_numbers = true)]
    build_repeat: Option<u32>,
    /// raymesh structures, comma-separated, or `all` (every one but
    /// `brute` and `aabb`, as for `raymesh bench --accel all`, with `bvh`
    /// first).
    /// The first runs as the engine `raymesh`, whose ratio to every other
    /// engine the tables give; each other runs beside it as
    /// `raymesh-NAME` (`raymesh-grid`, `raymesh-kdtree`, ...), built and
    /// traced like any peer, so that every structure meets Embree and the
    /// others in one run.
    #[arg(long, default_value = "bvh", value_parser = parse_accels)]
    accel: Accels,
    /// Peers to run, comma-separated (embree, obvhs, bvh, parry3d), `all`
    /// (every one built in) or `none`. `raymesh-ray`, run only when named,
    /// is raymesh with each ray made by the caller (`Ray::new`, then
    /// `Scene::intersect_bare(&Ray)`), beside raymesh's row queries.
    #[arg(long, default_value = "all")]
    peers: String,
    /// Print markdown tables as well.
    #[arg(long)]
    markdown: bool,
    /// Print JSON lines instead of the text report.
    #[arg(long)]
    json: bool,
    /// Draw Mrays/s per engine as a bar chart (PNG, or SVG by extension).
    #[arg(long)]
    chart: Option<PathBuf>,
    /// Eight consecutive rays at a time where the engine has packets
    /// (raymesh `Scene::intersect8_soa_bare` and `Scene::occluded8_soa`,
    /// the rays given as rows, `Rays8`; Embree `rtcIntersect8` and
    /// `rtcOccluded8`, as its `RTCRay8`); the Rust peers stay one ray at a
    /// time.
    #[arg(long)]
    packets: bool,
    /// Traces each task's 1,024 rays as one stream where the engine has a
    /// stream call (raymesh `Scene::intersect_stream`/`occluded_stream`,
    /// which interleave rays over the binary and wide BVHs and walk runs
    /// of eight coherent rays over the wide ones as packets, and whose
    /// occlusion streams over `bvh8` walk all their rays, and closest
    /// hits all the rays of a stream with no such run, in groups of 32
    /// where the groups share nodes; Embree
    /// `rtcIntersect1M`/`rtcOccluded1M` with the incoherent hint), closest
    /// and any hits; the Rust peers stay one ray at a time.
    #[arg(long, conflicts_with = "packets")]
    stream: bool,
    /// Build quality. `medium`: Embree's default builder and raymesh's
    /// binned SAH. `high`: Embree's spatial-split builder
    /// (`RTC_BUILD_QUALITY_HIGH`) against raymesh with spatial splits
    /// (`BuildConfig::spatial_splits` 0.25, as `raycast --spatial-splits`);
    /// the Rust peers have no such builder and build as they always do.
    #[arg(long, value_enum, default_value_t = Quality::Medium)]
    quality: Quality,
    /// Builds Embree's scene with `RTC_SCENE_FLAG_ROBUST`: its robust
    /// traversal and watertight triangle test, the guarantees raymesh
    /// always gives, instead of its default fast arithmetic.
    #[arg(long)]
    embree_robust: bool,
    /// Builds every engine first and keeps them all, then takes turns:
    /// each of the R repeats of a build, and of each workload and query,
    /// runs every engine once before the next repeat (the best of each
    /// engine's R is reported). Without it each engine builds and traces
    /// everything in turn, and a machine whose speed drifts over the run
    /// skews the ratios; with it the engines' structures are all in
    /// memory at once.
    #[arg(long)]
    interleave: bool,
    /// Queries to trace, comma-separated: `closest`, `any-hit` (both by
    /// default). One alone halves a run, and leaves a profiler or a
    /// counter run over the whole process with one query's passes.
    #[arg(long, default_value = "closest,any-hit", value_parser = parse_queries)]
    queries: Queries,
}

/// `--queries`' list, as the `any` flags the engines trace with
/// (`false`: closest hits), in the order given, each once.
#[derive(Clone, Debug)]
struct Queries(Vec<bool>);

/// Reads `--queries`: `closest` and `any-hit`, comma-separated, at
/// least one, none twice.
fn parse_queries(text: &str) -> Result<Queries> {
    let mut any = Vec::new();
    for q in text.split(',').map(str::trim) {
        let a = match q {
            "closest" => false,
            "any-hit" => true,
            _ => bail!("unknown query '{q}': expected closest or any-hit"),
        };
        ensure!(!any.contains(&a), "query '{q}' given twice");
        any.push(a);
    }
    Ok(Queries(any))
}

/// `--accel`'s structures, the one `raymesh` runs first; at least one,
/// none twice.
#[derive(Clone, Debug)]
struct Accels(Vec<AccelKind>);

/// Reads `--accel`: structure names (`raymesh raycast --accel`'s),
/// comma-separated, or `all`.
fn parse_accels(text: &str) -> Result<Accels> {
    if text.trim() == "all" {
        let rest = AccelKind::ALL.into_iter().filter(|k| {
            !matches!(k, AccelKind::Brute | AccelKind::Aabb) && *k != AccelKind::FASTEST_BVH
        });
        return Ok(Accels(
            std::iter::once(AccelKind::FASTEST_BVH)
                .chain(rest)
                .collect(),
        ));
    }
    let mut kinds = Vec::new();
    for name in text.split(',').map(str::trim) {
        let k: AccelKind = name.parse().map_err(anyhow::Error::msg)?;
        ensure!(
            !kinds.contains(&k),
            "structure '{name}' given twice (as {})",
            k.name()
        );
        kinds.push(k);
    }
    Ok(Accels(kinds))
}

/// Milliseconds of an engine's builds after which `--build-repeat`'s
/// default stops adding builds, once it has R.
const BUILD_MS: f64 = 250.0;

/// Most builds of an engine that `--build-repeat`'s default times.
const MAX_BUILDS: u32 = 50;

/// An engine's timed builds so far: the best, their total, their count.
#[derive(Clone, Copy, Debug)]
struct BuildTimes {
    best_ms: f64,
    spent_ms: f64,
    done: u32,
}

impl BuildTimes {
    const NONE: Self = Self {
        best_ms: f64::INFINITY,
        spent_ms: 0.0,
        done: 0,
    };

    /// Counts one more build, of `ms` milliseconds.
    fn add(&mut self, ms: f64) {
        self.best_ms = self.best_ms.min(ms);
        self.spent_ms += ms;
        self.done += 1;
    }
}

impl Args {
    /// Whether an engine whose builds so far are `t` is built again:
    /// `--build-repeat` times if given, else at least `--repeat` times
    /// and until [`BUILD_MS`], up to [`MAX_BUILDS`].
    fn more_builds(&self, t: &BuildTimes) -> bool {
        match self.build_repeat {
            Some(n) => t.done < n.max(1),
            None => t.done < self.repeat.max(1) || (t.spent_ms < BUILD_MS && t.done < MAX_BUILDS),
        }
    }
}

/// `--quality`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// Embree's default; raymesh's binned SAH.
    Medium,
    /// Spatial splits in both.
    High,
}

/// One engine's build on one mesh.
#[derive(Serialize)]
struct Build {
    kind: &'static str,
    mesh: String,
    engine: &'static str,
    /// The raymesh structure, for raymesh's engines.
    #[serde(skip_serializing_if = "Option::is_none")]
    accel: Option<&'static str>,
    threads: usize,
    quality: Quality,
    build_ms: f64,
    bytes_per_triangle: Option<f64>,
    /// SAH cost of the engine's tree, in raymesh's units, where known.
    #[serde(skip_serializing_if = "Option::is_none")]
    sah_cost: Option<f64>,
    /// Node tests a random ray is expected to make (see `TreeCost`).
    #[serde(skip_serializing_if = "Option::is_none")]
    node_tests: Option<f64>,
    /// Leaf tests, in the engine's blocks, a random ray is expected to make.
    #[serde(skip_serializing_if = "Option::is_none")]
    leaf_tests: Option<f64>,
}

impl Build {
    /// `engine`'s build on `mesh` (of `ntris` triangles) at `threads`
    /// threads, best of its builds `build_ms`, with the figures the
    /// engine tells of its structure (bytes, and its tree's costs).
    fn of(
        engine: &dyn Engine,
        mesh: String,
        threads: usize,
        quality: Quality,
        build_ms: f64,
        ntris: usize,
    ) -> Self {
        let cost = engine.tree_cost();
        Self {
            kind: "build",
            mesh,
            engine: engine.name(),
            accel: engine.accel().map(AccelKind::name),
            threads,
            quality,
            build_ms,
            bytes_per_triangle: engine.bytes().map(|b| b as f64 / ntris.max(1) as f64),
            sah_cost: cost.map(|c| c.sah),
            node_tests: cost.map(|c| c.node_tests),
            leaf_tests: cost.map(|c| c.leaf_tests),
        }
    }
}

/// Table cells: `cell` of each item, joined by ` | `.
fn cells<T>(items: &[T], cell: impl Fn(&T) -> String) -> String {
    items.iter().map(cell).collect::<Vec<_>>().join(" | ")
}

/// The engines to run, reference first: Embree when built in and asked
/// for, else raymesh; then raymesh (over `accels[0]`) and its other
/// structures' engines, then the other peers.
fn engine_names(peers: &str, accels: &[AccelKind]) -> Result<Vec<&'static str>> {
    let built: Vec<&'static str> = cfg!(feature = "embree")
        .then_some("embree")
        .into_iter()
        .chain(RUST_PEERS)
        .collect();
    let mut chosen: Vec<&'static str> = match peers.trim() {
        "all" => built.clone(),
        "none" => Vec::new(),
        list => list
            .split(',')
            .map(|p| {
                let p = p.trim();
                if p == "embree" && !cfg!(feature = "embree") {
                    bail!("embree is not built in: build with --features embree (README)");
                }
                built
                    .iter()
                    .chain(&OPT_IN_PEERS)
                    .find(|b| **b == p)
                    .copied()
                    .with_context(|| {
                        format!(
                            "unknown peer '{p}'; expected {} or {}",
                            built.join(", "),
                            OPT_IN_PEERS.join(", ")
                        )
                    })
            })
            .collect::<Result<_>>()?,
    };
    chosen.dedup();
    let at = usize::from(chosen.first() == Some(&"embree"));
    let ours =
        std::iter::once("raymesh").chain(accels.iter().skip(1).map(|&k| structure_engine(k)));
    chosen.splice(at..at, ours);
    Ok(chosen)
}

fn build_engine(
    name: &str,
    args: &Args,
    positions: &[raymesh_geometry::Vec3],
    triangles: &[[u32; 3]],
    threads: usize,
) -> Box<dyn Engine> {
    let quality = args.quality;
    // `raymesh` and `raymesh-ray` trace the first structure.
    let accel = args.accel.0[0];
    #[cfg(feature = "embree")]
    if name == "embree" {
        let high = quality == Quality::High;
        return Box::new(raymesh_bench::embree_peer::EmbreeScene::new(
            positions,
            triangles,
            threads,
            high,
            args.embree_robust,
        ));
    }
    let _ = threads;
    // Spatial splits for the structures that take them (the others build
    // as at medium quality).
    let kind = structure_of(name).unwrap_or(accel);
    let high = quality == Quality::High && kind.takes_spatial_splits();
    let config = BuildConfig {
        spatial_splits: if high { 0.25 } else { 0.0 },
        ..BuildConfig::default()
    };
    raymesh_bench::engines::build(name, accel, &config, positions, triangles)
}

/// `--interleave`'s pass over one mesh at one thread count: every engine
/// built (best of the builds `Args::more_builds` asks for, taking turns), then each workload and query
/// traced by every engine in turn, R rounds (best of each engine's R).
/// Returns the builds and traces in the order the one-engine-at-a-time
/// pass makes them (engine by engine; meshes named by the caller), and
/// each engine's Mrays/s in that order.
#[allow(clippy::type_complexity)]
fn interleaved(
    args: &Args,
    names: &[&'static str],
    mesh: &raymesh_mesh::IndexedMesh,
    tris: &[[u32; 3]],
    workloads: &[(String, Vec<[f32; 8]>)],
    run: &Runner<'_>,
    t: usize,
) -> (Vec<Build>, Vec<Trace>, Vec<(&'static str, Vec<f64>)>) {
    let build = |name: &str| {
        run.pool
            .install(|| build_engine(name, args, &mesh.positions, tris, t))
    };
    let mut built: Vec<Option<Box<dyn Engine>>> = names.iter().map(|_| None).collect();
    let mut times = vec![BuildTimes::NONE; names.len()];
    // Rounds until every engine has had its builds (`Args::more_builds`).
    while times.iter().any(|t| args.more_builds(t)) {
        for (i, &name) in names.iter().enumerate() {
            // One structure per engine in memory: the last round's is kept.
            built[i] = None;
            let e = build(name);
            times[i].add(e.build_ms());
            built[i] = Some(e);
        }
    }
    let engines: Vec<Box<dyn Engine>> = built.into_iter().flatten().collect();
    let builds = names
        .iter()
        .zip(&engines)
        .zip(&times)
        .map(|((_, e), b)| {
            Build::of(
                e.as_ref(),
                String::new(),
                t,
                args.quality,
                b.best_ms,
                tris.len(),
            )
        })
        .collect();
    let once = Runner { repeat: 1, ..*run };
    // Per engine, per (workload, query): Mrays/s and agreement.
    let mut cases: Vec<Vec<(f64, f64)>> = vec![Vec::new(); names.len()];
    for (_, rays) in workloads {
        for &any in &args.queries.0 {
            let mut best = vec![f64::INFINITY; names.len()];
            let mut answers: Vec<Vec<Answer>> = vec![Vec::new(); names.len()];
            for _ in 0..args.repeat.max(1) {
                for (i, e) in engines.iter().enumerate() {
                    let (secs, a) = e.trace(rays, any, &once);
                    best[i] = best[i].min(secs);
                    answers[i] = a;
                }
            }
            for i in 0..names.len() {
                let agree = agreement(&answers[i], &answers[0]);
                cases[i].push((rays.len() as f64 / best[i] / 1e6, agree));
            }
        }
    }
    let mut traces = Vec::new();
    let mut rates = Vec::new();
    for (i, &name) in names.iter().enumerate() {
        let mut k = 0;
        for (workload, _) in workloads {
            for &any in &args.queries.0 {
                let (mrays, agree) = cases[i][k];
                traces.push(Trace::new(
                    "",
                    workload,
                    t,
                    any,
                    name,
                    engines[i].accel(),
                    mrays,
                    agree,
                    names[0],
                ));
                k += 1;
            }
        }
        rates.push((name, cases[i].iter().map(|c| c.0).collect()));
    }
    (builds, traces, rates)
}

/// The fraction of rays whose answers in `a` and `b` agree ([`agrees`]).
fn agreement(a: &[Answer], b: &[Answer]) -> f64 {
    let same = a.iter().zip(b).filter(|(a, b)| agrees(a, b)).count();
    same as f64 / a.len().max(1) as f64
}

/// Whether two answers agree: both miss, or hit the same triangle, or at
/// `t` within 1e-4 relative.
fn agrees(a: &Answer, b: &Answer) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some((ta, pa)), Some((tb, pb))) => {
            pa == pb || (ta - tb).abs() <= 1e-4 * ta.abs().max(tb.abs())
        }
        _ => false,
    }
}

fn short(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}

fn main() -> Result<()> {
    let args = Args::parse();
    let threads = thread_list::parse(&args.threads)?;
    if let Some(chart) = &args.chart {
        chart::check_path(chart)?;
    }
    let names = engine_names(&args.peers, &args.accel.0)?;
    let reference = names[0];
    // A rays file, read once for every mesh.
    let file_rays = args
        .rays
        .as_ref()
        .map(|file| -> Result<(String, Vec<[f32; 8]>)> {
            let (rows, replaced) = traceable(npy::read_ray_rows(file)?);
            if let Some((first, row)) = replaced.first() {
                eprintln!(
                    "raymesh-peers: {}: {} of {} rows are not rays every engine can trace \
                     (row {first}: {:?}); each goes to every engine as an empty ray, \
                     which hits nothing",
                    file.display(),
                    replaced.len(),
                    rows.len(),
                    row,
                );
            }
            Ok((short(file), rows))
        })
        .transpose()?;
    let mut builds = Vec::new();
    let mut traces = Vec::new();
    for path in &args.meshes {
        let mesh = read_mesh(path)?;
        let tris = mesh.triangles();
        let mesh_name = short(path);
        let workloads: Vec<(String, Vec<[f32; 8]>)> = match &file_rays {
            Some(rays) => vec![rays.clone()],
            None => {
                let tm = TriangleMesh::new(mesh.positions.clone(), tris.clone());
                let scene = Scene::build(tm, AccelKind::FASTEST_BVH);
                args.workloads
                    .split(',')
                    .map(|w| {
                        let w: Workload = w.trim().parse().map_err(anyhow::Error::msg)?;
                        Ok((w.name().to_string(), make_rays(w, &scene, args.size, 1)))
                    })
                    .collect::<Result<_>>()?
            }
        };
        if !args.json {
            if args.embree_robust && names.contains(&"embree") {
                println!("Embree in robust mode (RTC_SCENE_FLAG_ROBUST)");
            }
            println!(
                "{}: {} triangles; {}",
                path.display(),
                tris.len(),
                workloads
                    .iter()
                    .map(|(w, r)| format!("{w} {} rays", r.len()))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        for &t in &threads {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .context("thread pool")?;
            let run = Runner {
                pool: &pool,
                repeat: args.repeat,
                packets: args.packets,
                stream: args.stream,
            };
            // The reference's answers per (workload, query), then each
            // engine in turn: built, traced, compared, dropped.
            let mut reference_answers: Vec<Vec<Answer>> = Vec::new();
            let mut rates: Vec<(&'static str, Vec<f64>)> = Vec::new();
            if args.interleave {
                let (b, tr, r) = interleaved(&args, &names, &mesh, &tris, &workloads, &run, t);
                for mut b in b {
                    b.mesh.clone_from(&mesh_name);
                    builds.push(b);
                }
                for mut tr in tr {
                    tr.mesh.clone_from(&mesh_name);
                    traces.push(tr);
                }
                rates = r;
            }
            for &name in names.iter().filter(|_| !args.interleave) {
                // Best of several builds (the first of a process pays for its
                // allocator and thread start-up); the last one is traced.
                let build = || build_engine(name, &args, &mesh.positions, &tris, t);
                let mut engine = pool.install(build);
                let mut times = BuildTimes::NONE;
                times.add(engine.build_ms());
                while args.more_builds(&times) {
                    drop(engine);
                    engine = pool.install(build);
                    times.add(engine.build_ms());
                }
                builds.push(Build::of(
                    engine.as_ref(),
                    mesh_name.clone(),
                    t,
                    args.quality,
                    times.best_ms,
                    tris.len(),
                ));
                let mut mine = Vec::new();
                let mut k = 0;
                for (workload, rays) in &workloads {
                    for &any in &args.queries.0 {
                        let (secs, answers) = engine.trace(rays, any, &run);
                        let agree = if name == reference {
                            reference_answers.push(answers);
                            1.0
                        } else {
                            agreement(&answers, &reference_answers[k])
                        };
                        let mrays = rays.len() as f64 / secs / 1e6;
                        mine.push(mrays);
                        traces.push(Trace::new(
                            &mesh_name,
                            workload,
                            t,
                            any,
                            name,
                            engine.accel(),
                            mrays,
                            agree,
                            reference,
                        ));
                        k += 1;
                    }
                }
                rates.push((name, mine));
            }
            // raymesh's ratio to each engine, now that all have run.
            let raymesh = rates
                .iter()
                .find(|(n, _)| *n == "raymesh")
                .map(|(_, r)| r.clone())
                .expect("raymesh always runs");
            let per_engine = workloads.len() * args.queries.0.len();
            let first = traces.len() - per_engine * names.len();
            for (i, tr) in traces[first..].iter_mut().enumerate() {
                tr.raymesh_ratio = raymesh[i % per_engine] / tr.mrays_per_s;
            }
            if !args.json {
                report(
                    &builds[builds.len() - names.len()..],
                    &traces[first..],
                    reference,
                );
            }
        }
    }
    if args.json {
        for b in &builds {
            println!("{}", serde_json::to_string(b)?);
        }
        for t in &traces {
            println!("{}", serde_json::to_string(t)?);
        }
    }
    if args.markdown {
        markdown(&names, &builds, &traces, &threads);
    }
    if let Some(path) = &args.chart {
        chart::draw(path, &names, &traces)?;
        if !args.json {
            println!("chart: {}", path.display());
        }
    }
    Ok(())
}

/// The text report of one mesh at one thread count.
fn report(builds: &[Build], traces: &[Trace], reference: &str) {
    let t = builds[0].threads;
    let line = cells(builds, |b| {
        let mut c = format!("{} {:.1} ms", b.engine, b.build_ms);
        if let Some(bytes) = b.bytes_per_triangle {
            c += &format!(", {bytes:.1} B/tri");
        }
        if let Some(sah) = b.sah_cost {
            c += &format!(", SAH {sah:.1}");
        }
        if let (Some(n), Some(l)) = (b.node_tests, b.leaf_tests) {
            c += &format!(", {n:.2} node + {l:.2} leaf tests a ray");
        }
        c
    });
    let quality = match builds[0].quality {
        Quality::Medium => String::new(),
        Quality::High => ", quality high".into(),
    };
    println!("  build, {t} thread(s){quality}: {line}");
    for case in traces.iter().filter(|tr| tr.engine == "raymesh") {
        let row: Vec<&Trace> = traces.iter().filter(|tr| tr.same_case(case)).collect();
        let (workload, query) = (&case.workload, case.query);
        let speeds = cells(&row, |tr| {
            format!("{} {}", tr.engine, raymesh::rate(tr.mrays_per_s))
        });
        println!("  {workload:<8} {t} thr {query:<8} Mrays/s: {speeds}");
        let peers: Vec<&Trace> = row
            .iter()
            .copied()
            .filter(|tr| tr.engine != "raymesh")
            .collect();
        if !peers.is_empty() {
            let ratios = cells(&peers, |tr| {
                format!("{} {:.2}", tr.engine, tr.raymesh_ratio)
            });
            println!("  {:<23} raymesh / peer: {ratios}", "");
        }
        let others: Vec<&Trace> = row
            .iter()
            .copied()
            .filter(|tr| tr.engine != reference)
            .collect();
        if !others.is_empty() {
            let agree = cells(&others, |tr| {
                format!("{} {:.3}%", tr.engine, 100.0 * tr.agree)
            });
            println!("  {:<23} hits agree with {reference}: {agree}", "");
        }
    }
}

/// Markdown tables: builds, bytes, Mrays/s with raymesh's ratios, and
/// agreement with the reference engine.
fn markdown(names: &[&str], builds: &[Build], traces: &[Trace], threads: &[usize]) {
    let peers: Vec<&str> = names.iter().copied().filter(|n| *n != "raymesh").collect();
    println!(
        "\n| mesh | threads | {} |",
        cells(names, |n| format!("{n} build ms"))
    );
    println!("| --- | --- |{}", " --- |".repeat(names.len()));
    let mut keys: Vec<(&str, usize)> = builds
        .iter()
        .map(|b| (b.mesh.as_str(), b.threads))
        .collect();
    keys.dedup();
    for (mesh, t) in keys {
        let row = cells(names, |n| {
            builds
                .iter()
                .find(|b| b.mesh == mesh && b.threads == t && b.engine == *n)
                .map_or(String::new(), |b| format!("{:.1}", b.build_ms))
        });
        println!("| {mesh} | {t} | {row} |");
    }
    println!(
        "\n| mesh | engine | bytes/triangle | SAH cost | node tests | leaf tests | node + leaf tests |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    for b in builds.iter().filter(|b| b.threads == threads[0]) {
        let bytes = b
            .bytes_per_triangle
            .map_or("not reported".to_string(), |x| format!("{x:.1}"));
        let f =
            |x: Option<f64>, digits: usize| x.map_or("-".to_string(), |x| format!("{x:.digits$}"));
        let both = b.node_tests.zip(b.leaf_tests).map(|(n, l)| n + l);
        println!(
            "| {} | {} | {bytes} | {} | {} | {} | {} |",
            b.mesh,
            b.engine,
            f(b.sah_cost, 1),
            f(b.node_tests, 2),
            f(b.leaf_tests, 2),
            f(both, 2)
        );
    }
    println!(
        "\n| mesh | workload | threads | query | {} | {} |",
        cells(names, |n| format!("{n} Mrays/s")),
        cells(&peers, |p| format!("raymesh / {p}"))
    );
    println!(
        "| --- | --- | --- | --- |{}",
        " --- |".repeat(names.len() + peers.len())
    );
    // The trace of engine `n` in the same case as `tr`.
    let find = |tr: &Trace, n: &str| traces.iter().find(|r| r.engine == n && r.same_case(tr));
    for tr in traces.iter().filter(|tr| tr.engine == "raymesh") {
        println!(
            "| {} | {} | {} | {} | {} | {} |",
            tr.mesh,
            tr.workload,
            tr.threads,
            tr.query,
            cells(names, |n| find(tr, n)
                .map_or(String::new(), |r| raymesh::rate(r.mrays_per_s))),
            cells(&peers, |n| find(tr, n)
                .map_or(String::new(), |r| format!("{:.2}", r.raymesh_ratio)))
        );
    }
    let reference = names[0];
    // With several raymesh structures beside Embree: each one's ratio to
    // Embree (the table above gives `raymesh`'s to each of them).
    let ours: Vec<&str> = names
        .iter()
        .copied()
        .filter(|n| *n == "raymesh" || structure_of(n).is_some())
        .collect();
    if reference == "embree" && ours.len() > 1 {
        let label = |n: &str| match traces.iter().find(|t| t.engine == n).and_then(|t| t.accel) {
            Some(a) if n == "raymesh" => format!("raymesh ({a}) / embree"),
            _ => format!("{n} / embree"),
        };
        println!(
            "\n| mesh | workload | threads | query | {} |",
            cells(&ours, |n| label(n))
        );
        println!("| --- | --- | --- | --- |{}", " --- |".repeat(ours.len()));
        for tr in traces.iter().filter(|tr| tr.engine == reference) {
            let ratios = cells(&ours, |n| {
                find(tr, n).map_or(String::new(), |r| {
                    format!("{:.2}", r.mrays_per_s / tr.mrays_per_s)
                })
            });
            println!(
                "| {} | {} | {} | {} | {ratios} |",
                tr.mesh, tr.workload, tr.threads, tr.query
            );
        }
    }
    let others: Vec<&str> = names.iter().copied().filter(|n| *n != reference).collect();
    if others.is_empty() {
        return;
    }
    println!(
        "\n| mesh | workload | query | {} |",
        cells(&others, |n| format!("{n}: hits agree with {reference}"))
    );
    println!("| --- | --- | --- |{}", " --- |".repeat(others.len()));
    for tr in traces
        .iter()
        .filter(|tr| tr.engine == reference && tr.threads == threads[0])
    {
        let agree = cells(&others, |n| {
            find(tr, n).map_or(String::new(), |r| format!("{:.3}%", 100.0 * r.agree))
        });
        println!("| {} | {} | {} | {agree} |", tr.mesh, tr.workload, tr.query);
    }
}

/// Embree's bound on a ray's coordinates (its `FLT_LARGE`): Embree's
/// `RayK::valid` asserts, and Debian's build aborts on, a ray whose origin
/// or direction has a component beyond it, or a NaN.
const EMBREE_LARGE: f32 = 1.844e18;

/// The row every engine is given in place of one it cannot trace: an
/// empty interval (`tmin` 1 past `tmax` 0) on a finite ray, which none
/// hits and none refuses.
const EMPTY_ROW: [f32; 8] = [0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0];

/// A ray as BENCH.md lays it out: `[ox, oy, oz, tmin, dx, dy, dz, tmax]`.
type Row = [f32; 8];

/// The rows of a rays file as every engine can trace them: each row
/// that is not a valid ray (`Ray::is_valid`: NaN, an infinite origin or
/// direction, a zero direction, an empty or NaN interval), which raymesh
/// answers with a miss, or whose origin or direction lies beyond
/// [`EMBREE_LARGE`], replaced by [`EMPTY_ROW`]; and the rows replaced,
/// each with its index. (Handed on as they were, such rows stopped the whole
/// run at Embree's assertion.)
fn traceable(mut rows: Vec<Row>) -> (Vec<Row>, Vec<(usize, Row)>) {
    let mut replaced = Vec::new();
    for (i, r) in rows.iter_mut().enumerate() {
        let within = r[..3]
            .iter()
            .chain(&r[4..7])
            .all(|v| v.abs() <= EMBREE_LARGE);
        if !(within && raymesh_geometry::Ray::from_row(r).is_valid()) {
            replaced.push((i, *r));
            *r = EMPTY_ROW;
        }
    }
    (rows, replaced)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chart's name and folder are checked before the run: a chart in
    /// a folder that does not exist was found out after the benchmark.
    #[test]
    fn chart_paths_are_checked_before_the_run() {
        let dir = std::env::temp_dir();
        chart::check_path(&dir.join("c.png")).unwrap();
        chart::check_path(&dir.join("c.svg")).unwrap();
        let e = chart::check_path(&dir.join("c.jpg"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a .png or .svg file"), "{e}");
        let missing = dir.join(format!("raymesh-no-folder-{}", std::process::id()));
        let e = chart::check_path(&missing.join("c.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
    }

    /// Rows that are not rays, or that Embree would refuse, become the
    /// empty row, and are named; valid rows stay as they are, bit for
    /// bit; the empty row is no valid ray to raymesh (which misses it).
    #[test]
    fn untraceable_rows_become_empty_rays() {
        let good = [0.5, -1.0, 2.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY];
        let with = |i: usize, v: f32| {
            let mut r = good;
            r[i] = v;
            r
        };
        let rows = vec![
            good,
            with(0, f32::NAN),
            with(5, f32::INFINITY),
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            [0.5, -1.0, 2.0, 2.0, 0.0, 0.0, -1.0, 1.0],
            with(7, f32::NAN),
            with(1, 1e19),
            with(6, -2e18),
            with(2, 1e18),
            with(3, 0.25),
        ];
        let (out, replaced) = traceable(rows.clone());
        let at: Vec<usize> = replaced.iter().map(|r| r.0).collect();
        assert_eq!(at, [1, 2, 3, 4, 5, 6, 7]);
        for (i, row) in &replaced {
            assert_eq!(row.map(f32::to_bits), rows[*i].map(f32::to_bits));
        }
        for (i, (a, b)) in rows.iter().zip(&out).enumerate() {
            let want = if at.contains(&i) { EMPTY_ROW } else { *a };
            assert_eq!(b.map(f32::to_bits), want.map(f32::to_bits), "row {i}");
        }
        assert!(!raymesh_geometry::Ray::from_row(&EMPTY_ROW).is_valid());
    }

    fn args(extra: &[&str]) -> Args {
        let mut argv = vec!["raymesh-peers", "mesh.off"];
        argv.extend_from_slice(extra);
        Args::try_parse_from(argv).expect("valid arguments")
    }

    /// How many builds `more_builds` asks for, each taking `ms`.
    fn builds(a: &Args, ms: f64) -> u32 {
        let mut t = BuildTimes::NONE;
        while a.more_builds(&t) {
            t.add(ms);
            assert!(t.done <= 1000, "no end to the builds");
        }
        assert_eq!(t.best_ms, ms);
        t.done
    }

    /// `--queries` keeps the order given; both by default; an unknown
    /// or repeated query, or none, is refused.
    #[test]
    fn queries_are_read_in_order() {
        assert_eq!(args(&[]).queries.0, [false, true]);
        assert_eq!(args(&["--queries", "any-hit"]).queries.0, [true]);
        assert_eq!(
            args(&["--queries", "any-hit, closest"]).queries.0,
            [true, false]
        );
        for bad in ["closest,closest", "any", "", "closest,"] {
            let argv = ["raymesh-peers", "mesh.off", "--queries", bad];
            assert!(Args::try_parse_from(argv).is_err(), "{bad:?} accepted");
        }
    }

    /// `--accel`: a list keeps its order; `all` is every structure but
    /// brute force and the bounded list, `bvh` first; a structure named
    /// twice (`bvh` is `bvh8`) or an unknown one is refused. The engines:
    /// raymesh over the first structure, then one per other structure,
    /// then the peers.
    #[test]
    fn structures_run_as_engines() {
        let kinds = |a: &[&str]| args(a).accel.0;
        assert_eq!(kinds(&[]), [AccelKind::FASTEST_BVH]);
        assert_eq!(
            kinds(&["--accel", "grid, bvh-binned"]),
            [AccelKind::Grid, AccelKind::BvhBinned]
        );
        let all = kinds(&["--accel", "all"]);
        assert_eq!(all[0], AccelKind::FASTEST_BVH);
        assert_eq!(all.len(), AccelKind::ALL.len() - 2);
        for k in AccelKind::ALL {
            let want = !matches!(k, AccelKind::Brute | AccelKind::Aabb);
            assert_eq!(all.contains(&k), want, "{k:?}");
        }
        for bad in ["bvh,bvh8", "grid,grid", "grid,foo", "", "all,grid"] {
            let argv = ["raymesh-peers", "mesh.off", "--accel", bad];
            assert!(Args::try_parse_from(argv).is_err(), "{bad:?} accepted");
        }
        let names = |peers: &str, accel: &str| {
            engine_names(peers, &args(&["--accel", accel]).accel.0).expect("engines")
        };
        assert_eq!(
            names("obvhs", "kdtree,bvh8,grid"),
            ["raymesh", "raymesh-bvh8", "raymesh-grid", "obvhs"]
        );
        assert_eq!(names("none", "bvh"), ["raymesh"]);
        assert_eq!(
            names("bvh, raymesh-ray", "grid,bvh4"),
            ["raymesh", "raymesh-bvh4", "bvh", "raymesh-ray"]
        );
    }

    /// By default: at least R builds, then more until 0.25 s of them, at
    /// most 50; `--build-repeat` gives the count exactly (at least one).
    #[test]
    fn builds_fill_the_time_or_the_count() {
        let default = args(&[]);
        assert_eq!(builds(&default, 1000.0), 3, "slow builds: R of them");
        assert_eq!(builds(&default, 100.0), 3, "R builds pass 0.25 s");
        assert_eq!(builds(&default, 50.0), 5, "until 0.25 s");
        assert_eq!(builds(&default, 0.1), MAX_BUILDS, "fast builds: capped");
        assert_eq!(builds(&args(&["--repeat", "7"]), 100.0), 7);
        assert_eq!(builds(&args(&["--build-repeat", "2"]), 0.1), 2);
        assert_eq!(builds(&args(&["--build-repeat", "9"]), 1000.0), 9);
        assert_eq!(builds(&args(&["--build-repeat", "0"]), 1.0), 1);
        assert_eq!(builds(&args(&["--repeat", "0"]), 1000.0), 1);
    }
}
