"""The encoder's per-thread scratch arrays (metraw.codec.scratch): reused, per thread, never read before written, and
what they are for: no fresh pages for a tile's per-pixel arrays."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import threading

import numpy as np
import pytest

from metraw import codec
from metraw.codec import native, scratch
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed


def _frame(h: int, w: int, seed: int = 3) -> RawImage:
    prof = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100.0, read_noise_e=3.0, white_level_dn=16000.0,
                              adc_bits=14, cfa_pattern="RGGB")
    yy, xx = np.mgrid[0:h, 0:w]
    mean = 50 + 9000 * (1 + np.sin(xx / 23.0) * np.cos(yy / 17.0))
    return RawImage(expose(mean, prof, rng_from_seed(seed)), prof)


def test_scratch_arrays_are_reused_within_a_thread_and_apart_across_threads():
    scratch.release()
    a = scratch.empty("t", 1000, np.int32)
    assert a.shape == (1000,) and a.dtype == np.int32
    b = scratch.empty("t", 500, np.uint16)   # smaller: the same memory, another view
    assert np.shares_memory(a, b) and b.shape == (500,) and b.dtype == np.uint16
    c = scratch.empty("t", 5000, np.int32)   # larger: grown
    assert c.shape == (5000,) and not np.shares_memory(a, c)
    assert np.shares_memory(scratch.empty("t", 10, np.int32), c)
    assert not np.shares_memory(scratch.empty("u", 10, np.int32), c)   # another name, another buffer
    other = []
    thread = threading.Thread(target=lambda: other.append(scratch.empty("t", 5000, np.int32)))
    thread.start()
    thread.join()
    assert not np.shares_memory(other[0], c)
    scratch.release()
    assert not np.shares_memory(scratch.empty("t", 10, np.int32), c)


def test_encoder_reads_nothing_left_in_its_scratch_arrays(monkeypatch):
    """The same bytes from fresh buffers and from buffers full of another frame's values or of garbage: the encoder
    writes every element of them it reads (one thread and two; a small frame's shared model too)."""
    small, big = _frame(96, 120, seed=5), _frame(600, 700, seed=6)
    for threads in (1, 2):
        monkeypatch.setattr(codec, "THREADS", threads)
        for img in (small, big):
            scratch.release()
            want = codec.encode(img, 1.0, 7)
            codec.encode(big if img is small else small, 2.0, 8)   # the buffers now hold another frame's values
            assert codec.encode(img, 1.0, 7) == want
            held = scratch._LOCAL.buffers   # this thread's, whatever their names: now garbage
            assert {"residuals", "tables", "words"} <= set(held), set(held)
            for buf in held.values():
                buf[:] = 0xA5
            assert codec.encode(img, 1.0, 7) == want
    np.testing.assert_array_equal(codec.decode(want).data, codec.round_trip(big, 1.0, 7))


_FAULTS = """
import ctypes, resource, sys, numpy as np
ctypes.CDLL(None, use_errno=True).prctl(41, 1, 0, 0, 0)   # PR_SET_THP_DISABLE: 4 KiB pages, whatever the host's THP
from metraw import codec
from metraw.codec import scratch
sys.path.insert(0, {tests!r})
from test_codec_scratch import _frame
codec.THREADS = 1
img = _frame(512, 1024)
def faults(mode):
    scratch.empty = reuse if mode == "reuse" else (lambda name, n, dtype: np.empty(n, dtype))
    codec.encode(img, 1.0, 0, check_profile=False)
    f0 = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    for _ in range(3):
        codec.encode(img, 1.0, 0, check_profile=False)
    return (resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - f0) / 3
reuse = scratch.empty
print(faults("fresh"), faults("reuse"))
"""


@pytest.mark.skipif(sys.platform != "linux" or platform.libc_ver()[0] != "glibc", reason="glibc on Linux")
def test_scratch_arrays_spare_the_encoder_fresh_pages():
    """With every block over 128 KiB a fresh mapping (glibc's MALLOC_MMAP_THRESHOLD_ fixed there: what a trimmed heap
    does), a 1-thread encode of a 0.5 MP frame faults its per-pixel arrays in page by page, once per call, unless they
    are reused: the residuals and table indices (4 + 4 bytes a pixel, all written) and, compiled, the alphabet
    indices (4; the rANS words, 2 bytes a pixel, are written only as far as the stream goes). Reused, at least 90 % of
    the pages of the arrays written in full are spared."""
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": "131072"}
    out = subprocess.run([sys.executable, "-c", _FAULTS.format(tests=os.path.dirname(__file__))], env=env,
                         capture_output=True, text=True, check=True)
    fresh, reused = map(float, out.stdout.split())
    per_pixel_bytes = 12 if native.LIB is not None else 8
    pages = per_pixel_bytes * 512 * 1024 / 4096
    assert fresh - reused >= 0.9 * pages, (fresh, reused, pages)
