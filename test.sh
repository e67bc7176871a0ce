#!/usr/bin/env bash
# Run the test suite (pytest on the CPU arch). Installs what it needs on first use.
# Extra arguments go to pytest, e.g. ./test.sh -k circle -x
set -euo pipefail
cd "$(dirname "$0")"
TS_EXTRAS=test source scripts/bootstrap.sh
ensure_vulkan
exec .venv/bin/python -m pytest "$@"
