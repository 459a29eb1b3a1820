#!/usr/bin/env bash
# What a clean `cargo test --workspace` costs at one commit (docs/development/testing.md): a fresh clone of this
# repository at COMMIT, an empty target directory, CARGO_INCREMENTAL=0 as .ci/run sets it; the build
# (`--no-run`) and the run timed apart, the test binaries counted, the target directory's size. Takes about ten
# minutes on two cores; run the commits to compare back to back, with nothing else on the machine.
#
#   docs/development/measure-test-cost.sh COMMIT [COMMIT ...]
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
[ "$#" -ge 1 ] || { echo "usage: $0 COMMIT [COMMIT ...]" >&2; exit 2; }
for commit in "$@"; do
    work="$(mktemp -d)"
    git clone -q "$repo" "$work/src"
    git -C "$work/src" checkout -q "$commit"
    export CARGO_TARGET_DIR="$work/target" CARGO_INCREMENTAL=0
    cd "$work/src"
    # bash's `time`: wall, user and system seconds of the build.
    TIMEFORMAT='%R %U %S'
    build=$( { time cargo test --workspace --no-run >"$work/build.log" 2>&1; } 2>&1 )
    start=$(date +%s.%N)
    cargo test --workspace >"$work/run.log" 2>&1 && status=passed || status=FAILED
    ran=$(date +%s.%N)
    binaries=$(grep -c '^     Running' "$work/run.log" || true)
    read -r wall user sys <<<"$build"
    printf '%s: build %.0f s wall (%.0f s CPU), run %.0f s (%s), %s test binaries, target %s\n' \
        "$commit" "$wall" "$(awk "BEGIN { print $user + $sys }")" "$(awk "BEGIN { print $ran - $start }")" "$status" "$binaries" \
        "$(du -sh "$work/target" | cut -f1)"
    cd "$repo"
    rm -rf "$work"
done
