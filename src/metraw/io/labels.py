"""Car labels of processed images: YOLO box files and mask images -> per-pixel car area fraction.

YOLO: one text line per object, ``class cx cy w h`` with the centre and size normalised by the
image width / height; boxes are axis-aligned rectangles. Class names come from a ``*.names``,
``classes.txt`` or ``data.yaml`` (``names:``) next to the images; the car classes are those named
(``labels_class``), by default ``CAR_CLASS_NAMES``. The mask
is the exact area fraction of each pixel covered by the union of the car boxes (pixel i spans
[i, i+1) in box coordinates) -- box-approximate, since a box is not a car's outline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metraw.errors import MetrawError

#: Class names counted as cars (motor vehicles: KIT/aerial-cars "car, truck, bus, minibus"; not "cyclist").
CAR_CLASS_NAMES = frozenset({"car", "truck", "bus", "minibus", "van", "pickup", "vehicle"})

MASK_SUFFIXES = ("_mask.png", ".mask.png")


#: Files that name a YOLO data set's classes, beside its images: Darknet's ``*.names`` / ``classes.txt`` (one name a
#: line) and the Ultralytics ``data.yaml`` (``names:`` a list, or a map of class id to name).
CLASS_FILE_PATTERNS = ("*.names", "classes.txt", "data.yaml", "data.yml")


def _names_from_file(path: Path) -> list[str]:
    """The class names one class-name file lists, in class-id order (``MetrawError`` naming the file)."""
    if path.suffix in (".yaml", ".yml"):
        from metraw.errors import read_yaml

        data = read_yaml(path, "YOLO data set file")
        names = data.get("names") if isinstance(data, dict) else None
        if isinstance(names, dict):
            try:
                ids = sorted(int(k) for k in names)
            except (TypeError, ValueError):
                raise MetrawError(f"{path}: names: map keys must be class ids 0, 1, ...") from None
            if ids != list(range(len(ids))):
                raise MetrawError(f"{path}: names: class ids {ids} are not 0 .. {len(ids) - 1}")
            names = [names.get(i, names.get(str(i))) for i in ids]
        if not isinstance(names, list):
            raise MetrawError(f"{path}: no names: list or map of the classes")
        names = ["" if n is None else str(n).strip() for n in names]
    else:
        names = [line.strip() for line in path.read_text(errors="replace").splitlines()]
        while names and not names[-1]:
            names.pop()
    if not names or any(not n for n in names):
        raise MetrawError(f"{path}: class-name file has empty entries")
    return names


def find_class_names(directory: Path) -> list[str] | None:
    """Class names from the class-name files in ``directory`` (``CLASS_FILE_PATTERNS``), else None; several files
    must list the same names."""
    candidates = sorted({c for pattern in CLASS_FILE_PATTERNS for c in directory.glob(pattern) if c.is_file()})
    if not candidates:
        return None
    lists = [_names_from_file(c) for c in candidates]
    if any(names != lists[0] for names in lists[1:]):
        raise MetrawError(f"{directory}: class-name files list different classes "
                          f"({', '.join(c.name for c in candidates)})")
    return lists[0]


def car_class_ids(names: list[str], car_classes: list[str] | tuple[str, ...] | None = None) -> set[int]:
    """Ids of the classes counted as cars: those named in ``car_classes`` (params ``labels_class``, case-insensitive;
    a name the data set does not list is a ``MetrawError``), by default those in ``CAR_CLASS_NAMES``."""
    if not car_classes:
        return {i for i, n in enumerate(names) if n.lower() in CAR_CLASS_NAMES}
    wanted = {c.lower() for c in car_classes}
    unknown = sorted(wanted - {n.lower() for n in names})
    if unknown:
        raise MetrawError(f"car class {', '.join(unknown)} (labels_class) is not among the data set's classes "
                          f"{names}")
    return {i for i, n in enumerate(names) if n.lower() in wanted}


def read_yolo(path: Path) -> np.ndarray:
    """Parse a YOLO label file -> (N, 5) float64 array [class, cx, cy, w, h]; strict about format."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise MetrawError(f"{path}: YOLO label file is not text") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != 5:
            raise MetrawError(f"{path}:{lineno}: malformed YOLO line (need 'class cx cy w h', got {len(fields)} fields)")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise MetrawError(f"{path}:{lineno}: malformed YOLO line (non-numeric field in {line.strip()!r})") from None
        cls, cx, cy, w, h = values
        if not all(np.isfinite(values)) or cls != int(cls) or cls < 0:
            raise MetrawError(f"{path}:{lineno}: malformed YOLO line (class must be a non-negative integer)")
        if not (0 <= cx <= 1 and 0 <= cy <= 1 and 0 < w <= 1 and 0 < h <= 1):
            raise MetrawError(f"{path}:{lineno}: YOLO box outside the normalised range [0, 1]: {line.strip()!r}")
        rows.append(values)
    return np.asarray(rows, dtype=np.float64).reshape(-1, 5)


def boxes_to_pixels(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """YOLO rows -> (N, 4) pixel rectangles [x0, y0, x1, y1] clipped to the image."""
    h, w = shape
    cx, cy, bw, bh = boxes[:, 1] * w, boxes[:, 2] * h, boxes[:, 3] * w, boxes[:, 4] * h
    rect = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
    return np.clip(rect, 0, [w, h, w, h])


def box_area_fraction(rects: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Exact fraction of each pixel covered by the union of axis-aligned rectangles, float32 (H, W).

    Coordinate compression: the cut lines of all rectangles and pixel edges split the image into
    cells that are wholly inside or outside the union; cell areas are summed per pixel.
    """
    h, w = shape
    if len(rects) == 0:
        return np.zeros(shape, np.float32)
    xs = np.unique(np.concatenate([np.arange(w + 1, dtype=np.float64), rects[:, 0], rects[:, 2]]))
    ys = np.unique(np.concatenate([np.arange(h + 1, dtype=np.float64), rects[:, 1], rects[:, 3]]))
    diff = np.zeros((len(ys), len(xs)), np.int32)
    xa, xb = np.searchsorted(xs, rects[:, 0]), np.searchsorted(xs, rects[:, 2])
    ya, yb = np.searchsorted(ys, rects[:, 1]), np.searchsorted(ys, rects[:, 3])
    np.add.at(diff, (ya, xa), 1)
    np.add.at(diff, (ya, xb), -1)
    np.add.at(diff, (yb, xa), -1)
    np.add.at(diff, (yb, xb), 1)
    covered = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:-1, :-1] > 0
    area = covered * np.diff(ys)[:, None] * np.diff(xs)[None, :]
    rows = np.add.reduceat(area, np.searchsorted(ys, np.arange(h)), axis=0)
    frac = np.add.reduceat(rows, np.searchsorted(xs, np.arange(w)), axis=1)
    return np.clip(frac, 0.0, 1.0).astype(np.float32)


def read_mask_image(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """A label mask image (PNG/TIFF) -> car area fraction in [0, 1] (``mask_fraction``); colour channels must agree
    (an alpha channel is dropped), the size must be the image's."""
    from metraw.io.pictures import decode_image

    m = decode_image(path)
    if m.ndim == 3:
        if m.shape[-1] in (2, 4):
            m = m[..., :-1]  # drop alpha
        if not all(np.array_equal(m[..., 0], m[..., i]) for i in range(1, m.shape[-1])):
            raise MetrawError(f"{path}: mask image has differing colour channels; need a single-band mask")
        m = m[..., 0]
    if m.shape != shape:
        raise MetrawError(f"{path}: mask shape {m.shape} differs from the image shape {shape}")
    return mask_fraction(m, path)


def mask_fraction(m: np.ndarray, path: Path | str) -> np.ndarray:
    """Mask values -> car area fraction (float32): 0 / 1 as they are; integers up to 255 / 255 (the 0-255
    convention, whatever the bit depth); a 16-bit mask with values above 255 / 65535; floats in [0, 1] as they are.
    Anything else (negative values, 32-bit values above 255, floats outside [0, 1]) is a ``MetrawError``."""
    kind = m.dtype.kind
    if kind == "b":
        return m.astype(np.float32)
    if kind in "iu":
        lo, hi = (int(m.min()), int(m.max())) if m.size else (0, 0)
        if lo >= 0 and hi <= 1:
            return m.astype(np.float32)
        if lo >= 0 and hi <= 255:
            return (m.astype(np.float64) / 255.0).astype(np.float32)
        if lo >= 0 and m.dtype == np.uint16:
            return (m.astype(np.float64) / 65535.0).astype(np.float32)
        raise MetrawError(f"{path}: mask values {lo}..{hi} outside 0 / 1 and 0-255 (area fraction; 0-65535 in a "
                          "16-bit mask)")
    if kind == "f":
        lo, hi = (float(np.min(m)), float(np.max(m))) if m.size else (0.0, 0.0)
        if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo and hi <= 1.0):
            raise MetrawError(f"{path}: mask values {lo:g}..{hi:g} outside [0, 1] (a float mask is the car area "
                              "fraction)")
        return m.astype(np.float32)
    raise MetrawError(f"{path}: mask dtype {m.dtype} not supported (need 8/16-bit integer, bool or float)")


def mask_file_for(image_path: Path) -> Path | None:
    """The mask image of ``image_path``: ``STEM_mask.png`` or ``STEM.mask.png`` beside it, the suffix in lower or
    upper case (``STEM_mask.PNG``, ``STEM_MASK.PNG``)."""
    for suffix in MASK_SUFFIXES:
        stem, ext = suffix.rsplit(".", 1)
        for name in (suffix, f"{stem}.{ext.upper()}", suffix.upper()):
            candidate = image_path.with_name(image_path.stem + name)
            if candidate.is_file():
                return candidate
    return None


def is_label_file(path: Path) -> bool:
    return any(path.name.lower().endswith(s) for s in MASK_SUFFIXES)


def image_of_mask(path: Path) -> str:
    """The image stem a mask file names (``IMG_0001_mask.png`` -> ``IMG_0001``)."""
    name = path.name
    for s in MASK_SUFFIXES:
        if name.lower().endswith(s):
            return name[: -len(s)]
    return path.stem


def attach_labels(image, path: Path, labels: str = "auto", class_names: list[str] | None = None,
                  car_classes: list[str] | tuple[str, ...] | None = None):
    """``image`` (a RawImage read from ``path``) with its car mask from the label file beside it.

    ``labels``: "mask" (``STEM_mask.png``, exact), "yolo" (``STEM.txt`` boxes: box-approximate, said so in
    ``meta['mask_kind']``; ``car_classes``: which classes are cars, ``car_class_ids``), "auto" (whichever exists,
    else none) or "none". A required label file that is
    missing, or a mask of another size than the image, is a ``MetrawError`` naming the file.
    """
    from metraw.raw.image import RawImage

    shape = image.shape
    yolo = path.with_suffix(".txt")
    mask_path = mask_file_for(path)
    kind, mask = labels, None
    if labels == "auto":
        kind = "yolo" if yolo.is_file() else "mask" if mask_path else "none"
    if kind == "yolo":
        if not yolo.is_file():
            raise MetrawError(f"{path}: no YOLO label file {yolo.name}")
        names = class_names if class_names is not None else find_class_names(path.parent)
        if names is None:
            raise MetrawError(f"{path}: YOLO labels need class names (a *.names, classes.txt or data.yaml "
                              "with names: next to it)")
        boxes = read_yolo(yolo)
        bad = sorted({int(c) for c in boxes[:, 0] if int(c) >= len(names)})
        if bad:
            raise MetrawError(f"{yolo}: class ids {bad} not in the {len(names)} class names")
        cars = car_class_ids(names, car_classes)
        is_car = np.isin(boxes[:, 0].astype(int), sorted(cars))
        mask = box_area_fraction(boxes_to_pixels(boxes[is_car], shape), shape)
        counts = {names[c]: int(np.sum(boxes[:, 0] == c)) for c in range(len(names))}
        image.meta.update({"labels": "yolo", "label_file": str(yolo), "mask_kind": "box-approximate: union of "
                           "axis-aligned YOLO boxes, area fraction per pixel", "boxes_per_class": counts,
                           "car_classes": [names[c] for c in sorted(cars)], "car_boxes": int(is_car.sum())})
    elif kind == "mask":
        if mask_path is None:
            raise MetrawError(f"{path}: no mask image {path.stem}{MASK_SUFFIXES[0]}")
        mask = read_mask_image(mask_path, shape)
        image.meta.update({"labels": "mask", "label_file": str(mask_path), "mask_kind": "mask image"})
    elif kind != "none":
        raise MetrawError(f"unknown label kind {labels!r} (use yolo, mask, none or auto)")
    if mask is None:
        return image
    return RawImage(data=image.data, profile=image.profile, mask=mask, flags=image.flags, provenance=image.provenance,
                    meta=image.meta)
