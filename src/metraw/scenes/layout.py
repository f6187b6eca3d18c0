"""Scene geometry: roads, parking lots, buildings, cars, trees and distractors, in metres.

A ``Scene`` is an ordered list of flat convex shapes (painted back to front, later shapes
occlude earlier ones) plus a table of *objects*: each shape belongs to one object, which
carries its per-band reflectance, height above ground [m], the cosine of the sun's
incidence on its surface, texture amplitudes, and whether it is a vehicle (the label).
Shadow casters are separate convex polygons with a height: a sample is in shadow when a
caster taller than the sample's own surface covers it.

Coordinates: x to the right (image columns), y down (image rows), in metres; the image
covers [0, size_m) x [0, size_m). Sun azimuth is measured from +x towards +y.
Layouts are drawn from one ``numpy.random.Generator``, so a seed fixes a scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

KINDS = ("urban", "suburban", "rural")

# Reflectances (R, G, B), typical values of dry materials in the visible (e.g. ASTER/ECOSTRESS
# spectral library orders of magnitude); each instance is jittered.
MATERIALS: dict[str, tuple[float, float, float]] = {
    # weathered city asphalt (the binder worn off the aggregate): 0.10-0.20 (LBNL heat-island measurements);
    # fresh asphalt (0.05) only in patches (``add_distractor`` "dark_rect"). 0.144 / 0.195 put the synthetic
    # cars' contrast against their surroundings where KIT AIS has it (``metraw.scenes.stats``; docs/sim-to-real.md).
    "asphalt": (0.144, 0.144, 0.136),
    "asphalt_old": (0.195, 0.1885, 0.1755),
    "concrete": (0.30, 0.29, 0.26),
    "sidewalk": (0.24, 0.23, 0.21),
    "marking": (0.55, 0.55, 0.52),
    "grass": (0.055, 0.11, 0.04),
    "dry_grass": (0.16, 0.17, 0.08),
    "crop": (0.07, 0.14, 0.05),
    "soil": (0.20, 0.15, 0.10),
    "gravel": (0.26, 0.24, 0.21),
    "tree": (0.035, 0.075, 0.03),
    "roof_tile": (0.28, 0.12, 0.08),
    "roof_grey": (0.18, 0.18, 0.18),
    "roof_dark": (0.07, 0.07, 0.075),
    "roof_gravel": (0.27, 0.26, 0.24),
    "roof_white": (0.60, 0.60, 0.58),
    "roof_metal": (0.33, 0.35, 0.37),
    "glass": (0.04, 0.05, 0.06),
}

# Car paint: (probability, reflectance). Shares close to German registrations (KBA 2023: grey 31 %, black 23 %,
# white 18 %, blue 10 %, silver 6 %, red 6 %): most cars are darker than a sunlit road.
CAR_COLOURS: list[tuple[float, tuple[float, float, float]]] = [
    (0.18, (0.62, 0.62, 0.60)),   # white
    (0.23, (0.035, 0.035, 0.04)),  # black
    (0.19, (0.11, 0.11, 0.12)),   # dark grey
    (0.12, (0.22, 0.22, 0.23)),   # mid grey
    (0.07, (0.32, 0.33, 0.34)),   # silver
    (0.10, (0.04, 0.07, 0.20)),   # blue
    (0.06, (0.36, 0.05, 0.04)),   # red
    (0.02, (0.06, 0.12, 0.07)),   # green
    (0.02, (0.22, 0.17, 0.12)),   # beige/brown
    (0.01, (0.50, 0.40, 0.05)),   # yellow
]

# Per-scene conditions the real data does not pin down (domain randomisation), drawn by ``draw_conditions``:
# aerosol optical depth at 550 nm, log-uniform (clean to hazy continental summer air; AERONET sites span
# 0.05-0.5); the sky view left to a surface in a cast shadow; the direct sunlight reflected onto shadowed
# surfaces by sunlit walls and ground (albedo 0.1-0.3 x view factor of the lit surroundings 0.2-0.5), in
# units of the direct beam; and the drone lens blur sigma [source pixels].
CONDITION_RANGES: dict[str, tuple[float, float]] = {
    "aerosol_depth_550": (0.05, 0.4),
    "shadow_sky_view": (0.6, 0.95),
    "bounce": (0.02, 0.15),
    "blur_px": (0.4, 1.2),
}

# Vehicle classes: (probability, length range [m], width range [m], height [m]).
VEHICLES = {
    "car": (0.82, (3.8, 5.0), (1.68, 1.90), 1.5),
    "van": (0.13, (4.9, 6.0), (1.90, 2.10), 2.2),
    "truck": (0.05, (7.0, 11.0), (2.40, 2.55), 3.2),
}


@dataclass
class Scene:
    """Geometry of one scene (see module docstring)."""

    kind: str
    size_m: float
    sun_azimuth_deg: float
    sun_elevation_deg: float
    # object table
    reflectance: list[tuple[float, float, float]] = field(default_factory=list)
    height_m: list[float] = field(default_factory=list)
    sun_cos: list[float] = field(default_factory=list)     # n . s, clipped at 0
    texture: list[tuple[float, float]] = field(default_factory=list)  # (coarse, fine) relative amplitude
    is_vehicle: list[bool] = field(default_factory=list)
    crown: list[bool] = field(default_factory=list)        # tree crown: hemispherical shading
    # shapes: (vertices (n, 2) convex CCW-or-CW, object id) or ("disc", cx, cy, r, object)
    shapes: list[tuple] = field(default_factory=list)
    casters: list[tuple[np.ndarray, float]] = field(default_factory=list)
    vehicles: list[dict] = field(default_factory=list)    # class, length_m, width_m, angle_deg, object
    # lighting and optics of this scene (keys of CONDITION_RANGES); a missing key: the renderer's setting
    conditions: dict[str, float] = field(default_factory=dict)

    # ------------------------------------------------------------------ building blocks
    @property
    def sun_vector(self) -> np.ndarray:
        """Unit vector towards the sun (x, y, z up)."""
        az, el = math.radians(self.sun_azimuth_deg), math.radians(self.sun_elevation_deg)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])

    def shadow_offset(self, height_m: float) -> np.ndarray:
        """Horizontal displacement [m] of the shadow of a point at ``height_m``."""
        s = self.sun_vector
        return -s[:2] / s[2] * height_m

    def new_object(self, reflectance, height_m=0.0, normal=(0.0, 0.0, 1.0), texture=(0.05, 0.03),
                   vehicle=False, crown=False) -> int:
        n = np.asarray(normal, dtype=np.float64)
        n = n / math.sqrt(float(n @ n))
        self.reflectance.append(tuple(float(v) for v in reflectance))
        self.height_m.append(float(height_m))
        self.sun_cos.append(max(0.0, float(n @ self.sun_vector)))
        self.texture.append((float(texture[0]), float(texture[1])))
        self.is_vehicle.append(bool(vehicle))
        self.crown.append(bool(crown))
        return len(self.reflectance) - 1

    def poly(self, verts, obj: int) -> None:
        self.shapes.append((np.asarray(verts, dtype=np.float64), obj))

    def disc(self, cx: float, cy: float, r: float, obj: int) -> None:
        self.shapes.append(("disc", float(cx), float(cy), float(r), obj))

    def cast(self, footprint, height_m: float) -> None:
        """Add the shadow of a vertical prism (convex ``footprint``, top at ``height_m``)."""
        fp = np.asarray(footprint, dtype=np.float64)
        self.casters.append((convex_hull(np.vstack([fp, fp + self.shadow_offset(height_m)])), float(height_m)))


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (monotone chain), counter-clockwise in (x, y), no repeated end point."""
    pts = np.unique(np.round(np.asarray(points, dtype=np.float64), 9), axis=0)
    if len(pts) < 3:
        return pts

    def half(seq):
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and _cross(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(o, a, b) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def rect(cx: float, cy: float, length: float, width: float, angle_rad: float) -> np.ndarray:
    """Corners of a rectangle centred at (cx, cy), ``length`` along ``angle_rad``."""
    u = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    v = np.array([-u[1], u[0]])
    c = np.array([cx, cy])
    hl, hw = length / 2, width / 2
    return np.array([c - hl * u - hw * v, c + hl * u - hw * v, c + hl * u + hw * v, c - hl * u + hw * v])


def local(cx, cy, angle_rad, pts) -> np.ndarray:
    """Points given in a body frame (along, across) mapped to the scene."""
    u = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    v = np.array([-u[1], u[0]])
    p = np.asarray(pts, dtype=np.float64)
    return np.array([cx, cy]) + p[:, :1] * u + p[:, 1:2] * v


def _jitter(rng, refl, rel=0.12):
    f = rng.normal(1.0, rel)
    tint = rng.normal(1.0, rel / 3, 3)
    return tuple(float(np.clip(r * f * t, 0.01, 0.95)) for r, t in zip(refl, tint))


# ---------------------------------------------------------------------- vehicles & objects
def add_vehicle(scene: Scene, rng: np.random.Generator, cx: float, cy: float, angle_rad: float,
                vclass: str | None = None) -> None:
    """A car/van/truck: body, windscreens, roof; it casts a shadow and is a labelled vehicle."""
    if vclass is None:
        names = list(VEHICLES)
        vclass = names[rng.choice(len(names), p=[VEHICLES[n][0] for n in names])]
    _, (l0, l1), (w0, w1), height = VEHICLES[vclass]
    length, width = rng.uniform(l0, l1), rng.uniform(w0, w1)
    probs = np.array([p for p, _ in CAR_COLOURS])
    paint = CAR_COLOURS[rng.choice(len(CAR_COLOURS), p=probs / probs.sum())][1]
    if vclass == "truck" and rng.random() < 0.6:
        paint = MATERIALS["roof_white"]
    paint = _jitter(rng, paint, 0.08)
    hl, hw = length / 2, width / 2
    ch = min(0.35, 0.18 * width)  # chamfered corners
    body = local(cx, cy, angle_rad, [(-hl + ch, -hw), (hl - ch, -hw), (hl, -hw + ch), (hl, hw - ch),
                                     (hl - ch, hw), (-hl + ch, hw), (-hl, hw - ch), (-hl, -hw + ch)])
    scene.cast(body, height)
    obj_body = scene.new_object(paint, height, texture=(0.02, 0.02), vehicle=True)
    scene.poly(body, obj_body)
    # glass mirrors the sky: from nearly black to a pale grey depending on the viewing geometry
    glass = _jitter(rng, tuple(g * rng.uniform(1.0, 4.0) for g in MATERIALS["glass"]), 0.2)
    if vclass == "car":
        # bonnet | windscreen | roof | rear window, along the body axis (front at +length)
        f_ws, r_ws = hl - 0.32 * length, hl - 0.48 * length
        r_rw, f_rw = -hl + 0.12 * length, -hl + 0.25 * length
        iw = hw - 0.12
        obj_g = scene.new_object(glass, height, texture=(0.02, 0.02), vehicle=True)
        scene.poly(local(cx, cy, angle_rad, [(r_ws, -iw), (f_ws, -iw + 0.12), (f_ws, iw - 0.12), (r_ws, iw)]), obj_g)
        scene.poly(local(cx, cy, angle_rad, [(r_rw, -iw + 0.1), (f_rw, -iw), (f_rw, iw), (r_rw, iw - 0.1)]), obj_g)
        # glossy roof: the paint plus the sky's specular reflection (what makes dark roofs grey from above)
        spec = rng.uniform(0.0, 0.08)
        roof = tuple(min(0.95, p * rng.normal(1.0, 0.05) + spec) for p in paint)
        obj_roof = scene.new_object(roof, height, texture=(0.02, 0.02), vehicle=True)
        scene.poly(local(cx, cy, angle_rad, [(f_rw + 0.05, -iw + 0.05), (r_ws - 0.05, -iw + 0.05),
                                             (r_ws - 0.05, iw - 0.05), (f_rw + 0.05, iw - 0.05)]), obj_roof)
        if rng.random() < 0.1:  # sunroof / panorama roof
            scene.poly(local(cx, cy, angle_rad, [(r_ws - 0.1, -0.4), (f_rw + 0.3, -0.4), (f_rw + 0.3, 0.4),
                                                 (r_ws - 0.1, 0.4)]), obj_g)
    else:
        cab = 1.6 if vclass == "van" else 2.2
        obj_g = scene.new_object(glass, height, texture=(0.02, 0.02), vehicle=True)
        scene.poly(local(cx, cy, angle_rad, [(hl - 0.25 * cab, -hw + 0.15), (hl - 0.05, -hw + 0.2),
                                             (hl - 0.05, hw - 0.2), (hl - 0.25 * cab, hw - 0.15)]), obj_g)
        if vclass == "truck":  # cargo box, slightly different shade from the cab
            box = _jitter(rng, paint, 0.1)
            obj_box = scene.new_object(box, height, texture=(0.03, 0.02), vehicle=True)
            scene.poly(local(cx, cy, angle_rad, [(-hl, -hw), (hl - cab - 0.2, -hw), (hl - cab - 0.2, hw), (-hl, hw)]),
                       obj_box)
    scene.vehicles.append({"class": vclass, "length_m": round(float(length), 3), "width_m": round(float(width), 3),
                           "angle_deg": round(math.degrees(angle_rad) % 360.0, 2), "object": obj_body})


def add_distractor(scene: Scene, rng: np.random.Generator, cx: float, cy: float, angle_rad: float,
                   base_height: float = 0.0) -> None:
    """Car-like things that are not vehicles: containers, dark rectangles, skips, roof units, skylights."""
    kind = rng.choice(["container", "dark_rect", "skip", "hvac", "skylight"])
    if kind == "container":
        length, width, h = rng.choice([6.06, 12.19]), 2.44, 2.6
        refl = _jitter(rng, [(0.30, 0.08, 0.05), (0.05, 0.10, 0.25), (0.12, 0.20, 0.10),
                             (0.35, 0.34, 0.32)][rng.integers(4)], 0.1)
        tex = (0.03, 0.06)
    elif kind == "dark_rect":  # tarpaulin, solar panel, dark patch of fresh asphalt
        length, width, h = rng.uniform(3.5, 5.5), rng.uniform(1.6, 2.4), 0.05
        refl, tex = _jitter(rng, (0.05, 0.05, 0.06), 0.2), (0.02, 0.02)
    elif kind == "skip":
        length, width, h = rng.uniform(3.0, 4.2), rng.uniform(1.6, 2.0), 1.4
        refl, tex = _jitter(rng, (0.25, 0.20, 0.06), 0.3), (0.06, 0.06)
    elif kind == "skylight":  # roof window or light dome: glass mirroring the sky, dark to pale
        length, width, h = rng.uniform(1.0, 3.0), rng.uniform(0.8, 1.8), 0.4
        refl, tex = _jitter(rng, tuple(g * rng.uniform(1.0, 8.0) for g in MATERIALS["glass"]), 0.2), (0.02, 0.02)
    else:
        length, width, h = rng.uniform(2.0, 4.5), rng.uniform(1.2, 2.0), 1.3
        refl, tex = _jitter(rng, (0.40, 0.40, 0.40), 0.2), (0.02, 0.04)
    fp = rect(cx, cy, length, width, angle_rad)
    scene.cast(fp, base_height + h)
    scene.poly(fp, scene.new_object(refl, base_height + h, texture=tex))
    if kind == "hvac" and rng.random() < 0.7:  # fan grille: a dark disc
        scene.disc(cx, cy, 0.3 * width, scene.new_object((0.05, 0.05, 0.05), base_height + h + 0.1, texture=(0.0, 0.05)))


#: Street furniture along sidewalks: (kind, probability). Lamp and signal heads on poles, shrubs, cabinets and
#: bins, bus shelters: the small round or boxy things beside the kerb a segmenter takes for cars unless it
#: has seen them (KIT AIS false alarms, 2026-11-25).
FURNITURE = (("lamp", 0.35), ("signal", 0.15), ("shrub", 0.25), ("cabinet", 0.17), ("shelter", 0.08))


def _circle(cx: float, cy: float, r: float, n: int) -> np.ndarray:
    """(n, 2) vertices of a regular n-gon of circumradius ``r`` [m] centred on (cx, cy): a disc's outline."""
    ang = np.arange(n) * 2 * math.pi / n
    return np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], axis=1)


def _pole(scene: Scene, x: float, y: float, height: float) -> None:
    """A thin pole: a dot from above and a line of shadow."""
    scene.cast(rect(x, y, 0.16, 0.16, 0.0), height)
    scene.disc(x, y, 0.1, scene.new_object((0.2, 0.2, 0.2), height, texture=(0.0, 0.0)))


def add_street_furniture(scene: Scene, rng: np.random.Generator, cx: float, cy: float, angle_rad: float,
                         toward_road: np.ndarray) -> None:
    """One piece of street furniture at (cx, cy) on a sidewalk; ``toward_road``: unit vector to the carriageway
    (a lamp's arm reaches over it). Not a vehicle."""
    kinds, probs = zip(*FURNITURE)
    kind = kinds[rng.choice(len(kinds), p=np.array(probs) / sum(probs))]
    if kind in ("lamp", "signal"):
        h = rng.uniform(6.0, 10.0) if kind == "lamp" else rng.uniform(2.5, 4.5)
        _pole(scene, cx, cy, h)
        hx, hy = np.array([cx, cy]) + toward_road * (rng.uniform(0.0, 1.8) if kind == "lamp" else 0.0)
        if kind == "lamp":
            refl = _jitter(rng, (0.35, 0.35, 0.34) if rng.random() < 0.6 else (0.07, 0.07, 0.08), 0.25)
        else:  # signal head, or a sign plate (white, blue, red)
            refl = _jitter(rng, [(0.04, 0.04, 0.04), (0.55, 0.55, 0.53), (0.05, 0.08, 0.25),
                                 (0.35, 0.05, 0.04)][rng.integers(4)], 0.15)
        if rng.random() < 0.5:
            r = rng.uniform(0.25, 0.55)
            scene.casters.append((_circle(hx, hy, r, 10) + scene.shadow_offset(h), h))
            scene.disc(hx, hy, r, scene.new_object(refl, h, texture=(0.02, 0.03)))
        else:
            head = rect(hx, hy, rng.uniform(0.5, 1.6), rng.uniform(0.3, 0.6), angle_rad + rng.choice([0.0, math.pi / 2]))
            scene.casters.append((head + scene.shadow_offset(h), h))
            scene.poly(head, scene.new_object(refl, h, texture=(0.02, 0.03)))
    elif kind == "shrub":
        r, h = rng.uniform(0.5, 1.4), rng.uniform(0.8, 2.2)
        ring = _circle(cx, cy, r, 12)
        scene.casters.append((convex_hull(np.vstack([ring, ring + scene.shadow_offset(h)])), h))
        scene.disc(cx, cy, r, scene.new_object(_jitter(rng, MATERIALS["tree"], 0.25), h, texture=(0.15, 0.18),
                                               crown=True))
    else:  # cabinet / bin / ticket machine, or a bus shelter
        if kind == "cabinet":
            length, width, h = rng.uniform(0.5, 1.5), rng.uniform(0.4, 0.8), rng.uniform(1.0, 1.6)
            refl = _jitter(rng, [(0.30, 0.30, 0.28), (0.06, 0.12, 0.07), (0.08, 0.08, 0.09),
                                 (0.45, 0.40, 0.10)][rng.integers(4)], 0.15)
        else:
            length, width, h = rng.uniform(3.0, 6.0), rng.uniform(1.4, 2.0), 2.5
            refl = _jitter(rng, (0.25, 0.26, 0.27) if rng.random() < 0.5 else (0.10, 0.11, 0.12), 0.2)
        fp = rect(cx, cy, length, width, angle_rad)
        scene.cast(fp, h)
        scene.poly(fp, scene.new_object(refl, h, texture=(0.03, 0.04)))


def add_tree(scene: Scene, rng: np.random.Generator, cx: float, cy: float, radius: float | None = None) -> None:
    """A tree crown (several overlapping lobes with hemispherical shading) and its shadow."""
    r = rng.uniform(2.0, 5.0) if radius is None else radius
    h = rng.uniform(1.6, 2.6) * r + 2.0
    leaf = _jitter(rng, MATERIALS["tree"], 0.2)
    n_lobes = int(rng.integers(3, 7))
    lobes = [(cx, cy, r * 0.75)]
    for _ in range(n_lobes):
        a, d = rng.uniform(0, 2 * math.pi), rng.uniform(0.2, 0.55) * r
        lobes.append((cx + d * math.cos(a), cy + d * math.sin(a), r * rng.uniform(0.35, 0.6)))
    for x, y, rr in lobes:
        off = scene.shadow_offset(h - 0.3 * r)
        ring = _circle(x, y, rr, 12)
        scene.casters.append((convex_hull(np.vstack([ring + scene.shadow_offset(h - 0.6 * r), ring + off])), h))
    for x, y, rr in lobes:
        scene.disc(x, y, rr, scene.new_object(_jitter(rng, leaf, 0.08), h, texture=(0.15, 0.18), crown=True))


def add_building(scene: Scene, rng: np.random.Generator, cx, cy, length, width, angle_rad, height,
                 roof: str | None = None, pitched: bool = False, equipment: int = 0) -> None:
    fp = rect(cx, cy, length, width, angle_rad)
    scene.cast(fp, height)
    roof = roof or str(rng.choice(["roof_grey", "roof_dark", "roof_gravel", "roof_white", "roof_metal", "roof_tile"]))
    refl = _jitter(rng, MATERIALS[roof], 0.12)
    if pitched:  # two planes meeting at the ridge along the length, slope 30-45 degrees
        slope = math.radians(rng.uniform(30, 45))
        u = np.array([math.cos(angle_rad), math.sin(angle_rad)])
        v = np.array([-u[1], u[0]])
        for side in (-1.0, 1.0):
            n = np.array([*(side * math.sin(slope) * v), math.cos(slope)])
            pts = local(cx, cy, angle_rad, [(-length / 2, 0), (length / 2, 0), (length / 2, side * width / 2),
                                            (-length / 2, side * width / 2)])
            scene.poly(pts, scene.new_object(refl, height, normal=n, texture=(0.05, 0.08)))
        return
    scene.poly(fp, scene.new_object(refl, height, texture=(0.06, 0.05)))
    parapet = _jitter(rng, MATERIALS["concrete"], 0.1)
    t = 0.4
    inner = rect(cx, cy, length - 2 * t, width - 2 * t, angle_rad)
    # parapet ring drawn as four thin rectangles over the roof edge
    for a, b in ((0, 1), (1, 2), (2, 3), (3, 0)):
        p, q = fp[a], fp[b]
        scene.poly(np.array([p, q, inner[b], inner[a]]), scene.new_object(parapet, height + 0.5, texture=(0.02, 0.03)))
    for _ in range(equipment):
        ex, ey = rng.uniform(-0.35, 0.35) * length, rng.uniform(-0.35, 0.35) * width
        p = local(cx, cy, angle_rad, [(ex, ey)])[0]
        add_distractor(scene, rng, p[0], p[1], angle_rad + rng.choice([0.0, math.pi / 2]), base_height=height)


# ---------------------------------------------------------------------- ground-level layers
def add_road(scene: Scene, rng, p0, angle_rad, length, lanes: int, lane_w=3.25, markings=True,
             sidewalk=2.5, material="asphalt", traffic=0.3, parked=0.5, furniture=0.0
             ) -> list[tuple[float, float, float, float]]:
    """A straight road through point ``p0`` with ``furniture`` pieces of street furniture per 100 m of each
    sidewalk. Returns parking slots along its curbs as (x, y, angle, dummy)."""
    cx, cy = p0
    width = lanes * lane_w
    if sidewalk:
        sw = _jitter(rng, MATERIALS["sidewalk"], 0.08)
        scene.poly(rect(cx, cy, length, width + 2 * sidewalk + (2 * 2.2 if parked else 0), angle_rad),
                   scene.new_object(sw, 0.0, texture=(0.05, 0.05)))
    park_w = 2.2 if parked else 0.0
    road = _jitter(rng, MATERIALS[material], 0.15)
    scene.poly(rect(cx, cy, length, width + 2 * park_w, angle_rad), scene.new_object(road, 0.0, texture=(0.10, 0.06)))
    mark = _jitter(rng, MATERIALS["marking"], 0.1)
    obj_m = scene.new_object(mark, 0.0, texture=(0.05, 0.08))
    if markings:
        for i in range(1, lanes):
            off = -width / 2 + i * lane_w
            dashed = i != lanes // 2 or lanes < 4
            if dashed:
                dash, gap = 3.0, rng.choice([6.0, 9.0])
                for s in np.arange(-length / 2, length / 2, dash + gap):
                    c = local(cx, cy, angle_rad, [(s + dash / 2, off)])[0]
                    scene.poly(rect(c[0], c[1], dash, 0.15, angle_rad), obj_m)
            else:
                for d in (-0.2, 0.2):
                    c = local(cx, cy, angle_rad, [(0, off + d)])[0]
                    scene.poly(rect(c[0], c[1], length, 0.12, angle_rad), obj_m)
        for side in (-1, 1):  # edge lines
            c = local(cx, cy, angle_rad, [(0, side * (width / 2 - 0.2))])[0]
            scene.poly(rect(c[0], c[1], length, 0.12, angle_rad), obj_m)
    # moving traffic in lanes (direction by side)
    for i in range(lanes):
        off = -width / 2 + (i + 0.5) * lane_w
        s = -length / 2 + rng.exponential(25.0)
        while s < length / 2:
            if rng.random() < traffic:
                c = local(cx, cy, angle_rad, [(s, off + rng.normal(0, 0.2))])[0]
                heading = angle_rad + (0.0 if off > 0 else math.pi) + rng.normal(0, 0.02)
                add_vehicle(scene, rng, c[0], c[1], heading)
            s += rng.uniform(8.0, 30.0)
    # parallel parking on both curbs
    if parked:
        for side in (-1, 1):
            off = side * (width / 2 + park_w / 2)
            s = -length / 2 + rng.uniform(0, 3)
            while s < length / 2:
                if rng.random() < parked:
                    c = local(cx, cy, angle_rad, [(s, off)])[0]
                    add_vehicle(scene, rng, c[0], c[1], angle_rad + (0 if rng.random() < 0.5 else math.pi)
                                + rng.normal(0, 0.02), vclass="car" if rng.random() < 0.9 else "van")
                s += rng.uniform(5.6, 7.5)
    if sidewalk and furniture > 0:
        normal = np.array([-math.sin(angle_rad), math.cos(angle_rad)])
        for side in (-1, 1):
            s = -length / 2 + rng.exponential(100.0 / furniture)
            while s < length / 2:
                inset = rng.uniform(0.3, max(0.31, sidewalk - 0.3))
                c = local(cx, cy, angle_rad, [(s, side * (width / 2 + park_w + inset))])[0]
                add_street_furniture(scene, rng, c[0], c[1], angle_rad, -side * normal)
                s += rng.exponential(100.0 / furniture)
    return []


def add_parking_lot(scene: Scene, rng, cx, cy, angle_rad, rows: int, slots: int, occupancy: float) -> None:
    """Rows of perpendicular bays (2.5 m x 5 m) with painted separators, aisles of 6 m."""
    bay_w, bay_l, aisle = 2.5, 5.0, 6.0
    length = slots * bay_w
    pair = 2 * bay_l + aisle
    depth = rows * bay_l + (rows // 2 + rows % 2) * aisle
    scene.poly(rect(cx, cy, length + 2, depth + 2, angle_rad),
               scene.new_object(_jitter(rng, MATERIALS[rng.choice(["asphalt", "asphalt_old"])], 0.1), 0.0,
                                texture=(0.12, 0.06)))
    obj_m = scene.new_object(_jitter(rng, MATERIALS["marking"], 0.1), 0.0, texture=(0.05, 0.08))
    for r in range(rows):
        block, inner = divmod(r, 2)
        row_c = -depth / 2 + block * pair + (bay_l / 2 if inner == 0 else bay_l * 1.5 + aisle)
        for k in range(slots + 1):
            c = local(cx, cy, angle_rad, [(-length / 2 + k * bay_w, row_c)])[0]
            scene.poly(rect(c[0], c[1], 0.12, bay_l, angle_rad), obj_m)
        for k in range(slots):
            if rng.random() < occupancy:
                c = local(cx, cy, angle_rad, [(-length / 2 + (k + 0.5) * bay_w + rng.normal(0, 0.15),
                                               row_c + rng.normal(0, 0.2))])[0]
                heading = angle_rad + math.pi / 2 + (0 if rng.random() < 0.5 else math.pi) + rng.normal(0, 0.04)
                add_vehicle(scene, rng, c[0], c[1], heading, vclass="car" if rng.random() < 0.92 else "van")
            elif rng.random() < 0.05:
                c = local(cx, cy, angle_rad, [(-length / 2 + (k + 0.5) * bay_w, row_c)])[0]
                add_distractor(scene, rng, c[0], c[1], angle_rad + math.pi / 2)


def _ground(scene: Scene, rng, materials: list[str], tiles: int) -> None:
    """Cover the scene with a patchwork of ground materials (rotated quads larger than the scene)."""
    s = scene.size_m
    big = 3 * s
    base = _jitter(rng, MATERIALS[materials[0]], 0.1)
    scene.poly(rect(s / 2, s / 2, big, big, 0.0), scene.new_object(base, 0.0, texture=(0.12, 0.15)))
    for _ in range(tiles):
        m = materials[int(rng.integers(len(materials)))]
        tex = (0.15, 0.2) if m in ("soil", "crop", "dry_grass", "grass") else (0.08, 0.1)
        scene.poly(rect(rng.uniform(0, s), rng.uniform(0, s), rng.uniform(0.3, 1.2) * s, rng.uniform(0.2, 0.8) * s,
                        rng.uniform(0, math.pi)), scene.new_object(_jitter(rng, MATERIALS[m], 0.12), 0.0, texture=tex))


# ---------------------------------------------------------------------- scene types
def draw_conditions(rng: np.random.Generator) -> dict[str, float]:
    """Lighting and optics of one scene, drawn from ``CONDITION_RANGES`` (aerosol depth log-uniform)."""
    out = {}
    for name, (lo, hi) in CONDITION_RANGES.items():
        v = math.exp(rng.uniform(math.log(lo), math.log(hi))) if name == "aerosol_depth_550" else rng.uniform(lo, hi)
        out[name] = round(float(v), 4)
    return out


def make_scene(kind: str, rng: np.random.Generator, size_m: float) -> Scene:
    """Draw the geometry of one scene of ``kind`` ("urban", "suburban", "rural")."""
    if kind not in KINDS:
        from metraw.errors import MetrawError

        raise MetrawError(f"unknown scene kind {kind!r}; expected one of {', '.join(KINDS)}")
    scene = Scene(kind, float(size_m), float(rng.uniform(0, 360)), float(rng.uniform(22, 65)))
    scene.conditions = draw_conditions(rng)
    {"urban": _urban, "suburban": _suburban, "rural": _rural}[kind](scene, rng)
    return scene


def _urban(scene: Scene, rng) -> None:
    s = scene.size_m
    theta = rng.uniform(0, math.pi)
    _ground(scene, rng, ["concrete", "sidewalk", "grass"], 2)
    c = np.array([s / 2, s / 2]) + rng.uniform(-0.25, 0.25, 2) * s
    # main road and maybe a cross street
    add_road(scene, rng, c, theta, 3 * s, lanes=int(rng.choice([2, 3, 4])), traffic=0.35, parked=rng.uniform(0.4, 0.9),
             material=str(rng.choice(["asphalt", "asphalt_old"])), furniture=rng.uniform(3.0, 12.0))
    u, v = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta), math.cos(theta)])
    if rng.random() < 0.5:
        add_road(scene, rng, c + u * rng.uniform(-0.3, 0.3) * s, theta + math.pi / 2, 3 * s, lanes=2,
                 traffic=0.3, parked=rng.uniform(0.3, 0.8), furniture=rng.uniform(3.0, 12.0))
    side = 1 if rng.random() < 0.5 else -1
    if rng.random() < 0.6:
        p = c + v * side * rng.uniform(14, 22) + u * rng.uniform(-10, 10)
        add_parking_lot(scene, rng, p[0], p[1], theta, rows=int(rng.choice([2, 4])), slots=int(rng.integers(6, 16)),
                        occupancy=rng.uniform(0.4, 0.95))
        side = -side
    for k in range(int(rng.integers(2, 5))):
        p = c + v * side * rng.uniform(18, 35) + u * rng.uniform(-35, 35)
        add_building(scene, rng, p[0], p[1], rng.uniform(15, 40), rng.uniform(10, 20), theta, rng.uniform(8, 30),
                     equipment=int(rng.integers(0, 5)))
        side = -side if rng.random() < 0.5 else side
    for _ in range(int(rng.integers(2, 10))):  # street trees along the curbs
        p = c + v * rng.choice([-1, 1]) * rng.uniform(5, 12) + u * rng.uniform(-35, 35)
        add_tree(scene, rng, p[0], p[1], rng.uniform(2.0, 4.0))
    for _ in range(int(rng.integers(0, 3))):
        p = rng.uniform(0, s, 2)
        add_distractor(scene, rng, p[0], p[1], theta + rng.choice([0.0, math.pi / 2]))


def _suburban(scene: Scene, rng) -> None:
    s = scene.size_m
    theta = rng.uniform(0, math.pi)
    _ground(scene, rng, ["grass", "grass", "dry_grass"], 4)
    c = np.array([s / 2, s / 2]) + rng.uniform(-0.3, 0.3, 2) * s
    u, v = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta), math.cos(theta)])
    add_road(scene, rng, c, theta, 3 * s, lanes=2, sidewalk=1.8, traffic=0.2, parked=rng.uniform(0.1, 0.4),
             markings=rng.random() < 0.6, furniture=rng.uniform(1.0, 5.0))
    for side in (-1, 1):
        x = -s
        while x < s:
            w = rng.uniform(9, 14)
            d = rng.uniform(13, 20)
            p = c + v * side * d + u * x
            add_building(scene, rng, p[0], p[1], rng.uniform(8, 13), rng.uniform(7, 10), theta, rng.uniform(6, 10),
                         roof=str(rng.choice(["roof_tile", "roof_tile", "roof_grey", "roof_dark"])), pitched=rng.random() < 0.8)
            # driveway with 0-2 cars
            q = c + v * side * (d / 2 + 1.0) + u * (x + w * 0.45 + 1.5)
            scene.poly(rect(q[0], q[1], d - 2, 3.2, theta + math.pi / 2),
                       scene.new_object(_jitter(rng, MATERIALS[rng.choice(["concrete", "gravel", "asphalt_old"])], 0.1),
                                        0.0, texture=(0.08, 0.08)))
            for k in range(int(rng.choice([0, 1, 1, 2]))):
                r = c + v * side * (d / 2 - 1.5 - 5.2 * k) + u * (x + w * 0.45 + 1.5)
                add_vehicle(scene, rng, r[0], r[1], theta + math.pi / 2 + rng.choice([0.0, math.pi]) + rng.normal(0, 0.03))
            x += w + rng.uniform(4, 10)
    for _ in range(int(rng.integers(6, 18))):
        p = c + v * rng.choice([-1, 1]) * rng.uniform(4, 35) + u * rng.uniform(-40, 40)
        add_tree(scene, rng, p[0], p[1])
    for _ in range(int(rng.integers(0, 3))):
        p = c + v * rng.choice([-1, 1]) * rng.uniform(8, 25) + u * rng.uniform(-30, 30)
        add_distractor(scene, rng, p[0], p[1], theta + rng.normal(0, 0.3))


def _rural(scene: Scene, rng) -> None:
    s = scene.size_m
    theta = rng.uniform(0, math.pi)
    _ground(scene, rng, ["crop", "soil", "dry_grass", "grass"], 3)
    c = np.array([s / 2, s / 2]) + rng.uniform(-0.35, 0.35, 2) * s
    u, v = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta), math.cos(theta)])
    add_road(scene, rng, c, theta, 3 * s, lanes=2, lane_w=3.0, sidewalk=0.0, markings=rng.random() < 0.5,
             traffic=0.15, parked=0.0, material=str(rng.choice(["asphalt", "asphalt_old"])))
    if rng.random() < 0.5:  # farmyard: a barn, a yard, a few vehicles and containers
        side = rng.choice([-1, 1])
        p = c + v * side * rng.uniform(18, 28) + u * rng.uniform(-15, 15)
        scene.poly(rect(p[0], p[1], 40, 25, theta), scene.new_object(_jitter(rng, MATERIALS["gravel"], 0.15), 0.0,
                                                                     texture=(0.2, 0.15)))
        q = p + v * side * 8
        add_building(scene, rng, q[0], q[1], rng.uniform(15, 30), rng.uniform(10, 15), theta, rng.uniform(6, 10),
                     roof=str(rng.choice(["roof_metal", "roof_grey", "roof_tile"])), pitched=True)
        for _ in range(int(rng.integers(1, 5))):
            r = p + u * rng.uniform(-15, 15) - v * side * rng.uniform(0, 6)
            if rng.random() < 0.7:
                add_vehicle(scene, rng, r[0], r[1], theta + rng.normal(0, 0.6))
            else:
                add_distractor(scene, rng, r[0], r[1], theta + rng.normal(0, 0.6))
    # hedgerows / tree lines
    for _ in range(int(rng.choice([0, 1, 1, 2]))):
        p0 = rng.uniform(0, s, 2)
        a = theta + rng.choice([0.0, math.pi / 2])
        for t in np.arange(-s, s, rng.uniform(6, 12)):
            p = p0 + t * np.array([math.cos(a), math.sin(a)]) + rng.normal(0, 0.8, 2)
            if -6 < p[0] < s + 6 and -6 < p[1] < s + 6:
                add_tree(scene, rng, p[0], p[1], rng.uniform(2.5, 4.5))
    for _ in range(int(rng.integers(0, 2))):
        p = rng.uniform(0, s, 2)
        add_distractor(scene, rng, p[0], p[1], rng.uniform(0, math.pi))
