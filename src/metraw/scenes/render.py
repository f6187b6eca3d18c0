"""Render a ``Scene`` into a drone raw: supersampled radiance -> pixel integral -> optics -> sensor.

Steps (per scene):

1. Rasterise the painted shapes on a grid of ``supersample`` x ``supersample`` samples per source
   pixel (scanline spans of convex polygons and discs: exact point-in-shape tests at sample
   centres, compiled: ``metraw.scenes.raster``). Each sample gets the id of the topmost object (shapes are
   painted by increasing height, so a tree crown hides the car below it) and the height of the
   tallest shadow caster covering it.
2. Per sample and band: reflectance x irradiance, with irradiance = direct beam x (n . s) when the
   sample's surface is not below a taller caster's shadow, plus diffuse sky (reduced to the
   shadow sky view in shadow: the sky seen from a street next to a tall building is partly
   blocked); a shadowed sample also gets ``bounce`` x the direct beam, the sunlight reflected onto
   it by sunlit walls and ground. Tree crowns get hemispherical shading (normal of a half sphere) instead of a flat
   n . s. Texture: multiplicative 1/f-like value noise (smooth, several octaves) plus fine grain,
   amplitudes per object.
3. Integrate over each pixel: mean of its samples (box pixel, 100 % fill factor).
   Aerosol depth, shadow sky view, bounce and lens blur come from the scene's ``conditions``
   (drawn per scene by ``layout.draw_conditions``: domain randomisation) or, when a scene has
   none, from ``RenderSettings``.
4. Optics: Gaussian blur of sigma ``blur_px`` source pixels on each band's radiance, evaluated only at the
   pixels of the band's colour (``blur_at_colour``: scipy's filter there, bit for bit; diffraction at
   f/2.8 has sigma ~0.42 lambda N = 0.27 px at 550 nm; the rest stands for lens aberration and
   defocus, typical of a 1" drone camera). The label is not blurred: it is geometry.
5. Sensor: expected photoelectrons from the radiometry in ``radiance`` with the scene's exposure,
   RGGB mosaic (each pixel keeps its own band), then Poisson shot noise and ``metraw.raw.sensor.readout``
   (dark current, full well, read noise, gain, black level, ADC). Pixels whose photoelectron count
   reached full well are flagged ``FLAG_SATURATED``.

The car mask is the fraction of each pixel's samples whose *visible* surface belongs to a vehicle
(a car under a tree crown counts only where it is seen), so the mask and the rendered car are
the same geometry. All per-sample arithmetic is + - * / and sqrt (correctly rounded in IEEE 754),
so the rendering is bit-identical on any machine; random numbers come from PCG64 streams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy import ndimage

from metraw.raw.cfa import color_index
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import readout
from metraw.scenes.layout import Scene
from metraw.scenes.radiance import electrons_per_reflectance
from metraw.scenes.raster import rasterise

#: Relative diffuse-sky irradiance on a surface in a cast shadow (sky partly hidden by the caster).
SHADOW_SKY_VIEW = 0.75
#: Sky view factor of a tree crown sample (the crown hides part of its own sky).
CROWN_SKY_VIEW = 0.8


@dataclass(frozen=True)
class RenderSettings:
    """Rendering choices with their documented defaults.

    ``supersample``: samples per pixel side (2 -> 4 samples/pixel; mask fractions in steps of 1/4).
    ``blur_px``: Gaussian sigma of the drone lens PSF [source pixels].
    ``auto_exposure``: choose the exposure so that a sunlit white surface (reflectance
    ``white_reflectance``) fills ``target_fill`` of the full well, capped at the camera's
    ``exposure_s`` (what a drone's auto-exposure does); otherwise use ``camera.exposure_s``.
    ``aerosol_depth_550``: aerosol optical depth at 550 nm (clear day).
    ``shadow_sky_view``: fraction of the diffuse sky a surface in a cast shadow still sees.
    ``bounce``: direct sunlight reflected onto shadowed surfaces by their sunlit surroundings, as a
    fraction of the direct beam on a horizontal surface.
    """

    supersample: int = 2
    blur_px: float = 0.5
    auto_exposure: bool = True
    white_reflectance: float = 0.8
    target_fill: float = 0.9
    aerosol_depth_550: float = 0.12
    shadow_sky_view: float = SHADOW_SKY_VIEW
    bounce: float = 0.0

    def for_scene(self, scene: Scene) -> "RenderSettings":
        """These settings with the scene's own ``conditions`` (aerosol, shadow sky view, bounce, blur)."""
        from dataclasses import replace

        return replace(self, **scene.conditions)


def _crown_shading(obj: np.ndarray, crowns, sun: np.ndarray) -> np.ndarray | None:
    """n . s of a hemisphere on the visible samples of each crown disc (0 elsewhere), or None."""
    if not crowns:
        return None
    out = np.zeros(obj.shape, np.float32)
    for o, cx, cy, r, (rows, lo, hi) in crowns:
        a, b = int(lo.min()), int(hi.max())
        if b <= a:
            continue
        r0, r1 = int(rows[0]), int(rows[-1]) + 1
        sel = obj[r0:r1, a:b] == o
        if not sel.any():
            continue
        yy = (np.arange(r0, r1, dtype=np.float64) - cy)[:, None] / r
        xx = (np.arange(a, b, dtype=np.float64) - cx)[None, :] / r
        zz = np.sqrt(np.maximum(1.0 - xx * xx - yy * yy, 0.0))
        cosv = np.maximum(xx * sun[0] + yy * sun[1] + zz * sun[2], 0.0).astype(np.float32)
        block = out[r0:r1, a:b]
        block[sel] = cosv[sel]
    return out


# ---------------------------------------------------------------------- texture
def value_noise(rng: np.random.Generator, size: int, cells_px: tuple[int, ...], slope: float = 1.0) -> np.ndarray:
    """Smooth random field (size, size), unit standard deviation approximately.

    Sum of octaves of bilinearly interpolated Gaussian lattice noise with lattice spacings
    ``cells_px``; octave amplitude proportional to spacing**slope (slope 1 gives a power
    spectrum falling roughly as k^-4 over the octaves' range, like natural ground cover).
    Only + and * are used, so the field is bit-identical across machines.
    """
    out = np.zeros((size, size), np.float32)
    total = 0.0
    for cell in cells_px:
        m = size // cell + 2
        g = rng.standard_normal((m, m)).astype(np.float32)
        t = (np.arange(size, dtype=np.float32) + np.float32(0.5)) / np.float32(cell)
        i0 = np.floor(t).astype(np.int64)
        w = (t - i0).astype(np.float32)
        w = w * w * (np.float32(3) - np.float32(2) * w)  # smoothstep, no lattice creases
        amp = np.float32(float(cell) ** slope)
        _add_bilinear(out, g, i0, w, (1 - w).astype(np.float32), amp)
        total += float(amp) ** 2
    return out / np.float32(math.sqrt(total) * 0.6)


@nb.njit(cache=True, nogil=True)
def _add_bilinear(out, g, i0, w, omw, amp):
    """out += amp * field, field the lattice ``g`` interpolated at the (size,) nodes i0 + w along both axes
    (``omw`` = 1 - w): rows[i, j] = g[i0_i, j] omw_i + g[i0_i + 1, j] w_i, then the same along the columns.
    float32 throughout, each element's operations as numpy's array expression of it (no fused multiply-add):
    bit-identical to it, in one pass over ``out``."""
    size = i0.size
    rows = np.empty((size, g.shape[1]), np.float32)
    for i in range(size):
        a, wi, oi = i0[i], w[i], omw[i]
        for j in range(g.shape[1]):
            rows[i, j] = g[a, j] * oi + g[a + 1, j] * wi
    for i in range(size):
        for x in range(size):
            a = i0[x]
            out[i, x] += amp * (rows[i, a] * omw[x] + rows[i, a + 1] * w[x])


# ---------------------------------------------------------------------- lens blur
def gaussian_weights(sigma_px: float, truncate: float = 4.0) -> np.ndarray:
    """The correlation weights ``scipy.ndimage.gaussian_filter1d`` uses for ``sigma_px`` (radius
    int(truncate sigma + 1/2), normalised to sum 1), computed as it does."""
    radius = int(truncate * float(sigma_px) + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma_px * sigma_px) * x ** 2)
    return (phi / phi.sum())[::-1].copy()


@nb.njit(cache=True, nogil=True)
def _reflect(i, n):
    return -i - 1 if i < 0 else (2 * n - i - 1 if i >= n else i)


@nb.njit(cache=True, nogil=True)
def blur_at_colour(px, weights, cidx, ci, out):
    """out[r, c] = ``scipy.ndimage.gaussian_filter(px, sigma, mode="reflect")``[r, c] (px float32, ``weights`` =
    ``gaussian_weights(sigma)``) at the pixels where cidx == ci, bit for bit: scipy's
    symmetric correlation in float64 (centre term first, then the pairs from the outermost in), rows first, the
    intermediate rounded to float32 as scipy stores it. Only the rows that hold colour ``ci`` are filtered: half
    of them on a Bayer mosaic. Other pixels of ``out`` are left as they are. Returns False, writing nothing, when
    the radius exceeds the image (the reflection would have to repeat), else True."""
    h, w = px.shape
    rad = (weights.size - 1) // 2
    if rad > min(h, w):
        return False
    acc = np.empty(w, np.float64)
    tmp = np.empty(w + 2 * rad, np.float32)  # the row pass's output, padded by reflection
    wc = weights[rad]
    for r in range(h):
        hit = False
        for c in range(w):
            if cidx[r, c] == ci:
                hit = True
                break
        if not hit:
            continue
        for c in range(w):
            acc[c] = np.float64(px[r, c]) * wc
        for k in range(rad, 0, -1):
            ra, rb, wk = _reflect(r - k, h), _reflect(r + k, h), weights[rad - k]
            for c in range(w):
                acc[c] += (np.float64(px[ra, c]) + np.float64(px[rb, c])) * wk
        for c in range(w):
            tmp[rad + c] = np.float32(acc[c])
        for k in range(1, rad + 1):
            tmp[rad - k] = tmp[rad + _reflect(-k, w)]
            tmp[rad + w - 1 + k] = tmp[rad + _reflect(w - 1 + k, w)]
        for c in range(w):
            acc[c] = np.float64(tmp[rad + c]) * wc
        for k in range(rad, 0, -1):
            wk = weights[rad - k]
            for c in range(w):
                acc[c] += (np.float64(tmp[rad + c - k]) + np.float64(tmp[rad + c + k])) * wk
        for c in range(w):
            if cidx[r, c] == ci:
                out[r, c] = np.float32(acc[c])
    return True


# ---------------------------------------------------------------------- main entry
def scene_exposure_s(camera: CalibrationProfile, k: dict[str, tuple[float, float]], sun_cos_flat: float,
                     settings: RenderSettings) -> float:
    """Exposure [s] of one scene (see ``RenderSettings.auto_exposure``); ``k`` is per second."""
    t_max = camera.exposure_s
    if not settings.auto_exposure:
        return t_max
    peak_per_s = max(kd * sun_cos_flat + ks for kd, ks in k.values()) * settings.white_reflectance
    t = settings.target_fill * camera.saturation_e / peak_per_s
    return float(min(t_max, t))


@nb.njit(cache=True, nogil=True)
def _flat_pixels(obj, caster_h, ss, h_eps, sun_cos, sky_view, tex_amp, refl, is_crown, crowns, coarse, fine, bounce,
                 v_shadow, inv, kd, ks):
    """Per pixel of ``obj``'s (ss x ss)-sample grid, as if its samples all saw the object o of its first sample:
    the lit fraction L (samples not below a taller caster), direct d = n.s(o) L + bounce (1 - L), sky
    s = sky_view(o) (v_shadow + (1 - v_shadow) L), texture t = max(1 + a(o) coarse + b(o) fine, 0.05), and per
    band c the expected electrons refl(o, c) t (kd_c d + ks_c s). Returns (those values, (bands, n, n) float32;
    the pixels whose samples must be taken one by one: mixed objects, or a tree crown where ``crowns``). float32
    arithmetic in the order of the former numpy expressions (bit-identical to them)."""
    n = obj.shape[0] // ss
    nb_ = kd.size
    px = np.empty((nb_, n, n), np.float32)
    special = np.empty((n, n), np.bool_)
    one, floor_ = np.float32(1.0), np.float32(0.05)
    for y in range(n):
        for x in range(n):
            o = obj[y * ss, x * ss]
            h0 = h_eps[o]
            uniform = True
            lit = np.float32(0.0)
            for dy in range(ss):
                for dx in range(ss):
                    if obj[y * ss + dy, x * ss + dx] != o:
                        uniform = False
                    if caster_h[y * ss + dy, x * ss + dx] <= h0:
                        lit += one
            lit *= inv
            special[y, x] = (not uniform) or (crowns and is_crown[o])
            d = sun_cos[o] * lit
            d += bounce * (one - lit)
            s = sky_view[o] * (v_shadow + (one - v_shadow) * lit)
            t = max(one + tex_amp[o, 0] * coarse[y, x] + tex_amp[o, 1] * fine[y, x], floor_)
            for c in range(nb_):
                px[c, y, x] = refl[o, c] * t * (kd[c] * d + ks[c] * s)
    return px, special


@nb.njit(cache=True, nogil=True)
def _saturation_flags_at_readout(counts, data, full_well, white):
    """FLAG_SATURATED where the photoelectron count reached the full well or the DN the white level."""
    flags = np.zeros(counts.shape, np.uint8)
    for y in range(counts.shape[0]):
        for x in range(counts.shape[1]):
            if counts[y, x] >= full_well or data[y, x] >= white:
                flags[y, x] = FLAG_SATURATED
    return flags


@nb.njit(cache=True, nogil=True)
def _seen(obj, n_objects):
    """Whether each object id occurs in ``obj`` (uint16), for ids 0 .. max(n_objects, largest id + 1) - 1."""
    seen = np.zeros(65536, np.bool_)
    top = 0
    for v in obj.ravel():
        seen[v] = True
        top = max(top, np.int64(v) + 1)
    return seen[:max(n_objects, top)]


def render(scene: Scene, camera: CalibrationProfile, size_px: int, rng: np.random.Generator,
           settings: RenderSettings = RenderSettings()) -> tuple[RawImage, np.ndarray]:
    """Render ``scene`` to a ``RawImage`` (with mask, flags, meta) and return it with the
    noiseless expected photoelectrons per pixel (float64, for tests and statistics)."""
    settings = settings.for_scene(scene)
    ss = settings.supersample
    gsd = camera.gsd_m
    obj, caster_h, crowns = rasterise(scene, size_px, gsd, ss)

    heights = np.asarray(scene.height_m, np.float32)
    refl = np.asarray(scene.reflectance, np.float32)          # (n_obj, 3)
    sun_cos = np.asarray(scene.sun_cos, np.float32)
    tex_amp = np.asarray(scene.texture, np.float32)           # (n_obj, 2)
    is_veh = np.asarray(scene.is_vehicle, bool)
    is_crown = np.asarray(scene.crown, bool)
    sky_view = np.where(is_crown, np.float32(CROWN_SKY_VIEW), np.float32(1.0)).astype(np.float32)

    # texture at pixel resolution (constant over a pixel's samples)
    coarse = value_noise(rng, size_px, (256, 64, 16, 4), slope=1.0)
    fine = rng.standard_normal((size_px, size_px)).astype(np.float32)

    k_per_s = electrons_per_reflectance(camera.replace(exposure_s=1.0), scene.sun_elevation_deg, 1.0,
                                        settings.aerosol_depth_550)
    exposure_s = scene_exposure_s(camera, k_per_s, scene.sun_vector[2], settings)
    profile = camera.replace(exposure_s=exposure_s)
    kd_ks = [tuple(np.float32(v * exposure_s) for v in k_per_s[c]) for c in camera.channels]

    # Per sample: direct = n . s if the sample is not under a taller caster's shadow, else 0;
    # sky = sky view (x SHADOW_SKY_VIEW in shadow). Pixel integral = mean over samples of
    # refl[obj] * texture(obj) * (kd direct + ks sky). In a pixel whose samples all see one flat
    # object, refl, texture and n . s factor out exactly and only the lit fraction is averaged;
    # mixed pixels (edges) and tree crowns (curved) are evaluated sample by sample.
    h_eps = heights + np.float32(0.05)
    inv = np.float32(1.0 / (ss * ss))
    ob = obj.reshape(size_px, ss, size_px, ss)
    crown_cos = _crown_shading(obj, crowns, scene.sun_vector)
    v_shadow, bounce = np.float32(settings.shadow_sky_view), np.float32(settings.bounce * scene.sun_vector[2])
    px_all, special = _flat_pixels(obj, caster_h, ss, h_eps, sun_cos, sky_view, tex_amp, refl, is_crown,
                                   crown_cos is not None, coarse, fine, bounce, v_shadow, inv,
                                   np.array([k[0] for k in kd_ks], np.float32),
                                   np.array([k[1] for k in kd_ks], np.float32))
    mixed = np.flatnonzero(special)
    my, mx = np.divmod(mixed, size_px)
    m_obj = ob[my, :, mx, :].reshape(len(mixed), ss * ss).astype(np.intp)
    m_lit = caster_h.reshape(size_px, ss, size_px, ss)[my, :, mx, :].reshape(len(mixed), ss * ss) <= h_eps[m_obj]
    m_dir = sun_cos[m_obj]
    if crown_cos is not None:
        m_crown = crown_cos.reshape(size_px, ss, size_px, ss)[my, :, mx, :].reshape(len(mixed), ss * ss)
        m_dir = np.where(is_crown[m_obj], m_crown, m_dir)
    m_dir = np.where(m_lit, m_dir, bounce)
    m_sky = sky_view[m_obj] * np.where(m_lit, np.float32(1.0), v_shadow)
    tc, tf = coarse.ravel()[mixed][:, None], fine.ravel()[mixed][:, None]
    m_tex = np.maximum(1 + tex_amp[m_obj, 0] * tc + tex_amp[m_obj, 1] * tf, np.float32(0.05))

    cidx = color_index(camera.cfa_pattern, (size_px, size_px))
    mean_e = np.zeros((size_px, size_px), np.float64)
    weights = gaussian_weights(settings.blur_px) if settings.blur_px > 0 else None
    for ci, (kd, ks) in enumerate(kd_ks):
        px = px_all[ci]
        px.ravel()[mixed] = (refl[m_obj, ci] * m_tex * (kd * m_dir + ks * m_sky)).sum(axis=1) * inv
        if weights is None or not blur_at_colour(px, weights, cidx, ci, mean_e):
            if weights is not None:  # a blur wider than the image (reflected more than once): scipy's own filter
                px = ndimage.gaussian_filter(px, settings.blur_px, mode="reflect", truncate=4.0)
            sel = cidx == ci
            mean_e[sel] = px[sel]
    mask = np.take(is_veh, obj[::ss, ::ss]).astype(np.float32)
    mask.ravel()[mixed] = is_veh[m_obj].sum(axis=1).astype(np.float32) * inv

    counts = rng.poisson(mean_e)
    data = readout(counts, profile, rng)
    flags = _saturation_flags_at_readout(counts, data, float(profile.full_well_e or np.inf), profile.white_level_dn)

    vis = _seen(obj, len(heights))
    vehicles = [dict(v, visible_fraction=None) for v in scene.vehicles]
    visible_ids = set(np.flatnonzero(vis).tolist())
    meta = {
        "scene_type": scene.kind,
        "sun_azimuth_deg": round(scene.sun_azimuth_deg, 3),
        "sun_elevation_deg": round(scene.sun_elevation_deg, 3),
        "conditions": dict(scene.conditions),
        "gsd_m": gsd,
        "car_count": int(sum(1 for v in scene.vehicles if v["object"] in visible_ids)),
        "car_pixel_fraction": float(mask.mean()),
        "vehicles": [{k: v[k] for k in ("class", "length_m", "width_m", "angle_deg")} for v in vehicles
                     if v["object"] in visible_ids],
    }
    img = RawImage(data=data, profile=profile, mask=mask, flags=flags, meta=meta,
                   provenance=[{"function": "metraw.scenes.render",
                                "params": {"supersample": ss, "blur_px": settings.blur_px,
                                           "auto_exposure": settings.auto_exposure,
                                           "aerosol_depth_550": settings.aerosol_depth_550,
                                           "shadow_sky_view": settings.shadow_sky_view, "bounce": settings.bounce}}])
    return img, mean_e
