#!/usr/bin/env bash
# Build the images from their real Dockerfiles without a Docker engine or a registry (podman, root):
#
#   docker/build-local.sh [cpu|nvidia ...]        (default: cpu)
#
# The Dockerfiles start FROM python:3.11-slim-bookworm, which no registry here serves. Once per machine
# this makes a stand-in under that name: a minimal Debian bookworm made by debootstrap from the machine's
# own Debian mirror, imported into podman, plus Debian's python3 (3.11), venv and pip. Then each flavor
# is built with chroot isolation (no cgroups needed) and the host's network, the machine's pip settings
# and CA bundle mounted read-only so that pip inside the build finds its packages. The images are
# garment-render:cpu and garment-render:nvidia; docker/run-local.sh serves one.
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
FLAVORS=("$@")
[ ${#FLAVORS[@]} -gt 0 ] || FLAVORS=(cpu)
BASE=docker.io/library/python:3.11-slim-bookworm
DEBIAN=localhost/debian:bookworm-slim

die() { echo "build-local: error: $*" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] || die "needs root (podman's chroot isolation and debootstrap)"
for tool in podman debootstrap; do
    command -v "$tool" >/dev/null || die "$tool is not installed: apt-get install -y podman debootstrap"
done

mirror() {   # the machine's own Debian mirror (deb822 or one-line sources), else Debian's own
    local uri
    uri=$(grep -hs '^URIs:' /etc/apt/sources.list.d/*.sources | awk '{print $2}' | grep -v security | head -n1 || true)
    [ -n "$uri" ] || uri=$(grep -hs '^deb ' /etc/apt/sources.list | awk '{print $2}' | grep -v security | head -n1 || true)
    echo "${uri:-http://deb.debian.org/debian}"
}

if ! podman image exists "$BASE"; then
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
    if ! podman image exists "$DEBIAN"; then
        echo "build-local: debootstrap bookworm from $(mirror) (about a minute)"
        debootstrap --variant=minbase bookworm "$work/rootfs" "$(mirror)" >"$work/debootstrap.log" 2>&1 \
            || { tail -20 "$work/debootstrap.log" >&2; die "debootstrap failed"; }
        tar -C "$work/rootfs" -c . | podman import - "$DEBIAN" >/dev/null
        rm -rf "$work/rootfs"
    fi
    cat >"$work/Containerfile" <<CONTAINERFILE
FROM $DEBIAN
RUN apt-get update && apt-get install -y --no-install-recommends python3 python3-venv python3-pip ca-certificates \\
    && rm -rf /var/lib/apt/lists/* && ln -s /usr/bin/python3 /usr/local/bin/python && ln -s /usr/bin/pip3 /usr/local/bin/pip
# Debian marks its Python as externally managed; the image is the environment.
ENV PIP_BREAK_SYSTEM_PACKAGES=1
CONTAINERFILE
    echo "build-local: the stand-in for $BASE"
    podman build --isolation=chroot --network=host -f "$work/Containerfile" -t "$BASE" "$work" >/dev/null
fi

mounts=()
[ -f /etc/pip.conf ] && mounts+=(-v /etc/pip.conf:/etc/pip.conf:ro)
[ -d /etc/ssl/certs ] && mounts+=(-v /etc/ssl/certs:/etc/ssl/certs:ro)
for flavor in "${FLAVORS[@]}"; do
    case "$flavor" in cpu|nvidia) ;; *) die "unknown flavor $flavor (cpu, nvidia)" ;; esac
    echo "build-local: garment-render:$flavor from docker/Dockerfile.$flavor"
    podman build --isolation=chroot --network=host --format docker "${mounts[@]}" \
        -f "docker/Dockerfile.$flavor" -t "garment-render:$flavor" .
done
