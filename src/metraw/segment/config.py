"""The segmenter's hyperparameters: ``TrainConfig`` and the ``training:`` section of params.yaml (``load_config``).

Apart from the training itself (``metraw.segment.train``) so that what only reads a configuration (the workflow's
DAG build: a profile's threads) imports neither torch nor the training's data pipeline.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from typing import Any

from metraw.errors import MetrawError, read_yaml

#: ``TrainConfig.precision`` values ("auto": ``metraw.segment.train.resolve_precision``).
PRECISIONS = ("float32", "bfloat16", "auto")
#: Training losses (``metraw.segment.train.segmentation_loss``): binary cross-entropy plus soft Dice, plus soft IoU
#: (Jaccard), or alone.
LOSSES = ("bce+dice", "bce+iou", "bce")
#: ``crops_per_image`` value: enough crops to cover each image's working-grid area once per epoch.
COVER = "cover"


@dataclass
class TrainConfig:
    """Hyperparameters of the segmenter (same for every parameter point).

    ``crop_px``: side of training crops in pixels of the network's working grid (packed CFA
    cells, pooled by ``grid_gsd_m``); images smaller than this are used whole.
    ``min_grid_px``: if > 0, inputs are upsampled bilinearly by the integer factor
    ceil(min_grid_px / smallest packed side) (0: native resolution).
    ``grid_gsd_m``: if > 0, the finest ground sampling [m per packed pixel] the network works
    at: finer inputs are average-pooled by floor(grid_gsd_m / packed GSD) and the logits
    upsampled back, so drone images cost what their ground content needs (0: never pool).
    ``crops_per_image``: random crops drawn per training image per epoch, or "cover": as many as the image's
    working-grid area holds, round(h w / crop_px^2), at least 1 (a 60 m drone scene at 0.135 m: 12; a
    satellite image of at most ~1.2 crops: 1), so one epoch sees every image's ground about once at any GSD.
    Training on the fly from the source (``metraw.segment.onthefly``) takes one crop per draw.
    ``tone_gamma_range``, ``channel_gain_range``: domain randomisation of tone curve and white balance of the
    training crops (``metraw.segment.data.tone_jitter``; 1.0 = off, the default: the emulated raws' noise
    model is exact and the network sees it unchanged). For models meant to run on processed real photos.
    ``replicates``: models trained per point with seeds ``seed``, ``seed + 1``, ... (the first is the model,
    the others its replicates: their spread is the training-to-training part of the IoU's uncertainty).
    ``draws_per_epoch``: fresh target draws per scene per epoch when training on the fly from the source
    (``metraw.segment.onthefly``; ignored when training on a store's fixed images).
    ``threads``: torch CPU threads, fixed here and not taken from the machine or the workflow's
    ``--cores``: the thread count changes the kernels' summation order, hence the weights' bytes. The batches
    are made in a background thread beside them (``metraw.segment.train.PREFETCH_BATCHES``): on small satellite
    crops 1 torch thread and the draws' thread fill 2 cores best (the ``default`` profile), on drone crops 2 torch
    threads.
    ``precision``: arithmetic of the training passes: "float32", "bfloat16" (autocast: convolutions in
    bfloat16 with float32 weights, optimiser and loss; faster where the hardware computes bfloat16, slower
    where it emulates it: see docs/training.md), or "auto": bfloat16 where the device computes it natively, else
    float32 (``metraw.segment.train.resolve_precision``; every training record and saved config holds the resolved
    value). Evaluation and prediction always run in float32.
    ``loss``: one of ``LOSSES`` (``metraw.segment.train.segmentation_loss``); "bce+dice", the default, is what the
    measured profiles use.
    ``predict_transforms``: dihedral transforms of the mosaic (turns, flips; 1, 2, 4 or 8) whose predictions
    ``metraw evaluate`` / ``predict`` average (``metraw.segment.evaluate.averaged_probability``); 1 (default) = a
    single pass. A prediction setting: training does not use it.
    ``condition``: condition the network on each image's payload (``metraw.segment.condition``: packed GSD, diffraction
    blur, light collected, smear, from the image's profile; FiLM in every block). False (default): a plain network.
    Only metraw's U-Net takes it: with another ``model`` the training runs unconditioned and records false.
    ``model``: the network, params.yaml ``training.model`` (``metraw.segment.networks.ModelSpec``: metraw's U-Net,
    sized by ``base_channels`` and ``depth``, an smp model or a python factory); None: metraw's U-Net.
    """

    epochs: int = 8
    learning_rate: float = 2e-3
    batch_size: int = 8
    crop_px: int = 128
    base_channels: int = 16
    depth: int = 3
    min_grid_px: int = 0
    grid_gsd_m: float = 0.0
    crops_per_image: int | str = 1
    tone_gamma_range: float = 1.0
    channel_gain_range: float = 1.0
    weight_decay: float = 1e-4
    replicates: int = 1
    draws_per_epoch: int = 1
    seed: int = 0
    threads: int = 2
    precision: str = "float32"
    loss: str = "bce+dice"
    predict_transforms: int = 1
    condition: bool = False
    model: dict[str, Any] | None = None
    split_seed: int = 0
    test_fraction: float = 0.2

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise MetrawError(f"unknown training parameter(s): {', '.join(sorted(unknown))}")
        crops = d.get("crops_per_image", 1)
        if crops != COVER and not (isinstance(crops, int) and not isinstance(crops, bool) and crops >= 1):
            raise MetrawError(f"crops_per_image must be a positive integer or {COVER!r}, got {crops!r}")
        if "predict_transforms" in d:
            from metraw.segment.data import check_transforms

            check_transforms(d["predict_transforms"])
        if d.get("precision", "float32") not in PRECISIONS:
            raise MetrawError(f"training precision must be one of {', '.join(PRECISIONS)}, got {d['precision']!r}")
        if not isinstance(d.get("condition", False), bool):
            raise MetrawError(f"training condition must be true or false, got {d['condition']!r}")
        if d.get("loss", "bce+dice") not in LOSSES:
            raise MetrawError(f"training loss must be one of {', '.join(LOSSES)}, got {d['loss']!r}")
        if d.get("model") is not None:
            from metraw.segment.networks import ModelSpec

            ModelSpec.from_dict(d["model"])  # one line naming what is wrong
        return cls(**d)


def load_config(params_path: str | os.PathLike, profile: str | None = None) -> TrainConfig:
    """The ``training:`` section of params.yaml for ``profile`` (default: ``training.profile``)."""
    params = read_yaml(params_path, "parameter file")
    tr = params.get("training") if isinstance(params, dict) else None
    if not isinstance(tr, dict) or "profiles" not in tr:
        raise MetrawError(f"{params_path} has no training.profiles section")
    name = profile or tr.get("profile", "default")
    if name not in tr["profiles"]:
        raise MetrawError(f"training profile {name!r} not in {params_path} (have {', '.join(tr['profiles'])})")
    d = dict(tr["profiles"][name])
    for key in ("split_seed", "test_fraction", "model"):  # the study's, for every profile (a profile may set its own)
        if key in tr:
            d.setdefault(key, tr[key])
    return TrainConfig.from_dict(d)
