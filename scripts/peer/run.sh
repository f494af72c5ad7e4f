#!/usr/bin/env bash
# The peer benchmark: reframe's independent tracer against Mitsuba 3's path tracer
# (scalar_rgb and llvm_ad_rgb) on an all-diffuse Cornell box (scripts/peer/peer.py has the
# method). Mitsuba is not a dependency of reframe: this makes its own Python environment.
#
#   scripts/peer/run.sh [peer.py flags: --spp 64 --res 256 --threads N --repeats 3 ...]
#
# Needs: reframe built (./setup.sh && cargo build --release), Python 3 with venv, and for
# llvm_ad_rgb an LLVM newer than Debian 12's default 15 (Debian's libllvm19, installed here
# with apt when run as root). Results: out/peer/peer.json and a table on stdout.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
venv=${PEER_VENV:-$root/.deps/peer-venv}
mitsuba_version=3.9.1
die() { echo "peer: $*" >&2; exit 1; }

[ -x "$root/target/release/reframe" ] || die "build reframe first: ./setup.sh && cargo build --release"
python=${PYTHON:-python3}
# A venv with pip (one that a failed attempt left half made is made again).
if ! "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
  "$python" -m venv --clear "$venv" 2>/dev/null || {
    [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null || die "$python cannot make a venv (install python3-venv)"
    apt-get update -q >/dev/null && apt-get install -y -q python3-venv >/dev/null
    /usr/bin/python3 -m venv --clear "$venv"
  }
fi
if ! "$venv/bin/python" -c "import mitsuba, sys; sys.exit(mitsuba.__version__ != '$mitsuba_version')" 2>/dev/null; then
  "$venv/bin/python" -m pip install -q "mitsuba==$mitsuba_version" numpy
fi
# Dr.Jit's LLVM backend: the newest libLLVM found (it needs more than Debian 12's LLVM 15).
if [ -z "${DRJIT_LIBLLVM_PATH:-}" ]; then
  find_llvm() {
    local v f
    for v in 21 20 19 18 17 16; do
      for f in /usr/lib/x86_64-linux-gnu/libLLVM-$v.so /usr/lib/x86_64-linux-gnu/libLLVM.so.$v* \
               /usr/lib/llvm-$v/lib/libLLVM*.so*; do
        [ -e "$f" ] && { echo "$f"; return 0; }
      done
    done
    return 0
  }
  llvm=$(find_llvm)
  if [ -z "$llvm" ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get install -y -q libllvm19 >/dev/null || { apt-get update -q >/dev/null && apt-get install -y -q libllvm19 >/dev/null; }
    llvm=$(find_llvm)
  fi
  [ -n "$llvm" ] || die "no libLLVM 16 or newer for llvm_ad_rgb (apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)"
  export DRJIT_LIBLLVM_PATH=$llvm
fi
exec "$venv/bin/python" "$root/scripts/peer/peer.py" "$@"
