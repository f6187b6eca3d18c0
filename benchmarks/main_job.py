"""Where the main job's time goes: wall time, job and CPU time per rule and the run's start-to-end, from a Snakemake log.

usage: python benchmarks/main_job.py [.snakemake/log/<run>.snakemake.log] [--benchmarks logs/benchmark] [--json OUT]

Reads the newest log under .snakemake/log/ by default (the run of `snakemake --cores all` in this folder) and prints
the host's CPU (model, AVX-512 or not, and ATEN_CPU_CAPABILITY when set: an AVX-512 host run as an AVX2-only one),
the run's wall time from its first job's start to its last job's end, the job-seconds per rule (count, sum, longest;
job time is wall time per job, so two jobs side by side on 2 cores count twice), the share of the cores kept busy,
and when each of the long single jobs started and ended. Snakemake logs each job's start and end to the second.
CPU per rule: the CPU seconds (user + system, the job's processes and their children) of each job's `benchmark:` record
(logs/benchmark/, one TSV per job, written by Snakemake, which samples the job's processes every second for its first
30 s, then every 30 s: a worker process that ends between two samples loses up to 30 s of its CPU).
"""

from __future__ import annotations

import argparse
import collections
import datetime
import glob
import json
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

STAMP = re.compile(r"^\[(\w{3} \w{3} +\d+ [\d:]+ \d{4})\]")
RULE = re.compile(r"^(?:local)?rule (\w+):")
JOBID = re.compile(r"^\s+jobid: (\d+)")
DONE = re.compile(r"^Finished jobid: (\d+)")
CORES = re.compile(r"^Provided cores: (\d+)")
#: Rules whose one job is long enough to print its start and end.
SINGLE = ("source_store", "pretrain_scenes", "decode_store", "pretrain", "train_source", "real_store", "aggregate")


def cpu() -> dict[str, str]:
    """The host's CPU model, its vector ISA and ATen's capability override (when set)."""
    model, flags = platform.processor() or "unknown", ""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
            elif line.startswith("Flags:"):
                flags = line.split(":", 1)[1]
    except (OSError, subprocess.CalledProcessError):
        pass
    isa = "AVX-512" if "avx512f" in flags.split() else "AVX2" if "avx2" in flags.split() else "neither AVX2 nor AVX-512"
    return {"model": model, "isa": isa, "aten_cpu_capability": os.environ.get("ATEN_CPU_CAPABILITY", "")}


def parse(path: str | Path) -> tuple[list[tuple[str, datetime.datetime, datetime.datetime]], int | None]:
    """(rule, start, end) of every finished job of a Snakemake log, and the cores it was given."""
    now, rule, cores = None, None, None
    started: dict[int, tuple[str, datetime.datetime]] = {}
    jobs = []
    for line in Path(path).read_text().splitlines():
        if m := STAMP.match(line):
            now = datetime.datetime.strptime(m.group(1), "%a %b %d %H:%M:%S %Y")
        elif m := CORES.match(line):
            cores = int(m.group(1))
        elif m := RULE.match(line):
            rule = m.group(1)
        elif (m := JOBID.match(line)) and rule is not None:
            started[int(m.group(1))] = (rule, now)
            rule = None
        elif (m := DONE.match(line)) and int(m.group(1)) in started:
            r, t0 = started.pop(int(m.group(1)))
            jobs.append((r, t0, now))
    return jobs, cores


def benchmark_cpu(folder: str | Path) -> dict[str, dict[str, float]]:
    """Per rule the summed ``cpu_time`` [s] and largest ``max_rss`` [MB] of the Snakemake benchmark records under
    ``folder`` (logs/benchmark/RULE.tsv or logs/benchmark/RULE/WILDCARDS.tsv); records without data ("NA": a job
    shorter than the first sample) count 0 and are counted apart."""
    out: dict[str, dict[str, float]] = {}
    for tsv in sorted(Path(folder).rglob("*.tsv")):
        rel = tsv.relative_to(folder)
        rule = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        lines = tsv.read_text().splitlines()
        if len(lines) < 2:
            continue
        row = dict(zip(lines[0].split("\t"), lines[-1].split("\t")))
        r = out.setdefault(rule, {"cpu_s": 0.0, "max_rss_mb": 0.0, "jobs": 0, "no_data": 0})
        r["jobs"] += 1
        try:
            r["cpu_s"] += float(row["cpu_time"])
            r["max_rss_mb"] = max(r["max_rss_mb"], float(row["max_rss"]))
        except (KeyError, ValueError):
            r["no_data"] += 1
    return out


def summary(path: str | Path, benchmarks: str | Path | None = None) -> dict:
    jobs, cores = parse(path)
    if not jobs:
        raise SystemExit(f"{path}: no finished job in this log")
    t0, t1 = min(j[1] for j in jobs), max(j[2] for j in jobs)
    wall = (t1 - t0).total_seconds()
    per_rule = collections.defaultdict(list)
    for r, s, e in jobs:
        per_rule[r].append((e - s).total_seconds())
    job_s = sum(sum(v) for v in per_rule.values())
    return {"log": str(path), "cpu": cpu(), "cores": cores, "jobs": len(jobs), "wall_s": wall,
            "job_s": job_s, "busy_share": job_s / (wall * cores) if cores and wall else None,
            "rules": {r: {"n": len(v), "sum_s": sum(v), "max_s": max(v)}
                      for r, v in sorted(per_rule.items(), key=lambda kv: -sum(kv[1]))},
            "single_jobs": [{"rule": r, "start_s": (s - t0).total_seconds(), "end_s": (e - t0).total_seconds()}
                            for r, s, e in sorted(jobs, key=lambda j: j[1]) if r in SINGLE],
            "cpu_per_rule": benchmark_cpu(benchmarks) if benchmarks and Path(benchmarks).is_dir() else {}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log", nargs="?", default=None, help="Snakemake log (default: the newest in .snakemake/log/)")
    ap.add_argument("--benchmarks", default="logs/benchmark",
                    help="the rules' Snakemake benchmark records (default: logs/benchmark; absent: no CPU column)")
    ap.add_argument("--json", default=None, help="also write the summary as JSON here")
    args = ap.parse_args(argv)
    path = args.log or (sorted(glob.glob(".snakemake/log/*.snakemake.log")) or [None])[-1]
    if path is None:
        print("main_job: no Snakemake log under .snakemake/log/ (run snakemake here first, or name a log)",
              file=sys.stderr)
        return 2
    s = summary(path, args.benchmarks)
    c = s["cpu"]
    print(f"{s['log']}: {s['jobs']} jobs on {s['cores']} cores of {c['model']} ({c['isa']}"
          + (f", ATEN_CPU_CAPABILITY={c['aten_cpu_capability']}" if c["aten_cpu_capability"] else "") + ")")
    print(f"wall {s['wall_s'] / 60:.1f} min (first job's start to last job's end); job time {s['job_s'] / 60:.1f} "
          f"min; cores busy {100 * (s['busy_share'] or 0):.0f} %")
    cpu_rules = s["cpu_per_rule"]
    print(f"{'rule':22s} {'jobs':>4s} {'sum s':>8s} {'max s':>7s}" + (f" {'CPU s':>8s} {'peak MB':>8s}" if cpu_rules else ""))
    for r, v in s["rules"].items():
        c = cpu_rules.get(r)
        print(f"{r:22s} {v['n']:4d} {v['sum_s']:8.0f} {v['max_s']:7.0f}"
              + (f" {c['cpu_s']:8.0f} {c['max_rss_mb']:8.0f}" if c else " " * 18 if cpu_rules else ""))
    if cpu_rules:
        total = sum(c["cpu_s"] for c in cpu_rules.values())
        print(f"CPU of the jobs {total:.0f} s ({total / 60:.1f} min; {total / s['wall_s']:.2f} cores over the wall time)"
              + (f"; {sum(c['no_data'] for c in cpu_rules.values())} jobs too short to sample"
                 if any(c["no_data"] for c in cpu_rules.values()) else ""))
    for j in s["single_jobs"]:
        print(f"  {j['rule']:18s} {j['start_s']:6.0f} s -> {j['end_s']:6.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(s, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
