"""Figures in the style of the seed study, drawn from fitted response GPs (matplotlib, Agg).

- ``response_map``: Fig. 7b, GP mean of IoU over focal length x diameter (others nominal),
  with the contour where the lower 2-sigma bound meets the required IoU;
- ``response_line``: Fig. 7c-e / 8a-c, GP mean and 2-sigma band against one parameter with the
  measured points (error bars: the per-point measurement sd) and optional tolerance interval, and
  optionally a second measured series (the sim-to-real benchmark's IoU on emulated real images,
  joined by a line, with its own error bars; not part of the GP);
- ``grid_map``: the IoU map of a cross grid from its *measured* points (left) and its 2-D GP's
  lower band with the tolerance region (right);
- ``channel_lines``: Fig. 8, a measured outcome per colour channel against one parameter, with
  error bars over images;
- ``categorical_bars``: a measured outcome per value of a categorical parameter (e.g. CFA pattern);
- ``example_images``: Fig. 6, the same scene at several parameter points.
Each function writes one PNG atomically and returns nothing; ``line_table`` gives the numbers
behind a line plot (for CSV / ``dvc plots``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.atomic import atomic_path
from metraw.spec.tolerance import ResponseGP, Tolerance

LABELS = {"focal_length_m": "focal length [m]", "diameter_m": "mirror diameter [m]", "exposure_s": "exposure time [s]",
          "pixel_pitch_m": "pixel pitch [m]", "haze_e": "haze [e-]",
          "path_radiance_w_m2_sr_m": "path radiance at 550 nm [W m$^{-2}$ sr$^{-1}$ m$^{-1}$]",
          "atmospheric_transmission": "atmospheric transmission", "cfa_pattern": "CFA pattern"}
CHANNEL_COLOURS = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "L": "0.3"}


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
                  replicate_points: Sequence[tuple[float, float]] = (), unmeasured: Sequence[float] = ()) -> None:
    """GP mean with 2-sigma band along ``name``; ``points``: (x, y, sd) measured on that line;
    ``real_points``: a second measured series (x, y, sd), drawn as a curve through its points;
    ``replicate_points``: (x, y) of every replicate model (training seeds), drawn as small dots;
    ``unmeasured``: x of the points whose every model is degenerate (issue #71), red crosses on the x axis (no IoU)."""
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
    if unmeasured:
        _unmeasured_marks(ax, list(unmeasured), None)
    if tolerance is not None and tolerance.meets_requirement:
        ax.axvspan(tolerance.min, tolerance.max, color="tab:green", alpha=0.10, label="tolerance")
        ax.axvline(tolerance.optimal, color="tab:green", lw=1, ls=":")
    _finish_line(fig, ax, path, name, ylabel, title, model.axes[model.names.index(name)].kind == "log")


#: Legend label of the points that measured nothing (every model degenerate, issue #71).
UNMEASURED_LABEL = "unmeasured: degenerate model"


def _unmeasured_marks(ax, x: Sequence[float], y: Sequence[float] | None) -> None:
    """Red crosses at ``x`` (and ``y``; None: on the x axis, below the curves) for the unmeasured points."""
    if y is None:
        ax.plot(x, [0.0] * len(x), "x", color="tab:red", ms=8, mew=2, clip_on=False,
                transform=ax.get_xaxis_transform(), label=UNMEASURED_LABEL)
    else:
        ax.plot(x, y, "x", color="tab:red", ms=8, mew=2, clip_on=False, zorder=5, label=UNMEASURED_LABEL)


def _finish_line(fig, ax, path: str | Path, name: str, ylabel: str, title: str, log_x: bool) -> None:
    """Axis scale, labels, title, grid and legend of a line figure; save it."""
    if log_x:
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
                 n: int = 80, title: str = "", unmeasured: Sequence[tuple[float, float]] = ()) -> dict[str, np.ndarray]:
    """GP mean over (xname, yname) with the others at ``at``; returns the grids drawn. ``unmeasured``: (x, y) of
    the points whose every model is degenerate, red crosses."""
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
    if unmeasured:
        _unmeasured_marks(ax, *zip(*unmeasured))
        ax.legend(fontsize=7, loc="best")
    for axis, nm in ((ax.xaxis, xname), (ax.yaxis, yname)):
        if model.axes[model.names.index(nm)].kind == "log":
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
    ax.set_xlabel(LABELS.get(xname, xname))
    ax.set_ylabel(LABELS.get(yname, yname))
    if title:
        ax.set_title(title, fontsize=9)
    _save(fig, path)
    return {"x": gx, "y": gy, "mean": mean, "lower": lower}


def grid_map(model: ResponseGP, summary: Mapping[str, Any], path: str | Path, *, required: float,
             title: str = "", unmeasured: Sequence[tuple[float, float]] = ()) -> None:
    """Left: measured IoU at the grid points (cells in grid order, value and 2 sd written in each; a
    frame marks points whose measured lower bound meets ``required``). Right: the 2-D GP's lower 2-sigma
    band on the mesh of ``summary`` (`metraw.spec.tolerance.grid_region`), the region meeting ``required``
    outlined, the measured points marked; ``unmeasured``: (x, y) of grid points whose every model is degenerate,
    red crosses (no cell of their own on the left: they measured nothing)."""
    plt = _plt()
    a, b = summary["axes"]
    pts = summary["points"]
    va, vb = sorted({p[a] for p in pts}), sorted({p[b] for p in pts})
    grid = np.full((len(vb), len(va)), np.nan)
    for p in pts:
        grid[vb.index(p[b]), va.index(p[a])] = p["iou"]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    im = ax0.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
    fig.colorbar(im, ax=ax0, label="IoU (measured)").formatter.set_useOffset(False)
    for p in pts:
        i, j = vb.index(p[b]), va.index(p[a])
        ax0.text(j, i, f"{p['iou']:.3f}\n$\\pm${2 * p['iou_sd']:.3f}", ha="center", va="center", fontsize=7,
                 color="w" if p["iou"] < np.nanmean(grid) else "k")
        if p["meets_requirement"]:
            ax0.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="tab:red", lw=2))
    ax0.set_xticks(range(len(va)), [f"{v:g}" for v in va])
    ax0.set_yticks(range(len(vb)), [f"{v:g}" for v in vb])
    ax0.set_xlabel(LABELS.get(a, a))
    ax0.set_ylabel(LABELS.get(b, b))
    ax0.set_title(f"measured points (red frame: IoU - 2 sd >= {required:g})", fontsize=8)
    A, B = np.meshgrid(summary["mesh"][a], summary["mesh"][b])
    lower = model.predict(np.column_stack([A.ravel(), B.ravel()])).lower.reshape(A.shape)
    im = ax1.pcolormesh(A, B, lower, shading="auto", cmap="viridis")
    bar = fig.colorbar(im, ax=ax1, label="IoU, GP lower 2$\\sigma$")
    bar.formatter.set_useOffset(False)
    bar.update_ticks()
    if lower.min() < required < lower.max():
        ax1.contour(A, B, lower, levels=[required], colors="tab:red", linewidths=1.5)
    ax1.plot([p[a] for p in pts], [p[b] for p in pts], "o", mfc="none", mec="w", ms=5)
    if unmeasured:
        _unmeasured_marks(ax1, *zip(*unmeasured))
        ax1.legend(fontsize=7, loc="best")
    for setter, nm in ((ax1.set_xscale, a), (ax1.set_yscale, b)):
        if model.axes[model.names.index(nm)].kind == "log":
            setter("log")
    ax1.set_xlabel(LABELS.get(a, a))
    ax1.set_ylabel(LABELS.get(b, b))
    ax1.set_title(f"2-D GP: lower band >= {required:g} (red contour) on "
                  f"{100 * summary['share_of_grid_ok']:.0f} % of the box", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    _save(fig, path)


def channel_lines(name: str, series: Mapping[str, Sequence[tuple[float, float, float]]], path: str | Path, *,
                  ylabel: str, log_x: bool = False, title: str = "") -> None:
    """One measured curve per colour channel: ``series[channel]`` = [(x, y, se), ...] (bars: 2 standard errors
    of the mean over the point's images)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.8, 3.4))
    for c, pts in series.items():
        if not pts:
            continue
        x, y, sd = (np.array(v, dtype=float) for v in zip(*sorted(pts)))
        ax.errorbar(x, y, yerr=2 * sd, fmt="o-", color=CHANNEL_COLOURS.get(c, None), ms=4, lw=1.2, capsize=2,
                    label=f"{c} (2 se over images)")
    _finish_line(fig, ax, path, name, ylabel, title, log_x)


def categorical_bars(name: str, values: Mapping[str, tuple[float, float]], path: str | Path, *, ylabel: str,
                     required: float | None = None, title: str = "", unmeasured: Sequence[str] = ()) -> None:
    """A measured outcome per category: ``values[label]`` = (y, sd), drawn with 2 sd bars; ``unmeasured``: the
    categories whose every model is degenerate, a red cross on the axis after the measured bars (no bar)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(3.6, 3.2))
    labels = list(values)
    y = np.array([values[v][0] for v in labels], dtype=float)
    sd = np.array([values[v][1] for v in labels], dtype=float)
    ax.bar(range(len(labels)), y, yerr=2 * sd, capsize=3, color="tab:blue", alpha=0.7)
    if unmeasured:
        _unmeasured_marks(ax, list(range(len(labels), len(labels) + len(unmeasured))), None)
        labels = [*labels, *unmeasured]
    if required is not None:
        ax.axhline(required, color="tab:red", ls="--", lw=1, label=f"required {required:g}")
        ax.legend(fontsize=7)
    _finish_bars(fig, ax, path, name, labels, ylabel, title, fontsize=9)


def categorical_channel_bars(name: str, values: Mapping[str, Mapping[str, tuple[float, float]]], path: str | Path, *,
                             ylabel: str, title: str = "") -> None:
    """A measured outcome per category and colour channel: ``values[label][channel]`` = (y, se), grouped bars per
    category (a mono sensor has one channel, L; a Bayer one R, G, B), with bars of 2 standard errors."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.2, 3.2))
    labels = list(values)
    width = 0.8 / max(len(v) for v in values.values())
    for i, label in enumerate(labels):
        chans = values[label]
        for j, (c, (y, se)) in enumerate(chans.items()):
            x = i + (j - (len(chans) - 1) / 2) * width
            ax.bar(x, y, width=width * 0.9, yerr=2 * se, capsize=2, color=CHANNEL_COLOURS.get(c, "tab:grey"),
                   alpha=0.8)
            ax.text(x, 0.02 * y, c, ha="center", va="bottom", fontsize=7, color="white")
    _finish_bars(fig, ax, path, name, labels, ylabel, (title + "\n" if title else "") + "bars: 2 se over images",
                 fontsize=8)


def _finish_bars(fig, ax, path: str | Path, name: str, labels: Sequence[str], ylabel: str, title: str,
                 fontsize: int) -> None:
    """Category ticks, labels, title and grid of a bar figure; save it."""
    ax.set_xticks(range(len(labels)), labels)
    ax.set_xlabel(LABELS.get(name, name))
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=fontsize)
    ax.grid(alpha=0.3, axis="y")
    _save(fig, path)


def quicklook(image) -> np.ndarray:
    """A display image (grey, 0..1) of a raw: electrons averaged over each CFA cell, 1-99 % stretch."""
    from metraw.raw.cfa import cell_size

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
