//! The indexed polygon mesh every reader produces.

use crate::{ErrorKind, Location, MeshError};
use raymesh_geometry::{triangle_is_degenerate, Aabb, Vec3};
use rayon::prelude::*;

/// Positions plus polygonal faces, stored compactly: the faces' vertex
/// indices back to back, and where each face starts (CSR layout).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexedMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// `face_starts[f]..face_starts[f + 1]` is face `f`'s range in `indices`.
    face_starts: Vec<u32>,
    indices: Vec<u32>,
}

/// Counts that `raymesh info` reports.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshStats {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of polygonal faces.
    pub faces: usize,
    /// Number of triangles after fan triangulation.
    pub triangles: usize,
    /// Bounding box of all vertices (empty for no vertices).
    pub bbox: Aabb,
    /// Triangles of zero area (in f64), including those with a repeated vertex.
    pub degenerate_triangles: usize,
    /// Vertices no face uses.
    pub unreferenced_vertices: usize,
}

impl IndexedMesh {
    /// An empty mesh.
    #[must_use]
    pub fn new() -> Self {
        Self {
            positions: Vec::new(),
            face_starts: vec![0],
            indices: Vec::new(),
        }
    }

    /// A mesh with room reserved for the given counts.
    #[must_use]
    pub fn with_capacity(vertices: usize, faces: usize, indices: usize) -> Self {
        let mut face_starts = Vec::with_capacity(faces + 1);
        face_starts.push(0);
        Self {
            positions: Vec::with_capacity(vertices),
            face_starts,
            indices: Vec::with_capacity(indices),
        }
    }

    /// Builds a mesh from positions and triangles, checking every index.
    pub fn from_triangles(positions: Vec<Vec3>, triangles: &[[u32; 3]]) -> Result<Self, MeshError> {
        Self::from_polygons(positions, triangles.iter().map(|t| &t[..]))
    }

    /// Builds a mesh from positions and polygons, checking every index, face
    /// size and coordinate. The error's location is the face number (as a line).
    pub fn from_polygons<'a, I>(positions: Vec<Vec3>, faces: I) -> Result<Self, MeshError>
    where
        I: IntoIterator<Item = &'a [u32]>,
    {
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::new(
                Location::File,
                ErrorKind::NonFinite(format!("in vertex {i}: {:?}", positions[i])),
            ));
        }
        let mut mesh = Self {
            positions,
            ..Self::new()
        };
        for (f, face) in faces.into_iter().enumerate() {
            mesh.push_face(face)
                .map_err(|kind| MeshError::new(Location::Line(f as u64 + 1), kind))?;
        }
        Ok(mesh)
    }

    /// Appends a face after checking its size and indices.
    pub fn push_face(&mut self, face: &[u32]) -> Result<(), ErrorKind> {
        if face.len() < 3 {
            return Err(ErrorKind::FaceTooSmall(face.len()));
        }
        if let Some(&i) = face.iter().find(|&&i| i as usize >= self.positions.len()) {
            return Err(ErrorKind::IndexOutOfRange {
                index: i as i64,
                vertices: self.positions.len(),
            });
        }
        self.push_face_unchecked(face);
        Ok(())
    }

    /// Reserves room for `faces` more triangles' worth of faces.
    pub(crate) fn reserve_faces(&mut self, faces: usize) {
        self.face_starts.reserve(faces);
        self.indices.reserve(3 * faces);
    }

    /// Appends triangles, given as their indices back to back, which the
    /// caller has checked.
    pub(crate) fn append_triangles_unchecked(&mut self, indices: Vec<u32>) {
        let base = self.indices.len() as u32;
        let n = (indices.len() / 3) as u32;
        if self.indices.is_empty() {
            self.indices = indices;
        } else {
            self.indices.extend_from_slice(&indices);
        }
        self.face_starts
            .par_extend((1..=n).into_par_iter().map(|f| base + 3 * f));
    }

    /// Appends a face whose indices the caller has checked.
    pub(crate) fn push_face_unchecked(&mut self, face: &[u32]) {
        self.indices.extend_from_slice(face);
        self.face_starts.push(self.indices.len() as u32);
    }

    /// Number of vertices.
    #[inline]
    #[must_use]
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of polygonal faces.
    #[inline]
    #[must_use]
    pub fn num_faces(&self) -> usize {
        self.face_starts.len() - 1
    }

    /// The vertex indices of face `f`, in winding order.
    #[inline]
    #[must_use]
    pub fn face(&self, f: usize) -> &[u32] {
        &self.indices[self.face_starts[f] as usize..self.face_starts[f + 1] as usize]
    }

    /// Every face in order.
    pub fn faces(&self) -> impl ExactSizeIterator<Item = &[u32]> + '_ {
        self.face_starts
            .windows(2)
            .map(|w| &self.indices[w[0] as usize..w[1] as usize])
    }

    /// Where each face starts in [`Self::indices`], and one past the last face's end.
    #[inline]
    pub(crate) fn face_starts(&self) -> &[u32] {
        &self.face_starts
    }

    /// All faces' indices back to back (see [`Self::face`] for one face).
    #[must_use]
    pub fn indices(&self) -> &[u32] {
        &self.indices
    }

    /// Whether every face is a triangle.
    #[must_use]
    pub fn is_triangle_mesh(&self) -> bool {
        self.indices.len() == 3 * self.num_faces()
    }

    /// Number of triangles of the fan triangulation.
    #[must_use]
    pub fn num_triangles(&self) -> usize {
        self.indices.len() - 2 * self.num_faces()
    }

    /// Fan triangulation `(v0, vi, vi+1)` of every face, in face order.
    #[must_use]
    pub fn triangles(&self) -> Vec<[u32; 3]> {
        let mut out = Vec::with_capacity(self.num_triangles());
        for f in self.faces() {
            for i in 1..f.len() - 1 {
                out.push([f[0], f[i], f[i + 1]]);
            }
        }
        out
    }

    /// For each triangle of [`Self::triangles`], the face it came from.
    #[must_use]
    pub fn triangle_faces(&self) -> Vec<u32> {
        let mut out = Vec::with_capacity(self.num_triangles());
        for (fi, f) in self.faces().enumerate() {
            out.extend(std::iter::repeat_n(fi as u32, f.len() - 2));
        }
        out
    }

    /// Bounding box of all vertices.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::from_points(self.positions.iter().copied())
    }

    /// The figures `raymesh info` prints.
    #[must_use]
    pub fn stats(&self) -> MeshStats {
        let mut used = vec![false; self.positions.len()];
        for &i in &self.indices {
            used[i as usize] = true;
        }
        let p = &self.positions;
        // Each face's fan, in parallel, without a triangle list in between.
        let degenerate = (0..self.num_faces())
            .into_par_iter()
            .map(|f| {
                let face = self.face(f);
                let a = p[face[0] as usize];
                face[1..]
                    .windows(2)
                    .filter(|w| triangle_is_degenerate([a, p[w[0] as usize], p[w[1] as usize]]))
                    .count()
            })
            .sum();
        MeshStats {
            vertices: self.num_vertices(),
            faces: self.num_faces(),
            triangles: self.num_triangles(),
            bbox: self.bounds(),
            degenerate_triangles: degenerate,
            unreferenced_vertices: used.iter().filter(|u| !**u).count(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_and_tri() -> IndexedMesh {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::Z,
            Vec3::ONE,
        ];
        IndexedMesh::from_polygons(p, [&[0u32, 1, 2, 3][..], &[0, 1, 4]]).unwrap()
    }

    #[test]
    fn fan_triangulation_in_face_order() {
        let m = quad_and_tri();
        assert_eq!(m.num_faces(), 2);
        assert_eq!(m.num_triangles(), 3);
        assert_eq!(m.triangles(), vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
        assert_eq!(m.triangle_faces(), vec![0, 0, 1]);
        assert!(!m.is_triangle_mesh());
    }

    #[test]
    fn stats_count_degenerate_and_unreferenced() {
        let mut m = quad_and_tri();
        m.push_face(&[1, 1, 2]).unwrap();
        let s = m.stats();
        assert_eq!(s.degenerate_triangles, 1);
        assert_eq!(s.unreferenced_vertices, 1);
        assert_eq!(s.bbox, Aabb::new(Vec3::ZERO, Vec3::ONE));
    }

    #[test]
    fn bad_faces_are_errors() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        let e = IndexedMesh::from_polygons(p.clone(), [&[0u32, 1][..]]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::FaceTooSmall(2)));
        let e = IndexedMesh::from_triangles(p, &[[0, 1, 3]]).unwrap_err();
        assert!(
            e.to_string()
                .contains("vertex index 3 out of range (3 vertices)"),
            "{e}"
        );
        let e = IndexedMesh::from_triangles(vec![Vec3::NAN; 3], &[[0, 1, 2]]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::NonFinite(_)));
    }

    #[test]
    fn empty_mesh() {
        let m = IndexedMesh::new();
        assert_eq!(m.num_faces(), 0);
        assert_eq!(m.num_triangles(), 0);
        assert!(m.bounds().is_empty());
        assert_eq!(m.stats().unreferenced_vertices, 0);
    }
}
