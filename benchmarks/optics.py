"""Speed and accuracy of metraw.physics.optics (run: nice -n 5 python benchmarks/optics.py).

Prints: time to build the kernels the emulation needs, the error of the fast path against an
independent dense spatial quadrature of the analytic annulus PSF, band-sampling error against a
64-wavelength reference, and the difference to POPPY as its pupil sampling is refined.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from scipy.special import j1, roots_legendre

from metraw.physics import optics as o
from metraw.physics.accuracy import Accuracy, kernel_radius_px

LAM, D = 550e-9, 0.2
LOD = LAM / D


def best_time(f, repeat=5):
    f()  # warm caches (wavelength-count cache, FFT plans)
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def dense_reference(n, eps, k, nq=16):
    t, w = roots_legendre(nq)
    c = np.arange(n) - (n - 1) / 2
    xs = (c[:, None] + t[None, :] / 2).ravel()
    ws = np.tile(w / 2, n)
    v = np.pi * np.hypot(xs[None, :], xs[:, None]) / k
    v = np.where(v == 0, 1e-12, v)
    a = 2 * j1(v) / v - (eps**2 * 2 * j1(eps * v) / (eps * v) if eps else 0)
    f = np.pi / 4 * (1 - eps**2) / k**2 * (a / (1 - eps**2)) ** 2 * ws[None, :] * ws[:, None]
    return f.reshape(n, nq, n, nq).sum(axis=(1, 3))


def main():
    print("## timing (best of 5, this machine)")
    print(f"{'kernel':58s} {'shape':>9s} {'n_lam':>5s} {'seconds':>8s}")
    band = (500e-9, 600e-9)
    for eps in (0.0, 0.3):
        for shape in (129, 257):
            n = o.n_band_wavelengths(band, D, LOD / 2, shape, eps)
            t = best_time(lambda: o.polychromatic_psf(band, D, LOD / 2, shape, eps))
            print(f"{'polychromatic 500-600 nm, p = lambda/2D, eps=' + str(eps):58s} {shape:>9d} {n:>5d} {t:8.4f}")
    wide = (400e-9, 700e-9)
    n = o.n_band_wavelengths(wide, D, LOD / 2, 129, 0.3)
    t = best_time(lambda: o.polychromatic_psf(wide, D, LOD / 2, 129, 0.3))
    print(f"{'polychromatic 400-700 nm, p = lambda/2D, eps=0.3':58s} {129:>9d} {n:>5d} {t:8.4f}")
    t = best_time(lambda: o.system_kernel(band, D, LOD / 2, 129, 0.3, smear_length_px=3.5, smear_angle_rad=0.3,
                                          jitter_sigma_px=0.3))
    print(f"{'system kernel (poly + smear 3.5 px + jitter 0.3 px + box)':58s} {129:>9d} {n:>5d} {t:8.4f}")
    r = kernel_radius_px(500e-9, D, LOD / 2, 0.3)
    t = best_time(lambda: o.polychromatic_psf(band, D, LOD / 2, 2 * r + 1, 0.3), repeat=2)
    print(f"{'poly, flux loss <= 1e-3 (kernel_radius_px)':58s} {2 * r + 1:>9d} {'':>5s} {t:8.4f}")
    t = best_time(lambda: o.diffraction_psf(LAM, D, LOD / 2, 129, 0.3, spider_vanes=4, spider_width_m=0.01), repeat=1)
    print(f"{'monochromatic, 4 spider vanes (pupil path, 512 samples)':58s} {129:>9d} {1:>5d} {t:8.4f}")

    print("\n## accuracy against a dense spatial quadrature (16x16 Gauss-Legendre per pixel)")
    print(f"{'eps':>4s} {'pixel':>10s} {'max|diff|/peak':>15s} {'sum diff':>10s}")
    for eps in (0.0, 0.3):
        for k in (2, 4):
            a = o.diffraction_psf(LAM, D, LAM / (k * D), 65, eps)
            ref = dense_reference(65, eps, k)
            print(f"{eps:4.1f} {'lambda/' + str(k) + 'D':>10s} {np.abs(a - ref).max() / ref.max():15.2e} {a.sum() - ref.sum():10.2e}")

    print("\n## band sampling: error vs 64 wavelengths (400-700 nm, eps 0.3, 129 px at lambda/2D)")
    ref = o.polychromatic_psf(wide, D, LOD / 2, 129, 0.3, n_wavelengths=64)
    for bse in (1e-3, 1e-4, 1e-5):
        acc = Accuracy(band_sampling_error=bse)
        n = o.n_band_wavelengths(wide, D, LOD / 2, 129, 0.3, acc)
        a = o.polychromatic_psf(wide, D, LOD / 2, 129, 0.3, accuracy=acc)
        t = best_time(lambda: o.polychromatic_psf(wide, D, LOD / 2, 129, 0.3, accuracy=acc), repeat=3)
        print(f"band_sampling_error={bse:.0e}: n={n:3d}  max|diff|/peak={np.abs(a - ref).max() / ref.max():.2e}  {t:.4f} s")

    try:
        import poppy
    except ImportError:
        print("\npoppy not installed: POPPY comparison skipped")
        return
    print("\n## POPPY 1.1 (MFT, detector oversample 16, binned) vs metraw, 33 px at lambda/2D")
    for eps in (0.0, 0.3):
        for npix in (512, 1024, 2048):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                osys = poppy.OpticalSystem(npix=npix, oversample=2)
                ap = poppy.CircularAperture(radius=D / 2)
                if eps:
                    ap = poppy.CompoundAnalyticOptic(opticslist=[ap, poppy.SecondaryObscuration(secondary_radius=eps * D / 2, n_supports=0)])
                osys.add_pupil(ap)
                osys.add_detector(pixelscale=LOD / 2 * 206264.80624709636, fov_pixels=33, oversample=16)
                pp = osys.calc_psf(wavelength=LAM)[0].data.reshape(33, 16, 33, 16).sum(axis=(1, 3))
            a = o.diffraction_psf(LAM, D, LOD / 2, 33, eps)
            print(f"eps={eps:.1f} npix={npix:5d}: max|diff|/peak={np.abs(a - pp).max() / a.max():.2e}  sum diff={pp.sum() - a.sum():+.2e}")


if __name__ == "__main__":
    main()
