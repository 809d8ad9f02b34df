"""Writing a file so that readers see the old content or the new one, never a half-written file."""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from pathlib import Path

TEMPORARY_PREFIX = ".tmp-"


@contextlib.contextmanager
def atomic_file(path: Path):
    """Open a temporary file beside `path` for binary writing; on a clean exit it replaces `path`
    (os.replace is atomic on POSIX), on an exception it is removed and the exception propagates.

    The writer holds an exclusive lock on its temporary while it writes, so that
    `remove_orphaned_temporaries` can tell a temporary whose writer died (kill -9) from one being
    written by a live process."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=TEMPORARY_PREFIX)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.replace(tmp, path)   # still locked: no cleaner can take it for an orphan meanwhile
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def remove_orphaned_temporaries(folder: Path) -> tuple[int, int]:
    """Delete the temporaries of `atomic_file` in `folder` that no live writer holds (their lock is
    free: the writer was killed before it could rename or remove them). Returns (files, bytes)."""
    files = size = 0
    for p in Path(folder).glob(TEMPORARY_PREFIX + "*"):
        try:
            fd = os.open(p, os.O_RDONLY)
        except OSError:
            continue   # gone meanwhile
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue   # a live writer holds it
            n = os.fstat(fd).st_size
            try:
                p.unlink()
            except OSError:
                continue
            files, size = files + 1, size + n
        finally:
            os.close(fd)
    return files, size
