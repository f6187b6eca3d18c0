"""Calibration accuracy: synthetic 20 MP frames with known K and read noise, and the real data.

    nice -n 5 python benchmarks/calibration.py [--small]

Synthetic truth: 5472 x 3648 RGGB, K = 0.3 DN/e-, read noise 5 e-, black 2048, 14-bit,
full well 40000 e- (made with metraw.raw.sensor). from_series: 12 flat levels x 2 frames + 2
darks, 1 % PRNU (must cancel). from_image: one frame of a scene with smooth gradients, sharp
edges and textured patches. Acceptance: series |dK| < 1 %, |d sigma_d| < 3 %; image 3 % / 10 %.
Real data (data/real of the repository; SOURCE.txt in each folder): Canon 550D DNG (canon_dng) and
MicaSense RedEdge frames (micasense), single-frame fit per channel via metraw.io.read_raw.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from metraw import calibrate
from metraw.calibrate.targets import flat_series, natural_scene_e
from metraw.errors import MetrawError
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
K, RN = 0.3, 5.0


def row(name, res, seconds, truth=True):
    p = res.profile
    uk, ur = p.uncertainty["gain_dn_per_e"], p.uncertainty["read_noise_e"]
    if truth:
        dk, dr = 100 * (p.gain_dn_per_e / K - 1), 100 * (p.read_noise_e / RN - 1)
        print(f"{name:<28}{p.gain_dn_per_e:9.4f} +- {uk:.4f} ({dk:+6.2f} %){p.read_noise_e:9.3f} +- {ur:.3f} "
              f"({dr:+6.2f} %){seconds:8.1f} s")
        return abs(dk), abs(dr)
    print(f"{name:<28}{p.gain_dn_per_e:9.4f} +- {uk:.4f}{p.read_noise_e:11.3f} +- {ur:.3f}   {seconds:6.1f} s")


def main() -> int:
    small = "--small" in sys.argv
    shape = (912, 1368) if small else (3648, 5472)
    prof = CalibrationProfile(gain_dn_per_e=K, black_level_dn=2048, read_noise_e=RN, white_level_dn=16383,
                              adc_bits=14, cfa_pattern="RGGB", full_well_e=40000)
    print(f"synthetic truth: {shape[1]} x {shape[0]} RGGB, K = {K} DN/e-, read noise = {RN} e-")
    print(f"{'method':<28}{'K [DN/e-]':>28}{'read noise [e-]':>30}{'time':>10}")
    t = time.perf_counter()
    series_shape = shape
    flats, darks = flat_series(prof, series_shape, np.linspace(200, 46000, 12), seed=11, prnu=0.01)
    res = calibrate.from_series(flats, darks, cfa_pattern="RGGB", white_level_dn=16383)
    ds = row(f"from_series {series_shape[1]}x{series_shape[0]}", res, time.perf_counter() - t)
    del flats, darks
    results = {"series": ds}
    for seed in (1, 2):
        scene = natural_scene_e(shape, 30000, seed=seed)
        img = expose(scene, prof, rng_from_seed(100 + seed))
        del scene
        t = time.perf_counter()
        res = calibrate.from_image(img, black_level_dn=2048, cfa_pattern="RGGB", white_level_dn=16383)
        results[f"image{seed}"] = row(f"from_image scene seed {seed}", res, time.perf_counter() - t)
        for ch in res.channels.values():
            print(f"    {ch.channel}: K {ch.gain_dn_per_e:.4f} +- {ch.gain_dn_per_e_u:.4f}, read noise "
                  f"{ch.read_noise_e:.3f} +- {ch.read_noise_e_u:.3f}, {ch.n_points} blocks, chi2 {ch.chi2_red:.2f}")
        del img
    ok_series = ds[0] < 1 and ds[1] < 3
    ok_image = all(results[k][0] < 3 and results[k][1] < 10 for k in results if k.startswith("image"))
    print(f"acceptance: from_series (<1 % K, <3 % read noise): {'met' if ok_series else 'NOT met'}; "
          f"from_image (<3 % K, <10 % read noise): {'met' if ok_image else 'NOT met'}")

    from metraw.io import read_raw

    print("\nreal data, single-frame fit (from_image) per channel:")
    files = [REAL / "canon_dng" / "colorchart.dng"] + sorted((REAL / "micasense").glob("*.tif"))
    for f in files:
        img = read_raw(f)
        t = time.perf_counter()
        try:
            res = calibrate.from_image(img)
        except MetrawError as exc:
            print(f"{f.parent.name}/{f.name}: refused: {exc}")
            continue
        dt = time.perf_counter() - t
        print(f"{f.parent.name}/{f.name} (black {img.profile.black_level_dn:.2f} DN, {img.profile.adc_bits}-bit, "
              f"{dt:.1f} s)")
        for ch in res.channels.values():
            print(f"    {ch.channel}: K {ch.gain_dn_per_e:.4f} +- {ch.gain_dn_per_e_u:.4f} DN/e-, read noise "
                  f"{ch.read_noise_e:.3f} +- {ch.read_noise_e_u:.3f} e-, {ch.n_points} blocks, "
                  f"mu-black {ch.signal_range_dn[0]:.0f}..{ch.signal_range_dn[1]:.0f} DN, chi2 {ch.chi2_red:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
