# Sourced by scripts/run and scripts/test: a local, pinned environment in .venv, made once and
# remade when requirements.lock changes. DDS traffic stays on this machine (shared memory only).
set -e
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${CLUSTERFEM_VENV:-$ROOT/.venv}"
PY="${PYTHON:-python3}"
stamp="$VENV/.lock-$(sha1sum "$ROOT/requirements.lock" "$ROOT/setup.py" | sha1sum | cut -c1-12)"
if [ ! -f "$stamp" ]; then
  echo "[env] creating $VENV with pinned dependencies (requirements.lock); this takes about a minute" >&2
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$ROOT/requirements.lock"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$ROOT"
  rm -f "$VENV"/.lock-*
  touch "$stamp"
fi
# shellcheck disable=SC1091
. "$VENV/bin/activate"
export FASTDDS_BUILTIN_TRANSPORTS=SHM
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( ( $$ % 100 ) + 100 ))}"
# numba's cache directory is keyed on the sources compiled code can read by clusterfem_ros.numba_cache
# (key_the_cache),
# in $VENV/numba_cache/<key>, unless NUMBA_CACHE_DIR is set.
export PYTHONUNBUFFERED=1
cd "$ROOT"
