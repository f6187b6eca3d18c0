"""``metraw evaluate STORE.zarr --model DIR --out metrics.json``: IoU of a trained segmenter."""

from __future__ import annotations

import json
import sys
import time


def register(subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="IoU / precision / recall of a trained segmenter on the test split",
                              description="Segment the test split of STORE with the model in DIR and write pooled "
                              "and per-image IoU, precision, recall and epochs as JSON (the time goes to stderr).")
    p.add_argument("store", help="RawStore (.zarr) with car masks (the same point the model was trained on, "
                   "or another store with the same number of images)")
    p.add_argument("--model", required=True, help="directory written by `metraw train`")
    p.add_argument("--out", required=True, help="output metrics JSON file")
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--progress", action="store_true", help="show progress bars even when not on a terminal")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.atomic import atomic_path
    from metraw.segment.evaluate import evaluate_store

    t0 = time.perf_counter()
    metrics = evaluate_store(args.store, args.model, device=args.device, progress=True if args.progress else None)
    with atomic_path(args.out, overwrite=args.overwrite) as tmp:
        tmp.write_text(json.dumps(metrics, indent=2))
    # the time goes to the log, not into the metrics: the same model and store give the same file
    print(f"metraw evaluate: {metrics['n_images']} test images in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    print(json.dumps({k: metrics[k] for k in ("iou", "precision", "recall", "mean_image_iou", "n_images")}))
    return 0
