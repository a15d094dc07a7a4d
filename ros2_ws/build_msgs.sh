#!/usr/bin/env bash
# Build the nifo_msgs interface package with the PyPI ROS 2 build tool chain and install it INTO the
# virtual environment (libraries to $VENV/lib, Python package to site-packages, share/ + ament index),
# where the pip-installed rclpy finds it exactly like the std_msgs wheel: no environment to source.
#   ros2_ws/build_msgs.sh /path/to/venv          (tools/bootstrap.sh runs it; idempotent, ~1 min)
# On a vehicle with a system ROS 2 none of this is needed: colcon build && source install/setup.bash.
set -euo pipefail
venv="$(cd "${1:?usage: build_msgs.sh VENV}" && pwd)"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
py="$venv/bin/python"
# 1. the whole CMake tool chain (the ament_cmake wheel alone does not pull all of it)
"$py" -m pip install -q -r "$here/build_msgs.requirements.txt"
# 2. the message wheels' exported CMake targets name their build machine's Python and numpy include
#    directories: point them at this venv's (only files inside the venv are touched)
pyinc="$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
npinc="$("$py" -c 'import numpy; print(numpy.get_include())')"
grep -rlZ --include='*.cmake' '/opt/python/cp3' "$venv/share" 2>/dev/null | xargs -0 -r sed -i \
  -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/lib/python3\.[0-9]*/site-packages/numpy/_core/include#$npinc#g" \
  -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/include/python3\.[0-9]*#$pyinc#g"
# 3. colcon build in a scratch directory, then merge the install tree into the venv
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
(
  export PATH="$venv/bin:$PATH" VIRTUAL_ENV="$venv" CMAKE_PREFIX_PATH="$venv" AMENT_PREFIX_PATH="$venv"
  cd "$work"
  "$venv/bin/colcon" --log-base "$work/log" build --base-paths "$here/src/nifo_msgs" \
    --build-base "$work/build" --install-base "$work/install" --merge-install \
    --cmake-args -DPython3_EXECUTABLE="$py" -DBUILD_TESTING=OFF >"$work/build.log" 2>&1 \
    || { tail -40 "$work/build.log" >&2; exit 1; }
)
inst="$work/install"
site="$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
cp -a "$inst/lib/"*.so "$venv/lib/"
cp -a "$inst/lib/python3."*/site-packages/nifo_msgs "$site/"
mkdir -p "$venv/share"
cp -a "$inst/share/nifo_msgs" "$venv/share/"
cp -a "$inst/share/ament_index/resource_index/." "$venv/share/ament_index/resource_index/"
"$py" -c 'from nifo_msgs.msg import Transmissibility, Coefficients, LoopStatus' \
  || { echo "nifo_msgs built but does not import" >&2; exit 1; }
