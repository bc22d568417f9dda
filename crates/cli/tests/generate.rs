//! End-to-end tests of `raymesh generate` and `raymesh rays --frame`.

mod common;
use common::*;
use std::path::Path;

fn info(path: &Path) -> serde_json::Value {
    let out = run_ok(raymesh().args(["info", "--json"]).arg(path));
    serde_json::from_str(&out).unwrap()
}

#[test]
fn generate_writes_meshes_of_the_asked_size() {
    let dir = tmpdir("generate");
    let terrain = dir.join("terrain.ply");
    run_ok(
        raymesh()
            .args(["generate", "terrain", "--triangles", "1000", "-o"])
            .arg(&terrain),
    );
    let v = info(&terrain);
    let t = v["triangles"].as_u64().unwrap();
    assert!((1000..1100).contains(&t), "{t}");
    assert_eq!(v["degenerate_triangles"], 0);
    assert_eq!(v["unreferenced_vertices"], 0);

    // Slivers: exactly the asked count, none degenerate, in the 8-cube.
    let slivers = dir.join("slivers.ply");
    run_ok(
        raymesh()
            .args(["generate", "slivers", "--triangles", "500", "-o"])
            .arg(&slivers),
    );
    let v = info(&slivers);
    assert_eq!(v["triangles"], 500);
    assert_eq!(v["degenerate_triangles"], 0);
    assert!(v["bbox"][1][0].as_f64().unwrap() < 8.25);

    // The teapot keeps its triangles; the stadium is 100 times wider.
    let stadium = dir.join("stadium.off");
    run_ok(
        raymesh()
            .args([
                "generate",
                "teapot-in-stadium",
                "--stadium-triangles",
                "200",
            ])
            .arg("--teapot")
            .arg(data("sphere.ply"))
            .arg("-o")
            .arg(&stadium),
    );
    let v = info(&stadium);
    assert!(v["triangles"].as_u64().unwrap() > 320 + 100);
    assert_eq!(v["degenerate_triangles"], 0);

    fails_with(
        raymesh()
            .args(["generate", "terrain", "-o"])
            .arg(dir.join("t.stl")),
        "must be .obj, .off or .ply",
    );
    fails_with(
        raymesh()
            .args(["generate", "terrain", "--triangles", "0", "-o"])
            .arg(&terrain),
        "--triangles",
    );
    // The stadium's count is checked as the teapot's is (a hundred
    // billion aborted on a failed allocation).
    for n in ["0", "99999999999"] {
        fails_with(
            raymesh()
                .args([
                    "generate",
                    "teapot-in-stadium",
                    "--stadium-triangles",
                    n,
                    "-o",
                ])
                .arg(&terrain),
            "--stadium-triangles must be between 1 and",
        );
    }
    fails_with(
        raymesh()
            .args(["generate", "sphere", "--teapot"])
            .arg(data("sphere.ply"))
            .arg("-o")
            .arg(&terrain),
        "--teapot goes with teapot-in-stadium",
    );
}

/// Rays framed on the teapot mostly hit it, and the grid (the structure
/// this scene is hard for) still returns what brute force returns, through
/// the grids of the teapot's cells.
#[test]
fn rays_framed_on_the_teapot_hit_it_and_agree() {
    let dir = tmpdir("frame");
    let stadium = dir.join("stadium.ply");
    run_ok(
        raymesh()
            .args(["generate", "teapot-in-stadium", "--triangles", "3000"])
            .arg("-o")
            .arg(&stadium),
    );
    let rays = dir.join("rays.npy");
    run_ok(
        raymesh()
            .arg("rays")
            .arg(&stadium)
            .args([
                "--workload",
                "primary",
                "--size",
                "32",
                "--frame",
                "-1,0,-1,1,2,1",
                "-o",
            ])
            .arg(&rays),
    );
    let mut hits = Vec::new();
    for accel in ["brute", "grid", "bvh8"] {
        let out = dir.join(format!("{accel}.npy"));
        let json = run_ok(
            raymesh()
                .arg("raycast")
                .arg(&stadium)
                .arg("--rays")
                .arg(&rays)
                .args(["--accel", accel, "--json", "--out"])
                .arg(&out),
        );
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        // The sphere fills most of the frame's view.
        assert!(v["hits"].as_u64().unwrap() > 32 * 32 / 3, "{accel}: {v}");
        hits.push(std::fs::read(&out).unwrap());
    }
    assert!(hits[1] == hits[0] && hits[2] == hits[0]);

    // The benchmark shows what the grid's second level buys: aimed at the
    // teapot, a grid of one level, its cells sized for the stadium, tested
    // 1,531 triangles a ray here, over 100 times the BVH's 12; the teapot's
    // cells' own grids bring that to 58 (counts, not times).
    let out = run_ok(
        raymesh()
            .arg("bench")
            .arg(&stadium)
            .args([
                "--accel",
                "grid,bvh8",
                "--workloads",
                "primary",
                "--size",
                "16",
            ])
            .args([
                "--threads",
                "1",
                "--repeat",
                "1",
                "--json",
                "--frame",
                "-1,0,-1,1,2,1",
            ]),
    );
    let per_ray: Vec<(String, f64)> = out
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["accel"].as_str().unwrap().to_string(),
                v["triangles_per_ray"].as_f64().unwrap(),
            )
        })
        .collect();
    let of = |a: &str| per_ray.iter().find(|r| r.0 == a).unwrap().1;
    assert!(of("grid") < 10.0 * of("bvh8"), "{per_ray:?}");

    for bad in ["1,2,3", "1,0,0,0,1,1", "a,b,c,d,e,f", "0,0,0,1,1,inf"] {
        fails_with(
            raymesh()
                .arg("rays")
                .arg(&stadium)
                .args(["--workload", "primary", "--frame", bad, "-o"])
                .arg(&rays),
            "--frame",
        );
    }
}

#[test]
fn scale_reports_every_size_structure_and_thread_count_with_a_chart() {
    let dir = tmpdir("scale");
    let chart = dir.join("scale.svg");
    let out = run_ok(
        raymesh()
            .args(["scale", "--sizes", "0.001,0.004", "--accel", "bvh8,grid"])
            .args([
                "--threads",
                "1,2",
                "--size",
                "16",
                "--repeat",
                "1",
                "--json",
                "--chart",
            ])
            .arg(&chart),
    );
    let rows: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 2 * 2 * 2);
    for r in &rows {
        for key in [
            "triangles",
            "accel",
            "threads",
            "build_ms",
            "build_mtris_per_s",
            "mrays_per_s",
            "nodes_per_ray",
            "triangles_per_ray",
            "bytes_per_triangle",
        ] {
            assert!(!r[key].is_null(), "{key} missing in {r}");
        }
        assert!(r["triangles"].as_u64().unwrap() >= 1000);
        // Primary rays at a terrain seen from above: something is hit,
        // so something is tested.
        assert!(r["triangles_per_ray"].as_f64().unwrap() > 0.0, "{r}");
        assert_eq!(r["build_speedup"].is_null(), r["threads"] == 1, "{r}");
    }
    let svg = std::fs::read_to_string(&chart).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("cost per ray"));

    for bad in [
        vec!["--sizes", "0"],
        vec!["--sizes", "x"],
        vec!["--sizes", "2000"],
        vec!["--threads", "0"],
    ] {
        let out = raymesh().arg("scale").args(&bad).output().unwrap();
        assert!(!out.status.success(), "{bad:?}");
        assert!(String::from_utf8_lossy(&out.stderr).contains(bad[0]) || bad[0] == "--threads");
    }
    let out = raymesh()
        .args(["scale", "--sizes", "0.001", "--chart"])
        .arg(dir.join("c.png"))
        .output()
        .unwrap();
    assert!(!out.status.success());
}
