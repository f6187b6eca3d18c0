"""Figures in the style of the seed study, drawn from fitted response GPs (matplotlib, Agg).

- ``response_map``: Fig. 7b, GP mean of IoU over focal length x diameter (others nominal),
  with the contour where the lower 2-sigma bound meets the required IoU;
- ``response_line``: Fig. 7c-e / 8a-c, GP mean and 2-sigma band against one parameter with the
  measured points (error bars: the per-point measurement sd) and optional tolerance interval, and
  optionally a second measured series (the sim-to-real benchmark's IoU on emulated real images,
  joined by a line, with its own error bars; not part of the GP);
- ``example_images``: Fig. 6, the same scene at several parameter points.
Each function writes one PNG atomically and returns nothing; ``line_table`` gives the numbers
behind a line plot (for CSV / ``dvc plots``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.atomic import atomic_path
from metraw.tolerance import ResponseGP, Tolerance

LABELS = {"focal_length_m": "focal length [m]", "diameter_m": "mirror diameter [m]", "exposure_s": "exposure time [s]",
          "pixel_pitch_m": "pixel pitch [m]", "haze_e": "haze [e-]"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> None:
    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png")
    _plt().close(fig)


def line_grid(model: ResponseGP, name: str, n: int = 200) -> np.ndarray:
    ax = model.axes[model.names.index(name)]
    return ax.from_unit(np.linspace(0.0, 1.0, n))


def line_table(model: ResponseGP, name: str, at: Mapping[str, float], n: int = 200) -> dict[str, np.ndarray]:
    """value, mean, lower, upper (2 sigma) along ``name`` with the others at ``at``."""
    grid = line_grid(model, name, n)
    p = model.line(name, grid, at)
    return {name: grid, "mean": p.mean, "lower": p.lower, "upper": p.upper}


def response_line(model: ResponseGP, name: str, at: Mapping[str, float], path: str | Path, *, ylabel: str,
                  points: Sequence[tuple[float, float, float]] = (), required: float | None = None,
                  tolerance: Tolerance | None = None, title: str = "",
                  real_points: Sequence[tuple[float, float, float]] = (), real_label: str = "real images (2 sd)",
                  replicate_points: Sequence[tuple[float, float]] = ()) -> None:
    """GP mean with 2-sigma band along ``name``; ``points``: (x, y, sd) measured on that line;
    ``real_points``: a second measured series (x, y, sd), drawn as a curve through its points;
    ``replicate_points``: (x, y) of every replicate model (training seeds), drawn as small dots."""
    plt = _plt()
    t = line_table(model, name, at)
    fig, ax = plt.subplots(figsize=(4.8, 3.4))
    x = t[name]
    ax.fill_between(x, t["lower"], t["upper"], color="tab:blue", alpha=0.25, lw=0, label="GP 2$\\sigma$ band")
    ax.plot(x, t["mean"], color="tab:blue", lw=1.6, label="GP mean")
    if points:
        px, py, ps = (np.array(v, dtype=float) for v in zip(*points))
        ax.errorbar(px, py, yerr=2 * ps, fmt="o", color="k", ms=4, capsize=2,
                    label="synthetic test (2 sd)" if real_points else "measured (2 sd)")
    if replicate_points:
        qx, qy = (np.array(v, dtype=float) for v in zip(*replicate_points))
        ax.plot(qx, qy, ".", color="0.45", ms=3, label="replicates (seeds)")
    if real_points:
        rx, ry, rs = (np.array(v, dtype=float) for v in zip(*sorted(real_points)))
        ax.errorbar(rx, ry, yerr=2 * rs, fmt="s-", color="tab:orange", ms=4, lw=1.2, capsize=2, label=real_label)
    if required is not None:
        ax.axhline(required, color="tab:red", ls="--", lw=1, label=f"required {required:g}")
    if tolerance is not None and tolerance.meets_requirement:
        ax.axvspan(tolerance.min, tolerance.max, color="tab:green", alpha=0.10, label="tolerance")
        ax.axvline(tolerance.optimal, color="tab:green", lw=1, ls=":")
    if model.axes[model.names.index(name)].kind == "log":
        ax.set_xscale("log")
    ax.set_xlabel(LABELS.get(name, name))
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    _save(fig, path)


def response_map(model: ResponseGP, xname: str, yname: str, at: Mapping[str, float], path: str | Path, *,
                 label: str, required: float | None = None, points: Sequence[tuple[float, float]] = (),
                 n: int = 80, title: str = "") -> dict[str, np.ndarray]:
    """GP mean over (xname, yname) with the others at ``at``; returns the grids drawn."""
    plt = _plt()
    gx, gy = line_grid(model, xname, n), line_grid(model, yname, n)
    X, Y = np.meshgrid(gx, gy)
    base = np.tile([float(at[nm]) for nm in model.names], (X.size, 1))
    base[:, model.names.index(xname)] = X.ravel()
    base[:, model.names.index(yname)] = Y.ravel()
    p = model.predict(base)
    mean, lower = p.mean.reshape(X.shape), p.lower.reshape(X.shape)
    fig, ax = plt.subplots(figsize=(5.0, 3.9))
    im = ax.pcolormesh(X, Y, mean, shading="auto", cmap="viridis")
    fig.colorbar(im, ax=ax, label=label)
    if required is not None and lower.min() < required < lower.max():
        cs = ax.contour(X, Y, lower, levels=[required], colors="w", linewidths=1.2)
        ax.clabel(cs, fmt={required: f"lower 2$\\sigma$ = {required:g}"}, fontsize=7)
    if points:
        px, py = zip(*points)
        ax.plot(px, py, "o", mfc="none", mec="w", ms=5)
    for axis, nm in ((ax.xaxis, xname), (ax.yaxis, yname)):
        if model.axes[model.names.index(nm)].kind == "log":
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
    ax.set_xlabel(LABELS.get(xname, xname))
    ax.set_ylabel(LABELS.get(yname, yname))
    if title:
        ax.set_title(title, fontsize=9)
    _save(fig, path)
    return {"x": gx, "y": gy, "mean": mean, "lower": lower}


def quicklook(image) -> np.ndarray:
    """A display image (grey, 0..1) of a raw: electrons averaged over each CFA cell, 1-99 % stretch."""
    from metraw.cfa import cell_size

    e = image.electrons()
    s = cell_size(image.profile.cfa_pattern)
    h, w = (e.shape[0] // s) * s, (e.shape[1] // s) * s
    g = e[:h, :w].reshape(h // s, s, w // s, s).mean(axis=(1, 3))
    lo, hi = np.percentile(g, [1, 99])
    return np.clip((g - lo) / (hi - lo if hi > lo else 1.0), 0, 1)


def example_images(panels: Sequence[tuple[str, Any]], path: str | Path, ncols: int = 4) -> None:
    """Fig. 6: one quicklook per (title, RawImage), same scene at different points."""
    plt = _plt()
    n = len(panels)
    ncols = min(ncols, n)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(2.6 * ncols, 2.7 * nrows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (title, img) in zip(axes.ravel(), panels):
        ax.imshow(quicklook(img), cmap="gray", interpolation="nearest")
        g = img.profile.gsd_m
        ax.set_title(f"{title}\nGSD {g:.2f} m" if g else title, fontsize=7)
    _save(fig, path)
