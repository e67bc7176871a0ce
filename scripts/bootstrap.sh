# Sourced by run.sh and test.sh: make .venv (Python 3.11, 3.12 or 3.13) and install the package
# with the extras named in $TS_EXTRAS, once per change of pyproject.toml.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"

# taichi 1.7.4 ships wheels for CPython 3.11 to 3.13 (pyproject's requires-python). $PYTHON,
# when set, is the only candidate; otherwise 3.11 comes first, then 3.12 and 3.13: the whole
# suite and the documented measurements run on 3.11, the newer two on a few test files.
find_python() {
  local cand cands=(python3.11 python3.12 python3.13 python3)
  [ -z "${PYTHON:-}" ] || cands=("$PYTHON")
  for cand in "${cands[@]}"; do
    if command -v "$cand" >/dev/null 2>&1 && \
       "$cand" -c 'import sys; sys.exit(not (3, 11) <= sys.version_info[:2] <= (3, 13))' 2>/dev/null; then
      echo "$cand"; return 0
    fi
  done
  if [ -n "${PYTHON:-}" ]; then
    echo "taichi_sim needs Python 3.11, 3.12 or 3.13 (taichi 1.7.4 has wheels for those) and" \
         "PYTHON=$PYTHON is not one of them; set PYTHON=/path/to/python3.13 (or 3.12, 3.11)" >&2
  else
    echo "taichi_sim needs Python 3.11, 3.12 or 3.13 (taichi 1.7.4 has wheels for those) and none" \
         "is on the PATH; install one, or set PYTHON=/path/to/python3.13 (or 3.12, 3.11)" >&2
  fi
  return 1
}

if [ ! -x "$venv/bin/python" ]; then
  py="$(find_python)"
  echo "[setup] creating $venv with $py" >&2
  "$py" -m venv "$venv"
fi

stamp="$venv/.installed-${TS_EXTRAS:-base}"
want="$(cat "$root/pyproject.toml" | sha256sum | cut -c1-16)"
if [ "$(cat "$stamp" 2>/dev/null || true)" != "$want" ]; then
  echo "[setup] installing taichi_sim${TS_EXTRAS:+[$TS_EXTRAS]} into .venv (first run only)" >&2
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    -e "$root${TS_EXTRAS:+[$TS_EXTRAS]}" >&2
  # the package's bytecode, once: where PYTHONDONTWRITEBYTECODE is set every command compiled its
  # 250 modules from source again (0.1-0.2 s of each start)
  "$venv/bin/python" -m compileall -q "$root/taichi_sim" >/dev/null 2>&1 || true
  echo "$want" > "$stamp"
fi

apt_updated=0
# apt-get install "$@" as root on Debian/Ubuntu (one apt-get update per run); 1 when it cannot.
apt_install() {
  [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 || return 1
  if [ "$apt_updated" = 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2 || true
    apt_updated=1
  fi
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >&2
}

# Software Vulkan (Mesa lavapipe) so GGUI can render offscreen on machines without a GPU.
ensure_vulkan() {
  if ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || \
     ls /usr/share/vulkan/icd.d/nvidia_icd*.json >/dev/null 2>&1 || \
     ls /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then
    return 0
  fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[setup] installing mesa-vulkan-drivers (software Vulkan for GGUI)" >&2
    apt_install mesa-vulkan-drivers libvulkan1 || \
      echo "[setup] could not install mesa-vulkan-drivers; rendering tests will be skipped" >&2
  else
    echo "[setup] no Vulkan driver found; install Debian's mesa-vulkan-drivers for rendering" >&2
  fi
}

# A virtual X server and an input driver for the launcher's real-window test
# (tests/test_launcher_window.py), plus the X libraries GLFW loads when it opens a window.
ensure_xvfb() {
  if command -v Xvfb >/dev/null 2>&1 && command -v xdotool >/dev/null 2>&1; then
    return 0
  fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[setup] installing xvfb and xdotool (the launcher's real-window test)" >&2
    apt_install xvfb xdotool libx11-xcb1 libxrandr2 libxinerama1 libxcursor1 libxi6 || \
      echo "[setup] could not install xvfb and xdotool; the real-window test will be skipped" >&2
  else
    echo "[setup] Xvfb or xdotool missing; install Debian's xvfb and xdotool for the real-window test" >&2
  fi
}
