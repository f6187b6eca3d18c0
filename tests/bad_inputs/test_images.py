"""Bad image files: empty, truncated, wrong dtype, NaN / negative, odd CFA sizes, all-saturated and
all-black frames, unknown CFA patterns."""

from __future__ import annotations

import numpy as np
import pytest

from metraw.io import default_camera
from metraw.io.store import RawStore
from metraw.raw.image import RawImage

from . import _inputs as make
from ._check import refused


# ----------------------------------------------------------------------------- empty and truncated
def test_zero_byte_dng_info(tmp_path):
    (tmp_path / "a.dng").write_bytes(b"")
    refused(["info", "a.dng"], "empty file", tmp_path)


def test_zero_byte_tiff_ingest(tmp_path):
    (tmp_path / "a.tif").write_bytes(b"")
    refused(["ingest", "a.tif", "--out", "s.zarr"], "empty file", tmp_path)


def test_truncated_dng_calibrate(tmp_path):
    make.truncate(make.dng(tmp_path / "a.dng"))
    refused(["calibrate", "a.dng", "--out", "p.json"], "truncated", tmp_path)


@pytest.mark.real
def test_truncated_real_dng_encode(tmp_path, real_data_dir):
    data = (real_data_dir / "canon_dng" / "colorchart.dng").read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 3])
    refused(["encode", "cut.dng", "out.mraw"], "truncated", tmp_path)


def test_truncated_tiff_check(tmp_path):
    make.truncate(make.plain_tiff(tmp_path / "a.tif", np.arange(200 * 300, dtype=np.uint16).reshape(200, 300)))
    make.spec(tmp_path / "spec.yaml")
    refused(["check", "a.tif", "--spec", "spec.yaml", "--json", "d.json"], "truncated", tmp_path)


# ----------------------------------------------------------------------------- wrong pixel values
def test_wrong_dtype_uint32_calibrate(tmp_path):
    make.plain_tiff(tmp_path / "a.tif", np.full((16, 16), 70000, np.uint32))
    refused(["calibrate", "a.tif", "--out", "p.json"], "unsigned 16-bit", tmp_path)


def test_fractional_float_encode(tmp_path):
    make.plain_tiff(tmp_path / "a.tif", np.full((16, 16), 100.5, np.float32))
    refused(["encode", "a.tif", "out.mraw"], "fractional", tmp_path)


def test_nan_float_calibrate(tmp_path):
    a = np.full((16, 16), 100.0, np.float32)
    a[2, 3] = np.nan
    make.plain_tiff(tmp_path / "a.tif", a)
    refused(["calibrate", "a.tif", "--out", "p.json"], "NaN", tmp_path)


def test_negative_float_ingest(tmp_path):
    a = np.full((16, 16), 100.0, np.float32)
    a[0, :4] = -3.0
    make.plain_tiff(tmp_path / "a.tif", a)
    refused(["ingest", "a.tif", "--out", "s.zarr"], "4 negative values", tmp_path)


# ----------------------------------------------------------------------------- odd CFA sizes
def test_odd_size_rggb_frame_calibrate(tmp_path):
    # a 5 x 4 RGGB mosaic is a valid image (the codec round-trips it) but holds no smooth blocks to fit
    make.metraw_tiff(tmp_path / "a.tif", make.ramp((5, 4)))
    refused(["calibrate", "a.tif", "--out", "p.json"], "too small", tmp_path)


def test_odd_size_rggb_frame_emulate(tmp_path):
    # a 5 x 4 drone frame covers 0.3 m of ground: less than one satellite pixel
    with RawStore.create(tmp_path / "src.zarr") as store:
        store.append(RawImage(np.random.default_rng(0).integers(300, 2000, (5, 4)).astype(np.uint16),
                              default_camera(make.REPO / "params.yaml")))
    refused(["emulate", "src.zarr", "out.zarr", "--params", str(make.REPO / "params.yaml"), "--workers", "1"],
            "source frame covers only", tmp_path)


# ----------------------------------------------------------------------------- frames that constrain nothing
def test_all_saturated_calibrate(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif", np.full((64, 64), 4095))
    refused(["calibrate", "a.tif", "--out", "p.json"], "saturated", tmp_path)


def test_all_black_calibrate(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif", np.full((64, 64), 64))
    refused(["calibrate", "a.tif", "--out", "p.json"], "all-black", tmp_path)


def test_all_saturated_encode_without_profile(tmp_path):
    # no --profile: encode calibrates from the frame, which a saturated frame cannot support
    make.metraw_tiff(tmp_path / "a.tif", np.full((64, 64), 4095))
    refused(["encode", "a.tif", "out.mraw"], "saturated", tmp_path)


# ----------------------------------------------------------------------------- headerless metadata
def _headerless(tmp_path, **changes) -> list[str]:
    """A 4 x 4 uint16 headerless raw and its ``--meta`` arguments (complete unless changed)."""
    np.full((4, 4), 300, np.uint16).tofile(tmp_path / "a.raw")
    meta = {**dict(width=4, height=4, dtype="uint16", cfa_pattern="RGGB", black_level_dn=0, adc_bits=12), **changes}
    return ["a.raw", *[a for k, v in meta.items() for a in ("--meta", f"{k}={v}")]]


def test_text_stored_shift_headerless_ingest(tmp_path):
    refused(["ingest", *_headerless(tmp_path, stored_shift="four"), "--out", "s.zarr"],
            "a.raw: stored_shift must be an integer", tmp_path)


def test_20_bit_headerless_ingest(tmp_path):
    refused(["ingest", *_headerless(tmp_path, adc_bits=20), "--out", "s.zarr"], "adc_bits must be in 1..16", tmp_path)


# ----------------------------------------------------------------------------- unknown CFA patterns
def test_unknown_cfa_headerless_ingest(tmp_path):
    refused(["ingest", *_headerless(tmp_path, cfa_pattern="RGBW"), "--out", "s.zarr"], "CFA pattern 'RGBW'", tmp_path)


def test_unknown_cfa_option_encode(tmp_path):
    make.metraw_tiff(tmp_path / "a.tif")
    refused(["encode", "a.tif", "out.mraw", "--black", "64", "--cfa", "XYZW"], "CFA pattern 'XYZW'", tmp_path)


def test_cmy_dng_info(tmp_path):
    # a CMY mosaic: LibRaw alone reads it as RGGB; the file's CFAPattern tag says otherwise
    make.dng(tmp_path / "a.dng", cfa_codes=(3, 4, 4, 5), plane_colours=(3, 4, 5))
    refused(["info", "a.dng"], "CFA pattern 'CMMY'", tmp_path)


def test_cmyg_dng_ingest(tmp_path):
    make.dng(tmp_path / "a.dng", cfa_codes=(3, 4, 5, 1), plane_colours=(3, 4, 5, 1))
    refused(["ingest", "a.dng", "--out", "s.zarr"], "CFA pattern", tmp_path)
