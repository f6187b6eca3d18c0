"""``metraw train STORE.zarr --out DIR``: train the car segmenter on one parameter point."""

from __future__ import annotations

import json
import sys

#: ``--draw-workers`` of ``metraw train --source`` and ``metraw pretrain`` (``onthefly.fit_draws``' draw_workers)
DRAW_WORKERS_HELP = ("processes making the on-the-fly draws during the training (0: the training process's prefetch "
                     "thread, as on a CPU, where the training takes the cores; on a GPU, which trains faster than one "
                     "core draws, most of the machine's cores). The models do not depend on it (default 0)")


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train the car segmenter on a store's training split",
                              description="Train the car segmenter (params training.model: metraw's compact U-Net by "
                              "default, an smp model or a python factory) on packed, variance-stabilised raw planes "
                              "of STORE's training split (fixed split seed); writes DIR/model.pt and DIR/train.json "
                              "(the same bytes for the same store, params and machine; the time goes to stderr).")
    p.add_argument("store", help="input RawStore (.zarr) with car masks")
    p.add_argument("--out", required=True, help="output directory for the checkpoint and training metrics")
    p.add_argument("--params", default="params.yaml", help="parameter file with a training: section (default: params.yaml)")
    p.add_argument("--profile", default=None, help="training profile name (default: training.profile in params)")
    p.add_argument("--device", default=None, help="torch device (default: cuda when present, else cpu)")
    p.add_argument("--epochs", type=int, default=None, help="override the profile's number of epochs")
    p.add_argument("--learning-rate", type=float, default=None,
                   help="override the profile's peak learning rate (of the one-cycle schedule), e.g. a gentler one "
                        "to fine-tune a strong pretraining (training.pretrain.finetune_learning_rate)")
    p.add_argument("--source", default=None,
                   help="train on the fly: fresh target draws (sampling phase, flip, photon noise) of this source "
                        "store's training scenes every epoch, at the target STORE was emulated for; STORE's test "
                        "split stays the test set (default: train on STORE's fixed images)")
    p.add_argument("--codec-step", type=float, default=None,
                   help="with --source: pass every draw through the noise-preserving codec at this step, as STORE "
                        "was written (default: no codec)")
    p.add_argument("--init", default=None,
                   help="with --source: fine-tune a pretrained model directory (`metraw pretrain`): replicate r "
                        "starts from its replicate r and trains --epochs (default: train from scratch)")
    p.add_argument("--replicates", type=int, default=None,
                   help="override the profile's number of replicate models (seeds seed, seed+1, ...)")
    p.add_argument("--workers", type=int, default=None,
                   help="with --source: processes building the scenes' expected fields (the models do not depend "
                        "on it; default 2)")
    p.add_argument("--draw-workers", type=int, default=None, help="with --source: " + DRAW_WORKERS_HELP)
    p.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    p.add_argument("--progress", action="store_true", help="show progress bars even when not on a terminal")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.errors import MetrawError
    from metraw.segment.config import load_config
    from metraw.segment.train import train_store
    from metraw.study.points import load_params

    load_params(args.params, complete=False)  # schema: one line naming a bad or unknown key
    config = load_config(args.params, args.profile)
    if args.epochs is not None:
        if args.epochs < 1:
            raise MetrawError(f"--epochs must be >= 1, got {args.epochs}")
        config.epochs = args.epochs
    if args.learning_rate is not None:
        if not args.learning_rate > 0:  # also refuses nan
            raise MetrawError(f"--learning-rate must be > 0, got {args.learning_rate}")
        config.learning_rate = args.learning_rate
    if args.replicates is not None:
        if args.replicates < 1:
            raise MetrawError(f"--replicates must be >= 1, got {args.replicates}")
        config.replicates = args.replicates
    progress = True if args.progress else None
    if args.workers is not None and args.workers < 1:
        raise MetrawError(f"--workers must be >= 1, got {args.workers}")
    if args.draw_workers is not None and args.draw_workers < 0:
        raise MetrawError(f"--draw-workers must be >= 0, got {args.draw_workers}")
    if args.source is not None:
        from metraw.segment.onthefly import train_store_on_the_fly

        record = train_store_on_the_fly(args.store, args.source, args.out, config, device=args.device,
                                        progress=progress, overwrite=args.overwrite, codec_step=args.codec_step,
                                        init_dir=args.init, workers=2 if args.workers is None else args.workers,
                                        draw_workers=args.draw_workers or 0)
    else:
        for name, value in (("--codec-step", args.codec_step), ("--init", args.init), ("--workers", args.workers),
                            ("--draw-workers", args.draw_workers)):
            if value is not None:
                raise MetrawError(f"{name} applies to on-the-fly draws only (give --source)")
        record = train_store(args.store, args.out, config, device=args.device, progress=progress,
                             overwrite=args.overwrite)
    # timings go to the log (stderr) and stdout, never into DIR (metraw.segment.train.TIMINGS)
    times = record.get("replicate_training_time_s", [record["training_time_s"]])
    print(f"metraw train: {record['n_train']} {'scenes drawn on the fly' if record.get('on_the_fly') else 'images'}, "
          f"{record['epochs']} epoch(s), {len(times)} replicate(s) in {sum(times):.2f} s "
          f"(preprocessing {record['preprocess_time_s']:.2f} s)", file=sys.stderr)
    print(json.dumps({k: record[k] for k in ("epochs", "training_time_s", "n_train", "upsample", "device")}))
    return 0
