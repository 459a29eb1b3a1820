#!/usr/bin/env bash
# Makes the pictures the README and docs/ show, from the current build: the demo's plot (`gonio plot` of the demo
# dry-run on the realistic simulated instrument) and a screenshot of the daemon's status page in headless
# Chromium while the daemon runs the same demo. Installs Debian's chromium when missing (root or sudo), as
# tests/browser/run.sh does.
#
#   docs/make-figures.sh                         # builds gonio (release) with cargo
#   GONIO=/path/to/gonio docs/make-figures.sh    # uses that binary
set -euo pipefail
cd "$(dirname "$0")/.."

fail() {
    echo "FAIL: $*" >&2
    exit 1
}

chromium="$(command -v chromium || command -v chromium-browser || true)"
if [ -z "$chromium" ]; then
    if [ "$(id -u)" -eq 0 ]; then as_root=(); else as_root=(sudo -n); fi
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q || fail "apt-get update failed"
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium ||
        fail "could not install Debian's chromium package"
    chromium="$(command -v chromium)"
fi
if [ -z "${GONIO:-}" ]; then
    cargo build --release -p gonio
    GONIO="${CARGO_TARGET_DIR:-target}/release/gonio"
fi
[ -x "$GONIO" ] || fail "no gonio binary at $GONIO"

work="$(mktemp -d)"
daemon_pid=""
cleanup() {
    [ -n "$daemon_pid" ] && kill "$daemon_pid" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT

echo "== the demo's plot"
"$GONIO" run config/campaigns/demo.toml --instrument config/instruments/realistic.toml --out "$work/demo" --quiet
"$GONIO" plot "$work/demo" --out docs/images/demo-plot.svg

echo "== the status page, the daemon running the demo at 10x"
port=7893
"$GONIO" daemon --instrument config/instruments/realistic.toml --data "$work/daemon" --sim-time-scale 10 \
    --listen "127.0.0.1:$port" 2>"$work/daemon.log" &
daemon_pid=$!
url="http://127.0.0.1:$port"
for _ in $(seq 50); do
    "$GONIO" ctl --url "$url" status >/dev/null 2>&1 && break
    sleep 0.2
done
"$GONIO" ctl --url "$url" submit config/campaigns/demo.toml
# About half the points, so that the progress, the ETA and the plot all show something.
for _ in $(seq 300); do
    done_points="$("$GONIO" ctl --url "$url" status | awk '{split($3, a, "/"); print a[1]}')"
    [ "${done_points:-0}" -ge 100 ] && break
    sleep 0.2
done
"$chromium" --headless --no-sandbox --disable-gpu --hide-scrollbars --window-size=1280,1000 \
    --virtual-time-budget=4000 --screenshot="$work/status.png" "$url/" 2>/dev/null
cp "$work/status.png" docs/images/status-page.png
echo "== wrote docs/images/demo-plot.svg and docs/images/status-page.png"
