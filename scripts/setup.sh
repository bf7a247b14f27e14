#!/usr/bin/env bash
# Idempotent set-up of dlo-vitac on a fresh machine: a Python 3.11 venv with ROS 2 Jazzy
# (PyPI ros-jazzy-* wheels), Taichi, PyTorch (CPU) and the rest; the wheels' CMake paths
# fixed for this interpreter; the ros_ws workspace built with colcon; scripts/env.sh written.
# Safe to re-run: every step checks whether it is needed and says what it does.
#
# Environment: DLO_VENV (venv path, default <repo>/.venv), DLO_PYTHON (interpreter, default python3.11).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${DLO_VENV:-$ROOT/.venv}"
PYTHON="${DLO_PYTHON:-python3.11}"
WS="$ROOT/ros_ws"
STAMPS="$VENV/.dlo-stamps"
REQ="$ROOT/scripts/requirements.txt"

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$1" >&2; [ $# -gt 1 ] && printf '[setup] fix: %s\n' "$2" >&2; exit 1; }

# ---- 1. prerequisites -------------------------------------------------------------------
command -v "$PYTHON" >/dev/null 2>&1 || die "no '$PYTHON' on PATH (the ROS 2 Jazzy wheels are built for CPython 3.11)" \
  "install Python 3.11 (e.g. 'apt install python3.11 python3.11-venv python3.11-dev' or pyenv), or set DLO_PYTHON=/path/to/python3.11"
pyver=$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
[ "$pyver" = "3.11" ] || die "'$PYTHON' is Python $pyver; the ROS 2 Jazzy wheels need 3.11" "set DLO_PYTHON to a Python 3.11 interpreter"
"$PYTHON" -c 'import venv, ensurepip' 2>/dev/null || die "Python 3.11 has no venv/ensurepip module" "install python3.11-venv"
"$PYTHON" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
  || die "Python 3.11 development headers (Python.h) are missing; building dlo_msgs needs them" "install python3.11-dev"
for tool in cc c++ make; do
  command -v "$tool" >/dev/null 2>&1 || die "no '$tool' on PATH; building the dlo_msgs interfaces needs a C/C++ toolchain" \
    "install one, e.g. 'apt install build-essential'"
done

# ---- 2. virtual environment and packages -------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  say "creating venv $VENV"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --upgrade pip
fi
mkdir -p "$STAMPS"
PIP=("$VENV/bin/python" -m pip install --quiet --disable-pip-version-check)
req_hash=$(sha256sum "$REQ" | cut -c1-16)
if [ "$(cat "$STAMPS/requirements" 2>/dev/null)" != "$req_hash" ]; then
  say "installing packages from scripts/requirements.txt (registries, by name)"
  "${PIP[@]}" -r "$REQ" 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
  if ! command -v cmake >/dev/null 2>&1 && [ ! -x "$VENV/bin/cmake" ]; then
    say "no cmake on PATH: installing the 'cmake' package into the venv"
    "${PIP[@]}" cmake
  fi
  echo "$req_hash" > "$STAMPS/requirements"
  rm -f "$STAMPS/cmake-paths"
else
  say "packages up to date"
fi

# ---- 3. fix the wheels' hard-coded /opt/python/cp311-cp311 paths -------------------------
if [ ! -f "$STAMPS/cmake-paths" ]; then
  pyinc=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  npinc=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
  files=$(grep -rl "/opt/python/cp311-cp311" "$VENV/share" 2>/dev/null || true)
  if [ -n "$files" ]; then
    say "rewriting /opt/python/cp311-cp311 include paths in $(echo "$files" | wc -l) files under $VENV/share"
    echo "$files" | xargs sed -i \
      -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$npinc#g" \
      -e "s#/opt/python/cp311-cp311/include/python3.11#$pyinc#g" \
      -e "s#/opt/python/cp311-cp311#$VENV#g"
  fi
  touch "$STAMPS/cmake-paths"
fi

# ---- 4. build the workspace ---------------------------------------------------------------
# Rebuild when a package's build inputs change (interfaces, manifests, setup files, shipped
# policies, parameters files). Python sources need no rebuild: env.sh puts them on PYTHONPATH ahead of the install tree.
# The hash of what was built lives in the workspace's own install tree (not in the venv: two clones sharing one
# DLO_VENV each build their own workspace).
src_hash=$(cd "$WS/src" && find . -type f \( -name '*.msg' -o -name '*.srv' -o -name 'CMakeLists.txt' \
  -o -name 'package.xml' -o -name 'setup.py' -o -name 'setup.cfg' -o -path '*/policies/*' -o -path '*/config/*' \) | sort | xargs sha256sum | sha256sum | cut -c1-16)
if [ "$(cat "$WS/install/.dlo-build-hash" 2>/dev/null)" != "$src_hash" ] || [ ! -d "$WS/install/dlo_msgs/lib" ]; then
  say "building ros_ws with colcon (log: ros_ws/log/latest_build)"
  (
    cd "$WS"
    export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1 LD_LIBRARY_PATH="$VENV/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    # A package no longer in src (renamed, split, removed) would stay in install/ (and in colcon's
    # install/setup.bash): remove its build and install trees.
    for old in build/dlo_* install/dlo_*; do
      if [ -d "$old" ] && [ ! -d "src/${old#*/}" ]; then
        say "removing $old (no package ${old#*/} in ros_ws/src any more)"
        rm -rf "$old"
      fi
    done
    colcon build --executor sequential \
      --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF >"$STAMPS/colcon.out" 2>&1 \
      || { tail -40 "$STAMPS/colcon.out" >&2; die "colcon build failed (output above; full log in ros_ws/log/latest_build)" \
           "fix the package named above, then re-run scripts/setup.sh"; }
    grep -E "^Finished|^Failed" "$STAMPS/colcon.out" | sed 's/^/[setup]   /' || true
  )
  echo "$src_hash" > "$WS/install/.dlo-build-hash"
else
  say "workspace up to date"
fi

# ---- 5. env.sh -----------------------------------------------------------------------------
# Source dirs of the Python packages come first on PYTHONPATH so edits need no rebuild; the
# install tree supplies dlo_msgs and the executables under install/<pkg>/lib/<pkg>.
sed -e "s#@VENV@#$VENV#g" "$ROOT/scripts/env.sh.in" > "$ROOT/scripts/env.sh.tmp"
if ! cmp -s "$ROOT/scripts/env.sh.tmp" "$ROOT/scripts/env.sh" 2>/dev/null; then
  mv "$ROOT/scripts/env.sh.tmp" "$ROOT/scripts/env.sh"
  say "wrote scripts/env.sh (source it: 'source scripts/env.sh')"
else
  rm -f "$ROOT/scripts/env.sh.tmp"
  say "scripts/env.sh up to date"
fi
say "done"
