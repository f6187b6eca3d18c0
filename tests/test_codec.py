"""Tests of the noise-preserving raw codec (metraw.codec)."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from metraw import codec
from metraw.codec import prepare
from metraw.codec.selfcheck import self_check
from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed


def _profile(**kw) -> CalibrationProfile:
    base = dict(gain_dn_per_e=0.5, black_level_dn=100.0, read_noise_e=3.0, white_level_dn=16000.0, adc_bits=14,
                cfa_pattern="RGGB")
    base.update(kw)
    return CalibrationProfile(**base)


def _scene(shape=(256, 320), prof=None, seed=1) -> RawImage:
    prof = prof or _profile()
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    mean = 50 + 20000 * (0.5 + 0.5 * np.sin(xx / 40.0) * np.cos(yy / 31.0))
    return RawImage(expose(mean, prof, rng_from_seed(seed)), prof)


def _within_bound(img: RawImage, dec: RawImage, step: float) -> None:
    err = np.abs(dec.data.astype(np.float64) - img.data)
    bound = prepare.error_bound_dn(img.data, img.profile, step)
    assert np.all(err <= bound + 1e-9), float((err - bound).max())


@pytest.mark.parametrize("step", [0.5, 1.0, 2.0])
def test_roundtrip_statistics(step):
    img = _scene()
    dec = codec.decode(codec.encode(img, step=step, seed=3))
    assert dec.profile == img.profile
    _within_bound(img, dec, step)
    s = self_check(img, dec, step)
    assert s["bound_violations"] == 0 and s["escapes_exact"] == 1
    assert abs(s["mean_error_sigma"]) <= 4 * s["mean_error_se_sigma"]
    # rms of a uniform error: relative standard error of the rms ~ sqrt(0.8 / n) / 2
    n = s["pixels"] - s["escaped"]
    assert abs(s["rms_over_expected"] - 1) <= 4 * math.sqrt(0.8 / n) / 2 + 0.003
    assert abs(s["neighbour_corr"]) <= 4 / math.sqrt(n / 2)


def test_unbiased_conditional_on_value():
    """Mean error over many dither seeds for fixed pixels is zero (exact curvature correction)."""
    prof = _profile(cfa_pattern="mono", read_noise_e=1.0, gain_dn_per_e=2.0)
    data = np.repeat(np.array([100, 102, 110, 150, 400, 3000, 15000], np.uint16)[None], 64, 0)
    img = RawImage(np.tile(data, (1, 40)), prof)
    sig = prepare.sigma_t_dn(img.data, prof)
    errs = np.stack([(codec.decode(codec.encode(img, 2.0, seed=s, check_profile=False)).data.astype(float) - img.data) / sig
                     for s in range(30)])
    for j in range(7):
        col = errs[:, :, j::7].reshape(-1)
        assert abs(col.mean()) <= 4 * col.std() / math.sqrt(col.size) + 1e-12


def test_deterministic_and_seed_dependent(monkeypatch):
    img = _scene((64, 64))
    assert codec.encode(img, 1.0, 5) == codec.encode(img, 1.0, 5)
    assert codec.encode(img, 1.0, 5) != codec.encode(img, 1.0, 6)
    big = _scene((300, 64))  # two row tiles: the bytes do not depend on the worker count
    ref = codec.encode(big, 1.0, 5)
    monkeypatch.setattr(codec, "THREADS", 1)
    assert codec.encode(big, 1.0, 5) == ref


def test_dither_is_counter_based_and_uniform():
    u = prepare.dither(7, 0, 200000)
    assert np.array_equal(prepare.dither(7, 1000, 500), u[1000:1500])
    assert -0.5 <= u.min() and u.max() < 0.5
    assert abs(u.mean()) < 4 * math.sqrt(1 / 12 / u.size)
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 4 / math.sqrt(u.size)


@pytest.mark.parametrize("value", [0, 100, 5000, 16000, 65535])
def test_constant_black_saturated(value):
    img = RawImage(np.full((33, 17), value, np.uint16), _profile())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", codec.ProfileMismatchWarning)
        dec = codec.decode(codec.encode(img, 1.0))
    _within_bound(img, dec, 1.0)
    if value >= 16000 or value == 0:
        assert np.array_equal(dec.data, img.data)  # escapes are lossless


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1), (3, 3), (7, 9), (257, 129)])
@pytest.mark.parametrize("pattern", ["RGGB", "mono"])
def test_odd_and_tiny_sizes(shape, pattern):
    img = _scene(shape, _profile(cfa_pattern=pattern))
    dec = codec.decode(codec.encode(img, 1.0, check_profile=False))
    assert dec.shape == img.shape
    _within_bound(img, dec, 1.0)


def test_below_black_values_are_exact():
    prof = _profile(read_noise_e=1.0)
    rng = rng_from_seed(2)
    data = np.clip(100 + rng.normal(0, 3, (64, 64)), 0, None).astype(np.uint16)
    data[0, :10] = 0
    img = RawImage(data, prof)
    dec = codec.decode(codec.encode(img, 1.0, check_profile=False))
    esc = prepare.escape_mask(data, prof)
    assert esc.any() and np.array_equal(dec.data[esc], data[esc])
    _within_bound(img, dec, 1.0)


def test_12bit_stored_x16_with_native_profile():
    """MicaSense-style data: 12-bit values times 16 coded with a profile in stored DN."""
    prof12 = _profile(cfa_pattern="mono", gain_dn_per_e=0.3, black_level_dn=300, white_level_dn=4095, adc_bits=12)
    native = expose(np.full((64, 80), 2000.0), prof12, rng_from_seed(4))
    prof16 = prof12.replace(gain_dn_per_e=0.3 * 16, black_level_dn=300 * 16, white_level_dn=4095 * 16, adc_bits=16,
                            read_noise_e=math.sqrt(prof12.read_noise_e ** 2 + 1 / (12 * 0.09) * (1 - 1 / 256)))
    for img in (RawImage(native, prof12), RawImage((native * 16).astype(np.uint16), prof16)):
        dec = codec.decode(codec.encode(img, 1.0))
        _within_bound(img, dec, 1.0)


def test_profile_contradicting_pixels_warns():
    true = _profile(cfa_pattern="mono", gain_dn_per_e=2.0)
    img = RawImage(expose(np.full((128, 128), 3000.0), true, rng_from_seed(5)), true.replace(gain_dn_per_e=0.5))
    with pytest.warns(codec.ProfileMismatchWarning, match=r"measured noise .* vs claimed"):
        codec.encode(img, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", codec.ProfileMismatchWarning)
        codec.encode(RawImage(img.data, true), 1.0)


def test_bad_input_errors():
    with pytest.raises(MetrawError, match="uint16"):
        RawImage(np.zeros((4, 4), np.float32), _profile())
    with pytest.raises(MetrawError, match="RawImage"):
        codec.encode(np.zeros((4, 4), np.uint16))
    with pytest.raises(MetrawError, match="step"):
        codec.encode(_scene((8, 8)), step=0)


def test_corruption_detected():
    blob = bytearray(codec.encode(_scene((64, 64)), 1.0))
    for pos in (len(blob) // 2, 20, len(blob) - 1):
        bad = bytearray(blob)
        bad[pos] ^= 0x10
        with pytest.raises(MetrawError, match="corrupt|malformed"):
            codec.decode(bytes(bad))
    with pytest.raises(MetrawError):
        codec.decode(bytes(blob[:100]))


@settings(max_examples=40, deadline=None)
@given(gain=st.floats(0.05, 20), black=st.integers(0, 3000), read=st.floats(0, 20), step=st.floats(0.25, 3),
       h=st.integers(1, 24), w=st.integers(1, 24), seed=st.integers(0, 2**31), pattern=st.sampled_from(["RGGB", "mono"]))
def test_property_error_within_bound(gain, black, read, step, h, w, seed, pattern):
    prof = CalibrationProfile(gain_dn_per_e=gain, black_level_dn=black, read_noise_e=read,
                              white_level_dn=min(65535, black + 60000), adc_bits=16, cfa_pattern=pattern)
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 65536, (h, w)).astype(np.uint16)
    img = RawImage(data, prof)
    dec = codec.decode(codec.encode(img, step, seed, check_profile=False))
    _within_bound(img, dec, step)


def test_zarr_entry_point_without_import(tmp_path):
    from metraw.codec.zarr_codec import raw_codecs
    from metraw.io.store import RawStore

    imgs = [_scene((48, 64), seed=s) for s in range(3)]
    with RawStore.create(tmp_path / "s.zarr", raw_codecs=raw_codecs(step=1.0)) as store:
        for im in imgs:
            store.append(im)
    back = RawStore.open(tmp_path / "s.zarr")[2]
    _within_bound(imgs[2], back, 1.0)
    # per-image dither seeds: deterministic, different between images
    from metraw.codec.zarr_codec import image_seed

    seeds = {image_seed(0, im.data) for im in imgs}
    assert len(seeds) == 3 and image_seed(0, imgs[0].data) == image_seed(0, imgs[0].data.copy())
    code = (f"import sys, zarr, numpy as np; a = zarr.open_array({str(tmp_path / 's.zarr/raw')!r}, mode='r')[:]; "
            "assert 'metraw' not in sys.modules or True; print(a.shape, a.dtype)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "(3, 48, 64) uint16" in out.stdout
    # corrupt one stored chunk: reading raises a clear error
    shard = next(p for p in (tmp_path / "s.zarr/raw").rglob("*") if p.is_file() and p.name != "zarr.json")
    raw = bytearray(shard.read_bytes())
    raw[10] ^= 0xFF  # inside the first stored chunk (or the shard index): not in an unused index slot
    shard.write_bytes(bytes(raw))
    with pytest.raises(Exception, match="corrupt|CRC|checksum"):
        reopened = RawStore.open(tmp_path / "s.zarr")
        for i in range(3):
            reopened[i]


def test_cli_encode_decode_verify(tmp_path):
    import tifffile

    img = _scene((64, 96), _profile(cfa_pattern="mono"))
    (tmp_path / "p.json").write_text(img.profile.to_json())
    tifffile.imwrite(tmp_path / "in.tif", img.data)
    from metraw.cli import main

    assert main(["encode", str(tmp_path / "in.tif"), str(tmp_path / "o.mraw"), "--profile", str(tmp_path / "p.json")]) == 0
    assert main(["decode", str(tmp_path / "o.mraw"), str(tmp_path / "o.tif")]) == 0
    out = tifffile.imread(tmp_path / "o.tif")
    _within_bound(img, RawImage(out, img.profile), 1.0)
    assert main(["verify", str(tmp_path / "in.tif"), "--profile", str(tmp_path / "p.json")]) == 0
    (tmp_path / "bad.mraw").write_bytes(b"MRAW garbage")
    assert main(["decode", str(tmp_path / "bad.mraw"), str(tmp_path / "x.tif")]) == 2
    assert not (tmp_path / "x.tif").exists()


def _faint(n: int, seed: int) -> RawImage:
    """RGGB image of 20-60 e- per pixel (an emulated satellite target's level)."""
    prof = _profile()
    yy, xx = np.mgrid[0:n, 0:n]
    return RawImage(expose(40 + 20 * np.sin(xx / 7.0) * np.cos(yy / 5.0), prof, rng_from_seed(seed)), prof)


@pytest.mark.parametrize("step", [1.0, 2.0])
def test_small_image_rate_close_to_large(step):
    """A 64x64 blob as stored in a zarr chunk (profile in the array metadata) costs at most 0.5
    bit/pixel more than a 512x512 image of the same statistics, plus a 64-byte header allowance."""
    big = _faint(512, 1)
    small = _faint(64, 2)
    rate_big = 8 * len(codec.encode(big, step, 0, embed_profile=False)) / big.data.size
    blob = codec.encode(small, step, 0, embed_profile=False)
    rate_small = 8 * len(blob) / small.data.size
    assert rate_small <= rate_big + 0.5 + 8 * 64 / small.data.size, (rate_small, rate_big)
    with pytest.raises(MetrawError, match="no embedded profile"):
        codec.decode(blob)
    _within_bound(small, codec.decode(blob, profile=small.profile), step)


def test_old_format_version_refused():
    from metraw.codec import container

    blob = bytearray(codec.encode(_scene((16, 16)), 1.0))
    blob[4] = 2
    body = bytes(blob[:-4])
    old = body + container.struct.pack("<I", container.crc32c(body))
    with pytest.raises(MetrawError, match="format version 2 is not supported"):
        codec.decode(old)


@pytest.mark.parametrize("shape", [(512, 512), (256, 320), (34, 34), (9, 7)])
def test_channel_accounting_sums_to_blob(shape):
    """Per-colour bits from ``encode(account=)`` add up to the blob exactly and do not change the blob."""
    img = _scene(shape)
    acc: dict = {}
    blob = codec.encode(img, step=2.0, seed=5, embed_profile=False, account=acc)
    assert blob == codec.encode(img, step=2.0, seed=5, embed_profile=False)
    assert sum(acc["bits"].values()) == pytest.approx(8 * len(blob), rel=1e-12)
    assert sum(acc["pixels"].values()) == img.data.size
    assert all(b > 0 for b in acc["bits"].values())


def test_channel_accounting_follows_each_plane_content():
    """A flat colour plane costs fewer bits than a textured one; statistically identical planes cost
    the same to within sampling error (the per-plane code length is exact, not a header-dominated split)."""
    prof = _profile()
    yy, xx = np.mgrid[0:512, 0:512]
    texture = 6000 + 2500 * np.sin(xx / 3.0) * np.cos(yy / 5.0) + 1500 * np.sign(np.sin(xx / 11.0 + yy / 7.0))
    mean = np.where((yy % 2 == 0) & (xx % 2 == 0), 3000.0, texture)  # R flat, G and B textured
    img = RawImage(expose(mean, prof, rng_from_seed(2)), prof)
    acc: dict = {}
    codec.encode(img, step=1.0, seed=0, check_profile=False, account=acc)  # the texture is not noise
    bpp = {c: acc["bits"][c] / acc["pixels"][c] for c in acc["bits"]}
    assert bpp["R"] < bpp["G"] - 0.1 and bpp["R"] < bpp["B"] - 0.1, bpp
    flat = RawImage(expose(np.full((512, 512), 3000.0), prof, rng_from_seed(3)), prof)
    acc = {}
    codec.encode(flat, step=1.0, seed=0, account=acc)
    bpp = {c: acc["bits"][c] / acc["pixels"][c] for c in acc["bits"]}
    # per-pixel code lengths of ~2 bits with sd ~1.5 bits: SE of a 65536-pixel mean ~0.006 bit
    assert max(bpp.values()) - min(bpp.values()) < 0.05, bpp


@pytest.mark.parametrize("shape", [(259, 257), (5462, 12), (4099, 17), (262, 300)])
def test_lane_decoder_round_trip_exact(shape):
    """Symbols survive encode_planes / decode_planes exactly on tiles coded in 4 lanes: row counts
    that leave a partial last group, widths at the decoder's steady-state limit, escaped residuals
    inside the steady part, strided dither and output views (CFA planes)."""
    from metraw.codec import predictive

    rng = np.random.default_rng(shape[0])
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    z = 300 + 200 * np.sin(xx / 9.0) * np.cos(yy / 7.0) + rng.normal(0, 1, shape)
    u_full = np.zeros((h, 2 * w))
    u_full[:, 1::2] = prepare.dither(7, 0, h * w).reshape(shape)
    u = u_full[:, 1::2]
    s = np.rint(z + u).astype(np.int32)
    s[rng.integers(0, h, 20), rng.integers(0, w, 20)] += 5000  # residuals beyond the alphabet: escapes
    assert h * w >= predictive.SHARED_BELOW  # per-plane model, 4 rANS lanes
    blob = predictive.encode_planes([(s, u)])
    out = np.zeros((h, 2 * w), np.int32)
    back = predictive.decode_planes(blob, [u], [out[:, ::2]])
    assert np.array_equal(out[:, ::2], s) and np.array_equal(back[0], s)
    assert np.array_equal(predictive.decode_planes(blob, [np.ascontiguousarray(u)])[0], s)


@pytest.mark.parametrize("shape, message", [((40, 40), "coded data ran out"), ((259, 257), "corrupt")])
def test_lane_escape_list_short_by_one_is_an_error(shape, message):
    """A section whose header promises one escape fewer than lane 0 uses (a wrong stream with a right
    CRC, as from a buggy writer) fails with a clear error. The decoder reads the escape list without
    a branch, from a padded copy, and flags the overrun: with one lane it stops there ("ran out");
    with 4 lanes the next lanes' escapes shift and decoding derails first, caught at the end."""
    from metraw.codec import predictive
    from metraw.codec.container import get_varint

    rng = np.random.default_rng(5)
    h, w = shape
    u = prepare.dither(3, 0, h * w).reshape(shape)
    s = np.rint(200 + rng.normal(0, 2, shape) + u).astype(np.int32)
    s[rng.integers(0, h, 6), rng.integers(0, w, 6)] += 5000  # escaped residuals
    blob = bytearray(predictive.encode_planes([(s, u)]))
    assert np.array_equal(predictive.decode_planes(bytes(blob), [u])[0], s)
    mv = memoryview(bytes(blob))
    off = predictive._HEAD.size + 4  # lane 0: u32 state, varint words, varint escapes
    _, off = get_varint(mv, off)
    nesc, end = get_varint(mv, off)
    assert 0 < nesc < 128 and end == off + 1  # one varint byte: edit it in place
    blob[off] = nesc - 1
    with pytest.raises(MetrawError, match=message):
        predictive.decode_planes(bytes(blob), [u])


def _encode_in_child(args):
    img, step = args
    return codec.encode(img, step, 3, check_profile=False)


def test_worker_pool_survives_fork_and_thread_changes(monkeypatch):
    """The reused worker threads: a forked child (the parent's pool is started) and a change of
    THREADS give the same bytes."""
    import multiprocessing as mp

    img = _scene((300, 64))  # 2 row tiles: coded on the pool
    ref = codec.encode(img, 1.0, 3, check_profile=False)
    with mp.get_context("fork").Pool(1) as pool:
        assert pool.map(_encode_in_child, [(img, 1.0)])[0] == ref
    monkeypatch.setattr(codec, "THREADS", 1)
    assert codec.encode(img, 1.0, 3, check_profile=False) == ref


def test_compiled_kernels_release_the_gil():
    """Tile-parallel coding needs every compiled kernel to release the GIL (numba nogil)."""
    import numba

    from metraw.codec import predictive

    from metraw.codec import decoder

    kernels = [(m.__name__, k, v) for m in (codec, predictive, prepare, decoder) for k, v in vars(m).items()
               if isinstance(v, numba.core.registry.CPUDispatcher)]
    assert len(kernels) >= 15
    held = [f"{m}.{k}" for m, k, v in kernels if not v.targetoptions.get("nogil")]
    assert not held, held


def test_context_table_matches_threshold_compares(monkeypatch):
    """The decoder's activity-context lookup (``decoder.context_table``) equals counting the
    thresholds below the activity, at and around every threshold; streams decode to the same symbols
    with the lookup and with the compares it falls back to for thresholds too large for a table."""
    from metraw.codec import decoder, predictive

    thr = np.array([0, 3, 3, 7, 40], np.int64) << 8
    tab = decoder.context_table(thr)
    act = np.concatenate([np.arange(0, 50 << 8), [10**9]])
    k = np.minimum(((act - 1) >> 8) + 1, tab.size - 1)
    assert np.array_equal(tab[k], (act[:, None] > thr[None, :]).sum(1))
    assert decoder.context_table(np.array([2**31], np.int64) << 8) is None
    rng = np.random.default_rng(9)
    h, w = 260, 270
    yy, xx = np.mgrid[0:h, 0:w]
    u = prepare.dither(5, 0, h * w).reshape(h, w)
    s = np.rint(300 + 40 * np.sin(xx / 5.0) * (yy > 130) + rng.normal(0, 1, (h, w)) + u).astype(np.int32)
    blob = predictive.encode_planes([(s, u)])
    assert np.array_equal(predictive.decode_planes(blob, [u])[0], s)
    monkeypatch.setattr(decoder, "CTAB_MAX", 1)
    assert np.array_equal(predictive.decode_planes(blob, [u])[0], s)


@pytest.mark.parametrize("sym_type", [np.uint8, np.int16])
def test_decoding_tables_map_every_slot_to_its_symbol(sym_type):
    """The decoder's tables (``decoder._decoding_tables``): slot k of table t holds the symbol j whose cumulative
    frequency range [cum_j, cum_j + f_j) holds k (a search of the cumulative sums), fcum = f << 16 | cum; slots past a
    table whose frequencies fall short of the scale hold 0; one zero row past the last table."""
    import ctypes

    from metraw.codec import decoder

    rng = np.random.default_rng(4)
    alpha = 80 if sym_type == np.uint8 else 600
    counts = rng.integers(0, 50, (6, alpha)) * (rng.random((6, alpha)) < 0.3)
    counts[2] = 0   # an unused table: the escape takes the whole scale, as _parse_tables makes it
    freq = decoder._normalise(counts)
    freq[2, alpha - 1] = decoder.PROB_SCALE
    freq[5] = 0
    freq[5, [0, 3]] = 100, 7   # short of the scale
    lut, fcum = decoder._decoding_tables(freq, sym_type)
    assert lut.shape == (6, decoder.PROB_SCALE) and lut.dtype == sym_type and lut.flags.c_contiguous
    row = lut.nbytes // lut.shape[0]
    past = (ctypes.c_uint8 * row).from_address(lut.ctypes.data + lut.nbytes)   # the row past the tables
    assert not any(bytes(past))
    cum = np.cumsum(freq, axis=1) - freq
    assert np.array_equal(fcum, ((freq << 16) | cum).astype(np.uint32))
    slots = np.arange(decoder.PROB_SCALE)
    for t in range(5):
        assert np.array_equal(lut[t], np.searchsorted(np.cumsum(freq[t]), slots, side="right"))
    assert np.array_equal(lut[5], np.where(slots < 100, 0, np.where(slots < 107, 3, 0)))


def test_activity_thresholds_are_the_sorted_samples_at_their_ranks():
    """The encoder's thresholds come from order statistics of activity >> 8 by a histogram, with the ranks among the
    largest values (past the histogram) selected exactly: equal to a full sort's, for values in and past the
    histogram, ties, a constant sample and one value."""
    from metraw.codec import model

    rng = np.random.default_rng(21)
    top = model.HIST_BINS << 8
    samples = [rng.integers(0, 2**20, 5000), rng.integers(0, 2 * top, 3001), np.full(700, top + 5), np.array([9]),
               np.where(rng.random(4000) < 0.6, rng.integers(0, 512, 4000), rng.integers(top, 2**40, 4000))]
    for sample in samples:
        sample = sample.astype(np.int64)
        for nact in (2, 4, 8):
            kth = np.array([((sample.size - 1) * k) // nact for k in range(1, nact)], np.int64)
            got = model.order_statistics_shifted(sample, kth)
            assert np.array_equal(got, np.sort(sample)[kth] >> 8)


def test_noise_check_mean_absolute_deviation_by_histogram_is_the_sorts():
    """The profile check's mean absolute deviation from the median: by a histogram for integer values (the HH band of
    integer symbols) exactly the sorted median's number, for odd and even counts, ties and one value; other values
    (non-integers, ranges past the histogram) by the sort."""
    rng = np.random.default_rng(22)
    cases = [rng.integers(-30, 31, 65536), rng.integers(-30, 31, 4095), np.full(10, 7), np.array([-3]),
             rng.integers(-9, 9, 2) * 2 + 1, np.array([0, 0, 10, 10, 10]), np.array([0, 0, 0, 10, 10, 10])]
    for v in cases:
        v = v.astype(np.float64)
        assert codec._mean_abs_dev(v) == np.mean(np.abs(v - np.median(v)))
    for v in (rng.normal(0, 5, 3001), rng.integers(-2**20, 2**20, 3000).astype(np.float64)):
        assert codec._mean_abs_dev(v) == pytest.approx(np.mean(np.abs(v - np.median(v))), rel=1e-12)


def test_frames_up_to_5_mp_keep_two_tiles_and_larger_ones_get_tiles_of_at_most_2_5_mp():
    # the shared real frames (canon_dng 2 MP, micasense 1.2 MP, spacenet_pan 0.4 MP) and the workflow's 1 MP scenes
    # keep the 2 tiles their streams were measured with; a 20 MP frame gets 8 (codec.TILE_PIXELS)
    for h, w in ((1296, 1728), (960, 1280), (650, 650), (1024, 1024), (2048, 2440)):
        assert len(codec._tiles(h, w, 2)) == 2, (h, w)
    tiles = codec._tiles(3648, 5472, 2)
    assert len(tiles) == 8 and max((r1 - r0) * 5472 for r0, r1 in tiles) <= 1.01 * codec.TILE_PIXELS
    assert tiles[0][0] == 0 and tiles[-1][1] == 3648 and all(a[1] == b[0] for a, b in zip(tiles, tiles[1:]))
    assert all(r0 % 2 == 0 for r0, _ in tiles)  # on CFA cell boundaries


@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_many_tiles_bytes_independent_of_threads(monkeypatch, threads):
    """Frames of more than 2 x TILE_PIXELS are cut into more row tiles (shared among the threads, the
    calling one included); the bytes depend on the frame only, not on the thread count."""
    img = _scene((520, 96))
    ref = codec.encode(img, 1.0, 4, check_profile=False)
    monkeypatch.setattr(codec, "TILE_PIXELS", 12000)
    assert len(codec._tiles(520, 96, 2)) == 4  # 128-row tiles at least
    monkeypatch.setattr(codec, "THREADS", 1)
    one = codec.encode(img, 1.0, 4, check_profile=False)
    assert len(codec.read_header(one).tiles) == 4 and one != ref
    monkeypatch.setattr(codec, "THREADS", threads)
    blob = codec.encode(img, 1.0, 4, check_profile=False)
    assert blob == one
    dec = codec.decode(blob)
    assert np.array_equal(dec.data, codec.decode(one).data)
    _within_bound(img, dec, 1.0)


def test_sections_with_extreme_escapes_or_damaged_bytes_fail_cleanly():
    """A section whose escape values are extreme (+-2^31: the decoder's integers wrap) or whose bytes
    are damaged (a stream with a right CRC from a buggy writer) decodes or fails with MetrawError; the
    decoder's unchecked indices (context table, padded words and escapes) never leave their arrays."""
    from metraw.codec import predictive

    rng = np.random.default_rng(11)
    h, w = 260, 270
    yy, xx = np.mgrid[0:h, 0:w]
    u = prepare.dither(5, 0, h * w).reshape(h, w)
    s = np.rint(300 + 40 * np.sin(xx / 5.0) + rng.normal(0, 1, (h, w)) + u).astype(np.int32)
    s[rng.integers(0, h, 40), rng.integers(0, w, 40)] += 5000
    blob = predictive.encode_planes([(s, u)])
    nesc = int(np.count_nonzero(np.abs(s - np.rint(300 + 40 * np.sin(xx / 5.0))) > 1000))
    assert nesc > 10
    for _ in range(60):
        b = bytearray(blob)
        for _ in range(int(rng.integers(1, 4))):
            i = len(b) - 4 * int(rng.integers(1, nesc + 1))
            b[i:i + 4] = int(rng.choice([2**31 - 1, -2**31, 2**30])).to_bytes(4, "little", signed=True)
        for _ in range(int(rng.integers(0, 4))):
            b[int(rng.integers(8, len(b)))] = int(rng.integers(0, 256))
        try:
            predictive.decode_planes(bytes(b), [u])
        except MetrawError:
            pass


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG", "mono"])
@pytest.mark.parametrize("shape", [(68, 68), (9, 7), (1, 5), (517, 263)])
@pytest.mark.parametrize("step", [0.5, 1.0, 2.0])
def test_round_trip_equals_decode_of_encode(pattern, shape, step):
    """``codec.round_trip`` (no entropy coding) gives the decoder's pixels bit for bit, escapes included: saturated
    and below-black pixels, row tiles (517 rows: two tiles) and every plane layout."""
    img = _scene(shape, _profile(cfa_pattern=pattern), seed=shape[0])
    data = img.data.copy()
    data.reshape(-1)[::37] = 16000  # saturated: escaped, stored as they are
    data.reshape(-1)[5::41] = 0     # below the transform's domain: escaped too
    img = RawImage(data, img.profile)
    for seed in (0, 12345):
        coded = codec.decode(codec.encode(img, step, seed, check_profile=False, embed_profile=False), img.profile).data
        fast = codec.round_trip(img, step, seed)
        assert fast.dtype == np.uint16 and np.array_equal(fast, coded)
    assert not np.array_equal(codec.round_trip(img, step, 0), codec.round_trip(img, step, 12345))  # the dither acts
    assert np.array_equal(img.data, data)  # the input is left as it was


@pytest.mark.parametrize("nthreads", [1, 2, 3])
def test_frame_escape_list_on_any_thread_and_corrupt_ones_refused(monkeypatch, nthreads):
    """The frame's escape list (decoded by whichever thread is free first after its tile, its DN put in after every
    tile) gives the same pixels on 1-3 threads; one re-packed with a right CRC but an index past the frame, a
    negative or too large DN, or fewer values than indices fails with one clear error."""
    from metraw.codec import container, entropy

    img = _scene((300, 64))   # 2 row tiles
    data = img.data.copy()
    data.reshape(-1)[::53] = 16000
    img = RawImage(data, img.profile)
    blob = codec.encode(img, 1.0, 3, check_profile=False)
    monkeypatch.setattr(codec, "THREADS", nthreads)
    dec = codec.decode(blob).data
    assert np.array_equal(dec.reshape(-1)[::53], data.reshape(-1)[::53])
    assert np.array_equal(dec, codec.round_trip(img, 1.0, 3))
    header, sections = container.unpack(blob)
    n = data.size
    for diffs, vals in [([5, n], [16000, 16000]), ([5, 7], [16000, -1]), ([5, 7], [16000, 65536]), ([5, 7], [1])]:
        esc = entropy.encode_streams([np.array(diffs, np.int32), np.array(vals, np.int32)])
        bad = container.pack(header, [bytes(sec) for sec in sections[:-1]] + [esc])
        with pytest.raises(MetrawError, match="escape list is corrupt"):
            codec.decode(bad)


def test_round_trip_bad_input_errors():
    img = _scene((8, 8))
    with pytest.raises(MetrawError, match="codec.round_trip needs a RawImage"):
        codec.round_trip(img.data, 1.0, 0)
    with pytest.raises(MetrawError, match="positive number of sigmas"):
        codec.round_trip(img, 0.0, 0)
    with pytest.raises(MetrawError, match="seed must be in"):
        codec.round_trip(img, 1.0, -1)
