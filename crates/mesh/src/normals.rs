//! Face and vertex normals of an indexed polygon mesh.

use crate::IndexedMesh;
use raymesh_geometry::Vec3;

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
            normals[b as usize] += n * fast_angle(e0.cross(e1).length(), e0.dot(e1));
            prev = at;
        }
    }
    for n in &mut normals {
        *n = n.normalize_or_zero();
    }
    normals
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
/// polygons); zero for a degenerate one.
#[must_use]
pub fn face_normal(mesh: &IndexedMesh, face: &[u32]) -> Vec3 {
    let p = &mesh.positions;
    let mut n = Vec3::ZERO;
    for i in 0..face.len() {
        let a = p[face[i] as usize];
        let b = p[face[(i + 1) % face.len()] as usize];
        n += Vec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    n.normalize_or_zero()
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
