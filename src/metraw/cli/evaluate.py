"""``metraw evaluate STORE.zarr --model DIR --out metrics.json``: IoU of a trained segmenter."""

from __future__ import annotations

import json
import sys
import time


def register(subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="IoU / precision / recall of a trained segmenter on a labelled store",
                              description="Segment STORE with the model in DIR and write pooled and per-image IoU, "
                              "precision, recall and epochs as JSON (the time goes to stderr): the test split of the "
                              "store the model was trained on, every image of any other (foreign) store. Images of "
                              "another ground sampling distance are resampled to the training GSD.")
    p.add_argument("store", help="RawStore (.zarr) with car masks: the training store, or any other")
    p.add_argument("--model", required=True, help="directory written by `metraw train`")
    p.add_argument("--out", required=True, help="output metrics JSON file")
    p.add_argument("--split", choices=("auto", "test", "all"), default="auto",
                   help="images to score: auto (default): the test split of the training store, all images of a "
                   "foreign one; test: the model's test split (a store with as many images as the training "
                   "store, e.g. another parameter point); all: every image")
    add_run_options(p, overwrite_help="replace an existing output file")
    p.set_defaults(func=run)


def add_run_options(p, overwrite_help: str) -> None:
    """--device, --transforms, --overwrite, --progress: shared by the commands that run a trained model (evaluate,
    predict)."""
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--transforms", type=int, choices=(1, 2, 4, 8), default=None,
                   help="dihedral transforms (turns and flips of the mosaic) whose predictions are averaged "
                   "(default: the model's predict_transforms: 1, or 8 for the source profile's drone model; 8 costs 8 "
                   "network passes)")
    p.add_argument("--overwrite", action="store_true", help=overwrite_help)
    p.add_argument("--progress", action="store_true", help="show progress bars even when not on a terminal")


def run(args) -> int:
    from pathlib import Path

    from metraw.atomic import atomic_path
    from metraw.errors import MetrawError
    from metraw.segment.evaluate import evaluate_store

    t0 = time.perf_counter()
    if Path(args.out).exists() and not args.overwrite:  # before the work, not after it
        raise MetrawError(f"output {args.out} already exists (use --overwrite to replace it)")
    metrics = evaluate_store(args.store, args.model, device=args.device, progress=True if args.progress else None,
                             split=args.split, transforms=args.transforms)
    with atomic_path(args.out, overwrite=args.overwrite) as tmp:
        tmp.write_text(json.dumps(metrics, indent=2))
    # the time goes to the log, not into the metrics: the same model and store give the same file
    what = "test images" if metrics["split"] == "test" else f"images ({metrics['split']})"
    print(f"metraw evaluate: {metrics['n_images']} {what} in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    if not metrics["gsd_matched"]:
        print(f"metraw evaluate: note: {metrics['gsd_note']}", file=sys.stderr)
    if metrics.get("n_degenerate_models"):  # issue #71: a failed training, not a measurement
        from metraw.segment.degenerate import describe

        models = metrics.get("replicates") or [metrics]
        print(f"metraw evaluate: note: {metrics['n_degenerate_models']} of {metrics['n_models']} model(s) degenerate"
              f"{' (the point measured nothing)' if metrics['degenerate'] else ''}: "
              + "; ".join(describe(m) for m in models if m["degenerate"]), file=sys.stderr)
    keys = ("iou", "precision", "recall", "box_iou", "box_precision", "box_recall", "object_recall",
            "object_precision", "mean_image_iou", "n_images", "split", "labels", "transforms")
    print(json.dumps({k: metrics[k] for k in keys if k in metrics}))
    return 0
