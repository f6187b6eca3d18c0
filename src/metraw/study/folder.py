"""One pass over a user's source folder before anything runs (``metraw check-folder``; the workflow's first rule
for a ``raws`` or ``photos`` source, workflow/rules/source.smk).

Every image is opened and its label file read: each image has its mask (``STEM_mask.png``) or its YOLO boxes
(``STEM.txt``, class names from ``*.names``, ``classes.txt`` or ``data.yaml``); a mask has its image's height x
width and a valid value range (``metraw.io.labels.mask_fraction``) and is neither all car nor unreadable; the
raws share one CFA pattern and one ADC bit depth; no two images share a name but for its case (``IMG.dng`` and
``IMG.DNG`` would share one label file); no label file names a missing image. Over the folder: some image holds a
labelled car, and so does the test split (``test_split``, the training's split by image index), which needs at
least one training and one test image. Sidecar files (``.xmp``, notes, ``.DS_Store``) are not images and are not
read. Every problem found is one line (``FolderProblems``); the pass reads each file once and writes nothing.
Images of different sizes are read as they are (each image keeps its own shape).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any, Callable

import numpy as np

from metraw.errors import MetrawError

#: Problems listed one a line before the rest are counted.
MAX_LISTED = 20


class FolderProblems(MetrawError):
    """Every problem of a source folder: the message is the only problem or a count, ``details`` one line each
    (the first ``MAX_LISTED``, then how many more); the CLI prints the message and then each detail line."""

    def __init__(self, folder: Path, problems: list[str]):
        self.problems = list(problems)
        if len(problems) == 1:
            super().__init__(problems[0])
            self.details: list[str] = []
        else:
            super().__init__(f"{folder}: {len(problems)} problems in the source folder (nothing run or written):")
            more = len(problems) - MAX_LISTED
            self.details = problems[:MAX_LISTED] + ([f"... and {more} more"] if more > 0 else [])


def _label_problems(path: Path, shape: tuple[int, int], labels: str, names: list[str] | None,
                    car_classes) -> tuple[list[str], int, float]:
    """(problems, cars in the image, car area fraction) of ``path``'s label file; cars are YOLO car boxes, or 1
    for a mask with any car pixel (a mask does not count its cars)."""
    from metraw.io.labels import (boxes_to_pixels, box_area_fraction, car_class_ids, mask_file_for,
                                  read_mask_image, read_yolo)

    if labels == "mask":
        mask_path = mask_file_for(path)
        if mask_path is None:
            return [f"{path}: no mask image {path.stem}_mask.png"], 0, 0.0
        try:
            mask = read_mask_image(mask_path, shape)
        except MetrawError as exc:
            return [str(exc)], 0, 0.0
        if mask.size and float(mask.min()) >= 1.0:
            return [f"{mask_path}: every pixel is car (an inverted mask? 0 is background, 1 or 255 car)"], 0, 1.0
        share = float(mask.mean()) if mask.size else 0.0
        return [], int(share > 0), share
    yolo = path.with_suffix(".txt")
    if not yolo.is_file():
        return [f"{path}: no YOLO label file {yolo.name}"], 0, 0.0
    try:
        boxes = read_yolo(yolo)
    except MetrawError as exc:
        return [str(exc)], 0, 0.0
    if names is None:
        return [], 0, 0.0  # the folder's missing class names are one problem of their own
    bad = sorted({int(c) for c in boxes[:, 0] if int(c) >= len(names)})
    if bad:
        return [f"{yolo}: class ids {bad} not in the {len(names)} class names"], 0, 0.0
    is_car = np.isin(boxes[:, 0].astype(int), sorted(car_class_ids(names, car_classes)))
    share = float(box_area_fraction(boxes_to_pixels(boxes[is_car], shape), shape).mean()) if is_car.any() else 0.0
    return [], int(is_car.sum()), share


def _image(path: Path, kind: str) -> tuple[tuple[int, int], str | None, int | None]:
    """(shape, CFA pattern, ADC bits) of one image file, read without labels; a photo has no CFA (None)."""
    if kind == "photos":
        from metraw.io.pictures import decode_image

        rgb = decode_image(path)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[-1] not in (3, 4):
            raise MetrawError(f"{path}: a photo must be 8-bit RGB, got {rgb.dtype} of shape {rgb.shape}")
        return tuple(rgb.shape[:2]), None, None
    from metraw.io import read_raw

    image = read_raw(path, labels="none")
    return tuple(image.shape), image.profile.cfa_pattern, int(image.profile.adc_bits)


def _orphan_labels(folder: Path, stems: set[str], labels: str) -> list[str]:
    """Label files whose image is not in the folder: masks, and (for YOLO labels) text files that read as YOLO
    boxes; other text files are notes and ignored."""
    from metraw.io.labels import image_of_mask, is_label_file, read_yolo

    out = []
    for f in sorted(folder.iterdir()):
        if not f.is_file() or f.name.startswith("."):
            continue
        if is_label_file(f) and image_of_mask(f) not in stems:
            out.append(f"{f}: mask of a missing image {image_of_mask(f)}.*")
        elif labels == "yolo" and f.suffix.lower() == ".txt" and f.name != "classes.txt" and f.stem not in stems:
            try:
                rows = read_yolo(f)
            except MetrawError:
                continue  # not YOLO lines: a note
            if len(rows):
                out.append(f"{f}: YOLO labels of a missing image {f.stem}.*")
    return out


def check_folder(folder: str | Path, *, kind: str = "raws", labels: str = "mask",
                 car_classes: list[str] | tuple[str, ...] | None = None,
                 test_split: Callable[[int], list[int]] | None = None) -> dict[str, Any]:
    """Check the source folder (module docstring) and return its summary: images, shapes, CFA pattern, bit depth,
    images and cars labelled, and the test split's images and cars (``test_split(n)``: the test images' indices
    among ``n``; None skips the split). Every problem found raises one ``FolderProblems``."""
    from metraw.io import image_files
    from metraw.io.labels import find_class_names

    folder = Path(folder)
    if kind not in ("raws", "photos"):
        raise MetrawError(f"unknown source kind {kind!r} (raws or photos)")
    if labels not in ("mask", "yolo"):
        raise MetrawError(f"unknown label kind {labels!r} (mask or yolo)")
    files = image_files([folder])
    problems: list[str] = []
    names = None
    if labels == "yolo":
        try:
            names = find_class_names(folder)
            if names is None:
                problems.append(f"{folder}: YOLO labels need class names (a *.names, classes.txt or data.yaml "
                                "with names: in the folder)")
            else:
                from metraw.io.labels import car_class_ids

                if not car_class_ids(names, car_classes):
                    problems.append(f"{folder}: no car class among the class names {names} (set labels_class)")
        except MetrawError as exc:
            problems.append(str(exc))
    by_lower = Counter(f.stem.lower() for f in files)
    for stem in sorted(s for s, n in by_lower.items() if n > 1):
        same = [f.name for f in files if f.stem.lower() == stem]
        problems.append(f"{folder}: {' and '.join(same)} are images of one name (they would share one label file)")
    shapes, first, cars, shares, read = [], None, [], [], 0
    for f in files:
        try:
            shape, pattern, bits = _image(f, kind)
        except MetrawError as exc:
            problems.append(str(exc))
            cars.append(0)
            shares.append(0.0)
            continue
        read += 1
        shapes.append(shape)
        if pattern is not None:
            first = first or (f, pattern, bits)
            if pattern != first[1]:
                problems.append(f"{f}: CFA pattern {pattern} differs from {first[1]} of {first[0].name}; one folder "
                                "holds the raws of one sensor")
            elif bits != first[2]:
                problems.append(f"{f}: {bits}-bit data differ from the {first[2]} bits of {first[0].name}; one "
                                "folder holds the raws of one sensor")
        found, n_cars, share = _label_problems(f, shape, labels, names, car_classes)
        problems += found
        cars.append(n_cars)
        shares.append(share)
    problems += _orphan_labels(folder, {f.stem for f in files}, labels)
    labelled = [i for i, c in enumerate(cars) if c > 0]
    test: list[int] = []
    if test_split is not None:
        try:
            test = [int(i) for i in test_split(len(files))]
        except MetrawError as exc:
            problems.append(f"{folder}: {exc}")
    if read == len(files) and not problems:
        what = "mask" if labels == "mask" else "YOLO file"
        if not labelled:
            problems.append(f"{folder}: no labelled car in any of the {len(files)} images (every {what} is empty): "
                            "the study has nothing to segment")
        elif test_split is not None and not any(cars[i] for i in test):
            problems.append(f"{folder}: no labelled car in the test split (images "
                            f"{', '.join(files[i].name for i in test)}): the IoU would measure nothing")
    if problems:
        raise FolderProblems(folder, problems)
    return {"folder": str(folder), "kind": kind, "labels": labels, "images": len(files),
            "files": [f.name for f in files], "shapes": [list(s) for s in sorted(set(shapes))],
            "cfa_pattern": first[1] if first else None, "adc_bits": first[2] if first else None,
            "images_with_cars": len(labelled), "cars": int(sum(cars)) if labels == "yolo" else None,
            "car_area_fraction": float(np.mean(shares)) if shares else 0.0,
            "test_images": len(test) if test_split is not None else None,
            "test_images_with_cars": sum(1 for i in test if cars[i]) if test_split is not None else None,
            "test_cars": int(sum(cars[i] for i in test)) if labels == "yolo" and test_split is not None else None}
