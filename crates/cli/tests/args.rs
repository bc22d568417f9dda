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
