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
            println!(
                "bounding box           [{}, {}, {}] .. [{}, {}, {}]",
                a.x, a.y, a.z, b.x, b.y, b.z
            );
        }
        println!("degenerate triangles   {}", s.degenerate_triangles);
        println!("unreferenced vertices  {}", s.unreferenced_vertices);
    }
    Ok(())
}
