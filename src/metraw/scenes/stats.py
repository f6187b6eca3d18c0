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
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from metraw.cfa import plane_offsets
from metraw.image import RawImage

#: Frequency band [cycles/m] of the spectral-slope fit (10 m to 0.67 m periods).
F_BAND_PER_M = (0.1, 1.5)


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
    gen_l, gen_w, comp, frac, slope = [], [], [], [], []
    for img in images:
        gsd = img.profile.gsd_m
        gen_l += [v["length_m"] for v in img.meta.get("vehicles", []) if v["class"] == "car"]
        gen_w += [v["width_m"] for v in img.meta.get("vehicles", []) if v["class"] == "car"]
        comp += mask_component_sizes_m(img.mask, gsd)
        frac.append(float(img.mask.mean()))
        slope.append(psd_slope(green_plane_e(img), 2 * gsd))
    rows["synthetic"] = _row(gen_l, gen_w, comp, frac, slope, len(frac))
    if kit_dir is not None and Path(kit_dir).is_dir():
        from metraw.io import read_raw

        box, frac, slope = [], [], []
        files = sorted(Path(kit_dir).glob("*.png"))
        for f in files:
            img = read_raw(f, gsd_m=kit_gsd_m, seed=0)
            h, w = img.shape
            txt = f.with_suffix(".txt")
            if txt.is_file():
                box += yolo_sizes_m(txt, w, h, kit_gsd_m)
            if img.mask is not None:
                frac.append(float(img.mask.mean()))
            slope.append(psd_slope(green_plane_e(img), 2 * kit_gsd_m))
        rows["KIT AIS (real)"] = _row([b[0] for b in box], [b[1] for b in box], [], frac, slope, len(files))
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
