//! `raymesh`: ray queries on triangle meshes and mesh connectivity, from the
//! command line. Each subcommand lives in its own module under `cmd/`.

mod cmd;

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(a) => cmd::info::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("raymesh: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
