"""IoU, precision and recall of car segmentation, per image and pooled over a test set.

Prediction and target live on the image's own mosaic grid (one value per CFA site): the
prediction is probability > 0.5 (logit > 0) per pixel; the target is the car *area fraction*
f of each pixel (the label geometry carried through the emulation). Scores are in ground area,
counting a predicted pixel as wholly car: TP = sum(b f), FP = sum(b (1 - f)), FN = sum((1 - b) f)
in pixel areas. For 0/1 masks these are the usual pixel counts; for coarse satellite pixels
that are partly car they charge the prediction for the area it really gets wrong, so IoU means
the same (overlap of car areas on the ground) at every parameter point.

Per image: IoU = TP / (TP + FP + FN), precision = TP / (TP + FP), recall = TP / (TP + FN);
undefined ratios (empty denominators) are reported as None and left out of means.
Overall: the same ratios from the counts pooled over all test images ("iou"), plus the mean of
the defined per-image IoUs with its standard error ("mean_image_iou", "mean_image_iou_se").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metraw.segment.data import PreparedImage


def confusion(pred: np.ndarray, target: np.ndarray) -> tuple[float, float, float]:
    """(TP, FP, FN) of a boolean prediction against a boolean or fractional (car area) target.

    Boolean targets give integer pixel counts; fractional targets in [0, 1] give areas in pixel
    units (TP = sum(pred * f), FP = sum(pred * (1 - f)), FN = sum((1 - pred) * f)).
    """
    pred = np.asarray(pred, dtype=bool)
    target = np.asarray(target)
    if pred.shape != target.shape:
        raise ValueError(f"prediction shape {pred.shape} differs from target shape {target.shape}")
    if target.dtype == bool:
        tp = int(np.count_nonzero(pred & target))
        return tp, int(np.count_nonzero(pred & ~target)), int(np.count_nonzero(~pred & target))
    f = target.astype(np.float64)
    if f.size and (f.min() < 0 or f.max() > 1):
        raise ValueError("fractional targets must lie in [0, 1]")
    tp = float(f[pred].sum())
    return tp, float(np.count_nonzero(pred)) - tp, float(f.sum()) - tp


def _ratio(num: float, den: float) -> float | None:
    return num / den if den > 0 else None


def scores(tp: float, fp: float, fn: float) -> dict[str, float | None]:
    """IoU, precision, recall from confusion counts (None where undefined)."""
    return {"iou": _ratio(tp, tp + fp + fn), "precision": _ratio(tp, tp + fp), "recall": _ratio(tp, tp + fn)}


def iou(pred: np.ndarray, target: np.ndarray) -> float | None:
    """Intersection over union of two boolean maps (None when both are empty)."""
    return scores(*confusion(pred, target))["iou"]


def summarise(per_image: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled scores and mean per-image IoU from per-image records holding tp/fp/fn."""
    tp = sum(r["tp"] for r in per_image)
    fp = sum(r["fp"] for r in per_image)
    fn = sum(r["fn"] for r in per_image)
    vals = np.array([r["iou"] for r in per_image if r["iou"] is not None], dtype=np.float64)
    mean = float(vals.mean()) if vals.size else None
    se = float(vals.std(ddof=1) / math.sqrt(vals.size)) if vals.size > 1 else None
    return {**scores(tp, fp, fn), "tp": tp, "fp": fp, "fn": fn, "n_images": len(per_image),
            "mean_image_iou": mean, "mean_image_iou_se": se}


def predict_logits(model, planes: np.ndarray, device: str = "cpu") -> np.ndarray:
    """Logits (S, h, w), one per CFA site, of one packed image (S, h, w) on its own grid."""
    import torch

    model.eval()
    with torch.no_grad():
        x = torch.from_numpy(np.ascontiguousarray(planes))[None].to(device)
        return model(x)[0].float().cpu().numpy()


def evaluate_images(model, images: list[PreparedImage], device: str = "cpu", progress: bool | None = None
                    ) -> dict[str, Any]:
    """Segment whole images and score them: {"per_image": [...], plus ``summarise`` keys}."""
    from metraw.progress import progress_bar

    records = []
    for img in progress_bar(images, desc="evaluate", disable=None if progress is None else not progress):
        planes, frac = img.full()
        pred = predict_logits(model, planes, device) > 0.0
        tp, fp, fn = confusion(pred, frac)
        records.append({"index": img.index, "shape": list(frac.shape), "tp": tp, "fp": fp, "fn": fn,
                        **scores(tp, fp, fn)})
    return {**summarise(records), "per_image": records}


def evaluate_store(store_path, model_dir, device: str | None = None, progress: bool | None = None
                   ) -> dict[str, Any]:
    """Score a trained model (``metraw.segment.train.train_store`` output) on a store's test split.

    The split is recomputed from the checkpoint's split seed and test fraction and must match
    the indices stored at training time (same store length and order). No wall-clock timings:
    the same model and store give the same record (``metraw evaluate`` logs its time on stderr).
    """
    from metraw.errors import MetrawError
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.train import TrainConfig, default_device, flush_denormals, load_model, set_determinism
    from metraw.store import RawStore

    device = device or default_device()
    model, ckpt, record = load_model(model_dir, device)
    config = TrainConfig.from_dict(ckpt["config"])
    set_determinism(config.seed, config.threads, device)
    store = RawStore.open(store_path)
    _, test_idx = split_indices(len(store), config.test_fraction, config.split_seed)
    if test_idx.tolist() != list(ckpt["test_indices"]):
        raise MetrawError(f"the test split of {store_path} ({len(store)} images) differs from the one the "
                          f"model in {model_dir} was trained with")
    images = prepare_store(store, test_idx, progress)
    with flush_denormals():
        out = evaluate_images(model, images, device, progress)
    out.update({"store": str(store_path), "model": str(model_dir), "epochs": record.get("epochs"),
                "upsample": ckpt["upsample"], "pool": ckpt.get("pool", 1), "device": device, "config": ckpt["config"],
                "packed_shape": list(images[0].packed_shape) if images else None})
    return out
