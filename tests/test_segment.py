"""Tests of metraw.segment: VST input statistics, CFA-respecting packing, IoU, training, CLI."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.raw.cfa import pack_planes
from metraw.raw.image import RawImage
from metraw.raw.sensor import expose, rng_from_seed
from metraw.segment.data import canonical_pack, prepare, split_indices, vst_mosaic
from metraw.segment.evaluate import confusion, iou, scores, summarise
from metraw.segment.toy import toy_profile, toy_scene, toy_store


# ----------------------------------------------------------------- input representation
@pytest.mark.parametrize("mean_e", [30.0, 2000.0])
def test_vst_input_has_unit_noise_variance_on_flat_image(mean_e):
    profile = toy_profile()
    img = RawImage(expose(np.full((512, 512), mean_e), profile, rng_from_seed(3)), profile,
                   mask=np.zeros((512, 512), np.float32))
    planes, _ = prepare(img).full()
    x = planes.ravel().astype(np.float64)
    n = x.size
    var = x.var(ddof=1)
    se = math.sqrt(2.0 / (n - 1))  # standard error of a Gaussian sample variance at unit variance
    # Anscombe's residual bias at >= 30 e- is < 0.3 %; allow 5 standard errors on top.
    assert abs(var - 1.0) < 5 * se + 0.003, (var, se)
    assert abs(np.median(x)) < 0.05  # centred


def test_canonical_pack_restores_rggb_for_every_pattern_and_transform():
    # A mosaic whose value encodes its colour: R=0, G=1, B=2 -> packed planes must read R, G, G, B.
    from metraw.raw.cfa import color_index

    for pattern in ("RGGB", "BGGR", "GRBG", "GBRG"):
        ci = color_index(pattern, (10, 14)).astype(np.float32)
        for k in range(8):
            planes, frac = canonical_pack(ci, np.ones_like(ci), pattern, k)
            assert planes.shape[0] == 4
            for site, colour in enumerate((0, 1, 1, 2)):
                assert np.all(planes[site] == colour), (pattern, k, site)
            assert np.all(frac == 1.0)


def test_mask_is_packed_per_site_like_the_image():
    z = np.zeros((4, 4), np.float32)
    mask = np.array([[1, 0.5, 0, 0], [1, 0, 0, 0], [0, 0, 1, 1], [0, 0, 1, 0.25]], np.float32)
    _, frac = canonical_pack(z, mask, "RGGB", 0)
    np.testing.assert_array_equal(frac, pack_planes(mask, "RGGB"))
    np.testing.assert_array_equal(frac[:, 0, 0], [1, 0.5, 1, 0])   # R, G, G, B sites of cell (0, 0)
    np.testing.assert_array_equal(frac[:, 1, 1], [1, 1, 1, 0.25])
    # a GBRG mosaic is shifted by one row to read R G / G B: the mask follows the same pixels
    _, frac_g = canonical_pack(np.zeros((5, 4), np.float32), np.vstack([np.zeros((1, 4)), mask]), "GBRG", 0)
    np.testing.assert_array_equal(frac_g, frac)


def test_split_is_fixed_and_disjoint():
    tr, te = split_indices(50, 0.2, 7)
    tr2, te2 = split_indices(50, 0.2, 7)
    assert np.array_equal(tr, tr2) and np.array_equal(te, te2)
    assert len(te) == 10 and len(set(tr) | set(te)) == 50 and not set(tr) & set(te)
    assert not np.array_equal(split_indices(50, 0.2, 8)[1], te)
    with pytest.raises(MetrawError):
        split_indices(1, 0.2, 0)


# ----------------------------------------------------------------- metrics
def test_iou_on_hand_made_masks():
    target = np.zeros((4, 4), bool)
    target[0:2, 0:2] = True          # 4 cells
    pred = np.zeros((4, 4), bool)
    pred[1:3, 1:3] = True            # 4 cells, overlap 1
    assert confusion(pred, target) == (1, 3, 3)
    assert iou(pred, target) == pytest.approx(1 / 7)
    s = scores(1, 3, 3)
    assert s["precision"] == pytest.approx(0.25) and s["recall"] == pytest.approx(0.25)
    assert iou(target, target) == 1.0
    assert iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) is None
    assert iou(np.ones((3, 3), bool), np.zeros((3, 3), bool)) == 0.0
    # pooled IoU sums counts; the mean per-image IoU skips undefined images
    recs = [{"tp": 1, "fp": 3, "fn": 3, "iou": 1 / 7}, {"tp": 4, "fp": 0, "fn": 0, "iou": 1.0},
            {"tp": 0, "fp": 0, "fn": 0, "iou": None}]
    out = summarise(recs)
    assert out["iou"] == pytest.approx(5 / 11)
    assert out["mean_image_iou"] == pytest.approx((1 / 7 + 1) / 2)


def test_area_iou_against_fractional_targets():
    # A car covering half of each of two pixels: predicting both costs half their area as FP.
    f = np.array([[0.5, 0.5, 0.0], [0.0, 1.0, 0.25]])
    pred = np.array([[True, True, False], [False, True, False]])
    tp, fp, fn = confusion(pred, f)
    assert (tp, fp, fn) == pytest.approx((2.0, 1.0, 0.25))
    assert iou(pred, f) == pytest.approx(2.0 / 3.25)
    # with 0/1 fractions the area scores equal the pixel counts
    b = f >= 0.5
    assert confusion(pred, b.astype(np.float32)) == pytest.approx(confusion(pred, b))
    # leaving out the half-covered pixels trades their FP area for FN area
    assert iou(f > 0.5, f) == pytest.approx(1.0 / 2.25)
    with pytest.raises(ValueError):
        confusion(pred, f * 3)


# ----------------------------------------------------------------- training
@pytest.mark.parametrize("text, match", [("training: {profiles: {default: {epochs: 2}\n", "is not valid YAML"),
                                          ("[1, 2]\n", "has no training.profiles section"),
                                          ("training: {profile: x}\n", "has no training.profiles section")])
def test_load_config_refuses_a_file_without_training_profiles(tmp_path, text, match):
    """One line naming the file, whatever is wrong with it (a YAML parser's error spans several lines)."""
    from metraw.segment.config import load_config

    (tmp_path / "p.yaml").write_text(text)
    with pytest.raises(MetrawError) as err:
        load_config(tmp_path / "p.yaml")
    assert match in str(err.value) and "p.yaml" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(MetrawError, match="not found"):
        load_config(tmp_path / "none.yaml")


@pytest.fixture(scope="module")
def tiny_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("seg") / "toy.zarr"
    toy_store(path, 12, 96, seed=2)
    return path


def _cfg(**kw):
    from metraw.segment.train import TrainConfig

    base = dict(epochs=2, learning_rate=3e-3, batch_size=4, crop_px=32, base_channels=8, depth=2, seed=0,
                test_fraction=0.25)
    base.update(kw)
    return TrainConfig(**base)


def test_small_predicted_objects_are_dropped_by_ground_area():
    from metraw.segment.evaluate import THRESHOLD, predicted_mask
    from metraw.segment.objects import MIN_OBJECT_AREA_M2, drop_small_objects

    prob = np.zeros((40, 40), np.float32)
    prob[2:5, 2:5] = 0.9                               # 9 px
    prob[20:26, 20:26] = 0.9                           # 36 px
    for k in range(12):                                # a diagonal chain: one 8-connected object of 12 px
        prob[10 + k, 30 + k % 2 + k // 2] = 0.8
    prob[30, 5] = THRESHOLD                            # not above the threshold: never car
    gsd_m = math.sqrt(MIN_OBJECT_AREA_M2 / 10.0)       # the smallest object: 10 pixels
    mask = predicted_mask(prob, gsd_m)
    assert not mask[2:5, 2:5].any() and mask[20:26, 20:26].all() and mask.sum() == 36 + 12
    assert predicted_mask(prob, None).sum() == 9 + 36 + 12  # GSD unknown: nothing dropped
    # another decision threshold: 0.85 keeps the 0.9 squares only, 0.4 adds the pixel at THRESHOLD
    assert predicted_mask(prob, gsd_m, 0.85).sum() == 36 and predicted_mask(prob, None, 0.85).sum() == 9 + 36
    assert predicted_mask(prob, None, 0.4).sum() == 9 + 36 + 12 + 1
    stack = np.stack([prob > THRESHOLD, np.zeros_like(prob, bool)])
    assert drop_small_objects(stack, 10).sum(axis=(1, 2)).tolist() == [48, 0]  # leading axes: separate images


def test_a_car_outline_scores_one_against_its_box_only_as_a_box():
    """A perfect outline of a car at 45 degrees, scored against its axis-aligned box label: the pixel IoU is
    the outline's share of the box, the box IoU (the predicted object's bounding box against the box) is 1."""
    import torch

    from metraw.segment.data import PreparedImage
    from metraw.segment.evaluate import score_image
    from metraw.segment.objects import object_boxes

    y, x = np.mgrid[0:48, 0:48] + 0.5
    u, v = (x - 24 + y - 24) / math.sqrt(2), (x - 24 - (y - 24)) / math.sqrt(2)
    car = (np.abs(u) < 12) & (np.abs(v) < 5)
    box = object_boxes(car)
    assert box.sum() > car.sum()

    class Fixed(torch.nn.Module):  # a "network" whose logits are the car outline
        def forward(self, x):
            # packed as the mono mosaic is (2 x 2 cells, metraw.raw.cfa.PACKED_CELL_PX)
            return torch.from_numpy(pack_planes(np.where(car, 8.0, -8.0).astype(np.float32), "RGGB"))[None]

    img = PreparedImage(np.zeros((48, 48), np.float32), box.astype(np.float16), "mono", 0, gsd_m=0.1)
    rec = score_image(Fixed(), img, boxes=True)
    assert rec["iou"] == pytest.approx(car.sum() / box.sum()) and rec["precision"] == 1.0
    assert (rec["box_tp"], rec["box_fp"], rec["box_fn"]) == (box.sum(), 0, 0)
    pooled = summarise([rec, {**rec, "box_tp": 0.0, "box_fn": float(box.sum())}])
    assert pooled["box_iou"] == pytest.approx(0.5) and pooled["box_precision"] == 1.0
    assert "box_iou" not in summarise([score_image(Fixed(), img)])  # exact labels: no box scores


def test_set_determinism_switches_deterministic_algorithms_without_importing_inductor():
    """The eager-mode switch (error on CPU, warn on CUDA), without torch._inductor's ~1 s import."""
    import subprocess
    import sys

    code = ("import sys, torch; from metraw.segment.train import set_determinism\n"
            "set_determinism(0, 1, 'cpu')\n"
            "a = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled())\n"
            "set_determinism(0, 1, 'cuda')\n"
            "b = (torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled())\n"
            "print(a, b, torch.get_num_threads(), 'torch._inductor' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")[0]
    assert out == "(True, False) (True, True) 1 False", out


def test_training_is_deterministic_and_evaluates(tiny_store, tmp_path):
    from metraw.segment.evaluate import evaluate_store
    from metraw.segment.train import CHECKPOINT, TIMINGS, TRAIN_METRICS, train_store

    out = []
    for run in ("a", "b"):
        rec = train_store(tiny_store, tmp_path / run, _cfg(), device="cpu", progress=False)
        # ~3 s on 2 free cores; 60 s was seen with the cores shared by other training jobs: a bound for a
        # runaway configuration, not a benchmark
        assert rec["training_time_s"] < 120
        out.append(evaluate_store(tiny_store, tmp_path / run, device="cpu", progress=False))
    # same seed, data and thread count: the same bytes (checkpoint, training record, metrics); the
    # wall-clock timings stay in the returned record and out of the files
    for name in (CHECKPOINT, TRAIN_METRICS):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert not set(TIMINGS) & set(json.loads((tmp_path / "a" / TRAIN_METRICS).read_text()))
    same = [json.dumps({k: v for k, v in m.items() if k != "model"}) for m in out]  # all but the model's path
    assert same[0] == same[1]
    assert out[0]["iou"] == out[1]["iou"] and out[0]["per_image"] == out[1]["per_image"]
    assert out[0]["n_images"] == 3 and len(out[0]["per_image"]) == 3
    assert 0.0 <= out[0]["iou"] <= 1.0
    rec_c = train_store(tiny_store, tmp_path / "c", _cfg(seed=1, epochs=1), device="cpu", progress=False)
    first = json.loads((tmp_path / "a" / "train.json").read_text())
    assert rec_c["loss_per_epoch"][0] != first["loss_per_epoch"][0]  # the seed matters


def test_fused_adamw_is_the_per_parameter_update_to_rounding():
    """``make_optimizer`` fuses AdamW on the CPU; 20 steps of it with weight decay end within float32 rounding of
    the per-parameter AdamW from the same weights, and far from where the model started."""
    import copy

    import torch

    from metraw.segment.train import TrainConfig, make_optimizer

    torch.manual_seed(0)
    cfg = TrainConfig.from_dict({"learning_rate": 1e-2})
    first = torch.nn.Sequential(torch.nn.Conv2d(4, 8, 3), torch.nn.GroupNorm(2, 8), torch.nn.Conv2d(8, 4, 1))
    models = [first, copy.deepcopy(first)]
    start = torch.cat([p.detach().flatten() for p in models[0].parameters()]).clone()
    fused = make_optimizer(models[0], cfg, "cpu")
    plain = torch.optim.AdamW(models[1].parameters(), lr=cfg.learning_rate, weight_decay=cfg.weight_decay,
                              foreach=False)
    assert fused.defaults["fused"] is True and fused.defaults["weight_decay"] == cfg.weight_decay > 0
    x = torch.randn(4, 4, 12, 12)
    for _ in range(20):
        for model, opt in ((models[0], fused), (models[1], plain)):
            loss = (model(x) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    a, b = (torch.cat([p.detach().flatten() for p in m.parameters()]) for m in models)
    assert torch.allclose(a, b, rtol=1e-4, atol=1e-5), float((a - b).abs().max())
    assert float((a - start).abs().max()) > 0.05  # 20 steps of lr 1e-2 did move the weights


def test_bfloat16_training_is_deterministic_learns_and_differs_from_float32(tiny_store):
    import torch

    from metraw.errors import MetrawError
    from metraw.io.store import RawStore
    from metraw.segment.data import prepare_store
    from metraw.segment.train import TrainConfig, fit

    images = prepare_store(RawStore.open(tiny_store), range(8), progress=False)
    runs = [fit(images, _cfg(epochs=4, precision=prec), device="cpu", progress=False)
            for prec in ("bfloat16", "bfloat16", "float32")]
    weights = [torch.cat([p.detach().flatten() for p in m.parameters()]) for m, _ in runs]
    assert torch.equal(weights[0], weights[1])  # same seed and data: the same weights
    assert not torch.equal(weights[0], weights[2])  # the arithmetic really changed
    assert weights[0].dtype == torch.float32  # autocast keeps float32 weights
    losses = runs[0][1]["loss_per_epoch"]
    assert losses[-1] < losses[0]
    with pytest.raises(MetrawError, match="precision"):
        TrainConfig.from_dict({"precision": "float16"})


def test_auto_precision_is_bfloat16_exactly_where_the_hardware_computes_it(tiny_store, monkeypatch):
    import torch

    from metraw.io.store import RawStore
    from metraw.segment.data import prepare_store
    from metraw.segment.train import fit, fit_replicates, resolve_precision

    def hardware(avx512_bf16: bool, amx: bool = False, cuda_bf16: bool = False, capability: str = "AVX512"):
        monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: capability)
        monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: avx512_bf16)
        monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
        monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: cuda_bf16)

    hardware(False)
    assert resolve_precision("auto", "cpu") == "float32"
    assert resolve_precision("bfloat16", "cpu") == "bfloat16" and resolve_precision("float32", "cpu") == "float32"
    assert resolve_precision("auto", "cuda") == "float32" and resolve_precision("auto", "meta") == "float32"
    hardware(False, amx=True)
    assert resolve_precision("auto", "cpu") == "bfloat16"
    hardware(True, amx=True, capability="AVX2")  # ATEN_CPU_CAPABILITY=avx2: the host runs as an AVX2-only one
    assert resolve_precision("auto", "cpu") == "float32"
    hardware(False, cuda_bf16=True)
    assert resolve_precision("auto", "cuda") == "bfloat16" and resolve_precision("auto", "cpu") == "float32"

    images = prepare_store(RawStore.open(tiny_store), range(8), progress=False)

    def weights(precision, device_bf16):
        hardware(device_bf16)
        runs = fit_replicates(_cfg(epochs=2, precision=precision), lambda cfg: fit(images, cfg, "cpu", progress=False),
                              {}, "cpu")
        (model, cfg, record), = runs
        assert cfg.precision == record["config"]["precision"] != "auto"  # the record says what ran
        return cfg.precision, torch.cat([p.detach().flatten() for p in model.parameters()])

    auto_native, explicit_bf16 = weights("auto", True), weights("bfloat16", False)
    auto_plain, explicit_fp32 = weights("auto", False), weights("float32", True)
    assert auto_native[0] == "bfloat16" and torch.equal(auto_native[1], explicit_bf16[1])
    assert auto_plain[0] == "float32" and torch.equal(auto_plain[1], explicit_fp32[1])
    assert not torch.equal(auto_native[1], auto_plain[1])


def test_losses_equal_their_formulas_on_saturated_logits():
    import torch
    import torch.nn.functional as F

    from metraw.segment.train import TrainConfig, segmentation_loss

    # saturated logits: p is 0 or 1 to float precision, so Dice and IoU are those of the 0/1 prediction
    pred = torch.tensor([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    frac = torch.tensor([1.0, 0.5, 0.0, 0.25, 0.0, 0.0])
    logits = (2 * pred - 1) * 40.0
    bce = float(F.binary_cross_entropy_with_logits(logits, frac))
    inter, p_sum, f_sum = 1.5, 3.0, 1.75
    assert float(segmentation_loss(logits, frac, "bce")) == pytest.approx(bce, rel=1e-6)
    assert float(segmentation_loss(logits, frac)) == pytest.approx(
        bce + 1 - (2 * inter + 1) / (p_sum + f_sum + 1), rel=1e-6)
    assert float(segmentation_loss(logits, frac, "bce+iou")) == pytest.approx(
        bce + 1 - (inter + 1) / (p_sum + f_sum - inter + 1), rel=1e-6)
    # IoU <= Dice for any overlap, so the IoU term is the larger loss unless the prediction is exact
    assert float(segmentation_loss(logits, frac, "bce+iou")) > float(segmentation_loss(logits, frac))
    with pytest.raises(MetrawError, match="loss"):
        TrainConfig.from_dict({"loss": "lovasz"})
    with pytest.raises(MetrawError, match="loss"):
        segmentation_loss(logits, frac, "focal")


def test_training_reduces_loss_and_upsampling_keeps_native_grid(tiny_store):
    import torch

    from metraw.segment.data import prepare_store
    from metraw.segment.train import fit

    images = prepare_store(__import__("metraw.io.store", fromlist=["RawStore"]).RawStore.open(tiny_store), range(8),
                           progress=False)
    model, rec = fit(images, _cfg(epochs=4, min_grid_px=96), device="cpu", progress=False)
    assert rec["upsample"] == 2  # 48 packed px -> factor 2 to reach 96
    # training flushes denormals only while it runs: the processor state is back for everyone else
    tiny = np.array([1e-40], np.float32)
    assert (tiny * np.float32(1.0))[0] != 0.0
    assert rec["loss_per_epoch"][-1] < rec["loss_per_epoch"][0]
    planes, frac = images[0].full()
    with torch.no_grad():
        y = model(torch.from_numpy(planes)[None])
    assert tuple(y.shape[1:]) == frac.shape  # one logit per CFA site: the mosaic grid


def test_cli_train_evaluate_and_errors(tiny_store, tmp_path, capsys):
    import yaml

    from metraw.cli import main

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"training": {"profile": "tiny", "split_seed": 0, "test_fraction": 0.25,
                                                   "profiles": {"tiny": dict(epochs=1, batch_size=4, crop_px=32,
                                                                             base_channels=8, depth=2)}}}))
    assert main(["train", str(tiny_store), "--out", str(tmp_path / "m"), "--params", str(params)]) == 0
    assert main(["evaluate", str(tiny_store), "--model", str(tmp_path / "m"), "--out", str(tmp_path / "e.json")]) == 0
    metrics = json.loads((tmp_path / "e.json").read_text())
    for key in ("iou", "per_image", "precision", "recall", "epochs"):
        assert key in metrics
    assert metrics["epochs"] == 1
    # timings are logged (stderr), not written into the results
    assert not [k for k in metrics if k.endswith("time_s")]
    err = capsys.readouterr().err
    assert re.search(r"metraw train: \d+ images, 1 epoch\(s\), 1 replicate\(s\) in [\d.]+ s", err), err
    assert re.search(r"metraw evaluate: 3 test images in [\d.]+ s", err), err
    assert main(["train", str(tiny_store), "--out", str(tmp_path / "m2"), "--params", str(params),
                 "--profile", "nope"]) == 2
    assert "training profile 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "m2").exists()
    assert main(["evaluate", str(tiny_store), "--model", str(tmp_path / "none"), "--out", str(tmp_path / "x.json")]) == 2
    assert not (tmp_path / "x.json").exists()


def test_image_without_mask_is_rejected():
    img = toy_scene(32, 0)
    img.mask = None
    with pytest.raises(MetrawError):
        prepare(img)
    assert vst_mosaic(img).dtype == np.float32


def test_pool_factor_follows_ground_sampling_and_keeps_the_grid():
    import torch

    from metraw.segment.data import PreparedImage
    from metraw.segment.model import Segmenter
    from metraw.segment.train import pool_factor

    z = np.zeros((8, 8), np.float32)
    drone = PreparedImage(z, z.astype(np.float16), "RGGB", 0, gsd_m=0.0587)   # packed cell 0.117 m
    sat = PreparedImage(z, z.astype(np.float16), "RGGB", 1, gsd_m=0.876)      # packed cell 1.75 m
    assert pool_factor([drone], 0.47) == 4 and pool_factor([drone], 0.2) == 1
    assert pool_factor([sat], 0.47) == 1 and pool_factor([drone], 0.0) == 1
    assert pool_factor([drone, PreparedImage(z, z.astype(np.float16), "RGGB", 2)], 0.47) == 1  # GSD unknown
    torch.manual_seed(0)
    model = Segmenter(4, 8, 2, pool=4).eval()
    with torch.no_grad():
        y = model(torch.randn(1, 4, 50, 70))
    assert y.shape == (1, 4, 50, 70)
    with pytest.raises(ValueError):
        Segmenter(4, 8, 2, upsample=2, pool=2)


def test_cover_draws_enough_crops_to_see_each_image_once_per_epoch(tiny_store):
    from metraw.io.store import RawStore
    from metraw.segment.data import PreparedImage, prepare_store
    from metraw.segment.train import TrainConfig, crops_to_cover, fit

    def image(h, w):
        return PreparedImage(np.zeros((h, w), np.float32), np.zeros((h, w), np.float16), "mono", 0)

    # packed 2 x 2: 128 x 128, 160 x 64, 68 x 68, 30 x 30 cells
    assert crops_to_cover([image(256, 256), image(320, 128), image(136, 136), image(60, 60)], 64).tolist() == [4, 2, 1, 1]
    rggb = PreparedImage(np.zeros((256, 256), np.float32), np.zeros((256, 256), np.float16), "RGGB", 0)
    assert crops_to_cover([rggb], 64).tolist() == [4]  # 128 x 128 packed cells
    for bad in (0, "all", True, 1.5):
        with pytest.raises(MetrawError, match="crops_per_image"):
            TrainConfig.from_dict({"crops_per_image": bad})
    images = prepare_store(RawStore.open(tiny_store), [0, 1, 2])
    cfg = TrainConfig(epochs=1, crop_px=16, base_channels=4, depth=2, batch_size=2, crops_per_image="cover")
    need = crops_to_cover(images, 16)
    assert need.min() > 1
    _, record = fit(images, cfg, "cpu", progress=False)
    assert record["steps"] == math.ceil(need.sum() / 2)


def test_tone_jitter_is_a_power_law_on_electrons_with_the_median_fixed():
    """z ~ 2 sqrt(e): a power g on the VST level is the power g on the photoelectrons; the image's level
    (median) maps to itself, and a channel gain c in electrons scales that plane by sqrt(c)."""
    from metraw.segment.data import tone_jitter

    level = 80.0
    planes = np.stack([np.linspace(-60, 120, 50, dtype=np.float32).reshape(5, 10)] * 4)
    same = tone_jitter(planes, level, rng_from_seed(0), 1.0, 1.0)
    np.testing.assert_allclose(same, planes, atol=1e-4)  # ranges of 1: identity (all above the clip)
    for seed in range(5):
        out = tone_jitter(planes, level, rng_from_seed(seed), 1.6, 1.0)
        zabs_in, zabs_out = (planes + level) / level, (out + level) / level
        g = math.log(zabs_out[0, 4, 9]) / math.log(zabs_in[0, 4, 9])  # one exponent for the whole crop
        assert 1 / 1.6 - 1e-6 <= g <= 1.6 + 1e-6
        np.testing.assert_allclose(zabs_out, zabs_in ** g, rtol=1e-4)
        at_level = tone_jitter(np.zeros((4, 2, 2), np.float32), level, rng_from_seed(seed), 1.6, 1.0)
        np.testing.assert_allclose(at_level, 0.0, atol=1e-4)  # the median stays put
        gains = tone_jitter(np.zeros((4, 2, 2), np.float32), level, rng_from_seed(seed), 1.0, 1.3)
        c = ((gains[:, 0, 0] + level) / level) ** 2
        assert np.all((c >= 1 / 1.3 - 1e-5) & (c <= 1.3 + 1e-5)) and np.ptp(c) > 0
