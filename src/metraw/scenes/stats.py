"""Dataset statistics to compare synthetic scenes with real aerial photos.

- car size [m]: for synthetic scenes, the generator's oriented car dimensions (``meta["vehicles"]``)
  and the oriented dimensions of mask components (second moments: a uniform rectangle of side L
  has variance L^2 / 12 along it); for KIT AIS, the YOLO box sides x GSD (longer side = length;
  axis-aligned boxes overestimate diagonal cars by up to ~35 %).
- car pixel fraction: mean of the mask (area fraction of vehicles).
- power-spectrum slope: green channel (mean of the two G sites of each 2 x 2 cell, electrons),
  Hann-windowed, radially averaged |FFT|^2, least-squares slope of log P vs log f over a common
  band of physical frequencies ``F_BAND_PER_M`` (cycles per metre), so images of different GSD
  compare over the same ground scales.
- radiance histogram: quantiles of log2(green / image median) (exposure-free: a scene's dynamic
  range), and of the chroma log2(R/G), log2(B/G) per CFA cell.
- car contrast: per car region, log2 of its mean green over the mean green of a ring ``RING_M`` wide
  around it; the share of cars darker than their ring. A region is the axis-aligned bounding box of a
  connected component of mask >= 0.5, for the synthetic scenes as for KIT's box labels, so that both
  regions hold the same share of road and shadow; the synthetic cars' exact outlines give the
  ``car_outline_contrast`` rows (no KIT value).
- clutter: share of the ground (green plane block-averaged to ``CLUTTER_CELL_M`` cells) whose
  local log-gradient exceeds ``CLUTTER_THRESHOLD`` (0.3 = a 23 % step from one cell to the next)
  outside cars -- how many car-sized edges the background offers a detector.
KIT car regions come from its YOLO boxes (axis-aligned, so a region holds some road too: a diagonal
car's contrast is biased towards zero, and so is a synthetic car's box contrast).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from metraw.raw.cfa import cell_size, plane_offsets
from metraw.raw.image import RawImage

#: Frequency band [cycles/m] of the spectral-slope fit (10 m to 0.67 m periods).
F_BAND_PER_M = (0.1, 1.5)
#: Width [m] of the ring around a car region whose mean is the car's background.
RING_M = 1.5
#: Ground cell [m] of the clutter measure (about a quarter of a car length).
CLUTTER_CELL_M = 0.5
#: Log-gradient (natural log per cell) above which a cell edge counts as clutter.
CLUTTER_THRESHOLD = 0.3


def green_plane_e(img: RawImage) -> np.ndarray:
    """Mean of the green CFA sites per 2 x 2 cell, in electrons (float64)."""
    e = img.electrons()
    h, w = (e.shape[0] // 2) * 2, (e.shape[1] // 2) * 2
    g = [e[dy:h:2, dx:w:2] for c, dy, dx in plane_offsets(img.cfa_pattern) if c == "G"]
    return sum(g) / len(g)


def psd_slope(plane: np.ndarray, pixel_m: float, band_per_m=F_BAND_PER_M) -> float:
    """Slope of the radially averaged power spectrum (log-log) of a square crop of ``plane``."""
    n = min(plane.shape)
    y0, x0 = (plane.shape[0] - n) // 2, (plane.shape[1] - n) // 2
    x = plane[y0:y0 + n, x0:x0 + n]
    x = x - x.mean()
    win = np.hanning(n)
    p = np.abs(np.fft.fft2(x * win[:, None] * win[None, :])) ** 2
    f = np.fft.fftfreq(n, d=pixel_m)
    fr = np.hypot(f[:, None], f[None, :])
    df = 1.0 / (n * pixel_m)
    k = np.rint(fr / df).astype(np.int64)
    radial = np.bincount(k.ravel(), weights=p.ravel()) / np.maximum(np.bincount(k.ravel()), 1)
    freqs = np.arange(len(radial)) * df
    sel = (freqs >= band_per_m[0]) & (freqs <= band_per_m[1]) & (radial > 0)
    if sel.sum() < 4:
        return float("nan")
    return float(np.polyfit(np.log(freqs[sel]), np.log(radial[sel]), 1)[0])


def cell_planes_e(img: RawImage) -> dict[str, np.ndarray]:
    """Mean electrons of each colour per CFA cell: {"R", "G", "B"} (float64; mono: {"G"}, per pixel)."""
    e = img.electrons()
    k = cell_size(img.cfa_pattern)
    h, w = (e.shape[0] // k) * k, (e.shape[1] // k) * k
    sites: dict[str, list[np.ndarray]] = {}
    for c, dy, dx in plane_offsets(img.cfa_pattern):
        sites.setdefault("G" if c in ("G", "L") else c, []).append(e[dy:h:k, dx:w:k].astype(np.float64))
    return {c: sum(v) / len(v) for c, v in sites.items()}


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    h, w = (a.shape[0] // k) * k, (a.shape[1] // k) * k
    return a[:h, :w].reshape(h // k, k, w // k, k).mean(axis=(1, 3))


def _bounding_boxes(regions: np.ndarray) -> np.ndarray:
    """Union of the axis-aligned bounding boxes of the connected components of a boolean array."""
    lab, _ = ndimage.label(regions)
    out = np.zeros(regions.shape, bool)
    for sl in ndimage.find_objects(lab):
        if sl is not None:
            out[sl] = True
    return out


def _region_contrast(g: np.ndarray, regions: np.ndarray, ring_px: int, min_cells: int = 4) -> list[float]:
    """log2(mean of ``g`` in each connected region / mean in a ring ``ring_px`` cells wide around it)."""
    lab, n = ndimage.label(regions)
    if n == 0:
        return []
    ring = np.where(lab == 0, ndimage.grey_dilation(lab, size=(2 * ring_px + 1,) * 2), 0)

    def count_and_mean(labels):
        count = np.bincount(labels.ravel(), minlength=n + 1)[1:]
        total = np.bincount(labels.ravel(), weights=g.ravel(), minlength=n + 1)[1:]
        return count, total / np.maximum(count, 1)

    (cells, inside), (ring_cells, around) = count_and_mean(lab), count_and_mean(ring)
    ok = (cells >= min_cells) & (ring_cells > 0) & (around > 0)
    return [float(v) for v in np.log2(inside[ok] / around[ok])]


def radiometry(img: RawImage, outlines: bool = True) -> dict[str, list[float]]:
    """Per-image samples for the histogram, chroma, car-contrast and clutter statistics (module docstring).
    ``outlines``: the mask holds the cars' outlines (False for box labels: no outline contrast)."""
    planes = cell_planes_e(img)
    g = np.maximum(planes["G"], 1.0)
    step = cell_size(img.cfa_pattern)
    cell_m = step * img.profile.gsd_m
    out: dict[str, list[float]] = {"log_rel": list(np.log2(g / np.median(g)).ravel()[::97])}
    if "R" in planes and "B" in planes:
        out["log_rg"] = list(np.log2(np.maximum(planes["R"], 1.0) / g).ravel()[::97])
        out["log_bg"] = list(np.log2(np.maximum(planes["B"], 1.0) / g).ravel()[::97])
    car = np.zeros(g.shape, bool)
    contrast, outline = [], []
    if img.mask is not None:
        m = img.mask[: step * g.shape[0], : step * g.shape[1]].astype(np.float64)
        car = _block_mean(m, step) >= 0.5
        ring_px = max(1, int(round(RING_M / cell_m)))
        outline = _region_contrast(g, car, ring_px) if outlines else []
        contrast = _region_contrast(g, _bounding_boxes(car), ring_px)
    out["car_outline_contrast"] = outline
    out["car_contrast"] = contrast
    k = max(1, int(round(CLUTTER_CELL_M / cell_m)))
    lg = np.log(_block_mean(g, k))
    not_car = _block_mean(car.astype(np.float64), k) < 0.5
    grad = np.maximum(np.abs(np.diff(lg, axis=0))[:, :-1], np.abs(np.diff(lg, axis=1))[:-1, :])
    sel = not_car[:-1, :-1]
    out["clutter"] = [float(np.mean(grad[sel] > CLUTTER_THRESHOLD))] if sel.any() else []
    return out


def radiometry_row(samples: list[dict[str, list[float]]]) -> dict[str, float]:
    """Quantiles of the pooled ``radiometry`` samples of a set of images."""
    pool: dict[str, list[float]] = {}
    for s in samples:
        for k, v in s.items():
            pool.setdefault(k, []).extend(v)

    def q(k, p):
        v = pool.get(k, [])
        return float(np.percentile(v, p)) if len(v) else float("nan")

    def darker(k):
        v = np.array(pool.get(k, []))
        return float(np.mean(v < 0)) if v.size else float("nan")

    cc = np.array(pool.get("car_contrast", []))
    return {
        "log2_rel_green_p05": q("log_rel", 5), "log2_rel_green_p95": q("log_rel", 95),
        "log2_R_over_G_median": q("log_rg", 50), "log2_B_over_G_median": q("log_bg", 50),
        "log2_B_over_G_p10": q("log_bg", 10), "log2_B_over_G_p90": q("log_bg", 90),
        "car_contrast_log2_p10": q("car_contrast", 10), "car_contrast_log2_median": q("car_contrast", 50),
        "car_contrast_log2_p90": q("car_contrast", 90),
        "car_abs_contrast_log2_median": float(np.median(np.abs(cc))) if cc.size else float("nan"),
        "cars_darker_than_ring_share": darker("car_contrast"),
        "car_outline_contrast_log2_median": q("car_outline_contrast", 50),
        "cars_outline_darker_share": darker("car_outline_contrast"),
        "clutter_share_median": q("clutter", 50),
    }


def mask_component_sizes_m(mask: np.ndarray, gsd_m: float, min_px: int = 50) -> list[tuple[float, float]]:
    """(length, width) [m] of each connected component of ``mask >= 0.5`` from its second moments."""
    lab, n = ndimage.label(mask >= 0.5)
    out = []
    for sl_i, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        yy, xx = np.nonzero(lab[sl] == sl_i)
        if len(yy) < min_px:
            continue
        cov = np.cov(np.stack([xx, yy]).astype(np.float64))
        ev = np.sort(np.linalg.eigvalsh(cov))[::-1]
        out.append((math.sqrt(12 * ev[0]) * gsd_m, math.sqrt(12 * max(ev[1], 0.0)) * gsd_m))
    return out


def yolo_sizes_m(label_file: Path, width_px: int, height_px: int, gsd_m: float, classes=(0,)) -> list[tuple[float, float]]:
    """(length, width) [m] of YOLO boxes of ``classes`` (longer side = length)."""
    out = []
    for line in Path(label_file).read_text().split("\n"):
        parts = line.split()
        if len(parts) != 5 or int(parts[0]) not in classes:
            continue
        a, b = float(parts[3]) * width_px * gsd_m, float(parts[4]) * height_px * gsd_m
        out.append((max(a, b), min(a, b)))
    return out


def summarise(images, kit_dir: Path | None = None, kit_gsd_m: float = 0.125) -> dict[str, dict[str, float]]:
    """Statistics of synthetic ``images`` (RawImages from metraw.scenes) and of the KIT AIS photos."""
    rows: dict[str, dict[str, float]] = {}
    gen_l, gen_w, comp, frac, slope, rad = [], [], [], [], [], []
    for img in images:
        rad.append(radiometry(img))
        gsd = img.profile.gsd_m
        gen_l += [v["length_m"] for v in img.meta.get("vehicles", []) if v["class"] == "car"]
        gen_w += [v["width_m"] for v in img.meta.get("vehicles", []) if v["class"] == "car"]
        comp += mask_component_sizes_m(img.mask, gsd)
        frac.append(float(img.mask.mean()))
        slope.append(psd_slope(green_plane_e(img), 2 * gsd))
    rows["synthetic"] = {**_row(gen_l, gen_w, comp, frac, slope, len(frac)), **radiometry_row(rad)}
    if kit_dir is not None and Path(kit_dir).is_dir():
        from metraw.io import read_raw

        box, frac, slope, rad = [], [], [], []
        files = sorted(Path(kit_dir).glob("*.png"))
        for f in files:
            img = read_raw(f, gsd_m=kit_gsd_m, seed=0)
            rad.append(radiometry(img, outlines=False))
            h, w = img.shape
            txt = f.with_suffix(".txt")
            if txt.is_file():
                box += yolo_sizes_m(txt, w, h, kit_gsd_m)
            if img.mask is not None:
                frac.append(float(img.mask.mean()))
            slope.append(psd_slope(green_plane_e(img), 2 * kit_gsd_m))
        rows["KIT AIS (real)"] = {**_row([b[0] for b in box], [b[1] for b in box], [], frac, slope, len(files)),
                                  **radiometry_row(rad)}
    return rows


def _row(lengths, widths, comp, frac, slope, n) -> dict[str, float]:
    def q(v, p):
        return float(np.percentile(v, p)) if len(v) else float("nan")

    return {
        "images": n,
        "cars": len(lengths),
        "car_length_m_median": q(lengths, 50), "car_length_m_p10": q(lengths, 10), "car_length_m_p90": q(lengths, 90),
        "car_width_m_median": q(widths, 50),
        "mask_component_length_m_median": q([c[0] for c in comp], 50),
        "mask_component_width_m_median": q([c[1] for c in comp], 50),
        "car_pixel_fraction_mean": float(np.mean(frac)) if frac else float("nan"),
        "car_pixel_fraction_median": q(frac, 50),
        "green_psd_slope_median": float(np.nanmedian(slope)) if slope else float("nan"),
        "green_psd_slope_p10": q(slope, 10), "green_psd_slope_p90": q(slope, 90),
    }


def format_table(rows: dict[str, dict[str, float]]) -> str:
    names = list(rows)
    keys = list(next(iter(rows.values())))
    lines = [f"{'statistic':<34}" + "".join(f"{n:>18}" for n in names)]
    for k in keys:
        lines.append(f"{k:<34}" + "".join(f"{rows[n][k]:>18.4g}" for n in names))
    return "\n".join(lines)
