"""``metraw calibrate``: measure gain and read noise per CFA channel, write the profile JSON.

    metraw calibrate IMAGE [--out profile.json]                 single-frame fit (from_image)
    metraw calibrate [IMAGE] --darks D1 D2 .. --flats F1 F2 ..  photon transfer (from_series)

Flats are listed level by level: each consecutive group of ``--frames-per-level`` files
(default 2) is one illumination level. IMAGE, when given with a series, supplies the
geometry the profile keeps. The profile is written atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from metraw.atomic import atomic_path
from metraw.errors import MetrawError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("calibrate", help="measure gain K and read noise (single frame or photon transfer)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", nargs="?", help="raw image file (single-frame fit, or geometry for a series)")
    p.add_argument("--darks", nargs="+", default=[], metavar="DARK", help=">= 2 dark frames")
    p.add_argument("--flats", nargs="+", default=[], metavar="FLAT", help="flat frames, level by level")
    p.add_argument("--frames-per-level", type=int, default=2, help="flat frames per illumination level (>= 2)")
    p.add_argument("--out", type=Path, help="write the calibrated profile JSON here")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run)


def check_fittable(image, name, black_level_dn: float | None = None) -> None:
    """Refuse, saying what is wrong, a frame a single-frame noise fit cannot use at all: every pixel
    saturated, or no pixel above the black level (``black_level_dn``, default the profile's)."""
    p = image.profile
    black = p.black_level_dn if black_level_dn is None else black_level_dn
    sat = image.saturated()
    if sat.all():
        raise MetrawError(f"{name}: all {sat.size} pixels are saturated (>= white level {p.white_level_dn:g} DN): "
                          "the frame cannot constrain a noise fit")
    if not (image.data[~sat] > black).any():
        raise MetrawError(f"{name}: no pixel above the black level {black:g} DN (an all-black frame): "
                          "the frame cannot constrain a noise fit")


def run(args: argparse.Namespace) -> int:
    from metraw.io import read_raw
    from metraw.progress import progress_bar

    if args.out is not None and args.out.exists() and not args.overwrite:
        raise MetrawError(f"output {args.out} already exists (use --overwrite to replace it)")
    if args.flats or args.darks:
        if not (args.flats and args.darks):
            raise MetrawError("a photon-transfer series needs both --flats and --darks")
        n = args.frames_per_level
        if n < 2 or len(args.flats) % n:
            raise MetrawError(f"--flats gives {len(args.flats)} files, not a whole number of levels of "
                              f"--frames-per-level {n} (>= 2)")
        base = read_raw(args.input).profile if args.input else None
        frames = [read_raw(f) for f in progress_bar(args.flats + args.darks, desc="reading")]
        from metraw import calibrate  # scipy: imported once the inputs are read

        flats, darks = frames[: len(args.flats)], frames[len(args.flats):]
        levels = [flats[i:i + n] for i in range(0, len(flats), n)]
        result = calibrate.from_series(levels, darks, profile=base)
        print(f"photon transfer (EMVA 1288): {len(levels)} levels x {n} frames, {len(darks)} darks")
    else:
        if not args.input:
            raise MetrawError("give an INPUT image, or --flats and --darks")
        image = read_raw(args.input)
        check_fittable(image, args.input)
        from metraw import calibrate

        result = calibrate.from_image(image)
        print(f"single-frame fit (one image, Poisson-Gaussian on smooth regions): {args.input}")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"  {'ch':<3}{'K [DN/e-]':>22}{'read noise [e-]':>22}{'black [DN]':>20}{'points':>8}{'chi2':>7}")
    for ch in result.channels.values():
        print(f"  {ch.channel:<3}{ch.gain_dn_per_e:>12.4f} +- {ch.gain_dn_per_e_u:<6.4f}"
              f"{ch.read_noise_e:>12.3f} +- {ch.read_noise_e_u:<6.3f}"
              f"{ch.black_level_dn:>11.2f} +- {ch.black_level_dn_u:<5.2f}{ch.n_points:>8d}{ch.chi2_red:>7.2f}")
    prof = result.profile
    unc = prof.uncertainty
    print(f"  profile: K = {prof.gain_dn_per_e:.4f} +- {unc['gain_dn_per_e']:.4f} DN/e-, "
          f"read noise = {prof.read_noise_e:.3f} +- {unc['read_noise_e']:.3f} e-")
    if args.out is not None:
        with atomic_path(args.out, overwrite=args.overwrite) as tmp:
            tmp.write_text(prof.to_json() + "\n")
        print(f"  wrote {args.out}")
    return 0
