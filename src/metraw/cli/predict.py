"""``metraw predict STORE.zarr --model DIR --out OUT.zarr``: car probability and mask of every image."""

from __future__ import annotations

import json
import sys
import time

from metraw.cli.evaluate import add_run_options


def register(subparsers) -> None:
    p = subparsers.add_parser("predict", help="car probability and mask of every image of a store (labels optional)",
                              description="Segment every image of STORE with the model in DIR and write its car "
                              "probability (float32) and mask (probability > 0.5, objects under 2 m^2 on the ground dropped) on the "
                              "image's mosaic grid into the "
                              "zarr group OUT (written atomically). Images of another ground sampling distance are "
                              "resampled to the training GSD and back. The time goes to stderr.")
    p.add_argument("store", help="RawStore (.zarr); labels not needed")
    p.add_argument("--model", required=True, help="directory written by `metraw train`")
    p.add_argument("--out", required=True, help="output zarr group (OUT.zarr)")
    p.add_argument("--overlay", default=None, metavar="FIG.png|DIR",
                   help="also write an overlay (quick-look RGB, predicted mask in cyan, labels in magenta) of the "
                   "first images: one PNG, or a folder of one PNG per image")
    p.add_argument("--overlay-count", type=int, default=4, help="images in the overlay (default: 4)")
    add_run_options(p, overwrite_help="replace existing outputs")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.segment.predict import predict_store

    t0 = time.perf_counter()
    summary = predict_store(args.store, args.model, args.out, device=args.device,
                            progress=True if args.progress else None, overwrite=args.overwrite,
                            overlay=args.overlay, overlay_count=args.overlay_count, transforms=args.transforms)
    print(f"metraw predict: {summary['n_images']} images in {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    if summary["gsd_note"]:
        print(f"metraw predict: note: {summary['gsd_note']}", file=sys.stderr)
    print(json.dumps(summary))
    return 0
