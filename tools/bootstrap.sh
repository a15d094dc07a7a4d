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
}
