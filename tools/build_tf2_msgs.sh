#!/bin/sh
# Build vendor/tf2_msgs (TFMessage only) into a pip-installed ROS 2 venv, so that rclpy can publish
# /tf and /tf_static: tf2_msgs has no PyPI wheel. A no-op where `import tf2_msgs` works (a ROS 2
# install has the real package, which is used). Needs cmake, a C/C++ compiler and Python headers;
# the ament/rosidl CMake tools (requirements/tf2_msgs_build.txt) go to a temporary prefix.
#
#   tools/build_tf2_msgs.sh VENV [PREFIX]    # PREFIX: where to install (default VENV)
set -eu
VENV=$(cd "$1" && pwd)
PREFIX=${2:-$VENV}
PY="$VENV/bin/python"
ROOT=$(cd "$(dirname "$0")/.." && pwd)
if PYTHONPATH="$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"].replace(sysconfig.get_paths()["data"], "'"$PREFIX"'", 1))')${PYTHONPATH:+:$PYTHONPATH}" \
    "$PY" -c 'import tf2_msgs.msg' 2>/dev/null; then
  echo "tf2_msgs: importable already, not built"
  exit 0
fi
for tool in cmake cc c++; do
  command -v "$tool" >/dev/null 2>&1 || { echo "tf2_msgs: $tool not found (apt-get install cmake g++)" >&2; exit 1; }
done
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT INT TERM
echo "tf2_msgs: building into $PREFIX"
"$PY" -m pip install -q --no-deps --prefix "$WORK/tools" -r "$ROOT/requirements/tf2_msgs_build.txt"
SITE=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"].replace(sysconfig.get_paths()["data"], "'"$WORK/tools"'", 1))')
export AMENT_PREFIX_PATH="$WORK/tools:$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
export PATH="$VENV/bin:$PATH"
cmake -S "$ROOT/vendor/tf2_msgs" -B "$WORK/build" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
  -DCMAKE_PREFIX_PATH="$WORK/tools;$VENV" -DCMAKE_INSTALL_PREFIX="$PREFIX" -DPython3_EXECUTABLE="$PY" \
  >"$WORK/cmake.log" 2>&1 || { cat "$WORK/cmake.log" >&2; exit 1; }
cmake --build "$WORK/build" -j 2 >"$WORK/build.log" 2>&1 || { cat "$WORK/build.log" >&2; exit 1; }
cmake --install "$WORK/build" >/dev/null
echo "tf2_msgs: installed into $PREFIX"
