//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `raymesh` binary under test.
pub fn raymesh() -> Command {
    Command::new(env!("CARGO_BIN_EXE_raymesh"))
}

/// A fixture mesh in `tests/data`.
pub fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name)
}

/// A fresh temporary folder for one test, removed with everything in it
/// when the test ends, whether it passes or fails (a failing test's files
/// would otherwise pile up in the temporary folder, one per run).
pub struct TmpDir(tempfile::TempDir);

impl std::ops::Deref for TmpDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<Path> for TmpDir {
    fn as_ref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<std::ffi::OsStr> for TmpDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.path().as_os_str()
    }
}

/// A fresh temporary folder for one test, named `raymesh-TAG-…` (see
/// [`TmpDir`]).
pub fn tmpdir(tag: &str) -> TmpDir {
    TmpDir(
        tempfile::Builder::new()
            .prefix(&format!("raymesh-{tag}-"))
            .tempdir()
            .unwrap(),
    )
}

/// Runs `cmd`, which must succeed; its standard output.
pub fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Runs `cmd`, which must fail with `needle` in its standard error.
pub fn fails_with(cmd: &mut Command, needle: &str) {
    let out = cmd.output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(needle), "{needle:?} not in {err}");
}

/// Writes BENCH.md's `workload` rays for `mesh` at image size `size` to
/// `out` (`raymesh rays`).
pub fn write_rays(mesh: &Path, workload: &str, size: u32, out: &Path) {
    run_ok(
        raymesh()
            .arg("rays")
            .arg(mesh)
            .args(["--workload", workload, "--size", &size.to_string(), "-o"])
            .arg(out),
    );
}
