"""Dataset store: many RawImages in one sharded zarr v3 group.

Layout of ``NAME.zarr``:

- ``raw``   (N, H, W) uint16 DN, one chunk per image, ``images_per_shard`` images per file;
- ``mask``  (N, H, W) float32 label fraction (0 where an image has no mask);
- ``flags`` (N, H, W) uint8 ``RawImage.flags``;
- root attributes ``metraw``: store version, image count, and per image its shape,
  profile (JSON), provenance, meta and whether it has a mask.

Images smaller than the store's (H, W) are zero-padded; their true shape is in the
attributes and reading returns exactly the image that was written. The image count in the
attributes is written last, so an interrupted append never exposes a half-written image.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

STORE_VERSION = 1
#: Target bytes of uncompressed raw data per shard file.
SHARD_TARGET_BYTES = 64 * 2**20
#: At most this many images per shard: a shard's index holds 16 bytes per image slot whether
#: filled or not, so small (emulated satellite) images must not get thousands of slots.
MAX_IMAGES_PER_SHARD = 256

#: A function (first image's profile) -> keyword arguments of ``zarr.Group.create_array`` that
#: choose the ``raw`` array's codecs (``serializer``, ``compressors``); ``None`` means lossless zstd.
RawCodecFactory = Callable[[CalibrationProfile], dict[str, Any]]


@functools.cache
def _zarr():
    """zarr, able to read the metraw raw codec: installed, metraw declares it through an entry point; run from a
    source tree (``PYTHONPATH=src``, no entry point) the codec module registers it on import."""
    from importlib.metadata import entry_points

    import zarr

    if not entry_points(group="zarr.codecs", name="metraw.raw"):  # metraw.codec.zarr_codec.CODEC_NAME
        import metraw.codec.zarr_codec  # noqa: F401

    return zarr


def _zstd():
    """Lossless zstd with the frame checksum: a damaged chunk is refused, never read as other pixels."""
    return _zarr().codecs.ZstdCodec(level=3, checksum=True)


def _default_raw_codecs(profile: CalibrationProfile) -> dict[str, Any]:
    return {"compressors": [_zstd()]}


def uncompressed_raw_codecs(profile: CalibrationProfile) -> dict[str, Any]:
    """The raw array stored as plain little-endian uint16, no compressor: the fastest to read (a working
    copy that many jobs read, ``write_decoded_copy``), at 2 bytes per pixel on disk."""
    return {"compressors": None}


#: Shard-index entry of a chunk slot that holds no chunk (offset and length all ones).
_EMPTY_SLOT = np.uint64(2**64 - 1)


def read_shard_index(path: str | os.PathLike, slots: int) -> np.ndarray:
    """(offset, nbytes) per chunk slot of a zarr shard file whose index is at the end (uint64 pairs
    + CRC-32C, the layout `RawStore` writes); an empty slot holds ``2**64 - 1`` twice."""
    index_len = 16 * slots + 4
    with open(path, "rb") as fh:
        fh.seek(max(0, os.fstat(fh.fileno()).st_size - index_len))
        return np.frombuffer(fh.read(index_len)[:-4], "<u8").reshape(-1, 2)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


class RawStore:
    """A dataset of RawImages backed by a zarr v3 group (see module docstring).

    Create with ``RawStore.create(path)`` (a context manager: the store appears at ``path``
    only when the ``with`` block completes), open with ``RawStore.open(path)``.
    """

    def __init__(self, root: Path, group, mode: str, raw_codecs: RawCodecFactory | None = None,
                 images_per_shard: int | None = None):
        self.path = root
        self._group = group
        self._mode = mode
        self._raw_codecs = raw_codecs or _default_raw_codecs
        self._pending: list[RawImage] = []
        attrs = group.attrs.get("metraw", {})
        if not isinstance(attrs, dict):
            raise MetrawError(f"{root} is not a metraw store (attribute 'metraw' is not an object)")
        if mode == "r" or attrs:
            if attrs.get("store_version") != STORE_VERSION:
                raise MetrawError(f"{root} is not a metraw store (store_version {attrs.get('store_version')!r})")
        self._records: list[dict[str, Any]] = list(attrs.get("images", []))
        self._attrs_extra: dict[str, Any] = dict(attrs.get("extra", {}))
        self._images_per_shard = images_per_shard or attrs.get("images_per_shard")
        if attrs:
            self._check_records(attrs.get("count"))

    # ----------------------------------------------------------------- construction
    @classmethod
    def create(cls, path: str | os.PathLike, overwrite: bool = False, raw_codecs: RawCodecFactory | None = None,
               images_per_shard: int | None = None) -> "_AtomicStore":
        """A new store at ``path``, written atomically (use as a context manager)."""
        return _AtomicStore(Path(path), overwrite, raw_codecs, images_per_shard)

    @staticmethod
    def is_store(path: str | os.PathLike) -> bool:
        """Whether ``path`` is a zarr v3 group (a directory holding ``zarr.json``)."""
        return (Path(path) / "zarr.json").is_file()

    @classmethod
    def open(cls, path: str | os.PathLike, mode: str = "r") -> "RawStore":
        """Open an existing store for reading (``"r"``) or appending (``"a"``)."""
        zarr = _zarr()
        path = Path(path)
        if not cls.is_store(path):
            raise MetrawError(f"{path} is not a zarr v3 store (no zarr.json)")
        try:
            group = zarr.open_group(str(path), mode="r" if mode == "r" else "r+", zarr_format=3)
        except Exception as exc:  # zarr raises several types for damaged metadata
            raise MetrawError(f"cannot open store {path}: {exc}") from None
        return cls(path, group, mode)

    # ----------------------------------------------------------------- reading
    def __len__(self) -> int:
        return len(self._records) + len(self._pending)

    def __getitem__(self, index: int) -> RawImage:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"image index {index} out of range for a store of {n} images")
        index %= n
        if index >= len(self._records):
            return self._pending[index - len(self._records)]
        rec = self._records[index]
        h, w = rec["shape"]
        data = self._read("raw", index, h, w)
        if not data.any():
            self._check_raw_chunks(index, h, w)  # zarr reads a lost chunk as zeros (the fill value)
        mask = self._read("mask", index, h, w) if rec["has_mask"] else None
        flags = self._read("flags", index, h, w) if rec["has_flags"] else None
        try:
            return RawImage(data=data, profile=self.profile(index), mask=mask, flags=flags,
                            provenance=rec["provenance"], meta=rec["meta"])
        except MetrawError as exc:
            raise MetrawError(f"store {self.path}: image {index}: {exc}") from None

    def __iter__(self) -> Iterator[RawImage]:
        for i in range(len(self)):
            yield self[i]

    def profile(self, index: int) -> CalibrationProfile:
        try:
            return CalibrationProfile.from_dict(self._records[index]["profile"])
        except MetrawError as exc:
            raise MetrawError(f"store {self.path}: image {index}: {exc}") from None

    def meta(self, index: int) -> dict[str, Any]:
        return self._records[index]["meta"]

    def shape(self, index: int) -> tuple[int, int]:
        return tuple(self._records[index]["shape"])  # type: ignore[return-value]

    @property
    def attrs(self) -> dict[str, Any]:
        """Dataset-level descriptive attributes (e.g. generator parameters)."""
        return self._attrs_extra

    @property
    def images_per_shard(self) -> int | None:
        """Images per shard file (None before the first image is written)."""
        return self._images_per_shard

    @property
    def origin(self) -> str:
        """The store to name in provenance records: the one this store is a decoded working copy of
        (``write_decoded_copy``, attribute ``decoded_from``), else this store's own path."""
        return str(self._attrs_extra.get("decoded_from", self.path))

    # ----------------------------------------------------------------- writing
    def append(self, image: RawImage) -> None:
        """Add an image; data is buffered and written a whole shard at a time."""
        if self._mode == "r":
            raise MetrawError(f"store {self.path} is open read-only")
        if not isinstance(image, RawImage):
            raise MetrawError("only RawImage objects can be stored")
        self._pending.append(image)
        if len(self._pending) >= self._shard_images(image.shape):
            self.flush()

    def extend(self, images: Iterable[RawImage], progress: bool | None = False, total: int | None = None) -> None:
        """Append every image; ``progress``: a bar on stderr (None: only on a terminal)."""
        from metraw.progress import progress_bar

        for image in progress_bar(images, total=total, desc="store", disable=None if progress is None else not progress):
            self.append(image)

    def set_attrs(self, **values: Any) -> None:
        self._attrs_extra.update(values)
        self._write_attrs()

    def flush(self) -> None:
        """Write buffered images, then publish the new count in the attributes."""
        if not self._pending:
            return
        start = len(self._records)
        images = self._pending
        self._ensure_arrays(images)
        h_max = max(img.shape[0] for img in images)
        w_max = max(img.shape[1] for img in images)
        arr_raw = self._group["raw"]
        _, H, W = arr_raw.shape
        new_shape = (start + len(images), max(H, h_max), max(W, w_max))
        for name in ("raw", "mask", "flags"):
            self._group[name].resize(new_shape)
        _, H, W = new_shape
        raw = np.zeros((len(images), H, W), np.uint16)
        mask = np.zeros((len(images), H, W), np.float32)
        flags = np.zeros((len(images), H, W), np.uint8)
        for i, img in enumerate(images):
            h, w = img.shape
            raw[i, :h, :w] = img.data
            if img.mask is not None:
                mask[i, :h, :w] = img.mask
            if img.flags is not None:
                flags[i, :h, :w] = img.flags
        sl = slice(start, start + len(images))
        with _zarr().config.set({"array.write_empty_chunks": True}):
            raw_array = self._group["raw"]  # every raw chunk on disk: a missing one is damage (see __getitem__)
        raw_array[sl] = raw
        self._group["mask"][sl] = mask
        self._group["flags"][sl] = flags
        for img in images:
            self._records.append({
                "shape": list(img.shape),
                "profile": img.profile.to_dict(),
                "provenance": img.provenance,
                "meta": img.meta,
                "has_mask": img.mask is not None,
                "has_flags": img.flags is not None,
            })
        self._pending = []
        self._write_attrs()

    def close(self) -> None:
        if self._mode != "r":
            self.flush()

    # ----------------------------------------------------------------- internals
    def _check_records(self, count: Any) -> None:
        """The per-image records of the attributes are complete (a damaged zarr.json is one clear error)."""
        if count != len(self._records):
            raise MetrawError(f"store {self.path} is damaged: its attributes count {count!r} images but "
                              f"describe {len(self._records)}")
        keys = ("shape", "profile", "provenance", "meta", "has_mask", "has_flags")
        for i, rec in enumerate(self._records):
            if not isinstance(rec, dict) or any(k not in rec for k in keys):
                raise MetrawError(f"store {self.path} is damaged: the record of image {i} lacks "
                                  f"{', '.join(k for k in keys if not isinstance(rec, dict) or k not in rec)}")
            shape = rec["shape"]
            if not (isinstance(shape, list) and len(shape) == 2 and all(isinstance(v, int) and v > 0 for v in shape)):
                raise MetrawError(f"store {self.path} is damaged: image {i} has shape {shape!r}")

    def _read(self, name: str, index: int, h: int, w: int) -> np.ndarray:
        """Image ``index`` of array ``name``; a damaged chunk or array is one ``MetrawError``."""
        try:
            return np.asarray(self._group[name][index, :h, :w])
        except MetrawError as exc:  # the raw codec's own check (CRC-32C)
            raise MetrawError(f"store {self.path}: image {index}: {name} chunk is corrupt: {exc}") from None
        except Exception as exc:  # zarr, numcodecs and the file system raise many types on damaged data
            raise MetrawError(f"store {self.path}: image {index}: {name} chunk is corrupt or unreadable "
                              f"({_one_line(exc)})") from None

    def _check_raw_chunks(self, index: int, h: int, w: int) -> None:
        """Every raw chunk holding image ``index`` is on disk (its shard file exists and indexes it).

        The raw array is written with every chunk stored, even an all-zero one, so a chunk that is
        not there was lost; zarr itself would read it as the fill value (zeros)."""
        arr = self._group["raw"]
        k, sh, sw = arr.shards or arr.chunks
        for j in range(-(-h // sh)):
            for m in range(-(-w // sw)):
                rel = Path("raw", "c", str(index // k), str(j), str(m))
                f = self.path / rel
                if not f.is_file():
                    raise MetrawError(f"store {self.path}: image {index}: raw data missing (shard file {rel} "
                                      "does not exist)")
                if arr.shards and read_shard_index(f, k)[index % k, 0] == _EMPTY_SLOT:
                    raise MetrawError(f"store {self.path}: image {index}: raw data missing (shard file {rel} "
                                      "holds no chunk for it)")

    def _shard_images(self, shape: tuple[int, int]) -> int:
        if self._images_per_shard:
            return self._images_per_shard
        return max(1, min(MAX_IMAGES_PER_SHARD, SHARD_TARGET_BYTES // (2 * shape[0] * shape[1])))

    def _ensure_arrays(self, images: list[RawImage]) -> None:
        if "raw" in self._group:
            return
        h = max(img.shape[0] for img in images)
        w = max(img.shape[1] for img in images)
        k = self._shard_images((h, w))
        self._images_per_shard = k
        common = dict(shape=(0, h, w), chunks=(1, h, w), shards=(k, h, w), fill_value=0)
        self._group.create_array("raw", dtype="uint16", **common, **self._raw_codecs(images[0].profile))
        self._group.create_array("mask", dtype="float32", compressors=[_zstd()], **common)
        self._group.create_array("flags", dtype="uint8", compressors=[_zstd()], **common)

    def _write_attrs(self) -> None:
        self._group.attrs["metraw"] = {
            "store_version": STORE_VERSION,
            "count": len(self._records),
            "images_per_shard": self._images_per_shard,
            "images": self._records,
            "extra": self._attrs_extra,
        }


def write_decoded_copy(source_path: str | os.PathLike, out_path: str | os.PathLike, overwrite: bool = False,
                       progress: bool | None = None) -> RawStore:
    """Copy the store at ``source_path`` to ``out_path`` with its raw array uncompressed
    (``uncompressed_raw_codecs``): the same images (pixels, masks, flags, profiles, provenance, meta), the same
    attributes plus ``decoded_from`` = ``source_path`` as given, and the same shard layout. A store written with
    the noise-preserving codec (``metraw scenes --codec-step``) is then read without decoding: ~12 instead of
    ~42 ms of CPU per 1 MP image, at 4x the disk. Returns the copy, open for reading."""
    source = RawStore.open(source_path)
    attrs = dict(source.attrs)
    attrs["decoded_from"] = str(source_path)
    with RawStore.create(out_path, overwrite=overwrite, raw_codecs=uncompressed_raw_codecs,
                         images_per_shard=source.images_per_shard) as copy:
        copy.set_attrs(**attrs)
        copy.extend(source, progress=progress, total=len(source))
    return RawStore.open(out_path)


class _AtomicStore:
    """Context manager behind ``RawStore.create``: build in a temporary path, rename at the end."""

    def __init__(self, path: Path, overwrite: bool, raw_codecs: RawCodecFactory | None, images_per_shard: int | None):
        self._ctx = atomic_path(path, overwrite=overwrite)
        self._raw_codecs = raw_codecs
        self._images_per_shard = images_per_shard
        self.store: RawStore | None = None

    def __enter__(self) -> RawStore:
        zarr = _zarr()
        tmp = self._ctx.__enter__()
        group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        self.store = RawStore(tmp, group, "w", self._raw_codecs, self._images_per_shard)
        self.store._write_attrs()
        return self.store

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.store.close()
            except BaseException as err:  # the partial store must not survive a failed flush
                self._ctx.__exit__(type(err), err, err.__traceback__)
                raise
        return self._ctx.__exit__(exc_type, exc, tb)
