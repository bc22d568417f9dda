#!/usr/bin/env bash
# A profile-guided (PGO) release build of raymesh's binaries: `raymesh`,
# and with `--bench` also `raymesh-peers` and `raymesh-ab`.
#
#   scripts/pgo-build.sh [--bench] [--features LIST]
#   scripts/pgo-build.sh --check [--bench]
#
# Each binary is first built instrumented (`-Cprofile-generate`), run on
# training work of its own (meshes it generates: no files needed), and
# built again with the merged profile (`-Cprofile-use`). The profile must
# come from the binary it optimizes: the library's generic code is
# compiled into each binary, and a profile taken from another binary does
# not match it (its walks then compile as without one). The binaries
# land in `target/pgo/use/release/`; the plain build in `target/` is
# untouched.
#
# `--features LIST` is passed to the bench crate (e.g. `embree,openmesh`,
# which need Debian's libembree-dev and libopenmesh-dev). Needs
# `llvm-profdata` of the compiler's own LLVM: the `llvm-tools` rustup
# component, added here when missing. `--check` only runs the training
# with the plain binaries already in `target/release/` (CI does, so that
# the training's commands keep up with the binaries' options).
set -euo pipefail
trap 'echo "pgo-build.sh: failed: $BASH_COMMAND" >&2' ERR
cd "$(dirname "$0")/.."

bench=false
check=false
features=""
while [ $# -gt 0 ]; do
    case "$1" in
        --bench) bench=true ;;
        --features) features="${2:?--features needs a list}"; shift ;;
        --check) check=true ;;
        -h | --help) sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "pgo-build.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
    esac
    shift
done
if [ -n "$features" ] && ! $bench; then
    echo "pgo-build.sh: --features is for the bench crate: give --bench too" >&2
    exit 2
fi

# The training set, run by the binaries in directory $1, its files in
# directory $2.
train() {
    local bin="$1" work="$2" mesh m w mode
    # Two meshes unlike the ones we benchmark on: a UV sphere (regular,
    # convex) and a terrain (a height field), each with its own rays.
    "$bin/raymesh" generate sphere --triangles 60000 -o "$work/sphere.ply" >/dev/null
    "$bin/raymesh" generate terrain --triangles 60000 -o "$work/terrain.ply" >/dev/null
    for mesh in sphere terrain; do
        m="$work/$mesh.ply"
        for w in primary random diffuse shadow; do
            "$bin/raymesh" rays "$m" --workload "$w" --size 256 -o "$work/$mesh-$w.npy" 2>/dev/null
            for mode in "" --packets --stream; do
                # shellcheck disable=SC2086 # an empty mode is no argument
                "$bin/raymesh" raycast "$m" --rays "$work/$mesh-$w.npy" --accel bvh8 $mode --threads 1 >/dev/null
                # shellcheck disable=SC2086
                "$bin/raymesh" raycast "$m" --rays "$work/$mesh-$w.npy" --accel bvh8 $mode --any-hit --threads 1 >/dev/null
            done
        done
        # The 4-wide BVH's, the grid's and the k-d tree's walks (AVX2
        # regions of their own: left out of the training, LLVM compiled
        # the grid's and the k-d tree's as cold and left their closures out
        # of line, every kernel intrinsic a call).
        for accel in bvh4 grid kdtree; do
            for w in primary random; do
                "$bin/raymesh" raycast "$m" --rays "$work/$mesh-$w.npy" --accel "$accel" --threads 1 >/dev/null
                "$bin/raymesh" raycast "$m" --rays "$work/$mesh-$w.npy" --accel "$accel" --any-hit --threads 1 >/dev/null
            done
            "$bin/raymesh" render "$m" --accel "$accel" --width 80 --height 60 --threads 1 -o "$work/$mesh-$accel.png" >/dev/null
        done
        "$bin/raymesh" render "$m" --width 160 --height 120 --threads 1 -o "$work/$mesh.png" >/dev/null
        # The counting walks: a heat map, and the counts `--stats` adds.
        "$bin/raymesh" render "$m" --heatmap --width 80 --height 60 --threads 1 -o "$work/$mesh-heat.png" >/dev/null
        "$bin/raymesh" raycast "$m" --rays "$work/$mesh-random.npy" --accel bvh8 --stats --threads 1 >/dev/null
        "$bin/raymesh" raycast "$m" --rays "$work/$mesh-random.npy" --accel bvh8 --stats --any-hit --threads 1 >/dev/null
        if $bench; then
            "$bin/raymesh-peers" "$m" --peers none --accel bvh8 --threads 1 --size 256 >/dev/null
            for w in primary random shadow; do
                for mode in "" --packets --stream; do
                    # shellcheck disable=SC2086
                    "$bin/raymesh-ab" "$m" --accel bvh8 --workload "$w" --size 256 --rounds 1 $mode >/dev/null
                done
            done
            for accel in grid kdtree; do
                "$bin/raymesh-peers" "$m" --peers none --accel "$accel" --threads 1 --size 128 >/dev/null
                "$bin/raymesh-ab" "$m" --accel "$accel" --workload random --size 128 --rounds 1 >/dev/null
            done
        fi
    done
    "$bin/raymesh" render --width 160 --height 120 --threads 1 -o "$work/demo.png" >/dev/null
    "$bin/raymesh" render --heatmap --width 80 --height 60 --threads 1 -o "$work/demo-heat.png" >/dev/null
}

# The builds of the walks the training can run on this CPU. Where it has
# AVX-512F and AVX-512VL the 8-wide walks run compiled for them, and the
# training runs a second time with them off (RAYMESH_AVX512=off), so that
# their AVX2 builds, which CPUs without AVX-512 run, are trained too.
# Elsewhere the AVX-512 builds are left out of the binaries
# (`--cfg raymesh_no_avx512`): code the training never ran, LLVM compiles
# as cold, and it left those walks' closures out of line, every kernel
# intrinsic a call to a function compiled for no AVX, so that the binary
# traced several times slower on a CPU with AVX-512 than here.
avx512=false
if grep -qw avx512f /proc/cpuinfo 2>/dev/null && grep -qw avx512vl /proc/cpuinfo 2>/dev/null; then
    avx512=true
fi
cfg=""
if ! $avx512; then
    cfg="--cfg raymesh_no_avx512"
fi

# The training, twice where the CPU has AVX-512 (see above).
train_all() {
    train "$1" "$2"
    if $avx512; then
        (export RAYMESH_AVX512=off && train "$1" "$2")
    fi
}

if $check; then
    bins=(raymesh)
    if $bench; then
        bins+=(raymesh-peers raymesh-ab)
    fi
    for b in "${bins[@]}"; do
        if [ ! -x "target/release/$b" ]; then
            echo "pgo-build.sh: --check needs target/release/$b: build it first (cargo build --release)" >&2
            exit 1
        fi
    done
    work="$(mktemp -d)"
    trap 'rm -rf "$work"' EXIT
    train_all "$PWD/target/release" "$work"
    echo "the training ran"
    exit 0
fi

profdata() {
    find "$(rustc --print sysroot)" -name llvm-profdata -type f 2>/dev/null | head -n 1
}
tool="$(profdata)"
if [ -z "$tool" ]; then
    echo "== rustup component add llvm-tools (for llvm-profdata)"
    rustup component add llvm-tools
    tool="$(profdata)"
fi
if [ -z "$tool" ]; then
    echo "pgo-build.sh: llvm-profdata not found in $(rustc --print sysroot)" >&2
    exit 1
fi

root="$PWD/target/pgo"
profiles="$root/profiles"
work="$root/work"
rm -rf "$profiles" "$work"
mkdir -p "$profiles" "$work"

packages=(-p raymesh)
if $bench; then
    packages+=(-p raymesh-bench)
    if [ -n "$features" ]; then
        packages+=(--features "$features")
    fi
fi

if $avx512; then
    echo "== this CPU has AVX-512: the training runs with and without it"
else
    echo "== this CPU has no AVX-512: the binaries are built without the AVX-512 walks ($cfg)"
fi

echo "== instrumented build"
RUSTFLAGS="-Cprofile-generate=$profiles $cfg" \
    cargo build --release --target-dir "$root/gen" "${packages[@]}"

echo "== training"
train_all "$root/gen/release" "$work"

echo "== merging $(find "$profiles" -name '*.profraw' | wc -l) profiles"
"$tool" merge -o "$root/merged.profdata" "$profiles"

echo "== optimized build"
RUSTFLAGS="-Cprofile-use=$root/merged.profdata $cfg" \
    cargo build --release --target-dir "$root/use" "${packages[@]}"

# A profile changes what LLVM inlines: code the training ran rarely or
# never is compiled as cold, and a walk's closure found cold stays out of
# line with its kernel's intrinsics as calls (several times slower than
# in the plain build). Say where (scripts/check-kernels-inlined.sh).
built=("$root/use/release/raymesh")
if $bench; then
    built+=("$root/use/release/raymesh-peers" "$root/use/release/raymesh-ab")
fi
echo "== kernels inlined"
if ! scripts/check-kernels-inlined.sh "${built[@]}"; then
    echo "pgo-build.sh: some walks the training ran rarely or never were compiled as cold code,"
    echo "  their kernels out of line: they run slower than in the plain build. The training"
    echo "  covers bvh8's one-ray, packet and stream walks, heat maps and --stats; add the"
    echo "  work that matters to you to train() if it is not there."
fi

echo "PGO binaries in target/pgo/use/release/"
