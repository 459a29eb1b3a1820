#!/usr/bin/env bash
# Mitsuba 3 reads gonio's RGL export (extra tier: needs Python 3 and PyPI's `mitsuba`, installed here if missing).
# Usage: GONIO=path/to/gonio tests/mitsuba/run.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
GONIO="${GONIO:-${CARGO_TARGET_DIR:-target}/debug/gonio}"
if ! python3 -c "import mitsuba" 2>/dev/null; then
    if ! python3 -m pip install --quiet mitsuba; then
        echo "FAIL: could not install mitsuba from PyPI (needed by tests/mitsuba/rgl_mitsuba.py)" >&2
        exit 1
    fi
fi
python3 tests/mitsuba/rgl_mitsuba.py "$GONIO"
