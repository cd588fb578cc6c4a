#!/usr/bin/env bash
# Installs what `pipeline` needs on a Debian machine that has only the Rust toolchain:
# FFmpeg's -dev libraries and pkg-config (ffmpeg-next), clang (bindgen), and the ffmpeg CLI
# (tests and benchmarks make their clips with it). Installs only what is missing; never asks.
set -euo pipefail

need=()
pkg_config_ok() { command -v pkg-config >/dev/null 2>&1 && pkg-config --exists libavcodec libavformat libavutil libswscale; }
pkg_config_ok || need+=(pkg-config libavcodec-dev libavformat-dev libavutil-dev libswscale-dev libswresample-dev libavfilter-dev libavdevice-dev)
command -v clang >/dev/null 2>&1 || need+=(clang)
[ -n "$(ls /usr/lib/llvm-*/lib/libclang*.so* 2>/dev/null | head -1)" ] || need+=(libclang-dev)
command -v ffmpeg >/dev/null 2>&1 || need+=(ffmpeg)

if [ ${#need[@]} -eq 0 ]; then
  echo "setup: FFmpeg libraries, clang and ffmpeg are present" >&2
  exit 0
fi
echo "setup: installing ${need[*]}" >&2
SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
echo "setup: done" >&2
