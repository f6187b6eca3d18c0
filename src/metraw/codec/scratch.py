"""Per-thread arrays the encoder reuses from call to call: a tile's residuals, table indices, alphabet indices and
rANS words (14 bytes a pixel in all).

A fresh megapixel int32 array is ~1000 pages, and glibc's allocator often gives such a block back to the kernel when
it is freed (``metraw.allocator`` explains when), so the next call's array is faulted in page by page, each page zeroed
by the kernel at its first write. Measured (2026-11-29, 2-core Intel Xeon VM, the AVX2 loops, canon_dng's calls
interleaved with the other frames' and JPEG-LS's as ``benchmarks/codec.py --speed`` runs them): a 1-thread encode
faulted ~5600 pages, 12 ms of system time beside its ~46 ms of user time; ~2600 pages and 6.5 ms on 2 threads. The
``metraw`` commands tune the allocator for the whole process (``metraw.allocator.tune``); a program that imports the
codec keeps its own allocator settings, and these arrays spare it the faults all the same.

Memory: each thread keeps the largest array it was asked for under each name, so at most 14 bytes a pixel of the
largest row tile it coded (``metraw.codec.TILE_PIXELS``: ~35 MB) until the thread ends or calls ``release()``. The
values are those of fresh ``np.empty`` arrays: the encoder writes every element it reads.
"""

from __future__ import annotations

import threading

import numpy as np

_LOCAL = threading.local()


def empty(name: str, n: int, dtype) -> np.ndarray:
    """An uninitialised 1-D array of ``n`` elements of ``dtype``: the calling thread's buffer ``name`` (grown when too
    small), valid until this thread asks for ``name`` again or calls ``release()``."""
    dtype = np.dtype(dtype)
    buffers = _LOCAL.__dict__.setdefault("buffers", {})
    nbytes = n * dtype.itemsize
    buf = buffers.get(name)
    if buf is None or buf.size < nbytes:
        buf = buffers[name] = np.empty(max(nbytes, 64), np.uint8)
    return buf[:nbytes].view(dtype)


def release() -> None:
    """Drop the calling thread's buffers (their memory goes back to the allocator)."""
    _LOCAL.__dict__.pop("buffers", None)
