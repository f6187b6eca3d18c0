"""Car labels of processed images: YOLO box files and mask images -> per-pixel car area fraction.

YOLO: one text line per object, ``class cx cy w h`` with the centre and size normalised by the
image width / height; boxes are axis-aligned rectangles. Class names come from a ``*.names``
file (or ``classes.txt``) next to the images; the car classes are ``CAR_CLASS_NAMES``. The mask
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


def find_class_names(directory: Path) -> list[str] | None:
    """Class names from the single ``*.names`` file (or ``classes.txt``) in ``directory``, else None."""
    candidates = sorted(directory.glob("*.names")) or sorted(directory.glob("classes.txt"))
    if not candidates:
        return None
    if len(candidates) > 1:
        raise MetrawError(f"{directory}: several class-name files ({', '.join(c.name for c in candidates)})")
    names = [line.strip() for line in candidates[0].read_text(errors="replace").splitlines()]
    while names and not names[-1]:
        names.pop()
    if not names or any(not n for n in names):
        raise MetrawError(f"{candidates[0]}: class-name file has empty entries")
    return names


def car_class_ids(names: list[str]) -> set[int]:
    return {i for i, n in enumerate(names) if n.lower() in CAR_CLASS_NAMES}


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
    """A label mask image (PNG/TIFF) -> car area fraction in [0, 1]: 0/1 as is, else / dtype max."""
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
    if m.dtype.kind not in "ub":
        raise MetrawError(f"{path}: mask dtype {m.dtype} not supported (need 8/16-bit integer or bool)")
    if m.dtype.kind == "b" or m.max() <= 1:
        return m.astype(np.float32)
    return (m.astype(np.float64) / np.iinfo(m.dtype).max).astype(np.float32)


def mask_file_for(image_path: Path) -> Path | None:
    for suffix in MASK_SUFFIXES:
        candidate = image_path.with_name(image_path.stem + suffix)
        if candidate.is_file():
            return candidate
    return None


def is_label_file(path: Path) -> bool:
    return any(path.name.endswith(s) for s in MASK_SUFFIXES)


def attach_labels(image, path: Path, labels: str = "auto", class_names: list[str] | None = None):
    """``image`` (a RawImage read from ``path``) with its car mask from the label file beside it.

    ``labels``: "mask" (``STEM_mask.png``, exact), "yolo" (``STEM.txt`` boxes: box-approximate, said so in
    ``meta['mask_kind']``), "auto" (whichever exists, else none) or "none". A required label file that is
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
            raise MetrawError(f"{path}: YOLO labels need class names (a *.names or classes.txt file next to it)")
        boxes = read_yolo(yolo)
        bad = sorted({int(c) for c in boxes[:, 0] if int(c) >= len(names)})
        if bad:
            raise MetrawError(f"{yolo}: class ids {bad} not in the {len(names)} class names")
        cars = car_class_ids(names)
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
