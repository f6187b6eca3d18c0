"""What a workflow result depends on beyond its inputs and parameters: metraw's own code.

Snakemake's between-workflow output cache keys a job by its command, params and upstream jobs, not by the
Python package its command runs; the aggregate (the one cached rule) passes ``code_digest()`` as a param, so a
changed metraw recomputes it instead of serving the outputs of the old code from the cache.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

#: The source files of the package that make up its behaviour (compiled extensions are built from the .c / .h).
SOURCE_SUFFIXES = (".py", ".c", ".h", ".yaml", ".json")


def code_digest(package_dir: str | Path | None = None) -> str:
    """SHA-256 (hex) over the relative path and bytes of every source file of ``package_dir`` (default: the
    installed metraw), in sorted path order; caches (``__pycache__``) and built extensions are left out."""
    root = Path(package_dir) if package_dir is not None else Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file()
                       and "__pycache__" not in p.relative_to(root).parts):
        name = path.relative_to(root).as_posix().encode()
        data = path.read_bytes()
        digest.update(len(name).to_bytes(8, "little") + name + len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()
