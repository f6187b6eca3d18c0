"""Embedded source dataset: synthetic drone raws of urban, suburban and rural scenes with exact car masks.

``generate(n, seed)`` yields ``RawImage`` objects as the source camera (Hasselblad L1D-20c on a
DJI Mavic 2 Pro at 250 m, GSD ~5.9 cm, ``scene_camera()``) would record them: geometry in
``layout``, daylight radiometry in ``radiance``, rendering and sensor in ``render``.
Scene ``i`` of seed ``s`` depends only on (s, i) (``numpy.random.SeedSequence(s, spawn_key=(i,))``),
so any subset can be regenerated in any order, in any number of processes, bit for bit.
"""

from __future__ import annotations

from typing import Iterator, Sequence

import numpy as np

from metraw.errors import MetrawError
from metraw.parallel import ordered_map
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import rng_from_seed
from metraw.scenes.layout import KINDS, make_scene
from metraw.scenes.render import RenderSettings, render

__all__ = ["KINDS", "RenderSettings", "generate", "generate_one", "scene_camera", "scene_seeds"]


def scene_camera() -> CalibrationProfile:
    """The camera the synthetic scenes are rendered for: the source camera of docs/emulation.md (the numbers of
    ``source.camera`` in params.yaml, which ``metraw.io.default_camera`` reads; tests/test_scenes.py keeps them equal).

    Hasselblad L1D-20c: 1" sensor, 2.41 um pitch, f = 10.26 mm at f/2.8 (D = 3.664 mm), 250 m
    altitude; 12-bit ADC, K = 0.25 DN/e-, black 256 DN, read noise 3 e-, full well 15000 e-;
    exposure 1 ms is the longest the auto-exposure may choose.
    """
    return CalibrationProfile(
        gain_dn_per_e=0.25, black_level_dn=256, read_noise_e=3.0, white_level_dn=4095, adc_bits=12,
        cfa_pattern="RGGB", full_well_e=15000.0, dark_current_e_per_s=1.0,
        qe_per_channel={"R": 0.45, "G": 0.55, "B": 0.40},
        pixel_pitch_m=2.41e-6, focal_length_m=10.26e-3, aperture_diameter_m=3.664e-3, obscuration_ratio=0.0,
        altitude_m=250.0, exposure_s=1.0e-3, ground_speed_m_per_s=0.0, optical_transmission=0.9,
        camera="Hasselblad L1D-20c (DJI Mavic 2 Pro)")


def scene_seeds(seed: int, index: int) -> tuple[int, int]:
    """(layout seed, rendering/noise seed) of scene ``index`` for dataset ``seed``."""
    if seed < 0 or index < 0:
        raise MetrawError(f"seed and index must be >= 0, got {seed} and {index}")
    ss = np.random.SeedSequence(int(seed), spawn_key=(int(index),))
    a, b = ss.generate_state(2, dtype=np.uint64)
    return int(a), int(b)


def generate_one(index: int, seed: int, size_px: int = 1024, camera: CalibrationProfile | None = None,
                 kinds: Sequence[str] = KINDS, settings: RenderSettings = RenderSettings(),
                 return_expected: bool = False):
    """Scene ``index`` of the dataset ``seed`` (kind ``kinds[index % len(kinds)]``)."""
    camera = camera or scene_camera()
    if camera.gsd_m is None:
        raise MetrawError("the source camera profile needs pixel_pitch_m, altitude_m and focal_length_m (GSD)")
    if size_px < 16 or size_px % 2:
        raise MetrawError(f"size_px must be an even number >= 16, got {size_px}")
    kinds = tuple(kinds)
    kind = kinds[index % len(kinds)]
    layout_seed, render_seed = scene_seeds(seed, index)
    scene = make_scene(kind, rng_from_seed(layout_seed), size_px * camera.gsd_m)
    img, mean_e = render(scene, camera, size_px, rng_from_seed(render_seed), settings)
    img.meta.update({"index": int(index), "seed": int(seed)})
    img.provenance[0]["params"].update({"seed": int(seed), "index": int(index), "kind": kind})
    return (img, mean_e) if return_expected else img


def _worker(args):
    return generate_one(*args)


def generate(n: int, seed: int, size_px: int = 1024, camera: CalibrationProfile | None = None,
             kinds: Sequence[str] = KINDS, workers: int = 1, settings: RenderSettings = RenderSettings(),
             start: int = 0) -> Iterator[RawImage]:
    """Yield ``n`` scenes (indices ``start .. start+n-1``) in order; ``workers`` > 1 uses processes.

    The bytes do not depend on ``workers``: every scene has its own seed.
    """
    if n < 0:
        raise MetrawError(f"n must be >= 0, got {n}")
    kinds = tuple(kinds)
    bad = [k for k in kinds if k not in KINDS]
    if not kinds or bad:
        raise MetrawError(f"kinds must be a non-empty subset of {', '.join(KINDS)}; got {', '.join(kinds) or 'none'}")
    jobs = [(start + i, seed, size_px, camera, kinds, settings) for i in range(n)]
    yield from ordered_map(_worker, jobs, workers)
