"""Contact sheet: false-colour previews of raw images with their car masks outlined.

Preview of a Bayer raw: subtract black, bin each 2 x 2 CFA cell into one RGB pixel (G = mean of
the two greens), white-balance with per-channel gains from the image's own mean (grey world),
scale so the 99.5th percentile is white, gamma 1/2.2. White balance: per-channel gains that make
a grey sunlit surface grey -- from the daylight radiometry of ``metraw.scenes.radiance`` (45 degree
sun) for a measured profile, from the QE ratios for an approximate raw made from a processed photo
(that conversion scales channels by QE, ``metraw.io.processed``). Masks (car area fraction >= 0.5) are
binned the same way and drawn as 1-pixel outlines. The same function serves synthetic scenes
and approximate raws made from real photos, so both are seen in the same style.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import plane_offsets
from metraw.raw.image import RawImage


def false_colour(img: RawImage) -> np.ndarray:
    """(H/2, W/2, 3) float RGB in [0, 1] from a Bayer raw (or (H, W, 3) grey for mono)."""
    e = img.data.astype(np.float64) - img.profile.black_level_dn
    if img.profile.is_mono:
        rgb = np.repeat(e[..., None], 3, axis=2)
    else:
        h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
        e = e[:h, :w]
        acc = {"R": 0.0, "G": 0.0, "B": 0.0}
        cnt = {"R": 0, "G": 0, "B": 0}
        for c, dy, dx in plane_offsets(img.cfa_pattern):
            acc[c] = acc[c] + e[dy::2, dx::2]
            cnt[c] += 1
        rgb = np.stack([acc[c] / cnt[c] for c in "RGB"], axis=2)
    rgb = np.maximum(rgb, 0.0) * white_balance_gains(img.profile)[None, None, :]
    top = np.percentile(rgb, 99.5)
    return np.clip(rgb / max(top, 1e-9), 0.0, 1.0) ** (1 / 2.2)


def white_balance_gains(profile) -> np.ndarray:
    """Gains (R, G, B), G = 1, that render a grey sunlit surface grey (see module docstring)."""
    if profile.is_mono:
        return np.ones(3)
    if not profile.approximate and None not in (profile.pixel_pitch_m, profile.focal_length_m,
                                                profile.aperture_diameter_m):
        from metraw.scenes.radiance import electrons_per_reflectance

        k = electrons_per_reflectance(profile, 45.0, 1.0)
        resp = np.array([k[c][0] * np.sqrt(0.5) + k[c][1] for c in "RGB"])
    else:
        resp = np.array([profile.qe_per_channel.get(c, 1.0) for c in "RGB"])
    return resp[1] / resp


def mask_outline(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Boolean outline (inner boundary) of ``mask >= 0.5`` resampled to ``shape`` by 2x2 binning."""
    m = np.asarray(mask, dtype=np.float32)
    if m.shape != shape:
        f = m.shape[0] // shape[0]
        m = m[:shape[0] * f, :shape[1] * f].reshape(shape[0], f, shape[1], f).mean(axis=(1, 3))
    inside = m >= 0.5
    edge = np.zeros_like(inside)
    edge[1:, :] |= inside[1:, :] & ~inside[:-1, :]
    edge[:-1, :] |= inside[:-1, :] & ~inside[1:, :]
    edge[:, 1:] |= inside[:, 1:] & ~inside[:, :-1]
    edge[:, :-1] |= inside[:, :-1] & ~inside[:, 1:]
    return edge


def preview(img: RawImage, outline_rgb=(1.0, 0.1, 0.9)) -> np.ndarray:
    """False-colour preview with the car mask outlined (if the image has a mask)."""
    rgb = false_colour(img)
    if img.mask is not None:
        edge = mask_outline(img.mask, rgb.shape[:2])
        rgb[edge] = outline_rgb
    return rgb


def contact_sheet(rows: Sequence[tuple[str, Sequence[RawImage]]], out_png: str | os.PathLike,
                  tile_px: int = 256, title: str = "") -> None:
    """Write a PNG grid: one row per (label, images), each image a square tile of ``tile_px``.

    Non-square images are centre-cropped to a square before resizing. Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metraw.atomic import atomic_path

    rows = [(label, list(images)) for label, images in rows if images]
    if not rows:
        raise MetrawError("contact sheet needs at least one image")
    ncol = max(len(images) for _, images in rows)
    dpi = 100
    fig, axes = plt.subplots(len(rows), ncol, figsize=(ncol * tile_px / dpi, len(rows) * (tile_px + 28) / dpi),
                             dpi=dpi, squeeze=False)
    for r, (label, images) in enumerate(rows):
        for c in range(ncol):
            ax = axes[r][c]
            ax.set_axis_off()
            if c >= len(images):
                continue
            img = images[c]
            rgb = preview(img)
            h, w = rgb.shape[:2]
            s = min(h, w)
            y0, x0 = (h - s) // 2, (w - s) // 2
            ax.imshow(rgb[y0:y0 + s, x0:x0 + s], interpolation="lanczos")
            gsd = img.profile.gsd_m or img.meta.get("gsd_m")
            side = f"{s * 2 * gsd:.0f} m" if gsd and not img.profile.is_mono else ""
            ax.set_title(f"{label} {side}".strip(), fontsize=7, pad=2)
    if title:
        fig.suptitle(title, fontsize=8)
    fig.subplots_adjust(left=0.005, right=0.995, bottom=0.005, top=0.93 if title else 0.97, wspace=0.02, hspace=0.15)
    with atomic_path(out_png, overwrite=True) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    plt.close(fig)


def real_kit_images(real_dir: str | os.PathLike, count: int, camera=None) -> list[RawImage]:
    """Up to ``count`` KIT AIS aerial photos (data/real/kit_ais of the repository, see its SOURCE.txt)
    converted to approximate raws with their YOLO boxes as masks by ``metraw.io.read_raw``
    (GSD 0.125 m). Empty list when the data or the reader is missing."""
    from pathlib import Path

    d = Path(real_dir)
    files = sorted(d.glob("*.png")) if d.is_dir() else []
    try:
        from metraw.io import read_raw
    except ImportError:
        return []
    step = max(1, len(files) // max(count, 1))
    return [read_raw(f, camera=camera, gsd_m=0.125, seed=0) for f in files[::step][:count]]


def scenes_contact_sheet(store, out_png: str | os.PathLike, per_kind: int = 3, real_dir=None,
                         tile_px: int = 200) -> None:
    """Contact sheet of a scenes store: ``per_kind`` scenes of each scene type, plus a row of
    real KIT aerial photos in the same style when ``real_dir`` holds them."""
    rows: dict[str, list[RawImage]] = {}
    for i in range(len(store)):
        kind = store.meta(i).get("scene_type", "?")
        if len(rows.setdefault(kind, [])) < per_kind:
            rows[kind].append(store[i])
        if len(rows) >= 3 and all(len(v) >= per_kind for v in rows.values()):
            break
    sheet = [(k, v) for k, v in rows.items()]
    if real_dir is not None:
        real = real_kit_images(real_dir, per_kind)
        if real:
            sheet.append(("KIT AIS real (approx. raw)", real))
    contact_sheet(sheet, out_png, tile_px=tile_px,
                  title="metraw scenes: false colour from the raw (2x2 binned), car masks outlined")
