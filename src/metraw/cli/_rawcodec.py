"""Shared ``--codec-step`` / ``--codec-seed`` / ``--codec-decoded`` options of the commands that write RawStores.

Absent ``--codec-step``: the raw array is stored losslessly (zstd, ``RawStore`` default). With
it: the noise-preserving codec ``metraw.raw`` at that step (``metraw.codec.zarr_codec``), the
store's attributes record it (``raw_codec``) and every image's provenance says so. With
``--codec-decoded`` as well: the pixels that store would decode to (``zarr_codec.decoded_pixels``),
stored uncompressed (attribute ``raw_stored``:
``decoded``): the same images, read without decoding, at ~4x the disk (a working store)."""

from __future__ import annotations

import argparse
import math
from typing import Any

from metraw.errors import MetrawError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--codec-step", dest="codec_step", type=float, default=None,
                        help="store the raw array with the noise-preserving codec at this quantisation step "
                             "[noise sigmas] (default: lossless zstd)")
    parser.add_argument("--codec-seed", dest="codec_seed", type=int, default=0,
                        help="dither seed of the codec (default 0)")
    parser.add_argument("--codec-decoded", dest="codec_decoded", action="store_true",
                        help="with --codec-step: store the pixels the codec decodes to, uncompressed, instead of "
                             "its stream (the same images, read without decoding, at ~4x the disk)")


class StoreCodec:
    """The raw codec chosen by the options: ``create_kwargs()`` for ``RawStore.create``, ``mark(image)``
    before ``append`` and ``attrs()`` for ``set_attrs``."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.step = getattr(args, "codec_step", None)
        self.seed = int(getattr(args, "codec_seed", 0) or 0)
        if self.step is not None and not (math.isfinite(self.step) and self.step > 0):
            raise MetrawError(f"--codec-step must be a positive number of sigmas, got {self.step}")
        if not 0 <= self.seed < 2**63:
            raise MetrawError(f"--codec-seed must be in [0, 2^63), got {self.seed}")
        self.decoded = bool(getattr(args, "codec_decoded", False))
        if self.decoded and self.step is None:
            raise MetrawError("--codec-decoded needs --codec-step")
        self._first = None

    @property
    def lossy(self) -> bool:
        return self.step is not None

    def create_kwargs(self) -> dict[str, Any]:
        if not self.lossy:
            return {}
        if self.decoded:
            from metraw.io.store import uncompressed_raw_codecs

            return {"raw_codecs": uncompressed_raw_codecs}
        from metraw.codec.zarr_codec import raw_codecs

        return {"raw_codecs": raw_codecs(self.step, self.seed)}

    def mark(self, image):
        if not self.lossy:
            return image
        from metraw.codec.zarr_codec import mark_quantised

        if self._first is None:
            self._first = image.profile
        marked = mark_quantised(image, self.step, self.seed, self._first)
        if not self.decoded:
            return marked
        from dataclasses import replace

        from metraw.codec.zarr_codec import decoded_pixels

        # what a coded store's array (profile: its first image's) reads back for this image
        return replace(marked, data=decoded_pixels(image.data, self.step, self.seed, self._first))

    def attrs(self) -> dict[str, Any]:
        if not self.lossy:
            return {}
        from metraw.codec.zarr_codec import quantisation_record

        record = {"raw_codec": quantisation_record(self.step, self.seed)}
        return {**record, "raw_stored": "decoded"} if self.decoded else record
