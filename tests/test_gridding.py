"""Banded Gaussian gridding operators (metraw.physics.gridding) against the dense matrix they stand for."""

from __future__ import annotations

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.physics.gridding import GaussianWindow


def _reference(pos, n_grid, periodic, half_width, sigma):
    """S built entry by entry from the definition: column i, the Gaussian about pos[i] at its nearest grid points."""
    s = np.zeros((n_grid, len(pos)))
    for i, p in enumerate(pos):
        k0 = int(np.rint(p))
        for k in range(k0 - half_width, k0 + half_width + 1):
            s[k % n_grid if periodic else k, i] += np.exp(-0.5 * ((k - p) / sigma) ** 2)
    return s


@pytest.mark.parametrize("periodic", [True, False])
def test_operators_are_the_products_with_the_window_matrix(periodic):
    rng = np.random.default_rng(1)
    n_grid, half_width, sigma = 97, 5, 1.3
    # periodic: points over the edges (their bands wrap); not periodic: bands inside the grid
    pos = rng.uniform(-4.0, n_grid + 4.0, 60) if periodic else rng.uniform(6.0, n_grid - 7.0, 60)
    w = GaussianWindow(pos, n_grid, periodic, half_width, sigma)
    s = _reference(pos, n_grid, periodic, half_width, sigma)
    assert np.array_equal(w.dense(), s)
    a, b = rng.normal(size=(60, 13)), rng.normal(size=(11, 60))
    g, h = rng.normal(size=(n_grid, 7)), rng.normal(size=(9, n_grid))
    for got, want in ((w.scatter_rows(a), s @ a), (w.scatter_cols(b), b @ s.T),
                      (w.gather_rows(g), s.T @ g), (w.gather_cols(h), h @ s)):
        assert got.shape == want.shape and got.flags.c_contiguous
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * np.abs(want).max())
    # scattering conserves the total for a window normalised per point (the sums of S's columns)
    total = s.sum(axis=0)
    assert w.scatter_rows(a).sum(axis=0) == pytest.approx(total @ a, rel=1e-13)


def test_a_band_leaving_a_non_periodic_grid_and_wrong_operands_are_refused():
    with pytest.raises(MetrawError, match="leaves the Fourier grid"):
        GaussianWindow(np.array([1.0, 50.0]), 60, False, 3, 1.0)
    w = GaussianWindow(np.array([10.0, 20.0]), 40, False, 3, 1.0)
    with pytest.raises(MetrawError, match="operand"):
        w.scatter_rows(np.ones((3, 4)))
    with pytest.raises(MetrawError, match="grid of shape"):
        w.gather_cols(np.ones((4, 39)))
