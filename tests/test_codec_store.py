"""Stores written with ``--codec-step``: the raw array uses the metraw.raw zarr codec, reads back in a
fresh process, every pixel's error obeys the codec's bound and the store says it is quantised."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from metraw.cli import main
from metraw.codec.prepare import error_bound_dn
from metraw.io.store import RawStore

STEP = 2.0


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("codec_store")
    plain, coded = d / "plain.zarr", d / "coded.zarr"
    assert main(["scenes", "--n", "2", "--size", "96", "--workers", "1", "--out", str(plain)]) == 0
    assert main(["scenes", "--n", "2", "--size", "96", "--workers", "1", "--out", str(coded),
                 "--codec-step", str(STEP), "--codec-seed", "3"]) == 0
    return plain, coded


READ = """
import json, sys
import numpy as np, zarr
from metraw.io.store import RawStore
s = RawStore.open(sys.argv[1])
np.save(sys.argv[2], np.stack([im.data for im in s]))
codecs = [c.to_dict()["name"] for c in zarr.open_group(sys.argv[1])["raw"].metadata.codecs]
inner = zarr.open_group(sys.argv[1])["raw"].metadata.codecs[0].to_dict().get("configuration", {}).get("codecs", [])
print(json.dumps({"codecs": codecs + [c["name"] for c in inner], "attrs": s.attrs,
                  "provenance": [im.provenance[-1] for im in s]}))
"""


def test_codec_store_reads_back_in_fresh_process_within_bound(stores, tmp_path):
    plain, coded = stores
    out = tmp_path / "decoded.npy"
    res = subprocess.run([sys.executable, "-c", READ, str(coded), str(out)], capture_output=True, text=True, check=True)
    info = json.loads(res.stdout)
    assert "metraw.raw" in info["codecs"]
    rec = info["attrs"]["raw_codec"]
    assert rec["codec"] == "metraw.raw" and rec["step_sigma"] == STEP and rec["seed"] == 3
    assert rec["added_variance_vst"] == pytest.approx(STEP ** 2 / 12)
    assert all(p["function"] == "metraw.codec.zarr_codec" and p["params"]["step_sigma"] == STEP
               and p["params"]["profile_matches_codec"] for p in info["provenance"])
    decoded = np.load(out)
    ref = RawStore.open(plain)
    assert decoded.shape[0] == len(ref) == 2
    for i, img in enumerate(ref):
        err = decoded[i].astype(np.int64) - img.data.astype(np.int64)
        assert np.any(err != 0)  # really quantised
        assert np.all(np.abs(err) <= error_bound_dn(img.data, img.profile, STEP))


HIDE_ENTRY_POINT = """
import importlib.metadata as md, sys
def entry_points(**select):  # as in a source tree on PYTHONPATH: metraw's dist-info (and its entry point) absent
    found = md.EntryPoints(e for d in md.distributions() for e in d.entry_points if not e.value.startswith("metraw."))
    return found.select(**select) if select else found
md.entry_points = entry_points
import zarr.registry
assert not md.entry_points(group="zarr.codecs", name="metraw.raw")
"""


def test_codec_store_reads_without_the_installed_entry_point(stores, tmp_path):
    """metraw run from a source tree (not installed) still opens and decodes a codec store, the same pixels."""
    plain, coded = stores
    out, ref_out = tmp_path / "hidden.npy", tmp_path / "installed.npy"
    subprocess.run([sys.executable, "-c", READ, str(coded), str(ref_out)], capture_output=True, text=True, check=True)
    res = subprocess.run([sys.executable, "-c", HIDE_ENTRY_POINT + READ, str(coded), str(out)], capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "metraw.raw" in json.loads(res.stdout)["codecs"]
    assert np.array_equal(np.load(out), np.load(ref_out))


def test_without_codec_step_store_is_lossless(stores):
    plain, _ = stores
    s = RawStore.open(plain)
    assert "raw_codec" not in s.attrs
    assert all(im.provenance[-1]["function"] != "metraw.codec.zarr_codec" for im in s)


@pytest.mark.parametrize("step", ["0", "-1", "nan"])
def test_bad_codec_step_is_a_clear_error(tmp_path, step, capsys):
    assert main(["scenes", "--n", "1", "--size", "32", "--out", str(tmp_path / "x.zarr"), "--codec-step", step]) == 2
    assert "--codec-step must be a positive number" in capsys.readouterr().err
    assert not (tmp_path / "x.zarr").exists()


def test_decoded_copy_holds_the_same_images_uncompressed(stores, tmp_path, capsys):
    """`metraw decode STORE OUT`: every image equal (pixels, masks, flags, profile, provenance, meta), the same
    attributes and shard layout, the raw chunks plain uint16 (2 bytes per pixel on disk), the same content
    digest (a model trained on the copy recognises the original), and the original named as its origin."""
    import zarr

    from metraw.io.store import read_shard_index
    from metraw.segment.train import store_digest

    _, coded = stores
    out = tmp_path / "copy.zarr"
    assert main(["decode", str(coded), str(out), "--threads", "2"]) == 0
    assert "2 images" in capsys.readouterr().out
    src, copy = RawStore.open(coded), RawStore.open(out)
    assert len(copy) == len(src) == 2
    for a, b in zip(src, copy):
        assert a.data.dtype == b.data.dtype and np.array_equal(a.data, b.data)
        assert np.array_equal(a.mask, b.mask) and np.array_equal(a.flags, b.flags)
        assert a.profile.to_dict() == b.profile.to_dict() and a.provenance == b.provenance and a.meta == b.meta
    assert copy.attrs == {**src.attrs, "decoded_from": str(coded)}
    assert copy.origin == str(coded) and src.origin == str(coded)
    assert copy.images_per_shard == src.images_per_shard
    assert store_digest(copy) == store_digest(src)
    raw = zarr.open_group(str(out))["raw"]
    inner = raw.metadata.codecs[0].to_dict()["configuration"]["codecs"]
    assert [c["name"] for c in inner] == ["bytes"], inner  # no compressor, no metraw.raw
    h, w = src.shape(0)
    index = read_shard_index(out / "raw" / "c" / "0" / "0" / "0", copy.images_per_shard)
    assert list(index[:2, 1]) == [2 * h * w] * 2


def test_codec_decoded_store_holds_what_the_coded_store_decodes_to(stores, tmp_path, capsys):
    """`metraw scenes --codec-step S --codec-decoded`: the images a --codec-step store of the same scenes reads as
    (pixels bit for bit, masks, flags, profile, provenance with its quantisation record, meta, content digest),
    the raw chunks plain uint16, attributes `raw_codec` as the coded store's plus `raw_stored: decoded`."""
    import zarr

    from metraw.segment.train import store_digest

    _, coded = stores
    out = tmp_path / "decoded.zarr"
    assert main(["scenes", "--n", "2", "--size", "96", "--workers", "1", "--out", str(out),
                 "--codec-step", str(STEP), "--codec-seed", "3", "--codec-decoded"]) == 0
    src, direct = RawStore.open(coded), RawStore.open(out)
    assert len(direct) == len(src) == 2
    for a, b in zip(src, direct):
        assert b.data.dtype == np.uint16 and np.array_equal(a.data, b.data)
        assert np.array_equal(a.mask, b.mask) and np.array_equal(a.flags, b.flags)
        assert a.profile.to_dict() == b.profile.to_dict() and a.provenance == b.provenance and a.meta == b.meta
    assert direct.attrs == {**src.attrs, "raw_stored": "decoded"}
    assert store_digest(direct) == store_digest(src)
    inner = zarr.open_group(str(out))["raw"].metadata.codecs[0].to_dict()["configuration"]["codecs"]
    assert [c["name"] for c in inner] == ["bytes"], inner
    # the pixels are the codec's, not the scenes' own: quantised at the step, so some differ from a lossless store
    plain = RawStore.open(stores[0])
    assert any(not np.array_equal(p.data, d.data) for p, d in zip(plain, direct))
    assert main(["scenes", "--n", "1", "--size", "32", "--out", str(tmp_path / "x.zarr"), "--codec-decoded"]) == 2
    assert "--codec-decoded needs --codec-step" in capsys.readouterr().err
    assert not (tmp_path / "x.zarr").exists()


def test_decoded_copy_refuses_bad_input_in_one_line(stores, tmp_path, capsys):
    _, coded = stores
    (tmp_path / "exists.zarr").mkdir()
    assert main(["decode", str(coded), str(tmp_path / "exists.zarr")]) == 2
    assert "already exists" in capsys.readouterr().err
    (tmp_path / "plain_dir").mkdir()
    assert main(["decode", str(tmp_path / "plain_dir"), str(tmp_path / "o.zarr")]) == 2
    assert "not a metraw store" in capsys.readouterr().err
    assert main(["decode", str(coded), str(tmp_path / "o.zarr"), "--threads", "0"]) == 2
    assert "--threads must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "o.zarr").exists()
