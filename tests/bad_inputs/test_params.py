"""params.yaml schema violations, through the commands that take ``--params`` (emulate, aggregate,
train) and through the workflow (``snakemake --cores 1 -n`` in a copy of it): non-positive focal
length, diameter and exposure, unknown keys, empty sweeps and sweep values that break the
constraint of the nominal field they replace."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

from . import _inputs as make
from ._check import refused

needs_snakemake = pytest.mark.skipif(not Path(sys.executable).with_name("snakemake").exists(),
                                     reason="snakemake is not installed next to this Python")

#: (case, change to params.yaml, word of the error line)
VIOLATIONS = {
    "focal_length_negative": (("target.nominal.focal_length_m", -1.0), "focal_length_m"),
    "diameter_zero": (("target.nominal.diameter_m", 0), "diameter_m"),
    "exposure_zero": (("target.nominal.exposure_s", 0.0), "exposure_s"),
    "unknown_nominal_key": (("target.nominal.focal_lenght_m", 1.2), "'focal_lenght_m' was unexpected"),
    "empty_sweep": (("target.sweeps.diameter_m", []), "target/sweeps/diameter_m: []"),
    "focal_sweep_value_negative": (("target.sweeps.focal_length_m", [0.8, -1]), "target/sweeps/focal_length_m/1"),
    "focal_sweep_value_zero": (("target.sweeps.focal_length_m", [0]), "target/sweeps/focal_length_m/0"),
    "exposure_sweep_value_zero": (("target.sweeps.exposure_s", [100e-6, 0.0]), "target/sweeps/exposure_s/1"),
    "sweep_of_unknown_field": (("target.sweeps.haze", [1.0]), "'haze' is not a field of target.nominal"),
    "sim_to_real_enabled_not_a_choice": (("sim_to_real.enabled", "yes"), "sim_to_real/enabled"),
    "sim_to_real_key_unknown": (("sim_to_real.gsd", 0.1), "'gsd' was unexpected"),
    # not a schema violation but the same refusal: the benchmark required and its real image folder missing
    "sim_to_real_required_folder_missing": (("sim_to_real", {"enabled": True, "path": "no_such_folder", "gsd_m": 0.135}),
                                            "'no_such_folder' does not exist"),
}


def _params(tmp_path, case):
    change, word = VIOLATIONS[case]
    return make.params(tmp_path / "params.yaml", change), word


# ----------------------------------------------------------------------------- through metraw commands
@pytest.mark.parametrize("case", ["focal_length_negative", "exposure_zero", "focal_sweep_value_negative",
                                  "unknown_nominal_key"])
def test_emulate(tmp_path, store, case):
    _, word = _params(tmp_path, case)
    refused(["emulate", "s.zarr", "out.zarr", "--params", "params.yaml", "--workers", "1"], word, tmp_path)


@pytest.mark.parametrize("case", ["diameter_zero", "empty_sweep", "exposure_sweep_value_zero"])
def test_aggregate(tmp_path, case):
    _, word = _params(tmp_path, case)
    (tmp_path / "results").mkdir()
    refused(["aggregate", "--params", "params.yaml", "--results", "results", "--out", "out"], word, tmp_path)


def test_train_unknown_training_key(tmp_path, store):
    make.params(tmp_path / "params.yaml", ("training.profiles.default.epoch", 3))
    refused(["train", "s.zarr", "--out", "model", "--params", "params.yaml"], "'epoch' was unexpected", tmp_path)


def test_train_partial_file_unknown_section(tmp_path, store):
    # metraw train reads only training:, but a misspelt top-level section is still an error
    (tmp_path / "params.yaml").write_text("trainnig: {profile: default}\n")
    refused(["train", "s.zarr", "--out", "model", "--params", "params.yaml"], "'trainnig' was unexpected", tmp_path)


# ----------------------------------------------------------------------------- through the workflow
@needs_snakemake
@pytest.mark.parametrize("case", list(VIOLATIONS))
def test_workflow_dry_run(tmp_path, case):
    params_file, word = _params(tmp_path, case)
    workspace = make.workflow(tmp_path / "workspace", params_file)
    params_file.unlink()
    cache = tmp_path / "cache"  # the profile turns Snakemake's output cache on: keep its folder outside the copy
    cache.mkdir()
    env = {**os.environ, "SNAKEMAKE_OUTPUT_CACHE": str(cache)}
    line = refused(["--cores", "1", "-n"], word, workspace, env=env, snakemake=True)
    assert "params.yaml" in line
    assert not list(cache.iterdir())
    shutil.rmtree(workspace)
