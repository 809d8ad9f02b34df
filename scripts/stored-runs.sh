#!/usr/bin/env bash
# Makes the stored benchmark runs that record the presets' digest again, one after another, and the
# files made from them (the broad runs' reports, the README's quality table, the trade curves). A
# preset change makes every one of them stale (tests/test_stored_runs.py fails until they are made
# again). Names the runs to make (default all, in this order):
#   broad-256   garment-render bench --broad --size 256   (~20 min warm, an hour from a cold cache; then
#               docs/presets.md from it: python -m garment_lab.preset_report)
#   broad-512   garment-render bench --broad --size 512   (~30 min warm, an hour cold)
#   error-split garment-render error-split                (~35 min)
#   energy      garment-render bench --energy             (~2 min)
#   materials   garment-render bench --materials          (~10 min)
#   one-shot    garment-render speed --one-shot           (~5 min)
#   sweep       garment-render bench                      (docs/sweep.json, sweep.md, pareto.png; ~30 min)
#   views       garment-render bench --views              (docs/views-bench.json and .md; ~2 min)
#   area        garment-render bench --area               (docs/area-bench.json and .md; ~8 min)
#   shadow-maps garment-render bench --shadow-maps        (docs/shadow-maps-bench.json and .md; ~7 min)
#   edges       garment-render bench --edges              (docs/edges-bench.json and .md; ~10 min warm, the broad
#               run's reference cache shared)
#   scale-out   python -m service.load --ray 1,2 --frames 32 --scenes 8   (docs/scale-out.json and .md; ~3 min)
#   service-bounds  python scripts/bench_service_bounds.py   (docs/service-bounds.json and .md; ~25 min)
#   fabrics     garment-render bench --fabrics               (docs/fabrics-bench.json and .md; ~10 min)
#   rotation    python scripts/bench_env_rotation.py         (docs/env-rotation.json and .md; ~1 min)
# and, named only (never by default), the broad runs retimed: their stored errors kept, every frame and
# the tracer's rate timed again (`bench --broad --retime`), for a change that leaves every image as it
# was (a faster shader that draws the same pixels, the machine's timings on another day):
#   broad-256-retime, broad-512-retime   (~13 min each)
# Times are for this project's 2-core machine. The frame times in them are judged against budgets:
# run this on a quiet machine, nothing else at work, and give each run the whole machine.
set -euo pipefail
cd "$(dirname "$0")/.."
all=(broad-256 broad-512 error-split energy materials one-shot sweep views area shadow-maps edges scale-out
     service-bounds fabrics rotation)
named=("${all[@]}" broad-256-retime broad-512-retime)
runs=("$@")
if [[ ${#runs[@]} -eq 0 ]]; then
    runs=("${all[@]}")
fi
for run in "${runs[@]}"; do
    if [[ " ${named[*]} " != *" $run "* ]]; then
        echo "unknown run '$run': the runs are ${named[*]}" >&2
        exit 2
    fi
done
bash scripts/setup.sh >/dev/null
gr=(.venv/bin/python -m renderer.cli)
py=.venv/bin/python
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

broad() {   # size, the stored run, its trade curve (curve.curve_stem names it), run or retime
    local size=$1 stored=$2 curve=$3 how=$4
    if [[ $how == retime ]]; then
        "${gr[@]}" bench --broad --retime "$stored" --out "$tmp/broad-$size"
    else
        "${gr[@]}" bench --broad --size "$size" --out "$tmp/broad-$size"
    fi
    cp "$tmp/broad-$size/broad.json" "$stored"
    "$py" - "$stored" <<'EOF'
import sys
from pathlib import Path

from garment_lab import broad

data = broad.rewrite(Path(sys.argv[1]))   # its report, with today's targets
if Path(sys.argv[1]).as_posix().endswith(broad.README_RUN):
    readme = Path("README.md")
    readme.write_text(broad.with_readme_table(readme.read_text(), data))
EOF
    "${gr[@]}" bench --broad --curve "$stored" --size "$size" --out docs/broad
    echo "made $stored, its report and $curve"
}

side() {    # a side bench's flag, the name of the files it writes, the stored run (its report beside it, .md)
    local flag=$1 stem=$2 stored=$3
    "${gr[@]}" bench "--$flag" --out "$tmp/$flag"
    cp "$tmp/$flag/$stem.json" "$stored"
    cp "$tmp/$flag/$stem.md" "${stored%.json}.md"
}

for run in "${runs[@]}"; do
    case "$run" in
        broad-256)   # and the presets' report, made from it (docs/presets.md)
            broad 256 docs/broad/broad-256.json docs/broad/trade_curve.json run
            "$py" -m garment_lab.preset_report ;;
        broad-512) broad 512 docs/broad/broad-512.json docs/broad/trade_curve-512.json run ;;
        broad-256-retime)
            broad 256 docs/broad/broad-256.json docs/broad/trade_curve.json retime
            "$py" -m garment_lab.preset_report ;;
        broad-512-retime) broad 512 docs/broad/broad-512.json docs/broad/trade_curve-512.json retime ;;
        error-split) "${gr[@]}" error-split --out docs/error-split ;;
        energy) "${gr[@]}" bench --energy --out docs/energy ;;
        materials) side materials materials docs/materials-bench.json ;;
        one-shot) "${gr[@]}" speed --one-shot --out docs/one-shot ;;
        sweep)
            "${gr[@]}" bench --out "$tmp/sweep"
            cp "$tmp/sweep/bench.json" docs/sweep.json
            cp "$tmp/sweep/bench.md" docs/sweep.md
            cp "$tmp/sweep/pareto.png" docs/pareto.png ;;
        views) side views views docs/views-bench.json ;;
        edges) side edges edges docs/edges-bench.json ;;
        fabrics) side fabrics fabrics docs/fabrics-bench.json ;;
        area) side area area docs/area-bench.json ;;
        shadow-maps) side shadow-maps shadow_maps docs/shadow-maps-bench.json ;;
        scale-out) "$py" -m service.load --ray 1,2 --frames 32 --scenes 8 --out docs/scale-out.md ;;
        service-bounds) "$py" scripts/bench_service_bounds.py --out docs ;;   # docs/service-bounds.json
        rotation) "$py" scripts/bench_env_rotation.py --out docs ;;   # docs/env-rotation.json
    esac
done
