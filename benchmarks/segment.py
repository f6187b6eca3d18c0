"""Segmenter benchmarks: source reference IoU, input-resolution choices on emulated targets,
and the robust (on-the-fly emulation) model against per-point models.

    nice -n 5 python benchmarks/segment.py source SRC.zarr [--profile default] [--n N]
    nice -n 5 python benchmarks/segment.py resolution SRC.zarr --n 60 --points nominal focal_length_m=0.8
    nice -n 5 python benchmarks/segment.py robust SRC.zarr --n 60 --points ...
    nice -n 5 python benchmarks/segment.py robust data/source.zarr --results results
        (robust model over the box spanned by params.yaml's sweeps, against the workflow's
         per-point models: their stores and metrics under results/points/)

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
    from metraw.io.store import RawStore
    from metraw.emulate.target import TargetSystem, parse_point

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
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.evaluate import evaluate_images
    from metraw.segment.train import fit
    from metraw.io.store import RawStore

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
    ap.add_argument("what", choices=["source", "resolution", "robust"])
    ap.add_argument("source")
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--profile", default="default")
    ap.add_argument("--points", nargs="*", default=["nominal", "focal_length_m=0.8"])
    ap.add_argument("--grids", nargs="*", type=int, default=[0, 64, 128])
    ap.add_argument("--epochs", type=int, default=None)
    ap.add_argument("--threads", type=int, default=None, help="override the profile's torch thread count")
    ap.add_argument("--work", default="/tmp/metraw_seg_bench")
    ap.add_argument("--json", default=None)
    ap.add_argument("--results", default=None, help="robust: compare with the workflow's per-point results here")
    ap.add_argument("--workers", type=int, default=2, help="robust: emulation worker processes")
    ap.add_argument("--robust-model", default=None,
                    help="robust: directory of the robust model: loaded if it exists, else trained and saved there")
    ap.add_argument("--train-only", action="store_true", help="robust: train (and save) the robust model, then stop")
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
    elif args.what == "resolution":
        for point in args.points:
            store = _emulated(source, point, work)
            for g in args.grids:
                rows.append(_run(store, replace(config, min_grid_px=g), f"{point} grid>={g}")[0])
    elif args.results:
        rows.extend(_robust_vs_workflow(Path(args.source), Path(args.results), config, args.workers,
                                        args.robust_model, args.train_only))
    else:
        rows.extend(_robust(source, args.points, config, work))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


def _robust(source: Path, points: list[str], config, work: Path):
    """Per-point models vs one model trained on the fly over the box spanned by the points."""
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.emulated import EmulatedDataset, fit_emulated
    from metraw.segment.evaluate import evaluate_images
    from metraw.segment.train import upsample_factor
    from metraw.io.store import RawStore
    from metraw.emulate.target import parse_point

    rows = []
    box: dict[str, list[float]] = {}
    for p in points:
        for k, v in ({} if p == "nominal" else parse_point(p)).items():
            lo, hi = box.get(k, [v, v])
            box[k] = [min(lo, v), max(hi, v)]
    stores = {p: _emulated(source, p, work) for p in points}
    per_point = {}
    for p in points:
        row, _ = _run(stores[p], config, f"per-point {p}")
        per_point[p] = row
    n = len(RawStore.open(source))
    tr, te = split_indices(n, config.test_fraction, config.split_seed)
    nominal_imgs = prepare_store(RawStore.open(stores[points[0]]), te[:1], False)
    f = upsample_factor(nominal_imgs, config.min_grid_px)
    from metraw.emulate.target import TargetSystem  # noqa: F401  (nominal comes from params.yaml)

    ds = EmulatedDataset(source, tr, box, "params.yaml", crop_px=config.crop_px, seed=config.seed)
    model, rec = fit_emulated(ds, config, workers=2, device="cpu", progress=False, upsample=f)
    print(f"# robust model over box {box}: trained in {rec['training_time_s']:.1f} s (on-the-fly emulation)")
    print(f"{'point':<34} {'per-point IoU':>13} {'robust IoU':>10}")
    for p in points:
        imgs = prepare_store(RawStore.open(stores[p]), te, False)
        ev = evaluate_images(model, imgs, "cpu", False)
        print(f"{p:<34} {per_point[p]['iou']:13.3f} {ev['iou']:10.3f}", flush=True)
        rows.append({"point": p, "per_point_iou": per_point[p]["iou"], "robust_iou": ev["iou"],
                     "robust_mean_iou": ev["mean_image_iou"], "robust_train_s": train_s})
    return rows


def _robust_vs_workflow(source: Path, results: Path, config, workers: int, model_dir=None, train_only=False):
    """One model trained on the fly over the sweep box vs the workflow's per-point models.

    The box spans each swept parameter's range (uniform draws, all parameters at once, so the
    robust model also sees combinations the one-at-a-time sweep never ran). Both models are
    scored on the same test split of every point's stored images.
    """
    from metraw.spec.aggregate import iou_measurement
    from metraw.study.points import load_params, parameter_points
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.emulated import EmulatedDataset, fit_emulated
    from metraw.segment.evaluate import evaluate_images
    from metraw.io.store import RawStore

    params = load_params("params.yaml")
    sweeps = params["target"]["sweeps"]
    nominal = params["target"]["nominal"]
    box = {k: [min(min(v), nominal[k]), max(max(v), nominal[k])] for k, v in sweeps.items()}
    n = len(RawStore.open(source))
    tr, te = split_indices(n, config.test_fraction, config.split_seed)
    from metraw.segment.train import load_model, save_model

    if model_dir and (Path(model_dir) / "model.pt").exists():
        model, _, rec = load_model(model_dir, "cpu")
    else:
        # sources decoded once here and shared with the forked workers (~7 MB per 1024 px image)
        ds = EmulatedDataset(source, tr, box, params, crop_px=config.crop_px, seed=config.seed).preload(progress=True)
        model, rec = fit_emulated(ds, config, workers=workers, device="cpu", progress=False)
        if model_dir:
            save_model(model_dir, model, config, rec, te)
    train_s = rec.get("training_time_s")  # absent when the model was loaded: train.json holds no timings
    print(f"# robust model over box {box}: {rec['steps']} steps in "
          f"{'n/a' if train_s is None else f'{train_s:.1f}'} s "
          f"(on-the-fly emulation, {workers} workers)", flush=True)
    if train_only:
        return []
    print(f"{'point':<24} {'per-point IoU':>16} {'robust IoU':>16} {'robust - per-point':>19}")
    rows = []
    for p in parameter_points(params):
        metrics = json.loads((results / "points" / p / "metrics.json").read_text())
        per, per_var = iou_measurement(metrics, p)
        imgs = prepare_store(RawStore.open(results / "points" / p / "target.zarr"), te, False)
        ev = evaluate_images(model, imgs, "cpu", False)
        rob, rob_var = iou_measurement(ev, p)
        print(f"{p:<24} {per:8.3f} +- {per_var ** 0.5:.3f} {rob:8.3f} +- {rob_var ** 0.5:.3f} {rob - per:+19.3f}",
              flush=True)
        rows.append({"point": p, "per_point_iou": per, "per_point_sd": per_var ** 0.5, "robust_iou": rob,
                     "robust_sd": rob_var ** 0.5, "robust_train_s": train_s, "box": box,
                     "robust_steps": rec["steps"], "n_test": len(ev["per_image"])})
    return rows


if __name__ == "__main__":
    main()
