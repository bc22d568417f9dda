//! `raymesh generate terrain|sphere|teapot-in-stadium|slivers -o OUT [--triangles N] [--teapot MESH]`.

use anyhow::{bail, Result};
use raymesh_mesh::io::{read_mesh, write_mesh, Format};
use raymesh_mesh::synthetic::{self, Triangulated};
use raymesh_mesh::Vec3;
use std::path::PathBuf;
use std::time::Instant;

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Kind {
    /// A height-field terrain over [-1, 1]² (y up), a square grid of quads.
    Terrain,
    /// A UV sphere of radius 1.
    Sphere,
    /// A dense mesh 2 units across on the field of a stadium 200 units
    /// across: the case a uniform grid handles worst.
    TeapotInStadium,
    /// Small triangles scattered through a cube, one in twenty a long thin
    /// sliver across it: the case spatial splits (`raycast
    /// --spatial-splits`) are for.
    Slivers,
}

/// Arguments of `raymesh generate`.
#[derive(clap::Args)]
pub struct Args {
    /// What to generate.
    #[arg(value_enum)]
    pub kind: Kind,
    /// Output mesh (.ply is binary; .obj and .off also work). Overwritten if it exists.
    #[arg(short = 'o', long = "output", visible_alias = "out")]
    pub output: PathBuf,
    /// Triangles (at least; terrain and sphere round up to whole rows). For
    /// teapot-in-stadium: the teapot's, when no --teapot file is given (a sphere).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1_000_000)]
    pub triangles: usize,
    /// teapot-in-stadium: the mesh to use as the teapot (any mesh file; it is scaled to 2 units).
    #[arg(long)]
    pub teapot: Option<PathBuf>,
    /// teapot-in-stadium: triangles of the stadium.
    #[arg(long, allow_negative_numbers = true, default_value_t = 2_000)]
    pub stadium_triangles: usize,
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    if Format::from_extension(&args.output).is_none_or(|f| f == Format::Stl) {
        bail!(
            "{}: the output must be .obj, .off or .ply",
            args.output.display()
        );
    }
    for (flag, n) in [
        ("--triangles", args.triangles),
        ("--stadium-triangles", args.stadium_triangles),
    ] {
        if n == 0 || n > (u32::MAX / 4) as usize {
            bail!(
                "{flag} must be between 1 and {} (32-bit indices)",
                u32::MAX / 4
            );
        }
    }
    if args.teapot.is_some() && args.kind != Kind::TeapotInStadium {
        bail!("--teapot goes with teapot-in-stadium");
    }
    let teapot: Vec<(&str, &std::path::Path)> = args
        .teapot
        .iter()
        .map(|t| ("--teapot mesh", t.as_path()))
        .collect();
    crate::cmd::check_output(&args.output, &teapot)?;
    let start = Instant::now();
    let mesh = match args.kind {
        Kind::Terrain => synthetic::terrain(args.triangles),
        Kind::Sphere => synthetic::uv_sphere(args.triangles, Vec3::ZERO, 1.0),
        Kind::Slivers => synthetic::slivers(args.triangles),
        Kind::TeapotInStadium => {
            let teapot = match &args.teapot {
                Some(path) => {
                    let m = read_mesh(path)?;
                    Triangulated {
                        triangles: m.triangles(),
                        positions: m.positions,
                    }
                }
                None => synthetic::uv_sphere(args.triangles, Vec3::ZERO, 1.0),
            };
            synthetic::teapot_in_stadium(teapot, args.stadium_triangles)
        }
    };
    let (v, t) = (mesh.positions.len(), mesh.triangles.len());
    let secs = start.elapsed().as_secs_f64();
    write_mesh(&args.output, &mesh.into_indexed())?;
    println!(
        "{:?}: {v} vertices, {t} triangles in {secs:.2} s; wrote {}",
        args.kind,
        args.output.display()
    );
    Ok(())
}
