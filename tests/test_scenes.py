"""Tests of the synthetic source dataset (metraw.scenes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from metraw.cli import main
from metraw.io.store import RawStore
from metraw.physics.daylight import neutral_response, solar_toa_irradiance_w_m2_m
from metraw.raw.sensor import rng_from_seed
from metraw.scenes import generate, generate_one, scene_camera
from metraw.scenes.layout import Scene, add_vehicle, make_scene, rect
from metraw.scenes.radiance import electrons_per_reflectance
from metraw.scenes.render import RenderSettings, render

ROOT = Path(__file__).resolve().parents[1]


def _flat_scene(size_m: float, refl=(0.2, 0.3, 0.25)) -> Scene:
    scene = Scene("rural", size_m, 30.0, 45.0)
    scene.poly(rect(size_m / 2, size_m / 2, 3 * size_m, 3 * size_m, 0.0), scene.new_object(refl, texture=(0.0, 0.0)))
    return scene


def test_same_seed_same_bytes_and_different_seed_differs():
    a = generate_one(4, 11, size_px=128)
    b = generate_one(4, 11, size_px=128)
    c = generate_one(4, 12, size_px=128)
    assert a.data.tobytes() == b.data.tobytes()
    assert a.mask.tobytes() == b.mask.tobytes() and a.flags.tobytes() == b.flags.tobytes()
    assert a.meta == b.meta
    assert a.data.tobytes() != c.data.tobytes()


def test_bytes_do_not_depend_on_worker_count_or_start():
    serial = list(generate(3, 5, size_px=64, workers=1))
    parallel = list(generate(3, 5, size_px=64, workers=2))
    tail = list(generate(1, 5, size_px=64, start=2))
    for s, p in zip(serial, parallel):
        assert s.data.tobytes() == p.data.tobytes() and s.mask.tobytes() == p.mask.tobytes()
    assert tail[0].data.tobytes() == serial[2].data.tobytes()
    assert [img.meta["scene_type"] for img in serial] == ["urban", "suburban", "rural"]


@pytest.mark.parametrize("angle_deg", [0.0, 17.0, 63.5])
def test_mask_is_exactly_the_rendered_car(angle_deg):
    """Untextured car of known reflectance on flat ground: each pixel's expected signal is
    ground + mask * (car - ground), so the mask and the rendered car are the same geometry."""
    cam = scene_camera()
    size = 160
    scene = _flat_scene(size * cam.gsd_m, refl=(0.1, 0.1, 0.1))
    car = scene.new_object((0.5, 0.5, 0.5), 1.5, texture=(0.0, 0.0), vehicle=True)
    poly = rect(4.7, 4.6, 4.5, 1.8, math.radians(angle_deg))
    scene.poly(poly, car)
    img, mean_e = render(scene, cam, size, rng_from_seed(1), RenderSettings(blur_px=0.0))
    k = electrons_per_reflectance(cam, scene.sun_elevation_deg, img.profile.exposure_s)
    cidx = img.color_index()
    for ci, c in enumerate("RGB"):
        kd, ks = k[c]
        e_per_refl = kd * scene.sun_cos[0] + ks
        sel = cidx == ci
        expected = e_per_refl * (0.1 + 0.4 * img.mask[sel])
        np.testing.assert_allclose(mean_e[sel], expected, rtol=2e-5)
    # area of the mask equals the polygon area up to the sampling of its edges
    area_true = 4.5 * 1.8
    area_mask = float(img.mask.sum()) * cam.gsd_m**2
    perimeter = 2 * (4.5 + 1.8)
    assert abs(area_mask - area_true) < 0.25 * perimeter * cam.gsd_m
    assert set(np.unique(img.mask)).issubset({0.0, 0.25, 0.5, 0.75, 1.0})


def test_shadowed_ground_gets_sky_view_and_bounce_light():
    """A flat ground half under a tall caster's shadow: the shadowed pixels get exactly
    rho (kd bounce sin(e) + ks V), the sunlit ones rho (kd sin(e) + ks), with the scene's own
    conditions (aerosol depth, sky view V, bounce) overriding the render settings."""
    cam = scene_camera()
    size = 64
    size_m = size * cam.gsd_m
    scene = _flat_scene(size_m, refl=(0.2, 0.2, 0.2))
    scene.conditions = {"aerosol_depth_550": 0.3, "shadow_sky_view": 0.7, "bounce": 0.1, "blur_px": 0.0}
    scene.casters.append((rect(size_m / 2, size_m * 0.25, 3 * size_m, size_m / 2, 0.0), 20.0))  # top half
    img, mean_e = render(scene, cam, size, rng_from_seed(0), RenderSettings(blur_px=0.5, aerosol_depth_550=0.05))
    k = electrons_per_reflectance(cam, 45.0, img.profile.exposure_s, aerosol_depth_550=0.3)
    sin_e = math.sin(math.radians(45.0))
    cidx = img.color_index()
    for ci, c in enumerate("RGB"):
        kd, ks = k[c]
        sel = cidx == ci
        top, bottom = sel[: size // 2 - 2], sel[size // 2 + 2:]
        np.testing.assert_allclose(mean_e[: size // 2 - 2][top], 0.2 * (kd * 0.1 * sin_e + ks * 0.7), rtol=2e-5)
        np.testing.assert_allclose(mean_e[size // 2 + 2:][bottom], 0.2 * (kd * sin_e + ks), rtol=2e-5)
    assert img.meta["conditions"]["bounce"] == 0.1 and img.provenance[0]["params"]["blur_px"] == 0.0


def test_tree_hides_car_from_the_mask():
    cam = scene_camera()
    size = 160
    scene = _flat_scene(size * cam.gsd_m)
    add_vehicle(scene, rng_from_seed(0), 4.7, 4.7, 0.0, vclass="car")
    full = scene.vehicles[0]["length_m"] * scene.vehicles[0]["width_m"]
    leaf = scene.new_object((0.04, 0.08, 0.03), 8.0, texture=(0.0, 0.0), crown=True)
    scene.disc(4.7 + 1.5, 4.7, 1.5, leaf)  # crown over the front half
    img, _ = render(scene, cam, size, rng_from_seed(0), RenderSettings(blur_px=0.0))
    visible = float(img.mask.sum()) * cam.gsd_m**2
    assert 0.3 * full < visible < 0.85 * full


def test_street_furniture_lines_the_sidewalks_and_is_never_a_car(monkeypatch):
    """Pieces come at the requested rate per 100 m of each sidewalk (Poisson, 5 sigma), all on the sidewalk band,
    and none of them enters the car mask."""
    import metraw.scenes.layout as layout

    placed = []
    real_add = layout.add_street_furniture

    def record(scene, rng, cx, cy, angle_rad, toward_road):
        placed.append((cx, cy, toward_road))
        real_add(scene, rng, cx, cy, angle_rad, toward_road)

    monkeypatch.setattr(layout, "add_street_furniture", record)
    scene = Scene("urban", 100.0, 30.0, 45.0)
    length, lanes, sidewalk, rate = 4000.0, 2, 2.5, 8.0
    layout.add_road(scene, rng_from_seed(4), (50.0, 50.0), 0.0, length, lanes=lanes, sidewalk=sidewalk, traffic=0.0,
                    parked=0.0, furniture=rate)
    expected = 2 * rate * length / 100.0
    assert abs(len(placed) - expected) < 5 * math.sqrt(expected)
    offsets = np.array([abs(cy - 50.0) for _, cy, _ in placed])
    kerb = lanes * 3.25 / 2
    assert offsets.min() >= kerb + 0.3 - 1e-9 and offsets.max() <= kerb + sidewalk - 0.3 + 1e-9
    assert all(np.sign(t[1]) == -np.sign(cy - 50.0) for _, cy, t in placed)  # arms reach over the road
    assert not any(scene.is_vehicle) and not scene.vehicles
    cam = scene_camera()
    size = 200
    street = Scene("urban", size * cam.gsd_m, 30.0, 45.0)
    layout.add_road(street, rng_from_seed(5), (street.size_m / 2,) * 2, 0.3, 3 * street.size_m, lanes=2,
                    traffic=0.0, parked=0.0, furniture=60.0)
    assert len(placed) > len(offsets)  # furniture was drawn in the rendered scene too
    img, _ = render(street, cam, size, rng_from_seed(0), RenderSettings(blur_px=0.0))
    assert float(img.mask.sum()) == 0.0


def test_flat_patch_noise_matches_profile():
    """Uniform ground, no texture, no blur: mean and variance of each colour plane match the
    EMVA model of the image's profile within 4 standard errors."""
    cam = scene_camera()
    size = 256
    scene = _flat_scene(size * cam.gsd_m)
    img, mean_e = render(scene, cam, size, rng_from_seed(3), RenderSettings(blur_px=0.0))
    p = img.profile
    dark = p.dark_current_e_per_s * p.exposure_s
    for ci in range(3):
        sel = img.color_index() == ci
        mu_e = float(mean_e[sel][0])
        assert np.all(mean_e[sel] == mu_e)
        x = img.data[sel].astype(np.float64)
        n = x.size
        mean_dn = p.black_level_dn + p.gain_dn_per_e * (mu_e + dark)
        var_dn = float(p.variance_dn2(mean_dn))
        assert abs(x.mean() - mean_dn) < 4 * math.sqrt(var_dn / n)
        assert abs(x.var(ddof=1) - var_dn) < 4 * var_dn * math.sqrt(2 / (n - 1))


def test_daylight_photon_counts_are_physical():
    lam = np.linspace(200e-9, 10e-6, 200000)
    total = float(np.trapezoid(solar_toa_irradiance_w_m2_m(lam), lam))
    assert abs(total - 1361.0) < 0.02 * 1361.0  # solar constant
    cam = scene_camera()
    k = electrons_per_reflectance(cam, 45.0, 1e-3)
    e_grey = {c: 0.3 * (kd * math.sin(math.radians(45)) + ks) for c, (kd, ks) in k.items()}
    assert all(2000 < e < cam.full_well_e for e in e_grey.values())  # thousands of e- for bright ground
    # e- scale with aperture area and exposure, not with altitude (etendue)
    k2 = electrons_per_reflectance(cam.replace(aperture_diameter_m=2 * cam.aperture_diameter_m,
                                               altitude_m=500.0), 45.0, 2e-3)
    assert math.isclose(k2["G"][0], 8 * k["G"][0], rel_tol=1e-12)
    # rendered scenes: hundreds of e- on dark asphalt in shadow, thousands on sunlit ground, never saturated
    # in the median (auto-exposure puts a sunlit 0.8 reflector at 0.9 of the full well)
    medians = [float(np.median(img.electrons())) for img in generate(6, 0, size_px=256)]
    assert all(300 < m < 0.5 * cam.full_well_e for m in medians) and float(np.median(medians)) > 800


def test_neutral_response_matches_the_rendered_grey_surface():
    """The channel ratios of a grey surface in daylight equal those of the absolute radiometry, and the
    blue channel of the default camera gets about half the green one (a bluish sun is still redder than
    the QE ratio alone suggests: 0.40 / 0.55 = 0.73)."""
    cam = scene_camera()
    for elevation in (20.0, 45.0, 70.0):
        k = electrons_per_reflectance(cam, elevation, 1e-3)
        grey = {c: kd * math.sin(math.radians(elevation)) + ks for c, (kd, ks) in k.items()}
        ratios = neutral_response(cam, elevation)
        assert max(ratios.values()) == 1.0
        for c in grey:
            assert math.isclose(ratios[c], grey[c] / max(grey.values()), rel_tol=1e-12)
    ratios = neutral_response(cam, 45.0)
    assert 0.45 < ratios["B"] / ratios["G"] < 0.60 and 0.85 < ratios["R"] / ratios["G"] < 0.95


def test_car_geometry_is_realistic():
    rng = rng_from_seed(2)
    lengths, widths = [], []
    for i in range(6):
        scene = make_scene(("urban", "suburban", "rural")[i % 3], rng, 60.0)
        lengths += [v["length_m"] for v in scene.vehicles if v["class"] == "car"]
        widths += [v["width_m"] for v in scene.vehicles if v["class"] == "car"]
    assert len(lengths) > 20
    assert 4.0 < np.median(lengths) < 4.8 and 1.7 < np.median(widths) < 1.9


def test_scene_camera_matches_params_yaml():
    params = ROOT / "params.yaml"
    import yaml

    src = yaml.safe_load(params.read_text())["source"]["camera"]
    cam = scene_camera()
    for key, value in src.items():
        assert getattr(cam, key) == value, key


def test_cli_writes_store_and_contact_sheet(tmp_path, capsys):
    out = tmp_path / "s.zarr"
    png = tmp_path / "sheet.png"
    assert main(["scenes", "--n", "3", "--seed", "1", "--size", "64", "--out", str(out), "--workers", "1",
                 "--contact-sheet", str(png), "--real-dir", str(tmp_path / "none")]) == 0
    store = RawStore.open(out)
    assert len(store) == 3
    assert [store.meta(i)["scene_type"] for i in range(3)] == ["urban", "suburban", "rural"]
    ref = generate_one(1, 1, size_px=64)
    assert store[1].data.tobytes() == ref.data.tobytes() and store[1].mask.tobytes() == ref.mask.tobytes()
    assert png.stat().st_size > 1000


def test_cli_bad_input_writes_nothing(tmp_path, capsys):
    out = tmp_path / "bad.zarr"
    assert main(["scenes", "--n", "2", "--size", "63", "--out", str(out)]) == 2
    assert main(["scenes", "--n", "2", "--kinds", "desert", "--size", "32", "--out", str(out), "--workers", "1"]) == 2
    assert "error" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".bad.zarr*"))


def test_stats_measure_known_inputs():
    from metraw.scenes.stats import mask_component_sizes_m, psd_slope

    white = rng_from_seed(0).standard_normal((256, 256))
    assert abs(psd_slope(white, 0.25)) < 0.2  # flat spectrum
    m = np.zeros((200, 200), np.float32)
    m[50:80, 40:116] = 1.0  # 76 x 30 px rectangle
    (length, width), = mask_component_sizes_m(m, 0.06)
    assert abs(length - 76 * 0.06) < 0.05 and abs(width - 30 * 0.06) < 0.05


def test_car_contrast_outline_and_box_regions():
    """A diagonal car of value a on a uniform ground b: its outline contrast is log2(a / b) exactly; its
    bounding box mixes in ground, log2((f a + (1 - f) b) / b) with f its share of the box."""
    from metraw.scenes.stats import _bounding_boxes, _region_contrast

    yy, xx = np.mgrid[0:120, 0:120]
    u, v = (xx - 60 + yy - 60) / np.sqrt(2), (yy - 60 - (xx - 60)) / np.sqrt(2)
    car = (np.abs(u) <= 20) & (np.abs(v) <= 8)
    a, b = 20.0, 80.0
    g = np.where(car, a, b)
    (outline,) = _region_contrast(g, car, ring_px=6)
    assert outline == pytest.approx(np.log2(a / b), abs=1e-12)
    box = _bounding_boxes(car)
    f = car.sum() / box.sum()
    assert 0.3 < f < 0.7  # diagonal: the box holds much ground
    (boxed,) = _region_contrast(g, box, ring_px=6)
    assert boxed == pytest.approx(np.log2((f * a + (1 - f) * b) / b), abs=1e-12)
    assert _region_contrast(g, np.zeros_like(car), ring_px=6) == []


# ---------------------------------------------------------------- compiled kernels against their numpy forms
def _reference_poly_spans(verts_s, n_rows, n_cols):
    """The scanline spans of a convex polygon as plain numpy (the renderer's former code)."""
    y0 = max(0, math.ceil(float(verts_s[:, 1].min())))
    y1 = min(n_rows - 1, math.floor(float(verts_s[:, 1].max())))
    if y1 < y0:
        return None
    rows = np.arange(y0, y1 + 1, dtype=np.float64)
    xmin, xmax = np.full(rows.shape, -np.inf), np.full(rows.shape, np.inf)
    p, q = verts_s, np.roll(verts_s, -1, axis=0)
    sign = 1.0 if float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1])) >= 0 else -1.0
    for (px, py), (qx, qy) in zip(p.tolist(), q.tolist()):
        a = -sign * (qy - py)
        b = sign * ((qx - px) * (rows - py) + (qy - py) * px)
        if a > 0:
            xmin = np.maximum(xmin, -b / a)
        elif a < 0:
            xmax = np.minimum(xmax, -b / a)
        else:
            xmax = np.where(b >= 0, xmax, -np.inf)
    lo, hi = np.clip(np.ceil(xmin), 0, n_cols), np.clip(np.floor(xmax) + 1, 0, n_cols)
    return rows.astype(np.int64), lo.astype(np.int64), hi.astype(np.int64)


def _reference_disc_spans(cx, cy, r, n_rows, n_cols):
    """The scanline spans of a disc as plain numpy (the renderer's former code)."""
    y0, y1 = max(0, math.ceil(cy - r)), min(n_rows - 1, math.floor(cy + r))
    if y1 < y0:
        return None
    rows = np.arange(y0, y1 + 1, dtype=np.float64)
    half = np.sqrt(np.maximum(r * r - (rows - cy) ** 2, 0.0))
    lo, hi = np.clip(np.ceil(cx - half), 0, n_cols), np.clip(np.floor(cx + half) + 1, 0, n_cols)
    return rows.astype(np.int64), lo.astype(np.int64), hi.astype(np.int64)


def _reference_paint(target, shapes, values):
    for s, v in zip(shapes, values):
        spans = (_reference_disc_spans(*s, *target.shape) if isinstance(s, tuple)
                 else _reference_poly_spans(s, *target.shape))
        if spans is not None:
            for r, a, b in zip(*(x.tolist() for x in spans)):
                if b > a:
                    target[r, a:b] = v


def _regular_polygon(rng, k, n):
    angles = np.sort(rng.uniform(0, 2 * np.pi, k))
    centre, radius = rng.uniform(-0.2 * n, 1.2 * n, 2), rng.uniform(0.5, 0.4 * n)
    verts = centre + radius * np.stack([np.cos(angles), np.sin(angles)], 1)
    return verts if rng.random() < 0.5 else verts[::-1].copy()  # both orientations


def test_compiled_painting_is_the_numpy_scanline_bit_for_bit():
    """Polygons of 3-200 vertices (both orientations, some outside the grid, one degenerate), discs, rectangles
    with sample-aligned edges: the compiled ``paint`` covers exactly the samples the numpy scanline code does,
    overwriting in order; and whole scenes rasterise to the same grids as that code."""
    from metraw.scenes.raster import PAIRWISE_BLOCK, paint, rasterise

    rng = np.random.default_rng(5)
    n = 97
    shapes = [_regular_polygon(rng, int(k), n) for k in rng.integers(3, 16, 60)]
    shapes += [_regular_polygon(rng, PAIRWISE_BLOCK + 72, n), _regular_polygon(rng, 9, n)]
    shapes += [np.array([[10.0, 10.0], [40.0, 10.0], [40.0, 30.0], [10.0, 30.0]]),  # edges through sample centres
               np.array([[5.0, 5.0], [50.0, 50.0], [20.0, 20.0]])]  # zero area
    shapes += [(float(x), float(y), float(r)) for x, y, r in zip(*rng.uniform([-10, -10, 0], [n + 10, n + 10, 30],
                                                                               (40, 3)).T)]
    order = rng.permutation(len(shapes))
    shapes = [shapes[i] for i in order]
    values = rng.integers(1, 60000, len(shapes)).astype(np.uint16)
    got, want = np.zeros((n, n + 5), np.uint16), np.zeros((n, n + 5), np.uint16)
    paint(got, shapes, values)
    _reference_paint(want, shapes, values)
    assert np.array_equal(got, want) and len(np.unique(got)) > 20

    camera = scene_camera()
    for i, kind in enumerate(("urban", "suburban", "rural")):
        scene = make_scene(kind, rng_from_seed(100 + i), 256 * camera.gsd_m)
        obj, caster_h, crowns = rasterise(scene, 256, camera.gsd_m, 2)
        d = camera.gsd_m / 2
        heights = np.asarray(scene.height_m)
        order = sorted(range(len(scene.shapes)), key=lambda j: (heights[scene.shapes[j][4] if isinstance(
            scene.shapes[j][0], str) else scene.shapes[j][1]], j))
        ref_shapes = [((s[1] / d - 0.5, s[2] / d - 0.5, s[3] / d), s[4]) if isinstance(s[0], str) else
                      (s[0] / d - 0.5, s[1]) for s in (scene.shapes[j] for j in order)]
        ref_obj = np.zeros_like(obj)
        _reference_paint(ref_obj, [s for s, _ in ref_shapes], [o for _, o in ref_shapes])
        ref_h = np.zeros_like(caster_h)
        casters = sorted(scene.casters, key=lambda c: c[1])
        _reference_paint(ref_h, [p / d - 0.5 for p, _ in casters], [np.float32(h) for _, h in casters])
        assert np.array_equal(obj, ref_obj) and np.array_equal(caster_h, ref_h)
        assert all(scene.crown[o] for o, *_ in crowns)
        for _, cx, cy, r, spans in crowns:  # the crowns' spans (shading boxes) are those painted
            want = _reference_disc_spans(cx, cy, r, *obj.shape)
            assert all(np.array_equal(a, b) for a, b in zip(spans, want))


def test_colour_blur_is_scipy_gaussian_filter_bit_for_bit():
    """``blur_at_colour`` gives scipy's ``gaussian_filter(mode="reflect")`` exactly at the colour's pixels (every
    CFA pattern, odd and even sizes, blurs whose radius reaches 1-6 pixels) and leaves the others alone."""
    from scipy import ndimage

    from metraw.raw.cfa import color_index
    from metraw.scenes.render import blur_at_colour, gaussian_weights

    rng = np.random.default_rng(8)
    for t, pattern in enumerate(("RGGB", "GRBG", "GBRG", "BGGR", "mono") * 4):
        h, w = int(rng.integers(12, 70)), int(rng.integers(12, 70))
        sigma = float(rng.uniform(0.2, 1.5))
        px = (rng.gamma(2.0, 1000.0, (h, w)) * rng.uniform(0.01, 3)).astype(np.float32)
        cidx = color_index(pattern, (h, w))
        want = ndimage.gaussian_filter(px, sigma, mode="reflect", truncate=4.0)
        for ci in np.unique(cidx):
            out = np.full((h, w), -1.0)
            blur_at_colour(px, gaussian_weights(sigma), cidx, ci, out)
            sel = cidx == ci
            assert np.array_equal(out[sel], want[sel].astype(np.float64)), (pattern, h, w, sigma, ci)
            assert np.all(out[~sel] == -1.0)
    out = np.full((12, 12), -1.0)  # a radius beyond the image would need repeated reflections: refused, untouched
    cidx = color_index("RGGB", (12, 12))
    assert not blur_at_colour(np.ones((12, 12), np.float32), gaussian_weights(3.5), cidx, 0, out)
    assert np.all(out == -1.0)


def test_value_noise_octave_is_the_numpy_bilinear_expression_bit_for_bit():
    from metraw.scenes.render import _add_bilinear

    rng = np.random.default_rng(9)
    for size, cell in ((64, 4), (96, 16), (50, 7)):
        m = size // cell + 2
        g = rng.standard_normal((m, m)).astype(np.float32)
        t = (np.arange(size, dtype=np.float32) + np.float32(0.5)) / np.float32(cell)
        i0 = np.floor(t).astype(np.int64)
        w = (t - i0).astype(np.float32)
        amp = np.float32(cell ** 1.3)
        start = rng.standard_normal((size, size)).astype(np.float32)
        rows = g[i0] * (1 - w)[:, None] + g[i0 + 1] * w[:, None]
        want = start + amp * (rows[:, i0] * (1 - w)[None, :] + rows[:, i0 + 1] * w[None, :])
        got = start.copy()
        _add_bilinear(got, g, i0, w, (1 - w).astype(np.float32), amp)
        assert got.dtype == np.float32 and np.array_equal(got, want)


@pytest.mark.parametrize("blur_px", [1.5, 6.0])
def test_lens_blur_of_a_shadow_edge_is_the_gaussian_filter_of_the_bands(blur_px):
    """A 16 px ground half in shadow, blurred by 1.5 px (the compiled per-colour filter) and by 6 px (a kernel wider
    than the image, reflected more than once: scipy's own filter): every pixel's expected electrons are the
    Gaussian filter of its band's two-level image, read at the pixel."""
    from scipy import ndimage

    cam = scene_camera()
    size = 16
    size_m = size * cam.gsd_m
    scene = _flat_scene(size_m, refl=(0.2, 0.2, 0.2))
    scene.conditions = {"aerosol_depth_550": 0.3, "shadow_sky_view": 0.7, "bounce": 0.1, "blur_px": blur_px}
    scene.casters.append((rect(size_m / 2, size_m * 0.25, 3 * size_m, size_m / 2, 0.0), 20.0))  # top half
    img, mean_e = render(scene, cam, size, rng_from_seed(0))
    k = electrons_per_reflectance(cam, 45.0, img.profile.exposure_s, aerosol_depth_550=0.3)
    sin_e = math.sin(math.radians(45.0))
    cidx = img.color_index()
    for ci, c in enumerate("RGB"):
        kd, ks = k[c]
        band = np.where(np.arange(size)[:, None] < size // 2, 0.2 * (kd * 0.1 * sin_e + ks * 0.7),
                        0.2 * (kd * sin_e + ks)) * np.ones((1, size))
        want = ndimage.gaussian_filter(band, blur_px, mode="reflect", truncate=4.0)
        sel = cidx == ci
        np.testing.assert_allclose(mean_e[sel], want[sel], rtol=1e-5)
