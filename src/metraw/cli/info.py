"""``metraw info PATH``: what a raw file or a metraw store holds (pattern, levels, bits, noise model)."""

from __future__ import annotations

import json
import math
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("info", help="describe a raw image file or a metraw zarr store",
                              description="Print CFA pattern, black/white level, bit depth, shape, gain and "
                                          "read noise (or 'unknown') and the approximate flag.")
    p.add_argument("path", help="image file (DNG, raw TIFF, GeoTIFF, PNG/JPEG + labels, metraw TIFF) or STORE.zarr")
    p.add_argument("--json", action="store_true", help="print a JSON object instead of text")
    p.add_argument("--all", action="store_true", help="for a store: list every image (default: first 10)")
    p.set_defaults(func=run)


def _value(profile, name: str, unit: str) -> str:
    u = profile.uncertainty.get(name)
    if u is not None and not math.isfinite(u):
        return "unknown (not in the file; fill with `metraw calibrate` or --camera)"
    text = f"{getattr(profile, name):g} {unit}"
    return text + (f" +- {u:.3g}" if u is not None else "")


def describe(image) -> dict:
    p = image.profile
    out = {"shape_hw": list(image.shape), "cfa_pattern": p.cfa_pattern,
           "black_level_dn": _value(p, "black_level_dn", "DN"), "white_level_dn": f"{p.white_level_dn:g} DN",
           "adc_bits": p.adc_bits, "gain_dn_per_e": _value(p, "gain_dn_per_e", "DN/e-"),
           "read_noise_e": _value(p, "read_noise_e", "e-"), "camera": p.camera,
           "approximate": f"yes: {p.approximate_reason}" if p.approximate else "no",
           "range_dn": f"{int(image.data.min())} .. {int(image.data.max())}"}
    if p.gsd_m is not None:
        out["gsd_m"] = f"{p.gsd_m:.4g}"
    elif image.meta.get("gsd_m") is not None:
        out["gsd_m"] = f"{image.meta['gsd_m']} (from file metadata)"
    if p.exposure_s:
        out["exposure_s"] = f"{p.exposure_s:g}"
    if image.mask is not None:
        out["mask"] = f"car fraction {float(image.mask.mean()):.4f} ({image.meta.get('mask_kind', 'mask')})"
        if "car_boxes" in image.meta:
            out["car_boxes"] = image.meta["car_boxes"]
    if image.provenance:
        out["provenance"] = ", ".join(step["function"] + (f"({step['params']['shift']})" if "shift" in step["params"]
                                                          else "") for step in image.provenance)
    for key in ("format", "black_level_source", "stored_scale", "BandName"):
        if key in image.meta:
            out[key] = image.meta[key]
    return out


def run(args) -> int:
    from metraw.errors import MetrawError

    path = Path(args.path)
    from metraw.io.store import RawStore

    if RawStore.is_store(path):
        store = RawStore.open(path)
        n = len(store)
        shapes = [store.shape(i) for i in range(n)]
        approx = sum(store.profile(i).approximate for i in range(n))
        head = {"store": str(path), "images": n, "distinct_shapes": sorted({tuple(s) for s in shapes}),
                "approximate_images": approx,
                "labelled_images": sum("labels" in store.meta(i) for i in range(n))}
        shown = range(n) if args.all else range(min(n, 10))
        rows = [{"index": i, **describe(store[i])} for i in shown]
        if args.json:
            print(json.dumps({**head, "images_info": rows}, default=str, indent=1))
            return 0
        for k, v in head.items():
            print(f"{k}: {v}")
        for row in rows:
            print("  " + "; ".join(f"{k}={v}" for k, v in row.items() if k not in ("approximate",))
                  + ("; approximate=yes" if row["approximate"] != "no" else "; approximate=no"))
        if len(rows) < n:
            print(f"  ... {n - len(rows)} more (use --all)")
        return 0
    if path.is_dir():
        raise MetrawError(f"{path}: a directory that is not a metraw zarr store")
    from metraw.io import read_raw

    info = {"file": str(path), **describe(read_raw(path))}
    if args.json:
        print(json.dumps(info, default=str, indent=1))
    else:
        width = max(len(k) for k in info)
        for k, v in info.items():
            print(f"{k:<{width}}  {v}")
    return 0
