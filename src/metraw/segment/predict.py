"""Car probability and mask of every image of a store, on each image's mosaic grid (``metraw predict``).

The network predicts one logit per CFA site of the canonically packed image (``metraw.segment.data``:
the mosaic shifted by at most one pixel to an R G / G B cell, whole cells only). The per-site
probabilities are put back on the mosaic by the inverse of that packing (``sites_to_mosaic``); the
at most one mosaic row / column per side that whole-cell packing drops gets the value of its nearest
predicted pixel (edge replication): every pixel has a probability, and ``packed_window`` (recorded per
image) says which rows and columns the network itself predicted (the ones ``metraw evaluate`` scores).

Images of another ground sampling distance than the training images are resampled to it for the
network and back (``metraw.segment.evaluate.resample_to_gsd``); the factor is recorded per image.
The mask is probability > 0.5 less the predicted objects smaller than ``MIN_OBJECT_AREA_M2`` on the ground
(``metraw.segment.evaluate.predicted_mask``), the rule ``metraw evaluate`` scores. Images need no labels.

Output: one zarr v3 group, written atomically, holding ``probability`` (float32) and ``mask`` (bool):
(N, H, W) arrays when all images share a shape ("layout": "stacked"), else one (H, W) array per image
``probability/<i>``, ``mask/<i>`` ("layout": "per_image"); attributes ``metraw_predict``: model,
store, threshold, smallest object area [m^2], GSD scale factors, per image its index, shape, packed window,
GSD scale and labels.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import PACKED_CELL_PX, PACKED_GEOMETRY, unpack_planes
from metraw.segment.data import canonical_window
from metraw.segment.evaluate import THRESHOLD
from metraw.segment.objects import MIN_OBJECT_AREA_M2

#: Colours (RGB, 0..1) of the overlay: predicted mask tint and outline, label outline.
PRED_RGB = (0.0, 0.9, 1.0)
LABEL_RGB = (1.0, 0.1, 0.9)


def packed_window(pattern: str, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the mosaic rows y0..y1-1 and columns x0..x1-1 that canonical packing covers."""
    dy, dx, h, w = canonical_window(pattern, shape, 0)
    return dy, dy + h, dx, dx + w


def sites_to_mosaic(values: np.ndarray, pattern: str, shape: tuple[int, int]) -> np.ndarray:
    """Per-site values (S, h, w) of the canonically packed image back on its (H, W) mosaic.

    Inverse of ``canonical_pack`` (transform 0); rows and columns outside ``packed_window`` take the
    value of the nearest packed pixel (edge replication).
    """
    y0, y1, x0, x1 = packed_window(pattern, shape)
    inner = unpack_planes(values, PACKED_GEOMETRY, (y1 - y0, x1 - x0))
    H, W = shape
    return np.pad(inner, ((y0, H - y1), (x0, W - x1)), mode="edge")


def predict_image(model, image, device: str, train_packed_gsd_m: float | None, recorded: bool = True,
                  transforms: int = 1) -> tuple[np.ndarray, dict[str, Any], str | None]:
    """(car probability (H, W) float32 on the mosaic grid, averaged over ``transforms`` dihedral transforms,
    info (shape, packed window, packed GSD [m], GSD scale), why the GSD was not matched or None);
    ``recorded``: the checkpoint has the training GSD."""
    from metraw.segment.condition import payload_condition
    from metraw.segment.data import vst_mosaic
    from metraw.segment.evaluate import averaged_probability, gsd_scale, image_packed_gsd_m

    gsd = image_packed_gsd_m(image)
    scale, matched, note = gsd_scale(gsd, train_packed_gsd_m, recorded)
    p = averaged_probability(model, vst_mosaic(image), image.cfa_pattern, device, scale, transforms,
                             payload_condition(image.profile))
    info = {"shape": list(image.shape), "packed_window": list(packed_window(image.cfa_pattern, image.shape)),
            "packed_gsd_m": gsd, "gsd_scale": scale, "gsd_matched": matched}
    return sites_to_mosaic(p, image.cfa_pattern, image.shape), info, note


def window_mask(probability: np.ndarray, window, packed_gsd_m: float | None, pattern: str) -> np.ndarray:
    """Car mask (H, W) of a probability map: ``predicted_mask`` on the ``packed_window`` the network predicted
    (the pixels ``metraw evaluate`` scores, so both see the same objects), edge-replicated outside it."""
    from metraw.segment.evaluate import predicted_mask

    y0, y1, x0, x1 = window
    H, W = probability.shape
    inner = predicted_mask(probability[y0:y1, x0:x1], packed_gsd_m / PACKED_CELL_PX if packed_gsd_m else None)
    return np.pad(inner, ((y0, H - y1), (x0, W - x1)), mode="edge")


def predict_store(store_path, model_dir, out_path, device: str | None = None, progress: bool | None = None,
                  overwrite: bool = False, overlay=None, overlay_count: int = 4, transforms: int | None = None
                  ) -> dict[str, Any]:
    """Segment every image of a store with a trained model and write the zarr group ``out_path``.

    ``transforms``: dihedral transforms averaged per prediction (default: the model's ``predict_transforms``).

    ``overlay``: a .png file (one figure, the first ``overlay_count`` images) or a folder (one
    ``overlay_<index>.png`` each), written with the group. Returns a summary (no timings).
    """
    import zarr

    from metraw.atomic import atomic_path
    from metraw.io.store import RawStore
    from metraw.progress import progress_bar
    from metraw.segment.evaluate import check_channels, label_kind, open_for_inference
    from metraw.segment.train import flush_denormals

    for path in (out_path, overlay):
        if path is not None and Path(path).exists() and not overwrite:
            raise MetrawError(f"output {path} already exists (use --overwrite to replace it)")
    if overlay is not None and overlay_count < 1:
        raise MetrawError(f"--overlay-count must be >= 1, got {overlay_count}")
    model, ckpt, _, config, transforms, device = open_for_inference(model_dir, device, transforms)
    store = RawStore.open(store_path)
    n = len(store)
    if n == 0:
        raise MetrawError(f"store {store_path} holds no images")
    shapes = [store.shape(i) for i in range(n)]
    stacked = len(set(shapes)) == 1
    train_gsd, recorded = ckpt.get("train_packed_gsd_m"), "train_packed_gsd_m" in ckpt
    zstd = zarr.codecs.ZstdCodec(level=3, checksum=True)
    records, notes, panels, car_px = [], [], [], 0
    with atomic_path(out_path, overwrite=overwrite) as tmp, flush_denormals():
        group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        if stacked:
            (H, W) = shapes[0]
            arrays = {name: group.create_array(name, shape=(n, H, W), chunks=(1, H, W), dtype=dtype,
                                               compressors=[zstd], fill_value=fill)
                      for name, dtype, fill in (("probability", "float32", 0.0), ("mask", "bool", False))}
        else:
            subgroups = {name: group.create_group(name) for name in ("probability", "mask")}
        for i in progress_bar(range(n), desc="predict", disable=None if progress is None else not progress):
            image = store[i]
            check_channels(ckpt, image.cfa_pattern, f"image {i} of {store_path}", model_dir)
            p, info, note = predict_image(model, image, device, train_gsd, recorded, transforms)
            mask = window_mask(p, info["packed_window"], info["packed_gsd_m"], image.cfa_pattern)
            if stacked:
                arrays["probability"][i] = p
                arrays["mask"][i] = mask
            else:
                for name, a in (("probability", p), ("mask", mask)):
                    subgroups[name].create_array(str(i), shape=a.shape, chunks=a.shape, dtype=a.dtype,
                                                 compressors=[zstd])[...] = a
            has_label = image.mask is not None
            records.append({"index": i, **info, "labels": label_kind(image.meta) if has_label else None})
            car_px += int(mask.sum())
            if note and note not in notes:
                notes.append(note)
            if overlay is not None and len(panels) < overlay_count:
                panels.append((i, image, mask, info["gsd_scale"]))
        scales = sorted({r["gsd_scale"] for r in records})
        attrs = {"model": str(model_dir), "store": str(store_path), "threshold": THRESHOLD,
                 "min_object_area_m2": MIN_OBJECT_AREA_M2, "transforms": transforms,
                 "layout": "stacked" if stacked else "per_image", "n_images": n,
                 "train_packed_gsd_m": train_gsd, "gsd_scale": scales[0] if len(scales) == 1 else None,
                 "gsd_matched": not notes, "gsd_note": "; ".join(notes) or None,
                 "edge": "rows/columns outside packed_window: nearest predicted pixel", "images": records}
        group.attrs["metraw_predict"] = attrs
        if overlay is not None:
            write_overlay(panels, overlay, overwrite)
    return {"n_images": n, "layout": attrs["layout"], "gsd_scale": attrs["gsd_scale"], "gsd_note": attrs["gsd_note"],
            "car_fraction": car_px / float(sum(h * w for h, w in shapes)), "out": str(out_path),
            "overlay": None if overlay is None else str(overlay)}


def load_prediction(path, index: int) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(probability, mask, that image's record) of image ``index`` of a ``predict_store`` output."""
    import zarr

    try:
        group = zarr.open_group(str(path), mode="r", zarr_format=3)
        attrs = group.attrs["metraw_predict"]
    except Exception as exc:  # zarr raises several types on a missing or damaged group
        raise MetrawError(f"cannot open prediction {path}: {' '.join(str(exc).split())[:200]}") from None
    if attrs["layout"] == "stacked":
        return np.asarray(group["probability"][index]), np.asarray(group["mask"][index]), attrs["images"][index]
    return (np.asarray(group[f"probability/{index}"][...]), np.asarray(group[f"mask/{index}"][...]),
            attrs["images"][index])


# ----------------------------------------------------------------- overlay figure
def _binned(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Fraction of ``mask`` in each cell of the quick-look grid ``shape`` (2 x 2 binning from (0, 0))."""
    m = np.asarray(mask, dtype=np.float32)
    if m.shape == shape:
        return m
    f = 2  # a Bayer cell; mono quick-looks keep the mosaic grid (above)
    return m[:shape[0] * f, :shape[1] * f].reshape(shape[0], f, shape[1], f).mean(axis=(1, 3))


def overlay_rgb(image, mask: np.ndarray) -> np.ndarray:
    """Quick-look RGB (``metraw.scenes.contact_sheet.false_colour``) with the predicted mask tinted and
    outlined in ``PRED_RGB`` and, when the image has labels, the label outline in ``LABEL_RGB``."""
    from metraw.scenes.contact_sheet import false_colour, mask_outline

    rgb = false_colour(image)
    shape = rgb.shape[:2]
    inside = _binned(mask, shape) >= 0.5
    rgb[inside] = 0.6 * rgb[inside] + 0.4 * np.asarray(PRED_RGB)
    rgb[mask_outline(mask, shape)] = PRED_RGB
    if image.mask is not None:
        rgb[mask_outline(image.mask, shape)] = LABEL_RGB
    return rgb


def write_overlay(panels: list[tuple[int, Any, np.ndarray, float]], path: str | os.PathLike,
                  overwrite: bool = False) -> None:
    """Overlay figures of (index, RawImage, mask, GSD scale): one PNG with all panels when ``path`` ends in
    .png, else a folder of ``overlay_<index>.png``; written atomically (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metraw.atomic import atomic_path

    def figure(group):
        aspect = max(image.shape[1] / image.shape[0] for _, image, _, _ in group)  # width / height
        ncol = min(4 if aspect < 1.5 else 1, len(group))
        nrow = -(-len(group) // ncol)
        width_in = 3.2 if aspect < 1.5 else 9.0  # panel width [in]
        fig, axes = plt.subplots(nrow, ncol, figsize=(width_in * ncol, (width_in / aspect + 0.4) * nrow), dpi=100,
                                 squeeze=False)
        for ax in axes.ravel():
            ax.set_axis_off()
        for ax, (i, image, mask, scale) in zip(axes.ravel(), group):
            ax.imshow(overlay_rgb(image, mask), interpolation="nearest")
            label = "" if image.mask is None else " / labels (magenta)"
            ax.set_title(f"image {i}: predicted (cyan){label}\nGSD scale x{scale:.3g}", fontsize=7)
        return fig

    def save(fig, target: Path) -> None:
        fig.savefig(target, format="png", dpi=100, bbox_inches="tight")
        plt.close(fig)

    with atomic_path(path, overwrite=overwrite) as tmp:
        if str(path).lower().endswith(".png"):
            save(figure(panels), tmp)
        else:
            tmp.mkdir(parents=True)
            for panel in panels:
                save(figure([panel]), tmp / f"overlay_{panel[0]:04d}.png")
