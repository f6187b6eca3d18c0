"""What a run can resolve (metraw.spec.resolution): the smallest IoU difference between two points at 2 sigma,
checked against the spread of measured differences of points that do not differ; a one-image test split resolves
nothing and says so."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metraw.spec.aggregate import iou_measurement
from metraw.spec.resolution import ONE_IMAGE_SD, RESOLUTION_FACTOR, log_lines, point_sd, resolution, spec_context


def _point(rng, n_images: int, iou: float) -> dict:
    """A point's metrics as `metraw evaluate` writes them: per-image tp/fp/fn of about ``iou``."""
    u = rng.uniform(50, 150, n_images)
    tp = u * np.clip(iou + rng.normal(0, 0.15, n_images), 0, 1)
    recs = [{"tp": float(a), "fp": float((c - a) / 2), "fn": float((c - a) / 2)} for a, c in zip(tp, u)]
    return {"iou": float(tp.sum() / u.sum()), "per_image": recs, "n_images": n_images}


def _row(metrics: dict, name: str) -> dict:
    iou, var = iou_measurement(metrics, name)
    tp, fn = (sum(r[k] for r in metrics["per_image"]) for k in ("tp", "fn"))
    return {"point": name, "iou": iou, "iou_sd": var ** 0.5, "n_test_images": metrics["n_images"], "n_replicates": 1,
            "recall": tp / (tp + fn) if tp + fn > 0 else None}


def test_two_equal_points_differ_by_more_than_the_resolvable_difference_five_percent_of_the_time(tmp_path):
    """Points of the same true IoU, each on its own 40 test images: |IoU_1 - IoU_2| exceeds delta = 2 sqrt(2) sigma
    in ~4.6 % of the pairs (two-sided 2 sigma of a normal difference); 2000 pairs give +- 0.5 % (1 sd)."""
    rng = np.random.default_rng(0)
    exceed, deltas = 0, []
    for k in range(2000):
        rows = [_row(_point(rng, 40, 0.5), f"p{i}") for i in range(2)]
        sigma = np.median([r["iou_sd"] for r in rows])
        deltas.append(RESOLUTION_FACTOR * sigma)
        exceed += abs(rows[0]["iou"] - rows[1]["iou"]) > RESOLUTION_FACTOR * sigma
    assert exceed / 2000 == pytest.approx(0.0455, abs=0.02)
    # the same definition through resolution(): the nominal metrics file gives the test split's size
    metrics = _point(rng, 40, 0.5) | {"true_objects": 57}
    (tmp_path / "m.json").write_text(json.dumps(metrics))
    rows = [_row(metrics, "nominal"), _row(_point(rng, 40, 0.3), "far")]
    res = resolution(rows, tmp_path / "m.json")
    assert res["test_images"] == 40 and res["test_cars"] == 57 and res["per_image_error"] == "measured"
    assert res["resolvable_iou_difference"] == pytest.approx(RESOLUTION_FACTOR * np.median([r["iou_sd"] for r in rows]))
    assert 0.02 < res["resolvable_iou_difference"] < 0.2 < res["iou_spread"] and res["resolves_points"]
    assert spec_context(res) == {"test_split": {"images": 40, "cars": 57},
                                 "resolvable_iou_difference": res["resolvable_iou_difference"]}
    assert len(log_lines(res)) == 1  # no warning: the points lie further apart than the run resolves


def test_a_one_image_test_split_resolves_nothing_and_warns(tmp_path):
    rng = np.random.default_rng(1)
    metrics = [_point(rng, 1, iou) for iou in (0.2, 0.4, 0.6)]
    (tmp_path / "m.json").write_text(json.dumps(metrics[0] | {"true_objects": 3}))
    rows = [_row(m, f"p{i}") | {"n_replicates": 2, "iou_replicate_sd": 0.1} for i, m in enumerate(metrics)]
    assert all(r["iou_sd"] == 0 for r in rows)  # one image: the measured variance is 0, which is no error bar
    assert point_sd(rows[0]) == pytest.approx((ONE_IMAGE_SD ** 2 + 0.1 ** 2 / 2) ** 0.5)
    res = resolution(rows, tmp_path / "m.json")
    assert res["resolvable_iou_difference"] > 1.41 and not res["resolves_points"]
    assert res["per_image_error"].startswith("bounded")
    info, warning = log_lines(res)
    assert "test split: 1 images, 3 cars" in info
    assert "warning" in warning and "cannot tell its points apart" in warning


def test_a_test_split_without_car_area_at_every_point_warns(tmp_path):
    rng = np.random.default_rng(2)
    rows = [_row(_point(rng, 3, 0.5), f"p{i}") | {"recall": None} for i in range(3)]
    (tmp_path / "m.json").write_text(json.dumps(_point(rng, 3, 0.5)))
    res = resolution(rows, tmp_path / "m.json")
    assert not res["test_split_has_cars"]
    assert any("no car area in the test split at any point" in line for line in log_lines(res)[1:])
    rows[1]["recall"] = 0.4  # one point's test images hold cars
    res = resolution(rows, tmp_path / "m.json")
    assert res["test_split_has_cars"] and not any("no car area" in line for line in log_lines(res))
