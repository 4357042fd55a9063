#!/usr/bin/env bash
# Set up the project from nothing: system packages (when root), a virtual environment in
# .venv, torch (CPU build unless a GPU is present), then the project with all extras.
# Idempotent: a second run only checks and exits quickly.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.setup-stamp
APT_PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0 libopenni2-0 libopenni2-dev"
TORCH_SPEC="torch==2.13.0"

need_apt=()
for p in $APT_PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need_apt+=("$p")
done
if [ ${#need_apt[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing system packages: ${need_apt[*]}"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need_apt[@]}") \
      || echo "setup: WARNING apt-get failed; rendering/OpenNI2 features may be unavailable"
  else
    echo "setup: missing system packages; run as root:"
    echo "  apt-get install -y ${need_apt[*]}"
  fi
fi

# The stamp records the hash of the files that define the environment: unchanged -> done.
want=$(cat pyproject.toml setup.py scripts/setup.sh | sha256sum | cut -c1-16)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$want" ] && [ -x $VENV/bin/python ]; then
  echo "setup: environment up to date ($VENV)"
  exit 0
fi

[ -x $VENV/bin/python ] || "$PY" -m venv $VENV
PIP="$VENV/bin/python -m pip"
$PIP install -q --upgrade pip >/dev/null 2>&1 || true
# torch first, pinned, so nothing later pulls a CUDA build onto a CPU machine; on a machine with
# an NVIDIA GPU the same pin resolves to the registry's CUDA build.
if ! $VENV/bin/python -c "import torch" 2>/dev/null; then
  echo "setup: installing $TORCH_SPEC"
  $PIP install -q "$TORCH_SPEC"
fi
echo "setup: installing the project with all extras"
$PIP install -q -e ".[all,dev]"
# The body model's first build takes about a minute and writes ~0.8 GB: do it once here,
# into the git-ignored .cache/anny, so that tests and synthesis start fast.
$VENV/bin/python scripts/build_anny_cache.py || echo "setup: WARNING anny cache not built"
echo "$want" > "$STAMP"
echo "setup: done ($VENV)"
