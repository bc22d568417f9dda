//! Synthetic meshes of any size, for scaling benchmarks and tests: a
//! height-field terrain, a UV sphere, the "teapot in a stadium" (a small
//! dense mesh inside a large sparse one, the case where a uniform grid's
//! one cell size fits neither; Haines, "Spline surface rendering, and
//! what's wrong with octrees", 1988, coined the name), and slivers (small
//! triangles with long thin ones across them, the case for spatial splits).
//!
//! All are y-up, deterministic (no seeds: slivers use one fixed sequence),
//! and made of non-degenerate triangles.

use crate::IndexedMesh;
use raymesh_geometry::{Aabb, Vec3};
use std::f32::consts::{PI, TAU};

/// Positions and triangles: the lean form a generator returns, without the
/// face table of an [`IndexedMesh`] (which costs 4 more bytes a triangle).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Triangulated {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Corner indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
}

impl Triangulated {
    /// The same triangles as an [`IndexedMesh`] (to write or to query).
    #[must_use]
    pub fn into_indexed(self) -> IndexedMesh {
        IndexedMesh::from_triangles(self.positions, &self.triangles)
            .expect("generators make indices in range")
    }

    /// Bounding box of the positions.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::from_points(self.positions.iter().copied())
    }

    /// Appends `other`'s triangles (its indices shifted).
    pub fn append(&mut self, other: &Self) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// The triangles moved and scaled so that their box is centred on
    /// `center` with its longest side `size` long.
    #[must_use]
    pub fn fitted(mut self, center: Vec3, size: f32) -> Self {
        let b = self.bounds();
        let scale = size / b.extent().max_element().max(f32::MIN_POSITIVE);
        let c = b.centroid();
        for p in &mut self.positions {
            *p = center + (*p - c) * scale;
        }
        self
    }
}

/// A grid of `cols × rows` quads over `[0, 1]²`, two triangles each, with
/// vertex `(i, j)` at `at(i / cols, j / rows)`; `wrap_u` joins the last
/// column to the first (for surfaces of revolution).
fn quad_grid(cols: u32, rows: u32, wrap_u: bool, at: impl Fn(f32, f32) -> Vec3) -> Triangulated {
    let vcols = if wrap_u { cols } else { cols + 1 };
    let mut positions = Vec::with_capacity(vcols as usize * (rows as usize + 1));
    for j in 0..=rows {
        for i in 0..vcols {
            positions.push(at(i as f32 / cols as f32, j as f32 / rows as f32));
        }
    }
    let mut triangles = Vec::with_capacity(2 * cols as usize * rows as usize);
    for j in 0..rows {
        for i in 0..cols {
            let i1 = if wrap_u { (i + 1) % vcols } else { i + 1 };
            let (a, b) = (j * vcols + i, j * vcols + i1);
            let (c, d) = (a + vcols, b + vcols);
            triangles.push([a, c, b]);
            triangles.push([b, c, d]);
        }
    }
    Triangulated {
        positions,
        triangles,
    }
}

/// Height of the terrain at `(x, z)` in `[-1, 1]²`: a few octaves of
/// sines, so that rays meet slopes, ridges and valleys at every scale.
fn height(x: f32, z: f32) -> f32 {
    0.15 * (3.1 * x).sin() * (2.3 * z).cos()
        + 0.06 * (7.7 * x + 5.3 * z).sin()
        + 0.025 * (19.0 * x - 13.0 * z).cos()
        + 0.01 * (47.0 * x + 41.0 * z).sin()
}

/// A height-field terrain over `[-1, 1]²` (y up) of at least `triangles`
/// triangles (and fewer than that plus one row of quads): a square grid
/// of quads. About 0.5 vertices a triangle, so 18 bytes a triangle.
#[must_use]
pub fn terrain(triangles: usize) -> Triangulated {
    let quads = triangles.div_ceil(2).max(1);
    let cols = ((quads as f64).sqrt().ceil() as u32).max(1);
    let rows = (quads as u32).div_ceil(cols).max(1);
    quad_grid(cols, rows, false, |u, v| {
        let (x, z) = (2.0 * u - 1.0, 2.0 * v - 1.0);
        Vec3::new(x, height(x, z), z)
    })
}

/// A UV sphere of about `triangles` triangles (twice as many segments
/// around as rings; the poles' triangles are thin but not degenerate).
#[must_use]
pub fn uv_sphere(triangles: usize, center: Vec3, radius: f32) -> Triangulated {
    // 2 · segments · rings triangles with segments = 2 · rings.
    let rings = (((triangles.max(16) as f64) / 4.0).sqrt().round() as u32).max(2);
    let segments = 2 * rings;
    // Rings stop short of the poles by half a step, so no quad collapses.
    quad_grid(segments, rings, true, |u, v| {
        let theta = PI * (0.5 + v * (rings as f32 - 1.0)) / rings as f32;
        let phi = TAU * u;
        center
            + radius
                * Vec3::new(
                    theta.sin() * phi.cos(),
                    -theta.cos(),
                    theta.sin() * phi.sin(),
                )
    })
}

/// Radius of the stadium's field; its stands rise from there.
pub const STADIUM_FIELD_RADIUS: f32 = 50.0;

/// A stadium of about `triangles` triangles: a round field of radius
/// [`STADIUM_FIELD_RADIUS`] (y = 0) and stands rising from its edge to
/// twice that radius and a fifth of it high. Large, sparse triangles.
#[must_use]
pub fn stadium(triangles: usize) -> Triangulated {
    let r = STADIUM_FIELD_RADIUS;
    // Half the triangles for the stands, half for the field.
    let per = (triangles / 2).max(16);
    let rings = (((per as f64) / 4.0).sqrt().round() as u32).max(2);
    let segments = 2 * rings;
    let stands = quad_grid(segments, rings, true, |u, v| {
        let phi = TAU * u;
        let radius = r * (1.0 + v);
        Vec3::new(radius * phi.cos(), 0.2 * r * v, radius * phi.sin())
    });
    // The field: concentric rings from a small inner circle, so that no
    // triangle degenerates at the centre.
    let mut field = quad_grid(segments, rings, true, |u, v| {
        let phi = TAU * u;
        let radius = r * (0.02 + 0.98 * v);
        Vec3::new(radius * phi.cos(), 0.0, radius * phi.sin())
    });
    // Close the inner circle with a fan around the centre.
    let centre = field.positions.len() as u32;
    field.positions.push(Vec3::ZERO);
    for i in 0..segments {
        field.triangles.push([centre, (i + 1) % segments, i]);
    }
    let mut out = stands;
    out.append(&field);
    out
}

/// The teapot in a stadium: `teapot` scaled to 2 units across and set on
/// the middle of a [`stadium`] of `stadium_triangles` triangles, 100 times
/// wider. A uniform grid sized for the whole scene puts the dense mesh in
/// a handful of cells with thousands of triangles each; hierarchies adapt.
#[must_use]
pub fn teapot_in_stadium(teapot: Triangulated, stadium_triangles: usize) -> Triangulated {
    let mut out = stadium(stadium_triangles);
    out.append(&teapot.fitted(Vec3::new(0.0, 1.0, 0.0), 2.0));
    out
}

/// Small triangles scattered through the cube `[0, 8]³`, one in twenty a
/// long thin sliver from its corner to a far point of the cube: what
/// architectural scenes (beams, walls, cables) do to a BVH. A sliver's box
/// overlaps everything along it, so every object split near it leaves two
/// overlapping children; spatial splits (`BuildConfig::spatial_splits`)
/// cut it into parts instead. `triangles` triangles, three vertices each,
/// from one fixed xorshift sequence.
#[must_use]
pub fn slivers(triangles: usize) -> Triangulated {
    let mut s = 0x9e37_79b9_u32;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut unit = move || Vec3::new(next(), next(), next());
    let mut positions = Vec::with_capacity(3 * triangles);
    for i in 0..triangles {
        let a = unit() * 8.0;
        let far = unit() * 8.0;
        // Along the triangle: a sliver to the far point, else a step of
        // 0.05 to 0.15 toward it; across it, a width of 0.01 to 0.05 at a
        // right angle, so that no triangle degenerates.
        let mut d = far - a;
        if d.length() < 1.0 {
            // Too near: four units along x instead, inside the cube.
            d = Vec3::X * if a.x < 4.0 { 4.0 } else { -4.0 };
        }
        let along = if i % 20 == 0 {
            d
        } else {
            d.normalize() * (0.05 + 0.1 * (i % 7) as f32 / 6.0)
        };
        let across = along.any_orthonormal_vector() * (0.01 + 0.04 * (i % 5) as f32 / 4.0);
        positions.extend([a, a + along, a + across]);
    }
    let triangles = (0..triangles as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    Triangulated {
        positions,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use raymesh_geometry::triangle_area2;

    #[test]
    fn slivers_are_clean_and_one_in_twenty_is_long() {
        let m = slivers(4000);
        check(&m);
        assert_eq!(m.triangles.len(), 4000);
        let long = m
            .triangles
            .iter()
            .filter(|t| {
                let [a, b, _] = t.map(|i| m.positions[i as usize]);
                (b - a).length() >= 1.0
            })
            .count();
        assert_eq!(long, 200);
        let b = m.bounds();
        assert!(
            b.min.min_element() > -0.25 && b.max.max_element() < 8.25,
            "{b:?}"
        );
        assert_eq!(slivers(4000), m, "the same mesh every time");
    }

    fn check(mesh: &Triangulated) {
        let n = mesh.positions.len() as u32;
        for t in &mesh.triangles {
            assert!(t.iter().all(|&i| i < n), "index out of range: {t:?}");
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            assert!(triangle_area2(a, b, c) > 0.0, "degenerate triangle {t:?}");
        }
        // Every vertex is used.
        let mut used = vec![false; n as usize];
        mesh.triangles
            .iter()
            .flatten()
            .for_each(|&i| used[i as usize] = true);
        assert!(used.iter().all(|&u| u));
    }

    #[test]
    fn terrain_has_the_asked_size_and_is_a_clean_height_field() {
        for n in [1, 2, 3, 100, 1001, 20_000] {
            let t = terrain(n);
            assert!(t.triangles.len() >= n, "{n}: {}", t.triangles.len());
            let cols = ((n.div_ceil(2) as f64).sqrt().ceil() as usize).max(1);
            assert!(
                t.triangles.len() < n + 2 * cols + 2,
                "{n}: {}",
                t.triangles.len()
            );
            check(&t);
            let b = t.bounds();
            assert_eq!((b.min.x, b.max.x, b.min.z, b.max.z), (-1.0, 1.0, -1.0, 1.0));
            assert!(b.max.y < 0.3 && b.min.y > -0.3);
        }
        // Manifold with one boundary: a closed mesh it is not, but the
        // half-edge structure takes it.
        let he = crate::HalfEdgeMesh::from_indexed(&terrain(500).into_indexed());
        he.validate().unwrap();
    }

    #[test]
    fn sphere_and_stadium_are_clean() {
        let s = uv_sphere(5000, Vec3::new(1.0, 2.0, 3.0), 2.0);
        check(&s);
        assert!((s.triangles.len() as f64 / 5000.0 - 1.0).abs() < 0.1);
        for p in &s.positions {
            assert!(((*p - Vec3::new(1.0, 2.0, 3.0)).length() - 2.0).abs() < 1e-5);
        }
        let he = crate::HalfEdgeMesh::from_indexed(&s.clone().into_indexed());
        he.validate().unwrap();
        assert!(he.boundary_loops().len() == 2, "open at the poles");

        let st = stadium(4000);
        check(&st);
        let b = st.bounds();
        assert!((b.max.x - 2.0 * STADIUM_FIELD_RADIUS).abs() < 1e-3);
    }

    #[test]
    fn the_teapot_sits_small_in_the_middle() {
        let scene = teapot_in_stadium(uv_sphere(10_000, Vec3::ZERO, 7.0), 2000);
        check(&scene);
        let teapot = &scene.positions[scene.positions.len() - 1..][0];
        assert!(teapot.length() < 3.0);
        let b = scene.bounds();
        assert!(b.extent().x > 100.0 * 1.9);
        // Most triangles are in the teapot's 2-unit box.
        let small = Aabb::new(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0));
        let inside = scene
            .triangles
            .iter()
            .filter(|t| {
                t.iter()
                    .all(|&i| small.contains(scene.positions[i as usize]))
            })
            .count();
        assert!(inside >= 9000, "{inside}");
    }
}
