"""Byte format of a metraw raw-codec blob (format version 3, compact binary header).

    magic "MRAW" | u8 version | u8 flags | f64 step | varint seed, height, width, tile count
    | varint rows per tile (all but the last)
    | [flags & 1: varint length | zlib(JSON {profile, provenance, meta})]
    | varint section count | (varint length, bytes) per section | u32 crc32c of everything before

Varints are LEB128 (7 bits per byte, little end first). The fixed part is ~20 bytes for a small
image; the metadata block (the calibration profile, ~350 bytes compressed) is left out when the
profile travels elsewhere (the zarr codec keeps it in the array metadata). Sections are the
coded tiles and the escape list. The trailing CRC-32C detects any corruption before decoding
starts. Version 2 (JSON header) blobs are refused with a clear error.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import google_crc32c

from metraw.errors import MetrawError

MAGIC = b"MRAW"
FORMAT_VERSION = 3
_FIXED = struct.Struct("<4sBBd")
FLAG_META = 1


def crc32c(data: bytes | memoryview) -> int:
    """CRC-32C (Castagnoli) of ``data``, via google-crc32c (a zarr dependency; its C extension
    takes only ``bytes``, so a view is copied once)."""
    return google_crc32c.value(data if isinstance(data, bytes) else bytes(data))


@dataclass
class Header:
    """Decoded fixed header: shape (h, w), step [sigma], dither seed, tile row starts, metadata."""

    shape: tuple[int, int]
    step: float
    seed: int
    tiles: list[tuple[int, int]]
    meta: dict[str, Any] | None = field(default=None)  # {"profile", "provenance", "meta"} or None


def put_varint(out: list[bytes], value: int) -> None:
    """Append ``value`` (>= 0) as an LEB128 varint."""
    value = int(value)
    if value < 0:
        raise ValueError("varint of a negative number")
    b = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            b.append(byte | 0x80)
        else:
            b.append(byte)
            break
    out.append(bytes(b))


def get_varint(mv: memoryview, off: int) -> tuple[int, int]:
    """(value, new offset) of the LEB128 varint at ``off``."""
    value = shift = 0
    while True:
        if off >= len(mv) or shift > 63:
            raise ValueError("truncated varint")
        byte = mv[off]
        off += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, off


def pack(header: Header, sections: list[bytes]) -> bytes:
    h, w = header.shape
    flags = FLAG_META if header.meta is not None else 0
    parts = [_FIXED.pack(MAGIC, FORMAT_VERSION, flags, header.step)]
    for v in (header.seed, h, w, len(header.tiles)):
        put_varint(parts, v)
    for r0, r1 in header.tiles[:-1]:
        put_varint(parts, r1 - r0)
    if header.meta is not None:
        blob = zlib.compress(json.dumps(header.meta, sort_keys=True, separators=(",", ":")).encode(), 9)
        put_varint(parts, len(blob))
        parts.append(blob)
    put_varint(parts, len(sections))
    for sec in sections:
        put_varint(parts, len(sec))
        parts.append(sec)
    body = b"".join(parts)
    return body + struct.pack("<I", crc32c(body))


def unpack(blob: bytes | memoryview) -> tuple[Header, list[memoryview]]:
    mv = memoryview(blob if isinstance(blob, (bytes, memoryview)) else bytes(blob))
    if len(mv) == 0:
        raise MetrawError("metraw raw-codec blob is empty (0 bytes)")
    if bytes(mv[:4]) != MAGIC[:len(mv)]:
        raise MetrawError("not a metraw raw-codec blob (bad magic)")
    if len(mv) < _FIXED.size + 4:
        raise MetrawError(f"metraw raw-codec blob is truncated ({len(mv)} bytes, shorter than its fixed header)")
    (stored,) = struct.unpack_from("<I", mv, len(mv) - 4)
    if crc32c(mv[:-4]) != stored:
        raise MetrawError("metraw raw-codec blob is corrupt (CRC-32C mismatch: damaged or truncated)")
    if mv[4] != FORMAT_VERSION:
        raise MetrawError(f"metraw raw-codec format version {mv[4]} is not supported (this metraw reads "
                          f"{FORMAT_VERSION}); re-encode the data with this version")
    try:
        _, _, flags, step = _FIXED.unpack_from(mv, 0)
        off = _FIXED.size
        seed, off = get_varint(mv, off)
        h, off = get_varint(mv, off)
        w, off = get_varint(mv, off)
        ntiles, off = get_varint(mv, off)
        if not 1 <= ntiles <= max(h, 1) or h >= 2**32 or w >= 2**32 or seed >= 2**63:
            raise ValueError("bad shape or tiling")
        tiles, r0 = [], 0
        for _ in range(ntiles - 1):
            n, off = get_varint(mv, off)
            tiles.append((r0, r0 + n))
            r0 += n
        tiles.append((r0, h))
        if any(r1 <= r0 for r0, r1 in tiles) and h > 0:
            raise ValueError("bad tiling")
        meta = None
        if flags & FLAG_META:
            n, off = get_varint(mv, off)
            meta = json.loads(zlib.decompress(bytes(mv[off:off + n])))
            off += n
        count, off = get_varint(mv, off)
        sections = []
        for _ in range(count):
            n, off = get_varint(mv, off)
            if off + n > len(mv) - 4:
                raise ValueError("section overruns the blob")
            sections.append(mv[off:off + n])
            off += n
    except (ValueError, struct.error, zlib.error) as exc:
        raise MetrawError(f"metraw raw-codec blob is malformed: {exc}") from None
    return Header((h, w), step, seed, tiles, meta), sections
