//! One module per subcommand.

pub mod bench;
pub mod generate;
pub mod info;
pub mod mesh;
pub mod raycast;
pub mod rays;
pub mod render;
pub mod scale;
pub mod subdivide;

/// Parses a non-negative, finite fraction (`--spatial-splits`): at most
/// 4, four times as many references as primitives, far past what pays.
pub fn parse_fraction(s: &str) -> Result<f32, String> {
    let f: f32 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if (0.0..=4.0).contains(&f) {
        Ok(f)
    } else {
        Err(format!("'{s}' is not a fraction in 0..=4"))
    }
}

/// Whether `a` and `b` name the same existing file (through links too:
/// the same device and inode on Unix, the same canonical path elsewhere).
pub fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        match (a.canonicalize(), b.canonicalize()) {
            (Ok(x), Ok(y)) => x == y,
            _ => false,
        }
    }
}

/// Checks, before the command's work, that `output` can be written where
/// it is named ([`raymesh::check_writable`]), and is none of the command's
/// `inputs` ([`refuse_output_over_input`]).
pub fn check_output(
    output: &std::path::Path,
    inputs: &[(&str, &std::path::Path)],
) -> anyhow::Result<()> {
    raymesh::check_writable(output)?;
    refuse_output_over_input(output, inputs)
}

/// Refuses an output that is one of the command's inputs (`inputs`: what
/// each is, and its path), called before the command's work (`render`
/// reads a mesh first, to frame it): writing it would destroy the
/// input the user gave (`raymesh subdivide m.off -o m.off`, or `raymesh
/// rays m.off -o m.off` by a slip of the keyboard). Any other existing
/// file named as the output is overwritten, as asked.
pub fn refuse_output_over_input(
    output: &std::path::Path,
    inputs: &[(&str, &std::path::Path)],
) -> anyhow::Result<()> {
    for (what, input) in inputs {
        if same_file(output, input) {
            anyhow::bail!(
                "{}: this is the input {what} {}; writing the output there would destroy it \
                 (choose another output name)",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Refuses `--spatial-splits` or `--optimize` with a structure that
/// would ignore it (`--accel grid --spatial-splits` built a grid and
/// reported the run as one with spatial splits).
pub fn check_build_flags(
    accel: raymesh_accel::AccelKind,
    spatial_splits: bool,
    optimize: bool,
) -> anyhow::Result<()> {
    if spatial_splits && !accel.takes_spatial_splits() {
        anyhow::bail!(
            "--spatial-splits applies to bvh-binned, bvh4 and bvh8 (and bvh), not {}",
            accel.name()
        );
    }
    if optimize && !accel.is_bvh() {
        anyhow::bail!(
            "--optimize rearranges BVHs (bvh-median, bvh-binned, bvh-sweep, bvh4, bvh8), not {}",
            accel.name()
        );
    }
    Ok(())
}

/// The most worker threads a command takes: more than the largest
/// machines have cores, and far below where a pool stops being usable
/// (on the 2-core VM, `raycast --threads 2000` on a tetrahedron took 2.7
/// s, 20000 over a minute, all of it the pool's threads starting and
/// waiting on one another).
pub const MAX_THREADS: usize = 1024;

/// A rayon pool of `threads` workers (all cores when `None`), at least
/// one and at most [`MAX_THREADS`].
pub fn thread_pool(threads: Option<usize>) -> anyhow::Result<rayon::ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        anyhow::ensure!(
            n <= MAX_THREADS,
            "--threads {n}: at most {MAX_THREADS} worker threads (this machine has {})",
            std::thread::available_parallelism().map_or(1, usize::from)
        );
        b = b.num_threads(n);
    }
    Ok(b.build()?)
}

/// A spinner on stderr naming the step under way (reading a file, building
/// a structure), with the time it has taken so far; hidden when stderr is
/// not a terminal. Clear it with `finish_and_clear` when the step is done.
pub fn stage(msg: String) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let b = indicatif::ProgressBar::new_spinner();
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} {msg} {elapsed}") {
        b.set_style(style);
    }
    b.set_message(msg);
    b.enable_steady_tick(std::time::Duration::from_millis(100));
    b
}

pub use raymesh::rate;

/// Reads a mesh file with a progress bar on a terminal: bytes while the
/// file comes in, then a spinner while it is parsed.
pub fn read_mesh(path: &std::path::Path) -> anyhow::Result<raymesh_mesh::IndexedMesh> {
    use std::io::IsTerminal;
    let name = path.display().to_string();
    let terminal = std::io::stderr().is_terminal();
    // Drawn from the first report on, once the file's size is known.
    let bar = indicatif::ProgressBar::hidden();
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "reading {msg} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} {eta}",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(name.clone());
    let mut parsing = None;
    let mesh = raymesh_mesh::io::read_mesh_with(path, &mut |done, total| {
        if terminal && bar.is_hidden() && done < total {
            bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
        }
        bar.set_length(total);
        bar.set_position(done);
        if done == total && parsing.is_none() {
            bar.finish_and_clear();
            parsing = Some(stage(format!("parsing {name}")));
        }
    });
    bar.finish_and_clear();
    if let Some(p) = parsing {
        p.finish_and_clear();
    }
    Ok(mesh?)
}
