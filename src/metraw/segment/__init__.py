"""Car segmentation on raw images: compact U-Net on packed, variance-stabilised CFA planes.

- ``data``: preprocessing (VST, canonical CFA packing, car fraction per pixel), split, crops;
- ``config``: the hyperparameters (``TrainConfig``) and params.yaml's ``training:`` section (``load_config``);
- ``condition``: the payload vector of an image's profile that a conditioned network takes (off by default);
- ``model``: the U-Net (plain torch; FiLM conditioning optional) and its resampling wrapper (upsample / pool);
- ``train``: training one model per parameter point (``train_store``), checkpoints;
- ``evaluate``: IoU / precision / recall per image and pooled (``evaluate_store``): a store's test split,
  or every image of a foreign store, resampled to the model's training ground sampling;
- ``predict``: car probability and mask per image of any store (``metraw predict``), overlay figures;
- ``onthefly`` and ``pretrain``: training on fresh draws of the source scenes (``metraw.emulate.draws``).

The package's names (``__all__``) are imported from their modules on first use (PEP 562), so that importing one light
module of it (``config``) does not load torch, numba and the data pipeline.
"""

import importlib

#: name -> the module of this package that defines it
_NAMES = {
    "TrainConfig": "config", "load_config": "config",
    "prepare": "data", "split_indices": "data", "vst_mosaic": "data",
    "confusion": "evaluate", "evaluate_store": "evaluate", "iou": "evaluate", "scores": "evaluate",
    "load_model": "train", "train_store": "train",
}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    module = _NAMES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_NAMES))
