"""The metraw raw codec as a zarr v3 array-to-bytes codec (name ``metraw.raw``).

Registered through the ``zarr.codecs`` entry point (pyproject.toml), so
``zarr.open_array(path)[:]`` decodes with metraw merely installed; importing this module also registers
it directly, which ``metraw.io.store`` does where that entry point is absent (metraw run from a source tree,
``PYTHONPATH=src``), so its stores open there too. The configuration carries
the step, the array's seed (each image is dithered with ``image_seed(seed, pixels)``, stored
in its blob) and the calibration profile: one profile per array (the store's ``raw``
array uses the first image's profile; images with another noise model still decode exactly to
what was encoded, but their error budget is relative to that profile). Chunks of any rank
>= 2 are coded image by image over the last two axes; each image blob (compact header without the profile, which is in
the codec configuration) has its own CRC-32C,
so a damaged chunk raises ``MetrawError`` instead of returning wrong pixels.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from zarr.abc.codec import ArrayBytesCodec
from zarr.core.buffer import Buffer, NDBuffer

from metraw.codec.container import get_varint, put_varint
from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

CODEC_NAME = "metraw.raw"


def image_seed(seed: int, image: np.ndarray) -> int:
    """Dither seed of one image in an array: a hash of the array's seed and the image's bytes.

    Deterministic (same pixels, same seed, same bytes) and different for different images, so
    the dither, hence the coding error, is independent between the images of a store even at
    the same pixel position. The seed is stored in each blob, so decoding does not recompute it."""
    from metraw.codec.container import crc32c
    from metraw.codec.prepare import _splitmix64

    return _splitmix64((int(seed) << 32) ^ crc32c(image.tobytes())) & (2**63 - 1)


def coded_image(pixels: np.ndarray, profile: CalibrationProfile, seed: int) -> tuple[RawImage, int]:
    """What ``MetrawRawCodec`` (array seed ``seed``, array profile ``profile``) codes for one image of its array:
    the image (uint16, C-ordered, with the array's profile) and its dither seed (``image_seed``)."""
    pixels = np.ascontiguousarray(pixels, dtype=np.uint16)
    return RawImage(pixels, profile), image_seed(seed, pixels)


def decoded_pixels(pixels: np.ndarray, step: float, seed: int, profile: CalibrationProfile) -> np.ndarray:
    """The uint16 pixels a ``MetrawRawCodec(step=step, seed=seed, profile=profile)`` array reads back for an
    image written as ``pixels`` (``codec.round_trip`` of its ``coded_image``), without coding them."""
    from metraw import codec

    image, image_dither_seed = coded_image(pixels, profile, seed)
    return codec.round_trip(image, step, image_dither_seed)


@dataclass(frozen=True)
class MetrawRawCodec(ArrayBytesCodec):
    """zarr v3 array -> bytes codec: noise-preserving quantisation + rANS (``metraw.codec``)."""

    step: float = 1.0
    seed: int = 0
    profile: str = ""  # CalibrationProfile JSON

    is_fixed_size = False

    def __init__(self, *, step: float = 1.0, seed: int = 0, profile: Any = None) -> None:
        if isinstance(profile, CalibrationProfile):
            profile = profile.to_json(indent=None)
        elif isinstance(profile, dict):
            profile = CalibrationProfile.from_dict(profile).to_json(indent=None)
        elif not isinstance(profile, str) or not profile:
            raise MetrawError("MetrawRawCodec needs the calibration profile of the array")
        object.__setattr__(self, "step", float(step))
        object.__setattr__(self, "seed", int(seed))
        object.__setattr__(self, "profile", profile)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "MetrawRawCodec":
        if data.get("name") != CODEC_NAME:
            raise MetrawError(f"not a {CODEC_NAME} codec configuration: {data.get('name')!r}")
        conf = dict(data.get("configuration", {}))
        return cls(step=conf["step"], seed=conf["seed"], profile=conf["profile"])

    def to_dict(self) -> dict[str, Any]:
        import json

        return {"name": CODEC_NAME, "configuration": {"step": self.step, "seed": self.seed,
                                                      "profile": json.loads(self.profile)}}

    def validate(self, *, shape, dtype, chunk_grid) -> None:  # noqa: D401 - zarr hook
        native = dtype.to_native_dtype() if hasattr(dtype, "to_native_dtype") else np.dtype(dtype)
        if np.dtype(native) != np.uint16:
            raise MetrawError(f"{CODEC_NAME} codes uint16 raw DN only, not {native}")
        if len(shape) < 2:
            raise MetrawError(f"{CODEC_NAME} needs arrays of rank >= 2, got shape {shape}")

    def _profile(self) -> CalibrationProfile:
        return CalibrationProfile.from_json(self.profile)

    def _encode_array(self, arr: np.ndarray) -> bytes:
        from metraw import codec

        prof = self._profile()
        lead = arr.reshape((-1,) + arr.shape[-2:])
        blobs = []
        for img in lead:
            image, image_dither_seed = coded_image(img, prof, self.seed)
            blobs.append(codec.encode(image, self.step, image_dither_seed, check_profile=False, embed_profile=False))
        parts: list[bytes] = []
        put_varint(parts, len(blobs))
        for b in blobs:
            put_varint(parts, len(b))
            parts.append(b)
        return b"".join(parts)

    def _decode_array(self, data: bytes, shape: tuple[int, ...]) -> np.ndarray:
        from metraw import codec

        mv = memoryview(data)
        prof = self._profile()
        try:
            count, off = get_varint(mv, 0)
            imgs = []
            for _ in range(count):
                n, off = get_varint(mv, off)
                if off + n > len(mv):
                    raise ValueError("image blob overruns the chunk")
                imgs.append(codec.decode(mv[off:off + n], profile=prof).data)
                off += n
        except (struct.error, ValueError) as exc:
            raise MetrawError(f"{CODEC_NAME} chunk is corrupt: {exc}") from None
        expected = int(np.prod(shape[:-2], dtype=np.int64))
        if count != expected or any(im.shape != tuple(shape[-2:]) for im in imgs):
            raise MetrawError(f"{CODEC_NAME} chunk is corrupt: it does not hold {expected} images of {shape[-2:]}")
        return np.stack(imgs).reshape(shape)

    async def _encode_single(self, chunk_array: NDBuffer, chunk_spec) -> Buffer | None:
        arr = np.asarray(chunk_array.as_numpy_array())
        return chunk_spec.prototype.buffer.from_bytes(self._encode_array(arr))

    async def _decode_single(self, chunk_bytes: Buffer, chunk_spec) -> NDBuffer:
        arr = self._decode_array(chunk_bytes.to_bytes(), tuple(chunk_spec.shape))
        return chunk_spec.prototype.nd_buffer.from_numpy_array(arr)

    def compute_encoded_size(self, input_byte_length: int, _chunk_spec) -> int:
        raise NotImplementedError  # variable size


def register() -> None:
    """Register ``MetrawRawCodec`` with zarr under ``CODEC_NAME`` (idempotent: the same class each time)."""
    from zarr.registry import register_codec

    register_codec(CODEC_NAME, MetrawRawCodec)


register()


def raw_codecs(step: float = 1.0, seed: int = 0) -> Callable[[CalibrationProfile], dict[str, Any]]:
    """Factory for ``RawStore.create(path, raw_codecs=...)``: profile -> create_array kwargs."""

    def factory(profile: CalibrationProfile) -> dict[str, Any]:
        return {"serializer": MetrawRawCodec(step=step, seed=seed, profile=profile), "compressors": None}

    return factory


def quantisation_record(step: float, seed: int) -> dict[str, Any]:
    """What a ``raw_codecs(step, seed)`` store did to its raw array, for store attributes and provenance.

    The decoded raw carries an extra, independent, zero-mean error: uniform of variance
    ``step^2 / 12`` in the variance-stabilised (generalised Anscombe, unit noise sigma) domain,
    i.e. about ``step^2 / 12 * sigma_T^2`` DN^2 with sigma_T = K sqrt(x + c) the transform's
    noise scale, plus the final rounding to integer DN; saturated and below-domain pixels are
    exact. The error budget refers to the profile in the codec configuration (the store's first
    image's profile)."""
    step = float(step)
    return {"codec": CODEC_NAME, "step_sigma": step, "seed": int(seed),
            "added_variance_vst": step * step / 12.0,
            "noise_variance_vst": 1.0 + step * step / 12.0,
            "note": "lossy noise-preserving codec: decoded DN = original + independent unbiased error of variance "
                    "step^2/12 in VST units (sigma_T^2 step^2/12 DN^2) + final rounding to integer DN; "
                    "|error| <= step sigma_T / 2 + K step^2 / 24 + 0.5 DN; saturated / below-black pixels exact"}


#: Profile fields the codec's preparation uses (transform, escapes, CFA planes).
NOISE_MODEL_FIELDS = ("gain_dn_per_e", "read_noise_e", "black_level_dn", "white_level_dn", "cfa_pattern")


def same_noise_model(a: CalibrationProfile, b: CalibrationProfile) -> bool:
    """Whether two profiles give the codec the same transform, escapes and planes."""
    return all(getattr(a, f) == getattr(b, f) for f in NOISE_MODEL_FIELDS)


def mark_quantised(image: RawImage, step: float, seed: int, codec_profile: CalibrationProfile | None = None) -> RawImage:
    """``image`` with a provenance entry saying its raw array is stored quantised at ``step``
    (``quantisation_record``). ``codec_profile``: the profile the store's codec uses (its first
    image's); the entry says whether this image's noise model (``NOISE_MODEL_FIELDS``) is the same:
    if not, the image still decodes to exactly what was encoded, but its error budget is relative
    to the codec's profile."""
    rec = quantisation_record(step, seed)
    rec["profile_matches_codec"] = bool(codec_profile is None or same_noise_model(codec_profile, image.profile))
    return image.derive(image.data, function="metraw.codec.zarr_codec", params=rec)
