//! `raymesh`: ray queries on triangle meshes and mesh connectivity, from the
//! command line. Each subcommand lives in its own module under `cmd/`.

mod cmd;

use raymesh::{npy, workload};

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Ray queries on triangle meshes, acceleration structures and mesh connectivity.
#[derive(Parser)]
#[command(name = "raymesh", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print counts, bounding box, degenerate triangles and unreferenced vertices of a mesh file.
    Info(cmd::info::Args),
    /// Cast rays from a .npy file at a mesh through a chosen acceleration structure.
    Raycast(cmd::raycast::Args),
    /// Run BENCH.md's workloads through the chosen structures and report speed, size and cost.
    Bench(cmd::bench::Args),
    /// Write one of BENCH.md's ray workloads for a mesh as a .npy file.
    Rays(cmd::rays::Args),
    /// Connectivity of a mesh (half-edge, winged-edge, compact): topology, repairs, memory, timings.
    Mesh(cmd::mesh::Args),
    /// Subdivide a mesh (Loop or Catmull–Clark) and write the result.
    Subdivide(cmd::subdivide::Args),
    /// Write a synthetic mesh of any size: terrain, sphere, or the teapot in a stadium.
    Generate(cmd::generate::Args),
    /// How build and trace scale with the triangle count (synthetic terrains), with a log-log chart.
    Scale(cmd::scale::Args),
    /// Ray-trace a scene file, a mesh, or (with no argument) the built-in demo to PNG.
    Render(cmd::render::Args),
}

/// Ends quietly when the reader of our output goes away (`raymesh … | head`):
/// `println!` panics on a broken pipe, and that is no error of the user's.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("Broken pipe") {
            std::process::exit(141); // 128 + SIGPIPE, as shells report it
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(a) => cmd::info::run(&a),
        Command::Raycast(a) => cmd::raycast::run(&a),
        Command::Rays(a) => cmd::rays::run(&a),
        Command::Bench(a) => cmd::bench::run(&a),
        Command::Render(a) => cmd::render::run(&a),
        Command::Mesh(a) => cmd::mesh::run(&a),
        Command::Subdivide(a) => cmd::subdivide::run(&a),
        Command::Generate(a) => cmd::generate::run(&a),
        Command::Scale(a) => cmd::scale::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("raymesh: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
