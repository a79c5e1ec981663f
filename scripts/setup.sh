#!/usr/bin/env bash
# Install everything reroom needs, idempotently: LLVM >= 17 for Mitsuba's fast
# llvm_ad_rgb variant (through apt, when root), and a virtual environment in
# .venv with reroom and its Python dependencies. Safe to run repeatedly: it
# only reinstalls when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${PYTHON:-python3}

have_llvm() {
  local f
  for f in /usr/lib/*/libLLVM-1[7-9].so* /usr/lib/*/libLLVM-2[0-9].so* /usr/lib/*/libLLVM.so.1[7-9]* \
           /usr/lib/*/libLLVM.so.2[0-9]* /usr/lib/llvm-1[7-9]/lib/libLLVM*.so*; do
    [ -e "$f" ] && return 0
  done
  return 1
}

if ! have_llvm; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "setup: installing libllvm19 (Mitsuba's llvm_ad_rgb variant needs LLVM >= 17)" >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19) >&2 \
      || echo "setup: WARNING: could not install libllvm19; reroom will fall back to Mitsuba's slow scalar_rgb variant" >&2
  else
    echo "setup: WARNING: no libLLVM >= 17 and not root: reroom will use Mitsuba's slow scalar_rgb variant." >&2
    echo "setup:          ask an administrator to run: apt-get install libllvm19" >&2
  fi
fi

# Open3D (TSDF fusion) links against libusb at import time.
if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "setup: installing libusb-1.0-0 (needed to import Open3D)" >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0) >&2 \
      || echo "setup: WARNING: could not install libusb-1.0-0; Open3D (mesh fusion) will not import" >&2
  else
    echo "setup: WARNING: libusb-1.0-0 is missing and we are not root; Open3D will not import" >&2
  fi
fi

# Headless Chromium: the browser check of report.html (tests/test_report.py skips
# without it). REROOM_SETUP_BROWSER=0 leaves it out (scripts/run.sh: the main job needs
# no browser). The install is ~50 s and ~100 packages on a fresh Debian 12.
have_chromium() {
  command -v chromium >/dev/null || command -v chromium-browser >/dev/null \
    || command -v google-chrome >/dev/null || [ -n "${REROOM_CHROMIUM:-}" ]
}
if [ "${REROOM_SETUP_BROWSER:-1}" != "0" ] && ! have_chromium; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "setup: installing chromium (headless browser check of report.html, about a minute)" >&2
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >&2 \
      || echo "setup: WARNING: could not install chromium; the report's browser test will be skipped" >&2
  else
    echo "setup: note: no chromium and not root: the report's browser test will be skipped" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv" >&2
  "$PY" -m venv .venv
fi
STAMP=.venv/.reroom-installed
HASH=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$HASH" ]; then
  echo "setup: installing reroom and its dependencies into .venv" >&2
  .venv/bin/python -m pip install -q --upgrade pip >&2
  .venv/bin/python -m pip install -q -e ".[dev]" >&2
  echo "$HASH" > "$STAMP"
fi
export PATH="$ROOT/.venv/bin:$PATH"
