#!/usr/bin/env bash
# Create the isolated virtual environment that holds the official nuscenes-devkit.
#
# Usage: scripts/devkit_venv.sh [VENV_DIR]      (default: <repo root>/.devkit-venv)
#
# The devkit pins numpy<2 while sianms runs on numpy 2, so the two can never share
# an environment: the devkit lives here, in its own venv, and is only ever driven
# as a subprocess (scripts/devkit_dump.py) whose JSON output our tests compare
# against. It is never a dependency of the sianms package.
#
# Idempotent: a finished environment carries a stamp file naming the exact
# requirements it was built from; a second run with the same requirements only
# re-checks the imports and exits.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV_DIR="${1:-${REPO_ROOT}/.devkit-venv}"
PYTHON="${PYTHON:-python3}"

# nuscenes-devkit 1.2.0 declares numpy>=1.22,<2 itself; the explicit numpy pin keeps
# the resolver from wandering to an old numpy without wheels for this Python, and the
# devkit's heavy optional stack (torch) is not needed by the loader or the detection
# evaluation, so nothing else is installed.
REQUIREMENTS=(
    "nuscenes-devkit==1.2.0"
    "numpy>=1.24,<2"
)
STAMP="${VENV_DIR}/.sianms-devkit-stamp"
WANTED_STAMP="$(printf '%s\n' "${REQUIREMENTS[@]}")"

check_imports() {
    "${VENV_DIR}/bin/python" - <<'EOF'
from nuscenes.nuscenes import NuScenes  # noqa: F401
from nuscenes.eval.detection.evaluate import DetectionEval  # noqa: F401
import numpy
import importlib.metadata as md
print(f"nuscenes-devkit {md.version('nuscenes-devkit')}, numpy {numpy.__version__}")
EOF
}

if [[ -f "${STAMP}" && "$(cat "${STAMP}")" == "${WANTED_STAMP}" ]] && check_imports; then
    echo "devkit venv up to date: ${VENV_DIR}"
    exit 0
fi

if [[ ! -x "${VENV_DIR}/bin/python" ]]; then
    echo "creating ${VENV_DIR}"
    "${PYTHON}" -m venv "${VENV_DIR}"
fi

# The stamp goes away first so that an interrupted install is redone next time.
rm -f "${STAMP}"
"${VENV_DIR}/bin/python" -m pip install --quiet --upgrade pip
"${VENV_DIR}/bin/python" -m pip install --quiet "${REQUIREMENTS[@]}"

check_imports
printf '%s\n' "${REQUIREMENTS[@]}" > "${STAMP}"
echo "devkit venv ready: ${VENV_DIR} ($(du -sh "${VENV_DIR}" | cut -f1))"
