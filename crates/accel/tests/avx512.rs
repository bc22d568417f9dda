//! The AVX-512 builds of the wide BVH walks (the AVX2 walks compiled
//! with AVX-512F and AVX-512VL, for their 32 vector registers) against
//! the AVX2 builds, on machines that have AVX-512: closest hits, any
//! hits and occlusion, bit for bit, and brute force's closest hits. The
//! switch is process-wide, so this file is its own test process. Where
//! the CPU lacks AVX-512 both runs take the AVX2 builds.

use raymesh_accel::*;

mod common;
use common::{bare_of as key, kernel_cases, row_answers, row_of};

#[test]
fn avx512_builds_agree_with_avx2_builds() {
    for ((name, m, rays, want), kind) in kernel_cases()
        .into_iter()
        .flat_map(|case| [AccelKind::Bvh8, AccelKind::Bvh4].map(|k| (case.clone(), k)))
    {
        let name = format!("{name} {}", kind.name());
        let s = Scene::from_mesh_with(&m, kind, &BuildConfig::default());
        let mut runs = Vec::new();
        for on in [true, false] {
            set_avx512_enabled(on);
            let run: Vec<_> = rays
                .iter()
                .map(|r| (key(s.intersect(r)), key(s.any_hit(r)), s.occluded(r)))
                .collect();
            for (i, (closest, _, occluded)) in run.iter().enumerate() {
                assert_eq!(*closest, want[i], "{name} avx512={on}: ray {i}");
                assert_eq!(*occluded, want[i].is_some(), "{name} avx512={on}: ray {i}");
            }
            // The queries of rows, whose rays are made in the same regions.
            for (i, r) in rays.iter().enumerate() {
                if let Some(row) = row_of(r) {
                    assert_eq!(row_answers(&s, &row), run[i], "{name} avx512={on}: row {i}");
                }
            }
            runs.push(run);
        }
        set_avx512_enabled(true);
        assert_eq!(runs[0], runs[1], "{name}: the two builds differ");
    }
}
