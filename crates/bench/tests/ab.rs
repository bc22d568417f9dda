//! `raymesh-ab` end to end: a build compared with itself, and baselines
//! that cannot serve.

use std::process::Command;

const MESH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../tests/data/elephant-with-holes.off"
);

fn ab(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_raymesh-ab"))
        .arg(MESH)
        .args(args)
        .output()
        .expect("raymesh-ab runs")
}

#[test]
fn a_build_compared_with_itself_returns_the_same_hits() {
    for mode in [&[][..], &["--packets"], &["--stream"]] {
        let mut args = vec!["--workload", "random", "--size", "24", "--chunk", "100"];
        args.extend(["--rounds", "1", "--accel", "bvh-binned", "--json"]);
        args.extend(mode);
        let out = ab(&args);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{mode:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let reports: Vec<serde_json::Value> = stdout
            .lines()
            .map(|l| serde_json::from_str(l).expect("a JSON line"))
            .collect();
        let queries: Vec<&str> = reports
            .iter()
            .map(|r| r["query"].as_str().unwrap())
            .collect();
        assert_eq!(queries, ["closest", "any-hit"], "{mode:?}");
        for r in &reports {
            assert_eq!(r["rays"], 576);
            // 576 rays in chunks of 100: six chunks, the last of 76.
            assert_eq!(r["chunks"], 6);
            assert_eq!(r["same_hits"], true, "{r}");
            let speedup = r["speedup"].as_f64().unwrap();
            assert!(speedup.is_finite() && speedup > 0.0, "{r}");
            assert!(r["chunk_q1"].as_f64() <= r["chunk_q3"].as_f64(), "{r}");
        }
    }
}

#[test]
fn a_rays_file_is_read_as_given() {
    let tmp = tempfile::Builder::new()
        .prefix("raymesh-ab-test-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let rays = dir.join("rays.npy");
    let mut file = std::fs::File::create(&rays).unwrap();
    raymesh::npy::write_rays(
        &mut file,
        &[
            [0.0, 0.0, -5.0, 0.0, 0.0, 0.0, 1.0, f32::INFINITY],
            [0.0, 0.0, 5.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY],
            [5.0, 5.0, 5.0, 0.0, 1.0, 0.0, 0.0, f32::INFINITY],
        ],
    )
    .unwrap();
    drop(file);
    let out = ab(&[
        "--rays",
        rays.to_str().unwrap(),
        "--query",
        "closest",
        "--rounds",
        "2",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("3 rays"), "{stdout}");
    assert!(stdout.contains("the same hits"), "{stdout}");
}

#[test]
fn baselines_that_cannot_serve_are_named() {
    let out = ab(&["--baseline", "/nonexistent/raymesh-ab", "--size", "8"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("starting the baseline build"), "{err}");
    // A program that is not raymesh-ab: it answers nothing.
    let out = ab(&["--baseline", "/bin/true", "--size", "8"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("the baseline build stopped"), "{err}");
}

#[test]
fn bad_settings_are_refused() {
    for (args, what) in [
        (&["--query", "nearest"][..], "unknown query 'nearest'"),
        (&["--chunk", "0"], "--chunk must be at least 1"),
        (&["--rounds", "0"], "--rounds must be at least 1"),
        // A negative count is a value, not a flag `-1`.
        (&["--rounds", "-1"], "for '--rounds <ROUNDS>'"),
        (&["--chunk", "-5"], "for '--chunk <CHUNK>'"),
        (&["--set", "leaves=4"], "unknown setting 'leaves'"),
        (
            &["--baseline-set", "max_leaf"],
            "setting 'max_leaf': expected KEY=VALUE",
        ),
        (
            &["--set", "max_leaf=0"],
            "setting max_leaf: '0' is not a count of 1 or more",
        ),
        (
            &["--set", "bins=65"],
            "setting bins: '65' is not between 2 and 64",
        ),
        (
            &["--set", "traversal_cost=-1"],
            "is not a number of 0 or more",
        ),
        (
            &["--set", "optimize=yes"],
            "setting optimize: 'yes' is not true or false",
        ),
    ] {
        let out = ab(args);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(what), "{args:?}: {err}");
    }
}

/// One binary, two build settings: leaves of at most 4 against the
/// default. Closest hits are the same whatever the tree; the report
/// names both settings.
#[test]
fn two_settings_of_one_binary() {
    let out = ab(&[
        "--workload",
        "random",
        "--size",
        "24",
        "--rounds",
        "1",
        "--accel",
        "bvh-binned",
        "--query",
        "closest",
        "--set",
        "max_leaf=16,traversal_cost=3",
        "--baseline-set",
        "max_leaf=4",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).trim()).expect("one JSON line");
    assert_eq!(r["same_hits"], true, "{r}");
    assert_eq!(r["set"], "max_leaf=16,traversal_cost=3", "{r}");
    assert_eq!(r["baseline_set"], "max_leaf=4", "{r}");
    // Smaller leaves, more nodes: the settings took.
    let nodes = |k: &str| r[k].as_u64().unwrap_or_else(|| panic!("{k} in {r}"));
    assert!(nodes("baseline_nodes") > nodes("nodes"), "{r}");
    let text = ab(&[
        "--workload",
        "random",
        "--size",
        "16",
        "--rounds",
        "1",
        "--baseline-set",
        "bins=8",
    ]);
    assert!(text.status.success());
    let stdout = String::from_utf8_lossy(&text.stdout);
    assert!(
        stdout.contains("settings: baseline bins=8, this build defaults"),
        "{stdout}"
    );
}
