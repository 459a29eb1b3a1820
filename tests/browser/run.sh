#!/usr/bin/env bash
# The daemon's live status page in a real headless Chromium, against `gonio daemon` running dry-runs on the
# simulated instrument (see status_page.py and console_panel.py for what is checked). Installs Debian's chromium package when no
# chromium is found (needs root or password-less sudo), builds gonio, runs the test. Never skips: a missing
# browser, Python or a broken page is a failure (exit 1).
#
#   tests/browser/run.sh                 # from anywhere; uses $CARGO_TARGET_DIR like cargo
#   GONIO=/path/to/gonio tests/browser/run.sh   # test that binary instead of building one
set -euo pipefail
cd "$(dirname "$0")/../.."

fail() {
    echo "FAIL: $*" >&2
    exit 1
}

chromium="$(command -v chromium || command -v chromium-browser || true)"
if [ -z "$chromium" ]; then
    echo "== installing chromium (Debian package)"
    if [ "$(id -u)" -eq 0 ]; then
        as_root=()
    elif command -v sudo >/dev/null 2>&1; then
        as_root=(sudo -n)
    else
        fail "chromium is not installed and this user can neither be root nor use sudo to install it"
    fi
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q ||
        fail "apt-get update failed"
    "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium ||
        fail "could not install Debian's chromium package"
    chromium="$(command -v chromium)" || fail "chromium still not found after installing it"
fi
command -v python3 >/dev/null 2>&1 || fail "python3 is needed to drive the browser"
echo "== $("$chromium" --version 2>/dev/null || echo "$chromium")"

if [ -z "${GONIO:-}" ]; then
    echo "== cargo build -p gonio"
    cargo build -p gonio
    GONIO="${CARGO_TARGET_DIR:-target}/debug/gonio"
fi
[ -x "$GONIO" ] || fail "no gonio binary at $GONIO"

echo "== status page in headless Chromium"
python3 tests/browser/status_page.py "$GONIO" "$chromium"
echo "== the status page's console panel in headless Chromium"
python3 tests/browser/console_panel.py "$GONIO" "$chromium"
echo "== gonio report's page in headless Chromium (and the status page's Report button)"
python3 tests/browser/report_page.py "$GONIO" "$chromium"
