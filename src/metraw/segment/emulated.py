"""On-the-fly emulation as data augmentation: one model trained across a tolerance box.

``EmulatedDataset`` draws, for every sample, a target parameter point from a box (uniform
ranges or discrete values per parameter), emulates the source image with ``metraw.emulate``
(photon statistics and label geometry as in the per-point stores) and returns a preprocessed,
CFA-respecting random crop. Randomness depends only on (seed, epoch, sample index) through
``numpy.random.SeedSequence``, so results do not depend on the number of DataLoader workers.
Call ``set_epoch(e)`` before each epoch (workers are re-created per epoch and see it).
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, Sequence

import numpy as np

from metraw.raw.cfa import PACKED_CELL_PX
from metraw.errors import MetrawError
from metraw.segment.data import prepare


def draw_point(box: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """One parameter point from ``box``: name -> [low, high] (uniform), or {"values": [...]} (choice),
    or {"low": a, "high": b, "log": true} (log-uniform)."""
    point = {}
    for name, spec in sorted(box.items()):
        if isinstance(spec, dict) and "values" in spec:
            values = list(spec["values"])
            point[name] = values[int(rng.integers(0, len(values)))]
        else:
            if isinstance(spec, dict):
                lo, hi, log = float(spec["low"]), float(spec["high"]), bool(spec.get("log", False))
            elif isinstance(spec, (list, tuple)) and len(spec) == 2:
                lo, hi, log = float(spec[0]), float(spec[1]), False
            else:
                raise MetrawError(f"box entry {name!r} must be [low, high], {{low, high[, log]}} or {{values: [...]}}")
            if not lo <= hi or (log and lo <= 0):
                raise MetrawError(f"box entry {name!r} has an invalid range [{lo}, {hi}]")
            u = rng.random()
            point[name] = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if log else lo + u * (hi - lo)
    return point


class EmulatedDataset:
    """Torch map-style dataset: source image ``indices[i]`` emulated at a random point of ``box``.

    ``source``: path of the source RawStore (opened lazily in each worker process).
    ``params``: params dict or path (``target.nominal`` gives the parameters not in ``box``).
    ``crop_px``: crop side in packed pixels (whole image if smaller); ``augment``: dihedral
    transforms. Items are (planes float32 (S, h, w), site car fractions float32 (S, h, w)).
    ``preload()`` decodes the source images once in this process: DataLoader workers forked
    from it share them (copy-on-write) instead of decoding every image again in every epoch
    (~7 MB per 1024 x 1024 image with its mask and flags).
    """

    def __init__(self, source, indices: Sequence[int], box: dict[str, Any], params: Any = "params.yaml",
                 crop_px: int = 64, seed: int = 0, mode: str = "auto", augment: bool = True,
                 emulate_kwargs: dict[str, Any] | None = None):
        from metraw.study.points import load_params

        self.source = str(source)
        self.indices = [int(i) for i in indices]
        self.box = dict(box)
        self.params = load_params(params) if isinstance(params, (str, os.PathLike)) else params
        self.crop_px = int(crop_px)
        self.seed = int(seed)
        self.mode = mode
        self.augment = augment
        self.emulate_kwargs = dict(emulate_kwargs or {})
        self.epoch = 0
        self._store = None
        self._preloaded: dict[int, Any] = {}
        draw_point(self.box, np.random.default_rng(0))  # validate the box now, in the parent

    def preload(self, progress: bool = False) -> "EmulatedDataset":
        """Decode every source image of ``indices`` now (kept in memory; see the class docstring)."""
        from metraw.progress import progress_bar
        from metraw.io.store import RawStore

        store = RawStore.open(self.source)
        for i in progress_bar(sorted(set(self.indices)), desc="preload sources", disable=not progress):
            self._preloaded[i] = store[i]
        return self

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.indices)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_store"] = None  # each worker opens its own handle
        state["_preloaded"] = {}  # pickled (spawned) workers read the store instead of copying the images
        return state

    def _rng(self, i: int) -> np.random.Generator:
        ss = np.random.SeedSequence(self.seed, spawn_key=(self.epoch, int(i)))
        return np.random.Generator(np.random.PCG64(ss))

    def sample(self, i: int):
        """(RawImage emulated, point) for item ``i`` of the current epoch."""
        from metraw.emulate.emulator import emulate
        from metraw.io.store import RawStore
        from metraw.emulate.target import TargetSystem

        source = self._preloaded.get(self.indices[i])
        if source is None:
            if self._store is None:
                self._store = RawStore.open(self.source)
            source = self._store[self.indices[i]]
        rng = self._rng(i)
        point = draw_point(self.box, rng)
        target = TargetSystem.from_params(self.params, point)
        image = emulate(source, target, self.mode, rng, **self.emulate_kwargs)
        return image, point

    def __getitem__(self, i: int):
        image, _ = self.sample(i)
        rng = self._rng(i)
        rng.random(16)  # decorrelate the crop stream from the point draw (same generator seed)
        return prepare(image, self.indices[i]).crop(self.crop_px, rng, self.augment)


def crop_collate(items):
    """Stack (planes, fraction) items, cutting all to the smallest common packed size."""
    import torch

    h = min(x.shape[-2] for x, _ in items)
    w = min(x.shape[-1] for x, _ in items)
    x = np.stack([a[:, :h, :w] for a, _ in items])
    y = np.stack([b[:, :h, :w] for _, b in items])
    return torch.from_numpy(x), torch.from_numpy(y)


def _worker_init(worker_id: int) -> None:
    import torch

    torch.set_num_threads(1)


def fit_emulated(dataset: EmulatedDataset, config, workers: int = 2, device: str | None = None,
                 progress: bool | None = None, upsample: int = 1):
    """Train one model on ``dataset`` (same architecture and hyperparameters as ``train.fit``).

    Emulation runs in ``workers`` DataLoader processes; the sample order is drawn from a seeded
    torch generator and every sample's randomness from (seed, epoch, index): deterministic for any
    number of workers. ``upsample`` fixes the input upsampling factor (choose it at the nominal point).
    """
    import torch
    from torch.utils.data import DataLoader

    from metraw.segment.train import build_model, default_device, resolve_precision, set_determinism, train_loop

    device = device or default_device()
    set_determinism(config.seed, config.threads, device)
    first, _ = dataset.sample(0)
    in_ch = PACKED_CELL_PX ** 2  # every mosaic packs in 4 planes (metraw.raw.cfa.PACKED_CELL_PX)
    model = build_model(in_ch, config, upsample).to(device)
    gen = torch.Generator().manual_seed(config.seed)
    steps = math.ceil(len(dataset) / config.batch_size)

    def epoch_batches(epoch):
        dataset.set_epoch(epoch)
        loader = DataLoader(dataset, batch_size=config.batch_size, shuffle=True, generator=gen,
                            num_workers=workers, collate_fn=crop_collate, worker_init_fn=_worker_init,
                            persistent_workers=False)
        yield from loader

    t0 = time.perf_counter()
    losses = train_loop(model, epoch_batches, steps, config, device, progress)
    record = {"epochs": config.epochs, "steps": steps * config.epochs, "loss_per_epoch": losses,
              "training_time_s": time.perf_counter() - t0, "device": device, "upsample": upsample,
              "in_channels": in_ch, "n_train": len(dataset), "box": dataset.box, "emulation_mode": dataset.mode,
              "emulated_on_the_fly": True, "precision": resolve_precision(config.precision, device)}
    return model, record
