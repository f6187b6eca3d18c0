"""``metraw pretrain SOURCE.zarr --out DIR``: one network per replicate trained across the parameter box."""

from __future__ import annotations

import json
import sys

from metraw.cli.train import DRAW_WORKERS_HELP


def register(subparsers) -> None:
    p = subparsers.add_parser("pretrain", help="pretrain the segmenter on draws across the tolerance box",
                              description="Train the segmenter on fresh target draws of SOURCE's training scenes "
                              "(and of every scene of --extra stores), each scene drawn at points_per_scene points of "
                              "training.pretrain.box (the nominal payload with one box parameter log-uniform in its "
                              "range; a seeded choice); writes a model directory like `metraw train`, which "
                              "`metraw train --init DIR` fine-tunes per point.")
    p.add_argument("source", help="source RawStore (.zarr) with car masks: its test split is never drawn")
    p.add_argument("--out", required=True, help="output model directory")
    p.add_argument("--extra", action="append", default=[],
                   help="a store of further scenes that belong to no test set (repeatable)")
    p.add_argument("--params", default="params.yaml", help="parameter file (nominal target, training profile and "
                   "training.pretrain; default: params.yaml)")
    p.add_argument("--profile", default=None, help="training profile name (default: training.profile in params)")
    p.add_argument("--cfa-pattern", default=None,
                   help="the sensor's colour filter array for every draw (default: the nominal's); the points of that "
                        "pattern fine-tune these networks")
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--epochs", type=int, default=None, help="override training.pretrain.epochs")
    p.add_argument("--batch-size", type=int, default=None,
                   help="override training.pretrain.batch_size (default: the training profile's batch size; larger "
                        "batches pay on a GPU, docs/training.md, 'GPUs')")
    p.add_argument("--points-per-scene", type=int, default=None,
                   help="override training.pretrain.points_per_scene")
    p.add_argument("--batches", choices=("payload", "mixed"), default=None,
                   help="override training.pretrain.batches: payload = each batch one box parameter at neighbouring "
                   "values; mixed = any payloads in a batch")
    p.add_argument("--codec-step", type=float, default=None,
                   help="pass every draw through the noise-preserving codec at this step (default: no codec)")
    p.add_argument("--replicates", type=int, default=None, help="override the profile's number of replicates")
    p.add_argument("--workers", type=int, default=2,
                   help="processes building the box's expected fields (the models do not depend on it; default 2)")
    p.add_argument("--draw-workers", type=int, default=0, help=DRAW_WORKERS_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    p.add_argument("--progress", action="store_true", help="show progress bars even when not on a terminal")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.emulate.target import TargetSystem
    from metraw.errors import MetrawError
    from metraw.raw.cfa import validate_pattern
    from metraw.segment.pretrain import pretrain_stores
    from metraw.segment.config import load_config
    from metraw.study.points import load_params, target_at
    from metraw.study.pretraining import pretrain_settings

    params = load_params(args.params)
    config = load_config(args.params, args.profile)
    settings = pretrain_settings(params)
    config.epochs = args.epochs if args.epochs is not None else settings["epochs"]
    config.batch_size = next(b for b in (args.batch_size, settings["batch_size"], config.batch_size) if b is not None)
    k = args.points_per_scene if args.points_per_scene is not None else settings["points_per_scene"]
    for name, value in (("--epochs", config.epochs), ("--batch-size", config.batch_size), ("--points-per-scene", k),
                        ("--workers", args.workers)):
        if value < 1:
            raise MetrawError(f"{name} must be >= 1, got {value}")
    if args.draw_workers < 0:
        raise MetrawError(f"--draw-workers must be >= 0, got {args.draw_workers}")
    if args.replicates is not None:
        if args.replicates < 1:
            raise MetrawError(f"--replicates must be >= 1, got {args.replicates}")
        config.replicates = args.replicates
    pattern = validate_pattern(args.cfa_pattern or params["target"]["nominal"]["cfa_pattern"])
    record = pretrain_stores(args.source, lambda overrides: TargetSystem.from_dict(
                                 target_at(params, {**overrides, "cfa_pattern": pattern})),
                             settings["box"], args.out, config, k, args.extra, device=args.device,
                             progress=True if args.progress else None, overwrite=args.overwrite,
                             codec_step=args.codec_step, workers=args.workers, batches=args.batches or settings["batches"],
                             draw_workers=args.draw_workers)
    times = record.get("replicate_training_time_s", [record["training_time_s"]])
    print(f"metraw pretrain: {record['n_train']} scenes x {k} points of the box ({', '.join(settings['box'])}; "
          f"{pattern} sensor), "
          f"{record['epochs']} epoch(s) in batches of {config.batch_size}, {len(times)} replicate(s) in {sum(times):.2f} s "
          f"(fields {record['preprocess_time_s']:.2f} s)", file=sys.stderr)
    print(json.dumps({**{key: record[key] for key in ("epochs", "n_train", "points_per_scene", "batches", "box", "device")},
                      "cfa_pattern": pattern}))
    return 0
