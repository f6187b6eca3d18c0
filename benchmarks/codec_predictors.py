"""Issue #18: what a faster stream version's predictor would cost in bits, before building one.

The decoder's sequential loop is bound by its per-pixel work (12 taps with per-context coefficients; see
docs/codec-speed.md). A loop that leaves most taps to a vectorised pass before each row needs
coefficients that do not depend on the pixel's activity context (which needs W, the pixel just decoded).
This script measures, on the shared real frames (``benchmarks/codec.py``'s ``frames()``), the empirical code
length H(r | activity context, dither-phase bin) of the coded residual r (the codec's definitions: 8 activity
contexts at the activity's quantiles, 4 folded phase bins; float arithmetic, no side information) for:

- ``base``: today's predictor, x ~ W + sum_i c_i(ctx) (n_i - W) + b(ctx) over 11 causal taps, least squares per
  context (what ``metraw.codec.predictive`` codes);
- ``shared``: one least-squares predictor for all contexts;
- ``sum+3``: a shared sum S of the 10 taps of the rows above (one vectorised pass), then per context
  x ~ W + a S + b (WW - W) + c (N - W) + d;
- ``sum+6``: per context N, NW, NE, NN, WW (and the bias) with a shared sum of the 6 farther taps.

Prints each variant's bits relative to ``base`` per frame and step. Run: python benchmarks/codec_predictors.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from codec import REAL_NAMES, frames  # noqa: E402

from metraw import codec  # noqa: E402
from metraw.codec import prepare  # noqa: E402
from metraw.raw.cfa import cell_size  # noqa: E402

NACT = 8   # activity contexts (``predictive.MAX_NACT``)
NPH = 4    # folded dither-phase bins (``predictive.NPH``)
ABOVE = ("N", "NW", "NE", "NN", "NWW", "NNW", "NNE", "NEE", "NNWW", "NNEE")
OFFSETS = {"X": (0, 0), "W": (0, -1), "WW": (0, -2), "N": (-1, 0), "NW": (-1, -1), "NE": (-1, 1), "NN": (-2, 0),
           "NWW": (-1, -2), "NNW": (-2, -1), "NNE": (-2, 1), "NEE": (-1, 2), "NNWW": (-2, -2), "NNEE": (-2, 2)}


def symbol_planes(img, step: float, seed: int = 0):
    """Each CFA plane's symbols and dither, as ``codec.encode`` makes them (one tile)."""
    h, w = img.shape
    pattern = img.profile.cfa_pattern
    cell = cell_size(pattern)
    grid = codec._plane_grid(0, h, w, pattern)
    dithers = codec._plane_dithers(seed, 0, h, w, pattern)
    return [(prepare.forward(img.data[dy::cell, dx::cell], img.profile, step, u).astype(np.float64), u)
            for (dy, dx, _, _), u in zip(grid, dithers)]


def neighbours(a: np.ndarray) -> dict[str, np.ndarray]:
    """The taps of the interior pixels (2 rows, 2 columns each side left out) as flat arrays."""
    h, w = a.shape
    return {k: a[2 + dy:h + dy, 2 + dx:w - 2 + dx].ravel() for k, (dy, dx) in OFFSETS.items()}


def activity_context(t: dict[str, np.ndarray]) -> np.ndarray:
    act = (np.abs(t["W"] - t["NW"]) + np.abs(t["N"] - t["NW"]) + np.abs(t["N"] - t["NE"]) + np.abs(t["W"] - t["WW"])
           + np.abs(t["N"] - t["NN"]))
    return np.searchsorted(np.unique(np.quantile(act, np.arange(1, NACT) / NACT)), act, side="left")


def fit_per_context(features: np.ndarray, target: np.ndarray, ctx: np.ndarray) -> np.ndarray:
    out = np.empty_like(target)
    for c in np.unique(ctx):
        m = ctx == c
        out[m] = features[m] @ np.linalg.lstsq(features[m], target[m], rcond=None)[0]
    return out


def code_length_bits(s: np.ndarray, u: np.ndarray, prediction: np.ndarray, ctx: np.ndarray) -> float:
    """sum over (context, phase bin) of n H(r): the residual as the codec folds and bins it."""
    m = prediction + u
    t = m - np.round(m)
    r = np.where(t < 0, -1, 1) * (s - np.round(m))
    cls = ctx * NPH + np.minimum((np.abs(t) * 2 * NPH).astype(np.int64), NPH - 1)
    pairs = np.stack([cls, r.astype(np.int64)])
    _, inverse, counts = np.unique(pairs, axis=1, return_inverse=True, return_counts=True)
    n_cls = np.bincount(cls)
    cls_of_pair = np.zeros(counts.size, np.int64)
    cls_of_pair[inverse.ravel()] = cls
    return float(-(counts * np.log2(counts / n_cls[cls_of_pair])).sum())


def predictions(x: np.ndarray):
    """(context, {variant: prediction}) of a plane's reconstructions x = s - u."""
    t = neighbours(x)
    ctx = activity_context(t)
    w_ = t["W"]
    diffs = np.stack([t[k] - w_ for k in ABOVE + ("WW",)] + [np.ones_like(w_)], 1)
    y = t["X"] - w_
    shared = np.linalg.lstsq(diffs, y, rcond=None)[0]
    s_above = diffs[:, :10] @ shared[:10]
    near = [ABOVE.index(k) for k in ("N", "NW", "NE", "NN")] + [10, 11]
    far = [i for i in range(10) if i not in near]
    coef_far = np.linalg.lstsq(diffs[:, far], y - fit_per_context(diffs[:, near], y, ctx), rcond=None)[0]
    s_far = diffs[:, far] @ coef_far
    return ctx, {
        "base": w_ + fit_per_context(diffs, y, ctx),
        "shared": w_ + diffs @ shared,
        "sum+3": w_ + fit_per_context(np.stack([s_above, t["WW"] - w_, t["N"] - w_, np.ones_like(w_)], 1), y, ctx),
        "sum+6": w_ + fit_per_context(np.column_stack([s_far, diffs[:, near]]), y, ctx),
    }


def main() -> int:
    for name, img in frames():
        if name not in REAL_NAMES:
            continue
        for step in (1.0, 2.0):
            bits: dict[str, float] = {}
            n = 0
            for s, u in symbol_planes(img, step):
                ctx, preds = predictions(s - u)
                sv, uv = neighbours(s)["X"], neighbours(u)["X"]
                n += sv.size
                for k, p in preds.items():
                    bits[k] = bits.get(k, 0.0) + code_length_bits(sv, uv, p, ctx)
            rel = "; ".join(f"{k} {100 * (v / bits['base'] - 1):+.2f} %" for k, v in bits.items() if k != "base")
            print(f"{name:13s} step {step:g}: base {bits['base'] / n:.4f} bit/pixel; {rel}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
