"""Parallel helpers whose results do not depend on the parallelism: an ordered map over worker
processes (fork where available; outputs independent of the number of workers when each item carries
its own seed), ``ordered_ahead``, the same over a pool the caller keeps across several maps, and ``prefetch``,
which makes a sequence's items ahead in one background thread."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def ordered_map(fn: Callable[[T], R], items: Iterable[T], workers: int, chunksize: int = 1) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in order; ``workers`` > 1 runs them in a process pool
    (``fn`` and the items must be picklable), otherwise in this process. A worker process that dies (killed:
    out of memory, a signal) raises ``MetrawError`` here instead of leaving the map waiting for ever."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    pool = _process_pool(min(workers, len(items)), "fork" if os.name == "posix" else "spawn")
    try:
        with _died_as_error():
            yield from pool.map(fn, items, chunksize=chunksize)
    finally:  # a consumer that stops early: the chunks not started are dropped, not worked through
        pool.shutdown(wait=True, cancel_futures=True)


def _process_pool(workers: int, start_method: str):
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing as mp

    return ProcessPoolExecutor(workers, mp_context=mp.get_context(start_method))


@contextlib.contextmanager
def _died_as_error():
    """``BrokenProcessPool`` (a worker process ended without its result) as one clear ``MetrawError``."""
    from concurrent.futures.process import BrokenProcessPool

    from metraw.errors import MetrawError

    try:
        yield
    except BrokenProcessPool:
        raise MetrawError("a worker process died before its result (killed, e.g. out of memory: fewer workers "
                          "need less memory)") from None


def fork_pool(workers: int):
    """A pool (``concurrent.futures.ProcessPoolExecutor``) of ``workers`` processes forked now, in the calling
    thread: they inherit the parent's objects (large read-only inputs set before the call reach them without
    pickling), and no fork happens later from a thread. Fork only: where the platform has none, one clear error.
    Use it as a context manager (``with fork_pool(n) as pool``)."""
    import multiprocessing as mp

    from metraw.errors import MetrawError

    if "fork" not in mp.get_all_start_methods():
        raise MetrawError("worker processes that share the training fields need fork(), which this platform lacks: "
                          "use 0 draw workers")
    pool = _process_pool(workers, "fork")
    with _died_as_error():
        pool.submit(int).result()  # a fork-context executor starts all its processes at its first task
    return pool


def ordered_ahead(pool, fn: Callable[[T], R], items: Iterable[T], ahead: int) -> Iterator[R]:
    """Yield ``fn(item)`` for each item, in order, computed in ``pool`` (an executor, ``fork_pool``) with at most
    ``ahead`` items in flight, so a slow consumer bounds the memory the results take. ``fn`` must be picklable.
    A worker process that dies raises ``MetrawError``."""
    from collections import deque

    if ahead < 1:
        raise ValueError(f"ahead must be >= 1, got {ahead}")
    pending: deque = deque()
    try:
        with _died_as_error():
            for item in items:
                pending.append(pool.submit(fn, item))
                if len(pending) >= ahead:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
    finally:  # a consumer that stops early: what it will not take is not computed
        for future in pending:
            future.cancel()


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
