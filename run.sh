#!/usr/bin/env bash
# The main job. Installs what it needs on first use (with the bench extra: scipy and matplotlib,
# which `bench` and the README's examples use); arguments go to `taichi-sim`.
set -euo pipefail
cd "$(dirname "$0")"
TS_EXTRAS=bench source scripts/bootstrap.sh
if [ $# -gt 0 ]; then
  exec .venv/bin/taichi-sim "$@"
fi
# The launcher (with a display): on the first use of this code, compile in the background, at low
# priority, what the launcher's first visit to each scene compiles, into Taichi's kernel cache, so
# that in later sessions no first switch waits on it (python -m taichi_sim.app.warm; the session
# already open compiles its own first visits: a Taichi program reads the cache's index once).
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] && [ "${TS_WARM:-1}" != 0 ]; then
  code="$(find taichi_sim -name '*.py' -print0 | sort -z | xargs -0 cat | sha256sum | cut -c1-16)"
  running="$(cat .venv/warm.pid 2>/dev/null || true)"
  if [ "$(cat .venv/.warmed 2>/dev/null || true)" != "$code" ] && \
     ! { [ -n "$running" ] && kill -0 "$running" 2>/dev/null; }; then
    echo "[setup] compiling the launcher's scenes ahead in the background (once; log: .venv/warm.log)" >&2
    # once per version of the code, also where a scene failed (the log names it)
    (nice -n 19 .venv/bin/python -m taichi_sim.app.warm >.venv/warm.log 2>&1; echo "$code" > .venv/.warmed) \
      </dev/null >/dev/null 2>&1 &
    echo $! > .venv/warm.pid
  fi
fi
exec .venv/bin/taichi-sim
