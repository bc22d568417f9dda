//! `raymesh raycast MESH --rays RAYS.npy [--out HITS.npy] [--accel NAME] [--any-hit] [--threads N] [--repeat R] [--json] [--stats] [--packets | --stream] [--no-simd] [--spatial-splits [FRACTION]]`.

use crate::npy::{self, HitRecord};
use anyhow::{Context, Result};
use raymesh_accel::{
    AccelKind, BareHit, BuildConfig, CountStats, Primitives, Ray, Rays8, Scene, TriangleMesh,
    Triangles, LANES,
};
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `raymesh raycast`.
#[derive(clap::Args)]
pub struct Args {
    /// Mesh file (.obj, .off, .ply, .stl); polygons are fan-triangulated in file order.
    pub mesh: PathBuf,
    /// Rays: a float32 (N, 8) .npy array, columns ox oy oz tmin dx dy dz tmax.
    #[arg(long)]
    pub rays: PathBuf,
    /// Write hits here: (N,) records t <f4, prim <i4, u <f4, v <f4; a miss is t = inf, prim = -1.
    #[arg(long, short = 'o', visible_alias = "output")]
    pub out: Option<PathBuf>,
    /// Acceleration structure: brute, aabb, bvh-median, bvh-binned, bvh-sweep, bvh4, bvh8, bvh (our fastest: bvh8), grid, kdtree.
    #[arg(long, default_value = "bvh")]
    pub accel: AccelKind,
    /// Any-hit queries (shadow rays): a hit record names the first hit found, not the closest.
    #[arg(long)]
    pub any_hit: bool,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, allow_negative_numbers = true)]
    pub threads: Option<usize>,
    /// Trace the rays this many times and report the best time.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub repeat: u32,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also count mean nodes visited and primitives tested per ray (in a separate, untimed pass).
    #[arg(long)]
    pub stats: bool,
    /// Trace eight consecutive rays at a time, as packets
    /// (`Scene::intersect8_soa_bare`, with `--any-hit` `Scene::any_hit8_soa_bare`,
    /// the eight rows as they lie): fast for
    /// coherent rays such as a camera's, in tiles of 8, or shadow rays
    /// toward one light; eight that do not share a direction octant and
    /// dominant axis are traced one by one. Closest hits: the same hits,
    /// bit for bit; any hits: the same rays hit, each with a hit of its
    /// own (not always the one found first one by one).
    #[arg(long)]
    pub packets: bool,
    /// Trace each task's rays as a stream (`Scene::stream_bare`, the hits
    /// of `Scene::intersect_stream` and `Scene::any_hit_stream` without
    /// their normals): a few rays walk the tree at once,
    /// interleaved, which hides memory latency on incoherent rays (random
    /// directions), most on meshes far larger than the caches. Over bvh4
    /// and bvh8, closest hits' runs of eight coherent rays (one octant, as
    /// a camera's) walk the tree as packets, and over bvh8 (with AVX2) any
    /// hits, and closest hits of streams with no such run (diffuse
    /// bounces), walk in groups of 32 rays of one octant where the groups
    /// share nodes; without either, interleaving is slower than one by
    /// one on coherent rays. Over a bvh8 whose nodes take less than half
    /// the core's L2 (with AVX2; 256 KiB, some 30,000 triangles, where
    /// the system does not say) rays that would be interleaved go one by
    /// one, which is faster there. BVHs only
    /// (bvh-median, bvh-binned, bvh-sweep, bvh4, bvh8); other structures
    /// trace one by one. Same hits, bit for bit.
    #[arg(long, conflicts_with = "packets")]
    pub stream: bool,
    /// Turn the SIMD kernels off and run the portable fallbacks (same hits,
    /// bit for bit), to measure what the kernels buy.
    #[arg(long)]
    pub no_simd: bool,
    /// Spatial splits (SBVH) for bvh-binned, bvh4 and bvh8: triangles that
    /// cross a node's best cut are clipped to both sides, for fewer nodes
    /// and triangles a ray tests on meshes of long or diagonal triangles,
    /// at the price of a slower build. FRACTION bounds the duplicated
    /// references (0.25 when given alone: up to 25% more); 0 turns them off.
    #[arg(long, allow_negative_numbers = true, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "0.25",
          value_parser = crate::cmd::parse_fraction)]
    pub spatial_splits: Option<f32>,
    /// Reinsertion optimization of the binary BVH after its build (every
    /// BVH: bvh-median, bvh-binned, bvh-sweep, and the tree bvh4 and bvh8
    /// collapse): subtrees moved to where they lower the SAH cost. Pays
    /// on poor trees (bvh-median), hardly on the binned SAH trees of
    /// scanned meshes; 1.2 to 10 times the build.
    #[arg(long)]
    pub optimize: bool,
}

/// The `--json` object.
#[derive(Serialize)]
struct Report {
    accel: &'static str,
    triangles: usize,
    rays: usize,
    hits: usize,
    build_ms: f64,
    trace_ms: f64,
    mrays_per_s: f64,
    bytes_per_triangle: f64,
    nodes: usize,
    leaves: usize,
    depth: usize,
    sah_cost: f64,
    /// Expected node and leaf tests of a random ray that meets the root
    /// box (`AccelStats::node_tests`, `leaf_tests`): BVHs only.
    #[serde(skip_serializing_if = "Option::is_none")]
    node_tests: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    leaf_tests: Option<f64>,
    any_hit: bool,
    packets: bool,
    stream: bool,
    threads: usize,
    spatial_splits: f32,
    optimize: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    nodes_per_ray: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    prims_per_ray: Option<f64>,
}

/// Rays per parallel task: small enough to balance, large enough to amortize.
const CHUNK: usize = 1024;

/// Traces every ray, given as its row (`ox oy oz tmin dx dy dz tmax`), in
/// parallel, into hit records: one at a time, each row handed to the query
/// as it lies (`Scene::intersect_bare_row`, `Scene::any_hit_bare_row`),
/// which makes the ray inside its walk.
pub fn trace(scene: &Scene<Triangles>, rows: &[[f32; 8]], any_hit: bool, out: &mut [HitRecord]) {
    out.par_chunks_mut(CHUNK)
        .zip(rows.par_chunks(CHUNK))
        .for_each(|(out, rows)| {
            // The hits without their normals, which a record leaves out.
            for (o, r) in out.iter_mut().zip(rows) {
                *o = record(if any_hit {
                    scene.any_hit_bare_row(r)
                } else {
                    scene.intersect_bare_row(r)
                });
            }
        });
}

/// A way of tracing a batch of rays given as rows: `(scene, rows,
/// any_hit, out)`, a hit record a row into `out`.
pub type Tracer = fn(&Scene<Triangles>, &[[f32; 8]], bool, &mut [HitRecord]);

/// How `raycast`, and `bench` with the same flags, trace a batch of
/// rays: [`trace_packets`] with `packets`, else [`trace_stream`] with
/// `stream`, else [`trace`] (one ray at a time).
pub fn tracer(packets: bool, stream: bool) -> Tracer {
    if packets {
        trace_packets
    } else if stream {
        trace_stream
    } else {
        trace
    }
}

/// A hit record of a hit, or [`HitRecord::MISS`].
fn record(h: Option<BareHit>) -> HitRecord {
    h.map_or(HitRecord::MISS, |h| HitRecord {
        t: h.t,
        prim: h.prim as i32,
        u: h.u,
        v: h.v,
    })
}

/// Traces every ray, in parallel, each task's rays as one stream
/// ([`Scene::intersect_stream`] or [`Scene::any_hit_stream`]), into hit
/// records: the same records as [`trace`]. Each task makes its rays from
/// their rows first (a stream is a slice of `Ray`s), one by one: made
/// eight at a time by rows ([`Rays8::rays`]) they cost more, bunny00's
/// 4M primary rays 219 -> 225 ms and random ones 936 -> 1,010 ms (one
/// thread, pinned).
pub fn trace_stream(
    scene: &Scene<Triangles>,
    rows: &[[f32; 8]],
    any_hit: bool,
    out: &mut [HitRecord],
) {
    out.par_chunks_mut(CHUNK)
        .zip(rows.par_chunks(CHUNK))
        .for_each(|(out, rows)| {
            let rays: Vec<Ray> = rows.iter().map(Ray::from_row).collect();
            let mut hits = vec![None; rays.len()];
            scene.stream_bare(&rays, any_hit, &mut hits);
            for (o, h) in out.iter_mut().zip(hits) {
                *o = record(h);
            }
        });
}

/// Closest hits (or with `any_hit` any hits) of every ray, in parallel,
/// eight consecutive rays traced together as a packet, given as rows
/// ([`Rays8::from_rows`]; [`Scene::intersect8_soa_bare`],
/// [`Scene::any_hit8_soa_bare`]), into hit records. Eight whose
/// directions do not share an octant ([`one_octant`]) go one by one from
/// their rows, as the packet queries would send them.
pub fn trace_packets(
    scene: &Scene<Triangles>,
    rows: &[[f32; 8]],
    any_hit: bool,
    out: &mut [HitRecord],
) {
    const _: () = assert!(CHUNK.is_multiple_of(LANES));
    out.par_chunks_mut(CHUNK)
        .zip(rows.par_chunks(CHUNK))
        .for_each(|(out, rows)| {
            let mut outs = out.chunks_mut(LANES);
            for packet in rows.chunks(LANES) {
                let o = outs.next().expect("as many records as rays");
                let whole = <&[[f32; 8]; LANES]>::try_from(packet).ok();
                if let Some(whole) = whole.filter(|p| one_octant(p)) {
                    let packet = Rays8::from_rows(whole);
                    let hits = if any_hit {
                        scene.any_hit8_soa_bare(&packet)
                    } else {
                        scene.intersect8_soa_bare(&packet)
                    };
                    for (o, h) in o.iter_mut().zip(hits) {
                        *o = record(h);
                    }
                } else {
                    for (o, r) in o.iter_mut().zip(packet) {
                        *o = record(if any_hit {
                            scene.any_hit_bare_row(r)
                        } else {
                            scene.intersect_bare_row(r)
                        });
                    }
                }
            }
        });
}

/// Whether the directions of `rows` all lie in one octant (the sign bits
/// of `dx dy dz` alike): the first thing a packet's rays must share
/// ([`Rays8::lanes`]). Rays that do not go one by one without being
/// transposed into a packet first, and back out of it.
fn one_octant(rows: &[[f32; 8]; LANES]) -> bool {
    // A sign bit is the same in every row where its AND over the rows is
    // its OR: no branch a row.
    let (mut and, mut or) = ([u32::MAX; 3], [0u32; 3]);
    for r in rows {
        for a in 0..3 {
            and[a] &= r[4 + a].to_bits();
            or[a] |= r[4 + a].to_bits();
        }
    }
    (0..3).all(|a| (and[a] ^ or[a]) >> 31 == 0)
}

/// Mean nodes visited and primitives tested per ray.
pub fn count(scene: &Scene<Triangles>, rows: &[[f32; 8]], any_hit: bool) -> (f64, f64) {
    let total = rows
        .par_chunks(CHUNK)
        .map(|rows| {
            let mut c = CountStats::default();
            for r in rows {
                let r = Ray::from_row(r);
                if any_hit {
                    scene.occluded_counted(&r, &mut c);
                } else {
                    scene.intersect_counted(&r, &mut c);
                }
            }
            c
        })
        .reduce(CountStats::default, |a, b| CountStats {
            nodes: a.nodes + b.nodes,
            prims: a.prims + b.prims,
        });
    let n = rows.len().max(1) as f64;
    (total.nodes as f64 / n, total.prims as f64 / n)
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    raymesh_accel::set_simd_enabled(!args.no_simd);
    crate::cmd::check_build_flags(args.accel, args.spatial_splits.is_some(), args.optimize)?;
    let pool = crate::cmd::thread_pool(args.threads)?;
    let threads = pool.current_num_threads();
    if let Some(out) = &args.out {
        crate::cmd::check_output(out, &[("mesh", &args.mesh), ("rays", &args.rays)])?;
    }
    let mut mesh = crate::cmd::read_mesh(&args.mesh)?;
    let rays = npy::read_ray_rows(&args.rays)?;
    // The corner copy the scene gathers is all a trace needs: the mesh
    // goes once the scene is built.
    let triangles = mesh.triangles();
    let positions = std::mem::take(&mut mesh.positions);
    drop(mesh);
    let tm = TriangleMesh::new(positions, triangles);
    let ntri = tm.len();
    let step = crate::cmd::stage(format!(
        "building {} over {ntri} triangles",
        args.accel.name()
    ));
    let config = BuildConfig {
        spatial_splits: args.spatial_splits.unwrap_or(0.0),
        optimize: args.optimize,
        ..BuildConfig::default()
    };
    let scene = pool.install(|| Scene::from_mesh_with(&tm, args.accel, &config));
    drop(tm);
    step.finish_and_clear();
    let copy_bytes = scene.prims().bytes();
    let mut stats = scene.stats();
    // The corner copy is part of what the structure costs (the mesh's own buffers are not).
    stats.bytes += copy_bytes;
    let mut hits = vec![HitRecord::MISS; rays.len()];
    let mut best = f64::INFINITY;
    for _ in 0..args.repeat {
        let start = Instant::now();
        pool.install(|| tracer(args.packets, args.stream)(&scene, &rays, args.any_hit, &mut hits));
        best = best.min(start.elapsed().as_secs_f64() * 1e3);
    }
    let counted = args
        .stats
        .then(|| pool.install(|| count(&scene, &rays, args.any_hit)));
    if let Some(out) = &args.out {
        let f = std::fs::File::create(out)
            .with_context(|| format!("{}: cannot create", out.display()))?;
        let mut w = std::io::BufWriter::new(f);
        npy::write_hits(&mut w, &hits)
            .and_then(|()| std::io::Write::flush(&mut w))
            .with_context(|| format!("{}: cannot write", out.display()))?;
    }
    let nhits = hits.iter().filter(|h| h.prim >= 0).count();
    let report = Report {
        accel: stats.name,
        triangles: ntri,
        rays: rays.len(),
        hits: nhits,
        build_ms: stats.build_ms,
        trace_ms: best,
        mrays_per_s: if best > 0.0 {
            rays.len() as f64 / best / 1e3
        } else {
            0.0
        },
        bytes_per_triangle: stats.bytes as f64 / ntri.max(1) as f64,
        nodes: stats.nodes,
        leaves: stats.leaves,
        depth: stats.depth,
        sah_cost: stats.sah_cost,
        node_tests: stats.node_tests,
        leaf_tests: stats.leaf_tests,
        any_hit: args.any_hit,
        packets: args.packets,
        stream: args.stream,
        threads,
        spatial_splits: config.spatial_splits,
        optimize: config.optimize,
        nodes_per_ray: counted.map(|c| c.0),
        prims_per_ray: counted.map(|c| c.1),
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "structure          {} ({} threads{}{}{})",
            report.accel,
            threads,
            if args.any_hit { ", any hit" } else { "" },
            if config.spatial_splits > 0.0 {
                format!(", spatial splits up to {}%", config.spatial_splits * 100.0)
            } else {
                String::new()
            },
            if config.optimize {
                ", optimized by reinsertion"
            } else {
                ""
            }
        );
        println!("triangles          {}", report.triangles);
        println!("rays               {} ({} hit)", report.rays, report.hits);
        println!("build              {:.2} ms", report.build_ms);
        println!(
            "trace (best of {})  {:.2} ms = {:.2} Mrays/s",
            args.repeat, report.trace_ms, report.mrays_per_s
        );
        println!(
            "structure size     {:.1} bytes/triangle, {} nodes, {} leaves, depth {}",
            report.bytes_per_triangle, report.nodes, report.leaves, report.depth
        );
        println!("SAH cost           {:.2}", report.sah_cost);
        if let (Some(n), Some(l)) = (report.node_tests, report.leaf_tests) {
            println!(
                "expected tests     {n:.2} node tests, {l:.2} leaf tests (a random ray meeting the root box)"
            );
        }
        if let (Some(n), Some(p)) = (report.nodes_per_ray, report.prims_per_ray) {
            println!("per ray            {n:.1} nodes visited, {p:.1} triangles tested");
        }
        if let Some(out) = &args.out {
            println!("hits written to    {}", out.display());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eight rows share an octant when every direction component's sign
    /// bit is alike, `-0.0` counting as negative (as in `Rays8::lanes`);
    /// one row off in any axis, or the last, breaks it.
    #[test]
    fn one_octant_reads_every_rows_sign_bits() {
        let row = |i: usize| [i as f32, 0.0, 1.0, 0.0, 1.0 + i as f32, -2.0, -0.0, 9.0];
        let rows: [[f32; 8]; LANES] = std::array::from_fn(row);
        assert!(one_octant(&rows));
        for i in 0..LANES {
            for a in 4..7 {
                let mut off = rows;
                off[i][a] = -off[i][a];
                assert!(!one_octant(&off), "row {i}, column {a}");
            }
        }
        // Origins, `tmin` and `tmax` do not matter.
        let mut others = rows;
        others[3][0] = -5.0;
        others[5][7] = -1.0;
        assert!(one_octant(&others));
    }
}
