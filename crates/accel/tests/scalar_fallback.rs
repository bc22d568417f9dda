//! The portable fallbacks of the SIMD kernels, checked on machines that
//! have the instructions: with the kernels switched off (a process-wide
//! switch, so this file is its own test process), every BVH over
//! [`Triangles`] (and the k-d tree and grid, whose leaves gather
//! triangles into blocks) still returns brute force's bits, and the same
//! as with the kernels on, one ray at a time and as a stream.

use raymesh_accel::*;

mod common;
use common::{load, sphere_rays};

/// Hit as bits, so that `-0.0` and `0.0` differ and NaN compares.
fn key(h: Option<Hit>) -> Option<(u32, u32, u32, u32)> {
    h.map(|h| (h.prim, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()))
}

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
    for name in [
        "elephant-with-holes.off",
        "sphere.ply",
        "cube_quad.off",
        "degtri_sliding.off",
    ] {
        let m = load(name);
        let rays = sphere_rays(&m, 400);
        let brute = Scene::build(m.clone(), AccelKind::Brute);
        let want: Vec<_> = rays.iter().map(|r| key(brute.intersect(r))).collect();
        assert!(want.iter().filter(|w| w.is_some()).count() > rays.len() / 10);
        for kind in kinds {
            let s = Scene::build(Triangles::from_mesh(&m), kind);
            for on in [true, false] {
                set_simd_enabled(on);
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
                }
            }
            set_simd_enabled(true);
        }
    }
}
