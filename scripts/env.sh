# Sourced by scripts/run and scripts/test, or by you (`. scripts/env.sh`): a local, pinned environment in .venv,
# made once and remade when requirements.lock, setup.py or setup.cfg change. It leaves the caller's shell options
# as they were (no `set -e` left behind); a failing step returns 1. DDS discovery stays on this host
# (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set): ROS tools on this host see the topics with their defaults.
_cf_env() {
  local root venv py stamp
  root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)" || return 1
  venv="${CLUSTERFEM_VENV:-$root/.venv}"
  py="${PYTHON:-python3}"
  stamp="$venv/.lock-$(sha1sum "$root/requirements.lock" "$root/setup.py" "$root/setup.cfg" | sha1sum | cut -c1-12)" \
    || return 1
  if [ ! -f "$stamp" ]; then
    echo "[env] creating $venv with pinned dependencies (requirements.lock); this takes a few minutes" >&2
    "$py" -m venv "$venv" || return 1
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$root/requirements.lock" || return 1
    # PEP 660 (--use-pep517), not setup.py develop: the console scripts go to $venv/bin, and setup.cfg's
    # [develop] options (for colcon) are not read
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
      --use-pep517 -e "$root" || return 1
    rm -f "$venv"/.lock-*
    touch "$stamp" || return 1
  fi
  # shellcheck disable=SC1091
  . "$venv/bin/activate" || return 1
  export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
  export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( ( $$ % 100 ) + 100 ))}"
  # numba's cache directory is keyed on the sources compiled code can read by clusterfem_ros.numba_cache
  # (key_the_cache), in $VENV/numba_cache/<key>, unless NUMBA_CACHE_DIR is set.
  export PYTHONUNBUFFERED=1
  cd "$root" || return 1
}
_cf_env || { unset -f _cf_env; return 1; }
unset -f _cf_env
