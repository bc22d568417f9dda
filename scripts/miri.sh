#!/usr/bin/env bash
# Runs the SIMD kernels' tests of raymesh-accel under Miri, the Rust
# interpreter that reports undefined behaviour: every load and store of
# the kernels' `unsafe` blocks (`crates/accel/src/simd.rs`), checked
# against the memory it may touch, on the AVX2 and SSE paths and their
# fallbacks alike.
#
#   scripts/miri.sh [TEST FILTER [CARGO ARGS...]]    # default: simd::
#   scripts/miri.sh neon:: --target aarch64-unknown-linux-gnu
#
# The second form interprets the NEON kernels' tests as aarch64 code, on
# any machine. `--test NAME` runs an integration test's instead of the
# unit tests (RAYMESH_PROPTEST_CASES=1 keeps the agreement tests short).
#
# Not part of CI: Miri interprets every operation, and the 15 tests of
# `simd::` take about 20 minutes on one core even with the property tests
# cut to 16 cases each (`test_util::config`). Installs the nightly
# toolchain's `miri` and `rust-src` components where they are missing.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! cargo +nightly miri --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal --component miri,rust-src
fi

filter="${1:-simd::}"
shift || true

# The x86-64 kernels run where the CPU has AVX2: Miri's CPU has what the
# build enables, so the build enables AVX2 and POPCNT (the SSE kernels
# run on any x86-64). AVX-512, which Miri implements only in part, stays
# off. (NEON is part of every aarch64 build.)
if [[ " $* " != *aarch64* ]]; then
    export RUSTFLAGS="-C target-feature=+avx2,+popcnt --cfg raymesh_no_avx512"
fi
# -Zmiri-disable-isolation: the walks read the L2's size from sysfs.
# -Zmiri-tree-borrows, -Zmiri-permissive-provenance: crossbeam-epoch
#   0.9.21 (under rayon's pool) fails Stacked Borrows, the stricter of
#   Miri's two aliasing models, in its own code, and casts integers to
#   pointers; Tree Borrows accepts it.
# -Zmiri-ignore-leaks: rayon's pool threads outlive the tests.
export MIRIFLAGS="-Zmiri-disable-isolation -Zmiri-tree-borrows -Zmiri-permissive-provenance -Zmiri-ignore-leaks"
# A target folder of its own: Miri's builds are not the native ones.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-target/miri}"

# The unit tests, unless the arguments name other targets (`--test agree`).
targets=(--lib)
if [[ " $* " == *" --test"* ]]; then
    targets=()
fi
cargo +nightly miri test -p raymesh-accel "${targets[@]}" "$@" "$filter"
