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
# numba re-checks a cached function only against its own file, not the kernels it inlines from other
# files: after an edit to fem/cluster_force_kernel.py the cached integrator would keep the old code. The
# cache directory is keyed on the whole package's source, so an edit or a pull starts a fresh cache.
src_key="$(cat "$ROOT"/clusterfem_ros/*.py "$ROOT"/clusterfem_ros/*/*.py "$ROOT"/clusterfem_ros/*/*/*.py 2>/dev/null \
  | sha1sum | cut -c1-12)"
if [ -z "${NUMBA_CACHE_DIR:-}" ]; then
  export NUMBA_CACHE_DIR="$VENV/numba_cache/$src_key"
  mkdir -p "$NUMBA_CACHE_DIR"
  find "$VENV/numba_cache" -mindepth 1 -maxdepth 1 ! -name "$src_key" -exec rm -rf {} + 2>/dev/null || true
fi
export PYTHONUNBUFFERED=1
cd "$ROOT"
