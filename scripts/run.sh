#!/usr/bin/env bash
# The main job on the embedded default: install what is needed, then
# `reroom demo` (extra arguments are passed on, e.g. --out DIR): the `furnished`
# synthetic scan, `reroom run` on it, and out/demo/report.html.
set -euo pipefail
cd "$(dirname "$0")/.."
# The demo needs no browser (it screenshots its report only when one exists).
REROOM_SETUP_BROWSER=${REROOM_SETUP_BROWSER:-0}
source scripts/setup.sh
exec .venv/bin/reroom demo "$@"
