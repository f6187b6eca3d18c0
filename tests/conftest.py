"""Shared fixtures."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

#: Slowest first under pytest-xdist (``-n``): the whole-workflow tests start at once, one worker each, while the
#: other worker runs the short tests; scheduled last, they would run side by side on two busy cores at the end.
SLOW_FIRST = ("test_changing_one_sweep_value_reruns_only_that_point", "test_killed_runs_resume_with_identical_results",
              "test_real_path_runs_on_fake_photos")


def pytest_sessionstart(session):
    """In the controller of a pytest-xdist run, before its workers start: fill numba's caches once, one process per
    group of ``tests/numba_warmup.py`` side by side, so that the workers and the workflow jobs they start read the
    compiled functions instead of each compiling them. On a fresh clone (2-core Intel VM, wall): 557 s without it,
    523 s with it (55 s of it the warm-up); with warm caches it costs ~2.5 s. Only for a run of the whole folder
    (no paths given, or tests/ itself): a run of chosen files compiles just what they use. A group that fails is
    reported and skipped over: the tests themselves then show what is wrong."""
    config = session.config
    if not getattr(config.option, "numprocesses", None) or hasattr(config, "workerinput"):
        return
    here = Path(__file__).resolve().parent
    whole = config.args_source == pytest.Config.ArgsSource.TESTPATHS or any(
        Path(config.invocation_params.dir, arg.split("::")[0]).resolve() == here for arg in config.args)
    if not whole:
        return
    from numba_warmup import GROUPS

    t0 = time.perf_counter()
    script = Path(__file__).with_name("numba_warmup.py")
    procs = {name: subprocess.Popen([sys.executable, str(script), name], stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, text=True) for name in GROUPS}
    errors = {name: proc.communicate()[1] for name, proc in procs.items()}
    failed = {name: errors[name].strip().splitlines()[-1:] for name, proc in procs.items() if proc.returncode}
    line = f"numba caches warmed in {time.perf_counter() - t0:.1f} s ({', '.join(GROUPS)} side by side)"
    if failed:
        line += "; failed: " + "; ".join(f"{name}: {' '.join(err)}" for name, err in failed.items())
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line(line)


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, the workflow tests (``SLOW_FIRST`` in that order, then other ``workflow`` tests) first;
    the order is the same in every worker, as xdist requires."""
    if not getattr(config.option, "numprocesses", None):
        return

    def rank(item) -> int:
        name = getattr(item, "originalname", item.name)
        if name in SLOW_FIRST:
            return SLOW_FIRST.index(name)
        return len(SLOW_FIRST) + (0 if item.get_closest_marker("workflow") else 1)

    items.sort(key=rank)  # stable: the collection order within each rank


#: Real third-party files committed with the repository (data/real; licenses and sources in its README.md).
REAL_DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "real"


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """data/real of the repository: always present, never skipped."""
    assert REAL_DATA_DIR.is_dir(), f"{REAL_DATA_DIR} is part of the repository"
    return REAL_DATA_DIR


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """A 6-scene synthetic source (256 px) and its emulation at a 0.72 m GSD target (~20 px frames):
    (source store path, target store path, target) for the on-the-fly training tests."""
    import dataclasses

    from metraw.emulate.emulator import emulate
    from metraw.emulate.target import TargetSystem
    from metraw.io.store import RawStore
    from metraw.scenes import generate_one

    root = tmp_path_factory.mktemp("otf")
    params = Path(__file__).resolve().parents[1] / "params.yaml"
    target = dataclasses.replace(TargetSystem.from_params(str(params)), focal_length_m=2.0)
    scenes = [generate_one(i, 0, 256) for i in range(6)]
    with RawStore.create(root / "src.zarr") as s:
        for img in scenes:
            s.append(img)
    with RawStore.create(root / "tgt.zarr") as s:
        for i, img in enumerate(scenes):
            s.append(emulate(img, target, "auto", i))
    return root / "src.zarr", root / "tgt.zarr", target
