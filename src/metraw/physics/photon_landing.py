"""Photon landing for the emulator's photon chain (`metraw.emulate`): one compiled loop per colour.

Every kept photon of a source cell (or pre-binned block) gets a continuous ground position and is
counted in the target pixel it lands in:

- position uniform in its cell;
- PSF displacement: wavelength uniform in the band, radius by inverse CDF of the annulus
  encircled energy (linear interpolation of the table, as ``np.interp``; beyond the table the
  r^-2 asymptote), direction uniform;
- smear uniform along the track, jitter Gaussian per axis;
- edge folding (reflect), rotation to the target grid, the colour's detection mask.

Random numbers come from SplitMix64 (Steele, Lea & Flood 2014, the generator of Java's
``SplittableRandom``; passes BigCrush), drawn inside the loop so that no per-photon arrays are
made. Uniforms are the top 53 bits of an output, so they lie on the grid k 2^-53 in [0, 1).
A uniform direction phi = 2 pi u is evaluated without a branch or a libm call: cos and sin of
the nearest-below multiple of 2 pi / 1024 from a table, rotated by the remainder b < 6.2e-3 rad
whose cos and sin are Taylor polynomials (truncation < 1e-19, below double rounding). The
Gaussian jitter pair uses Marsaglia's polar method (a point uniform in the unit disc).
Both are exact transformations, not approximations. The stream is a function of ``key`` alone
(one per colour, drawn from the caller's numpy Generator), so the same seed gives the same counts.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["land_photons"]

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53
_DIR_N = 1024  # direction table: cos, sin of 2 pi k / _DIR_N
_DIR_COS = np.cos(2.0 * np.pi * np.arange(_DIR_N) / _DIR_N)
_DIR_SIN = np.sin(2.0 * np.pi * np.arange(_DIR_N) / _DIR_N)
_DIR_STEP = 2.0 * math.pi / _DIR_N


@nb.njit(inline="always")
def _next(state):
    """SplitMix64: the advanced state and a uniform double in [0, 1) (53 bits)."""
    state = state + _GAMMA
    z = state
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    z = z ^ (z >> _S31)
    return state, float(z >> _S11) * _TO_UNIT


@nb.njit(inline="always")
def _direction(u):
    """cos and sin of 2 pi u, u in [0, 1): table node plus Taylor rotation (see module docstring)."""
    t = u * _DIR_N
    k = int(t)
    b = (t - k) * _DIR_STEP
    b2 = b * b
    cb = 1.0 - b2 * (0.5 - b2 * (1.0 / 24.0 - b2 * (1.0 / 720.0)))
    sb = b * (1.0 - b2 * (1.0 / 6.0 - b2 * (1.0 / 120.0)))
    ca, sa = _DIR_COS[k], _DIR_SIN[k]
    return ca * cb - sa * sb, sa * cb + ca * sb


@nb.njit(inline="always")
def _disc(state):
    """A point (a, b) uniform in the open unit disc minus its centre, and s = a^2 + b^2."""
    while True:
        state, u = _next(state)
        state, v = _next(state)
        a = 2.0 * u - 1.0
        b = 2.0 * v - 1.0
        s = a * a + b * b
        if 0.0 < s < 1.0:
            return state, a, b, s


@nb.njit(cache=True, nogil=True)
def land_photons(kept, bw, block, clamp_w, clamp_h, key, lo, hi, v_scale, ee, vt, guide, v_max, tail,
                 smear_x, smear_y, jitter, reflect, wm, hm, cx, cy, c_r, s_r, gt, wt, ht, det, out):
    """Land the ``kept`` photons (int64, flat over blocks ``bw`` wide, each ``block`` m) and add
    their counts per target pixel into ``out`` (int64, flat ht x wt).

    ``clamp_w``/``clamp_h`` > 0: positions clamped inside the footprint (partial pre-bin blocks);
    ``ee``/``vt``/``guide``: encircled-energy table in v and its guide index; radius in m is
    v lambda ``v_scale``; beyond ``ee[-1]`` v = ``v_max`` ``tail`` / (1 - u). ``smear_x/y``: smear
    vector (m), ``jitter``: rms per axis (m), both 0 when off. ``reflect``: fold positions into the
    footprint ``wm`` x ``hm`` (m). ``cx, cy``: frame centre (m); ``c_r, s_r``: cos/sin of its
    rotation; ``gt``: target GSD (m); ``det``: 1 where a pixel detects this colour, else 0 (int8,
    flat ht x wt; counted without a branch, as out[pix] += det[pix]).
    """
    state = np.uint64(key)
    ee_last = ee[ee.size - 1]
    nb_ = guide.size - 1
    smear = smear_x != 0.0 or smear_y != 0.0
    for cell in range(kept.size):
        k = kept[cell]
        if k == 0:
            continue
        by = cell // bw
        bx = cell - by * bw
        for _ in range(k):
            state, ux = _next(state)
            state, uy = _next(state)
            x = (bx + ux) * block
            y = (by + uy) * block
            if clamp_w > 0.0:
                x = min(x, clamp_w)
                y = min(y, clamp_h)
            state, ul = _next(state)
            lam = lo + (hi - lo) * ul
            state, u = _next(state)
            if u > ee_last:
                v = v_max * tail / max(1.0 - u, 1e-300)
            else:
                i = int(u * nb_)
                a = guide[i]
                b = guide[min(i + 1, nb_)] + 1
                while b - a > 1:  # ee[a] <= u < ee[b]
                    m = (a + b) >> 1
                    if ee[m] <= u:
                        a = m
                    else:
                        b = m
                d = ee[a + 1] - ee[a]
                v = vt[a] if d <= 0.0 else vt[a] + (vt[a + 1] - vt[a]) * (u - ee[a]) / d
            r = v * lam * v_scale
            state, w = _next(state)
            cos_phi, sin_phi = _direction(w)
            x += r * cos_phi
            y += r * sin_phi
            if smear:
                state, t = _next(state)
                x += (t - 0.5) * smear_x
                y += (t - 0.5) * smear_y
            if jitter > 0.0:
                state, p, q, s = _disc(state)
                g = jitter * math.sqrt(-2.0 * math.log(s) / s)
                x += p * g
                y += q * g
            if reflect:  # x % p is x itself for 0 <= x < p: the modulo only where a photon left the period
                if x < 0.0 or x >= 2.0 * wm:
                    x = x % (2.0 * wm)
                if x > wm:
                    x = 2.0 * wm - x
                if y < 0.0 or y >= 2.0 * hm:
                    y = y % (2.0 * hm)
                if y > hm:
                    y = 2.0 * hm - y
            dx = x - cx
            dy = y - cy
            col = math.floor((c_r * dx + s_r * dy) / gt + wt / 2)
            row = math.floor((-s_r * dx + c_r * dy) / gt + ht / 2)
            if col < 0 or col >= wt or row < 0 or row >= ht:
                continue
            pix = int(row) * wt + int(col)
            out[pix] += det[pix]
