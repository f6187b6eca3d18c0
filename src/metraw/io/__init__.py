"""Reading raw images into ``RawImage`` and writing them losslessly.

``read_raw(path, **metadata)`` recognises the file by its content (and suffix where content
cannot tell):

- camera raws (DNG, CR2, NEF, ...) through rawpy/LibRaw            -> ``metraw.io.camera``
- raw TIFF (MicaSense x16 data, BlackLevel tag), GeoTIFF pan, metraw TIFF -> ``metraw.io.tiff``
- headerless ``.raw`` / ``.bin`` with explicit metadata              -> ``metraw.io.headerless``
- metraw codec files (``.mraw``, magic "MRAW")                        -> ``metraw.codec.decode``
- processed 8-bit RGB (PNG, JPEG) + labels -> approximate raw      -> ``metraw.io.processed``

Every failure caused by the file (corrupt, truncated, unsupported, NaN, wrong dtype, missing
metadata, malformed labels) is a ``MetrawError`` with one line naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError, read_yaml
from metraw.io._unknown import noise_model_known, unknown_fields
from metraw.io.camera import RAW_SUFFIXES, read_camera_raw
from metraw.io.headerless import HEADERLESS_SUFFIXES, read_headerless
from metraw.io.labels import is_label_file
from metraw.io.processed import PROCESSED_SUFFIXES, approximate_raw, read_processed, srgb_to_linear
from metraw.io.tiff import is_tiff, read_tiff, tiff_kind, write_tiff
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile, check_claims, load_profile

__all__ = ["read_raw", "read_mraw", "write_tiff", "default_camera", "approximate_raw", "srgb_to_linear", "image_files",
           "noise_model_known", "unknown_fields", "SUPPORTED_SUFFIXES"]

SUPPORTED_SUFFIXES = RAW_SUFFIXES | HEADERLESS_SUFFIXES | PROCESSED_SUFFIXES | {".tif", ".tiff", ".mraw"}

#: Profile fields a stated camera may fill in when a raw file does not give them.
_FILLABLE = ("gain_dn_per_e", "read_noise_e", "dark_current_e_per_s", "full_well_e", "qe_per_channel",
             "pixel_pitch_m", "focal_length_m", "aperture_diameter_m", "obscuration_ratio", "altitude_m",
             "exposure_s", "ground_speed_m_per_s", "optical_transmission")


def read_raw(path: str | os.PathLike, *, camera: CalibrationProfile | None = None, labels: str = "auto",
             seed: int = 0, white_fraction: float = 1.0, gsd_m: float | None = None,
             car_classes: list[str] | tuple[str, ...] | None = None, **metadata: Any) -> RawImage:
    """Read one image file as a ``RawImage`` (see the module docstring for formats).

    ``camera``: for processed images, the camera whose photoelectrons and sensor model the
    approximate raw gets (default: ``default_camera()``, the source camera of params.yaml); for
    real raws, it fills gain / read noise / geometry the file does not state (``uncertainty``
    then comes from the camera profile). ``labels``: "auto", "yolo", "mask" or "none": the car mask from
    ``STEM_mask.png`` (exact) or YOLO boxes in ``STEM.txt`` (box-approximate), for any format. ``seed``: makes
    the approximate raw's noise reproducible. ``gsd_m``: ground sample distance of a processed photo [m].
    ``car_classes``: the YOLO classes counted as cars (default ``metraw.io.labels.CAR_CLASS_NAMES``).
    ``metadata``: headerless raw fields (width, height, ...).
    """
    path = Path(path)
    if not path.exists():
        raise MetrawError(f"{path}: no such file")
    if path.is_dir():
        raise MetrawError(f"{path}: is a directory, not an image file")
    suffix = path.suffix.lower()
    if suffix in HEADERLESS_SUFFIXES:
        return _labelled(_with_camera(read_headerless(path, **metadata), camera), path, labels, car_classes)
    if metadata:
        raise MetrawError(f"{path}: metadata {sorted(metadata)} is only used for headerless .raw files")
    if path.stat().st_size == 0:
        raise MetrawError(f"{path}: empty file")
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head[:4] == b"MRAW":
        return _labelled(_with_camera(read_mraw(path), camera), path, labels, car_classes)
    if is_tiff(head):
        kind = "cfa" if suffix in RAW_SUFFIXES else tiff_kind(path)
        if kind == "cfa":
            return _labelled(_with_camera(read_camera_raw(path), camera), path, labels, car_classes)
        if kind != "rgb8":
            return _labelled(_with_camera(read_tiff(path), camera), path, labels, car_classes)
    elif not (head[:8] == b"\x89PNG\r\n\x1a\n" or head[:3] == b"\xff\xd8\xff"):
        if suffix in PROCESSED_SUFFIXES | {".tif", ".tiff"}:
            raise MetrawError(f"{path}: corrupt file (content does not match its {suffix} suffix)")
        # LibRaw sniffs the format
        return _labelled(_with_camera(read_camera_raw(path), camera), path, labels, car_classes)
    return read_processed(path, camera if camera is not None else default_camera(), labels=labels, seed=seed,
                          white_fraction=white_fraction, gsd_m=gsd_m, car_classes=car_classes)


def _labelled(image: RawImage, path: Path, labels: str, car_classes=None) -> RawImage:
    """A raw image with the car mask of its label file (``metraw.io.labels.attach_labels``); a raw that carries
    a mask already (a .mraw) keeps it unless a label file is asked for."""
    if labels == "none" or (labels == "auto" and image.mask is not None):
        return image
    from metraw.io.labels import attach_labels

    return attach_labels(image, path, labels, car_classes=car_classes)


def read_mraw(path: str | os.PathLike) -> RawImage:
    """A ``.mraw`` file (a `metraw.codec` blob with its embedded profile); damage is one ``MetrawError``."""
    from metraw import codec

    path = Path(path)
    try:
        blob = path.read_bytes()
    except OSError as exc:
        raise MetrawError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return codec.decode(blob)
    except MetrawError as exc:
        raise MetrawError(f"{path}: {exc}") from None


def image_files(inputs: list[str | os.PathLike]) -> list[Path]:
    """Expand files and directories (non-recursive) into the image files to ingest, sorted per directory."""
    out: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in SUPPORTED_SUFFIXES
                           and not is_label_file(f) and not f.name.startswith("."))
            if not found:
                raise MetrawError(f"{p}: directory holds no supported image files")
            out.extend(found)
        elif p.exists():
            out.append(p)
        else:
            raise MetrawError(f"{p}: no such file or directory")
    return out


def default_camera(params_path: str | os.PathLike | None = None) -> CalibrationProfile:
    """The source camera of params.yaml (``source.camera``), from ``params_path``, the working
    directory or the repository this package is installed from."""
    candidates = [Path(params_path)] if params_path else [Path.cwd() / "params.yaml",
                                                           Path(__file__).resolve().parents[3] / "params.yaml"]
    for candidate in candidates:
        if candidate.is_file():
            params = read_yaml(candidate, "parameter file")
            try:
                cam = dict(params["source"]["camera"])
            except (KeyError, TypeError, ValueError) as exc:
                raise MetrawError(f"{candidate}: no readable source.camera ({exc})") from None
            try:
                return check_claims(CalibrationProfile.from_dict({"schema_version": 1, **cam}))
            except MetrawError as exc:
                raise MetrawError(f"{candidate}: source.camera: {exc}") from None
    raise MetrawError("no camera profile given (--camera) and no params.yaml with source.camera found")


def load_camera(path: str | os.PathLike) -> CalibrationProfile:
    """A camera profile from a JSON file (``CalibrationProfile.to_json``) or a params.yaml."""
    p = Path(path)
    if not p.is_file():
        raise MetrawError(f"{p}: camera profile not found")
    if p.suffix.lower() in (".yaml", ".yml"):
        return default_camera(p)
    return load_profile(p)


def _with_camera(image: RawImage, camera: CalibrationProfile | None) -> RawImage:
    """Fill what the file does not state (unknown noise terms, missing geometry) from ``camera``."""
    if camera is None:
        return image
    prof = image.profile
    unknown = set(unknown_fields(prof))
    changes: dict[str, Any] = {}
    uncertainty = dict(prof.uncertainty)
    for name in _FILLABLE:
        current = getattr(prof, name)
        if name in unknown or current is None:
            changes[name] = getattr(camera, name)
            uncertainty.pop(name, None)
            if name in camera.uncertainty:
                uncertainty[name] = camera.uncertainty[name]
    if "qe_per_channel" in changes and set(camera.qe_per_channel) != set(prof.channels):
        changes.pop("qe_per_channel")
    if not changes:
        return image
    meta = dict(image.meta)
    meta["filled_from_camera"] = {"camera": camera.camera, "fields": sorted(changes)}
    meta["unknown"] = {k: v for k, v in meta.get("unknown", {}).items() if k not in changes}
    return RawImage(data=image.data, profile=prof.replace(uncertainty=uncertainty, **changes), mask=image.mask,
                    flags=image.flags, provenance=image.provenance, meta=meta)
