#!/usr/bin/env bash
# One-shot, idempotent set-up for a fresh Linux machine (Debian 12 / Ubuntu 22.04+, with or
# without an NVIDIA GPU). Creates ./.venv with rsb_maniskill installed in editable mode and,
# where no GPU Vulkan driver exists, a software Vulkan driver new enough for SAPIEN.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${RSB_VENV:-.venv}
PY=${PYTHON:-python3}
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"

SECONDS=0
stage() {
  # One line per stage with the time since the start: a fresh machine's set-up takes minutes.
  echo "setup: [${SECONDS} s] $*"
}

have_nvidia() { command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; }

lavapipe_version() {
  # Prints the installed mesa-vulkan-drivers version (empty if none).
  dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | sed 's/^[0-9]*://' || true
}

install_software_vulkan() {
  # SAPIEN needs VK_KHR_external_semaphore_fd, which lavapipe has from Mesa 24.3 on.
  # Debian 12 ships Mesa 22.3, so take bookworm-backports (Mesa 25.x) there.
  command -v apt-get >/dev/null 2>&1 || { echo "setup: no apt-get; install Mesa lavapipe >= 24.3 (mesa-vulkan-drivers) by hand" >&2; return 0; }
  local v; v=$(lavapipe_version)
  if [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3; then return 0; fi
  . /etc/os-release
  if [ "${ID:-}" = debian ] && [ "${VERSION_CODENAME:-}" = bookworm ]; then
    if ! grep -rqs bookworm-backports /etc/apt/sources.list /etc/apt/sources.list.d/; then
      echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee /etc/apt/sources.list.d/bookworm-backports.list >/dev/null
    fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  fi
  v=$(lavapipe_version)
  if [ -z "$v" ] || ! dpkg --compare-versions "$v" ge 24.3; then
    echo "setup: warning: Mesa lavapipe is '${v:-missing}' (< 24.3); CPU rendering will be unavailable" >&2
  fi
}

install_chromium() {
  # The report page's test (tests/reporting/test_html_report.py) drives a headless Chromium. Debian ships
  # one; Ubuntu's `chromium` is a snap wrapper that containers cannot run.
  command -v chromium >/dev/null 2>&1 && return 0
  command -v apt-get >/dev/null 2>&1 || { echo "setup: no apt-get; install Chromium (or set RSB_CHROMIUM) for the report's browser test" >&2; return 0; }
  . /etc/os-release
  if [ "${ID:-}" != debian ]; then
    echo "setup: note: install Chromium or Chrome (or set RSB_CHROMIUM) for the report's browser test" >&2
    return 0
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null \
    || echo "setup: warning: apt-get install chromium failed; the report's browser test will fail" >&2
}

uv_flags_from_pip() {
  # uv reads no pip.conf: pass on pip's own index settings (its config files and PIP_* variables,
  # as `pip config list` shows them, in $PIP_CONFIG), so a lab's private index or wheel mirror
  # serves uv as it serves pip. unsafe-best-match: like pip, the newest release any index has
  # (uv's default takes a package from the first index that lists it).
  echo "--index-strategy=unsafe-best-match"
  local line key value v
  printf '%s\n' "$PIP_CONFIG" | while IFS= read -r line; do
    key=${line%%=*}; key=${key#*.}; value=${line#*=}; value=${value#\'}; value=${value%\'}
    case $key in
      index-url) echo "--index-url=$value" ;;
      extra-index-url) for v in $value; do echo "--extra-index-url=$v"; done ;;
      find-links) for v in $value; do echo "--find-links=$v"; done ;;
      constraint) for v in $value; do echo "--constraint=$v"; done ;;
      trusted-host) for v in $value; do echo "--allow-insecure-host=$v"; done ;;
      no-index) case $value in 0|false|no|off) ;; *) echo "--no-index" ;; esac ;;
    esac
  done | awk '!seen[$0]++'  # a setting in a file and in PIP_* shows twice
}

stage "1/5 Vulkan driver"
if have_nvidia; then
  echo "setup: NVIDIA GPU found; using its Vulkan driver"
  command -v apt-get >/dev/null 2>&1 && ! ldconfig -p | grep -q libvulkan.so.1 && { $SUDO apt-get update -qq; $SUDO apt-get install -y -qq libvulkan1 >/dev/null; } || true
else
  install_software_vulkan
fi

stage "2/5 Chromium (for the report page's browser test)"
install_chromium

stage "3/5 virtual environment $VENV, pip and uv"
if [ ! -x "$VENV/bin/python" ]; then
  $PY -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip"
$PIP install -q --upgrade pip >/dev/null
$PIP install -q uv 2>/dev/null || true  # optional: install() falls back to pip
PIP_CONFIG=$($PIP config list 2>/dev/null || true)
mapfile -t UV_FLAGS < <(uv_flags_from_pip)
CERT=$(printf '%s\n' "$PIP_CONFIG" | sed -n "s/^[^=]*\.cert='\(.*\)'$/\1/p" | head -n 1)
[ -n "$CERT" ] && [ -z "${SSL_CERT_FILE:-}" ] && export SSL_CERT_FILE=$CERT  # pip's CA bundle, for uv

install() {
  # uv installs in parallel: the project's pins take about 30 s where pip takes 70 s on a fresh
  # machine. Pip does it where uv cannot (no uv for this platform, an index setting uv lacks).
  # --compile-bytecode, as pip does: where PYTHONDONTWRITEBYTECODE is set (CI's often is), every
  # process would otherwise compile torch's and SAPIEN's Python anew (3 s more per import).
  if [ -x "$VENV/bin/uv" ] && "$VENV/bin/uv" pip install -q --compile-bytecode --python "$VENV/bin/python" \
       "${UV_FLAGS[@]}" "$@"; then
    return 0
  fi
  echo "setup: uv could not install $*; pip does (slower)" >&2
  $PIP install -q "$@"
}

stage "4/5 PyTorch (the CPU build where there is no GPU; about 200 MB)"
if ! $VENV/bin/python -c "import torch" 2>/dev/null; then
  if have_nvidia; then
    install torch
  else
    # The CPU wheel: a plain `pip install mani-skill` would pull a multi-GB CUDA torch.
    # A local wheel mirror (find-links) may already hold it; else PyTorch's CPU index.
    install "torch==2.13.0+cpu" 2>/dev/null \
      || install torch --index-url https://download.pytorch.org/whl/cpu
  fi
fi
stage "5/5 rsb_maniskill and its pins (ManiSkill, SAPIEN, mplib, LeRobot, Ray, ...)"
install -e ".[dev,expert,eval,hub,export,ray,baselines,vla_eval]"
if have_nvidia; then
  # GPU physics needs SAPIEN's PhysX GPU library, fetched from GitHub: stage it now, while there
  # is network (compute nodes often have none). Prints where it went.
  $VENV/bin/python -m rsb_maniskill.sim.physx_gpu || echo "setup: warning: PhysX GPU library not staged; GPU physics (physx_cuda) will need it (see docs/gpu.md)" >&2
fi
echo "setup: done in ${SECONDS} s ($($VENV/bin/python -c 'import mani_skill, sapien, torch; print("mani_skill", mani_skill.__version__, "sapien", sapien.__version__, "torch", torch.__version__)'))"
