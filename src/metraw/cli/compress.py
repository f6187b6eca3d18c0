"""``metraw compress``: codec bits/pixel and compression ratio per CFA channel on a store.

Every image of the store is encoded with `metraw.codec.encode` (step in noise sigmas, seeded
dither) as a whole, as the zarr codec stores it (compact header, the profile lives in the array
metadata: ``bits_per_pixel`` and ``ratio`` vs 16-bit storage). The per-channel numbers come
from the same blob: each CFA colour's code length under the rANS tables actually used (sum of
-log2 p over its symbols, which rANS attains to within its final state) plus its share of the
side information (its own predictor and tables; shared overhead in proportion), so the channel
bits add up exactly to the blob's bits. The median photoelectrons per pixel of each image are
reported too (the compressed size follows the signal level; `metraw aggregate` takes the
nominal point's scene spread from it). When the store's raw array is itself stored with the
codec (``metraw emulate --codec-step``), its pixels are already quantised; ``stored`` then gives
the bytes of the raw array's chunks on disk (read from the shard indexes; the indexes themselves
are reported apart).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.raw.image import RawImage

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


def measure_image(image: RawImage, step: float, seed: int, encode: Callable[..., bytes]) -> dict[str, Any]:
    """bits/pixel and ratio of the whole image and of each channel (exact attribution of the whole
    blob's bits, see the module docstring), and the median signal [e-]."""
    account: dict[str, Any] = {}
    whole = len(encode(image, step=step, seed=seed, embed_profile=False, account=account))
    n = image.data.size
    rec: dict[str, Any] = {"bytes": whole, "pixels": n, "bits_per_pixel": 8 * whole / n,
                           "ratio": BITS_RAW * n / (8 * whole), "channels": {}}
    for colour, bits in account["bits"].items():
        npx = account["pixels"][colour]
        if npx == 0:
            continue
        rec["channels"][colour] = {"bits": bits, "pixels": npx, "bits_per_pixel": bits / npx,
                                   "ratio": BITS_RAW * npx / bits}
    e = image.electrons()[~image.saturated()]
    rec["signal_median_e"] = float(np.median(e)) if e.size else None
    return rec


def summarise(images: list[dict[str, Any]], step: float, seed: int) -> dict[str, Any]:
    tot_b = sum(r["bytes"] for r in images)
    tot_n = sum(r["pixels"] for r in images)
    channels = {}
    for c in dict.fromkeys(k for r in images for k in r["channels"]):
        b = sum(r["channels"][c]["bits"] for r in images if c in r["channels"])
        n = sum(r["channels"][c]["pixels"] for r in images if c in r["channels"])
        channels[c] = {"bits_per_pixel": b / n, "ratio": BITS_RAW * n / b}
    sig = np.array([r["signal_median_e"] for r in images if r["signal_median_e"] is not None], dtype=np.float64)
    return {"codec": "metraw.codec", "step": step, "seed": seed, "n_images": len(images), "bits_raw": BITS_RAW,
            "overall": {"bits_per_pixel": 8 * tot_b / tot_n, "ratio": BITS_RAW * tot_n / (8 * tot_b)},
            "channels": channels,
            "signal_e": None if not sig.size else {"median": float(np.median(sig)),
                                                    "p05": float(np.percentile(sig, 5)),
                                                    "p95": float(np.percentile(sig, 95))},
            "images": images}


def stored_raw(store, n: int) -> dict[str, Any]:
    """How the store holds its raw array: the codec record (``raw_codec`` attribute; None = lossless
    zstd) and the bytes of its image chunks on disk, read from the shard indexes (the indexes
    themselves, 16 bytes per chunk slot, are excluded and reported apart), per true pixel over
    all images (images smaller than the array are zero-padded)."""
    import zarr

    from metraw.io.store import read_shard_index

    arr = zarr.open_group(str(store.path), mode="r")["raw"]
    per_shard = int(arr.shards[0]) if arr.shards else 1
    chunk_bytes = index_bytes = 0
    for f in sorted((Path(store.path) / "raw" / "c").rglob("*")):
        if not f.is_file():
            continue
        idx = read_shard_index(f, per_shard)
        used = idx[:, 0] != np.uint64(2**64 - 1)
        chunk_bytes += int(idx[used, 1].sum())
        index_bytes += 16 * per_shard + 4  # (offset, nbytes) uint64 per chunk + CRC-32C, at the end
    pixels = sum(int(np.prod(store.shape(i))) for i in range(len(store)))
    return {"raw_codec": store.attrs.get("raw_codec"), "chunk_bytes": chunk_bytes, "shard_index_bytes": index_bytes,
            "pixels": pixels, "bits_per_pixel": 8 * chunk_bytes / pixels if pixels else None,
            "all_images": n == len(store)}


def run(args) -> int:
    from metraw.codec import encode
    from metraw.io.store import RawStore
    from metraw.progress import progress_bar

    if not (math.isfinite(args.step) and args.step > 0):
        raise MetrawError(f"--step must be a positive number of sigmas, got {args.step}")
    if args.limit is not None and args.limit < 1:
        raise MetrawError(f"--limit must be >= 1, got {args.limit}")
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
    result["channel_attribution"] = ("code length of each colour's symbols under the coder's tables + share of "
                                     "side information; channel bits sum to the blob's bits")
    result["stored"] = stored_raw(store, n)
    result["warnings"] = sorted({str(w.message) for w in caught})
    with atomic_path(out, overwrite=args.overwrite) as tmp:
        tmp.write_text(json.dumps(result, indent=1) + "\n")
    ch = ", ".join(f"{c} {v['bits_per_pixel']:.2f} b/px (x{v['ratio']:.2f})" for c, v in result["channels"].items())
    print(f"compress: {n} images, {result['overall']['bits_per_pixel']:.3f} bits/pixel, ratio "
          f"{result['overall']['ratio']:.2f} vs 16 bit; per channel: {ch}")
    return 0
