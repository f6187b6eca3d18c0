"""A user's source folder as it arrives (README "Your own data"), through ``metraw check-folder`` (the workflow's
first rule for a raws or photos source, metraw.study.folder) and, for the first case, the workflow itself.

Refused: every problem named, one line each, exit status 2, nothing written, inputs unchanged. Read: what a user's
folder may hold and the study takes (stated per case): an RGBA or 16-bit mask, raws of different sizes, sidecar
files, upper-case extensions, YOLO class names in a data.yaml. The raws are DNGs LibRaw reads
(``tests/raw_folder.py``)."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from PIL import Image

from raw_folder import WHITE_LEVEL_DN, write_dng

from . import _inputs as make
from ._check import _main, refused, tree

SHAPE = (48, 64)


def _mask(shape=SHAPE, value=255, dtype=np.uint8) -> np.ndarray:
    m = np.zeros(shape, dtype)
    m[10:20, 10:30] = value
    return m


def _raw(folder: Path, name: str, pattern: str = "RGGB", shape=SHAPE, mask=None, suffix: str = ".dng",
         white: int = WHITE_LEVEL_DN, mask_name: str | None = None) -> Path:
    """One DNG of ``shape`` and its mask PNG (``mask``: an array, default a car block; False: none)."""
    folder.mkdir(parents=True, exist_ok=True)
    data = np.random.default_rng(len(name)).poisson(600.0, shape).clip(0, white)
    path = write_dng(folder / f"{name}{suffix}", data, pattern, white_level_dn=white)
    if mask is not False:
        m = _mask(shape) if mask is None else mask
        Image.fromarray(m).save(folder / (mask_name or f"{name}_mask.png"))
    return path


def _folder(tmp_path: Path, n: int = 5, **kw) -> Path:
    for i in range(n):
        _raw(tmp_path / "raws", f"IMG_{i:04d}", **kw)
    return tmp_path / "raws"


def _check(tmp_path: Path, word: str, *extra: str) -> str:
    return refused(["check-folder", "raws", *extra], word, tmp_path, inprocess=True)


def _passes(tmp_path: Path, *extra: str, folder: str = "raws") -> dict:
    """check-folder succeeds on the folder; its summary (written to a JSON outside the case's folder)."""
    out = tmp_path.parent / f"{tmp_path.name}_summary.json"
    status, err = _main(["check-folder", folder, *extra, "--out", str(out)], tmp_path)
    assert status == 0, err
    return json.loads(out.read_text())


def _problems(tmp_path: Path, *extra: str) -> list[str]:
    """check-folder refuses with several problems: a header line counting them and one line each; nothing
    written, inputs unchanged. The problem lines."""
    before = tree(tmp_path)
    status, err = _main(["check-folder", "raws", *extra], tmp_path)
    lines = err.splitlines()
    assert status == 2, err
    assert lines[0].startswith("metraw check-folder: error: raws: ") and "problems in the source folder" in lines[0]
    assert tree(tmp_path) == before
    return [line.strip() for line in lines[1:]]


# ---------------------------------------------------------------- refused before anything runs
def test_every_mask_empty_is_refused(tmp_path):
    _folder(tmp_path, mask=np.zeros(SHAPE, np.uint8))
    _check(tmp_path, "no labelled car in any of the 5 images (every mask is empty)")


@pytest.mark.skipif(shutil.which("snakemake") is None, reason="snakemake is needed")
def test_the_workflow_refuses_every_mask_empty_before_the_calibration(tmp_path):
    """README's recipe on a folder of empty masks: the first rule fails within seconds, with one line in its
    log; no calibration, no store, no spec."""
    from workflow_workspace import make_workspace, run, tiny_params

    params = tiny_params()
    params["source"]["dataset"] = "raws"
    params["source"]["raws"] = {"path": "raws", "labels": "mask"}
    root = make_workspace(tmp_path / "ws", params)
    _folder(root, mask=np.zeros(SHAPE, np.uint8))
    t0 = time.perf_counter()
    proc = run(["snakemake", "--cores", "1"], root, check=False)
    elapsed = time.perf_counter() - t0
    assert proc.returncode != 0 and elapsed < 60, (elapsed, proc.stderr[-2000:])
    log = [line for line in (root / "logs" / "source_check.log").read_text().splitlines()]
    assert log == ["metraw check-folder: error: raws: no labelled car in any of the 5 images (every mask is empty): "
                   "the study has nothing to segment"]
    assert "no labelled car" in proc.stdout + proc.stderr  # on the terminal too
    assert not (root / "results" / "source" / "camera.json").exists() and not (root / "data" / "source.zarr").exists()
    assert not (root / "results" / "spec.yaml").exists()


def test_a_missing_mask_a_mixed_cfa_pattern_and_a_mask_of_the_wrong_size_in_one_run(tmp_path):
    _folder(tmp_path, n=4)
    _raw(tmp_path / "raws", "b_missing", mask=False)
    _raw(tmp_path / "raws", "c_grbg", "GRBG")
    _raw(tmp_path / "raws", "d_small", mask=_mask((SHAPE[0], SHAPE[1] - 2)))
    lines = _problems(tmp_path)
    assert len(lines) == 3
    assert lines[0] == "raws/b_missing.dng: no mask image b_missing_mask.png"
    assert lines[1].startswith("raws/c_grbg.dng: CFA pattern GRBG differs from RGGB of IMG_0000.dng")
    assert lines[2] == f"raws/d_small_mask.png: mask shape {(SHAPE[0], SHAPE[1] - 2)} differs from the image shape {SHAPE}"


def test_more_than_twenty_problems_are_listed_twenty_then_counted(tmp_path):
    _folder(tmp_path, n=25, mask=False)
    lines = _problems(tmp_path)
    assert len(lines) == 21 and lines[-1] == "... and 5 more"
    assert all("no mask image" in line for line in lines[:20])


def test_mixed_bit_depths(tmp_path):
    _folder(tmp_path)
    _raw(tmp_path / "raws", "z_14bit", white=16383)
    _check(tmp_path, "raws/z_14bit.dng: 14-bit data differ from the 12 bits of IMG_0000.dng")


def test_a_mask_all_ones_is_refused_as_every_pixel_car(tmp_path):
    """0/1 masks are read as they are, so a mask of ones everywhere says every pixel is a car: refused (most likely
    an inverted mask), naming the file."""
    _folder(tmp_path)
    _raw(tmp_path / "raws", "z_ones", mask=np.ones(SHAPE, np.uint8))
    _check(tmp_path, "raws/z_ones_mask.png: every pixel is car")


@pytest.mark.parametrize("values, dtype, word", [
    (1000, np.int32, "mask values 0..1000 outside 0 / 1 and 0-255"),
    (-1, np.int16, "mask values -1..0 outside 0 / 1 and 0-255"),
    (1.5, np.float32, "mask values 0..1.5 outside [0, 1]"),
])
def test_mask_values_outside_0_1_and_0_255_are_refused(tmp_path, values, dtype, word):
    _folder(tmp_path)
    tifffile.imwrite(tmp_path / "raws" / "IMG_0001_mask.tif", _mask(value=values, dtype=dtype))
    os.remove(tmp_path / "raws" / "IMG_0001_mask.png")
    (tmp_path / "raws" / "IMG_0001_mask.tif").rename(tmp_path / "raws" / "IMG_0001_mask.png")  # a TIFF named .png
    _check(tmp_path, f"raws/IMG_0001_mask.png: {word}")


def test_a_mask_with_differing_colour_channels_is_refused(tmp_path):
    _folder(tmp_path)
    rgb = np.stack([_mask(), _mask(), np.zeros(SHAPE, np.uint8)], axis=-1)
    Image.fromarray(rgb).save(tmp_path / "raws" / "IMG_0002_mask.png")
    _check(tmp_path, "raws/IMG_0002_mask.png: mask image has differing colour channels")


def test_img_dng_and_IMG_DNG_side_by_side_are_refused(tmp_path):
    """Two images whose names differ in case only would share one label file (IMG_mask.png): refused."""
    _folder(tmp_path)
    _raw(tmp_path / "raws", "IMG", suffix=".dng")
    _raw(tmp_path / "raws", "IMG", suffix=".DNG", mask=False)
    _check(tmp_path, "IMG.DNG and IMG.dng are images of one name")


def test_too_few_images_to_split(tmp_path):
    _folder(tmp_path, n=2)  # 2 x 0.2 rounds to no test image
    _check(tmp_path, "cannot split 2 images with test_fraction 0.2")


def test_no_car_in_the_test_split(tmp_path):
    _folder(tmp_path)
    Image.fromarray(np.zeros(SHAPE, np.uint8)).save(tmp_path / "raws" / "IMG_0002_mask.png")  # split seed 0: test
    _check(tmp_path, "no labelled car in the test split (images IMG_0002.dng)")


def test_a_mask_of_a_missing_image(tmp_path):
    _folder(tmp_path)
    Image.fromarray(_mask()).save(tmp_path / "raws" / "IMG_0009_mask.png")
    _check(tmp_path, "raws/IMG_0009_mask.png: mask of a missing image IMG_0009")


def test_yolo_labels_of_a_missing_image(tmp_path):
    _yolo_folder(tmp_path)
    (tmp_path / "raws" / "IMG_0009.txt").write_text("0 0.5 0.5 0.2 0.2\n")
    _check(tmp_path, "raws/IMG_0009.txt: YOLO labels of a missing image", "--labels", "yolo")


def test_a_corrupt_raw_is_named(tmp_path):
    _folder(tmp_path)
    make.truncate(tmp_path / "raws" / "IMG_0003.dng", 0.3)
    line = _check(tmp_path, "raws/IMG_0003.dng")
    assert "IMG_0003" in line


# ---------------------------------------------------------------- YOLO class names
def _yolo_folder(tmp_path: Path, names_file: tuple[str, str] | None = ("classes.txt", "car\ntruck\n"),
                 class_id: int = 0) -> Path:
    folder = tmp_path / "raws"
    for i in range(5):
        _raw(folder, f"IMG_{i:04d}", mask=False)
        (folder / f"IMG_{i:04d}.txt").write_text(f"{class_id} 0.3 0.3 0.2 0.25\n1 0.7 0.7 0.1 0.1\n")
    if names_file:
        (folder / names_file[0]).write_text(names_file[1])
    return folder


def test_yolo_without_class_names_is_refused(tmp_path):
    _yolo_folder(tmp_path, names_file=None)
    _check(tmp_path, "YOLO labels need class names (a *.names, classes.txt or data.yaml", "--labels", "yolo")


@pytest.mark.parametrize("names", [["car", "person"], {0: "car", 1: "person"}])
def test_data_yaml_names_as_a_list_or_a_map_are_read(tmp_path, names):
    _yolo_folder(tmp_path, ("data.yaml", yaml.safe_dump({"path": ".", "names": names})))
    summary = _passes(tmp_path, "--labels", "yolo")
    assert summary["cars"] == 5 and summary["images_with_cars"] == 5 and summary["test_cars"] == 1


def test_data_yaml_names_with_a_gap_in_the_ids_is_refused(tmp_path):
    _yolo_folder(tmp_path, ("data.yaml", "names: {0: car, 2: person}\n"))
    _check(tmp_path, "names: class ids [0, 2] are not 0 .. 1", "--labels", "yolo")


def test_class_name_files_that_disagree_are_refused(tmp_path):
    _yolo_folder(tmp_path, ("classes.txt", "car\nperson\n"))
    (tmp_path / "raws" / "data.yaml").write_text("names: [person, car]\n")
    _check(tmp_path, "class-name files list different classes (classes.txt, data.yaml)", "--labels", "yolo")


def test_labels_class_picks_which_class_is_car(tmp_path):
    """A data set whose car class is not named "car": none counted by default (refused: nothing to segment), every
    box of it with --car-class (params.yaml labels_class)."""
    _yolo_folder(tmp_path, ("classes.txt", "automobile\nperson\n"))
    _check(tmp_path, "no car class among the class names ['automobile', 'person'] (set labels_class)",
           "--labels", "yolo")
    summary = _passes(tmp_path, "--labels", "yolo", "--car-class", "automobile")
    assert summary["cars"] == 5
    _check(tmp_path, "car class bus (labels_class) is not among", "--labels", "yolo", "--car-class", "bus")


def test_class_ids_beyond_the_names_are_refused(tmp_path):
    _yolo_folder(tmp_path, ("data.yaml", "names: [car, person]\n"), class_id=4)
    assert _problems(tmp_path, "--labels", "yolo") == [f"raws/IMG_{i:04d}.txt: class ids [4] not in the 2 class "
                                                       "names" for i in range(5)]


def test_every_yolo_file_without_a_car_box_is_refused(tmp_path):
    _yolo_folder(tmp_path, ("classes.txt", "car\nperson\n"), class_id=1)
    _check(tmp_path, "no labelled car in any of the 5 images (every YOLO file is empty)", "--labels", "yolo")


# ---------------------------------------------------------------- read as they are
def test_an_rgba_mask_is_read_without_its_alpha(tmp_path):
    _folder(tmp_path)
    rgba = np.stack([_mask()] * 3 + [np.full(SHAPE, 255, np.uint8)], axis=-1)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "raws" / "IMG_0001_mask.png")
    summary = _passes(tmp_path)
    assert summary["images_with_cars"] == 5
    assert summary["car_area_fraction"] == pytest.approx(200 / (SHAPE[0] * SHAPE[1]))


@pytest.mark.parametrize("full", [65535, 255])
def test_a_16_bit_mask_is_read_as_0_65535_or_0_255(tmp_path, full):
    """A 16-bit mask: values up to 255 are the 0-255 convention saved in 16 bits, larger ones 0-65535; a car pixel
    is 1 either way."""
    from metraw.io.labels import read_mask_image

    _folder(tmp_path)
    path = tmp_path / "raws" / "IMG_0001_mask.png"
    Image.fromarray(_mask(value=full, dtype=np.uint16)).save(path)
    assert np.asarray(Image.open(path)).dtype == np.uint16 or Image.open(path).mode.startswith("I;16")
    frac = read_mask_image(path, SHAPE)
    assert frac.max() == 1.0 and frac.sum() == 200
    assert _passes(tmp_path)["images_with_cars"] == 5


def test_raws_of_different_sizes_are_read_each_at_its_own_size(tmp_path):
    _folder(tmp_path, n=4)
    _raw(tmp_path / "raws", "IMG_9999", shape=(64, 96))
    summary = _passes(tmp_path)
    assert summary["shapes"] == [list(SHAPE), [64, 96]] and summary["images"] == 5
    status, err = _main(["ingest", "raws", "--labels", "mask", "--out", str(tmp_path.parent / "d.zarr")], tmp_path)
    assert status == 0, err
    from metraw.io.store import RawStore

    assert sorted({RawStore.open(tmp_path.parent / "d.zarr")[i].shape for i in range(5)}) == [SHAPE, (64, 96)]


def test_sidecar_files_are_ignored(tmp_path):
    folder = _folder(tmp_path)
    (folder / "IMG_0000.xmp").write_text("<x:xmpmeta/>")
    (folder / "IMG_0000.dng.xmp").write_text("<x:xmpmeta/>")
    (folder / "notes.txt").write_text("flight 3, 250 m, overcast\n")
    (folder / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1")
    summary = _passes(tmp_path)
    assert summary["files"] == [f"IMG_{i:04d}.dng" for i in range(5)]


def test_upper_case_extensions_are_read(tmp_path):
    for i in range(5):
        _raw(tmp_path / "raws", f"IMG_{i:04d}", suffix=".DNG", mask_name=f"IMG_{i:04d}_mask.PNG")
    summary = _passes(tmp_path)
    assert summary["files"] == [f"IMG_{i:04d}.DNG" for i in range(5)] and summary["images_with_cars"] == 5


def test_a_photos_folder_with_data_yaml(tmp_path):
    from workflow_workspace import fake_real_folder

    folder = fake_real_folder(tmp_path / "photos", n=5)
    (folder / "aerial.names").unlink()
    (folder / "data.yaml").write_text("names: {0: car, 1: truck, 2: bus, 3: minibus, 4: cyclist}\n")
    summary = _passes(tmp_path, "--kind", "photos", "--labels", "yolo", folder="photos")
    assert summary["cars"] == 30 and summary["cfa_pattern"] is None and summary["test_images"] == 1
