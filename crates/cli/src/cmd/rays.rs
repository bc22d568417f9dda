//! `raymesh rays MESH --workload NAME [--size N] [--seed S] -o RAYS.npy`: the
//! ray workloads of BENCH.md as .npy files, for `raycast` and for peers.

use crate::npy;
use crate::workload::{make_rays_framing, parse_frame, Workload};
use anyhow::{bail, Context, Result};
use raymesh_accel::{AccelKind, Scene, Surface, TriangleMesh};
use std::path::PathBuf;

/// Arguments of `raymesh rays`.
#[derive(clap::Args)]
pub struct Args {
    /// Mesh file the workload is defined from (its bounding box, and hits for diffuse and shadow rays).
    pub mesh: PathBuf,
    /// primary, random, diffuse or shadow (see ../shared/BENCH.md).
    #[arg(long)]
    pub workload: Workload,
    /// Image width and height (random: the square root of the ray count).
    #[arg(long, allow_negative_numbers = true, default_value_t = 1024)]
    pub size: u32,
    /// Seed of the random workloads.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1)]
    pub seed: u64,
    /// Aim at this box instead of the mesh's whole box: six numbers,
    /// `minx,miny,minz,maxx,maxy,maxz` (e.g. `-1,0,-1,1,2,1` for the teapot
    /// of `raymesh generate teapot-in-stadium`).
    #[arg(long, allow_hyphen_values = true)]
    pub frame: Option<String>,
    /// Output .npy file (overwritten if it exists).
    #[arg(long, short = 'o', visible_alias = "output")]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: &Args) -> Result<()> {
    // 8192² rays are 2 GiB of .npy; more would not fit a machine like ours.
    if args.size == 0 || args.size > 8192 {
        bail!("--size must be in 1..=8192");
    }
    crate::cmd::check_output(&args.out, &[("mesh", &args.mesh)])?;
    let mesh = crate::cmd::read_mesh(&args.mesh)?;
    let scene = Scene::build(
        TriangleMesh::new(mesh.positions.clone(), mesh.triangles()),
        AccelKind::FASTEST_BVH,
    );
    let frame = match &args.frame {
        None => scene.bounds(),
        Some(text) => parse_frame(text)?,
    };
    let rays = make_rays_framing(args.workload, &scene, frame, args.size, args.seed);
    let f = std::fs::File::create(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let mut w = std::io::BufWriter::new(f);
    npy::write_rays(&mut w, &rays)
        .and_then(|()| std::io::Write::flush(&mut w))
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    eprintln!(
        "wrote {} {} rays to {}",
        rays.len(),
        args.workload.name(),
        args.out.display()
    );
    Ok(())
}
