"""Toy car scenes (flat background + dark/bright rectangles) for tests and benchmarks.

Not a scene model: ``metraw.scenes`` generates the real synthetic drone scenes. These images
only give the segmenter a known, exact mask to learn, with the camera's true noise model.
"""

from __future__ import annotations

import numpy as np

from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed


def toy_profile(pattern: str = "RGGB") -> CalibrationProfile:
    """A 12-bit camera: K = 0.25 DN/e-, black 256 DN, 3 e- read noise, 15000 e- full well."""
    return CalibrationProfile(gain_dn_per_e=0.25, black_level_dn=256, read_noise_e=3.0, white_level_dn=4095,
                              adc_bits=12, cfa_pattern=pattern, full_well_e=15000.0)


def toy_scene(size_px: int, rng: np.random.Generator | int, profile: CalibrationProfile | None = None,
              background_e: float = 400.0, contrast: float = 0.5, n_cars: int = 6, car_px: tuple[int, int] = (10, 20)
              ) -> RawImage:
    """One exposed toy scene with ``n_cars`` axis-aligned rectangles (exact 0/1 mask).

    Cars are ``car_px`` = (width, length) pixels, randomly oriented, each brighter or darker
    than the textured background by ``contrast`` (relative). Mean signal ``background_e``.
    """
    rng = rng_from_seed(rng)
    profile = profile or toy_profile()
    yy, xx = np.mgrid[0:size_px, 0:size_px] / size_px
    phase = rng.uniform(0, 2 * np.pi, 2)
    mean = background_e * (1.0 + 0.2 * np.sin(2 * np.pi * 2 * xx + phase[0]) * np.sin(2 * np.pi * 3 * yy + phase[1]))
    mask = np.zeros((size_px, size_px), np.float32)
    for _ in range(n_cars):
        a, b = car_px if rng.random() < 0.5 else car_px[::-1]
        y0 = int(rng.integers(0, size_px - a))
        x0 = int(rng.integers(0, size_px - b))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        mean[y0:y0 + a, x0:x0 + b] = background_e * (1.0 + sign * contrast)
        mask[y0:y0 + a, x0:x0 + b] = 1.0
    data = expose(mean, profile, rng)
    return RawImage(data=data, profile=profile, mask=mask, meta={"scene": "toy"})


def toy_store(path, n_images: int, size_px: int, seed: int = 0, **kwargs) -> None:
    """Write ``n_images`` toy scenes into a new RawStore at ``path``."""
    from metraw.io.store import RawStore

    rng = rng_from_seed(seed)
    with RawStore.create(path) as store:
        for _ in range(n_images):
            store.append(toy_scene(size_px, rng, **kwargs))
