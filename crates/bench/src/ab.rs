//! `raymesh-ab [--baseline OTHER] MESH [--rays RAYS.npy | --workload W
//! --size N] [--accel A] [--query closest,any-hit,occluded] [--packets |
//! --stream] [--rows] [--chunk C] [--rounds R] [--instances K] [--spatial-splits [F]]
//! [--optimize] [--set K=V,...] [--baseline-set K=V,...] [--json]`:
//! two builds of raymesh on the same rays, taking turns chunk by chunk, so
//! that a change of a few percent can be told from this machine's drift.
//!
//! Each build runs as child processes (`raymesh-ab --serve ...`, this
//! file's other half) that build the scene once and then trace the chunks
//! the parent names, one at a time, on one thread, answering with the time
//! it took and a checksum of the hits. The parent sends every chunk to both
//! builds, in turn (first one, then the other, then the other first for
//! the next chunk), so both see the machine in the same state; a whole
//! run's speeds drift by ±10–20% on the shared VMs this project runs on,
//! and a comparison of two separate runs cannot resolve a 3% change.
//! The checksums say whether both builds returned the same hits, bit for
//! bit. Without `--baseline` the build is compared with itself: the spread
//! of that run is the noise floor; with `--set` and `--baseline-set`, two
//! build settings of one binary are compared (a leaf size, a cost).

use anyhow::{bail, ensure, Context, Result};
use clap::Parser;
use raymesh::npy;
use raymesh::workload::{make_rays, row_ray, Workload};
use raymesh_accel::{
    AccelKind, BareHit, BuildConfig, Ray, Rays8, Scene, Surface, TriangleMesh, Triangles, LANES,
};
use raymesh_mesh::io::read_mesh;
use serde::Serialize;
use std::borrow::Cow;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Instant;

/// What a child prints once its scene is built, before the first chunk;
/// the parent checks it, so a baseline too old to serve fails clearly.
/// v2: a chunk's time covers its queries alone, the checksum taken after
/// the clock stops (v1 timed it too: see [`trace_into`]), so v1 and v2 builds
/// are not compared.
const READY: &str = "raymesh-ab ready v2";

/// Compares two builds of raymesh on the same rays, chunk by chunk.
#[derive(Parser)]
struct Args {
    /// Mesh file.
    mesh: PathBuf,
    /// The other build's `raymesh-ab` binary (the baseline; build it from
    /// the commit to compare with). Default: this binary itself, whose
    /// comparison with itself shows the measurement's noise.
    #[arg(long)]
    baseline: Option<PathBuf>,
    /// Rays from a file (BENCH.md's (N, 8) float32 .npy).
    #[arg(long, conflicts_with = "workload")]
    rays: Option<PathBuf>,
    /// A workload of BENCH.md to generate instead (primary, random,
    /// diffuse, shadow).
    #[arg(long, default_value = "random")]
    workload: Workload,
    /// Image size of the generated workload.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1024)]
    size: u32,
    /// Structure to build.
    #[arg(long, default_value = "bvh")]
    accel: AccelKind,
    /// Queries to compare, comma-separated: closest, any-hit, occluded
    /// (whether each ray hits: `Scene::occluded`, `occluded8`,
    /// `occluded_stream`, the calls behind `raymesh-peers`'s any-hit rows).
    #[arg(long, default_value = "closest,any-hit")]
    query: String,
    /// Eight consecutive rays at a time (`Scene::intersect8_bare`,
    /// `Scene::any_hit8_bare`, `Scene::occluded8`; with `--rows`, each
    /// eight rows go in as rows, `Rays8`, to `Scene::intersect8_soa_bare`,
    /// `any_hit8_soa_bare` and `occluded8_soa`, as `raymesh-peers
    /// --packets` and `raycast --packets` hand them).
    #[arg(long, conflicts_with = "stream")]
    packets: bool,
    /// Each chunk traced as streams of 1,024 rays (`Scene::stream_bare`).
    #[arg(long)]
    stream: bool,
    /// Each ray made from its row (`ox oy oz tmin dx dy dz tmax`) inside
    /// the timed pass, as `raymesh-peers` makes them (and Embree makes
    /// its own), so that `Ray::new` is timed with the queries; without it
    /// the rays are made once, before any chunk (a baseline from before
    /// `--rows` refuses it). One ray at a time, each row goes in as it
    /// lies (`Scene::intersect_bare_row`, `any_hit_bare_row`,
    /// `occluded_row`), the ray made inside the query, as `raymesh-peers`
    /// hands them over since stop 74; packets go in as rows (`Rays8`),
    /// and streams make their `Ray`s from the rows first.
    #[arg(long)]
    rows: bool,
    /// Rays a chunk: each build traces a chunk, then the other.
    #[arg(long, allow_negative_numbers = true, default_value_t = 65536)]
    chunk: usize,
    /// Passes over all the rays (after one untimed pass).
    #[arg(long, allow_negative_numbers = true, default_value_t = 3)]
    rounds: usize,
    /// Processes of each build, taking the chunks in turn: where a
    /// process's data happens to lie in memory changes its speed by a
    /// few percent (two runs of one binary differ so), and several
    /// processes average that out.
    #[arg(long, allow_negative_numbers = true, default_value_t = 2)]
    instances: usize,
    /// Spatial splits, as `raymesh raycast --spatial-splits`.
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "0.25")]
    spatial_splits: Option<f32>,
    /// Reinsertion optimization, as `raymesh raycast --optimize`.
    #[arg(long)]
    optimize: bool,
    /// Build settings of this build, `KEY=VALUE` comma-separated, over
    /// the defaults (and `--spatial-splits`, `--optimize`): `max_leaf`,
    /// `traversal_cost`, `bins`, `leaf_block`, `grid_density`,
    /// `grid_subgrid_min`, `grid_subgrid_ratio`, `spatial_splits`,
    /// `optimize`. With `--baseline-set` and no
    /// `--baseline`, one binary compares two settings.
    #[arg(long, value_name = "KEY=VALUE,...")]
    set: Option<String>,
    /// Build settings of the baseline, as `--set` (a baseline binary from
    /// before `--set` existed refuses them).
    #[arg(long, value_name = "KEY=VALUE,...")]
    baseline_set: Option<String>,
    /// One JSON object a query instead of the text report.
    #[arg(long)]
    json: bool,
    /// Internal: run as a child that traces the chunks it is sent.
    #[arg(long, hide = true)]
    serve: bool,
}

/// A query the builds are compared on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Query {
    Closest,
    AnyHit,
    Occluded,
}

impl Query {
    fn name(self) -> &'static str {
        match self {
            Self::Closest => "closest",
            Self::AnyHit => "any-hit",
            Self::Occluded => "occluded",
        }
    }

    fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "closest" => Ok(Self::Closest),
            "any-hit" | "any" => Ok(Self::AnyHit),
            "occluded" => Ok(Self::Occluded),
            other => bail!("unknown query '{other}'; expected closest, any-hit or occluded"),
        }
    }
}

/// One query's comparison (`--json`).
#[derive(Serialize)]
struct Report {
    mesh: String,
    accel: &'static str,
    rays: usize,
    chunks: usize,
    rounds: usize,
    query: &'static str,
    mode: &'static str,
    /// Whether the rays were made from their rows in the timed pass
    /// (`--rows`).
    rows: bool,
    baseline_mrays_per_s: f64,
    build_mrays_per_s: f64,
    /// Total time of the baseline over total time of this build: above 1
    /// when this build is faster.
    speedup: f64,
    /// The same ratio over each two chunks (one with each build first):
    /// median and quartiles.
    chunk_median: f64,
    chunk_q1: f64,
    chunk_q3: f64,
    /// Whether both builds returned the same hits, bit for bit.
    same_hits: bool,
    /// `--set` and `--baseline-set`, as given.
    set: Option<String>,
    baseline_set: Option<String>,
    /// Nodes of each side's structure, where both are this binary's with
    /// other settings (the parent builds both to say so).
    nodes: Option<usize>,
    baseline_nodes: Option<usize>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.serve {
        return serve(&args);
    }
    compare(&args)
}

/// The scene both halves build from the arguments.
fn build_scene(args: &Args) -> Result<Scene<Triangles>> {
    let mesh = read_mesh(&args.mesh)?;
    let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
    let config = config(args, args.set.as_deref())?;
    Ok(Scene::from_mesh_with(&tm, args.accel, &config))
}

/// The build settings of the arguments with `set` (`--set`'s form)
/// applied over them.
fn config(args: &Args, set: Option<&str>) -> Result<BuildConfig> {
    let mut config = BuildConfig {
        spatial_splits: args.spatial_splits.unwrap_or(0.0),
        optimize: args.optimize,
        ..BuildConfig::default()
    };
    for item in set.into_iter().flat_map(|s| s.split(',')) {
        let item = item.trim();
        if item.is_empty() {
            continue;
        }
        let (key, value) = item
            .split_once('=')
            .with_context(|| format!("setting '{item}': expected KEY=VALUE"))?;
        let (key, value) = (key.trim(), value.trim());
        let bad = |what: &str| format!("setting {key}: '{value}' is not {what}");
        match key {
            "max_leaf" | "leaf_block" => {
                let n: usize = value.parse().with_context(|| bad("a count"))?;
                ensure!(n > 0, "{}", bad("a count of 1 or more"));
                if key == "max_leaf" {
                    config.max_leaf = Some(n);
                } else {
                    config.leaf_block = Some(n);
                }
            }
            "grid_subgrid_min" => {
                config.grid_subgrid_min = value.parse().with_context(|| bad("a count"))?;
            }
            "bins" => {
                let n: usize = value.parse().with_context(|| bad("a count"))?;
                ensure!((2..=64).contains(&n), "{}", bad("between 2 and 64"));
                config.bins = n;
            }
            "traversal_cost" | "grid_density" | "grid_subgrid_ratio" | "spatial_splits" => {
                let x: f32 = value.parse().with_context(|| bad("a number"))?;
                ensure!(
                    x.is_finite() && x >= 0.0,
                    "{}",
                    bad("a number of 0 or more")
                );
                match key {
                    "traversal_cost" => config.traversal_cost = x,
                    "grid_density" => config.grid_density = x,
                    "grid_subgrid_ratio" => config.grid_subgrid_ratio = x,
                    _ => config.spatial_splits = x,
                }
            }
            "optimize" => {
                config.optimize = value.parse().with_context(|| bad("true or false"))?;
            }
            _ => bail!(
                "unknown setting '{key}'; expected max_leaf, traversal_cost, bins, \
                 leaf_block, grid_density, grid_subgrid_min, grid_subgrid_ratio, \
                 spatial_splits or optimize"
            ),
        }
    }
    Ok(config)
}

/// The child: builds the scene, reads the rays, then answers each line
/// `trace FIRST END QUERY` with `NANOSECONDS CHECKSUM` until `quit` or the
/// end of its input.
fn serve(args: &Args) -> Result<()> {
    let rays_path = args.rays.as_deref().context("--serve needs --rays")?;
    let file_rows = npy::read_ray_rows(rays_path)?;
    let rays: Vec<Ray> = file_rows.iter().map(Ray::from_row).collect();
    let rows = if args.rows { file_rows } else { Vec::new() };
    let scene = build_scene(args)?;
    let mut hits = Vec::new();
    let mut out = std::io::stdout().lock();
    writeln!(out, "{READY} {}", rays.len())?;
    out.flush()?;
    for line in std::io::stdin().lock().lines() {
        let line = line?;
        let words: Vec<&str> = line.split_whitespace().collect();
        match words[..] {
            ["quit"] => break,
            ["trace", first, end, query] => {
                let (first, end): (usize, usize) = (first.parse()?, end.parse()?);
                ensure!(
                    first <= end && end <= rays.len(),
                    "chunk {first}..{end} out of range"
                );
                let query = Query::parse(query)?;
                hits.clear();
                hits.resize(end - first, None);
                let input = if args.rows {
                    Input::Rows(&rows[first..end])
                } else {
                    Input::Rays(&rays[first..end])
                };
                let start = Instant::now();
                trace_into(&scene, input, query, args.packets, args.stream, &mut hits);
                let ns = start.elapsed().as_nanos();
                let sum = checksum(&hits);
                writeln!(out, "{ns} {sum:016x}")?;
                out.flush()?;
            }
            _ => bail!("unknown request '{line}'"),
        }
    }
    Ok(())
}

/// Traces `rays` on this thread and returns a checksum of the hits.
#[cfg(test)]
fn trace(scene: &Scene<Triangles>, rays: &[Ray], query: Query, packets: bool, stream: bool) -> u64 {
    let mut hits = vec![None; rays.len()];
    trace_into(scene, Input::Rays(rays), query, packets, stream, &mut hits);
    checksum(&hits)
}

/// A chunk's rays: made before the clock starts, or rows to make them
/// from inside the timed pass (`--rows`).
#[derive(Clone, Copy)]
enum Input<'a> {
    Rays(&'a [Ray]),
    Rows(&'a [[f32; 8]]),
}

impl<'a> Input<'a> {
    fn len(self) -> usize {
        match self {
            Self::Rays(r) => r.len(),
            Self::Rows(r) => r.len(),
        }
    }

    /// `f` of rays `range`, at most [`LANES`] and at least one: borrowed,
    /// or made from their rows on the stack (a packet's rays, made with no
    /// allocation).
    fn with_few<R>(self, range: std::ops::Range<usize>, f: impl FnOnce(&[Ray]) -> R) -> R {
        match self {
            Self::Rays(r) => f(&r[range]),
            Self::Rows(rows) => {
                let rows = &rows[range];
                assert!(!rows.is_empty() && rows.len() <= LANES);
                let rays: [Ray; LANES] =
                    std::array::from_fn(|k| row_ray(&rows[k.min(rows.len() - 1)]));
                f(&rays[..rows.len()])
            }
        }
    }

    /// Rays `range`: borrowed, or made from their rows.
    fn rays(self, range: std::ops::Range<usize>) -> Cow<'a, [Ray]> {
        match self {
            Self::Rays(r) => Cow::Borrowed(&r[range]),
            Self::Rows(r) => Cow::Owned(r[range].iter().map(row_ray).collect()),
        }
    }
}

/// What an occlusion query's answer goes into the checksum as.
fn occluded_hit(hit: bool) -> Option<BareHit> {
    hit.then_some(BareHit {
        t: 0.0,
        prim: 0,
        u: 0.0,
        v: 0.0,
    })
}

/// Traces `input` on this thread into `hits` (one each): what a chunk's
/// time covers. The checksum is taken afterwards: FNV-1a is a chain of 16
/// dependent multiplies a ray, which timed with the queries (protocol v1)
/// added its latency to every ray and, being the harness's own code, moved
/// with the harness's compilation (a build profiled in its raymesh crates
/// but not raymesh_accel read 1.05–1.09× the plain one on a Zen 3, the
/// walks' code unchanged instruction for instruction).
fn trace_into(
    scene: &Scene<Triangles>,
    input: Input,
    query: Query,
    packets: bool,
    stream: bool,
    hits: &mut [Option<BareHit>],
) {
    assert_eq!(input.len(), hits.len());
    let one = |r: &Ray| match query {
        Query::Closest => scene.intersect_bare(r),
        Query::AnyHit => scene.any_hit_bare(r),
        Query::Occluded => occluded_hit(scene.occluded(r)),
    };
    if stream {
        for (c, out) in hits.chunks_mut(1024).enumerate() {
            let part = input.rays(c * 1024..c * 1024 + out.len());
            if query == Query::Occluded {
                let mut occluded = vec![false; part.len()];
                scene.occluded_stream(&part, &mut occluded);
                for (h, o) in out.iter_mut().zip(occluded) {
                    *h = occluded_hit(o);
                }
            } else {
                scene.stream_bare(&part, query == Query::AnyHit, out);
            }
        }
    } else if packets {
        for (c, out) in hits.chunks_mut(LANES).enumerate() {
            // Whole packets of rows go in as rows (`Rays8`), as
            // `raymesh-peers --packets` and `raycast --packets` hand them.
            if let Input::Rows(rows) = input {
                let at = c * LANES;
                if let Ok(p) = <&[[f32; 8]; LANES]>::try_from(&rows[at..at + out.len()]) {
                    let p = Rays8::from_rows(p);
                    out.copy_from_slice(&match query {
                        Query::Closest => scene.intersect8_soa_bare(&p),
                        Query::AnyHit => scene.any_hit8_soa_bare(&p),
                        Query::Occluded => scene.occluded8_soa(&p).map(occluded_hit),
                    });
                    continue;
                }
            }
            input.with_few(c * LANES..c * LANES + out.len(), |part| {
                if let Ok(packet) = <&[Ray; LANES]>::try_from(part) {
                    out.copy_from_slice(&match query {
                        Query::Closest => scene.intersect8_bare(packet),
                        Query::AnyHit => scene.any_hit8_bare(packet),
                        Query::Occluded => scene.occluded8(packet).map(occluded_hit),
                    });
                } else {
                    for (r, h) in part.iter().zip(out) {
                        *h = one(r);
                    }
                }
            });
        }
    } else {
        match input {
            Input::Rays(rays) => {
                for (r, h) in rays.iter().zip(hits) {
                    *h = one(r);
                }
            }
            Input::Rows(rows) => {
                // Each row handed over as it lies, as `raymesh-peers`
                // hands them (the ray made inside the query).
                for (r, h) in rows.iter().zip(hits) {
                    *h = match query {
                        Query::Closest => scene.intersect_bare_row(r),
                        Query::AnyHit => scene.any_hit_bare_row(r),
                        Query::Occluded => occluded_hit(scene.occluded_row(r)),
                    };
                }
            }
        }
    }
}

/// [`Checksum`] of `hits` in order.
fn checksum(hits: &[Option<BareHit>]) -> u64 {
    let mut sum = Checksum::default();
    hits.iter().for_each(|h| sum.add(*h));
    sum.0
}

/// FNV-1a over each ray's hit (primitive and the bits of `t`, `u`, `v`).
struct Checksum(u64);

impl Default for Checksum {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Checksum {
    fn add(&mut self, h: Option<BareHit>) {
        let words = h.map_or([u32::MAX; 4], |h| {
            [h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()]
        });
        for w in words {
            for b in w.to_le_bytes() {
                self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
}

/// A running child and its pipes.
struct Server {
    name: &'static str,
    child: Child,
    input: BufWriter<ChildStdin>,
    output: BufReader<ChildStdout>,
}

impl Server {
    /// Starts `binary --serve` with the comparison's settings and waits
    /// until it has built its scene.
    fn start(
        name: &'static str,
        binary: &Path,
        args: &Args,
        set: Option<&str>,
        rays: &Path,
        n: usize,
    ) -> Result<Self> {
        let mut cmd = Command::new(binary);
        if let Some(set) = set {
            cmd.arg(format!("--set={set}"));
        }
        cmd.arg("--serve")
            .arg(&args.mesh)
            .arg("--rays")
            .arg(rays)
            .arg("--accel")
            .arg(args.accel.name());
        if let Some(f) = args.spatial_splits {
            cmd.arg(format!("--spatial-splits={f}"));
        }
        for (on, flag) in [
            (args.optimize, "--optimize"),
            (args.packets, "--packets"),
            (args.stream, "--stream"),
            (args.rows, "--rows"),
        ] {
            if on {
                cmd.arg(flag);
            }
        }
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting the {name} build, {}", binary.display()))?;
        let input = BufWriter::new(child.stdin.take().context("child stdin")?);
        let output = BufReader::new(child.stdout.take().context("child stdout")?);
        let mut server = Self {
            name,
            child,
            input,
            output,
        };
        let line = server.read_line()?;
        let expected = format!("{READY} {n}");
        if line.starts_with("raymesh-ab ready v1 ") {
            bail!(
                "the {name} build ({}) is a raymesh-ab from before v2, which timed its \
                 checksum with the queries (about 16 dependent multiplies a ray): its \
                 figures are not comparable. Build the baseline with this version's \
                 crates/bench/src/ab.rs (e.g. `git checkout OLD && git checkout main -- \
                 crates/bench/src/ab.rs`, then build raymesh-ab)",
                binary.display()
            );
        }
        if line != expected {
            bail!(
                "the {name} build ({}) answered '{line}' where '{expected}' was expected: \
                 is it a raymesh-ab binary, of this version or later?",
                binary.display()
            );
        }
        Ok(server)
    }

    fn read_line(&mut self) -> Result<String> {
        let mut line = String::new();
        let n = self.output.read_line(&mut line)?;
        if n == 0 {
            let status = self.child.wait()?;
            bail!(
                "the {} build stopped ({status}); its error is above",
                self.name
            );
        }
        Ok(line.trim_end().to_string())
    }

    /// Traces rays `first..end` and returns (nanoseconds, checksum).
    fn trace(&mut self, first: usize, end: usize, query: Query) -> Result<(u64, u64)> {
        writeln!(self.input, "trace {first} {end} {}", query.name())?;
        self.input.flush()?;
        let line = self.read_line()?;
        let parse = || -> Option<(u64, u64)> {
            let (ns, sum) = line.split_once(' ')?;
            Some((ns.parse().ok()?, u64::from_str_radix(sum, 16).ok()?))
        };
        parse().with_context(|| format!("the {} build answered '{line}'", self.name))
    }

    fn quit(mut self) -> Result<()> {
        writeln!(self.input, "quit")?;
        self.input.flush()?;
        drop(self.input);
        let status = self.child.wait()?;
        ensure!(
            status.success(),
            "the {} build exited with {status}",
            self.name
        );
        Ok(())
    }
}

/// A temporary file removed when dropped.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The `q`-quantile of sorted values (nearest rank).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn compare(args: &Args) -> Result<()> {
    ensure!(args.chunk > 0, "--chunk must be at least 1");
    ensure!(args.rounds > 0, "--rounds must be at least 1");
    ensure!(args.instances > 0, "--instances must be at least 1");
    // Settings checked here, so that a typo is named at once, not by a
    // child after the rays are made.
    for set in [&args.set, &args.baseline_set] {
        config(args, set.as_deref())?;
    }
    let queries: Vec<Query> = args
        .query
        .split(',')
        .map(Query::parse)
        .collect::<Result<_>>()?;
    let this = std::env::current_exe().context("finding this binary")?;
    let baseline = args.baseline.clone().unwrap_or_else(|| this.clone());
    // The rays: the given file, or the workload written to a temporary
    // file that both children read.
    let (rays_path, n, _temp, source) = match &args.rays {
        Some(p) => {
            let n = npy::read_ray_rows(p)?.len();
            (p.clone(), n, None, p.display().to_string())
        }
        None => {
            let mesh = read_mesh(&args.mesh)?;
            let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
            let scene = Scene::build(tm, AccelKind::FASTEST_BVH);
            let rays = make_rays(args.workload, &scene, args.size, 1);
            let path = std::env::temp_dir().join(format!(
                "raymesh-ab-{}-{}.npy",
                std::process::id(),
                args.workload.name()
            ));
            let mut w = BufWriter::new(
                std::fs::File::create(&path)
                    .with_context(|| format!("creating {}", path.display()))?,
            );
            npy::write_rays(&mut w, &rays)?;
            w.flush()?;
            let source = format!("{} {}", args.workload.name(), args.size);
            (path.clone(), rays.len(), Some(TempFile(path)), source)
        }
    };
    ensure!(n > 0, "{}: no rays", rays_path.display());
    // Two settings of this one binary: both structures, as it builds them.
    let structures = (args.baseline.is_none()
        && (args.set.is_some() || args.baseline_set.is_some()))
    .then(|| -> Result<_> {
        let mesh = read_mesh(&args.mesh)?;
        let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
        let stats = |set: &Option<String>| -> Result<raymesh_accel::AccelStats> {
            let c = config(args, set.as_deref())?;
            Ok(Scene::from_mesh_with(&tm, args.accel, &c).stats())
        };
        Ok([stats(&args.baseline_set)?, stats(&args.set)?])
    })
    .transpose()?;
    // `servers[i]` is instance `i / 2` of the baseline (even `i`) or of
    // this build (odd `i`).
    let mut servers = Vec::new();
    for _ in 0..args.instances {
        let base_set = args.baseline_set.as_deref();
        servers.push(Server::start(
            "baseline", &baseline, args, base_set, &rays_path, n,
        )?);
        servers.push(Server::start(
            "this",
            &this,
            args,
            args.set.as_deref(),
            &rays_path,
            n,
        )?);
    }
    let chunks: Vec<(usize, usize)> = (0..n)
        .step_by(args.chunk)
        .map(|f| (f, (f + args.chunk).min(n)))
        .collect();
    let mode = if args.stream {
        "stream"
    } else if args.packets {
        "packets"
    } else {
        "single"
    };
    if !args.json {
        println!(
            "{}: {} rays ({source}{}), {}, {mode}; {} chunks of up to {}, {} rounds, \
             {} processes of each build taking turns",
            args.mesh.display(),
            n,
            if args.rows {
                ", made in the timed pass"
            } else {
                ""
            },
            args.accel.name(),
            chunks.len(),
            args.chunk,
            args.rounds,
            args.instances
        );
        if args.set.is_some() || args.baseline_set.is_some() {
            let show = |s: &Option<String>| s.clone().unwrap_or_else(|| "defaults".into());
            println!(
                "  settings: baseline {}, this build {}",
                show(&args.baseline_set),
                show(&args.set)
            );
        }
        if let Some([b, t]) = &structures {
            let show = |s: &raymesh_accel::AccelStats| {
                format!(
                    "{} nodes, depth {}, SAH {:.2}",
                    s.nodes, s.depth, s.sah_cost
                )
            };
            println!("  structures: baseline {}, this build {}", show(b), show(t));
        }
    }
    for &query in &queries {
        // One untimed pass each: pages faulted in, caches and predictors warm.
        for s in &mut servers {
            s.trace(0, n, query)?;
        }
        let mut total = [0u64; 2];
        let mut ratios = Vec::new();
        let mut same = true;
        let mut turn = 0usize;
        let mut pair = [0u64; 2];
        for _ in 0..args.rounds {
            for &(first, end) in &chunks {
                let mut t = [0u64; 2];
                let mut sums = [0u64; 2];
                let order = if turn.is_multiple_of(2) {
                    [0, 1]
                } else {
                    [1, 0]
                };
                // Each turn goes to the next process of each build, so
                // that with two or more no process traces twice in a row
                // (its data still in the caches) and with one each build
                // does so equally often.
                let base = 2 * (turn % args.instances);
                turn += 1;
                for k in order {
                    (t[k], sums[k]) = servers[base + k].trace(first, end, query)?;
                }
                same &= sums[0] == sums[1];
                total[0] += t[0];
                total[1] += t[1];
                // Turns go in pairs, one with each build first, so that
                // whatever going first or second does to a chunk's time
                // (the other process's data in the caches) cancels.
                pair[0] += t[0];
                pair[1] += t[1];
                if turn.is_multiple_of(2) {
                    ratios.push(pair[0].max(1) as f64 / pair[1].max(1) as f64);
                    pair = [0; 2];
                }
            }
        }
        if pair != [0; 2] {
            ratios.push(pair[0].max(1) as f64 / pair[1].max(1) as f64);
        }
        ratios.sort_by(f64::total_cmp);
        let rate = |ns: u64| (n * args.rounds) as f64 / (ns.max(1) as f64 * 1e-9) / 1e6;
        let report = Report {
            mesh: args.mesh.display().to_string(),
            accel: args.accel.name(),
            rays: n,
            chunks: chunks.len(),
            rounds: args.rounds,
            query: query.name(),
            mode,
            rows: args.rows,
            baseline_mrays_per_s: rate(total[0]),
            build_mrays_per_s: rate(total[1]),
            speedup: total[0] as f64 / total[1].max(1) as f64,
            chunk_median: quantile(&ratios, 0.5),
            chunk_q1: quantile(&ratios, 0.25),
            chunk_q3: quantile(&ratios, 0.75),
            same_hits: same,
            set: args.set.clone(),
            baseline_set: args.baseline_set.clone(),
            nodes: structures.as_ref().map(|s| s[1].nodes),
            baseline_nodes: structures.as_ref().map(|s| s[0].nodes),
        };
        if args.json {
            println!("{}", serde_json::to_string(&report)?);
        } else {
            println!(
                "  {:<8} baseline {:.3} Mrays/s, this build {:.3}: {:.3}x (by pairs of turns: median {:.3}, quartiles {:.3}..{:.3}); {}",
                query.name(),
                report.baseline_mrays_per_s,
                report.build_mrays_per_s,
                report.speedup,
                report.chunk_median,
                report.chunk_q1,
                report.chunk_q3,
                if same { "the same hits" } else { "HITS DIFFER" }
            );
        }
    }
    for s in servers {
        s.quit()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use raymesh::workload::unpack_ray;

    #[test]
    fn checksums_tell_hits_apart() {
        let hit = |t: f32| {
            Some(BareHit {
                t,
                prim: 3,
                u: 0.25,
                v: 0.5,
            })
        };
        let sum = checksum;
        assert_eq!(sum(&[hit(1.0), None]), sum(&[hit(1.0), None]));
        assert_ne!(sum(&[hit(1.0), None]), sum(&[None, hit(1.0)]));
        assert_ne!(
            sum(&[hit(1.0)]),
            sum(&[hit(f32::from_bits(1.0f32.to_bits() + 1))])
        );
        assert_ne!(sum(&[hit(1.0)]), sum(&[None]));
    }

    /// The elephant (holes and all) over an 8-wide BVH, and random rays.
    fn elephant_and_rays() -> (Scene<Triangles>, Vec<Ray>) {
        let mesh = read_mesh(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/data/elephant-with-holes.off"
        ))
        .unwrap();
        let tm = TriangleMesh::new(mesh.positions.clone(), mesh.triangles());
        let scene = Scene::from_mesh_with(&tm, AccelKind::Bvh8, &BuildConfig::default());
        let rays = make_rays(Workload::Random, &scene, 21, 1)
            .into_iter()
            .map(unpack_ray)
            .collect();
        (scene, rays)
    }

    #[test]
    fn every_mode_traces_the_same_closest_hits() {
        let (scene, rays) = elephant_and_rays();
        let single = trace(&scene, &rays, Query::Closest, false, false);
        assert_eq!(single, trace(&scene, &rays, Query::Closest, true, false));
        assert_eq!(single, trace(&scene, &rays, Query::Closest, false, true));
        assert_ne!(single, Checksum::default().0, "the rays hit something");
    }

    #[test]
    fn rows_and_occlusion_answer_as_the_rays_do() {
        let (scene, rays) = elephant_and_rays();
        let rows: Vec<[f32; 8]> = rays.iter().map(Ray::row).collect();
        let run = |input: Input, query, packets, stream| {
            let mut hits = vec![None; input.len()];
            trace_into(&scene, input, query, packets, stream, &mut hits);
            hits
        };
        for query in [Query::Closest, Query::AnyHit, Query::Occluded] {
            for (packets, stream) in [(false, false), (true, false), (false, true)] {
                assert_eq!(
                    run(Input::Rays(&rays), query, packets, stream),
                    run(Input::Rows(&rows), query, packets, stream),
                    "{query:?}, packets {packets}, stream {stream}"
                );
            }
        }
        // Whether each ray hits, in every mode, is whether it has a
        // closest hit.
        let closest = run(Input::Rays(&rays), Query::Closest, false, false);
        let hit: Vec<bool> = closest.iter().map(Option::is_some).collect();
        assert!(hit.contains(&true) && hit.contains(&false));
        for (packets, stream) in [(false, false), (true, false), (false, true)] {
            let occluded = run(Input::Rows(&rows), Query::Occluded, packets, stream);
            let got: Vec<bool> = occluded.iter().map(Option::is_some).collect();
            assert_eq!(got, hit, "packets {packets}, stream {stream}");
        }
    }

    #[test]
    fn quantiles_take_the_nearest_rank() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(quantile(&v, 0.5), 3.0);
        assert_eq!(quantile(&v, 0.25), 2.0);
        assert_eq!(quantile(&v, 0.75), 4.0);
        assert_eq!(quantile(&[7.0], 0.5), 7.0);
    }
}
