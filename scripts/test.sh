#!/usr/bin/env bash
# Sets everything up, then checks the code with ruff (pyproject.toml) and runs the test suite (extra
# arguments go to pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check renderer service simulation tests scripts
# In parallel processes (pytest-xdist; GARMENT_RENDER_TEST_WORKERS, default 3): much of the suite waits
# on servers, subprocesses and one-thread stages, so three processes on two cores finish sooner.
exec .venv/bin/python -m pytest -q -n "${GARMENT_RENDER_TEST_WORKERS:-3}" --dist worksteal "$@"
