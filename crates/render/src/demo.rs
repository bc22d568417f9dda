//! The built-in demo scene and the procedural meshes scenes can name as
//! `builtin:NAME`.

use crate::SceneDesc;
use raymesh_geometry::Vec3;
use raymesh_mesh::IndexedMesh;
use std::path::Path;

/// The demo scene (`scenes/demo.json`, compiled into the binary).
#[must_use]
pub fn demo_scene() -> SceneDesc {
    SceneDesc::parse(
        include_str!("../../../scenes/demo.json"),
        Path::new("<demo>"),
    )
    .expect("the built-in demo scene parses")
}

/// A (2, 3) torus knot tube: `segments` rings of `sides` vertices, two
/// triangles per quad, radius about 3.4. The frame follows three.js's
/// TorusKnotGeometry (tangent, and the sum of neighbouring curve points).
#[must_use]
pub fn torus_knot(segments: u32, sides: u32) -> IndexedMesh {
    let (p, q, tube) = (2.0f32, 3.0f32, 0.45f32);
    let curve = |u: f32| {
        let r = 2.0 + (q * u).cos();
        Vec3::new(r * (p * u).cos(), r * (p * u).sin(), (q * u).sin())
    };
    let (segments, sides) = (segments.max(3), sides.max(3));
    let mut positions = Vec::with_capacity((segments * sides) as usize);
    for i in 0..segments {
        let u = i as f32 / segments as f32 * std::f32::consts::TAU;
        let (p1, p2) = (curve(u), curve(u + 0.01));
        let t = p2 - p1;
        let n0 = p2 + p1;
        let b = t.cross(n0).normalize();
        let n = b.cross(t).normalize();
        for j in 0..sides {
            let v = j as f32 / sides as f32 * std::f32::consts::TAU;
            positions.push(p1 + tube * (v.cos() * n + v.sin() * b));
        }
    }
    let mut tris = Vec::with_capacity((2 * segments * sides) as usize);
    for i in 0..segments {
        for j in 0..sides {
            let i1 = (i + 1) % segments;
            let j1 = (j + 1) % sides;
            let (a, b, c, d) = (
                i * sides + j,
                i1 * sides + j,
                i1 * sides + j1,
                i * sides + j1,
            );
            tris.push([a, b, d]);
            tris.push([b, c, d]);
        }
    }
    IndexedMesh::from_triangles(positions, &tris).expect("indices are in range by construction")
}
