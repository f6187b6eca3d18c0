"""Raw functions keep (or report deviations from) independence, known distribution and unbiasedness."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.physics.rawfunc import add_poisson, bin_same_colour, redistribute, shoot, stochastic_round, thin, thin_counts
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed


def profile(**changes) -> CalibrationProfile:
    base = dict(gain_dn_per_e=0.5, black_level_dn=100.0, read_noise_e=2.0, white_level_dn=16383.0, adc_bits=14,
                cfa_pattern="RGGB", full_well_e=30000.0, pixel_pitch_m=3e-6)
    return CalibrationProfile(**{**base, **changes})


def flat(shape, mean_e, seed=0, **changes) -> RawImage:
    p = profile(**changes)
    return RawImage(expose(np.full(shape, float(mean_e)), p, rng_from_seed(seed)), p)


def check_mean_var(img: RawImage, mean_e: float, k_se: float = 5.0):
    """Per colour plane: mean DN and variance agree with the profile's noise model (sampling errors)."""
    p = img.profile
    want_dn = p.black_level_dn + p.gain_dn_per_e * mean_e
    for plane in img.planes():
        x = plane.astype(np.float64).ravel()
        var_model = float(p.variance_dn2(want_dn))
        assert abs(x.mean() - want_dn) <= k_se * math.sqrt(var_model / x.size), (x.mean(), want_dn)
        assert abs(x.var(ddof=1) / var_model - 1) <= k_se * math.sqrt(2 / x.size) * 1.1, (x.var(), var_model)


def neighbour_corr(img: RawImage, border: int = 0) -> float:
    e = img.electrons()
    if border:
        e = e[border:-border, border:-border]
    for plane_view in (e[0::2, 0::2], e[0::2, 1::2], e[1::2, 0::2], e[1::2, 1::2]):
        plane_view -= plane_view.mean()
    return float((e[:, :-1] * e[:, 1:]).sum() / (e * e).sum())


def test_stochastic_round_is_unbiased_and_bounded():
    rng = rng_from_seed(0)
    x = np.full(200_000, 3.3)
    n = stochastic_round(x, rng)
    assert set(np.unique(n)) == {3, 4}
    assert abs(n.mean() - 3.3) <= 5 * math.sqrt(0.21 / x.size)
    with pytest.raises(MetrawError):
        stochastic_round(np.array([-1.0]), rng)


def test_thin_counts_of_poisson_is_poisson():
    rng = rng_from_seed(1)
    lam, p = 400.0, 0.1
    k = thin_counts(rng.poisson(lam, 200_000), p, rng)
    assert abs(k.mean() - p * lam) <= 5 * math.sqrt(p * lam / k.size)
    assert abs(k.var() / (p * lam) - 1) <= 5 * math.sqrt(2 / k.size)
    with pytest.raises(MetrawError, match="probability"):
        thin_counts(np.array([3]), 1.5, rng)


def test_shoot_conserves_photons_and_follows_the_kernel():
    rng = rng_from_seed(2)
    kernel = np.array([[0.0, 0.1, 0.0], [0.1, 0.5, 0.2], [0.0, 0.1, 0.0]])
    counts = np.zeros((5, 5), np.int64)
    counts[2, 2] = 100_000
    full = shoot(counts, kernel, rng)
    assert full.shape == (7, 7) and full.sum() == 100_000
    got = full[2:5, 2:5] / 100_000  # source (2, 2) + kernel index (a, b)
    se = np.sqrt(kernel * (1 - kernel) / 100_000)
    assert np.all(np.abs(got - kernel) <= 5 * se + 1e-12)


def test_bin_same_colour_keeps_the_noise_model():
    img = flat((400, 600), 500.0, seed=3)
    out = bin_same_colour(img, 2)
    assert out.shape == (200, 300) and out.profile.cfa_pattern == "RGGB"
    assert out.profile.pixel_pitch_m == pytest.approx(6e-6)
    check_mean_var(out, 4 * 500.0)
    assert abs(neighbour_corr(out)) <= 5 / math.sqrt(out.data.size)
    assert "Irwin-Hall" in out.provenance[-1]["params"]["deviation"]


def test_bin_flags_saturation():
    img = flat((40, 40), 500.0, seed=4)
    data = img.data.copy()
    data[0, 0] = img.profile.white_level_dn
    out = bin_same_colour(RawImage(data, img.profile), 2)
    assert out.flags[0, 0] & FLAG_SATURATED and not out.flags[0, 1] & FLAG_SATURATED


def test_thin_scales_the_mean_and_keeps_poisson_variance():
    img = flat((400, 600), 4000.0, seed=5)
    out = thin(img, 0.05, seed=6, profile_changes={"exposure_s": 1e-3})
    assert out.profile.exposure_s == 1e-3
    # p = 0.05: the source read noise (2 e-) leaks as p^2 (sigma^2 + 1/4) = 0.011 e-^2 of a 200 e- variance
    check_mean_var(out, 0.05 * 4000.0)
    assert abs(neighbour_corr(out)) <= 5 / math.sqrt(out.data.size)
    assert "excess variance" in out.provenance[-1]["params"]["deviation"]


def test_thin_excess_variance_is_the_reported_p_squared_bound():
    """Var(kept) = p lam + p^2 Var(source noise): at p = 0.3, read noise 3 e- and lam = 40 e- the excess over
    Poisson(p lam) is p^2 (9 + 1/12) = 0.82 e-^2 (ADC rounding 1/12 DN^2 at K = 1; the counts are integers, so
    no stochastic rounding). The reported bound p^2 (sigma_d^2 + 1/4) must hold and be tight, where the old
    p (sigma_d^2 + 1/4) = 2.8 e-^2 was 3.4x loose."""
    prof = CalibrationProfile(gain_dn_per_e=1.0, black_level_dn=100, read_noise_e=3.0, white_level_dn=16000,
                              adc_bits=14, cfa_pattern="mono")
    img = RawImage(expose(np.full((1200, 1200), 40.0), prof, rng_from_seed(1)), prof)
    p = 0.3
    out = thin(img, p, seed=2)
    e = out.data.astype(np.float64) - prof.black_level_dn
    n = e.size
    var = e.var()
    se = var * math.sqrt(2.0 / (n - 1))  # sd of a sample variance (near-Gaussian counts)
    excess = var - (p * 40.0 + prof.read_noise_e**2 + 1 / 12)  # minus the target's Poisson, read and ADC parts
    bound = p**2 * (prof.read_noise_e**2 + 0.25)
    assert abs(excess - p**2 * (prof.read_noise_e**2 + 1 / 12)) < 4 * se
    assert excess < bound + 4 * se
    assert f"{bound:.3g} e-^2" in out.provenance[-1]["params"]["deviation"]


def test_redistribute_conserves_flux_and_keeps_pixels_independent():
    img = flat((300, 400), 300.0, seed=7)
    kernel = np.full((3, 3), 1 / 9)
    out = redistribute(img, kernel, seed=8)
    inner = out.electrons()[4:-4, 4:-4]
    assert abs(inner.mean() - 300.0) <= 5 * math.sqrt(310 / inner.size)
    assert 0 < out.provenance[-1]["params"]["lost_fraction"] < 0.02
    # away from the edges (which lose light, the documented edge policy): independent neighbours,
    # both across colours and along one colour plane
    assert abs(neighbour_corr(out, border=4)) <= 5 / math.sqrt(out.data.size)
    g = out.electrons()[4:-4:2, 4:-4:2]
    g = g - g.mean()
    assert abs((g[:, :-1] * g[:, 1:]).sum() / (g * g).sum()) <= 5 / math.sqrt(g.size)
    with pytest.raises(MetrawError, match="odd"):
        redistribute(img, np.ones((2, 2)) / 4)


def test_add_poisson_adds_mean_and_variance():
    img = flat((400, 600), 300.0, seed=9, gain_dn_per_e=1.0)
    out = add_poisson(img, 50.0, seed=10, label="haze")
    check_mean_var(out, 350.0)
    assert out.provenance[-1]["params"]["deviation"] == "none"
