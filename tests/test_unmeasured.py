"""Degenerate segmenters (issue #71): `metraw evaluate` marks a model that predicts no car (or every pixel car) on
the whole test split, and `metraw aggregate` keeps a point whose every model is degenerate out of the fit, lists it as
unmeasured, drops a point's degenerate replicates from its mean, and writes nothing when no point was measured.

The aggregate tests run on metrics made by `metraw.segment.evaluate`'s own summary functions from hand-made per-image
counts (fast); the evaluation tests on a tiny trained model whose output layer is set to call nothing (or everything)
car, the state a collapsed training ends in."""

from __future__ import annotations

import json
import math
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

from metraw.segment.degenerate import EVERYTHING, NOTHING, degeneracy
from metraw.segment.evaluate import point_degeneracy, replicate_summary, summarise

REPO = Path(__file__).resolve().parents[1]
SHAPE = [4, 40, 40]  # packed shape of one hand-made test image: 6400 sites


def _records(rng, n: int, iou: float, kind: str | None = None) -> list[dict]:
    """Per-image records of one model on ``n`` test images of 6400 sites: pooled IoU about ``iou``; ``kind`` NOTHING:
    no pixel predicted car, EVERYTHING: every pixel."""
    out = []
    for _ in range(n):
        true = float(rng.uniform(300, 600))
        if kind == NOTHING:
            tp, fp = 0.0, 0.0
        elif kind == EVERYTHING:
            tp, fp = true, math.prod(SHAPE) - true
        else:
            tp = true * float(np.clip(iou + rng.normal(0, 0.03), 0.05, 0.95))
            fp = 0.5 * (true - tp)
        out.append({"shape": SHAPE, "tp": tp, "fp": fp, "fn": true - tp,
                    "iou": tp / (tp + fp + true - tp) if true else None})
    return out


def _metrics(rng, iou: float, kinds: list[str | None], n: int = 6) -> dict:
    """A metrics record as `metraw evaluate` writes it for a model with len(kinds) replicates (kinds[i]: model i's
    degeneracy, None for a working model at IoU about ``iou``)."""
    recs = [_records(rng, n, iou + 0.01 * i, k) for i, k in enumerate(kinds)]
    out = {**summarise(recs[0]), "per_image": recs[0], "epochs": 3}
    out.update(degeneracy(recs[0]))
    if len(kinds) > 1:
        out.update(replicate_summary(out, [(i, r) for i, r in enumerate(recs[1:], 1)], 0))
    out.update(point_degeneracy(out))
    return out


def _params(root: Path, focal=(1.0, 1.2)) -> dict:
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["target"]["sweeps"] = {"focal_length_m": list(focal), "diameter_m": [0.35, 0.5], "exposure_s": [300.0e-6]}
    params["target"].pop("grids", None)
    root.mkdir(parents=True, exist_ok=True)
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return params


def _study(root: Path, kinds: dict[str, list], focal=(1.0, 1.2), replicates: int = 3) -> dict[str, dict]:
    """A study's hand-made metrics: IoU rising with diameter and falling away from f = 1.644 m; ``kinds[point]``:
    the degeneracy of each of its models (default: all working)."""
    from metraw.study.points import parameter_points, target_params

    params = _params(root, focal)
    made = {}
    for point in parameter_points(params):
        tp = target_params(params, point)
        iou = 0.3 + 0.4 * (tp["diameter_m"] - 0.2) - 0.2 * abs(tp["focal_length_m"] - 1.644)
        m = _metrics(np.random.default_rng(zlib.crc32(point.encode())), iou, kinds.get(point, [None] * replicates))
        path = root / "results" / point / "metrics.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(m))
        made[point] = m
    return made


def _aggregate(root: Path, out: str = "out") -> int:
    from metraw.cli import main

    return main(["aggregate", "--params", str(root / "params.yaml"), "--results", str(root / "results"),
                 "--out", str(root / out), "--compression-pattern", ""])


# ----------------------------------------------------------------------------- the verdict
def test_degeneracy_counts_predicted_and_true_car_pixels():
    rng = np.random.default_rng(0)
    nothing = degeneracy(_records(rng, 3, 0.4, NOTHING))
    assert nothing["degenerate"] and nothing["degenerate_reason"] == NOTHING
    assert nothing["predicted_car_px"] == 0 and nothing["scored_px"] == 3 * 6400 and nothing["true_car_px"] > 900
    every = degeneracy(_records(rng, 3, 0.4, EVERYTHING))
    assert every["degenerate_reason"] == EVERYTHING and every["predicted_car_px"] == 3 * 6400
    working = degeneracy(_records(rng, 3, 0.4))
    assert not working["degenerate"] and working["degenerate_reason"] is None
    assert 0 < working["predicted_car_px"] < 3 * 6400
    # one predicted pixel on one image is a prediction: the rule is about the whole split
    recs = _records(rng, 3, 0.4, NOTHING)
    recs[1].update(tp=1.0, fn=recs[1]["fn"] - 1.0)
    assert not degeneracy(recs)["degenerate"]
    # a split without cars predicted as such is right, not degenerate
    empty = [{"shape": SHAPE, "tp": 0.0, "fp": 0.0, "fn": 0.0}]
    assert not degeneracy(empty)["degenerate"]


def test_point_is_degenerate_only_when_every_model_is():
    rng = np.random.default_rng(1)
    some = _metrics(rng, 0.4, [None, NOTHING, None])
    assert [r["degenerate"] for r in some["replicates"]] == [False, True, False]
    assert some["replicates"][1]["predicted_car_px"] == 0
    assert not some["degenerate"] and some["n_degenerate_models"] == 1 and some["n_models"] == 3
    every = _metrics(rng, 0.4, [NOTHING, EVERYTHING, NOTHING])
    assert every["degenerate"] and every["n_degenerate_models"] == 3 and every["degenerate_reason"] == NOTHING
    single = _metrics(rng, 0.4, [NOTHING])
    assert single["degenerate"] and single["n_models"] == 1 and "replicates" not in single


# ----------------------------------------------------------------------------- the aggregate
def test_a_degenerate_point_is_left_out_and_the_others_fit(tmp_path, capsys):
    bad = "focal_length_m-1.0"
    _study(tmp_path / "a", {bad: [NOTHING, NOTHING, NOTHING]})
    assert _aggregate(tmp_path / "a") == 0
    printed = capsys.readouterr().out
    table = json.loads((tmp_path / "a" / "out" / "aggregate.json").read_text())
    assert bad not in [r["point"] for r in table["points"]] and len(table["points"]) == 5
    (entry,) = table["unmeasured_points"]
    assert entry["point"] == bad and entry["focal_length_m"] == 1.0 and "iou" not in entry
    assert entry["n_models"] == 3 and all(m["predicted_car_px"] == 0 for m in entry["models"])
    assert all(m["true_car_px"] > 0 for m in entry["models"]) and "quick.yaml" in entry["levers"]
    assert table["iou_gp"]["leave_one_out"]["n"] == 5
    spec = yaml.safe_load((tmp_path / "a" / "out" / "spec.yaml").read_text())
    assert [p["point"] for p in spec["context"]["unmeasured_points"]] == [bad]
    lines = [ln for ln in printed.splitlines() if "unmeasured:" in ln]
    assert len(lines) == 1 and bad in lines[0] and "0 of 38400 px predicted car" in lines[0]
    assert "epochs" in lines[0] and "quick.yaml" in lines[0]
    # left out = as if the point had not been asked for: the same GP, tolerances and joint region as a study
    # without f = 1.0 m (the other points' metrics are the same files)
    made = _study(tmp_path / "b", {}, focal=(1.2,))
    for point in made:
        assert (tmp_path / "b" / "results" / point / "metrics.json").read_bytes() == \
            (tmp_path / "a" / "results" / point / "metrics.json").read_bytes()
    assert _aggregate(tmp_path / "b") == 0
    ref = json.loads((tmp_path / "b" / "out" / "aggregate.json").read_text())
    for key in ("iou_gp", "tolerances", "joint_region", "points"):
        assert table[key] == ref[key], key
    assert (tmp_path / "a" / "out" / "figures" / "fig7c_iou_focal_length.png").is_file()


def test_no_measured_point_writes_nothing_and_exits_2(tmp_path, capsys):
    from metraw.study.points import parameter_points

    params = _params(tmp_path)
    _study(tmp_path, {p: [NOTHING] for p in parameter_points(params)}, replicates=1)
    assert _aggregate(tmp_path) == 2
    cap = capsys.readouterr()
    err = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert len(err) == 1 and "no point was measured" in err[0] and "6 of 6 points unmeasured" in err[0]
    assert len([ln for ln in cap.out.splitlines() if "unmeasured:" in ln]) == 6
    assert not (tmp_path / "out").exists()


def test_too_few_measured_points_for_the_gp_write_nothing(tmp_path, capsys):
    kinds = {p: [EVERYTHING] for p in ("nominal", "focal_length_m-1.0", "focal_length_m-1.2", "diameter_m-0.35")}
    _study(tmp_path, kinds, replicates=1)
    assert _aggregate(tmp_path) == 2
    assert "only 2 measured point(s) for the IoU GP" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_degenerate_replicates_are_dropped_from_the_point_mean(tmp_path):
    made = _study(tmp_path, {"diameter_m-0.5": [None, NOTHING, None], "diameter_m-0.35": [NOTHING, None, None]})
    assert _aggregate(tmp_path) == 0
    table = json.loads((tmp_path / "out" / "aggregate.json").read_text())
    rows = {r["point"]: r for r in table["points"]}
    assert "unmeasured_points" not in table
    for point, gone in (("diameter_m-0.5", 1), ("diameter_m-0.35", 0)):
        reps = made[point]["replicates"]
        kept = [r["iou"] for i, r in enumerate(reps) if i != gone]
        row = rows[point]
        assert row["degenerate_replicates"] == [gone] and "1 of 3 replicate models degenerate" in row["degenerate_note"]
        assert row["iou"] == pytest.approx(np.mean(kept)) and row["n_replicates"] == 2
        assert row["replicate_ious"] == pytest.approx(kept)
        seed_se = np.std(kept, ddof=1) / math.sqrt(2)
        assert row["iou_sd"] > seed_se  # the test-image error comes on top, from a working model's counts
    # with the first model gone, the test-image term is the first working replicate's
    from metraw.spec.aggregate import iou_measurement

    rep1 = made["diameter_m-0.35"]["replicates"][1]
    alone = {"iou": rep1["iou"], "per_image": [dict(zip(("tp", "fp", "fn"), c)) for c in rep1["per_image_counts"]]}
    kept = [r["iou"] for r in made["diameter_m-0.35"]["replicates"][1:]]
    expected = iou_measurement(alone, "x")[1] + (np.std(kept, ddof=1) / math.sqrt(2)) ** 2
    assert rows["diameter_m-0.35"]["iou_sd"] == pytest.approx(math.sqrt(expected))
    # the working points are untouched
    assert "degenerate_replicates" not in rows["nominal"]
    assert rows["nominal"]["iou"] == pytest.approx(made["nominal"]["iou_replicate_mean"])


def test_verdict_fields_change_no_byte_of_a_study_without_degenerate_models(tmp_path):
    """The default study: no point degenerate, so the aggregate writes what it wrote before the verdict existed
    (metrics without the verdict fields, as metraw evaluate wrote them before issue #71)."""
    made = _study(tmp_path / "new", {})
    _params(tmp_path / "old")
    old_keys = ("degenerate", "degenerate_reason", "predicted_car_px", "true_car_px", "scored_px",
                "n_degenerate_models", "n_models")
    for point, m in made.items():
        old = {k: v for k, v in m.items() if k not in old_keys}
        old["replicates"] = [{k: v for k, v in r.items() if k not in old_keys and k != "per_image_counts"}
                             for r in m["replicates"]]
        (tmp_path / "old" / "results" / point).mkdir(parents=True)
        (tmp_path / "old" / "results" / point / "metrics.json").write_text(json.dumps(old))
    assert _aggregate(tmp_path / "new") == 0 and _aggregate(tmp_path / "old") == 0
    for name in ("aggregate.json", "spec.yaml"):
        new = (tmp_path / "new" / "out" / name).read_text().replace(str(tmp_path / "new"), "ROOT")
        old = (tmp_path / "old" / "out" / name).read_text().replace(str(tmp_path / "old"), "ROOT")
        assert new == old, name
    assert "unmeasured" not in (tmp_path / "new" / "out" / "aggregate.json").read_text()


def test_metrics_written_before_the_verdict_still_mark_a_model_that_predicts_nothing(tmp_path):
    from metraw.spec.unmeasured import point_status

    m = _metrics(np.random.default_rng(3), 0.4, [NOTHING, NOTHING])
    for r in m["replicates"]:
        for k in ("degenerate", "degenerate_reason", "predicted_car_px", "true_car_px", "scored_px"):
            r.pop(k)
    status = point_status(m)
    assert status["unmeasured"] and [v["degenerate_reason"] for v in status["models"]] == [NOTHING, NOTHING]
    single = _metrics(np.random.default_rng(4), 0.4, [EVERYTHING])
    for k in ("degenerate", "degenerate_reason"):
        single.pop(k)
    assert point_status(single)["models"][0]["degenerate_reason"] == EVERYTHING  # from its per-image records


# ----------------------------------------------------------------------------- metraw evaluate on a collapsed model
@pytest.fixture(scope="module")
def collapsed(tmp_path_factory):
    """A toy store and a tiny model with one replicate, trained for one epoch, whose models' output layers are then set
    to call every pixel background (logit -50): what a training that collapsed leaves behind."""
    from metraw.segment.toy import toy_store
    from metraw.segment.train import TrainConfig, train_store

    root = tmp_path_factory.mktemp("collapsed")
    toy_store(root / "toy.zarr", 12, 96, seed=2)
    config = TrainConfig(epochs=1, learning_rate=3e-3, batch_size=4, crop_px=32, base_channels=4, depth=2, seed=0,
                         test_fraction=0.25, replicates=2)
    train_store(root / "toy.zarr", root / "model", config, device="cpu", progress=False)
    return root


def _set_head_bias(model_dir: Path, value: float) -> None:
    import torch

    from metraw.segment.train import CHECKPOINT

    ckpt = torch.load(model_dir / CHECKPOINT, weights_only=False)
    (key,) = [k for k in ckpt["state_dict"] if k.endswith("head.bias")]
    ckpt["state_dict"][key] = torch.full_like(ckpt["state_dict"][key], value)
    torch.save(ckpt, model_dir / CHECKPOINT)


def test_evaluate_marks_a_collapsed_model_and_its_point(collapsed, tmp_path, capsys):
    from metraw.cli import main

    model = collapsed / "model"
    _set_head_bias(model, -50.0)  # the first model calls nothing car; its replicate still works
    assert main(["evaluate", str(collapsed / "toy.zarr"), "--model", str(model), "--out", str(tmp_path / "a.json")]) == 0
    m = json.loads((tmp_path / "a.json").read_text())
    first, second = m["replicates"]
    assert first["degenerate"] and first["degenerate_reason"] == NOTHING and first["predicted_car_px"] == 0
    assert first["true_car_px"] == pytest.approx(sum(r["tp"] + r["fn"] for r in m["per_image"]))
    assert first["scored_px"] == sum(math.prod(r["shape"]) for r in m["per_image"]) == 3 * 96 * 96
    assert not second["degenerate"] and second["predicted_car_px"] > 0
    assert len(second["per_image_counts"]) == 3
    assert not m["degenerate"] and m["n_degenerate_models"] == 1 and m["n_models"] == 2
    assert m["iou"] == 0.0 and m["precision"] is None and m["predicted_car_px"] == 0
    assert "1 of 2 model(s) degenerate: no predicted car pixel (0 of 27648 px" in capsys.readouterr().err
    _set_head_bias(model / "replicate-1", 50.0)  # and the replicate every pixel
    assert main(["evaluate", str(collapsed / "toy.zarr"), "--model", str(model), "--out", str(tmp_path / "b.json")]) == 0
    m = json.loads((tmp_path / "b.json").read_text())
    assert m["degenerate"] and m["n_degenerate_models"] == 2 and m["degenerate_reason"] == NOTHING
    assert m["replicates"][1]["degenerate_reason"] == EVERYTHING
    assert m["replicates"][1]["predicted_car_px"] == 3 * 96 * 96
    capsys.readouterr()
    # a tiny study of such models: every point unmeasured, named, no spec and exit 2
    from metraw.study.points import parameter_points

    params = _params(tmp_path / "study")
    for point in parameter_points(params):
        (tmp_path / "study" / "results" / point).mkdir(parents=True)
        (tmp_path / "study" / "results" / point / "metrics.json").write_text(json.dumps(m))
    assert _aggregate(tmp_path / "study") == 2
    cap = capsys.readouterr()
    assert "no point was measured" in cap.err and not (tmp_path / "study" / "out").exists()
    named = [ln for ln in cap.out.splitlines() if "unmeasured:" in ln]
    assert len(named) == 6 and "every pixel predicted car; no predicted car pixel" in named[0]
    assert f"0 of {3 * 96 * 96} px predicted car" in named[0]
