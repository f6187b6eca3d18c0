"""The workflow's source kinds (params.yaml ``source.dataset``) and the files each one reads.

- ``synthetic``: the embedded scene generator (``metraw scenes``); no files.
- ``raws``: a team's own calibrated camera raws (DNG and every format ``metraw ingest`` reads) in one folder,
  a car mask beside each (``STEM_mask.png``; or YOLO boxes ``STEM.txt``, box-approximate), and the camera's
  calibration: photon transfer from flat and dark frames (EMVA 1288) when ``calibration.flats`` and ``darks``
  are given, else a camera profile JSON (``calibration.profile``), else the single-frame noise fit of the raws.
  The geometry (pixel pitch, focal length, aperture, altitude) comes from ``source.camera``, the files' tags where
  they state it (exposure time, focal length), and ``raws.gsd_m`` (sets the altitude) when given.
- ``photos``: processed 8-bit photos (PNG, JPEG) with boxes or masks at a stated GSD, ingested as approximate raws.

``source_files`` checks the folders before anything runs (one ``MetrawError`` line naming what is missing);
the workflow's first rule for a raws or photos source then reads the whole folder once (``metraw check-folder``,
``check_folder_arguments``; ``metraw.study.folder``) and reports every problem it finds before the calibration.
Paths are relative to the workflow folder (``base``).
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError

def calibration_method(raws: dict[str, Any]) -> str:
    """``photon_transfer`` (flats and darks given), ``profile`` (a profile JSON given) or ``single_frame``."""
    cal = raws.get("calibration") or {}
    if cal.get("flats") or cal.get("darks"):
        return "photon_transfer"
    return "profile" if cal.get("profile") else "single_frame"


def _folder_files(path: str, what: str, base: Path) -> list[str]:
    from metraw.io import image_files

    folder = base / path
    if not folder.is_dir():
        raise MetrawError(f"{path}: {what} folder does not exist (relative to {base.resolve()})")
    return [str(Path(path) / f.name) for f in image_files([folder])]


def source_files(params: dict[str, Any], origin: str = "params.yaml", base: str | Path = ".") -> dict[str, list[str]]:
    """The files the source reads, by role (``images``, ``flats``, ``darks``, ``profile``; paths as given in
    params, relative to ``base``): empty for the synthetic source. A missing or empty folder, flats without
    darks (or the reverse) or a missing profile file is a ``MetrawError`` naming it."""
    source = params["source"]
    kind = source["dataset"]
    base = Path(base)
    if kind == "synthetic":
        return {}
    section = source.get(kind) or {}
    if not section.get("path"):
        raise MetrawError(f"{origin}: source.dataset is {kind} but source.{kind}.path is not given")
    try:
        files = {"images": _folder_files(section["path"], f"source.{kind}.path", base)}
        if kind == "photos":
            return files
        cal = section.get("calibration") or {}
        method = calibration_method(section)
        if method == "photon_transfer":
            if not (cal.get("flats") and cal.get("darks")):
                raise MetrawError(f"source.raws.calibration needs both flats and darks for a photon transfer "
                                  f"(given: {', '.join(k for k in ('flats', 'darks') if cal.get(k))})")
            files["flats"] = _folder_files(cal["flats"], "source.raws.calibration.flats", base)
            files["darks"] = _folder_files(cal["darks"], "source.raws.calibration.darks", base)
        elif method == "profile":
            if not (base / cal["profile"]).is_file():
                raise MetrawError(f"{cal['profile']}: camera profile (source.raws.calibration.profile) not found")
            files["profile"] = [cal["profile"]]
        return files
    except MetrawError as exc:
        raise MetrawError(f"{origin}: {exc}") from None


def car_class_arguments(section: dict[str, Any]) -> str:
    """`` --car-class NAME`` for each class of the source's ``labels_class`` (a name or a list), else ""."""
    names = section.get("labels_class") or []
    names = [names] if isinstance(names, str) else list(names)
    return "".join(f" --car-class {shlex.quote(str(n))}" for n in names)


def check_folder_arguments(params: dict[str, Any]) -> str:
    """The arguments of ``metraw check-folder`` for a raws or photos source: its folder, kind, labels, car classes
    and the training's train/test split (the split the study will score on)."""
    kind = params["source"]["dataset"]
    section = params["source"][kind]
    training = params.get("training") or {}
    labels = section.get("labels", "mask" if kind == "raws" else "yolo")
    return (f"{shlex.quote(section['path'])} --kind {kind} --labels {labels}{car_class_arguments(section)}"
            f" --test-fraction {training.get('test_fraction', 0.2)} --split-seed {training.get('split_seed', 0)}")
