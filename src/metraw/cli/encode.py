"""``metraw encode INPUT OUTPUT [--step Q] [--seed S] [--profile P.json | --black B --cfa PATTERN]``."""

from __future__ import annotations

import sys
from pathlib import Path

from metraw.errors import MetrawError


def register(sub) -> None:
    p = sub.add_parser("encode", help="compress a raw image with the noise-preserving codec (.mraw)")
    p.add_argument("input", help="raw image (DNG/TIFF/... readable by metraw.io.read_raw)")
    p.add_argument("output", help="output .mraw file")
    p.add_argument("--step", type=float, default=1.0, help="quantisation step in noise sigmas (default 1)")
    p.add_argument("--seed", type=int, default=0, help="dither seed (default 0)")
    p.add_argument("--profile", help="calibration profile JSON (else: calibrated from the image)")
    p.add_argument("--black", type=float, help="black level [DN] for single-frame calibration")
    p.add_argument("--cfa", help="CFA pattern (RGGB, BGGR, GRBG, GBRG, mono)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run)


def load_or_calibrate(path: str, profile_path: str | None, black: float | None, cfa: str | None):
    """Read a raw image and give it a profile: from ``profile_path``, or calibrated from the image."""
    from metraw.io import read_raw
    from metraw.raw.cfa import validate_pattern
    from metraw.raw.image import RawImage
    from metraw.raw.profile import load_profile

    if not Path(path).is_file():
        raise MetrawError(f"input {path} does not exist")
    if cfa is not None:
        validate_pattern(cfa)
    prof = load_profile(profile_path) if profile_path else None
    image = read_raw(path)
    if prof is not None:
        return image.derive(image.data, prof, function="set_profile", params={"profile": str(profile_path)},
                            ), None
    from metraw.cli.calibrate import check_fittable

    check_fittable(image, path, black)
    from metraw.calibrate import from_image  # scipy: imported once the input is read

    kw = {}
    if black is not None:
        kw["black_level_dn"] = black
    if cfa is not None:
        kw["cfa_pattern"] = cfa
    res = from_image(image.data if kw else image, **kw, profile=None if kw else image.profile)
    data = image.data >> res.unused_low_bits if res.unused_low_bits else image.data
    return RawImage(data, res.profile, provenance=image.provenance, meta=image.meta), res


def run(args) -> int:
    from metraw.atomic import atomic_path

    if Path(args.output).exists() and not args.overwrite:
        raise MetrawError(f"output {args.output} already exists (use --overwrite to replace it)")
    image, res = load_or_calibrate(args.input, args.profile, args.black, args.cfa)
    from metraw import codec  # numba: imported once the input is read
    if res is not None:
        p = res.profile
        print(f"metraw encode: no profile given: calibrated from the image (K = {p.gain_dn_per_e:.4g} DN/e-, "
              f"read noise {p.read_noise_e:.3g} e-, black {p.black_level_dn:g} DN)", file=sys.stderr)
    blob = codec.encode(image, step=args.step, seed=args.seed)
    with atomic_path(args.output, overwrite=args.overwrite) as tmp:
        tmp.write_bytes(blob)
    bpp = 8 * len(blob) / image.data.size
    print(f"{args.output}: {len(blob)} bytes, {bpp:.3f} bits/pixel, step {args.step} sigma")
    return 0
