#!/usr/bin/env bash
# The main job on the embedded default: install what is needed, then
# `reroom demo` (extra arguments are passed on, e.g. --out DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
exec .venv/bin/reroom demo "$@"
