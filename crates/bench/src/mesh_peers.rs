//! `raymesh-mesh-peers MESH... [--threads LIST] [--repeat R] [--json]
//! [--markdown]`: raymesh's half-edge mesh against OpenMesh 9 (built with
//! `--features openmesh`) in one run, on the operations `raymesh mesh
//! --bench` times (building the connectivity from indexed triangles,
//! walking every vertex's one-ring, vertex normals, one Loop step), one
//! Catmull–Clark step (OpenMesh's on a polygon mesh), and the edits
//! OpenMesh users make, on a copy: every edge split at its midpoint,
//! flipped where a flip is allowed, collapsed where a collapse is allowed
//! (then the garbage collected), each over every edge of the mesh in one
//! order (the triangles', each edge named by its two vertices and looked
//! up by `find_halfedge`), and every face split in three at its centroid.
//! The two take turns: a pass of every operation for raymesh, then one
//! for OpenMesh, `--repeat` times; each reports its best. OpenMesh runs
//! on one thread; raymesh in a pool of each given size (the edits are
//! sequential in both). Each operation's results are compared (counts,
//! the one-ring's neighbours, the faces after Loop, the vertices and
//! faces after Catmull–Clark, and after each edit pass the live counts,
//! the number of edits made and a signature of every vertex's
//! neighbours), so that the two are seen to do the same work.

#[cfg(feature = "openmesh")]
mod openmesh_peer;
use raymesh_bench::thread_list;

use anyhow::{bail, Context, Result};
use clap::Parser;
use raymesh_geometry::Vec3;
use raymesh_mesh::handle::{Face, Vertex};
use raymesh_mesh::io::read_mesh;
use raymesh_mesh::{HalfEdgeMesh, IndexedMesh};
use serde::Serialize;
use std::collections::HashSet;
use std::path::PathBuf;
use std::time::Instant;

/// Mesh operations side by side with OpenMesh.
#[derive(Parser)]
struct Args {
    /// Mesh files (triangle meshes; polygons are fan-triangulated for
    /// OpenMesh's triangle mesh and raymesh alike).
    #[arg(required = true)]
    meshes: Vec<PathBuf>,
    /// raymesh's thread counts, comma-separated (OpenMesh uses one).
    #[arg(long, allow_negative_numbers = true, default_value = "1")]
    threads: String,
    /// Timed repeats of each operation; the best is reported.
    #[arg(long, allow_negative_numbers = true, default_value_t = 5)]
    repeat: u32,
    /// JSON lines instead of the text report.
    #[arg(long)]
    json: bool,
    /// A markdown table as well.
    #[arg(long)]
    markdown: bool,
}

/// One operation on one mesh.
#[derive(Serialize)]
struct Row {
    mesh: String,
    threads: usize,
    operation: &'static str,
    unit: &'static str,
    raymesh: f64,
    /// `None` where OpenMesh is not built in.
    openmesh: Option<f64>,
    /// OpenMesh's time over raymesh's: above 1 when raymesh is faster.
    speedup: Option<f64>,
    /// Whether both gave the same result (counts, neighbours, faces).
    agree: Option<bool>,
    /// Triangles OpenMesh refused to add (non-manifold ones; raymesh
    /// repairs them instead), on the build row.
    #[serde(skip_serializing_if = "Option::is_none")]
    refused: Option<usize>,
    /// Vertices raymesh added by splitting non-manifold ones (OpenMesh
    /// keeps such vertices as they are), on the build row.
    #[serde(skip_serializing_if = "Option::is_none")]
    split_vertices: Option<usize>,
    /// The edits raymesh made, on an edit row (splits, flips or
    /// collapses: as many as OpenMesh made where the row agrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    edits: Option<usize>,
}

/// An edit both libraries make over every edge of a mesh, on a copy
/// (the number is the shim's `kind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(i32)]
enum Edit {
    /// Split at the edge's midpoint: the triangles beside it become four.
    Split = 0,
    /// Flipped, where a flip is allowed (an interior edge whose far
    /// vertices are not joined yet).
    Flip = 1,
    /// The half-edge's start merged into its end where a collapse is
    /// allowed (the link condition and the boundary rules); then the
    /// deleted elements collected.
    Collapse = 2,
    /// Every face of the mesh as built (by index, not the edges' list)
    /// split in three at its centroid.
    SplitFace = 3,
}

/// The edits and their rows' names, in the order they run and report.
const EDITS: [(Edit, &str); 4] = [
    (Edit::Split, "split every edge at its midpoint"),
    (Edit::Flip, "flip every edge that may be"),
    (
        Edit::Collapse,
        "collapse every edge that may be, then collect",
    ),
    (Edit::SplitFace, "split every face at its centroid"),
];

/// What an edit pass left: a signature of the connectivity
/// ([`ring_signature`], taken before any garbage collection, so by the
/// vertices' indices then), the live vertex, edge and face counts, and
/// how many edits were made. `#[repr(C)]`: the OpenMesh shim fills its
/// `RmEdits`, the same fields, for its side.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Edits {
    ring: u64,
    vertices: usize,
    edges: usize,
    faces: usize,
    done: usize,
}

/// The mesh's edges as vertex pairs, each once, in the order and the
/// direction the triangles first give them (so each pair is a half-edge
/// of the mesh as built): the edits' work list, the same for both.
fn edge_pairs(mesh: &IndexedMesh) -> Vec<[u32; 2]> {
    let mut seen = HashSet::new();
    let mut pairs = Vec::new();
    for t in mesh.triangles() {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            if seen.insert((a.min(b), a.max(b))) {
                pairs.push([a, b]);
            }
        }
    }
    pairs
}

/// One pair of neighbours, `v` and `w`, mixed into a 64-bit word (the
/// shim's `mix`, the same arithmetic).
fn mix(v: u64, w: u64) -> u64 {
    ((v << 32) | w).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// The sum of [`mix`] over every live vertex and each of its neighbours:
/// the same for two meshes whose vertices of the same indices have the
/// same neighbours, whatever the order of their edges and faces.
fn ring_signature(he: &HalfEdgeMesh) -> u64 {
    let mut s = 0u64;
    for v in (0..he.num_vertices()).map(Vertex::new) {
        if he.is_deleted_vertex(v) {
            continue;
        }
        for w in he.vertex_vertices(v) {
            s = s.wrapping_add(mix(u64::from(v.0), u64::from(w.0)));
        }
    }
    s
}

/// raymesh's side of an edit pass, on a copy of `he` (not timed): the
/// seconds the edits took (and the garbage collection after collapses;
/// not the signature taken before it) and what they left.
fn edit(he: &HalfEdgeMesh, edit: Edit, pairs: &[[u32; 2]]) -> (f64, Edits) {
    let mut m = he.clone();
    let start = Instant::now();
    let mut done = 0;
    if edit == Edit::SplitFace {
        for f in (0..he.num_faces()).map(Face::new) {
            let mut c = Vec3::ZERO;
            for v in m.face_vertices(f) {
                c += m.position(v);
            }
            done += usize::from(m.split_face(f, c / 3.0).is_some());
        }
    } else {
        for &[a, b] in pairs {
            let (a, b) = (Vertex::new(a as usize), Vertex::new(b as usize));
            let Some(h) = m.find_halfedge(a, b) else {
                continue;
            };
            let made = match edit {
                Edit::Split => {
                    let p = (m.position(a) + m.position(b)) * 0.5;
                    m.split(h.edge(), p).is_some()
                }
                Edit::Flip => m.flip(h.edge()),
                Edit::Collapse => m.collapse(h),
                Edit::SplitFace => unreachable!("faces are split above"),
            };
            done += usize::from(made);
        }
    }
    let mut secs = start.elapsed().as_secs_f64();
    let ring = ring_signature(&m);
    if edit == Edit::Collapse {
        let start = Instant::now();
        m.garbage_collect();
        secs += start.elapsed().as_secs_f64();
    }
    let edits = Edits {
        ring,
        vertices: m.num_vertices(),
        edges: m.num_edges(),
        faces: m.num_faces(),
        done,
    };
    (secs, edits)
}

/// OpenMesh's side of a row, where it ran: its time, and whether its
/// result matched raymesh's.
type Other = Option<(f64, bool)>;

/// One run of `f`: the lesser of `best` and its time, in milliseconds,
/// and its result.
fn best_of<T>(best: f64, f: impl FnOnce() -> T) -> (f64, T) {
    let t = Instant::now();
    let r = std::hint::black_box(f());
    (best.min(t.elapsed().as_secs_f64() * 1e3), r)
}

/// raymesh's one-ring walk over every vertex, clockwise as OpenMesh's
/// `vv_range`: the sum of the neighbours' indices and their number.
fn one_ring(he: &HalfEdgeMesh) -> (u64, u64) {
    let (mut sum, mut n) = (0u64, 0u64);
    for v in 0..he.num_vertices() {
        for w in he.vertex_vertices_cw(Vertex::new(v)) {
            sum = sum.wrapping_add(w.0 as u64);
            n += 1;
        }
    }
    (sum, n)
}

/// What OpenMesh measured, where it is built in: per operation, its time
/// and whether its result matched raymesh's.
#[cfg(feature = "openmesh")]
struct OmRun {
    build_ms: f64,
    ring_ns: f64,
    normals_ms: f64,
    loop_ms: f64,
    cc_ms: f64,
    agree_build: bool,
    agree_ring: bool,
    agree_loop: bool,
    agree_cc: bool,
    refused: usize,
    /// Per edit of [`EDITS`]: its best time in milliseconds, and whether
    /// what it left matched raymesh's.
    edits: [(f64, bool); EDITS.len()],
}

fn short(p: &std::path::Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    )
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.repeat == 0 {
        bail!("--repeat must be at least 1");
    }
    let threads = thread_list::parse(&args.threads)?;
    let mut rows = Vec::new();
    for path in &args.meshes {
        let read = read_mesh(path)?;
        // Triangles for both: OpenMesh's `TriMesh` takes no polygons, and
        // raymesh's half-edge mesh would otherwise keep them.
        let mesh = IndexedMesh::from_triangles(read.positions.clone(), &read.triangles())
            .with_context(|| path.display().to_string())?;
        if !args.json {
            println!(
                "{}: {} vertices, {} triangles",
                path.display(),
                mesh.positions.len(),
                mesh.triangles().len()
            );
        }
        for &t in &threads {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .context("thread pool")?;
            rows.extend(pool.install(|| compare(&args, &mesh, short(path), t))?);
        }
    }
    if args.json {
        for r in &rows {
            println!("{}", serde_json::to_string(r)?);
        }
        return Ok(());
    }
    for r in &rows {
        let om = match r.openmesh {
            Some(o) => format!("{o:.3} {}", r.unit),
            None if cfg!(feature = "openmesh") => "has no such step".into(),
            None => "not built (--features openmesh)".into(),
        };
        let ratio = r
            .speedup
            .map_or(String::new(), |s| format!(", raymesh {s:.2}x"));
        let agree = match (r.agree, r.refused, r.split_vertices) {
            (Some(true), ..) => ", same result".to_string(),
            (Some(false), Some(k), _) if k > 0 => {
                format!(", results differ: OpenMesh refused {k} non-manifold triangles")
            }
            (Some(false), _, Some(k)) => {
                format!(", results differ: raymesh split non-manifold vertices ({k} added)")
            }
            (Some(false), ..) => ", RESULTS DIFFER".to_string(),
            (None, ..) => String::new(),
        };
        let made = r.edits.map_or(String::new(), |k| format!(" ({k} edits)"));
        println!(
            "  {:<2} thr {:<45} raymesh {:.3} {}{made} | openmesh {om}{ratio}{agree}",
            r.threads, r.operation, r.raymesh, r.unit
        );
    }
    if args.markdown {
        println!();
        println!("| mesh | threads | operation | raymesh | OpenMesh | raymesh speedup |");
        println!("| --- | --- | --- | --- | --- | --- |");
        for r in &rows {
            println!(
                "| {} | {} | {} | {:.3} {} | {} | {} |",
                r.mesh,
                r.threads,
                r.operation,
                r.raymesh,
                r.unit,
                r.openmesh
                    .map_or("-".into(), |o| format!("{o:.3} {}", r.unit)),
                r.speedup.map_or("-".into(), |s| format!("{s:.2}")),
            );
        }
    }
    Ok(())
}

/// Both libraries on one mesh, raymesh in the current pool.
fn compare(args: &Args, mesh: &IndexedMesh, name: String, threads: usize) -> Result<Vec<Row>> {
    // One pass of each operation for raymesh, then one for OpenMesh, R
    // times: the best of each.
    let mut he = HalfEdgeMesh::from_indexed(mesh);
    let [mut build_ms, mut ring_ms, mut normals_ms, mut loop_ms, mut loop_he_ms, mut cc_ms] =
        [f64::INFINITY; 6];
    let mut cc_counts = (0, 0);
    let (mut ring_sum, mut ring_n, mut sub) = (0, 0, None);
    let pairs = edge_pairs(mesh);
    let mut edit_ms = [f64::INFINITY; EDITS.len()];
    let mut edits = [Edits::default(); EDITS.len()];
    #[cfg(feature = "openmesh")]
    let mut om_turns = OmTurns::new(mesh);
    for _ in 0..args.repeat {
        (build_ms, he) = best_of(build_ms, || HalfEdgeMesh::from_indexed(mesh));
        (ring_ms, (ring_sum, ring_n)) = best_of(ring_ms, || one_ring(&he));
        normals_ms = best_of(normals_ms, || he.vertex_normals()).0;
        (loop_ms, sub) = best_of(loop_ms, || he.loop_subdivide());
        loop_he_ms = best_of(loop_he_ms, || he.loop_subdivided()).0;
        let cc;
        (cc_ms, cc) = best_of(cc_ms, || he.catmull_clark_subdivided());
        cc_counts = (cc.num_vertices(), cc.num_faces());
        for (i, &(e, _)) in EDITS.iter().enumerate() {
            let (secs, left) = edit(&he, e, &pairs);
            edit_ms[i] = edit_ms[i].min(secs * 1e3);
            edits[i] = left;
        }
        #[cfg(feature = "openmesh")]
        om_turns.pass(mesh, &pairs);
    }
    let ring_ns = ring_ms * 1e6 / ring_n.max(1) as f64;
    let sub_faces = sub.as_ref().map(|m| m.triangles().len());
    #[cfg(feature = "openmesh")]
    let om = Some(om_turns.finish(&he, (ring_sum, ring_n), sub_faces, cc_counts, &edits));
    #[cfg(not(feature = "openmesh"))]
    let om: Option<()> = {
        let _ = (ring_sum, sub_faces, edits, cc_counts);
        None
    };
    let row = |operation, unit, raymesh: f64, other: Other| Row {
        mesh: name.clone(),
        threads,
        operation,
        unit,
        raymesh,
        openmesh: other.map(|o| o.0),
        speedup: other.map(|o| o.0 / raymesh.max(1e-9)),
        agree: other.map(|o| o.1),
        refused: None,
        split_vertices: None,
        edits: None,
    };
    #[cfg(feature = "openmesh")]
    let (b, r, nm, l, cc, ed) = match &om {
        Some(o) => (
            Some((o.build_ms, o.agree_build)),
            Some((o.ring_ns, o.agree_ring)),
            Some((o.normals_ms, true)),
            Some((o.loop_ms, o.agree_loop)),
            Some((o.cc_ms, o.agree_cc)),
            o.edits.map(Some),
        ),
        None => (None, None, None, None, None, [None; EDITS.len()]),
    };
    #[cfg(not(feature = "openmesh"))]
    let (b, r, nm, l, cc, ed): (Other, Other, Other, Other, Other, [Other; EDITS.len()]) = {
        let _ = om;
        (None, None, None, None, None, [None; EDITS.len()])
    };
    // Where the two meshes differ (OpenMesh refused triangles, or raymesh
    // split vertices), so do the one-rings; the rows say why.
    let split = (he.num_vertices() > mesh.positions.len())
        .then(|| he.num_vertices() - mesh.positions.len());
    let mut rows = vec![
        Row {
            refused: refused(&om),
            split_vertices: split,
            ..row("build from indexed triangles", "ms", build_ms, b)
        },
        Row {
            refused: refused(&om),
            split_vertices: split,
            ..row("one-ring walk, per neighbour", "ns", ring_ns, r)
        },
        // Weighted otherwise (raymesh by corner angles, OpenMesh's
        // `update_normals` its faces' unit normals alike): no comparison.
        Row {
            agree: None,
            ..row("vertex normals", "ms", normals_ms, nm)
        },
    ];
    if sub.is_some() {
        rows.push(row(
            "one Loop step, to an indexed mesh",
            "ms",
            loop_ms,
            None,
        ));
        rows.push(row(
            "one Loop step, with its connectivity",
            "ms",
            loop_he_ms,
            l,
        ));
    }
    rows.push(Row {
        refused: refused(&om),
        split_vertices: split,
        ..row(
            "one Catmull-Clark step, with its connectivity",
            "ms",
            cc_ms,
            cc,
        )
    });
    for (i, &(_, name)) in EDITS.iter().enumerate() {
        rows.push(Row {
            refused: refused(&om),
            split_vertices: split,
            edits: Some(edits[i].done),
            ..row(name, "ms", edit_ms[i], ed[i])
        });
    }
    Ok(rows)
}

/// The triangles OpenMesh refused, where it ran.
#[cfg(feature = "openmesh")]
fn refused(om: &Option<OmRun>) -> Option<usize> {
    om.as_ref().map(|o| o.refused)
}

#[cfg(not(feature = "openmesh"))]
fn refused(_: &Option<()>) -> Option<usize> {
    None
}

/// OpenMesh's turns on a mesh: its mesh, its best times so far, and
/// its last results.
#[cfg(feature = "openmesh")]
struct OmTurns {
    om: openmesh_peer::OmMesh,
    times: [f64; 5],
    ring: (u64, u64),
    loop_faces: usize,
    /// Vertices and faces after its Catmull–Clark step.
    cc: (usize, usize),
    /// Per edit of [`EDITS`]: the best time in milliseconds and what the
    /// last pass left.
    edits: [(f64, Edits); EDITS.len()],
}

#[cfg(feature = "openmesh")]
impl OmTurns {
    fn new(mesh: &IndexedMesh) -> Self {
        Self {
            om: openmesh_peer::OmMesh::build(mesh),
            times: [f64::INFINITY; 5],
            ring: (0, 0),
            loop_faces: 0,
            cc: (0, 0),
            edits: [(f64::INFINITY, Edits::default()); EDITS.len()],
        }
    }

    /// One run of each operation.
    fn pass(&mut self, mesh: &IndexedMesh, pairs: &[[u32; 2]]) {
        let [build, ring, normals, step, cc] = &mut self.times;
        (*build, self.om) = best_of(*build, || openmesh_peer::OmMesh::build(mesh));
        (*ring, self.ring) = best_of(*ring, || self.om.one_ring());
        *normals = best_of(*normals, || self.om.normals()).0;
        let (s, faces) = self.om.loop_step();
        *step = step.min(s * 1e3);
        self.loop_faces = faces;
        let (s, vertices, faces) = openmesh_peer::catmull_clark(mesh);
        *cc = cc.min(s * 1e3);
        self.cc = (vertices, faces);
        for (i, &(e, _)) in EDITS.iter().enumerate() {
            let (secs, left) = self.om.edit(e, pairs);
            self.edits[i] = (self.edits[i].0.min(secs * 1e3), left);
        }
    }

    /// Its times, and whether each result matches raymesh's (`ring`:
    /// raymesh's one-ring sum and count; `faces`: its triangles after a
    /// Loop step; `cc`: its vertices and faces after a Catmull–Clark
    /// step; `edits`: what its edit passes left).
    fn finish(
        self,
        he: &HalfEdgeMesh,
        ring: (u64, u64),
        faces: Option<usize>,
        cc: (usize, usize),
        edits: &[Edits; EDITS.len()],
    ) -> OmRun {
        let (v, e, f) = self.om.counts();
        let [build_ms, ring_ms, normals_ms, loop_ms, cc_ms] = self.times;
        OmRun {
            build_ms,
            ring_ns: ring_ms * 1e6 / self.ring.1.max(1) as f64,
            normals_ms,
            loop_ms,
            cc_ms,
            agree_build: self.om.refused == 0
                && (v, e, f) == (he.num_vertices(), he.num_edges(), he.num_faces()),
            agree_ring: self.ring == ring,
            agree_loop: faces == Some(self.loop_faces),
            agree_cc: cc == self.cc,
            refused: self.om.refused,
            edits: std::array::from_fn(|i| (self.edits[i].0, self.edits[i].1 == edits[i])),
        }
    }
}
