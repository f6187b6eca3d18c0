"""Object-level scores: cars found and false alarms, matched by overlap (issue #15).

At 2-5 target pixels per car, pixel IoU says little about what a user reads: how many cars were
found. Objects are 8-connected components on the image's mosaic grid: true cars are the components
of pixels with car area fraction >= ``TRUE_MIN_FRACTION``; predicted objects are the components of
the predicted mask. A true car is *found* when at least one predicted pixel lies on it; a predicted
object is a *false alarm* when none of its pixels has any car area. Cars parked bumper to bumper
merge into one component at coarse GSD: counts are of separable objects, not of cars.
"""

from __future__ import annotations

import numpy as np

#: A mosaic pixel belongs to a true object when at least this fraction of its area is car.
TRUE_MIN_FRACTION = 0.25

_EIGHT = np.ones((3, 3), dtype=bool)


def object_counts(pred: np.ndarray, frac: np.ndarray) -> dict[str, int]:
    """Counts of true objects, found objects, predicted objects and false alarms for one image.

    ``pred``: boolean mask; ``frac``: car area fraction per pixel, same shape (any leading axes are
    treated as separate images, e.g. packed CFA planes are scored on their own grids).
    """
    from scipy import ndimage

    pred = np.asarray(pred, bool)
    frac = np.asarray(frac, np.float64)
    if pred.shape != frac.shape:
        raise ValueError(f"prediction {pred.shape} and labels {frac.shape} differ in shape")
    if pred.ndim > 2:
        parts = [object_counts(p, f) for p, f in zip(pred.reshape(-1, *pred.shape[-2:]),
                                                      frac.reshape(-1, *frac.shape[-2:]))]
        return {k: sum(p[k] for p in parts) for k in parts[0]}
    truth, n_true = ndimage.label(frac >= TRUE_MIN_FRACTION, structure=_EIGHT)
    found = np.unique(truth[pred & (truth > 0)])
    comp, n_pred = ndimage.label(pred, structure=_EIGHT)
    hit = np.unique(comp[(frac > 0) & (comp > 0)])
    return {"true_objects": int(n_true), "found_objects": int(found.size), "predicted_objects": int(n_pred),
            "false_alarms": int(n_pred - hit.size)}


def object_scores(counts: dict[str, int]) -> dict[str, float | None]:
    """Object recall (found / true), precision (1 - false alarms / predicted) and their F1."""
    rec = counts["found_objects"] / counts["true_objects"] if counts["true_objects"] else None
    prec = 1 - counts["false_alarms"] / counts["predicted_objects"] if counts["predicted_objects"] else None
    f1 = 2 * prec * rec / (prec + rec) if prec is not None and rec is not None and prec + rec > 0 else None
    return {"object_recall": rec, "object_precision": prec, "object_f1": f1}
