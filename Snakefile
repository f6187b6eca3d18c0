# metraw workflow: source raws -> emulated target raws per parameter point -> segmenter
# training and evaluation -> compression -> Gaussian-process tolerances and figures.
# Run: snakemake --cores all        (workflow/profiles/default applies, via the link profiles/; dvc repro drives the same rules; see dvc.yaml)
# Report: snakemake --report results/report.html (after a run)

import os
import sys
from pathlib import Path

from snakemake.utils import min_version

min_version("9.0")

configfile: "params.yaml"

# DVC stages pass the point(s) they stand for (--config dvc_point=... / dvc_points=...); they are
# checked against params.yaml in workflow/rules/common.smk and are not workflow parameters.
DVC_CHECK = {key: str(config.pop(key)) for key in ("dvc_point", "dvc_points", "dvc_real") if key in config}

# One clear line and exit status 2 for a bad params.yaml (or --config override), before anything is written
# (the output cache folder below included).
from metraw.errors import MetrawError
from metraw.study.points import validate_params, write_effective_params
from metraw.study.sim_to_real import resolve_enabled
from metraw.study.sources import source_files
from metraw.segment.networks import factory_files

try:
    validate_params(config, "params.yaml (with --config overrides)")
    # The files of a raws or photos source (metraw.study.sources): a missing or empty folder is one line here
    SOURCE_FILES = source_files(config, "params.yaml (with --config overrides)")
    # Sim-to-real benchmark (workflow/rules/sim_to_real.smk): on when params.yaml sim_to_real.enabled is true
    # (its real image folder then required) or auto and the folder exists; off when false or absent.
    SIM_TO_REAL = resolve_enabled(config, "params.yaml (with --config overrides)")
    # A python factory's file (training.model; metraw.segment.networks): every training rule takes it as input
    MODEL_FILES = factory_files(config.get("training"), "params.yaml (with --config overrides)")
    if DVC_CHECK.get("dvc_real") and not SIM_TO_REAL:
        missing = (config.get("sim_to_real") or {}).get("path")
        raise MetrawError(
            f"dvc.yaml's sim-to-real stage needs the real image folder {missing!r}, which does not exist (or "
            "sim_to_real is off): set sim_to_real.enabled to false and regenerate dvc.yaml with "
            "`python workflow/scripts/dvc_yaml.py`")
except MetrawError as exc:
    sys.stderr.write(f"metraw workflow: error: {exc}\n")
    sys.exit(2)

# The configuration the rules run with (params.yaml merged with --config/--configfile), written where
# every `metraw ... --params` reads it, so an override reaches the commands and not only the DAG.
# Rewritten only when its content changes; its path never changes, so no command string changes with it.
PARAMS_FILE = write_effective_params(config, Path(".snakemake") / "metraw" / "params.yaml")

# Between-workflow output cache (--cache, on in profiles/default): the aggregate comes back from it when a sweep
# value is reverted. Default location .snakemake-cache/ next to this file (ignored by git and DVC); a
# SNAKEMAKE_OUTPUT_CACHE set by the user wins. Snakemake creates no cache folder itself.
if workflow.enable_cache:
    Path(os.environ.setdefault("SNAKEMAKE_OUTPUT_CACHE", str(Path(workflow.basedir) / ".snakemake-cache"))).mkdir(
        parents=True, exist_ok=True)

# Every metraw command of the jobs ends its log with one line of the CPU, wall time and peak memory it used
# (metraw.progress.usage_line); benchmarks/main_job.py sums them per rule. The jobs inherit this environment.
os.environ.setdefault("METRAW_USAGE_LOG", "1")

report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"


# a point wildcard is one of the parameter points (common.smk), so no rule's pattern swallows another's
wildcard_constraints:
    point="|".join(re.escape(p) for p in dict.fromkeys(POINTS + SCREEN_POINTS)),


include: "workflow/rules/source.smk"
include: "workflow/rules/emulate.smk"
include: "workflow/rules/segment.smk"
include: "workflow/rules/aggregate.smk"
if SIM_TO_REAL:
    include: "workflow/rules/sim_to_real.smk"


rule all:
    input:
        "results/source/calibration.json",
        "results/source/metrics.json",
        "results/spec.yaml",
        "results/aggregate.json",
        SIM_TO_REAL_METRICS,
