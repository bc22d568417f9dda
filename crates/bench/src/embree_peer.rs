//! Intel Embree 3 through its C API, with the mesh's own vertex and index
//! buffers shared (not copied), for side-by-side measurements.
//!
//! The FFI calls are `unsafe`; each block states what keeps it sound. This
//! module is the only unsafe code of the benchmark crate, and the library
//! crates never depend on it.
#![allow(unsafe_code)]

use embree::sys::{
    rtcAttachGeometry, rtcBuildBVH, rtcCommitGeometry, rtcCommitScene, rtcIntersect1,
    rtcIntersect1M, rtcIntersect8, rtcNewBVH, rtcNewDevice, rtcNewGeometry, rtcNewScene,
    rtcOccluded1, rtcOccluded1M, rtcOccluded8, rtcReleaseBVH, rtcReleaseDevice, rtcReleaseGeometry,
    rtcReleaseScene, rtcSetDeviceMemoryMonitorFunction, rtcSetGeometryBuildQuality,
    rtcSetSceneBuildQuality, rtcSetSceneFlags, rtcSetSharedGeometryBuffer, rtcThreadLocalAlloc,
    RTCBounds, RTCBufferType, RTCBuildArguments, RTCBuildFlags, RTCBuildPrimitive, RTCBuildQuality,
    RTCDevice, RTCFormat, RTCGeometryType, RTCHit, RTCHit8, RTCRay, RTCRay8, RTCRayHit, RTCRayHit8,
    RTCScene, RTCSceneFlags, RTCThreadLocalAllocator,
};
use raymesh_geometry::{Aabb, Vec3};
use std::ffi::c_void;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::Instant;

/// A packet's valid mask, aligned as the packet is (Embree may load it
/// with aligned vector loads).
#[repr(C, align(32))]
struct Valid8([i32; 8]);

/// Bytes Embree has allocated, as its memory monitor reports them.
static ALLOCATED: AtomicI64 = AtomicI64::new(0);

unsafe extern "C" fn monitor(_user: *mut std::ffi::c_void, bytes: isize, _post: bool) -> bool {
    ALLOCATED.fetch_add(bytes as i64, Ordering::Relaxed);
    true
}

/// An Embree scene over one triangle mesh.
pub struct EmbreeScene {
    device: RTCDevice,
    scene: RTCScene,
    // Shared with Embree: must outlive `scene` (and read by `tree_cost`).
    vertices: Vec<f32>,
    indices: Vec<u32>,
    /// Milliseconds to build the BVH (geometry set-up and `rtcCommitScene`).
    pub build_ms: f64,
    /// Bytes Embree allocated while building.
    pub bytes: i64,
    /// Built with quality high (spatial splits).
    high: bool,
}

impl EmbreeScene {
    /// Builds Embree's default BVH (build quality medium), or its
    /// spatial-split BVH (quality high) when `high`, with `threads` threads;
    /// `robust` sets `RTC_SCENE_FLAG_ROBUST` (robust traversal, watertight
    /// triangle test) on the scene.
    pub fn new(
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        threads: usize,
        high: bool,
        robust: bool,
    ) -> Self {
        let quality = if high {
            RTCBuildQuality::HIGH
        } else {
            RTCBuildQuality::MEDIUM
        };
        // Embree reads vertices 16 bytes at a time: one float of padding at the end.
        let mut vertices: Vec<f32> = positions.iter().flat_map(|p| p.to_array()).collect();
        vertices.push(0.0);
        let indices: Vec<u32> = triangles.iter().flatten().copied().collect();
        let config =
            std::ffi::CString::new(format!("threads={threads}")).expect("no NUL in config");
        // SAFETY: the config string lives across the call; the buffers handed
        // to rtcSetSharedGeometryBuffer are owned by the returned value, which
        // releases the scene (and so every use of them) in Drop before they
        // are freed; counts match the buffers' lengths.
        unsafe {
            let device = rtcNewDevice(config.as_ptr());
            assert!(!device.is_null(), "Embree: rtcNewDevice failed");
            rtcSetDeviceMemoryMonitorFunction(device, Some(monitor), std::ptr::null_mut());
            let start = Instant::now();
            let before = ALLOCATED.load(Ordering::Relaxed);
            let geom = rtcNewGeometry(device, RTCGeometryType::TRIANGLE);
            rtcSetSharedGeometryBuffer(
                geom,
                RTCBufferType::VERTEX,
                0,
                RTCFormat::FLOAT3,
                vertices.as_ptr().cast(),
                0,
                12,
                positions.len(),
            );
            rtcSetSharedGeometryBuffer(
                geom,
                RTCBufferType::INDEX,
                0,
                RTCFormat::UINT3,
                indices.as_ptr().cast(),
                0,
                12,
                triangles.len(),
            );
            rtcSetGeometryBuildQuality(geom, quality);
            rtcCommitGeometry(geom);
            let scene = rtcNewScene(device);
            rtcSetSceneBuildQuality(scene, quality);
            if robust {
                rtcSetSceneFlags(scene, RTCSceneFlags::ROBUST);
            }
            rtcAttachGeometry(scene, geom);
            rtcReleaseGeometry(geom);
            rtcCommitScene(scene);
            let build_ms = start.elapsed().as_secs_f64() * 1e3;
            let bytes = ALLOCATED.load(Ordering::Relaxed) - before;
            Self {
                device,
                scene,
                vertices,
                indices,
                build_ms,
                bytes,
                high,
            }
        }
    }

    /// A hit record before the query: no geometry, no primitive.
    const NO_HIT: RTCHit = RTCHit {
        Ng_x: 0.0,
        Ng_y: 0.0,
        Ng_z: 0.0,
        u: 0.0,
        v: 0.0,
        primID: u32::MAX,
        geomID: u32::MAX,
        instID: [u32::MAX],
    };

    fn ray(r: &[f32; 8]) -> RTCRay {
        RTCRay {
            org_x: r[0],
            org_y: r[1],
            org_z: r[2],
            tnear: r[3],
            dir_x: r[4],
            dir_y: r[5],
            dir_z: r[6],
            time: 0.0,
            tfar: r[7],
            mask: u32::MAX,
            id: 0,
            flags: 0,
        }
    }

    /// Closest hit: `(t, prim, u, v)`, or `None`.
    pub fn intersect(&self, r: &[f32; 8]) -> Option<(f32, u32, f32, f32)> {
        let mut ctx = embree::IntersectContext::incoherent();
        let mut rh = RTCRayHit {
            ray: Self::ray(r),
            hit: Self::NO_HIT,
        };
        // SAFETY: the scene is committed and alive; ctx and rh are valid for the call.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        (rh.hit.geomID != u32::MAX).then_some((rh.ray.tfar, rh.hit.primID, rh.hit.u, rh.hit.v))
    }

    /// Closest hits of eight rays as one packet (`rtcIntersect8`, with the
    /// coherent-rays hint: the packet mode is for camera rays).
    pub fn intersect8(&self, r: &[[f32; 8]; 8]) -> [Option<(f32, u32)>; 8] {
        let mut ctx = embree::IntersectContext::coherent();
        let mut rh = RTCRayHit8 {
            ray: Self::ray8(r),
            hit: RTCHit8 {
                Ng_x: [0.0; 8],
                Ng_y: [0.0; 8],
                Ng_z: [0.0; 8],
                u: [0.0; 8],
                v: [0.0; 8],
                primID: [u32::MAX; 8],
                geomID: [u32::MAX; 8],
                instID: [[u32::MAX; 8]],
            },
        };
        let valid = Valid8([-1; 8]);
        // SAFETY: the scene is committed and alive; `valid` holds 8 ints
        // and `rh` is an 8-ray packet, both with the 32-byte alignment
        // rtcIntersect8 asks of packets, and valid for the call.
        unsafe { rtcIntersect8(valid.0.as_ptr(), self.scene, &mut ctx, &mut rh) };
        std::array::from_fn(|i| {
            (rh.hit.geomID[i] != u32::MAX).then_some((rh.ray.tfar[i], rh.hit.primID[i]))
        })
    }

    /// Whether each of eight rays hits anything, as one packet
    /// (`rtcOccluded8`, with the coherent-rays hint, as `intersect8`).
    pub fn occluded8(&self, r: &[[f32; 8]; 8]) -> [bool; 8] {
        let mut ctx = embree::IntersectContext::coherent();
        let mut ray = Self::ray8(r);
        let valid = Valid8([-1; 8]);
        // SAFETY: as for rtcIntersect8 in `intersect8`: a committed scene,
        // and a valid mask and packet of 8 with 32-byte alignment.
        unsafe { rtcOccluded8(valid.0.as_ptr(), self.scene, &mut ctx, &mut ray) };
        // Embree sets `tfar` to -inf where the ray is occluded.
        std::array::from_fn(|i| ray.tfar[i] == f32::NEG_INFINITY)
    }

    /// Eight rays (BENCH.md's layout) as an Embree packet.
    fn ray8(r: &[[f32; 8]; 8]) -> RTCRay8 {
        let lane = |k: usize| std::array::from_fn(|i| r[i][k]);
        RTCRay8 {
            org_x: lane(0),
            org_y: lane(1),
            org_z: lane(2),
            tnear: lane(3),
            dir_x: lane(4),
            dir_y: lane(5),
            dir_z: lane(6),
            time: [0.0; 8],
            tfar: lane(7),
            mask: [u32::MAX; 8],
            id: [0; 8],
            flags: [0; 8],
        }
    }

    /// Closest hits (`any == false`, `(t, prim)`) or any hits (`(0, 0)`)
    /// of a batch of rays in one stream call (`rtcIntersect1M` or
    /// `rtcOccluded1M`, with the incoherent-rays hint), into `out`.
    pub fn stream(&self, rays: &[[f32; 8]], any: bool, out: &mut [Option<(f32, u32)>]) {
        let mut ctx = embree::IntersectContext::incoherent();
        let m = u32::try_from(rays.len()).expect("a stream of fewer than 2^32 rays");
        if any {
            let mut rs: Vec<RTCRay> = rays.iter().map(Self::ray).collect();
            // SAFETY: the scene is committed and alive; `rs` holds `m`
            // rays, 16-byte aligned (the type says so), `size_of` apart.
            unsafe {
                rtcOccluded1M(
                    self.scene,
                    &mut ctx,
                    rs.as_mut_ptr(),
                    m,
                    std::mem::size_of::<RTCRay>(),
                );
            }
            for (o, r) in out.iter_mut().zip(&rs) {
                *o = (r.tfar == f32::NEG_INFINITY).then_some((0.0, 0));
            }
        } else {
            let mut rhs: Vec<RTCRayHit> = rays
                .iter()
                .map(|r| RTCRayHit {
                    ray: Self::ray(r),
                    hit: Self::NO_HIT,
                })
                .collect();
            // SAFETY: as above, for `m` ray-hit records.
            unsafe {
                rtcIntersect1M(
                    self.scene,
                    &mut ctx,
                    rhs.as_mut_ptr(),
                    m,
                    std::mem::size_of::<RTCRayHit>(),
                );
            }
            for (o, rh) in out.iter_mut().zip(&rhs) {
                *o = (rh.hit.geomID != u32::MAX).then_some((rh.ray.tfar, rh.hit.primID));
            }
        }
    }

    /// Any hit.
    pub fn occluded(&self, r: &[f32; 8]) -> bool {
        let mut ctx = embree::IntersectContext::incoherent();
        let mut ray = Self::ray(r);
        // SAFETY: as for intersect.
        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut ray) };
        ray.tfar == f32::NEG_INFINITY
    }
}

// SAFETY: Embree's committed scenes may be queried from any number of
// threads at once (rtcIntersect1/rtcOccluded1 are thread-safe), and nothing
// mutates the scene or the shared buffers after construction.
unsafe impl Send for EmbreeScene {}
// SAFETY: as for Send.
unsafe impl Sync for EmbreeScene {}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: released once, scene before device; nothing uses them after.
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}

/// A node or leaf of the tree [`builder_sah`] has Embree build: a leaf
/// has `leaf_count > 0` and nothing else; a node, `n` children and their
/// boxes.
#[repr(C)]
struct Item {
    leaf_count: u32,
    n: u32,
    children: [*const Item; 8],
    bounds: [RTCBounds; 8],
}

/// SAH cost, in raymesh's units (`AccelStats::sah_cost`: 1 for the root,
/// plus each child box's area relative to the root's, times its triangles
/// for a leaf), of the 8-wide tree Embree's SAH builder makes for the
/// triangles: `rtcBuildBVH` with the settings Embree gives its own BVH8
/// of `Triangle4` leaves (quality medium, blocks of 4, leaves of 4 to 32,
/// traversal and intersection cost 1). The tree `rtcCommitScene` builds is
/// internal; this is the same builder on the same boxes, for issue 7's
/// "an SAH cost no worse than Embree's structure gives". With it, the
/// node tests (the root's, and one per inner child box) and the leaf
/// tests (each leaf in `Triangle4` blocks of 4) that a random ray is
/// expected to make, by the same areas: their sum is the cost this
/// builder minimizes.
///
/// The scene's shared buffers give the triangles: `vertices` three floats
/// a vertex (and a padding float), `indices` three a triangle.
fn builder_sah(device: RTCDevice, vertices: &[f32], indices: &[u32]) -> crate::engines::TreeCost {
    let zero = crate::engines::TreeCost {
        sah: 0.0,
        node_tests: 0.0,
        leaf_tests: 0.0,
    };
    let vertex = |v: u32| Vec3::from_slice(&vertices[3 * v as usize..][..3]);
    let mut root_box = Aabb::EMPTY;
    let mut prims: Vec<RTCBuildPrimitive> = indices
        .chunks_exact(3)
        .enumerate()
        .map(|(i, t)| {
            let b = t.iter().fold(Aabb::EMPTY, |b, &v| b.grow(vertex(v)));
            root_box = root_box.union(b);
            RTCBuildPrimitive {
                lower_x: b.min.x,
                lower_y: b.min.y,
                lower_z: b.min.z,
                geomID: 0,
                upper_x: b.max.x,
                upper_y: b.max.y,
                upper_z: b.max.z,
                primID: i as u32,
            }
        })
        .collect();
    if prims.is_empty() || root_box.half_area() <= 0.0 {
        return zero;
    }

    unsafe extern "C" fn alloc(a: RTCThreadLocalAllocator) -> *mut Item {
        // SAFETY: `a` is the allocator Embree handed to the callback; the
        // memory is Embree's, valid until the BVH is released, and zeroed
        // here before any field is read.
        unsafe {
            let p = rtcThreadLocalAlloc(a, std::mem::size_of::<Item>(), 32).cast::<Item>();
            assert!(!p.is_null(), "Embree: rtcThreadLocalAlloc failed");
            p.write_bytes(0, 1);
            p
        }
    }
    unsafe extern "C" fn create_node(
        a: RTCThreadLocalAllocator,
        n: u32,
        _: *mut c_void,
    ) -> *mut c_void {
        // SAFETY: see `alloc`; Embree asks for at most its branching factor, 8.
        unsafe {
            let p = alloc(a);
            (*p).n = n.min(8);
            p.cast()
        }
    }
    unsafe extern "C" fn set_children(
        node: *mut c_void,
        kids: *mut *mut c_void,
        n: u32,
        _: *mut c_void,
    ) {
        // SAFETY: `node` came from `create_node`, `kids` holds `n` pointers.
        unsafe {
            let node = node.cast::<Item>();
            for k in 0..(n as usize).min(8) {
                (*node).children[k] = (*kids.add(k)).cast::<Item>();
            }
        }
    }
    unsafe extern "C" fn set_bounds(
        node: *mut c_void,
        b: *mut *const RTCBounds,
        n: u32,
        _: *mut c_void,
    ) {
        // SAFETY: `node` came from `create_node`, `b` holds `n` pointers to boxes.
        unsafe {
            let node = node.cast::<Item>();
            for k in 0..(n as usize).min(8) {
                (*node).bounds[k] = **b.add(k);
            }
        }
    }
    unsafe extern "C" fn create_leaf(
        a: RTCThreadLocalAllocator,
        _: *const RTCBuildPrimitive,
        count: usize,
        _: *mut c_void,
    ) -> *mut c_void {
        // SAFETY: see `alloc`.
        unsafe {
            let p = alloc(a);
            (*p).leaf_count = count.max(1) as u32;
            p.cast()
        }
    }

    let root_area = f64::from(root_box.half_area());
    // SAFETY: the arguments describe `prims` (alive across the call, its
    // length as count and capacity) and the callbacks above, which write
    // only the items they allocate; the tree is read before the BVH that
    // owns its memory is released.
    unsafe {
        let bvh = rtcNewBVH(device);
        let args = RTCBuildArguments {
            byteSize: std::mem::size_of::<RTCBuildArguments>(),
            buildQuality: RTCBuildQuality::MEDIUM,
            buildFlags: RTCBuildFlags::NONE,
            maxBranchingFactor: 8,
            maxDepth: 32,
            sahBlockSize: 4,
            minLeafSize: 4,
            maxLeafSize: 32,
            traversalCost: 1.0,
            intersectionCost: 1.0,
            bvh,
            primitives: prims.as_mut_ptr(),
            primitiveCount: prims.len(),
            primitiveArrayCapacity: prims.len(),
            createNode: Some(create_node),
            setNodeChildren: Some(set_children),
            setNodeBounds: Some(set_bounds),
            createLeaf: Some(create_leaf),
            splitPrimitive: None,
            buildProgress: None,
            userPtr: std::ptr::null_mut(),
        };
        let root = rtcBuildBVH(&args).cast::<Item>().cast_const();
        assert!(!root.is_null(), "Embree: rtcBuildBVH failed");
        let cost = if (*root).leaf_count > 0 {
            // One leaf: as raymesh counts a root node holding it.
            let n = (*root).leaf_count;
            crate::engines::TreeCost {
                sah: 1.0 + f64::from(n),
                node_tests: 1.0,
                leaf_tests: f64::from(n.div_ceil(4)),
            }
        } else {
            let mut cost = crate::engines::TreeCost {
                sah: 1.0,
                node_tests: 1.0,
                leaf_tests: 0.0,
            };
            let mut stack = vec![root];
            while let Some(node) = stack.pop() {
                let node = &*node;
                for k in 0..node.n as usize {
                    let b = &node.bounds[k];
                    let area = f64::from(
                        Aabb::new(
                            Vec3::new(b.lower_x, b.lower_y, b.lower_z),
                            Vec3::new(b.upper_x, b.upper_y, b.upper_z),
                        )
                        .half_area(),
                    ) / root_area;
                    let child = &*node.children[k];
                    if child.leaf_count > 0 {
                        cost.sah += area * f64::from(child.leaf_count);
                        cost.leaf_tests += area * f64::from(child.leaf_count.div_ceil(4));
                    } else {
                        cost.sah += area;
                        cost.node_tests += area;
                        stack.push(node.children[k]);
                    }
                }
            }
            cost
        };
        rtcReleaseBVH(bvh);
        cost
    }
}

impl crate::engines::Engine for EmbreeScene {
    fn name(&self) -> &'static str {
        "embree"
    }
    fn build_ms(&self) -> f64 {
        self.build_ms
    }
    fn bytes(&self) -> Option<usize> {
        usize::try_from(self.bytes).ok()
    }
    fn tree_cost(&self) -> Option<crate::engines::TreeCost> {
        // Not timed, and built only when asked: once per reported build.
        // `builder_sah` rebuilds the medium tree; the spatial-split tree of
        // quality high has no counterpart there.
        (!self.high).then(|| builder_sah(self.device, &self.vertices, &self.indices))
    }
    fn trace(
        &self,
        rays: &[[f32; 8]],
        any: bool,
        run: &crate::engines::Runner,
    ) -> (f64, Vec<crate::engines::Answer>) {
        if run.stream {
            run.run_chunks(rays, |rays, out| self.stream(rays, any, out))
        } else if any && run.packets {
            run.run8(
                rays,
                |p| self.occluded8(p).map(|o| o.then_some((0.0, 0))),
                |r| self.occluded(r).then_some((0.0, 0)),
            )
        } else if any {
            run.run(rays, |r| self.occluded(r).then_some((0.0, 0)))
        } else if run.packets {
            run.run8(
                rays,
                |p| self.intersect8(p),
                |r| self.intersect(r).map(|(t, p, _, _)| (t, p)),
            )
        } else {
            run.run(rays, |r| self.intersect(r).map(|(t, p, _, _)| (t, p)))
        }
    }
}
