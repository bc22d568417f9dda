//! OpenMesh 9 (Debian's `libopenmesh-dev`) through the small C interface
//! in `openmesh/shim.cpp`, for side-by-side measurements of the mesh
//! structures.
//!
//! The FFI calls are `unsafe`; each block states what keeps it sound.
//! Like `embree_peer`, this module is unsafe code of the benchmark crate
//! only; the library crates never depend on it.
#![allow(unsafe_code)]

use crate::{Edit, Edits};
use raymesh_mesh::IndexedMesh;
use std::ffi::c_void;

extern "C" {
    fn raymesh_om_build(
        pos: *const f32,
        nv: usize,
        tri: *const u32,
        nt: usize,
        failed: *mut usize,
    ) -> *mut c_void;
    fn raymesh_om_free(m: *mut c_void);
    fn raymesh_om_vertices(m: *const c_void) -> usize;
    fn raymesh_om_edges(m: *const c_void) -> usize;
    fn raymesh_om_faces(m: *const c_void) -> usize;
    fn raymesh_om_one_ring(m: *const c_void, count: *mut u64) -> u64;
    fn raymesh_om_normals(m: *mut c_void) -> f64;
    fn raymesh_om_loop(m: *const c_void, faces: *mut usize) -> u64;
    fn raymesh_om_edit(
        m: *const c_void,
        kind: i32,
        pairs: *const u32,
        n: usize,
        out: *mut Edits,
    ) -> u64;
    fn raymesh_om_catmull_clark(
        pos: *const f32,
        nv: usize,
        tri: *const u32,
        nt: usize,
        vertices: *mut usize,
        faces: *mut usize,
    ) -> u64;
}

/// `mesh` as the shim takes it: 3 floats a vertex, 3 indices a triangle
/// (polygons fan-triangulated).
fn flat(mesh: &IndexedMesh) -> (Vec<f32>, Vec<u32>) {
    let pos = mesh.positions.iter().flat_map(|p| p.to_array()).collect();
    let tri = mesh.triangles().into_iter().flatten().collect();
    (pos, tri)
}

/// One Catmull–Clark step by OpenMesh (`CatmullClarkT`, on a polygon
/// mesh built from `mesh`'s triangles, not timed): the seconds the step
/// took, and its vertices and faces after.
pub fn catmull_clark(mesh: &IndexedMesh) -> (f64, usize, usize) {
    let (pos, tri) = flat(mesh);
    let (mut vertices, mut faces) = (0usize, 0usize);
    // SAFETY: `pos` holds 3 floats a vertex and `tri` 3 indices a
    // triangle, every index below the vertex count (an `IndexedMesh`
    // checks them); both outlive the call, which copies them; the two
    // counts are valid places to write.
    let ns = unsafe {
        raymesh_om_catmull_clark(
            pos.as_ptr(),
            mesh.positions.len(),
            tri.as_ptr(),
            tri.len() / 3,
            &mut vertices,
            &mut faces,
        )
    };
    (ns as f64 * 1e-9, vertices, faces)
}

/// An OpenMesh triangle mesh (`TriMesh_ArrayKernelT<>`), owned.
pub struct OmMesh {
    ptr: *mut c_void,
    /// Triangles OpenMesh refused to add (non-manifold ones).
    pub refused: usize,
}

impl OmMesh {
    /// OpenMesh's mesh of `mesh`'s vertices and fan-triangulated faces,
    /// added one by one (`add_vertex`, `add_face`), as its readers do.
    pub fn build(mesh: &IndexedMesh) -> Self {
        let (pos, tri) = flat(mesh);
        let mut refused = 0usize;
        // SAFETY: `pos` holds 3 floats a vertex and `tri` 3 indices a
        // triangle, every index below the vertex count (an `IndexedMesh`
        // checks them); both outlive the call, which copies them.
        let ptr = unsafe {
            raymesh_om_build(
                pos.as_ptr(),
                mesh.positions.len(),
                tri.as_ptr(),
                tri.len() / 3,
                &mut refused,
            )
        };
        assert!(!ptr.is_null(), "OpenMesh could not allocate the mesh");
        Self { ptr, refused }
    }

    /// Vertices, edges and faces.
    pub fn counts(&self) -> (usize, usize, usize) {
        // SAFETY: `ptr` is a live mesh made by `raymesh_om_build`.
        unsafe {
            (
                raymesh_om_vertices(self.ptr),
                raymesh_om_edges(self.ptr),
                raymesh_om_faces(self.ptr),
            )
        }
    }

    /// Every vertex's one-ring, clockwise (`vv_range`): the sum of the
    /// neighbours' indices and their number.
    pub fn one_ring(&self) -> (u64, u64) {
        let mut n = 0u64;
        // SAFETY: `ptr` is a live mesh; `n` is a valid place to write.
        let sum = unsafe { raymesh_om_one_ring(self.ptr, &mut n) };
        (sum, n)
    }

    /// Face and vertex normals (`update_normals`); the sum of the vertex
    /// normals' x components.
    pub fn normals(&mut self) -> f64 {
        // SAFETY: `ptr` is a live mesh, borrowed mutably here alone.
        unsafe { raymesh_om_normals(self.ptr) }
    }

    /// One Loop step (`Subdivider::Uniform::LoopT`) on a copy: the
    /// seconds the step took (the copy not counted) and the faces after.
    pub fn loop_step(&self) -> (f64, usize) {
        let mut faces = 0usize;
        // SAFETY: `ptr` is a live mesh, which the call only copies.
        let ns = unsafe { raymesh_om_loop(self.ptr, &mut faces) };
        (ns as f64 * 1e-9, faces)
    }

    /// `edit` on a copy, over each edge `pairs` names by its vertices
    /// (`find_halfedge`; pairs no edge joins any more are passed over),
    /// or for `Edit::SplitFace` over every face by index:
    /// the seconds the edits took (the copy not counted) and what they
    /// left. Panics if a pair names a vertex the mesh does not have.
    pub fn edit(&self, edit: Edit, pairs: &[[u32; 2]]) -> (f64, Edits) {
        let nv = self.counts().0;
        assert!(
            pairs.iter().flatten().all(|&v| (v as usize) < nv),
            "an edge pair names a vertex OpenMesh's mesh does not have"
        );
        let flat = pairs.as_flattened();
        let mut out = Edits::default();
        // SAFETY: `ptr` is a live mesh, which the call only copies;
        // `flat` holds 2 indices a pair, each a vertex of the mesh
        // (checked above), and outlives the call; `out` is a valid
        // `RmEdits` (`#[repr(C)]`, the same fields) to write.
        let ns =
            unsafe { raymesh_om_edit(self.ptr, edit as i32, flat.as_ptr(), pairs.len(), &mut out) };
        (ns as f64 * 1e-9, out)
    }
}

impl Drop for OmMesh {
    fn drop(&mut self) {
        // SAFETY: `ptr` came from `raymesh_om_build` and is freed once.
        unsafe { raymesh_om_free(self.ptr) }
    }
}
