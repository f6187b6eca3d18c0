"""End-to-end emulation: the raw image a target system would record of a source raw's scene.

docs/emulation.md. Per source colour c the light is thinned with p_c = alpha_c / phi_c,

    alpha_c = [A_t / h_t^2 * t_t * tau_t * eta_t,c * T_atm] / [A_s / h_s^2 * t_s * tau_s * eta_s,c]

(A aperture area, h altitude, t exposure, tau optical transmission, eta QE, phi_c the fraction of
source pixels of colour c): a source pixel stands for the c-light of its whole CFA cell, so its
photons are placed uniformly in that cell. Each photon is displaced by the target's system
kernel (polychromatic diffraction PSF of the annular aperture, uniform motion smear of length
v t along the track, Gaussian jitter), mapped to the target frame (GSD = pitch h / f, any
offset, rotation and non-integer GSD ratio) and detected only on a target pixel of its colour
(every pixel for a mono target). Then haze path radiance (Poisson), dark current, read noise,
gain, black, rounding, full well and ADC (`metraw.raw.sensor.readout`).

Two chains of one continuous model, each the other's test:

- photon (reference): counts (stochastically rounded, optionally pre-binned exactly into blocks
  no wider than ``max_prebin_fraction_of_psf`` of the PSF FWHM), binomial thinning, then every
  kept photon gets a continuous position: uniform in its cell (block), plus a PSF displacement
  drawn exactly (wavelength uniform in the band, radius by inverse CDF of the annulus encircled
  energy, its r^-2 tail beyond the table drawn from the asymptote), plus smear and jitter, in one
  compiled loop that draws its own random numbers (`metraw.physics.photon_landing`).
  Cost: O(kept photons): 35 ns a kept photon on one core, thinning included (93 ns with numpy's uniforms; 2026-11-27).
- expected (FFT): the same model in expectation, evaluated in the Fourier domain where it is exact:
  cell counts are spread onto an oversampled ground grid (Gaussian gridding, separable banded
  operators: `metraw.physics.gridding`), multiplied by the transfer functions (cell box, annulus OTF averaged over the band,
  smear, jitter, target pixel box) and evaluated at the target pixel centres (type-2 gridding).
  The OTF vanishes beyond D / lambda, so a grid at twice that band limit loses nothing; the
  gridding error is ~1e-5 of the signal. Then one Poisson draw per target pixel: its excess
  variance over the photon chain is of relative order p (reported), negligible for drone to
  satellite (p ~ 1e-4).
- ``mode="auto"``: "expected" when every p_c <= ``poisson_shortcut_max_p``, else "photon".

Edge policy (light that would come from ground outside the source frame):
``"reflect"`` (default): the scene is mirror-extended beyond the source footprint (exact for a flat
field; in the photon chain photons leaving the footprint are reflected back, the same for kernels
symmetric about the frame axes; for oblique smear the mirrored kernel is used, reported);
``"zero"``: no light from outside (edge pixels are darker); ``"valid"``: the target frame keeps
only pixels whose one-sided kernel tail beyond the footprint is <= ``kernel_flux_loss`` (a
kernel larger than the frame is an error saying so). The label mask follows the same geometry,
without blur: the car-area fraction of each target pixel (source cells assigned by centre).
"""

from __future__ import annotations

import math
from dataclasses import field

import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from metraw.emulate.plan import EmulationPlan, plan_emulation
from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.physics.accuracy import DEFAULT_ACCURACY, Accuracy
from metraw.physics.gridding import GaussianWindow
from metraw.physics.photon_landing import land_photons
from metraw.physics.rawfunc import stochastic_round, thin_counts
from metraw.raw.cfa import color_index, plane_offsets
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.sensor import readout, rng_from_seed

__all__ = ["emulate", "expected_electrons", "photon_electrons"]


# ----------------------------------------------------------------------------- source cells
def _cell_planes(source: RawImage, plan: EmulationPlan) -> dict[str, np.ndarray]:
    """Photoelectrons per source cell and colour, float64 (DN - black) / K summed over same-colour sites."""
    prof = source.profile
    step = 1 if prof.is_mono else 2
    hc, wc = plan.cells_shape
    data = source.data[: hc * step, : wc * step]
    out: dict[str, np.ndarray] = {}
    count: dict[str, int] = {}
    for ch, dy, dx in plane_offsets(prof.cfa_pattern):
        plane = data[dy::step, dx::step]
        if ch in out:
            out[ch] += plane
        else:
            out[ch] = plane.astype(np.float64)
        count[ch] = count.get(ch, 0) + 1
    for ch in out:
        out[ch] -= count[ch] * prof.black_level_dn
        out[ch] /= prof.gain_dn_per_e
    return out


def _saturated_cells(source: RawImage, plan: EmulationPlan) -> np.ndarray | None:
    sat = source.saturated()
    if not sat.any():
        return None
    step = 1 if source.profile.is_mono else 2
    hc, wc = plan.cells_shape
    s = sat[: hc * step, : wc * step]
    return s.reshape(hc, step, wc, step).any(axis=(1, 3)) if step == 2 else s


# ----------------------------------------------------------------------------- gridding
class _Fourier:
    """Type-1 gridding of cell values, transfer in Fourier space, type-2 evaluation at target pixel centres."""

    def __init__(self, plan: EmulationPlan):
        self.plan = plan
        hy, hx = plan.grid_h_m
        oy0, ox0 = plan.grid_origin
        Ny, Nx = plan.grid_shape
        hc, wc = plan.cells_shape
        cell = plan.cell_m
        self.periodic = per = plan.edge == "reflect"
        g = plan.gridding
        self.Sy = GaussianWindow((np.arange(hc) + 0.5) * cell / hy + oy0, Ny, per, *g)
        self.Sx = GaussianWindow((np.arange(wc) + 0.5) * cell / hx + ox0, Nx, per, *g)
        ht, wt = plan.frame_shape
        gt = plan.target_gsd_m
        c, s = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
        u = (np.arange(wt) + 0.5 - wt / 2) * gt
        v = (np.arange(ht) + 0.5 - ht / 2) * gt
        if s == 0.0:
            self.separable = True
            self.Ty = GaussianWindow((c * v + plan.centre_m[1]) / hy + oy0, Ny, per, *g)
            self.Tx = GaussianWindow((c * u + plan.centre_m[0]) / hx + ox0, Nx, per, *g)
        else:
            self.separable = False
            X = plan.centre_m[0] + c * u[None, :] - s * v[:, None]
            Y = plan.centre_m[1] + s * u[None, :] + c * v[:, None]
            self.px = (X / hx + ox0).ravel()
            self.py = (Y / hy + oy0).ravel()

    def grid(self, cells: np.ndarray) -> np.ndarray:
        # Sy @ cells @ Sx^T; the column scatter (scattered writes) costs ~4x the row scatter (whole rows) per element,
        # so it goes on the side with fewer rows: after the row scatter when the grid has fewer rows than the cells
        if self.Sy.n_grid < self.Sy.n_points:
            g = self.Sx.scatter_cols(self.Sy.scatter_rows(cells))
        else:
            g = self.Sy.scatter_rows(self.Sx.scatter_cols(cells))
        if self.periodic:  # even extension about ground 0 (and so about the far edge): g(k) += g(-k mod N)
            g = g + np.roll(g[::-1], 1, axis=0)
            g = g + np.roll(g[:, ::-1], 1, axis=1)
        return g

    def filtered(self, grid: np.ndarray, channel: str) -> np.ndarray:
        """The gridded cells times ``channel``'s transfer functions, back on the ground grid.

        The FFTs take scipy's workers (1 unless a caller sets ``scipy.fft.set_workers``; the values do not depend
        on it): the emulation and the training's field processes each fill a core, and a second FFT thread there
        cost ~70 % more CPU per transform (a 384 x 384 grid: 1.5 against 0.9 ms) and waited for a core (8.8 ms).
        """
        G = sfft.rfft2(grid) * self.plan.transfer[channel]
        return sfft.irfft2(G, self.plan.grid_shape)

    def evaluate(self, grid: np.ndarray, channel: str) -> np.ndarray:
        plan = self.plan
        g = self.filtered(grid, channel)
        if self.separable:
            return self.Tx.gather_cols(self.Ty.gather_rows(g))
        plan_m, plan_s = plan.gridding
        offs = np.arange(-plan_m, plan_m + 1)
        ky = np.rint(self.py).astype(np.int64)[:, None] + offs
        kx = np.rint(self.px).astype(np.int64)[:, None] + offs
        wy = np.exp(-0.5 * ((ky - self.py[:, None]) / plan_s) ** 2)
        wx = np.exp(-0.5 * ((kx - self.px[:, None]) / plan_s) ** 2)
        ky %= plan.grid_shape[0]
        kx %= plan.grid_shape[1]
        out = np.zeros(len(self.px))
        for a in range(offs.size):
            out += wy[:, a] * np.einsum("ij,ij->i", g[ky[:, a][:, None], kx], wx)
        return out.reshape(plan.frame_shape)

    def arrivals(self, cells: np.ndarray, channel: str) -> np.ndarray:
        """Expected photons of ``channel`` arriving in each target pixel from ``cells`` (already thinned)."""
        return self.evaluate(self.grid(cells), channel)


def _detect(target: TargetSystem, channel: str, shape) -> np.ndarray | None:
    if target.cfa_pattern == "mono":
        return None
    return color_index(target.cfa_pattern, shape) == target.channels.index(channel)


# ----------------------------------------------------------------------------- chains
def expected_electrons(source: RawImage, target: TargetSystem, accuracy: Accuracy | None = None,
                       edge: str = "reflect") -> tuple[np.ndarray, EmulationPlan]:
    """Expected detected photoelectrons per target pixel (signal only, before haze and dark), float64.

    Negative expectations (dark areas where the source's read noise dominates) are clipped at 0.
    """
    plan = plan_emulation(source.profile, source.shape, target, accuracy, edge)
    return _expected(_cell_planes(source, plan), plan, target, _Fourier(plan)), plan


def _expected(cells: dict[str, np.ndarray], plan, target, fourier) -> np.ndarray:
    out = np.zeros(plan.frame_shape)
    for c, e in cells.items():
        arrive = fourier.arrivals(plan.p[c] * e, c)
        det = _detect(target, c, plan.frame_shape)
        out += arrive if det is None else np.where(det, arrive, 0.0)
    return np.maximum(out, 0.0)


def photon_electrons(source: RawImage, target: TargetSystem, accuracy: Accuracy | None = None,
                     edge: str = "reflect", seed: int | np.random.Generator = 0) -> tuple[np.ndarray, EmulationPlan]:
    """One photon-exact draw of the detected photoelectrons per target pixel (int64), and the plan."""
    plan = plan_emulation(source.profile, source.shape, target, accuracy, edge)
    return _photons(_cell_planes(source, plan), plan, target, rng_from_seed(seed)), plan


def _photons(cells: dict[str, np.ndarray], plan: EmulationPlan, target, rng) -> np.ndarray:
    ht, wt = plan.frame_shape
    out = np.zeros(ht * wt, dtype=np.int64)
    B = plan.prebin
    block = B * plan.cell_m
    hc, wc = plan.cells_shape
    Hm, Wm = hc * plan.cell_m, wc * plan.cell_m
    c_r, s_r = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
    gt = plan.target_gsd_m
    table = plan.psf_table
    for c, e in cells.items():
        e = np.maximum(e, 0.0)
        if B > 1:
            hb, wb = -(-hc // B), -(-wc // B)
            pad = np.zeros((hb * B, wb * B))
            pad[:hc, :wc] = e
            e = pad.reshape(hb, B, wb, B).sum(axis=(1, 3))
        kept = thin_counts(stochastic_round(e, rng), plan.p[c], rng).ravel()
        det = _detect(target, c, plan.frame_shape)
        det_flat = np.ones(ht * wt, np.int8) if det is None else det.ravel().astype(np.int8)
        lo, hi = plan.bands[c]
        key = np.uint64(rng.integers(0, 2**64, dtype=np.uint64))  # this colour's photon stream
        land_photons(kept, e.shape[1], block, Wm * (1 - 1e-12) if B > 1 else 0.0, Hm * (1 - 1e-12) if B > 1 else 0.0,
                     key, lo, hi, plan.altitude_m / (math.pi * plan.diameter_m), table["ee"], table["v"],
                     table["guide"], table["v_max"], table["tail"], plan.smear_m * math.cos(plan.smear_angle_rad),
                     plan.smear_m * math.sin(plan.smear_angle_rad), plan.jitter_m, plan.edge == "reflect", Wm, Hm,
                     plan.centre_m[0], plan.centre_m[1], c_r, s_r, gt, wt, ht, det_flat, out)
    return out.reshape(ht, wt)


def _cell_mask(source: RawImage, plan: EmulationPlan) -> np.ndarray:
    """Car-area fraction of every source CFA cell (float64): the mean of its pixels' fractions."""
    step = 1 if source.profile.is_mono else 2
    hc, wc = plan.cells_shape
    m = source.mask[: hc * step, : wc * step]
    if step == 2:  # mean over the cell's four pixels (float32 sums of four fractions, then float64)
        return (m[0::2, 0::2] + m[0::2, 1::2] + m[1::2, 0::2] + m[1::2, 1::2]).astype(np.float64) / 4.0
    return m.astype(np.float64)


def _mask_fraction(source: RawImage, plan: EmulationPlan) -> np.ndarray:
    """Car-area fraction per target pixel: source cells assigned to the pixel holding their centre."""
    hc, wc = plan.cells_shape
    m = _cell_mask(source, plan)
    ht, wt = plan.frame_shape
    gt = plan.target_gsd_m
    c_r, s_r = math.cos(plan.rotation_rad), math.sin(plan.rotation_rad)
    x = (np.arange(wc) + 0.5) * plan.cell_m - plan.centre_m[0]
    y = (np.arange(hc) + 0.5) * plan.cell_m - plan.centre_m[1]
    if s_r == 0.0:  # axis-aligned frame: separable 0/1 assignment matrices
        col = np.floor(c_r * x / gt + wt / 2).astype(np.int64)
        row = np.floor(c_r * y / gt + ht / 2).astype(np.int64)
        okc, okr = (col >= 0) & (col < wt), (row >= 0) & (row < ht)
        ax = sp.csr_matrix((np.ones(okc.sum()), (col[okc], np.flatnonzero(okc))), shape=(wt, wc))
        ay = sp.csr_matrix((np.ones(okr.sum()), (row[okr], np.flatnonzero(okr))), shape=(ht, hc))
        total = np.asarray(ay @ (ax @ m.T).T)
        count = np.outer(np.asarray(ay.sum(axis=1)).ravel(), np.asarray(ax.sum(axis=1)).ravel())
        frac = np.where(count > 0, total / np.maximum(count, 1), 0.0)
        return np.clip(frac, 0.0, 1.0).astype(np.float32)
    col = np.floor((c_r * x[None, :] + s_r * y[:, None]) / gt + wt / 2).astype(np.int64)
    row = np.floor((-s_r * x[None, :] + c_r * y[:, None]) / gt + ht / 2).astype(np.int64)
    ok = (col >= 0) & (col < wt) & (row >= 0) & (row < ht)
    pix = (row * wt + col)[ok]
    total = np.bincount(pix, weights=m[ok], minlength=ht * wt)
    count = np.bincount(pix, minlength=ht * wt)
    frac = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return np.clip(frac, 0.0, 1.0).reshape(ht, wt).astype(np.float32)


def emulate(source: RawImage, target: TargetSystem, mode: str = "auto", seed: int | np.random.Generator = 0,
            accuracy: Accuracy | None = None, edge: str = "reflect") -> RawImage:
    """The raw image ``target`` would record of ``source``'s scene (see module docstring).

    ``mode``: "photon" | "expected" | "auto". The result carries the target's profile, the label
    mask (car-area fraction per target pixel), flags (FLAG_SATURATED where the target pixel
    saturates or where light from saturated source pixels exceeds ``kernel_flux_loss`` of its
    expected signal: their true value is unknown, only a lower bound) and a provenance entry
    with the effects modelled and skipped and the error bounds claimed.
    """
    if mode not in ("photon", "expected", "auto"):
        raise MetrawError(f"emulation mode must be photon, expected or auto, got {mode!r}")
    acc = accuracy or DEFAULT_ACCURACY
    rng = rng_from_seed(seed)
    plan = plan_emulation(source.profile, source.shape, target, acc, edge)
    pmax = max(plan.p.values())
    chain = mode if mode != "auto" else ("expected" if pmax <= acc.poisson_shortcut_max_p else "photon")
    cells = _cell_planes(source, plan)
    fourier = None
    mean_signal = None
    if chain == "photon":
        counts = _photons(cells, plan, target, rng).astype(np.float64)
    else:
        fourier = _Fourier(plan)
        mean_signal = _expected(cells, plan, target, fourier)
        counts = rng.poisson(mean_signal).astype(np.float64)
    tshape = plan.frame_shape
    haze = np.take(np.array([target.haze_for(c) for c in target.channels]), color_index(target.cfa_pattern, tshape))
    if np.any(haze > 0):
        counts += rng.poisson(haze)
    profile = target.profile()
    if source.profile.approximate:  # a raw rebuilt from a processed photo stays flagged through the emulation
        profile = profile.replace(approximate=True, approximate_reason="emulated from an approximate source: "
                                  + (source.profile.approximate_reason or "source profile marked approximate"))
    data = readout(counts, profile, rng)
    flags = np.zeros(tshape, np.uint8)
    sat_t = data >= profile.white_level_dn
    if profile.full_well_e is not None:
        sat_t |= counts >= profile.full_well_e
    flags[sat_t] |= FLAG_SATURATED
    sat_cells = _saturated_cells(source, plan)
    n_fed = 0
    if sat_cells is not None:
        fourier = fourier or _Fourier(plan)
        total = mean_signal if mean_signal is not None else _expected(cells, plan, target, fourier)
        sat_light = _expected({c: np.where(sat_cells, e, 0.0) for c, e in cells.items()}, plan, target, fourier)
        fed = sat_light > acc.kernel_flux_loss * np.maximum(total, 1e-300)
        n_fed = int(fed.sum())
        flags[fed] |= FLAG_SATURATED
    mask = _mask_fraction(source, plan) if source.mask is not None else None
    bounds = dict(plan.bounds)
    read_s2 = source.profile.read_noise_e**2 + 0.25
    clipped = {c: float(-np.minimum(e, 0).sum()) for c, e in cells.items()}
    mean_cell = max(1.0, float(np.mean([(e.sum() + clipped[c]) / e.size for c, e in cells.items()])))
    if chain == "expected":
        bounds["poisson_shortcut_excess_variance_rel"] = pmax * (1.0 + read_s2 / mean_cell)
    bounds["source_noise_excess_variance_rel"] = pmax * read_s2 / mean_cell
    mean_signal_e = float(counts.mean() - haze.mean())
    params = {
        "target": target.to_dict(), "mode": mode, "chain": chain, "seed": seed if isinstance(seed, int) else None,
        "accuracy": acc.to_dict(), **plan.summary(), "error_bounds": bounds, "clipped_negative_source_e": clipped,
        "saturated_source_cells": 0 if sat_cells is None else int(sat_cells.sum()),
        "target_pixels_fed_by_saturated": n_fed, "mean_signal_e": mean_signal_e,
        "haze_e": {c: target.haze_for(c) for c in target.channels},
        "deviation": ("source read noise and rounding are thinned with the signal (relative excess variance "
                      f"<= {bounds['source_noise_excess_variance_rel']:.2g})"
                      + ("; expected chain + one Poisson draw per pixel (relative excess variance "
                         f"<= {bounds['poisson_shortcut_excess_variance_rel']:.2g})" if chain == "expected" else "")),
    }
    out = source.derive(data, profile, function="emulate", params=params, mask=mask, flags=flags)
    out.meta["emulation"] = {"chain": chain, "gsd_ratio": plan.target_gsd_m / plan.source_gsd_m, "p": plan.p,
                             "mean_signal_e": mean_signal_e, "modelled": plan.modelled, "skipped": plan.skipped,
                             "error_bounds": bounds}
    return out
