"""On-the-fly training from fresh target draws, replicates, and their IoU uncertainty (issue #15)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from metraw.emulate import emulate
from metraw.errors import MetrawError
from metraw.store import RawStore
from metraw.target import TargetSystem

PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """A 6-scene synthetic source (256 px) and its emulation at a 0.72 m GSD target (~20 px frames)."""
    from metraw.scenes import generate_one

    root = tmp_path_factory.mktemp("otf")
    target = dataclasses.replace(TargetSystem.from_params(str(PARAMS)), focal_length_m=2.0)
    scenes = [generate_one(i, 0, 256) for i in range(6)]
    with RawStore.create(root / "src.zarr") as s:
        for img in scenes:
            s.append(img)
    with RawStore.create(root / "tgt.zarr") as s:
        for i, img in enumerate(scenes):
            s.append(emulate(img, target, "auto", i))
    return root / "src.zarr", root / "tgt.zarr", target


def _cfg(**kw):
    from metraw.segment.train import TrainConfig

    base = dict(epochs=2, learning_rate=3e-3, batch_size=2, crop_px=16, base_channels=4, depth=2, seed=0,
                test_fraction=0.34, replicates=2)
    base.update(kw)
    return TrainConfig(**base)


def test_store_target_is_the_emulated_one(stores):
    from metraw.segment.onthefly import store_target

    src, tgt, target = stores
    assert store_target(RawStore.open(tgt)).gsd_m == pytest.approx(target.gsd_m)
    with pytest.raises(MetrawError, match="no emulated images"):
        store_target(RawStore.open(src))


def test_on_the_fly_replicates_are_deterministic_and_scored(stores, tmp_path):
    from metraw.segment.evaluate import evaluate_store
    from metraw.segment.onthefly import train_store_on_the_fly
    from metraw.segment.train import CHECKPOINT, TIMINGS, TRAIN_METRICS, replicate_dirs

    src, tgt, _ = stores
    for run in ("a", "b"):
        rec = train_store_on_the_fly(tgt, src, tmp_path / run, _cfg(), device="cpu", progress=False, codec_step=1.0)
    assert rec["on_the_fly"] and rec["replicate_seeds"] == [0, 1] and rec["draws"] == 4 * 2
    for rel in (CHECKPOINT, TRAIN_METRICS, f"replicate-1/{CHECKPOINT}"):
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    written = json.loads((tmp_path / "a" / TRAIN_METRICS).read_text())
    assert not set(TIMINGS) & set(written) and written["codec_step"] == 1.0
    assert [p.name for p in replicate_dirs(tmp_path / "a")] == ["replicate-1"]
    # the two seeds train different networks
    assert (tmp_path / "a" / CHECKPOINT).read_bytes() != (tmp_path / "a" / "replicate-1" / CHECKPOINT).read_bytes()
    m = evaluate_store(tgt, tmp_path / "a", device="cpu", progress=False)
    assert m["split"] == "test" and m["n_images"] == 2  # the store's own test split: never-trained scenes
    assert [r["seed"] for r in m["replicates"]] == [0, 1] and m["replicates"][0]["iou"] == m["iou"]
    ious = [r["iou"] for r in m["replicates"]]
    assert m["iou_replicate_mean"] == pytest.approx(np.mean(ious))
    assert m["iou_replicate_sd"] == pytest.approx(np.std(ious, ddof=1))
    assert m["iou_replicate_se"] == pytest.approx(np.std(ious, ddof=1) / np.sqrt(2))
    assert {"true_objects", "found_objects", "object_f1"} <= set(m)


def test_aggregate_adds_the_seed_spread_to_the_test_image_error():
    from metraw.cli.aggregate import iou_measurement

    per_image = [{"tp": tp, "fp": 2.0, "fn": 1.0} for tp in (1.0, 3.0, 2.0, 4.0)]
    single = {"iou": 0.5, "per_image": per_image}
    iou, var = iou_measurement(single, "x")
    assert iou == 0.5 and var > 0
    rep = {**single, "iou_replicate_mean": 0.45, "iou_replicate_se": 0.03}
    iou_r, var_r = iou_measurement(rep, "x")
    assert iou_r == 0.45 and var_r == pytest.approx(var + 0.03**2)


def test_static_baseline_reuses_one_draw_and_on_the_fly_does_not(stores):
    from metraw.segment.onthefly import build_fields, draw_prepared

    src, _, target = stores
    field = build_fields(RawStore.open(src), [0], target, progress=False)[0]
    a, b = draw_prepared(field, 0, 0), draw_prepared(field, 0, 1)
    assert not np.array_equal(a.z, b.z)  # a new draw each epoch
    assert np.array_equal(a.z, draw_prepared(field, 0, 0).z)  # and the same one for the same (seed, epoch)


def test_cli_on_the_fly_and_its_errors(stores, tmp_path, capsys):
    import yaml

    from metraw.cli import main

    src, tgt, _ = stores
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"training": {"profile": "tiny", "split_seed": 0, "test_fraction": 0.34,
                                                   "profiles": {"tiny": dict(epochs=1, batch_size=2, crop_px=16,
                                                                             base_channels=4, depth=2)}}}))
    assert main(["train", str(tgt), "--source", str(src), "--out", str(tmp_path / "m"), "--params", str(params),
                 "--replicates", "2"]) == 0
    assert "4 scenes drawn on the fly, 1 epoch(s), 2 replicate(s)" in capsys.readouterr().err
    assert (tmp_path / "m" / "replicate-1" / "model.pt").is_file()
    # a source that is not the store's (another image count): one line, nothing written
    with RawStore.create(tmp_path / "short.zarr") as s:
        s.append(RawStore.open(src)[0])
    assert main(["train", str(tgt), "--source", str(tmp_path / "short.zarr"), "--out", str(tmp_path / "m2"),
                 "--params", str(params)]) == 2
    assert "not emulated from that source" in capsys.readouterr().err
    assert not (tmp_path / "m2").exists()
    assert main(["train", str(tgt), "--codec-step", "1", "--out", str(tmp_path / "m3"), "--params", str(params)]) == 2
    assert "--codec-step applies to on-the-fly draws only" in capsys.readouterr().err
