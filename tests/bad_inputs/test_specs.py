"""Files given as ``--spec`` that are not a specification (``metraw check``, ``metraw normalise``)."""

from __future__ import annotations

import yaml

from . import _inputs as make
from ._check import refused


def _spec(tmp_path, change=None) -> str:
    """A valid spec.yaml, edited by ``change(dict)``."""
    path = make.spec(tmp_path / "spec.yaml")
    if change:
        data = yaml.safe_load(path.read_text())
        change(data)
        path.write_text(yaml.safe_dump(data))
    make.metraw_tiff(tmp_path / "a.tif")
    return "spec.yaml"


def test_params_file_as_spec_check(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    make.params(tmp_path / "params.yaml")
    refused(["check", "a.tif", "--spec", "params.yaml", "--json", "d.json"], "not a metraw spec", tmp_path)


def test_not_yaml_normalise(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    (tmp_path / "spec.yaml").write_text("spec_version: 1\nparameters: {gsd_m: [1, 2\n")
    refused(["normalise", "a.tif", "out.tif", "--spec", "spec.yaml"], "not valid YAML", tmp_path)


def test_limit_without_max_check(tmp_path):
    spec = _spec(tmp_path, lambda d: d["image_properties"]["gsd_m"].pop("max"))
    refused(["check", "a.tif", "--spec", spec], "image_properties.gsd_m lacks 'max'", tmp_path)


def test_text_limit_normalise(tmp_path):
    spec = _spec(tmp_path, lambda d: d["image_properties"]["signal_e"].update(min="low"))
    refused(["normalise", "a.tif", "out.zarr", "--spec", spec], "min must be a number", tmp_path)


def test_min_above_max_check(tmp_path):
    spec = _spec(tmp_path, lambda d: d["image_properties"]["gsd_m"].update(min=2.0))
    refused(["check", "a.tif", "--spec", spec], "min 2.0 > max 1.0", tmp_path)


def test_unknown_image_property_normalise(tmp_path):
    spec = _spec(tmp_path, lambda d: d["image_properties"].update(gsd={"optimal": 1, "min": 0, "max": 2, "unit": "m"}))
    refused(["normalise", "a.tif", "out.tif", "--spec", spec], "unknown entries: gsd", tmp_path)


def test_directory_as_spec_check(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    (tmp_path / "results").mkdir()
    refused(["check", "a.tif", "--spec", "results"], "cannot read spec file results", tmp_path)
