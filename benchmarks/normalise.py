"""Does normalisation pay? IoU of the nominal model on better-than-spec images, before and after `normalise`.

usage: python benchmarks/normalise.py --source data/source.zarr --spec results/spec.yaml \
           --model results/points/nominal/model --params params.yaml \
           [--points focal_length_m=3.288 diameter_m=0.5 exposure_s=60e-6] [--n N] [--json OUT.json]

For each point (``name=value,...`` overrides of target.nominal in params.yaml) the test-split
source images (``split_indices(n, test_fraction, split_seed)`` of params.yaml's training section,
the first ``--n`` of them) are emulated exactly as ``metraw emulate`` does (image i with seed
(emulation seed, i)), checked against the spec (`metraw.spec.check.check`), and, where the verdict is
NORMALISE, brought to spec with the planned chain of raw functions (`metraw.spec.check.apply_chain`:
same-colour binning, photon redistribution, binomial thinning; the label mask follows the
geometry). The nominal model (trained on the nominal point) segments the raw image as emulated
("before": the finer/sharper/brighter image fed straight to the model, the mismatch a deployed
model would face) and the normalised image ("after"; PASS images enter unchanged, REJECT images
are left out of "after" and of the paired difference). The reference row is the same model on the
nominal point's own emulated test images.

IoU is the pooled ground-area IoU of `metraw.segment.evaluate`; "+-" is its sampling standard
error over the draw of test images (ratio-estimator delta method, `metraw.spec.aggregate.
iou_measurement`). The paired difference after - before is computed on the same images with the
same linearisation (per-image influence terms differenced before averaging), so its standard
error is smaller than either IoU's when the two track each other.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from collections import Counter
from typing import Any

import numpy as np


def emulate_points(source, indices, target, mode: str, seed: int, accuracy=None):
    """Yield (index, emulated RawImage) as `metraw emulate` makes them (image i: seed (seed, i))."""
    from metraw.emulate.emulator import emulate

    for i in indices:
        rng = np.random.Generator(np.random.PCG64([seed, int(i)]))
        yield int(i), emulate(source[int(i)], target, mode=mode, seed=rng, accuracy=accuracy)


def pooled(metrics: dict[str, Any], where: str) -> tuple[float | None, float | None]:
    """(pooled IoU, its standard error) of an `evaluate_images` result; (None, None) when empty."""
    from metraw.spec.aggregate import iou_measurement

    if not metrics.get("per_image") or metrics.get("iou") is None:
        return None, None
    iou, var = iou_measurement(metrics, where)
    return iou, math.sqrt(var)


def _influence(records: list[dict[str, Any]]) -> np.ndarray:
    """Per-image linearised contribution (TP_i - R U_i) / mean(U) of the pooled IoU R."""
    tp = np.array([r["tp"] for r in records], dtype=np.float64)
    u = tp + np.array([r["fp"] + r["fn"] for r in records], dtype=np.float64)
    r = tp.sum() / u.sum() if u.sum() > 0 else 0.0
    return (tp - r * u) / max(u.mean(), 1e-300)


def paired_difference(before: list[dict[str, Any]], after: list[dict[str, Any]]) -> tuple[float | None, float | None]:
    """(IoU_after - IoU_before, standard error) on the same images (records in the same order)."""
    from metraw.segment.evaluate import summarise

    if not before or len(before) != len(after):
        return None, None
    b, a = summarise(before)["iou"], summarise(after)["iou"]
    if a is None or b is None:
        return None, None
    if len(before) < 2:
        return a - b, None
    d = _influence(after) - _influence(before)
    return a - b, float(math.sqrt(np.var(d, ddof=1) / len(d)))


def describe_chain(chains: list[list[dict[str, Any]]]) -> str:
    """One line for the chains of a point's NORMALISE images: each step with its parameter range."""
    if not chains:
        return "-"
    by_step: dict[tuple[int, str], dict[str, list[float]]] = {}
    shapes = Counter(tuple(s["function"] for s in c) for c in chains)
    for c in chains:
        for k, s in enumerate(c):
            for name, v in s["params"].items():
                by_step.setdefault((k, s["function"]), {}).setdefault(name, []).append(v)
    parts = []
    for (k, fn), pars in sorted(by_step.items()):
        items = []
        for name, vals in pars.items():
            if all(isinstance(v, (int, float)) for v in vals):
                lo, hi = min(vals), max(vals)
                items.append(f"{name}={lo:.3g}" if math.isclose(lo, hi, rel_tol=1e-3) else f"{name}={lo:.3g}..{hi:.3g}")
            else:
                items.append(f"{name}={'/'.join(sorted(set(map(str, vals))))}")
        parts.append(f"{fn}({', '.join(items)})")
    text = " -> ".join(parts)
    if len(shapes) > 1:
        text += " [chains differ: " + "; ".join(f"{n}x {'+'.join(s)}" for s, n in shapes.items()) + "]"
    return text


def run_point(label: str, target, source, indices, spec, model, device, mode, seed, accuracy, verbose) -> dict[str, Any]:
    from metraw.segment.data import prepare
    from metraw.segment.evaluate import evaluate_images
    from metraw.spec.check import apply_chain, check

    verdicts: Counter = Counter()
    chains, reasons = [], Counter()
    before, after, kept_before = [], [], []
    t0 = time.perf_counter()
    for i, img in emulate_points(source, indices, target, mode, seed, accuracy):
        d = check(img, spec)
        verdicts[d.verdict] += 1
        for r in d.reasons:
            reasons[re.split(r" = |: ", r)[0]] += 1  # group by what the reason is about
        prep = prepare(img, i)
        before.append(prep)
        if d.verdict == "REJECT":
            if verbose:
                print(f"  {label} image {i}: REJECT: {'; '.join(d.reasons)}", file=sys.stderr)
            continue
        if d.verdict == "NORMALISE":
            chains.append(d.chain)
            # own seed stream per image for the raw functions' draws, disjoint from the emulation's
            img = apply_chain(img, d.chain, seed=np.random.Generator(np.random.PCG64([seed, int(i), 1])))
        after.append(prepare(img, i))
        kept_before.append(prep)
    res_before = evaluate_images(model, before, device, progress=False)
    res_after = evaluate_images(model, after, device, progress=False) if after else {"per_image": []}
    res_kept = evaluate_images(model, kept_before, device, progress=False) if kept_before else {"per_image": []}
    iou_b, se_b = pooled(res_before, f"{label} before")
    iou_a, se_a = pooled(res_after, f"{label} after")
    delta, se_d = paired_difference(res_kept["per_image"], res_after["per_image"])
    return {"point": label, "target": target.to_dict(), "n": len(before), "verdicts": dict(verdicts),
            "chain": describe_chain(chains), "reasons": dict(reasons),
            "iou_before": iou_b, "iou_before_se": se_b, "iou_after": iou_a, "iou_after_se": se_a,
            "n_after": len(after), "delta_paired": delta, "delta_paired_se": se_d,
            "gsd_before_m": target.gsd_m, "shape_before": list(before[0].z.shape) if before else None,
            "shape_after": list(after[0].z.shape) if after else None,
            "per_image_before": res_before["per_image"], "per_image_after": res_after["per_image"],
            "time_s": time.perf_counter() - t0}


def _pm(v, se) -> str:
    if v is None:
        return "-"
    return f"{v:.3f}" + ("" if se is None else f" +- {se:.3f}")


def format_table(rows: list[dict[str, Any]], reference: dict[str, Any]) -> str:
    ref = _pm(reference["iou_before"], reference["iou_before_se"])
    head = ["point", "n", "decision", "chain", "IoU before", "IoU after", "after - before (paired)", "reference (nominal)"]
    body = []
    for r in rows:
        dec = ", ".join(f"{k} {v}/{r['n']}" for k, v in sorted(r["verdicts"].items()))
        body.append([r["point"], str(r["n"]), dec, r["chain"], _pm(r["iou_before"], r["iou_before_se"]),
                     _pm(r["iou_after"], r["iou_after_se"]), _pm(r["delta_paired"], r["delta_paired_se"]), ref])
    body.append(["nominal (reference)", str(reference["n"]),
                 ", ".join(f"{k} {v}/{reference['n']}" for k, v in sorted(reference["verdicts"].items())),
                 "-", ref, "-", "-", ref])
    widths = [max(len(x[c]) for x in [head] + body) for c in range(len(head))]
    line = lambda cells: "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"  # noqa: E731
    return "\n".join([line(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [line(b) for b in body])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", required=True, help="source RawStore (the workflow's data/source.zarr)")
    ap.add_argument("--spec", default="results/spec.yaml", help="specification (default results/spec.yaml)")
    ap.add_argument("--model", required=True, help="nominal model directory (results/points/nominal/model)")
    ap.add_argument("--params", default="params.yaml", help="parameter file (target.nominal, emulation, training split)")
    ap.add_argument("--points", nargs="+", default=["focal_length_m=3.288", "diameter_m=0.5", "exposure_s=60e-6"],
                    help="target overrides per point, name=value[,name=value] (default: f 2x nominal, "
                         "D 0.5 m, exposure 60 us)")
    ap.add_argument("--n", type=int, default=None, help="use only the first N test images")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1: the machine is shared)")
    ap.add_argument("--json", default=None, help="also write all numbers (per image too) as JSON here")
    ap.add_argument("--verbose", action="store_true", help="print each rejected image's reasons")
    args = ap.parse_args(argv)

    import torch

    from metraw.emulate.target import TargetSystem, parse_point
    from metraw.errors import MetrawError
    from metraw.io.store import RawStore
    from metraw.physics.accuracy import Accuracy
    from metraw.segment.data import split_indices
    from metraw.segment.train import load_model
    from metraw.spec.builder import Specification
    from metraw.study.points import load_params

    torch.set_num_threads(args.threads)
    try:
        params = load_params(args.params)
        spec = Specification.load(args.spec)
        source = RawStore.open(args.source)
        model, ckpt, _ = load_model(args.model, "cpu")
        training = params.get("training") or {}
        _, test_idx = split_indices(len(source), float(training.get("test_fraction", 0.2)),
                                    int(training.get("split_seed", 0)))
        if [int(i) for i in ckpt.get("test_indices", [])] != test_idx.tolist():
            print(f"warning: the model's test split differs from the source's ({len(source)} images): the "
                  "test images below may include the model's training images", file=sys.stderr)
        if args.n is not None:
            if args.n < 1:
                raise MetrawError(f"--n must be >= 1, got {args.n}")
            test_idx = test_idx[: args.n]
        emu = dict((params.get("target") or {}).get("emulation") or {})
        mode, seed = emu.get("mode", "auto"), int(emu.get("seed", 0))
        accuracy = Accuracy()
        points = [(p, TargetSystem.from_params(params, parse_point(p))) for p in args.points]
    except MetrawError as exc:
        print(f"benchmarks/normalise.py: error: {exc}", file=sys.stderr)
        return 2

    t0 = time.perf_counter()
    common = (source, test_idx, spec, model, "cpu", mode, seed, accuracy, args.verbose)
    reference = run_point("nominal", TargetSystem.from_params(params), *common)
    rows = [run_point(label, target, *common) for label, target in points]
    print(f"IoU of the nominal model ({args.model}) before and after `normalise`, spec {args.spec}, "
          f"{len(test_idx)} test images of {args.source}, emulation mode {mode}, seed {seed}")
    print(format_table(rows, reference))
    for r in rows + [reference]:
        top = "; ".join(f"{k} ({v}x)" for k, v in Counter(r["reasons"]).most_common(4))
        print(f"  {r['point']}: GSD {r['gsd_before_m']:.3f} m, image {r['shape_before']} px -> {r['shape_after']} px; "
              f"reasons: {top}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    if args.json:
        from metraw.atomic import atomic_path

        with atomic_path(args.json, overwrite=True) as tmp:
            tmp.write_text(json.dumps({"reference": reference, "points": rows, "spec": args.spec,
                                       "model": args.model, "source": args.source,
                                       "test_indices": [int(i) for i in test_idx]}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
