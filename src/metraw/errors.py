"""User-facing errors: one clear line, non-zero exit from the CLI."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any


class MetrawError(Exception):
    """An error caused by the user's input or environment, reported as one line."""


def read_yaml(path: str | os.PathLike, what: str) -> Any:
    """The content of the YAML file ``path``; a missing, unreadable or malformed file is a `MetrawError` naming it
    as ``what`` (e.g. "spec file": "spec file PATH not found", "... is not valid YAML: ...")."""
    import yaml

    try:
        return yaml.safe_load(Path(path).read_text())
    except FileNotFoundError:
        raise MetrawError(f"{what} {path} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MetrawError(f"cannot read {what} {path}: {getattr(exc, 'strerror', None) or exc}") from None
    except yaml.YAMLError as exc:
        raise MetrawError(f"{what} {path} is not valid YAML: {' '.join(str(exc).split())}") from None
