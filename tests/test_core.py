"""Core objects: CalibrationProfile, RawImage, CFA helpers, sensor model, atomic writes."""

import json

import numpy as np
import pytest

from metraw import CalibrationProfile, MetrawError, RawImage
from metraw.atomic import atomic_path
from metraw.raw.cfa import color_index, fill_factor, pack_planes, plane_offsets, unpack_planes
from metraw.raw.sensor import expose, readout, rng_from_seed
from metraw.raw.vst import anscombe


def make_profile(**kw):
    base = dict(gain_dn_per_e=0.5, black_level_dn=64.0, read_noise_e=3.0, white_level_dn=4095.0, adc_bits=12,
                full_well_e=8000.0, pixel_pitch_m=2.41e-6, focal_length_m=10.26e-3, altitude_m=250.0)
    base.update(kw)
    return CalibrationProfile(**base)


def test_profile_json_round_trip_is_exact():
    p = make_profile(uncertainty={"gain_dn_per_e": 0.002}, approximate=True, approximate_reason="test")
    q = CalibrationProfile.from_json(p.to_json())
    assert q == p
    assert json.loads(p.to_json())["schema_version"] == 1


def test_profile_gsd_of_source_camera_is_5_9_cm():
    assert make_profile().gsd_m == pytest.approx(2.41e-6 * 250 / 10.26e-3)
    assert 0.058 < make_profile().gsd_m < 0.06


@pytest.mark.parametrize("bad, message", [
    ({"gain_dn_per_e": 0.0}, "gain_dn_per_e must be > 0"),
    ({"read_noise_e": -1.0}, "read_noise_e must be >= 0"),
    ({"black_level_dn": 5000.0}, "black_level_dn < white_level_dn"),
    ({"cfa_pattern": "RGBW"}, "unsupported CFA pattern"),
    ({"gain_dn_per_e": float("nan")}, "must be finite"),
])
def test_profile_rejects_invalid_values(bad, message):
    with pytest.raises(MetrawError, match=message):
        make_profile(**bad)


def test_profile_json_errors_are_clear():
    with pytest.raises(MetrawError, match="lacks required field"):  # no schema_version: the current one
        CalibrationProfile.from_dict({"gain_dn_per_e": 1})
    with pytest.raises(MetrawError, match="schema_version 99"):
        CalibrationProfile.from_dict({"schema_version": 99})
    d = make_profile().to_dict()
    d["focal_lenght_m"] = 1.0
    with pytest.raises(MetrawError, match="unknown fields: focal_lenght_m"):
        CalibrationProfile.from_dict(d)
    with pytest.raises(MetrawError, match="not valid JSON"):
        CalibrationProfile.from_json("{")


def test_rawimage_rejects_wrong_dtype_and_mask_shape():
    p = make_profile()
    with pytest.raises(MetrawError, match="uint16"):
        RawImage(np.zeros((4, 4), np.float32), p)
    with pytest.raises(MetrawError, match="mask shape"):
        RawImage(np.zeros((4, 4), np.uint16), p, mask=np.zeros((3, 4)))
    with pytest.raises(MetrawError, match="fractions in"):
        RawImage(np.zeros((4, 4), np.uint16), p, mask=np.full((4, 4), 2.0))


def test_derive_appends_provenance_without_touching_the_original():
    img = RawImage(np.zeros((4, 4), np.uint16), make_profile())
    out = img.derive(img.data + 1, function="add_one", params={"value": np.int64(1)})
    assert img.provenance == []
    assert out.provenance == [{"function": "add_one", "params": {"value": 1}}]


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG", "mono"])
@pytest.mark.parametrize("shape", [(6, 8), (5, 7), (1, 1)])
def test_pack_unpack_round_trip(pattern, shape):
    data = np.arange(np.prod(shape), dtype=np.uint16).reshape(shape)
    planes = pack_planes(data, pattern)
    assert planes.shape[0] == len(plane_offsets(pattern))
    assert np.array_equal(unpack_planes(planes, pattern, shape), data)


def test_color_index_and_fill_factors():
    idx = color_index("GRBG", (2, 2))
    assert idx.tolist() == [[1, 0], [2, 1]]  # G R / B G in (R, G, B) order
    assert fill_factor("RGGB", "G") == 0.5 and fill_factor("RGGB", "R") == 0.25 and fill_factor("mono", "L") == 1


def test_readout_statistics_follow_emva_model():
    """Mean and variance of simulated DN match K*mu + black and K^2 sd^2 + K*mu + 1/12."""
    p = make_profile(gain_dn_per_e=2.0, read_noise_e=2.5)
    rng = rng_from_seed(1)
    mu_e, n = 400.0, 400_000
    dn = expose(np.full(n, mu_e), p, rng).astype(np.float64)
    expected_var = p.variance_dn2(p.black_level_dn + p.gain_dn_per_e * mu_e)
    assert expected_var == pytest.approx(4 * 2.5**2 + 4 * 400 + 1 / 12)  # K^2 sd^2 + K^2 mu_e + 1/12
    se_mean = np.sqrt(expected_var / n)
    se_var = expected_var * np.sqrt(2.0 / (n - 1))
    assert abs(dn.mean() - (64 + 2 * mu_e)) < 4 * se_mean
    assert abs(dn.var() - expected_var) < 4 * se_var


def test_readout_clips_at_full_well_and_adc():
    p = make_profile(gain_dn_per_e=1.0, full_well_e=1000.0, read_noise_e=0.0)
    out = readout(np.array([5000.0, 10.0]), p, rng_from_seed(0))
    assert out.tolist() == [1064, 74]
    p2 = make_profile(gain_dn_per_e=1.0, full_well_e=None, read_noise_e=0.0)
    assert readout(np.array([1e6]), p2, rng_from_seed(0)).tolist() == [4095]


def _numpy_readout(counts_e, profile, rng, exposure_s=None):
    """The EMVA readout as plain numpy expressions (``metraw.raw.sensor.readout`` before it was compiled)."""
    charge = np.asarray(counts_e, dtype=np.float64)
    t = profile.exposure_s if exposure_s is None else exposure_s
    if profile.dark_current_e_per_s > 0 and t:
        charge = charge + rng.poisson(profile.dark_current_e_per_s * t, size=charge.shape)
    if profile.full_well_e is not None:
        charge = np.minimum(charge, profile.full_well_e)
    if profile.read_noise_e > 0:
        charge = charge + rng.normal(0.0, profile.read_noise_e, size=charge.shape)
    dn = np.rint(profile.gain_dn_per_e * charge + profile.black_level_dn)
    return np.clip(dn, 0, profile.white_level_dn).astype(np.uint16)


@pytest.mark.parametrize("fields", [{}, {"read_noise_e": 0.0}, {"full_well_e": None, "dark_current_e_per_s": 5e4},
                                    {"full_well_e": 3000.0, "dark_current_e_per_s": 2e3, "gain_dn_per_e": 0.37}])
def test_compiled_readout_is_the_numpy_model_bit_for_bit(fields):
    """Same random draws in the same order, same float64 arithmetic: identical DN, for integer and float counts,
    1-D, 2-D and non-contiguous inputs, ties of the rounding included (counts on half-DN steps)."""
    p = make_profile(exposure_s=1e-3, **fields)
    rng = rng_from_seed(4)
    for counts in (rng.poisson(rng.uniform(0, 5000, (64, 48))), rng.uniform(0, 6000, 1000),
                   np.arange(0, 4000, 0.5)[::3], np.full((3, 5), 2.5e6), np.float64(1234.5)):
        got = readout(counts, p, rng_from_seed(11), exposure_s=2e-3)
        want = _numpy_readout(counts, p, rng_from_seed(11), exposure_s=2e-3)
        assert got.dtype == np.uint16 and got.shape == np.shape(counts) and np.array_equal(got, want)


def test_same_seed_same_bytes():
    p = make_profile()
    a = expose(np.full((64, 64), 100.0), p, rng_from_seed(7))
    b = expose(np.full((64, 64), 100.0), p, rng_from_seed(7))
    c = expose(np.full((64, 64), 100.0), p, rng_from_seed(8))
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()


def test_anscombe_gives_unit_variance():
    p = make_profile(gain_dn_per_e=0.7, read_noise_e=2.0)
    rng = rng_from_seed(3)
    for mu in (5.0, 50.0, 2000.0):
        z = anscombe(expose(np.full(200_000, mu), p, rng), p)
        assert z.var() == pytest.approx(1.0, abs=0.04)


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    dest = tmp_path / "out.bin"
    with pytest.raises(RuntimeError):
        with atomic_path(dest) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_path(dest) as tmp:
        tmp.write_bytes(b"whole")
    assert dest.read_bytes() == b"whole" and sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]
    with pytest.raises(MetrawError, match="already exists"):
        with atomic_path(dest):
            pass


def test_atomic_path_removes_the_temporary_of_a_killed_writer_only(tmp_path):
    import os
    import subprocess
    import sys

    from metraw.atomic import _owner

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    host = _owner().rsplit("-", 1)[0]
    dest = tmp_path / "out.zarr"
    killed = tmp_path / f".out.zarr.{host}-{int(dead.stdout)}.abcd_123.partial"   # its process is gone
    running = tmp_path / f".out.zarr.{host}-{os.getpid()}.efgh_456.partial"       # a live writer's
    other_host = tmp_path / ".out.zarr.elsewhere-1.ijkl_789.partial"                # not ours to judge
    for d in (killed, running, other_host):
        (d / "out.zarr").mkdir(parents=True)
    with atomic_path(dest) as tmp:
        tmp.write_text("done")
    assert dest.read_text() == "done"
    assert not killed.exists() and running.exists() and other_host.exists()
