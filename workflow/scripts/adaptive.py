"""The adaptive sweep's driver (issue #70; docs/statistics.md "An adaptive sweep"): Snakemake once per round.

    python workflow/scripts/adaptive.py --cores all --configfile my.yaml      (my.yaml: target.adaptive.enabled: true)

Round R: write the points chosen so far to results/adaptive/chosen.yaml (``target.adaptive.chosen``), run Snakemake
with it as the last ``--configfile`` for every point's metrics.json (the points: `metraw.study.points.parameter_points`,
so each trained point is an ordinary Snakemake target, cached by its name as in the listed study), fit the IoU GP and
choose the next points (`metraw.spec.adaptive.plan_round`), write results/adaptive/round_R.json; until the record says
stop. Then one Snakemake run of the whole workflow (compression, the sim-to-real scores, the aggregate: spec.yaml,
figures) on every point trained. The choices are recomputed from the points' metrics on every run (one BLAS thread,
the GP seeded: same metrics, same choices), so running it again replays the rounds with zero jobs each, and a
larger budget replays them and adds rounds on top. Arguments other than --configfile go to every Snakemake run.

Why a driver and not a checkpoint per round: each run is an ordinary static DAG of the listed study's rules, so the
dry run, the SLURM profile, the output cache and every rule's up-to-date check work as they do for the listed points;
a chain of checkpoints would need a rule per round whose inputs are all earlier rounds' points, re-evaluated on every
DAG build, and the choice (a GP fit) would run inside Snakemake's DAG evaluation.
"""

from __future__ import annotations

import argparse
import copy
import json
import re
import subprocess
import sys
from pathlib import Path

import yaml

from metraw.atomic import atomic_path
from metraw.errors import MetrawError, read_yaml

ADAPTIVE_DIR = Path("results/adaptive")
CHOSEN_FILE = ADAPTIVE_DIR / "chosen.yaml"
METRICS = "results/points/{point}/metrics.json"


def merged_config(configfiles: list[str]) -> dict:
    """params.yaml updated by each config file in turn, nested keys merged (as Snakemake's --configfile does)."""
    from snakemake.utils import update_config

    config = read_yaml(Path("params.yaml"), "parameter file")
    for f in configfiles:
        update_config(config, read_yaml(Path(f), "config file") or {})
    return config


def _write_if_changed(path: Path, text: str) -> None:
    if not path.is_file() or path.read_text() != text:
        with atomic_path(path, overwrite=True) as tmp:
            tmp.write_text(text)


def snakemake(args: list[str], configfiles: list[str], targets: list[str]) -> int:
    """Run Snakemake (its output passed on) and return how many jobs it ran (its job-stats total; 0 when nothing was
    to be done)."""
    cmd = [sys.executable, "-m", "snakemake", *args, "--configfile", *configfiles, str(CHOSEN_FILE),
           *(["--", *targets] if targets else [])]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    jobs = 0
    for line in proc.stdout:
        sys.stderr.write(line)
        m = re.match(r"^total\s+(\d+)\s*$", line.strip())
        if m:
            jobs = max(jobs, int(m.group(1)))
    if proc.wait() != 0:
        raise SystemExit(f"adaptive: snakemake failed ({proc.returncode}): {' '.join(cmd)}")
    return jobs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configfile", "--configfiles", nargs="+", default=[], dest="configfiles")
    ours, passed = parser.parse_known_args(argv)
    try:
        from threadpoolctl import threadpool_limits

        from metraw.spec.adaptive import plan_round
        from metraw.spec.aggregate import box_model_scores, load_point_results
        from metraw.spec.screening import DEFAULT_SCREEN, screened_rows
        from metraw.study.pretraining import pretrain_settings
        from metraw.study.points import adaptive_settings, parameter_points, screen_points, validate_params

        config = merged_config(ours.configfiles)
        config.setdefault("target", {}).setdefault("adaptive", {})["chosen"] = []
        validate_params(config, "params.yaml (with --configfile)")
        if not adaptive_settings(config)["enabled"]:
            raise MetrawError("target.adaptive.enabled is false: set it in a config file (the listed study runs with "
                              "plain snakemake)")
        if adaptive_settings(config)["screen"] and not pretrain_settings(config)["enabled"]:
            raise MetrawError("target.adaptive.screen scores the pretrained box model: it needs "
                              "training.pretrain.enabled: true")
        chosen: list[list[dict]] = []
        total_jobs = 0
        for r in range(10_000):
            config["target"]["adaptive"]["chosen"] = copy.deepcopy(chosen)
            validate_params(config, f"round {r}")
            _write_if_changed(CHOSEN_FILE, yaml.safe_dump({"target": {"adaptive": {"chosen": chosen}}}, sort_keys=False))
            points = list(parameter_points(config))
            screens = [DEFAULT_SCREEN.format(results="results", point=p) for p in screen_points(config)]
            jobs = snakemake(passed, ours.configfiles, [METRICS.format(point=p) for p in points] + screens)
            total_jobs += jobs
            rows = load_point_results(config, "results", METRICS.replace("results/", "{results}/"), "")
            screened, screening = screened_rows(config, box_model_scores(config, "results"), rows)
            with threadpool_limits(limits=1):
                record = plan_round(config, rows, r, screened=screened, screening=screening)
            _write_if_changed(ADAPTIVE_DIR / f"round_{r}.json", json.dumps(record, indent=2) + "\n")
            print(f"adaptive round {r}: {len(points)} points trained"
                  + (f", {len(screened)} more scored by the box model alone" if screening else "")
                  + f" ({jobs} jobs run); widest doubt "
                  + ", ".join(f"{n} {v['widest']:.3f}" for n, v in record["lines"].items())
                  + (f"; stop: {record['stop']['reason']}" if record["stop"]["stopped"] else
                     "; next: " + ", ".join(c["name"] for c in record["chosen"])), file=sys.stderr)
            if record["stop"]["stopped"]:
                break
            chosen.append([c["overrides"] for c in record["chosen"]])
        for old in ADAPTIVE_DIR.glob("round_*.json"):  # a smaller budget than last time: its later rounds are gone
            if int(old.stem.split("_")[1]) > r:
                old.unlink()
        jobs = snakemake(passed, ours.configfiles, [])
        total_jobs += jobs
        print(f"adaptive: {len(points)} points in {r + 1} rounds; the whole workflow ran {jobs} jobs, "
              f"{total_jobs} in all", file=sys.stderr)
    except MetrawError as exc:
        sys.stderr.write(f"metraw adaptive: error: {exc}\n")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
