"""Issue #15, item 3: the robust (pretrained) model against the per-point models of a finished workflow run.

    python benchmarks/robust.py [--results results] [--params params.yaml] [--margin 0.02]

Scores ``results/pretrained/<pattern>/model`` (every replicate: the box model of the point's CFA pattern alone, no
fine-tuning) on the test split of each fine-tuned point's store (``results/points/P/target.zarr``, the images the point's own models were scored
on) with ``metraw.segment.evaluate.evaluate_store``, and prints per point the IoU of both (mean over replicates),
their difference, the standard error of the difference paired by replicate (pretrained replicate r against the
point's replicate r, fine-tuned from it: the test images are the same, so the test-image error cancels largely),
and whether the robust model is within ``--margin`` of the point's models or above. Points marked ``*`` are the
issue's ten (the nominal and the one-at-a-time focal-length, diameter and exposure points). Nothing is written.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

#: The issue's ten points: the nominal and the one-at-a-time focal-length, diameter and exposure points.
ISSUE_PARAMETERS = ("focal_length_m", "diameter_m", "exposure_s")


def issue_point(point: str) -> bool:
    """Whether ``point`` is the nominal or one of ``ISSUE_PARAMETERS`` changed alone."""
    return point == "nominal" or ("+" not in point and point.rsplit("-", 1)[0] in ISSUE_PARAMETERS)


def replicate_ious(metrics: dict) -> list[float]:
    """The pooled IoU of each replicate, in seed order, of an ``evaluate_store`` record."""
    return [r["iou"] for r in sorted(metrics.get("replicates") or [{"seed": 0, "iou": metrics["iou"]}],
                                     key=lambda r: r["seed"])]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results", help="the workflow's results directory")
    ap.add_argument("--params", default="params.yaml", help="the run's params (its fine-tuned points)")
    ap.add_argument("--margin", type=float, default=0.02, help="IoU the robust model may fall below a point's")
    args = ap.parse_args(argv)

    from metraw.segment.evaluate import evaluate_store
    from metraw.study.points import load_params
    from metraw.study.pretraining import fine_tuned_points, point_patterns

    results = Path(args.results)
    params = load_params(args.params)
    points = fine_tuned_points(params)
    models = {p: results / "pretrained" / pattern / "model" for p, pattern in point_patterns(params).items()}
    missing = [str(results / "points" / p / "metrics.json") for p in points
               if not (results / "points" / p / "metrics.json").is_file()]
    missing += sorted({str(models[p]) for p in points if not models[p].is_dir()})
    if missing or not points:
        print(f"robust.py: needs a finished run with pretraining: every fine-tuned point's metrics.json and its "
              f"pattern's pretrained model (missing: {', '.join(missing) or 'none'}; fine-tuned points: {len(points)})",
              file=sys.stderr)
        return 2
    print(f"| point | robust (pretrained alone) | per-point (fine-tuned) | robust - per-point | paired SE | within "
          f"{args.margin} |\n|---|---|---|---|---|---|")
    hits = {True: 0, False: 0}
    totals = {True: 0, False: 0}
    for point in points:
        own = json.loads((results / "points" / point / "metrics.json").read_text())
        robust = evaluate_store(results / "points" / point / "target.zarr", models[point], "cpu", progress=False,
                                split="test")
        a, b = replicate_ious(robust), replicate_ious(own)
        diffs = [x - y for x, y in zip(a, b)]
        mean = sum(diffs) / len(diffs)
        se = (math.sqrt(sum((d - mean) ** 2 for d in diffs) / (len(diffs) - 1) / len(diffs))
              if len(diffs) > 1 else float("nan"))
        ok = mean >= -args.margin
        key = issue_point(point)
        hits[key] += ok
        totals[key] += 1
        print(f"| {point}{' *' if key else ''} | {sum(a) / len(a):.4f} | {sum(b) / len(b):.4f} | {mean:+.4f} | "
              f"{se:.4f} | {'yes' if ok else 'no'} |", flush=True)
    print(f"\nwithin {args.margin} or above: {hits[True]} of the issue's {totals[True]} points (*), "
          f"{hits[False]} of the {totals[False]} others")
    return 0


if __name__ == "__main__":
    sys.exit(main())
