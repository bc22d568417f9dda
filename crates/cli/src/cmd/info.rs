//! `raymesh info FILE [--json]`.

use anyhow::Result;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `raymesh info`.
#[derive(clap::Args)]
pub struct Args {
    /// Mesh file (.obj, .off, .ply, .stl).
    pub file: PathBuf,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The `--json` object; `f32` fields print in their shortest round-trip form.
#[derive(Serialize)]
struct InfoJson {
    vertices: usize,
    faces: usize,
    triangles: usize,
    /// `[[minx, miny, minz], [maxx, maxy, maxz]]`, or null for a mesh without vertices.
    bbox: Option<[[f32; 3]; 2]>,
    degenerate_triangles: usize,
    unreferenced_vertices: usize,
}

/// Reads the mesh and prints its figures.
pub fn run(args: &Args) -> Result<()> {
    let mesh = crate::cmd::read_mesh(&args.file)?;
    let s = mesh.stats();
    if args.json {
        let out = InfoJson {
            vertices: s.vertices,
            faces: s.faces,
            triangles: s.triangles,
            bbox: (!s.bbox.is_empty()).then(|| [s.bbox.min.to_array(), s.bbox.max.to_array()]),
            degenerate_triangles: s.degenerate_triangles,
            unreferenced_vertices: s.unreferenced_vertices,
        };
        println!("{}", serde_json::to_string(&out)?);
    } else {
        println!("file                   {}", args.file.display());
        println!("vertices               {}", s.vertices);
        println!("faces                  {}", s.faces);
        println!("triangles              {}", s.triangles);
        if s.bbox.is_empty() {
            println!("bounding box           (empty)");
        } else {
            let (a, b) = (s.bbox.min, s.bbox.max);
            let [ax, ay, az, bx, by, bz] = [a.x, a.y, a.z, b.x, b.y, b.z].map(coord);
            println!("bounding box           [{ax}, {ay}, {az}] .. [{bx}, {by}, {bz}]");
        }
        println!("degenerate triangles   {}", s.degenerate_triangles);
        println!("unreferenced vertices  {}", s.unreferenced_vertices);
    }
    Ok(())
}

/// A coordinate as a person reads it: as written below a million and
/// from a ten-thousandth up (`0.125`, `-3`), in scientific notation
/// outside that (`1e38`, not thirty-nine digits; `1.5e-7`). Both forms
/// are the value's shortest round-trip text.
fn coord(x: f32) -> String {
    let a = x.abs();
    if a == 0.0 || (1e-4..1e6).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::coord;

    /// Coordinates read as written in the everyday range and in scientific
    /// notation past it, each the value's own shortest text.
    #[test]
    fn coordinates_read_as_a_person_writes_them() {
        for (x, want) in [
            (0.0, "0"),
            (-3.0, "-3"),
            (0.125, "0.125"),
            (0.0004, "0.0004"),
            (123456.5, "123456.5"),
            (1e6, "1e6"),
            (-1e38, "-1e38"),
            (1.5e-7, "1.5e-7"),
            (f32::MAX, "3.4028235e38"),
        ] {
            assert_eq!(coord(x), want, "{x}");
            assert_eq!(coord(x).parse::<f32>(), Ok(x));
        }
    }
}
