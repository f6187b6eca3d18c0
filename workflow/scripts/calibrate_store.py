"""Snakemake script: single-frame noise calibration of source images vs. their stored profile.

For up to ``MAX_IMAGES`` images spread over the store, fit gain and read noise with
``metraw.calibrate.from_image`` and compare with the profile the image carries (z-scores
with the fit's standard uncertainty). The result is written as JSON; a profile that the
pixels contradict (|z| > 5 on the gain) is reported, not silently accepted. Besides the
largest gain z, the JSON holds the z distribution per quantity (``z_summary``: the list of z,
the share with |z| <= 2 - about 95 % for an honest uncertainty - the median |z| - about 0.67 -
and the counts of fitted and refused images): one image within the limit says little.
"""

import json
import math

import numpy as np

from metraw import progress
from metraw.calibrate import from_image
from metraw.errors import MetrawError
from metraw.io.store import RawStore

MAX_IMAGES = 8
Z_LIMIT = 5.0
#: |z| below which a fit agrees with its profile at ~95 % for an honest Gaussian uncertainty.
Z_HONEST = 2.0


def z_summary(zs: list[float], refused: int) -> dict:
    """Distribution of the z-scores of one quantity over the fitted images."""
    finite = [z for z in zs if z is not None and math.isfinite(z)]
    a = np.abs(np.asarray(finite, dtype=float))
    return {
        "z": [float(z) for z in finite],
        "fraction_abs_z_le_2": float(np.mean(a <= Z_HONEST)) if a.size else None,
        "median_abs_z": float(np.median(a)) if a.size else None,
        "max_abs_z": float(a.max()) if a.size else None,
        "fitted": len(finite),
        "refused": int(refused),
    }


def calibrate_store(store_path: str) -> dict:
    store = RawStore.open(store_path)
    indices = np.unique(np.linspace(0, len(store) - 1, min(MAX_IMAGES, len(store))).astype(int))
    rows = []
    for i in indices:
        image = store[int(i)]
        claimed = image.profile
        row = {"index": int(i), "claimed_gain_dn_per_e": claimed.gain_dn_per_e,
               "claimed_read_noise_e": claimed.read_noise_e, "approximate": claimed.approximate}
        try:
            result = from_image(image)
        except MetrawError as exc:
            row["refused"] = str(exc)
            rows.append(row)
            continue
        fit = result.profile
        k_u = fit.uncertainty.get("gain_dn_per_e", float("nan"))
        rn_u = fit.uncertainty.get("read_noise_e", float("nan"))
        row.update({
            "gain_dn_per_e": fit.gain_dn_per_e, "gain_uncertainty": k_u,
            "read_noise_e": fit.read_noise_e, "read_noise_uncertainty": rn_u,
            "gain_z": (fit.gain_dn_per_e - claimed.gain_dn_per_e) / k_u,
            "read_noise_z": (fit.read_noise_e - claimed.read_noise_e) / rn_u,
        })
        rows.append(row)
    fitted = [r for r in rows if "gain_z" in r]
    refused = len(rows) - len(fitted)
    return {
        "store": store_path,
        "images_checked": len(rows),
        "images_fitted": len(fitted),
        "images_refused": refused,
        "max_abs_gain_z": max((abs(r["gain_z"]) for r in fitted), default=None),
        # None: no image could be fitted, so the pixels neither confirm nor contradict the profile
        "profile_consistent": all(abs(r["gain_z"]) <= Z_LIMIT for r in fitted) if fitted else None,
        "z_limit": Z_LIMIT,
        "z_summary": {
            "gain_dn_per_e": z_summary([r["gain_z"] for r in fitted], refused),
            "read_noise_e": z_summary([r["read_noise_z"] for r in fitted], refused),
        },
        "images": rows,
    }


if "snakemake" in globals():
    report = calibrate_store(snakemake.input[0])  # noqa: F821 (injected by Snakemake)
    with open(snakemake.output[0], "w") as fh:  # noqa: F821
        json.dump(report, fh, indent=2)
    if progress.usage_wanted():  # the job's log ends like a metraw command's (benchmarks/main_job.py reads it)
        with open(snakemake.log[0], "a") as fh:  # noqa: F821
            print(progress.usage_line("calibrate_store"), file=fh)
