"""Training of the car segmenter on one parameter point (one RawStore).

One architecture, one set of hyperparameters (a ``TrainConfig`` from the ``training:`` section
of params.yaml) and one fixed split (``split_seed``, by image index) for every parameter point,
so points differ only by their data. Deterministic on CPU: same seed and data give the same
weights and the same IoU (seeded torch, deterministic algorithms, fixed thread count, all
random crops and augmentations drawn from one seeded numpy generator in the main process).
CUDA is used when present (deterministic algorithms requested, warn-only there).

``model.pt`` and ``train.json`` are a function of the data, the code and the config (seed and
thread count included): two runs on one machine write the same bytes. Wall-clock timings
(``TIMINGS``) are returned in the in-memory training record but never written to them: they go to
the command's log (stderr). Another machine may give other weights: torch's CPU kernels pick
their instruction set (AVX2, AVX-512, oneDNN) and summation order by processor.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.parallel import prefetch
from metraw.raw.cfa import PACKED_CELL_PX, cfa_family
from metraw.raw.sensor import rng_from_seed
from metraw.segment.config import COVER, LOSSES, TrainConfig
from metraw.segment.data import PreparedImage, batch_crops, prepare_store, source_indices, split_indices

CHECKPOINT = "model.pt"
TRAIN_METRICS = "train.json"
#: Sub-directory of a model directory holding replicate ``r`` (seed + r), a model directory itself.
REPLICATE_DIR = "replicate-{r}"
#: ``torch.cpu`` probes of native bfloat16 (AVX512-BF16, AMX): "auto" trains in bfloat16 on a CPU where one is true.
BF16_CPU_PROBES = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
#: Training batches made ahead by a background thread while the network trains on the current one
#: (``metraw.parallel.prefetch``: the on-the-fly draws overlap torch; the same batches in the same order).
#: 0: made in turn with the training steps.
PREFETCH_BATCHES = 2
#: Wall-clock fields of the training record: returned by ``fit``/``train_store``, left out of train.json.
TIMINGS = ("training_time_s", "preprocess_time_s", "draw_time_s", "replicate_training_time_s")


def default_device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def resolve_precision(precision: str, device: str) -> str:
    """The arithmetic ``precision`` stands for on ``device``: "auto" is "bfloat16" on a CUDA GPU that supports it
    and on a CPU with bfloat16 instructions (AVX512-BF16 or AMX: oneDNN then runs bfloat16 convolutions natively),
    else "float32"; "float32" and "bfloat16" stand for themselves. A resolved training is deterministic on a
    given machine; the same params may train in another arithmetic on another machine, which the record says."""
    if precision != "auto":
        return precision
    import torch

    kind = torch.device(device).type
    if kind == "cuda":
        return "bfloat16" if torch.cuda.is_bf16_supported() else "float32"
    if kind == "cpu":
        # the hardware's bfloat16 units, and ATen dispatching its AVX-512 kernels (ATEN_CPU_CAPABILITY=avx2 caps it:
        # a host run as an AVX2-only one trains in float32, as such a host would)
        capability = getattr(torch.backends.cpu, "get_cpu_capability", lambda: "AVX512")()
        probes = (getattr(torch.cpu, name, None) for name in BF16_CPU_PROBES)
        native = capability.startswith("AVX512") and any(probe is not None and probe() for probe in probes)
        return "bfloat16" if native else "float32"
    return "float32"


def set_determinism(seed: int, threads: int, device: str) -> None:
    """Seed torch, request deterministic algorithms and fix the CPU thread count."""
    import torch

    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.manual_seed(seed)
    if "torch._inductor.config" in sys.modules:  # a caller compiles: its Inductor config is told as well
        torch.use_deterministic_algorithms(True, warn_only=device != "cpu")
    else:  # the same eager-mode switch without importing Inductor (~1 s of every metraw train/evaluate process)
        torch._C._set_deterministic_algorithms(True, warn_only=device != "cpu")
    torch.set_num_threads(threads)
    if device != "cpu":
        torch.backends.cudnn.benchmark = False


def upsample_factor(images: list[PreparedImage], min_grid_px: int) -> int:
    """Integer bilinear upsampling factor bringing the smallest packed side to >= min_grid_px."""
    if min_grid_px <= 0:
        return 1
    side = min(min(img.packed_shape) for img in images)
    return max(1, math.ceil(min_grid_px / side))


def pool_factor(images: list[PreparedImage], grid_gsd_m: float) -> int:
    """Integer average-pooling factor so a working-grid pixel is about ``grid_gsd_m`` on the ground.

    floor(grid_gsd_m / packed GSD) of the finest image, at least 1; 1 when ``grid_gsd_m`` <= 0
    or an image's profile lacks the geometry (GSD unknown).
    """
    gsds = packed_gsds_m(images)
    if grid_gsd_m <= 0 or gsds is None:
        return 1
    return max(1, int(math.floor(grid_gsd_m / min(gsds) + 1e-9)))


def packed_gsds_m(images: list[PreparedImage]) -> list[float] | None:
    """Packed-grid GSD of every image [m per packed pixel] (mosaic GSD x CFA cell side); None when an
    image's profile lacks the geometry (or there are no images)."""
    gsds = [img.gsd_m * PACKED_CELL_PX for img in images if img.gsd_m]
    return gsds if gsds and len(gsds) == len(images) else None


def training_packed_gsd_m(images: list[PreparedImage]) -> float | None:
    """Median ground sample distance of the training images' packed grid [m per packed pixel]
    (mosaic GSD x CFA cell side); None when any image's profile lacks the geometry. Recorded in the
    checkpoint so that ``metraw evaluate`` / ``predict`` can resample images of another GSD to it."""
    gsds = packed_gsds_m(images)
    return None if gsds is None else float(np.median(gsds))


def store_digest(store) -> str:
    """Content identity of a RawStore (hex sha256): its image count, every image's shape, profile and
    meta, and the raw bytes of its first, middle and last images. Recorded in train.json so that
    ``metraw evaluate`` recognises the training store wherever it lies (a copy included)."""
    import hashlib

    n = len(store)
    h = hashlib.sha256()
    h.update(json.dumps({"n_images": n, "images": [[list(store.shape(i)), store.profile(i).to_dict(), store.meta(i)]
                                                    for i in range(n)]}, sort_keys=True, default=str).encode())
    for i in sorted({0, n // 2, n - 1}) if n else ():
        h.update(np.ascontiguousarray(store[i].data).tobytes())
    return h.hexdigest()


def segmentation_loss(logits, target, kind: str = "bce+dice"):
    """Binary cross-entropy against the car area fraction f of each mosaic pixel, plus (``kind``) the batch's
    soft Dice loss 1 - (2 I + 1) / (P + F + 1) or soft IoU (Jaccard) loss 1 - (I + 1) / (P + F - I + 1), with
    I = sum p f, P = sum p, F = sum f (p: sigmoid of the logits); "bce": the cross-entropy alone."""
    import torch.nn.functional as F

    if kind not in LOSSES:
        raise MetrawError(f"unknown loss {kind!r} (have {', '.join(LOSSES)})")
    bce = F.binary_cross_entropy_with_logits(logits, target)
    if kind == "bce":
        return bce
    p = logits.sigmoid()
    inter = (p * target).sum()
    total = p.sum() + target.sum()
    if kind == "bce+iou":
        return bce + (1.0 - (inter + 1.0) / (total - inter + 1.0))
    return bce + (1.0 - (2 * inter + 1.0) / (total + 1.0))


@contextmanager
def flush_denormals():
    """Flush denormal floats to zero inside the block only (denormal activations slow CPU
    convolutions; results stay deterministic). The flag is processor state shared by the whole
    process (numpy included), so it is switched back off on exit, never left on for other code."""
    import torch

    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


#: Device types whose AdamW runs fused (one kernel over all parameters instead of ~10 small operations per
#: parameter tensor): the same update, rounded in another order; on a 2-core CPU 7.8 % less time per training step
#: of the default network (batch 8, 34 x 34 packed pixels, bfloat16; median of 15 interleaved rounds).
FUSED_ADAMW_DEVICES = ("cpu", "cuda")


def make_optimizer(model, config: TrainConfig, device: str):
    """AdamW at ``config.learning_rate`` and ``config.weight_decay``, fused on ``FUSED_ADAMW_DEVICES``."""
    import torch

    fused = True if torch.device(device).type in FUSED_ADAMW_DEVICES else None
    return torch.optim.AdamW(model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay,
                             fused=fused)


def train_loop(model, epoch_batches, steps_per_epoch: int, config: TrainConfig, device: str,
               progress: bool | None = None) -> list[float]:
    """AdamW + one-cycle schedule over ``config.epochs``; ``epoch_batches(epoch)`` yields (x, y) batches.

    x: (B, S, h, w) packed VST planes, y: (B, S, h, w) site car fractions (numpy arrays or tensors); a third item,
    the images' conditioning vectors (B, K), goes to a conditioned network (``TrainConfig.condition``).
    Returns the mean loss per epoch.
    """
    import torch

    from metraw.progress import progress_bar, step_log

    opt = make_optimizer(model, config, device)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=config.learning_rate,
                                                total_steps=steps_per_epoch * config.epochs, pct_start=0.15)
    losses = []
    disable = None if progress is None else not progress
    # off a terminal: a log line every LOG_INTERVAL_S counted in steps (an epoch can outlast it), no epoch bar
    steps_log = step_log(steps_per_epoch * config.epochs, "train", unit="steps", disable=disable)
    bar = progress_bar(range(config.epochs), desc="train", disable=True if steps_log is not None else disable)
    dev_type = torch.device(device).type
    autocast = resolve_precision(config.precision, device) == "bfloat16"
    with flush_denormals():
        for epoch in bar:
            model.train()
            run, n = 0.0, 0
            batches = epoch_batches(epoch)
            for x, y, *cond in (prefetch(batches, PREFETCH_BATCHES) if PREFETCH_BATCHES else batches):
                x = torch.as_tensor(x).to(device)
                y = torch.as_tensor(y).to(device)
                with torch.autocast(dev_type, dtype=torch.bfloat16, enabled=autocast):
                    c = condition_tensor(model, cond[0] if cond else None, device)
                    logits = model(x) if c is None else model(x, c)
                loss = segmentation_loss(logits.float(), y, config.loss)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                if n < steps_per_epoch:  # the schedule has exactly steps_per_epoch steps per epoch
                    sched.step()
                run += float(loss.detach())
                n += 1
                if steps_log is not None:
                    steps_log.update(note=f"epoch {epoch + 1}/{config.epochs}, {len(x)} images per step, "
                                     f"loss {run / n:.4f}")
            losses.append(run / max(n, 1))
            if hasattr(bar, "set_postfix"):
                bar.set_postfix(loss=f"{losses[-1]:.4f}")
    if steps_log is not None:
        steps_log.close()
    return losses


def condition_tensor(model, condition, device: str, where: str = "training batch"):
    """The (B, K) conditioning tensor a conditioned ``model`` takes (one clear error when the images have none),
    or None for a plain network (the vectors are then not used)."""
    import torch

    from metraw.segment.condition import require_condition

    if not getattr(model, "n_condition", 0):
        return None
    return torch.as_tensor(require_condition(condition, where)).to(device)


def build_model(in_channels: int, config: TrainConfig, upsample: int, pool: int = 1, spec=None):
    """The network of ``spec`` (default ``config.model``: ``metraw.segment.networks``) around its working grid,
    freshly initialised from torch's global generator. metraw's U-Net is sized by ``config`` (``base_channels``,
    ``depth``, ``condition``); another kind takes no conditioning."""
    from metraw.segment.condition import CONDITION_FEATURES
    from metraw.segment.model import ForeignSegmenter, Segmenter
    from metraw.segment.networks import ModelSpec, build_core

    spec = ModelSpec.from_dict(config.model) if spec is None else spec
    if spec.kind == "metraw":
        return Segmenter(in_channels, config.base_channels, config.depth, upsample, pool,
                         n_condition=len(CONDITION_FEATURES) if config.condition else 0)
    network, multiple = build_core(spec, in_channels, in_channels)
    return ForeignSegmenter(network, multiple, upsample, pool)


def resolved_config(config: TrainConfig, device: str) -> TrainConfig:
    """``config`` as a training runs it: its precision resolved for ``device`` (``resolve_precision``), and
    ``condition`` false for a network that takes no conditioning (any but metraw's U-Net)."""
    from dataclasses import replace

    from metraw.segment.networks import ModelSpec

    return replace(config, precision=resolve_precision(config.precision, device),
                   condition=config.condition and ModelSpec.from_dict(config.model).kind == "metraw")


def check_network(config: TrainConfig, in_channels: int = PACKED_CELL_PX ** 2) -> None:
    """Build ``config``'s network on the CPU and check its contract on one dummy batch
    (``networks.check_contract``): one line naming the model and what is wrong, before any data is prepared. The
    trainings' entry points (``train_store``, ``onthefly.train_store_on_the_fly``, ``pretrain.pretrain_stores``) call
    it once, not every replicate's ``new_network``."""
    from metraw.segment.networks import ModelSpec, check_contract

    check_contract(build_model(in_channels, config, 1, 1), ModelSpec.from_dict(config.model), in_channels)


def grid_factors(images: list[PreparedImage], config: TrainConfig, upsample: int | None = None) -> tuple[int, int]:
    """(upsampling, pooling) factors of the network's working grid for ``images`` (pooling only without
    upsampling); ``upsample`` overrides the one ``config.min_grid_px`` gives."""
    f = upsample_factor(images, config.min_grid_px) if upsample is None else upsample
    return f, (pool_factor(images, config.grid_gsd_m) if f == 1 else 1)


def new_network(images: list[PreparedImage], config: TrainConfig, device: str, upsample: int | None = None):
    """Seed torch (``set_determinism``) and build a fresh network sized for ``images``:
    (model on ``device``, upsampling factor, pooling factor, input channels)."""
    set_determinism(config.seed, config.threads, device)
    f, pool = grid_factors(images, config, upsample)
    in_ch = PACKED_CELL_PX ** 2
    if len({cfa_family(img.pattern) for img in images}) > 1:
        raise MetrawError("cannot train on a mix of mono and CFA images")
    return build_model(in_ch, config, f, pool).to(device), f, pool, in_ch


def fit(images: list[PreparedImage], config: TrainConfig, device: str | None = None,
        progress: bool | None = None, upsample: int | None = None) -> tuple[Any, dict[str, Any]]:
    """Train a fresh model on prepared images; returns (model, training record)."""
    if not images:
        raise MetrawError("no training images")
    device = device or default_device()
    model, f, pool, in_ch = new_network(images, config, device, upsample)
    cover = config.crops_per_image == COVER
    per_image = crops_to_cover(images, config.crop_px * pool) if cover else None
    steps_per_epoch = math.ceil((per_image.sum() if cover else len(images) * config.crops_per_image)
                                / config.batch_size)
    rng = rng_from_seed(config.seed)

    def epoch_batches(_epoch):
        if cover:
            order = rng.permutation(np.repeat(np.arange(len(images)), per_image))
        else:
            order = np.concatenate([rng.permutation(len(images)) for _ in range(config.crops_per_image)])
        for s in range(steps_per_epoch):
            batch = [images[i] for i in order[s * config.batch_size:(s + 1) * config.batch_size]]
            yield batch_crops(batch, config.crop_px * pool, rng, augment=True, gamma_range=config.tone_gamma_range,
                              gain_range=config.channel_gain_range)

    t0 = time.perf_counter()
    losses = train_loop(model, epoch_batches, steps_per_epoch, config, device, progress)
    record = {"epochs": config.epochs, "steps": steps_per_epoch * config.epochs, "loss_per_epoch": losses,
              "training_time_s": time.perf_counter() - t0, "device": device, "upsample": f,
              "pool": pool, "in_channels": in_ch, "sensor": cfa_family(images[0].pattern), "n_train": len(images),
              "train_packed_gsd_m": training_packed_gsd_m(images)}
    return model, record


def crops_to_cover(images: list[PreparedImage], crop_side_px: int) -> np.ndarray:
    """Crops per image that its packed area holds: round(h w / crop_side_px^2), at least 1 (``crop_side_px``: the
    crop's side in packed pixels, i.e. crop_px times the pooling factor)."""
    return np.array([max(1, round(h * w / crop_side_px ** 2)) for h, w in (img.packed_shape for img in images)])


def train_store(store_path: str | os.PathLike, out_dir: str | os.PathLike, config: TrainConfig,
                device: str | None = None, progress: bool | None = None, overwrite: bool = False
                ) -> dict[str, Any]:
    """Train on the training split of a store; write ``model.pt`` and ``train.json`` into ``out_dir``."""
    from metraw.io.store import RawStore

    check_network(config)
    store = RawStore.open(store_path)
    _, n_source = source_indices(store)
    if n_source != len(store):
        raise MetrawError(f"{store_path} holds {len(store)} of its source's {n_source} images (emulated with "
                          "--images test): train on fresh draws of the source instead (--source)")
    train_idx, test_idx = split_indices(len(store), config.test_fraction, config.split_seed)
    digest = store_digest(store)
    t0 = time.perf_counter()
    images = prepare_store(store, train_idx, progress)
    prep_s = time.perf_counter() - t0
    runs = fit_replicates(config, lambda cfg: fit(images, cfg, device, progress),
                          {"store": store.origin, "store_digest": digest, "n_images": len(store),
                           "train_indices": train_idx.tolist(), "test_indices": test_idx.tolist(),
                           "preprocess_time_s": prep_s}, device)
    save_replicates(out_dir, runs, test_idx, overwrite)
    return runs[0][2]


def fit_replicates(config: TrainConfig, fit_one, common: dict[str, Any], device: str | None = None) -> list:
    """``fit_one(cfg)`` -> (model, record) for seeds ``seed`` .. ``seed + replicates - 1`` (at least one); every
    record gets ``common``, its own config as the training ran it (``resolved_config`` for ``device``, default
    ``default_device()``) and its network's record (``networks.network_record``). Returns
    [(model, config, record), ...] for ``save_replicates``."""
    from dataclasses import replace

    from metraw.segment.networks import ModelSpec, network_record

    resolved = resolved_config(config, device or default_device())
    spec = ModelSpec.from_dict(config.model)
    runs = []
    for r in range(max(1, config.replicates)):
        cfg = replace(resolved, seed=config.seed + r)
        model, record = fit_one(cfg)
        record.update({**common, "config": asdict(cfg), "network": network_record(model, spec)})
        runs.append((model, cfg, record))
    return runs


def save_replicates(out_dir, runs: list, test_indices, overwrite: bool = False) -> None:
    """Write the first (model, config, record) of ``runs`` as the model directory and the others into its
    ``REPLICATE_DIR`` sub-directories, in one atomic step. The first record gets the replicates' seeds and
    training times."""
    first = runs[0][2]
    first["replicate_seeds"] = [cfg.seed for _, cfg, _ in runs]
    first["replicate_training_time_s"] = [rec["training_time_s"] for _, _, rec in runs]
    extra = [(REPLICATE_DIR.format(r=r), run) for r, run in enumerate(runs) if r > 0]
    save_model(out_dir, *runs[0], test_indices, overwrite, extra=extra)


def replicate_dirs(model_dir) -> list[Path]:
    """The replicate model directories inside ``model_dir`` (sorted by replicate number)."""
    found = [p for p in Path(model_dir).glob(REPLICATE_DIR.format(r="*")) if (p / CHECKPOINT).is_file()]
    return sorted(found, key=lambda p: int(p.name.rsplit("-", 1)[1]))


def save_model(out_dir, model, config: TrainConfig, record: dict[str, Any], test_indices, overwrite: bool = False,
               extra: list | None = None) -> None:
    """Write ``model.pt`` (weights, config, upsampling, test split, training packed GSD) and ``train.json``
    (``record`` without its wall-clock ``TIMINGS``, so that the same training writes the same bytes) atomically;
    ``extra``: (sub-directory name, (model, config, record)) written the same way inside it (replicates)."""
    from metraw.atomic import atomic_path

    with atomic_path(out_dir, overwrite=overwrite) as tmp:
        tmp.mkdir(parents=True)
        _write_model(tmp, model, config, record, test_indices)
        for name, (m, c, r) in extra or []:
            (tmp / name).mkdir()
            _write_model(tmp / name, m, c, r, test_indices)


def _write_model(folder: Path, model, config: TrainConfig, record: dict[str, Any], test_indices) -> None:
    import torch

    torch.save({"state_dict": {k: v.cpu() for k, v in model.state_dict().items()},
                "config": asdict(config), "upsample": record["upsample"], "pool": record.get("pool", 1),
                "in_channels": record["in_channels"], "sensor": record.get("sensor", "bayer"),
                "test_indices": [int(i) for i in test_indices],
                "train_packed_gsd_m": record.get("train_packed_gsd_m"), "network": record.get("network")},
               folder / CHECKPOINT)
    (folder / TRAIN_METRICS).write_text(json.dumps({k: v for k, v in record.items() if k not in TIMINGS}, indent=2))


def load_model(model_dir: str | os.PathLike, device: str | None = None):
    """(model, checkpoint dict, training record) from a directory written by ``train_store``."""
    import torch

    model_dir = Path(model_dir)
    ckpt_path = model_dir / CHECKPOINT
    if not ckpt_path.is_file():
        raise MetrawError(f"{model_dir} holds no {CHECKPOINT} (train a model with `metraw train` first)")
    from metraw.segment.networks import check_rebuilt, spec_from_record

    ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    config = TrainConfig.from_dict(ckpt["config"])
    where = f"the model in {model_dir}"
    try:  # the network the checkpoint records (its factory file where it was), else metraw's U-Net (older ones)
        spec = spec_from_record(ckpt.get("network"))
        model = build_model(ckpt["in_channels"], config, ckpt["upsample"], ckpt.get("pool", 1), spec=spec)
        check_rebuilt(ckpt.get("network") or {}, spec, model)
    except MetrawError as exc:
        raise MetrawError(f"{where} cannot be rebuilt: {exc}") from None
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as exc:
        raise MetrawError(f"{where} cannot be rebuilt: its weights do not fit the network "
                          f"{spec.describe()} builds now ({' '.join(str(exc).split())[:160]})") from None
    model.to(device or default_device())
    record_path = model_dir / TRAIN_METRICS
    record = json.loads(record_path.read_text()) if record_path.is_file() else {}
    return model, ckpt, record


def checkpoint_sensor(ckpt: dict[str, Any]) -> str:
    """The images a checkpoint's network was trained on, "mono" or "bayer": its ``sensor``, or for checkpoints
    written before it was recorded, "bayer" for four input planes and "mono" for one."""
    return ckpt.get("sensor", "bayer" if ckpt.get("in_channels") == 4 else "mono")


def pretrained_states(model_dir: str | os.PathLike, n: int, sensor: str | None = None,
                      model: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The weights of the first ``n`` replicates of a model directory (``metraw pretrain``'s), in replicate
    order: replicate r of a point fine-tunes from the r-th. ``sensor`` ("mono" or "bayer"): the images the
    fine-tuning sees; a network pretrained on the other kind is a one-line error (both take four planes).
    ``model``: the fine-tuning's ``training.model``; a pretraining of another network is a one-line error."""
    import torch

    dirs = [Path(model_dir)] + replicate_dirs(model_dir)
    if not (Path(model_dir) / CHECKPOINT).is_file():
        raise MetrawError(f"{model_dir} holds no {CHECKPOINT} (pretrain with `metraw pretrain` first)")
    if len(dirs) < n:
        raise MetrawError(f"{model_dir} holds {len(dirs)} pretrained replicate(s); {n} are asked for (one per replicate)")
    ckpts = [torch.load(d / CHECKPOINT, map_location="cpu", weights_only=True) for d in dirs[:n]]
    have = checkpoint_sensor(ckpts[0])
    if model is not None:
        from metraw.segment.networks import ModelSpec, spec_from_record

        pretrained, wanted = spec_from_record(ckpts[0].get("network")), ModelSpec.from_dict(model)
        if pretrained.identity() != wanted.identity():
            raise MetrawError(f"{model_dir} holds a pretraining of {pretrained.describe()}; this training uses "
                              f"{wanted.describe()}: pretrain with the same training.model")
    if sensor is not None and have != sensor:
        raise MetrawError(f"{model_dir} was pretrained on {have} images; this training sees {sensor} images: "
                          "pretrain with its sensor's pattern (metraw pretrain --cfa-pattern)")
    return [c["state_dict"] for c in ckpts]
