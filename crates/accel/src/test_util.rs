//! Inputs shared by the unit tests.

use proptest::prelude::*;
use raymesh_geometry::{Aabb, Vec3};

/// `n` small boxes in seven overlapping clusters (a fixed xorshift
/// sequence): enough structure that SAH builders have real choices.
pub(crate) fn clustered_boxes(n: usize) -> Vec<Aabb> {
    let mut next = xorshift(0x2545_f491);
    (0..n)
        .map(|i| {
            let cluster = Vec3::splat((i % 7) as f32 * 3.0);
            let p = cluster + Vec3::new(next(), next(), next()) * 2.0;
            let e = Vec3::new(next(), next(), next()) * 0.05;
            Aabb::new(p, p + e)
        })
        .collect()
}

/// A fixed xorshift sequence from `seed` (not 0), as floats in [0, 1].
pub(crate) fn xorshift(seed: u32) -> impl FnMut() -> f32 {
    let mut s = seed;
    move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32) / (u32::MAX as f32)
    }
}

/// The configuration of a property test that runs `n` cases: `n`, or
/// under Miri, which interprets every operation (about a thousand times
/// slower), [`MIRI_CASES`] drawn by proptest's XorShift generator rather
/// than its ChaCha one (whose rounds took most of Miri's time: 15 s a
/// case of a node-test comparison). Under Miri the tests check what the
/// kernels' `unsafe` loads and stores touch; the native run's `n` cases
/// check their answers.
pub(crate) fn config(n: u32) -> ProptestConfig {
    if cfg!(miri) {
        ProptestConfig {
            cases: MIRI_CASES,
            rng_algorithm: proptest::test_runner::RngAlgorithm::XorShift,
            failure_persistence: None,
            ..ProptestConfig::default()
        }
    } else {
        ProptestConfig::with_cases(n)
    }
}

/// Property-test cases under Miri (see [`config`]).
const MIRI_CASES: u32 = 16;

/// The bits of `x` as the kernel-against-fallback tests compare them:
/// `x.to_bits()`, but under Miri every NaN as one. Rust leaves the sign
/// and payload of a NaN an operation makes unspecified, and Miri draws
/// them at random, so that two runs of the same code may differ there;
/// the hardware gives each operation one NaN, and the native run checks
/// those bits as they are.
pub(crate) fn bits(x: f32) -> u32 {
    if cfg!(miri) && x.is_nan() {
        f32::NAN.to_bits()
    } else {
        x.to_bits()
    }
}

/// A rayon pool of `threads` workers, for tests that compare thread counts.
pub(crate) fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
}

/// Coordinates that include the hard cases: zeros of both signs,
/// infinities, NaN, huge and tiny values.
pub(crate) fn hard_coord() -> impl Strategy<Value = f32> {
    prop_oneof![
        6 => -8.0f32..8.0,
        1 => Just(0.0f32),
        1 => Just(-0.0f32),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
        1 => Just(f32::NAN),
        1 => Just(1e30f32),
        1 => Just(-1e-30f32),
        1 => (-2i32..3).prop_map(|i| i as f32),
    ]
}

/// Vectors of [`hard_coord`]s.
pub(crate) fn hard_vec3() -> impl Strategy<Value = Vec3> {
    (hard_coord(), hard_coord(), hard_coord()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// Lattice coordinates make edge functions round to exactly zero
/// (rays through shared edges and vertices), which takes the f64 path.
pub(crate) fn lattice() -> impl Strategy<Value = Vec3> {
    (-3i32..4, -3i32..4, -3i32..4)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32) * 0.5)
}

/// Checks a block test's lanes against the scalar test's hit of each
/// lane (`want(k)`): the same lanes hit, with the same bits of `t`,
/// `u` and `v`.
pub(crate) fn lanes_match(
    mask: u32,
    out: &crate::BlockHits,
    want: impl Fn(usize) -> Option<raymesh_geometry::TriHit>,
) -> Result<(), TestCaseError> {
    for k in 0..8 {
        let want = want(k);
        prop_assert_eq!(mask >> k & 1 != 0, want.is_some(), "lane {}", k);
        if let Some(w) = want {
            let h = out.get(k);
            prop_assert_eq!(
                (bits(h.t), bits(h.u), bits(h.v)),
                (bits(w.t), bits(w.u), bits(w.v)),
                "lane {}",
                k
            );
        }
    }
    Ok(())
}

/// Checks a SIMD kernel of the `W`-wide node test against the portable
/// loops, bit for bit: a node of the `used` boxes among `corners` (the
/// others empty), a ray from `o` along `d` starting at `tmin`, `bound`.
#[cfg(any(
    target_arch = "x86_64",
    all(target_arch = "aarch64", target_feature = "neon")
))]
pub(crate) fn node_kernel_matches<const W: usize>(
    kernel: impl Fn(&crate::bvh::WideNode<W>, &crate::bvh::BoxRay, f32, &mut [f32; W]) -> u32,
    corners: &[(Vec3, Vec3)],
    used: u32,
    (o, d, tmin, bound): (Vec3, Vec3, f32, f32),
) -> Result<(), TestCaseError> {
    let mut node = crate::bvh::WideNode::<W>::empty();
    for (i, (a, b)) in corners.iter().enumerate() {
        if used >> i & 1 != 0 {
            node.set_box(i, Aabb::new(a.min(*b), a.max(*b)));
        }
    }
    let ray = raymesh_geometry::Ray::new(o, d, tmin.min(0.0), f32::INFINITY);
    let mut r = crate::bvh::BoxRay::new(&ray);
    r.tmin = tmin;
    let (mut ta, mut tb) = ([0.0f32; W], [0.0f32; W]);
    let ma = kernel(&node, &r, bound, &mut ta);
    let mb = crate::bvh::slab_scalar(&node, &r, bound, &mut tb);
    prop_assert_eq!(ma, mb);
    for i in 0..W {
        prop_assert_eq!(bits(ta[i]), bits(tb[i]), "lane {}", i);
    }
    Ok(())
}
