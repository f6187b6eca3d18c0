"""Sim-to-real: realism statistics of the synthetic scenes against real KIT AIS photos, and the
synthetic-only / real-only / mixed training table at drone resolution and at the nominal satellite point.

    nice -n 5 python benchmarks/sim_to_real.py [--work benchmarks/work/sim_to_real] [--n-synthetic 480]
                                              [--epochs 20] [--real-weight N] [--json out.json]

Real data: data/real/kit_ais of the repository (15 of the set's 65 images; ``--kit DIR`` for the whole set;
SOURCE.txt: crops of nadir aerial photos of Munich from the KIT AIS data set, CC-BY 3.0, via
github.com/jekhor/aerial-cars-dataset; YOLO car boxes), ingested as
approximate raws of the source camera (``metraw ingest --labels yolo --gsd-m 0.135``). Its labels are
axis-aligned boxes: the scores on it are *box-approximate* (a car at 45 degrees fills half its box, so even a
perfect segmenter scores well below 1 there).

Protocol (every model: the default training profile of params.yaml, same network, same seed):
- drone resolution = KIT's own ground sampling (0.135 m): the synthetic scenes are rendered by the same
  camera flown at the altitude that gives that GSD (575 m instead of 250 m; same etendue, same photon counts),
  so synthetic and real images share one grid and can be mixed without resampling;
- the real images are split by image (``--real-test`` of them, seeded) into train and test; synthetic scenes
  use the workflow's split (test_fraction of params.yaml);
- real-only takes as many crops per epoch as synthetic-only (the same number of steps);
- mixed = synthetic training scenes + real training images, each real image drawn ``--real-weight`` times per
  epoch (default 4 with a fixed number of crops per image: a real image is ~10x a synthetic scene's area;
  1 with ``crops_per_image: cover``, which already draws crops in proportion to each image's area);
- nominal point: both stores emulated through ``target.nominal`` (photon-exact chain), then the same three
  trainings.
Every model is scored on the real test images and on the synthetic test scenes (pooled IoU, precision,
recall); a synthetic-only model also on the real training images, which it never saw (``real_validation``:
for choosing training settings without the test images). Stores are cached in ``--work``; models are
retrained every run (seconds to minutes each; ``train_s`` includes the scoring).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
KIT = ROOT / "data" / "real" / "kit_ais"


def run(cmd: list[str]) -> None:
    """Run a metraw CLI command (``cmd[0] == "metraw"``) through this interpreter's metraw package (the same
    source tree as the imports here, e.g. a clone on PYTHONPATH, not whichever ``metraw`` is on PATH)."""
    if cmd[0] == "metraw":
        cmd = [sys.executable, "-m", "metraw", *cmd[1:]]
    print("+", " ".join(cmd), file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True)


def stores(work: Path, params_path: Path, kit: Path, n_synthetic: int, kit_gsd_m: float, with_nominal: bool = True,
           kinds: str = "urban,suburban,rural") -> dict[str, Path]:
    """The real and synthetic stores at KIT's GSD and at the nominal point (made once, cached in ``work``)."""
    params = yaml.safe_load(params_path.read_text())
    cam = params["source"]["camera"]
    altitude_m = kit_gsd_m * cam["focal_length_m"] / cam["pixel_pitch_m"]
    size_px = 2 * round(60.0 / kit_gsd_m / 2)  # the ground area of a default 1024 px scene (60 m)
    p_kit = dict(params, source=dict(params["source"], camera=dict(cam, altitude_m=altitude_m)))
    work.mkdir(parents=True, exist_ok=True)
    cam_file = work / "camera_at_kit_gsd.yaml"
    cam_file.write_text(yaml.safe_dump(p_kit))
    tag = "" if kinds == "urban,suburban,rural" else "_" + kinds.replace(",", "_")
    out = {"real": work / "real.zarr", "synthetic": work / f"synthetic_{n_synthetic}{tag}.zarr"}
    if not out["real"].exists():
        run(["metraw", "ingest", str(kit), "--labels", "yolo", "--gsd-m", str(kit_gsd_m), "--camera", str(params_path),
             "--out", str(out["real"])])
    if not out["synthetic"].exists():
        run(["metraw", "scenes", "--n", str(n_synthetic), "--seed", "0", "--size", str(size_px), "--camera", str(cam_file),
             "--kinds", kinds, "--workers", "2", "--out", str(out["synthetic"])])
    for name in ("real", "synthetic") if with_nominal else ():
        nominal = work / f"{out[name].stem}_nominal.zarr"
        if not nominal.exists():
            run(["metraw", "emulate", str(out[name]), str(nominal), "--params", str(params_path), "--workers", "2"])
        out[f"{name}_nominal"] = nominal
    return out


def real_split(n: int, n_test: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    perm = np.random.default_rng(seed).permutation(n)
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


def scores(model, images, transforms: int, overlays: Path | None = None, boxes: bool = False) -> dict[str, float]:
    """Pooled pixel IoU, precision, recall and object recall / precision (``metraw.segment.objects``) of the
    predictions averaged over ``transforms`` dihedral transforms, and with ``boxes`` (box labels) the predicted
    objects' bounding boxes scored against them; with ``overlays``, one PNG per image there (green: hit, red:
    false alarm, blue: missed label)."""
    from metraw.segment.evaluate import evaluate_images
    from metraw.segment.train import flush_denormals

    with flush_denormals():
        r = evaluate_images(model, images, "cpu", progress=False, boxes=boxes, transforms=transforms)
        if overlays is not None:
            write_overlays(model, images, overlays, transforms)
    keys = ("iou", "precision", "recall", "object_recall", "object_precision") + (
        ("box_iou", "box_precision", "box_recall") if boxes else ())
    return {k: None if r.get(k) is None else round(float(r[k]), 4) for k in keys}


def write_overlays(model, images, folder: Path, transforms: int) -> None:
    from PIL import Image

    from metraw.atomic import atomic_path
    from metraw.segment.evaluate import _mosaic, averaged_probability, predicted_mask

    folder.mkdir(parents=True, exist_ok=True)
    for img in images:
        planes, frac = img.full()
        prob = averaged_probability(model, img.z, img.pattern, "cpu", transforms=transforms)
        pred = predicted_mask(_mosaic(prob, img.pattern), img.gsd_m)
        g = planes[1] if planes.shape[0] > 1 else planes[0]
        grey = np.clip((g - np.percentile(g, 1)) / (np.ptp(np.percentile(g, [1, 99])) + 1e-9), 0, 1)
        rgb = np.repeat((0.8 * grey)[..., None], 3, axis=-1)
        site = 1 if planes.shape[0] > 1 else 0  # the first green site of each packed cell
        truth, p = frac[site] >= 0.5, pred[site // 2::2, site % 2::2] if planes.shape[0] > 1 else pred
        rgb[p & truth] = 0.5 * rgb[p & truth] + [0, 0.5, 0]
        rgb[p & ~truth] = 0.5 * rgb[p & ~truth] + [0.5, 0, 0]
        rgb[~p & truth] = 0.5 * rgb[~p & truth] + [0, 0, 0.5]
        with atomic_path(folder / f"{img.index:04d}.png", overwrite=True) as tmp:
            Image.fromarray((255 * rgb).astype(np.uint8)).save(tmp, format="PNG")


def table_for(level: str, real_store: Path, syn_store: Path, config, real_test: int, real_weight: int | None,
              seed: int, trainings: tuple[str, ...] = ("synthetic-only", "real-only", "mixed"),
              overlays: Path | None = None) -> list[dict]:
    from metraw.io.store import RawStore
    from metraw.segment.data import prepare_store, split_indices
    from metraw.segment.train import COVER, crops_to_cover, fit, grid_factors

    real, syn = RawStore.open(real_store), RawStore.open(syn_store)
    r_train, r_test = real_split(len(real), real_test, seed)
    s_train, s_test = split_indices(len(syn), config.test_fraction, config.split_seed)
    rt, rs = prepare_store(real, r_train), prepare_store(real, r_test)
    st, ss = prepare_store(syn, s_train), prepare_store(syn, s_test)
    # a real-only epoch takes as many crops as a synthetic-only one (same steps: 45 real images against 384
    # scenes); mixing repeats the real images real_weight times ("cover" already draws them by area)
    syn_crops = int(crops_to_cover(st, config.crop_px * grid_factors(st, config)[1]).sum()) \
        if config.crops_per_image == COVER else len(st) * config.crops_per_image
    per_real = max(1, round(syn_crops / len(rt)))
    if real_weight is None:
        real_weight = 1 if config.crops_per_image == COVER else 4
    runs = {"synthetic-only": (st, config),
            "real-only": (rt, replace(config, crops_per_image=per_real)),
            "mixed": (st + rt * real_weight, config)}
    rows = []
    for name, (images, cfg) in runs.items():
        if name not in trainings:
            continue
        t0 = time.perf_counter()
        model, record = fit(images, cfg, "cpu", progress=False)
        row = {"level": level, "training": name, "n_train_images": len(images),
               "real_test": scores(model, rs, cfg.predict_transforms, overlays and overlays / f"{level}_{name}_real",
                                   boxes=True)}
        if name == "synthetic-only":  # the real training images, never seen: a validation set for settings
            row["real_validation"] = scores(model, rt, cfg.predict_transforms, boxes=True)
        row["synthetic_test"] = scores(model, ss, cfg.predict_transforms,
                                       overlays and overlays / f"{level}_{name}_synthetic")
        row["train_s"] = round(time.perf_counter() - t0, 1)
        rows.append(row)
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kit", type=Path, default=KIT)
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "work" / "sim_to_real")
    ap.add_argument("--n-synthetic", type=int, default=480)
    ap.add_argument("--kit-gsd-m", type=float, default=0.135)
    ap.add_argument("--epochs", type=int, default=None, help="override the profile's epochs")
    ap.add_argument("--profile", default=None,
                    help="training profile of params.yaml (default: training.profile; 'source' = the drone-resolution "
                         "reference's)")
    ap.add_argument("--train-seed", type=int, default=None, help="override the profile's training seed")
    ap.add_argument("--depth", type=int, default=None,
                    help="override the profile's U-Net depth (the default profile's was 3 until 2026-11-26, now 2)")
    ap.add_argument("--tone-gamma-range", type=float, default=None,
                    help="override the profile's tone_gamma_range (tone-curve randomisation of training crops)")
    ap.add_argument("--channel-gain-range", type=float, default=None,
                    help="override the profile's channel_gain_range (white-balance randomisation of training crops)")
    ap.add_argument("--transforms", type=int, choices=(1, 2, 4, 8), default=None,
                    help="override the profile's predict_transforms (dihedral transforms averaged per prediction)")
    ap.add_argument("--crops-per-image", default=None,
                    help="override the profile's crops_per_image (a positive integer, or 'cover')")
    ap.add_argument("--real-test", type=int, default=20, help="real images held out for testing")
    ap.add_argument("--real-weight", type=int, default=None,
                    help="times each real image is drawn per epoch (mixed; default 4, or 1 with crops_per_image: cover)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default="urban,suburban,rural",
                    help="scene types of the synthetic store (KIT AIS shows city streets only: 'urban')")
    ap.add_argument("--levels", default="source,nominal")
    ap.add_argument("--trainings", default="synthetic-only,real-only,mixed",
                    help="which trainings to run (comma-separated subset)")
    ap.add_argument("--no-realism", action="store_true", help="skip the realism tables")
    ap.add_argument("--overlays", type=Path, default=None,
                    help="write each test image's prediction overlay (PNG) under this folder")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if not args.kit.is_dir():
        sys.exit(f"sim_to_real: no real data at {args.kit} (see data/real/README.md)")

    from metraw.io.store import RawStore
    from metraw.scenes.stats import format_table, summarise
    from metraw.segment.train import TrainConfig, load_config

    levels = args.levels.split(",")
    paths = stores(args.work, args.params, args.kit, args.n_synthetic, args.kit_gsd_m, "nominal" in levels,
                   args.kinds)
    if not args.no_realism:
        syn = RawStore.open(paths["synthetic"])
        first = [syn[i] for i in range(min(60, len(syn)))]
        print("== realism: synthetic scenes (first 60, all kinds) vs KIT AIS")
        print(format_table(summarise(first, args.kit)))
        print("== realism: the urban ones among them (KIT AIS shows city streets only)")
        print(format_table(summarise([im for im in first if im.meta.get("scene_type") == "urban"], args.kit)))

    config = load_config(args.params, args.profile)
    if args.epochs:
        config = replace(config, epochs=args.epochs)
    if args.train_seed is not None:
        config = replace(config, seed=args.train_seed)
    if args.depth is not None:
        if args.depth < 1:
            ap.error(f"--depth must be >= 1, got {args.depth}")
        config = replace(config, depth=args.depth)
    if args.tone_gamma_range:
        config = replace(config, tone_gamma_range=args.tone_gamma_range)
    if args.channel_gain_range:
        config = replace(config, channel_gain_range=args.channel_gain_range)
    if args.transforms:
        config = replace(config, predict_transforms=args.transforms)
    if args.crops_per_image:
        crops = args.crops_per_image
        config = replace(config, crops_per_image=int(crops) if crops.isdigit() else crops)
        TrainConfig.from_dict(asdict(config))  # one-line error on a bad value
    rows = []
    trainings = tuple(args.trainings.split(","))
    for level in levels:
        suffix = "" if level == "source" else f"_{level}"
        rows += table_for(level, paths[f"real{suffix}"], paths[f"synthetic{suffix}"], config, args.real_test,
                          args.real_weight, args.seed, trainings, args.overlays)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "epochs": config.epochs, "real_test": args.real_test,
                                         "real_weight": args.real_weight,
                                         "transforms": config.predict_transforms,
                                         "crops_per_image": config.crops_per_image}, indent=1))
    print("\n== training data vs test images (pooled IoU / precision / recall; real labels are boxes: pixels "
          "against boxes, then each predicted object's bounding box against them)")
    print(f"{'level':8s} {'training':15s} {'real test, pixels':>24s} {'real test, boxes':>24s} {'synthetic test':>24s}"
          f" {'real validation, pixels':>24s}")
    for r in rows:
        f = lambda s, b="": "-" if s is None else " / ".join(  # noqa: E731
            "-" if s[b + k] is None else f"{s[b + k]:.3f}" for k in ("iou", "precision", "recall"))
        print(f"{r['level']:8s} {r['training']:15s} {f(r['real_test']):>24s} {f(r['real_test'], 'box_'):>24s} "
              f"{f(r['synthetic_test']):>24s} {f(r.get('real_validation')):>24s}")


if __name__ == "__main__":
    main()
