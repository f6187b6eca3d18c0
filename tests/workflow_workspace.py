"""A tiny temporary copy of the workflow, shared by the workflow tests (test_workflow_jobs, test_workflow_resume).

``make_workspace`` copies the Snakefile, workflow/ (profiles included, via the same ``profiles`` link as the
repository) and a params.yaml (``tiny_params``: the repository's, shrunk) into a fresh git + DVC repository with
its generated dvc.yaml; ``run`` runs a command there. Never touches the repository's data/ or results/.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "workflow" / "scripts" / "dvc_yaml.py"

needs_tools = pytest.mark.skipif(shutil.which("snakemake") is None or shutil.which("dvc") is None,
                                 reason="snakemake and dvc executables are needed")


def tiny_params() -> dict:
    """The repository's params.yaml shrunk: 4 scenes of 160 px, 1 epoch, 4 points (the GP's leave-one-out needs 4)."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["source"]["dataset"] = "synthetic"
    params["source"]["synthetic"].update(n_scenes=4, size_px=160, seed=0)
    params["target"]["sweeps"] = {"focal_length_m": [1.2], "diameter_m": [0.35], "exposure_s": [300.0e-6]}
    params["training"]["profile"] = "default"
    params["training"]["profiles"]["default"].update(epochs=1, batch_size=4, crop_px=4, base_channels=4, depth=2,
                                                     min_grid_px=0, crops_per_image=1)
    return params


def workflow_env() -> dict[str, str]:
    """The environment of the workflow commands: fixed hash seed, the workspace's own .snakemake-cache/."""
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    env.pop("SNAKEMAKE_OUTPUT_CACHE", None)  # the workspace's own .snakemake-cache/ (the Snakefile's default)
    return env


def run(cmd: list[str], cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    """Run ``cmd`` (niced: the machine is shared) in ``cwd``; fail with its output's tail unless ``check`` is off."""
    proc = subprocess.run(["nice", "-n", "5", *cmd], cwd=cwd, capture_output=True, text=True, env=workflow_env())
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def make_workspace(root: Path, params: dict) -> Path:
    """Workflow files + params + generated dvc.yaml in a fresh git + DVC repository (``root`` made if needed)."""
    root.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", ".dvcignore"):
        shutil.copy2(REPO / name, root / name)
    shutil.copytree(REPO / "workflow", root / "workflow", ignore=shutil.ignore_patterns("__pycache__"))
    os.symlink(os.readlink(REPO / "profiles"), root / "profiles")  # profiles -> workflow/profiles, as in the repo
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    (root / ".gitignore").write_text("/data/\n/results/\n/logs/\n.snakemake/\n/.snakemake-cache/\n")
    run(["python", str(SCRIPT)], root)
    run(["git", "init", "-q"], root)
    run(["dvc", "init", "-q"], root)
    run(["dvc", "config", "core.autostage", "false"], root)
    return root


def file_digests(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` by path relative to it; symlinks are followed, into folders too
    (the aggregate's figures/ and plots/ are links into the output cache)."""
    digests = {}
    for dirpath, _, names in os.walk(folder, followlinks=True):
        for name in names:
            f = Path(dirpath) / name
            digests[str(f.relative_to(folder))] = hashlib.sha256(f.read_bytes()).hexdigest()
    return dict(sorted(digests.items()))
