#!/usr/bin/env bash
# Sets up a fresh Debian/Ubuntu machine: Mesa's EGL/OpenGL (when missing), Chromium (for the test of
# the viewer page, when missing), podman, debootstrap and shellcheck (for the image tests, when
# missing), a virtual environment in .venv and the project with its test and Ray dependencies. Safe to
# run again; it skips what is done.
set -euo pipefail
cd "$(dirname "$0")/.."

need_pkgs=()
for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri libgles2; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need_pkgs+=("$pkg")
done
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
if [ ${#need_pkgs[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${need_pkgs[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need_pkgs[@]}"
fi
# Headless Chromium runs the viewer page's test. Not fatal: without it that one test says why it skipped.
if ! command -v chromium >/dev/null 2>&1; then
    echo "setup: installing Debian's chromium (for the viewer page's test)"
    { [ ${#need_pkgs[@]} -gt 0 ] || $SUDO apt-get update -qq; } &&
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium ||
        echo "setup: could not install chromium; the viewer page's test will be skipped" >&2
fi

# podman and debootstrap build and run the real images (tests/test_image.py, docker/README.md)
# and shellcheck lints their scripts (tests/test_docker.py). Not fatal either: those tests say why they skip.
image_tools=()
for tool in podman debootstrap shellcheck; do command -v "$tool" >/dev/null 2>&1 || image_tools+=("$tool"); done
if [ ${#image_tools[@]} -gt 0 ]; then
    echo "setup: installing ${image_tools[*]} (the image tests)"
    { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
        "${image_tools[@]}"; } >/dev/null 2>&1 || echo "setup: could not install ${image_tools[*]}; the image tests will be skipped" >&2
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $($PYTHON --version)"
    "$PYTHON" -m venv .venv
fi
stamp=.venv/.installed-$(cat pyproject.toml lab/pyproject.toml | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e '.[test,ray]' -e ./lab
    rm -f .venv/.installed-*
    touch "$stamp"
fi
.venv/bin/python -c "import renderer.gpu.context as c; g = c.GLContext(); print('setup: OpenGL', g.version, 'on', g.renderer_name); g.release()"
