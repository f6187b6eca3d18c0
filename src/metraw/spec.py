"""Specification vector and the runtime decision: PASS, NORMALISE or REJECT an image.

The spec (``results/spec.yaml``, the form of the seed study's Fig. 2) lists per system parameter
its optimal value, min, max and unit, from the Gaussian-process tolerances (`metraw.tolerance`).
An image does not carry "a focal length": what it carries are *image properties*, each
objectively measurable from the image and its profile, all in ground units so they do not
change when pixels are binned:

- ``gsd_m``: ground sample distance, pitch * altitude / focal length (profile);
- ``diffraction_m``: diffraction blur on the ground, lambda_ref * altitude / D (profile,
  lambda_ref = 550 nm; the obscuration changes the Airy shape, not this scale);
- ``smear_m``: motion smear, ground speed * exposure (profile);
- ``signal_e``: median photoelectrons per pixel, (DN - black) / K over unsaturated pixels
  (measured from the pixels; scene dependent, so its limits include the 5-95 % spread of the
  training scenes at the nominal point).

The property limits follow from the one-at-a-time parameter intervals with the others at
nominal (gsd from focal length, diffraction from diameter, smear from exposure, signal from all
three through the photon budget ~ D^2 t / f^2). They form a box; the joint-region share in
aggregate.json says how safe the corners of that box are.

Decision, per property: inside [min, max] -> fine; on the *worse* side (coarser GSD, more blur,
less light) -> REJECT; on the *better* side -> NORMALISE to the optimal value with raw functions
that only degrade (binning same-colour pixels to a coarser GSD, photon redistribution through a
blur kernel, binomial thinning of light); if no such move reaches the spec -> REJECT. A property
that cannot be established (missing geometry) -> REJECT. Independently, the noise model claimed
by the profile is checked against the pixels (single-frame fit, `metraw.calibrate.from_image`):
a profile that contradicts the pixels -> REJECT with measured vs claimed numbers.

That is the decision of specs without a property model (older runs). A spec with a ``property_model``
(`metraw.property_model`: IoU fitted over the system's image properties, gsd_m, diffraction_m, smear_m,
reference_signal_e and haze_fraction, on every point of the run) is judged by that fit instead: PASS when
the predicted IoU at the image's own properties meets the requirement, NORMALISE only toward what the fit
says helps, REJECT otherwise; the noise-profile check is the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from metraw.atomic import atomic_path
from metraw.cfa import cfa_family
from metraw.errors import MetrawError
from metraw.image import RawImage
from metraw.property_model import (AIRY_SIGMA_PER_LAMBDA_D, WAVELENGTH_REF_M, PropertyModel, decide,
                                   geometry_properties, median_signal_e, property_lines, stated_haze_per_pixel_e)

SPEC_VERSION = 1
#: A profile contradicts its pixels when |measured - claimed| exceeds this many combined
#: standard uncertainties *and* this relative difference (guards against tiny uncertainties).
NOISE_Z_LIMIT = 3.0
NOISE_REL_LIMIT = 0.10

UNITS = {"focal_length_m": "m", "diameter_m": "m", "exposure_s": "s", "pixel_pitch_m": "m",
         "altitude_m": "m", "gsd_m": "m", "diffraction_m": "m", "smear_m": "m", "signal_e": "e-", "haze_e": "e-",
         "reference_signal_e": "e-", "haze_fraction": "",
         "path_radiance_w_m2_sr_m": "W m-2 sr-1 m-1", "atmospheric_transmission": ""}
#: Which direction is "better" for an image property.
BETTER = {"gsd_m": "lower", "diffraction_m": "lower", "smear_m": "lower", "signal_e": "higher", "haze_e": "lower",
          "reference_signal_e": "higher", "haze_fraction": "lower"}


@dataclass
class Limit:
    """One line of the spec: optimal value, min, max, unit (+ free-form details)."""

    optimal: float | None
    min: float | None
    max: float | None
    unit: str
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"optimal": _f(self.optimal), "min": _f(self.min), "max": _f(self.max), "unit": self.unit,
                **{k: _plain(v) for k, v in self.details.items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], name: str = "entry") -> "Limit":
        if not isinstance(d, Mapping):
            raise MetrawError(f"spec {name} must be a mapping of optimal, min, max, unit, got {d!r}")
        missing = [k for k in ("optimal", "min", "max", "unit") if k not in d]
        if missing:
            raise MetrawError(f"spec {name} lacks {', '.join(map(repr, missing))}")
        for k in ("optimal", "min", "max"):
            if d[k] is not None and (isinstance(d[k], bool) or not isinstance(d[k], (int, float))):
                raise MetrawError(f"spec {name}: {k} must be a number or null, got {d[k]!r}")
        if None not in (d["min"], d["max"]) and d["min"] > d["max"]:
            raise MetrawError(f"spec {name}: min {d['min']} > max {d['max']}")
        return cls(d["optimal"], d["min"], d["max"], d["unit"],
                   {k: v for k, v in d.items() if k not in ("optimal", "min", "max", "unit")})


@dataclass
class Choice:
    """A categorical line of the spec: the allowed values, the optimal one (+ free-form details)."""

    optimal: str
    allowed: list[str]
    unit: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"optimal": self.optimal, "allowed": list(self.allowed), "unit": self.unit,
                **{k: _plain(v) for k, v in self.details.items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], name: str = "entry") -> "Choice":
        if not isinstance(d.get("allowed"), list) or not all(isinstance(v, str) for v in d["allowed"]):
            raise MetrawError(f"spec {name}: allowed must be a list of words, got {d.get('allowed')!r}")
        if not isinstance(d.get("optimal"), str):
            raise MetrawError(f"spec {name}: optimal must be a word, got {d.get('optimal')!r}")
        return cls(d["optimal"], list(d["allowed"]), str(d.get("unit", "")),
                   {k: v for k, v in d.items() if k not in ("optimal", "allowed", "unit")})


@dataclass
class Specification:
    """Parameters (system, Fig. 2 form) and image properties with their limits."""

    required_iou: float
    parameters: dict[str, Limit | Choice]
    properties: dict[str, Limit]
    context: dict[str, Any] = field(default_factory=dict)
    #: IoU over the image properties, fitted on every point of the run (`metraw.property_model`); the runtime
    #: decision uses it when present, else the per-property limits.
    property_model: Any = None

    def to_dict(self) -> dict[str, Any]:
        out = {"spec_version": SPEC_VERSION, "required_iou": float(self.required_iou),
               "parameters": {k: v.to_dict() for k, v in self.parameters.items()},
               "image_properties": {k: v.to_dict() for k, v in self.properties.items()},
               "context": _plain(self.context)}
        if self.property_model is not None:
            out["property_model"] = _plain(self.property_model.to_dict())
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Specification":
        if not isinstance(d, Mapping) or d.get("spec_version") != SPEC_VERSION:
            raise MetrawError(f"not a metraw spec (spec_version {d.get('spec_version') if isinstance(d, Mapping) else None!r},"
                              f" this metraw reads {SPEC_VERSION})")
        missing = [k for k in ("required_iou", "parameters", "image_properties") if k not in d]
        if missing:
            raise MetrawError(f"spec lacks {', '.join(map(repr, missing))}")
        iou = d["required_iou"]
        if isinstance(iou, bool) or not isinstance(iou, (int, float)) or not 0 < iou < 1:
            raise MetrawError(f"spec required_iou must be a number in (0, 1), got {iou!r}")
        sections = {}
        for section in ("parameters", "image_properties"):
            if not isinstance(d[section], Mapping):
                raise MetrawError(f"spec {section} must be a mapping, got {d[section]!r}")
            sections[section] = {k: (Choice if isinstance(v, Mapping) and "allowed" in v and section == "parameters"
                                     else Limit).from_dict(v, f"{section}.{k}") for k, v in d[section].items()}
        for k, lim in sections["image_properties"].items():
            if None in (lim.optimal, lim.min, lim.max):
                raise MetrawError(f"spec image_properties.{k}: optimal, min and max must be numbers")
        unknown = sorted(set(sections["image_properties"]) - set(BETTER))
        if unknown:
            raise MetrawError(f"spec image_properties has unknown entries: {', '.join(unknown)} "
                              f"(known: {', '.join(BETTER)})")
        if not isinstance(d.get("context") or {}, Mapping):
            raise MetrawError("spec context must be a mapping")
        model = None
        if d.get("property_model") is not None:
            if not isinstance(d["property_model"], Mapping):
                raise MetrawError("spec property_model must be a mapping")
            try:
                model = PropertyModel.from_dict(d["property_model"])
            except MetrawError as exc:
                raise MetrawError(f"spec property_model: {exc}") from None
        return cls(float(iou), sections["parameters"], sections["image_properties"], dict(d.get("context") or {}),
                   model)

    def save(self, path: str | Path, overwrite: bool = True) -> None:
        with atomic_path(path, overwrite=overwrite) as tmp:
            tmp.write_text("# metraw specification vector (see metraw.spec); generated by metraw aggregate\n"
                           + yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def load(cls, path: str | Path) -> "Specification":
        try:
            data = yaml.safe_load(Path(path).read_text())
        except FileNotFoundError:
            raise MetrawError(f"spec file {path} not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise MetrawError(f"cannot read spec file {path}: {getattr(exc, 'strerror', None) or exc}") from None
        except yaml.YAMLError as exc:
            raise MetrawError(f"spec file {path} is not valid YAML: {' '.join(str(exc).split())}") from None
        try:
            return cls.from_dict(data)
        except MetrawError as exc:
            raise MetrawError(f"spec file {path}: {exc}") from None


def _f(v):
    return None if v is None else float(v)


def _plain(v):
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None  # JSON/YAML-safe: an infinite uncertainty means "not stated"
    return v


# ---------------------------------------------------------------------- building the spec
#: Parameters that move the scene's photoelectrons per pixel (`photon_budget`).
BUDGET_PARAMETERS = ("focal_length_m", "diameter_m", "exposure_s", "pixel_pitch_m", "atmospheric_transmission")


def photon_budget(values: Mapping[str, float], nominal: Mapping[str, float]) -> float:
    """Scene photoelectrons per pixel relative to nominal: D^2 (1 - eps^2) t p^2 T / f^2 (altitude fixed;
    pitch p and atmospheric transmission T count when the nominal states them)."""
    def g(name, default=1.0):
        return float(values.get(name, nominal.get(name, default)))

    def budget(v):
        eps = v("obscuration_ratio", 0.0)
        return (v("diameter_m") ** 2 * (1 - eps**2) * v("exposure_s") * v("pixel_pitch_m") ** 2
                * v("atmospheric_transmission") / v("focal_length_m") ** 2)

    return budget(g) / budget(lambda name, default=1.0: float(nominal.get(name, default)))


def image_properties_of(values: Mapping[str, float]) -> dict[str, float]:
    """gsd_m, diffraction_m, smear_m of a system (needs altitude, pitch, f, D, speed, exposure)."""
    h = float(values["altitude_m"])
    return {"gsd_m": float(values["pixel_pitch_m"]) * h / float(values["focal_length_m"]),
            "diffraction_m": WAVELENGTH_REF_M * h / float(values["diameter_m"]),
            "smear_m": float(values.get("ground_speed_m_per_s", 0.0)) * float(values["exposure_s"])}


def build_spec(tolerances: Mapping[str, Any], nominal: Mapping[str, Any], required_iou: float,
               signal_reference_e: Mapping[str, float] | None = None, context: Mapping[str, Any] | None = None,
               choices: Mapping[str, Mapping[str, Any]] | None = None, property_model: Any = None,
               model_at: Mapping[str, float] | None = None) -> Specification:
    """The specification from `metraw.tolerance.Tolerance` objects (keyed by parameter name).

    ``nominal``: full nominal target parameters (altitude_m, pixel_pitch_m, ...).
    ``signal_reference_e``: ``{"median": ..., "p05": ..., "p95": ...}`` per-image median
    photoelectrons per pixel over the nominal point's images (scene spread); without it the
    spec has no ``signal_e`` line. ``choices``: categorical parameters
    (`metraw.tolerance.categorical_choice`), written as `Choice` lines (allowed values, optimal one).
    ``property_model``: IoU fitted over the image properties (`metraw.property_model.PropertyModel`); with it the
    image_properties lines are the fit's (optimal: argmax along the property with the others at ``model_at``,
    the nominal point's properties; min / max: the sampled range) and the runtime check uses the model.
    """
    params: dict[str, Limit | Choice] = {}
    for name, t in tolerances.items():
        params[name] = Limit(t.optimal, t.min, t.max, UNITS.get(name, ""), {
            "iou_at_optimal": t.mean_at_optimal, "iou_lower_2sigma_at_optimal": t.lower_at_optimal,
            "required_iou": required_iou, "meets_requirement": t.meets_requirement,
            "nominal": float(nominal[name]),
            "min_limited_by": t.min_limited_by, "max_limited_by": t.max_limited_by,
            "min_extrapolated": t.min_extrapolated, "max_extrapolated": t.max_extrapolated,
            "sampled_range": [t.sampled_min, t.sampled_max]})
    nominal_f = {k: v for k, v in nominal.items() if isinstance(v, (int, float))}
    optimum = {**nominal_f, **{k: v.optimal for k, v in params.items()}}
    for name, c in (choices or {}).items():
        params[name] = Choice(c["optimal"], list(c["allowed"]), "", {
            "nominal": c["nominal"], "highest": c["highest"], "rule": c["rule"], "required_iou": required_iou,
            "allowed_families": sorted({cfa_family(v) for v in c["allowed"]}) if name == "cfa_pattern" else None,
            "measured": {v: {"iou": r["iou"], "iou_sd": r["iou_sd"]} for v, r in c["values"].items()}})
    if property_model is not None:
        props = {name: Limit(line["optimal"], line["min"], line["max"], line["unit"], {
            "iou_at_optimal": line["iou_at_optimal"], "flat": line["flat"], "from": "property model (every point of the "
            "run), others at the nominal point's properties; min / max: the sampled range; flat: no value along it "
            "beats the nominal's by more than 2 predictive sd, so the optimal is the nominal's"})
            for name, line in property_lines(property_model, model_at).items()}
    else:
        props = _property_limits(params, nominal, nominal_f, optimum, signal_reference_e)
    ctx = {"wavelength_ref_m": WAVELENGTH_REF_M, "altitude_m": nominal.get("altitude_m"),
           "pixel_pitch_m": nominal.get("pixel_pitch_m"), "ground_speed_m_per_s": nominal.get("ground_speed_m_per_s"),
           "cfa_pattern": nominal.get("cfa_pattern"), "optimum": optimum,
           "property_box": "one-at-a-time limits, others at nominal (see aggregate.json joint region)"}
    ctx.update(context or {})
    return Specification(float(required_iou), params, props, ctx, property_model)


def _property_limits(params: Mapping[str, Limit | Choice], nominal: Mapping[str, Any], nominal_f: Mapping[str, float],
                     optimum: Mapping[str, float], signal_reference_e: Mapping[str, float] | None) -> dict[str, Limit]:
    """The image-property limits of a spec without a property model: from the one-at-a-time parameter intervals
    (GSD from focal length, diffraction from diameter, smear from exposure, haze from path radiance, signal from
    the photon budget widened by the nominal scenes' spread)."""
    props: dict[str, Limit] = {}
    which = {"gsd_m": "focal_length_m", "diffraction_m": "diameter_m", "smear_m": "exposure_s"}
    for prop, par in which.items():
        lim = params.get(par)
        if lim is None or lim.min is None:
            continue
        ends = [image_properties_of({**nominal_f, par: v})[prop] for v in (lim.min, lim.max)]
        if prop == "smear_m" and not nominal_f.get("ground_speed_m_per_s"):
            continue
        props[prop] = Limit(image_properties_of(optimum)[prop], min(ends), max(ends), "m",
                            {"better": BETTER[prop], "from_parameter": par})
    path = params.get("path_radiance_w_m2_sr_m")
    if isinstance(path, Limit) and path.min is not None:
        from metraw.target import TargetSystem

        def haze(radiance):
            e = TargetSystem.from_dict({**nominal, "path_radiance_w_m2_sr_m": radiance}).path_radiance_electrons()
            return float(np.mean(list(e.values())))

        props["haze_e"] = Limit(haze(path.optimal), haze(path.min), haze(path.max), "e-",
                                {"better": "lower", "from_parameter": "path_radiance_w_m2_sr_m (nominal payload)",
                                 "note": "mean path-radiance e- per pixel over the channels, as the image's "
                                         "provenance states it (emulate / atmosphere)"})
    budget = [p for p in BUDGET_PARAMETERS if isinstance(params.get(p), Limit) and params[p].min is not None]
    if signal_reference_e and all(p in budget for p in ("focal_length_m", "diameter_m", "exposure_s")):
        factors = [photon_budget({p: v}, nominal_f) for p in budget for v in (params[p].min, params[p].max)]
        lo, hi = signal_reference_e["p05"] * min(factors), signal_reference_e["p95"] * max(factors)
        # The optimum combines every parameter's optimal value, a corner that the one-at-a-time lines
        # need not reach: its signal can lie outside [lo, hi]. The spec's optimal signal is clipped into
        # the range; light_scale (<= 1) is the factor from the optimum system's light to that level.
        joint = signal_reference_e["median"] * photon_budget(optimum, nominal_f)
        optimal = min(max(joint, lo), hi)
        props["signal_e"] = Limit(
            optimal, lo, hi, "e-",
            {"better": "higher", "from_parameter": ", ".join(budget) + " (photon budget)",
             "nominal_scene_median_e": signal_reference_e["median"],
             "nominal_scene_p05_e": signal_reference_e["p05"], "nominal_scene_p95_e": signal_reference_e["p95"],
             "optimum_system_median_e": joint, "light_scale": optimal / joint})
    return props


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
    from metraw.io._unknown import unknown_fields

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
    `metraw.property_model.decide` judges the properties)."""
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
    from metraw.cfa import cell_size

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
    (the ``haze_e`` of specs without a property model; `metraw.property_model.stated_haze_per_pixel_e`)."""
    return stated_haze_per_pixel_e(image, per_pixel=False)


def light_ratio(profile, optimum: Mapping[str, Any], bin_factor: int = 1) -> float | None:
    """Photoelectrons per pixel the optimum system collects from a scene, relative to this image's
    system after ``bin_factor`` x ``bin_factor`` binning: T D^2 (1 - eps^2) t (pitch / f)^2 per
    pixel (altitude cancels: pixel footprint ~ (pitch h / f)^2, aperture solid angle ~ D^2 / h^2).
    None when either side lacks D, exposure, pitch or focal length. QE and haze are taken equal.
    """
    def light(d, eps, t, pitch, f, trans):
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
    """Apply a normalisation chain with `metraw.rawfunc` (deterministic for a given seed)."""
    from metraw import rawfunc
    from metraw.sensor import rng_from_seed

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
