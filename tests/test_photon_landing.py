"""metraw.physics.photon_landing: its random stream and direction against independent references.

The landing itself is tested against the expected chain in tests/test_emulate.py
(test_mean_of_photon_draws_agrees_with_expected, with and without smear, jitter and rotation).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import stats

from metraw.physics.photon_landing import _direction, _disc, _next

MASK64 = (1 << 64) - 1


def splitmix64(state: int, n: int) -> list[int]:
    """Reference SplitMix64 (Steele, Lea & Flood 2014) in Python integers: n outputs after ``state``."""
    out = []
    for _ in range(n):
        state = (state + 0x9E3779B97F4A7C15) & MASK64
        z = state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
        out.append(z ^ (z >> 31))
    return out


@nb.njit
def _uniforms(key, n):
    state = np.uint64(key)
    out = np.empty(n)
    for i in range(n):
        state, out[i] = _next(state)
    return out


@nb.njit
def _directions(u):
    c, s = np.empty(u.size), np.empty(u.size)
    for i in range(u.size):
        c[i], s[i] = _direction(u[i])
    return c, s


@nb.njit
def _normal_pairs(key, n):
    state = np.uint64(key)
    out = np.empty(2 * n)
    for i in range(n):
        state, a, b, s = _disc(state)
        g = math.sqrt(-2.0 * math.log(s) / s)
        out[2 * i], out[2 * i + 1] = a * g, b * g
    return out


def test_stream_is_splitmix64_top_53_bits():
    assert splitmix64(0, 1)[0] == 0xE220A8397B1DCDAF  # the published first output for seed 0
    for key in (0, 1, 2**63 + 12345, MASK64):
        want = np.array([(z >> 11) * 2.0**-53 for z in splitmix64(key, 1000)])
        assert np.array_equal(_uniforms(np.uint64(key), 1000), want)


def test_uniforms_are_uniform_and_seeds_differ():
    u = _uniforms(np.uint64(7), 200_000)
    assert 0.0 <= u.min() and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    # consecutive values uncorrelated: Pearson r of the lag-1 pairs within 4 standard errors (1/sqrt(n))
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 4 / math.sqrt(u.size)
    assert not np.array_equal(u[:100], _uniforms(np.uint64(8), 100))


def test_direction_equals_cos_sin_to_rounding():
    u = np.concatenate([np.random.default_rng(1).random(1_000_000), [0.0, 0.25, 0.5, 0.75, 1 - 2.0**-53]])
    c, s = _directions(u)
    assert np.abs(c - np.cos(2 * np.pi * u)).max() < 4e-15
    assert np.abs(s - np.sin(2 * np.pi * u)).max() < 4e-15


def test_polar_method_gives_standard_normals():
    x = _normal_pairs(np.uint64(3), 100_000)
    assert stats.kstest(x, "norm").pvalue > 1e-3
    # the pair's two members independent: r within 4 standard errors
    assert abs(np.corrcoef(x[0::2], x[1::2])[0, 1]) < 4 / math.sqrt(x.size / 2)
