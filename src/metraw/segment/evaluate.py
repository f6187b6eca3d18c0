"""IoU, precision and recall of car segmentation, per image and pooled over a test set.

Prediction and target live on the image's own mosaic grid (one value per CFA site): the
prediction is probability > 0.5 per pixel (the float32 sigmoid of the logit, ``car_probability``)
without the predicted objects smaller than ``MIN_OBJECT_AREA_M2`` on the ground (``predicted_mask``: the
same rule as the masks of ``metraw predict``); the target is the car *area fraction*
f of each pixel (the label geometry carried through the emulation). Scores are in ground area,
counting a predicted pixel as wholly car: TP = sum(b f), FP = sum(b (1 - f)), FN = sum((1 - b) f)
in pixel areas. For 0/1 masks these are the usual pixel counts; for coarse satellite pixels
that are partly car they charge the prediction for the area it really gets wrong, so IoU means
the same (overlap of car areas on the ground) at every parameter point. The probability may be the average
over turns and flips of the mosaic (``averaged_probability``, ``TrainConfig.predict_transforms``; recorded as
"transforms").

Per image: IoU = TP / (TP + FP + FN), precision = TP / (TP + FP), recall = TP / (TP + FN);
undefined ratios (empty denominators) are reported as None and left out of means.
Overall: the same ratios from the counts pooled over all scored images ("iou"), plus the mean of
the defined per-image IoUs with its standard error ("mean_image_iou", "mean_image_iou_se").

Which images (``evaluate_store``): on the store the model was trained on (recognised by the
content digest recorded in train.json, or by its path for models trained before the digest was
recorded) its test split; on any other ("foreign") store all its images; ``split`` overrides.

Ground sampling: the model learnt cars at the packed GSD of its training images
(``train_packed_gsd_m`` in the checkpoint; a [low, high] range for a model pretrained across a box of
payloads: ``gsd_scale``). An image whose packed GSD differs from it by more than
``GSD_TOLERANCE`` is resampled to it before the network and the logits back to the image's grid
(``resample_to_gsd``); the factor is recorded per image ("gsd_scale"). Checkpoints without the
field, or images without a known GSD, are not resampled ("gsd_matched": false and the reason).

Labels: masks made from YOLO boxes (image meta ``mask_kind`` "box-approximate: ...") overstate the
car area (a box is not an outline): each image and the pooled record say "box-approximate",
"exact" or (pooled) "mixed". On box-labelled images ``evaluate_store`` also scores every predicted
object as its axis-aligned bounding box against the boxes ("box_iou", "box_precision", "box_recall":
box against box, like a detector; ``metraw.segment.objects.object_boxes``).

Degenerate models (issue #71, ``metraw.segment.degenerate``): a model that calls no pixel car on the whole scored
split, or every pixel, is marked ("degenerate", "degenerate_reason", "predicted_car_px", "true_car_px", "scored_px")
in each ``replicates`` record; the top level holds the first model's counts and the point's verdict ("degenerate":
every model is; "n_degenerate_models" of "n_models"). The aggregate leaves such a point out of the fit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import PACKED_GEOMETRY, pack_planes, unpack_planes
from metraw.segment.degenerate import degeneracy
from metraw.segment.data import (TRANSFORM_SETS, PreparedImage, canonical_pack, canonical_window, check_transforms,
                                 undo_dihedral)
from metraw.segment.objects import (MIN_OBJECT_AREA_M2, drop_small_objects, object_boxes, object_counts,
                                    object_scores)

#: Per-image object counts (``metraw.segment.objects``), pooled by ``summarise``.
OBJECT_KEYS = ("true_objects", "found_objects", "predicted_objects", "false_alarms")
#: Per-image confusion counts of the predicted objects' bounding boxes (box-labelled images only).
BOX_KEYS = ("box_tp", "box_fp", "box_fn")
#: Probability above which a pixel is predicted car.
THRESHOLD = 0.5

#: Relative difference of packed GSDs [-] above which an image is resampled to the training GSD.
GSD_TOLERANCE = 0.02
#: ``split`` values of ``evaluate_store``.
SPLITS = ("auto", "test", "all")


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
    objects = {k: sum(r.get(k, 0) for r in per_image) for k in OBJECT_KEYS} if all(
        OBJECT_KEYS[0] in r for r in per_image) else None
    boxes = {k: sum(r[k] for r in per_image) for k in BOX_KEYS} if per_image and all(
        BOX_KEYS[0] in r for r in per_image) else None
    return {**scores(tp, fp, fn), "tp": tp, "fp": fp, "fn": fn, "n_images": len(per_image),
            "mean_image_iou": mean, "mean_image_iou_se": se,
            **({**objects, **object_scores(objects)} if objects else {}),
            **({**boxes, **{f"box_{k}": v for k, v in scores(*boxes.values()).items()}} if boxes else {})}


# ----------------------------------------------------------------- ground sampling
def gsd_scale(image_packed_gsd_m: float | None, train_packed_gsd_m: float | None, recorded: bool = True,
              tolerance: float = GSD_TOLERANCE) -> tuple[float, bool, str | None]:
    """(scale [-], matched, reason) for an image: scale = image packed GSD / training packed GSD.

    1.0 when the two agree within ``tolerance`` (relative) or when either is unknown; ``matched``
    is False only in the latter case, ``reason`` then says which is unknown (``recorded`` False:
    a checkpoint from before the training GSD was recorded). ``train_packed_gsd_m`` may be a range
    [low, high] (a model pretrained across a box of payloads): images inside it are not resampled,
    others are resampled to its nearer end.
    """
    if not recorded:
        return 1.0, False, ("the checkpoint records no training GSD (a model trained before train_packed_gsd_m "
                            "was recorded): images not resampled")
    if not train_packed_gsd_m:
        return 1.0, False, "training GSD unknown (training images without geometry): images not resampled"
    if not image_packed_gsd_m:
        return 1.0, False, "image GSD unknown (profile without geometry, no meta gsd_m): not resampled"
    if isinstance(train_packed_gsd_m, (list, tuple)):
        low, high = (float(v) for v in train_packed_gsd_m)
        train_packed_gsd_m = min(max(float(image_packed_gsd_m), low), high)
    scale = float(f"{float(image_packed_gsd_m) / float(train_packed_gsd_m):.9g}")  # no float noise in records
    return (1.0 if abs(scale - 1.0) <= tolerance else scale), True, None


def image_packed_gsd_m(image) -> float | None:
    """Packed GSD of a RawImage [m per packed pixel]: the profile's geometry, else its meta ``gsd_m``
    (processed photos ingested with ``--gsd-m``), times the packed cell's side; None when unknown."""
    from metraw.raw.cfa import PACKED_CELL_PX

    gsd = image.profile.gsd_m
    if not gsd:
        meta_gsd = image.meta.get("gsd_m") if isinstance(image.meta, dict) else None
        gsd = float(meta_gsd) if isinstance(meta_gsd, (int, float)) and meta_gsd > 0 else None
    return gsd * PACKED_CELL_PX if gsd else None


def resample_to_gsd(x, scale: float, size: tuple[int, int] | None = None):
    """Resample planes or logits (B, C, h, w) by ``scale`` [-] (new side = round(side * scale)), or to
    ``size`` when given: bilinear, antialiased along a shrinking axis (an area average, no aliasing)."""
    import torch.nn.functional as F

    h, w = x.shape[-2:]
    if size is None:
        size = (max(1, int(round(h * scale))), max(1, int(round(w * scale))))
    if tuple(size) == (h, w):
        return x
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False,
                         antialias=size[0] < h or size[1] < w)


def predict_logits(model, planes: np.ndarray, device: str = "cpu", scale: float = 1.0,
                   condition: np.ndarray | None = None) -> np.ndarray:
    """Logits (S, h, w), one per CFA site, of one packed image (S, h, w) on its own grid.

    ``scale`` != 1 (image packed GSD / training packed GSD): the planes are resampled to the
    training GSD for the network and its logits back to (h, w) (``resample_to_gsd``).
    ``condition``: the image's payload vector (``metraw.segment.condition``), used by a conditioned network.
    """
    import torch

    from metraw.segment.train import condition_tensor

    model.eval()
    with torch.no_grad():
        x = resample_to_gsd(torch.from_numpy(np.ascontiguousarray(planes))[None].to(device), scale)
        c = condition_tensor(model, None if condition is None else condition[None], device, "prediction")
        y = resample_to_gsd(model(x) if c is None else model(x, c), scale, size=tuple(planes.shape[-2:]))
        return y[0].float().cpu().numpy()


def averaged_probability(model, z: np.ndarray, pattern: str, device: str = "cpu", scale: float = 1.0,
                         transforms: int = 1, condition: np.ndarray | None = None) -> np.ndarray:
    """Car probability (S, h, w) per site of the mosaic ``z`` packed canonically (``canonical_pack``, transform 0),
    averaged over ``transforms`` (1, 2, 4 or 8) dihedral transforms (``data.dihedral``; the sets of
    ``data.TRANSFORM_SETS``: 2 and 4 keep the image axes, so the smear stays along the track).

    Each transform turns or flips the mosaic *before* packing, so every plane keeps its colour, exactly as in
    training; its probabilities are unpacked to the transformed mosaic, turned back, and averaged per mosaic
    pixel over the transforms whose packed window covers it (a transform's window may lose one edge row or
    column). The scene and the noise model have these symmetries; the network's errors do not all share them,
    so the average cancels part of them. ``transforms`` = 1 is the plain prediction. ``condition``: as
    ``predict_logits``.
    """
    check_transforms(transforms)
    planes, _ = canonical_pack(z, None, pattern, 0)
    if transforms == 1:
        return car_probability(predict_logits(model, planes, device, scale, condition))
    total = np.zeros(z.shape, np.float64)
    count = np.zeros(z.shape, np.float64)
    for k in TRANSFORM_SETS[transforms]:
        dy, dx, h, w = canonical_window(pattern, z.shape, k)
        packed = planes if k == 0 else canonical_pack(z, None, pattern, k)[0]
        p = car_probability(predict_logits(model, packed, device, scale, condition))
        shape_k = (z.shape[1], z.shape[0]) if k % 2 else z.shape
        summed = np.zeros(shape_k, np.float64)
        covered = np.zeros(shape_k, np.float64)
        summed[dy:dy + h, dx:dx + w] = _mosaic(p, pattern)
        covered[dy:dy + h, dx:dx + w] = 1.0
        total += undo_dihedral(summed, k)
        count += undo_dihedral(covered, k)
    dy, dx, h, w = canonical_window(pattern, z.shape, 0)
    mean = (total / np.maximum(count, 1.0))[dy:dy + h, dx:dx + w]
    return _packed(mean.astype(np.float32), pattern, planes.shape)


def car_probability(logits: np.ndarray) -> np.ndarray:
    """Car probability (float32 sigmoid of the logits); see ``predicted_mask`` for the decision."""
    import torch

    return torch.sigmoid(torch.from_numpy(np.ascontiguousarray(logits, dtype=np.float32))).numpy()


def min_object_area_px(gsd_m: float | None) -> float:
    """``MIN_OBJECT_AREA_M2`` in mosaic pixels of ground sampling ``gsd_m`` [m]; 0 (keep all) when unknown."""
    return MIN_OBJECT_AREA_M2 / gsd_m ** 2 if gsd_m else 0.0


def predicted_mask(probability: np.ndarray, gsd_m: float | None, threshold: float = THRESHOLD) -> np.ndarray:
    """Car mask of a probability map on the mosaic grid (H, W): probability > ``threshold``, less the
    8-connected objects smaller than ``MIN_OBJECT_AREA_M2`` (``gsd_m``: mosaic pixel [m]; None: keep all)."""
    return drop_small_objects(np.asarray(probability) > threshold, min_object_area_px(gsd_m))


# ----------------------------------------------------------------- scoring
def label_kind(meta: dict[str, Any] | None) -> str:
    """"box-approximate" for masks made from boxes (meta ``mask_kind``), else "exact"."""
    kind = (meta or {}).get("mask_kind", "") if isinstance(meta, dict) else ""
    return "box-approximate" if str(kind).startswith("box-approximate") else "exact"


def pooled_label_kind(kinds: list[str]) -> str | None:
    """One kind when all images agree, "mixed" otherwise (None without images)."""
    distinct = sorted(set(kinds))
    return None if not distinct else distinct[0] if len(distinct) == 1 else "mixed"


def score_image(model, img: PreparedImage, device: str = "cpu", scale: float = 1.0, boxes: bool = False,
                transforms: int = 1, threshold: float = THRESHOLD) -> dict[str, Any]:
    """Segment one whole image (``averaged_probability`` over ``transforms``) and score it: index, shape, tp, fp,
    fn, iou, precision, recall, object counts and, with ``boxes`` (box labels), the confusion counts of the
    predicted objects' bounding boxes. ``threshold``: the decision's probability (``predicted_mask``)."""
    planes, frac = img.full()
    prob = averaged_probability(model, img.z, img.pattern, device, scale, transforms, img.condition)
    mosaic_pred = predicted_mask(_mosaic(prob, img.pattern), img.gsd_m, threshold)
    mosaic_frac = _mosaic(frac, img.pattern)
    pred = _packed(mosaic_pred, img.pattern, frac.shape)
    tp, fp, fn = confusion(pred, frac)
    rec = {"index": img.index, "shape": list(frac.shape), "tp": tp, "fp": fp, "fn": fn, **scores(tp, fp, fn),
           **object_counts(mosaic_pred, mosaic_frac)}
    if boxes:
        rec.update(zip(BOX_KEYS, confusion(_packed(object_boxes(mosaic_pred), img.pattern, frac.shape), frac)))
    return rec


def _mosaic(values: np.ndarray, pattern: str) -> np.ndarray:
    """Packed (S, h, w) values back on the (canonical) mosaic grid (``pattern``: any; every mosaic packs alike)."""
    return unpack_planes(values, PACKED_GEOMETRY, (2 * values.shape[-2], 2 * values.shape[-1]))


def _packed(mosaic: np.ndarray, pattern: str, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of ``_mosaic``: mosaic values as packed planes of ``shape`` (S, h, w)."""
    return pack_planes(mosaic, PACKED_GEOMETRY)


def evaluate_images(model, images: list[PreparedImage], device: str = "cpu", progress: bool | None = None,
                    boxes: bool = False, transforms: int = 1, threshold: float = THRESHOLD) -> dict[str, Any]:
    """Segment whole images (no resampling) and score them: {"per_image": [...], plus ``summarise`` keys};
    ``boxes``: the labels are boxes, score the predicted objects' bounding boxes too; ``transforms``: dihedral
    transforms averaged per prediction; ``threshold``: the decision's probability (``score_image``)."""
    from metraw.progress import progress_bar

    records = [score_image(model, img, device, boxes=boxes, transforms=transforms, threshold=threshold)
               for img in progress_bar(images, desc="evaluate", disable=None if progress is None else not progress)]
    return {**summarise(records), "per_image": records}


# ----------------------------------------------------------------- models and stores
def open_model(model_dir, device: str):
    """``load_model`` with one-line errors: a missing directory, an unreadable checkpoint."""
    from pathlib import Path

    from metraw.segment.train import load_model

    if not Path(model_dir).is_dir():
        raise MetrawError(f"model directory {model_dir} does not exist (train one with `metraw train`)")
    try:
        return load_model(model_dir, device)
    except MetrawError:
        raise
    except Exception as exc:  # torch raises many types on a damaged checkpoint
        raise MetrawError(f"cannot read the model in {model_dir}: {' '.join(str(exc).split())[:200]}") from None


def open_for_inference(model_dir, device: str | None, transforms: int | None):
    """A trained model ready to score or predict: (model, checkpoint, record, its TrainConfig, the dihedral
    transforms to average (``transforms``, default the model's ``predict_transforms``), device), torch seeded and
    threaded as the model's config says."""
    from metraw.segment.config import TrainConfig
    from metraw.segment.train import default_device, set_determinism

    device = device or default_device()
    model, ckpt, record = open_model(model_dir, device)
    config = TrainConfig.from_dict(ckpt["config"])
    transforms = config.predict_transforms if transforms is None else transforms
    check_transforms(transforms)
    set_determinism(config.seed, config.threads, device)
    return model, ckpt, record, config, transforms, device


def check_channels(ckpt: dict[str, Any], pattern: str, where: str, model_dir) -> None:
    """The model was trained on images of the image's sensor kind (mono or Bayer: the checkpoint's ``sensor``),
    and takes its four packed planes, else a one-line error."""
    from metraw.raw.cfa import cfa_family
    from metraw.segment.train import checkpoint_sensor

    if ckpt.get("in_channels") != 4:
        raise MetrawError(f"the model in {model_dir} takes {ckpt.get('in_channels')} packed plane(s) (a mono model "
                          "of an older metraw, which packed mono mosaics in 1 plane): train it again")
    sensor = checkpoint_sensor(ckpt)
    if sensor != cfa_family(pattern):
        raise MetrawError(f"the model in {model_dir} was trained on {sensor} images but {where} is {pattern} "
                          f"({cfa_family(pattern)}): sensor mismatch")


def training_store(store, store_path, record: dict[str, Any]) -> tuple[bool, str]:
    """(whether ``store`` is the one the model was trained on, how that was decided).

    By the content digest of train.json ("store_digest") when recorded; else (older models) by the
    resolved path of its "store" record and the image count.
    """
    from pathlib import Path

    from metraw.segment.train import store_digest

    if record.get("store_digest"):
        same = len(store) == record.get("n_images") and store_digest(store) == record["store_digest"]
        return same, "store_digest"
    recorded = record.get("store")
    same = bool(recorded) and Path(recorded).resolve() == Path(store_path).resolve() \
        and len(store) == record.get("n_images")
    return same, "path"


def select_images(store, store_path, model_dir, ckpt: dict[str, Any], config, split: str, is_training: bool
                  ) -> tuple[list[int], str]:
    """(store positions, split name) to score: the checkpoint's test split ("test") or every image. The test
    split is by source image (``data.split_positions``): a store emulated with ``--images test`` holds only it."""
    from metraw.segment.data import source_indices, split_positions

    if split not in SPLITS:
        raise MetrawError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    if len(store) == 0:
        raise MetrawError(f"store {store_path} holds no images")
    if split == "test" or (split == "auto" and is_training):
        n_source = source_indices(store)[1]
        if n_source < 2:
            raise MetrawError(f"store {store_path} has {len(store)} image: no test split to score")
        test_idx, positions = split_positions(store, config.test_fraction, config.split_seed)
        if test_idx.tolist() != [int(i) for i in ckpt["test_indices"]]:
            raise MetrawError(f"the test split of {store_path} ({n_source} source images) differs from the one the "
                              f"model in {model_dir} was trained with (use --split all)")
        return positions.tolist(), "test"
    return list(range(len(store))), "all (training store)" if is_training else "all (foreign store)"


def evaluate_store(store_path, model_dir, device: str | None = None, progress: bool | None = None,
                   split: str = "auto", transforms: int | None = None) -> dict[str, Any]:
    """Score a trained model (``metraw.segment.train.train_store`` output) on a store.

    ``split``: "auto" scores the test split of the training store and every image of a foreign
    one; "test" the checkpoint's test split (recomputed from its split seed and test fraction: the
    store must have as many images as the training store, e.g. another parameter point); "all"
    every image. Images are read, segmented and scored one at a time. No wall-clock timings: the
    same model and store give the same record (``metraw evaluate`` logs its time on stderr).
    ``transforms``: dihedral transforms averaged per prediction (``averaged_probability``); default the
    model's ``predict_transforms``.
    """
    from metraw.io.store import RawStore
    from metraw.progress import progress_bar
    from metraw.segment.data import prepare
    from metraw.segment.config import TrainConfig
    from metraw.segment.train import flush_denormals, replicate_dirs

    model, ckpt, record, config, transforms, device = open_for_inference(model_dir, device, transforms)
    store = RawStore.open(store_path)
    is_training, identified_by = training_store(store, store_path, record)
    indices, split_name = select_images(store, store_path, model_dir, ckpt, config, split, is_training)
    train_gsd = ckpt.get("train_packed_gsd_m")
    replicas = [open_model(d, device)[:2] for d in replicate_dirs(model_dir)]  # (model, checkpoint)
    rep_records: list[list[dict[str, Any]]] = [[] for _ in replicas]
    records, notes, packed_shape = [], [], None
    with flush_denormals():
        for i in progress_bar(indices, desc="evaluate", disable=None if progress is None else not progress):
            image = store[i]
            if image.mask is None:
                raise MetrawError(f"image {i} of {store_path} has no label mask: `metraw evaluate` needs labelled "
                                  "images (`metraw predict` segments unlabelled ones)")
            check_channels(ckpt, image.cfa_pattern, f"image {i} of {store_path}", model_dir)
            gsd = image_packed_gsd_m(image)
            scale, matched, note = gsd_scale(gsd, train_gsd, "train_packed_gsd_m" in ckpt)
            img = prepare(image, i)
            packed_shape = packed_shape or list(img.packed_shape)
            labels = label_kind(image.meta)
            boxes = labels == "box-approximate"
            rec = score_image(model, img, device, scale, boxes, transforms)
            rec.update({"labels": labels, "packed_gsd_m": gsd, "gsd_scale": scale, "gsd_matched": matched})
            records.append(rec)
            for (rmodel, _), rrecs in zip(replicas, rep_records):
                rrecs.append(score_image(rmodel, img, device, scale, boxes, transforms))
            if note and note not in notes:
                notes.append(note)
    out = {**summarise(records), "per_image": records}
    out.update({"split": split_name, "training_store": is_training, "training_store_by": identified_by,
                "labels": pooled_label_kind([r["labels"] for r in records]), "train_packed_gsd_m": train_gsd,
                "gsd_matched": not notes, "gsd_note": "; ".join(notes) or None,
                "store": store.origin, "model": str(model_dir), "network": ckpt.get("network"),
                "epochs": record.get("epochs"),
                "upsample": ckpt["upsample"], "pool": ckpt.get("pool", 1), "device": device, "config": ckpt["config"],
                "packed_shape": packed_shape, "threshold": THRESHOLD, "min_object_area_m2": MIN_OBJECT_AREA_M2,
                "transforms": transforms})
    out.update(degeneracy(records))  # the first model's counts; "degenerate" is reset below for the point
    if replicas:
        out.update(replicate_summary(out, [(TrainConfig.from_dict(c["config"]).seed, recs)
                                           for (_, c), recs in zip(replicas, rep_records)], config.seed))
    out.update(point_degeneracy(out))
    return out


def point_degeneracy(metrics: dict[str, Any]) -> dict[str, Any]:
    """The point's verdict over its models (issue #71): "degenerate" when every model (the first and its replicates)
    is degenerate (``metraw.segment.degenerate``), its "degenerate_reason" then the first model's, and
    "n_degenerate_models" of "n_models". Each replicate's own verdict and counts are in ``metrics["replicates"]``;
    the top-level counts (predicted_car_px, true_car_px, scored_px) are the first model's, as its "iou" is."""
    models = metrics.get("replicates") or [metrics]
    bad = sum(bool(m["degenerate"]) for m in models)
    every = bad == len(models)
    return {"degenerate": every, "degenerate_reason": metrics["degenerate_reason"] if every else None,
            "n_degenerate_models": bad, "n_models": len(models)}


def replicate_summary(primary: dict[str, Any], replicas: list[tuple[int, list[dict[str, Any]]]],
                      primary_seed: int) -> dict[str, Any]:
    """Scores of every replicate model (same images) and the IoU's mean and spread over the training seeds; each
    model's degenerate verdict and counts (``metraw.segment.degenerate.degeneracy``).

    ``iou_replicate_mean``: mean of the pooled IoUs of the model and its replicates; ``iou_replicate_sd``: their
    standard deviation (training-to-training); ``iou_replicate_se`` = sd / sqrt(n) (the mean's seed error; the
    test-image sampling error comes on top, the test images being the same for all).
    """
    keys = ("iou", "precision", "recall", "object_f1")
    reps = [{"seed": primary_seed, **{k: primary.get(k) for k in keys}, **degeneracy(primary["per_image"])}]
    for seed, recs in replicas:
        summ = summarise(recs)
        # each model's degenerate verdict, and its per-image (tp, fp, fn): the aggregate's test-image error of a
        # point whose first model is degenerate comes from the first model that is not (metraw.spec.unmeasured)
        reps.append({"seed": seed, **{k: summ.get(k) for k in keys}, **degeneracy(recs),
                     "per_image_counts": [[r["tp"], r["fp"], r["fn"]] for r in recs]})
    ious = np.array([r["iou"] for r in reps if r["iou"] is not None], dtype=np.float64)
    sd = float(ious.std(ddof=1)) if ious.size > 1 else None
    return {"replicates": reps, "n_replicates": len(reps),
            "iou_replicate_mean": float(ious.mean()) if ious.size else None, "iou_replicate_sd": sd,
            "iou_replicate_se": sd / math.sqrt(ious.size) if sd is not None else None}
