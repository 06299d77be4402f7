"""Chunked work on two threads: embree and numpy's large array operations release the GIL."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

WORKERS = 2


def threaded(work: Callable, count: int, workers: int = WORKERS):
    """Yield work(0), ..., work(count - 1) in order, computed on `workers` threads.

    If the consumer stops early (an exception such as a cancel raised from a progress callback,
    or closing the generator), chunks not yet started are dropped instead of computed.
    """
    if workers <= 1 or count <= 1:
        yield from (work(k) for k in range(count))
        return
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        yield from pool.map(work, range(count))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
