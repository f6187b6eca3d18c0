"""``metraw calibrate``: measure gain and read noise per CFA channel, write the profile JSON.

    metraw calibrate IMAGE.. [--out profile.json]                single-frame fit (from_image), images combined
    metraw calibrate [IMAGE] --darks D1 D2 .. --flats F1 F2 ..  photon transfer (from_series)

Inputs, darks and flats are files or folders (their image files, sorted by name). Flats are listed
level by level: each consecutive group of ``--frames-per-level`` files (default 2) is one
illumination level. IMAGE, when given with a series, supplies the geometry the profile keeps;
``--camera`` (a profile JSON or a params.yaml with source.camera) supplies it otherwise: the written
profile is then that camera with the measured radiometry (gain, read noise, black level, and their
uncertainties). The profile (``--out``) and the whole result (``--report``) are written atomically.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from metraw.atomic import atomic_path
from metraw.errors import MetrawError

#: A flat frame with more than this fraction of its pixels at the white level counts as saturated.
SATURATED_FRACTION = 0.01
#: Relative difference of exposure times [s] above which darks do not match the flats (EMVA 1288: same time).
EXPOSURE_TOLERANCE = 0.01


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("calibrate", help="measure gain K and read noise (single frame or photon transfer)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="*", metavar="INPUT",
                   help="raw image files or folders (single-frame fit; or the geometry of a series)")
    p.add_argument("--darks", nargs="+", default=[], metavar="DARK", help=">= 2 dark frames (files or a folder)")
    p.add_argument("--flats", nargs="+", default=[], metavar="FLAT", help="flat frames, level by level (or a folder)")
    p.add_argument("--frames-per-level", type=int, default=2, help="flat frames per illumination level (>= 2)")
    p.add_argument("--camera", help="camera profile (JSON, or a params.yaml with source.camera) whose geometry and "
                                    "sensor data the written profile keeps beside the measured radiometry")
    p.add_argument("--profile", help="a measured camera profile JSON to use instead of measuring (its missing "
                                     "geometry from --camera); written to --out as the calibration")
    p.add_argument("--gsd-m", type=float, default=None,
                   help="ground sample distance of the images [m]: sets the profile's altitude (pitch x altitude / "
                        "focal length = GSD)")
    p.add_argument("--max-images", type=int, default=8,
                   help="single-frame fit: at most this many input images, spread over the list (default 8)")
    p.add_argument("--out", type=Path, help="write the calibrated profile JSON here")
    p.add_argument("--report", type=Path, help="write the whole result (method, per-channel fits, files) as JSON")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out / --report")
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


def _files(items: list[str]) -> list[Path]:
    from metraw.io import image_files

    return image_files(items) if items else []


def _camera_with_radiometry_of(profile, camera):
    """``camera`` with the radiometry the frames state (CFA pattern, white level, ADC bits, black level)."""
    if camera is None:
        return profile
    return camera.replace(cfa_pattern=profile.cfa_pattern, white_level_dn=profile.white_level_dn,
                          adc_bits=profile.adc_bits, black_level_dn=profile.black_level_dn,
                          uncertainty={k: v for k, v in camera.uncertainty.items()
                                       if k not in ("gain_dn_per_e", "read_noise_e", "black_level_dn")})


def check_series(flat_files: list[Path], flats: list, dark_files: list[Path], darks: list, per_level: int) -> None:
    """Refuse, naming the file, a series the photon transfer cannot use: fewer than 2 flat levels below
    saturation (a level counts as saturated when a frame has > 1 % of its pixels at the white level), or darks
    whose exposure time differs from the flats' (EMVA 1288 takes both at one exposure time)."""
    import numpy as np

    saturated = []
    for i in range(0, len(flats), per_level):
        fractions = [float(np.mean(f.saturated())) for f in flats[i:i + per_level]]
        worst = int(np.argmax(fractions))
        if fractions[worst] > SATURATED_FRACTION:
            saturated.append((flat_files[i + worst], fractions[worst]))
    usable = len(flats) // per_level - len(saturated)
    if usable < 2:
        name, frac = saturated[0]
        raise MetrawError(f"{name}: flat frame saturates ({frac:.0%} of its pixels at the white level "
                          f"{flats[0].profile.white_level_dn:g} DN); the photon transfer needs >= 2 levels below "
                          f"saturation and the series has {usable}")
    flat_t = {f.profile.exposure_s for f in flats if f.profile.exposure_s}
    if len(flat_t) == 1:
        t_flat = flat_t.pop()
        for name, dark in zip(dark_files, darks):
            t_dark = dark.profile.exposure_s
            if t_dark and abs(t_dark - t_flat) > EXPOSURE_TOLERANCE * t_flat:
                raise MetrawError(f"{name}: dark frame exposed {t_dark:g} s, the flats {t_flat:g} s; darks must "
                                  "have the flats' exposure time (EMVA 1288)")


def _finite(value):
    """``value`` with every non-finite float (a refused channel's NaN +- inf) as None: strict JSON."""
    import math

    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _at_gsd(profile, gsd_m: float | None):
    """``profile`` with the altitude at which its pixel pitch and focal length sample the ground at ``gsd_m``."""
    if gsd_m is None:
        return profile
    if not (gsd_m > 0 and profile.pixel_pitch_m and profile.focal_length_m):
        raise MetrawError(f"--gsd-m {gsd_m}: needs a positive value and a camera with pixel_pitch_m and "
                          "focal_length_m (give --camera)")
    return profile.replace(altitude_m=gsd_m * profile.focal_length_m / profile.pixel_pitch_m)


def _given_profile(args: argparse.Namespace, camera) -> int:
    """``--profile``: a measured profile (its geometry filled from ``camera`` where it has none) as the result."""
    from metraw.io import load_camera

    if args.flats or args.darks or args.inputs:
        raise MetrawError("--profile uses a measured profile: give no images, --flats or --darks with it")
    profile = load_camera(args.profile)
    if camera is not None:
        missing = {k: getattr(camera, k) for k in ("pixel_pitch_m", "focal_length_m", "aperture_diameter_m",
                                                    "altitude_m", "exposure_s") if getattr(profile, k) is None}
        profile = profile.replace(**missing)
    profile = _at_gsd(profile, args.gsd_m)
    unc = profile.uncertainty
    print(f"given profile {args.profile}: K = {profile.gain_dn_per_e:.4f} +- {unc.get('gain_dn_per_e', 0):.4f} DN/e-, "
          f"read noise = {profile.read_noise_e:.3f} +- {unc.get('read_noise_e', 0):.3f} e-")
    for path, text in ((args.out, profile.to_json() + "\n"),
                       (args.report, json.dumps({"method": "profile", "profile": profile.to_dict(),
                                                 "files": {"profile": [args.profile]}}, indent=2) + "\n")):
        if path is not None:
            with atomic_path(path, overwrite=args.overwrite) as tmp:
                tmp.write_text(text)
            print(f"  wrote {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    from metraw.io import load_camera, read_raw
    from metraw.progress import progress_bar

    for path in (args.out, args.report):
        if path is not None and path.exists() and not args.overwrite:
            raise MetrawError(f"output {path} already exists (use --overwrite to replace it)")
    camera = load_camera(args.camera) if args.camera else None
    if args.profile:
        return _given_profile(args, camera)
    inputs = _files(args.inputs)
    if args.flats or args.darks:
        if not (args.flats and args.darks):
            raise MetrawError("a photon-transfer series needs both --flats and --darks")
        n = args.frames_per_level
        flat_files, dark_files = _files(args.flats), _files(args.darks)
        if n < 2 or len(flat_files) % n:
            raise MetrawError(f"--flats gives {len(flat_files)} files, not a whole number of levels of "
                              f"--frames-per-level {n} (>= 2)")
        if len(dark_files) < 2:
            raise MetrawError(f"--darks gives {len(dark_files)} file(s); the photon transfer needs >= 2 dark frames")
        frames = [read_raw(f) for f in progress_bar(flat_files + dark_files, desc="reading")]
        flats, darks = frames[: len(flat_files)], frames[len(flat_files):]
        check_series(flat_files, flats, dark_files, darks, n)
        base = read_raw(inputs[0]).profile if inputs else None
        base = _camera_with_radiometry_of(base or flats[0].profile, camera) if (base or camera) else None
        from metraw import calibrate  # scipy: imported once the inputs are read

        levels = [flats[i:i + n] for i in range(0, len(flats), n)]
        result = calibrate.from_series(levels, darks, profile=base)
        used = {"flats": [str(f) for f in flat_files], "darks": [str(f) for f in dark_files]}
        print(f"photon transfer (EMVA 1288): {len(levels)} levels x {n} frames, {len(darks)} darks")
    else:
        if not inputs:
            raise MetrawError("give an INPUT image, or --flats and --darks")
        import numpy as np

        if len(inputs) > args.max_images:
            picks = np.unique(np.linspace(0, len(inputs) - 1, args.max_images).astype(int))
            inputs = [inputs[i] for i in picks]
        from metraw import calibrate

        results, fitted, refused = [], [], {}
        for f in progress_bar(inputs, desc="fitting"):
            image = read_raw(f, labels="none")
            check_fittable(image, f)
            profile = _camera_with_radiometry_of(image.profile, camera)
            try:
                results.append(calibrate.from_image(image, profile=profile))
                fitted.append(str(f))
            except MetrawError as exc:  # a frame too small or too textured: the others may still fit
                refused[str(f)] = str(exc)
        if not results:
            first = next(iter(refused))
            raise MetrawError(f"{first}: {refused[first]} (and every other image: none can be fitted)"
                              if len(refused) > 1 else f"{first}: {refused[first]}")
        result = calibrate.combine_images(results)
        for name, why in refused.items():
            result.notes.append(f"{name} not fitted: {why}")
        used = {"images": fitted, "refused": refused}
        print(f"single-frame fit (Poisson-Gaussian on smooth regions): {len(results)} of {len(inputs)} image(s)")
    for note in result.notes:
        print(f"  note: {note}")
    print(f"  {'ch':<3}{'K [DN/e-]':>22}{'read noise [e-]':>22}{'black [DN]':>20}{'points':>8}{'chi2':>7}")
    for ch in result.channels.values():
        print(f"  {ch.channel:<3}{ch.gain_dn_per_e:>12.4f} +- {ch.gain_dn_per_e_u:<6.4f}"
              f"{ch.read_noise_e:>12.3f} +- {ch.read_noise_e_u:<6.3f}"
              f"{ch.black_level_dn:>11.2f} +- {ch.black_level_dn_u:<5.2f}{ch.n_points:>8d}{ch.chi2_red:>7.2f}")
    prof = _at_gsd(result.profile, args.gsd_m)
    unc = prof.uncertainty
    print(f"  profile: K = {prof.gain_dn_per_e:.4f} +- {unc['gain_dn_per_e']:.4f} DN/e-, "
          f"read noise = {prof.read_noise_e:.3f} +- {unc['read_noise_e']:.3f} e-")
    if args.out is not None:
        with atomic_path(args.out, overwrite=args.overwrite) as tmp:
            tmp.write_text(prof.to_json() + "\n")
        print(f"  wrote {args.out}")
    if args.report is not None:
        with atomic_path(args.report, overwrite=args.overwrite) as tmp:
            tmp.write_text(json.dumps(_finite({**result.to_dict(), "profile": prof.to_dict(), "files": used}),
                                      indent=2) + "\n")
        print(f"  wrote {args.report}")
    return 0
