"""Bring your own network (params.yaml ``training.model``, ``metraw.segment.networks``): the default is metraw's
U-Net unchanged, a python factory or an smp model trains, evaluates and predicts through the same commands, a
checkpoint carries its network and is refused when that network cannot be rebuilt. Toy stores, one epoch."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import shutil
import sys

import pytest
import torch
import yaml

from metraw.cli import main
from metraw.errors import MetrawError
from metraw.segment.config import TrainConfig
from metraw.segment.networks import ModelSpec, check_contract, factory_files
from metraw.segment.train import build_model, load_model, pretrained_states, resolved_config

from networks_helpers import smp_available

NET = '''import torch
from torch import nn


def build(in_channels, out_channels, width=6):
    return nn.Sequential(nn.Conv2d(in_channels, width, 3, padding=1), nn.ReLU(),
                         nn.Conv2d(width, out_channels, 1))
'''


def _run(argv, cwd) -> int:
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
            status = main(argv)
    finally:
        os.chdir(here)
    assert status == 0, err.getvalue()[-2000:]
    return status


def _params(folder, model, **profile):
    prof = {"epochs": 1, "batch_size": 4, "crop_px": 32, "replicates": 2, "threads": 1, "condition": True, **profile}
    (folder / "p.yaml").write_text(yaml.safe_dump({"training": {"profile": "t", "model": model,
                                                                "profiles": {"t": prof}}}))


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    from metraw.segment.toy import toy_store

    folder = tmp_path_factory.mktemp("toy")
    toy_store(folder / "toy.zarr", 10, 64, seed=0)
    return folder / "toy.zarr"


def _state_bytes(model) -> bytes:
    return b"".join(v.numpy().tobytes() for v in model.state_dict().values())


# ----------------------------------------------------------------- the spec
def test_spec_from_params_and_back():
    assert ModelSpec.from_dict(None) == ModelSpec() == ModelSpec.from_dict({"kind": "metraw"})
    smp = ModelSpec.from_dict({"kind": "smp", "arch": "Unet", "encoder": "resnet18", "encoder_weights": None})
    assert smp.to_dict() == {"kind": "smp", "arch": "Unet", "encoder": "resnet18", "encoder_weights": None}
    assert smp.describe() == "smp Unet (resnet18)"
    py = ModelSpec.from_dict({"kind": "python", "factory": "pkg.nets:build", "kwargs": {"w": 3}})
    assert py.factory_file() is None and py.to_dict() == {"kind": "python", "factory": "pkg.nets:build",
                                                          "kwargs": {"w": 3}}
    for bad, word in (({"kind": "python", "factory": "net.py"}, "FILE.py:FUNCTION"), ({"kind": "smp"}, "arch and encoder"),
                      ({"kind": "metraw", "arch": "Unet"}, "unknown: arch"), ("Unet", "must be a mapping"),
                      ({"kind": "python", "factory": "n.py:b", "pad_multiple": 0}, "positive integer")):
        with pytest.raises(MetrawError, match=word):
            ModelSpec.from_dict(bad)


def test_study_model_reaches_every_profile(tmp_path):
    from metraw.segment.config import load_config

    (tmp_path / "p.yaml").write_text(yaml.safe_dump({"training": {
        "profile": "a", "model": {"kind": "python", "factory": "n.py:build"},
        "profiles": {"a": {"epochs": 1}, "b": {"epochs": 1, "model": {"kind": "metraw"}}}}}))
    assert load_config(tmp_path / "p.yaml").model == {"kind": "python", "factory": "n.py:build"}
    assert load_config(tmp_path / "p.yaml", "b").model == {"kind": "metraw"}  # a profile's own wins


# ----------------------------------------------------------------- metraw's U-Net, unchanged
def test_default_network_is_the_unet_as_before():
    """No model, {kind: metraw} and the U-Net built directly: the same weights from the same seed, and the contract
    check changes neither them nor torch's global random state (the default study's bytes do not move)."""
    from metraw.segment.model import Segmenter

    config = TrainConfig(base_channels=8, depth=2, condition=True)
    nets = []
    for model in (None, {"kind": "metraw"}, "direct"):
        torch.manual_seed(3)
        nets.append(Segmenter(4, 8, 2, 1, 1, n_condition=4) if model == "direct"
                    else build_model(4, TrainConfig(**{**config.__dict__, "model": model}), 1, 1))
    assert _state_bytes(nets[0]) == _state_bytes(nets[1]) == _state_bytes(nets[2])
    plain = build_model(4, TrainConfig(base_channels=8, depth=2), 1, 1)
    before, rng = _state_bytes(plain), torch.get_rng_state()
    check_contract(plain, ModelSpec())
    assert _state_bytes(plain) == before and torch.equal(torch.get_rng_state(), rng) and plain.training


# ----------------------------------------------------------------- a python factory
def test_foreign_network_pads_and_crops_any_size(tmp_path):
    (tmp_path / "net.py").write_text(NET)
    spec = ModelSpec.from_dict({"kind": "python", "factory": f"{tmp_path}/net.py:build"})
    model = build_model(4, TrainConfig(model=spec.to_dict()), 1, 2)  # pooled x2, as a drone image
    assert model.multiple == 32 and model.n_condition == 0
    for shape in ((1, 4, 37, 45), (3, 4, 64, 64), (2, 4, 5, 7)):
        assert tuple(model(torch.randn(*shape)).shape) == shape
    config = resolved_config(TrainConfig(model=spec.to_dict(), condition=True, precision="float32"), "cpu")
    assert config.condition is False  # only metraw's U-Net takes the payload: the record says so


def test_python_factory_trains_evaluates_predicts_and_is_recorded(tmp_path, toy, monkeypatch):
    work = tmp_path / "study"
    work.mkdir()
    shutil.copytree(toy, work / "toy.zarr")
    (work / "net.py").write_text(NET)
    _params(work, {"kind": "python", "factory": "net.py:build", "kwargs": {"width": 5}})
    _run(["train", "toy.zarr", "--out", "m", "--params", "p.yaml"], work)
    ckpt = torch.load(work / "m" / "model.pt", weights_only=True)
    net = ckpt["network"]
    assert net["kind"] == "python" and net["factory"] == "net.py:build" and net["kwargs"] == {"width": 5}
    assert net["factory_file"] == str((work / "net.py").resolve())
    assert net["factory_sha256"] == hashlib.sha256(NET.encode()).hexdigest()
    assert net["parameters"] == (4 * 9 * 5 + 5) + (5 * 4 + 4) and net["conditioned"] is False
    assert ckpt["config"]["condition"] is False and ckpt["config"]["model"]["kind"] == "python"
    assert json.loads((work / "m" / "replicate-1" / "train.json").read_text())["network"] == net
    _run(["evaluate", "toy.zarr", "--model", "m", "--out", "metrics.json"], work)
    metrics = json.loads((work / "metrics.json").read_text())
    assert metrics["network"]["name"] == "python net.py:build" and metrics["n_replicates"] == 2
    _run(["predict", "toy.zarr", "--model", "m", "--out", "pred.zarr"], work)

    # the workflow folder moved: the factory is found again by its relative path (same bytes)
    moved = tmp_path / "moved"
    work.rename(moved)
    monkeypatch.chdir(moved)
    model, _, _ = load_model(moved / "m", "cpu")
    assert sum(p.numel() for p in model.parameters()) == net["parameters"]
    # an edited factory file: refused (the weights belong to the network that was trained)
    (moved / "net.py").write_text(NET.replace("width=6", "width=7"))
    with pytest.raises(MetrawError, match="factory file .*net.py changed since the training"):
        load_model(moved / "m", "cpu")
    (moved / "net.py").unlink()
    with pytest.raises(MetrawError, match="cannot be rebuilt: training.model factory 'net.py:build': no file"):
        load_model(moved / "m", "cpu")


def test_module_factory_whose_network_changed_is_refused(tmp_path, toy, monkeypatch):
    """A factory given as a module (no file to hash): a checkpoint whose network now builds other weights (a
    changed default, kwargs the factory reads otherwise) is refused by the parameter count, in one line."""
    pkg = tmp_path / "lib" / "mynets"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(NET)
    monkeypatch.syspath_prepend(str(tmp_path / "lib"))
    monkeypatch.chdir(tmp_path)
    shutil.copytree(toy, tmp_path / "toy.zarr")
    _params(tmp_path, {"kind": "python", "factory": "mynets:build"}, replicates=1)
    _run(["train", "toy.zarr", "--out", "m", "--params", "p.yaml"], tmp_path)
    (pkg / "__init__.py").write_text(NET.replace("width=6", "width=9"))
    monkeypatch.delitem(sys.modules, "mynets")
    with pytest.raises(MetrawError, match=r"cannot be rebuilt: python mynets:build now builds 373 parameters, the checkpoint holds 250: its factory or kwargs"):
        load_model(tmp_path / "m", "cpu")


def test_fine_tuning_refuses_a_pretraining_of_another_network(tmp_path, toy):
    (tmp_path / "net.py").write_text(NET)
    shutil.copytree(toy, tmp_path / "toy.zarr")
    _params(tmp_path, {"kind": "metraw"}, base_channels=4, depth=2, replicates=1, condition=False)
    _run(["train", "toy.zarr", "--out", "pre", "--params", "p.yaml"], tmp_path)
    assert len(pretrained_states(tmp_path / "pre", 1, model={"kind": "metraw"})) == 1
    with pytest.raises(MetrawError, match="holds a pretraining of metraw U-Net; this training uses python"):
        pretrained_states(tmp_path / "pre", 1, model={"kind": "python", "factory": f"{tmp_path}/net.py:build"})
    # a factory's pretraining: the same file by another path is the same network, other kwargs are not
    _params(tmp_path, {"kind": "python", "factory": "net.py:build", "kwargs": {"width": 5}}, replicates=1)
    _run(["train", "toy.zarr", "--out", "pre_py", "--params", "p.yaml"], tmp_path)
    same = {"kind": "python", "factory": f"{tmp_path}/./net.py:build", "kwargs": {"width": 5}}
    assert len(pretrained_states(tmp_path / "pre_py", 1, model=same)) == 1
    with pytest.raises(MetrawError, match="holds a pretraining of python .*net.py:build; this training uses python"):
        pretrained_states(tmp_path / "pre_py", 1, model={**same, "kwargs": {"width": 6}})


def test_workflow_inputs_are_the_factory_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "net.py").write_text(NET)
    training = {"model": {"kind": "python", "factory": "net.py:build"},
                "profiles": {"a": {}, "b": {"model": {"kind": "python", "factory": "net.py:build"}},
                             "c": {"model": {"kind": "smp", "arch": "Unet", "encoder": "resnet18"}}}}
    assert factory_files(training) == ["net.py"] and factory_files({"model": {"kind": "metraw"}}) == []


# ----------------------------------------------------------------- the aggregate names the network
def test_aggregate_names_the_network_of_every_point():
    from metraw.spec.aggregate import study_network

    rec = {"name": "smp Unet (resnet18)", "kind": "smp", "arch": "Unet", "encoder": "resnet18",
           "encoder_weights": None, "parameters": 14328692, "conditioned": False, "multiple": 32}
    rows = [{"point": p, "_network": rec} for p in ("nominal", "diameter_m-0.1")]
    assert study_network(rows) == {k: v for k, v in rec.items() if k not in ("multiple", "encoder_weights")}
    assert study_network([{"point": "nominal", "_network": None}]) is None
    with pytest.raises(MetrawError, match="nominal with smp Unet .resnet18., d with metraw U-Net"):
        study_network(rows[:1] + [{"point": "d", "_network": {"name": "metraw U-Net", "kind": "metraw"}}])


# ----------------------------------------------------------------- segmentation-models-pytorch
@pytest.mark.skipif(not smp_available(), reason="segmentation-models-pytorch not importable (pip install 'metraw[models]')")
def test_smp_model_trains_and_evaluates(tmp_path, toy):
    shutil.copytree(toy, tmp_path / "toy.zarr")
    model = {"kind": "smp", "arch": "Unet", "encoder": "resnet18", "encoder_weights": None,
             "kwargs": {"encoder_depth": 3, "decoder_channels": [32, 16, 8]}}
    _params(tmp_path, model, replicates=1)
    _run(["train", "toy.zarr", "--out", "m", "--params", "p.yaml"], tmp_path)
    net = torch.load(tmp_path / "m" / "model.pt", weights_only=True)["network"]
    assert net["name"] == "smp Unet (resnet18)" and net["multiple"] == 8 and net["conditioned"] is False
    _run(["evaluate", "toy.zarr", "--model", "m", "--out", "metrics.json"], tmp_path)
    assert json.loads((tmp_path / "metrics.json").read_text())["network"]["parameters"] == net["parameters"]
