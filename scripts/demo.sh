#!/usr/bin/env bash
# Sets everything up, starts the render service and a cloth simulation that posts every frame to it
# (a dress sewn from two panels, draped on a mannequin, lit by the bundled procedural studio), and prints the address of
# the viewer page that shows the latest frame of each scene with its timings. Ctrl-C stops both.
#
#   bash scripts/demo.sh [--host 127.0.0.1] [--port 8000] [--frames N] [--size 512x512] [--preset fast]
#                        [--views front,three-quarter] [--spacing 0.025] [--env MAP.hdr]
#   bash scripts/demo.sh --still    # the one-frame render of the bundled default to out/demo.png (anti-aliased)
#
# Options other than --host, --port and --still go to `python -m simulation.demo` (see its --help);
# --frames 0 (the default) simulates until Ctrl-C, draping the dress anew every 90 frames.
set -euo pipefail
cd "$(dirname "$0")/.."

host=127.0.0.1
port=8000
still=0
sim_args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --host) host="$2"; shift 2 ;;
        --port) port="$2"; shift 2 ;;
        --still) still=1; shift ;;
        -h|--help) sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) sim_args+=("$1"); shift ;;
    esac
done

bash scripts/setup.sh
mkdir -p out

if [ "$still" = 1 ]; then
    .venv/bin/garment-render render --out out/demo.png --exr out/demo.exr --timings out/demo_timings.json \
        --size 512x512 --albedo 0.8,0.2,0.2 --specular 0.5 --glossiness 0.8 --aa-samples 4 "${sim_args[@]}"
    echo "demo: wrote out/demo.png, out/demo.exr, out/demo_timings.json"
    exit 0
fi

# Background children of a script ignore SIGINT, so Ctrl-C reaches this shell only: it stops them.
pids=()
cleanup() {
    trap - EXIT INT TERM
    for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
    for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
    echo "demo: stopped"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

url="http://$host:$port"
.venv/bin/python -m service.main --host "$host" --port "$port" --log-level warning > out/demo_service.log 2>&1 &
pids+=("$!")
if ! .venv/bin/python -c "
import sys, time, httpx
deadline = time.monotonic() + 120
while time.monotonic() < deadline:
    try:
        if httpx.get('$url/health/ready', timeout=2).status_code == 200:
            sys.exit(0)
    except httpx.TransportError:
        pass
    time.sleep(0.2)
sys.exit(1)"; then
    echo "demo: the service did not start on $url; its log (out/demo_service.log):" >&2
    tail -n 30 out/demo_service.log >&2
    exit 1
fi

.venv/bin/python -m simulation.demo --server "$url" "${sim_args[@]}" &
pids+=("$!")
echo "demo: the viewer is at $url/view (service log: out/demo_service.log; Ctrl-C stops the demo)"

if wait "${pids[1]}"; then
    echo "demo: the simulation is done; the viewer keeps showing its last frames at $url/view (Ctrl-C stops)"
else
    echo "demo: the simulation stopped with an error (above)" >&2
    exit 1
fi
wait "${pids[0]}"
