"""``metraw compress``: codec bits/pixel and compression ratio per CFA channel on a store.

Every image of the store is encoded with `metraw.codec.encode` (step in noise sigmas, seeded
dither) as a whole, as the zarr codec stores it (compact header, the profile lives in the array
metadata: ``bits_per_pixel`` and ``ratio`` vs 16-bit storage), and
each CFA colour plane on its own, as a mono raw with the same noise model, for the per-channel
numbers. The median photoelectrons per pixel of each image are reported too (the compressed
size follows the signal level; `metraw aggregate` takes the nominal point's scene spread from it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.image import RawImage

BITS_RAW = 16


def register(sub) -> None:
    p = sub.add_parser("compress", help="codec bits/pixel and ratio per CFA channel on an emulated store",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("store", help="metraw store (.zarr)")
    p.add_argument("--out", required=True, help="output JSON (compression.json)")
    p.add_argument("--step", type=float, default=1.0, help="quantisation step in noise sigmas (default 1.0)")
    p.add_argument("--seed", type=int, default=0, help="dither seed (default 0)")
    p.add_argument("--limit", type=int, default=None, help="only the first N images")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def channel_images(image: RawImage) -> dict[str, RawImage]:
    """Each CFA colour plane as a mono RawImage (same noise model; planes of one colour concatenated
    side by side, e.g. the two green planes of a Bayer pattern)."""
    from metraw.cfa import plane_offsets, split_planes

    p = image.profile
    if p.is_mono:
        return {"L": image}
    groups: dict[str, list[np.ndarray]] = {}
    for (colour, _, _), plane in zip(plane_offsets(p.cfa_pattern), split_planes(image.data, p.cfa_pattern)):
        groups.setdefault(colour, []).append(np.ascontiguousarray(plane))
    out = {}
    for colour, planes in groups.items():
        h = min(pl.shape[0] for pl in planes)
        data = np.concatenate([pl[:h] for pl in planes], axis=1)
        prof = p.replace(cfa_pattern="mono", qe_per_channel={"L": p.qe_per_channel.get(colour, 1.0)},
                         band_edges_m={"L": p.band_edges_m.get(colour, (0.0, 0.0))})
        out[colour] = RawImage(data=data, profile=prof)
    return out


def measure_image(image: RawImage, step: float, seed: int, encode: Callable[..., bytes]) -> dict[str, Any]:
    """bits/pixel and ratio of the whole image and of each channel, and the median signal [e-]."""
    whole = len(encode(image, step=step, seed=seed, embed_profile=False))
    n = image.data.size
    rec: dict[str, Any] = {"bytes": whole, "pixels": n, "bits_per_pixel": 8 * whole / n,
                           "ratio": BITS_RAW * n / (8 * whole), "channels": {}}
    for colour, sub in channel_images(image).items():
        b = len(encode(sub, step=step, seed=seed, embed_profile=False))
        rec["channels"][colour] = {"bytes": b, "pixels": sub.data.size, "bits_per_pixel": 8 * b / sub.data.size,
                                   "ratio": BITS_RAW * sub.data.size / (8 * b)}
    e = image.electrons()[~image.saturated()]
    rec["signal_median_e"] = float(np.median(e)) if e.size else None
    return rec


def summarise(images: list[dict[str, Any]], step: float, seed: int) -> dict[str, Any]:
    tot_b = sum(r["bytes"] for r in images)
    tot_n = sum(r["pixels"] for r in images)
    channels = {}
    for c in images[0]["channels"]:
        b = sum(r["channels"][c]["bytes"] for r in images)
        n = sum(r["channels"][c]["pixels"] for r in images)
        channels[c] = {"bits_per_pixel": 8 * b / n, "ratio": BITS_RAW * n / (8 * b)}
    sig = np.array([r["signal_median_e"] for r in images if r["signal_median_e"] is not None], dtype=np.float64)
    return {"codec": "metraw.codec", "step": step, "seed": seed, "n_images": len(images), "bits_raw": BITS_RAW,
            "overall": {"bits_per_pixel": 8 * tot_b / tot_n, "ratio": BITS_RAW * tot_n / (8 * tot_b)},
            "channels": channels,
            "signal_e": None if not sig.size else {"median": float(np.median(sig)),
                                                    "p05": float(np.percentile(sig, 5)),
                                                    "p95": float(np.percentile(sig, 95))},
            "images": images}


def run(args) -> int:
    from metraw.codec import encode
    from metraw.progress import progress_bar
    from metraw.store import RawStore

    if not (math.isfinite(args.step) and args.step > 0):
        raise MetrawError(f"--step must be a positive number of sigmas, got {args.step}")
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise MetrawError(f"output {out} already exists (use --overwrite to replace it)")
    store = RawStore.open(args.store)
    n = len(store) if args.limit is None else min(len(store), args.limit)
    if n == 0:
        raise MetrawError(f"store {args.store} holds no images")
    import warnings

    images = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for i in progress_bar(range(n), desc="compress"):
            rec = measure_image(store[i], args.step, args.seed, encode)
            images.append({"index": i, **rec})
    result = summarise(images, args.step, args.seed)
    result["store"] = str(args.store)
    result["warnings"] = sorted({str(w.message) for w in caught})
    with atomic_path(out, overwrite=args.overwrite) as tmp:
        tmp.write_text(json.dumps(result, indent=1) + "\n")
    ch = ", ".join(f"{c} {v['bits_per_pixel']:.2f} b/px (x{v['ratio']:.2f})" for c, v in result["channels"].items())
    print(f"compress: {n} images, {result['overall']['bits_per_pixel']:.3f} bits/pixel, ratio "
          f"{result['overall']['ratio']:.2f} vs 16 bit; per channel: {ch}")
    return 0
