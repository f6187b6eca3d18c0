"""Byte format of a metraw raw-codec blob.

    magic "MRAW" | u8 format version | u32 header length | header (UTF-8 JSON)
    | u32 section count | (u64 length, bytes) per section | u32 crc32c of everything before

The header carries the profile, shape, step, seed and tiling; sections are the coded tiles
and the escape lists. The trailing CRC-32C detects any corruption before decoding starts.
"""

from __future__ import annotations

import json
import struct
from typing import Any

import crc32c as _crc32c

from metraw.errors import MetrawError

MAGIC = b"MRAW"
FORMAT_VERSION = 2


def crc32c(data: bytes | memoryview) -> int:
    return _crc32c.crc32c(data)


def pack(header: dict[str, Any], sections: list[bytes]) -> bytes:
    head = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    parts = [MAGIC, struct.pack("<BI", FORMAT_VERSION, len(head)), head, struct.pack("<I", len(sections))]
    for sec in sections:
        parts.append(struct.pack("<Q", len(sec)))
        parts.append(sec)
    body = b"".join(parts)
    return body + struct.pack("<I", crc32c(body))


def unpack(blob: bytes | memoryview) -> tuple[dict[str, Any], list[memoryview]]:
    mv = memoryview(bytes(blob) if not isinstance(blob, (bytes, memoryview)) else blob)
    if len(mv) < 13 or bytes(mv[:4]) != MAGIC:
        raise MetrawError("not a metraw raw-codec blob (bad magic)")
    (stored,) = struct.unpack_from("<I", mv, len(mv) - 4)
    if crc32c(mv[:-4]) != stored:
        raise MetrawError("metraw raw-codec blob is corrupt (CRC-32C mismatch)")
    version, hlen = struct.unpack_from("<BI", mv, 4)
    if version != FORMAT_VERSION:
        raise MetrawError(f"metraw raw-codec format version {version} is not supported (this metraw reads {FORMAT_VERSION})")
    try:
        header = json.loads(bytes(mv[9:9 + hlen]))
        off = 9 + hlen
        (count,) = struct.unpack_from("<I", mv, off)
        off += 4
        sections = []
        for _ in range(count):
            (n,) = struct.unpack_from("<Q", mv, off)
            off += 8
            if off + n > len(mv) - 4:
                raise ValueError("section overruns the blob")
            sections.append(mv[off:off + n])
            off += n
    except (ValueError, struct.error) as exc:
        raise MetrawError(f"metraw raw-codec blob is malformed: {exc}") from None
    return header, sections
