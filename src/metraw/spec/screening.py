"""The adaptive sweep's screening by the box model (issue #70; docs/statistics.md, "Screening by the box model").

With ``target.adaptive.screen`` the pretrained box model (`metraw.segment.pretrain`: one network per replicate,
trained across the payload box, shared by every point) is scored alone, without fine-tuning, on the test split of
every range end and grid corner (`metraw.study.points.screen_points`): what the listed study and the unscreened
initial design train a point for, at the cost of an emulation and an evaluation. The IoU GP then takes each
screened point that is not trained as a measurement of the fine-tuned IoU:

    IoU(x) = IoU_box(x) + delta,        var = var_box(x) + s^2 (1 + 1/n)

delta, the IoU fine-tuning adds, is the mean of d_i = IoU_fine-tuned - IoU_box over the n trained points at the
nominal categories (each scored both ways on the same test images); s is the sample sd of those d_i when n >= 3
(their spread across the points: what delta does not capture at a new point, with the test-image noise of the
pairs), else ``target.adaptive.screen_offset_sd``; s^2 / n is delta's own error. The offset is taken as one value
for the whole study, its spread as independent per point: both stated in the aggregate (``screening``). A point
trained later replaces its screened row. The categorical values are trained, never screened.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.errors import MetrawError

#: A point's box-model score, as the workflow's rule ``screen`` writes it (``metraw aggregate --screen-pattern``).
DEFAULT_SCREEN = "{results}/points/{point}/screen.json"
#: Fewest pairs (trained points scored by the box model too) whose sample sd replaces ``screen_offset_sd``.
MIN_PAIRS_FOR_SD = 3


def offset(pairs: Sequence[Mapping[str, float]], prior_sd: float) -> dict[str, Any]:
    """delta and s from ``pairs`` (each ``fine_tuned``, ``box``: IoUs of one point): mean difference, its spread
    (sample sd with >= ``MIN_PAIRS_FOR_SD`` pairs, else ``prior_sd``) and the sd a screened row gets on top of its
    own, s sqrt(1 + 1/n)."""
    d = np.array([p["fine_tuned"] - p["box"] for p in pairs], dtype=np.float64)
    n = len(d)
    if n == 0:
        raise MetrawError("screening: no trained point has a box-model score (the nominal is always both)")
    measured = n >= MIN_PAIRS_FOR_SD
    s = float(np.std(d, ddof=1)) if measured else float(prior_sd)
    return {"offset": float(d.mean()), "offset_sd": s, "n_pairs": n,
            "offset_sd_from": "pairs" if measured else "target.adaptive.screen_offset_sd",
            "added_sd": s * math.sqrt(1.0 + 1.0 / n)}


def screened_rows(params: dict[str, Any], box: Mapping[str, tuple[float, float]],
                  trained_rows: Sequence[Mapping[str, Any]]) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The IoU GP's rows of the screened points that are not trained (parameters, ``iou``, ``iou_sd``, ``box_iou``,
    ``box_iou_sd``, ``screened: True``) and the ``screening`` record (offset, its sd and source, the pairs, the rows);
    ([], None) without screening. ``box``: point -> (IoU, its variance) of the box model at every screen point
    (`metraw.spec.aggregate.box_model_scores`); ``trained_rows``: the trained points' rows (`load_point_results`)."""
    from metraw.study.points import CATEGORICAL, adaptive_settings, screen_points, swept_parameters, target_params

    points = screen_points(params)
    if not points:
        return [], None
    missing = [p for p in points if p not in box]
    if missing:
        raise MetrawError(f"screening: no box-model score for {len(missing)} point(s), e.g. {missing[0]}")
    settings = adaptive_settings(params)
    names = swept_parameters(params)
    trained = {r["point"]: r for r in trained_rows}
    pairs = [{"point": p, "fine_tuned": float(trained[p]["iou"]), "box": box[p][0]} for p in points if p in trained]
    off = offset(pairs, settings["screen_offset_sd"])
    rows = []
    for point in points:
        if point in trained:
            continue
        tp = target_params(params, point)
        iou, var = box[point]
        rows.append({"point": point, **{n: tp[n] if n in CATEGORICAL else float(tp[n]) for n in names},
                     "iou": iou + off["offset"], "iou_sd": math.sqrt(var + off["added_sd"] ** 2),
                     "box_iou": iou, "box_iou_sd": math.sqrt(var), "screened": True})
    record = {**off, "pairs": [{**p, "difference": p["fine_tuned"] - p["box"]} for p in pairs],
              "rows": [{k: r[k] for k in ("point", "box_iou", "box_iou_sd", "iou", "iou_sd")} for r in rows],
              "rule": "IoU = IoU_box + offset, var = var_box + offset_sd^2 (1 + 1/n_pairs)"}
    return rows, record
