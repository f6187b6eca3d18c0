"""Damaged ``.mraw`` files (the noise-preserving codec's container): a flipped bit anywhere, truncation,
wrong magic, wrong format version. A damaged blob is refused, never decoded to other pixels."""

from __future__ import annotations

import struct

import pytest

from metraw.codec.container import crc32c

from ._check import refused

#: Where a bit is flipped (byte offset; negative from the end) and the word of the refusal.
FLIPS = {
    "magic": (1, "bad magic"),
    "version": (4, "corrupt"),
    "step": (10, "corrupt"),
    "shape varint": (15, "corrupt"),
    "payload start": (40, "corrupt"),
    "payload middle": (0.5, "corrupt"),
    "last payload byte": (-5, "corrupt"),
    "crc": (-1, "corrupt"),
}


def _write(tmp_path, blob: bytes, name="a.mraw"):
    (tmp_path / name).write_bytes(blob)
    return name


@pytest.mark.parametrize("where", list(FLIPS))
def test_flipped_bit_decode(tmp_path, mraw_blob, where):
    pos, word = FLIPS[where]
    pos = int(pos * len(mraw_blob)) if isinstance(pos, float) else pos % len(mraw_blob)
    for bit in (0, 7):
        blob = bytearray(mraw_blob)
        blob[pos] ^= 1 << bit
        _write(tmp_path, bytes(blob))
        refused(["decode", "a.mraw", "out.tif"], word, tmp_path, inprocess=True)


def test_truncated_decode(tmp_path, mraw_blob):
    _write(tmp_path, mraw_blob[: len(mraw_blob) // 2])
    refused(["decode", "a.mraw", "out.tif"], "damaged or truncated", tmp_path, inprocess=True)


def test_truncated_inside_header_decode(tmp_path, mraw_blob):
    _write(tmp_path, mraw_blob[:10])
    refused(["decode", "a.mraw", "out.tif"], "truncated (10 bytes", tmp_path, inprocess=True)


def test_zero_byte_decode(tmp_path):
    _write(tmp_path, b"")
    refused(["decode", "a.mraw", "out.tif"], "empty", tmp_path, inprocess=True)


def test_wrong_magic_decode(tmp_path, mraw_blob):
    _write(tmp_path, b"MRAX" + mraw_blob[4:])
    refused(["decode", "a.mraw", "out.tif"], "bad magic", tmp_path, inprocess=True)


def test_wrong_version_decode(tmp_path, mraw_blob):
    body = mraw_blob[:4] + bytes([9]) + mraw_blob[5:-4]
    _write(tmp_path, body + struct.pack("<I", crc32c(body)))  # a consistent blob of another format version
    refused(["decode", "a.mraw", "out.tif"], "format version 9 is not supported", tmp_path, inprocess=True)


def test_flipped_bit_info(tmp_path, mraw_blob):
    blob = bytearray(mraw_blob)
    blob[len(blob) // 3] ^= 0x10
    _write(tmp_path, bytes(blob))
    refused(["info", "a.mraw"], "a.mraw: metraw raw-codec blob is corrupt", tmp_path, inprocess=True)


def test_truncated_ingest(tmp_path, mraw_blob):
    (tmp_path / "in").mkdir()
    _write(tmp_path, mraw_blob[:-100], "in/a.mraw")
    refused(["ingest", "in", "--out", "s.zarr"], "corrupt", tmp_path, inprocess=True)
