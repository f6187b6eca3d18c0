"""Raw functions: RawImage -> RawImage steps that keep pixel errors independent, of known
distribution and unbiased (docs/noise-model.md), or report the deviation they introduce.

Each function appends a provenance entry through `RawImage.derive`; where a step is not exact
its ``params["deviation"]`` says what differs from the ideal model and by how much.

Array-level building blocks (used by `metraw.emulate` too):
`stochastic_round`, `thin_counts`, `shoot` (multinomial photon redistribution through a kernel).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metraw.errors import MetrawError
from metraw.physics.atmosphere import path_radiance_electrons
from metraw.raw.cfa import cell_size, channel_names, plane_offsets
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import readout, rng_from_seed

__all__ = ["stochastic_round", "thin_counts", "shoot", "bin_same_colour", "thin", "redistribute",
           "add_poisson", "read_out"]


# ----------------------------------------------------------------------------- array helpers
def stochastic_round(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Integerise non-negative counts without bias: floor(x) + Bernoulli(frac(x)) (int64).

    The mean is kept exactly; the added variance is frac (1 - frac) <= 1/4 per element.
    Negative or non-finite input is an error (clip upstream and report it).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.size and (not np.all(np.isfinite(x)) or x.min() < 0):
        raise MetrawError("stochastic_round needs finite counts >= 0")
    base = np.floor(x)
    frac = x - base
    out = base.astype(np.int64)
    nz = frac > 0
    if np.any(nz):
        out[nz] += (rng.random(int(nz.sum())) < frac[nz])
    return out


def thin_counts(n: np.ndarray, p: float | np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Binomial thinning: keep each of ``n`` integer counts with probability ``p`` (int64).

    If n ~ Poisson(lam), the result is exactly Poisson(p lam), independent between elements.
    """
    p = np.asarray(p, dtype=np.float64)
    if p.size and (np.any(p < 0) or np.any(p > 1)):
        raise MetrawError(f"thinning probability must lie in [0, 1], got {p.min()}..{p.max()}")
    n = np.asarray(n)
    if n.size and n.min() < 0:
        raise MetrawError("thinning needs counts >= 0")
    return rng.binomial(n.astype(np.int64), p).astype(np.int64)


def shoot(counts: np.ndarray, kernel: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Photon shooting: move each of the integer ``counts`` (H, W) by an offset drawn from ``kernel``.

    ``kernel`` (kh, kw) with odd sides holds the probability of each offset (its centre is offset
    0; it is renormalised to sum 1). Returns ``full`` (H + kh - 1, W + kw - 1) int64 landing counts:
    the grid index of a photon from ``counts[i, j]`` displaced by kernel index (a, b) is
    (i + a, j + b), i.e. a true convolution ``full = counts (*) kernel`` in expectation.
    Every photon picks its destination independently (multinomial per source element), so landing
    counts of Poisson sources are independent Poisson. Cost: O(number of photons).
    """
    counts = np.asarray(counts)
    kernel = np.asarray(kernel, dtype=np.float64)
    kh, kw = kernel.shape
    h, w = counts.shape
    out_w = w + kw - 1
    out = np.zeros((h + kh - 1) * out_w, dtype=np.int64)
    flat = counts.ravel().astype(np.int64)
    total = int(flat.sum())
    if total == 0:
        return out.reshape(h + kh - 1, out_w)
    if kernel.min() < 0 or not kernel.sum() > 0:
        raise MetrawError("photon-shooting kernel must be >= 0 with a positive sum")
    cdf = np.cumsum(kernel.ravel())
    cdf /= cdf[-1]
    src = np.flatnonzero(flat)
    src_row, src_col = np.divmod(src, w)
    base = src_row * out_w + src_col  # landing index of offset (0, 0)
    # Photons are processed in chunks to bound memory (8 bytes per photon per temporary).
    chunk = 1 << 23
    reps = flat[src]
    starts = np.concatenate(([0], np.cumsum(reps)))
    first = 0
    while first < len(src):
        last = int(np.searchsorted(starts, starts[first] + chunk, side="right")) - 1
        last = max(last, first + 1)
        nph = int(starts[last] - starts[first])
        pos = np.repeat(base[first:last], reps[first:last])
        k = np.searchsorted(cdf, rng.random(nph), side="right")
        np.minimum(k, cdf.size - 1, out=k)
        a, b = np.divmod(k, kw)
        pos += a * out_w + b
        out += np.bincount(pos, minlength=out.size)
        first = last
    return out.reshape(h + kh - 1, out_w)


def _counts_estimate(image: RawImage, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """Integer photoelectron counts from DN: (DN - black)/K clipped at 0, stochastically rounded."""
    e = image.electrons()
    negative = e < 0
    clipped_mean = float(-e[negative].sum() / e.size) if np.any(negative) else 0.0
    n = stochastic_round(np.maximum(e, 0.0), rng)
    return n, {"negative_fraction": float(negative.mean()), "clipping_bias_e_per_pixel": clipped_mean}


def _saturation_flags(image: RawImage) -> np.ndarray:
    flags = np.zeros(image.shape, np.uint8) if image.flags is None else image.flags.copy()
    flags[image.saturated()] |= FLAG_SATURATED
    return flags


# ----------------------------------------------------------------------------- raw functions
def read_out(counts_e: np.ndarray, like: RawImage, profile: CalibrationProfile | None, rng, *,
             function: str, params: dict[str, Any], flags: np.ndarray | None = None,
             mask: Any = "keep") -> RawImage:
    """Digitise photoelectron counts with `metraw.raw.sensor.readout` into a derived RawImage.

    Pixels at or above the white level (or full well) are flagged saturated.
    """
    profile = profile or like.profile
    data = readout(counts_e, profile, rng)
    out_flags = np.zeros(data.shape, np.uint8) if flags is None else flags.copy()
    sat = data >= profile.white_level_dn
    if profile.full_well_e is not None:
        sat |= np.asarray(counts_e) >= profile.full_well_e
    out_flags[sat] |= FLAG_SATURATED
    return like.derive(data, profile, function=function, params=params, flags=out_flags, mask=mask)


def bin_same_colour(image: RawImage, factor: int) -> RawImage:
    """Exact binning: sum the DN of ``factor`` x ``factor`` same-colour pixels (CFA kept).

    In photoelectrons the sum of independent Poisson counts is Poisson and the sum of read noises
    is Gaussian with variance factor^2 sigma_d^2; so the output DN = sum(DN) - (m - 1) black
    (m = factor^2) is a raw with the same gain and black level, read noise
    sqrt(m sigma_d^2 + (m - 1) / (12 K^2)) (the m input roundings become additive noise), full well
    m times larger, pitch ``factor`` times larger. Deviation: the summed rounding noise is a sum of
    uniforms (Irwin-Hall), modelled as Gaussian. Rows/columns not filling a whole block are dropped.
    Output pixels fed by a saturated input are flagged saturated.
    """
    factor = int(factor)
    if factor < 1:
        raise MetrawError(f"binning factor must be >= 1, got {factor}")
    p = image.profile
    step = cell_size(p.cfa_pattern)
    block = step * factor
    h, w = image.shape
    hb, wb = h // block, w // block
    if hb == 0 or wb == 0:
        raise MetrawError(f"image {image.shape} is smaller than one {block} x {block} binning block")
    m = factor * factor

    def bin_array(a: np.ndarray, how: str) -> np.ndarray:
        a = a[: hb * block, : wb * block]
        out = np.empty((hb * step, wb * step), dtype=np.float64)
        for _, dy, dx in plane_offsets(p.cfa_pattern):
            plane = a[dy::step, dx::step].astype(np.float64).reshape(hb, factor, wb, factor)
            out[dy::step, dx::step] = plane.sum(axis=(1, 3)) if how == "sum" else plane.max(axis=(1, 3))
        return out

    total = bin_array(image.data, "sum") - (m - 1) * p.black_level_dn
    white = min(65535.0, (p.white_level_dn - p.black_level_dn) * m + p.black_level_dn)
    sat = bin_array(image.saturated().astype(np.uint8), "max") > 0
    flags = np.zeros(total.shape, np.uint8)
    if image.flags is not None:
        flags |= bin_array(image.flags, "max").astype(np.uint8)
    overflow = total > white
    flags[sat | overflow] |= FLAG_SATURATED
    data = np.clip(total, 0, white).astype(np.uint16)
    k = p.gain_dn_per_e
    read = math.sqrt(m * p.read_noise_e**2 + (m - 1) / (12.0 * k * k))
    profile = p.replace(
        read_noise_e=read, white_level_dn=white, adc_bits=max(p.adc_bits, int(math.ceil(math.log2(white + 1)))),
        full_well_e=None if p.full_well_e is None else p.full_well_e * m,
        dark_current_e_per_s=p.dark_current_e_per_s * m,
        pixel_pitch_m=None if p.pixel_pitch_m is None else p.pixel_pitch_m * factor,
    )
    mask = None
    if image.mask is not None:
        mm = image.mask[: hb * block, : wb * block].astype(np.float64)
        mask = np.empty_like(total, dtype=np.float32)
        for _, dy, dx in plane_offsets(p.cfa_pattern):
            mask[dy::step, dx::step] = mm[dy::step, dx::step].reshape(hb, factor, wb, factor).mean(axis=(1, 3))
    deviation = ("none" if m == 1 else
                 f"summed ADC rounding of {m} pixels (Irwin-Hall, variance {(m - 1) / 12:.3g} DN^2) "
                 "is modelled as Gaussian read noise")
    return image.derive(data, profile, function="bin_same_colour",
                        params={"factor": factor, "dropped_rows": h - hb * block, "dropped_cols": w - wb * block,
                                "deviation": deviation}, mask=mask, flags=flags)


def _per_pixel(image: RawImage, values: dict[str, float]) -> np.ndarray:
    """A per-channel value laid out on the image's CFA (one value per pixel)."""
    return np.take(np.array([values[c] for c in image.profile.channels]), image.color_index())


def thin(image: RawImage, p: float | dict[str, float], seed: int | np.random.Generator = 0,
         profile_changes: dict[str, Any] | None = None) -> RawImage:
    """Binomial thinning: keep each photoelectron with probability ``p`` (one value or per channel).

    Counts are estimated as (DN - black)/K, clipped at 0 and stochastically rounded; each is
    thinned with `thin_counts` and read out again with fresh read noise and dark current.
    ``profile_changes`` sets the new geometry (e.g. ``{"exposure_s": ...}``) that the thinning
    stands for. Deviation (reported): the source's read noise and rounding (variance at most
    sigma_d^2 + 1/4 on the estimated counts) are thinned with the signal, Var = p lam + p^2 (sigma_d^2 + 1/4):
    an excess variance of at most p^2 (sigma_d^2 + 1/4) e-^2 per pixel over Poisson(p lam) (relative order
    p sigma_d^2 / lam); clipping negative counts biases dark pixels by p times the reported clipping bias.
    """
    rng = rng_from_seed(seed)
    prof = image.profile
    channels = channel_names(prof.cfa_pattern)
    pmap = {c: float(p) for c in channels} if not isinstance(p, dict) else {c: float(p[c]) for c in channels}
    n, info = _counts_estimate(image, rng)
    kept = thin_counts(n, _per_pixel(image, pmap), rng)
    new_profile = prof.replace(**(profile_changes or {}))
    pmax = max(pmap.values())
    info["deviation"] = (f"source read noise and rounding thinned with the signal: excess variance <= "
                         f"{pmax**2 * (prof.read_noise_e**2 + 0.25):.3g} e-^2 per pixel (p^2 (sigma_d^2 + 1/4), "
                         f"p = {pmax:.3g})")
    return read_out(kept, image, new_profile, rng, function="thin",
                    params={"p": pmap, **info}, flags=_saturation_flags(image))


def atmosphere(image: RawImage, transmission: float, path_radiance_w_m2_sr_m: float, exponent: float = 2.0,
               seed: int | np.random.Generator = 0) -> RawImage:
    """The image seen through (more) atmosphere: the scene's light thinned by ``transmission`` (binomial,
    exact) plus path radiance collected through the image's own optics (independent Poisson, exact).

    ``path_radiance_w_m2_sr_m``: spectral path radiance at 550 nm with spectral slope ``exponent``
    (`metraw.physics.atmosphere`); its photoelectrons per pixel follow from the profile's pitch, focal length,
    aperture, exposure, optics transmission, QE and bands. Counts are estimated, thinned and read out
    again as in `thin`; the same deviation is reported (the source's read noise and rounding are thinned
    with the signal: excess variance <= T^2 (sigma_d^2 + 1/4) e-^2; none for a noiseless integer source).
    """
    if not 0 <= transmission <= 1:
        raise MetrawError(f"atmosphere: transmission must lie in [0, 1], got {transmission!r}")
    rng = rng_from_seed(seed)
    prof = image.profile
    haze = path_radiance_electrons(prof, float(path_radiance_w_m2_sr_m), float(exponent))
    n, info = _counts_estimate(image, rng)
    kept = thin_counts(n, float(transmission), rng)
    added = rng.poisson(_per_pixel(image, haze))
    info["deviation"] = (f"source read noise and rounding thinned with the signal: excess variance <= "
                         f"{transmission**2 * (prof.read_noise_e**2 + 0.25):.3g} e-^2 per pixel")
    return read_out(kept + added, image, prof, rng, function="atmosphere",
                    params={"transmission": float(transmission), "path_radiance_w_m2_sr_m": float(path_radiance_w_m2_sr_m),
                            "path_radiance_exponent": float(exponent), "haze_e": haze, **info},
                    flags=_saturation_flags(image))


def redistribute(image: RawImage, kernel: np.ndarray, seed: int | np.random.Generator = 0) -> RawImage:
    """Photon redistribution: each photoelectron moves by an offset drawn from ``kernel``.

    ``kernel`` (odd sides, >= 0) is a probability over offsets in units of the CFA cell: a photon
    stays on its own colour plane, so colours never mix. Photons leaving the frame are lost
    (edge policy: no light enters from outside; the lost fraction is reported). Output counts are
    independent Poisson when the input counts are. Deviation (reported): the source read noise
    (sigma_d^2 + 1/4 e-^2 per pixel) travels with the photons and fresh read noise is added.
    """
    rng = rng_from_seed(seed)
    kernel = np.asarray(kernel, dtype=np.float64)
    if kernel.ndim != 2 or kernel.shape[0] % 2 == 0 or kernel.shape[1] % 2 == 0:
        raise MetrawError(f"kernel must be 2-D with odd sides, got shape {kernel.shape}")
    prof = image.profile
    step = cell_size(prof.cfa_pattern)
    n, info = _counts_estimate(image, rng)
    out = np.zeros_like(n)
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    total_in = int(n.sum())
    for _, dy, dx in plane_offsets(prof.cfa_pattern):
        plane = n[dy::step, dx::step]
        full = shoot(plane, kernel, rng)
        out[dy::step, dx::step] = full[ry: ry + plane.shape[0], rx: rx + plane.shape[1]]
    info["lost_fraction"] = float(1.0 - out.sum() / total_in) if total_in else 0.0
    info["deviation"] = (f"source read noise travels with the photons: excess variance <= "
                         f"{prof.read_noise_e**2 + 0.25:.3g} e-^2 per pixel")
    flags = _saturation_flags(image)
    sat = (flags & FLAG_SATURATED) != 0
    if np.any(sat):  # a saturated source pixel feeds every pixel its kernel reaches
        from scipy.ndimage import binary_dilation

        for _, dy, dx in plane_offsets(prof.cfa_pattern):
            grown = binary_dilation(sat[dy::step, dx::step], structure=kernel > 0)
            flags[dy::step, dx::step][grown] |= FLAG_SATURATED
    return read_out(out, image, prof, rng, function="redistribute",
                    params={"kernel_shape": list(kernel.shape), **info}, flags=flags)


def add_poisson(image: RawImage, mean_e: float | np.ndarray, seed: int | np.random.Generator = 0,
                label: str = "poisson") -> RawImage:
    """Add independent Poisson photoelectrons of mean ``mean_e`` (haze path radiance, dark current).

    The sum of independent Poisson terms is Poisson, so the noise model keeps its form; the DN
    become rint(DN + K k). Deviation (reported): when K k is not an integer the new rounding adds
    up to 1/12 DN^2 to a pixel's variance. Pixels pushed to the white level are flagged saturated.
    """
    rng = rng_from_seed(seed)
    mean = np.broadcast_to(np.asarray(mean_e, dtype=np.float64), image.shape)
    if not np.all(np.isfinite(mean)) or mean.min() < 0:
        raise MetrawError(f"{label}: mean photoelectrons must be finite and >= 0")
    k = image.profile.gain_dn_per_e
    added = rng.poisson(mean)
    dn = np.rint(image.data.astype(np.float64) + k * added)
    white = image.profile.white_level_dn
    flags = _saturation_flags(image)
    flags[dn >= white] |= FLAG_SATURATED
    data = np.minimum(dn, white).astype(np.uint16)
    exact = float(k).is_integer()
    return image.derive(data, function="add_poisson",
                        params={"label": label, "mean_e": float(mean.mean()),
                                "deviation": "none" if exact else "re-rounding adds <= 1/12 DN^2 per pixel"},
                        flags=flags)
