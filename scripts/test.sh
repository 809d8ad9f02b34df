#!/usr/bin/env bash
# Sets everything up, then checks the code with ruff (pyproject.toml) and runs the test suite (extra
# arguments go to pytest). With --system first: the system checks instead (tests marked `system`: a
# Ray cluster's faults, fresh installs from the wheel, the images, the service fuzzed, the benchmarks
# end to end), which take longer; CI runs both. A system test named on the command line runs with
# --system only (the suite deselects them).
set -euo pipefail
cd "$(dirname "$0")/.."
selection="not system"
if [[ "${1:-}" == "--system" ]]; then
    selection="system"
    shift
fi
bash scripts/setup.sh
.venv/bin/ruff check renderer service simulation tests scripts client
# In parallel processes (pytest-xdist; GARMENT_RENDER_TEST_WORKERS, default 3): much of the suite waits
# on servers, subprocesses and one-thread stages, so three processes on two cores finish sooner.
exec .venv/bin/python -m pytest -q -n "${GARMENT_RENDER_TEST_WORKERS:-3}" --dist worksteal -m "$selection" "$@"
