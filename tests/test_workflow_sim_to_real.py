"""The sim-to-real benchmark in the workflow, without the repository's data/real: a fake real folder made in the test
(small 8-bit PNGs with YOLO boxes and an aerial.names, `fake_real_folder`) stands in for KIT AIS.

Dry runs (seconds): with the folder the job list holds real_store, emulate_real and evaluate_real per point
and evaluate_source_real, and the aggregate's command reads their metrics; ``enabled: auto`` without the
folder gives none of them (the chain's jobs only); ``enabled: true`` without it is one error line and exit
status 2. dvc.yaml holds the same stages. One real run (marked workflow, ~1 min) makes the nominal point's
real metrics and the drone-resolution reference's from the fake photos.
"""

from __future__ import annotations

import collections
import json
import re
from pathlib import Path

import pytest

from workflow_workspace import fake_real_folder, make_workspace, needs_tools, sim_to_real_params, tiny_params
from workflow_workspace import run as _run

POINTS = ("nominal", "focal_length_m-1.2", "diameter_m-0.35", "exposure_s-0.0003")
REAL_RULES = ("real_store", "emulate_real", "evaluate_real", "evaluate_source_real")


def _dry(root: Path, *targets: str) -> tuple[collections.Counter, str]:
    """Jobs of a dry run ('rule' or 'rule[point]', without 'all') and its printed shell commands."""
    proc = _run(["snakemake", "--cores", "2", "--dry-run", "--printshellcmds", "--", *targets], root)
    jobs = collections.Counter()
    for m in re.finditer(r"^(?:local)?rule (\w+):\n((?:[ \t]+.*\n?)*)", proc.stdout, flags=re.M):
        if m.group(1) != "all":
            point = re.search(r"wildcards: point=(\S+)", m.group(2))
            jobs[f"{m.group(1)}[{point.group(1)}]" if point else m.group(1)] += 1
    return jobs, proc.stdout


def _chain_jobs() -> collections.Counter:
    jobs = collections.Counter({"source_store": 1, "decode_store": 1, "calibrate_source": 1, "train_source": 1,
                                "evaluate_source": 1, "pretrain_scenes": 1, "pretrain": 1, "aggregate": 1})
    jobs.update({f"{rule}[{p}]": 1 for rule in ("emulate", "train", "evaluate", "compress") for p in POINTS})
    return jobs


def _real_jobs() -> collections.Counter:
    jobs = collections.Counter({"real_store": 1, "decode_store": 1, "evaluate_source_real": 1})
    jobs.update({f"{rule}[{p}]": 1 for rule in ("emulate_real", "evaluate_real") for p in POINTS})
    return jobs


@needs_tools
@pytest.mark.parametrize("enabled", [True, "auto"])
def test_dry_run_lists_the_real_jobs(tmp_path, enabled):
    fake_real_folder(tmp_path / "real")
    root = make_workspace(tmp_path, sim_to_real_params(tiny_params(), "real", enabled))
    jobs, text = _dry(root)
    assert jobs == _chain_jobs() + _real_jobs(), jobs
    # the real store is ingested like the kit_ais source; each point's emulation has the emulate rule's flags, but
    # emulates every real image (the synthetic store holds the test split only: training draws from the source)
    assert re.search(r"metraw ingest real --labels yolo --camera \S+ --gsd-m 0.135 --white-fraction 1.0 --seed 0 "
                     r"--out data/real.zarr --codec-step 1.0 --codec-seed 0", text), text
    # each emulation reads its store's decoded working copy (rule decode_store)
    assert re.search(r"metraw decode data/source.zarr data/source.decoded.zarr --threads 1 2>", text), text
    assert re.search(r"metraw decode data/real.zarr data/real.decoded.zarr --threads 1 2>", text), text
    emulate = re.search(r"metraw emulate data/source.decoded.zarr results/points/nominal/target.zarr (.*?) 2>",
                        text).group(1)
    assert "--images test" in emulate
    assert (f"metraw emulate data/real.decoded.zarr results/points/nominal/real.zarr "
            f"{emulate.replace('--images test', '--images all')} 2>") in text
    assert ("metraw evaluate results/points/nominal/real.zarr --model results/points/nominal/model --split all "
            "--out results/points/nominal/real_metrics.json") in text
    assert ("metraw evaluate data/real.zarr --model results/source/model --split all "
            "--out results/source/real_metrics.json") in text
    assert "--real-metrics-pattern 'results/points/{point}/real_metrics.json'" in text
    # DVC: the same stages (one per rule per point), the aggregate depending on their metrics
    stages = _run(["dvc", "stage", "list"], root).stdout
    for rule in REAL_RULES[1:3]:
        assert len(re.findall(rf"^{rule}_\S+\s+Outputs results/points/[^/]+/real", stages, flags=re.M)) == len(POINTS)
    assert re.search(r"^real_store\s", stages, flags=re.M) and re.search(r"^evaluate_source_real\s", stages, re.M)


@needs_tools
def test_auto_without_the_folder_runs_no_real_job(tmp_path):
    root = make_workspace(tmp_path, sim_to_real_params(tiny_params(), "no_such_folder", "auto"))
    jobs, text = _dry(root)
    assert jobs == _chain_jobs(), jobs
    assert "real" not in " ".join(jobs) and "--real-metrics-pattern" not in text


@needs_tools
def test_true_without_the_folder_is_one_error_line(tmp_path):
    root = make_workspace(tmp_path, sim_to_real_params(tiny_params(), "no_such_folder", True))
    proc = _run(["snakemake", "--cores", "1", "--dry-run"], root, check=False)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if not line.startswith("Using workflow specific profile")]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("metraw workflow: error: params.yaml") and "'no_such_folder' does not exist" in lines[0]
    assert not (root / ".snakemake" / "metraw").exists()  # refused before the effective params are written


@needs_tools
@pytest.mark.workflow
def test_real_path_runs_on_fake_photos(tmp_path):
    """Nominal point and source reference on 3 fake photos: ingest, emulate, score on all images."""
    fake_real_folder(tmp_path / "real")
    root = make_workspace(tmp_path, sim_to_real_params(tiny_params(), "real"))
    targets = ["results/points/nominal/real_metrics.json", "results/source/real_metrics.json"]
    _run(["snakemake", "--cores", "2", "--", *targets], root)
    point = json.loads((root / targets[0]).read_text())
    source = json.loads((root / targets[1]).read_text())
    for m in (point, source):
        assert m["n_images"] == 3 and m["split"] == "all (foreign store)" and m["labels"] == "box-approximate"
        assert 0 <= m["iou"] <= 1 and len(m["per_image"]) == 3
    # the point's real images are emulated to the model's own ground sampling; the drone photos are resampled
    assert {r["gsd_scale"] for r in point["per_image"]} == {1.0}
    assert all(r["gsd_scale"] != 1.0 for r in source["per_image"])
    assert _dry(root, *targets)[0] == {}
