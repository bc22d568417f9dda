//! `--threads LIST`, shared by the benchmark binaries.

use anyhow::{bail, Context, Result};

/// The thread counts of a comma-separated list, each at least 1.
pub fn parse(list: &str) -> Result<Vec<usize>> {
    let threads: Vec<usize> = list
        .split(',')
        .map(|t| t.trim().parse())
        .collect::<Result<_, _>>()
        .context("--threads: a comma-separated list of counts")?;
    if threads.contains(&0) {
        bail!("thread counts must be at least 1");
    }
    Ok(threads)
}
