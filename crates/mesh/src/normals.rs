//! Face and vertex normals of an indexed polygon mesh.

use crate::IndexedMesh;
use raymesh_geometry::{DVec3, Vec3};

/// Angle-weighted vertex normals (Thürmer & Wüthrich, "Computing vertex
/// normals from polygonal facets", 1998): each face adds its unit normal
/// (Newell's, [`face_normal`]) weighted by its interior angle at the
/// vertex, which makes the result independent of how polygons are
/// triangulated. Vertices of no face, or only of degenerate faces, get a
/// zero normal; a corner with an edge of zero length weighs nothing.
///
/// The angle is [`fast_angle`] of the two edges' cross and dot products,
/// as the half-edge mesh's normals take it: no square roots of the edges'
/// lengths, and accurate at small angles, where `acos` of a dot product
/// of unit vectors loses digits.
#[must_use]
pub fn vertex_normals(mesh: &IndexedMesh) -> Vec<Vec3> {
    let p = &mesh.positions;
    let mut normals = vec![Vec3::ZERO; p.len()];
    for f in mesh.faces() {
        let n = face_normal(mesh, f);
        if n == Vec3::ZERO {
            continue;
        }
        let mut prev = p[f[f.len() - 1] as usize];
        for (i, &b) in f.iter().enumerate() {
            let at = p[b as usize];
            let next = p[f[(i + 1) % f.len()] as usize];
            let (e0, e1) = (prev - at, next - at);
            normals[b as usize] += n * corner_angle(e0, e1);
            prev = at;
        }
    }
    for n in &mut normals {
        *n = n.normalize_or_zero();
    }
    normals
}

/// The angle between edges `e0` and `e1`: [`fast_angle`] of their cross
/// and dot products in `f32`, and in `f64` where those left `f32`'s
/// range (edges longer than about 1e19 overflow the cross product's
/// length, shorter than about 1e-19 underflow both to zero), so that a
/// mesh's normals are the same at any scale.
#[inline]
fn corner_angle(e0: Vec3, e1: Vec3) -> f32 {
    // The cross product's squared length must be a normal float (or the
    // product zero: collinear edges), else its length overflowed or lost
    // its digits.
    let (c, dot) = (e0.cross(e1), e0.dot(e1));
    let c2 = c.length_squared();
    if ((c2.is_normal() && c2 < f32::INFINITY) || c == Vec3::ZERO)
        && dot.is_finite()
        && c2.max(dot.abs()) >= f32::MIN_POSITIVE
    {
        return fast_angle(c2.sqrt(), dot);
    }
    let (e0, e1) = (e0.as_dvec3(), e1.as_dvec3());
    let (cross, dot) = (e0.cross(e1).length(), e0.dot(e1));
    // The angle depends on the ratio alone.
    let scale = cross.max(dot.abs());
    if scale > 0.0 && scale.is_finite() {
        fast_angle((cross / scale) as f32, (dot / scale) as f32)
    } else {
        0.0
    }
}

/// The angle between two vectors whose dot product is `dot` and whose
/// cross product has length `cross` (≥ 0): `atan2(cross, dot)` with a
/// polynomial arctangent (Abramowitz & Stegun 4.4.49 form, |error| < 1e-5
/// rad), about five times cheaper than `acos` of normalized vectors and
/// accurate at small and large angles alike.
#[inline]
#[must_use]
pub fn fast_angle(cross: f32, dot: f32) -> f32 {
    // Selects, not branches: which of the two is larger is a coin toss
    // from one corner to the next, and mispredictions cost twice the math.
    let (y, x) = (cross, dot.abs());
    let (num, den) = (x.min(y), x.max(y));
    let t = if den > 0.0 { num / den } else { 0.0 }; // in [0, 1]
    let t2 = t * t;
    let a = t
        * (0.999_866
            + t2 * (-0.330_299_5 + t2 * (0.180_141 + t2 * (-0.085_133 + t2 * 0.020_835_1))));
    let a = if y > x {
        std::f32::consts::FRAC_PI_2 - a
    } else {
        a
    };
    if dot < 0.0 {
        std::f32::consts::PI - a
    } else {
        a
    }
}

/// Unit normal of a polygon by Newell's method (robust for non-planar
/// polygons); zero for a degenerate one. Worked out again in `f64` where
/// `f32` gives none (a degenerate polygon, or one whose squared normal
/// leaves `f32`'s range: past about 1e9.5 units across, or below 1e-9.5,
/// whose normals were zero), so that a mesh's normals are the same at
/// any scale.
#[must_use]
pub fn face_normal(mesh: &IndexedMesh, face: &[u32]) -> Vec3 {
    let p = &mesh.positions;
    let edge = |i: usize| (p[face[i] as usize], p[face[(i + 1) % face.len()] as usize]);
    let mut n = Vec3::ZERO;
    for i in 0..face.len() {
        let (a, b) = edge(i);
        n += Vec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    let unit = n.normalize_or_zero();
    if unit != Vec3::ZERO {
        return unit;
    }
    let mut n = DVec3::ZERO;
    for i in 0..face.len() {
        let (a, b) = edge(i);
        let (a, b) = (a.as_dvec3(), b.as_dvec3());
        n += DVec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    n.normalize_or_zero().as_vec3()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_corners_point_outward_diagonally() {
        let m = crate::io::read_bytes(
            b"OFF\n8 6 0\n-1 -1 -1\n1 -1 -1\n1 1 -1\n-1 1 -1\n-1 -1 1\n1 -1 1\n1 1 1\n-1 1 1\n\
              4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 1 2 6 5\n4 0 4 7 3\n",
            crate::io::Format::Off,
        )
        .unwrap();
        let n = vertex_normals(&m);
        for (v, n) in m.positions.iter().zip(&n) {
            assert!((n.dot(v.normalize()) - 1.0).abs() < 1e-5, "{v} {n}");
        }
        assert_eq!(face_normal(&m, m.face(1)), Vec3::Z);
    }

    #[test]
    fn triangulation_does_not_change_angle_weighted_normals() {
        // A quad split two ways plus a triangle: the shared vertex normal is the same.
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let quad =
            IndexedMesh::from_polygons(p.clone(), [&[0u32, 1, 2, 3][..], &[0, 4, 1]]).unwrap();
        let tris =
            IndexedMesh::from_polygons(p, [&[0u32, 1, 2][..], &[0, 2, 3], &[0, 4, 1]]).unwrap();
        let (a, b) = (vertex_normals(&quad)[0], vertex_normals(&tris)[0]);
        // Equal up to the fast arctangent's error (< 2e-5 rad per angle):
        // the quad's right angle is one evaluation, the triangles' two
        // halves are two. Weighting corners alike would be off by 0.1.
        assert!((a - b).length() < 2e-5, "{a} {b}");
        let uniform = (Vec3::Z + Vec3::Y * 2.0).normalize();
        assert!((a - uniform).length() > 0.1);
    }

    #[test]
    fn normals_are_the_same_at_any_scale() {
        let cube = |s: f32| {
            let p = [
                [-1., -1., -1.],
                [1., -1., -1.],
                [1., 1., -1.],
                [-1., 1., -1.],
                [-1., -1., 1.],
                [1., -1., 1.],
                [1., 1., 1.],
                [-1., 1., 1.],
            ]
            .map(|v| Vec3::from_array(v) * s)
            .to_vec();
            let f: [&[u32]; 6] = [
                &[0, 3, 2, 1],
                &[4, 5, 6, 7],
                &[0, 1, 5, 4],
                &[2, 3, 7, 6],
                &[1, 2, 6, 5],
                &[0, 4, 7, 3],
            ];
            IndexedMesh::from_polygons(p, f).unwrap()
        };
        // And a tetrahedron, whose corners' angles are not right angles
        // (whose dot products are zero).
        let tet = |s: f32| {
            let p = [
                [0.0, 0.0, 0.0],
                [1.0, 0.1, 0.0],
                [0.2, 1.0, 0.0],
                [0.3, 0.2, 1.0],
            ]
            .map(|v| Vec3::from_array(v) * s)
            .to_vec();
            let f: [&[u32]; 4] = [&[0, 2, 1], &[0, 1, 3], &[0, 3, 2], &[1, 2, 3]];
            IndexedMesh::from_polygons(p, f).unwrap()
        };
        for mesh in [cube, tet] {
            let unit = vertex_normals(&mesh(1.0));
            for s in [1e12f32, 1e20, 1e37, 1e-12, 1e-20, 1e-36] {
                let m = mesh(s);
                let (a, b) = (
                    face_normal(&m, m.face(1)),
                    face_normal(&mesh(1.0), m.face(1)),
                );
                assert!((a - b).length() < 1e-6, "{a} against {b} at {s}");
                for (a, b) in vertex_normals(&m).iter().zip(&unit) {
                    assert!((*a - *b).length() < 1e-5, "{a} against {b} at {s}");
                }
            }
        }
    }

    #[test]
    fn fast_angle_matches_atan2() {
        let mut worst = 0.0f32;
        for i in 0..=2000 {
            let a = i as f32 / 2000.0 * std::f32::consts::PI;
            let (d, c) = (a.cos() * 3.7, a.sin().abs() * 3.7);
            worst = worst.max((fast_angle(c, d) - c.atan2(d)).abs());
        }
        assert!(worst < 2e-5, "{worst}");
        assert_eq!(fast_angle(0.0, 0.0), 0.0);
    }

    #[test]
    fn isolated_and_degenerate_vertices_get_zero() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0, Vec3::Y];
        let m = IndexedMesh::from_triangles(p, &[[0, 1, 2]]).unwrap();
        assert!(vertex_normals(&m).iter().all(|n| *n == Vec3::ZERO));
    }
}
