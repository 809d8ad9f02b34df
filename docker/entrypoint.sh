#!/usr/bin/env bash
# Entrypoint of the garment-render images.
#
#   (no arguments) | serve [FLAGS]   check the cache directories and the OpenGL context (prints the renderer),
#                                    then exec the HTTP service: python -m service.main [FLAGS]
#                                    (host, port and every limit from GARMENT_RENDER_* variables)
#   check                            only the checks above; exit 0 when a GL 4.5 context can be made
#   render|sequence|reference|devices ARGS
#                                    one-shot garment-render command (e.g. render --out /out/frame.png)
#   anything else                    executed as given (bash, python, ...)
#
# GARMENT_RENDER_REQUIRE_GPU=1 (set by the NVIDIA image) makes the check fail on a software renderer
# (llvmpipe, softpipe) instead of serving from the CPU; GARMENT_RENDER_SKIP_GL_CHECK=1 skips the check
# before serving; GARMENT_RENDER_PYTHON picks the interpreter (default: python on PATH).
set -euo pipefail

PYTHON="${GARMENT_RENDER_PYTHON:-python}"
NVIDIA_VENDOR=/usr/share/glvnd/egl_vendor.d/10_nvidia.json

log() { echo "entrypoint: $*" >&2; }

# The PEM disk cache and the state directory must be writable by this user; a volume mounted from the host
# keeps the host's owner, which is the usual reason they are not.
check_dirs() {
    local name dir
    for name in GARMENT_RENDER_PEM_CACHE_DIR GARMENT_RENDER_STATE_DIR; do
        dir="${!name:-}"
        [ -n "$dir" ] || continue
        if ! mkdir -p "$dir" 2>/dev/null || [ ! -w "$dir" ]; then
            log "$name=$dir is not a directory writable by uid $(id -u); give the volume to that user" \
                "(e.g. chown $(id -u):$(id -g) on the host path) or use a named volume"
            exit 1
        fi
    done
}

check_gl() {
    if [ -f "$NVIDIA_VENDOR" ] && ! ldconfig -p 2>/dev/null | grep -q 'libEGL_nvidia\.so\.0'; then
        log "the NVIDIA EGL vendor file is here but libEGL_nvidia.so.0 is not: start the container with" \
            "--gpus all (NVIDIA container toolkit) and NVIDIA_DRIVER_CAPABILITIES including graphics" \
            "(now: ${NVIDIA_DRIVER_CAPABILITIES:-unset})"
    fi
    "$PYTHON" - <<'EOF'
import os
import sys

from renderer.errors import GLContextError
from renderer.gpu.context import GLContext

try:
    gl = GLContext()
except GLContextError as exc:
    sys.exit(f"entrypoint: no OpenGL 4.5 context: {exc}")
print(f"entrypoint: OpenGL {gl.version} on {gl.renderer_name} (context in {gl.create_ms:.0f} ms)",
      file=sys.stderr, flush=True)
name = gl.renderer_name
gl.release()
software = any(s in name.lower() for s in ("llvmpipe", "softpipe", "swrast"))
if software and os.environ.get("GARMENT_RENDER_REQUIRE_GPU", "0") == "1":
    sys.exit(f"entrypoint: GARMENT_RENDER_REQUIRE_GPU=1 but OpenGL runs on the CPU ({name}): start the "
             "container with --gpus all and NVIDIA_DRIVER_CAPABILITIES including graphics, or set "
             "GARMENT_RENDER_REQUIRE_GPU=0 to allow it")
EOF
}

command="${1:-serve}"
[ $# -eq 0 ] || shift
case "$command" in
    serve)
        check_dirs
        [ "${GARMENT_RENDER_SKIP_GL_CHECK:-0}" = 1 ] || check_gl
        log "serving on ${GARMENT_RENDER_HOST:-127.0.0.1}:${GARMENT_RENDER_PORT:-8000}," \
            "PEM cache ${GARMENT_RENDER_PEM_CACHE_DIR:-memory only}, state ${GARMENT_RENDER_STATE_DIR:-none}"
        # exec: the service is this process, so `docker stop` (SIGTERM) reaches uvicorn's graceful shutdown.
        exec "$PYTHON" -m service.main "$@"
        ;;
    check)
        check_dirs
        check_gl
        ;;
    render|sequence|reference|devices)
        exec garment-render "$command" "$@"
        ;;
    *)
        exec "$command" "$@"
        ;;
esac
