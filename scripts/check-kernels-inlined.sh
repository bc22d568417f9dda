#!/usr/bin/env bash
# Checks that no x86 SIMD intrinsic was left out of line in raymesh's
# release binaries: each must be inlined into a kernel compiled for its
# instruction set (a walk under `Avx2::run`, a `#[target_feature]`
# function).
#
#   scripts/check-kernels-inlined.sh [BINARY...]
#
# Without arguments it checks the binaries found in `target/release/`
# (`raymesh`, `raymesh-peers`, `raymesh-ab`). Exits 1, naming each
# binary and the functions, when one has out-of-line intrinsics.
#
# Why: the AVX2 walks reach their triangle kernel through closures, and
# LLVM inlines a closure only while it judges it cheap, judging it as
# compiled outside the AVX2 region, where every intrinsic of the kernel
# still counts as a call. The one-ray closest-hit walk sits near that
# limit: one branch added to the kernel (an early return, stop 61) took
# its leaf closure past it, the 378 intrinsic calls in it stayed calls to
# functions compiled for no AVX at all, and `bvh8` ran 4 times slower
# (`raymesh-ab` on the dragon: 0.24x) with every test passing. The
# symbols of those intrinsics (`core::core_arch::x86::avx::_mm256_*`)
# are what this looks for; a sound build has none. A profile-guided build
# may have some where its training ran a walk rarely or never (LLVM then
# compiles the walk as cold code): scripts/pgo-build.sh runs this on its
# binaries and says so.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$(uname -m)" != x86_64 ]; then
    echo "check-kernels-inlined.sh: not an x86-64 host; nothing checked"
    exit 0
fi
if ! command -v nm >/dev/null; then
    echo "check-kernels-inlined.sh: nm (binutils) not found; nothing checked"
    exit 0
fi

binaries=("$@")
if [ ${#binaries[@]} -eq 0 ]; then
    for b in raymesh raymesh-peers raymesh-ab; do
        if [ -x "target/release/$b" ]; then
            binaries+=("target/release/$b")
        fi
    done
fi
if [ ${#binaries[@]} -eq 0 ]; then
    echo "check-kernels-inlined.sh: no binary to check (build with cargo build --release first)" >&2
    exit 1
fi

failed=0
for b in "${binaries[@]}"; do
    out_of_line=$(nm -C "$b" | grep -E 'core::core_arch::x86(_64)?::[a-z0-9_]+::_mm' || true)
    if [ -n "$out_of_line" ]; then
        n=$(printf '%s\n' "$out_of_line" | wc -l)
        echo "$b: $n SIMD intrinsics left out of line (a kernel compiled outside its AVX2 region):"
        printf '%s\n' "$out_of_line" | awk '{print "  " $NF}' | head -20
        failed=1
    else
        echo "$b: every SIMD intrinsic inlined"
    fi
done
exit $failed
