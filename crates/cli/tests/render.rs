//! End-to-end tests of `raymesh render`: outputs, and never overwriting a file the user did not name.

mod common;
use common::*;

use std::path::PathBuf;

#[test]
fn demo_and_mesh_render_without_overwriting() {
    let dir = tmpdir("render");
    let small = ["--width", "64", "--height", "48", "--spp", "1"];
    // The demo goes to raymesh.png; an existing one is kept and a free name is used.
    std::fs::write(dir.join("raymesh.png"), b"keep me").unwrap();
    let out = raymesh()
        .current_dir(&dir)
        .arg("render")
        .args(small)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("wrote raymesh-1.png"), "{text}");
    assert_eq!(std::fs::read(dir.join("raymesh.png")).unwrap(), b"keep me");
    assert!(std::fs::read(dir.join("raymesh-1.png"))
        .unwrap()
        .starts_with(b"\x89PNG"));
    // -o names the file: then it is overwritten.
    let out = raymesh()
        .current_dir(&dir)
        .arg("render")
        .args(small)
        .args(["-o", "raymesh.png"])
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(std::fs::read(dir.join("raymesh.png"))
        .unwrap()
        .starts_with(b"\x89PNG"));
    // A mesh gets a scene made on the spot; the heat map says its scale.
    let out = raymesh()
        .current_dir(&dir)
        .arg("render")
        .arg(data("tetrahedron.off"))
        .args(small)
        .arg("--heatmap")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("wrote tetrahedron-heatmap.png") && text.contains("logarithmic"),
        "{text}"
    );
    // Spatial splits change the tree, never the image.
    let plain = dir.join("plain.png");
    let split = dir.join("split.png");
    for (out, extra) in [(&plain, None), (&split, Some("--spatial-splits=1"))] {
        let mut cmd = raymesh();
        cmd.current_dir(&dir)
            .arg("render")
            .arg(data("elephant-with-holes.off"))
            .args(small)
            .arg("-o")
            .arg(out);
        cmd.args(extra);
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert_eq!(
        std::fs::read(&plain).unwrap(),
        std::fs::read(&split).unwrap()
    );
    // Bad input: a clear error, nothing written.
    let out = raymesh()
        .current_dir(&dir)
        .arg("render")
        .arg(dir.join("none.json"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("none.json: cannot read"));
    // A mesh a scene names that cannot be read: the scene, the field, the
    // file and why (the reason had been dropped).
    let scene = dir.join("lost.json");
    std::fs::write(
        &scene,
        r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0]},
            "surfaces": [{"type": "mesh", "file": "gone.off"}]}"#,
    )
    .unwrap();
    fails_with(
        raymesh()
            .arg("render")
            .arg(&scene)
            .arg("-o")
            .arg(dir.join("lost.png")),
        "gone.off: cannot read: No such file",
    );
}

#[test]
fn example_scenes_parse_and_render() {
    let scenes = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let dir = tmpdir("scenes");
    for name in ["demo.json", "spheres.json", "elephants.json"] {
        let png = dir.join(format!("{name}.png"));
        let out = raymesh()
            .arg("render")
            .arg(scenes.join(name))
            .args(["--width", "40", "--height", "30", "--spp", "1", "-o"])
            .arg(&png)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // A PNG of the size asked for: the signature, then IHDR's width and height.
        let bytes = std::fs::read(&png).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{name}");
        assert_eq!(&bytes[16..24], &[0, 0, 0, 40, 0, 0, 0, 30], "{name}");
    }
}

/// A mesh far larger or smaller than the scene `render` makes around a
/// mesh can light in f32 is refused with a message that says so (it had
/// failed on a JSON `null` of the generated scene, blamed on the mesh
/// file's line 1), and a mesh 1e15 units across renders.
#[test]
fn meshes_out_of_range_are_refused_plainly() {
    let dir = tmpdir("render-range");
    let tet = |s: f32| {
        format!(
            "OFF\n4 4 0\n0 0 0\n{s:e} 0 0\n0 {s:e} 0\n0 0 {s:e}\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
        )
    };
    for (s, word) in [(1e30f32, "too large"), (1e-25, "too small")] {
        let path = dir.join(format!("tet{s:e}.off"));
        std::fs::write(&path, tet(s)).unwrap();
        let out = raymesh()
            .arg("render")
            .arg(&path)
            .args(["--width", "8", "--height", "8", "-o"])
            .arg(dir.join("out.png"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{s}");
        assert!(err.contains(word) && err.contains("units across"), "{err}");
    }
    let path = dir.join("big.off");
    std::fs::write(&path, tet(1e15)).unwrap();
    run_ok(
        raymesh()
            .arg("render")
            .arg(&path)
            .args(["--width", "8", "--height", "8", "--spp", "1", "-o"])
            .arg(dir.join("big.png")),
    );
}
