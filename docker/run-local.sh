#!/usr/bin/env bash
# Serve a locally built image (docker/build-local.sh) where no container runtime can run it: the
# image's own filesystem, mounted by podman, becomes the root of the service's process (chroot), as
# its user, with its environment, its entrypoint, its two volumes bound to host folders and a fresh
# /tmp (a container's writable layer; the mounted image is read-only).
#
#   docker/run-local.sh IMAGE PORT PEM_CACHE_DIR STATE_DIR [ENTRYPOINT ARGS...]   (default args: serve)
#
# The service listens on 127.0.0.1:PORT. The folders must be writable by the image's user (uid
# 10001). SIGTERM or SIGINT stops the service and undoes every mount.
set -euo pipefail

[ $# -ge 4 ] || { sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; }
IMAGE=$1 PORT=$2 PEM=$3 STATE=$4
shift 4
[ $# -gt 0 ] || set -- serve
[ "$(id -u)" -eq 0 ] || { echo "run-local: needs root (mounts, chroot)" >&2; exit 2; }

root=$(podman image mount "$IMAGE")
env_of() { podman image inspect --format "{{range .Config.Env}}{{println .}}{{end}}" "$IMAGE"; }
user=$(podman image inspect --format '{{.Config.User}}' "$IMAGE")
pem_in=$(env_of | sed -n 's/^GARMENT_RENDER_PEM_CACHE_DIR=//p')
state_in=$(env_of | sed -n 's/^GARMENT_RENDER_STATE_DIR=//p')
bound=()
# shellcheck disable=SC2317  # run by the EXIT trap
cleanup() {
    local i
    for ((i = ${#bound[@]} - 1; i >= 0; i--)); do umount -R "${bound[i]}" 2>/dev/null || true; done
    podman image unmount "$IMAGE" >/dev/null 2>&1 || true
}
trap cleanup EXIT
bind() { mount "$1" "$2" "$3"; bound+=("$3"); }
bind --bind /proc "$root/proc"
bind --rbind /dev "$root/dev"
# The image's filesystem is mounted read-only; a container would write /tmp to its own layer.
mount -t tmpfs -o mode=1777 tmpfs "$root/tmp"
bound+=("$root/tmp")
bind --bind "$PEM" "$root$pem_in"
bind --bind "$STATE" "$root$state_in"
uid=$(chroot "$root" id -u "${user:-root}") gid=$(chroot "$root" id -g "${user:-root}")
mapfile -t environment < <(env_of | grep -v "^$")
env -i "${environment[@]}" HOME=/tmp GARMENT_RENDER_HOST=127.0.0.1 GARMENT_RENDER_PORT="$PORT" \
    chroot --userspec="$uid:$gid" "$root" /bin/sh -c 'cd /app && exec /app/docker/entrypoint.sh "$@"' sh "$@" &
child=$!
trap 'kill -TERM "$child" 2>/dev/null || true' TERM INT
status=0
wait "$child" || status=$?
# A signal interrupts the first wait: wait again for the service to finish.
kill -0 "$child" 2>/dev/null && { wait "$child" || status=$?; }
exit "$status"
