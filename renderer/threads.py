"""Threads for the CPU stages of a new map (the source resampled to a cube, face by face; the area
lights' search): their numpy work (lookups, products, searches, reductions over large arrays) releases
the GIL, so chunks of it run on every core. Results are the same as in one thread: each chunk writes its
own part of the output."""

from __future__ import annotations

import concurrent.futures
import os
import threading
from collections.abc import Callable, Iterable
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

_pool: concurrent.futures.ThreadPoolExecutor | None = None
_lock = threading.Lock()


def map_threads(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """[fn(item) for item in items], the calls spread over a pool of one thread per core (made on
    first use, shared by the process); the first exception is raised."""
    global _pool
    items = list(items)
    cores = os.cpu_count() or 1
    if cores < 2 or len(items) < 2:
        return [fn(item) for item in items]
    with _lock:
        if _pool is None:
            _pool = concurrent.futures.ThreadPoolExecutor(max_workers=cores, thread_name_prefix="garment-render-cpu")
    return list(_pool.map(fn, items))
