"""Haze as physics (issue 17): path radiance collected through the target optics, atmospheric transmission.

Metrological checks at low counts (< 10 e- per pixel): mean within 3 standard errors, variance within
1 % of the model (and within its own sampling error), neighbour correlation |rho| <= 0.005.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metraw.emulate.emulator import emulate
from metraw.errors import MetrawError
from metraw.physics.atmosphere import band_photon_radiance, path_radiance_electrons, pixel_etendue_m2_sr
from metraw.physics.daylight import C_LIGHT_M_PER_S, H_PLANCK_J_S
from metraw.physics.rawfunc import atmosphere
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

from test_emulate import colour_planes, flat_source, gsd_ratio_target, radiometric_e, target

PLANES = (("R", "R", (0, 0)), ("G1", "G", (0, 1)), ("G2", "G", (1, 0)), ("B", "B", (1, 1)))


def neighbour_rho(e: np.ndarray) -> float:
    """Largest |correlation| of horizontally / vertically adjacent pixels (each colour plane centred)."""
    resid = np.empty_like(e, dtype=np.float64)
    for _, _, (dy, dx) in PLANES:
        p = e[..., dy::2, dx::2]
        resid[..., dy::2, dx::2] = p - p.mean()
    out = []
    for a, b in ((resid[..., :-1, :], resid[..., 1:, :]), (resid[..., :, :-1], resid[..., :, 1:])):
        out.append(abs((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum())))
    return max(out)


def assert_metrology(e: np.ndarray, mean_want: dict[str, float], extra_var: float) -> None:
    """Per colour plane: mean within 3 SE, variance = mean + extra within 1 % and 4 SE; |rho| <= 0.005."""
    for name, ch, _ in PLANES:
        x = colour_planes(e)[name].astype(np.float64).ravel()
        var_model = mean_want[ch] + extra_var
        assert mean_want[ch] < 10.0
        assert abs(x.mean() - mean_want[ch]) <= 3 * math.sqrt(var_model / x.size), (name, x.mean(), mean_want[ch])
        rel_se = math.sqrt((2.0 + 1.0 / var_model) / x.size)  # Poisson-like excess kurtosis 1/mean
        assert abs(x.var(ddof=1) / var_model - 1) <= min(0.01, 4 * rel_se), (name, x.var(), var_model)
    assert neighbour_rho(e) <= 0.005


def test_band_photon_radiance_is_the_integral_of_the_power_law():
    lam = np.linspace(500e-9, 590e-9, 20001)
    for a in (0.0, 0.5, 1.0, 2.0, 4.0):
        spectral = 2e7 * (lam / 550e-9) ** -a * lam / (H_PLANCK_J_S * C_LIGHT_M_PER_S)
        numeric = float(np.trapezoid(spectral, lam))
        assert band_photon_radiance(2e7, a, (500e-9, 590e-9)) == pytest.approx(numeric, rel=1e-8)
    with pytest.raises(MetrawError, match="band edges"):
        band_photon_radiance(2e7, 2.0, (590e-9, 500e-9))


def test_path_radiance_scales_like_the_scene_signal():
    """e- ~ D^2 (1 - eps^2) * (pitch / f)^2 * t * tau * QE: the same etendue as the scene's light."""
    t0 = target(path_radiance_w_m2_sr_m=2e7)
    e0 = t0.path_radiance_electrons()
    prof = t0.profile()
    want_g = (pixel_etendue_m2_sr(prof) * prof.exposure_s * prof.optical_transmission * 0.55
              * band_photon_radiance(2e7, 2.0, prof.band_edges_m["G"]))
    assert e0["G"] == pytest.approx(want_g, rel=1e-12)
    assert 15 < e0["G"] < 35  # clear day, nominal payload: comparable to the ~30-40 e- of the scene
    for change, factor in ((dict(exposure_s=360e-6), 2.0), (dict(diameter_m=0.4), 4.0),
                           (dict(pixel_pitch_m=4.8e-6), 4.0), (dict(focal_length_m=1.644 * 2), 0.25),
                           (dict(altitude_m=300000.0), 1.0), (dict(atmospheric_transmission=0.5), 1.0)):
        e1 = target(path_radiance_w_m2_sr_m=2e7, **change).path_radiance_electrons()
        assert e1["G"] / e0["G"] == pytest.approx(factor, rel=1e-12), change
    # bluer with a steeper (clearer, Rayleigh-like) spectral slope
    steep = target(path_radiance_w_m2_sr_m=2e7, path_radiance_exponent=4.0).path_radiance_electrons()
    assert steep["B"] / steep["R"] > e0["B"] / e0["R"]
    # haze_e adds to it, and a target's haze_for is the sum
    both = target(path_radiance_w_m2_sr_m=2e7, haze_e=1.5)
    assert both.haze_for("R") == pytest.approx(e0["R"] + 1.5, rel=1e-12)
    with pytest.raises(MetrawError, match="path_radiance_w_m2_sr_m"):
        target(path_radiance_w_m2_sr_m=-1.0)
    with pytest.raises(MetrawError, match="path_radiance_exponent"):
        target(path_radiance_exponent=9.0)


def test_atmosphere_raw_function_low_counts():
    """A noiseless integer source (6 e- per pixel) through T = 0.7 and ~2-3 e- of path radiance."""
    prof = CalibrationProfile(gain_dn_per_e=1.0, black_level_dn=64.0, read_noise_e=0.0, white_level_dn=4095.0,
                              adc_bits=12, cfa_pattern="RGGB", qe_per_channel={"R": 0.45, "G": 0.55, "B": 0.40},
                              pixel_pitch_m=2.4e-6, focal_length_m=1.644, aperture_diameter_m=0.2,
                              obscuration_ratio=0.3, exposure_s=180e-6, optical_transmission=0.8)
    src = RawImage(expose(np.full((2048, 2048), 6.0), prof, rng_from_seed(1)), prof)
    radiance = 2.5e6
    out = atmosphere(src, 0.7, radiance, 2.0, seed=2)
    haze = path_radiance_electrons(prof, radiance, 2.0)
    assert 1.5 < min(haze.values()) and max(haze.values()) < 4
    assert out.provenance[-1]["function"] == "atmosphere"
    assert out.provenance[-1]["params"]["haze_e"] == pytest.approx(haze)
    assert_metrology(out.electrons(), {c: 0.7 * 6.0 + haze[c] for c in haze}, extra_var=0.0)
    # same seed, same bytes; a different seed differs
    assert np.array_equal(atmosphere(src, 0.7, radiance, 2.0, seed=2).data, out.data)
    assert not np.array_equal(atmosphere(src, 0.7, radiance, 2.0, seed=3).data, out.data)
    with pytest.raises(MetrawError, match="transmission"):
        atmosphere(src, 1.2, radiance)
    with pytest.raises(MetrawError, match="exposure_s"):
        atmosphere(RawImage(src.data, prof.replace(exposure_s=None)), 0.7, radiance)


@pytest.fixture(scope="module")
def hazy_draws():
    """A flat source emulated at low counts through T = 0.5 and path radiance (expected chain)."""
    tgt = gsd_ratio_target(6.0, exposure_s=6.0e-5, ground_speed_m_per_s=0.0, atmospheric_transmission=0.5,
                           path_radiance_w_m2_sr_m=3e7, read_noise_e=1.0)
    src = flat_source((600, 900), 10000.0, seed=1)
    return tgt, src, [emulate(src, tgt, mode="auto", seed=s) for s in range(40)]


def test_emulated_haze_low_counts(hazy_draws):
    tgt, src, outs = hazy_draws
    e = np.stack([o.electrons() for o in outs])
    src_e = src.electrons()
    want = {}
    for name, ch, _ in PLANES:
        want[ch] = radiometric_e(tgt, colour_planes(src_e)[name].mean(), ch) + tgt.haze_for(ch)
    haze = tgt.path_radiance_electrons()
    assert all(0.5 < haze[c] < 3 for c in haze), haze
    assert_metrology(e, want, extra_var=tgt.read_noise_e**2 + 1.0 / 12)
    assert outs[0].provenance[-1]["params"]["haze_e"] == pytest.approx({c: tgt.haze_for(c) for c in haze})
