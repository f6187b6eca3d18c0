"""What a study's test split can resolve (docs/statistics.md, "What a run can resolve").

Each point's IoU carries a standard error ``iou_sd`` (``metraw.spec.aggregate.iou_measurement``: the per-image
sampling error of the pooled IoU plus the replicate models' standard error). Two points measured with errors
sigma_1 and sigma_2 differ by more than two standard deviations of their difference when
|IoU_1 - IoU_2| > 2 sqrt(sigma_1^2 + sigma_2^2); with the typical error sigma (the median over the points) the
smallest IoU difference the run resolves is

    delta = 2 sqrt(2) sigma.

A test split of one image has no per-image spread to measure: there sigma's per-image term is its bound, 0.5
(Popoviciu: a quantity in [0, 1] has a standard deviation of at most 0.5), so delta >= 1.41 and the run resolves
nothing. The aggregate warns when delta exceeds the spread of the points' IoUs (max - min): the study cannot tell
its points apart, and its tolerances rest on noise; it warns too when the test split holds no car area at any point
(recall undefined everywhere: the emulation can lose a source's sliver of a car at the image's edge; a user's folder
whose test split holds no car is refused before anything runs, ``metraw check-folder``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

#: delta = RESOLUTION_FACTOR x sigma: two standard deviations of the difference of two points' IoUs.
RESOLUTION_FACTOR = 2.0 * math.sqrt(2.0)
#: The standard deviation bound of a quantity in [0, 1] (Popoviciu), a one-image test split's per-image term.
ONE_IMAGE_SD = 0.5


def point_sd(row: dict[str, Any]) -> float:
    """A point's IoU standard error; with one test image, the per-image term is ``ONE_IMAGE_SD`` (unmeasurable)."""
    if (row.get("n_test_images") or 0) >= 2:
        return float(row["iou_sd"])
    reps = int(row.get("n_replicates") or 1)
    rep_se = float(row.get("iou_replicate_sd") or 0.0) / math.sqrt(reps) if reps > 1 else 0.0
    return math.sqrt(ONE_IMAGE_SD ** 2 + rep_se ** 2)


def test_split(metrics_path: str | Path) -> dict[str, int | None]:
    """The test split's size from a point's metrics file: images and cars (ground-truth objects; None when the
    metrics do not count them)."""
    metrics = json.loads(Path(metrics_path).read_text())
    cars = metrics.get("true_objects")
    return {"images": int(metrics.get("n_images") or 0), "cars": None if cars is None else int(cars)}


def resolution(rows: list[dict[str, Any]], nominal_metrics: str | Path) -> dict[str, Any]:
    """The test split's size (at the nominal point), the typical IoU error, the smallest resolvable IoU difference
    and whether it is below the IoU spread over the measured points (rows with a finite IoU)."""
    measured = [r for r in rows if r.get("iou") is not None and math.isfinite(float(r["iou"]))]
    sds = [point_sd(r) for r in measured]
    ious = [float(r["iou"]) for r in measured]
    sigma = float(np.median(sds)) if sds else math.inf
    delta = RESOLUTION_FACTOR * sigma
    spread = max(ious) - min(ious) if ious else 0.0
    split = test_split(nominal_metrics)
    return {"test_images": split["images"], "test_cars": split["cars"], "iou_sd_median": sigma,
            "test_split_has_cars": any(r.get("recall") is not None for r in measured),
            "resolvable_iou_difference": delta, "iou_spread": spread, "resolves_points": bool(delta < spread),
            "per_image_error": "measured" if split["images"] >= 2 else
            f"bounded ({ONE_IMAGE_SD}: one test image has no per-image spread)",
            "definition": "2 sqrt(2) x the median IoU standard error of the points (per-image and replicate "
                          "spread): the smallest IoU difference between two points at 2 sigma"}


def spec_context(res: dict[str, Any]) -> dict[str, Any]:
    """What spec.yaml states of the run's resolution (its context section)."""
    return {"test_split": {"images": res["test_images"], "cars": res["test_cars"]},
            "resolvable_iou_difference": res["resolvable_iou_difference"]}


def log_lines(res: dict[str, Any]) -> list[str]:
    """The aggregate log's lines: the test split and the resolvable difference, and a warning when it exceeds the
    points' IoU spread."""
    cars = "cars not counted" if res["test_cars"] is None else f"{res['test_cars']} cars"
    lines = [f"  test split: {res['test_images']} images, {cars}; resolvable IoU difference "
             f"{res['resolvable_iou_difference']:.3f} (2 sqrt(2) x median IoU sd {res['iou_sd_median']:.3f}; "
             f"per-image error {res['per_image_error']})"]
    if not res["test_split_has_cars"]:
        lines.append("metraw aggregate: warning: no car area in the test split at any point (recall undefined "
                     "everywhere): the IoU measures false alarms only")
    if not res["resolves_points"]:
        lines.append(f"metraw aggregate: warning: the resolvable IoU difference {res['resolvable_iou_difference']:.3f}"
                     f" exceeds the IoU spread over the points ({res['iou_spread']:.3f}): this run cannot tell its "
                     f"points apart (test split of {res['test_images']} images; more test images or replicates)")
    return lines
