"""Single-frame noise fit (metraw.calibrate.from_image) on the embedded synthetic drone scenes.

    nice -n 5 python benchmarks/noise_fit.py [--n 32] [--size 1024] [--seed 0] [--cache DIR]

Each scene ``metraw.scenes.generate_one(i, seed, size)`` carries its exact truth in its profile
(K = 0.25 DN/e-, read noise 3 e- for the default camera). Per image: the fitted gain and read
noise with their stated 1-sigma uncertainty and z = (fit - truth) / uncertainty, or the reason
the fit refused. Summary per quantity: share of fitted images with |z| <= 2 (95 % expected for
an honest Gaussian uncertainty), median |z| (0.67 expected), and the refused count.
``--cache DIR`` keeps the generated raw data as .npy files (generation dominates the run time).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from metraw.calibrate import from_image
from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.scenes import KINDS, generate_one, scene_camera


def scene(i: int, seed: int, size: int, cache: Path | None) -> RawImage:
    if cache is None:
        return generate_one(i, seed, size)
    path = cache / f"scene_s{seed}_n{size}_i{i}.npy"
    prof_path = path.with_suffix(".json")
    if path.exists() and prof_path.exists():
        from metraw.raw.profile import CalibrationProfile
        return RawImage(np.load(path), CalibrationProfile.from_json(prof_path.read_text()))
    img = generate_one(i, seed, size)
    cache.mkdir(parents=True, exist_ok=True)
    np.save(path, img.data)
    prof_path.write_text(img.profile.to_json())
    return img


def summary(zs: list[float]) -> str:
    if not zs:
        return "no fits"
    a = np.abs(np.asarray(zs))
    return f"|z|<=2: {np.mean(a <= 2):5.1%}  median |z|: {np.median(a):5.2f}  max |z|: {a.max():6.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32, help="number of scenes (indices 0..n-1)")
    ap.add_argument("--size", type=int, default=1024, help="scene side in pixels")
    ap.add_argument("--seed", type=int, default=0, help="dataset seed")
    ap.add_argument("--cache", type=Path, default=None, help="folder to keep generated scenes in")
    args = ap.parse_args(argv)
    cam = scene_camera()
    print(f"{args.n} embedded scenes of {args.size} px, seed {args.seed}; truth K = {cam.gain_dn_per_e} DN/e-, "
          f"read noise = {cam.read_noise_e} e-")
    print(f"{'i':>3} {'kind':<9}{'K':>8} {'+-':>7} {'z_K':>7}{'RN':>8} {'+-':>7} {'z_RN':>7}  note")
    zk, zr, refused = [], [], 0
    t0 = time.perf_counter()
    fit_s = 0.0
    for i in range(args.n):
        img = scene(i, args.seed, args.size, args.cache)
        truth = img.profile
        kind = KINDS[i % len(KINDS)]  # generate_one's default kinds
        t = time.perf_counter()
        try:
            res = from_image(img)
        except MetrawError as exc:
            fit_s += time.perf_counter() - t
            refused += 1
            print(f"{i:>3} {kind:<9}{'refused':>8}  {str(exc)[:110]}")
            continue
        fit_s += time.perf_counter() - t
        p = res.profile
        uk, ur = p.uncertainty["gain_dn_per_e"], p.uncertainty["read_noise_e"]
        z1 = (p.gain_dn_per_e - truth.gain_dn_per_e) / uk
        z2 = (p.read_noise_e - truth.read_noise_e) / ur
        zk.append(z1)
        zr.append(z2)
        print(f"{i:>3} {kind:<9}{p.gain_dn_per_e:8.4f} {uk:7.4f} {z1:7.2f}{p.read_noise_e:8.3f} {ur:7.3f} {z2:7.2f}")
    n_fit = len(zk)
    print(f"fitted {n_fit} of {args.n} ({n_fit / max(args.n, 1):.0%}), refused {refused}; "
          f"fit time {fit_s / max(args.n, 1):.2f} s/image, total {time.perf_counter() - t0:.0f} s")
    print(f"gain       {summary(zk)}")
    print(f"read noise {summary(zr)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
