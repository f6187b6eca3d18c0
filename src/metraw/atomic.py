"""Write outputs atomically: build at a temporary sibling path, rename when complete.

A failed or interrupted command leaves nothing half-written at the destination.
"""

from __future__ import annotations

import contextlib
import os
import shutil
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
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".partial", dir=dest.parent))
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
