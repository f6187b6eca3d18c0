"""Raw TIFF files: metraw's own TIFF (lossless round trip), MicaSense-style raw TIFF, GeoTIFF pan.

- metraw TIFF (``write_tiff``): page 0 uint16 DN with the profile, provenance and meta as JSON in
  the ImageDescription; optional pages "mask" (float32) and "flags" (uint8). zlib (deflate)
  compression, lossless.
- Raw TIFF from a camera (e.g. MicaSense RedEdge: 12-bit data stored x16, BlackLevel tag, XMP
  with DarkRowValue, band, exposure): unused low bits common to every pixel are shifted out
  (lossless; the shift is in the provenance) and the black level is scaled by the same factor.
- GeoTIFF of a processed satellite product (e.g. SpaceNet/WorldView pan, 11-bit): read as mono
  raw marked *approximate*: black level and gain unknown, resampled pixels (noise correlated).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.io._unknown import (UNKNOWN_BLACK_LEVEL_DN, UNKNOWN_GAIN_DN_PER_E, UNKNOWN_READ_NOISE_E,
                                unknown_uncertainty)
from metraw.io.dn import as_dn, bits_needed, unused_low_bits
from metraw.raw.image import FLAG_DEFECT, RawImage
from metraw.raw.profile import CalibrationProfile

METRAW_TIFF_KEY = "metraw_tiff"
METRAW_TIFF_VERSION = 1
_PHOTOMETRIC_CFA = 32803


def write_tiff(path: str | Path, image: RawImage, overwrite: bool = False) -> Path:
    """Write ``image`` losslessly to a TIFF (atomic: nothing appears at ``path`` on failure)."""
    import tifffile

    path = Path(path)
    pages = ["raw"] + (["mask"] if image.mask is not None else []) + (["flags"] if image.flags is not None else [])
    description = json.dumps({METRAW_TIFF_KEY: METRAW_TIFF_VERSION, "profile": image.profile.to_dict(),
                              "provenance": image.provenance, "meta": image.meta, "pages": pages},
                             sort_keys=True)
    with atomic_path(path, overwrite=overwrite) as tmp:
        with tifffile.TiffWriter(str(tmp)) as tw:
            tw.write(image.data, description=description, metadata=None, compression="zlib",
                     photometric="minisblack")
            if image.mask is not None:
                tw.write(image.mask.astype(np.float32), metadata=None, compression="zlib", photometric="minisblack")
            if image.flags is not None:
                tw.write(image.flags, metadata=None, compression="zlib", photometric="minisblack")
    return path


def is_tiff(head: bytes) -> bool:
    return head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def tiff_kind(path: Path) -> str:
    """"metraw", "cfa" (DNG / CFA TIFF: hand to LibRaw), "rgb8" (processed colour) or "mono"."""
    tif = _open(path)
    with tif:
        page = tif.pages[0]
        if _metraw_header(page, path) is not None:
            return "metraw"
        if "DNGVersion" in page.tags or page.photometric == _PHOTOMETRIC_CFA:
            return "cfa"
        if page.samplesperpixel >= 3 and page.dtype == np.uint8:
            return "rgb8"
        return "mono"


def read_tiff(path: Path) -> RawImage:
    tif = _open(path)
    with tif:
        _check_extent(tif, path)
        page = tif.pages[0]
        header = _metraw_header(page, path)
        try:
            arrays = [p.asarray() for p in tif.pages] if header is not None else [page.asarray()]
        except Exception as exc:  # tifffile / imagecodecs raise many types on damaged data
            raise MetrawError(f"{path}: corrupt TIFF pixel data ({exc})") from None
        if header is not None:
            return _from_metraw(path, header, arrays)
        if page.samplesperpixel > 1 or arrays[0].ndim > 2 and arrays[0].shape[-1] > 1:
            raise MetrawError(f"{path}: TIFF has {page.samplesperpixel} samples per pixel; a raw TIFF must be "
                              "a single band (one file per band)")
        data = as_dn(arrays[0], str(path))
        tags = page.tags
        bits_per_sample = int(page.bitspersample)
        if "ModelPixelScaleTag" in tags or "GeoKeyDirectoryTag" in tags:
            return _geotiff(path, data, tags, bits_per_sample)
        return _camera_tiff(path, data, tags, bits_per_sample)


# ----------------------------------------------------------------------------- helpers
def _open(path: Path):
    import logging

    import tifffile

    logging.getLogger("tifffile").setLevel(logging.ERROR)  # damaged files are reported as one MetrawError

    try:
        tif = tifffile.TiffFile(str(path))
    except Exception as exc:
        raise MetrawError(f"{path}: corrupt or truncated TIFF ({exc})") from None
    try:
        if len(tif.pages) == 0:
            raise ValueError("no image pages")
        tif.pages[0].tags  # noqa: B018 - parse the first IFD now, inside the error handler
    except Exception as exc:
        tif.close()
        raise MetrawError(f"{path}: corrupt or truncated TIFF ({exc})") from None
    return tif


def _check_extent(tif, path: Path) -> None:
    size = path.stat().st_size
    for page in tif.pages:
        for off, n in zip(page.dataoffsets, page.databytecounts):
            if off + n > size:
                raise MetrawError(f"{path}: truncated TIFF (pixel data ends at byte {off + n}, file has {size})")


def _metraw_header(page, path: Path) -> dict[str, Any] | None:
    desc = page.description or ""
    if f"\"{METRAW_TIFF_KEY}\":" not in desc:  # keys are sorted: a long "meta" can come first
        return None
    try:
        header = json.loads(desc)
    except json.JSONDecodeError as exc:
        raise MetrawError(f"{path}: metraw TIFF header is damaged: {exc}") from None
    return header if isinstance(header, dict) and METRAW_TIFF_KEY in header else None


def _from_metraw(path: Path, header: dict[str, Any], arrays: list[np.ndarray]) -> RawImage:
    if header[METRAW_TIFF_KEY] != METRAW_TIFF_VERSION:
        raise MetrawError(f"{path}: metraw TIFF version {header[METRAW_TIFF_KEY]} is not supported")
    pages = header.get("pages", ["raw"])
    if not isinstance(pages, list) or "raw" not in pages or len(arrays) != len(pages):
        raise MetrawError(f"{path}: metraw TIFF lists pages {pages} but holds {len(arrays)}")
    if "profile" not in header:
        raise MetrawError(f"{path}: metraw TIFF header has no profile")
    parts = dict(zip(pages, arrays))
    if parts["raw"].dtype != np.uint16:
        raise MetrawError(f"{path}: metraw TIFF raw page must be uint16, got {parts['raw'].dtype}")
    try:
        return RawImage(data=parts["raw"], profile=CalibrationProfile.from_dict(header["profile"]),
                        mask=parts.get("mask"), flags=parts.get("flags"),
                        provenance=header.get("provenance", []), meta=header.get("meta", {}))
    except MetrawError as exc:
        raise MetrawError(f"{path}: metraw TIFF header: {exc}") from None


def _exif(tags) -> dict[str, Any]:
    return dict(tags["ExifTag"].value) if "ExifTag" in tags else {}


def _rational(value) -> float | None:
    if isinstance(value, tuple) and len(value) == 2:
        return value[0] / value[1] if value[1] else None
    return float(value) if isinstance(value, (int, float)) else None


def _xmp_values(tags) -> dict[str, Any]:
    """A few scalar / sequence fields from XMP (MicaSense, Pix4D camera namespaces)."""
    if "XMP" not in tags:
        return {}
    text = tags["XMP"].value
    text = text.decode("utf-8", "replace") if isinstance(text, bytes) else str(text)
    out: dict[str, Any] = {}
    for name in ("BandName", "CentralWavelength", "WavelengthFWHM", "BandSensitivity", "PressureAlt"):
        m = re.search(rf"<\w+:{name}>([^<]*)</\w+:{name}>", text)
        if m:
            v = m.group(1).strip()
            try:
                out[name] = float(v)
            except ValueError:
                out[name] = v
    for name in ("DarkRowValue", "RadiometricCalibration"):
        m = re.search(rf"<\w+:{name}>(.*?)</\w+:{name}>", text, re.S)
        if m:
            out[name] = [float(v) for v in re.findall(r"<rdf:li>([^<]*)</rdf:li>", m.group(1))]
    return out


def _camera_tiff(path: Path, data: np.ndarray, tags, bits_per_sample: int) -> RawImage:
    """A single-band raw TIFF written by a camera (MicaSense RedEdge and similar)."""
    provenance = [{"function": "io.read_tiff", "params": {"path": str(path)}}]
    meta: dict[str, Any] = {"source_file": str(path), "format": "raw TIFF"}
    shift = unused_low_bits(data) if bits_per_sample == 16 else 0
    if bits_per_sample - shift < 8:  # fewer than 8 significant bits left: coincidence, not packing
        shift = 0
    if shift:
        data = data >> np.uint16(shift)
        provenance.append({"function": "io.shift_unused_low_bits", "params": {"shift": shift}})
        meta["stored_scale"] = 2**shift
    scale = float(2**shift)
    adc_bits = bits_per_sample - shift
    uncertainty = unknown_uncertainty("gain_dn_per_e", "read_noise_e")
    unknown = {"gain_dn_per_e": "not stated in the file", "read_noise_e": "not stated in the file"}
    xmp = _xmp_values(tags)
    black_tag = None
    if "BlackLevel" in tags:
        value = tags["BlackLevel"].value
        black_tag = [float(v) / scale for v in (value if isinstance(value, tuple) else (value,))]
        meta["black_level_tag_dn"] = black_tag
    if xmp.get("DarkRowValue"):
        # MicaSense: mean of optically masked rows per quadrant, measured in this frame; the
        # manufacturer's radiometric pipeline subtracts their mean, so it is the black level here.
        dark = np.asarray(xmp["DarkRowValue"]) / scale
        black = float(dark.mean())
        meta["dark_row_value_dn"] = dark.tolist()
        meta["black_level_source"] = "mean of XMP DarkRowValue (optically masked rows of this frame)"
        if len(dark) > 1:
            uncertainty["black_level_dn"] = float(dark.std(ddof=1))
    elif black_tag is not None:
        black = float(np.mean(black_tag))
        meta["black_level_source"] = "BlackLevel tag"
        if len(set(black_tag)) > 1:
            uncertainty["black_level_dn"] = float(np.std(black_tag))
    else:
        black = UNKNOWN_BLACK_LEVEL_DN
        uncertainty["black_level_dn"] = math.inf
        unknown["black_level_dn"] = "no BlackLevel tag or dark rows in the file"
    meta["unknown"] = unknown
    exif = _exif(tags)
    exposure_s = _rational(exif.get("ExposureTime"))
    f_number = _rational(exif.get("FNumber"))
    focal_m = _rational(exif.get("FocalLength"))
    focal_m = focal_m * 1e-3 if focal_m else None
    pitch_m = None
    res = _rational(exif.get("FocalPlaneXResolution"))
    unit = {2: 25.4e-3, 3: 1e-2, 4: 1e-3, 5: 1e-6}.get(exif.get("FocalPlaneResolutionUnit"))
    if res and unit:
        pitch_m = unit / res
    for key in ("ISOSpeed", "ISOSpeedRatings"):
        if key in exif:
            meta["iso"] = exif[key]
    meta.update({k: v for k, v in xmp.items() if k not in ("DarkRowValue",)})
    bands = {}
    if isinstance(xmp.get("CentralWavelength"), float) and isinstance(xmp.get("WavelengthFWHM"), float):
        c, w = xmp["CentralWavelength"] * 1e-9, xmp["WavelengthFWHM"] * 1e-9
        bands = {"L": (c - w / 2, c + w / 2)}
    make = str(tags["Make"].value).strip() if "Make" in tags else ""
    model = str(tags["Model"].value).strip() if "Model" in tags else ""
    profile = CalibrationProfile(
        gain_dn_per_e=UNKNOWN_GAIN_DN_PER_E, black_level_dn=black, read_noise_e=UNKNOWN_READ_NOISE_E,
        white_level_dn=float(2**adc_bits - 1), adc_bits=adc_bits, cfa_pattern="mono",
        band_edges_m=bands, pixel_pitch_m=pitch_m, focal_length_m=focal_m,
        aperture_diameter_m=focal_m / f_number if focal_m and f_number else None,
        exposure_s=exposure_s or None, camera=f"{make} {model}".strip() or "unknown", uncertainty=uncertainty)
    return RawImage(data=data, profile=profile, provenance=provenance, meta=meta)


def _geotiff(path: Path, data: np.ndarray, tags, bits_per_sample: int) -> RawImage:
    """A processed satellite product (orthorectified, resampled): approximate mono raw."""
    meta: dict[str, Any] = {"source_file": str(path), "format": "GeoTIFF (processed satellite product)",
                            "unknown": {"gain_dn_per_e": "not stated", "read_noise_e": "not stated",
                                        "black_level_dn": "not stated (product DN, offset unknown)"}}
    geokeys = tags["GeoKeyDirectoryTag"].value if "GeoKeyDirectoryTag" in tags else ()
    keys = {geokeys[i]: geokeys[i + 3] for i in range(4, len(geokeys) - 3, 4)}
    if "ModelPixelScaleTag" in tags and keys.get(3076) == 9001:  # projected CRS, linear unit metre
        sx, sy = tags["ModelPixelScaleTag"].value[:2]
        meta["gsd_m"] = float(sx) if abs(sx - sy) < 1e-9 * max(sx, sy) else [float(sx), float(sy)]
    if keys.get(3072):
        meta["epsg"] = int(keys[3072])
    flags = None
    if "GDAL_NODATA" in tags:
        try:
            nodata = float(str(tags["GDAL_NODATA"].value).strip("\x00 "))
        except ValueError:
            nodata = None
        if nodata is not None:
            meta["nodata_dn"] = nodata
            fill = data == nodata
            if fill.any():
                flags = np.where(fill, FLAG_DEFECT, 0).astype(np.uint8)
                meta["nodata_pixels"] = int(fill.sum())
    adc_bits = max(11, bits_needed(int(data.max())))
    meta["adc_bits_source"] = ("11-bit product range" if adc_bits == 11 else
                               f"data exceed 11 bits (max {int(data.max())}); bit depth from the data")
    profile = CalibrationProfile(
        gain_dn_per_e=UNKNOWN_GAIN_DN_PER_E, black_level_dn=UNKNOWN_BLACK_LEVEL_DN,
        read_noise_e=UNKNOWN_READ_NOISE_E, white_level_dn=float(2**adc_bits - 1), adc_bits=adc_bits,
        cfa_pattern="mono", camera="satellite pan product (GeoTIFF)",
        uncertainty=unknown_uncertainty("gain_dn_per_e", "read_noise_e", "black_level_dn"),
        approximate=True,
        approximate_reason="processed satellite product: radiometrically corrected and resampled "
                           "(orthorectified) DN, black level and gain unknown, pixel noise correlated")
    return RawImage(data=data, profile=profile, flags=flags,
                    provenance=[{"function": "io.read_tiff", "params": {"path": str(path)}}], meta=meta)
