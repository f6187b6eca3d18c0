"""Tests of metraw.physics.optics against independent references (spatial quadrature of the analytic
annulus PSF, scipy dblquad, radial encircled-energy integrals, shifted-PSF averages, POPPY)."""

import math

import numpy as np
import pytest
from scipy.integrate import dblquad, quad
from scipy.optimize import brentq
from scipy.special import j0, j1, roots_hermite, roots_legendre

from metraw.errors import MetrawError
from metraw.physics import kernels
from metraw.physics import optics as o
from metraw.physics.accuracy import Accuracy, airy_flux_outside, kernel_radius_px

LAM, D = 550e-9, 0.2
LOD = LAM / D


# ---------------------------------------------------------------- independent spatial reference


def ref_intensity_per_px(x, y, eps, k):
    """Analytic annulus PSF at (x, y) [px] for pixel = lambda/(k D), unit total flux, per px^2."""
    v = np.pi * np.hypot(x, y) / k
    v = np.where(v == 0, 1e-12, v)
    a = 2 * j1(v) / v
    if eps > 0:
        a = a - eps**2 * 2 * j1(eps * v) / (eps * v)
    i0 = np.pi / 4 * (1 - eps**2) / k**2
    return i0 * (a / (1 - eps**2)) ** 2


def ref_pixel_integrated(n, eps, k, nq=16):
    """Gauss-Legendre (nq x nq nodes per pixel) integral of the analytic PSF over each pixel."""
    t, w = roots_legendre(nq)
    c = np.arange(n) - (n - 1) / 2
    xs = (c[:, None] + t[None, :] / 2).ravel()
    ws = np.tile(w / 2, n)
    f = ref_intensity_per_px(xs[None, :], xs[:, None], eps, k) * ws[None, :] * ws[:, None]
    return f.reshape(n, nq, n, nq).sum(axis=(1, 3))


CASES = [(0.0, 2), (0.0, 4), (0.3, 2), (0.3, 4)]


@pytest.mark.parametrize("eps,k", CASES)
def test_psf_matches_pixel_integrated_analytic(eps, k):
    n = 33
    a = o.diffraction_psf(LAM, D, LAM / (k * D), (n, n), eps)
    ref = ref_pixel_integrated(n, eps, k, 16)
    ref24 = ref_pixel_integrated(n, eps, k, 24)
    assert np.abs(ref - ref24).max() < 1e-9 * ref.max()  # the reference itself has converged
    err = np.abs(a - ref).max() / ref.max()
    assert err <= 1e-4, err
    assert err <= 1e-6, err  # what the method actually achieves (psf_quadrature_error)
    # the array's sum is the energy enclosed by the array
    assert abs(a.sum() - ref.sum()) < 1e-5  # flux wrapped by the FFT period, after correction


def test_reference_quadrature_against_dblquad():
    eps, k, n = 0.3, 2, 33
    ref = ref_pixel_integrated(n, eps, k, 16)
    a = o.diffraction_psf(LAM, D, LAM / (k * D), (n, n), eps)
    for j, i in [(16, 16), (16, 19), (13, 20)]:
        x0, y0 = i - 16, j - 16
        val, _ = dblquad(lambda y, x: float(ref_intensity_per_px(x, y, eps, k)), x0 - 0.5, x0 + 0.5,
                         y0 - 0.5, y0 + 0.5, epsabs=1e-12, epsrel=1e-10)
        assert abs(val - ref[j, i]) < 1e-9
        assert abs(val - a[j, i]) < 1e-6 * a.max()


def test_odd_shape_centred_and_symmetric_and_offset():
    a = o.diffraction_psf(LAM, D, LOD / 2, (21, 21), 0.3)
    assert np.unravel_index(a.argmax(), a.shape) == (10, 10)
    np.testing.assert_allclose(a, a[::-1, ::-1], atol=1e-12)
    np.testing.assert_allclose(a, a.T, atol=1e-12)
    # even shape: centre between the four central pixels
    b = o.diffraction_psf(LAM, D, LOD / 2, (20, 20))
    np.testing.assert_allclose(b[9:11, 9:11], b[9, 9], rtol=1e-10)
    # integer offset == shifted array
    c = o.diffraction_psf(LAM, D, LOD / 2, (21, 21), 0.3, center_offset_px=(2.0, -3.0))
    np.testing.assert_allclose(c[2:, :-3], a[:-2, 3:], atol=1e-9 * a.max())
    # sub-pixel offset against the independent reference
    d = o.diffraction_psf(LAM, D, LOD / 2, (15, 15), 0.0, center_offset_px=(0.3, -0.25))
    t, w = roots_legendre(16)
    cy, cx = 7.3, 6.75
    xs = ((np.arange(15) - cx)[:, None] + t / 2).ravel()
    ys = ((np.arange(15) - cy)[:, None] + t / 2).ravel()
    ws = np.tile(w / 2, 15)
    ref = (ref_intensity_per_px(xs[None, :], ys[:, None], 0.0, 2) * ws[None, :] * ws[:, None]).reshape(15, 16, 15, 16).sum(axis=(1, 3))
    assert np.abs(d - ref).max() < 1e-6 * ref.max()


def test_undersampled_pixels_are_exact_too():
    # pixel = 2 lambda/D (strongly aliased PSF): the folding of the OTF * sinc spectrum is exact
    n, k = 9, 0.5
    a = o.diffraction_psf(LAM, D, 2 * LOD, (n, n), 0.3)
    ref = ref_pixel_integrated(n, 0.3, k, 24)
    assert np.abs(a - ref).max() < 1e-6 * ref.max()


# ---------------------------------------------------------------- encircled energy, FWHM


def _first_dark_v(eps):
    f = lambda v: 2 * j1(v) / v - (eps**2 * 2 * j1(eps * v) / (eps * v) if eps else 0.0)
    return brentq(f, 2.5, 4.5, xtol=1e-14)


@pytest.mark.parametrize("eps", [0.0, 0.3])
def test_encircled_energy_first_dark_ring(eps):
    v0 = _first_dark_v(eps)
    r = v0 * LOD / np.pi
    ee = float(o.encircled_energy(r, LAM, D, eps))
    # independent reference: radial quadrature of the analytic intensity, normalised by 2/(1-eps^2)
    def integrand(v):
        a = 2 * j1(v) / v - (eps**2 * 2 * j1(eps * v) / (eps * v) if eps else 0.0)
        return (a / (1 - eps**2)) ** 2 * v
    ref = quad(integrand, 1e-12, v0, epsabs=1e-13, limit=200)[0] / (2 / (1 - eps**2))
    assert abs(ee - ref) < 1e-6, (ee, ref)
    if eps == 0:
        assert abs(ee - (1 - j0(v0) ** 2 - j1(v0) ** 2)) < 1e-9
        assert abs(ee - 0.8378) < 1e-4
    else:
        assert abs(ee - 0.8378) > 0.05  # the obscuration moves energy into the rings


def test_array_sum_is_square_encircled_energy_and_bounded_by_circles():
    a = o.diffraction_psf(LAM, D, LOD / 4, (65, 65), 0.3)
    half = 32.5 / 4 * LOD
    inner = float(o.encircled_energy(half, LAM, D, 0.3))
    outer = float(o.encircled_energy(half * math.sqrt(2), LAM, D, 0.3))
    assert inner < a.sum() < outer


def test_fwhm_clear_aperture():
    # unintegrated profile: point samples of the same Fourier engine at a moving centre offset
    p = LOD / 8
    val = lambda s: o.diffraction_psf(LAM, D, p, (1, 1), 0.0, pixel_integrate=False, center_offset_px=(0.0, -s))[0, 0]
    peak = val(0.0)
    s_half = brentq(lambda s: val(s) - peak / 2, 1.0, 8.0, xtol=1e-9)
    fwhm = 2 * s_half * p / LOD
    assert abs(fwhm / 1.029 - 1) < 1e-3, fwhm
    assert abs(fwhm / (o.fwhm_rad(LAM, D) / LOD) - 1) < 1e-6
    # peak density of a unit-flux Airy pattern is (pi/4)(D/lambda)^2 per sr
    assert abs(peak / (np.pi / 4 / 64) - 1) < 1e-6


def test_kernel_radius_bounds_flux_loss():
    for eps in (0.0, 0.3):
        r = kernel_radius_px(LAM, D, LOD / 2, eps, flux_loss=1e-2)
        a = o.diffraction_psf(LAM, D, LOD / 2, 2 * r + 1, eps)
        assert 1 - a.sum() <= 1e-2
        assert 1 - a.sum() > 0.3e-2  # and not wastefully large
    assert airy_flux_outside(50, 0.0) == pytest.approx(2 / (np.pi**2 * 50))


# ---------------------------------------------------------------- polychromatic


def test_polychromatic_band_sampling_error():
    band = (400e-9, 700e-9)
    acc = Accuracy(band_sampling_error=1e-4)
    n = o.n_band_wavelengths(band, D, LOD / 2, 65, 0.3, acc)
    a = o.polychromatic_psf(band, D, LOD / 2, 65, 0.3, accuracy=acc)
    ref = o.polychromatic_psf(band, D, LOD / 2, 65, 0.3, n_wavelengths=64)
    assert 1 < n < 64
    assert np.abs(a - ref).max() <= 1e-4 * ref.max()
    # flat spectrum == uniform average of monochromatic PSFs (midpoint rule, many wavelengths)
    lams = 400e-9 + (np.arange(150) + 0.5) * 2e-9
    mono = sum(o.diffraction_psf(lk, D, LOD / 2, 17, 0.3) for lk in lams) / len(lams)
    ref17 = o.polychromatic_psf(band, D, LOD / 2, 17, 0.3, n_wavelengths=64)
    assert np.abs(mono - ref17).max() < 2e-4 * ref17.max()
    # spectral weights: a delta-like spectrum reduces to the monochromatic PSF
    w = o.polychromatic_psf((549.999e-9, 550.001e-9), D, LOD / 2, 17, 0.3, weights=lambda lam: 1 + 0 * lam)
    np.testing.assert_allclose(w, o.diffraction_psf(LAM, D, LOD / 2, 17, 0.3), atol=1e-8)


# ---------------------------------------------------------------- composition (exact, Fourier)


def test_system_kernel_smear_and_jitter_equal_shifted_psf_averages():
    p, n, band = LOD / 2, 25, (500e-9, 600e-9)
    L, ang = 3.7, 0.4
    k = o.system_kernel(band, D, p, n, 0.3, smear_length_px=L, smear_angle_rad=ang, n_wavelengths=4)
    t, w = roots_legendre(48)
    ref = sum(wi / 2 * o.polychromatic_psf(band, D, p, n, 0.3, n_wavelengths=4,
                                           center_offset_px=(ti * L / 2 * math.sin(ang), ti * L / 2 * math.cos(ang)))
              for ti, wi in zip(t, w))
    assert np.abs(k - ref).max() < 1e-5 * ref.max()
    s = 0.8
    kj = o.system_kernel(LAM, D, p, n, 0.0, jitter_sigma_px=s)
    th, wh = roots_hermite(16)
    refj = sum(wa * wb / np.pi * o.diffraction_psf(LAM, D, p, n, 0.0, center_offset_px=(math.sqrt(2) * s * ta, math.sqrt(2) * s * tb))
               for ta, wa in zip(th, wh) for tb, wb in zip(th, wh))
    assert np.abs(kj - refj).max() < 1e-5 * refj.max()
    # no smear, no jitter: the plain PSF
    np.testing.assert_allclose(o.system_kernel(LAM, D, p, n, 0.3), o.diffraction_psf(LAM, D, p, n, 0.3), atol=1e-14)


# ---------------------------------------------------------------- pupil path (vanes, WFE)


def test_pupil_path_agrees_with_analytic_annulus():
    p, n = LOD / 2, 33
    ana = o.diffraction_psf(LAM, D, p, n, 0.3)
    num = o._engine([LAM], [1.0], D, p, (n, n), 0.3, zern={1: 0.0, 4: 1e-12}, zern_ref_lam=LAM,
                    pupil_samples=512, pupil_correction=False)
    err = np.abs(num - ana).max() / ana.max()
    assert err < 3e-3, err  # raw grey-pupil discretisation at 512 samples across D (measured 1.8e-3)


def test_zernike_tilt_is_a_shift_and_defocus_strehl():
    p, n, c = LOD / 2, 25, 0.1
    tilt = o.diffraction_psf(LAM, D, p, n, 0.3, zernike_rms_waves={2: c})
    shift_px = 4 * c * LOD / p  # Z2 = 2 rho cos(theta): tilt angle = 4 c lambda / D along +x
    ref = o.diffraction_psf(LAM, D, p, n, 0.3, center_offset_px=(0.0, shift_px))
    # pupil path: first-order grey-pupil error, 8.6e-4 of the peak at 512 samples, 4.3e-4 at 1024
    assert np.abs(tilt - ref).max() < 1.5e-3 * ref.max()
    c4 = 0.05
    pk = lambda z: o.diffraction_psf(LAM, D, p, 1, 0.3, zernike_rms_waves=z, pixel_integrate=False)[0, 0]
    strehl = pk({4: c4}) / pk(None)
    eps = 0.3
    re = quad(lambda r: math.cos(2 * math.pi * c4 * math.sqrt(3) * (2 * r * r - 1)) * 2 * r, eps, 1)[0] / (1 - eps**2)
    im = quad(lambda r: math.sin(2 * math.pi * c4 * math.sqrt(3) * (2 * r * r - 1)) * 2 * r, eps, 1)[0] / (1 - eps**2)
    assert abs(strehl - (re * re + im * im)) < 2e-4


def test_spider_vanes_symmetry_convergence_and_area():
    p, n = LOD / 2, 33
    kw = dict(spider_vanes=4, spider_width_m=0.01)
    a = o.diffraction_psf(LAM, D, p, n, 0.3, **kw)
    np.testing.assert_allclose(a, a.T, atol=1e-9 * a.max())
    np.testing.assert_allclose(a, a[::-1, :], atol=1e-9 * a.max())
    b = o.diffraction_psf(LAM, D, p, n, 0.3, pupil_samples=1024, **kw)
    assert np.abs(a - b).max() < 1e-3 * b.max()  # measured 2.4e-4
    clear = o.diffraction_psf(LAM, D, p, n, 0.3)
    assert a.max() < clear.max()  # vanes scatter light into spikes
    assert o.pupil_area_m2(D, 0.3, 4, 0.01) == pytest.approx(np.pi / 4 * D * D * 0.91 - 4 * 0.01 * 0.1 * 0.7)


# ---------------------------------------------------------------- geometric kernels


def test_smear_kernel_exact():
    k = kernels.smear_kernel(3.0, 0.0, (5, 5))
    np.testing.assert_allclose(k[2, 1:4], 1 / 3)
    assert k.sum() == pytest.approx(1.0)
    k = kernels.smear_kernel(2.0, np.pi / 2, (5, 5))
    np.testing.assert_allclose(k[1:4, 2], [0.25, 0.5, 0.25])
    # oblique: fraction of a dense set of points on the segment in each pixel
    L, ang = 7.3, 0.61
    k = kernels.smear_kernel(L, ang, (15, 15), center_offset_px=(0.2, -0.1))
    t = (np.arange(2_000_000) + 0.5) / 2_000_000 - 0.5
    x, y = 7 - 0.1 + t * L * math.cos(ang), 7 + 0.2 + t * L * math.sin(ang)
    h = np.zeros((15, 15))
    np.add.at(h, (np.floor(y + 0.5).astype(int), np.floor(x + 0.5).astype(int)), 1 / t.size)
    assert np.abs(k - h).max() < 2e-6
    assert kernels.smear_kernel(0.0, 0.3, (3, 3))[1, 1] == 1.0
    np.testing.assert_allclose(kernels.smear_kernel(0.0, 0.0, (2, 2)), 0.25)


def test_jitter_and_pixel_response_moments_and_compose():
    n = 41
    yy, xx = np.mgrid[:n, :n] - 20.0
    var = lambda k: float((k * xx**2).sum() / k.sum())
    s = 1.3
    jk = kernels.jitter_kernel(s, n)
    assert jk.sum() == pytest.approx(1.0, abs=1e-12)
    assert var(jk) == pytest.approx(s * s + 1 / 12, rel=1e-9)  # pixel integration adds the box variance
    pr = kernels.pixel_response_kernel(2.5, n, diffusion_sigma_px=1.5)
    assert pr.sum() == pytest.approx(1.0, abs=1e-12)
    # Sheppard's 1/12 is exact to ~exp(-2 pi^2 sigma^2) for these smooth kernels
    assert var(pr) == pytest.approx(2.5**2 / 12 + 2.25 + 1 / 12, rel=1e-9)
    box = kernels.pixel_response_kernel(2.5, 5)
    np.testing.assert_allclose(box.sum(axis=0), [0, 0.3, 0.4, 0.3, 0], atol=1e-15)
    c = kernels.compose(jk, pr)
    assert c.shape == (81, 81) and c.sum() == pytest.approx(1.0, abs=1e-12)
    yy2, xx2 = np.mgrid[:81, :81] - 40.0
    assert float((c * xx2**2).sum()) == pytest.approx(s * s + 2.25 + 2.5**2 / 12 + 2 / 12, rel=1e-6)
    np.testing.assert_allclose(kernels.compose(jk, pr, shape=n), kernels.compose(pr, jk)[20:61, 20:61], atol=1e-15)
    with pytest.raises(MetrawError):
        kernels.compose(jk, pr, shape=40)


# ---------------------------------------------------------------- normalisation, errors, accuracy


def test_normalise_and_errors():
    a = o.diffraction_psf(LAM, D, LOD / 2, 15, normalise="array")
    assert a.sum() == pytest.approx(1.0)
    for bad in [dict(obscuration=1.0), dict(obscuration=-0.1)]:
        with pytest.raises(MetrawError, match="obscuration"):
            o.diffraction_psf(LAM, D, LOD / 2, 15, **bad)
    with pytest.raises(MetrawError, match="shape"):
        o.diffraction_psf(LAM, D, LOD / 2, (0, 5))
    with pytest.raises(MetrawError, match="wavelength_m"):
        o.diffraction_psf(-1.0, D, LOD / 2, 5)
    with pytest.raises(MetrawError, match="band_edges_m"):
        o.polychromatic_psf((600e-9, 500e-9), D, LOD / 2, 5)
    with pytest.raises(MetrawError, match="normalise"):
        o.diffraction_psf(LAM, D, LOD / 2, 5, normalise="peak")
    with pytest.raises(MetrawError, match="kernel_flux_loss"):
        Accuracy(kernel_flux_loss=2.0)
    acc = Accuracy.from_dict(Accuracy().with_(negligible_smear_px=0.1).to_dict())
    assert acc.negligible_smear_px == 0.1
    with pytest.raises(MetrawError, match="unknown"):
        Accuracy.from_dict({"nope": 1})


# ---------------------------------------------------------------- POPPY (test-only dependency)


@pytest.mark.parametrize("eps", [0.0, 0.3])
def test_against_poppy(eps):
    poppy = pytest.importorskip("poppy")
    import warnings

    p, n, ov = LOD / 2, 33, 8
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        osys = poppy.OpticalSystem(npix=512, oversample=2)
        ap = poppy.CircularAperture(radius=D / 2)
        if eps > 0:
            ap = poppy.CompoundAnalyticOptic(opticslist=[ap, poppy.SecondaryObscuration(secondary_radius=eps * D / 2, n_supports=0)])
        osys.add_pupil(ap)
        osys.add_detector(pixelscale=p * 206264.80624709636, fov_pixels=n, oversample=ov)
        ref = osys.calc_psf(wavelength=LAM)[0].data.reshape(n, ov, n, ov).sum(axis=(1, 3))
    a = o.diffraction_psf(LAM, D, p, n, eps)
    diff = np.abs(a - ref).max() / a.max()
    # POPPY's pupil discretisation (npix 512) and 8x8 detector sub-sampling: ~3e-3 of the peak
    assert diff < 5e-3, diff
    assert abs(a.sum() - ref.sum()) < 2e-3
