//! Meshes for raymesh: the indexed polygon mesh that every file format reads
//! into, the readers and writers for OBJ, OFF, PLY and STL, and the
//! half-edge mesh with its queries, validation and subdivision.
//!
//! Faces stay polygons (connectivity structures need them); a fan-triangulated
//! view is made on demand, with triangles in the file's face order, so that
//! triangle `i` of [`IndexedMesh::triangles`] is the `prim` index that ray
//! queries report.

pub mod compact;
mod error;
pub mod half_edge;
pub mod handle;
mod indexed;
pub mod io;
pub mod normals;
pub mod packed;
pub mod synthetic;
pub mod winged_edge;

pub use compact::CompactMesh;
pub use error::{ErrorKind, Location, MeshError};
pub use half_edge::HalfEdgeMesh;
pub use indexed::{IndexedMesh, MeshStats};
pub use raymesh_geometry::{Aabb, Vec3};
pub use winged_edge::WingedEdgeMesh;
