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
        "$bin/raymesh" render "$m" --width 160 --height 120 --threads 1 -o "$work/$mesh.png" >/dev/null
        if $bench; then
            "$bin/raymesh-peers" "$m" --peers none --accel bvh8 --threads 1 --size 256 >/dev/null
            for w in primary random shadow; do
                for mode in "" --packets --stream; do
                    # shellcheck disable=SC2086
                    "$bin/raymesh-ab" "$m" --accel bvh8 --workload "$w" --size 256 --rounds 1 $mode >/dev/null
                done
            done
        fi
    done
    "$bin/raymesh" render --width 160 --height 120 --threads 1 -o "$work/demo.png" >/dev/null
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
    train "$PWD/target/release" "$work"
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

echo "== instrumented build"
RUSTFLAGS="-Cprofile-generate=$profiles" \
    cargo build --release --target-dir "$root/gen" "${packages[@]}"

echo "== training"
train "$root/gen/release" "$work"

echo "== merging $(find "$profiles" -name '*.profraw' | wc -l) profiles"
"$tool" merge -o "$root/merged.profdata" "$profiles"

echo "== optimized build"
RUSTFLAGS="-Cprofile-use=$root/merged.profdata" \
    cargo build --release --target-dir "$root/use" "${packages[@]}"

echo "PGO binaries in target/pgo/use/release/"
