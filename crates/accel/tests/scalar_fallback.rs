//! The portable fallbacks of the SIMD kernels, checked on machines that
//! have the instructions: with the kernels switched off (a process-wide
//! switch, so this file is its own test process), every BVH over
//! [`Triangles`] (and the k-d tree and grid, whose leaves gather
//! triangles into blocks) still returns brute force's bits, and the same
//! as with the kernels on, one ray at a time (as a `Ray` and as a row),
//! as a stream, and in packets of eight.

use raymesh_accel::*;

mod common;
use common::{bare_of as key, kernel_cases, row_answers, row_of};

#[test]
fn fallbacks_agree_with_brute_force_and_with_the_kernels() {
    let kinds = [
        AccelKind::BvhBinned,
        AccelKind::BvhSweep,
        AccelKind::Bvh4,
        AccelKind::Bvh8,
        AccelKind::KdTree,
        AccelKind::Grid,
    ];
    // Whether the kernels run: the switch must turn them off at once, or
    // this test would compare them with themselves.
    let has_avx2 = Avx2::detect().is_some();
    #[cfg(target_arch = "x86_64")]
    assert_eq!(has_avx2, std::is_x86_feature_detected!("avx2"));
    for (name, m, rays, want) in kernel_cases() {
        for kind in kinds {
            let s = Scene::build(Triangles::from_mesh(&m), kind);
            for on in [true, false] {
                set_simd_enabled(on);
                assert_eq!(Avx2::detect().is_some(), on && has_avx2, "simd={on}");
                let mut stream = vec![None; rays.len()];
                s.intersect_stream(&rays, &mut stream);
                let mut any = vec![None; rays.len()];
                s.any_hit_stream(&rays, &mut any);
                for (i, r) in rays.iter().enumerate() {
                    assert_eq!(
                        key(stream[i]),
                        want[i],
                        "{name} {kind} simd={on}: stream, ray {i} {r:?}"
                    );
                    assert_eq!(
                        key(any[i]),
                        key(s.any_hit(r)),
                        "{name} {kind} simd={on}: any-hit stream, ray {i}"
                    );
                    assert_eq!(
                        key(s.intersect(r)),
                        want[i],
                        "{name} {kind} simd={on}: ray {i} {r:?}"
                    );
                    assert_eq!(
                        s.occluded(r),
                        want[i].is_some(),
                        "{name} {kind} simd={on}: any hit, ray {i}"
                    );
                    // The queries of rows, whose rays are made inside.
                    if let Some(row) = row_of(r) {
                        assert_eq!(
                            row_answers(&s, &row),
                            (want[i], key(s.any_hit(r)), want[i].is_some()),
                            "{name} {kind} simd={on}: row {i}"
                        );
                    }
                }
                // Packets: eight copies of each ray (a packet whose every
                // lane reaches every leaf it does, so its leaves take the
                // triangle-by-triangle test), and each eight consecutive
                // rays (a packet where they share an octant and axis
                // order, one by one where not).
                for (i, r) in rays.iter().enumerate() {
                    let p = [*r; 8];
                    let (hits, any, occluded) = (s.intersect8(&p), s.any_hit8(&p), s.occluded8(&p));
                    for k in 0..8 {
                        let what =
                            format!("{name} {kind} simd={on}: ray {i} in a packet, lane {k}");
                        assert_eq!(key(hits[k]), want[i], "{what}");
                        assert_eq!(any[k].is_some(), want[i].is_some(), "{what}");
                        assert_eq!(occluded[k], want[i].is_some(), "{what}");
                    }
                }
                for (c, eight) in rays.chunks_exact(8).enumerate() {
                    let p: [Ray; 8] = std::array::from_fn(|k| eight[k]);
                    let hits = s.intersect8(&p);
                    for k in 0..8 {
                        assert_eq!(
                            key(hits[k]),
                            want[8 * c + k],
                            "{name} {kind} simd={on}: packet {c}, lane {k}"
                        );
                    }
                }
            }
            set_simd_enabled(true);
        }
    }
}
