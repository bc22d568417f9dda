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

/// A rayon pool of `threads` workers (all cores when `None`).
pub fn thread_pool(threads: Option<usize>) -> anyhow::Result<rayon::ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        b = b.num_threads(n);
    }
    Ok(b.build()?)
}
