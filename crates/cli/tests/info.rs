//! End-to-end tests of `raymesh info`.

mod common;
use common::*;

#[test]
fn info_json_has_the_contract_keys() {
    let out = raymesh()
        .args(["info", "--json"])
        .arg(data("degtri_sliding.off"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["vertices"], 8);
    assert_eq!(v["faces"], 8);
    assert_eq!(v["triangles"], 8);
    assert!(v["degenerate_triangles"].as_u64().unwrap() > 0);
    assert_eq!(v["unreferenced_vertices"], 0);
    let bbox = v["bbox"].as_array().unwrap();
    assert_eq!(bbox.len(), 2);
    assert_eq!(bbox[0].as_array().unwrap().len(), 3);
}

#[test]
fn info_quads_triangulate() {
    let out = raymesh()
        .args(["info", "--json"])
        .arg(data("cube_quad.off"))
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["faces"].as_u64(), v["triangles"].as_u64()),
        (Some(6), Some(12))
    );
    assert_eq!(
        v["bbox"],
        serde_json::json!([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    );
    assert_eq!(v["degenerate_triangles"], 0);
}

#[test]
fn info_table() {
    let out = raymesh()
        .arg("info")
        .arg(data("tetrahedron.off"))
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("vertices               4"), "{text}");
    assert!(text.contains("triangles              4"), "{text}");
}

#[test]
fn bad_input_fails_with_the_error_on_stderr() {
    let dir = tmpdir("cli");
    let bad = dir.join("bad.off");
    std::fs::write(&bad, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").unwrap();
    let out = raymesh()
        .args(["info", "--json"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("bad.off:6: vertex index 7 out of range (3 vertices)"),
        "{err}"
    );
    let out = raymesh()
        .arg("info")
        .arg(dir.join("missing.ply"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr)
        .unwrap()
        .contains("missing.ply"));
}

#[test]
fn a_closed_pipe_ends_quietly() {
    use std::process::Stdio;
    let mut child = raymesh()
        .arg("info")
        .arg(data("elephant-with-holes.off"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // the reader goes away before anything is written
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    // 141 when the write met the closed pipe; 0 in the rare case that the
    // output fit in the pipe's buffer before the reader went away.
    assert!(
        matches!(out.status.code(), Some(141) | Some(0)),
        "{:?}",
        out.status
    );
}
