"""metraw.allocator: glibc keeps freed large arrays for reuse instead of faulting them in afresh."""

import os
import platform
import subprocess
import sys
import textwrap

import pytest

from metraw import allocator

glibc_only = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's allocator only")

# a training step's pattern: a working set of 12 arrays of 16 MiB (192 MiB), written, then all freed; 4 rounds
PROBE = textwrap.dedent("""
    import resource, sys
    import numpy as np
    if sys.argv[1] == "tuned":
        from metraw import allocator
        assert allocator.tune()
    faults = []
    for _ in range(4):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        arrays = [np.ones(4 * 2**20, np.float32) for _ in range(12)]
        del arrays
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    print(" ".join(map(str, faults)))
""")


def _page_faults_per_round(mode: str) -> list[int]:
    env = {k: v for k, v in os.environ.items() if k not in allocator._USER_SETTINGS}
    out = subprocess.run([sys.executable, "-c", PROBE, mode], env=env, capture_output=True, text=True, check=True)
    return [int(v) for v in out.stdout.split()]


@glibc_only
def test_tuned_allocator_reuses_a_freed_working_set_without_page_faults():
    plain, tuned = _page_faults_per_round("plain"), _page_faults_per_round("tuned")
    # the first round faults its pages in either way (192 MiB = 49152 pages of 4 KiB; fewer with huge pages)
    assert tuned[0] > 1000 and plain[0] > 1000, (plain, tuned)
    # then glibc's defaults give part of the freed heap back and fault it in again every round; tuned, it is reused
    assert min(plain[1:]) > 1000, plain
    assert max(tuned[1:]) < 100, tuned


def test_tune_leaves_an_allocator_set_by_the_environment_alone():
    for name in allocator._USER_SETTINGS:
        assert allocator.tune({name: "1"}) is False
