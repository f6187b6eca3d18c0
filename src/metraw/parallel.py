"""Ordered parallel map over worker processes (fork where available): results in input order, so
outputs do not depend on the number of workers when each item carries its own seed."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def ordered_map(fn: Callable[[T], R], items: Iterable[T], workers: int, chunksize: int = 1) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in order; ``workers`` > 1 runs them in a process pool
    (``fn`` and the items must be picklable), otherwise in this process."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    import multiprocessing as mp

    ctx = mp.get_context("fork" if os.name == "posix" else "spawn")
    with ctx.Pool(min(workers, len(items))) as pool:
        yield from pool.imap(fn, items, chunksize=chunksize)
