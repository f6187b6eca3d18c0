"""Synthetic calibration targets with known truth: flat/dark series and a natural-looking scene.

Expected photoelectron maps [e-] for ``metraw.raw.sensor.expose``; used by the calibration tests
and benchmark to check that ``metraw.calibrate`` recovers a known gain and read noise.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed


def flat_series(profile: CalibrationProfile, shape: tuple[int, int], levels_e: Sequence[float],
                frames_per_level: int = 2, seed: int = 0, prnu: float = 0.0,
                ) -> tuple[list[list[np.ndarray]], list[np.ndarray]]:
    """Flat frames at each mean level [e-] (``frames_per_level`` each) and as many dark frames.

    ``prnu``: relative pixel gain non-uniformity (fixed pattern, the same in every frame),
    which a photon-transfer measurement must cancel.
    """
    rng = rng_from_seed(seed)
    gain_map = 1.0 + prnu * rng.standard_normal(shape) if prnu > 0 else np.ones(shape)
    flats = [[expose(np.full(shape, lv) * gain_map, profile, rng) for _ in range(frames_per_level)]
             for lv in levels_e]
    darks = [expose(np.zeros(shape), profile, rng) for _ in range(frames_per_level)]
    return flats, darks


def natural_scene_e(shape: tuple[int, int], max_e: float, seed: int = 0, texture: bool = True,
                    min_fraction: float = 0.005) -> np.ndarray:
    """Expected photoelectrons of a scene with smooth gradients, sharp edges and textured patches.

    Values span ``min_fraction * max_e`` .. ``max_e``: a smooth 2-D background (ramps and slow
    waves), rectangles and discs with sharp edges at other levels, and (``texture``) patches
    of fine multiplicative texture (+-40 %, one to a few pixels in scale).
    """
    rng = rng_from_seed(seed)
    h, w = shape
    y = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None]
    x = np.linspace(0.0, 1.0, w, dtype=np.float32)[None, :]
    base = 0.5 * x + 0.3 * y + 0.2 * (0.5 + 0.5 * np.sin(2 * np.pi * (1.3 * x + 0.7 * y)))
    scene = (min_fraction + (1 - min_fraction) * base ** 3).astype(np.float32)
    for _ in range(16):  # flat patches with sharp edges (rectangles and discs)
        level = np.float32(np.exp(rng.uniform(np.log(min_fraction), 0.0)))  # dark patches too
        cy, cx = rng.uniform(0, 1, 2)
        ry, rx = rng.uniform(0.03, 0.12, 2)
        if rng.uniform() < 0.5:
            inside = (np.abs(y - cy) < ry) & (np.abs(x - cx) < rx)
        else:
            inside = ((y - cy) / ry) ** 2 + ((x - cx) / rx) ** 2 < 1
        scene = np.where(inside, level, scene)
    if texture:
        for _ in range(6):
            cy, cx = rng.integers(0, h), rng.integers(0, w)
            sy, sx = int(rng.integers(h // 24, h // 10)), int(rng.integers(w // 24, w // 10))
            y0, x0 = max(cy - sy, 0), max(cx - sx, 0)
            patch = scene[y0:cy + sy, x0:cx + sx]
            tex = rng.standard_normal(patch.shape).astype(np.float32)
            tex = 0.5 * (tex + np.roll(tex, 1, axis=int(rng.integers(0, 2))))  # 1-2 pixel grain
            patch *= np.clip(1.0 + 0.4 * tex, 0.05, 2.0)
    return np.clip(scene, 0, 1.2) * np.float32(max_e)
