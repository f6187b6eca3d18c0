"""IoU as a function of image properties, fitted on every point of a run (lines, grids and categorical points).

An incoming image carries no "focal length" or "aperture": it carries properties that can be established from
its profile and provenance. The IoU of a point is an average over the study's scenes, so each property describes
the system and its air, not the one scene in front of it (a dark car park and a bright one seen by the same
satellite are judged alike), and each moves with the collected light only where the task does:

- ``gsd_m``: ground sample distance, pitch x altitude / focal length (profile);
- ``diffraction_m``: diffraction blur on the ground, 550 nm x altitude / aperture diameter (profile);
- ``smear_m``: motion smear on the ground, ground speed x exposure (profile);
- ``reference_signal_e``: photoelectrons per pixel from the reference ground (`REFERENCE_SCENE`: grey, 20 %
  reflectance, sun at 45 degrees) through the image's optics, exposure, pixel, QE and stated air: the light
  itself, which the task does depend on (shot noise against the read noise), as the system delivers it;
- ``haze_fraction``: path radiance's share of the light from that reference ground, haze / (haze + reference
  signal), with the path-radiance photoelectrons the emulation's provenance states. Both terms are collected
  through the same aperture, pixel, exposure, optics transmission and QE, so the same air gives the same
  fraction behind any payload; it grows with path radiance and with a lower transmission of the ground's light,
  i.e. with the loss of contrast the segmenter sees. (A count of path-radiance electrons would call the same
  air "worse" behind a bigger mirror; a share of the image's own mean signal would call it worse over a darker
  scene.)

``PropertyModel`` holds the run's points (the median of each property over the point's test images, the point's
measured IoU and its standard error) and fits a `metraw.spec.tolerance.ResponseGP` over the property axes (log axes
for the scale properties). It is stored in spec.yaml and refitted, deterministically, when a spec is loaded.
The runtime decision it supports (`metraw.spec.check.check`): PASS when the predicted IoU at the image's own
properties meets the requirement, REJECT when it does not; NORMALISE only toward what the fit says helps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.errors import MetrawError
from metraw.physics.atmosphere import pixel_etendue_m2_sr
from metraw.physics.daylight import lambertian_photon_radiance
from metraw.raw.cfa import channel_names, color_index
from metraw.raw.image import RawImage

#: The properties in the order of the model's axes.
PROPERTIES = ("gsd_m", "diffraction_m", "smear_m", "reference_signal_e", "haze_fraction")
#: Working axis of each property (`metraw.spec.tolerance.Axis`): log for scale quantities.
AXIS_KINDS = {"gsd_m": "log", "diffraction_m": "log", "smear_m": "linear", "reference_signal_e": "log",
              "haze_fraction": "linear"}
UNITS = {"gsd_m": "m", "diffraction_m": "m", "smear_m": "m", "reference_signal_e": "e-", "haze_fraction": ""}
#: The direction a raw function can move a property without adding noise it does not state: coarser GSD
#: (binning), more blur and smear (photon redistribution), less light (binomial thinning), more haze (Poisson).
DEGRADES = {"gsd_m": "up", "diffraction_m": "up", "smear_m": "up", "reference_signal_e": "down", "haze_fraction": "up"}
#: A move toward the fit's optimum is planned only when it raises the predicted IoU by more than this many
#: predictive standard deviations (of the image's own prediction): normalise never degrades on noise.
HELPS_SIGMA = 2.0
#: A property's own effect is identified when two points of the run differ in it by more than ``IDENTIFY_STEP``
#: (relative) while every other property agrees within ``IDENTIFY_SAME`` (relative). One-at-a-time sweeps move
#: several properties at once (a longer exposure: more signal *and* more smear); along a property that never moved
#: alone the fit cannot tell its effect from its companions', so no normalisation moves it and its line states the
#: nominal's value.
IDENTIFY_STEP = 0.05
IDENTIFY_SAME = 0.02
#: Reference wavelength of the diffraction scale [m].
WAVELENGTH_REF_M = 550e-9
#: Gaussian sigma of the Airy core in units of lambda/D (best-fit Gaussian to the Airy disc).
AIRY_SIGMA_PER_LAMBDA_D = 0.42
#: The reference ground of ``reference_signal_e`` and ``haze_fraction``: a horizontal grey Lambertian surface of this
#: reflectance under the sun at this elevation in clear air (`metraw.physics.daylight.lambertian_photon_radiance`).
REFERENCE_SCENE = {"reflectance": 0.2, "sun_elevation_deg": 45.0, "aerosol_depth_550": 0.12}


@dataclass(frozen=True)
class StatedAir:
    """What an image's provenance states about the air and the light since its emulation: ``transmission`` (one
    way, on the scene's light; None when no step states it), ``haze_e`` (mean path-radiance photoelectrons per
    pixel; None when no step states it) and ``light_factor`` (binomial thinnings since, which the profile's
    geometry does not show)."""

    transmission: float | None
    haze_e: float | None
    light_factor: float = 1.0


def stated_air(image: RawImage, per_pixel: bool = True) -> StatedAir:
    """The provenance's `StatedAir`, steps applied in order: ``emulate`` (the target's atmospheric transmission
    and per-channel haze, weighted by the channels' share of the mosaic, or with ``per_pixel`` False the plain
    mean over the channels, as older specs' ``haze_e``), ``atmosphere`` (transmission and haze on top), haze
    ``add_poisson``, ``bin_same_colour`` (haze x factor^2; the binned profile's pitch carries the signal's),
    ``thin`` (haze and light x p, unless the thinning changed the profile's geometry, which then states it)."""
    transmission = haze = None
    light = 1.0
    shares = _channel_shares(image) if per_pixel else None

    def mean(values) -> float:
        if not isinstance(values, Mapping):
            return float(values)
        if shares is None:
            return float(np.mean([float(v) for v in values.values()]))
        return sum(shares.get(c, 0.0) * float(v) for c, v in values.items()) / max(
            sum(shares.get(c, 0.0) for c in values), 1e-300)

    for step in image.provenance:
        par = step.get("params") or {}
        fn = step.get("function")
        if fn == "emulate" and "haze_e" in par:
            haze, light = mean(par["haze_e"]), 1.0
            transmission = float((par.get("target") or {}).get("atmospheric_transmission", 1.0))
        elif fn == "atmosphere" and "haze_e" in par:
            t = float(par.get("transmission", 1.0))
            haze = (haze or 0.0) * t + mean(par["haze_e"])
            transmission = (1.0 if transmission is None else transmission) * t
        elif fn == "add_poisson" and par.get("label") == "haze" and haze is not None:
            haze += float(par.get("mean_e", 0.0))
        elif fn == "bin_same_colour" and haze is not None:
            haze *= int(par.get("factor", 1)) ** 2
        elif fn == "thin" and "p" in par and not par.get("profile_changes"):
            p = mean(par["p"])
            light *= p
            haze = None if haze is None else haze * p
    return StatedAir(transmission, haze, light)


def stated_haze_per_pixel_e(image: RawImage, per_pixel: bool = True) -> float | None:
    """Mean path-radiance photoelectrons per pixel the image's provenance states (`stated_air`); None when no
    step states it."""
    return stated_air(image, per_pixel).haze_e


def _channel_shares(image: RawImage) -> dict[str, float]:
    names = channel_names(image.profile.cfa_pattern)
    counts = np.bincount(color_index(image.profile.cfa_pattern, image.shape).ravel(), minlength=len(names))
    return {c: float(n) / image.data.size for c, n in zip(names, counts)}


def _unsaturated_electrons(image: RawImage) -> np.ndarray:
    """(DN - black) / K of the unsaturated pixels (a MetrawError when every pixel is saturated)."""
    ok = ~image.saturated()
    if not ok.any():
        raise MetrawError("every pixel is saturated: no signal level can be measured")
    return image.electrons()[ok]


def median_signal_e(image: RawImage) -> float:
    """Median photoelectrons per pixel, (DN - black) / K over unsaturated pixels."""
    return float(np.median(_unsaturated_electrons(image)))


def reference_signal_e(image: RawImage) -> float | None:
    """Photoelectrons per pixel the image's system records from the reference ground (`REFERENCE_SCENE`)
    through its air: pixel etendue x exposure x optics transmission x QE_c x band photon radiance, averaged over
    the mosaic's channels, times the air's transmission (as the provenance states it; 1 when it states none)
    and the thinnings since the emulation. None when the profile lacks pitch, focal length,
    aperture or exposure."""
    return _reference_signal(image, stated_air(image))


def _reference_signal(image: RawImage, air: StatedAir) -> float | None:
    """`reference_signal_e` with the provenance's `StatedAir` already read."""
    prof = image.profile
    if None in (prof.pixel_pitch_m, prof.focal_length_m, prof.aperture_diameter_m, prof.exposure_s) \
            or not prof.aperture_diameter_m:
        return None
    t_air = 1.0 if air.transmission is None else air.transmission
    scale = pixel_etendue_m2_sr(prof) * prof.exposure_s * prof.optical_transmission * t_air * air.light_factor
    shares = _channel_shares(image)
    return float(sum(share * scale * prof.qe_per_channel.get(c, 1.0) * _reference_radiance(prof.band_edges_m[c])
                     for c, share in shares.items()))


@lru_cache(maxsize=64)
def _reference_radiance(band_m: tuple[float, float]) -> float:
    return lambertian_photon_radiance(tuple(band_m), **REFERENCE_SCENE)


def haze_fraction(image: RawImage) -> float | None:
    """Path radiance's share of the light from the reference ground, haze / (haze + reference signal), both in
    photoelectrons per pixel through the same optics (see module docstring); None when the provenance states no
    haze or the profile lacks the geometry."""
    air = stated_air(image)
    return _fraction(air.haze_e, _reference_signal(image, air))


def _fraction(haze: float | None, signal: float | None) -> float | None:
    if haze is None or signal is None or haze + signal <= 0:
        return None
    return float(haze / (haze + signal))


def geometry_properties(profile) -> dict[str, float | None]:
    """gsd_m, diffraction_m, smear_m from a profile (None where its geometry is missing)."""
    h = profile.altitude_m
    return {"gsd_m": profile.gsd_m,
            "diffraction_m": None if h is None or not profile.aperture_diameter_m
            else WAVELENGTH_REF_M * h / profile.aperture_diameter_m,
            "smear_m": None if profile.exposure_s is None else profile.ground_speed_m_per_s * profile.exposure_s}


def image_properties(image: RawImage) -> dict[str, float | None]:
    """Every property of ``image`` (see module docstring); None where the profile or provenance cannot state it."""
    out = geometry_properties(image.profile)
    air = stated_air(image)  # the provenance read once for both
    out["reference_signal_e"] = _reference_signal(image, air)
    out["haze_fraction"] = _fraction(air.haze_e, out["reference_signal_e"])
    return out


@dataclass
class PropertyModel:
    """The run's points in property space and the GP of IoU over them (see module docstring).

    ``names``: the properties used (those that every point states and that vary); ``points``: one record per
    point, ``{"point", "iou", "iou_sd", <property>: median value, ...}``; ``seed``: the GP's restarts.
    """

    names: list[str]
    points: list[dict[str, Any]]
    seed: int = 0
    _gp: Any = field(default=None, repr=False, compare=False)

    @classmethod
    def from_points(cls, points: Sequence[Mapping[str, Any]], seed: int = 0) -> "PropertyModel":
        """Keep the properties every point states and that vary between points."""
        names = [p for p in PROPERTIES if all(r.get(p) is not None for r in points)
                 and len({round(float(r[p]), 12) for r in points}) > 1]
        if not names:
            raise MetrawError("no image property varies between the points: nothing to fit IoU against")
        return cls(names, [dict(r) for r in points], seed)

    @property
    def gp(self):
        if self._gp is None:
            from metraw.spec.tolerance import Axis, ResponseGP

            X = np.array([[float(r[n]) for n in self.names] for r in self.points])
            axes = [Axis(n, AXIS_KINDS[n], float(X[:, j].min()), float(X[:, j].max()))
                    for j, n in enumerate(self.names)]
            self._gp = ResponseGP(self.names, X, [r["iou"] for r in self.points],
                                  [r["iou_sd"] ** 2 for r in self.points], axes=axes, seed=self.seed)
        return self._gp

    def predict(self, props: Mapping[str, float]) -> tuple[float, float]:
        """(mean, predictive sd) of IoU at ``props``."""
        p = self.gp.predict(np.array([[float(props[n]) for n in self.names]]))
        return float(p.mean[0]), float(p.sd[0])

    def reference(self, name: str) -> float:
        """The nominal point's value of ``name`` (the points' median when no point is called nominal)."""
        for r in self.points:
            if r.get("point") == "nominal":
                return float(r[name])
        return float(np.median([float(r[name]) for r in self.points]))

    def identified(self, name: str) -> bool:
        """Whether two points of one sensor (their ``sensor``, when stated: mono or bayer) differ in ``name`` alone
        (``IDENTIFY_STEP``, ``IDENTIFY_SAME``)."""
        def rel(a: float, b: float) -> float:
            return abs(a - b) / max(abs(a), abs(b), 1e-300)

        others = [n for n in self.names if n != name]
        pts = self.points
        return any(p.get("sensor") == q.get("sensor") and rel(float(p[name]), float(q[name])) > IDENTIFY_STEP
                   and all(rel(float(p[n]), float(q[n])) <= IDENTIFY_SAME for n in others)
                   for i, p in enumerate(pts) for q in pts[i + 1:])

    def sampled_range(self, name: str) -> tuple[float, float]:
        values = [float(r[name]) for r in self.points]
        return min(values), max(values)

    def best_move(self, name: str, props: Mapping[str, float], n_grid: int = 201,
                  here: tuple[float, float] | None = None) -> dict[str, Any] | None:
        """The value of ``name`` in its degrade-only direction (from the image's own value to the end of the
        sampled range), others held at the image's values, that maximises the predicted IoU, when it beats the
        image's own prediction (``here``: its (mean, sd), when the caller has it) by more than ``HELPS_SIGMA``
        predictive sd, and the run identifies the property's own effect (``identified``); else None."""
        from metraw.spec.tolerance import Axis

        if not self.identified(name):
            return None
        have = float(props[name])
        lo, hi = self.sampled_range(name)
        end = hi if DEGRADES[name] == "up" else lo
        if (DEGRADES[name] == "up" and end <= have) or (DEGRADES[name] == "down" and end >= have):
            return None
        ax = Axis(name, AXIS_KINDS[name], min(have, end), max(have, end))
        grid = ax.from_unit(np.linspace(0.0, 1.0, n_grid))
        j = self.names.index(name)
        X = np.tile([float(props[n]) for n in self.names], (n_grid, 1))
        X[:, j] = grid
        p = self.gp.predict(X)
        i = int(np.argmax(p.mean))
        here = here or self.predict(props)
        gain = float(p.mean[i]) - here[0]
        if gain <= HELPS_SIGMA * here[1]:
            return None
        return {"property": name, "from": have, "to": float(grid[i]), "predicted_iou": float(p.mean[i]),
                "predicted_iou_here": here[0], "gain": gain}

    def optimum_line(self, name: str, at: Mapping[str, float], n_grid: int = 201) -> dict[str, Any]:
        """Argmax of the predicted IoU along ``name`` over its sampled range, the others at ``at``; when it beats
        the prediction at ``at`` by no more than ``HELPS_SIGMA`` predictive sd the line is flat within the fit's
        error and its optimal value is ``at``'s own (``flat``: True), so no image is told to move for nothing."""
        from metraw.spec.tolerance import Axis

        lo, hi = self.sampled_range(name)
        grid = Axis(name, AXIS_KINDS[name], lo, hi).from_unit(np.linspace(0.0, 1.0, n_grid))
        j = self.names.index(name)
        X = np.tile([float(at[n]) for n in self.names], (n_grid, 1))
        X[:, j] = grid
        p = self.gp.predict(X)
        i = int(np.argmax(p.mean))
        here_mean, here_sd = self.predict(at)
        if float(p.mean[i]) - here_mean <= HELPS_SIGMA * here_sd:
            return {"optimal": float(at[name]), "iou_at_optimal": here_mean, "min": lo, "max": hi, "flat": True,
                    "identified": self.identified(name)}
        return {"optimal": float(grid[i]), "iou_at_optimal": float(p.mean[i]), "min": lo, "max": hi, "flat": False,
                "identified": self.identified(name)}

    def to_dict(self) -> dict[str, Any]:
        return {"properties": list(self.names), "units": {n: UNITS[n] for n in self.names},
                "axes": {n: AXIS_KINDS[n] for n in self.names}, "seed": self.seed,
                "points": [{k: (float(v) if isinstance(v, (int, float, np.floating)) and not isinstance(v, bool)
                                else v) for k, v in r.items()} for r in self.points]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "PropertyModel":
        try:
            names = [str(n) for n in d["properties"]]
            points = [dict(r) for r in d["points"]]
            unknown = sorted(set(names) - set(PROPERTIES))
            if unknown:
                raise MetrawError(f"unknown image properties {unknown} (known: {', '.join(PROPERTIES)})")
            for r in points:
                for key in (*names, "iou", "iou_sd"):
                    if not isinstance(r.get(key), (int, float)) or not math.isfinite(float(r[key])):
                        raise MetrawError(f"point {r.get('point', '?')}: {key} must be a finite number")
        except (KeyError, TypeError) as exc:
            raise MetrawError(f"property_model needs properties and points ({exc})") from None
        return cls(names, points, int(d.get("seed", 0)))


def plan_moves(image: RawImage, model: PropertyModel, props: Mapping[str, float],
               here: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """The raw-function chain of the moves the fit says help (``PropertyModel.best_move``), each toward the fit's
    argmax in its degrade-only direction, others at the image's values; [] when no move helps. ``here``: the
    image's own predicted (mean, sd), when the caller has it."""
    here = here or model.predict(props)
    from metraw.raw.cfa import cell_size

    chain: list[dict[str, Any]] = []
    step = cell_size(image.profile.cfa_pattern)
    gsd = props.get("gsd_m")
    for name in model.names:
        move = model.best_move(name, props, here=here)
        if move is None:
            continue
        have, want = move["from"], move["to"]
        effect = (f"{name} {have:.4g} -> {want:.4g} {UNITS[name]} (predicted IoU {move['predicted_iou_here']:.3f} "
                  f"-> {move['predicted_iou']:.3f})")
        if name == "gsd_m":
            factor = max(2, int(round(want / have)))
            chain.append({"function": "bin_same_colour", "params": {"factor": factor}, "effect": effect})
        elif name == "diffraction_m" and gsd:
            sigma_m = AIRY_SIGMA_PER_LAMBDA_D * math.sqrt(want**2 - have**2)
            chain.append({"function": "redistribute", "params": {"kernel": "gaussian",
                                                                 "sigma_cells": sigma_m / (gsd * step)},
                          "effect": effect})
        elif name == "smear_m" and gsd:
            extra = math.sqrt(max(want**2 - have**2, 0.0))  # box variances add: L^2 / 12
            chain.append({"function": "redistribute", "params": {"kernel": "box_along_track",
                                                                 "length_cells": extra / (gsd * step)},
                          "effect": effect})
        elif name == "reference_signal_e":
            chain.append({"function": "thin", "params": {"p": want / have}, "effect": effect})
        elif name == "haze_fraction":
            signal = props["reference_signal_e"] if "reference_signal_e" in props else reference_signal_e(image)
            haze = have * signal / (1.0 - have)  # h / (h + s) = have
            add = want * signal / (1.0 - want) - haze  # (h + a) / (h + a + s) = want
            chain.append({"function": "add_poisson", "params": {"mean_e": add, "label": "haze"}, "effect": effect})
    return chain


def decide(image: RawImage, model: PropertyModel,
           required_iou: float) -> tuple[list[str], list[str], dict[str, dict[str, Any]], list[dict[str, Any]]]:
    """The property model's part of the runtime decision: (reject reasons, other reasons, per-property findings,
    normalisation chain). REJECT when a property the model needs cannot be established, or when the predicted
    IoU at the image's own properties is below ``required_iou``; else PASS, or NORMALISE with the moves that
    the fit says raise the predicted IoU (``plan_moves``)."""
    props = image_properties(image)
    found, reject, reasons = {}, [], []
    if "reference_signal_e" in model.names and props["reference_signal_e"] is not None \
            and stated_air(image).transmission is None:
        reasons.append("atmospheric transmission not stated by the image's provenance: reference_signal_e taken "
                       "through transmission 1 (assumed)")
    for name in model.names:
        lo, hi = model.sampled_range(name)
        v = props.get(name)
        found[name] = {"value": v, "sampled_min": lo, "sampled_max": hi, "unit": UNITS[name],
                       "status": "unknown" if v is None else "inside" if lo <= v <= hi else "outside sampled range",
                       "source": "profile and provenance" if name in ("reference_signal_e", "haze_fraction")
                       else "profile"}
        if v is None and name == "haze_fraction":
            # the air of an image whose provenance does not state it (a real image): assumed as the nominal
            # point's, and said so; the other properties are established or the image is rejected
            props[name] = model.reference(name)
            found[name].update(value=props[name], status="assumed", source="the nominal point's (not stated)")
            reasons.append(f"haze_fraction not stated by the image's provenance: taken as the nominal point's "
                           f"{props[name]:.3g} (assumed)")
        elif v is None:
            reject.append(f"{name} cannot be determined (the profile lacks the geometry)")
    if reject:
        return reject, reasons, found, []
    mean, sd = model.predict(props)
    outside = [n for n in model.names if found[n]["status"] != "inside"]
    where = ", ".join(f"{n} {props[n]:.4g}" for n in model.names)
    line = (f"predicted IoU {mean:.3f} +- {sd:.3f} at the image's properties ({where})"
            + (f"; extrapolated in {', '.join(outside)}" if outside else ""))
    found["predicted_iou"] = {"value": mean, "sd": sd, "required": required_iou}
    if mean < required_iou:
        return [f"{line} is below the required IoU {required_iou:g}"], reasons, found, []
    reasons.append(f"{line} meets the required IoU {required_iou:g}")
    return reject, reasons, found, plan_moves(image, model, props, here=(mean, sd))


def store_properties(store) -> dict[str, float | None]:
    """The median of each property over the images of a `metraw.io.store.RawStore` (a point's test images); None
    for a property some image cannot state."""
    per_image = [image_properties(store[i]) for i in range(len(store))]
    if not per_image:
        raise MetrawError("an empty store has no image properties")
    return {name: (None if any(p[name] is None for p in per_image)
                   else float(np.median([p[name] for p in per_image]))) for name in PROPERTIES}


def property_lines(model: PropertyModel, at: Mapping[str, float]) -> dict[str, dict[str, Any]]:
    """Per property: the fit's argmax along it over the sampled range, the others at ``at`` (the nominal point's
    properties), with the sampled range; what spec.yaml's image_properties lines state under a property model."""
    return {name: {**model.optimum_line(name, at), "unit": UNITS[name]} for name in model.names}
