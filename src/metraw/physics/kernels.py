"""The geometric blur kernels of a moving, jittering imager (motion smear, jitter, pixel response, their
composition), exactly pixel-integrated, and the argument checks they share with `metraw.physics.optics`
(whose docstring states the conventions: ``[y, x]`` arrays, the kernel centre, pixel integration)."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

from metraw.errors import MetrawError

__all__ = ["smear_kernel", "jitter_kernel", "pixel_response_kernel", "compose"]

# ----------------------------------------------------------------------------- validation helpers


def _shape2(shape) -> tuple[int, int]:
    if isinstance(shape, (int, np.integer)):
        shape = (int(shape), int(shape))
    try:
        ny, nx = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise MetrawError(f"shape must be an int or a pair of ints, got {shape!r}") from None
    if ny < 1 or nx < 1:
        raise MetrawError(f"shape must be positive, got {shape!r}")
    return ny, nx


def _positive(name: str, v: float) -> float:
    v = float(v)
    if not math.isfinite(v) or v <= 0:
        raise MetrawError(f"{name} must be a finite number > 0, got {v!r}")
    return v


def _nonneg(name: str, v: float) -> float:
    v = float(v)
    if not math.isfinite(v) or v < 0:
        raise MetrawError(f"{name} must be a finite number >= 0, got {v!r}")
    return v


def _obscuration(eps: float) -> float:
    eps = float(eps)
    if not 0 <= eps < 1:
        raise MetrawError(f"obscuration (linear, fraction of the diameter) must lie in [0, 1), got {eps!r}")
    return eps


def _offset(off) -> tuple[float, float]:
    try:
        dy, dx = (float(o) for o in off)
    except (TypeError, ValueError):
        raise MetrawError(f"center_offset_px must be a pair (dy, dx), got {off!r}") from None
    if not (math.isfinite(dy) and math.isfinite(dx)):
        raise MetrawError(f"center_offset_px must be finite, got {off!r}")
    return dy, dx


def _centre(ny: int, nx: int, off) -> tuple[float, float]:
    dy, dx = _offset(off)
    return (ny - 1) / 2 + dy, (nx - 1) / 2 + dx


# ----------------------------------------------------------------------------- geometric kernels


def _split_index(coord: np.ndarray):
    """Pixel index of coordinates; points exactly on a pixel boundary go half to each side."""
    f = np.floor(coord + 0.5)
    on = np.abs(coord + 0.5 - np.round(coord + 0.5)) < 1e-12
    lo = np.where(on, np.round(coord + 0.5) - 1, f)
    hi = np.where(on, np.round(coord + 0.5), f)
    return lo.astype(np.int64), hi.astype(np.int64)


def smear_kernel(length_px, angle_rad, shape, *, center_offset_px=(0.0, 0.0)) -> np.ndarray:
    """Uniform linear motion smear of total length ``length_px`` along ``angle_rad``, exactly pixel-integrated.

    Each value is the fraction of the segment (centred on the kernel centre) lying in that pixel;
    parts outside the array are lost (sum < 1 then), parts on a pixel boundary are split evenly.
    """
    L = _nonneg("length_px", length_px)
    ny, nx = _shape2(shape)
    cy, cx = _centre(ny, nx, center_offset_px)
    a = float(angle_rad)
    ca, sa = math.cos(a), math.sin(a)
    x0, y0 = cx - ca * L / 2, cy - sa * L / 2
    ts = [np.array([0.0, 1.0])]
    if L > 0:
        for c0, d in ((x0, ca * L), (y0, sa * L)):
            if abs(d) > 1e-15:
                lo, hi = sorted((c0, c0 + d))
                k = np.arange(math.ceil(lo - 0.5), math.floor(hi - 0.5) + 1) + 0.5
                ts.append((k - c0) / d)
    t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
    if L == 0 or t.size < 2:
        tm, dt = np.array([0.5]), np.array([1.0])
    else:
        tm, dt = (t[1:] + t[:-1]) / 2, np.diff(t)
        keep = dt > 0
        tm, dt = tm[keep], dt[keep]
    xm, ym = x0 + tm * ca * L, y0 + tm * sa * L
    out = np.zeros((ny, nx))
    xl, xh = _split_index(xm)
    yl, yh = _split_index(ym)
    for yi in (yl, yh):
        for xi in (xl, xh):
            ok = (yi >= 0) & (yi < ny) & (xi >= 0) & (xi < nx)
            np.add.at(out, (yi[ok], xi[ok]), dt[ok] / 4)
    return out


def _gauss_cell_1d(n: int, c: float, sigma: float) -> np.ndarray:
    e = np.arange(n + 1) - 0.5 - c
    if sigma == 0:
        cdf = np.where(e > 0, 1.0, np.where(e < 0, 0.0, 0.5))
    else:
        cdf = 0.5 * (1 + erf(e / (math.sqrt(2) * sigma)))
    return np.diff(cdf)


def jitter_kernel(sigma_px, shape, *, center_offset_px=(0.0, 0.0)) -> np.ndarray:
    """Isotropic Gaussian jitter of standard deviation ``sigma_px``, exactly pixel-integrated (separable erf)."""
    s = _nonneg("sigma_px", sigma_px)
    ny, nx = _shape2(shape)
    cy, cx = _centre(ny, nx, center_offset_px)
    return np.outer(_gauss_cell_1d(ny, cy, s), _gauss_cell_1d(nx, cx, s))


def _box_gauss_cell_1d(n: int, c: float, width: float, sigma: float) -> np.ndarray:
    """Cell integrals of (box of width w, unit area) * Gaussian(sigma), cells [k-1/2, k+1/2]."""
    e = np.arange(n + 1) - 0.5 - c
    if width == 0:
        return _gauss_cell_1d(n, c, sigma)
    a, b = -width / 2, width / 2
    if sigma == 0:
        # cumulative of the box: clip((x - a)/w, 0, 1)
        return np.diff(np.clip((e - a) / width, 0.0, 1.0))
    s2 = math.sqrt(2) * sigma

    def F(x):  # antiderivative of Phi(x / sigma)
        return x * 0.5 * (1 + erf(x / s2)) + sigma / math.sqrt(2 * math.pi) * np.exp(-(x / sigma) ** 2 / 2)

    cum = (F(e - a) - F(e - b)) / width  # P(X <= e) for X = box + gauss
    return np.diff(cum)


def pixel_response_kernel(width_px, shape, *, height_px=None, diffusion_sigma_px=0.0, center_offset_px=(0.0, 0.0)) -> np.ndarray:
    """Detector pixel response on a finer grid: a box ``width_px`` x ``height_px`` (grid pixels; e.g. the
    target pixel in source cells, or less than the pitch for a fill factor < 1), optionally blurred by
    Gaussian charge diffusion, exactly integrated over the grid pixels. Its MTF is
    sinc(u w) sinc(v h) exp(-2 pi^2 sigma^2 (u^2 + v^2)). Sum 1 over the infinite plane."""
    w = _nonneg("width_px", width_px)
    h = w if height_px is None else _nonneg("height_px", height_px)
    s = _nonneg("diffusion_sigma_px", diffusion_sigma_px)
    ny, nx = _shape2(shape)
    cy, cx = _centre(ny, nx, center_offset_px)
    return np.outer(_box_gauss_cell_1d(ny, cy, h, s), _box_gauss_cell_1d(nx, cx, w, s))


def compose(*kernels: np.ndarray, shape=None) -> np.ndarray:
    """Discrete convolution of kernels (each centred on its array centre).

    Without ``shape`` the full convolution is returned: its sum is exactly the product of the sums.
    With ``shape`` the centred crop (must have the parity of the full size). Note: each
    pixel-integrated kernel carries its own pixel box, so a discrete composition of k of them is
    blurred by (k - 1) extra grid-pixel boxes (variance (k-1)/12 px^2 per axis); `system_kernel`
    composes optics, smear, jitter and the pixel box exactly.
    """
    from scipy.signal import convolve2d, fftconvolve  # here, not at the top: scipy.signal costs ~1 s to import

    if not kernels:
        raise MetrawError("compose needs at least one kernel")
    out = np.asarray(kernels[0], dtype=np.float64)
    for k in kernels[1:]:
        k = np.asarray(k, dtype=np.float64)
        if k.ndim != 2 or out.ndim != 2:
            raise MetrawError("compose takes 2-D kernels")
        if min(k.size, out.size) < 64:
            out = convolve2d(out, k, mode="full")
        else:
            out = fftconvolve(out, k, mode="full")
    if shape is not None:
        ny, nx = _shape2(shape)
        Ny, Nx = out.shape
        if (Ny - ny) % 2 or (Nx - nx) % 2 or ny > Ny or nx > Nx:
            raise MetrawError(f"cannot crop a {Ny}x{Nx} composition to a centred {ny}x{nx} (parity or size)")
        y0, x0 = (Ny - ny) // 2, (Nx - nx) // 2
        out = out[y0:y0 + ny, x0:x0 + nx]
    return out
