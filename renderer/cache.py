"""The PEM-set cache: bounded in GPU memory with LRU eviction, persisted on disk within a byte
budget (the least recently used files go first: a hit renews its file's time).

Key: the environment map's content hash, the cube face size, every PEM setting (light count, filter,
levels) and a format version, so a change to any of them, or to the build code's output format,
never returns a stale set. Disk entries are written atomically (temporary file + rename) and carry
their key, checked on load; an unreadable entry, or one found under another set's name, is rebuilt
and replaced, never trusted. A set larger than the disk budget is not written (it would evict every
other entry), and the temporaries of writers killed mid-write are removed when a cache opens.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .atomic import TEMPORARY_PREFIX, atomic_file, remove_orphaned_temporaries
from .gpu.context import GLContext
from .lighting.pem import PEMSet, PEMSettings

log = logging.getLogger(__name__)

# Bump when the stored arrays or the build's numerical output change.
# 2: solid-angle weighted chains (A = chain(L * w)); 3: regions carry mean_cos; 4: entries carry their key;
# 5: an area set's remainder takes every light of the budget the area lights leave; 6: a wide area light
# is cut into pieces by its energy.
FORMAT_VERSION = 6


@dataclass
class CacheStats:
    hits: int = 0
    misses: int = 0
    disk_hits: int = 0
    disk_errors: int = 0
    evictions: int = 0
    disk_evictions: int = 0
    builds: int = 0
    build_ms_total: float = 0.0
    entries: int = 0
    bytes: int = 0
    disk_key_mismatches: int = 0    # entries whose stored key is not their name's (copied, renamed): rebuilt
    disk_too_large: int = 0         # sets not written: larger alone than the disk budget
    temporaries_removed: int = 0    # orphaned temporaries of killed writers removed at start-up
    temporary_bytes_removed: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


# The cache's own files (cache_key's names): eviction never touches anything else in the directory.
_ENTRY_NAME = re.compile(r"^[0-9a-f]{32}\.npz$")


def cache_key(content_hash: str, face_size: int, settings: PEMSettings) -> str:
    raw = f"v{FORMAT_VERSION}|{content_hash}|{face_size}|{settings.key()}"
    return hashlib.sha256(raw.encode()).hexdigest()[:32]


class PEMCache:
    """name: shown in statistics; max_bytes: GPU bytes of PEMs kept resident; disk_dir: None for
    memory only; disk_max_bytes: bytes of entries kept in disk_dir (entries of older formats count
    too, and go first as they are never used). Used from the GL thread only, like everything
    holding GPU objects."""

    def __init__(self, gl: GLContext, max_bytes: int = 1 << 30, disk_dir: str | Path | None = None,
                 name: str = "pem-sets", disk_max_bytes: int = 4 << 30):
        self.gl, self.max_bytes, self.name = gl, int(max_bytes), name
        self.disk_max_bytes = int(disk_max_bytes)
        self.disk_dir = Path(disk_dir) if disk_dir else None
        self._entries: OrderedDict[str, PEMSet] = OrderedDict()
        self.stats = CacheStats()
        if self.disk_dir:
            self.disk_dir.mkdir(parents=True, exist_ok=True)
            n, size = remove_orphaned_temporaries(self.disk_dir)
            self.stats.temporaries_removed, self.stats.temporary_bytes_removed = n, size
            if n:
                log.warning("removed %d orphaned temporaries (%d bytes) from %s", n, size, self.disk_dir)

    def get(self, content_hash: str, cube: np.ndarray, settings: PEMSettings) -> PEMSet:
        """The PEM set of `cube` (identified by `content_hash`) for `settings`: from memory, from
        disk, or built (and then stored in both)."""
        self.gl.check_thread()
        key = cache_key(content_hash, cube.shape[1], settings)
        pems = self._entries.get(key)
        if pems is not None:
            self._entries.move_to_end(key)
            self.stats.hits += 1
            return pems
        self.stats.misses += 1
        pems = self._load(key, cube, settings)
        if pems is None:
            t0 = time.perf_counter()
            pems = PEMSet(self.gl, cube, settings)
            self.stats.builds += 1
            self.stats.build_ms_total += (time.perf_counter() - t0) * 1e3
            self._store(key, pems)
        self._entries[key] = pems
        self._evict(keep=key)
        self._update()
        return pems

    def __contains__(self, key: str) -> bool:
        return key in self._entries

    def _path(self, key: str) -> Path | None:
        return self.disk_dir / f"{key}.npz" if self.disk_dir else None

    def _load(self, key: str, cube: np.ndarray, settings: PEMSettings) -> PEMSet | None:
        path = self._path(key)
        if path is None or not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                stored = {k: data[k] for k in data.files}
            found = str(stored.pop("cache_key", ""))
            if found != key:   # another set's file under this name (copied, renamed): never trusted
                log.warning("PEM cache entry %s holds the set of key %r; rebuilding it", path, found or None)
                self.stats.disk_key_mismatches += 1
                return None
            pems = PEMSet(self.gl, cube, settings, stored=stored)
        except Exception as exc:  # a truncated or foreign file: rebuild rather than trust it
            log.warning("PEM cache entry %s is unreadable (%s); rebuilding it", path, exc)
            self.stats.disk_errors += 1
            return None
        self.stats.disk_hits += 1
        try:
            os.utime(path)   # recently used: the last to be evicted
        except OSError:
            pass
        return pems

    def _store(self, key: str, pems: PEMSet) -> None:
        path = self._path(key)
        if path is None:
            return
        arrays = pems.export()
        size = sum(a.nbytes for a in arrays.values())
        if size > self.disk_max_bytes:   # it would evict every other entry and still not fit
            log.warning("PEM set %s (%d bytes) is larger than the disk budget (%d bytes); not stored",
                        key, size, self.disk_max_bytes)
            self.stats.disk_too_large += 1
            return
        arrays["cache_key"] = np.array(key)   # checked on load against the name it is found under
        try:
            with atomic_file(path) as f:
                np.savez(f, **arrays)
        except OSError as exc:
            log.warning("could not write PEM cache entry %s: %s", path, exc)
            self.stats.disk_errors += 1
            return
        self._evict_disk(keep=path)

    def _evict_disk(self, keep: Path) -> None:
        """Delete the least recently used entries until the directory's entries fit disk_max_bytes
        (never `keep`, the entry just written). Another process may delete or use them meanwhile: a
        file gone is skipped, and a reader that still holds one open keeps its data."""
        entries, writing = [], 0
        for path in self.disk_dir.iterdir():
            temporary = path.name.startswith(TEMPORARY_PREFIX)
            if not (temporary or _ENTRY_NAME.match(path.name)):
                continue
            try:
                st = path.stat()
            except OSError:
                continue
            if temporary:   # being written (by another process): counted, never evicted
                writing += st.st_size
            else:
                entries.append((st.st_mtime, st.st_size, path))
        total = writing + sum(size for _, size, _ in entries)
        for _, size, path in sorted(entries, key=lambda e: e[0]):
            if total <= self.disk_max_bytes:
                break
            if path == keep:
                continue
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:
                log.warning("could not evict PEM cache entry %s: %s", path, exc)
                continue
            total -= size
            self.stats.disk_evictions += 1

    def _evict(self, keep: str) -> None:
        while self._resident_bytes() > self.max_bytes and len(self._entries) > 1:
            key, pems = next(iter(self._entries.items()))
            if key == keep:
                break
            del self._entries[key]
            pems.release()  # frees the GPU memory now, not at garbage collection
            self.stats.evictions += 1

    def _resident_bytes(self) -> int:
        return sum(p.nbytes for p in self._entries.values())

    def _update(self) -> None:
        self.stats.entries = len(self._entries)
        self.stats.bytes = self._resident_bytes()

    def clear(self) -> None:
        self.gl.check_thread()
        for pems in self._entries.values():
            pems.release()
        self._entries.clear()
        self._update()
