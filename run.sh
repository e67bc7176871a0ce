#!/usr/bin/env bash
# The main job. Installs what it needs on first use; arguments go to `taichi-sim`.
set -euo pipefail
cd "$(dirname "$0")"
TS_EXTRAS= source scripts/bootstrap.sh
if [ $# -gt 0 ]; then
  exec .venv/bin/taichi-sim "$@"
fi
exec .venv/bin/taichi-sim
