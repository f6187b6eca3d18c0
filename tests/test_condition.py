"""Payload conditioning of the segmenter (metraw.segment.condition; FiLM in metraw.segment.model; issue #15)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError

PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"


def test_payload_features_are_the_physics_of_the_profile():
    from metraw.segment.condition import CONDITION_FEATURES, payload_condition

    nominal = TargetSystem.from_params(str(PARAMS))
    v = payload_condition(nominal.profile())
    assert v.dtype == np.float32 and v.shape == (len(CONDITION_FEATURES),)
    # by hand at the nominal payload: 2.4 um pixels, f = 1.644 m, D = 0.2 m, 600 km, 180 us, 6900 m/s, RGGB
    packed = 2 * 2.4e-6 * 600e3 / 1.644
    fwhm = 1.029 * 550e-9 / 0.2 * 600e3
    light = math.pi * 0.2**2 / 4 * (2.4e-6 / 1.644) ** 2 * 180e-6
    expected = [math.log2(packed), math.log2(fwhm / packed), math.log2(light / 1e-17), 6900 * 180e-6 / packed]
    assert v == pytest.approx(np.array(expected, np.float32), rel=1e-6, abs=1e-6)
    # scaling laws: twice the aperture halves the blur and collects 4x the light; twice the focal length halves the
    # GSD, doubles the blur in pixels, quarters the light per pixel and doubles the smear in pixels
    d2 = payload_condition(dataclasses.replace(nominal, diameter_m=0.4).profile()) - v
    assert d2 == pytest.approx([0, -1, 2, 0], abs=1e-5)
    f2 = payload_condition(dataclasses.replace(nominal, focal_length_m=2 * 1.644).profile())
    assert f2[:3] - v[:3] == pytest.approx([-1, 1, -2], abs=1e-5) and f2[3] == pytest.approx(2 * v[3], rel=1e-5)
    mono = payload_condition(dataclasses.replace(nominal, cfa_pattern="mono").profile())
    assert mono[0] == pytest.approx(v[0], abs=1e-6)  # a mono mosaic packs in 2 x 2 cells as a Bayer one does
    # the atmosphere is not a payload feature (unknown at deployment)
    hazy = dataclasses.replace(nominal, atmospheric_transmission=0.5, path_radiance_w_m2_sr_m=6e7)
    assert np.array_equal(payload_condition(hazy.profile()), v)
    # a profile without its geometry has no vector
    assert payload_condition(nominal.profile().replace(focal_length_m=None)) is None


def test_a_conditioned_network_starts_as_the_plain_one_and_needs_its_condition():
    import torch

    from metraw.segment.model import Segmenter

    torch.manual_seed(0)
    plain = Segmenter(4, base_channels=8, depth=2)
    cond = Segmenter(4, base_channels=8, depth=2, n_condition=4)
    missing, unexpected = cond.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("unet.film.") for k in missing)
    x = torch.randn(2, 4, 20, 20)
    c = torch.randn(2, 4)
    assert torch.equal(plain(x), cond(x, c))  # FiLM is zero at initialisation: the identity
    with pytest.raises(ValueError, match="conditioned"):
        cond(x)
    with pytest.raises(ValueError, match=r"shape \(2, 4\)"):
        cond(x, c[:, :3])
    # once trained, the condition changes the logits (per image: the batch's other image is not affected)
    with torch.no_grad():
        for layer in cond.unet.film:
            layer.weight.normal_(0, 0.3)
    c2 = c.clone()
    c2[1] += 1.0
    y1, y2 = cond(x, c), cond(x, c2)
    assert torch.equal(y1[0], y2[0]) and (y1[1] - y2[1]).abs().max() > 1e-3


def test_a_conditioned_model_trains_saves_and_scores_and_refuses_images_without_geometry(stores, tmp_path):
    import torch

    from metraw.io.store import RawStore
    from metraw.segment.data import prepare
    from metraw.segment.evaluate import evaluate_store, predict_logits
    from metraw.segment.onthefly import train_store_on_the_fly
    from metraw.segment.train import CHECKPOINT, TrainConfig, load_model

    src, tgt, _ = stores
    cfg = TrainConfig(epochs=2, learning_rate=3e-3, batch_size=2, crop_px=16, base_channels=4, depth=2, seed=0,
                      test_fraction=0.34, replicates=1, condition=True)
    for run in ("a", "b"):
        train_store_on_the_fly(tgt, src, tmp_path / run, cfg, device="cpu", progress=False)
    assert (tmp_path / "a" / CHECKPOINT).read_bytes() == (tmp_path / "b" / CHECKPOINT).read_bytes()
    model, ckpt, _ = load_model(tmp_path / "a", "cpu")
    assert ckpt["config"]["condition"] and model.n_condition == 4
    film = [float(layer.weight.detach().abs().max()) for layer in model.unet.film]
    assert min(film) > 0  # the conditioning layers were trained, not left at zero
    m = evaluate_store(tgt, tmp_path / "a", device="cpu", progress=False)
    assert m["n_images"] == 2 and 0.0 <= m["iou"] <= 1.0
    image = RawStore.open(tgt)[0]
    img = prepare(image, 0)
    planes, _ = img.full()
    logits = predict_logits(model, planes, "cpu", condition=img.condition)
    assert logits.shape == planes.shape and np.isfinite(logits).all()
    other = predict_logits(model, planes, "cpu", condition=img.condition + np.float32(1.0))
    assert np.abs(other - logits).max() > 1e-4  # the payload vector reaches the logits
    with pytest.raises(MetrawError, match="conditioned on the payload"):
        predict_logits(model, planes, "cpu")
    # a plain model ignores the vector
    plain, _, _ = load_model(tmp_path / "a", "cpu")
    plain.unet.n_condition = 0
    plain.unet.film = torch.nn.ModuleList()
    assert np.array_equal(predict_logits(plain, planes, "cpu", condition=img.condition),
                          predict_logits(plain, planes, "cpu"))


def test_condition_must_be_a_boolean():
    from metraw.segment.train import TrainConfig

    with pytest.raises(MetrawError, match="condition must be true or false"):
        TrainConfig.from_dict({"condition": "yes"})
