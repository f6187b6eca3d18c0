"""Points that measured nothing (issue #71): the aggregate's handling of degenerate segmenters.

A model that predicts no car pixel on the whole test split, or every pixel car, is a failed training
(`metraw.segment.degenerate`; `metraw evaluate` marks it in metrics.json). Its IoU is not a measurement of the
payload, and an IoU of 0 with no spread would pull the GP down and fool any rule that compares IoU differences
with their errors. So, per point:

- every model degenerate (the first and all its replicates): the point is **unmeasured**. It is left out of
  everything fitted (IoU GP, tolerances, joint region, categorical choice, grid maps, property model, the compression
  ratio GP too, so that both GPs stand on the same points; its compression ratio is measured all the same and
  listed), listed under ``unmeasured_points`` in aggregate.json and under ``context.unmeasured_points`` in spec.yaml,
  drawn as a red x on the figures' axis (not as IoU 0), and `metraw aggregate` prints one line for it with the
  counts it saw and the levers (``metraw.segment.degenerate.LEVERS``).
- some models degenerate: those replicates are **dropped** from the point's mean and error (``drop_models``: the
  mean and seed spread of the others; the test-image error of the first model left), the same seeds from its
  real-image scores; the row then says which (``degenerate_replicates``) and the point is fitted as usual.
- none degenerate: nothing changes (no key is added: the aggregate's output is byte for byte what it was).

When no point is measured the aggregate writes nothing: one line, exit status 2 (``require_measured``).
Metrics written before the verdict was recorded: a model whose precision is undefined predicted no car pixel
(TP + FP = 0), and the first model's per-image records give the full verdict.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.segment.degenerate import LEVERS, NOTHING, degeneracy

#: The keys of one model's verdict.
VERDICT_KEYS = ("degenerate", "degenerate_reason", "predicted_car_px", "true_car_px", "scored_px")


def _model_verdict(record: dict[str, Any], per_image: list[dict[str, Any]] | None) -> dict[str, Any]:
    """One model's verdict: as recorded; else from its per-image records (with shapes); else from its precision."""
    if "degenerate_reason" in record:
        return {k: record.get(k) for k in VERDICT_KEYS}
    if per_image and all("shape" in r and "tp" in r for r in per_image):
        return degeneracy(per_image)
    nothing = record.get("precision") is None and record.get("iou") is not None
    return {"degenerate": nothing, "degenerate_reason": NOTHING if nothing else None, "predicted_car_px": None,
            "true_car_px": None, "scored_px": None}


def model_verdicts(metrics: dict[str, Any]) -> list[dict[str, Any]]:
    """Every model's verdict (first model, then its replicates), each with its training seed (None without
    replicates)."""
    reps = metrics.get("replicates") or []
    if not reps:
        first = {k: metrics.get(k) for k in ("iou", "precision")}
        if "degenerate_reason" in metrics:  # a single model: its own verdict is the point's
            first.update({k: metrics.get(k) for k in VERDICT_KEYS})
        return [{"seed": None, **_model_verdict(first, metrics.get("per_image"))}]
    return [{"seed": r.get("seed"), **_model_verdict(r, metrics.get("per_image") if i == 0 else None)}
            for i, r in enumerate(reps)]


def drop_models(metrics: dict[str, Any], seeds: list[Any]) -> dict[str, Any]:
    """``metrics`` without the replicate models of ``seeds``: replicates, n_replicates and the replicate mean, sd and
    se of the others; when the first model goes, its IoU, precision, recall, object F1 and per-image counts are the
    first remaining model's (``per_image_counts`` of its replicate record; none in metrics written before them: the
    test-image error is then left out). Returned as it is for no ``seeds``."""
    if not seeds:
        return metrics
    reps = metrics.get("replicates") or []
    kept = [r for r in reps if r.get("seed") not in seeds]
    if not kept or len(kept) == len(reps):
        return metrics
    out = dict(metrics, replicates=kept, n_replicates=len(kept))
    ious = np.array([r["iou"] for r in kept if r.get("iou") is not None], dtype=np.float64)
    sd = float(ious.std(ddof=1)) if ious.size > 1 else None
    out.update(iou_replicate_mean=float(ious.mean()) if ious.size else None, iou_replicate_sd=sd,
               iou_replicate_se=sd / math.sqrt(ious.size) if sd is not None else None)
    if reps[0].get("seed") in seeds:
        first = kept[0]
        out.update({k: first.get(k) for k in ("iou", "precision", "recall", "object_f1")})
        out["per_image"] = [{"tp": tp, "fp": fp, "fn": fn} for tp, fp, fn in first.get("per_image_counts", [])]
    return out


def point_status(metrics: dict[str, Any]) -> dict[str, Any]:
    """{"models": verdicts, "unmeasured": every model degenerate, "dropped": seeds of the degenerate replicates to
    leave out of a measured point (empty for an unmeasured one: nothing of it is fitted)}."""
    models = model_verdicts(metrics)
    bad = [m for m in models if m["degenerate"]]
    unmeasured = len(bad) == len(models)
    return {"models": models, "unmeasured": unmeasured, "dropped": [] if unmeasured else [m["seed"] for m in bad]}


def row_fields(status: dict[str, Any], n_models: int) -> dict[str, Any]:
    """What a point's row gains: nothing for a point without degenerate models (the output stays byte for byte),
    ``degenerate_replicates`` (seeds) and a note for one with some, the private ``_unmeasured`` (its verdicts, not
    written with the row) for one with all."""
    if status["unmeasured"]:
        return {"_unmeasured": status["models"]}
    if status["dropped"]:
        return {"degenerate_replicates": status["dropped"],
                "degenerate_note": f"{len(status['dropped'])} of {n_models} replicate models degenerate "
                                   f"(seeds {', '.join(map(str, status['dropped']))}): left out of this point's mean "
                                   "and error"}
    return {}


def split(rows: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(measured rows, unmeasured rows), each in the given order."""
    return [r for r in rows if "_unmeasured" not in r], [r for r in rows if "_unmeasured" in r]


def entry(row: dict[str, Any], names: list[str]) -> dict[str, Any]:
    """An unmeasured point as aggregate.json and spec.yaml list it: its parameters, why, each model's counts, the
    levers; no IoU (it measured none)."""
    models = row["_unmeasured"]
    reasons = sorted({m["degenerate_reason"] for m in models})
    out = {"point": row["point"], **{n: row[n] for n in names},
           "reason": f"every model degenerate ({'; '.join(reasons)}): a failed training, not an IoU",
           "n_models": len(models), "n_test_images": row.get("n_test_images"), "epochs": row.get("epochs"),
           "models": [{k: m[k] for k in ("seed", "degenerate_reason", "predicted_car_px", "true_car_px", "scored_px")}
                      for m in models],
           "levers": LEVERS}
    if "ratio" in row:
        out["ratio"] = row["ratio"]
    return out


def line(row: dict[str, Any]) -> str:
    """One printed line per unmeasured point: what it saw and the levers."""
    models = row["_unmeasured"]
    first = models[0]
    counts = "" if first["predicted_car_px"] is None else (
        f" ({first['predicted_car_px']} of {first['scored_px']} px predicted car against "
        f"{first['true_car_px']:.6g} true car px, first model)")
    reasons = "; ".join(sorted({m["degenerate_reason"] for m in models}))
    return (f"  unmeasured: {row['point']}: all {len(models)} model(s) degenerate on its {row.get('n_test_images')} "
            f"test images, {reasons}{counts}; left out of the fit. Levers: {LEVERS}")


def require_measured(measured: list[dict[str, Any]], unmeasured: list[dict[str, Any]], n_fit: int | None = None,
                     needed: int = 3) -> None:
    """One-line error when no point (or, ``n_fit``, too few of the GP's points: ``needed``) was measured because
    of degenerate models; nothing is written then."""
    if not unmeasured:
        return
    what = f"{len(unmeasured)} of {len(measured) + len(unmeasured)} points unmeasured (every model degenerate: " \
           f"{', '.join(r['point'] for r in unmeasured[:6])}{', ...' if len(unmeasured) > 6 else ''})"
    if not measured:
        raise MetrawError(f"no point was measured: {what}; no spec written. Levers: {LEVERS}")
    if n_fit is not None and n_fit < needed:
        raise MetrawError(f"only {n_fit} measured point(s) for the IoU GP (it needs {needed}): {what}; no spec "
                          f"written. Levers: {LEVERS}")
