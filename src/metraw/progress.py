"""Progress of long work: a tqdm bar on a terminal, timed log lines elsewhere (a job's log file, SLURM output).

Snakemake sends each job's stderr to ``logs/...``; a bar there is one ever-growing line of carriage returns and
nothing reaches ``tail -f`` until it ends. Off a terminal, long work therefore writes one plain line every
``LOG_INTERVAL_S`` seconds (and a last one when it ends, if it wrote any): where it is, its rate and the time
left. Work shorter than the interval writes nothing, so quick commands and their errors stay one line. The interval
counts from the process's last progress line, whichever loop wrote it (or from its first loop's start): a command
made of several loops each shorter than the interval (a fine-tuning's fields, then three replicates' trainings) still
writes a line every interval instead of staying silent to its end; each command counts from its own start
(`start_command`).
"""

from __future__ import annotations

import math
import os
import re
import resource
import sys
import time
from typing import Any, Iterable, Iterator, TypeVar

T = TypeVar("T")

#: Seconds between two progress lines off a terminal (``METRAW_LOG_INTERVAL_S`` overrides it): well under a minute,
#: so no running job's log stays silent for longer.
LOG_INTERVAL_S = 20.0
#: ``time.monotonic()`` of this process's last progress line, or of its first `LogProgress`'s start (None before it)
_LAST_LINE_S: list[float | None] = [None]


def start_command() -> None:
    """A command starts (``metraw.cli.main``): the silence counts from its own first loop again, not from a loop of an
    earlier command in the same process (tests, a notebook): a quick command and its error stay one line there too."""
    _LAST_LINE_S[0] = None


def log_interval_s() -> float:
    """``LOG_INTERVAL_S``, or the ``METRAW_LOG_INTERVAL_S`` environment variable when set (> 0)."""
    try:
        value = float(os.environ.get("METRAW_LOG_INTERVAL_S", LOG_INTERVAL_S))
    except ValueError:
        return LOG_INTERVAL_S
    return value if value > 0 else LOG_INTERVAL_S


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


class LogProgress:
    """Counts done of ``total`` (None: unknown) and writes a line to ``stream`` when the process has written none for
    ``interval_s``: ``desc: done/total (pct) in elapsed, rate unit/s, about left`` plus any ``note`` given to
    `update`."""

    def __init__(self, total: int | None, desc: str, unit: str = "it", interval_s: float | None = None,
                 stream=None) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.interval_s = log_interval_s() if interval_s is None else float(interval_s)
        self.stream = stream or sys.stderr
        self.done = 0
        self.note = ""
        self.lines = 0
        self.written = -1  # ``done`` at the last line
        self.t0 = time.monotonic()
        if _LAST_LINE_S[0] is None:
            _LAST_LINE_S[0] = self.t0

    def update(self, n: int = 1, note: str | None = None) -> None:
        self.done += n
        if note is not None:
            self.note = note
        now = time.monotonic()
        if now - _LAST_LINE_S[0] >= self.interval_s:  # the process's silence, not only this loop's
            self.write(now)

    def write(self, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        elapsed = now - self.t0
        rate = self.done / elapsed if elapsed > 0 else math.inf
        where = f"{self.done}/{self.total} ({100 * self.done / self.total:.0f} %)" if self.total else f"{self.done}"
        left = (f", about {_duration((self.total - self.done) / rate)} left"
                if self.total and 0 < rate < math.inf and self.done < self.total else "")
        note = f"; {self.note}" if self.note else ""
        print(f"{self.desc}: {where} in {_duration(elapsed)}, {rate:.3g} {self.unit}/s{left}{note}",
              file=self.stream, flush=True)
        _LAST_LINE_S[0], self.written = now, self.done
        self.lines += 1

    def close(self) -> None:
        """The last line, when the work wrote any (work shorter than the interval stays silent)."""
        if self.lines and self.written != self.done:
            self.write()


def _logged(iterable: Iterable[T], total: int | None, desc: str) -> Iterator[T]:
    if total is None:
        try:
            total = len(iterable)  # type: ignore[arg-type]
        except TypeError:
            total = None
    log = LogProgress(total, desc or "progress")
    for item in iterable:
        yield item
        log.update()
    log.close()


def progress_bar(iterable: Iterable[T], total: int | None = None, desc: str = "",
                 disable: bool | None = None) -> Iterable[T]:
    """``iterable`` with its progress on stderr. ``disable``: True nothing, False a tqdm bar, None a bar on a
    terminal and timed log lines elsewhere (`LogProgress`)."""
    if disable is True:
        return iterable
    if disable is None and not sys.stderr.isatty():
        return _logged(iterable, total, desc)
    from tqdm.auto import tqdm

    return tqdm(iterable, total=total, desc=desc, disable=False, file=sys.stderr, dynamic_ncols=True)


def step_log(total: int, desc: str, unit: str = "it", disable: bool | None = None) -> LogProgress | None:
    """A `LogProgress` for work counted in steps inside a loop that has its own bar (e.g. a training's steps
    under its bar of epochs): off a terminal unless ``disable`` is True; None on a terminal or when disabled."""
    if disable is not None or sys.stderr.isatty():
        return None
    return LogProgress(total, desc, unit)


#: Environment variable that makes every successful ``metraw`` command end with `usage_line` on stderr (the
#: workflow sets it, so each job's log ends with what the job used; ``benchmarks/main_job.py`` reads it).
USAGE_ENV = "METRAW_USAGE_LOG"
_USAGE = re.compile(r"^metraw \S+: resources: ([\d.]+) s CPU .*, peak RSS ([\d.]+) MB$")
#: ``time.monotonic()`` when this module was first imported: for the command line, its start (`usage_line`'s wall)
_IMPORTED_S = time.monotonic()


def usage_wanted() -> bool:
    """Whether ``USAGE_ENV`` is set to anything but empty or "0"."""
    return os.environ.get(USAGE_ENV, "") not in ("", "0")


def usage_line(command: str, wall_s: float | None = None) -> str:
    """``metraw COMMAND: resources: C s CPU (U user + S system), W s wall, peak RSS M MB``: this process's CPU and that
    of its children it waited for (worker processes), its wall time (``wall_s``; default: since this module's import,
    for the command line its start) and the largest resident set of it or any such child (``getrusage``; kB on
    Linux)."""
    wall_s = time.monotonic() - _IMPORTED_S if wall_s is None else wall_s
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    user, system = me.ru_utime + kids.ru_utime, me.ru_stime + kids.ru_stime
    rss_mb = max(me.ru_maxrss, kids.ru_maxrss) / 1024.0
    return (f"metraw {command}: resources: {user + system:.1f} s CPU ({user:.1f} user + {system:.1f} system), "
            f"{wall_s:.1f} s wall, peak RSS {rss_mb:.0f} MB")


def parse_usage_line(line: str) -> tuple[float, float] | None:
    """(CPU s, peak RSS MB) of a `usage_line`; None for any other line."""
    m = _USAGE.match(line)
    return (float(m.group(1)), float(m.group(2))) if m else None
