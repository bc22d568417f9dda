//! The engines a benchmark run compares, behind one small interface:
//! raymesh itself, and the Rust crates obvhs, bvh and parry3d as their
//! users would call them (Embree lives in `embree_peer`, behind a feature).
//!
//! Every engine gets the mesh as indexed triangles and BENCH.md's packed
//! rays `[ox, oy, oz, tmin, dx, dy, dz, tmax]`, converts them to its own
//! types before the clock starts, and answers closest-hit queries with
//! `(t, triangle index in the input)` and any-hit queries with a flag.

use raymesh_accel::{AccelKind, BuildConfig, Rays8, Scene, Surface, TriangleMesh, Triangles};
use raymesh_geometry::Vec3;
use rayon::prelude::*;
use rayon::ThreadPool;
use std::time::Instant;

/// One query's answer: the closest hit's `t` and triangle, or for any-hit
/// queries `(0, 0)` when something was hit.
pub type Answer = Option<(f32, u32)>;

/// Runs timed passes over a ray set on a fixed thread pool.
pub struct Runner<'a> {
    /// The pool every pass runs on.
    pub pool: &'a ThreadPool,
    /// Passes; the best is reported.
    pub repeat: u32,
    /// Eight consecutive rays at a time, for the engines that trace
    /// packets (raymesh's `Scene::intersect8_soa_bare` and
    /// `Scene::occluded8_soa`, given the rays as rows, Embree's
    /// `rtcIntersect8` and `rtcOccluded8`); the others trace one ray at a
    /// time regardless.
    pub packets: bool,
    /// Traces each task's rays as one stream, for the engines with a
    /// stream call (raymesh's `Scene::intersect_stream`, Embree's
    /// `rtcIntersect1M`); the others trace one ray at a time regardless.
    pub stream: bool,
}

impl Runner<'_> {
    /// Best time of `repeat` timed passes of `pass` on the pool, in
    /// seconds, and the last pass's answers: what every `run` shares.
    fn best_of(&self, pass: impl Fn() -> Vec<Answer> + Sync) -> (f64, Vec<Answer>) {
        let mut best = f64::INFINITY;
        let mut out = Vec::new();
        for _ in 0..self.repeat.max(1) {
            let start = Instant::now();
            out = self.pool.install(&pass);
            best = best.min(start.elapsed().as_secs_f64());
        }
        (best, out)
    }

    /// [`Self::run`] with each task's rays (1,024, the last fewer) given
    /// to `chunk` together, answers in the rays' order.
    pub fn run_chunks<R: Sync>(
        &self,
        rays: &[R],
        chunk: impl Fn(&[R], &mut [Answer]) + Sync,
    ) -> (f64, Vec<Answer>) {
        self.best_of(|| {
            let mut out: Vec<Answer> = vec![None; rays.len()];
            out.par_chunks_mut(1024)
                .zip(rays.par_chunks(1024))
                .for_each(|(out, rays)| chunk(rays, out));
            out
        })
    }

    /// [`Self::run`] with each eight consecutive rays given to `eight`
    /// together (the last few, if the count is not a multiple of eight, to
    /// `one`), answers in the rays' order; tasks take 1,024 rays at least.
    pub fn run8<R: Sync>(
        &self,
        rays: &[R],
        eight: impl Fn(&[R; 8]) -> [Answer; 8] + Sync,
        one: impl Fn(&R) -> Answer + Sync,
    ) -> (f64, Vec<Answer>) {
        self.best_of(|| {
            let mut out: Vec<Answer> = vec![None; rays.len()];
            out.par_chunks_mut(8)
                .zip(rays.par_chunks(8))
                .with_min_len(128)
                .for_each(|(out, c)| match <&[R; 8]>::try_from(c) {
                    Ok(p) => out.copy_from_slice(&eight(p)),
                    Err(_) => {
                        for (o, r) in out.iter_mut().zip(c) {
                            *o = one(r);
                        }
                    }
                });
            out
        })
    }

    /// Best time of `repeat` passes of `f` over every ray (1,024-ray
    /// chunks on the pool), in seconds, and the last pass's answers.
    pub fn run<R: Sync>(&self, rays: &[R], f: impl Fn(&R) -> Answer + Sync) -> (f64, Vec<Answer>) {
        self.best_of(|| rays.par_iter().with_min_len(1024).map(&f).collect())
    }
}

/// What a tree costs a random ray that meets its root box, by the SAH's
/// area ratios: `sah` in raymesh's units (`AccelStats::sah_cost`: every
/// triangle of a leaf one test), and the node and leaf tests expected
/// (`AccelStats::node_tests`, `leaf_tests`), each leaf counted in the
/// engine's own blocks: raymesh's of 8 triangles, Embree's of 4. Their
/// sum is the cost Embree's builder minimizes (unit costs, leaves in
/// blocks), and compares trees whose leaves are tested in blocks of
/// different widths, which `sah` does not.
#[derive(Clone, Copy, Debug)]
pub struct TreeCost {
    /// The SAH cost, every primitive one test.
    pub sah: f64,
    /// Expected node tests.
    pub node_tests: f64,
    /// Expected leaf tests, in the engine's blocks.
    pub leaf_tests: f64,
}

/// A ray-tracing engine built over one mesh.
pub trait Engine: Send + Sync {
    /// Short name for tables.
    fn name(&self) -> &'static str;
    /// The raymesh structure it traces, for raymesh's engines.
    fn accel(&self) -> Option<AccelKind> {
        None
    }
    /// Milliseconds its build took, from indexed triangles to a structure
    /// ready to trace (its own copies of the triangles included).
    fn build_ms(&self) -> f64;
    /// Bytes its structure holds (triangle copies included, the caller's
    /// mesh apart), where the engine tells.
    fn bytes(&self) -> Option<usize>;
    /// What its tree costs a random ray, where it can be had: the SAH in
    /// raymesh's units and the expected node and leaf tests.
    fn tree_cost(&self) -> Option<TreeCost> {
        None
    }
    /// Traces every ray for the closest hit (`any == false`) or any hit.
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>);
}

/// Which engines to run, by name.
pub const RUST_PEERS: [&str; 3] = ["obvhs", "bvh", "parry3d"];

/// Engines run only when named (`--peers raymesh-ray`), not by `all`:
/// raymesh itself through another entry point, for a side-by-side
/// measure of the entry points in one run.
pub const OPT_IN_PEERS: [&str; 1] = ["raymesh-ray"];

/// The engine that runs raymesh over structure `kind` beside the one
/// named `raymesh` (`raymesh-peers --accel bvh8,grid`: `raymesh-grid`).
#[must_use]
pub fn structure_engine(kind: AccelKind) -> &'static str {
    match kind {
        AccelKind::Brute => "raymesh-brute",
        AccelKind::Aabb => "raymesh-aabb",
        AccelKind::BvhMedian => "raymesh-bvh-median",
        AccelKind::BvhBinned => "raymesh-bvh-binned",
        AccelKind::BvhSweep => "raymesh-bvh-sweep",
        AccelKind::Bvh4 => "raymesh-bvh4",
        AccelKind::Bvh8 => "raymesh-bvh8",
        AccelKind::Grid => "raymesh-grid",
        AccelKind::KdTree => "raymesh-kdtree",
    }
}

/// The structure of a [`structure_engine`]'s name, if `name` is one.
#[must_use]
pub fn structure_of(name: &str) -> Option<AccelKind> {
    AccelKind::ALL
        .into_iter()
        .find(|&k| structure_engine(k) == name)
}

/// Builds the named engine over the mesh on the current thread pool
/// (callers `install` the pool whose thread count they measure):
/// `raymesh` and `raymesh-ray` over structure `accel`, a
/// [`structure_engine`] over its own.
pub fn build(
    name: &str,
    accel: AccelKind,
    config: &BuildConfig,
    positions: &[Vec3],
    triangles: &[[u32; 3]],
) -> Box<dyn Engine> {
    if let Some(kind) = structure_of(name) {
        let mut engine = Raymesh::new(kind, config, positions, triangles);
        engine.name = structure_engine(kind);
        return Box::new(engine);
    }
    match name {
        "raymesh" => Box::new(Raymesh::new(accel, config, positions, triangles)),
        "raymesh-ray" => Box::new(RaymeshRay(Raymesh::new(
            accel, config, positions, triangles,
        ))),
        "obvhs" => Box::new(Obvhs::new(positions, triangles)),
        "bvh" => Box::new(BvhCrate::new(positions, triangles)),
        "parry3d" => Box::new(Parry::new(positions, triangles)),
        other => unreachable!("unknown engine {other}"),
    }
}

/// raymesh with each ray made by the caller: `Ray::new` from the row
/// (`raymesh::workload::unpack_ray`, a call), then the `&Ray` queries
/// (`Scene::intersect_bare`, `occluded`), one ray at a time, as
/// `raymesh-peers` called raymesh before stop 74. Beside `raymesh` (the
/// row queries, the ray made inside the walk's SIMD region) it measures
/// what the entry point costs, in the same run.
pub struct RaymeshRay(Raymesh);

impl Engine for RaymeshRay {
    fn name(&self) -> &'static str {
        "raymesh-ray"
    }
    fn accel(&self) -> Option<AccelKind> {
        self.0.accel()
    }
    fn build_ms(&self) -> f64 {
        self.0.build_ms()
    }
    fn bytes(&self) -> Option<usize> {
        self.0.bytes()
    }
    fn tree_cost(&self) -> Option<TreeCost> {
        self.0.tree_cost()
    }
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>) {
        let ray = |r: &[f32; 8]| raymesh::workload::unpack_ray(*r);
        if any {
            run.run(rays, |r| self.0.scene.occluded(&ray(r)).then_some((0.0, 0)))
        } else {
            run.run(rays, |r| {
                self.0.scene.intersect_bare(&ray(r)).map(|h| (h.t, h.prim))
            })
        }
    }
}

/// raymesh's scene over its fastest layout for the chosen structure.
pub struct Raymesh {
    scene: Scene<Triangles>,
    build_ms: f64,
    /// `raymesh`, or the [`structure_engine`] it runs as.
    name: &'static str,
    accel: AccelKind,
}

impl Raymesh {
    fn new(
        accel: AccelKind,
        config: &BuildConfig,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
    ) -> Self {
        // The mesh in raymesh's type stands for the caller's (which Embree
        // shares); making it is not part of the build. Gathering the
        // triangle rows is.
        let tm = TriangleMesh::new(positions.to_vec(), triangles.to_vec());
        let start = Instant::now();
        let scene = Scene::from_mesh_with(&tm, accel, config);
        Self {
            scene,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
            name: "raymesh",
            accel,
        }
    }
}

impl Engine for Raymesh {
    fn name(&self) -> &'static str {
        self.name
    }
    fn accel(&self) -> Option<AccelKind> {
        Some(self.accel)
    }
    fn build_ms(&self) -> f64 {
        self.build_ms
    }
    fn bytes(&self) -> Option<usize> {
        // The structure plus its triangle rows, as `raymesh raycast` counts.
        Some(self.scene.stats().bytes + self.scene.prims().bytes())
    }
    fn tree_cost(&self) -> Option<TreeCost> {
        let s = self.scene.stats();
        Some(TreeCost {
            sah: s.sah_cost,
            node_tests: s.node_tests?,
            leaf_tests: s.leaf_tests?,
        })
    }
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>) {
        // Each engine makes its rays inside the timed pass, as Embree must
        // (its per-ray set-up happens inside its calls): `Ray::new`'s
        // reciprocal and shear are part of what a query costs.
        //
        // The closest hits come from the queries without the normal
        // (`intersect_bare` and its packet and stream forms): the cheapest
        // that answer what the harness asks of every engine, `t` and the
        // triangle. Embree has no such query; its `rtcIntersect1` returns
        // the normal it stores for each triangle as well.
        let ray = |r: &[f32; 8]| raymesh::workload::unpack_ray(*r);
        let hit = |h: Option<raymesh_accel::BareHit>| h.map(|h| (h.t, h.prim));
        // Packets go in as rows (`Rays8`), as Embree's go in as its
        // `RTCRay8`: the rays' constants made for the eight at once.
        if run.packets && any {
            return run.run8(
                rays,
                |p| {
                    let o = self.scene.occluded8_soa(&Rays8::from_rows(p));
                    o.map(|o| o.then_some((0.0, 0)))
                },
                |r| self.scene.occluded(&ray(r)).then_some((0.0, 0)),
            );
        }
        if run.packets {
            return run.run8(
                rays,
                |p| {
                    self.scene
                        .intersect8_soa_bare(&Rays8::from_rows(p))
                        .map(hit)
                },
                |r| hit(self.scene.intersect_bare(&ray(r))),
            );
        }
        if run.stream && any {
            // Occlusion, as Embree's `rtcOccluded1M` answers it.
            return run.run_chunks(rays, |rays, out| {
                let rays: Vec<_> = rays.iter().map(raymesh::workload::row_ray).collect();
                let mut occluded = vec![false; rays.len()];
                self.scene.occluded_stream(&rays, &mut occluded);
                for (o, hit) in out.iter_mut().zip(occluded) {
                    *o = hit.then_some((0.0, 0));
                }
            });
        }
        if run.stream {
            return run.run_chunks(rays, |rays, out| {
                // Made in place (`row_ray`, inlined): the one-ray closures keep
                // `unpack_ray`'s call, 1-3% faster there than inlined.
                let rays: Vec<_> = rays.iter().map(raymesh::workload::row_ray).collect();
                let mut hits = vec![None; rays.len()];
                self.scene.stream_bare(&rays, false, &mut hits);
                for (o, h) in out.iter_mut().zip(hits) {
                    *o = h.map(|h| (h.t, h.prim));
                }
            });
        }
        // One ray at a time, each row handed over as it lies, as Embree's
        // `RTCRay` is: the ray is made inside the query
        // (`Scene::occluded_row`, `intersect_bare_row`), where the walk's
        // SIMD region computes its constants.
        if any {
            run.run(rays, |r| self.scene.occluded_row(r).then_some((0.0, 0)))
        } else {
            run.run(rays, |r| hit(self.scene.intersect_bare_row(r)))
        }
    }
}

/// obvhs's compressed 8-wide BVH (Ylitie et al. 2017), built from its
/// PLOC builder at its "medium" preset, over its own triangles in leaf
/// order (as its examples recommend), tested with its Möller–Trumbore.
pub struct Obvhs {
    bvh: obvhs::cwbvh::CwBvh,
    tris: Vec<obvhs::triangle::Triangle>,
    build_ms: f64,
}

impl Obvhs {
    fn new(positions: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        use glam::Vec3A;
        let start = Instant::now();
        let p = |i: u32| Vec3A::from_array(positions[i as usize].to_array());
        let tris: Vec<obvhs::triangle::Triangle> = triangles
            .iter()
            .map(|&[a, b, c]| obvhs::triangle::Triangle {
                v0: p(a),
                v1: p(b),
                v2: p(c),
            })
            .collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &tris,
            obvhs::BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| tris[i as usize])
            .collect();
        Self {
            bvh,
            tris,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }
}

impl Engine for Obvhs {
    fn name(&self) -> &'static str {
        "obvhs"
    }
    fn build_ms(&self) -> f64 {
        self.build_ms
    }
    fn bytes(&self) -> Option<usize> {
        Some(
            std::mem::size_of_val(self.bvh.nodes.as_slice())
                + std::mem::size_of_val(self.bvh.primitive_indices.as_slice())
                + std::mem::size_of_val(self.tris.as_slice()),
        )
    }
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>) {
        use glam::Vec3A;
        let ray = |r: &[f32; 8]| {
            obvhs::ray::Ray::new(
                Vec3A::new(r[0], r[1], r[2]),
                Vec3A::new(r[4], r[5], r[6]),
                r[3],
                r[7],
            )
        };
        if any {
            run.run(rays, |r| {
                let miss = self
                    .bvh
                    .ray_traverse_miss(ray(r), |ray, id| self.tris[id].intersect(ray));
                (!miss).then_some((0.0, 0))
            })
        } else {
            run.run(rays, |r| {
                let mut hit = obvhs::ray::RayHit::none();
                self.bvh
                    .ray_traverse(ray(r), &mut hit, |ray, id| self.tris[id].intersect(ray))
                    .then(|| {
                        let prim = self.bvh.primitive_indices[hit.primitive_id as usize];
                        (hit.t, prim)
                    })
            })
        }
    }
}

/// A triangle for the `bvh` crate, which wants nalgebra points and a node
/// index slot per shape.
struct BvhTri {
    p: [nalgebra::Point3<f32>; 3],
    /// The triangle's index in the input.
    id: u32,
    node: usize,
}

impl bvh::aabb::Bounded<f32, 3> for BvhTri {
    fn aabb(&self) -> bvh::aabb::Aabb<f32, 3> {
        bvh::aabb::Aabb::empty()
            .grow(&self.p[0])
            .grow(&self.p[1])
            .grow(&self.p[2])
    }
}

impl bvh::bounding_hierarchy::BHShape<f32, 3> for BvhTri {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node = index;
    }
    fn bh_node_index(&self) -> usize {
        self.node
    }
}

/// Two-sided Möller–Trumbore (1997): the `bvh` crate's own triangle test
/// culls back faces, which would make its closest hits differ from every
/// other engine's, so its structure is measured with this one.
pub fn moller_trumbore(
    o: Vec3,
    d: Vec3,
    p: &[nalgebra::Point3<f32>; 3],
    tmin: f32,
    tmax: f32,
) -> f32 {
    let v = |q: &nalgebra::Point3<f32>| Vec3::new(q.x, q.y, q.z);
    let (a, b, c) = (v(&p[0]), v(&p[1]), v(&p[2]));
    let (e1, e2) = (b - a, c - a);
    let pv = d.cross(e2);
    let det = e1.dot(pv);
    if det == 0.0 || !det.is_finite() {
        return f32::INFINITY;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(pv) * inv;
    if !(0.0..=1.0).contains(&u) {
        return f32::INFINITY;
    }
    let q = s.cross(e1);
    let w = d.dot(q) * inv;
    if !(w >= 0.0 && u + w <= 1.0) {
        return f32::INFINITY;
    }
    let t = e2.dot(q) * inv;
    if t >= tmin && t <= tmax {
        t
    } else {
        f32::INFINITY
    }
}

/// The `bvh` crate's binary SAH BVH (built in parallel with its rayon
/// executor on more than one thread), traversed nearest box first with its
/// distance iterator for closest hits and with its plain iterator for any
/// hit.
pub struct BvhCrate {
    bvh: bvh::bvh::Bvh<f32, 3>,
    shapes: Vec<BvhTri>,
    build_ms: f64,
}

impl BvhCrate {
    fn new(positions: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let start = Instant::now();
        let p = |i: u32| {
            let q = positions[i as usize];
            nalgebra::Point3::new(q.x, q.y, q.z)
        };
        let mut shapes: Vec<BvhTri> = triangles
            .iter()
            .zip(0..)
            .map(|(&[a, b, c], id)| BvhTri {
                p: [p(a), p(b), p(c)],
                id,
                node: 0,
            })
            .collect();
        let bvh = if rayon::current_num_threads() > 1 {
            bvh::bvh::Bvh::build_with_executor(&mut shapes, bvh::bvh::rayon_executor)
        } else {
            bvh::bvh::Bvh::build(&mut shapes)
        };
        Self {
            bvh,
            shapes,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }

    fn ray(r: &[f32; 8]) -> bvh::ray::Ray<f32, 3> {
        // The crate's rays start at t = 0: move the origin to tmin.
        let o = nalgebra::Point3::new(r[0], r[1], r[2]);
        let d = nalgebra::Vector3::new(r[4], r[5], r[6]);
        bvh::ray::Ray::new(o + d * r[3], d)
    }
}

impl Engine for BvhCrate {
    fn name(&self) -> &'static str {
        "bvh"
    }
    fn build_ms(&self) -> f64 {
        self.build_ms
    }
    fn bytes(&self) -> Option<usize> {
        Some(
            std::mem::size_of_val(self.bvh.nodes.as_slice())
                + std::mem::size_of_val(self.shapes.as_slice()),
        )
    }
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>) {
        let make = |r: &[f32; 8]| (Self::ray(r), r[3], r[7]);
        let test = |ray: &bvh::ray::Ray<f32, 3>, tri: &BvhTri, tmax: f32| {
            let o = Vec3::new(ray.origin.x, ray.origin.y, ray.origin.z);
            let d = Vec3::new(ray.direction.x, ray.direction.y, ray.direction.z);
            moller_trumbore(o, d, &tri.p, 0.0, tmax)
        };
        if any {
            run.run(rays, |r| {
                let (ray, tmin, tmax) = &make(r);
                let limit = tmax - tmin;
                self.bvh
                    .traverse_iterator(ray, &self.shapes)
                    .any(|tri| test(ray, tri, limit).is_finite())
                    .then_some((0.0, 0))
            })
        } else {
            use bvh::aabb::Bounded;
            run.run(rays, |r| {
                let (ray, tmin, tmax) = &make(r);
                let mut best = tmax - tmin;
                let mut hit = None;
                for tri in self.bvh.nearest_traverse_iterator(ray, &self.shapes) {
                    // Boxes come nearest first: stop at one beyond the hit.
                    match ray.intersection_slice_for_aabb(&tri.aabb()) {
                        Some((entry, _)) if entry > best => break,
                        _ => {}
                    }
                    let t = test(ray, tri, best);
                    if t.is_finite() && (hit.is_none() || t < best) {
                        best = t;
                        hit = Some(tri.id);
                    }
                }
                hit.map(|p| (best + tmin, p))
            })
        }
    }
}

/// parry3d's triangle mesh and its BVH, queried with its own ray casts.
pub struct Parry {
    mesh: parry3d::shape::TriMesh,
    build_ms: f64,
}

impl Parry {
    fn new(positions: &[Vec3], triangles: &[[u32; 3]]) -> Self {
        let start = Instant::now();
        let vertices = positions
            .iter()
            .map(|p| parry3d::math::Vector::new(p.x, p.y, p.z))
            .collect();
        let mesh = parry3d::shape::TriMesh::new(vertices, triangles.to_vec())
            .expect("parry3d accepts the mesh");
        Self {
            mesh,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }
}

impl Engine for Parry {
    fn name(&self) -> &'static str {
        "parry3d"
    }
    fn build_ms(&self) -> f64 {
        self.build_ms
    }
    fn bytes(&self) -> Option<usize> {
        None
    }
    fn trace(&self, rays: &[[f32; 8]], any: bool, run: &Runner) -> (f64, Vec<Answer>) {
        use parry3d::query::{Ray, RayCast};
        use parry3d::shape::CompositeShapeRef;
        // parry's rays start at t = 0: move the origin to tmin.
        let make = |r: &[f32; 8]| {
            let d = parry3d::math::Vector::new(r[4], r[5], r[6]);
            let o = parry3d::math::Vector::new(r[0], r[1], r[2]) + d * r[3];
            (Ray::new(o, d), r[3], r[7])
        };
        if any {
            run.run(rays, |r| {
                let (ray, tmin, tmax) = &make(r);
                self.mesh
                    .intersects_local_ray(ray, tmax - tmin)
                    .then_some((0.0, 0))
            })
        } else {
            run.run(rays, |r| {
                let (ray, tmin, tmax) = &make(r);
                CompositeShapeRef(&self.mesh)
                    .cast_local_ray(ray, tmax - tmin, true)
                    .map(|(prim, t)| (t + tmin, prim))
            })
        }
    }
}
