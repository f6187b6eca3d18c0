"""Issue #15: learning curves and the scratch / fine-tune / robust table for satellite-resolution training.

    python benchmarks/onthefly.py --source data/source.zarr [--params params.yaml] [--out DIR]
        [--scenes 60,120,240,384] [--seeds 0,1,2] [--epochs 20] [--dpe 1,2,4] [--finetune-epochs 5]
        [--sections curve,draws,box,ceiling,levers] [--levers depth3,depth2,...] [--thresholds 0.3] [--codec-step 1.0]
        [--more-scenes STORE]

Test set: the source's test split (params ``training.split_seed`` / ``test_fraction``), drawn at each
point ``--test-draws`` times per scene with a fixed seed (random phases and flips): a fixed set of
never-trained scenes. Scores are pooled area IoU, precision, recall and object F1
(``metraw.segment.objects``), per seed; tables give mean +- standard error over seeds.

Sections:
- ``speed``: median cost of a scene's expected stage and of one draw (raw; with codec and VST);
- ``curve``: nominal IoU against the number of distinct training scenes, static (one fixed emulated
  image per scene, the per-point store's protocol) against on-the-fly draws (1 draw per scene per epoch),
  at the same number of optimiser steps for every n (epochs x n fixed at the profile's epochs x all scenes);
- ``draws``: nominal IoU against on-the-fly draws per scene per epoch (all training scenes);
- ``box``: the robust model pretrained as the workflow's ``pretrain`` rule does (``metraw.segment.pretrain``: the
  training scenes, plus ``--more-scenes``' further ones, each drawn at ``training.pretrain.points_per_scene`` points of
  ``training.pretrain.box`` for ``training.pretrain.epochs``, in ``training.pretrain.batches``), then at every point of params.yaml: that robust model,
  it fine-tuned on the point's draws for ``--finetune-epochs`` (points of the nominal's CFA family), and a model
  trained from scratch (the profile's epochs);
- ``ceiling``: where the nominal IoU goes: the nominal payload's ground sampling (focal length and pitch: GSD
  0.88 m) with the image's degradations added back one at a time (``CEILING``), from a near-ideal payload (1 m
  aperture: diffraction 0.33 m and 25x the light; no smear, no haze) to the nominal one, each trained from scratch
  on its draws (the profile's epochs) and scored on its own test draws;
- ``levers``: nominal IoU of cheap changes to the profile's training, each on the fly with all training scenes
  (``LEVERS``: U-Net depth, input upsampling, soft-IoU or no overlap term in the loss); every model is also scored
  at the decision thresholds ``--thresholds`` (a diagnostic on the test set, not a tuned rule).
``--more-scenes STORE``: a larger store of the same generator and seed (``metraw scenes --n N`` with N above the
source's count: scene i depends only on the seed and i); its scenes past the source's count join the nominal training
scenes of the ``curve``, ``draws`` and ``levers`` sections and the pretraining scenes of ``box`` (the test set stays
the source's).
Writes ``onthefly.csv`` (one row per run) and ``onthefly.png`` (the curves) into ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np


#: ``levers`` section: name -> TrainConfig changes to the profile ("upsample": factor of the input, overriding
#: ``min_grid_px``). Each names its depth, so the rows do not move when the profile's depth does (3 until 2026-11-26).
LEVERS = {
    "depth3": {"depth": 3},
    "depth2": {"depth": 2},
    "depth1": {"depth": 1},
    "depth3-upsample2": {"depth": 3, "upsample": 2},
    "depth3-bce+iou": {"depth": 3, "loss": "bce+iou"},
    "depth3-bce": {"depth": 3, "loss": "bce"},
    "depth2-dpe2": {"depth": 2, "draws_per_epoch": 2},
}


#: ``ceiling`` section: (label, overrides of the nominal payload), from a near-ideal payload at the nominal's
#: ground sampling to the nominal one; each rung adds one degradation back.
CEILING = (
    ("ideal: D 1.0 m, no smear, no haze", {"diameter_m": 1.0, "ground_speed_m_per_s": 0.0,
                                           "atmospheric_transmission": 1.0, "path_radiance_w_m2_sr_m": 0.0}),
    ("+ smear (6.9 km/s)", {"diameter_m": 1.0, "atmospheric_transmission": 1.0, "path_radiance_w_m2_sr_m": 0.0}),
    ("+ haze (T 0.8, 2e7 path radiance)", {"diameter_m": 1.0}),
    ("nominal: + D 0.2 m", {}),
)


def test_set(fields, n_draws: int):
    from metraw.segment.data import prepare
    from metraw.segment.onthefly import draw_rng

    return [prepare(f.draw(draw_rng(10**6, k, f.index)), f.index) for f in fields for k in range(n_draws)]


def score(model, test, thresholds=()) -> dict:
    """Pooled scores at the default decision threshold, plus ``iou@t`` / ``object_f1@t`` at each of ``thresholds``."""
    from metraw.segment.evaluate import evaluate_images

    ev = evaluate_images(model, test, "cpu", False)
    out = {k: ev.get(k) for k in ("iou", "precision", "recall", "object_f1", "object_recall", "object_precision")}
    for t in thresholds:
        ev = evaluate_images(model, test, "cpu", False, threshold=t)
        out[f"iou@{t}"], out[f"object_f1@{t}"] = ev.get("iou"), ev.get("object_f1")
    return out


def mean_se(values):
    v = np.array([x for x in values if x is not None], float)
    if v.size == 0:
        return float("nan"), float("nan")
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=None, help="source store of the sweep (required unless --tables-from)")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--out", default="benchmarks/results/onthefly")
    ap.add_argument("--scenes", default="60,120,240,384")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--workers", type=int, default=2, help="processes building the expected fields (default 2)")
    ap.add_argument("--epochs", type=int, default=None, help="default: the training profile's")
    ap.add_argument("--dpe", default="1,2,4")
    ap.add_argument("--finetune-epochs", type=int, default=None, help="box section (default: training.pretrain.finetune_epochs)")
    ap.add_argument("--test-draws", type=int, default=2)
    ap.add_argument("--sections", default="speed,curve,draws,box")
    ap.add_argument("--levers", default=",".join(LEVERS), help=f"levers section: any of {', '.join(LEVERS)}")
    ap.add_argument("--codec-step", type=float, default=None, help="training draws through the codec at this step "
                    "(the workflow's codec.step; default: none, as the curve rows in docs/training.md)")
    ap.add_argument("--more-scenes", default=None, help="curve, draws, levers and box sections: add the scenes of this "
                    "larger store of the same generator and seed past the source's count to the training scenes")
    ap.add_argument("--thresholds", default="0.3", help="levers section: extra decision thresholds to score")
    ap.add_argument("--tables-from", default=None, help="print the tables and draw the figure from a CSV this "
                    "benchmark wrote (no training)")
    args = ap.parse_args(argv)
    levers = args.levers.split(",")
    unknown = [name for name in levers if name not in LEVERS]
    if unknown:
        ap.error(f"unknown lever(s) {', '.join(unknown)} (have {', '.join(LEVERS)})")
    try:
        thresholds = [float(t) for t in args.thresholds.split(",") if t]
    except ValueError:
        ap.error(f"--thresholds must be comma-separated numbers, got {args.thresholds!r}")
    if args.tables_from:
        rows = read_rows(args.tables_from)
        print_tables(rows)
        plot(rows, Path(args.out) / "onthefly.png")
        return 0
    if not args.source:
        ap.error("--source is required (unless --tables-from prints an earlier run's tables)")

    from metraw.emulate.target import TargetSystem
    from metraw.io.store import RawStore
    from metraw.segment.data import split_indices
    from metraw.segment.onthefly import build_fields, fit_draws
    from metraw.segment.train import load_config
    from metraw.study.points import load_params, parameter_points, target_params

    params = load_params(args.params)
    base = load_config(args.params)
    if args.epochs:
        base.epochs = args.epochs
    seeds = [int(s) for s in args.seeds.split(",")]
    store = RawStore.open(args.source)
    train_idx, test_idx = split_indices(len(store), base.test_fraction, base.split_seed)
    more = RawStore.open(args.more_scenes) if args.more_scenes else None
    last = len(store) - 1
    if more is not None and (len(more) <= len(store) or not np.array_equal(more[last].data, store[last].data)):
        ap.error(f"--more-scenes {args.more_scenes}: not a larger store of the source's generator and seed "
                 f"({len(more)} scenes; its scene {last} must equal the source's)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    sections = set(args.sections.split(","))
    points = list(parameter_points(params))

    def target(point):
        return TargetSystem.from_dict(target_params(params, point))

    def run(section, point, mode, n_scenes, dpe, seed, fields, test, epochs, init=None, changes=None, lever="",
            thresholds=(), keys=None):
        changes = dict(changes or {})
        upsample = changes.pop("upsample", None)
        cfg = dataclasses.replace(base, seed=seed, epochs=epochs, **changes)
        t0 = time.perf_counter()
        model, rec = fit_draws(fields, cfg, "cpu", False, init_state=init, draws_per_epoch=dpe,
                               static=mode == "static", upsample=upsample,
                               codec_step=args.codec_step, payload_keys=keys)
        row = {"section": section, "point": point, "mode": mode, "n_scenes": n_scenes, "draws_per_epoch": dpe,
               "seed": seed, "epochs": epochs, "lever": lever, "train_s": round(time.perf_counter() - t0, 1),
               **score(model, test, thresholds)}
        rows.append(row)
        print(json.dumps(row), flush=True)
        return model

    fields_at = {}

    def fields_for(point):
        if point not in fields_at:
            t0 = time.perf_counter()
            tr = build_fields(store, train_idx, target(point), workers=args.workers)
            te = build_fields(store, test_idx, target(point), workers=args.workers)
            fields_at[point] = (tr, test_set(te, args.test_draws))
            print(f"# fields at {point}: {len(tr)} train scenes, {len(fields_at[point][1])} test images, "
                  f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return fields_at[point]

    if "speed" in sections:
        speed(store, train_idx[:48], target("nominal"))
    if not sections & {"curve", "draws", "box", "ceiling", "levers"}:
        return 0
    if sections & {"curve", "draws", "box", "levers"}:
        nominal_fields, nominal_test = fields_for("nominal")
        if more is not None:
            nominal_fields = nominal_fields + build_fields(more, range(len(store), len(more)), target("nominal"),
                                                            workers=args.workers)
            print(f"# {len(nominal_fields)} training scenes with {args.more_scenes}", file=sys.stderr, flush=True)
    if "curve" in sections:
        for n in [int(s) for s in args.scenes.split(",")]:
            for seed in seeds:
                for mode in ("static", "on-the-fly"):  # same number of steps for every n (epochs scaled)
                    epochs = max(1, round(base.epochs * len(nominal_fields) / n))
                    run("curve", "nominal", mode, n, 1, seed, nominal_fields[:n], nominal_test, epochs)
    if "draws" in sections:
        for dpe in [int(s) for s in args.dpe.split(",")]:
            for seed in seeds:
                run("draws", "nominal", "on-the-fly", len(nominal_fields), dpe, seed, nominal_fields, nominal_test,
                    base.epochs)
    if "box" in sections:
        from metraw.raw.cfa import cfa_family
        from metraw.segment.pretrain import box_fields, payload_keys, sample_box
        from metraw.study.points import target_at
        from metraw.study.pretraining import pretrain_settings

        settings = pretrain_settings(params)
        finetune_epochs = args.finetune_epochs or settings["finetune_epochs"]
        family = cfa_family(target("nominal").cfa_pattern)
        # the pretraining's scenes: the source's training scenes and, with --more-scenes, that store's further ones
        scenes = [(store, int(i), int(i)) for i in train_idx]
        scenes += [(more, i, i) for i in range(len(store), len(more))] if more is not None else []
        for seed in seeds:
            overrides = sample_box(settings["box"], len(scenes), settings["points_per_scene"], seed)
            t0 = time.perf_counter()
            box = box_fields(scenes, [[TargetSystem.from_dict(target_at(params, o)) for o in per] for per in overrides],
                             workers=args.workers)
            print(f"# box fields: {len(scenes)} scenes x {settings['points_per_scene']} points, "
                  f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
            keys = payload_keys(settings["box"], overrides) if settings["batches"] == "payload" else None
            robust = run("box", "all", "robust", len(scenes), 1, seed, box, nominal_test, settings["epochs"], keys=keys)
            del box
            robust_row = rows[-1]
            state = {k: v.clone() for k, v in robust.state_dict().items()}
            for p in points:
                tr, te = fields_for(p)
                if cfa_family(target(p).cfa_pattern) == family:
                    rows.append({**robust_row, "point": p, **score(robust, te)})
                    print(json.dumps(rows[-1]), flush=True)
                    run("box", p, "fine-tune", len(tr), 1, seed, tr, te, finetune_epochs, init=state)
                run("box", p, "scratch", len(tr), 1, seed, tr, te, base.epochs)

    if "ceiling" in sections:
        from metraw.study.points import target_at

        for label, overrides in CEILING:
            rung = TargetSystem.from_dict(target_at(params, overrides))
            tr = build_fields(store, train_idx, rung, workers=args.workers)
            if more is not None:
                tr += build_fields(more, range(len(store), len(more)), rung, workers=args.workers)
            te = test_set(build_fields(store, test_idx, rung, workers=args.workers), args.test_draws)
            for seed in seeds:
                run("ceiling", label, "on-the-fly", len(tr), 1, seed, tr, te, base.epochs)
            del tr, te

    if "levers" in sections:
        for name in levers:
            changes = dict(LEVERS[name])
            dpe = changes.pop("draws_per_epoch", 1)
            for seed in seeds:
                run("levers", "nominal", "on-the-fly", len(nominal_fields), dpe, seed, nominal_fields, nominal_test,
                    base.epochs, changes=changes, lever=name, thresholds=thresholds)

    with open(out / "onthefly.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)
    print_tables(rows)
    plot(rows, out / "onthefly.png")
    return 0


def speed(store, indices, target) -> None:
    """Median cost of the expected stage per scene and of one draw (raw; + codec + VST), one core."""
    from metraw.emulate.draws import build_field
    from metraw.segment.data import prepare
    from metraw.segment.onthefly import through_codec

    images = [store[int(i)] for i in indices]
    build_field(images[0], target)  # the plan (optics tables) is made once per target
    t_field, t_draw, t_full = [], [], []
    for k, img in enumerate(images):
        t0 = time.perf_counter()
        f = build_field(img, target, index=k)
        t_field.append(time.perf_counter() - t0)
        for j in range(10):
            t0 = time.perf_counter()
            d = f.draw(1000 * k + j)
            t1 = time.perf_counter()
            prepare(through_codec(d, 1.0, j))
            t_full.append(time.perf_counter() - t0)
            t_draw.append(t1 - t0)
    print(f"# speed at nominal ({images[0].shape[0]} px scenes -> {f.frame_shape} px draws, one core): expected stage "
          f"{1e3 * np.median(t_field):.1f} ms/scene; draw {1e3 * np.median(t_draw):.2f} ms "
          f"({1 / np.median(t_draw):.0f} draws/s); draw + codec + VST {1e3 * np.median(t_full):.2f} ms "
          f"({1 / np.median(t_full):.0f} draws/s)", flush=True)


def read_rows(path) -> list[dict]:
    """Rows of an ``onthefly.csv`` with numbers parsed (empty cells: None)."""
    def value(v):
        if v == "":
            return None
        try:
            return int(v)
        except ValueError:
            try:
                return float(v)
            except ValueError:
                return v

    with open(path, newline="") as fh:
        return [{k: value(v) for k, v in r.items()} for r in csv.DictReader(fh)]


def print_tables(rows) -> None:
    names = {"iou": "IoU", "precision": "precision", "recall": "recall", "object_f1": "object F1"}

    def table(sel, key, label, extra=()):
        groups = {}
        for r in rows:
            if sel(r):
                groups.setdefault(key(r), []).append(r)
        if not groups:
            return
        metrics = [*names, *extra]
        print(f"\n{label}\n| group | n seeds | " + " | ".join(names.get(m, m) for m in metrics) + " | train s |\n|"
              + "---|" * (len(metrics) + 3))
        for k, rs in groups.items():
            cells = []
            for m in metrics:
                mu, se = mean_se([r.get(m) for r in rs])
                cells.append(f"{mu:.3f} +- {se:.3f}" if np.isfinite(se) else f"{mu:.3f}")
            print(f"| {k} | {len(rs)} | " + " | ".join(cells) + f" | {np.median([r['train_s'] for r in rs]):.0f} |")

    table(lambda r: r["section"] == "curve", lambda r: f"{r['mode']} {r['n_scenes']} scenes", "learning curve (nominal)")
    table(lambda r: r["section"] == "draws", lambda r: f"{r['draws_per_epoch']} draws/scene/epoch", "draws (nominal)")
    box_table(rows)
    table(lambda r: r["section"] == "ceiling", lambda r: r["point"],
          "ceiling ladder (nominal ground sampling 0.88 m; each rung adds one degradation; from scratch)")
    table(lambda r: r["section"] == "levers", lambda r: r["lever"],
          "levers (nominal; IoU at other decision thresholds: a test-set diagnostic)",
          sorted({k for r in rows if r["section"] == "levers" for k in r if k.startswith("iou@")}))


def box_table(rows) -> None:
    """Per point: IoU of the robust model, of it fine-tuned and of the model from scratch, and the differences
    (mean +- standard error over seeds; a difference is paired by seed)."""
    by = {}
    for r in rows:
        if r["section"] == "box" and r["point"] != "all":
            by.setdefault(r["point"], {}).setdefault(r["mode"], {})[r["seed"]] = r
    if not by:
        return

    def cell(values):
        mu, se = mean_se(values)
        return "" if not np.isfinite(mu) else f"{mu:+.3f} +- {se:.3f}" if np.isfinite(se) else f"{mu:+.3f}"

    print("\nscratch / fine-tune / robust, paired by seed (IoU; a difference > -0.02: within 0.02 of scratch or above)\n"
          "| point | robust | fine-tune | scratch | fine-tune - scratch | robust - scratch | fine-tune s | scratch s |\n"
          "|---|---|---|---|---|---|---|---|")
    for point, modes in by.items():
        sc = modes.get("scratch", {})
        iou = {m: [r["iou"] for r in modes.get(m, {}).values()] for m in ("robust", "fine-tune", "scratch")}
        diff = {m: [modes[m][s]["iou"] - sc[s]["iou"] for s in modes.get(m, {}) if s in sc] for m in ("fine-tune", "robust")}
        secs = {m: [r["train_s"] for r in modes.get(m, {}).values()] for m in ("fine-tune", "scratch")}
        print(f"| {point} | " + " | ".join(cell(iou[m]).lstrip("+") for m in iou) + " | "
              + " | ".join(cell(diff[m]) for m in diff) + " | "
              + " | ".join(f"{np.median(v):.0f}" if v else "" for v in secs.values()) + " |")


def plot(rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = [r for r in rows if r["section"] == "curve"]
    draws = [r for r in rows if r["section"] == "draws"]
    if not curve:
        return
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(9, 3.5), sharey=True)
    for mode in ("static", "on-the-fly"):
        ns = sorted({r["n_scenes"] for r in curve if r["mode"] == mode})
        stats = [mean_se([r["iou"] for r in curve if r["mode"] == mode and r["n_scenes"] == n]) for n in ns]
        ax.errorbar(ns, [s[0] for s in stats], yerr=[2 * np.nan_to_num(s[1]) for s in stats], marker="o",
                    capsize=3, label=mode)
        for r in curve:
            if r["mode"] == mode:
                ax.plot(r["n_scenes"], r["iou"], ".", color="grey", alpha=0.5)
    ax.set_xscale("log")
    ax.set_xlabel("distinct training scenes (same number of steps)")
    ax.set_ylabel("nominal IoU (test scenes, mean $\\pm$ 2 se)")
    ax.legend()
    dpes = sorted({r["draws_per_epoch"] for r in draws})
    if dpes:
        stats = [mean_se([r["iou"] for r in draws if r["draws_per_epoch"] == d]) for d in dpes]
        total = [d * draws[0]["n_scenes"] * draws[0]["epochs"] for d in dpes]
        ax2.errorbar(total, [m for m, _ in stats], yerr=[2 * np.nan_to_num(e) for _, e in stats], marker="o",
                     capsize=3, color="tab:orange", label="on-the-fly, all scenes")
        ax2.set_xscale("log")
        ax2.set_xlabel("training draws (scenes x draws/epoch x epochs)")
        ax2.legend()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
