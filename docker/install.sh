#!/usr/bin/env bash
# The install steps of both images (docker/Dockerfile.cpu, docker/Dockerfile.nvidia), kept in one script so
# that they can be run, dry-run or checked on a plain Debian machine without Docker (tests/test_docker.py).
#
#   docker/install.sh [--flavor cpu|nvidia] [--python PY] [--src DIR] [--user NAME] [--check | --dry-run] [STEP...]
#
# Steps (default: all three, in this order):
#   system   Debian packages of the flavor's OpenGL/EGL stack; for nvidia the glvnd EGL vendor file; the
#            non-root user; the directories named by GARMENT_RENDER_PEM_CACHE_DIR and GARMENT_RENDER_STATE_DIR
#            (and /out) owned by that user. Needs root.
#   deps     the Python dependencies listed in pyproject.toml (a layer of their own: they change less often
#            than the source)
#   project  the project itself, editable from --src (the renderer reads its GLSL from <src>/shaders), then a
#            check that it imports and finds its shaders
#
# --check changes nothing: it verifies that the steps' results are present (packages, vendor file,
# dependencies at the required versions, the project and its console script) and exits 1 naming what is
# missing. --dry-run prints the commands a real run would execute.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
SRC="$(cd "$HERE/.." && pwd)"
FLAVOR=cpu
PYTHON="${PYTHON:-python3}"
RUN_USER=render
RUN_UID=10001
MODE=install
STEPS=()

# OpenGL through glvnd: libEGL.so.1 and libGL.so.1 dispatch to a vendor library chosen by the files in
# /usr/share/glvnd/egl_vendor.d (moderngl's EGL backend loads both).
GLVND_PACKAGES=(libegl1 libgl1 libglvnd0)
CPU_PACKAGES=(libegl-mesa0 libgl1-mesa-dri)  # Mesa's EGL vendor (50_mesa.json) and llvmpipe
# The NVIDIA image adds no vendor library: the container toolkit injects the driver's libEGL_nvidia.so.0
# (NVIDIA_DRIVER_CAPABILITIES must include "graphics"); the image only ships the vendor file naming it.
# Debian's libegl1 and libgl1 depend on Mesa all the same, so without a GPU that image would fall back to
# llvmpipe: it sets GARMENT_RENDER_REQUIRE_GPU=1 and the entrypoint refuses a software renderer.
NVIDIA_VENDOR_SRC="$HERE/nvidia/10_nvidia.json"
NVIDIA_VENDOR_DST=/usr/share/glvnd/egl_vendor.d/10_nvidia.json

usage() { sed -n '2,19p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
say() { echo "install: $*"; }
die() { echo "install: error: $*" >&2; exit 1; }

while [ $# -gt 0 ]; do
    case "$1" in
        --flavor) FLAVOR="$2"; shift 2 ;;
        --python) PYTHON="$2"; shift 2 ;;
        --src) SRC="$(cd "$2" && pwd)"; shift 2 ;;
        --user) RUN_USER="$2"; shift 2 ;;
        --check) MODE=check; shift ;;
        --dry-run) MODE=dry-run; shift ;;
        -h|--help) usage; exit 0 ;;
        system|deps|project) STEPS+=("$1"); shift ;;
        *) usage >&2; die "unknown argument: $1" ;;
    esac
done
[ ${#STEPS[@]} -gt 0 ] || STEPS=(system deps project)
case "$FLAVOR" in
    cpu) PACKAGES=("${GLVND_PACKAGES[@]}" "${CPU_PACKAGES[@]}") ;;
    nvidia) PACKAGES=("${GLVND_PACKAGES[@]}") ;;
    *) die "--flavor must be cpu or nvidia, got '$FLAVOR'" ;;
esac

# Run a command, or print it under --dry-run.
run() {
    if [ "$MODE" = dry-run ]; then
        printf '+'; printf ' %q' "$@"; printf '\n'
    else
        "$@"
    fi
}

# The runtime dependencies of pyproject.toml, one per line (tomllib: Python >= 3.11).
requirements() {
    "$PYTHON" - "$SRC/pyproject.toml" <<'EOF'
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    print("\n".join(tomllib.load(f)["project"]["dependencies"]))
EOF
}

step_system() {
    if [ "$MODE" = check ]; then
        local missing=()
        for pkg in "${PACKAGES[@]}"; do
            dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
        done
        [ ${#missing[@]} -eq 0 ] || die "missing Debian packages: ${missing[*]} (run docker/install.sh system as root)"
        say "Debian packages present: ${PACKAGES[*]}"
        if [ "$FLAVOR" = nvidia ]; then
            [ -f "$NVIDIA_VENDOR_DST" ] || die "no NVIDIA EGL vendor file at $NVIDIA_VENDOR_DST"
            grep -q 'libEGL_nvidia.so.0' "$NVIDIA_VENDOR_DST" || die "$NVIDIA_VENDOR_DST does not name libEGL_nvidia.so.0"
            say "NVIDIA EGL vendor file present: $NVIDIA_VENDOR_DST"
        fi
        return
    fi
    [ "$MODE" = dry-run ] || [ "$(id -u)" -eq 0 ] || die "the system step needs root (it runs apt-get and useradd)"
    run apt-get update
    run env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${PACKAGES[@]}"
    run sh -c 'rm -rf /var/lib/apt/lists/*'
    if [ "$FLAVOR" = nvidia ]; then
        run install -D -m 0644 "$NVIDIA_VENDOR_SRC" "$NVIDIA_VENDOR_DST"
    fi
    if [ "$MODE" = dry-run ] || ! id -u "$RUN_USER" >/dev/null 2>&1; then
        run useradd --uid "$RUN_UID" --user-group --create-home --shell /bin/bash "$RUN_USER"
    fi
    # Named volumes start as a copy of the image's directory, owner included: created here, owned by the
    # user, they are writable by the service without a chown at start.
    local dirs=(/out)
    [ -z "${GARMENT_RENDER_PEM_CACHE_DIR:-}" ] || dirs+=("$GARMENT_RENDER_PEM_CACHE_DIR")
    [ -z "${GARMENT_RENDER_STATE_DIR:-}" ] || dirs+=("$GARMENT_RENDER_STATE_DIR")
    run install -d -o "$RUN_USER" -g "$RUN_USER" -m 0755 "${dirs[@]}"
}

step_deps() {
    local reqs=()
    mapfile -t reqs < <(requirements) || true
    [ ${#reqs[@]} -gt 0 ] || die "no dependencies read from $SRC/pyproject.toml"
    if [ "$MODE" = check ]; then
        # pip vendors `packaging`; use it when the environment has no copy of its own.
        "$PYTHON" - "${reqs[@]}" <<'EOF' || die "Python dependencies missing or too old (see above)"
import sys
from importlib import metadata
try:
    from packaging.requirements import Requirement
except ImportError:
    from pip._vendor.packaging.requirements import Requirement
bad = []
for line in sys.argv[1:]:
    req = Requirement(line)
    try:
        version = metadata.version(req.name)
    except metadata.PackageNotFoundError:
        bad.append(f"{req.name} (not installed)")
        continue
    if not req.specifier.contains(version, prereleases=True):
        bad.append(f"{req.name} {version} (needs {req.specifier})")
if bad:
    print("install: error: " + "; ".join(bad), file=sys.stderr)
    sys.exit(1)
EOF
        say "Python dependencies satisfied: ${#reqs[@]} from pyproject.toml"
        return
    fi
    run "$PYTHON" -m pip install --no-cache-dir "${reqs[@]}"
}

# The project imports, finds its GLSL, and its console script sits beside the interpreter.
verify_project() {
    "$PYTHON" - "$SRC" <<'EOF' || die "the project is not installed from $SRC (run docker/install.sh project)"
import sys
from pathlib import Path
import renderer, service.main
from renderer.gpu.shaders import SHADER_DIR
src = Path(sys.argv[1]).resolve()
where = Path(renderer.__file__).resolve()
if src not in where.parents:
    sys.exit(f"install: error: renderer is imported from {where}, not from {src}")
if not SHADER_DIR.is_dir() or not any(SHADER_DIR.iterdir()):
    sys.exit(f"install: error: no shaders in {SHADER_DIR}")
print(f"install: project imports from {where.parent}, shaders in {SHADER_DIR}")
EOF
    local bindir
    bindir="$("$PYTHON" -c 'import sys, sysconfig; print(sysconfig.get_path("scripts"))')"
    [ -x "$bindir/garment-render" ] || die "no garment-render console script in $bindir"
}

step_project() {
    if [ "$MODE" = check ]; then
        verify_project
        return
    fi
    # Editable: the renderer locates shaders/ beside its package, so the source tree stays the install.
    run "$PYTHON" -m pip install --no-cache-dir --no-deps -e "$SRC"
    [ "$MODE" = dry-run ] || verify_project
}

say "flavor $FLAVOR, mode $MODE, steps ${STEPS[*]}, python $PYTHON, source $SRC"
for step in "${STEPS[@]}"; do
    "step_$step"
done
