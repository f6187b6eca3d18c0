"""Separable Gaussian gridding: 1-D banded window operators applied along the rows or columns of 2-D arrays.

``GaussianWindow(pos, n_grid, periodic, half_width, sigma)`` stands for the (n_grid x len(pos)) matrix S whose
column i holds a Gaussian of ``sigma`` grid points centred at grid coordinate ``pos[i]`` (float), sampled at the
2 ``half_width`` + 1 grid points nearest to it (wrapped modulo ``n_grid`` when ``periodic``). The expected-value
emulation (``metraw.emulate``) spreads cell values onto the Fourier grid with S (type-1 gridding) and evaluates the
filtered grid at target pixel centres with S^T (type-2):

- ``scatter_rows(A)`` = S @ A and ``scatter_cols(A)`` = A @ S^T;
- ``gather_rows(G)`` = S^T @ G and ``gather_cols(G)`` = G @ S.

Compiled loops over the band (numba), reading and writing whole rows of C-ordered float64 arrays (the column
scatter works on transposed copies, which pays for itself): no sparse matrix. The sums are the sparse products'
to rounding (the order of the band's terms differs: ~1e-16 relative).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from metraw.errors import MetrawError


class GaussianWindow:
    """The banded matrix S (see module docstring): ``index`` (len(pos), 2 M + 1) grid rows, ``weight`` the same
    shape, float64."""

    def __init__(self, pos: np.ndarray, n_grid: int, periodic: bool, half_width: int, sigma: float):
        pos = np.asarray(pos, np.float64)
        k0 = np.rint(pos).astype(np.int64)
        offs = np.arange(-half_width, half_width + 1)
        rows = k0[:, None] + offs[None, :]
        self.weight = np.ascontiguousarray(np.exp(-0.5 * ((rows - pos[:, None]) / sigma) ** 2))
        if periodic:
            rows = rows % n_grid
        elif rows.size and (rows.min() < 0 or rows.max() >= n_grid):
            raise MetrawError("internal error: gridding support leaves the Fourier grid")
        self.index = np.ascontiguousarray(rows)
        self.n_grid = int(n_grid)

    @property
    def n_points(self) -> int:
        return self.index.shape[0]

    def dense(self) -> np.ndarray:
        """S as a dense (n_grid, n_points) array (tests)."""
        out = np.zeros((self.n_grid, self.n_points))
        for i in range(self.n_points):
            np.add.at(out[:, i], self.index[i], self.weight[i])
        return out

    def scatter_rows(self, a: np.ndarray) -> np.ndarray:
        """S @ a: (n_points, n) -> (n_grid, n)."""
        return _scatter_rows(self._checked(a, 0, self.n_points, "operand"), self.index, self.weight, self.n_grid)

    def scatter_cols(self, a: np.ndarray) -> np.ndarray:
        """a @ S^T: (n, n_points) -> (n, n_grid)."""
        return _scatter_cols(self._checked(a, 1, self.n_points, "operand"), self.index, self.weight, self.n_grid)

    def gather_rows(self, g: np.ndarray) -> np.ndarray:
        """S^T @ g: (n_grid, n) -> (n_points, n)."""
        return _gather_rows(self._checked(g, 0, self.n_grid, "grid"), self.index, self.weight)

    def gather_cols(self, g: np.ndarray) -> np.ndarray:
        """g @ S: (n, n_grid) -> (n, n_points)."""
        return _gather_cols(self._checked(g, 1, self.n_grid, "grid"), self.index, self.weight)

    @staticmethod
    def _checked(a, axis: int, n: int, what: str) -> np.ndarray:
        """``a`` as C-ordered float64, 2-D with ``n`` along ``axis`` (``what``: operand or grid, for the message)."""
        a = np.ascontiguousarray(a, np.float64)
        if a.ndim != 2 or a.shape[axis] != n:
            raise MetrawError(f"internal error: gridding {what} of shape {a.shape}, expected {n} along axis {axis}")
        return a


@nb.njit(cache=True, nogil=True)
def _scatter_rows(a, index, weight, n_grid):
    out = np.zeros((n_grid, a.shape[1]))
    for i in range(a.shape[0]):
        for o in range(index.shape[1]):
            row, w = index[i, o], weight[i, o]
            for c in range(a.shape[1]):
                out[row, c] += w * a[i, c]
    return out


@nb.njit(cache=True, nogil=True)
def _scatter_cols(a, index, weight, n_grid):
    # on the transposes, so that the innermost loop runs along contiguous rows (it vectorises; ~1.5x faster than
    # scattered writes at the emulator's 384 x 512 cells); each element's sum takes its terms in the same order
    n = a.shape[0]
    at = np.ascontiguousarray(a.T)
    out_t = np.zeros((n_grid, n))
    for j in range(at.shape[0]):
        for o in range(index.shape[1]):
            k, w = index[j, o], weight[j, o]
            for r in range(n):
                out_t[k, r] += w * at[j, r]
    return np.ascontiguousarray(out_t.T)


@nb.njit(cache=True, nogil=True)
def _gather_rows(g, index, weight):
    out = np.zeros((index.shape[0], g.shape[1]))
    for i in range(index.shape[0]):
        for o in range(index.shape[1]):
            row, w = index[i, o], weight[i, o]
            for c in range(g.shape[1]):
                out[i, c] += w * g[row, c]
    return out


@nb.njit(cache=True, nogil=True)
def _gather_cols(g, index, weight):
    out = np.empty((g.shape[0], index.shape[0]))
    for r in range(g.shape[0]):
        for j in range(index.shape[0]):
            s = 0.0
            for o in range(index.shape[1]):
                s += weight[j, o] * g[r, index[j, o]]
            out[r, j] = s
    return out
