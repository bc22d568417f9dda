//! Two levels: a top structure over instances, each an object (with its own
//! bottom structure) placed by an affine transform, so one mesh is stored
//! once and drawn many times.

use crate::{
    Accel, AccelKind, AccelStats, BuildConfig, CountStats, Hit, NoStats, RayCounter, Surface, LANES,
};
use raymesh_geometry::{Aabb, Mat3, Mat4, Ray, Vec3};

/// Most instances a scene may have for [`Surface::intersect8`] to trace
/// packets through it (its lanes list the instances their rays enter,
/// with no culling by the best hit; more instances trace ray by ray), and
/// for [`Surface::intersect_stream`] and [`Surface::occluded_stream`] to
/// trace streams through it (each ray lists its instances the same way).
pub const PACKET_INSTANCES: usize = 64;

/// One placement of an object.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index of the object in [`Instances::objects`].
    pub object: u32,
    /// Object-to-world transform (affine).
    pub transform: Mat4,
}

#[derive(Clone, Debug)]
struct Placed {
    object: u32,
    world_to_object: Mat4,
    normal_matrix: Mat3,
    /// Whether the transform is the identity: then the world ray is the
    /// object ray, and carrying it over costs no new [`Ray`] (whose
    /// reciprocal and shear take six divisions).
    identity: bool,
}

/// Instances of objects under a top-level structure.
///
/// A ray is carried into object space with the inverse transform without
/// normalizing its direction, so `t` means the same in both spaces. The
/// closest hit is the least `(t, instance, prim)`.
pub struct Instances<S> {
    objects: Vec<S>,
    placed: Vec<Placed>,
    top: Accel,
    bounds: Aabb,
}

impl<S: Surface> Instances<S> {
    /// Builds the top structure of `kind` over the instances' world boxes.
    /// Instances with a singular transform or an unknown object are skipped
    /// with an error naming them.
    pub fn build(objects: Vec<S>, instances: &[Instance], kind: AccelKind) -> Result<Self, String> {
        let mut placed = Vec::with_capacity(instances.len());
        let mut boxes = Vec::with_capacity(instances.len());
        for (k, inst) in instances.iter().enumerate() {
            let obj = objects
                .get(inst.object as usize)
                .ok_or_else(|| format!("instance {k}: no object {}", inst.object))?;
            let m = inst.transform;
            let det = m.determinant();
            if !(det.is_finite() && det != 0.0) {
                return Err(format!("instance {k}: transform is singular or not finite"));
            }
            let inv = m.inverse();
            boxes.push(transform_box(&m, obj.bounds()));
            placed.push(Placed {
                object: inst.object,
                world_to_object: inv,
                normal_matrix: Mat3::from_mat4(inv).transpose(),
                identity: m == Mat4::IDENTITY,
            });
        }
        let top = Accel::build(kind, &boxes, &BuildConfig::default());
        let bounds = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        Ok(Self {
            objects,
            placed,
            top,
            bounds,
        })
    }

    /// The objects.
    #[must_use]
    pub fn objects(&self) -> &[S] {
        &self.objects
    }

    /// Figures of the top structure.
    #[must_use]
    pub fn top_stats(&self) -> AccelStats {
        self.top.stats()
    }

    /// The object instance `k` places.
    #[must_use]
    pub fn object_of(&self, k: u32) -> u32 {
        self.placed[k as usize].object
    }

    /// Carries an object-space normal of instance `k` to world space (unit length).
    #[must_use]
    pub fn normal_to_world(&self, k: u32, n: Vec3) -> Vec3 {
        (self.placed[k as usize].normal_matrix * n).normalize_or_zero()
    }

    /// Closest hit, counting the work of both levels.
    pub fn intersect_counted(&self, ray: &Ray, stats: &mut CountStats) -> Option<Hit> {
        let mut bottom = CountStats::default();
        let hit = self.intersect_with(ray, stats, |obj, r| obj.intersect_count(r, &mut bottom));
        stats.nodes += bottom.nodes;
        stats.prims += bottom.prims;
        hit
    }

    /// One loop for counted and plain queries: `bottom` queries an object
    /// with a ray in its space; `counter` counts the top level.
    fn intersect_with<C: RayCounter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        mut bottom: impl FnMut(&S, &Ray) -> Option<Hit>,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = ray.tmax();
        self.top.traverse(ray, counter, &mut |k| {
            let p = &self.placed[k as usize];
            let local = self.local_ray(p, ray, tmax);
            if let Some(h) = bottom(&self.objects[p.object as usize], &local) {
                if better(best, k, &h) {
                    best = Some(placed_hit(p, k, h));
                    tmax = h.t;
                }
            }
            tmax
        });
        best
    }

    fn local_ray(&self, p: &Placed, ray: &Ray, tmax: f32) -> Ray {
        if p.identity {
            return ray.with_tmax(tmax);
        }
        Ray::new(
            p.world_to_object.transform_point3(ray.origin()),
            p.world_to_object.transform_vector3(ray.dir()),
            ray.tmin(),
            tmax,
        )
    }
}

impl<S: Surface> Instances<S> {
    /// For each instance, a bit per lane whose ray enters its box (a scene
    /// of at most [`PACKET_INSTANCES`] instances).
    fn packet_lanes(&self, rays: &[Ray; LANES]) -> [u8; PACKET_INSTANCES] {
        let mut lanes = [0u8; PACKET_INSTANCES];
        for (i, r) in rays.iter().enumerate() {
            self.top.traverse(r, &mut NoStats, &mut |k| {
                lanes[k as usize] |= 1 << i;
                r.tmax()
            });
        }
        lanes
    }

    /// For each ray of a stream, a bit per instance whose box it enters (a
    /// scene of at most [`PACKET_INSTANCES`] instances).
    ///
    /// A wide BVH over the boxes answers from its root where the ray's
    /// walk would go no deeper ([`Accel::root_leaves_each`]: a mesh and
    /// its floor, the renderer's scene of a mesh file, are two leaves),
    /// without the one-ray walk's set-up: that walk a ray was 5% of a
    /// render of bunny00.
    fn stream_masks(&self, rays: &[Ray]) -> Vec<u64> {
        self.top.root_leaves_each(rays, |r| self.walk_mask(r))
    }

    /// A bit per instance whose box `ray` enters, by the top structure's
    /// walk.
    fn walk_mask(&self, ray: &Ray) -> u64 {
        let mut m = 0u64;
        self.top.traverse(ray, &mut NoStats, &mut |k| {
            m |= 1 << k;
            ray.tmax()
        });
        m
    }

    /// The walk both stream queries share, over answers of type `T`
    /// (`T::default()`: no hit): each ray's `one(ray)` in a scene of more
    /// than [`PACKET_INSTANCES`] instances; else, instance by instance,
    /// `whole(object, rays, answers)` of the rays that enter its box and
    /// to which `bound(answer so far, ray)` gives a bound, carried into
    /// the object's space with it, each answer handed to `merge(answer so
    /// far, instance, placement, answer)`. One identity instance takes
    /// the stream whole, with no copy, each answer merged where its ray
    /// enters the instance's box (as the one-ray walk asks first).
    fn stream_query<T: Copy + Default>(
        &self,
        rays: &[Ray],
        out: &mut [T],
        one: impl Fn(&Ray) -> T,
        whole: impl Fn(&S, &[Ray], &mut [T]),
        bound: impl Fn(&T, &Ray) -> Option<f32>,
        merge: impl Fn(&mut T, u32, &Placed, T),
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        if self.placed.len() > PACKET_INSTANCES {
            for (o, r) in out.iter_mut().zip(rays) {
                *o = one(r);
            }
            return;
        }
        if let [p] = &self.placed[..] {
            if p.identity {
                whole(&self.objects[p.object as usize], rays, out);
                for (o, r) in out.iter_mut().zip(rays) {
                    let answer = std::mem::take(o);
                    if self.enters_one(r) {
                        merge(o, 0, p, answer);
                    }
                }
                return;
            }
        }
        out.fill(T::default());
        let masks = self.stream_masks(rays);
        let (mut which, mut local, mut answers) = (Vec::new(), Vec::new(), Vec::new());
        for (k, p) in self.placed.iter().enumerate() {
            self.gather(
                k,
                rays,
                &masks,
                |i| bound(&out[i], &rays[i]),
                &mut which,
                &mut local,
            );
            if which.is_empty() {
                continue;
            }
            answers.clear();
            answers.resize(which.len(), T::default());
            whole(&self.objects[p.object as usize], &local, &mut answers);
            for (&i, &a) in which.iter().zip(&answers) {
                merge(&mut out[i], k as u32, p, a);
            }
        }
    }

    /// Whether `ray` enters the box of a scene's one instance (whose
    /// object the one-ray queries then ask).
    fn enters_one(&self, ray: &Ray) -> bool {
        let mut entered = false;
        self.top.traverse(ray, &mut NoStats, &mut |_| {
            entered = true;
            f32::NEG_INFINITY
        });
        entered
    }

    /// The rays of a stream that enter instance `k`'s box (by `masks`, of
    /// [`Self::stream_masks`]) and are given a bound by `bound(i)` (`None`:
    /// the ray needs this instance no more): their indices into `which`,
    /// and them carried into the object's space with that bound into
    /// `local`, both in the stream's order (so that coherent runs stay
    /// together).
    fn gather(
        &self,
        k: usize,
        rays: &[Ray],
        masks: &[u64],
        bound: impl Fn(usize) -> Option<f32>,
        which: &mut Vec<usize>,
        local: &mut Vec<Ray>,
    ) {
        which.clear();
        local.clear();
        let p = &self.placed[k];
        for (i, (&m, r)) in masks.iter().zip(rays).enumerate() {
            if m >> k & 1 != 0 {
                if let Some(tmax) = bound(i) {
                    which.push(i);
                    local.push(self.local_ray(p, r, tmax));
                }
            }
        }
    }
}

/// Whether `h`, a hit in instance `k`, comes before `best`: the least
/// `(t, instance, prim)`, so that the hit does not depend on the order
/// in which instances are visited.
fn better(best: Option<Hit>, k: u32, h: &Hit) -> bool {
    match best {
        None => true,
        Some(b) => h.t < b.t || (h.t == b.t && (k, h.prim) < (b.instance, b.prim)),
    }
}

/// An object's hit `h` as a hit of instance `k` placed by `p`: the
/// instance noted, the normal carried to world space (as it is, under
/// the identity: the object's unit normal, with no square root and
/// division to make it unit again). Inlined: called, it handed each hit
/// back through memory, and the caller's wider loads of it waited on the
/// callee's narrower stores (a quarter of the stream merge's samples in a
/// render).
#[inline(always)]
fn placed_hit(p: &Placed, k: u32, mut h: Hit) -> Hit {
    h.instance = k;
    if !p.identity {
        h.normal = (p.normal_matrix * h.normal).normalize_or_zero();
    }
    h
}

impl<S: Surface> Surface for Instances<S> {
    fn bounds(&self) -> Aabb {
        self.bounds
    }
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.intersect_with(ray, &mut NoStats, |obj, r| obj.intersect(r))
    }
    fn intersect_count(&self, ray: &Ray, stats: &mut CountStats) -> Option<Hit> {
        self.intersect_counted(ray, stats)
    }
    /// Packets through a few instances: each lane lists the instances
    /// whose boxes its ray enters, and each instance so listed traces the
    /// lanes that listed it as one packet of its object (lanes that did not
    /// repeat one that did, their answers unused), each lane bounded by
    /// its best hit so far. The best hit is the least `(t, instance,
    /// prim)`, whatever the order, so the hits are those of
    /// [`Surface::intersect`] ray by ray. Scenes of more than
    /// [`PACKET_INSTANCES`] instances trace ray by ray.
    fn intersect8(&self, rays: &[Ray; LANES]) -> [Option<Hit>; LANES] {
        if self.placed.len() > PACKET_INSTANCES {
            return rays.each_ref().map(|r| self.intersect(r));
        }
        let lanes = self.packet_lanes(rays);
        let mut best: [Option<Hit>; LANES] = [None; LANES];
        for (k, &m) in lanes.iter().enumerate().filter(|(_, &m)| m != 0) {
            let p = &self.placed[k];
            let first = m.trailing_zeros() as usize;
            let local: [Ray; LANES] = std::array::from_fn(|i| {
                let i = if m >> i & 1 != 0 { i } else { first };
                self.local_ray(p, &rays[i], best[i].map_or(rays[i].tmax(), |h| h.t))
            });
            let hits = self.objects[p.object as usize].intersect8(&local);
            for (i, h) in hits.into_iter().enumerate() {
                let Some(h) = h.filter(|_| m >> i & 1 != 0) else {
                    continue;
                };
                if better(best[i], k as u32, &h) {
                    best[i] = Some(placed_hit(p, k as u32, h));
                }
            }
        }
        best
    }
    /// Packets through a few instances, as [`Self::intersect8`]: each
    /// instance that some lane's ray enters tests the lanes that entered
    /// it and are not yet found occluded as one packet of its object.
    /// The answers are those of [`Surface::occluded`] ray by ray.
    fn occluded8(&self, rays: &[Ray; LANES]) -> [bool; LANES] {
        if self.placed.len() > PACKET_INSTANCES {
            return rays.each_ref().map(|r| self.occluded(r));
        }
        let lanes = self.packet_lanes(rays);
        let mut found = [false; LANES];
        for (k, &listed) in lanes.iter().enumerate() {
            let m = (0..LANES).fold(listed, |m, i| if found[i] { m & !(1 << i) } else { m });
            if m == 0 {
                continue;
            }
            let p = &self.placed[k];
            let first = m.trailing_zeros() as usize;
            let local: [Ray; LANES] = std::array::from_fn(|i| {
                let i = if m >> i & 1 != 0 { i } else { first };
                self.local_ray(p, &rays[i], rays[i].tmax())
            });
            let occluded = self.objects[p.object as usize].occluded8(&local);
            for (i, f) in found.iter_mut().enumerate() {
                *f |= m >> i & 1 != 0 && occluded[i];
            }
        }
        found
    }
    /// Streams through a few instances: each ray lists the instances whose
    /// boxes it enters, and each instance so listed traces the rays that
    /// listed it, in the stream's order, as one stream of its object
    /// (whose structure may take them as packets or groups), each bounded
    /// by its best hit so far. The best hit is the least `(t, instance,
    /// prim)`, whatever the order, so the hits are those of
    /// [`Surface::intersect`] ray by ray. Scenes of more than
    /// [`PACKET_INSTANCES`] instances trace ray by ray.
    fn intersect_stream(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        self.stream_query(
            rays,
            out,
            |r| self.intersect(r),
            |obj, local, hits| obj.intersect_stream(local, hits),
            |best, r| Some(best.map_or(r.tmax(), |h| h.t)),
            |best, k, p, h| {
                if let Some(h) = h.filter(|h| better(*best, k, h)) {
                    *best = Some(placed_hit(p, k, h));
                }
            },
        );
    }
    /// Streams through a few instances, as [`Self::intersect_stream`]:
    /// each instance that some ray enters tests the rays that entered it
    /// and are not yet found occluded as one stream of its object. The
    /// answers are those of [`Surface::occluded`] ray by ray.
    fn occluded_stream(&self, rays: &[Ray], out: &mut [bool]) {
        self.stream_query(
            rays,
            out,
            |r| self.occluded(r),
            |obj, local, found| obj.occluded_stream(local, found),
            |&found, r| (!found).then(|| r.tmax()),
            |found, _, _, f| *found |= f,
        );
    }
    fn occluded(&self, ray: &Ray) -> bool {
        let mut hit = false;
        self.top.traverse(ray, &mut NoStats, &mut |k| {
            let p = &self.placed[k as usize];
            if self.objects[p.object as usize].occluded(&self.local_ray(p, ray, ray.tmax())) {
                hit = true;
                f32::NEG_INFINITY
            } else {
                ray.tmax()
            }
        });
        hit
    }
}

/// World box of a transformed box: the box of its eight transformed corners.
fn transform_box(m: &Mat4, b: Aabb) -> Aabb {
    if b.is_empty() {
        return Aabb::EMPTY;
    }
    let w = (0..8).fold(Aabb::EMPTY, |acc, i| {
        let c = Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        );
        acc.grow(m.transform_point3(c))
    });
    // Pad for the rounding of the transform (of the corners here, of the ray later).
    let pad = w.extent() * 1e-5 + Vec3::splat(w.min.abs().max(w.max.abs()).max_element() * 1e-6);
    Aabb::new(w.min - pad, w.max + pad)
}
