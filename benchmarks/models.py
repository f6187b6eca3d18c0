"""Speed against error of the segmenter's networks (issue #68; docs/training.md "Your own model").

usage: python benchmarks/models.py [--run] [--models metraw,smp_unet_resnet18,...] [--points nominal,...] [--out DIR]

For each network (a ``training.model`` of ``MODELS``) the default study's workflow trains and scores the given points
(default: the nominal and the two ends of the diameter sweep) with the default training budget: the pretraining
across the box and each point's fine-tunes. ``--run`` runs ``snakemake --cores 2 --configfile MODEL.yaml`` for the
points' metrics, one network after the other in this workflow folder (the scenes and emulations are made once: a
changed ``training.model`` reruns only the pretraining, the trainings and the evaluations), and copies each
network's metrics and training logs to ``OUT/<model>/``; without ``--run`` it only reads ``OUT``. It prints, per
network and point, the IoU (mean of the replicates) +- its error (test images and replicate seeds, as the aggregate
takes it: ``metraw.spec.aggregate.iou_measurement``), the replicates' sd, and the CPU seconds of the point's
fine-tune job (its 3 replicates; the job's usage line) and of the pretraining, with the host's CPU model. The
networks' images, batches, epochs and seeds are the same; only metraw's U-Net takes the payload conditioning.
Needs segmentation-models-pytorch for the smp networks (``pip install -e ".[models]"``).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from metraw.progress import parse_usage_line
from metraw.spec.aggregate import iou_measurement

#: The networks compared: name -> training.model
MODELS = {
    "metraw": {"kind": "metraw"},
    "smp_unet_resnet18": {"kind": "smp", "arch": "Unet", "encoder": "resnet18", "encoder_weights": None},
    "smp_unet_mnv3s": {"kind": "smp", "arch": "Unet", "encoder": "timm-mobilenetv3_small_100", "encoder_weights": None},
}
POINTS = ("nominal", "diameter_m-0.1", "diameter_m-0.5")


def cpu_model() -> str:
    """The host's CPU model name (lscpu)."""
    out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    name = next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "?")
    family = next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("CPU family")), "?")
    return f"{name} (family {family})"


def log_cpu_s(path: Path) -> float | None:
    """CPU seconds of the last usage line of a job's log."""
    found = None
    for line in path.read_text(errors="replace").splitlines() if path.is_file() else []:
        found = parse_usage_line(line) or found
    return None if found is None else found[0]


def run(models: list[str], points: list[str], out: Path) -> None:
    """Train and score every network at ``points`` through the workflow; copy its results to ``out/<model>``."""
    targets = [f"results/points/{p}/metrics.json" for p in points]
    for name in models:
        config = out / f"{name}.yaml"
        out.mkdir(parents=True, exist_ok=True)
        config.write_text(yaml.safe_dump({"training": {"model": MODELS[name]}}))
        log = out / f"{name}.snakemake.log"
        with log.open("w") as f:
            proc = subprocess.run(["snakemake", "--cores", "2", "--configfile", str(config), "--", *targets],
                                  stdout=f, stderr=subprocess.STDOUT)
        if proc.returncode:
            sys.exit(f"models.py: snakemake failed for {name} (see {log})")
        folder = out / name
        folder.mkdir(exist_ok=True)
        for p in points:
            shutil.copy2(f"results/points/{p}/metrics.json", folder / f"{p}.metrics.json")
            shutil.copy2(f"logs/train/{p}.log", folder / f"{p}.train.log")
        shutil.copy2("logs/pretrain/RGGB.log", folder / "pretrain.log")


def table(models: list[str], points: list[str], out: Path) -> list[dict]:
    rows = []
    for name in models:
        folder = out / name
        pretrain_s = log_cpu_s(folder / "pretrain.log")
        for p in points:
            path = folder / f"{p}.metrics.json"
            if not path.is_file():
                continue
            metrics = json.loads(path.read_text())
            iou, var = iou_measurement(metrics, str(path))
            rows.append({"model": name, "point": p, "parameters": (metrics.get("network") or {}).get("parameters"),
                         "iou": iou, "iou_sd": math.sqrt(var), "replicate_sd": metrics.get("iou_replicate_sd"),
                         "n_test_images": metrics.get("n_images"),
                         "finetune_cpu_s": log_cpu_s(folder / f"{p}.train.log"), "pretrain_cpu_s": pretrain_s})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", action="store_true", help="train and score the networks first (in this workflow folder)")
    ap.add_argument("--models", default=",".join(MODELS), help="networks, of " + ", ".join(MODELS))
    ap.add_argument("--points", default=",".join(POINTS))
    ap.add_argument("--out", default="benchmarks/models_runs", help="where each network's results go")
    args = ap.parse_args(argv)
    models, points, out = args.models.split(","), args.points.split(","), Path(args.out)
    unknown = sorted(set(models) - set(MODELS))
    if unknown:
        print(f"models.py: unknown network(s) {', '.join(unknown)} (have {', '.join(MODELS)})", file=sys.stderr)
        return 2
    if args.run:
        run(models, points, out)
    rows = table(models, points, out)
    print(f"# CPU: {cpu_model()}")
    print("| network | parameters | point | IoU +- sd | replicate sd | fine-tune CPU s (3 replicates) | pretraining CPU s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['parameters']} | {r['point']} | {r['iou']:.3f} +- {r['iou_sd']:.3f} | "
              f"{r['replicate_sd']:.3f} | {r['finetune_cpu_s']:.0f} | {r['pretrain_cpu_s']:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
