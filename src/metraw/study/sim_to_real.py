"""Sim-to-real benchmark (issue #16): a synthetic-trained model scored on real images at each parameter point.

The workflow (workflow/rules/sim_to_real.smk) ingests a folder of real aerial photos with YOLO car
boxes (params.yaml ``sim_to_real``; the KIT AIS photos of Munich by default) as approximate raws,
emulates them through every parameter point exactly as the synthetic source, and scores each
point's synthetic-trained model on all of them (``metraw evaluate --split all``). This module holds
what does not need the workflow: whether the benchmark is on (``resolve_enabled``), the per-point
real columns and sim-to-real gap (``real_columns``) and the summary of ``aggregate.json``
(``summary``). The measurements themselves (IoU and its delta-method variance) come from
``metraw.spec.aggregate.iou_measurement``; the GP, tolerances and spec stay on the synthetic IoU.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError

#: Largest |synthetic test IoU - real IoU| at the nominal point that counts as "transfers" (issue #16).
GAP_TOLERANCE = 0.05
#: Values of params.yaml ``sim_to_real.enabled``.
ENABLED_VALUES = (True, False, "auto")

#: Why a synthetic-trained model can score lower on (emulated) real images than on its synthetic test split.
REASONS = {
    "box-approximate": ("real labels are axis-aligned YOLO boxes (box-approximate): the box of a car parked or "
                        "driving at an angle covers more ground than the car, so the real car area is overstated "
                        "and a correct car outline scores FN in the box corners (real IoU and recall understated)"),
    "approximate-raw": ("the real raws are approximate: reconstructed from processed 8-bit sRGB photos (tone "
                        "curve, white balance, demosaicing, compression undone only approximately), so their "
                        "noise and colour differ from a camera's raw"),
    "scene-realism": ("scene realism: the synthetic scenes' cars, roads, roofs, shadows and clutter differ from "
                      "real streets (the model learnt the synthetic ones)"),
}


def resolve_enabled(params: dict[str, Any], origin: str = "params.yaml", base: str | Path = ".") -> bool:
    """Whether the sim-to-real benchmark runs: ``sim_to_real.enabled`` true (the folder is required: a
    missing one is a MetrawError), false (off), "auto" (on when ``sim_to_real.path``, relative to
    ``base``, is a folder). No ``sim_to_real`` section: off."""
    section = params.get("sim_to_real")
    if not section:
        return False
    enabled = section.get("enabled", "auto")
    if enabled not in ENABLED_VALUES:
        raise MetrawError(f"{origin}: sim_to_real/enabled: {enabled!r} is not one of true, false, auto")
    if enabled is False:
        return False
    path = section.get("path")
    present = bool(path) and (Path(base) / path).is_dir()
    if enabled is True and not present:
        where = "" if not path or Path(path).is_absolute() else f" (relative to {Path(base).resolve()})"
        raise MetrawError(f"{origin}: sim_to_real/enabled is true but the real image folder {path!r} does not exist"
                          f"{where}; set sim_to_real.enabled to auto or false to run without the sim-to-real benchmark")
    return present


def real_columns(row: dict[str, Any], real: dict[str, Any], real_iou: float, iou_var: float, real_var: float,
                 tolerance: float = GAP_TOLERANCE) -> dict[str, Any]:
    """The real-image columns of one point's row (``row`` holds its synthetic "iou", with replicates their mean):
    real_iou (+ sd) as measured the same way (``real_iou``, ``real_var``: the replicate mean where the record has
    replicates), precision, recall, labels, image count, ``sim_to_real_gap`` = synthetic test IoU - real IoU with
    its sd (independent image sets: the variances add), whether it is within ``tolerance`` and a note."""
    rec = _real_fields(real, real_iou, real_var)
    gap = _gap_fields(row, rec, iou_var, real_var, tolerance)
    return {**rec, "sim_to_real_gap": gap["gap"], "sim_to_real_gap_sd": gap["gap_sd"],
            "sim_to_real_within_tolerance": gap["within_tolerance"], "sim_to_real_note": gap["note"]}


def _real_fields(real: dict[str, Any], real_iou: float, real_var: float) -> dict[str, Any]:
    """real_iou (+ sd) as measured, precision, recall, labels and image count of a real-image metrics record,
    and on box labels the predicted objects' bounding boxes against them (real_box_iou, None when not scored)."""
    return {"real_iou": float(real_iou), "real_iou_sd": math.sqrt(max(real_var, 0.0)),
            "real_precision": real.get("precision"), "real_recall": real.get("recall"),
            "real_box_iou": real.get("box_iou"), "real_box_precision": real.get("box_precision"),
            "real_labels": real.get("labels"), "real_n_images": real.get("n_images")}


def _gap_fields(synthetic: dict[str, Any], rec: dict[str, Any], syn_var: float, real_var: float,
                tolerance: float) -> dict[str, Any]:
    """gap = synthetic IoU - real IoU, its sd (the variances add), within ``tolerance`` and the note."""
    gap = float(synthetic["iou"]) - rec["real_iou"]
    gap_sd = math.sqrt(max(syn_var, 0.0) + max(real_var, 0.0))
    return {"gap": gap, "gap_sd": gap_sd, "within_tolerance": abs(gap) <= tolerance,
            "note": gap_note(gap, gap_sd, rec["real_labels"], tolerance,
                             precision=(synthetic.get("precision"), rec["real_precision"]),
                             recall=(synthetic.get("recall"), rec["real_recall"]))}


def reasons(labels: str | None) -> list[str]:
    """The reasons that apply to real metrics with these labels (``REASONS`` keys)."""
    keys = ["box-approximate"] if labels in ("box-approximate", "mixed") else []
    return keys + ["approximate-raw", "scene-realism"]


def gap_note(gap: float, gap_sd: float, labels: str | None, tolerance: float = GAP_TOLERANCE,
             precision: tuple[float | None, float | None] = (None, None),
             recall: tuple[float | None, float | None] = (None, None)) -> str:
    """The gap against the tolerance and, when it is larger, why it can be; with the synthetic and real
    ``precision`` and ``recall``, which of the two fell. Box labels contain the car, so they can lower
    recall but not precision: a fall in precision is false alarms on the real images."""
    head = (f"synthetic test IoU - real IoU = {gap:+.3f} (sd {gap_sd:.3f}); "
            f"{'within' if abs(gap) <= tolerance else 'outside'} {tolerance:g}")
    if abs(gap) <= tolerance:
        return head
    parts = [head]
    if None not in precision and None not in recall:
        parts.append(f"precision {precision[0]:.3f} -> {precision[1]:.3f}, recall {recall[0]:.3f} -> {recall[1]:.3f} "
                     "(a fall in precision is false alarms on the real images, which box labels cannot cause: "
                     "scene realism and the approximate raws; a fall in recall is car area missed, box corners "
                     "included)")
    return ". ".join(parts) + ". Reasons a gap can be large: " + "; ".join(REASONS[k] for k in reasons(labels))


def summary(rows: list[dict[str, Any]], nominal: str, source: dict[str, Any] | None = None,
            tolerance: float = GAP_TOLERANCE) -> dict[str, Any]:
    """Top-level ``sim_to_real`` block of aggregate.json from rows carrying ``real_columns``; ``source``:
    the drone-resolution model's synthetic and real records (``source_record``), when measured."""
    with_real = [r for r in rows if "real_iou" in r]
    nom = next((r for r in with_real if r["point"] == nominal), None)
    labels = sorted({str(r.get("real_labels")) for r in with_real})
    out: dict[str, Any] = {
        "tolerance": tolerance,
        "basis": "GP, tolerances and spec.yaml use the synthetic test IoU only; real_* columns are reported beside it",
        "labels": labels[0] if len(labels) == 1 else "mixed",
        "points_within_tolerance": sum(bool(r["sim_to_real_within_tolerance"]) for r in with_real),
        "n_points": len(with_real),
        "nominal": None if nom is None else {
            "synthetic_iou": nom["iou"], "real_iou": nom["real_iou"], "gap": nom["sim_to_real_gap"],
            "gap_sd": nom["sim_to_real_gap_sd"], "within_tolerance": nom["sim_to_real_within_tolerance"],
            "note": nom["sim_to_real_note"]},
        "reasons": {k: REASONS[k] for k in reasons(labels[0] if len(labels) == 1 else "mixed")},
        "source": source,
    }
    return out


def source_record(synthetic: dict[str, Any] | None, real: dict[str, Any], syn: tuple[float, float],
                  real_measured: tuple[float, float], tolerance: float = GAP_TOLERANCE) -> dict[str, Any]:
    """The drone-resolution reference: the source-trained model on its synthetic test split and on the
    un-emulated real images (resampled by ``metraw evaluate`` to its training GSD); ``syn`` and ``real_measured``
    are the (IoU, variance) measurements of the two records (replicate means where they have replicates)."""
    rec: dict[str, Any] = _real_fields(real, *real_measured)
    if synthetic is not None and synthetic.get("iou") is not None:
        syn_iou, syn_var = syn
        rec.update({"synthetic_iou": float(syn_iou), "synthetic_iou_sd": math.sqrt(max(syn_var, 0.0)),
                    **_gap_fields({**synthetic, "iou": syn_iou}, rec, syn_var, real_measured[1], tolerance)})
    return rec
