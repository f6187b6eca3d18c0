"""Pretraining across the tolerance box, fine-tuning per point (issue #15, items 2-3).

Training every point from scratch spends most of the sweep's time teaching each network the same
things (what a car looks like in noisy packed raw planes) from only the few hundred source scenes a
point sees. Here one network per replicate learns once from fresh draws of many scenes across a box
of target parameters (``training.pretrain.box``: parameter -> [low, high]): each scene gets
``points_per_scene`` points, each the nominal payload with one box parameter drawn log-uniform in its
range (the study's one-at-a-time structure, without its grid of values), and each of its draws picks one
of them (``onthefly.draw_prepared``). Every CFA pattern among the points gets its own pretraining (the box's
targets carry that pattern: a mono network's input differs from a Bayer one's), and each point then fine-tunes
its replicate r from replicate r of its pattern's pretraining for a few epochs
(``onthefly.train_store_on_the_fly(init_dir=...)``), so replicates stay independent trainings and points of
different sensors are trained alike. The box is declared on its own, not taken from the sweeps, so
changing a sweep value reruns only that point (the pretrained networks do not depend on it).

Scenes come from the source store's training split (its test split is every point's test set and is
never drawn) and, optionally, from stores of further scenes that belong to no test set (another
generator seed). Their draw streams are told apart by the scene index: the extra stores' scenes are
numbered after the source's. Which pretrainings a study needs, from its params alone: ``metraw.study.pretraining``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from metraw.emulate.draws import DEFAULT_OVERSAMPLE
from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.raw.cfa import cfa_family
from metraw.raw.sensor import rng_from_seed
from metraw.segment.config import TrainConfig
from metraw.study.pretraining import BATCHES


def sample_box(box: dict[str, Sequence[float]], n_scenes: int, points_per_scene: int,
               seed: int) -> list[list[dict[str, float]]]:
    """Per scene ``points_per_scene`` overrides of the nominal payload, each one parameter of ``box``
    (name -> [low, high], both > 0) drawn log-uniform in its range; the same for the same arguments."""
    if not box:
        raise MetrawError("the pretraining box is empty (training.pretrain.box: parameter -> [low, high])")
    if points_per_scene < 1:
        raise MetrawError(f"points_per_scene must be >= 1, got {points_per_scene}")
    for name, (low, high) in box.items():
        if not 0 < low < high:
            raise MetrawError(f"pretraining box {name}: the range [{low}, {high}] must have 0 < low < high")
    names = list(box)
    rng = rng_from_seed(seed)
    out = []
    for _ in range(n_scenes):
        axes = rng.integers(0, len(names), size=points_per_scene)
        u = rng.random(points_per_scene)
        out.append([{names[a]: float(math.exp(math.log(box[names[a]][0])
                                             + ui * math.log(box[names[a]][1] / box[names[a]][0])))}
                    for a, ui in zip(axes, u)])
    return out


def payload_keys(box: dict[str, Sequence[float]], overrides: Sequence[Sequence[dict[str, float]]]
                 ) -> list[list[tuple[int, float]]]:
    """Per scene, per point of ``sample_box`` the batch key (index of its box parameter, log of its value): sorted,
    the draws of one parameter come together, in the order of its value."""
    names = list(box)
    return [[(names.index(name), math.log(value)) for o in per_scene for name, value in o.items()]
            for per_scene in overrides]


def box_fields(scenes: Sequence[tuple[Any, int, int]], targets: Sequence[Sequence[TargetSystem]],
               oversample: int = DEFAULT_OVERSAMPLE, progress: bool | None = None, workers: int = 1) -> list[list]:
    """Per scene (store, image index, draw index) the ``PhaseField`` s at its ``targets`` (all of one CFA family;
    ``onthefly.scene_fields``: ``workers`` processes)."""
    from metraw.segment.onthefly import scene_fields

    if len({cfa_family(t.cfa_pattern) for ts in targets for t in ts}) > 1:
        raise MetrawError("the pretraining box mixes mono and colour-filter targets (the network inputs differ)")
    return scene_fields([(store, i, draw_index, ts) for (store, i, draw_index), ts in zip(scenes, targets)],
                        oversample, progress, workers, desc="box fields")


@dataclass
class BoxDraws:
    """What a pretraining draws from: the box fields of its scenes, their batch keys and the record's common part."""
    fields: list            # per scene the PhaseFields at its box points (``box_fields``)
    keys: list | None       # per scene, per field the batch key (``payload_keys``); None for mixed batches
    test_indices: Any       # the source's test split (never drawn)
    common: dict[str, Any]  # what every replicate's record holds about the data


def prepare_box(source_path, make_target: Callable[[dict[str, float]], TargetSystem], box: dict[str, Sequence[float]],
                config: TrainConfig, points_per_scene: int, extra_paths: Sequence = (), progress: bool | None = None,
                workers: int = 1, batches: str = "payload", max_scenes: int | None = None) -> BoxDraws:
    """The box fields of the training split of ``source_path`` and every scene of ``extra_paths`` (``sample_box``
    seeded with ``config.seed``; ``make_target`` turns an override into the full target), built by ``workers``
    processes. ``max_scenes``: only the first that many scenes (source first; the box points of a scene do not
    depend on how many follow it)."""
    from metraw.io.store import RawStore
    from metraw.segment.data import split_indices

    if batches not in BATCHES:
        raise MetrawError(f"pretraining batches must be one of {', '.join(BATCHES)}, got {batches!r}")
    source = RawStore.open(source_path)
    train_idx, test_idx = split_indices(len(source), config.test_fraction, config.split_seed)
    scenes = [(source, int(i), int(i)) for i in train_idx]
    first = len(source)
    extras = [RawStore.open(path) for path in extra_paths]
    for extra in extras:
        scenes += [(extra, i, first + i) for i in range(len(extra))]
        first += len(extra)
    if max_scenes is not None:
        scenes = scenes[:max_scenes]
    overrides = sample_box(box, len(scenes), points_per_scene, config.seed)
    t0 = time.perf_counter()
    fields = box_fields(scenes, [[make_target(o) for o in per_scene] for per_scene in overrides], progress=progress,
                        workers=workers)
    common = {"pretraining": True, "source": source.origin, "extra_sources": [extra.origin for extra in extras],
              "n_images": len(source), "train_indices": train_idx.tolist(), "test_indices": test_idx.tolist(),
              "box": {k: [float(v) for v in r] for k, r in box.items()}, "points_per_scene": int(points_per_scene),
              "batches": batches, "preprocess_time_s": time.perf_counter() - t0}
    return BoxDraws(fields, payload_keys(box, overrides) if batches == "payload" else None, test_idx, common)


def fit_box(draws: BoxDraws, config: TrainConfig, device: str | None = None, progress: bool | None = None,
            codec_step: float | None = None, draw_workers: int = 0, n_scenes: int | None = None) -> list:
    """``config.replicates`` networks trained on fresh draws of ``draws`` (``onthefly.fit_draws``; ``n_scenes``: of
    its first that many scenes only); [(model, config, record), ...] for ``train.save_replicates``."""
    from metraw.segment.onthefly import fit_draws
    from metraw.segment.train import fit_replicates

    n = len(draws.fields) if n_scenes is None else n_scenes
    if not 0 < n <= len(draws.fields):
        raise MetrawError(f"n_scenes must be in 1..{len(draws.fields)}, got {n}")
    keys = None if draws.keys is None else draws.keys[:n]
    return fit_replicates(config, lambda cfg: fit_draws(draws.fields[:n], cfg, device, progress,
                                                        draws_per_epoch=cfg.draws_per_epoch, codec_step=codec_step,
                                                        payload_keys=keys, draw_workers=draw_workers),
                          draws.common, device)


def pretrain_stores(source_path, make_target: Callable[[dict[str, float]], TargetSystem], box: dict[str, Sequence[float]],
                    out_dir, config: TrainConfig, points_per_scene: int, extra_paths: Sequence = (),
                    device: str | None = None, progress: bool | None = None, overwrite: bool = False,
                    codec_step: float | None = None, workers: int = 1, batches: str = "payload",
                    draw_workers: int = 0) -> dict[str, Any]:
    """Pretrain ``config.replicates`` networks on ``box`` (``sample_box``, seeded with ``config.seed``;
    ``make_target`` turns an override into the full target) from the training split of ``source_path``
    (the split every point's test set comes from) and every scene of ``extra_paths``; write them like
    ``train.train_store`` (model directory with replicate sub-directories). Returns the first replicate's record.
    ``workers``: processes building the box's expected fields (``box_fields``); ``draw_workers``: processes drawing
    from them during the training (``onthefly.fit_draws``). ``batches``: one of ``BATCHES``."""
    from metraw.segment.train import check_network, save_replicates

    check_network(config)
    draws = prepare_box(source_path, make_target, box, config, points_per_scene, extra_paths, progress, workers, batches)
    runs = fit_box(draws, config, device, progress, codec_step, draw_workers)
    save_replicates(out_dir, runs, draws.test_indices, overwrite)
    return runs[0][2]
