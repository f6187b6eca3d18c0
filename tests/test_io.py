"""metraw.io: raw readers, lossless TIFF round trip, approximate raw from processed images, labels."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import tifffile

from metraw import CalibrationProfile, MetrawError, RawImage
from metraw.io import default_camera, noise_model_known, read_raw, srgb_to_linear, write_tiff
from metraw.io.dn import unused_low_bits
from metraw.io.labels import box_area_fraction, boxes_to_pixels, read_yolo
from metraw.io.processed import approximate_raw
from metraw.physics.daylight import neutral_response
from metraw.raw.image import FLAG_SATURATED
from metraw.raw.sensor import rng_from_seed

KSIG = 5.0  # tolerance in standard errors


def _png(path, rgb):
    import imagecodecs

    path.write_bytes(imagecodecs.png_encode(np.ascontiguousarray(rgb)))


def _camera(**changes):
    base = dict(gain_dn_per_e=0.5, black_level_dn=64, read_noise_e=2.5, white_level_dn=16383, adc_bits=14,
                cfa_pattern="RGGB", full_well_e=30000, qe_per_channel={"R": 0.4, "G": 0.6, "B": 0.3},
                pixel_pitch_m=2.4e-6, focal_length_m=10e-3, exposure_s=1e-3, camera="test cam")
    base.update(changes)
    return CalibrationProfile(**base)


# ------------------------------------------------------------------------------ helpers
def test_srgb_inverse_matches_the_standard_curve():
    lin = np.linspace(0, 1, 1001)
    encoded = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)  # IEC 61966-2-1 forward
    np.testing.assert_allclose(srgb_to_linear(encoded), lin, atol=2e-6)
    assert srgb_to_linear(0.5) == pytest.approx(0.21404114, rel=1e-6)


def test_unused_low_bits():
    rng = rng_from_seed(1)
    x = rng.integers(0, 4096, (64, 64)).astype(np.uint16)
    x[0, 0] = 1
    assert unused_low_bits(x) == 0
    assert unused_low_bits(x * np.uint16(16)) == 4
    assert unused_low_bits(np.uint16(8) * (2 * x + 1)) == 3
    assert unused_low_bits(np.zeros((4, 4), np.uint16)) == 0


# ------------------------------------------------------------------------------ TIFF
def test_write_tiff_round_trip_is_lossless(tmp_path):
    rng = rng_from_seed(2)
    data = rng.integers(0, 16384, (33, 47)).astype(np.uint16)
    mask = rng.random((33, 47)).astype(np.float32)
    flags = (data > 16000).astype(np.uint8) * FLAG_SATURATED
    prof = _camera(uncertainty={"gain_dn_per_e": 0.01, "read_noise_e": math.inf})
    img = RawImage(data, prof, mask=mask, flags=flags, provenance=[{"function": "x", "params": {"a": 1}}],
                   meta={"scene": "urban"})
    write_tiff(tmp_path / "a.tif", img)
    back = read_raw(tmp_path / "a.tif")
    assert back.data.dtype == np.uint16 and np.array_equal(back.data, data)
    assert np.array_equal(back.mask, mask) and np.array_equal(back.flags, flags)
    assert back.profile.to_dict() == prof.to_dict()
    assert back.provenance == img.provenance and back.meta == img.meta
    # atomic and no silent overwrite
    with pytest.raises(MetrawError, match="already exists"):
        write_tiff(tmp_path / "a.tif", img)
    assert [p.name for p in tmp_path.iterdir()] == ["a.tif"]


def test_raw_tiff_x16_is_shifted_down_losslessly(tmp_path):
    rng = rng_from_seed(3)
    twelve = rng.integers(250, 4096, (40, 60)).astype(np.uint16)
    twelve[0, 0] = 301  # make sure bit 0 is used
    tifffile.imwrite(tmp_path / "x16.tif", twelve * np.uint16(16), metadata=None,
                     extratags=[(50714, "I", 1, 4800, True)])
    img = read_raw(tmp_path / "x16.tif")
    assert np.array_equal(img.data, twelve)
    assert img.profile.adc_bits == 12 and img.profile.white_level_dn == 4095
    assert img.profile.black_level_dn == 300  # 4800 / 16
    assert {"function": "io.shift_unused_low_bits", "params": {"shift": 4}} in img.provenance
    assert img.profile.cfa_pattern == "mono" and not noise_model_known(img.profile)
    assert math.isinf(img.profile.uncertainty["gain_dn_per_e"])


# ------------------------------------------------------------------------------ headerless
def test_headerless_round_trip_and_byte_order(tmp_path):
    rng = rng_from_seed(4)
    data = rng.integers(0, 4096, (20, 30)).astype(np.uint16)
    (tmp_path / "a.raw").write_bytes(b"HDR!" + data.astype(">u2").tobytes())
    img = read_raw(tmp_path / "a.raw", width=30, height=20, dtype=">u2", offset_bytes=4, cfa_pattern="GRBG",
                   black_level_dn=64, adc_bits=12, gain_dn_per_e=0.4, read_noise_e=3.0)
    assert np.array_equal(img.data, data)
    assert img.profile.cfa_pattern == "GRBG" and img.profile.white_level_dn == 4095
    assert noise_model_known(img.profile)
    with pytest.raises(MetrawError, match="exceed the white level"):  # little-endian misread
        read_raw(tmp_path / "a.raw", width=30, height=20, dtype="<u2", offset_bytes=4, cfa_pattern="GRBG",
                 black_level_dn=64, adc_bits=12)


# ------------------------------------------------------------------------------ labels
def test_box_area_fraction_is_exact():
    rects = np.array([[1.25, 2.5, 6.75, 4.0], [5.0, 3.0, 9.5, 7.25], [-1, -1, 0.5, 0.5]], float)
    rects = np.clip(rects, 0, [10, 8, 10, 8])
    m = box_area_fraction(rects, (8, 10))
    # union area: 5.5*1.5 + 4.5*4.25 - overlap (1.75 * 1.0) + 0.25
    assert m.sum() == pytest.approx(5.5 * 1.5 + 4.5 * 4.25 - 1.75 * 1.0 + 0.25, abs=1e-5)
    assert m[3, 5] == 1.0 and m[2, 1] == pytest.approx(0.75 * 0.5) and m[0, 0] == pytest.approx(0.25)
    # against brute-force supersampling (error <= 2/s per pixel edge coverage)
    s = 64
    yy, xx = (np.mgrid[0:8 * s, 0:10 * s] + 0.5) / s
    inside = np.zeros(yy.shape, bool)
    for x0, y0, x1, y1 in rects:
        inside |= (xx >= x0) & (xx < x1) & (yy >= y0) & (yy < y1)
    brute = inside.reshape(8, s, 10, s).mean(axis=(1, 3))
    np.testing.assert_allclose(m, brute, atol=2.0 / s)


def test_yolo_parsing_and_car_classes(tmp_path):
    (tmp_path / "aerial.names").write_text("car\ntruck\nbus\nminibus\ncyclist\n")
    (tmp_path / "im.txt").write_text("0 0.25 0.5 0.2 0.25\n4 0.75 0.5 0.2 0.25\n3 0.5 0.125 0.1 0.25\n")
    _png(tmp_path / "im.png", np.full((16, 40, 3), 120, np.uint8))
    boxes = read_yolo(tmp_path / "im.txt")
    assert boxes.shape == (3, 5)
    img = read_raw(tmp_path / "im.png", camera=_camera())
    # cars: class 0 (8 x 4 px) and minibus (4 x 4 px); the cyclist is not a car
    assert img.mask.sum() == pytest.approx(8 * 4 + 4 * 4)
    assert img.mask[8, 30] == 0 and img.meta["car_boxes"] == 2
    assert img.meta["boxes_per_class"]["cyclist"] == 1 and "box-approximate" in img.meta["mask_kind"]
    assert img.profile.approximate and "processed" in img.profile.approximate_reason
    np.testing.assert_array_equal(boxes_to_pixels(boxes[:1], (16, 40)), [[6, 6, 14, 10]])


def test_mask_png_labels(tmp_path):
    _png(tmp_path / "im.png", np.full((8, 8, 3), 60, np.uint8))
    m = np.zeros((8, 8), np.uint8)
    m[2:5, 3:6] = 255
    _png(tmp_path / "im_mask.png", m)
    img = read_raw(tmp_path / "im.png", camera=_camera(), labels="mask")
    assert np.array_equal(img.mask, m / 255.0)


# ------------------------------------------------------------------------------ approximate raw physics
def test_approximate_raw_mean_and_variance_follow_the_camera_model():
    cam = _camera()
    v = 150
    rgb = np.full((256, 256, 3), v, np.uint8)
    img = approximate_raw(rgb, cam, rng_from_seed(5))
    lin = srgb_to_linear(v / 255.0)
    neutral = neutral_response(cam, 45.0)  # white balance undone for daylight
    scale = cam.saturation_e * np.array([neutral[c] for c in "RGB"])
    assert scale[1] == cam.saturation_e and scale[2] < scale[0] < scale[1]
    for (c, dy, dx) in [("R", 0, 0), ("G", 0, 1), ("G", 1, 0), ("B", 1, 1)]:
        x = img.data[dy::2, dx::2].astype(float)
        mu_e = lin * scale["RGB".index(c)]
        mean_dn = cam.black_level_dn + cam.gain_dn_per_e * (mu_e + cam.dark_current_e_per_s * cam.exposure_s)
        var_dn = float(cam.variance_dn2(mean_dn))
        n = x.size
        assert abs(x.mean() - mean_dn) < KSIG * math.sqrt(var_dn / n)
        assert abs(x.var(ddof=1) - var_dn) < KSIG * var_dn * math.sqrt(2 / (n - 1))
    assert img.profile.approximate and img.provenance[0]["function"] == "io.approximate_raw"


def test_approximate_raw_is_deterministic(tmp_path):
    rgb = rng_from_seed(6).integers(0, 256, (31, 45, 3)).astype(np.uint8)
    a = approximate_raw(rgb, _camera(), rng_from_seed(7))
    b = approximate_raw(rgb, _camera(), rng_from_seed(7))
    c = approximate_raw(rgb, _camera(), rng_from_seed(8))
    assert a.data.tobytes() == b.data.tobytes() and a.data.tobytes() != c.data.tobytes()
    _png(tmp_path / "p.png", rgb)
    x = read_raw(tmp_path / "p.png", camera=_camera(), seed=3, labels="none")
    y = read_raw(tmp_path / "p.png", camera=_camera(), seed=3, labels="none")
    assert x.data.tobytes() == y.data.tobytes()


def test_gsd_sets_altitude():
    img = approximate_raw(np.zeros((4, 4, 3), np.uint8), _camera(), rng_from_seed(0), gsd_m=0.13)
    assert img.profile.gsd_m == pytest.approx(0.13)
    assert approximate_raw(np.zeros((4, 4, 3), np.uint8), _camera(), rng_from_seed(0)).profile.gsd_m is None


def test_default_camera_is_params_source_camera():
    cam = default_camera()
    assert cam.cfa_pattern == "RGGB" and cam.gain_dn_per_e > 0 and "Hasselblad" in cam.camera


def test_camera_fills_unknown_noise_terms(tmp_path):
    tifffile.imwrite(tmp_path / "m.tif", np.arange(1, 601, dtype=np.uint16).reshape(20, 30), metadata=None,
                     extratags=[(50714, "I", 1, 0, True)])
    img = read_raw(tmp_path / "m.tif", camera=_camera(cfa_pattern="mono", qe_per_channel={}))
    assert img.profile.gain_dn_per_e == 0.5 and img.profile.read_noise_e == 2.5 and noise_model_known(img.profile)
    assert img.meta["filled_from_camera"]["camera"] == "test cam"


# ------------------------------------------------------------------------------ real data (data/real)
def test_real_canon_dng(real_data_dir):
    # canon_dng/SOURCE.txt: Canon 550D DNG, RGGB, BlackLevel 2056, WhiteLevel 15000
    img = read_raw(real_data_dir / "canon_dng" / "colorchart.dng")
    p = img.profile
    assert (p.cfa_pattern, p.black_level_dn, p.white_level_dn, p.adc_bits) == ("RGGB", 2056, 15000, 14)
    assert img.shape == (1156, 1734)  # DNG ActiveArea (26, 152, 1182, 1886)
    assert not p.approximate and not noise_model_known(p)


def test_real_micasense(real_data_dir):
    # micasense/SOURCE.txt: 12-bit data stored x16, BlackLevel 4800, XMP DarkRowValue
    path = real_data_dir / "micasense" / "IMG_0000_1.tif"
    stored = tifffile.imread(path)
    img = read_raw(path)
    assert np.array_equal(img.data.astype(np.uint32) * 16, stored)
    p = img.profile
    assert p.adc_bits == 12 and p.white_level_dn == 4095 and p.cfa_pattern == "mono"
    assert img.meta["black_level_tag_dn"] == [300.0] * 4
    assert p.black_level_dn == pytest.approx(np.mean([5092, 5082, 5049, 5063]) / 16)
    assert p.exposure_s == pytest.approx(472.5e-6) and p.pixel_pitch_m == pytest.approx(3.75e-6)


def test_real_spacenet_pan(real_data_dir):
    img = read_raw(real_data_dir / "spacenet_pan" / "pan1.tif")
    assert img.profile.cfa_pattern == "mono" and img.profile.adc_bits == 11 and img.profile.approximate
    assert img.meta["gsd_m"] == pytest.approx(0.5, rel=1e-4)


def test_real_kit_image(real_data_dir):
    # kit_ais/SOURCE.txt: YOLO boxes, classes car, truck, bus, minibus, cyclist
    path = real_data_dir / "kit_ais" / "MOS74.png"
    img = read_raw(path)
    lines = [l.split() for l in path.with_suffix(".txt").read_text().splitlines() if l.strip()]
    assert img.meta["car_boxes"] == sum(l[0] in "0123" for l in lines)
    assert img.profile.approximate and img.mask is not None and 0 < img.mask.mean() < 0.5
    assert json.loads(json.dumps(img.meta)) == img.meta
