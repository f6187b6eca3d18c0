"""Bad option values that a command only reads deep inside (after opening its inputs)."""

from __future__ import annotations

from . import _inputs as make
from ._check import refused


def test_text_accuracy_emulate(tmp_path, store):
    refused(["emulate", "s.zarr", "out.zarr", "--params", str(make.REPO / "params.yaml"), "--accuracy",
             "kernel_flux_loss=tiny"], "--accuracy: could not convert string to float", tmp_path)


def test_negative_limit_compress(tmp_path, store):
    refused(["compress", "s.zarr", "--out", "c.json", "--limit", "-1"], "--limit must be >= 1", tmp_path)
