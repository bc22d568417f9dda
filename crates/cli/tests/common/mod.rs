//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::PathBuf;
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

/// A fresh temporary folder for one test.
pub fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("raymesh-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
