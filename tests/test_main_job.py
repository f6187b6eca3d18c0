"""benchmarks/main_job.py: a run's wall time, job time and CPU per rule from a Snakemake log and its jobs' logs; the
usage line every metraw command ends its log with under the workflow (metraw.progress.usage_line)."""

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

from metraw import progress

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def main_job():
    spec = importlib.util.spec_from_file_location("metraw_main_job", REPO / "benchmarks" / "main_job.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


LOG = """Provided cores: 2
[Sat Nov 28 10:00:00 2026]
rule pretrain:
    output: results/pretrained/RGGB/model
    log: logs/pretrain/RGGB.log
    jobid: 3
[Sat Nov 28 10:00:10 2026]
rule train:
    log: logs/train/a.log
    jobid: 5
[Sat Nov 28 10:01:10 2026]
Finished jobid: 5 (Rule: train)
[Sat Nov 28 10:01:10 2026]
rule train:
    log: logs/train/b.log
    jobid: 6
[Sat Nov 28 10:02:00 2026]
Finished jobid: 3 (Rule: pretrain)
[Sat Nov 28 10:02:40 2026]
Finished jobid: 6 (Rule: train)
"""


def test_wall_job_time_and_cpu_per_rule(main_job, tmp_path):
    log = tmp_path / ".snakemake" / "log" / "run.snakemake.log"
    log.parent.mkdir(parents=True)
    log.write_text(LOG)
    (tmp_path / "logs" / "train").mkdir(parents=True)
    (tmp_path / "logs" / "pretrain").mkdir()
    (tmp_path / "logs/pretrain/RGGB.log").write_text(
        "train: 3360/3360 (100 %) in 6m46s\n"
        "metraw pretrain: resources: 118.2 s CPU (117.0 user + 1.2 system), 120.0 s wall, peak RSS 900 MB\n")
    (tmp_path / "logs/train/a.log").write_text(
        "metraw train: resources: 55.5 s CPU (55.0 user + 0.5 system), 60.0 s wall, peak RSS 300 MB\n")
    (tmp_path / "logs/train/b.log").write_text("metraw train: error: something\n")  # a failed command: no usage
    s = main_job.summary(log)  # the run's folder found from the log's place
    assert s["cores"] == 2 and s["jobs"] == 3
    assert s["wall_s"] == 160.0                                   # 10:00:00 -> 10:02:40
    assert s["rules"]["train"] == {"n": 2, "sum_s": 150.0, "max_s": 90.0}
    assert s["rules"]["pretrain"]["sum_s"] == 120.0
    assert s["busy_share"] == pytest.approx(270.0 / 320.0)
    assert s["cpu_per_rule"]["pretrain"] == {"cpu_s": 118.2, "max_rss_mb": 900.0, "jobs": 1, "no_data": 0}
    assert s["cpu_per_rule"]["train"] == {"cpu_s": 55.5, "max_rss_mb": 300.0, "jobs": 2, "no_data": 1}


def test_several_logs_are_one_run(main_job, tmp_path, capsys):
    """An adaptive sweep's rounds: each a Snakemake log; their jobs are summed, the wall spans them all."""
    logs = []
    for i, (start, end, rule) in enumerate([("10:00:00", "10:01:40", "pretrain"), ("10:05:00", "10:06:40", "train")]):
        log = tmp_path / ".snakemake" / "log" / f"run{i}.snakemake.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(f"Provided cores: 2\n[Sat Nov 28 {start} 2026]\nrule {rule}:\n    jobid: 1\n"
                       f"[Sat Nov 28 {end} 2026]\nFinished jobid: 1 (Rule: {rule})\n")
        logs.append(str(log))
    s = main_job.summary(logs)
    assert s["jobs"] == 2 and s["wall_s"] == 400.0  # 10:00:00 -> 10:06:40
    assert s["rules"]["train"]["sum_s"] == s["rules"]["pretrain"]["sum_s"] == 100.0
    assert main_job.main([*logs, "--root", str(tmp_path)]) == 0
    assert "2 jobs on 2 cores" in capsys.readouterr().out


def test_without_usage_lines_no_cpu_column(main_job, tmp_path, capsys):
    log = tmp_path / "run.snakemake.log"
    log.write_text(LOG)
    assert main_job.main([str(log), "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "CPU s" not in out and "wall 2.7 min" in out


def test_a_command_ends_with_its_usage_line_only_when_asked_and_only_on_success(tmp_path):
    script = "from metraw.cli import main; import sys; sys.exit(main(sys.argv[1:]))"
    env_on = {"METRAW_USAGE_LOG": "1", "PATH": "/usr/bin:/bin"}
    # a command that succeeds: its usage line last
    done = subprocess.run([sys.executable, "-c", script, "info", str(REPO / "data/real/canon_dng/colorchart.dng")],
                          capture_output=True, text=True, env=env_on, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    m = re.fullmatch(r"metraw info: resources: ([\d.]+) s CPU \(([\d.]+) user \+ ([\d.]+) system\), ([\d.]+) s wall, "
                     r"peak RSS (\d+) MB", last)
    assert m, last
    cpu, user, system, wall, rss = map(float, m.groups())
    assert cpu == pytest.approx(user + system, abs=0.11) and cpu > 0 and wall > 0 and rss > 20
    # not asked: no line; asked, but the command fails: its error stays its one line
    quiet = subprocess.run([sys.executable, "-c", script, "info", str(REPO / "data/real/canon_dng/colorchart.dng")],
                           capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"}, cwd=tmp_path)
    assert quiet.returncode == 0 and "resources:" not in quiet.stderr
    failed = subprocess.run([sys.executable, "-c", script, "info", str(tmp_path / "absent.dng")],
                            capture_output=True, text=True, env=env_on, cwd=tmp_path)
    assert failed.returncode == 2 and failed.stderr.strip().count("\n") == 0 and "resources:" not in failed.stderr


def test_usage_line_counts_the_children_it_waited_for():
    import multiprocessing as mp

    before = float(re.search(r"([\d.]+) s CPU", progress.usage_line("x", 1.0)).group(1))
    ctx = mp.get_context("fork")
    proc = ctx.Process(target=_spin, args=(0.5,))
    proc.start()
    proc.join()
    after = float(re.search(r"([\d.]+) s CPU", progress.usage_line("x", 1.0)).group(1))
    assert after - before >= 0.45  # the child's 0.5 s of CPU, waited for


def _spin(seconds):
    import time

    t = time.process_time()
    while time.process_time() - t < seconds:
        pass
