"""Training on fresh target draws: every epoch sees new target images of the source scenes (issue #15).

An emulated store holds one image per source scene; a network trained on those few hundred arrays
of ~34 x 34 packed pixels overfits them (so the workflow's per-point stores hold only the test split:
``metraw emulate --images test``). Here each training scene gets its
``metraw.emulate.draws.PhaseField`` (the expected stage, computed once, ~40 ms per 1024 px scene) and every
epoch draws, per scene, a new target raw: a random sampling phase of the target pixel grid on the
ground (a whole CFA period in steps of GSD/K), a random flip of the scene, fresh photon and read
noise. Each draw is exactly what the emulator would record (``tests/test_draws.py``); no
augmentation is applied after the target CFA is laid (no rotation of the smear, no CFA shift).

Determinism: draw k of scene i in epoch e uses ``SeedSequence(seed, spawn_key=(e, i))``; batches
and crops come from one seeded generator, as in ``metraw.segment.train.fit``.
"""

from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np

from metraw.emulate.draws import DEFAULT_OVERSAMPLE, PhaseField, build_field
from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.parallel import fork_pool, ordered_ahead
from metraw.raw.cfa import PACKED_CELL_PX, cfa_family
from metraw.raw.sensor import rng_from_seed
from metraw.segment.config import TrainConfig
from metraw.segment.data import batch_crops, prepare
from metraw.segment.train import default_device, new_network, train_loop, training_packed_gsd_m


def build_fields(store, indices: Sequence[int], target, oversample: int = DEFAULT_OVERSAMPLE,
                 progress: bool | None = None, workers: int = 1) -> list[PhaseField]:
    """``PhaseField`` of source images ``indices`` of a RawStore seen by ``target`` (``scene_fields``)."""
    return [f for (f,) in scene_fields([(store, int(i), int(i), [target]) for i in indices], oversample,
                                       progress, workers)]


def scene_fields(jobs: Sequence[tuple[Any, int, int, Sequence[TargetSystem]]], oversample: int = DEFAULT_OVERSAMPLE,
                 progress: bool | None = None, workers: int = 1, desc: str = "expected fields") -> list[list[PhaseField]]:
    """Per job (RawStore, image index, draw index, targets) the ``PhaseField`` s of that image at its targets, in
    job order (the image is read once for all of them). ``workers`` > 1: in that many worker processes, each
    reading the stores by path; every image is decoded on one codec thread (``metraw.codec.threads``), so that
    ``workers`` is the cores used (a second codec thread cost ~12 % more CPU per 1 MP source image: 39 against
    35 ms). The fields depend on neither. The draw index seeds the scene's draws (``draw_rng``)."""
    from metraw import codec
    from metraw.parallel import ordered_map
    from metraw.progress import progress_bar

    if workers < 1:
        raise MetrawError(f"workers must be >= 1, got {workers}")
    stores = {str(store.path): store for store, *_ in jobs}
    job = _SceneFields(stores, oversample)
    items = [(str(store.path), int(i), int(index), list(targets)) for store, i, index, targets in jobs]
    disable = None if progress is None else not progress
    with codec.threads(1):
        return list(progress_bar(ordered_map(job, items, workers, chunksize=4), total=len(items), desc=desc,
                                 disable=disable))


class _SceneFields:
    """``scene_fields``' job, picklable for worker processes: they reopen the stores by path (once per task)."""

    def __init__(self, stores: dict, oversample: int):
        self.stores, self.oversample = stores, int(oversample)

    def __getstate__(self):
        return {"stores": {}, "oversample": self.oversample}

    def __call__(self, item) -> list[PhaseField]:
        from metraw.io.store import RawStore

        path, i, index, targets = item
        if path not in self.stores:
            self.stores[path] = RawStore.open(path)
        image = self.stores[path][i]
        return [build_field(image, t, self.oversample, index=index) for t in targets]


def draw_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator of one draw: scene ``index`` in ``epoch`` (independent of batch order and workers)."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed), spawn_key=(int(epoch), int(index)))))


def draw_prepared(field: PhaseField | Sequence[PhaseField], seed: int, epoch: int, codec_step: float | None = None):
    """One fresh draw of ``field`` prepared for the segmenter (VST, mask). A sequence of fields (the same
    scene at several target points) draws one of them uniformly first (the robust model's box).
    ``codec_step``: pass the draw through the noise-preserving codec at that step, as the per-point stores
    are (their test images are what the model is scored on)."""
    fields = [field] if isinstance(field, PhaseField) else list(field)
    rng = draw_rng(seed, epoch, fields[0].index)
    chosen = fields[int(rng.integers(0, len(fields)))] if len(fields) > 1 else fields[0]
    image = chosen.draw(rng)
    if codec_step:
        image = through_codec(image, codec_step, int(rng.integers(0, 2**31)))
    return prepare(image, chosen.index)


def through_codec(image, step: float, seed: int):
    """``image`` with its raw replaced by its round trip through the noise-preserving codec (step, dither seed):
    ``codec.round_trip``, the pixels ``decode(encode(...))`` gives, without coding them."""
    from dataclasses import replace

    from metraw.codec import round_trip

    return replace(image, data=round_trip(image, step, seed))


def fit_draws(fields: list, config: TrainConfig, device: str | None = None,
              progress: bool | None = None, init_state: dict[str, Any] | None = None,
              draws_per_epoch: int = 1, static: bool = False, codec_step: float | None = None,
              upsample: int | None = None, payload_keys: Sequence[Sequence[Any]] | None = None,
              draw_workers: int = 0) -> tuple[Any, dict[str, Any]]:
    """Train on fresh draws of ``fields`` (``draws_per_epoch`` per scene per epoch); returns (model, record).

    ``fields``: one ``PhaseField`` per training scene, or per scene a list of fields (one per target
    point of a box: each draw picks one). ``init_state``: a state dict to start from (fine-tuning a
    pretrained network of the same architecture); None trains from scratch. Same network, loss and
    schedule as ``train.fit``. ``static=True`` is the baseline of a per-point store: one fixed draw per
    scene for the whole training, with the stores' dihedral augmentation after the CFA (``train.fit``).
    ``upsample``: input upsampling factor overriding ``config.min_grid_px``'s (``train.new_network``).
    ``payload_keys`` (box fields only): per scene, per field a sortable key of its payload. Each epoch every draw
    first picks its field, the draws are sorted by key and cut into batches of ``config.batch_size``, and the
    batches are shuffled: each batch holds one payload, or neighbouring ones (``payload_batches``). Without it a
    batch mixes payloads at random. ``draw_workers`` > 0: the draws are made in that many forked processes (they
    inherit ``fields``), up to ``DRAWS_AHEAD`` batches ahead of the training, for a device that trains faster than
    one core draws (a GPU); 0 makes them in the training process's prefetch thread. Every draw has its own seed
    and the crops are cut here in batch order, so the model does not depend on ``draw_workers``.
    """
    if not fields:
        raise MetrawError("no training scenes")
    if draw_workers < 0:
        raise MetrawError(f"draw workers must be >= 0, got {draw_workers}")
    device = device or default_device()
    box = not isinstance(fields[0], PhaseField)
    if payload_keys is not None and (not box or static or len(payload_keys) != len(fields)
                                     or any(len(k) != len(f) for k, f in zip(payload_keys, fields))):
        raise MetrawError("payload_keys needs box fields (per scene a list of fields) and one key per field")
    every = [f for scene in fields for f in ([scene] if isinstance(scene, PhaseField) else scene)]
    first = every[0]
    families = {cfa_family(f.target.cfa_pattern) for f in every}
    if len(families) > 1:
        raise MetrawError("the training fields mix mono and colour-filter targets: a network learns one sensor's "
                          "images; train them separately")
    probe = [prepare(first.draw(0), first.index)]
    fixed = [draw_prepared(f, config.seed, 0, codec_step) for f in fields] if static else None
    model, f_up, pool, in_ch = new_network(probe, config, device, upsample)
    if init_state is not None:
        try:
            model.load_state_dict(init_state)
        except RuntimeError:
            raise MetrawError("the pretrained weights do not fit this network (another depth, width or input "
                              "layout): pretrain with the same training profile") from None
    n = len(fields) * draws_per_epoch
    steps_per_epoch = math.ceil(n / config.batch_size)
    rng = rng_from_seed(config.seed)
    # wall time spent making the batches; they are made in train_loop's prefetch thread, beside the training steps,
    # so it overlaps training_time_s (not a part of it to subtract)
    timing = {"draw_s": 0.0}

    def epoch_batches(epoch, draw_pool=None):
        if payload_keys is None:
            order = rng.permutation(n)
            batches = [order[s * config.batch_size:(s + 1) * config.batch_size] for s in range(steps_per_epoch)]
            chosen = None
        else:
            batches, chosen = payload_batches(payload_keys, draws_per_epoch, config.batch_size, rng)
        if static:
            made = ([fixed[j % len(fields)] for j in ids] for ids in batches)
        else:  # draw j: its scene's field(s) (-1), or the one field payload_batches chose for it
            specs = [[(int(j % len(fields)), -1 if chosen is None else int(chosen[j]),
                       epoch * draws_per_epoch + int(j) // len(fields)) for j in ids] for ids in batches]
            made = (map(_draw_batch, specs) if draw_pool is None
                    else ordered_ahead(draw_pool, _draw_batch, specs, DRAWS_AHEAD))
        t0 = time.perf_counter()
        for batch in made:
            xy = batch_crops(batch, config.crop_px * pool, rng, augment=static)
            timing["draw_s"] += time.perf_counter() - t0
            yield xy
            t0 = time.perf_counter()

    t0 = time.perf_counter()
    _DRAWING.update(fields=fields, seed=config.seed, codec_step=codec_step)
    try:
        if draw_workers and not static:
            from metraw import codec

            with codec.threads(1):  # forked inside: each draw process codes on one thread (the bytes do not change)
                draw_pool = fork_pool(draw_workers)
            with draw_pool:
                losses = train_loop(model, lambda epoch: epoch_batches(epoch, draw_pool), steps_per_epoch, config,
                                    device, progress)
        else:
            losses = train_loop(model, epoch_batches, steps_per_epoch, config, device, progress)
    finally:
        _DRAWING.clear()
    total = time.perf_counter() - t0
    record = {"epochs": config.epochs, "steps": steps_per_epoch * config.epochs, "loss_per_epoch": losses,
              "training_time_s": total, "draw_time_s": timing["draw_s"], "device": device, "upsample": f_up,
              "pool": pool, "in_channels": in_ch, "sensor": families.pop(), "n_train": len(fields),
              "draws": n * config.epochs,
              "draws_per_epoch": draws_per_epoch, "oversample": first.oversample, "static": static, "codec_step": codec_step,
              "fine_tuned": init_state is not None, "payload_batches": payload_keys is not None,
              # a box trains at every packed GSD of its targets, not at the first draw's
              "train_packed_gsd_m": packed_gsd_range_m(every) if box else training_packed_gsd_m(probe),
              "on_the_fly": True}
    return model, record


# batches of draws a draw process pool makes ahead of the training (fit_draws' draw_workers): enough to keep its
# processes busy while the training takes one, few enough that the waiting batches take little memory
DRAWS_AHEAD = 32
# what fit_draws is drawing from: the fields, the training seed and the codec step. The training process's own
# draws read it, and a draw pool's processes inherit it when they fork (the fields are not pickled).
_DRAWING: dict[str, Any] = {}


def _draw_batch(specs: Sequence[tuple[int, int, int]]) -> list:
    """The prepared draws of one batch: per draw (scene, chosen field or -1 for the scene's own choice, draw epoch)
    of ``_DRAWING``'s fields (``draw_prepared``)."""
    fields, seed, codec_step = _DRAWING["fields"], _DRAWING["seed"], _DRAWING["codec_step"]
    return [draw_prepared(fields[scene] if field < 0 else fields[scene][field], seed, epoch, codec_step)
            for scene, field, epoch in specs]


def payload_batches(payload_keys: Sequence[Sequence[Any]], draws_per_epoch: int, batch_size: int,
                    rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray]:
    """One epoch of payload-homogeneous batches: draw j (scene j % n, n scenes, ``draws_per_epoch`` draws each)
    picks field ``chosen[j]`` of its scene uniformly; the draws sorted by that field's key are cut into batches of
    ``batch_size`` (the last may be short), returned in random order. Returns (batches of draw ids, chosen).

    Why: the soft Dice term of the loss (``segmentation_loss``) is pooled over a batch. Across a box of payloads a
    mixed batch's Dice is carried by its bright, sharp images, and a network told each image's payload
    (``TrainConfig.condition``) then learns to predict no car at the dim corner; batch crops are also cut to the
    batch's smallest image. Batches of one payload keep the Dice per payload, as fine-tuning at one point does
    (docs/training.md, "Batches of one payload")."""
    n = len(payload_keys) * draws_per_epoch
    chosen = rng.integers(0, np.tile([len(keys) for keys in payload_keys], draws_per_epoch)).astype(np.int64)
    order = sorted(rng.permutation(n).tolist(), key=lambda j: payload_keys[j % len(payload_keys)][chosen[j]])
    batches = [np.array(order[s:s + batch_size], np.int64) for s in range(0, n, batch_size)]
    return [batches[i] for i in rng.permutation(len(batches))], chosen


def packed_gsd_range_m(fields: Sequence[PhaseField]) -> list[float]:
    """[lowest, highest] packed-grid GSD [m per packed pixel] of the fields' targets (mosaic GSD x CFA cell side):
    what a model trained across a box records (evaluate / predict resample only images outside it)."""
    gsds = [f.target.gsd_m * PACKED_CELL_PX for f in fields]
    return [float(min(gsds)), float(max(gsds))]


def store_target(store) -> TargetSystem:
    """The target an emulated store was made for (its first image's ``emulate`` provenance)."""
    for entry in reversed(store[0].provenance if len(store) else []):
        if entry.get("function") == "emulate" and "target" in entry.get("params", {}):
            return TargetSystem.from_dict(entry["params"]["target"])
    raise MetrawError("the store holds no emulated images (no 'emulate' step in its provenance): on-the-fly "
                      "training needs a per-point store emulated from --source")


def train_store_on_the_fly(store_path, source_path, out_dir, config: TrainConfig, device: str | None = None,
                           progress: bool | None = None, overwrite: bool = False,
                           codec_step: float | None = None, init_dir=None, workers: int = 1,
                           draw_workers: int = 0) -> dict[str, Any]:
    """Train ``config.replicates`` models on fresh draws of ``source_path``'s training scenes at the target of the
    emulated store ``store_path`` (emulated from that source: all its images, or only its test split with
    ``metraw emulate --images test``); write them like ``train.train_store``. The source's test split, held by the
    store, stays the fixed test set. ``init_dir``: a pretrained model
    directory (``metraw pretrain``): replicate r fine-tunes its replicate r (``config.epochs`` epochs). ``workers``:
    processes building the scenes' expected fields (``scene_fields``); ``draw_workers``: processes drawing from them
    during the training (``fit_draws``)."""
    from metraw.io.store import RawStore
    from metraw.segment.data import source_indices, split_indices, split_positions
    from metraw.segment.train import check_network, fit_replicates, pretrained_states, save_replicates, store_digest

    check_network(config)
    store = RawStore.open(store_path)
    source = RawStore.open(source_path)
    _, n_source = source_indices(store)
    if n_source != len(source):
        raise MetrawError(f"{store_path} was emulated from a {n_source}-image source but the source {source_path} has "
                          f"{len(source)}: it was not emulated from that source")
    target = store_target(store)
    train_idx, test_idx = split_indices(n_source, config.test_fraction, config.split_seed)
    split_positions(store, config.test_fraction, config.split_seed)  # the store holds the test split
    inits = (pretrained_states(init_dir, max(1, config.replicates), cfa_family(target.cfa_pattern),
                               config.model) if init_dir is not None else None)
    t0 = time.perf_counter()
    fields = build_fields(source, train_idx, target, progress=progress, workers=workers)
    fields_s = time.perf_counter() - t0
    digest = store_digest(store)
    runs = fit_replicates(config, lambda cfg: fit_draws(fields, cfg, device, progress,
                                                        init_state=None if inits is None else inits[cfg.seed - config.seed],
                                                        draws_per_epoch=cfg.draws_per_epoch, codec_step=codec_step,
                                                        draw_workers=draw_workers),
                          {"store": str(store_path), "store_digest": digest, "source": source.origin,
                           "init": None if init_dir is None else str(init_dir),
                           "n_images": len(store), "source_images": n_source, "train_indices": train_idx.tolist(),
                           "test_indices": test_idx.tolist(), "preprocess_time_s": fields_s}, device)
    save_replicates(out_dir, runs, test_idx, overwrite)
    return runs[0][2]
