"""Reference renders in worker processes: one per core, each held to one thread."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os

_ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


@contextlib.contextmanager
def one_thread_pool(workers: int):
    """A process pool of `workers` spawned processes (the parent may hold a GL context: no fork)
    whose numpy and BLAS use one thread each; the parent's environment is restored afterwards."""
    saved = {k: os.environ.get(k) for k in _ONE_THREAD}
    os.environ.update(_ONE_THREAD)   # inherited by the spawned workers
    try:
        with cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            yield pool
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
