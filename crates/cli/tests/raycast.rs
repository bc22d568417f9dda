//! End-to-end tests of `raymesh rays` and `raymesh raycast`.

mod common;
use common::*;

use std::path::Path;

/// The data part of a .npy file (after the header).
fn npy_data(path: &Path) -> Vec<u8> {
    let b = std::fs::read(path).unwrap();
    let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
    b[10 + hlen..].to_vec()
}

#[test]
fn every_structure_writes_the_same_hits() {
    let dir = tmpdir("raycast");
    let mesh = data("elephant-with-holes.off");
    for w in ["primary", "random", "diffuse", "shadow"] {
        let rays = dir.join(format!("{w}.npy"));
        write_rays(&mesh, w, 48, &rays);
        let mut reference: Option<Vec<u8>> = None;
        for accel in [
            "brute",
            "aabb",
            "bvh-median",
            "bvh-binned",
            "bvh-sweep",
            "bvh4",
            "bvh8",
            "bvh",
            "grid",
            "kdtree",
        ] {
            let out = dir.join(format!("{w}-{accel}.npy"));
            let json = run_ok(
                raymesh()
                    .arg("raycast")
                    .arg(&mesh)
                    .arg("--rays")
                    .arg(&rays)
                    .args(["--accel", accel, "--json", "--out"])
                    .arg(&out),
            );
            let v: serde_json::Value = serde_json::from_str(&json).unwrap();
            for key in [
                "accel",
                "triangles",
                "rays",
                "hits",
                "build_ms",
                "trace_ms",
                "mrays_per_s",
                "bytes_per_triangle",
                "nodes",
                "depth",
                "sah_cost",
            ] {
                assert!(v.get(key).is_some(), "{accel}: no '{key}' in {json}");
            }
            assert_eq!(v["triangles"], 4463);
            // The expected tests a ray, for BVHs only: at least the root's
            // one node test, and some leaf tests.
            let bvh = accel.starts_with("bvh");
            for key in ["node_tests", "leaf_tests"] {
                assert_eq!(v.get(key).is_some(), bvh, "{accel}: '{key}' in {json}");
            }
            if bvh {
                assert!(v["node_tests"].as_f64().unwrap() >= 1.0, "{accel}: {json}");
                assert!(v["leaf_tests"].as_f64().unwrap() > 0.0, "{accel}: {json}");
            }
            let hits = npy_data(&out);
            match &reference {
                None => {
                    assert!(v["hits"].as_u64().unwrap() > 0, "{w}: nothing hit");
                    reference = Some(hits);
                }
                Some(r) => assert!(r == &hits, "{w}: {accel} wrote other hits than brute force"),
            }
        }
        // The portable fallbacks of the SIMD kernels write the same bits.
        let out = dir.join(format!("{w}-no-simd.npy"));
        run_ok(
            raymesh()
                .arg("raycast")
                .arg(&mesh)
                .arg("--rays")
                .arg(&rays)
                .args(["--accel", "bvh8", "--no-simd", "--out"])
                .arg(&out),
        );
        assert!(
            reference.as_ref() == Some(&npy_data(&out)),
            "{w}: bvh8 --no-simd wrote other hits than brute force"
        );
        // Spatial splits (parts of triangles in several leaves) and
        // reinsertion (other trees): the same hits; the JSON says which.
        for (accel, flag, key, want) in [
            (
                "bvh-binned",
                "--spatial-splits",
                "spatial_splits",
                serde_json::json!(0.25),
            ),
            (
                "bvh8",
                "--spatial-splits",
                "spatial_splits",
                serde_json::json!(0.25),
            ),
            (
                "bvh-median",
                "--optimize",
                "optimize",
                serde_json::json!(true),
            ),
            ("bvh8", "--optimize", "optimize", serde_json::json!(true)),
        ] {
            let out = dir.join(format!("{w}-{accel}{flag}.npy"));
            let json = run_ok(
                raymesh()
                    .arg("raycast")
                    .arg(&mesh)
                    .arg("--rays")
                    .arg(&rays)
                    .args(["--accel", accel, flag, "--json", "--out"])
                    .arg(&out),
            );
            let v: serde_json::Value = serde_json::from_str(&json).unwrap();
            assert_eq!(v[key], want, "{json}");
            assert!(
                reference.as_ref() == Some(&npy_data(&out)),
                "{w}: {accel} {flag} wrote other hits than brute force"
            );
        }
        // Packets of eight rays, and streams of rays walking the binary
        // BVHs interleaved, with and without the SIMD kernels.
        for (accel, mode, simd) in [
            ("bvh8", "--packets", true),
            ("bvh4", "--packets", true),
            ("bvh-binned", "--packets", true),
            ("bvh8", "--packets", false),
            ("bvh-binned", "--stream", true),
            ("bvh-sweep", "--stream", true),
            ("bvh-binned", "--stream", false),
        ] {
            let out = dir.join(format!("{w}-{accel}{mode}-{simd}.npy"));
            let mut cmd = raymesh();
            cmd.arg("raycast")
                .arg(&mesh)
                .arg("--rays")
                .arg(&rays)
                .args(["--accel", accel, mode, "--out"])
                .arg(&out);
            if !simd {
                cmd.arg("--no-simd");
            }
            run_ok(&mut cmd);
            assert!(
                reference.as_ref() == Some(&npy_data(&out)),
                "{w}: {accel} {mode} (simd {simd}) wrote other hits than brute force"
            );
        }
    }
}

#[test]
fn any_hit_agrees_on_what_is_hit() {
    let dir = tmpdir("anyhit");
    let mesh = data("sphere.ply");
    let rays = dir.join("r.npy");
    write_rays(&mesh, "random", 40, &rays);
    let count = |extra: &[&str]| -> u64 {
        let json = run_ok(
            raymesh()
                .arg("raycast")
                .arg(&mesh)
                .arg("--rays")
                .arg(&rays)
                .args(["--json", "--threads", "2"])
                .args(extra),
        );
        serde_json::from_str::<serde_json::Value>(&json).unwrap()["hits"]
            .as_u64()
            .unwrap()
    };
    let closest = count(&[]);
    assert!(closest > 0);
    for accel in ["brute", "bvh", "grid", "kdtree"] {
        assert_eq!(count(&["--any-hit", "--accel", accel]), closest, "{accel}");
    }
    assert_eq!(
        count(&["--any-hit", "--accel", "bvh-binned", "--stream"]),
        closest,
        "bvh-binned --stream"
    );
    for accel in ["bvh8", "bvh4", "bvh-binned"] {
        assert_eq!(
            count(&["--any-hit", "--accel", accel, "--packets"]),
            closest,
            "{accel} --packets"
        );
    }
    // A camera's rays, which go as packets.
    let primary = dir.join("p.npy");
    write_rays(&mesh, "primary", 24, &primary);
    let hits = |extra: &[&str]| -> Vec<u8> {
        let out = dir.join("h.npy");
        run_ok(
            raymesh()
                .arg("raycast")
                .arg(&mesh)
                .arg("--rays")
                .arg(&primary)
                .arg("--out")
                .arg(&out)
                .args(extra),
        );
        npy_data(&out)
    };
    // Hit records of 16 bytes: `t`, `prim`, `u`, `v`; a miss has prim -1.
    let hit_or_miss = |records: &[u8]| -> Vec<bool> {
        records
            .chunks_exact(16)
            .map(|r| i32::from_le_bytes(r[4..8].try_into().unwrap()) >= 0)
            .collect()
    };
    let reference = hit_or_miss(&hits(&["--accel", "brute"]));
    assert!(reference.iter().any(|&h| h) && reference.iter().any(|&h| !h));
    for accel in ["bvh8", "bvh4", "bvh-binned"] {
        let got = hit_or_miss(&hits(&["--any-hit", "--accel", accel, "--packets"]));
        assert_eq!(got, reference, "{accel} --any-hit --packets, primary rays");
    }
    let table = run_ok(
        raymesh()
            .arg("raycast")
            .arg(&mesh)
            .arg("--rays")
            .arg(&rays)
            .args(["--stats", "--repeat", "2"]),
    );
    assert!(table.contains("nodes visited"), "{table}");
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = tmpdir("badrays");
    let mesh = data("tetrahedron.off");
    let bad = dir.join("bad.npy");
    std::fs::write(&bad, b"\x93NUMPY\x01\x00\x46\x00{'descr': '<f8', 'fortran_order': False, 'shape': (1, 8), }          \n").unwrap();
    let out = raymesh()
        .arg("raycast")
        .arg(&mesh)
        .arg("--rays")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.npy") && err.contains("dtype is '<f8'"),
        "{err}"
    );
    let out = raymesh()
        .arg("raycast")
        .arg(&mesh)
        .args(["--rays", "x.npy", "--accel", "octree"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown structure 'octree'"));
    for bad in ["-0.5", "nan", "lots", "9"] {
        let out = raymesh()
            .arg("raycast")
            .arg(&mesh)
            .args(["--rays", "x.npy", &format!("--spatial-splits={bad}")])
            .output()
            .unwrap();
        assert!(!out.status.success(), "--spatial-splits {bad} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("--spatial-splits") && err.contains(bad),
            "{err}"
        );
    }
    // Flags the structure would ignore are refused, not dropped quietly.
    for (accel, flag) in [
        ("grid", "--spatial-splits"),
        ("kdtree", "--spatial-splits"),
        ("bvh-sweep", "--spatial-splits"),
        ("bvh-median", "--spatial-splits"),
        ("brute", "--optimize"),
        ("grid", "--optimize"),
        ("kdtree", "--optimize"),
    ] {
        fails_with(
            raymesh()
                .arg("raycast")
                .arg(&mesh)
                .args(["--rays", "x.npy", "--accel", accel, flag]),
            &format!("{flag} "),
        );
        fails_with(
            raymesh().args(["render", "--accel", accel, flag]),
            &format!("{flag} "),
        );
    }
}

/// `raymesh bench` of fixture `mesh` with `args` and `--json`, which must
/// succeed: its output and the rows it parses to.
fn bench_json(mesh: &str, args: &[&str]) -> (String, Vec<serde_json::Value>) {
    let out = run_ok(
        raymesh()
            .arg("bench")
            .arg(data(mesh))
            .args(args)
            .arg("--json"),
    );
    let rows = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    (out, rows)
}

#[test]
fn bench_reports_every_structure_workload_and_thread_count() {
    let (_, rows) = bench_json(
        "sphere.ply",
        &[
            "--size",
            "16",
            "--repeat",
            "1",
            "--threads",
            "1,2",
            "--accel",
            "bvh,grid",
        ],
    );
    assert_eq!(
        rows.len(),
        2 * 4 * 2,
        "structures × workloads × thread counts"
    );
    for r in &rows {
        for key in [
            "build_ms_1_thread",
            "bytes_per_triangle",
            "sah_cost",
            "closest_mrays_per_s",
            "any_hit_mrays_per_s",
            "nodes_per_ray",
            "triangles_per_ray",
        ] {
            assert!(r[key].as_f64().is_some_and(|v| v >= 0.0), "{key} in {r}");
        }
    }
    let bad = raymesh()
        .arg("bench")
        .arg(data("sphere.ply"))
        .args(["--workloads", "sideways"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("unknown workload 'sideways'"));
}

#[test]
fn bench_traces_as_packets_or_streams() {
    for (flag, key) in [("--packets", "packets"), ("--stream", "stream")] {
        let out = run_ok(raymesh().arg("bench").arg(data("sphere.ply")).args([
            "--size",
            "16",
            "--repeat",
            "1",
            "--threads",
            "1",
            "--accel",
            "bvh8,bvh-binned",
            "--workloads",
            "primary,random",
            flag,
            "--json",
        ]));
        let rows: Vec<serde_json::Value> = out
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(rows.len(), 2 * 2, "{flag}: structures × workloads");
        for r in &rows {
            assert_eq!(r[key], true, "{flag}: {r}");
            let other = if key == "packets" {
                "stream"
            } else {
                "packets"
            };
            assert_eq!(r[other], false, "{flag}: {r}");
            assert!(r["closest_mrays_per_s"].as_f64().is_some_and(|v| v > 0.0));
            assert!(r["any_hit_mrays_per_s"].as_f64().is_some_and(|v| v > 0.0));
        }
        let table = run_ok(raymesh().arg("bench").arg(data("sphere.ply")).args([
            "--size",
            "8",
            "--repeat",
            "1",
            "--threads",
            "1",
            "--accel",
            "bvh8",
            "--workloads",
            "random",
            flag,
        ]));
        let mode = if key == "packets" {
            "packets of 8"
        } else {
            "streams"
        };
        assert!(table.contains(&format!("rays traced as {mode}")), "{table}");
    }
    let both = raymesh()
        .arg("bench")
        .arg(data("sphere.ply"))
        .args(["--packets", "--stream"])
        .output()
        .unwrap();
    assert!(!both.status.success());
    assert!(String::from_utf8_lossy(&both.stderr).contains("cannot be used with"));
}

/// `bench --spatial-splits --optimize` over several structures reports, per
/// row, what that structure's build took: the settings apply to the BVHs
/// that take them and no other (the grid's rows had said 0.25 and true).
#[test]
fn bench_rows_say_which_builds_took_the_settings() {
    let (out, rows) = bench_json(
        "tetrahedron.off",
        &[
            "--size",
            "4",
            "--repeat",
            "1",
            "--threads",
            "1",
            "--workloads",
            "primary",
            "--accel",
            "bvh8,bvh-sweep,grid,kdtree",
            "--spatial-splits",
            "--optimize",
        ],
    );
    let got: Vec<(String, f64, bool)> = rows
        .iter()
        .map(|r| {
            (
                r["accel"].as_str().unwrap().to_string(),
                r["spatial_splits"].as_f64().unwrap(),
                r["optimize"].as_bool().unwrap(),
            )
        })
        .collect();
    let want = [
        ("bvh8", 0.25, true),
        ("bvh-sweep", 0.0, true),
        ("grid", 0.0, false),
        ("kdtree", 0.0, false),
    ];
    assert_eq!(got.len(), want.len(), "{out}");
    for ((a, s, o), (wa, ws, wo)) in got.iter().zip(want) {
        assert_eq!((a.as_str(), *s, *o), (wa, ws, wo), "{out}");
    }
}
