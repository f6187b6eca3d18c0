"""Camera raw files (DNG, CR2, NEF, ARW, ...) through rawpy / LibRaw.

Reads the visible (active) area of the sensor as it was digitised: no demosaicing, no scaling.
Black level per channel: a scalar when the channels agree, else their mean with the spread noted
in ``meta`` and in the profile's black-level uncertainty. White level and CFA pattern come from
LibRaw (``white_level``, ``raw_colors_visible`` + ``color_desc``). The ADC bit depth is the
smallest that holds the white level. Gain and read noise are not in these files: they are marked
unknown (see ``metraw.io._unknown``).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from metraw.errors import MetrawError
from metraw.io._unknown import UNKNOWN_GAIN_DN_PER_E, UNKNOWN_READ_NOISE_E, unknown_uncertainty
from metraw.io.dn import as_dn, bits_needed
from metraw.raw.cfa import BAYER_PATTERNS
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

#: File suffixes handed to LibRaw without sniffing.
RAW_SUFFIXES = {".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2",
                ".raf", ".pef", ".srw", ".x3f", ".3fr", ".fff", ".iiq", ".erf", ".kdc", ".mef", ".mos",
                ".mrw", ".rwl", ".dcr"}


def read_camera_raw(path: Path) -> RawImage:
    import rawpy

    libraw_said: list[str] = []
    try:
        with _c_stderr_to(libraw_said), rawpy.imread(str(path)) as raw:
            data = np.array(raw.raw_image_visible, copy=True)
            colors = np.array(raw.raw_colors_visible[:2, :2])
            desc = raw.color_desc.decode("ascii", "replace")
            blacks = [float(b) for b in raw.black_level_per_channel]
            white = float(raw.white_level)
            sizes = raw.sizes
            raw_type = str(raw.raw_type)
            n_colors = int(raw.num_colors)
    except rawpy.LibRawFileUnsupportedError:
        raise MetrawError(f"{path}: unsupported format (LibRaw does not recognise it as a camera raw)") from None
    except (rawpy.LibRawError, OSError) as exc:
        detail = "; ".join(libraw_said) or (exc.args[0].decode("utf-8", "replace")
                                            if exc.args and isinstance(exc.args[0], bytes) else str(exc))
        raise MetrawError(f"{path}: corrupt or truncated camera raw ({detail})") from None
    if "Stack" in raw_type or data.ndim != 2:
        raise MetrawError(f"{path}: raw type {raw_type} (linear/demosaiced DNG) is not a single-sensor mosaic")
    _check_tiff_cfa(path)
    pattern = _pattern(colors, desc, n_colors, path)
    data = as_dn(data, str(path))
    meta: dict[str, Any] = {"source_file": str(path), "format": "camera raw (rawpy/LibRaw)",
                            "raw_area": {"top_margin": int(sizes.top_margin), "left_margin": int(sizes.left_margin),
                                         "raw_height": int(sizes.raw_height), "raw_width": int(sizes.raw_width)},
                            "unknown": {"gain_dn_per_e": "not stated in the file", "read_noise_e": "not stated in the file"}}
    uncertainty = unknown_uncertainty("gain_dn_per_e", "read_noise_e")
    black = blacks[0]
    if len(set(blacks)) > 1:
        black = float(np.mean(blacks))
        meta["black_level_per_channel_dn"] = blacks
        meta["note"] = "black level differs per channel; profile holds their mean, spread in uncertainty"
        uncertainty["black_level_dn"] = float(np.std(blacks))
    camera, tagged = _camera_tags(path)
    if tagged:
        meta["from_tags"] = sorted(tagged)
    profile = CalibrationProfile(
        gain_dn_per_e=UNKNOWN_GAIN_DN_PER_E, black_level_dn=black, read_noise_e=UNKNOWN_READ_NOISE_E,
        white_level_dn=white, adc_bits=bits_needed(white), cfa_pattern=pattern, camera=camera,
        uncertainty=uncertainty, **tagged)
    return RawImage(data=data, profile=profile, provenance=[{"function": "io.read_camera_raw",
                    "params": {"path": str(path), "crop": "visible area"}}], meta=meta)


def _pattern(colors: np.ndarray, desc: str, n_colors: int, path: Path) -> str:
    if colors.shape != (2, 2) or max(colors.ravel()) >= len(desc):
        raise MetrawError(f"{path}: CFA layout {colors.tolist()} / {desc!r} is not a 2x2 Bayer pattern")
    letters = "".join(desc[i] for i in colors.ravel())
    if letters not in BAYER_PATTERNS:
        raise MetrawError(f"{path}: CFA pattern {letters!r} ({desc!r}) is not supported (need one of "
                          f"{', '.join(BAYER_PATTERNS)})")
    return letters


#: Colour codes of the TIFF/EP and DNG CFAPattern tag.
_CFA_CODES = "RGBCMYW"


def _check_tiff_cfa(path: Path) -> None:
    """Refuse a TIFF-based raw (DNG) whose CFAPattern tag names colours other than R, G, B or a cell
    other than 2 x 2: LibRaw reads some of these (e.g. a CMY mosaic) as RGGB without a word."""
    try:
        import tifffile

        with tifffile.TiffFile(str(path)) as tif:
            pages = list(tif.pages)
            pages += [sub for page in pages for sub in (getattr(page, "pages", None) or [])]
            tags = [page.tags for page in pages if "CFAPattern" in page.tags]
            if not tags:
                return
            dims = tuple(tags[0]["CFARepeatPatternDim"].value) if "CFARepeatPatternDim" in tags[0] else (2, 2)
            codes = bytes(tags[0]["CFAPattern"].value)
    except Exception:  # not a TIFF, or tags LibRaw could read but tifffile cannot: LibRaw's word stands
        return
    letters = "".join(_CFA_CODES[c] if c < len(_CFA_CODES) else "?" for c in codes)
    if dims != (2, 2) or set(letters) - set("RGB"):
        raise MetrawError(f"{path}: CFA pattern {letters!r} ({dims[0]} x {dims[1]} cell, from the file's CFAPattern "
                          f"tag) is not supported (need a 2 x 2 Bayer cell: {', '.join(BAYER_PATTERNS)})")


#: EXIF tags of a TIFF-based raw (DNG) that state the profile's geometry: tag name -> profile field [SI].
_EXIF_FIELDS = {"ExposureTime": "exposure_s", "FocalLength": "focal_length_m"}
_EXIF_SCALE = {"ExposureTime": 1.0, "FocalLength": 1e-3}  # EXIF: seconds; millimetres


def _camera_tags(path: Path) -> tuple[str, dict[str, float]]:
    """The camera's name (Make, Model) and the geometry a TIFF-based raw (DNG) states in its EXIF tags: exposure
    time [s] and focal length [m] where given as positive numbers; ("unknown", {}) for other raws (the name is
    descriptive only, and params may give the geometry)."""
    try:
        import tifffile

        with tifffile.TiffFile(str(path)) as tif:
            tags = tif.pages[0].tags
            make = str(tags["Make"].value).strip() if "Make" in tags else ""
            model = str(tags["Model"].value).strip() if "Model" in tags else ""
            try:
                exif = dict(tags["ExifTag"].value) if "ExifTag" in tags else {}
                exif.update({n: tags[n].value for n in _EXIF_FIELDS if n in tags and n not in exif})
            except Exception:  # unreadable EXIF: the geometry stays unknown, the name stands
                exif = {}
    except Exception:  # non-TIFF camera raws, or tags tifffile cannot read
        return "unknown", {}
    name = model if model.lower().startswith(make.lower()) else f"{make} {model}".strip()
    geometry = {}
    for tag, fieldname in _EXIF_FIELDS.items():
        value = exif.get(tag)
        if isinstance(value, (tuple, list)) and len(value) == 2:
            value = value[0] / value[1] if value[1] else None
        if isinstance(value, (int, float)) and value > 0:
            geometry[fieldname] = float(value) * _EXIF_SCALE[tag]
    return name or "unknown", geometry


@contextlib.contextmanager
def _c_stderr_to(lines: list[str]) -> Iterator[None]:
    """Capture what C code (LibRaw) writes to file descriptor 2, so errors stay one clean line."""
    fd = 2
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", "replace")
            lines.extend(line.split(": ", 1)[-1].strip() for line in text.splitlines() if line.strip())
