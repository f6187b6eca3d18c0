"""Fixtures of the bad-input corpus: small stores and a codec blob, made once per session and copied
into each case's folder (a case may only break its own copy)."""

from __future__ import annotations

import contextlib
import io
import shutil

import pytest

from metraw.cli import main


def _scenes(folder, *extra):
    out = folder / "s.zarr"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["scenes", "--n", "5", "--size", "64", "--workers", "1", "--out", str(out), *extra]) == 0
    return out


@pytest.fixture(scope="session")
def _store_template(tmp_path_factory):
    return _scenes(tmp_path_factory.mktemp("store"))


@pytest.fixture(scope="session")
def _codec_store_template(tmp_path_factory):
    return _scenes(tmp_path_factory.mktemp("codec_store"), "--codec-step", "1")


@pytest.fixture
def store(tmp_path, _store_template):
    """A tiny metraw store (5 synthetic drone scenes of 64 px, lossless zstd) in the case's folder."""
    return shutil.copytree(_store_template, tmp_path / "s.zarr")


@pytest.fixture
def codec_store(tmp_path, _codec_store_template):
    """The same, its raw array stored with the noise-preserving codec (``--codec-step 1``)."""
    return shutil.copytree(_codec_store_template, tmp_path / "s.zarr")


@pytest.fixture(scope="session")
def model(tmp_path_factory, _store_template):
    """A segmenter trained for one epoch on the store (a narrow, shallow U-Net), for ``metraw evaluate``."""
    folder = tmp_path_factory.mktemp("model")
    (folder / "params.yaml").write_text("training: {profile: tiny, profiles: {tiny: {epochs: 1, batch_size: 4, "
                                        "crop_px: 16, base_channels: 4, depth: 2}}}\n")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["train", str(_store_template), "--out", str(folder / "model"), "--params",
                     str(folder / "params.yaml")]) == 0
    return folder / "model"


@pytest.fixture(scope="session")
def mraw_blob() -> bytes:
    """A valid .mraw blob (a 64 x 64 RGGB ramp, profile embedded)."""
    from metraw import codec
    from metraw.raw.image import RawImage

    from ._inputs import PROFILE, ramp

    blob = codec.encode(RawImage(ramp(), PROFILE), step=1.0, seed=0)
    assert codec.decode(blob).data.shape == (64, 64)  # the undamaged blob decodes: a refusal is the damage's
    return blob
