"""The sharded zarr v3 dataset store."""

import numpy as np
import pytest

from metraw import CalibrationProfile, MetrawError, RawImage
from metraw.io.store import RawStore
from metraw.raw.image import FLAG_SATURATED
from metraw.raw.sensor import expose, rng_from_seed


def images(n, shape=(40, 50), seed=0):
    p = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=64, read_noise_e=3, white_level_dn=4095, adc_bits=12)
    rng = rng_from_seed(seed)
    out = []
    for i in range(n):
        mask = (rng.random(shape) > 0.8).astype(np.float32)
        out.append(RawImage(expose(np.full(shape, 100.0 + i), p, rng), p, mask=mask, meta={"index": i},
                            provenance=[{"function": "test", "params": {"i": i}}]))
    return out


def test_round_trip_with_padding_and_random_access(tmp_path):
    imgs = images(9) + [images(1, shape=(21, 33), seed=5)[0]]
    imgs[3].flags = np.zeros(imgs[3].shape, np.uint8)
    imgs[3].flags[0, 0] = FLAG_SATURATED
    imgs[4].mask = None
    with RawStore.create(tmp_path / "s.zarr", images_per_shard=4) as store:
        store.extend(imgs)
        store.set_attrs(generator="test")
    store = RawStore.open(tmp_path / "s.zarr")
    assert len(store) == 10 and store.attrs == {"generator": "test"}
    for i in (9, 0, 4, 3, 7):
        got, want = store[i], imgs[i]
        assert got.data.tobytes() == want.data.tobytes()
        assert got.profile == want.profile and got.meta == want.meta and got.provenance == want.provenance
        if want.mask is None:
            assert got.mask is None
        else:
            assert np.array_equal(got.mask, want.mask)
    assert store[3].flags[0, 0] == FLAG_SATURATED and store[2].flags is None
    # a handful of files: 10 images in shards of 4 -> 3 shard files per array
    assert len(list((tmp_path / "s.zarr" / "raw" / "c").iterdir())) == 3


def test_append_to_existing_store(tmp_path):
    imgs = images(5)
    with RawStore.create(tmp_path / "s.zarr", images_per_shard=2) as store:
        store.extend(imgs[:3])
    store = RawStore.open(tmp_path / "s.zarr", mode="a")
    store.extend(imgs[3:])
    store.close()
    store = RawStore.open(tmp_path / "s.zarr")
    assert [store[i].meta["index"] for i in range(len(store))] == [0, 1, 2, 3, 4]
    assert store[4].data.tobytes() == imgs[4].data.tobytes()


def test_failed_creation_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with RawStore.create(tmp_path / "s.zarr") as store:
            store.extend(images(2))
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_open_errors(tmp_path):
    with pytest.raises(MetrawError, match="not a zarr v3 store"):
        RawStore.open(tmp_path)
    with RawStore.create(tmp_path / "s.zarr") as store:
        store.extend(images(1))
    with pytest.raises(MetrawError, match="read-only"):
        RawStore.open(tmp_path / "s.zarr").append(images(1)[0])
    with pytest.raises(IndexError):
        RawStore.open(tmp_path / "s.zarr")[5]
