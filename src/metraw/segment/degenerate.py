"""Degenerate segmenters (issue #71): a model that predicts no car pixel on the whole scored split, or every pixel
car, learnt nothing of the task. Its IoU (0 for "nothing", the car share of the images for "everything") measures a
failed training, not the images it was given, so the aggregate keeps such a model out of the fit
(`metraw.spec.unmeasured`).

``degeneracy`` judges one model from the per-image records of ``metraw.segment.evaluate.score_image`` (tp, fp,
fn in pixel units, the packed shape). Pixel counts are in mosaic sites (one per CFA site) of the scored images:
predicted car pixels = TP + FP (the pixels the model calls car, each counted whole), true car pixels = TP + FN (the
car area of the labels, in pixels; fractional for coarse pixels). Plain Python and numpy only: the aggregate reads
it without torch.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

#: Why a model is degenerate (``degeneracy``'s "degenerate_reason").
NOTHING = "no predicted car pixel"
EVERYTHING = "every pixel predicted car"
#: What to change when a point's models are degenerate (printed by `metraw aggregate`).
LEVERS = ("train on more images (a photo set of 15 collapsed, one of 41 trained with the default config), or longer "
          "(training.pretrain epochs and finetune_epochs), or with the default config where this run used "
          "workflow/config/quick.yaml")


def degeneracy(per_image: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Whether one model's predictions on the scored images are degenerate, with the counts that show it.

    {"degenerate": bool, "degenerate_reason": NOTHING, EVERYTHING or None, "predicted_car_px": int,
    "true_car_px": float, "scored_px": int}. Degenerate: no pixel predicted car although the labels hold cars, or
    every pixel predicted car although some are not. A split without any car (or all car) gives no verdict
    (not degenerate): predicting it is right.
    """
    predicted, true, scored = 0, 0.0, 0
    for r in per_image:
        predicted += int(round(float(r["tp"]) + float(r["fp"])))  # a count: TP + FP = predicted pixels (to rounding)
        true += float(r["tp"]) + float(r["fn"])
        scored += math.prod(int(s) for s in r["shape"])
    reason = None
    if predicted == 0 and true > 0:
        reason = NOTHING
    elif predicted >= scored > 0 and true < scored:
        reason = EVERYTHING
    return {"degenerate": reason is not None, "degenerate_reason": reason, "predicted_car_px": predicted,
            "true_car_px": float(f"{true:.9g}"), "scored_px": scored}


def describe(record: dict[str, Any]) -> str:
    """One model's verdict in words: 'no predicted car pixel (0 of 123456 px predicted car; 4567 true car px)'."""
    return (f"{record['degenerate_reason'] or 'not degenerate'} ({record['predicted_car_px']} of "
            f"{record['scored_px']} px predicted car; {record['true_car_px']:.6g} true car px)")
