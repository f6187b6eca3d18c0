"""Diffraction PSF of an annular aperture (the blur kernels of a moving, jittering imager: `metraw.physics.kernels`).

Conventions
-----------
- Arrays are indexed ``[y, x]``; pixel ``(j, i)`` covers ``[i - 1/2, i + 1/2] x [j - 1/2, j + 1/2]``
  in pixel units; the kernel centre is the array centre ``((ny - 1)/2, (nx - 1)/2)`` plus
  ``center_offset_px = (dy, dx)`` (odd shapes: the centre pixel). Angles ``*_angle_rad`` are measured
  from +x (axis 1) towards +y (axis 0).
- "Pixel-integrated": every value is the fraction of the kernel's total flux that falls in that
  pixel (the kernel convolved with the pixel box, sampled at the pixel centre). Kernels are
  normalised so that their total over the infinite plane is 1; the array's sum is the flux enclosed
  by the array (< 1 for the diffraction PSF, whose wings fall as r^-3). ``normalise="array"``
  rescales to sum 1 instead (puts the truncated wing flux back into the core: right for flat fields,
  wrong by <= that flux near edges).
- The diffraction PSF is normalised to the flux *transmitted* by the pupil: losses to the central
  obscuration and spider vanes belong to the collecting area (`pupil_area_m2`), not to the PSF.

Method
------
Everything optical is computed in the Fourier domain, where it is exact: the optical transfer
function (OTF) of the annulus is the analytic autocorrelation of two annuli (circle-overlap areas),
and it vanishes beyond the cutoff D/lambda. Multiplying by the pixel box's transfer function
(sinc x sinc), the motion smear's (sinc along the track) and the jitter's (Gaussian) gives a
compactly supported spectrum; its exact samples, folded into one FFT period (Poisson summation),
give the pixel-integrated kernel *exactly*, up to the periodic wrap-around of the PSF's r^-3 wings,
which the FFT size keeps below ``accuracy.psf_quadrature_error`` of the peak. So the pixel
integration involves no quadrature at all, at any pixel scale (under- or over-sampled), and kernels
composed here (`system_kernel`) integrate over the pixel exactly once.
Spider vanes and Zernike wavefront error take the pupil path: the OTF is the FFT autocorrelation of
a grey-level (area-weighted) sampled pupil, with the sampling chosen so the lag grid coincides with
the frequency grid; the analytic annulus OTF is used as a control variate (OTF = analytic annulus +
[sampled pupil - sampled annulus]), cancelling most of the pupil-edge discretisation error.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Mapping

import numpy as np
import scipy.fft as sfft
from scipy.special import j1

from metraw.errors import MetrawError
from metraw.physics.accuracy import DEFAULT_ACCURACY, Accuracy
from metraw.physics.kernels import _centre, _nonneg, _obscuration, _positive, _shape2

__all__ = [
    "annulus_otf",
    "annulus_intensity",
    "diffraction_psf",
    "polychromatic_psf",
    "system_kernel",
    "band_wavelengths",
    "n_band_wavelengths",
    "encircled_energy",
    "pupil_area_m2",
    "fwhm_rad",
    "noll_zernike",
]


# ----------------------------------------------------------------------------- analytic annulus


def _circle_overlap(d: np.ndarray, a: float, b: float) -> np.ndarray:
    """Area of the intersection of two discs of radii a, b whose centres are d apart."""
    d = np.asarray(d, dtype=np.float64)
    out = np.zeros_like(d)
    if a <= 0 or b <= 0:
        return out
    small = min(a, b)
    inside = d <= abs(a - b)
    out[inside] = math.pi * small * small
    part = (d > abs(a - b)) & (d < a + b)
    dd = d[part]
    c1 = np.clip((dd * dd + a * a - b * b) / (2 * dd * a), -1.0, 1.0)
    c2 = np.clip((dd * dd + b * b - a * a) / (2 * dd * b), -1.0, 1.0)
    k = (-dd + a + b) * (dd + a - b) * (dd - a + b) * (dd + a + b)
    out[part] = a * a * np.arccos(c1) + b * b * np.arccos(c2) - 0.5 * np.sqrt(np.maximum(k, 0.0))
    return out


def annulus_otf(rho, obscuration: float = 0.0) -> np.ndarray:
    """OTF of an annular pupil at normalised frequency rho = f * lambda / D (cutoff rho = 1), OTF(0) = 1.

    The autocorrelation of the annulus (outer radius 1/2, inner radius eps/2, in units of D) divided
    by its area: [C(1/2, 1/2) - 2 C(1/2, eps/2) + C(eps/2, eps/2)] / (pi/4 (1 - eps^2)), C = disc overlap.
    """
    eps = _obscuration(obscuration)
    rho = np.abs(np.asarray(rho, dtype=np.float64))
    a = _circle_overlap(rho, 0.5, 0.5)
    if eps > 0:
        a = a - 2.0 * _circle_overlap(rho, 0.5, eps / 2) + _circle_overlap(rho, eps / 2, eps / 2)
    return np.clip(a / (math.pi / 4 * (1 - eps * eps)), 0.0, None)


def annulus_intensity(v, obscuration: float = 0.0) -> np.ndarray:
    """Point PSF of the annulus at v = pi D theta / lambda, normalised to 1 at v = 0.

    I(v) = [2 J1(v)/v - eps^2 2 J1(eps v)/(eps v)]^2 / (1 - eps^2)^2. The peak surface density of a
    unit-flux PSF is (pi/4)(1 - eps^2)(D/lambda)^2 per steradian.
    """
    eps = _obscuration(obscuration)
    v = np.abs(np.asarray(v, dtype=np.float64))
    vs = np.where(v < 1e-8, 1e-8, v)
    amp = np.where(v < 1e-8, 1.0, 2 * j1(vs) / vs)
    if eps > 0:
        ve = eps * vs
        amp = amp - eps**2 * np.where(v < 1e-8, 1.0, 2 * j1(ve) / ve)
    return (amp / (1 - eps * eps)) ** 2


def pupil_area_m2(diameter_m: float, obscuration: float = 0.0, spider_vanes: int = 0, spider_width_m: float = 0.0) -> float:
    """Transmitting area of the pupil [m^2]: annulus minus radial spider vanes.

    Vanes run from the obscuration's edge to the rim; their mutual overlap near the centre (only when
    the obscuration is smaller than the vanes' width allows) is neglected.
    """
    _positive("diameter_m", diameter_m)
    _obscuration(obscuration)
    # The one formula of the collected light, pi / 4 D^2 (1 - eps^2) (the target's aperture_area_m2, the
    # emulation plan's source aperture, atmosphere.pixel_etendue_m2_sr), in their arithmetic: D**2 and eps**2 on
    # the caller's own types (a numpy float squares as x * x, a Python float through pow: they differ in the last
    # bit now and then), so the emulator's floats are the ones it always had.
    area = math.pi / 4 * diameter_m**2 * (1 - obscuration**2)
    return area - int(spider_vanes) * _nonneg("spider_width_m", spider_width_m) * diameter_m / 2 * (1 - obscuration)


def encircled_energy(radius_rad, wavelength_m, diameter_m: float, obscuration: float = 0.0, *, weights=None) -> np.ndarray:
    """Fraction of the (annulus, unit-flux) PSF's energy within radius_rad of its centre.

    ``wavelength_m`` may be a scalar or an array of wavelengths with ``weights`` (summing to 1).
    Computed in the Fourier domain: EE(r) = 2 v int_0^1 OTF(rho) J1(2 v rho) d rho, v = pi D r / lambda.
    """
    eps = _obscuration(obscuration)
    d = _positive("diameter_m", diameter_m)
    lam = np.atleast_1d(np.asarray(wavelength_m, dtype=np.float64))
    w = np.full(lam.size, 1.0 / lam.size) if weights is None else np.asarray(weights, dtype=np.float64)
    r = np.asarray(radius_rad, dtype=np.float64)
    # Gauss-Legendre on pieces between the OTF's derivative breakpoints
    bps = sorted({0.0, 1.0, *([eps, (1 - eps) / 2, (1 + eps) / 2] if eps > 0 else [])})
    x, gw = np.polynomial.legendre.leggauss(256)
    rho, wr = [], []
    for lo, hi in zip(bps[:-1], bps[1:]):
        if hi > lo:
            rho.append((hi - lo) / 2 * x + (hi + lo) / 2)
            wr.append((hi - lo) / 2 * gw)
    rho, wr = np.concatenate(rho), np.concatenate(wr)
    otf = annulus_otf(rho, eps) * wr
    out = np.zeros(r.shape)
    for lk, wk in zip(lam, w):
        v = math.pi * d * r / lk
        out = out + wk * 2 * v * (j1(2 * np.multiply.outer(v, rho)) @ otf)
    return out


def fwhm_rad(wavelength_m: float, diameter_m: float, obscuration: float = 0.0) -> float:
    """FWHM [rad] of the monochromatic annulus point PSF (analytic I(v), root-found): 1.029 lambda/D for eps = 0."""
    from scipy.optimize import brentq

    eps = _obscuration(obscuration)
    v = brentq(lambda t: annulus_intensity(t, eps) - 0.5, 1e-6, 2.0, xtol=1e-14)
    return 2 * v / math.pi * _positive("wavelength_m", wavelength_m) / _positive("diameter_m", diameter_m)


# ----------------------------------------------------------------------------- Zernike / pupil


def _noll_to_nm(j: int) -> tuple[int, int]:
    if j < 1:
        raise MetrawError(f"Noll index must be >= 1, got {j}")
    n, j1_ = 0, j - 1
    while j1_ > n:
        n += 1
        j1_ -= n
    m = (-1) ** j * ((n % 2) + 2 * int((j1_ + ((n + 1) % 2)) / 2.0))
    return n, m


def noll_zernike(j: int, rho: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Noll-normalised Zernike polynomial Z_j (unit rms over the unit disc), rho in units of the outer radius."""
    n, m = _noll_to_nm(int(j))
    am = abs(m)
    rad = np.zeros_like(rho, dtype=np.float64)
    for k in range((n - am) // 2 + 1):
        c = (-1) ** k * math.factorial(n - k) / (
            math.factorial(k) * math.factorial((n + am) // 2 - k) * math.factorial((n - am) // 2 - k)
        )
        rad = rad + c * rho ** (n - 2 * k)
    if m == 0:
        return math.sqrt(n + 1) * rad
    trig = np.cos(am * theta) if m > 0 else np.sin(am * theta)
    return math.sqrt(2 * (n + 1)) * rad * trig


def _zernike_coeffs(z) -> dict[int, float]:
    if z is None:
        return {}
    if isinstance(z, Mapping):
        out = {int(k): float(v) for k, v in z.items()}
    else:
        out = {j + 1: float(c) for j, c in enumerate(np.atleast_1d(np.asarray(z, dtype=np.float64)))}
    for j, c in out.items():
        _noll_to_nm(j)
        if not math.isfinite(c):
            raise MetrawError(f"zernike coefficient Z{j} must be finite, got {c!r}")
    return {j: c for j, c in out.items() if c != 0.0}


def _pupil_field(npix: int, dx: float, diameter: float, eps: float, vanes: int, width: float, angle: float,
                 wave=None, supersample: int = 16):
    """Sampled pupil field: each cell holds the mean over the cell of transmission x exp(2 pi i W), W = wave(x, y)
    in waves (cell centre for interior cells, supersampled for cells cut by an edge)."""
    c = (np.arange(npix) - (npix - 1) / 2) * dx
    R = diameter / 2
    phis = [angle + 2 * math.pi * k / vanes for k in range(vanes)] if vanes > 0 else []

    def inside(x, y):
        r = np.hypot(x, y)
        m = (r <= R) & (r >= eps * R)
        for ph in phis:
            along = x * math.cos(ph) + y * math.sin(ph)
            perp = -x * math.sin(ph) + y * math.cos(ph)
            m &= ~((along > 0) & (np.abs(perp) <= width / 2))
        return m

    y, x = np.meshgrid(c, c, indexing="ij")
    amp = inside(x, y).astype(np.complex128)
    if wave is not None:
        amp *= np.exp(2j * math.pi * wave(x, y))
    r = np.hypot(x, y)
    sd = np.abs(r - R)
    if eps > 0:
        sd = np.minimum(sd, np.abs(r - eps * R))
    for ph in phis:
        along = x * math.cos(ph) + y * math.sin(ph)
        perp = -x * math.sin(ph) + y * math.cos(ph)
        sd = np.minimum(sd, np.where(along > -dx, np.abs(np.abs(perp) - width / 2), np.inf))
        sd = np.minimum(sd, np.where(np.abs(perp) < width / 2 + dx, np.abs(along), np.inf))
    edge = sd < 0.75 * dx
    if edge.any():
        s = (np.arange(supersample) + 0.5) / supersample - 0.5
        sy, sx = np.meshgrid(s * dx, s * dx, indexing="ij")
        ex, ey = x[edge][:, None], y[edge][:, None]
        px, py = ex + sx.ravel()[None, :], ey + sy.ravel()[None, :]
        sub = inside(px, py).astype(np.complex128)
        if wave is not None:
            sub *= np.exp(2j * math.pi * wave(px, py))
        amp[edge] = sub.mean(axis=1)
    return amp


# ----------------------------------------------------------------------------- Fourier engine


def _fold(G: np.ndarray, K: int, M: int) -> np.ndarray:
    """Sum the samples G[m], m = -K..K (both axes), into one period of length M (Poisson summation)."""
    n = 2 * K + 1
    start = (-K) % M
    L = -(-(start + n) // M) * M
    B = np.zeros((L, L), dtype=G.dtype)
    B[start:start + n, start:start + n] = G
    return B.reshape(L // M, M, L // M, M).sum(axis=(0, 2))


def _wing_radius_px(u_c_min: float, eps: float, tol: float) -> float:
    """Distance [px] beyond which the (ring-averaged) PSF wing, summed over ~10 replicas, is < tol of the peak."""
    v = (40.0 / (math.pi * tol * (1 - eps) ** 2 * (1 + eps))) ** (1 / 3)
    return v / (math.pi * u_c_min)


def _fft_size(ny, nx, cy, cx, u_c_min, eps, acc, extra_px=0.0, min_size=0) -> int:
    reach = max(cy, nx - 1 - cx, cx, ny - 1 - cy, 0.0) + extra_px
    m = max(ny, nx) + reach + _wing_radius_px(u_c_min, eps, acc.psf_quadrature_error)
    # flux wrapped into the array after the asymptotic correction (~2 % residual of ~9 replicas'
    # wings, density 1/(pi^3 u_c (1-eps) r^3)) kept below 10 x psf_quadrature_error
    resid = 0.02 * 9.0 * ny * nx / (math.pi**3 * u_c_min * (1 - eps))
    m = int(math.ceil(max(m, reach + (resid / (10 * acc.psf_quadrature_error)) ** (1 / 3))))
    return sfft.next_fast_len(max(m, min_size, 8))


def _engine(lams, wts, D, p, shape, eps, *, offset=(0.0, 0.0), box_px=1.0, smear_px=0.0, smear_angle=0.0,
            jitter_px=0.0, vanes=0, vane_width=0.0, vane_angle=0.0, zern=None, zern_ref_lam=None,
            pupil_samples=512, pupil_correction=True, accuracy=None):
    acc = accuracy or DEFAULT_ACCURACY
    ny, nx = shape
    cy, cx = _centre(ny, nx, offset)
    lams = np.asarray(lams, dtype=np.float64)
    u_cs = p * D / lams  # cutoff in cycles per pixel
    u_c_min, u_c_max = float(u_cs.min()), float(u_cs.max())
    pupil = vanes > 0 or bool(zern)
    min_size = int(math.ceil(pupil_samples / u_c_min)) if pupil else 0
    M = _fft_size(ny, nx, cy, cx, u_c_min, eps, acc, extra_px=smear_px / 2 + 6 * jitter_px, min_size=min_size)
    K = int(math.ceil(M * u_c_max))
    m = np.arange(-K, K + 1)
    u = m / M
    uy, ux = u[:, None], u[None, :]
    ur = np.hypot(uy, ux)
    otf = np.zeros((2 * K + 1, 2 * K + 1), dtype=np.complex128 if pupil else np.float64)
    if not pupil:  # the annulus OTF is even in ux and uy: evaluate one quadrant, mirror
        q = np.zeros((K + 1, K + 1))
        urq = ur[K:, K:]
        for lam, w, uc in zip(lams, wts, u_cs):
            q += w * annulus_otf(urq / uc, eps)
        otf[K:, K:] = q
        otf[:K, K:] = q[:0:-1, :]
        otf[:, :K] = otf[:, :K:-1]
    for lam, w, uc in zip(lams, wts, u_cs) if pupil else ():
        ana = annulus_otf(ur / uc, eps)
        dxp = lam / (M * p)  # pupil sample [m]: lag index == frequency index
        npup = int(math.ceil(D / dxp)) + 4
        wave = None
        if zern:
            scale = zern_ref_lam / lam

            def wave(x, y, scale=scale):
                rr, th = np.hypot(x, y) / (D / 2), np.arctan2(y, x)
                return scale * sum(c * noll_zernike(j, rr, th) for j, c in zern.items())

        field = _pupil_field(npup, dxp, D, eps, vanes, vane_width, vane_angle, wave)
        L = sfft.next_fast_len(2 * npup)
        idx = m % L

        def auto(f):
            F = sfft.fft2(f, s=(L, L))
            R = sfft.ifft2(F * F.conj())
            return np.conj(R[np.ix_(idx, idx)]) / R[0, 0].real

        num = auto(field)
        if pupil_correction:
            num = num - auto(_pupil_field(npup, dxp, D, eps, 0, 0.0, 0.0)) + ana
        otf += w * num
    # separable factors: pixel box, Gaussian jitter, shift to the kernel centre
    fy = np.sinc(u * box_px) * np.exp(-2 * math.pi**2 * jitter_px**2 * u**2)
    G = otf * (fy * np.exp(-2j * math.pi * u * cy))[:, None] * (fy * np.exp(-2j * math.pi * u * cx))[None, :]
    if smear_px > 0:
        G = G * np.sinc(smear_px * (ux * math.cos(smear_angle) + uy * math.sin(smear_angle)))
    g = sfft.irfft2(_fold(G, K, M)[:, : M // 2 + 1], s=(M, M))[:ny, :nx]
    # remove the wrap-around of the neighbouring periods' r^-3 wings (ring-averaged asymptote,
    # density 1 / (pi^3 u_c (1 - eps) r^3) per px^2 for a unit-flux PSF; u_c averaged as 1/u_c)
    inv_uc = float(np.sum(np.asarray(wts) / u_cs))
    g = g - _wrap_wings(ny, nx, cy, cx, M, inv_uc / (math.pi**3 * (1 - eps)))
    return np.ascontiguousarray(g)


def _wrap_wings(ny, nx, cy, cx, M, coef, J=2):
    """Sum over the periodic replicas (j != 0) of the asymptotic wing density coef / r^3 at each pixel.

    The sum varies on the scale of the period M (>> 1 px): it is evaluated on a coarse grid (<= 17
    nodes per axis) and interpolated with a bicubic spline (relative error << 1e-3 of the correction).
    """
    from scipy.interpolate import RectBivariateSpline

    yc = np.linspace(0, ny - 1, min(ny, 17))
    xc = np.linspace(0, nx - 1, min(nx, 17))
    y = yc[:, None] - cy
    x = xc[None, :] - cx
    out = np.zeros((yc.size, xc.size))
    for jy in range(-J, J + 1):
        for jx in range(-J, J + 1):
            if jy or jx:
                out += np.hypot(y - jy * M, x - jx * M) ** -3
    out += 2 * math.pi / ((J + 0.5) * M**3)  # farther replicas, as a continuum
    if yc.size < ny or xc.size < nx:
        ky, kx = min(3, yc.size - 1), min(3, xc.size - 1)
        if ky >= 1 and kx >= 1:
            out = RectBivariateSpline(yc, xc, out, kx=ky, ky=kx)(np.arange(ny), np.arange(nx))
        else:
            out = np.broadcast_to(out.mean(), (ny, nx))
    return coef * out


# ----------------------------------------------------------------------------- wavelengths


def band_wavelengths(band_edges_m, n: int, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre wavelengths [m] across the band and their weights (sum 1).

    ``weights``: None (flat photon spectrum per unit wavelength), a callable giving the relative
    photon spectral density at a wavelength, or an array of that density at the n nodes.
    """
    lo, hi = (float(b) for b in band_edges_m)
    if not (0 < lo <= hi):
        raise MetrawError(f"band_edges_m must be (low, high) with 0 < low <= high, got {band_edges_m!r}")
    n = int(n)
    if n < 1:
        raise MetrawError(f"n_wavelengths must be >= 1, got {n}")
    if hi == lo:
        return np.array([lo]), np.array([1.0])
    x, w = np.polynomial.legendre.leggauss(n)
    lam = (hi - lo) / 2 * x + (hi + lo) / 2
    if weights is not None:
        s = np.asarray(weights(lam) if callable(weights) else weights, dtype=np.float64)
        if s.shape != lam.shape or np.any(s < 0) or not np.all(np.isfinite(s)) or s.sum() <= 0:
            raise MetrawError("weights must give n finite non-negative spectral densities, not all zero")
        w = w * s
    return lam, w / w.sum()


_N_CANDIDATES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)


@lru_cache(maxsize=256)
def _n_band_cached(lo, hi, D, p, eps, r_max_px, tol):
    r = np.linspace(0.0, r_max_px, int(min(20000, max(200, 16 * r_max_px))))

    def prof(n):
        lam, w = band_wavelengths((lo, hi), n)
        out = np.zeros_like(r)
        for lk, wk in zip(lam, w):
            uc = p * D / lk
            out += wk * (math.pi / 4) * (1 - eps * eps) * uc * uc * annulus_intensity(math.pi * r * uc, eps)
        return out

    prev = prof(_N_CANDIDATES[0])
    for a, b in zip(_N_CANDIDATES[:-1], _N_CANDIDATES[1:]):
        cur = prof(b)
        if np.max(np.abs(prev - cur)) <= tol * cur.max():
            return a
        prev = cur
    return _N_CANDIDATES[-1]


def n_band_wavelengths(band_edges_m, diameter_m, pixel_scale_rad, shape, obscuration=0.0, accuracy=None) -> int:
    """Number of wavelengths so that band sampling changes no pixel by more than
    ``accuracy.band_sampling_error`` of the peak (a-posteriori: n vs the next larger candidate, on
    the unintegrated flat-spectrum annulus profile out to the array's corner)."""
    acc = accuracy or DEFAULT_ACCURACY
    lo, hi = (float(b) for b in band_edges_m)
    ny, nx = _shape2(shape)
    r_max = math.hypot(ny / 2, nx / 2) + 1
    return _n_band_cached(lo, hi, float(diameter_m), float(pixel_scale_rad), _obscuration(obscuration),
                          round(r_max, 3), float(acc.band_sampling_error))


# ----------------------------------------------------------------------------- public PSFs


def _finish(a: np.ndarray, normalise: str) -> np.ndarray:
    if normalise == "total":
        return a
    if normalise == "array":
        return a / a.sum()
    raise MetrawError(f"normalise must be 'total' or 'array', got {normalise!r}")


def _common(diameter_m, pixel_scale_rad, shape, obscuration, spider_vanes, spider_width_m):
    D = _positive("diameter_m", diameter_m)
    p = _positive("pixel_scale_rad", pixel_scale_rad)
    eps = _obscuration(obscuration)
    sh = _shape2(shape)
    nv = int(spider_vanes)
    if nv < 0:
        raise MetrawError(f"spider_vanes must be >= 0, got {spider_vanes!r}")
    w = _nonneg("spider_width_m", spider_width_m)
    if nv > 0 and w == 0:
        nv = 0
    return D, p, eps, sh, nv, w


def diffraction_psf(wavelength_m, diameter_m, pixel_scale_rad, shape, obscuration=0.0, *, spider_vanes=0,
                    spider_width_m=0.0, spider_angle_rad=0.0, zernike_rms_waves=None, center_offset_px=(0.0, 0.0),
                    pixel_integrate=True, normalise="total", pupil_samples=512, accuracy: Accuracy | None = None) -> np.ndarray:
    """Monochromatic PSF of an annular aperture, integrated over each (square) pixel.

    wavelength_m, diameter_m [m]; pixel_scale_rad = angular side of a pixel; obscuration = linear
    central obscuration (fraction of D). Optional radial spider vanes (``spider_vanes`` of width
    ``spider_width_m``, the first at ``spider_angle_rad``) and Zernike wavefront error
    ``zernike_rms_waves`` (Noll-normalised over the full disc of diameter D; a sequence starting at
    Z1 = piston, or a dict {noll_j: waves rms}). ``pixel_integrate=False`` samples the point PSF
    at the pixel centres instead (per unit pixel area). Returns float64 ``shape`` array whose total
    over the infinite plane is 1 (see module docstring).
    """
    lam = _positive("wavelength_m", wavelength_m)
    D, p, eps, sh, nv, w = _common(diameter_m, pixel_scale_rad, shape, obscuration, spider_vanes, spider_width_m)
    zern = _zernike_coeffs(zernike_rms_waves)
    a = _engine([lam], [1.0], D, p, sh, eps, offset=center_offset_px, box_px=1.0 if pixel_integrate else 0.0,
                vanes=nv, vane_width=w, vane_angle=float(spider_angle_rad), zern=zern, zern_ref_lam=lam,
                pupil_samples=int(pupil_samples), accuracy=accuracy)
    return _finish(a, normalise)


def polychromatic_psf(band_edges_m, diameter_m, pixel_scale_rad, shape, obscuration=0.0, *, n_wavelengths=None,
                      weights=None, spider_vanes=0, spider_width_m=0.0, spider_angle_rad=0.0, zernike_rms_waves=None,
                      center_offset_px=(0.0, 0.0), pixel_integrate=True, normalise="total", pupil_samples=512,
                      accuracy: Accuracy | None = None) -> np.ndarray:
    """Photon-weighted average of `diffraction_psf` over the band ``(low_m, high_m)``.

    Flat photon spectrum per unit wavelength unless ``weights`` (see `band_wavelengths`). The number
    of wavelengths (Gauss-Legendre nodes) comes from `n_band_wavelengths` when None. Zernike
    wavefront error is given in waves at the band centre (a fixed optical path difference).
    """
    return system_kernel(band_edges_m, diameter_m, pixel_scale_rad, shape, obscuration, n_wavelengths=n_wavelengths,
                         weights=weights, spider_vanes=spider_vanes, spider_width_m=spider_width_m,
                         spider_angle_rad=spider_angle_rad, zernike_rms_waves=zernike_rms_waves,
                         center_offset_px=center_offset_px, box_px=1.0 if pixel_integrate else 0.0,
                         normalise=normalise, pupil_samples=pupil_samples, accuracy=accuracy)


def system_kernel(band_edges_m, diameter_m, pixel_scale_rad, shape, obscuration=0.0, *, smear_length_px=0.0,
                  smear_angle_rad=0.0, jitter_sigma_px=0.0, box_px=1.0, n_wavelengths=None, weights=None,
                  spider_vanes=0, spider_width_m=0.0, spider_angle_rad=0.0, zernike_rms_waves=None,
                  center_offset_px=(0.0, 0.0), normalise="total", pupil_samples=512,
                  accuracy: Accuracy | None = None) -> np.ndarray:
    """Exact composite kernel: polychromatic PSF * motion smear * Gaussian jitter * pixel box, on the grid.

    All factors multiply in the Fourier domain and the box (of side ``box_px`` grid pixels, 1 = the
    grid pixel, 0 = point sampling) is applied once, so this is the probability that a photon lands
    in each grid pixel. ``band_edges_m`` may be a scalar wavelength (monochromatic). Smear is uniform
    motion of total length ``smear_length_px`` centred on the kernel centre, along ``smear_angle_rad``.
    """
    D, p, eps, sh, nv, w = _common(diameter_m, pixel_scale_rad, shape, obscuration, spider_vanes, spider_width_m)
    if np.ndim(band_edges_m) == 0:
        lo = hi = _positive("wavelength_m", band_edges_m)
    else:
        lo, hi = (float(b) for b in band_edges_m)
    acc = accuracy or DEFAULT_ACCURACY
    if n_wavelengths is None:
        n_wavelengths = 1 if hi == lo else n_band_wavelengths((lo, hi), D, p, sh, eps, acc)
    lam, wts = band_wavelengths((lo, hi), n_wavelengths, weights)
    zern = _zernike_coeffs(zernike_rms_waves)
    a = _engine(lam, wts, D, p, sh, eps, offset=center_offset_px, box_px=_nonneg("box_px", box_px),
                smear_px=_nonneg("smear_length_px", smear_length_px), smear_angle=float(smear_angle_rad),
                jitter_px=_nonneg("jitter_sigma_px", jitter_sigma_px), vanes=nv, vane_width=w,
                vane_angle=float(spider_angle_rad), zern=zern, zern_ref_lam=(lo + hi) / 2,
                pupil_samples=int(pupil_samples), accuracy=acc)
    return _finish(a, normalise)
