#!/usr/bin/env bash
# One-time (and idempotent) set-up of everything reframe needs to build and run on Debian 12/13:
#   - Debian packages: OpenImageIO (headers and library), libclang (bindgen), pkg-config, g++;
#   - Embree 4: the system's libembree4.so.4 if there is one, otherwise the Embree 4.4.0 runtime
#     shipped in the PyPI wheel embreex==4.4.0.post1 (pinned, sha256-checked), unpacked into .deps/;
#   - Open Image Denoise 2.5.1 (for --denoise; Debian 12 has no package): its CPU runtime from the
#     PyPI wheel pyoidn==2.5.1.0 (pinned, sha256-checked), unpacked into .deps/oidn/lib;
#   - with --tests, also what the test suite needs beyond that: Slurm (slurmctld, slurmd,
#     slurm-client) and munge, for the one-node cluster of tests/slurm.rs. Their services are
#     installed without being started or enabled: the test runs its own daemons.
# Fast when everything is already there. Run as root (or with sudo) the first time.
set -euo pipefail
cd "$(dirname "$0")"
with_tests=0
for a in "$@"; do
  case "$a" in
    --tests) with_tests=1 ;;
    *) echo "setup: unknown option $a (only --tests)" >&2; exit 2 ;;
  esac
done

EMBREE_WHEEL=embreex-4.4.0.post1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl
EMBREE_SHA256=2cd0f7d5c6342e6247e31f700761689cae7829454d8c6de0c41e62124a023e1f
EMBREE_SONAME=libembree4-4aef3270.so.4
DEPS=.deps/embree4
OIDN_WHEEL=pyoidn-2.5.1.0-py3-none-manylinux2014_x86_64.whl
OIDN_SHA256=32ad13368f8de1ef63001942ad05b02a00cd732d1206d97f352d3a3f606d823e
OIDN_DEPS=.deps/oidn

say() { echo "setup: $*" >&2; }

# --- Debian packages -------------------------------------------------------------------------
pkgs=(libopenimageio-dev libclang-dev pkg-config g++ python3 fonts-dejavu-core)
services=(slurmctld slurmd munge)
[ "$with_tests" = 1 ] && pkgs+=(slurmctld slurmd slurm-client munge)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
SUDO=""
if [ ${#missing[@]} -gt 0 ]; then
  say "installing Debian packages: ${missing[*]}"
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { say "need root to install ${missing[*]}"; exit 1; }
    SUDO=sudo
  fi
  # Daemons in the list are installed, not started: a policy-rc.d that refuses every start
  # while apt runs (unless the machine has one of its own).
  policy=""
  if [ ! -e /usr/sbin/policy-rc.d ]; then
    policy=/usr/sbin/policy-rc.d
    printf '#!/bin/sh\nexit 101\n' | $SUDO tee "$policy" >/dev/null
    $SUDO chmod +x "$policy"
    trap '$SUDO rm -f "$policy"' EXIT
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  [ -n "$policy" ] && $SUDO rm -f "$policy"
  trap - EXIT
  # ... nor enabled at boot, where systemd runs.
  for s in "${services[@]}"; do
    if [[ " ${missing[*]} " == *" $s "* ]] && [ -d /run/systemd/system ]; then
      $SUDO systemctl disable "$s" >/dev/null 2>&1 || true
    fi
  done
fi

# --- Embree 4 --------------------------------------------------------------------------------
embree() {
  if ldconfig -p 2>/dev/null | grep -q 'libembree4\.so\.4 '; then
    return 0  # the system's Embree 4; build.rs finds it
  fi
  if [ -f "$DEPS/lib/.sha256" ] && [ "$(cat "$DEPS/lib/.sha256")" = "$EMBREE_SHA256" ] \
     && [ -e "$DEPS/lib/$EMBREE_SONAME" ]; then
    return 0  # already unpacked
  fi
  say "fetching the Embree 4.4.0 runtime (PyPI wheel embreex==4.4.0.post1)"
  local tmp
  tmp=$(fetch_wheel "$EMBREE_WHEEL" "$EMBREE_SHA256" --python-version 3.11 --implementation cp \
    --platform manylinux_2_28_x86_64 embreex==4.4.0.post1)
  rm -rf "$DEPS" && mkdir -p "$DEPS/lib"
  python3 - "$tmp/$EMBREE_WHEEL" "$DEPS/lib" <<'PY'
import sys, zipfile, os
whl, dest = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(whl) as z:
    for n in z.namelist():
        if n.startswith("embreex.libs/") and not n.endswith("/"):
            p = os.path.join(dest, os.path.basename(n))
            with open(p, "wb") as f:
                f.write(z.read(n))
            os.chmod(p, 0o755)
PY
  ln -sf "$EMBREE_SONAME" "$DEPS/lib/libembree4.so"
  echo "$EMBREE_SHA256" > "$DEPS/lib/.sha256"
  say "Embree 4 runtime in $DEPS/lib"
  rm -rf "$tmp"
}

# --- Open Image Denoise ----------------------------------------------------------------------
# The CPU runtime only: the library, its core, its CPU device module and TBB (the wheel's GPU
# modules are left out; the library loads the device modules it finds beside its core).
oidn() {
  if [ -f "$OIDN_DEPS/lib/.sha256" ] && [ "$(cat "$OIDN_DEPS/lib/.sha256")" = "$OIDN_SHA256" ] \
     && [ -e "$OIDN_DEPS/lib/libOpenImageDenoise.so.2" ]; then
    return 0  # already unpacked
  fi
  say "fetching the Open Image Denoise 2.5.1 runtime (PyPI wheel pyoidn==2.5.1.0)"
  local tmp
  tmp=$(fetch_wheel "$OIDN_WHEEL" "$OIDN_SHA256" --platform manylinux2014_x86_64 pyoidn==2.5.1.0)
  rm -rf "$OIDN_DEPS" && mkdir -p "$OIDN_DEPS/lib"
  python3 - "$tmp/$OIDN_WHEEL" "$OIDN_DEPS/lib" <<'PY'
import sys, zipfile, os
whl, dest = sys.argv[1], sys.argv[2]
keep = ["libOpenImageDenoise.so.2.5.1", "libOpenImageDenoise_core.so.2.5.1",
        "libOpenImageDenoise_device_cpu.so.2.5.1", "libtbb.so.12.19"]
with zipfile.ZipFile(whl) as z:
    for name in keep:
        p = os.path.join(dest, name)
        with open(p, "wb") as f:
            f.write(z.read("pyoidn/oidn/lib/" + name))
        os.chmod(p, 0o755)
PY
  ln -sf libOpenImageDenoise.so.2.5.1 "$OIDN_DEPS/lib/libOpenImageDenoise.so.2"
  ln -sf libtbb.so.12.19 "$OIDN_DEPS/lib/libtbb.so.12"
  echo "$OIDN_SHA256" > "$OIDN_DEPS/lib/.sha256"
  rm -rf "$tmp"
  say "Open Image Denoise runtime in $OIDN_DEPS/lib"
}

need_pip() {
  if ! python3 -m pip --version >/dev/null 2>&1; then
    say "installing pip"
    DEBIAN_FRONTEND=noninteractive ${SUDO:-} apt-get install -y -qq --no-install-recommends python3-pip >/dev/null
  fi
}

# fetch_wheel WHEEL SHA256 PIP-ARGS...: download the pinned wheel WHEEL (pip download PIP-ARGS)
# into a new temporary folder, check its sha256 and print the folder; on a mismatch remove it
# and stop.
fetch_wheel() {
  local wheel=$1 sha=$2 tmp
  shift 2
  need_pip >&2
  tmp=$(mktemp -d)
  python3 -m pip download --quiet --no-deps --only-binary=:all: -d "$tmp" "$@" >&2
  if ! echo "$sha  $tmp/$wheel" | sha256sum --check --status; then
    say "sha256 mismatch for $wheel"
    rm -rf "$tmp"
    exit 1
  fi
  echo "$tmp"
}

embree
oidn
