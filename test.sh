#!/usr/bin/env bash
# Run the test suite (pytest on the CPU arch). Installs what it needs on first use.
# Extra arguments go to pytest, e.g. ./test.sh -k circle -x
# Tests run in one worker process per core (pytest-xdist; most of their time is Taichi compiling
# kernels, which is single-threaded); TS_TEST_WORKERS=0 runs them in this process.
set -euo pipefail
cd "$(dirname "$0")"
TS_EXTRAS=test source scripts/bootstrap.sh
ensure_vulkan
ensure_xvfb
workers=(-n "${TS_TEST_WORKERS:-auto}")
[ "${TS_TEST_WORKERS:-auto}" = 0 ] && workers=()
# -rs: a skipped test says why in the summary (no Vulkan, no Xvfb).
exec .venv/bin/python -m pytest -rs "${workers[@]}" "$@"
