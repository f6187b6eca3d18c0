"""Issue #15's acceptance targets, read from a finished workflow run's aggregate and specification.

    python benchmarks/segmentation_targets.py [--results results]

Reads ``results/aggregate.json`` and ``results/spec.yaml`` (nothing is recomputed or written) and prints, per target,
the run's value, the target, whether it is met and by how much it is missed:

- the nominal's IoU >= 0.30 and the diameter 0.5 m point's >= 0.35;
- every point's standard error (replicates and test images, the GP's per-point noise) <= 0.015;
- the IoU monotone along the one-at-a-time diameter line and the focal-length line over 0.8-2.0 m, the nominal
  included: each step down no larger than 2 standard errors of the difference (sds in quadrature);
- ``spec.required_iou`` >= 0.25 with a non-empty specification (every continuous parameter has a tolerance), and
  the highest requirement the run's specification would meet everywhere (the lowest GP lower bound at the
  parameters' optima);
- the GP's leave-one-out share inside 2 sigma >= 0.85.

The robust model's target (within 0.02 at 8 of the 10 points) needs the models themselves:
``python benchmarks/robust.py --results results``. Exit status 0 whether or not the targets are met.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import yaml

from metraw.study.points import same_value

NOMINAL_IOU, DIAMETER_05_IOU, MAX_SD, REQUIRED_IOU, LOO_SHARE = 0.30, 0.35, 0.015, 0.25, 0.85
FOCAL_RANGE_M = (0.8, 2.0)


def line(points: list[dict], nominal: dict, name: str) -> list[dict]:
    """The one-at-a-time line of ``name`` through the nominal (the nominal included), sorted by its value: every
    other parameter nominal (``metraw.study.points.same_value``, as the aggregate's own lines)."""
    on_line = [p for p in points if all(same_value(p[k], nominal[k]) for k in nominal if k != name)]
    return sorted(on_line, key=lambda p: p[name])


def worst_step(points: list[dict]) -> tuple[float, float]:
    """(largest fall of IoU between neighbours in units of the difference's sd, that fall) along ``points``."""
    worst = (-math.inf, 0.0)
    for a, b in zip(points, points[1:]):
        fall = a["iou"] - b["iou"]
        worst = max(worst, (fall / math.hypot(a["iou_sd"], b["iou_sd"]), fall))
    return worst


def rows(aggregate: dict, spec: dict) -> list[tuple[str, str, str, bool, str]]:
    """(target, run's value, wanted, met, shortfall) for every target the aggregate answers."""
    points, nominal = aggregate["points"], aggregate["nominal"]
    by_name = {p["point"]: p for p in points}
    nominal_iou = by_name["nominal"]["iou"]
    d_line = line(points, nominal, "diameter_m")
    d05 = [p for p in d_line if same_value(p["diameter_m"], 0.5)]
    f_line = [p for p in line(points, nominal, "focal_length_m")
              if FOCAL_RANGE_M[0] <= p["focal_length_m"] <= FOCAL_RANGE_M[1]]
    sd_max = max(points, key=lambda p: p["iou_sd"])
    continuous = {k: v for k, v in spec["parameters"].items() if "allowed" not in v}
    weakest = min(continuous, key=lambda k: continuous[k]["iou_lower_2sigma_at_optimal"])
    empty = sorted(k for k, v in continuous.items() if not v["meets_requirement"])
    loo = aggregate["iou_gp"]["leave_one_out"]
    out = [("nominal IoU", f"{nominal_iou:.3f}", f">= {NOMINAL_IOU}", nominal_iou >= NOMINAL_IOU,
            f"{NOMINAL_IOU - nominal_iou:.3f}")]
    if d05:
        iou = d05[0]["iou"]
        out.append(("diameter 0.5 m IoU", f"{iou:.3f}", f">= {DIAMETER_05_IOU}", iou >= DIAMETER_05_IOU,
                    f"{DIAMETER_05_IOU - iou:.3f}"))
    out.append(("largest standard error", f"{sd_max['iou_sd']:.4f} ({sd_max['point']})", f"<= {MAX_SD}",
                sd_max["iou_sd"] <= MAX_SD, f"{sd_max['iou_sd'] - MAX_SD:.4f}"))
    for name, pts in (("diameter", d_line), ("focal length 0.8-2.0 m", f_line)):
        z, fall = worst_step(pts)
        values = " / ".join(f"{p['iou']:.3f}" for p in pts)
        out.append((f"monotone in {name}", f"{values} (worst fall {fall:+.3f}, {z:.1f} sd)", "fall <= 2 sd",
                    z <= 2.0, f"{z - 2.0:.1f} sd"))
    req = spec["required_iou"]
    out.append(("spec.required_iou, non-empty spec", f"{req} ({'empty: ' + ', '.join(empty) if empty else 'non-empty'})",
                f">= {REQUIRED_IOU}, non-empty", req >= REQUIRED_IOU and not empty, f"{REQUIRED_IOU - req:.3f}"))
    lower = continuous[weakest]["iou_lower_2sigma_at_optimal"]
    out.append(("highest requirement a non-empty spec meets", f"{lower:.3f} ({weakest})", f">= {REQUIRED_IOU}",
                lower >= REQUIRED_IOU, f"{REQUIRED_IOU - lower:.3f}"))
    share = loo["share_inside"]
    out.append(("leave-one-out inside 2 sigma", f"{share:.2f} ({round(share * loo['n'])} of {loo['n']})",
                f">= {LOO_SHARE}", share >= LOO_SHARE, f"{LOO_SHARE - share:.2f}"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results", help="the workflow's results directory")
    args = ap.parse_args(argv)
    results = Path(args.results)
    try:
        aggregate = json.loads((results / "aggregate.json").read_text())
        spec = yaml.safe_load((results / "spec.yaml").read_text())
    except (OSError, ValueError, yaml.YAMLError) as exc:
        ap.exit(2, f"segmentation_targets: error: cannot read the run's aggregate and spec in {results}: {exc}\n")
    print(f"{'target':44s} {'run':58s} {'wanted':26s} met  short by")
    for target, value, wanted, met, short in rows(aggregate, spec):
        print(f"{target:44s} {value:58s} {wanted:26s} {'yes' if met else 'NO ':3s}  {'' if met else short}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
