"""Bad networks (params.yaml ``training.model``, issue #68): each refused in one line naming the model and what is
wrong, exit status 2, nothing written, before any data is prepared (``metraw.segment.networks``)."""

from __future__ import annotations

import pytest
import yaml

from ._check import refused

from networks_helpers import smp_available


def _params(folder, model, profile=None):
    """A training-only params file in ``folder`` whose network is ``model``."""
    path = folder / "p.yaml"
    prof = {"epochs": 1, "batch_size": 4, "crop_px": 32, "replicates": 1, "threads": 1, **(profile or {})}
    path.write_text(yaml.safe_dump({"training": {"profile": "t", "model": model, "profiles": {"t": prof}}}))
    return path


def _factory(folder, body, name="net.py"):
    (folder / name).write_text(body)
    return {"kind": "python", "factory": f"{name}:build"}


def _train(tmp_path, model, word):
    _params(tmp_path, model)
    return refused(["train", "s.zarr", "--out", "m", "--params", "p.yaml"], word, tmp_path, inprocess=True)


def test_missing_factory_file(tmp_path, store):
    line = _train(tmp_path, {"kind": "python", "factory": "nowhere.py:build"}, "no file")
    assert "nowhere.py" in line


def test_missing_function(tmp_path, store):
    _train(tmp_path, _factory(tmp_path, "def make(i, o):\n    return None\n"), "defines no 'build'")


def test_import_error_inside_the_module(tmp_path, store):
    line = _train(tmp_path, _factory(tmp_path, "import no_such_package_xyz\n\ndef build(i, o):\n    pass\n"),
                  "importing it raised ModuleNotFoundError")
    assert "no_such_package_xyz" in line


def test_wrong_output_shape(tmp_path, store):
    body = "from torch import nn\n\ndef build(i, o):\n    return nn.Conv2d(i, 1, 3, padding=1)\n"
    _train(tmp_path, _factory(tmp_path, body), "returns logits of shape (2, 1, 32, 64)")


def test_nan_outputs(tmp_path, store):
    body = ("import torch\nfrom torch import nn\n\nclass Nan(nn.Conv2d):\n    def forward(self, x):\n"
            "        return super().forward(x) * float('nan')\n\ndef build(i, o):\n    return Nan(i, o, 1)\n")
    _train(tmp_path, _factory(tmp_path, body), "non-finite logits")


def test_build_raises(tmp_path, store):
    body = "def build(i, o, width=8):\n    raise ValueError('width must be even')\n"
    _train(tmp_path, _factory(tmp_path, body), "raised ValueError: width must be even")


def test_build_returns_no_module(tmp_path, store):
    _train(tmp_path, _factory(tmp_path, "def build(i, o):\n    return 'a model'\n"), "not a torch.nn.Module")


def test_forward_fails(tmp_path, store):
    body = "from torch import nn\n\ndef build(i, o):\n    return nn.Conv2d(i + 1, o, 1)\n"  # expects 5 planes
    _train(tmp_path, _factory(tmp_path, body), "its forward pass on a (2, 4, 32, 64) batch raised RuntimeError")


def test_unknown_kind(tmp_path, store):
    _train(tmp_path, {"kind": "keras", "factory": "x.py:build"}, "training/model/kind: 'keras' is not one of ['metraw', 'smp', 'python']")


@pytest.mark.skipif(not smp_available(), reason="segmentation-models-pytorch not importable (pip install 'metraw[models]')")
def test_unknown_smp_architecture(tmp_path, store):
    line = _train(tmp_path, {"kind": "smp", "arch": "UNetPlusPlusPlus", "encoder": "resnet18",
                             "encoder_weights": None}, "smp has no architecture 'UNetPlusPlusPlus'")
    assert "Unet" in line  # the architectures it has


@pytest.mark.skipif(not smp_available(), reason="segmentation-models-pytorch not importable (pip install 'metraw[models]')")
def test_unknown_smp_encoder(tmp_path, store):
    _train(tmp_path, {"kind": "smp", "arch": "Unet", "encoder": "resnet19", "encoder_weights": None},
           "smp could not build it")


def test_smp_without_encoder(tmp_path, store):
    _train(tmp_path, {"kind": "smp", "arch": "Unet"}, "training/model: 'encoder' is a required property")


def test_key_of_another_kind(tmp_path, store):
    _train(tmp_path, {"kind": "smp", "arch": "Unet", "encoder": "resnet18", "factory": "x.py:build"},
           "training.model of kind smp takes")


def test_snakemake_refuses_a_missing_factory_before_any_job(tmp_path):
    """The workflow's DAG build checks a factory file without importing it: one line, before anything runs."""
    from metraw.errors import MetrawError
    from metraw.segment.networks import factory_files

    (tmp_path / "net.py").write_text("def make():\n    pass\n")
    with pytest.raises(MetrawError, match="net.py defines no 'build'"):
        factory_files({"model": {"kind": "python", "factory": str(tmp_path / "net.py") + ":build"}})
    (tmp_path / "bad.py").write_text("def build(:\n")
    with pytest.raises(MetrawError, match="bad.py line 1"):
        factory_files({"profiles": {"t": {"model": {"kind": "python", "factory": str(tmp_path / "bad.py") + ":build"}}}})
