"""Car segmentation on raw images: compact U-Net on packed, variance-stabilised CFA planes.

- ``data``: preprocessing (VST, canonical CFA packing, car fraction per pixel), split, crops;
- ``condition``: the payload vector of an image's profile that a conditioned network takes (off by default);
- ``model``: the U-Net (plain torch; FiLM conditioning optional) and its resampling wrapper (upsample / pool);
- ``train``: training one model per parameter point (``train_store``), checkpoints;
- ``evaluate``: IoU / precision / recall per image and pooled (``evaluate_store``): a store's test split,
  or every image of a foreign store, resampled to the model's training ground sampling;
- ``predict``: car probability and mask per image of any store (``metraw predict``), overlay figures;
- ``onthefly`` and ``pretrain``: training on fresh draws of the source scenes (``metraw.emulate.draws``).
"""

from metraw.segment.data import prepare, split_indices, vst_mosaic
from metraw.segment.evaluate import confusion, evaluate_store, iou, scores
from metraw.segment.train import TrainConfig, load_config, load_model, train_store

__all__ = ["TrainConfig", "confusion", "evaluate_store", "iou", "load_config", "load_model",
           "prepare", "scores", "split_indices", "train_store", "vst_mosaic"]

