//! No command writes its output over one of its inputs.

mod common;

use common::{data, fails_with, raymesh, run_ok, tmpdir, write_rays};
use std::path::Path;

/// Every command that writes a file refuses, before it builds or writes, an output
/// that is one of its inputs (named the same way, by another path, or
/// through a link), and leaves that input as it was; an output that is
/// some other existing file is overwritten, as asked.
#[test]
fn no_command_writes_its_output_over_an_input() {
    let dir = tmpdir("outputs");
    let mesh = dir.join("t.off");
    std::fs::copy(data("tetrahedron.off"), &mesh).unwrap();
    let rays = dir.join("r.npy");
    write_rays(&mesh, "random", 4, &rays);
    let scene = dir.join("s.json");
    std::fs::write(
        &scene,
        r#"{"camera": {"eye": [0, 0, 5], "target": [0, 0, 0]},
            "surfaces": [{"type": "mesh", "file": "t.off"}]}"#,
    )
    .unwrap();
    let before = |p: &Path| std::fs::read(p).unwrap();
    let (mesh_bytes, ray_bytes, scene_bytes) = (before(&mesh), before(&rays), before(&scene));
    // The same file by another name: `dir/./t.off`, and a link to it.
    let dotted = dir.join(".").join("t.off");
    let mut aliases = vec![mesh.clone(), dotted];
    #[cfg(unix)]
    {
        let link = dir.join("link.off");
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&mesh, &link).unwrap();
        aliases.push(link);
    }
    for out in &aliases {
        let s = |a: &str| a.to_string();
        let cases: Vec<Vec<String>> = vec![
            vec![s("subdivide"), mesh.display().to_string(), s("-o")],
            vec![
                s("rays"),
                mesh.display().to_string(),
                s("--workload"),
                s("random"),
                s("--size"),
                s("2"),
                s("-o"),
            ],
            vec![
                s("raycast"),
                mesh.display().to_string(),
                s("--rays"),
                rays.display().to_string(),
                s("--out"),
            ],
            vec![s("render"), mesh.display().to_string(), s("-o")],
            vec![s("render"), scene.display().to_string(), s("-o")],
            vec![
                s("generate"),
                s("teapot-in-stadium"),
                s("--teapot"),
                mesh.display().to_string(),
                s("--triangles"),
                s("100"),
                s("-o"),
            ],
        ];
        for args in cases {
            fails_with(
                raymesh().args(&args).arg(out),
                "writing the output there would destroy it",
            );
        }
    }
    // The rays as `raycast`'s output, the scene as `render`'s.
    fails_with(
        raymesh()
            .arg("raycast")
            .arg(&mesh)
            .arg("--rays")
            .arg(&rays)
            .arg("--out")
            .arg(&rays),
        "this is the input rays",
    );
    fails_with(
        raymesh().arg("render").arg(&scene).arg("-o").arg(&scene),
        "this is the input scene",
    );
    assert_eq!(before(&mesh), mesh_bytes);
    assert_eq!(before(&rays), ray_bytes);
    assert_eq!(before(&scene), scene_bytes);
    // Another existing file is the user's to overwrite.
    let other = dir.join("other.off");
    std::fs::write(&other, "old").unwrap();
    run_ok(raymesh().arg("subdivide").arg(&mesh).arg("-o").arg(&other));
    assert!(before(&other).starts_with(b"OFF"));
}

/// Every command that writes a file refuses, before its work, an output it
/// could not write: in a folder that does not exist, under a path through
/// a file, or a folder itself; and `render` an output that is not a PNG.
/// (They had run to their end and then failed to write, the render or the
/// subdivision lost, some saying "cannot read" of the file to write.)
#[test]
fn outputs_that_cannot_be_written_are_refused_before_the_work() {
    let dir = tmpdir("unwritable");
    let mesh = dir.join("t.off");
    std::fs::copy(data("tetrahedron.off"), &mesh).unwrap();
    let rays = dir.join("r.npy");
    write_rays(&mesh, "random", 4, &rays);
    let m = mesh.display().to_string();
    let r = rays.display().to_string();
    let commands: Vec<(Vec<&str>, &str)> = vec![
        (vec!["subdivide", &m, "-o"], "s.off"),
        (
            vec!["rays", &m, "--workload", "random", "--size", "2", "-o"],
            "r2.npy",
        ),
        (vec!["raycast", &m, "--rays", &r, "--out"], "h.npy"),
        (
            vec!["render", &m, "--width", "4", "--height", "4", "-o"],
            "i.png",
        ),
        (
            vec!["render", "--width", "4", "--height", "4", "-o"],
            "demo.png",
        ),
        (
            vec!["generate", "sphere", "--triangles", "100", "-o"],
            "g.ply",
        ),
        (
            vec![
                "scale", "--sizes", "0.0001", "--size", "8", "--repeat", "1", "--chart",
            ],
            "c.svg",
        ),
    ];
    let missing = dir.join("no-such-folder");
    for (args, name) in &commands {
        fails_with(
            raymesh().args(args).arg(missing.join(name)),
            &format!("cannot write there: {} does not exist", missing.display()),
        );
        fails_with(
            raymesh().args(args).arg(mesh.join(name)),
            &format!("cannot write there: {} is not a folder", mesh.display()),
        );
        let folder = dir.join(name);
        std::fs::create_dir(&folder).unwrap();
        fails_with(raymesh().args(args).arg(&folder), "this is a folder");
        std::fs::remove_dir(&folder).unwrap();
        // Nothing was made, and the same command writes where it can.
        assert!(!missing.exists());
        run_ok(raymesh().args(args).arg(dir.join(name)));
        assert!(dir.join(name).is_file(), "{args:?}");
    }
    for name in ["i.jpg", "i.json", "i"] {
        fails_with(
            raymesh().arg("render").arg("-o").arg(dir.join(name)),
            "render writes PNG images (.png)",
        );
        assert!(!dir.join(name).exists());
    }
}
