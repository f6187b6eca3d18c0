"""benchmarks/main_job.py: a run's wall time, job time and CPU per rule from a Snakemake log and its benchmark records."""

import importlib.util
from pathlib import Path

import pytest

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
    jobid: 3
[Sat Nov 28 10:00:10 2026]
rule train:
    jobid: 5
[Sat Nov 28 10:01:10 2026]
Finished jobid: 5 (Rule: train)
[Sat Nov 28 10:01:10 2026]
rule train:
    jobid: 6
[Sat Nov 28 10:02:00 2026]
Finished jobid: 3 (Rule: pretrain)
[Sat Nov 28 10:02:40 2026]
Finished jobid: 6 (Rule: train)
"""
HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def test_wall_job_time_and_cpu_per_rule(main_job, tmp_path):
    log = tmp_path / "run.snakemake.log"
    log.write_text(LOG)
    bench = tmp_path / "benchmark"
    (bench / "train").mkdir(parents=True)
    (bench / "pretrain").mkdir()
    (bench / "pretrain" / "RGGB.tsv").write_text(HEADER + "120.0\t0:02:00\t900.5\t1\t1\t1\t0\t0\t95\t118.25\n")
    (bench / "train" / "a.tsv").write_text(HEADER + "60.0\t0:01:00\t300.0\t1\t1\t1\t0\t0\t90\t55.5\n")
    (bench / "train" / "b.tsv").write_text(HEADER + "0.4\t0:00:00\tNA\tNA\tNA\tNA\tNA\tNA\tNA\tNA\n")
    s = main_job.summary(log, bench)
    assert s["cores"] == 2 and s["jobs"] == 3
    assert s["wall_s"] == 160.0                                   # 10:00:00 -> 10:02:40
    assert s["rules"]["train"] == {"n": 2, "sum_s": 150.0, "max_s": 90.0}
    assert s["rules"]["pretrain"]["sum_s"] == 120.0
    assert s["busy_share"] == pytest.approx(270.0 / 320.0)
    assert s["cpu_per_rule"]["pretrain"] == {"cpu_s": 118.25, "max_rss_mb": 900.5, "jobs": 1, "no_data": 0}
    assert s["cpu_per_rule"]["train"] == {"cpu_s": 55.5, "max_rss_mb": 300.0, "jobs": 2, "no_data": 1}


def test_without_benchmark_records_no_cpu_column(main_job, tmp_path, capsys):
    log = tmp_path / "run.snakemake.log"
    log.write_text(LOG)
    assert main_job.main([str(log), "--benchmarks", str(tmp_path / "absent")]) == 0
    out = capsys.readouterr().out
    assert "CPU s" not in out and "wall 2.7 min" in out
