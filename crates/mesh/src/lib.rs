//! Meshes for raymesh: the indexed polygon mesh that every file format reads
//! into, and the readers and writers for OBJ, OFF, PLY and STL.
//!
//! Faces stay polygons (connectivity structures need them); a fan-triangulated
//! view is made on demand, with triangles in the file's face order, so that
//! triangle `i` of [`IndexedMesh::triangles`] is the `prim` index that ray
//! queries report.

mod error;
mod indexed;
pub mod io;
pub mod normals;

pub use error::{ErrorKind, Location, MeshError};
pub use indexed::{IndexedMesh, MeshStats};
pub use raymesh_geometry::{Aabb, Vec3};
