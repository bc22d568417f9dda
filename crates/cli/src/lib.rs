//! Support code of the `raymesh` tool that the benchmark crate shares: the
//! numpy ray and hit files of `../shared/BENCH.md`, its ray workloads, how
//! tables print rates, and the check that an output can be written.

pub mod npy;
pub mod workload;

/// A rate for a table: two decimals, or three significant digits when it
/// is below 0.1 (a grid on the teapot in a stadium runs at 0.0016 Mrays/s,
/// which two decimals would print as 0.00).
pub fn rate(x: f64) -> String {
    if x > 0.0 && x < 0.1 {
        let digits = (2 - x.log10().floor() as i32).clamp(0, 9) as usize;
        format!("{x:.digits$}")
    } else {
        format!("{x:.2}")
    }
}

/// Checks that a file can be made at `output`: its folder exists (raymesh
/// makes no folders) and it is not a folder itself. Commands call it
/// before their work: without it a render, a subdivision or a benchmark
/// ran to its end and then failed to write, its work lost.
pub fn check_writable(output: &std::path::Path) -> anyhow::Result<()> {
    if output.is_dir() {
        anyhow::bail!(
            "{}: this is a folder; name a file to write",
            output.display()
        );
    }
    let folder = output.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(folder) = folder {
        if !folder.is_dir() {
            let why = if folder.exists() {
                "is not a folder"
            } else {
                "does not exist"
            };
            anyhow::bail!(
                "{}: cannot write there: {} {why}",
                output.display(),
                folder.display()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn writable_paths_need_an_existing_folder_and_a_file_name() {
        let tmp = tempfile::Builder::new()
            .prefix("raymesh-writable-")
            .tempdir()
            .unwrap();
        let dir = tmp.path();
        let file = dir.join("f.txt");
        std::fs::write(&file, "x").unwrap();
        let err = |p: &std::path::Path| super::check_writable(p).unwrap_err().to_string();
        // An existing file is the caller's to overwrite; a bare name is in
        // the working folder.
        super::check_writable(&file).unwrap();
        super::check_writable(&dir.join("new.png")).unwrap();
        super::check_writable(std::path::Path::new("new.png")).unwrap();
        assert!(err(dir).ends_with("this is a folder; name a file to write"));
        let missing = dir.join("missing").join("a.png");
        assert!(
            err(&missing).ends_with(&format!("{} does not exist", dir.join("missing").display()))
        );
        assert!(err(&file.join("a.png")).ends_with(&format!("{} is not a folder", file.display())));
    }

    #[test]
    fn small_rates_keep_three_significant_digits() {
        assert_eq!(super::rate(5.26), "5.26");
        assert_eq!(super::rate(0.25), "0.25");
        assert_eq!(super::rate(0.0016), "0.00160");
        assert_eq!(super::rate(0.04), "0.0400");
        assert_eq!(super::rate(0.0), "0.00");
    }
}

/// The README's Rust examples, run as doctests so that they keep up with
/// the library.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;
