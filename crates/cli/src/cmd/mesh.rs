//! `raymesh mesh FILE [--strict] [--json] [--bench]`: connectivity of a mesh
//! in the three structures, and what they cost.

use anyhow::Result;
use raymesh_mesh::half_edge::{BuildOptions, RepairReport};
use raymesh_mesh::handle::Vertex;
use raymesh_mesh::{CompactMesh, HalfEdgeMesh, IndexedMesh, WingedEdgeMesh};
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `raymesh mesh`.
#[derive(clap::Args)]
pub struct Args {
    /// Mesh file (.obj, .off, .ply, .stl).
    pub file: PathBuf,
    /// Refuse non-manifold or inconsistent input (naming the faces) instead of repairing it.
    #[arg(long)]
    pub strict: bool,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also time building each structure, a one-ring walk, vertex normals and one Loop step (best of 5).
    #[arg(long)]
    pub bench: bool,
}

#[derive(Serialize)]
struct Bytes {
    /// Each null for a mesh without vertices, where a per-vertex figure
    /// means nothing.
    half_edge: Option<f64>,
    winged_edge: Option<f64>,
    /// Null when some face is not a triangle.
    compact: Option<f64>,
}

#[derive(Serialize)]
struct BuildMs {
    half_edge: f64,
    winged_edge: f64,
    compact: Option<f64>,
}

#[derive(Serialize)]
struct Report {
    vertices: usize,
    edges: usize,
    faces: usize,
    half_edges: usize,
    boundary_loops: usize,
    components: usize,
    euler_characteristic: i64,
    genus: i64,
    non_manifold_edges: usize,
    non_manifold_vertices: usize,
    inconsistent_edges: usize,
    repeated_faces: usize,
    degenerate_faces: usize,
    added_vertices: usize,
    added_edges: usize,
    bytes_per_vertex: Bytes,
    #[serde(skip_serializing_if = "Option::is_none")]
    build_ms: Option<BuildMs>,
    #[serde(skip_serializing_if = "Option::is_none")]
    one_ring_ns_per_neighbor: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    normals_ms: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    loop_ms: Option<f64>,
}

/// Best of `n` timings of `f`, in milliseconds.
fn best_ms<T>(n: usize, mut f: impl FnMut() -> T) -> f64 {
    (0..n)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn build(m: &IndexedMesh) -> HalfEdgeMesh {
    HalfEdgeMesh::from_indexed(m)
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    let mesh = crate::cmd::read_mesh(&args.file)?;
    let (he, report): (HalfEdgeMesh, RepairReport) = HalfEdgeMesh::build(
        &mesh,
        BuildOptions {
            strict: args.strict,
        },
    )
    .map_err(|e| e.with_path(&args.file))?;
    let we = WingedEdgeMesh::from_half_edge(&he);
    let cm = CompactMesh::from_half_edge(&he);
    // Per vertex: none for a mesh without vertices (the compact form's
    // index arrays keep a word each even then).
    let per_vertex = |bytes: usize| {
        let nv = he.num_vertices();
        (nv > 0).then(|| bytes as f64 / nv as f64)
    };
    let mut r = Report {
        vertices: he.num_vertices(),
        edges: he.num_edges(),
        faces: he.num_faces(),
        half_edges: he.num_halfedges(),
        boundary_loops: he.boundary_loops().len(),
        components: he.components().0,
        euler_characteristic: he.euler_characteristic(),
        genus: he.genus(),
        non_manifold_edges: report.non_manifold_edges,
        non_manifold_vertices: report.non_manifold_vertices,
        inconsistent_edges: report.inconsistent_edges,
        repeated_faces: report.repeated_faces.len(),
        degenerate_faces: report.degenerate_faces.len(),
        added_vertices: report.added_vertices,
        added_edges: report.added_edges,
        bytes_per_vertex: Bytes {
            half_edge: per_vertex(he.memory_bytes()),
            winged_edge: per_vertex(we.memory_bytes()),
            compact: cm.as_ref().and_then(|c| per_vertex(c.memory_bytes())),
        },
        build_ms: None,
        one_ring_ns_per_neighbor: None,
        normals_ms: None,
        loop_ms: None,
    };
    if args.bench {
        const RUNS: usize = 5;
        let he_ms = best_ms(RUNS, || build(&mesh));
        r.build_ms = Some(BuildMs {
            half_edge: he_ms,
            winged_edge: best_ms(RUNS, || WingedEdgeMesh::from_half_edge(&build(&mesh))),
            compact: cm
                .as_ref()
                .map(|_| best_ms(RUNS, || CompactMesh::from_half_edge(&build(&mesh)))),
        });
        let mut neighbors = 0u64;
        let ring_ms = best_ms(RUNS, || {
            let (mut sum, mut n) = (0u64, 0u64);
            for v in 0..he.num_vertices() {
                // Clockwise, as OpenMesh's default vv_iter walks.
                for w in he.vertex_vertices_cw(Vertex::new(v)) {
                    sum = sum.wrapping_add(w.0 as u64);
                    n += 1;
                }
            }
            neighbors = n;
            sum
        });
        r.one_ring_ns_per_neighbor = Some(ring_ms * 1e6 / neighbors.max(1) as f64);
        r.normals_ms = Some(best_ms(RUNS, || he.vertex_normals()));
        if he.is_triangle_mesh() {
            r.loop_ms = Some(best_ms(RUNS, || he.loop_subdivide()));
        }
    }
    if args.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!("file                   {}", args.file.display());
    println!("vertices               {}", r.vertices);
    println!("edges                  {}", r.edges);
    println!("faces                  {}", r.faces);
    println!("half-edges             {}", r.half_edges);
    println!("boundary loops         {}", r.boundary_loops);
    println!("components             {}", r.components);
    println!("Euler characteristic   {}", r.euler_characteristic);
    println!("genus                  {}", r.genus);
    println!("non-manifold edges     {}", r.non_manifold_edges);
    println!("non-manifold vertices  {}", r.non_manifold_vertices);
    if !report.is_clean() {
        println!(
            "repairs                {} inconsistent edges, {} repeated faces, {} faces naming a vertex twice; added {} vertices, {} edges (every face kept)",
            r.inconsistent_edges, r.repeated_faces, r.degenerate_faces, r.added_vertices, r.added_edges
        );
    }
    let b = &r.bytes_per_vertex;
    match (b.half_edge, b.winged_edge) {
        (Some(he), Some(we)) => println!(
            "bytes per vertex       half-edge {he:.1}, winged-edge {we:.1}, compact {}",
            b.compact
                .map_or("n/a (not all triangles)".to_string(), |c| format!("{c:.1}"))
        ),
        _ => println!("bytes per vertex       n/a (no vertices)"),
    }
    if let Some(ms) = &r.build_ms {
        println!(
            "build (best of 5)      half-edge {:.2} ms, winged-edge {:.2} ms, compact {}",
            ms.half_edge,
            ms.winged_edge,
            ms.compact
                .map_or("n/a".to_string(), |c| format!("{c:.2} ms"))
        );
        println!(
            "one-ring walk          {:.2} ns per neighbour",
            r.one_ring_ns_per_neighbor.unwrap_or(0.0)
        );
        println!(
            "vertex normals         {:.2} ms",
            r.normals_ms.unwrap_or(0.0)
        );
        if let Some(l) = r.loop_ms {
            println!("one Loop step          {l:.2} ms");
        }
    }
    Ok(())
}
