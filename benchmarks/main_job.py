"""Where the main job's time goes: wall time, job and CPU time per rule and the run's start-to-end, from a Snakemake log.

usage: python benchmarks/main_job.py [.snakemake/log/<run>.snakemake.log ...] [--json OUT]

Reads the newest log under .snakemake/log/ by default (the run of `snakemake --cores all` in this folder) and prints
the host's CPU (model, AVX-512 or not, and ATEN_CPU_CAPABILITY when set: an AVX-512 host run as an AVX2-only one),
the run's wall time from its first job's start to its last job's end, the job-seconds per rule (count, sum, longest;
job time is wall time per job, so two jobs side by side on 2 cores count twice), the share of the cores kept busy,
and when each of the long single jobs started and ended. Snakemake logs each job's start and end to the second.
CPU per rule: each job's log (the `log:` the Snakemake log names, relative to the folder the run ran in) ends with the
line its metraw command writes under the workflow (`metraw.progress.usage_line`: the CPU of the command and of the
worker processes it waited for, and the peak memory); a job without one (an older run, a failed command) counts apart.
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

from metraw.progress import parse_usage_line

STAMP = re.compile(r"^\[(\w{3} \w{3} +\d+ [\d:]+ \d{4})\]")
RULE = re.compile(r"^(?:local)?rule (\w+):")
LOG = re.compile(r"^\s+log: (.+)$")
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


def parse(path: str | Path) -> tuple[list[tuple[str, datetime.datetime, datetime.datetime, list[str]]], int | None]:
    """(rule, start, end, log files) of every finished job of a Snakemake log, and the cores it was given."""
    now, rule, logs, cores = None, None, [], None
    started: dict[int, tuple[str, datetime.datetime, list[str]]] = {}
    jobs = []
    for line in Path(path).read_text().splitlines():
        if m := STAMP.match(line):
            now = datetime.datetime.strptime(m.group(1), "%a %b %d %H:%M:%S %Y")
        elif m := CORES.match(line):
            cores = int(m.group(1))
        elif m := RULE.match(line):
            rule, logs = m.group(1), []
        elif (m := LOG.match(line)) and rule is not None:
            logs = [p.strip() for p in m.group(1).split(",") if p.strip()]
        elif (m := JOBID.match(line)) and rule is not None:
            started[int(m.group(1))] = (rule, now, logs)
            rule, logs = None, []
        elif (m := DONE.match(line)) and int(m.group(1)) in started:
            r, t0, job_logs = started.pop(int(m.group(1)))
            jobs.append((r, t0, now, job_logs))
    return jobs, cores


def job_usage(log_files: list[str], root: Path) -> tuple[float, float] | None:
    """(CPU s, peak RSS MB) of the last `usage_line` in a job's log files under ``root``; None without one."""
    found = None
    for name in log_files:
        path = root / name
        if path.is_file():
            for line in path.read_text(errors="replace").splitlines():
                found = parse_usage_line(line) or found
    return found


def cpu_per_rule(jobs, root: Path) -> dict[str, dict[str, float]]:
    """Per rule the summed CPU s and largest peak RSS MB of its jobs' usage lines, and how many jobs had none."""
    out: dict[str, dict[str, float]] = {}
    for r, _, _, logs in jobs:
        if not logs:
            continue
        c = out.setdefault(r, {"cpu_s": 0.0, "max_rss_mb": 0.0, "jobs": 0, "no_data": 0})
        c["jobs"] += 1
        usage = job_usage(logs, root)
        if usage is None:
            c["no_data"] += 1
        else:
            c["cpu_s"] += usage[0]
            c["max_rss_mb"] = max(c["max_rss_mb"], usage[1])
    return out if any(c["jobs"] > c["no_data"] for c in out.values()) else {}


def summary(path: str | Path | list, root: str | Path | None = None) -> dict:
    """The run's timing; ``path``: its Snakemake log, or several (an adaptive sweep's: one per round and the whole
    workflow's, taken as one run); ``root``: the folder it ran in (its job logs; default: the log's
    .snakemake/log/../..)."""
    paths = [path] if isinstance(path, (str, Path)) else list(path)
    jobs, cores = [], None
    for p in paths:
        more, c = parse(p)
        jobs += more
        cores = cores or c
    path = paths[0] if len(paths) == 1 else f"{paths[0]} and {len(paths) - 1} more"
    root = Path(root) if root is not None else Path(paths[0]).resolve().parents[2]
    if not jobs:
        raise SystemExit(f"{path}: no finished job in this log")
    t0, t1 = min(j[1] for j in jobs), max(j[2] for j in jobs)
    wall = (t1 - t0).total_seconds()
    per_rule = collections.defaultdict(list)
    for r, s, e, _ in jobs:
        per_rule[r].append((e - s).total_seconds())
    job_s = sum(sum(v) for v in per_rule.values())
    return {"log": str(path), "cpu": cpu(), "cores": cores, "jobs": len(jobs), "wall_s": wall,
            "job_s": job_s, "busy_share": job_s / (wall * cores) if cores and wall else None,
            "rules": {r: {"n": len(v), "sum_s": sum(v), "max_s": max(v)}
                      for r, v in sorted(per_rule.items(), key=lambda kv: -sum(kv[1]))},
            "single_jobs": [{"rule": r, "start_s": (s - t0).total_seconds(), "end_s": (e - t0).total_seconds()}
                            for r, s, e, _ in sorted(jobs, key=lambda j: j[1]) if r in SINGLE],
            "cpu_per_rule": cpu_per_rule(jobs, root)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log", nargs="*", default=None,
                    help="Snakemake log (default: the newest in .snakemake/log/); several: one run (an adaptive sweep's "
                    "rounds: .snakemake/log/*.snakemake.log)")
    ap.add_argument("--root", default=None,
                    help="the folder the run ran in, where its logs/ are (default: the one holding the log's .snakemake)")
    ap.add_argument("--json", default=None, help="also write the summary as JSON here")
    args = ap.parse_args(argv)
    path = args.log or (sorted(glob.glob(".snakemake/log/*.snakemake.log")) or [None])[-1]
    if isinstance(path, list) and len(path) == 1:
        path = path[0]
    if path is None:
        print("main_job: no Snakemake log under .snakemake/log/ (run snakemake here first, or name a log)",
              file=sys.stderr)
        return 2
    s = summary(path, args.root)
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
              + (f"; {sum(c['no_data'] for c in cpu_rules.values())} jobs without a usage line in their log"
                 if any(c["no_data"] for c in cpu_rules.values()) else ""))
    for j in s["single_jobs"]:
        print(f"  {j['rule']:18s} {j['start_s']:6.0f} s -> {j['end_s']:6.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(s, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
