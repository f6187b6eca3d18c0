"""glibc's memory allocator set for metraw's large, short-lived arrays (process-wide, values unchanged).

glibc's malloc serves a block of at least M_MMAP_THRESHOLD bytes (128 KiB at start, raised as such blocks are
freed, up to 32 MiB) with a fresh mmap and unmaps it on free(); it also gives the free memory at the top of the
heap back to the kernel beyond M_TRIM_THRESHOLD. Setting either by hand fixes both (the dynamic raise stops).
metraw's commands allocate and free the same few-MB arrays thousands of times (training activations, scene
planes, expected fields), and each block the kernel got back is faulted in (zeroed) page by page on its next
allocation. Measured (2026-11-27, one torch thread, bfloat16): a drone-resolution training step (batch 8 of
4 x 256 x 256) faulted ~6800 pages, 10-14 ms of system time beside ~108 ms of user time; with the mmap threshold
at 32 MiB and the trim threshold at 256 MiB, ~0 faults and ~0 system time, the same user time. Setting only the
trim threshold is worse (the mmap threshold then stays at 128 KiB: 74 ms of system time a step).

Only where metraw's process is in charge: ``tune()`` does nothing where the environment sets glibc's allocator
(``MALLOC_*_`` variables, ``GLIBC_TUNABLES``) or the C library is not glibc. The arithmetic does not change;
a process keeps up to ``TRIM_THRESHOLD_BYTES`` of freed memory for reuse.
"""

from __future__ import annotations

import ctypes
import os
import platform

#: Blocks at least this large still get their own mmap (and go back to the kernel when freed) [bytes].
MMAP_THRESHOLD_BYTES = 32 * 2**20
#: Free memory at the top of the heap kept for reuse, at most [bytes].
TRIM_THRESHOLD_BYTES = 256 * 2**20

_M_TRIM_THRESHOLD = -1  # mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_",
                  "GLIBC_TUNABLES")


def tune(environ=os.environ) -> bool:
    """Set glibc's mmap and trim thresholds to the module's values; True where they were set, False where the
    environment sets the allocator itself or the C library is not glibc (nothing changed)."""
    if any(name in environ for name in _USER_SETTINGS) or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD,
                                                                                       TRIM_THRESHOLD_BYTES))
