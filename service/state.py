"""Environment maps, fabrics and scenes written to a state directory (GARMENT_RENDER_STATE_DIR), so
that any process of the service (uvicorn --workers N, each with its own GL context and memory) and a
restarted one can restore them on first use, by id. Without a state directory they live in the
memory of the process that made them.

Layout: environments/<id>.json (how it was uploaded) + environments/<id>.<exr|hdr> (the bytes as
uploaded); fabrics/<id>.json (its name) + fabrics/<id>.u3m (the U3M or U3MA bytes as uploaded);
scenes/<id>.json (the SceneCreate body, meshes inline, fabrics by id); scenes/<id>.frames (the frames
rendered of the scene by every process, one counter under a file lock: the service's frame sequence
is one for all of them). Files are written to a temporary name and renamed, so a reader never sees
half a file.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

from renderer.atomic import atomic_file, remove_orphaned_temporaries


def _atomic_write(path: Path, data: bytes) -> None:
    with atomic_file(path) as f:
        f.write(data)


def _safe_id(item_id: str) -> str:
    if not item_id or not all(c.isalnum() or c == "_" for c in item_id):
        raise ValueError(f"not an id: {item_id!r}")
    return item_id


class StateDir:
    def __init__(self, root: Path):
        self.root = Path(root)
        self.environments = self.root / "environments"
        self.fabrics = self.root / "fabrics"
        self.scenes = self.root / "scenes"
        for folder in (self.environments, self.fabrics, self.scenes):
            folder.mkdir(parents=True, exist_ok=True)
        # What writers killed mid-write left behind (no live process holds their lock).
        self.temporaries_removed = sum(remove_orphaned_temporaries(d)[0]
                                       for d in (self.environments, self.fabrics, self.scenes))

    def scene_ids(self) -> list[str]:
        """The ids of the stored scenes (any process may restore them)."""
        return sorted(p.stem for p in self.scenes.glob("*.json"))

    # -- environments ----------------------------------------------------------------------------
    def save_environment(self, env_id: str, data: bytes, meta: dict) -> None:
        env_id = _safe_id(env_id)
        _atomic_write(self.environments / f"{env_id}.{meta['kind']}", data)
        _atomic_write(self.environments / f"{env_id}.json", json.dumps(meta).encode())

    def load_environment(self, env_id: str) -> tuple[bytes, dict] | None:
        try:
            env_id = _safe_id(env_id)
            meta = json.loads((self.environments / f"{env_id}.json").read_text())
            return (self.environments / f"{env_id}.{meta['kind']}").read_bytes(), meta
        except (OSError, ValueError, KeyError):
            return None

    def delete_environment(self, env_id: str) -> None:
        for p in self.environments.glob(f"{_safe_id(env_id)}.*"):
            p.unlink(missing_ok=True)

    # -- fabrics -----------------------------------------------------------------------------------
    def save_fabric(self, fabric_id: str, data: bytes, meta: dict) -> None:
        fabric_id = _safe_id(fabric_id)
        _atomic_write(self.fabrics / f"{fabric_id}.u3m", data)
        _atomic_write(self.fabrics / f"{fabric_id}.json", json.dumps(meta).encode())

    def load_fabric(self, fabric_id: str) -> tuple[bytes, dict] | None:
        try:
            fabric_id = _safe_id(fabric_id)
            meta = json.loads((self.fabrics / f"{fabric_id}.json").read_text())
            return (self.fabrics / f"{fabric_id}.u3m").read_bytes(), meta
        except (OSError, ValueError):
            return None

    def delete_fabric(self, fabric_id: str) -> None:
        for p in self.fabrics.glob(f"{_safe_id(fabric_id)}.*"):
            p.unlink(missing_ok=True)

    # -- scenes ----------------------------------------------------------------------------------
    def save_scene(self, scene_id: str, body_json: str) -> None:
        _atomic_write(self.scenes / f"{_safe_id(scene_id)}.json", body_json.encode())

    def load_scene(self, scene_id: str) -> str | None:
        try:
            return (self.scenes / f"{_safe_id(scene_id)}.json").read_text()
        except (OSError, ValueError):
            return None

    def delete_scene(self, scene_id: str) -> None:
        (self.scenes / f"{_safe_id(scene_id)}.json").unlink(missing_ok=True)
        (self.scenes / f"{_safe_id(scene_id)}.frames").unlink(missing_ok=True)

    def count_frames(self, scene_id: str, n: int = 1) -> int:
        """Add `n` frames to the scene's count over every process that renders it and return the new
        count (an exclusive lock on its file: processes on one machine, or on a file system whose
        locks reach every node)."""
        fd = os.open(self.scenes / f"{_safe_id(scene_id)}.frames", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            raw = os.pread(fd, 8, 0)
            count = (int.from_bytes(raw, "little") if len(raw) == 8 else 0) + n
            os.pwrite(fd, count.to_bytes(8, "little"), 0)
            return count
        finally:
            os.close(fd)   # and with it the lock
