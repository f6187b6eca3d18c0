"""Issue #17: compression ratio per colour channel against exposure, extended until smear dominates.

    python benchmarks/compression_exposure.py --source data/source.zarr [--params params.yaml] [--scenes 48]
        [--exposures-us 50,100,180,300,500,800,1200,2000] [--out docs/figures]

Every scene of the first ``--scenes`` of the source is emulated at the nominal point of params.yaml with
only the exposure changed, twice: with the orbit's ground speed (motion smear v t along track) and with
the ground speed set to 0 (no smear: the signal grows, nothing blurs). Each image is compressed as
``metraw compress`` does (`metraw.cli.compress.measure_image`, ``codec.step`` of params.yaml) and the
per-channel ratio (16 bit / bits per pixel) is averaged over the images with its standard error.
The same scenes and noise seeds are used at every exposure, so the change of the ratio from one exposure
to the next is measured per image (paired): ``step_change`` and its standard error ``step_change_se`` say
whether the curve turns. Writes ``compression_exposure.csv`` (one row per exposure, smear on/off, channel)
and ``compression_exposure.png`` into ``--out``. The codec's self-check warns that the pixels look noisier
than the profile at high signal: that is scene texture in its high-pass estimate, not noise; the warnings
are silenced here.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from metraw.atomic import atomic_path


def measure(source, target, n: int, step: float, seed: int) -> dict[str, list[float]]:
    from metraw.cli.compress import measure_image
    from metraw.codec import encode
    from metraw.emulate.emulator import emulate

    ratios: dict[str, list[float]] = {}
    for i in range(n):
        img = emulate(source[i], target, seed=(seed, i))
        rec = measure_image(img, step, seed, encode)
        for c, v in rec["channels"].items():
            ratios.setdefault(c, []).append(v["ratio"])
        ratios.setdefault("all", []).append(rec["ratio"])
        ratios.setdefault("signal_e", []).append(rec["signal_median_e"])
    return ratios


def main(argv: list[str] | None = None) -> int:
    from metraw.emulate.target import TargetSystem
    from metraw.io.store import RawStore
    from metraw.study.points import NOMINAL, load_params, target_params

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", required=True)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--scenes", type=int, default=48)
    ap.add_argument("--exposures-us", default="50,100,180,300,500,800,1200,2000,3000")
    ap.add_argument("--out", default="docs/figures")
    args = ap.parse_args(argv)
    params = load_params(args.params)
    source = RawStore.open(args.source)
    n = min(args.scenes, len(source))
    step, seed = float(params["codec"]["step"]), int(params["codec"].get("seed", 0))
    nominal = TargetSystem.from_dict(target_params(params, NOMINAL))
    from metraw.codec import ProfileMismatchWarning

    warnings.simplefilter("ignore", ProfileMismatchWarning)
    rows = []
    previous: dict[tuple[bool, str], np.ndarray] = {}
    for t_us in [float(v) for v in args.exposures_us.split(",")]:
        for smear in (True, False):
            target = nominal.replace(exposure_s=t_us / 1e6,
                                     ground_speed_m_per_s=nominal.ground_speed_m_per_s if smear else 0.0)
            t0 = time.perf_counter()
            ratios = measure(source, target, n, step, seed)
            signal = float(np.median(ratios.pop("signal_e")))
            for c, v in ratios.items():
                v = np.asarray(v)
                d = v - previous[(smear, c)] if (smear, c) in previous else None
                previous[(smear, c)] = v
                rows.append({"exposure_s": t_us / 1e6, "smear": smear, "smear_m": target.smear_m,
                             "smear_px": target.smear_m / target.gsd_m, "channel": c, "ratio": float(v.mean()),
                             "ratio_se": float(v.std(ddof=1) / math.sqrt(v.size)), "n_images": int(v.size),
                             "step_change": None if d is None else float(d.mean()),
                             "step_change_se": None if d is None else float(d.std(ddof=1) / math.sqrt(d.size)),
                             "signal_median_e": signal, "haze_e": target.haze_for("G")})
            change = rows[-1]["step_change"]  # the last channel is "all"
            print(f"t = {t_us:g} us, smear {'on ' if smear else 'off'} ({target.smear_m / target.gsd_m:.2f} px): "
                  f"ratio {np.mean(ratios['all']):.3f}"
                  + ("" if change is None else f", change {change:+.3f} +- {rows[-1]['step_change_se']:.3f}")
                  + f", median signal {signal:.0f} e- ({time.perf_counter() - t0:.1f} s)", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "compression_exposure.csv", overwrite=True) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    plot(rows, out / "compression_exposure.png")
    print(f"wrote {out / 'compression_exposure.csv'}, {out / 'compression_exposure.png'}")
    return 0


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metraw.spec.figures import CHANNEL_COLOURS

    fig, ax = plt.subplots(figsize=(5.6, 3.8), layout="constrained")
    for smear, style in ((True, "o-"), (False, "s--")):
        for c in sorted({r["channel"] for r in rows if r["channel"] != "all"}):
            sel = sorted((r for r in rows if r["smear"] is smear and r["channel"] == c), key=lambda r: r["exposure_s"])
            x = np.array([r["exposure_s"] * 1e6 for r in sel])
            y = np.array([r["ratio"] for r in sel])
            e = np.array([2 * r["ratio_se"] for r in sel])
            ax.errorbar(x, y, yerr=e, fmt=style, color=CHANNEL_COLOURS.get(c), ms=3.5, lw=1.1, capsize=2,
                        alpha=1.0 if smear else 0.55, label=f"{c}, {'smear v t' if smear else 'no smear'}")
    ax.set_xscale("log")
    ax.set_xlabel("exposure time [us]")
    ax.set_ylabel("compression ratio vs 16 bit (2 se)")
    ax.set_title("codec ratio per channel vs exposure (nominal payload)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6.5, ncol=2)
    with atomic_path(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
