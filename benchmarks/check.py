"""Does the runtime check agree with the measured IoU? `metraw check` on every test image of every point of a run.

usage: python benchmarks/check.py [--results results] [--spec results/spec.yaml] [--params params.yaml]
                                  [--source data/source.zarr --source-n 24] [--json OUT.json]

For each point of params.yaml, every image of its store (results/points/{point}/target.zarr: the test split) is
checked against the spec (`metraw.spec.check.check`, the noise profile measured as the command does) and counted as
PASS / NORMALISE / REJECT beside the point's measured IoU +- sd (results/points/{point}/metrics.json; sd: the
test-image sampling error and the replicates' spread, as the aggregate uses it). NORMALISE images are brought to
spec with their planned chain (`metraw.spec.check.apply_chain`) and the point's own model scores them before and after
(pooled IoU, paired difference). The two agreement counts of issue #51:

- REJECTed images at points whose IoU - 2 sd >= required_iou (the point meets the requirement): should be 0;
- PASSed images at points whose IoU + 2 sd < required_iou (the point misses it): should be 0.

With ``--source``, the first ``--source-n`` test images of the source store are checked too, and the number whose
noise profile the single-frame fit contradicts ("profile contradicts the pixels") is printed (should be 0).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from normalise import paired_difference, pooled  # noqa: E402  (benchmarks/normalise.py)


def check_point(point: str, results: Path, spec, required: float, seed: int) -> dict:
    from metraw.io.store import RawStore
    from metraw.segment.data import prepare
    from metraw.segment.evaluate import evaluate_images
    from metraw.segment.train import load_model
    from metraw.spec.aggregate import _read_measured
    from metraw.spec.check import apply_chain, check

    folder = results / "points" / point
    _, (iou, var) = _read_measured(folder / "metrics.json", "metrics file")
    sd = math.sqrt(var)
    store = RawStore.open(folder / "target.zarr")
    verdicts: Counter = Counter()
    reasons: Counter = Counter()
    before, after = [], []
    predicted = []
    for i in range(len(store)):
        image = store[i]
        d = check(image, spec)
        verdicts[d.verdict] += 1
        if "predicted_iou" in d.properties:
            predicted.append(d.properties["predicted_iou"]["value"])
        if d.verdict == "REJECT":
            reasons[d.reasons[0].split(" (")[0].split(" = ")[0][:60]] += 1
        if d.verdict == "NORMALISE":
            before.append(prepare(image, i))
            moved = apply_chain(image, d.chain, seed=np.random.Generator(np.random.PCG64([seed, i, 1])))
            after.append(prepare(moved, i))
    row = {"point": point, "iou": iou, "iou_sd": sd, "n": len(store), "verdicts": dict(verdicts),
           "reject_reasons": dict(reasons), "meets": iou - 2 * sd >= required, "misses": iou + 2 * sd < required,
           "predicted_iou_median": float(np.median(predicted)) if predicted else None}
    if before:
        model, _, _ = load_model(folder / "model", "cpu")
        res_b = evaluate_images(model, before, "cpu", progress=False)
        res_a = evaluate_images(model, after, "cpu", progress=False)
        row["normalised"] = {"iou_before": pooled(res_b, f"{point} before"), "iou_after": pooled(res_a, f"{point} after"),
                             "paired": paired_difference(res_b["per_image"], res_a["per_image"])}
    return row


def _pm(pair) -> str:
    v, se = pair if isinstance(pair, tuple) else (pair, None)
    return "-" if v is None else f"{v:.3f}" + ("" if se is None else f" +- {se:.3f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results", help="a finished run's results folder")
    ap.add_argument("--spec", default=None, help="the spec to check against (default RESULTS/spec.yaml)")
    ap.add_argument("--params", default="params.yaml", help="the run's parameters (its points)")
    ap.add_argument("--source", default=None, help="also check test images of this source store (data/source.zarr)")
    ap.add_argument("--source-n", type=int, default=24, help="how many source test images (default 24)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the normalisation's draws")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--json", default=None, help="also write every number here")
    args = ap.parse_args(argv)

    import torch

    from metraw.errors import MetrawError
    from metraw.spec.builder import Specification
    from metraw.study.points import load_params, parameter_points

    torch.set_num_threads(args.threads)
    results = Path(args.results)
    try:
        if not results.is_dir():
            raise MetrawError(f"{results}: no results folder (run the workflow first)")
        params = load_params(args.params)
        spec = Specification.load(args.spec or results / "spec.yaml")
        points = list(parameter_points(params))
        t0 = time.perf_counter()
        rows = [check_point(p, results, spec, spec.required_iou, args.seed) for p in points]
        source = _check_source(args, params, spec) if args.source else None
    except MetrawError as exc:
        print(f"benchmarks/check.py: error: {exc}", file=sys.stderr)
        return 2
    req = spec.required_iou
    print(f"metraw check on every test image of every point ({args.results}, spec {args.spec or results / 'spec.yaml'}, "
          f"required IoU {req:g}; {'property model' if spec.property_model is not None else 'property limits'})")
    head = ["point", "IoU +- sd", "class", "predicted (median)", "PASS", "NORMALISE", "REJECT",
            "normalised IoU before / after (paired diff)"]
    body = []
    for r in rows:
        cls = "meets" if r["meets"] else "misses" if r["misses"] else "within 2 sd"
        norm = r.get("normalised")
        body.append([r["point"], f"{r['iou']:.3f} +- {r['iou_sd']:.3f}", cls, _pm(r["predicted_iou_median"]),
                     *(str(r["verdicts"].get(k, 0)) for k in ("PASS", "NORMALISE", "REJECT")),
                     "-" if not norm else f"{_pm(norm['iou_before'])} / {_pm(norm['iou_after'])} "
                                          f"({_pm(norm['paired'])})"])
    widths = [max(len(x[c]) for x in [head] + body) for c in range(len(head))]
    print("| " + " | ".join(h.ljust(w) for h, w in zip(head, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for b in body:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(b, widths)) + " |")
    bad_reject = sum(r["verdicts"].get("REJECT", 0) for r in rows if r["meets"])
    bad_pass = sum(r["verdicts"].get("PASS", 0) for r in rows if r["misses"])
    print(f"REJECTed images at points whose IoU - 2 sd >= {req:g}: {bad_reject}")
    print(f"PASSed images at points whose IoU + 2 sd < {req:g}: {bad_pass}")
    for r in rows:
        if r["reject_reasons"]:
            print(f"  {r['point']}: REJECT reasons: " + "; ".join(f"{k} ({v}x)" for k, v in r["reject_reasons"].items()))
    if source is not None:
        print(f"source: {source['n']} test images of {args.source}: {source['verdicts']}; rejected for the noise "
              f"profile: {source['noise_rejects']}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"points": rows, "source": source, "bad_reject": bad_reject,
                                               "bad_pass": bad_pass}, indent=1, default=float))
    return 0


def _check_source(args, params, spec) -> dict:
    from metraw.io.store import RawStore
    from metraw.segment.data import split_indices
    from metraw.spec.check import check

    store = RawStore.open(args.source)
    training = params.get("training") or {}
    _, test = split_indices(len(store), float(training.get("test_fraction", 0.2)), int(training.get("split_seed", 0)))
    verdicts: Counter = Counter()
    noise_rejects = 0
    for i in test[: args.source_n]:
        d = check(store[int(i)], spec)
        verdicts[d.verdict] += 1
        noise_rejects += any(r.startswith("profile contradicts the pixels") for r in d.reasons)
    return {"n": int(min(len(test), args.source_n)), "verdicts": dict(verdicts), "noise_rejects": noise_rejects}


if __name__ == "__main__":
    sys.exit(main())
