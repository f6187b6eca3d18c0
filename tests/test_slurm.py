"""The sweep through a real SLURM (workflow/profiles/slurm), byte for byte the results of a local run.

A single-node SLURM on this machine (workflow/scripts/local_slurm.sh: slurmctld + slurmd on localhost, munge;
installed with apt-get when missing, so it needs root) runs the tiny sweep of tests/workflow_workspace.py:
workspace B with ``snakemake --workflow-profile workflow/profiles/slurm`` (the workspace's copy of the profile),
workspace A with ``snakemake --cores 2`` (profiles/default), side by side. Then:

* every job of B went through sbatch: each SLURM job id the run reports has a COMPLETED line in SLURM's own
  job completion records (jobcomp/filetxt, the file ``sacct -c`` reads) with B as its working directory, and
  ``scontrol show job`` gives its Comment ``rule_<rule>...``: every rule of the sweep but ``all`` (a local rule);
* every file under results/ and data/ of B is byte-identical to A's (sha256; symlinks followed) -- the
  only files B has beyond A's are Snakemake's empty ``.snakemake_timestamp`` markers in the aggregate's
  directory outputs (figures/, plots/): A's aggregate goes through the between-workflow output cache of
  profiles/default (the outputs become symlinks into it, without markers); Snakemake's cache works only for
  jobs it runs itself, so under SLURM the aggregate runs as a plain job.

The local cluster's settings the profile leaves to the user are passed here: no account
(``--slurm-no-account``), job states from squeue (no accounting database: ``--slurm-status-command squeue``),
a short first status check, and the SLURM logs kept for a failure's message.

Marker ``slurm``, left out of the default ``python3 -m pytest -q`` (pyproject addopts): installing SLURM and
running 21 jobs through it takes 4-7 min on 2 shared cores, beyond the test budget (docs/benchmarks.md). Run it with
``python3 -m pytest -m slurm tests/test_slurm.py``. Skipped with the reason when SLURM cannot be started
(not root, no apt-get, no package source, daemons refusing) or the executor plugin is not installed
(``pip install -e '.[slurm]'``).
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import time
from pathlib import Path

import pytest

from workflow_workspace import REPO, file_digests, make_workspace, needs_tools, run, tiny_params, workflow_env

pytestmark = [pytest.mark.slurm, pytest.mark.workflow, needs_tools]

START = REPO / "workflow" / "scripts" / "local_slurm.sh"
LOCAL = ["snakemake", "--cores", "2"]
SLURM = ["snakemake", "--workflow-profile", "workflow/profiles/slurm",
         # the local cluster has no accounts and no accounting database (see local_slurm.sh)
         "--slurm-no-account", "--slurm-status-command", "squeue",
         "--slurm-init-seconds-before-status-checks", "2", "--slurm-keep-successful-logs"]
COMPARED = ("results", "data")
#: Snakemake's marker in directory outputs it did not take from the output cache (see the docstring)
MARKER = ".snakemake_timestamp"
SUBMITTED = re.compile(r"Job \d+ has been submitted with SLURM jobid (\d+) \(log: [^)]*/rule_(\w+)/")


def digests(root: Path) -> dict[str, str]:
    return {f"{sub}/{name}": d for sub in COMPARED if (root / sub).is_dir()
            for name, d in file_digests(root / sub).items()}


@pytest.fixture(scope="module")
def slurm_cluster() -> dict[str, str]:
    """Start (or find running) the local single-node SLURM; skip with its reason when that cannot be done."""
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        pytest.skip("snakemake-executor-plugin-slurm is not installed (pip install -e '.[slurm]')")
    try:
        proc = subprocess.run(["bash", str(START)], capture_output=True, text=True, timeout=900)
    except subprocess.TimeoutExpired:
        pytest.skip("SLURM could not be started: local_slurm.sh took over 15 min (apt-get without network?)")
    if proc.returncode != 0:
        pytest.skip(f"SLURM could not be started (local_slurm.sh exit {proc.returncode}): "
                    f"{proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.stdout[-300:]}")
    config = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, check=True).stdout
    settings = dict(re.findall(r"^(\w+)\s*=\s*(.*?)\s*$", config, flags=re.M))
    return {"started": proc.stderr.strip(), "jobcomp": settings.get("JobCompLoc", ""),
            "jobcomp_type": settings.get("JobCompType", "")}


def job_records(jobcomp: Path, ids: set[str]) -> dict[str, dict[str, str]]:
    """SLURM's job completion lines (jobcomp/filetxt: ``Key=Value`` fields) of the given job ids."""
    records = {}
    for line in jobcomp.read_text().splitlines():
        fields = dict(re.findall(r"(\w+)=(\S*)", line))
        if fields.get("JobId") in ids:
            records[fields["JobId"]] = {**fields, "line": line}
    return records


def job_comment(job_id: str) -> str:
    out = subprocess.run(["scontrol", "show", "job", "-o", job_id], capture_output=True, text=True).stdout
    match = re.search(r"\bComment=(\S+)", out)
    return match.group(1) if match else ""


def test_sweep_through_slurm_matches_local_run(tmp_path, slurm_cluster):
    assert slurm_cluster["jobcomp_type"] == "jobcomp/filetxt", slurm_cluster
    jobcomp = Path(slurm_cluster["jobcomp"])
    params = tiny_params()
    a, b = make_workspace(tmp_path / "local", params), make_workspace(tmp_path / "slurm", params)
    assert (b / "workflow" / "profiles" / "slurm" / "config.yaml").is_file()

    t0 = time.perf_counter()
    with open(tmp_path / "local.txt", "w") as log:  # the reference runs alongside (SLURM jobs wait between polls)
        reference = subprocess.Popen(["nice", "-n", "5", *LOCAL], cwd=a, env=workflow_env(), stdout=log,
                                     stderr=subprocess.STDOUT)
    try:
        proc = run(SLURM, b, check=False)
        reference.wait()
    finally:
        if reference.poll() is None:
            reference.kill()
            reference.wait()
    wall_s = time.perf_counter() - t0
    log_text = proc.stdout + proc.stderr
    (tmp_path / "slurm.txt").write_text(log_text)
    assert proc.returncode == 0, log_text[-4000:]
    assert reference.returncode == 0, (tmp_path / "local.txt").read_text()[-3000:]

    # 1. every job went through sbatch, and SLURM's own records show it
    submitted = dict(SUBMITTED.findall(log_text))  # SLURM job id -> rule (from the executor's log path)
    assert submitted, log_text[-3000:]
    local_jobs = re.findall(r"^localrule (\w+):", log_text, flags=re.M)
    assert local_jobs == ["all"], local_jobs  # nothing ran on the submitting host but the target rule
    deadline = time.monotonic() + 30  # slurmctld appends the completion line as the job ends
    while len(records := job_records(jobcomp, set(submitted))) < len(submitted) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert set(records) == set(submitted), sorted(set(submitted) - set(records))
    for job_id, rule in submitted.items():
        rec = records[job_id]
        assert rec["JobState"] == "COMPLETED" and rec["WorkDir"] == str(b), rec["line"]
        comment = job_comment(job_id)
        assert comment == f"rule_{rule}" or comment.startswith(f"rule_{rule}_wildcards_"), (job_id, rule, comment)
    rules = sorted(set(submitted.values()))
    assert rules == ["aggregate", "calibrate_source", "compress", "decode_store", "emulate", "evaluate", "evaluate_source",
                     "pretrain", "pretrain_scenes", "source_store", "train", "train_source"], rules

    # 2. the same bytes as the local run
    ref, got = digests(a), digests(b)
    missing = sorted(set(ref) - set(got))
    extra = sorted(set(got) - set(ref))
    differ = sorted(k for k in set(ref) & set(got) if ref[k] != got[k])
    print(json.dumps({
        "slurm": slurm_cluster["started"], "wall_s_both_runs": round(wall_s, 1), "jobs_via_sbatch": len(submitted),
        "job_records": [f"{records[j]['line'].split(' Partition=')[0]} Comment={job_comment(j)}"
                        for j in sorted(submitted, key=int)],
        "outputs_compared": len(ref), "identical": len(set(ref) & set(got)) - len(differ),
        "differences": differ, "missing": missing, "extra": extra}, indent=1))
    assert any(k.endswith("/model/model.pt") for k in ref) and any(".zarr/" in k for k in ref)
    assert missing == [] and differ == [], (missing, differ)
    assert all(Path(k).name == MARKER and k.startswith(("results/figures/", "results/plots/")) for k in extra), extra
    assert all((b / k).stat().st_size == 0 for k in extra)
