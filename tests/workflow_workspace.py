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
    """The repository's params.yaml shrunk: 4 scenes of 160 px, 1 epoch, 4 points (the GP's leave-one-out needs 4),
    pretraining on 2 extra scenes for 1 epoch."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["source"]["dataset"] = "synthetic"
    params["source"]["synthetic"].update(n_scenes=4, size_px=160, seed=0)
    params["target"]["sweeps"] = {"focal_length_m": [1.2], "diameter_m": [0.35], "exposure_s": [300.0e-6]}
    params["target"].pop("grids", None)
    params["training"]["profile"] = "default"
    params["training"]["profiles"]["default"].update(epochs=1, batch_size=4, crop_px=4, base_channels=4, depth=2,
                                                     min_grid_px=0, crops_per_image=1)
    params["training"]["pretrain"].update(epochs=1, points_per_scene=2, finetune_epochs=1, extra_scenes=2)
    # the sim-to-real benchmark off (a test turns it on with a fake_real_folder): job counts stay those of the chain
    params["sim_to_real"] = {"enabled": False}
    return params


def chain_targets(points: tuple[str, ...]) -> tuple[str, ...]:
    """The ends of ``points``' chains (each point's metrics and compression results): every rule but the aggregate,
    for the tests that build a few points and no spec."""
    return tuple(f"results/points/{point}/{name}" for point in points for name in ("metrics.json", "compression.json"))


def sim_to_real_params(params: dict, path: str, enabled: bool | str = True) -> dict:
    """``params`` with the sim-to-real benchmark on ``path`` (relative to the workspace), as params.yaml has it."""
    return {**params, "sim_to_real": {"enabled": enabled, "path": path, "gsd_m": 0.135, "white_fraction": 1.0,
                                      "seed": 0}}


def fake_real_folder(folder: Path, n: int = 3, size: tuple[int, int] = (150, 200), seed: int = 0) -> Path:
    """A stand-in for the KIT AIS folder (not in CI): ``n`` small 8-bit sRGB PNGs of grey streets with a few
    coloured cars (axis-aligned rectangles), a YOLO .txt of their boxes each (class 0, normalised cx cy w h)
    and an aerial.names listing the classes."""
    import numpy as np
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "aerial.names").write_text("car\ntruck\nbus\nminibus\ncyclist\n")
    rng = np.random.default_rng(seed)
    h, w = size
    for i in range(n):
        img = np.clip(rng.normal(110, 12, (h, w, 3)), 0, 255)
        img[:, w // 3: w // 3 + 8] = 200  # a road marking
        lines = []
        for _ in range(6):
            bh, bw = (int(v) for v in rng.integers(12, 34, 2))
            y, x = int(rng.integers(0, h - bh)), int(rng.integers(0, w - bw))
            img[y:y + bh, x:x + bw] = rng.integers(20, 240, 3)
            lines.append(f"0 {(x + bw / 2) / w:.6f} {(y + bh / 2) / h:.6f} {bw / w:.6f} {bh / h:.6f}")
        Image.fromarray(img.astype(np.uint8)).save(folder / f"MOS{i}.png")
        (folder / f"MOS{i}.txt").write_text("\n".join(lines) + "\n")
    return folder


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
    # what `dvc config core.autostage false` writes into the empty config `dvc init` leaves (one DVC start-up less)
    (root / ".dvc" / "config").write_text("[core]\n    autostage = false\n")
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
