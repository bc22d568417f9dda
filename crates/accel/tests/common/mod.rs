//! Meshes shared by the integration tests.

use raymesh_accel::{TriangleMesh, Vec3};
use std::path::PathBuf;

/// A mesh from the repository's `tests/data`, fan-triangulated.
pub fn load(name: &str) -> TriangleMesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name);
    let m = raymesh_mesh::io::read_mesh(path).unwrap();
    TriangleMesh::new(m.positions.clone(), m.triangles())
}

/// A soup of triangles as an indexed mesh, three vertices each.
#[allow(dead_code)] // not every test file makes soups
pub fn tri_mesh(tris: &[[Vec3; 3]]) -> TriangleMesh {
    let positions: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let triangles = (0..tris.len() as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    TriangleMesh::new(positions, triangles)
}
