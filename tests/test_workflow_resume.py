"""A killed workflow run resumes, and its results are byte for byte those of an uninterrupted run.

Two workspaces with the same tiny params (tests/workflow_workspace.py, with one sweep value: 2 points) build the
chain of both points up to their metrics and compression results (``TARGETS``: source store, pretraining,
emulate, train, evaluate, compress). A runs ``snakemake --cores 2`` once, uninterrupted. B is killed like a dying
node (SIGKILL to Snakemake and every job it started) twice, each time resumed with the same command:

1. while an ``emulate`` job is writing its store (its temporary ``.partial`` sibling exists);
2. while a ``train`` job runs (the resumed run after kill 1, once emulation is done).

After each kill the rerun first fails on Snakemake's stale lock (.snakemake/locks): like a user, the test then
runs ``snakemake --unlock``, then the same command again. Finally every file under results/ and data/ of B
(zarr stores, model checkpoints, JSON) is compared with A's by sha256. The aggregate is not built: it only reads
the points' results, in one job that no kill interrupts here (its bytes are compared across two processes in
test_parameter_space.py), and it would need the 4 points of its leave-one-out, twice the jobs.

All of them are identical: results are a function of inputs, code, seeds and the configured thread count
(timings go to logs/, never into results), and B has no file A lacks. A SIGKILLed writer cannot remove its
temporary directory (metraw.atomic's ``.<name>.<host>-<pid>.<random>.partial`` next to the output), and
Snakemake does not know it: the next write of the same output removes it (its process is gone), so none is left.

Machine dependence (why the same config elsewhere can give another IoU, e.g. 0.174 vs 0.178): the emulator
(numpy/numba) is driven by integers and seeded generators and gives the same stores on any machine; torch's CPU
kernels choose their instruction set (AVX2, AVX-512, oneDNN paths) and summation order by processor and thread
count, so model.pt differs in its last bits between machines, and through the thresholded predictions so do
metrics.json, aggregate.json, spec.yaml, figures/ and plots/. The thread count is fixed by the training config
(``TrainConfig.threads``, not the machine or ``--cores``); on a CUDA machine the device itself differs.
The comparison here is of two runs on one machine.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from workflow_workspace import chain_targets, file_digests, make_workspace, needs_tools, run, tiny_params, workflow_env

psutil = pytest.importorskip("psutil")  # Snakemake's own dependency

POINTS = ("nominal", "focal_length_m-1.2")
TARGETS = chain_targets(POINTS)
COMMAND = ["snakemake", "--cores", "2", "--", *TARGETS]
DRY_RUN = ["snakemake", "--cores", "2", "--dry-run", "--", *TARGETS]
COMPARED = ("results", "data")
START_TIMEOUT_S = 300


def digests(root: Path) -> dict[str, str]:
    """sha256 of every file under results/ and data/ of a workspace."""
    return {f"{sub}/{name}": d for sub in COMPARED if (root / sub).is_dir()
            for name, d in file_digests(root / sub).items()}


def partials(root: Path) -> dict[str, str]:
    """Files inside the temporary ``.<name>.<random>.partial`` directories of unfinished writes (and their sha256)."""
    return {name: d for name, d in digests(root).items() if re.search(r"(^|/)\.[^/]+\.partial/", name)}


def rule_jobs(leader: psutil.Process, rule: str) -> list[dict]:
    """The running ``metraw RULE`` commands among Snakemake's descendants: their arguments and start time."""
    found = []
    for proc in leader.children(recursive=True):
        try:
            cmd = proc.cmdline()
            if "metraw" in " ".join(cmd[:2]) and rule in cmd[1:3] and proc.status() != psutil.STATUS_ZOMBIE:
                args = itertools.takewhile(lambda arg: not arg.startswith("-"), cmd[2:])  # rule, input, output
                found.append({"args": " ".join(args), "started": proc.create_time()})
        except psutil.Error:  # ended meanwhile
            continue
    return found


def group_alive(pgid: int) -> bool:
    """Whether a process of group ``pgid`` still runs (zombies waiting for their parent do not count)."""
    for proc in psutil.process_iter():
        try:
            if os.getpgid(proc.pid) == pgid and proc.status() != psutil.STATUS_ZOMBIE:
                return True
        except (OSError, psutil.Error):
            continue
    return False


def kill_during(root: Path, rule: str, ready) -> dict:
    """Run COMMAND in ``root`` in its own process group, wait until ``ready(root, jobs of rule)`` holds, then
    SIGKILL the whole group. Returns the rule's jobs that were running and the temporaries left."""
    # Its own session, hence process group: the jobs Snakemake starts (the shell, `metraw ...`, its forked
    # emulation workers) stay in that group. Killing the group is a node dying: killing only Snakemake's PID
    # would orphan the running jobs, which would finish and write their outputs while (or after) the rerun
    # starts the same jobs again: a race, not a resume.
    with open(root / f"killed-during-{rule}.txt", "w") as log:
        proc = subprocess.Popen(["nice", "-n", "5", *COMMAND], cwd=root, env=workflow_env(), start_new_session=True,
                                stdout=log, stderr=subprocess.STDOUT)
    leader = psutil.Process(proc.pid)
    deadline = time.monotonic() + START_TIMEOUT_S
    try:
        while not ((running := rule_jobs(leader, rule)) and ready(root, running)):
            assert proc.poll() is None, f"snakemake ended ({proc.returncode}) before a {rule} job ran"
            assert time.monotonic() < deadline, f"no {rule} job within {START_TIMEOUT_S} s"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    gone_by = time.monotonic() + 10
    while group_alive(proc.pid):
        assert time.monotonic() < gone_by, "processes of the killed group survive"
        time.sleep(0.05)
    return {"rule": rule, "running": sorted(job["args"] for job in running), "temporaries": partials(root)}


def emulation_writing(root: Path, running) -> bool:
    """An emulation has written a first file into its store's temporary sibling (``.target.zarr.*.partial``).

    The directory alone is not enough: it exists empty for a moment before zarr writes its metadata, and a
    kill then leaves no file to find."""
    return any(p.is_file() for p in root.glob("results/points/*/.target.zarr.*.partial/**/*"))


def training_for(seconds: float):
    """A train job that has run ``seconds`` (past its start: importing torch, reading its store, training)."""
    return lambda root, running: any(time.time() - job["started"] >= seconds for job in running)


def resume(root: Path, expect_lock: bool) -> None:
    """What a user does after a crash: the same command; Snakemake refuses on its stale lock: --unlock, again."""
    if expect_lock:
        proc = run(COMMAND, root, check=False)
        assert proc.returncode != 0 and "Directory cannot be locked" in proc.stdout + proc.stderr, proc.stderr[-2000:]
    run(["snakemake", "--unlock"], root)


@needs_tools
@pytest.mark.workflow
def test_killed_runs_resume_with_identical_results(tmp_path):
    params = tiny_params()
    params["target"]["sweeps"] = {"focal_length_m": [1.2]}
    a, b = make_workspace(tmp_path / "A", params), make_workspace(tmp_path / "B", params)
    # the reference runs alongside B's first two runs (a workflow run of tiny jobs leaves a core mostly idle)
    t0 = time.perf_counter()
    with open(tmp_path / "reference.txt", "w") as log:
        reference = subprocess.Popen(["nice", "-n", "5", *COMMAND], cwd=a, env=workflow_env(), start_new_session=True,
                                     stdout=log, stderr=subprocess.STDOUT)
    try:
        kills = [kill_during(b, "emulate", emulation_writing)]
        resume(b, expect_lock=True)
        # the resumed run, once one of its train jobs (its point's emulation done) has run for a second
        kills.append(kill_during(b, "train", training_for(1.0)))
        resume(b, expect_lock=True)
        reference.wait()
    finally:
        if reference.poll() is None:  # a failure above: stop the reference and its jobs
            os.killpg(reference.pid, signal.SIGKILL)
            reference.wait()
    assert reference.returncode == 0, (tmp_path / "reference.txt").read_text()[-3000:]
    left = {name: d for k in kills for name, d in k["temporaries"].items()}
    assert any(name.startswith("results/points/") for name in kills[0]["temporaries"]), kills[0]
    assert not all((b / target).exists() for target in TARGETS)  # the kills did interrupt the run
    run(COMMAND, b)
    timings = {"all_runs_s": time.perf_counter() - t0}
    assert "Nothing to be done" in run(DRY_RUN, b).stdout

    ref, got = digests(a), digests(b)
    extra = {name: got[name] for name in sorted(set(got) - set(ref))}
    missing = sorted(set(ref) - set(got))
    differ = sorted(k for k in set(ref) & set(got) if ref[k] != got[k])
    print(json.dumps({"kills": len(kills), "outputs_compared": len(ref), "differences": len(differ) + len(missing),
                      "killed_writers_temporaries": sorted(extra), "kills_detail": kills,
                      **{k: round(v, 1) for k, v in timings.items()}}, indent=1))
    assert not partials(a)
    assert set(TARGETS) | {f"results/points/{point}/model/model.pt" for point in POINTS} <= set(ref)
    assert any(k.startswith("results/pretrained/") for k in ref) and any(".zarr/" in k for k in ref)
    assert missing == [] and differ == [], (missing, differ)
    # the killed writers did leave temporaries (`left`), and B has no file beyond A's: metraw.atomic removes a
    # dead writer's temporary when the next write of the same output starts
    assert left, "no killed writer left a temporary: the kills landed outside the writes"
    assert extra == {}, (sorted(extra), sorted(left))
