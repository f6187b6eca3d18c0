"""A team's raw folder gone wrong (params.yaml ``source.dataset: raws``; README "Your own data"): a raw without
its mask, a mask of the wrong size, mixed CFA patterns or bit depths in one folder, an empty folder, flats that
saturate, darks with another exposure than the flats, geometry missing. Each is one line naming the file (or
the key), exit status 2, nothing written; the files are DNGs LibRaw reads (``tests/raw_folder.py``)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from raw_folder import EXPOSURE_S, WHITE_LEVEL_DN, write_dng

from . import _inputs as make
from ._check import refused

SHAPE = (48, 64)


def _raw(folder: Path, name: str, pattern: str = "RGGB", mask_shape=SHAPE, white: int = WHITE_LEVEL_DN,
         level: float = 600.0, exposure_s: float = EXPOSURE_S) -> Path:
    """One DNG of ``SHAPE`` (Poisson around ``level`` DN) and, unless ``mask_shape`` is None, its mask PNG."""
    folder.mkdir(parents=True, exist_ok=True)
    data = np.random.default_rng(len(name)).poisson(level, SHAPE).clip(0, white)
    path = write_dng(folder / f"{name}.dng", data, pattern, white_level_dn=white, exposure_s=exposure_s)
    if mask_shape is not None:
        mask = np.zeros(mask_shape, np.uint8)
        mask[10:20, 10:30] = 255
        Image.fromarray(mask).save(folder / f"{name}_mask.png")
    return path


def _ingest(tmp_path: Path, word: str) -> str:
    return refused(["ingest", "raws", "--labels", "mask", "--out", "s.zarr"], word, tmp_path)


def test_a_raw_without_its_mask(tmp_path):
    _raw(tmp_path / "raws", "a")
    _raw(tmp_path / "raws", "b", mask_shape=None)
    assert "raws/b.dng" in _ingest(tmp_path, "no mask image b_mask.png")


def test_a_mask_of_the_wrong_size(tmp_path):
    _raw(tmp_path / "raws", "a", mask_shape=(SHAPE[0], SHAPE[1] - 2))
    assert "a_mask.png" in _ingest(tmp_path, f"differs from the image shape {SHAPE}")


def test_mixed_cfa_patterns_in_one_folder(tmp_path):
    _raw(tmp_path / "raws", "a", "RGGB")
    _raw(tmp_path / "raws", "b", "GRBG")
    assert "raws/b.dng" in _ingest(tmp_path, "CFA pattern GRBG differs from RGGB of a.dng")


def test_mixed_bit_depths_in_one_folder(tmp_path):
    _raw(tmp_path / "raws", "a", white=4095)
    _raw(tmp_path / "raws", "b", white=16383)
    assert "raws/b.dng" in _ingest(tmp_path, "14-bit data differ from the 12 bits of a.dng")


def test_an_empty_folder(tmp_path):
    (tmp_path / "raws").mkdir()
    _ingest(tmp_path, "raws: directory holds no supported image files")
    refused(["calibrate", "raws", "--out", "p.json"], "raws: directory holds no supported image files", tmp_path)


def _series(tmp_path: Path, flat_levels, dark_exposure_s: float = EXPOSURE_S) -> None:
    for j, level in enumerate(flat_levels):
        _raw(tmp_path / "flats", f"flat_{j:02d}", mask_shape=None, level=level)
    for j in range(2):
        _raw(tmp_path / "darks", f"dark_{j:02d}", mask_shape=None, level=130.0, exposure_s=dark_exposure_s)


def test_flats_that_saturate(tmp_path):
    # 3 levels x 2 frames, two of the levels at the white level: 1 usable level, the photon transfer needs 2
    _series(tmp_path, [500.0, 500.0, 5000.0, 5000.0, 9000.0, 9000.0])
    line = refused(["calibrate", "--flats", "flats", "--darks", "darks", "--out", "p.json"],
                   "flat frame saturates", tmp_path)
    assert "flats/flat_02.dng" in line and "has 1" in line


def test_darks_with_another_exposure_than_the_flats(tmp_path):
    _series(tmp_path, [300.0, 300.0, 900.0, 900.0], dark_exposure_s=2 * EXPOSURE_S)
    line = refused(["calibrate", "--flats", "flats", "--darks", "darks", "--out", "p.json"],
                   "dark frame exposed 0.002 s, the flats 0.001 s", tmp_path)
    assert "darks/dark_00.dng" in line


@pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake is needed")
@pytest.mark.parametrize("case, change, word", [
    ("geometry_missing", ("source.camera.focal_length_m", make.DELETE), "'focal_length_m' is a required property"),
    ("labels_not_a_choice", ("source.raws.labels", "boxes"), "source/raws/labels"),
    ("folder_missing", ("source.raws.path", "no_such_raws"), "no_such_raws: source.raws.path folder does not exist"),
])
def test_workflow_refuses_a_bad_raws_source(tmp_path, case, change, word):
    params_file = make.params(tmp_path / "params.yaml", ("source.dataset", "raws"),
                              ("source.raws.path", "raws"), change)
    workspace = make.workflow(tmp_path / "workspace", params_file)
    params_file.unlink()
    _raw(workspace / "raws", "a")
    cache = tmp_path / "cache"  # the profile turns Snakemake's output cache on: keep its folder outside the copy
    cache.mkdir()
    env = {**os.environ, "SNAKEMAKE_OUTPUT_CACHE": str(cache)}
    refused(["--cores", "1", "-n"], word, workspace, env=env, snakemake=True)
