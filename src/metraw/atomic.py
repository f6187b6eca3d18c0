"""Write outputs atomically: build at a temporary sibling path, rename when complete.

A failed or interrupted command leaves nothing half-written at the destination.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Iterator

from metraw.errors import MetrawError


@contextlib.contextmanager
def atomic_path(destination: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``destination``; move it into place on success.

    Works for files and directories (e.g. zarr stores). On any exception the temporary
    path is removed and the destination is untouched.
    """
    dest = Path(destination)
    if dest.exists() and not overwrite:
        raise MetrawError(f"output {dest} already exists (use --overwrite to replace it)")
    dest.parent.mkdir(parents=True, exist_ok=True)
    _remove_orphans(dest)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{dest.name}.{_owner()}.", suffix=".partial", dir=dest.parent))
    tmp = tmp_dir / dest.name
    try:
        yield tmp
        if not tmp.exists():
            raise MetrawError(f"internal error: nothing was written for {dest}")
        if dest.exists():
            _remove(dest)
        os.replace(tmp, dest)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def _owner() -> str:
    """Host and process writing a temporary (``host-pid``; dots and dashes in the host name become ``_``)."""
    return f"{re.sub(r'[^A-Za-z0-9_]', '_', socket.gethostname())}-{os.getpid()}"


def _remove_orphans(dest: Path) -> None:
    """Remove the temporaries of earlier writes of ``dest`` whose process is gone (SIGKILL, power loss).

    Such a write can never complete and nobody else knows its directory. Only temporaries of this host
    whose process no longer exists are removed: a live writer's (or another host's) are left alone.
    """
    host, _ = _owner().rsplit("-", 1)
    pattern = re.compile(rf"\.{re.escape(dest.name)}\.{re.escape(host)}-(\d+)\.[a-z0-9_]{{8}}\.partial")
    for tmp in dest.parent.iterdir():
        m = pattern.fullmatch(tmp.name)
        if m and not _alive(int(m.group(1))):
            shutil.rmtree(tmp, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True
