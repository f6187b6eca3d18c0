"""Calibration profiles with missing or absurd fields, wherever a command takes one: ``check`` /
``normalise --profile``, ``encode`` / ``verify --profile``, ``ingest`` / ``scenes --camera`` (JSON or a
params.yaml with source.camera)."""

from __future__ import annotations

import pytest

from . import _inputs as make
from ._check import refused


#: case -> (changes to the profile in p.json, None removing a field; the command; the word of the refusal;
#: run in process, for the codec commands)
CASES = {
    "negative_gain_check": (dict(gain_dn_per_e=-1.0), ["check", "a.tif", "--spec", "spec.yaml", "--profile", "p.json",
                                                       "--json", "d.json"], "gain_dn_per_e must be > 0", False),
    "zero_read_noise_encode": (dict(read_noise_e=0.0), ["encode", "a.tif", "out.mraw", "--profile", "p.json"],
                               "read_noise_e is 0", True),
    "white_below_black_ingest_camera": (dict(white_level_dn=50.0), ["ingest", "a.tif", "--camera", "p.json", "--out",
                                                                    "s.zarr"], "black_level_dn < white_level_dn", False),
    "missing_gain_verify": (dict(gain_dn_per_e=None), ["verify", "a.tif", "--profile", "p.json"],
                            "lacks required field(s): gain_dn_per_e", True),
    "text_gain_scenes_camera": (dict(gain_dn_per_e="high"), ["scenes", "--n", "1", "--size", "16", "--camera", "p.json",
                                                             "--out", "s.zarr"], "gain_dn_per_e must be a number", False),
    "unknown_cfa_encode": (dict(cfa_pattern="RGBW"), ["encode", "a.tif", "out.mraw", "--profile", "p.json"],
                           "CFA pattern 'RGBW'", True),
    "unknown_field_ingest_camera": (dict(gain=0.5), ["ingest", "a.tif", "--camera", "p.json", "--out", "s.zarr"],
                                    "unknown fields: gain", False),
}


@pytest.mark.parametrize("case", list(CASES))
def test_profile(tmp_path, case):
    changes, argv, word, inprocess = CASES[case]
    make.metraw_tiff(tmp_path / "a.tif")
    make.spec(tmp_path / "spec.yaml")
    make.profile_json(tmp_path / "p.json", **changes)
    refused(argv, word, tmp_path, inprocess=inprocess)


def test_profile_not_json_normalise(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    make.spec(tmp_path / "spec.yaml")
    (tmp_path / "p.json").write_text("gain_dn_per_e: 0.5\n")
    refused(["normalise", "a.tif", "out.tif", "--spec", "spec.yaml", "--profile", "p.json"], "not valid JSON",
            tmp_path)


def test_partial_profile_negative_exposure_check(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    make.spec(tmp_path / "spec.yaml")
    (tmp_path / "p.json").write_text('{"exposure_s": -0.001}')
    refused(["check", "a.tif", "--spec", "spec.yaml", "--profile", "p.json"], "exposure_s must be > 0", tmp_path)


def test_missing_profile_file_encode(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    refused(["encode", "a.tif", "out.mraw", "--profile", "none.json"], "cannot read profile none.json", tmp_path,
            inprocess=True)


def test_params_camera_zero_read_noise_scenes(tmp_path):
    make.params(tmp_path / "params.yaml", ("source.camera.read_noise_e", 0.0))
    refused(["scenes", "--n", "1", "--size", "16", "--camera", "params.yaml", "--out", "s.zarr"],
            "source.camera: profile read_noise_e is 0", tmp_path)
