"""Segmenter benchmarks: source reference IoU and input-resolution choices on emulated targets (the robust model
trained on fresh draws against per-point models: benchmarks/robust.py).

    nice -n 5 python benchmarks/segment.py source SRC.zarr [--profile default] [--n N]
    nice -n 5 python benchmarks/segment.py resolution SRC.zarr --n 60 --points nominal focal_length_m=0.8

Prints tables (IoU pooled over the test split, mean per-image IoU +- standard error, times).
Emulated stores are cached under --work (default /tmp/metraw_seg_bench).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def _subset(store_path: str, n: int | None, work: Path):
    """First n images of a store as their own store (so the split is over n images)."""
    from metraw.io.store import RawStore

    src = RawStore.open(store_path)
    if n is None or n >= len(src):
        return Path(store_path)
    out = work / f"source_{n}.zarr"
    if not out.exists():
        with RawStore.create(out) as s:
            for i in range(n):
                s.append(src[i])
    return out


def _emulated(source: Path, point: str, work: Path) -> Path:
    from metraw.emulate.emulator import emulate
    from metraw.emulate.target import TargetSystem, parse_point
    from metraw.io.store import RawStore

    overrides = {} if point == "nominal" else parse_point(point)
    out = work / f"{source.stem}_{point.replace('=', '_')}.zarr"
    if out.exists():
        return out
    target = TargetSystem.from_params("params.yaml", overrides)
    src = RawStore.open(source)
    t0 = time.perf_counter()
    with RawStore.create(out) as s:
        for i in range(len(src)):
            s.append(emulate(src[i], target, "auto", seed=i))
    print(f"# emulated {point}: {len(src)} images in {time.perf_counter() - t0:.1f} s", flush=True)
    return out


def _run(store: Path, config, label: str):
    from metraw.io.store import RawStore
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.evaluate import evaluate_images
    from metraw.segment.train import fit

    s = RawStore.open(store)
    tr, te = split_indices(len(s), config.test_fraction, config.split_seed)
    t0 = time.perf_counter()
    train_imgs, test_imgs = prepare_store(s, tr, False), prepare_store(s, te, False)
    prep = time.perf_counter() - t0
    model, rec = fit(train_imgs, config, "cpu", False)
    t1 = time.perf_counter()
    ev = evaluate_images(model, test_imgs, "cpu", False)
    ev_s = time.perf_counter() - t1
    row = {"label": label, "packed": "x".join(map(str, test_imgs[0].packed_shape)), "upsample": rec["upsample"],
           "pool": rec["pool"],
           "iou": ev["iou"], "mean_iou": ev["mean_image_iou"], "se": ev["mean_image_iou_se"],
           "precision": ev["precision"], "recall": ev["recall"], "prep_s": prep, "train_s": rec["training_time_s"],
           "eval_s": ev_s, "n_train": len(tr), "n_test": len(te)}
    def fmt(v):
        return "  n/a" if v is None else f"{v:.3f}"

    print(f"{label:<34} {row['packed']:>8} {row['upsample']:>3} {row['pool']:>4} {fmt(row['iou'])} {fmt(row['mean_iou'])}"
          f"+-{fmt(row['se'])} {fmt(row['precision'])} {fmt(row['recall'])} {prep:6.1f} {rec['training_time_s']:7.1f}"
          f" {ev_s:6.1f}", flush=True)
    return row, model


HEADER = (f"{'run':<34} {'packed':>8} {'up':>3} {'pool':>4} {'IoU':>5} {'mean+-se':>11} {'prec':>5} {'rec':>5} "
          f"{'prep_s':>6} {'train_s':>7} {'eval_s':>6}")


def main() -> None:
    import torch

    from metraw.segment.train import load_config

    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=["source", "resolution"])
    ap.add_argument("source")
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--points", nargs="*", default=["nominal", "focal_length_m=0.8"])
    ap.add_argument("--grids", nargs="*", type=int, default=[0, 64, 128])
    ap.add_argument("--epochs", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None, help="override the profile's torch thread count")
    ap.add_argument("--work", default="/tmp/metraw_seg_bench")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    torch.set_num_threads(2)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    config = load_config("params.yaml", args.profile)
    if args.epochs:
        config = replace(config, epochs=args.epochs)
    if args.threads:
        config = replace(config, threads=args.threads)
    source = _subset(args.source, args.n, work)
    rows = []
    print(f"# profile {args.profile}: {json.dumps(config.__dict__)}")
    print(HEADER)
    if args.what == "source":
        rows.append(_run(source, config, "source")[0])
    else:
        for point in args.points:
            store = _emulated(source, point, work)
            for g in args.grids:
                rows.append(_run(store, replace(config, min_grid_px=g), f"{point} grid>={g}")[0])
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
