//! Intel Embree 3 through its C API, with the mesh's own vertex and index
//! buffers shared (not copied), for side-by-side measurements.
//!
//! The FFI calls are `unsafe`; each block states what keeps it sound. This
//! module is the only unsafe code of the benchmark crate, and the library
//! crates never depend on it.
#![allow(unsafe_code)]

use embree::sys::{
    rtcAttachGeometry, rtcCommitGeometry, rtcCommitScene, rtcIntersect1, rtcIntersect1M,
    rtcIntersect8, rtcNewDevice, rtcNewGeometry, rtcNewScene, rtcOccluded1, rtcOccluded1M,
    rtcReleaseDevice, rtcReleaseGeometry, rtcReleaseScene, rtcSetDeviceMemoryMonitorFunction,
    rtcSetSceneBuildQuality, rtcSetSharedGeometryBuffer, RTCBufferType, RTCBuildQuality, RTCDevice,
    RTCFormat, RTCGeometryType, RTCHit, RTCHit8, RTCRay, RTCRay8, RTCRayHit, RTCRayHit8, RTCScene,
};
use raymesh_geometry::Vec3;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::Instant;

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
    // Shared with Embree: must outlive `scene`.
    _vertices: Vec<f32>,
    _indices: Vec<u32>,
    /// Milliseconds to build the BVH (geometry set-up and `rtcCommitScene`).
    pub build_ms: f64,
    /// Bytes Embree allocated while building.
    pub bytes: i64,
}

impl EmbreeScene {
    /// Builds Embree's default BVH (build quality medium) with `threads` threads.
    pub fn new(positions: &[Vec3], triangles: &[[u32; 3]], threads: usize) -> Self {
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
            rtcCommitGeometry(geom);
            let scene = rtcNewScene(device);
            rtcSetSceneBuildQuality(scene, RTCBuildQuality::MEDIUM);
            rtcAttachGeometry(scene, geom);
            rtcReleaseGeometry(geom);
            rtcCommitScene(scene);
            let build_ms = start.elapsed().as_secs_f64() * 1e3;
            let bytes = ALLOCATED.load(Ordering::Relaxed) - before;
            Self {
                device,
                scene,
                _vertices: vertices,
                _indices: indices,
                build_ms,
                bytes,
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
        let lane = |k: usize| std::array::from_fn(|i| r[i][k]);
        let mut rh = RTCRayHit8 {
            ray: RTCRay8 {
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
            },
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
        /// The valid mask, aligned as the packet is (Embree may load it
        /// with aligned vector loads).
        #[repr(C, align(32))]
        struct Valid([i32; 8]);
        let valid = Valid([-1; 8]);
        // SAFETY: the scene is committed and alive; `valid` holds 8 ints
        // and `rh` is an 8-ray packet, both with the 32-byte alignment
        // rtcIntersect8 asks of packets, and valid for the call.
        unsafe { rtcIntersect8(valid.0.as_ptr(), self.scene, &mut ctx, &mut rh) };
        std::array::from_fn(|i| {
            (rh.hit.geomID[i] != u32::MAX).then_some((rh.ray.tfar[i], rh.hit.primID[i]))
        })
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
    fn trace(
        &self,
        rays: &[[f32; 8]],
        any: bool,
        run: &crate::engines::Runner,
    ) -> (f64, Vec<crate::engines::Answer>) {
        if run.stream {
            run.run_chunks(rays, |rays, out| self.stream(rays, any, out))
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
