#!/usr/bin/env bash
# Sets everything up, then checks the code with ruff (pyproject.toml) and runs the test suite (extra
# arguments go to pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check renderer service simulation tests scripts
exec .venv/bin/python -m pytest -q "$@"
