"""``metraw check-folder FOLDER``: one pass over a source folder before the study runs (`metraw.study.folder`):
every problem one line, exit status 2, nothing written; else a summary line and, with ``--out``, the summary as
JSON (the workflow's first rule for a raws or photos source)."""

from __future__ import annotations

import json
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("check-folder", help="check a source folder (images, labels, sensor) before a study",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="the source folder (params.yaml source.raws.path or source.photos.path)")
    p.add_argument("--kind", choices=("raws", "photos"), default="raws", help="camera raws or processed photos")
    p.add_argument("--labels", choices=("mask", "yolo"), default="mask",
                   help="STEM_mask.png masks or STEM.txt YOLO boxes (default: mask)")
    p.add_argument("--car-class", action="append", default=[], metavar="NAME",
                   help="YOLO class counted as car (repeatable; default: the classes named car, truck, bus, ...)")
    p.add_argument("--test-fraction", type=float, default=0.2, help="share of images in the test split (training)")
    p.add_argument("--split-seed", type=int, default=0, help="seed of the train/test split (training.split_seed)")
    p.add_argument("--out", type=Path, help="write the summary as JSON here (atomically)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run)


def run(args) -> int:
    import time

    from metraw.atomic import atomic_path
    from metraw.errors import MetrawError
    from metraw.segment.data import split_indices
    from metraw.study.folder import check_folder

    t0 = time.perf_counter()
    if args.out is not None and args.out.exists() and not args.overwrite:
        raise MetrawError(f"output {args.out} already exists (use --overwrite to replace it)")
    summary = check_folder(args.folder, kind=args.kind, labels=args.labels, car_classes=args.car_class or None,
                           test_split=lambda n: split_indices(n, args.test_fraction, args.split_seed)[1].tolist())
    summary["split"] = {"test_fraction": args.test_fraction, "split_seed": args.split_seed}
    if args.out is not None:
        with atomic_path(args.out, overwrite=args.overwrite) as tmp:
            tmp.write_text(json.dumps(summary, indent=2) + "\n")
    sensor = f", {summary['cfa_pattern']} {summary['adc_bits']}-bit" if summary["cfa_pattern"] else ""
    cars = f", {summary['cars']} car boxes" if summary["cars"] is not None else ""
    print(f"{args.folder}: {summary['images']} images ok{sensor}, shapes (H, W) {summary['shapes']}; "
          f"{summary['images_with_cars']} with cars{cars}; test split {summary['test_images']} images, "
          f"{summary['test_images_with_cars']} with cars ({time.perf_counter() - t0:.1f} s)")
    return 0
