//! End-to-end tests of `raymesh mesh` and `raymesh subdivide`.

mod common;
use common::*;

fn json(args: &[&str], file: &str) -> serde_json::Value {
    let out = raymesh().args(args).arg(data(file)).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn mesh_json_has_the_contract_keys() {
    let v = json(&["mesh", "--json", "--bench"], "double-torus-example.off");
    for key in [
        "vertices",
        "edges",
        "faces",
        "half_edges",
        "boundary_loops",
        "components",
        "euler_characteristic",
        "genus",
        "non_manifold_edges",
        "non_manifold_vertices",
    ] {
        assert!(v.get(key).is_some(), "no {key}");
    }
    assert_eq!(
        (v["genus"].as_i64(), v["euler_characteristic"].as_i64()),
        (Some(2), Some(-2))
    );
    for key in ["half_edge", "winged_edge"] {
        assert!(v["bytes_per_vertex"][key].as_f64().unwrap() > 0.0, "{key}");
        assert!(v["build_ms"][key].as_f64().is_some(), "{key}");
    }
    assert!(
        v["bytes_per_vertex"]["compact"].is_null(),
        "the double torus has quads"
    );
    for key in ["one_ring_ns_per_neighbor", "normals_ms"] {
        assert!(v[key].as_f64().unwrap() >= 0.0, "{key}");
    }
    assert!(
        v.get("loop_ms").is_none(),
        "the double torus has quads: no Loop step"
    );
    let t = json(&["mesh", "--json", "--bench"], "sphere.ply");
    assert!(t["loop_ms"].as_f64().unwrap() >= 0.0);
    assert!(t["bytes_per_vertex"]["compact"].as_f64().unwrap() > 0.0);
    assert!(t["build_ms"]["compact"].as_f64().is_some());
    let q = json(&["mesh", "--json"], "cube_quad.off");
    assert!(
        q["bytes_per_vertex"]["compact"].is_null(),
        "quads have no compact form"
    );
    let b = json(&["mesh", "--json"], "mesh_with_border.off");
    assert_eq!(b["boundary_loops"], 1);
}

#[test]
fn strict_names_the_faces_and_default_repairs() {
    let dir = tmpdir("meshcli");
    let bowtie = dir.join("bowtie.off");
    std::fs::write(
        &bowtie,
        "OFF\n5 2 0\n0 0 0\n1 0 0\n0 1 0\n-1 0 0\n0 -1 0\n3 0 1 2\n3 0 3 4\n",
    )
    .unwrap();
    let out = raymesh()
        .args(["mesh", "--json"])
        .arg(&bowtie)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (
            v["non_manifold_vertices"].as_u64(),
            v["faces"].as_u64(),
            v["vertices"].as_u64()
        ),
        (Some(1), Some(2), Some(6))
    );
    let out = raymesh()
        .args(["mesh", "--strict"])
        .arg(&bowtie)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bowtie.off")
            && err.contains("1 non-manifold vertices")
            && err.contains("faces 0, 1"),
        "{err}"
    );
}

#[test]
fn subdivide_writes_the_levels_asked_for() {
    let dir = tmpdir("subdiv");
    let out_ply = dir.join("s.ply");
    let out = raymesh()
        .arg("subdivide")
        .arg(data("sphere.ply"))
        .args(["--levels", "2", "-o"])
        .arg(&out_ply)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = raymesh()
        .args(["info", "--json"])
        .arg(&out_ply)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["faces"], 320 * 16);
    let out_obj = dir.join("c.obj");
    let out = raymesh()
        .arg("subdivide")
        .arg(data("cube_quad.off"))
        .args(["--scheme", "catmull-clark", "-o"])
        .arg(&out_obj)
        .output()
        .unwrap();
    assert!(out.status.success());
    let out = raymesh()
        .arg("subdivide")
        .arg(data("cube_quad.off"))
        .arg("-o")
        .arg(&out_obj)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("catmull-clark"));
}

#[test]
fn a_mesh_without_vertices_has_no_bytes_per_vertex() {
    let dir = tmpdir("mesh-empty");
    let file = dir.join("empty.off");
    std::fs::write(&file, "OFF\n0 0 0\n").unwrap();
    let out = run_ok(raymesh().args(["mesh", "--json"]).arg(&file));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["vertices"].as_u64(), Some(0));
    for key in ["half_edge", "winged_edge", "compact"] {
        assert!(v["bytes_per_vertex"][key].is_null(), "{key}: {v}");
    }
    let text = run_ok(raymesh().arg("mesh").arg(&file));
    assert!(
        text.contains("bytes per vertex       n/a (no vertices)"),
        "{text}"
    );
}
