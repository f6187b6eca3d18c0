"""A team's raw folder made at test time from real file formats: DNG camera raws (the tags LibRaw needs: CFA
pattern, black and white level, exposure time), a car mask PNG per raw, and flat and dark series of a known gain
and read noise (``make_raw_folder``). ``write_dng`` writes one mosaic as a DNG that rawpy/LibRaw reads back
exactly."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

#: The camera the folder's files are made with: gain and read noise are what the calibration must recover.
TRUE_GAIN_DN_PER_E = 0.5
TRUE_READ_NOISE_E = 4.0
BLACK_LEVEL_DN = 128
WHITE_LEVEL_DN = 4095
EXPOSURE_S = 1.0e-3
#: Flat levels [e-] (up to ~60 % of the (4095 - 128) / 0.5 = 7934 e- the ADC reaches), 2 frames each.
FLAT_LEVELS_E = (300.0, 1000.0, 2000.0, 3200.0, 4600.0)

_CFA_CODES = {"R": 0, "G": 1, "B": 2}


def write_dng(path: Path, data: np.ndarray, pattern: str = "RGGB", black_level_dn: int = BLACK_LEVEL_DN,
              white_level_dn: int = WHITE_LEVEL_DN, exposure_s: float = EXPOSURE_S) -> Path:
    """One Bayer mosaic (uint16 DN) as an uncompressed DNG 1.4 (CFA photometric interpretation)."""
    import tifffile

    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, "metraw test camera", True),  # UniqueCameraModel
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, tuple(_CFA_CODES[c] for c in pattern), True),  # CFAPattern
        (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (1, 1), True),  # BlackLevelRepeatDim
        (50714, "I", 1, int(black_level_dn), True),  # BlackLevel
        (50717, "I", 1, int(white_level_dn), True),  # WhiteLevel
        (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),  # ColorMatrix1: identity
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1: D65
        (271, "s", 0, "metraw", True),  # Make
        (272, "s", 0, "test camera", True),  # Model
        (33434, "2I", 1, (int(round(exposure_s * 1e6)), 1_000_000), True),  # ExposureTime [s]
    ]
    tifffile.imwrite(path, np.asarray(data, np.uint16), photometric=32803, compression=None, subfiletype=0,
                     extratags=tags, metadata=None)
    return path


def true_camera():
    """The source camera of params.yaml with the folder's gain, read noise, black and white level."""
    from metraw.io import default_camera

    return dataclasses.replace(default_camera(Path(__file__).resolve().parents[1] / "params.yaml"),
                               gain_dn_per_e=TRUE_GAIN_DN_PER_E, read_noise_e=TRUE_READ_NOISE_E,
                               black_level_dn=float(BLACK_LEVEL_DN), white_level_dn=float(WHITE_LEVEL_DN),
                               adc_bits=12, dark_current_e_per_s=0.0, exposure_s=EXPOSURE_S)


def make_raw_folder(folder: Path, n_images: int = 4, size_px: int = 160, flat_px: int = 96, seed: int = 0) -> Path:
    """``folder`` with ``n_images`` synthetic drone scenes as DNG + ``STEM_mask.png`` (car area fraction x 255; the
    generator's scenes in order, those with cars on less than 1 % of their area skipped),
    ``flats/`` (``FLAT_LEVELS_E`` x 2 frames) and ``darks/`` (2 frames), all of ``true_camera()``."""
    from PIL import Image

    from metraw.raw.sensor import expose, rng_from_seed
    from metraw.scenes import generate_one

    camera = true_camera()
    folder.mkdir(parents=True, exist_ok=True)
    i, scene_index = 0, 0
    while i < n_images:
        scene = generate_one(scene_index, seed, size_px, camera=camera)
        scene_index += 1
        mask8 = np.round(np.clip(scene.mask, 0, 1) * 255).astype(np.uint8)
        if mask8.mean() < 0.01 * 255:
            continue  # a small scene without a car (or a sliver of one at its edge, which the emulation may lose)
        write_dng(folder / f"IMG_{i:04d}.dng", scene.data, camera.cfa_pattern)
        Image.fromarray(mask8).save(folder / f"IMG_{i:04d}_mask.png")
        i += 1
    rng = rng_from_seed(seed + 1000)
    for sub, levels in (("flats", [e for e in FLAT_LEVELS_E for _ in range(2)]), ("darks", [0.0, 0.0])):
        (folder / sub).mkdir(exist_ok=True)
        for j, level_e in enumerate(levels):
            frame = expose(np.full((flat_px, flat_px), level_e), camera, rng)
            write_dng(folder / sub / f"{sub[:-1]}_{j:02d}.dng", frame, camera.cfa_pattern)
    return folder
