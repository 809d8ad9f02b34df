#!/usr/bin/env bash
# Sets everything up, then renders the bundled default (procedural studio environment, procedural
# dress on a body proxy) to out/demo.png, out/demo.exr and out/demo_timings.json.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
mkdir -p out
.venv/bin/garment-render render --out out/demo.png --exr out/demo.exr --timings out/demo_timings.json \
    --size 512x512 --lights 48 --albedo 0.8,0.2,0.2 --specular 0.5 --glossiness 0.8 "$@"
echo "demo: wrote out/demo.png, out/demo.exr, out/demo_timings.json"
