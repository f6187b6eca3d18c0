"""Every module of the package imports from the declared dependencies alone.

In a fresh virtual environment (as `.ci/run` builds) a module importing something that
`pyproject.toml` does not declare fails here, not at a user's first command."""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import metraw


def _modules() -> list[str]:
    names = [m.name for m in pkgutil.walk_packages(metraw.__path__, prefix="metraw.")]
    # __main__ runs the CLI; the codec's C library is loaded with ctypes (metraw.codec.native), not imported
    return sorted(n for n in names if not n.endswith(".__main__") and n != "metraw.codec._simd")


def test_the_walk_finds_the_package():
    names = _modules()
    # a walk that silently found nothing (e.g. an empty path) would pass the test below vacuously
    assert {"metraw.codec.container", "metraw.cli.emulate", "metraw.segment.train"} <= set(names)
    assert len(names) >= 50, names


@pytest.mark.parametrize("name", _modules())
def test_module_imports(name):
    importlib.import_module(name)


def test_the_params_schema_ships_inside_the_package():
    # a non-editable install has no workflow/ beside it: metraw.study.points falls back to metraw/schemas/,
    # a link to workflow/schemas/params.schema.yaml that setuptools copies into the wheel
    from pathlib import Path

    packaged = Path(metraw.__file__).parent / "schemas" / "params.schema.yaml"
    workflow = Path(__file__).resolve().parents[1] / "workflow" / "schemas" / "params.schema.yaml"
    assert packaged.read_bytes() == workflow.read_bytes()
