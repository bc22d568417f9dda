//! `raymesh-mesh-peers` end to end: the rows it reports and, where the
//! crate is built with `--features openmesh`, OpenMesh's agreement.

use std::process::Command;

fn data(name: &str) -> String {
    format!("{}/../../tests/data/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn run(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_raymesh-mesh-peers"))
        .args(args)
        .output()
        .expect("raymesh-mesh-peers runs")
}

#[test]
fn every_operation_is_reported_and_openmesh_agrees_where_built() {
    let elephant = data("elephant-with-holes.off");
    let cube = data("cube_quad.off");
    let out = run(&[
        &elephant,
        &cube,
        "--threads",
        "1,2",
        "--repeat",
        "2",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    // Ten operations, two meshes (the cube's quads fan-triangulated, so
    // it has a Loop step too), two thread counts.
    assert_eq!(rows.len(), 40);
    for r in &rows {
        let t = r["raymesh"].as_f64().unwrap();
        assert!(t.is_finite() && t >= 0.0, "{r}");
        let op = r["operation"].as_str().unwrap();
        if cfg!(feature = "openmesh") && op != "one Loop step, to an indexed mesh" {
            assert!(r["openmesh"].as_f64().unwrap() >= 0.0, "{r}");
            if op != "vertex normals" {
                assert_eq!(r["agree"], true, "{r}");
            }
        } else {
            assert!(r["openmesh"].is_null(), "{r}");
        }
    }
    let ops: Vec<&str> = rows[..10]
        .iter()
        .map(|r| r["operation"].as_str().unwrap())
        .collect();
    assert_eq!(
        ops,
        [
            "build from indexed triangles",
            "one-ring walk, per neighbour",
            "vertex normals",
            "one Loop step, to an indexed mesh",
            "one Loop step, with its connectivity",
            "one Catmull-Clark step, with its connectivity",
            "split every edge at its midpoint",
            "flip every edge that may be",
            "collapse every edge that may be, then collect",
            "split every face at its centroid",
        ]
    );
    // The edits made: every edge split (the elephant's 7,371 edges, the
    // cube's 18), some flipped and some collapsed, every face split (4,463
    // and 12); the same on each thread count (the edits run on one).
    let made = |mesh: usize, threads: usize, op: usize| {
        rows[(2 * mesh + threads) * 10 + op]["edits"]
            .as_u64()
            .unwrap()
    };
    for threads in 0..2 {
        assert_eq!(made(0, threads, 6), 7371);
        assert_eq!(made(1, threads, 6), 18);
        assert_eq!(made(0, threads, 9), 4463);
        assert_eq!(made(1, threads, 9), 12);
        for mesh in 0..2 {
            for op in 6..10 {
                assert!(made(mesh, threads, op) > 0, "mesh {mesh}, edit {op}");
                assert_eq!(made(mesh, threads, op), made(mesh, 0, op));
            }
        }
    }
    for r in rows.iter().filter(|r| r["edits"].is_u64()) {
        let op = r["operation"].as_str().unwrap();
        assert!(
            op.contains("every edge") || op.contains("every face"),
            "{r}"
        );
    }
}

#[test]
fn bad_arguments_are_clear_errors() {
    let elephant = data("elephant-with-holes.off");
    for (args, what) in [
        (
            vec![elephant.as_str(), "--repeat", "0"],
            "--repeat must be at least 1",
        ),
        (
            vec![elephant.as_str(), "--threads", "0"],
            "thread counts must be at least 1",
        ),
        (vec![elephant.as_str(), "--threads", "two"], "--threads"),
        // A negative count is a value, not a flag `-1`.
        (vec![elephant.as_str(), "--threads", "-1"], "--threads"),
        (
            vec![elephant.as_str(), "--repeat", "-1"],
            "for '--repeat <REPEAT>'",
        ),
        (vec!["/nonexistent/mesh.off"], "mesh.off"),
    ] {
        let out = run(&args);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(what), "{args:?}: {err}");
    }
}
