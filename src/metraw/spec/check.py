"""The runtime decision on an image against a spec (`metraw.spec.builder`): PASS, NORMALISE or REJECT.

Decision, per property: inside [min, max] -> fine; on the *worse* side (coarser GSD, more blur,
less light) -> REJECT; on the *better* side -> NORMALISE to the optimal value with raw functions
that only degrade (binning same-colour pixels to a coarser GSD, photon redistribution through a
blur kernel, binomial thinning of light); if no such move reaches the spec -> REJECT. A property
that cannot be established (missing geometry) -> REJECT. Independently, the noise model claimed
by the profile is checked against the pixels (single-frame fit, `metraw.calibrate.from_image`):
a profile that contradicts the pixels -> REJECT with measured vs claimed numbers.

That is the decision of specs without a property model (older runs). A spec with a ``property_model``
(`metraw.spec.property_model`: IoU fitted over the system's image properties, gsd_m, diffraction_m, smear_m,
reference_signal_e and haze_fraction, on every point of the run) is judged by that fit instead: PASS when
the predicted IoU at the image's own properties meets the requirement, NORMALISE only toward what the fit
says helps, REJECT otherwise; the noise-profile check is the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from metraw.errors import MetrawError
from metraw.raw.cfa import cfa_family
from metraw.raw.image import RawImage
from metraw.spec.builder import BETTER, Choice, Limit, Specification, _plain
from metraw.spec.property_model import (AIRY_SIGMA_PER_LAMBDA_D, WAVELENGTH_REF_M, decide, geometry_properties,
                                   median_signal_e, stated_haze_per_pixel_e)

#: A profile contradicts its pixels when |measured - claimed| exceeds this many combined
#: standard uncertainties *and* this relative difference (guards against tiny uncertainties).
NOISE_Z_LIMIT = 3.0
NOISE_REL_LIMIT = 0.10


# ---------------------------------------------------------------------- measuring an image
def profile_properties(image: RawImage) -> dict[str, float | None]:
    """gsd_m, diffraction_m, smear_m from the profile (None where geometry is missing)."""
    return geometry_properties(image.profile)


def noise_consistency(image: RawImage) -> dict[str, Any]:
    """Single-frame noise fit vs the profile's gain and read noise (in the image's stored DN).

    Returns ``{"measured": bool, "consistent": bool | None, "checks": {...}, "note": ...}``;
    ``consistent`` is False when a quantity differs by more than NOISE_Z_LIMIT combined sigma
    and NOISE_REL_LIMIT relative.
    """
    from metraw.calibrate import from_image

    try:
        res = from_image(image)
    except MetrawError as exc:
        return {"measured": False, "consistent": None, "note": f"noise not measurable from the pixels: {exc}"}
    scale = float(1 << res.unused_low_bits)
    claimed = image.profile
    checks = {}
    consistent = True
    for name, meas, meas_u, claim in (
            ("gain_dn_per_e", res.profile.gain_dn_per_e * scale, res.profile.uncertainty.get("gain_dn_per_e", 0.0) * scale,
             claimed.gain_dn_per_e),
            ("read_noise_e", res.profile.read_noise_e, res.profile.uncertainty.get("read_noise_e", 0.0),
             claimed.read_noise_e)):
        claim_u = claimed.uncertainty.get(name, 0.0)
        comb = math.hypot(meas_u, claim_u)
        diff = meas - claim
        z = diff / comb if comb > 0 else math.inf
        rel = abs(diff) / abs(claim) if claim else math.inf
        bad = abs(z) > NOISE_Z_LIMIT and rel > NOISE_REL_LIMIT
        # Read noise near zero is poorly constrained by one frame: judge it by z alone only if K agrees.
        checks[name] = {"measured": meas, "measured_u": meas_u, "claimed": claim, "claimed_u": claim_u,
                        "z": z if math.isfinite(z) else None, "relative_difference": rel, "contradicts": bad}
        consistent &= not bad
    return {"measured": True, "consistent": consistent, "checks": checks, "notes": list(res.notes)}


#: Profile fields each ground property needs.
GEOMETRY_NEEDS = {"gsd_m": ("pixel_pitch_m", "altitude_m", "focal_length_m"),
                  "diffraction_m": ("altitude_m", "aperture_diameter_m"), "smear_m": ("exposure_s",)}


def _missing_geometry(profile, prop: str) -> str:
    missing = [k for k in GEOMETRY_NEEDS.get(prop, ()) if not getattr(profile, k)]
    return "the profile lacks " + (", ".join(missing) if missing else "the geometry")


def _signal_with_known_gain(image: RawImage, noise: Mapping[str, Any] | None) -> tuple[float | None, str]:
    """(median photoelectrons per pixel, where the number comes from) or (None, why not).

    With a gain marked unknown in the profile (uncertainty inf: a convention value) the signal in
    e- is taken with the gain measured from the pixels' noise when that fit succeeded; with an
    unknown black level it cannot be established.
    """
    from metraw.io import unknown_fields

    unknown = set(unknown_fields(image.profile))
    if "black_level_dn" in unknown:
        return None, "the profile's black level is unknown: no photoelectron count without it"
    if "gain_dn_per_e" not in unknown:
        return median_signal_e(image), "pixels"
    g = (noise or {}).get("checks", {}).get("gain_dn_per_e") if (noise or {}).get("measured") else None
    if not g or not g["measured"] > 0 or not math.isfinite(g["measured_u"]):
        return None, "the profile's gain is unknown and was not measured from the noise"
    k = image.profile.gain_dn_per_e
    return median_signal_e(image) * k / g["measured"], f"pixels, gain {g['measured']:.4g} DN/e- measured from the noise"


# ---------------------------------------------------------------------- decision
@dataclass
class Decision:
    """Outcome of `check`: verdict, reasons, per-property findings and the normalisation chain."""

    verdict: str
    reasons: list[str]
    properties: dict[str, dict[str, Any]]
    chain: list[dict[str, Any]]
    noise: dict[str, Any] | None

    def to_dict(self) -> dict[str, Any]:
        return _plain({"verdict": self.verdict, "reasons": self.reasons, "properties": self.properties,
                       "chain": self.chain, "noise": self.noise})


def _fmt(v: float | None, unit: str) -> str:
    return "unknown" if v is None else f"{v:.4g} {unit}"


def check(image: RawImage, spec: Specification, measure_noise: bool = True) -> Decision:
    """PASS / NORMALISE / REJECT for one image (see module docstring; with a property model in the spec,
    `metraw.spec.property_model.decide` judges the properties)."""
    reasons: list[str] = []
    reject: list[str] = []
    found: dict[str, dict[str, Any]] = {}
    noise = noise_consistency(image) if measure_noise else None
    have = image.profile.cfa_pattern
    choice = spec.parameters.get("cfa_pattern")
    if isinstance(choice, Choice):
        families = sorted({cfa_family(v) for v in choice.allowed})
    else:
        families = [cfa_family(spec.context["cfa_pattern"])] if spec.context.get("cfa_pattern") else None
    if families is not None and cfa_family(have) not in families:
        reject.append(f"CFA pattern {have} ({cfa_family(have)}) is not among the spec's allowed "
                      f"{', '.join(families) or '(none meets the required IoU)'}: no raw function turns one "
                      "filter array into another")
    if spec.property_model is not None:
        more_reject, more_reasons, found, model_chain = decide(image, spec.property_model, spec.required_iou)
        return _verdict(image, noise, reject + more_reject, reasons + more_reasons, found, model_chain)
    values: dict[str, float | None] = dict(profile_properties(image))
    bin_factor = None
    if "gsd_m" in spec.properties and values["gsd_m"] is not None:
        bin_factor = binning_factor(values["gsd_m"], spec.properties["gsd_m"])
    signal_source = "pixels"
    if "signal_e" in spec.properties:
        values["signal_e"], signal_source = _signal_with_known_gain(image, noise)
        if bin_factor and values["signal_e"] is not None:
            # Binning to the spec's GSD sums m^2 pixels: judge the light at the GSD the image will have.
            values["signal_e"] *= bin_factor**2
            reasons.append(f"signal_e judged after the planned {bin_factor} x {bin_factor} binning "
                           f"(x{bin_factor**2} per pixel)")
    if "haze_e" in spec.properties:
        values["haze_e"] = stated_haze_e(image)
        if bin_factor and values["haze_e"] is not None:
            values["haze_e"] *= bin_factor**2  # judged at the binned GSD, like signal_e
    better_side: dict[str, float] = {}
    for prop, lim in spec.properties.items():
        v = values.get(prop)
        status = "pass"
        if v is None and prop == "haze_e":
            status = "unknown"
            reasons.append("haze_e not stated by the image's provenance (emulate / atmosphere): not checked")
        elif v is None:
            status = "unknown"
            reject.append(f"{prop} cannot be determined ({signal_source if prop == 'signal_e' else _missing_geometry(image.profile, prop)})")
        else:
            lower_is_better = lim.details.get("better", BETTER.get(prop)) == "lower"
            below, above = v < lim.min, v > lim.max
            if (below and not lower_is_better) or (above and lower_is_better):
                status = "worse"
                reject.append(f"{prop} = {_fmt(v, lim.unit)} is worse than the spec limit "
                              f"{_fmt(lim.max if lower_is_better else lim.min, lim.unit)}"
                              + (": path radiance cannot be removed without adding noise" if prop == "haze_e" else ""))
            elif below or above:
                status = "better"
                better_side[prop] = v
                reasons.append(f"{prop} = {_fmt(v, lim.unit)} is better than the spec range "
                               f"[{_fmt(lim.min, lim.unit)}, {_fmt(lim.max, lim.unit)}]: normalise to "
                               f"{_fmt(lim.optimal, lim.unit)}")
        found[prop] = {"value": v, "min": lim.min, "max": lim.max, "optimal": lim.optimal, "unit": lim.unit,
                       "status": status, "source": {"signal_e": signal_source, "haze_e": "provenance"}.get(prop, "profile")}
    chain: list[dict[str, Any]] = []
    if not reject and better_side:
        chain, problems = plan_normalisation(image, spec, values)
        reject.extend(problems)
    return _verdict(image, noise, reject, reasons, found, chain)


def _verdict(image: RawImage, noise: Mapping[str, Any] | None, reject: list[str], reasons: list[str],
             found: dict[str, dict[str, Any]], chain: list[dict[str, Any]]) -> Decision:
    """The decision from what `check` found: the noise profile's word added, REJECT before NORMALISE before PASS."""
    if noise and noise.get("consistent") is False:
        for name, c in noise["checks"].items():
            if c["contradicts"]:
                reject.append(f"profile contradicts the pixels: {name} measured {c['measured']:.4g} "
                              f"+- {c['measured_u']:.2g}, claimed {c['claimed']:.4g} "
                              f"({100 * c['relative_difference']:.0f} % apart, z = {c['z']:.1f})")
    elif noise and not noise["measured"]:
        reasons.append(noise["note"] + " (profile taken as claimed)")
    if image.profile.approximate:
        reasons.append(f"profile is approximate: {image.profile.approximate_reason or 'no reason given'}")
    if reject:
        return Decision("REJECT", reject + reasons, found, [], noise)
    if chain:
        return Decision("NORMALISE", reasons, found, chain, noise)
    return Decision("PASS", reasons or ["every property within the spec"], found, [], noise)


def plan_normalisation(image: RawImage, spec: Specification, values: Mapping[str, float | None]
                       ) -> tuple[list[dict[str, Any]], list[str]]:
    """The chain of degrading raw functions bringing better-than-spec properties to spec.

    Order: bin to a coarser GSD (integer same-colour factor closest to the optimal GSD within the
    spec; binning multiplies the signal per pixel by factor^2), then extra blur (diffraction and
    smear, photon redistribution through a Gaussian / along-track box kernel whose variance adds
    to the image's own; the discrete kernels on the same-colour cell grid carry exactly the planned
    variance, also below one cell), then binomial thinning of light when the signal is above the
    spec: p = the optimum system's collected light per pixel / this system's (`light_ratio`, from
    the profile geometry, so each scene keeps its own brightness), or, without geometry, the spec's
    optimal signal / the measured median.
    Returns (chain, problems): problems are reasons no physical move reaches the spec.
    """
    from metraw.raw.cfa import cell_size

    props = spec.properties
    chain: list[dict[str, Any]] = []
    problems: list[str] = []
    gsd = values.get("gsd_m")
    signal = values.get("signal_e")
    step = cell_size(image.profile.cfa_pattern)
    bin_m = 1
    if "gsd_m" in props and gsd is not None and gsd < props["gsd_m"].min:
        lim = props["gsd_m"]
        m = binning_factor(gsd, lim)
        if m is None:
            problems.append(f"gsd_m = {gsd:.4g} m: no integer same-colour binning factor lands in "
                            f"[{lim.min:.4g}, {lim.max:.4g}] m")
        else:
            chain.append({"function": "bin_same_colour", "params": {"factor": m},
                          "effect": f"gsd_m {gsd:.4g} -> {gsd * m:.4g} m"})
            gsd = gsd * m
            bin_m = m
        # values["signal_e"] was already judged at the binned GSD by `check`.
    blur_var_m2 = 0.0
    blur_notes = []
    if "diffraction_m" in props and values.get("diffraction_m") is not None \
            and values["diffraction_m"] < props["diffraction_m"].min:
        have, want = values["diffraction_m"], props["diffraction_m"].optimal
        blur_var_m2 = (AIRY_SIGMA_PER_LAMBDA_D ** 2) * (want**2 - have**2)
        blur_notes.append(f"diffraction_m {have:.4g} -> {want:.4g} m (Gaussian approximation of the Airy core)")
    if blur_var_m2 > 0 and gsd:
        sigma_cells = math.sqrt(blur_var_m2) / (gsd * step)
        chain.append({"function": "redistribute", "params": {"kernel": "gaussian", "sigma_cells": sigma_cells},
                      "effect": "; ".join(blur_notes), "profile_changes": {
                          "aperture_diameter_m": WAVELENGTH_REF_M * image.profile.altitude_m
                          / props["diffraction_m"].optimal}})
    if "smear_m" in props and values.get("smear_m") is not None and values["smear_m"] < props["smear_m"].min:
        have, want = values["smear_m"], props["smear_m"].optimal
        extra = math.sqrt(max(want**2 - have**2, 0.0))  # box variances add: L^2/12
        speed = image.profile.ground_speed_m_per_s
        chain.append({"function": "redistribute", "params": {"kernel": "box_along_track", "length_cells": extra / (gsd * step)},
                      "effect": f"smear_m {have:.4g} -> {want:.4g} m (box variances add; along-track = image columns)",
                      "profile_changes": {"exposure_s": want / speed} if speed else {}})
    if "signal_e" in props and signal is not None and signal > props["signal_e"].max:
        ratio = light_ratio(image.profile, spec.context.get("optimum") or {}, bin_m)
        if ratio is not None:
            # this scene as the optimum system would record it (times the spec's light_scale when the
            # optimum's signal lies above the spec's range): thin by the ratio of collected light
            scale = float(props["signal_e"].details.get("light_scale", 1.0))
            p, basis = ratio * scale, (f"collected light per pixel: the optimum system's / this system's"
                                       f"{' after binning' if bin_m > 1 else ''} (profile geometry)"
                                       f"{f' x light_scale {scale:.3g}' if scale != 1.0 else ''}")
        else:
            p, basis = props["signal_e"].optimal / signal, "spec's optimal signal / measured median (no geometry)"
        if p >= 1:
            problems.append(f"signal_e = {signal:.4g} e- above the spec but the light ratio is {p:.3g} >= 1: "
                            "thinning cannot bring it to spec")
        else:
            chain.append({"function": "thin", "params": {"p": p},
                          "effect": f"signal_e {signal:.4g} -> {signal * p:.4g} e- per pixel (p = {basis})"})
    haze = values.get("haze_e")  # already judged at the binned GSD by `check`
    if haze is not None and chain and chain[-1]["function"] == "thin":
        haze *= chain[-1]["params"]["p"]  # thinning removes path-radiance photons with the scene's
    if "haze_e" in props and haze is not None and haze < props["haze_e"].min:
        # less path radiance than the spec: add the missing light as independent Poisson counts (exact)
        add = props["haze_e"].optimal - haze
        chain.append({"function": "add_poisson", "params": {"mean_e": add, "label": "haze"},
                      "effect": f"haze_e {haze:.4g} -> {props['haze_e'].optimal:.4g} e- per pixel"})
    return chain, problems


def stated_haze_e(image: RawImage) -> float | None:
    """Mean path-radiance photoelectrons per pixel the image's provenance states, as the channels' plain mean
    (the ``haze_e`` of specs without a property model; `metraw.spec.property_model.stated_haze_per_pixel_e`)."""
    return stated_haze_per_pixel_e(image, per_pixel=False)


def light_ratio(profile, optimum: Mapping[str, Any], bin_factor: int = 1) -> float | None:
    """Photoelectrons per pixel the optimum system collects from a scene, relative to this image's
    system after ``bin_factor`` x ``bin_factor`` binning: T D^2 (1 - eps^2) t (pitch / f)^2 per
    pixel (altitude cancels: pixel footprint ~ (pitch h / f)^2, aperture solid angle ~ D^2 / h^2).
    None when either side lacks D, exposure, pitch or focal length. QE and haze are taken equal.
    """
    def light(d, eps, t, pitch, f, trans):
        # the collected light of optics.pupil_area_m2 without its pi / 4, in this arithmetic order (through
        # pupil_area_m2 the ratio's last bit would change for ~40 % of systems, and with it the planned chain)
        return trans * d * d * (1.0 - eps * eps) * t * (pitch / f) ** 2

    need = ("diameter_m", "exposure_s", "pixel_pitch_m", "focal_length_m")
    if any(optimum.get(k) is None for k in need) or None in (
            profile.aperture_diameter_m, profile.exposure_s, profile.pixel_pitch_m, profile.focal_length_m):
        return None
    opt = light(float(optimum["diameter_m"]), float(optimum.get("obscuration_ratio", 0.0)),
                float(optimum["exposure_s"]), float(optimum["pixel_pitch_m"]), float(optimum["focal_length_m"]),
                float(optimum.get("optical_transmission", 1.0)))
    have = light(profile.aperture_diameter_m, profile.obscuration_ratio, profile.exposure_s,
                 profile.pixel_pitch_m, profile.focal_length_m, profile.optical_transmission) * bin_factor**2
    return opt / have if have > 0 else None


def binning_factor(gsd_m: float, lim: Limit, largest: int = 64) -> int | None:
    """Integer same-colour binning factor taking a finer-than-spec GSD into [min, max], closest
    to the optimal GSD (log distance); None when the GSD is not finer than min or no factor fits."""
    if not gsd_m < lim.min:
        return None
    factors = [m for m in range(2, largest + 1) if lim.min <= gsd_m * m <= lim.max]
    if not factors:
        return None
    return min(factors, key=lambda k: abs(math.log(gsd_m * k / lim.optimal)))


def _variance_1d(w: np.ndarray) -> float:
    """Second central moment [cells^2] of a centred odd-length 1-D kernel (normalised)."""
    x = np.arange(w.size, dtype=np.float64) - w.size // 2
    return float((w * x**2).sum() / w.sum())


def _match_variance(make, variance: float, hi: float) -> np.ndarray:
    """The 1-D kernel ``make(s)`` whose discrete variance equals ``variance`` (bisection on s).

    ``make`` must give a variance that grows continuously with s from 0; the photons of a
    redistribution move by whole cells, so what the kernel must get right is the second moment
    (the low-frequency MTF): a sampled kernel of the nominal width does not have it below ~1 cell
    (a sampled Gaussian of sigma 0.36 cell has a third of the variance; a box shorter than a cell
    none at all).
    """
    lo = 0.0
    while _variance_1d(make(hi)) < variance:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _variance_1d(make(mid)) < variance:
            lo = mid
        else:
            hi = mid
    return make(hi)


def _sampled_gaussian(s: float) -> np.ndarray:
    r = max(1, int(math.ceil(4.0 * s)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / max(s, 1e-12)) ** 2)
    return g / g.sum()


def _fractional_box(length: float) -> np.ndarray:
    """Box of ``length`` cells centred on a cell, with fractional end weights (sum 1)."""
    half = max(length, 1.0) / 2.0
    r = max(1, int(math.ceil(half - 0.5)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.clip(np.minimum(x + 0.5, half) - np.maximum(x - 0.5, -half), 0.0, None)
    return w / w.sum()


def _gaussian_kernel(sigma: float) -> np.ndarray:
    """2-D separable Gaussian on the cell grid whose variance per axis is exactly sigma^2 [cells^2]."""
    g = _match_variance(_sampled_gaussian, sigma * sigma, max(sigma, 0.5))
    return np.outer(g, g)


def _box_kernel(length: float) -> np.ndarray:
    """Along-track (columns) box of ``length`` cells as an odd (1, n) kernel whose variance is
    exactly length^2 / 12 [cells^2] (the continuous box's)."""
    return _match_variance(_fractional_box, length * length / 12.0, length + 2.0)[None, :]


def apply_chain(image: RawImage, chain: list[dict[str, Any]], seed: int = 0) -> RawImage:
    """Apply a normalisation chain with `metraw.physics.rawfunc` (deterministic for a given seed)."""
    from metraw.physics import rawfunc
    from metraw.raw.sensor import rng_from_seed

    rng = rng_from_seed(seed)
    out = image
    for step in chain:
        fn, par = step["function"], step["params"]
        if fn == "bin_same_colour":
            out = rawfunc.bin_same_colour(out, int(par["factor"]))
        elif fn == "redistribute":
            if par["kernel"] == "gaussian":
                kernel = _gaussian_kernel(float(par["sigma_cells"]))
            elif par["kernel"] == "box_along_track":
                kernel = _box_kernel(float(par["length_cells"]))
            else:
                raise MetrawError(f"unknown normalisation kernel {par['kernel']!r}")
            out = rawfunc.redistribute(out, kernel, seed=rng)
            if step.get("profile_changes"):
                # The blurred image stands for the equivalent system (larger blur scale): say so.
                out.profile = out.profile.replace(**step["profile_changes"])
                out.provenance[-1]["params"]["profile_changes"] = dict(step["profile_changes"])
        elif fn == "thin":
            out = rawfunc.thin(out, float(par["p"]), seed=rng)
        elif fn == "add_poisson":
            out = rawfunc.add_poisson(out, float(par["mean_e"]), seed=rng, label=str(par.get("label", "poisson")))
        else:
            raise MetrawError(f"unknown normalisation step {fn!r}")
    return out
