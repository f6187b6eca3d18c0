"""The specification vector of a study (``build_spec``, ``Specification``) and the image properties it limits.

The spec (``results/spec.yaml``, the form of the seed study's Fig. 2) lists per system parameter
its optimal value, min, max and unit, from the Gaussian-process tolerances (`metraw.spec.tolerance`).
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

The runtime decision on an image against a spec (PASS, NORMALISE or REJECT): `metraw.spec.check`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from metraw.atomic import atomic_path
from metraw.errors import MetrawError, read_yaml
from metraw.raw.cfa import cfa_family
from metraw.spec.property_model import WAVELENGTH_REF_M, PropertyModel, property_lines

SPEC_VERSION = 1
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
    #: IoU over the image properties, fitted on every point of the run (`metraw.spec.property_model`); the runtime
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
        data = read_yaml(path, "spec file")
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
        # D^2 (1 - eps^2): optics.pupil_area_m2 without its pi / 4, in this arithmetic order (the spec's bytes)
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
    """The specification from `metraw.spec.tolerance.Tolerance` objects (keyed by parameter name).

    ``nominal``: full nominal target parameters (altitude_m, pixel_pitch_m, ...).
    ``signal_reference_e``: ``{"median": ..., "p05": ..., "p95": ...}`` per-image median
    photoelectrons per pixel over the nominal point's images (scene spread); without it the
    spec has no ``signal_e`` line. ``choices``: categorical parameters
    (`metraw.spec.tolerance.categorical_choice`), written as `Choice` lines (allowed values, optimal one).
    ``property_model``: IoU fitted over the image properties (`metraw.spec.property_model.PropertyModel`); with it the
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
            "iou_at_optimal": line["iou_at_optimal"], "flat": line["flat"], "identified": line["identified"],
            "from": "property model (every point of the run), others at the nominal point's properties; min / max: "
            "the sampled range; flat: no value along it beats the nominal's by more than 2 predictive sd, so the "
            "optimal is the nominal's; identified: some points differ in this property alone (else its line carries "
            "the properties that moved with it, and no normalisation moves it)"})
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
        from metraw.emulate.target import TargetSystem

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
