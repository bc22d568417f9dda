//! Counts given on the command line are checked before any work.

mod common;

use common::{data, fails_with, raymesh};

/// `bench` and `scale` refuse a zero or malformed repeat count, image size
/// or thread count with a message naming the flag (`bench --repeat 0` ran
/// once and said nothing; `--threads 1,x` said "invalid digit found in
/// string"), and every command more than 1,024 threads.
#[test]
fn commands_refuse_bad_counts() {
    let mesh = data("tetrahedron.off");
    for cmd in ["bench", "scale"] {
        let base = || {
            let mut c = raymesh();
            c.arg(cmd);
            if cmd == "bench" {
                c.arg(&mesh);
            }
            c
        };
        fails_with(base().args(["--repeat", "0"]), "'--repeat <REPEAT>'");
        fails_with(base().args(["--size", "0"]), "'--size <SIZE>'");
        fails_with(base().args(["--size", "9000"]), "not in 1..=8192");
        fails_with(
            base().args(["--threads", "0"]),
            "--threads: thread counts must be at least 1",
        );
        fails_with(base().args(["--threads", "1,x"]), "--threads:");
        fails_with(
            base().args(["--threads", "1,100000"]),
            "at most 1024 worker threads",
        );
    }
    // One thread count: `raycast` and `render` (100,000 threads ran for
    // minutes before; the check comes before any file is read).
    fails_with(
        raymesh().args(["raycast", "m.off", "--rays", "r.npy", "--threads", "100000"]),
        "--threads 100000: at most 1024 worker threads",
    );
    fails_with(
        raymesh().args(["render", "--threads", "100000"]),
        "--threads 100000: at most 1024 worker threads",
    );
}

/// `bench --peers` hands the run to `raymesh-peers` (here a script that
/// records its arguments, named by `RAYMESH_PEERS`) with the command's own
/// settings translated and the arguments after `--` passed on; settings
/// `raymesh-peers` has no form of are refused, not dropped; a missing
/// `raymesh-peers` is an error that says how to build it.
#[cfg(unix)]
/// A negative count or size is a value out of range, named with its flag,
/// not an unknown flag: clap took `--sizes -1` for a flag `-1` ("unexpected
/// argument '-1' found"), on every numeric flag of every command.
#[test]
fn negative_numbers_are_values_out_of_range() {
    let mesh = data("tetrahedron.off");
    let m = mesh.to_str().unwrap();
    let cases: [(&[&str], &str); 12] = [
        (&["scale", "--sizes", "-1"], "--sizes: -1 is not within"),
        (&["scale", "--threads", "-2"], "--threads:"),
        (&["scale", "--size", "-3"], "'--size <SIZE>'"),
        (&["bench", m, "--repeat", "-1"], "'--repeat <REPEAT>'"),
        (&["bench", m, "--threads", "-1"], "--threads:"),
        (
            &["raycast", m, "--rays", "r.npy", "--threads", "-1"],
            "'--threads <THREADS>'",
        ),
        (
            &["raycast", m, "--rays", "r.npy", "--spatial-splits", "-0.5"],
            "--spatial-splits",
        ),
        (
            &["rays", m, "--size", "-16", "-o", "r.npy"],
            "'--size <SIZE>'",
        ),
        (&["render", "--width", "-640"], "'--width <WIDTH>'"),
        (&["render", "--spp", "-1"], "'--spp <SPP>'"),
        (
            &["generate", "terrain", "--triangles", "-5", "-o", "t.ply"],
            "'--triangles <TRIANGLES>'",
        ),
        (
            &["subdivide", m, "--levels", "-1", "-o", "s.off"],
            "'--levels <LEVELS>'",
        ),
    ];
    for (args, needle) in cases {
        let out = raymesh().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(
            err.contains(needle) && !err.contains("unexpected argument"),
            "{args:?}: {needle:?} not in {err}"
        );
    }
}

#[test]
fn bench_hands_peers_to_raymesh_peers() {
    use std::os::unix::fs::PermissionsExt;
    let dir = common::tmpdir("peers");
    let (script, log) = (dir.join("fake-peers"), dir.join("args.txt"));
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nprintf '%s\\n' \"$@\" > '{}'\n[ \"$1\" != fail.off ]\n",
            log.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let peers = || {
        let mut c = raymesh();
        c.env("RAYMESH_PEERS", &script);
        c
    };
    // Each list of arguments as one string, split at spaces.
    let args = |extra: &str| {
        common::run_ok(
            peers()
                .args(["bench", "a.off", "b.off", "--peers", "embree"])
                .args(extra.split(' ')),
        );
        std::fs::read_to_string(&log).unwrap().replace('\n', " ")
    };
    assert_eq!(
        args("--threads 1,2 --size 64 --repeat 2 --json -- --interleave --chart c.png"),
        "a.off b.off --peers embree --accel bvh --workloads primary,random,diffuse,shadow \
         --size 64 --threads 1,2 --repeat 2 --json --interleave --chart c.png "
    );
    assert_eq!(
        args("--accel bvh8,grid --workloads random --threads 1 --stream"),
        "a.off b.off --peers embree --accel bvh8,grid --workloads random --size 1024 \
         --threads 1 --repeat 3 --stream "
    );
    // Its failure is the command's.
    fails_with(
        peers().args(["bench", "fail.off", "--peers", "all", "--threads", "1"]),
        "fake-peers failed",
    );
    for flag in [
        &["--optimize"][..],
        &["--spatial-splits"],
        &["--frame", "0,0,0,1,1,1"],
    ] {
        fails_with(
            peers()
                .args(["bench", "a.off", "--peers", "all"])
                .args(flag),
            "does not go with --peers",
        );
    }
    fails_with(
        peers().args(["bench", "a.off", "--peers", "all", "--threads", "1,100000"]),
        "at most 1024 worker threads",
    );
    fails_with(
        raymesh()
            .env("RAYMESH_PEERS", dir.join("none"))
            .args(["bench", "a.off", "--peers", "all"]),
        "which is not a file",
    );
    // Arguments after `--` are for the peers only.
    fails_with(
        raymesh().args(["bench", "a.off", "--", "--interleave"]),
        "--peers <LIST>",
    );
}

/// Every command that writes a file takes its path as `-o`, `--out` or
/// `--output`, whichever the command's help names first: `rays` and
/// `raycast` said `--out` and the others `--output`, and each refused the
/// other's spelling.
#[test]
fn output_flags_take_either_spelling() {
    let mesh = data("tetrahedron.off");
    let dir = common::tmpdir("output-flags");
    for (i, flag) in ["-o", "--out", "--output"].into_iter().enumerate() {
        let rays = dir.join(format!("rays{i}.npy"));
        let hits = dir.join(format!("hits{i}.npy"));
        let sub = dir.join(format!("sub{i}.obj"));
        let gen = dir.join(format!("gen{i}.ply"));
        let png = dir.join(format!("img{i}.png"));
        let m = mesh.to_str().unwrap();
        for (args, file) in [
            (
                vec!["rays", m, "--workload", "random", "--size", "4", flag],
                &rays,
            ),
            (
                vec!["raycast", m, "--rays", rays.to_str().unwrap(), flag],
                &hits,
            ),
            (vec!["subdivide", m, "--levels", "1", flag], &sub),
            (vec!["generate", "sphere", "--triangles", "100", flag], &gen),
            (
                vec!["render", m, "--width", "8", "--height", "8", flag],
                &png,
            ),
        ] {
            common::run_ok(raymesh().args(&args).arg(file));
            assert!(
                std::fs::metadata(file).is_ok_and(|m| m.len() > 0),
                "{} {flag}: no {}",
                args[0],
                file.display()
            );
        }
    }
}
