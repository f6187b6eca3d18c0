"""The adaptive sweep's rule (metraw.spec.adaptive, issue #70) on a noisy synthetic IoU curve with a known crossing:
how many trained points it takes to know the crossing to the stop width, against the uniform grid of that
resolution. No training: each "trained point" is the curve plus seeded normal noise of a stated sd, read as the
aggregate reads a point's IoU; the rounds run as the driver (workflow/scripts/adaptive.py) runs them.

    python benchmarks/adaptive_synthetic.py [--figure docs/figures/adaptive_synthetic.png]

Prints a row per (stop width, points per round, seed): points trained, rounds, the GP mean's crossing and its error,
the widest stretch of doubt left; writes the figure of one sweep (stop width 0.05, 2 points a round, seed 0).
The curve: IoU(f) = 0.05 + 0.25 / (1 + exp((f - 1.5 m) / 0.12 m)) over f = 0.8-2.0 m (nominal 1.644 m), noise sd
0.004 (about a default-study point's IoU sd), required IoU 0.15: the crossing is at 1.5 + 0.12 ln 1.5 = 1.5487 m.
"""

from __future__ import annotations

import argparse
import copy
import math
import tempfile
from pathlib import Path

import numpy as np
import yaml

from metraw.spec import adaptive
from metraw.study.points import parameter_points, point_rounds

REPO = Path(__file__).resolve().parents[1]
REQUIRED = 0.15
NOISE_SD = 0.004
CROSSING_M = 1.5 + 0.12 * math.log(1.5)


def iou_curve(f: float) -> float:
    return 0.05 + 0.25 / (1.0 + math.exp((f - 1.5) / 0.12))


def params_for(width: float, per_round: int, budget: int = 40) -> dict:
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["target"]["sweeps"] = {"focal_length_m": [0.8, 2.0]}
    params["target"].pop("grids", None)
    params["target"]["adaptive"] = {"enabled": True, "budget": budget, "points_per_round": per_round,
                                    "stop_width": width, "line_candidates": 81}
    params["spec"]["required_iou"] = REQUIRED
    return params


def measure(params: dict, seed: int) -> list[dict]:
    rows = []
    for name, overrides in parameter_points(params).items():
        f = float(overrides.get("focal_length_m", params["target"]["nominal"]["focal_length_m"]))
        noise = np.random.default_rng([seed, int(round(f * 1e6))]).normal(0.0, NOISE_SD)
        rows.append({"point": name, "focal_length_m": f, "iou": iou_curve(f) + noise, "iou_sd": NOISE_SD})
    return rows


def sweep(params: dict, seed: int) -> tuple[dict, list[dict]]:
    params = copy.deepcopy(params)
    records = []
    while True:
        record = adaptive.plan_round(params, measure(params, seed), len(records))
        records.append(record)
        if record["stop"]["stopped"]:
            return params, records
        params["target"]["adaptive"].setdefault("chosen", []).append([c["overrides"] for c in record["chosen"]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--figure", default="")
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    print("| stop width | per round | seed | uniform grid | points trained | rounds | crossing found [m] | error [m] "
          "| widest doubt |")
    print("|---|---|---|---|---|---|---|---|---|")
    for width in (0.1, 0.05, 0.02):
        for per_round in (1, 2):
            for seed in range(args.seeds):
                _, records = sweep(params_for(width, per_round), seed)
                last = records[-1]
                line = last["lines"]["focal_length_m"]
                found = line["mean_crossings"][0] if len(line["mean_crossings"]) == 1 else float("nan")
                print(f"| {width:g} | {per_round} | {seed} | {round(1 / width) + 1} | {last['n_trained']} | "
                      f"{len(records)} | {found:.4f} | {found - CROSSING_M:+.4f} | {line['widest']:.3f} |")
    if args.figure:
        params, records = sweep(params_for(0.05, 2), 0)
        model, _, at = adaptive.fit_iou(params, measure(params, 0))
        with tempfile.TemporaryDirectory() as tmp:
            (path,) = adaptive.round_figures(model, measure(params, 0), point_rounds(params), at, REQUIRED, tmp)
            Path(args.figure).write_bytes(path.read_bytes())
        print(f"wrote {args.figure}: {records[-1]['n_trained']} points in {len(records)} rounds")


if __name__ == "__main__":
    main()
