#!/usr/bin/env bash
# The main job. Installs what it needs on first use (with the bench extra: scipy and matplotlib,
# which `bench` and the README's examples use); arguments go to `taichi-sim`.
set -euo pipefail
cd "$(dirname "$0")"
TS_EXTRAS=bench source scripts/bootstrap.sh
if [ $# -gt 0 ]; then
  exec .venv/bin/taichi-sim "$@"
fi
exec .venv/bin/taichi-sim
