"""Damaged stores (zarr RawStore): a missing shard file, a shard without an image's chunk, a corrupted
chunk (lossless zstd and the noise-preserving codec), damaged metadata -- in the commands that read
stores. zarr alone would read a lost chunk as zeros; metraw refuses it."""

from __future__ import annotations

import json

import pytest

from metraw.io.store import read_shard_index

from . import _inputs as make
from ._check import refused

SHARD = "raw/c/0/0/0"  # the one shard file of the five 64 px images


def _flip(path, *fractions: float) -> None:
    """Flip one bit at each of these fractions of the file's length."""
    data = bytearray(path.read_bytes())
    for f in fractions:
        data[int(len(data) * f)] ^= 0x04
    path.write_bytes(bytes(data))


def test_missing_shard_info(tmp_path, store):
    (store / SHARD).unlink()
    refused(["info", "s.zarr"], "raw data missing (shard file raw/c/0/0/0 does not exist)", tmp_path)


def test_missing_shard_compress(tmp_path, store):
    (store / SHARD).unlink()
    refused(["compress", "s.zarr", "--out", "c.json"], "raw data missing", tmp_path)


def test_missing_chunk_in_shard_check(tmp_path, store):
    # image 1's slot of the shard index emptied (offset, length = 2^64 - 1), the index CRC made to match
    from metraw.codec.container import crc32c

    import zarr

    shard = store / SHARD
    data = bytearray(shard.read_bytes())
    index = read_shard_index(shard, zarr.open_array(store / "raw", mode="r").shards[0]).copy()
    index[1] = 2**64 - 1
    body = index.astype("<u8").tobytes()
    data[-len(body) - 4:] = body + crc32c(body).to_bytes(4, "little")
    shard.write_bytes(bytes(data))
    make.spec(tmp_path / "spec.yaml")
    refused(["check", "s.zarr#1", "--spec", "spec.yaml", "--json", "d.json"], "holds no chunk for it", tmp_path)


@pytest.mark.parametrize("where", [0.1, 0.5, 0.9])
def test_corrupt_chunk_emulate(tmp_path, store, where):
    _flip(store / SHARD, where)
    refused(["emulate", "s.zarr", "out.zarr", "--params", str(make.REPO / "params.yaml"), "--workers", "1"],
            "chunk is corrupt", tmp_path)


def test_corrupt_shard_index_info(tmp_path, store):
    _flip(store / SHARD, 0.9995)  # in the shard index (its own CRC-32C)
    refused(["info", "s.zarr"], "chunk is corrupt", tmp_path)


def test_corrupt_codec_chunk_compress(tmp_path, codec_store):
    _flip(codec_store / SHARD, 0.3)  # a blob of the noise-preserving codec (its CRC-32C)
    refused(["compress", "s.zarr", "--out", "c.json"], "CRC-32C mismatch", tmp_path, inprocess=True)


def test_corrupt_chunks_train(tmp_path, store):
    _flip(store / SHARD, 0.1, 0.3, 0.5, 0.7, 0.9)  # every image's chunk: whichever the training split reads
    refused(["train", "s.zarr", "--out", "model", "--params", str(make.REPO / "params.yaml")], "chunk is corrupt",
            tmp_path)


def test_corrupt_chunks_evaluate(tmp_path, store, model):
    _flip(store / SHARD, 0.1, 0.3, 0.5, 0.7, 0.9)  # every image's chunk: whichever the test split reads
    refused(["evaluate", "s.zarr", "--model", str(model), "--out", "metrics.json"], "chunk is corrupt", tmp_path,
            inprocess=True)  # torch is imported here already (the model fixture)


def test_corrupt_chunks_predict(tmp_path, store, model):
    _flip(store / SHARD, 0.1, 0.3, 0.5, 0.7, 0.9)  # every image's chunk: predict reads them all
    refused(["predict", "s.zarr", "--model", str(model), "--out", "p.zarr", "--overlay", "o.png"], "chunk is corrupt",
            tmp_path, inprocess=True)  # torch is imported here already (the model fixture)


def test_damaged_zarr_json_info(tmp_path, store):
    (store / "zarr.json").write_text('{"zarr_format": 3, "node_type": "gro')
    refused(["info", "s.zarr"], "cannot open store", tmp_path)


def test_image_count_mismatch_compress(tmp_path, store):
    meta = json.loads((store / "zarr.json").read_text())
    meta["attributes"]["metraw"]["count"] = 7
    (store / "zarr.json").write_text(json.dumps(meta))
    refused(["compress", "s.zarr", "--out", "c.json"], "attributes count 7 images but describe 5", tmp_path)


def test_damaged_image_record_emulate(tmp_path, store):
    meta = json.loads((store / "zarr.json").read_text())
    del meta["attributes"]["metraw"]["images"][1]["profile"]["gain_dn_per_e"]
    (store / "zarr.json").write_text(json.dumps(meta))
    refused(["emulate", "s.zarr", "out.zarr", "--params", str(make.REPO / "params.yaml"), "--workers", "2"],
            "image 1: profile lacks required field(s): gain_dn_per_e", tmp_path)
