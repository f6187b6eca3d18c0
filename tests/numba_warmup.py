"""Fill numba's on-disk caches before a parallel test run (tests/conftest.py runs each group in its own process).

On a fresh clone nothing is compiled: every pytest-xdist worker, and every workflow job the workflow tests start,
would compile the same functions at the same time (the codec's 45-55 s of compiling, the scene renderer's and the
emulator's ~11 s, on the 2-core Intel VM), each in its own process. Compiled once here, in two processes side by
side, they are read from the cache (``cache=True``; ``__pycache__`` next to the sources) by all the others. The
inputs are tiny synthetic images of the kinds the tests use (Bayer and mono, faint and bright, steps 0.5 / 1 / 2,
tiles with and without lanes), so that the functions compile for the argument types the tests pass. Nothing here
asserts: the tests check the results.

Run: python tests/numba_warmup.py codec|emulation
"""

from __future__ import annotations

import sys

import numpy as np


def codec() -> None:
    from metraw import codec as mcodec
    from metraw.codec import prepare
    from metraw.raw.image import RawImage
    from metraw.raw.profile import CalibrationProfile
    from metraw.raw.sensor import expose, rng_from_seed

    prepare.dither(0, 0, 16)
    for pattern in ("RGGB", "mono"):
        prof = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100, read_noise_e=3, white_level_dn=16000,
                                  adc_bits=14, cfa_pattern=pattern)
        for electrons in (40.0, 20000.0):
            for side in (64, 600):   # one shared model; 8-lane tiles (>= 2^16 pixels a plane)
                yy, xx = np.mgrid[0:side, 0:side]
                mean = electrons * (0.6 + 0.4 * np.sin(xx / 9.0) * np.cos(yy / 7.0))
                img = RawImage(expose(mean, prof, rng_from_seed(side)), prof)
                for step in (0.5, 1.0, 2.0):
                    mcodec.decode(mcodec.encode(img, step=step, check_profile=False, account={}))
        # the table and context variants of real frames: rare large residuals (16-bit tables), steep but
        # predictable texture (the activity context by compares), random high contrast (both)
        rng = np.random.default_rng(0)
        yy, xx = np.mgrid[0:600, 0:600]
        spiky = expose(np.full((600, 600), 2000.0), prof, rng_from_seed(1))
        spiky[rng.random(spiky.shape) < 0.01] = 15000
        steep = expose(8000 + 7000 * np.sin(xx / 2.0) * np.sin(yy / 2.5), prof, rng_from_seed(2))
        for data in (spiky, steep, rng.integers(100, 16000, (600, 600)).astype(np.uint16)):
            mcodec.decode(mcodec.encode(RawImage(data, prof), step=0.5, check_profile=False))


def emulation() -> None:
    from pathlib import Path

    from metraw.emulate.emulator import emulate
    from metraw.emulate.target import TargetSystem
    from metraw.scenes import generate_one

    target = TargetSystem.from_params(str(Path(__file__).resolve().parents[1] / "params.yaml"))
    for size in (96, 160):
        scene = generate_one(0, 0, size)
        for mode in ("auto", "photon", "expected"):
            emulate(scene, target, mode, 0)


GROUPS = {"codec": codec, "emulation": emulation}


if __name__ == "__main__":
    if len(sys.argv) != 2 or sys.argv[1] not in GROUPS:
        sys.exit(f"usage: python {sys.argv[0]} {'|'.join(GROUPS)}")
    GROUPS[sys.argv[1]]()
