"""A team's own camera raws as the workflow's source (params.yaml ``source.dataset: raws``), from real file formats.

``raw_folder.make_raw_folder`` writes, at test time, 4 DNG camera raws (read back by rawpy/LibRaw), a car mask PNG
each, and flat and dark series of a known gain (0.5 DN/e-) and read noise (4 e-). The workflow runs from that
folder at tiny size as README's "Your own data" says (photon transfer -> ingest -> emulate -> pretrain -> train ->
evaluate -> compress) for two of its points, and the calibration it records in results/ and in the store matches
the known camera within its stated uncertainty. The aggregate and the spec are not built: they read only the
points' metrics and compression results, whatever the source (the whole chain to the spec runs in
test_workflow_jobs.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from raw_folder import TRUE_GAIN_DN_PER_E, TRUE_READ_NOISE_E, make_raw_folder
from workflow_workspace import chain_targets, make_workspace, needs_tools, tiny_params
from workflow_workspace import run as _run

#: |fit - truth| / stated uncertainty above which the calibration contradicts the known camera (3 sigma: a
#: correct fit fails this 0.3 % of the time; the seeds are fixed, so the test is deterministic).
Z_MAX = 3.0
#: Two points' results: every rule of the chain from the raws, without the aggregate and the other points
POINTS = ("nominal", "focal_length_m-1.2")
TARGETS = chain_targets(POINTS)


def raws_params(calibration: dict | None = None) -> dict:
    """tiny_params with the raws source on the workspace's ``raws`` folder (photon transfer by default)."""
    params = tiny_params()
    params["source"]["dataset"] = "raws"
    params["source"]["raws"] = {"path": "raws", "labels": "mask",
                                "calibration": calibration if calibration is not None else
                                {"flats": "raws/flats", "darks": "raws/darks", "frames_per_level": 2}}
    return params


@needs_tools
@pytest.mark.workflow
def test_workflow_runs_from_dng_raws_and_recovers_the_camera(tmp_path):
    root = make_workspace(tmp_path / "ws", raws_params())
    make_raw_folder(root / "raws")
    # the same configuration given as --configfile over the repository's params, as README's "Your own data" does
    (root / "my.yaml").write_text(yaml.safe_dump({"source": raws_params()["source"]}))
    dry = _run(["snakemake", "--cores", "2", "--dry-run", "--configfile", "my.yaml"], root).stdout
    assert "rule source_camera:" in dry and "metraw calibrate --flats raws/flats --darks raws/darks" in dry
    assert "rule aggregate:" in dry  # the whole workflow would run from the raws; the test builds two points
    _run(["snakemake", "--cores", "2", "--configfile", "my.yaml", "--", *TARGETS], root)

    camera = json.loads((root / "results" / "source" / "camera.json").read_text())
    report = json.loads((root / "results" / "source" / "camera_calibration.json").read_text())
    assert report["method"] == "photon_transfer" and len(report["files"]["flats"]) == 10
    k, k_u = camera["gain_dn_per_e"], camera["uncertainty"]["gain_dn_per_e"]
    rn, rn_u = camera["read_noise_e"], camera["uncertainty"]["read_noise_e"]
    print(f"calibration: K = {k:.4f} +- {k_u:.4f} DN/e- (true {TRUE_GAIN_DN_PER_E}), "
          f"read noise = {rn:.3f} +- {rn_u:.3f} e- (true {TRUE_READ_NOISE_E})")
    assert 0 < k_u < 0.05 * k and 0 < rn_u < 0.1 * rn
    assert abs(k - TRUE_GAIN_DN_PER_E) / k_u < Z_MAX
    assert abs(rn - TRUE_READ_NOISE_E) / rn_u < Z_MAX
    # the geometry is params' camera; the exposure is the DNGs' own tag (1 ms), not params' (also 1 ms here)
    assert camera["pixel_pitch_m"] == pytest.approx(2.41e-6) and camera["altitude_m"] == pytest.approx(250.0)

    from metraw.io.store import RawStore

    store = RawStore.open(root / "data" / "source.zarr")
    assert len(store) == 4 and store.attrs["camera_profile"]["gain_dn_per_e"] == k
    image = store[0]
    assert image.profile.gain_dn_per_e == k and image.profile.uncertainty["gain_dn_per_e"] == k_u
    assert image.profile.cfa_pattern == "RGGB" and image.profile.black_level_dn == 128
    assert image.meta["labels"] == "mask" and 0 < float(image.mask.mean()) < 1
    for point in POINTS:
        metrics = json.loads((root / "results" / "points" / point / "metrics.json").read_text())
        compression = json.loads((root / "results" / "points" / point / "compression.json").read_text())
        assert 0 <= metrics["iou"] <= 1 and metrics["n_images"] >= 1 and compression["overall"]["bits_per_pixel"] > 0
    # nothing left to do: the calibration and the store are up to date
    assert "Nothing to be done" in _run(["snakemake", "--cores", "2", "--dry-run", "--configfile", "my.yaml", "--",
                                         *TARGETS], root).stdout


@needs_tools
def test_dvc_yaml_of_a_raws_source_calibrates_first(tmp_path):
    root = make_workspace(tmp_path / "ws", raws_params())
    stages = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]
    assert stages["source_check"]["deps"][0] == "raws" and stages["source_check"]["outs"] == [
        "results/source/folder_check.json"]
    assert stages["source_camera"]["deps"][:4] == ["results/source/folder_check.json", "raws", "raws/flats",
                                                   "raws/darks"]
    assert stages["source_camera"]["outs"] == ["results/source/camera.json",
                                               "results/source/camera_calibration.json"]
    assert stages["source_store"]["deps"][:2] == ["results/source/camera.json", "raws"]


@needs_tools
@pytest.mark.parametrize("calibration, expect", [
    ({"profile": "camera.json"}, "--profile camera.json"),
    ({}, "metraw calibrate raws --camera"),
])
def test_the_other_calibration_methods_are_one_command_each(tmp_path, calibration, expect):
    root = make_workspace(tmp_path / "ws", raws_params(calibration))
    make_raw_folder(root / "raws", n_images=1, size_px=64, flat_px=8)
    (root / "camera.json").write_text("{}")
    dry = _run(["snakemake", "--cores", "2", "--dry-run", "--printshellcmds"], root).stdout
    assert expect in dry, dry[-2000:]
    # the folder is checked first, with the training's split: the calibration waits for it
    assert "metraw check-folder raws --kind raws --labels mask --test-fraction 0.2 --split-seed 0" in dry


@needs_tools
@pytest.mark.parametrize("breakage, message", [
    ("no folder", "raws: source.raws.path folder does not exist"),
    ("empty folder", "directory holds no supported image files"),
    ("no darks", "needs both flats and darks"),
])
def test_a_bad_raws_source_is_one_line_before_anything_runs(tmp_path, breakage, message):
    params = raws_params({"flats": "raws/flats"} if breakage == "no darks" else None)
    root = make_workspace(tmp_path / "ws", raws_params())  # dvc.yaml generated from a valid config
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    if breakage != "no folder":
        (root / "raws").mkdir()
    if breakage == "no darks":
        make_raw_folder(root / "raws", n_images=1, size_px=64, flat_px=8)
    proc = _run(["snakemake", "--cores", "2", "--dry-run"], root, check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("metraw workflow: error:")]
    assert len(lines) == 1 and message in lines[0], proc.stderr[-2000:]
    assert not (root / "results").exists() and not (root / "data").exists()


@needs_tools
def test_a_photos_source_is_checked_before_its_ingest(tmp_path):
    from workflow_workspace import fake_real_folder

    params = tiny_params()
    params["source"]["dataset"] = "photos"
    params["source"]["photos"] = {"path": "photos", "gsd_m": 0.135, "labels": "yolo", "labels_class": ["car"],
                                  "white_fraction": 1.0, "seed": 0}
    root = make_workspace(tmp_path / "ws", params)
    fake_real_folder(root / "photos", n=5)
    stages = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]
    assert list(stages)[0] == "source_check" and stages["source_store"]["deps"][0] == "results/source/folder_check.json"
    dry = _run(["snakemake", "--cores", "2", "--dry-run", "--printshellcmds", "--", "data/source.zarr"], root).stdout
    assert ("metraw check-folder photos --kind photos --labels yolo --car-class car --test-fraction 0.2 "
            "--split-seed 0 --out results/source/folder_check.json") in dry
    assert "metraw ingest photos --labels yolo --car-class car --camera" in dry
