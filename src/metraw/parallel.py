"""Parallel helpers whose results do not depend on the parallelism: an ordered map over worker
processes (fork where available; outputs independent of the number of workers when each item carries
its own seed), ``ordered_ahead``, the same over a pool the caller keeps across several maps, and ``prefetch``,
which makes a sequence's items ahead in one background thread."""

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


def fork_pool(workers: int):
    """A process pool of ``workers`` forked processes: they inherit the parent's objects (large read-only inputs
    set before the call reach them without pickling). Fork only: where the platform has none, one clear error."""
    import multiprocessing as mp

    from metraw.errors import MetrawError

    if "fork" not in mp.get_all_start_methods():
        raise MetrawError("worker processes that share the training fields need fork(), which this platform lacks: "
                          "use 0 draw workers")
    return mp.get_context("fork").Pool(workers)


def ordered_ahead(pool, fn: Callable[[T], R], items: Iterable[T], ahead: int) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in order, computed in ``pool`` (``multiprocessing.pool.Pool``) with at most
    ``ahead`` items in flight, so a slow consumer bounds the memory the results take. ``fn`` must be picklable."""
    from collections import deque

    if ahead < 1:
        raise ValueError(f"ahead must be >= 1, got {ahead}")
    pending: deque = deque()
    for item in items:
        pending.append(pool.apply_async(fn, (item,)))
        if len(pending) >= ahead:
            yield pending.popleft().get()
    while pending:
        yield pending.popleft().get()


def prefetch(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """Yield ``items`` in their order, each made up to ``depth`` ahead by one background thread.

    The producer's work overlaps the consumer's wherever either releases the GIL (numpy, the codec's
    numba kernels, torch operators). One thread makes the items one after the other, so a generator
    drawing from a seeded generator yields the same items as without prefetching. An exception of the
    producer is raised in the consumer at its place in the sequence; a consumer that stops early stops
    the producer (after the item it is making).
    """
    import queue
    import threading

    if depth < 1:
        raise ValueError(f"depth must be >= 1, got {depth}")
    slots: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def put(entry) -> bool:
        while not stop.is_set():
            try:
                slots.put(entry, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    return
            put((end, None))
        except BaseException as error:  # handed to the consumer, raised there
            put((None, error))

    worker = threading.Thread(target=produce, name="metraw-prefetch", daemon=True)
    worker.start()
    try:
        while True:
            item, error = slots.get()
            if error is not None:
                raise error
            if item is end:
                return
            yield item
    finally:
        stop.set()
        worker.join()
