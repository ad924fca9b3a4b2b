#!/usr/bin/env bash
# Creates or refreshes .venv with the CPU builds of torch and Open3D plus the package and its dev extras.
# Idempotent: re-running only installs what is missing.
set -euo pipefail
PY=${PY:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
cd "$(dirname "$0")/.."

# open3d needs libusb-1.0 at import time.
if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing libusb-1.0-0 (needed by open3d)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "setup: open3d needs libusb-1.0-0; run: sudo apt-get install -y libusb-1.0-0" >&2
        exit 1
    fi
fi

# Chromium lets the tests open report.html in a real headless browser; optional (the test skips without it).
if ! command -v chromium >/dev/null && [ -z "${RECON_SKIP_BROWSER:-}" ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing chromium for the report test (RECON_SKIP_BROWSER=1 skips this)"
    { DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1 \
      || { apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1; }; } \
        || echo "setup: chromium could not be installed; the browser test will be skipped"
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
PIP=".venv/bin/python -m pip"
$PIP install -q --upgrade pip >/dev/null
# Pin torch first: an unpinned torch would pull the CUDA build (several GB).
# On a CUDA machine use instead: pip install torch==$TORCH_VERSION --index-url https://download.pytorch.org/whl/cu128
.venv/bin/python -c "import torch" 2>/dev/null || $PIP install -q "torch==$TORCH_VERSION"
# CPU Open3D; on a CUDA machine use `pip install open3d` instead.
.venv/bin/python -c "import open3d" 2>/dev/null || $PIP install -q open3d-cpu
$PIP install -q -e ".[dev]"
.venv/bin/python -c "import torch, open3d, pycolmap, trimesh, cv2; print('setup: ok torch', torch.__version__, 'open3d', open3d.__version__, 'pycolmap', pycolmap.__version__)"
