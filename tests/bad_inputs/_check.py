"""The one check every bad-input case makes: the command refuses the input properly.

`refused` runs a command as a subprocess (so exit status and stderr are the real ones; or, with
``inprocess``, through ``metraw.cli.main`` in this process, for commands whose imports -- numba, the
codec -- would make every subprocess slow: the exit status is then main's return value, stderr is
what it printed, and an unexpected exception propagates as the test's failure) and asserts the four
properties of a refusal:

1. exit status 2;
2. exactly one line on stderr, ``metraw CMD: error: ...`` (``metraw workflow: error: ...`` for
   Snakemake), naming the problem: it contains ``word``;
3. nothing left behind: no file or folder appears under ``root`` (the case's folder, holding its
   inputs and outputs), so no output and no ``.partial`` temporary next to it;
4. every input unchanged: the sha256 of every file under ``root`` is the same before and after.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import subprocess
import sys
from pathlib import Path

#: Snakemake's own notice when it reads the workflow profile (not an error; printed before the Snakefile runs).
SNAKEMAKE_PROFILE_NOTICE = "Using workflow specific profile"


def tree(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (symlinks as their target, folders as "dir"), by relative path."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(dirpath) / name
            key = str(p.relative_to(root))
            if p.is_symlink():
                out[key] = "link -> " + os.readlink(p)
            elif p.is_dir():
                out[key] = "dir"
            else:
                out[key] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def refused(argv: list[str], word: str, root: Path, *, cwd: Path | None = None, env: dict | None = None,
            snakemake: bool = False, inprocess: bool = False, timeout: float = 300) -> str:
    """Run ``metraw ARGV`` (or, with ``snakemake``, ``snakemake ARGV``) in ``cwd`` (default ``root``) and
    assert the four properties of a refusal (module docstring); return the error line."""
    before = tree(root)
    prefix = "metraw workflow: error: " if snakemake else f"metraw {argv[0]}: error: "
    if inprocess:
        status, stderr = _main(argv, cwd or root)
    else:
        cmd = ([str(Path(sys.executable).with_name("snakemake"))] if snakemake else [sys.executable, "-m", "metraw"])
        proc = subprocess.run(cmd + argv, cwd=cwd or root, env=env, capture_output=True, text=True, timeout=timeout)
        status, stderr = proc.returncode, proc.stderr
    lines = [line for line in stderr.splitlines() if not (snakemake and line.startswith(SNAKEMAKE_PROFILE_NOTICE))]
    assert status == 2, f"exit status {status}, stderr:\n{stderr[-3000:]}"
    assert len(lines) == 1, f"{len(lines)} lines on stderr:\n{stderr[-3000:]}"
    assert lines[0].startswith(prefix), lines[0]
    assert word in lines[0], f"{word!r} not in: {lines[0]}"
    after = tree(root)
    left = sorted(set(after) - set(before))
    assert not left, f"left behind: {left}"
    changed = sorted(k for k in before if after.get(k) != before[k])
    assert not changed, f"inputs changed or removed: {changed}"
    return lines[0]


def _main(argv: list[str], cwd: Path) -> tuple[int, str]:
    """``metraw.cli.main(argv)`` run in ``cwd``: (exit status, what it wrote to stderr)."""
    from metraw.cli import main

    err, here = io.StringIO(), os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = main(argv)
    finally:
        os.chdir(here)
    return status, err.getvalue()
