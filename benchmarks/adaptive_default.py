"""Issue #70's acceptance: an adaptive run of the default study against the listed (fixed) run.

    python benchmarks/adaptive_default.py --fixed RUN_DIR --adaptive RUN_DIR

RUN_DIR: a folder the workflow ran in (``snakemake --cores all`` for the fixed run; ``python
workflow/scripts/adaptive.py --cores all --configfile workflow/config/adaptive.yaml`` for the adaptive one). The fixed
run's IoU GP is refitted from its ``results/aggregate.json`` points and its effective params as the aggregate fits
it (`metraw.spec.adaptive.fit_iou`: the same rows, variances and seed, so the same GP). For every tolerance end of
either run set by the requirement, it prints the fixed run's end and the stretch of the line where the fixed GP's
2-sigma band holds ``required_iou`` (`metraw.spec.adaptive.line_bands`: where the fixed run cannot tell the side of
the requirement), the adaptive run's end, and whether it lies inside; then each run's trained points, each screened
row (box model + offset) against the fixed run's fine-tuned IoU at the same point, and the CPU of its fine-tunes and
of all its jobs (`benchmarks/main_job.py`: the adaptive run's Snakemake logs, one per round and the whole
workflow's, taken as one run). Nothing is written.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main_job():
    spec = importlib.util.spec_from_file_location("metraw_main_job", HERE / "main_job.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def compare(fixed: dict, adaptive: dict, params: dict) -> list[dict]:
    """Per parameter and end: the fixed end, its band stretch, the adaptive end, inside or not. ``params``: the fixed
    run's effective params; its IoU GP is refitted from its aggregate.json points as the aggregate fits it
    (`metraw.spec.adaptive.fit_iou`: the same rows, variances and seed)."""
    from metraw.spec.adaptive import fit_iou, line_bands, nearest_stretch

    model, _, at = fit_iou(params, fixed["points"])
    level = float(fixed["required_iou"])
    out = []
    for name in model.names:
        ax = model.axes[model.names.index(name)]
        band, _ = line_bands(model, name, at, level)
        f, a = fixed["tolerances"][name], adaptive["tolerances"].get(name)
        for side in ("min", "max"):
            fb, ab = f[f"{side}_limited_by"], a[f"{side}_limited_by"] if a else None
            if "requirement" not in (fb, ab):
                continue
            where = a[side] if ab == "requirement" else f[side]
            near = nearest_stretch(band, float(ax.to_unit(where))) if where is not None else None
            inside = (ab == "requirement" and near is not None and near["low"] <= a[side] <= near["high"])
            out.append({"parameter": name, "end": side, "fixed": f[side], "fixed_by": fb, "band": near,
                        "adaptive": a[side] if a else None, "adaptive_by": ab, "inside": inside})
    return out


def screening_check(fixed: dict, adaptive: dict) -> list[dict]:
    """Each screened row of the adaptive run (box model + offset, its stated sd) against the fixed run's fine-tuned
    IoU at the same point (trained there): difference and z = difference / sqrt(sd_screened^2 + sd_fixed^2)."""
    trained = {r["point"]: r for r in fixed["points"]}
    out = []
    for r in (adaptive.get("screening") or {}).get("rows", []):
        f = trained.get(r["point"])
        if f is not None:
            d = r["iou"] - f["iou"]
            out.append({"point": r["point"], "screened": r["iou"], "screened_sd": r["iou_sd"], "fixed": f["iou"],
                        "fixed_sd": f["iou_sd"], "difference": d, "z": d / float(np.hypot(r["iou_sd"], f["iou_sd"]))})
    return out


def cpu(folder: Path, logs: list[str]) -> dict:
    s = main_job().summary(logs, folder)
    rules = s["cpu_per_rule"]
    return {"cpu": s["cpu"]["model"], "isa": s["cpu"]["isa"], "wall_s": s["wall_s"],
            "train_cpu_s": rules.get("train", {}).get("cpu_s"), "train_jobs": rules.get("train", {}).get("jobs"),
            "all_cpu_s": sum(r["cpu_s"] for r in rules.values()), "jobs": s["jobs"],
            "no_usage": sum(r["no_data"] for r in rules.values())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fixed", required=True, help="folder of the listed study's run")
    ap.add_argument("--adaptive", required=True, help="folder of the adaptive run")
    args = ap.parse_args(argv)
    runs = {k: Path(getattr(args, k)) for k in ("fixed", "adaptive")}
    agg = {}
    for k, folder in runs.items():
        path = folder / "results" / "aggregate.json"
        if not path.is_file():
            print(f"adaptive_default.py: {path} is missing: run the {k} study there first", file=sys.stderr)
            return 2
        agg[k] = json.loads(path.read_text())
    if not agg["adaptive"].get("adaptive"):
        print(f"adaptive_default.py: {runs['adaptive']} holds a listed run, not an adaptive one", file=sys.stderr)
        return 2
    from metraw.study.points import load_params

    effective = runs["fixed"] / ".snakemake" / "metraw" / "params.yaml"  # the params the run used (Snakefile)
    rows = compare(agg["fixed"], agg["adaptive"], load_params(effective if effective.is_file()
                                                              else runs["fixed"] / "params.yaml"))
    print(f"required IoU {agg['fixed']['required_iou']}; fixed run's 2-sigma band crossing vs the adaptive end\n")
    print("| parameter | end | fixed (limited by) | fixed GP +-2 sigma holds the requirement | adaptive (limited by) | "
          "inside |\n|---|---|---|---|---|---|")
    for r in rows:
        band = f"{r['band']['low']:.4g} - {r['band']['high']:.4g}" if r["band"] else "none"
        fmt = (lambda v: "none" if v is None else f"{v:.4g}")
        print(f"| {r['parameter']} | {r['end']} | {fmt(r['fixed'])} ({r['fixed_by']}) | {band} | "
              f"{fmt(r['adaptive'])} ({r['adaptive_by']}) | {'yes' if r['inside'] else 'NO'} |")
    print(f"\n{sum(r['inside'] for r in rows)} of {len(rows)} ends inside")
    a = agg["adaptive"]["adaptive"]
    print(f"trained points: fixed {len(agg['fixed']['points'])}, adaptive {len(agg['adaptive']['points'])} "
          f"(rounds: {a['rounds']}); screened (box model only): "
          f"{len((agg['adaptive'].get('screening') or {}).get('rows', []))}")
    if agg["adaptive"].get("screening"):
        s = agg["adaptive"]["screening"]
        print(f"screening offset (fine-tuned - box) {s['offset']:+.4f}, sd {s['offset_sd']:.4f} "
              f"({s['offset_sd_from']}, {s['n_pairs']} pairs)")
    checks = screening_check(agg["fixed"], agg["adaptive"])
    if checks:
        print("\nscreened rows (box model + offset) against the fixed run's fine-tuned IoU at the same point:\n")
        print("| point | screened | fixed (fine-tuned) | difference | z |\n|---|---|---|---|---|")
        for c in checks:
            print(f"| {c['point']} | {c['screened']:.3f} +- {c['screened_sd']:.3f} | {c['fixed']:.3f} +- "
                  f"{c['fixed_sd']:.3f} | {c['difference']:+.3f} | {c['z']:+.2f} |")
        z = np.array([c["z"] for c in checks])
        print(f"\n|z| <= 2 at {int((np.abs(z) <= 2).sum())} of {len(z)}; mean z {z.mean():+.2f}, sd of z "
              f"{z.std(ddof=1) if len(z) > 1 else float('nan'):.2f} (1 if the stated errors hold and are independent)")
    print()
    for k, folder in runs.items():
        logs = sorted(glob.glob(str(folder / ".snakemake" / "log" / "*.snakemake.log")))
        if k == "fixed":
            logs = logs[-1:]
        c = cpu(folder, logs)
        print(f"{k}: {c['cpu']} ({c['isa']}): fine-tunes {c['train_cpu_s']:.0f} CPU-s ({c['train_jobs']} jobs), all "
              f"jobs {c['all_cpu_s']:.0f} CPU-s ({c['jobs']} jobs, {c['no_usage']} without a usage line), wall "
              f"{c['wall_s'] / 60:.1f} min ({len(logs)} Snakemake log(s))")
    return 0


if __name__ == "__main__":
    sys.exit(main())
