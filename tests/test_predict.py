"""`metraw evaluate` / `metraw predict` on foreign stores: test split vs all images, resampling to the
training GSD, box-approximate labels, the mosaic-grid output of predict and its agreement with evaluate,
one-line errors. Tiny toy stores and a narrow U-Net trained for one epoch (a few seconds)."""

from __future__ import annotations

import contextlib
import io
import json
import math
import shutil

import numpy as np
import pytest

from metraw.raw.image import RawImage
from metraw.raw.sensor import rng_from_seed
from metraw.segment.data import canonical_pack
from metraw.segment.evaluate import confusion, gsd_scale, predict_logits, resample_to_gsd
from metraw.segment.objects import MIN_OBJECT_AREA_M2, drop_small_objects
from metraw.segment.predict import load_prediction, packed_window, sites_to_mosaic
from metraw.segment.toy import toy_profile, toy_scene

BOX = "box-approximate: union of axis-aligned YOLO boxes, area fraction per pixel"


# ----------------------------------------------------------------- unit: GSD, resampling, unpacking
def test_gsd_scale_rules():
    assert gsd_scale(0.27, 0.117)[0] == pytest.approx(0.27 / 0.117)          # KIT on the drone model: x2.3
    assert gsd_scale(0.1015, 0.1) == (1.0, True, None)                        # within 2 %: not resampled
    assert gsd_scale(0.103, 0.1)[0] == pytest.approx(1.03)
    assert gsd_scale(0.05, 0.1)[0] == pytest.approx(0.5)
    scale, matched, note = gsd_scale(0.2, None, recorded=False)
    assert (scale, matched) == (1.0, False) and "trained before" in note
    assert gsd_scale(0.2, None)[1:] == (False, "training GSD unknown (training images without geometry): "
                                        "images not resampled")
    scale, matched, note = gsd_scale(None, 0.1)
    assert (scale, matched) == (1.0, False) and "image GSD unknown" in note
    # a model pretrained across a range of GSDs: inside it as is, outside resampled to the nearer end
    assert gsd_scale(1.3, [0.9, 3.5]) == (1.0, True, None) and gsd_scale(0.9, [0.9, 3.5]) == (1.0, True, None)
    assert gsd_scale(0.6, [0.9, 3.5])[0] == pytest.approx(0.6 / 0.9)
    assert gsd_scale(4.2, (0.9, 3.5))[:2] == (pytest.approx(1.2), True)


class _Recorder:
    """A 'model' returning its input as logits and keeping what it saw (its working grid)."""

    def __init__(self):
        self.seen = None

    def eval(self):
        return self

    def __call__(self, x):
        self.seen = x.clone()
        return x


def _disc(side_px: int, radius_px: float) -> np.ndarray:
    yy, xx = np.mgrid[0:side_px, 0:side_px] + 0.5
    inside = np.hypot(yy - side_px / 2, xx - side_px / 2) < radius_px
    return np.where(inside, 4.0, -4.0).astype(np.float32)


@pytest.mark.parametrize("side_px,radius_px,scale", [(64, 6.0, 2.0), (128, 16.0, 0.5), (60, 5.0, 2.3)])
def test_resampling_shows_the_network_a_disc_at_its_training_size(side_px, radius_px, scale):
    # a car of fixed ground size: radius_px image pixels; the network must see it at radius_px * scale
    # of its own (training-GSD) pixels, and the logits must come back on the image grid at radius_px
    planes = np.stack([_disc(side_px, radius_px)] * 4)
    model = _Recorder()
    logits = predict_logits(model, planes, "cpu", scale)
    seen = model.seen[0, 0].numpy()
    assert seen.shape == (round(side_px * scale),) * 2
    assert np.count_nonzero(seen > 0) == pytest.approx(math.pi * (radius_px * scale) ** 2, rel=0.08)
    assert logits.shape == planes.shape
    assert np.count_nonzero(logits[0] > 0) == pytest.approx(math.pi * radius_px**2, rel=0.08)
    # a constant logit stays that constant through both resamplings
    const = predict_logits(_Recorder(), np.full((4, side_px, side_px), 1.5, np.float32), "cpu", scale)
    np.testing.assert_allclose(const, 1.5, rtol=1e-6)


def test_resample_to_gsd_is_identity_at_scale_one():
    import torch

    x = torch.randn(1, 4, 10, 12)
    assert resample_to_gsd(x, 1.0) is x
    assert tuple(resample_to_gsd(x, 0.5).shape) == (1, 4, 5, 6)


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG", "GRBG", "BGGR", "mono"])
@pytest.mark.parametrize("shape", [(8, 10), (9, 11)])
def test_sites_to_mosaic_inverts_the_canonical_packing(pattern, shape):
    m = rng_from_seed(1).random(shape).astype(np.float32)
    planes, _ = canonical_pack(m, None, pattern, 0)
    back = sites_to_mosaic(planes, pattern, shape)
    y0, y1, x0, x1 = packed_window(pattern, shape)
    assert back.shape == shape
    np.testing.assert_array_equal(back[y0:y1, x0:x1], m[y0:y1, x0:x1])
    # dropped rows / columns take the nearest packed pixel
    if y0:
        np.testing.assert_array_equal(back[0, x0:x1], m[1, x0:x1])
    if y1 < shape[0]:
        np.testing.assert_array_equal(back[-1, x0:x1], m[y1 - 1, x0:x1])
    if x1 < shape[1]:
        np.testing.assert_array_equal(back[y0:y1, -1], m[y0:y1, x1 - 1])
    step = 2  # every mosaic packs in 2 x 2 cells (metraw.raw.cfa.PACKED_CELL_PX)
    assert (y1 - y0) % step == 0 and (x1 - x0) % step == 0 and shape[0] - (y1 - y0) < 2 * step


# ----------------------------------------------------------------- stores and a tiny model
def _profile(pattern: str = "RGGB", gsd_m: float = 0.05):
    """The toy camera with a nadir geometry giving ``gsd_m`` per mosaic pixel."""
    return toy_profile(pattern).replace(pixel_pitch_m=5e-6, focal_length_m=0.05, altitude_m=gsd_m * 0.05 / 5e-6)


def _store(path, sizes, seed, profile, labels=True, meta=None):
    from metraw.io.store import RawStore

    rng = rng_from_seed(seed)
    with RawStore.create(path) as store:
        for k, size in enumerate(sizes):
            img = toy_scene(size, rng, profile=profile, n_cars=3, car_px=(6, 10))
            extra = meta(k) if meta else {}
            store.append(RawImage(img.data, img.profile, mask=img.mask if labels else None,
                                  meta={**img.meta, **extra}))
    return path


def _cli(*argv) -> tuple[int, str, str]:
    from metraw.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("predict")
    d = {"root": root,
         "train": _store(root / "train.zarr", [64] * 8, 1, _profile()),
         # foreign: another CFA phase, odd size (a dropped row and column), YOLO-box labels
         "boxes": _store(root / "boxes.zarr", [81] * 3, 5, _profile("GBRG"), meta=lambda k: {"mask_kind": BOX}),
         # foreign at twice the GSD, one of its two images with box labels
         "coarse": _store(root / "coarse.zarr", [48] * 2, 7, _profile(gsd_m=0.1),
                          meta=lambda k: {"mask_kind": BOX} if k == 0 else {}),
         # unlabelled, two shapes (stored one array per image)
         "unlabelled": _store(root / "unlabelled.zarr", [48, 64], 9, _profile(), labels=False)}
    (root / "params.yaml").write_text("training: {profile: tiny, test_fraction: 0.25, profiles: {tiny: {epochs: 1, "
                                      "batch_size: 4, crop_px: 16, base_channels: 4, depth: 2, "
                                      "predict_transforms: 8}}}\n")
    status, _, err = _cli("train", d["train"], "--out", root / "model", "--params", root / "params.yaml")
    assert status == 0, err
    d["model"] = root / "model"
    return d


def _evaluate(data, store, name, *extra):
    out = data["root"] / f"{name}.json"
    status, stdout, stderr = _cli("evaluate", store, "--model", data["model"], "--out", out, "--overwrite", *extra)
    assert status == 0, stderr
    return json.loads(out.read_text()), json.loads(stdout), stderr


def test_checkpoint_records_training_gsd_and_store_digest(data):
    import torch

    record = json.loads((data["model"] / "train.json").read_text())
    ckpt = torch.load(data["model"] / "model.pt", weights_only=True)
    assert record["train_packed_gsd_m"] == pytest.approx(0.1) and ckpt["train_packed_gsd_m"] == pytest.approx(0.1)
    assert len(record["store_digest"]) == 64


def test_evaluate_scores_the_test_split_of_the_training_store_and_all_of_a_foreign_one(data):
    m, line, err = _evaluate(data, data["train"], "train")
    assert (m["split"], m["training_store"], m["n_images"]) == ("test", True, 2)
    record = json.loads((data["model"] / "train.json").read_text())
    assert [r["index"] for r in m["per_image"]] == record["test_indices"]
    assert m["labels"] == "exact" and m["gsd_matched"] and {r["gsd_scale"] for r in m["per_image"]} == {1.0}
    assert "2 test images in" in err
    # a copy of the training store elsewhere is still the training store (content digest, not path)
    copy = shutil.copytree(data["train"], data["root"] / "copy" / "train.zarr", dirs_exist_ok=True)
    assert _evaluate(data, copy, "copy")[0]["split"] == "test"
    every = _evaluate(data, data["train"], "train_all", "--split", "all")[0]
    assert (every["split"], every["n_images"]) == ("all (training store)", 8)
    m, line, err = _evaluate(data, data["boxes"], "boxes")
    assert (m["split"], m["training_store"], m["n_images"]) == ("all (foreign store)", False, 3)
    assert m["labels"] == "box-approximate" and {r["labels"] for r in m["per_image"]} == {"box-approximate"}
    assert line["labels"] == "box-approximate" and line["split"] == "all (foreign store)"
    assert "3 images (all (foreign store)) in" in err


def test_foreign_store_at_twice_the_gsd_is_resampled_by_two(data):
    m, line, _ = _evaluate(data, data["coarse"], "coarse")
    assert [r["gsd_scale"] for r in m["per_image"]] == [pytest.approx(2.0)] * 2
    assert m["per_image"][0]["packed_gsd_m"] == pytest.approx(0.2) and m["gsd_matched"] is True
    assert m["labels"] == "mixed" and [r["labels"] for r in m["per_image"]] == ["box-approximate", "exact"]
    out = data["root"] / "coarse_pred.zarr"
    assert _cli("predict", data["coarse"], "--model", data["model"], "--out", out)[0] == 0
    _, _, rec = load_prediction(out, 1)
    assert rec["gsd_scale"] == pytest.approx(2.0)


def test_predict_writes_the_mosaic_grid_and_agrees_with_evaluate(data):
    from metraw.io.store import RawStore

    out, fig_dir = data["root"] / "boxes_pred.zarr", data["root"] / "overlays"
    status, line, err = _cli("predict", data["boxes"], "--model", data["model"], "--out", out, "--overlay", fig_dir,
                             "--overlay-count", "2")
    assert status == 0, err
    assert json.loads(line)["n_images"] == 3 and "metraw predict: 3 images in" in err
    assert sorted(p.name for p in fig_dir.iterdir()) == ["overlay_0000.png", "overlay_0001.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in fig_dir.iterdir())
    m = _evaluate(data, data["boxes"], "boxes2")[0]
    store = RawStore.open(data["boxes"])
    tp = fp = fn = 0.0
    for i in range(len(store)):
        p, mask, rec = load_prediction(out, i)
        assert p.dtype == np.float32 and mask.dtype == bool and p.shape == mask.shape == (81, 81)
        y0, y1, x0, x1 = rec["packed_window"]
        assert (y0, y1, x0, x1) == (1, 81, 0, 80)  # GBRG: shifted one row to R G / G B, whole cells
        # the mask: probability > 0.5 less the objects under MIN_OBJECT_AREA_M2, judged inside the window
        gsd_m = rec["packed_gsd_m"] / 2
        inner = (p > 0.5)[y0:y1, x0:x1]
        assert np.all((p >= 0) & (p <= 1)) and not np.any(mask & ~(p > 0.5))
        np.testing.assert_array_equal(mask[y0:y1, x0:x1], drop_small_objects(inner, MIN_OBJECT_AREA_M2 / gsd_m ** 2))
        np.testing.assert_array_equal(mask[0], mask[1])  # outside the window: the nearest pixel's decision
        np.testing.assert_array_equal(p[0], p[1])  # the dropped first row: its nearest neighbour's value
        counts = confusion(mask[y0:y1, x0:x1], store[i].mask[y0:y1, x0:x1])
        assert counts == pytest.approx(tuple(m["per_image"][i][k] for k in ("tp", "fp", "fn")))
        tp, fp, fn = tp + counts[0], fp + counts[1], fn + counts[2]
    assert (tp, fp, fn) == pytest.approx((m["tp"], m["fp"], m["fn"]))
    import zarr

    attrs = zarr.open_group(str(out), mode="r").attrs["metraw_predict"]
    assert attrs["threshold"] == 0.5 and attrs["layout"] == "stacked" and attrs["gsd_scale"] == 1.0
    assert attrs["min_object_area_m2"] == MIN_OBJECT_AREA_M2
    assert attrs["store"] == str(data["boxes"]) and attrs["model"] == str(data["model"])
    # an existing output is refused without --overwrite, replaced with it
    assert _cli("predict", data["boxes"], "--model", data["model"], "--out", out)[0] == 2
    assert _cli("predict", data["boxes"], "--model", data["model"], "--out", out, "--overwrite")[0] == 0


def test_transforms_default_to_the_models_and_can_be_set(data):
    m8, line8, _ = _evaluate(data, data["boxes"], "t8")
    m1, line1, _ = _evaluate(data, data["boxes"], "t1", "--transforms", "1")
    assert (m8["transforms"], line8["transforms"], m1["transforms"], line1["transforms"]) == (8, 8, 1, 1)
    out8, out1 = data["root"] / "t8.zarr", data["root"] / "t1.zarr"
    assert _cli("predict", data["boxes"], "--model", data["model"], "--out", out8)[0] == 0
    assert _cli("predict", data["boxes"], "--model", data["model"], "--out", out1, "--transforms", "1")[0] == 0
    import zarr

    assert zarr.open_group(str(out1), mode="r").attrs["metraw_predict"]["transforms"] == 1
    p8, p1 = load_prediction(out8, 0)[0], load_prediction(out1, 0)[0]
    assert np.abs(p8 - p1).max() > 1e-3  # a network without symmetry: the average is another prediction
    for i, rec in enumerate(m1["per_image"]):  # one pass: predict's mask is what evaluate scored
        _, mask, info = load_prediction(out1, i)
        y0, y1, x0, x1 = info["packed_window"]
        from metraw.io.store import RawStore

        counts = confusion(mask[y0:y1, x0:x1], RawStore.open(data["boxes"])[i].mask[y0:y1, x0:x1])
        assert counts == pytest.approx(tuple(rec[k] for k in ("tp", "fp", "fn")))


def test_predict_needs_no_labels_and_stores_unequal_shapes_per_image(data):
    out, fig = data["root"] / "unlabelled_pred.zarr", data["root"] / "unlabelled.png"
    status, _, err = _cli("predict", data["unlabelled"], "--model", data["model"], "--out", out, "--overlay", fig)
    assert status == 0, err
    assert fig.read_bytes()[:4] == b"\x89PNG"
    shapes = []
    for i in range(2):
        p, mask, rec = load_prediction(out, i)
        assert rec["labels"] is None and not np.any(mask & ~(p > 0.5))
        shapes.append(p.shape)
    assert shapes == [(48, 48), (64, 64)]


def test_old_checkpoint_without_training_gsd_is_not_resampled(data, tmp_path):
    import torch

    old = shutil.copytree(data["model"], tmp_path / "old")
    ckpt = torch.load(old / "model.pt", weights_only=True)
    del ckpt["train_packed_gsd_m"]
    torch.save(ckpt, old / "model.pt")
    status, _, err = _cli("evaluate", data["coarse"], "--model", old, "--out", tmp_path / "m.json")
    assert status == 0, err
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["gsd_matched"] is False and "trained before train_packed_gsd_m" in m["gsd_note"]
    assert {r["gsd_scale"] for r in m["per_image"]} == {1.0} and "note: the checkpoint records no" in err


# ----------------------------------------------------------------- errors: one line, exit 2, nothing left
def _refused(argv, word, root):
    before = sorted(p.name for p in root.iterdir())
    status, _, err = _cli(*argv)
    assert status == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"metraw {argv[0]}: error: ") and word in lines[0], err
    assert sorted(p.name for p in root.iterdir()) == before


@pytest.fixture(scope="module")
def mono_model(data):
    from metraw.segment.train import TrainConfig, build_model, save_model

    cfg = TrainConfig(epochs=1, base_channels=4, depth=2)
    out = data["root"] / "mono_model"
    save_model(out, build_model(4, cfg, 1, 1), cfg, {"upsample": 1, "pool": 1, "in_channels": 4, "sensor": "mono",
                                                     "train_packed_gsd_m": None}, [0])
    return out


@pytest.fixture(scope="module")
def old_mono_model(data):
    """A mono model as metraw wrote it before mono mosaics packed in 2 x 2 cells: one input plane."""
    from metraw.segment.train import TrainConfig, build_model, save_model

    cfg = TrainConfig(epochs=1, base_channels=4, depth=2)
    out = data["root"] / "old_mono_model"
    save_model(out, build_model(1, cfg, 1, 1), cfg, {"upsample": 1, "pool": 1, "in_channels": 1,
                                                     "train_packed_gsd_m": None}, [0])
    return out


@pytest.mark.parametrize("command", ["evaluate", "predict"])
def test_errors(data, mono_model, old_mono_model, tmp_path, command):
    out = tmp_path / ("o.json" if command == "evaluate" else "o.zarr")
    run = [command, data["train"], "--model", data["model"], "--out", out]
    _refused([command, data["train"], "--model", tmp_path / "nope", "--out", out],
             "model directory", tmp_path)
    _refused([command, data["train"], "--model", mono_model, "--out", out], "sensor mismatch", tmp_path)
    _refused([command, data["train"], "--model", old_mono_model, "--out", out], "a mono model of an older metraw",
             tmp_path)
    (tmp_path / "not_a_store").mkdir()
    _refused([command, tmp_path / "not_a_store", *run[2:]], "is not a zarr v3 store", tmp_path)
    (tmp_path / "broken.zarr").mkdir()
    (tmp_path / "broken.zarr" / "zarr.json").write_text('{"zarr_format": 3, "node_')
    _refused([command, tmp_path / "broken.zarr", *run[2:]], "cannot open store", tmp_path)
    (tmp_path / "bad_model").mkdir()
    (tmp_path / "bad_model" / "model.pt").write_bytes(b"not a checkpoint")
    _refused([command, data["train"], "--model", tmp_path / "bad_model", "--out", out], "cannot read the model",
             tmp_path)
    if command == "evaluate":
        _refused([*run[:1], data["unlabelled"], *run[2:]], "has no label mask", tmp_path)
        _refused([command, data["boxes"], *run[2:], "--split", "test"], "differs from the one the model", tmp_path)
    else:
        _refused([*run, "--overlay", tmp_path / "f.png", "--overlay-count", "0"], "--overlay-count", tmp_path)
