"""The user's cache folder, where a one-shot command keeps what the next one can reuse: the PEM sets
(cache.PEMCache's disk entries) and the glossiness calibration's tables (lighting/glossiness.py).

`GARMENT_RENDER_CACHE_DIR` names it; else `$XDG_CACHE_HOME/garment-render`, else
`~/.cache/garment-render`. Everything in it can be deleted at any time: it is rebuilt on use. An entry
is written atomically and names the code that made it (`code_digest`), so a changed build never
reads an old entry."""

from __future__ import annotations

import hashlib
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .atomic import atomic_file

log = logging.getLogger(__name__)

ENV_VAR = "GARMENT_RENDER_CACHE_DIR"


def user_cache_dir(*parts: str) -> Path:
    """The cache folder (module doc), or a sub-folder of it; not created here."""
    root = os.environ.get(ENV_VAR)
    if not root:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "garment-render"
    return Path(root).joinpath(*parts)


def code_digest(*modules: str) -> str:
    """A short hash of the source files of `modules` (the names of imported modules): an entry made by
    other code has another name."""
    h = hashlib.sha256()
    for m in modules:
        h.update(Path(sys.modules[m].__file__).read_bytes())
    return h.hexdigest()[:16]


def cached_arrays(folder: Path, name: str, code: tuple[str, ...], build: Callable[[], dict[str, np.ndarray]],
                  max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """`load_or_build` of the entry `name` in `folder`, made by the modules named in `code` (their
    source's digest is in the entry's file name)."""
    return load_or_build(Path(folder) / f"{name}-{code_digest(*code)}.npz", build, max_bytes)


def load_or_build(path: Path, build: Callable[[], dict[str, np.ndarray]],
                  max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """The arrays stored at `path`, else `build()`'s, stored there for the next process. An entry
    that cannot be read is built anew and replaced; a folder that cannot be written only costs the
    build (logged). `max_bytes`: the entries of `path`'s folder are kept within it, the least
    recently used deleted first (a read renews an entry)."""
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
            try:
                os.utime(path)
            except OSError:
                pass
            return arrays
        except Exception as exc:   # truncated or foreign: rebuilt, never trusted
            log.warning("cache entry %s is unreadable (%s); building it anew", path, exc)
    arrays = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as f:
            np.savez(f, **arrays)
        if max_bytes is not None:
            _keep_within(path.parent, max_bytes, keep=path)
    except OSError as exc:
        log.warning("could not write cache entry %s: %s", path, exc)
    return arrays


def _keep_within(folder: Path, max_bytes: int, keep: Path) -> None:
    entries = []
    for p in folder.glob("*.npz"):
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in entries)
    for _, size, p in sorted(entries, key=lambda e: e[0]):
        if total <= max_bytes:
            break
        if p != keep:
            p.unlink(missing_ok=True)
            total -= size
