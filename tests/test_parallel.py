"""metraw.parallel: ordered process map and background prefetching keep order, seeds and errors."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from metraw import codec
from metraw.errors import MetrawError
from metraw.parallel import fork_pool, ordered_ahead, ordered_map, prefetch


def _square(x: int) -> int:
    return x * x


def test_ordered_map_gives_the_same_results_in_order_for_any_worker_count():
    assert list(ordered_map(_square, range(9), 1)) == list(ordered_map(_square, range(9), 2, chunksize=2)) == [
        x * x for x in range(9)]


def _slow_first(x: int) -> int:
    time.sleep(0.2 if x == 0 else 0.0)  # the first item finishes last: the results must still come in order
    return x * x


def test_ordered_ahead_keeps_order_and_bounds_the_items_in_flight(monkeypatch):
    with fork_pool(2) as pool:
        for ahead in (1, 3, 20):
            assert list(ordered_ahead(pool, _slow_first, range(7), ahead)) == [x * x for x in range(7)]
        submitted = []
        real = pool.submit
        monkeypatch.setattr(pool, "submit", lambda fn, item: submitted.append(item) or real(fn, item))
        made = ordered_ahead(pool, _square, range(10), 3)
        assert next(made) == 0 and submitted == [0, 1, 2]  # 3 in flight when the first is handed over
        assert list(made) == [x * x for x in range(1, 10)]
        with pytest.raises(ValueError, match="ahead must be >= 1"):
            next(ordered_ahead(pool, _square, range(2), 0))


def _dies_at_3(x: int) -> int:
    if x == 3:
        os._exit(9)  # as the kernel's out-of-memory killer ends a worker: no result, no exception
    return x


def test_a_worker_that_dies_is_one_clear_error_not_a_map_that_waits_for_ever():
    signal.alarm(60)  # the failure this guards against is a hang: end the test instead of the suite
    try:
        for workers in (2, 3):
            with pytest.raises(MetrawError, match="worker process died"):
                list(ordered_map(_dies_at_3, range(8), workers))
        with fork_pool(2) as pool, pytest.raises(MetrawError, match="worker process died"):
            list(ordered_ahead(pool, _dies_at_3, range(8), 2))
    finally:
        signal.alarm(0)


def _slow(x: int) -> int:
    time.sleep(0.2)
    return x


def test_a_consumer_that_stops_early_stops_the_work():
    made = ordered_map(_slow, range(64), 2)
    assert next(made) == 0
    start = time.perf_counter()
    made.close()  # the chunks not started are dropped (64 x 0.2 s would take ~6 s on 2 workers)
    assert time.perf_counter() - start < 2.0


def test_fork_pool_refuses_a_platform_without_fork_in_one_line(monkeypatch):
    import multiprocessing

    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    with pytest.raises(MetrawError, match="need fork"):
        fork_pool(2)


def test_prefetch_yields_a_seeded_generator_unchanged_and_runs_ahead_in_another_thread():
    def draws(seed, made, threads):
        rng = np.random.default_rng(seed)
        for _ in range(20):
            threads.add(threading.get_ident())
            made.append(1)
            yield rng.normal(size=3)

    plain = list(draws(5, [], set()))
    made, threads = [], set()
    got = []
    for item in prefetch(draws(5, made, threads), depth=2):
        got.append(item)
        if len(got) == 3:
            time.sleep(0.2)  # the consumer is busy: the producer makes the next items meanwhile, at most depth + 1
            assert len(made) in (3 + 2, 3 + 3), len(made)
    assert len(got) == 20 and all(np.array_equal(a, b) for a, b in zip(got, plain))
    assert threads == {next(iter(threads))} != {threading.get_ident()}  # one background thread made them all


def test_prefetch_raises_the_producers_error_in_place_and_an_early_stop_stops_the_producer():
    def failing():
        yield 1
        yield 2
        raise ValueError("bad item 3")

    got = []
    with pytest.raises(ValueError, match="bad item 3"):
        for item in prefetch(failing()):
            got.append(item)
    assert got == [1, 2]

    made = []

    def endless():
        while True:
            made.append(1)
            yield len(made)

    for item in prefetch(endless(), depth=1):
        if item == 4:
            break
    n = len(made)
    time.sleep(0.2)
    assert n <= 4 + 2 and len(made) == n  # stopped: nothing made after the consumer left
    with pytest.raises(ValueError, match="depth must be >= 1"):
        next(prefetch(iter([1]), depth=0))


def test_codec_threads_is_restored_after_the_block_even_on_error():
    before = codec.THREADS
    with pytest.raises(RuntimeError):
        with codec.threads(1):
            assert codec.THREADS == 1
            raise RuntimeError
    assert codec.THREADS == before
    with pytest.raises(ValueError, match=">= 1"):
        with codec.threads(0):
            pass
