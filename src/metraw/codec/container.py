"""Byte format of a metraw raw-codec blob (format version 3, compact binary header).

    magic "MRAW" | u8 version | u8 flags | u32 height | u32 width | f64 step | u64 seed
    | u16 tile count | u32 first row per tile
    | [flags & 1: u32 length | zlib(JSON {profile, provenance, meta})]
    | u16 section count | (u32 length, bytes) per section | u32 crc32c of everything before

The fixed part is 33 bytes plus 4 per tile; the metadata block (the calibration profile, ~350
bytes compressed) is left out when the profile travels elsewhere (the zarr codec keeps it in the
array metadata). Sections are the coded tiles and the escape list. The trailing CRC-32C
detects any corruption before decoding starts. Version 2 (JSON header) blobs are refused
with a clear error.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import crc32c as _crc32c

from metraw.errors import MetrawError

MAGIC = b"MRAW"
FORMAT_VERSION = 3
_FIXED = struct.Struct("<4sBBIIdQH")
FLAG_META = 1


def crc32c(data: bytes | memoryview) -> int:
    return _crc32c.crc32c(data)


@dataclass
class Header:
    """Decoded fixed header: shape (h, w), step [sigma], dither seed, tile row starts, metadata."""

    shape: tuple[int, int]
    step: float
    seed: int
    tiles: list[tuple[int, int]]
    meta: dict[str, Any] | None = field(default=None)  # {"profile", "provenance", "meta"} or None


def pack(header: Header, sections: list[bytes]) -> bytes:
    h, w = header.shape
    flags = FLAG_META if header.meta is not None else 0
    parts = [_FIXED.pack(MAGIC, FORMAT_VERSION, flags, h, w, header.step, header.seed, len(header.tiles)),
             struct.pack(f"<{len(header.tiles)}I", *[t[0] for t in header.tiles])]
    if header.meta is not None:
        blob = zlib.compress(json.dumps(header.meta, sort_keys=True, separators=(",", ":")).encode(), 9)
        parts += [struct.pack("<I", len(blob)), blob]
    parts.append(struct.pack("<H", len(sections)))
    for sec in sections:
        parts.append(struct.pack("<I", len(sec)))
        parts.append(sec)
    body = b"".join(parts)
    return body + struct.pack("<I", crc32c(body))


def unpack(blob: bytes | memoryview) -> tuple[Header, list[memoryview]]:
    mv = memoryview(blob if isinstance(blob, (bytes, memoryview)) else bytes(blob))
    if len(mv) < 6 or bytes(mv[:4]) != MAGIC:
        raise MetrawError("not a metraw raw-codec blob (bad magic)")
    (stored,) = struct.unpack_from("<I", mv, len(mv) - 4)
    if crc32c(mv[:-4]) != stored:
        raise MetrawError("metraw raw-codec blob is corrupt (CRC-32C mismatch)")
    if mv[4] != FORMAT_VERSION:
        raise MetrawError(f"metraw raw-codec format version {mv[4]} is not supported (this metraw reads "
                          f"{FORMAT_VERSION}); re-encode the data with this version")
    if len(mv) < _FIXED.size + 6:
        raise MetrawError("metraw raw-codec blob is corrupt (truncated)")
    try:
        _, _, flags, h, w, step, seed, ntiles = _FIXED.unpack_from(mv, 0)
        off = _FIXED.size
        starts = list(struct.unpack_from(f"<{ntiles}I", mv, off))
        off += 4 * ntiles
        tiles = [(r0, r1) for r0, r1 in zip(starts, starts[1:] + [h])]
        if any(r1 <= r0 for r0, r1 in tiles) or (tiles and tiles[0][0] != 0):
            raise ValueError("bad tiling")
        meta = None
        if flags & FLAG_META:
            (n,) = struct.unpack_from("<I", mv, off)
            off += 4
            meta = json.loads(zlib.decompress(bytes(mv[off:off + n])))
            off += n
        (count,) = struct.unpack_from("<H", mv, off)
        off += 2
        sections = []
        for _ in range(count):
            (n,) = struct.unpack_from("<I", mv, off)
            off += 4
            if off + n > len(mv) - 4:
                raise ValueError("section overruns the blob")
            sections.append(mv[off:off + n])
            off += n
    except (ValueError, struct.error, zlib.error) as exc:
        raise MetrawError(f"metraw raw-codec blob is malformed: {exc}") from None
    return Header((h, w), step, seed, tiles, meta), sections
