# Sourced by nifo.sh and test.sh: create .venv on first use and (re)install when
# pyproject.toml changed. Needs only python3 (>= 3.10) on PATH.
nifo_bootstrap() {
  local here="$1" extras="$2"
  local venv="$here/.venv" py="${PYTHON:-python3}"
  local stamp="$venv/.nifo-installed${extras:+-$extras}"
  if [ ! -x "$venv/bin/python" ]; then
    echo "nifo: creating virtual environment in $venv (first use only)" >&2
    "$py" -m venv "$venv"
    "$venv/bin/python" -m pip install -q --upgrade pip >&2
  fi
  if [ ! -f "$stamp" ] || [ "$here/pyproject.toml" -nt "$stamp" ]; then
    local spec="$here[ros${extras:+,$extras}]"
    echo "nifo: installing $spec into .venv (a few minutes the first time)" >&2
    "$venv/bin/python" -m pip install -q -e "$spec" >&2
    touch "$stamp"
  fi
  # ROS result messages (nifo_msgs, ros2_ws/src): built with the PyPI ROS tool chain and installed into
  # .venv like the std_msgs wheel (ros2_ws/build_msgs.sh; needs a C/C++ compiler). Rebuilt when changed.
  local mstamp="$venv/.nifo-msgs"
  if [ ! -f "$mstamp" ] || [ -n "$(find "$here/ros2_ws/src/nifo_msgs" "$here/ros2_ws/build_msgs.sh" \
        "$here/ros2_ws/build_msgs.requirements.txt" -newer "$mstamp" 2>/dev/null | head -1)" ]; then
    echo "nifo: building the ROS result messages (nifo_msgs) into .venv (first use only, about a minute)" >&2
    if ! command -v c++ >/dev/null 2>&1; then   # the message build compiles C/C++ type support
      if [ "$(id -u)" -eq 0 ]; then
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2 \
          && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends g++ make >/dev/null || true
      else
        echo "nifo: no C++ compiler for the ROS messages; run: sudo apt-get install -y g++ make" >&2
      fi
    fi
    if bash "$here/ros2_ws/build_msgs.sh" "$venv" >&2; then
      touch "$mstamp"
    else
      echo "nifo: WARNING: nifo_msgs could not be built (above); the ROS nodes need it, the rest of nifo does not" >&2
    fi
  fi
  nifo_compile_bytecode "$here" "$venv/bin/python"
}

# nifo's own modules compiled to bytecode, as pip compiles the packages it installs: where PYTHONDONTWRITEBYTECODE is
# set (this machine's environment) Python would otherwise compile them again in every process (about 190 modules;
# measured on 2026-12-07, a process importing the pipeline: 1.72 -> 1.40 s wall, 1.40 -> 1.22 CPU-s; issue 58). Up to
# date, this only compares their times (0.1 s). Never fatal: without it nifo runs the same, only slower to start.
nifo_compile_bytecode() {
  local here="$1" py="$2"
  "$py" -m compileall -q "$here/nifo" "$here/nifo_core" "$here/nifo_nodes" "$here/launch_scripts" \
    "$here/ros2_ws/src" >/dev/null 2>&1 || true
}

# Headless Chromium renders the HTML report in tests/test_report_browser.py (Debian's package).
# Installed when missing and root (apt-get, quiet); otherwise fail with the one command to run.
nifo_need_chromium() {
  if command -v chromium >/dev/null 2>&1; then
    return 0
  fi
  if [ "$(id -u)" -ne 0 ]; then
    echo "nifo: headless Chromium is missing (the report's browser test needs it). Run:" >&2
    echo "  sudo apt-get update && sudo apt-get install -y chromium" >&2
    return 1
  fi
  echo "nifo: installing Debian's chromium (headless browser for the report test; first run only)" >&2
  DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2 \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null \
    || { echo "nifo: apt-get could not install chromium; run: apt-get update && apt-get install -y chromium" >&2; return 1; }
  command -v chromium >/dev/null 2>&1 || { echo "nifo: chromium still not on PATH after apt-get" >&2; return 1; }
}
