"""Small inputs made at test time (nothing binary is committed): raw TIFFs, DNG-like TIFFs, profiles,
params.yaml variants, specs and copies of the workflow."""

from __future__ import annotations

import copy
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import yaml

from metraw.io import write_tiff
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.spec.builder import Limit, Specification

REPO = Path(__file__).resolve().parents[2]

#: A satellite-like camera with every field stated (the profile the profile cases break one field of).
PROFILE = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=64, read_noise_e=3.0, white_level_dn=4095, adc_bits=12,
                             cfa_pattern="RGGB", full_well_e=10000.0, pixel_pitch_m=2.4e-6, focal_length_m=1.644,
                             aperture_diameter_m=0.2, altitude_m=600e3, exposure_s=180e-6,
                             ground_speed_m_per_s=6900.0)


def ramp(shape=(64, 64), seed=0) -> np.ndarray:
    """A noisy brightness ramp in DN of `PROFILE` (what a usable frame looks like)."""
    h, w = shape
    electrons = np.random.default_rng(seed).poisson(50 + 3000 * np.mgrid[0:h, 0:w][1] / w)
    return (PROFILE.black_level_dn + PROFILE.gain_dn_per_e * electrons).astype(np.uint16)


def metraw_tiff(path: Path, data: np.ndarray | None = None, profile: CalibrationProfile = PROFILE) -> Path:
    """A metraw raw TIFF (pixels + profile), ``data`` default `ramp`."""
    return write_tiff(path, RawImage(np.asarray(ramp() if data is None else data, np.uint16), profile))


def plain_tiff(path: Path, data: np.ndarray) -> Path:
    """A bare single-band TIFF of ``data`` as it is (any dtype)."""
    tifffile.imwrite(path, data, metadata=None)
    return path


def dng(path: Path, cfa_codes=(0, 1, 1, 2), plane_colours=(0, 1, 2), shape=(64, 96)) -> Path:
    """A minimal DNG LibRaw reads: one CFA page with DNGVersion, CFARepeatPatternDim, CFAPattern
    (colour codes 0 R, 1 G, 2 B, 3 C, 4 M, 5 Y) and CFAPlaneColor tags."""
    data = np.random.default_rng(1).integers(0, 4000, shape).astype(np.uint16)
    tags = [(50706, "B", 4, (1, 4, 0, 0)), (33421, "H", 2, (2, 2)), (33422, "B", 4, tuple(cfa_codes)),
            (50710, "B", len(plane_colours), tuple(plane_colours))]
    tifffile.imwrite(path, data, photometric=32803, extratags=tags, metadata=None)
    return path


def truncate(path: Path, keep: float = 0.5) -> Path:
    """Cut ``path`` to the first ``keep`` of its bytes, in place."""
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


def profile_json(path: Path, base: dict[str, Any] | None = None, **changes: Any) -> Path:
    """A profile JSON: `PROFILE` (or ``base``) with fields changed; a change to ``None`` removes the field."""
    data = dict(PROFILE.to_dict() if base is None else base)
    for key, value in changes.items():
        if value is None:
            data.pop(key, None)
        else:
            data[key] = value
    path.write_text(json.dumps(data))
    return path


DELETE = object()


def params(path: Path, *changes: tuple[str, Any]) -> Path:
    """The repository's params.yaml with ``(dotted.key, value)`` changes (value `DELETE` removes the key)."""
    p = copy.deepcopy(yaml.safe_load((REPO / "params.yaml").read_text()))
    for dotted, value in changes:
        *parents, last = dotted.split(".")
        node = p
        for key in parents:
            node = node[key]
        if value is DELETE:
            del node[last]
        else:
            node[last] = value
    path.write_text(yaml.safe_dump(p, sort_keys=False))
    return path


def spec(path: Path) -> Path:
    """A valid specification (the spec a check case needs when the problem is elsewhere)."""
    props = {"gsd_m": Limit(0.9, 0.8, 1.0, "m", {"better": "lower"}),
             "signal_e": Limit(150.0, 60.0, 400.0, "e-", {"better": "higher"})}
    Specification(0.6, {"focal_length_m": Limit(1.6, 1.44, 1.8, "m")}, props, {"cfa_pattern": "RGGB"}).save(path)
    return path


def workflow(root: Path, params_file: Path) -> Path:
    """A copy of the workflow in ``root``: Snakefile, workflow/, the ``profiles`` link and ``params_file``."""
    root.mkdir(parents=True)
    shutil.copy2(REPO / "Snakefile", root / "Snakefile")
    shutil.copytree(REPO / "workflow", root / "workflow", ignore=shutil.ignore_patterns("__pycache__"))
    os.symlink(os.readlink(REPO / "profiles"), root / "profiles")
    shutil.copy2(params_file, root / "params.yaml")
    return root
