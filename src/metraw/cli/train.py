"""``metraw train STORE.zarr --out DIR``: train the car segmenter on one parameter point."""

from __future__ import annotations

import json
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train the car segmenter on a store's training split",
                              description="Train the compact U-Net on packed, variance-stabilised raw planes "
                              "of STORE's training split (fixed split seed); writes DIR/model.pt and DIR/train.json "
                              "(the same bytes for the same store, params and machine; the time goes to stderr).")
    p.add_argument("store", help="input RawStore (.zarr) with car masks")
    p.add_argument("--out", required=True, help="output directory for the checkpoint and training metrics")
    p.add_argument("--params", default="params.yaml", help="params file with a training: section (default: params.yaml)")
    p.add_argument("--profile", default=None, help="training profile name (default: training.profile in params)")
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--epochs", type=int, default=None, help="override the profile's number of epochs")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    p.add_argument("--progress", action="store_true", help="show progress bars even when not on a terminal")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.points import load_params
    from metraw.segment.train import load_config, train_store

    load_params(args.params, complete=False)  # schema: one line naming a bad or unknown key
    config = load_config(args.params, args.profile)
    if args.epochs is not None:
        config.epochs = args.epochs
    record = train_store(args.store, args.out, config, device=args.device, progress=True if args.progress else None,
                         overwrite=args.overwrite)
    # timings go to the log (stderr) and stdout, never into DIR (metraw.segment.train.TIMINGS)
    print(f"metraw train: {record['n_train']} images, {record['epochs']} epoch(s) in {record['training_time_s']:.2f} s "
          f"(preprocessing {record['preprocess_time_s']:.2f} s)", file=sys.stderr)
    print(json.dumps({k: record[k] for k in ("epochs", "training_time_s", "n_train", "upsample", "device")}))
    return 0
