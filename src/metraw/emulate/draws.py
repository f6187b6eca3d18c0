"""Fresh target images of one source scene, each draw cheap: the expected stage cached (issue #15).

A target pixel grid can lie anywhere on the ground: at a GSD ratio of ~8 one source scene gives
many distinct target images, differing in where the pixel (and CFA) boundaries fall, plus fresh
photon and read noise. ``PhaseField`` evaluates the emulator's expected chain
(`metraw.emulate`, "expected" mode: cell photons thinned, gridded, multiplied by the transfer
functions - annulus OTF, smear, jitter, target pixel box - and evaluated at pixel centres) once,
on a lattice ``oversample`` (K) times finer than the target pixels, for every source colour.
A draw then

1. picks a sampling phase (a, b) in [0, 2K)^2 lattice steps: target pixel centres are every K-th
   lattice point from (a, b), so the phase spans one whole CFA period (2 pixels) in steps of GSD/K;
2. picks a flip of the scene about the footprint centre (x, y or both): with an axis-aligned
   track the transfer functions are even in each axis (uniform smear is symmetric), so the
   flipped array *is* the field of the flipped scene. Rotations by 90 degrees would turn the
   smear across track and are not drawn;
3. lays the target CFA on the chosen pixels (each pixel detects its own colour's arrivals),
   then one Poisson draw per pixel, haze (Poisson), dark current, read noise, gain, black, ADC
   (`metraw.raw.sensor.readout`) - exactly ``emulate(mode="expected")`` of the flipped scene with
   ``frame_offset_m = GSD (a / K - 1 + 1 / (2K))`` and a frame 2 pixels smaller than the full one.

Labels: the car fraction per target pixel, source cells assigned by centre (as
`metraw.emulate`): cell car fractions are summed once into sub-cells of GSD/K, and a pixel
sums its K x K sub-cells. The lattice values are exact evaluations of the continuous model, not
interpolations: a draw at phase (a, b) equals the emulator's expected chain at that offset to
its gridding accuracy (tests/test_draws.py). Memory: 3 float32 lattices of ~(2 x frame)^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from metraw.emulate.emulator import _cell_mask, _cell_planes, _detect, _Fourier, _saturated_cells
from metraw.emulate.plan import plan_emulation
from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.physics.accuracy import DEFAULT_ACCURACY, Accuracy
from metraw.physics.gridding import GaussianWindow
from metraw.raw.cfa import color_index
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.sensor import readout, rng_from_seed

__all__ = ["PhaseField", "build_field", "DEFAULT_OVERSAMPLE"]

#: Lattice steps per target pixel: 2 gives 16 sampling phases per CFA period (4 per axis).
DEFAULT_OVERSAMPLE = 2


@dataclass
class PhaseField:
    """Expected arrivals of one source scene at one target on a K-fold lattice (see module docstring).

    ``field[c]``: float32 (ny, nx) expected photoelectrons of source colour c arriving in a target
    pixel centred on each lattice point; ``sat[c]``: the same for light from saturated source
    cells (None when there are none); ``sub_total``: float32 (ny + K - 1, nx + K - 1) summed car
    fraction of the source cells in each GSD/K sub-cell, ``sub_count_y/x``: cells per sub-cell
    row/column (separable). ``frame_shape``: the drawn target frame (rows, cols).
    """

    target: TargetSystem
    oversample: int
    frame_shape: tuple[int, int]
    field: dict[str, np.ndarray]
    sat: dict[str, np.ndarray] | None
    sub_total: np.ndarray | None
    sub_count_y: np.ndarray | None
    sub_count_x: np.ndarray | None
    source_meta: dict[str, Any]
    index: int = -1

    @property
    def n_phases(self) -> int:
        """Distinct (phase, flip) combinations: (2K)^2 phases x 4 flips."""
        return (2 * self.oversample) ** 2 * 4

    def phase_offset_m(self, a: int, b: int) -> tuple[float, float]:
        """``frame_offset_m`` (x, y) [m] of the emulator frame that phase (a: rows, b: columns) reproduces."""
        k, gt = self.oversample, self.target.gsd_m
        return gt * (b / k - 1 + 1 / (2 * k)), gt * (a / k - 1 + 1 / (2 * k))

    def expected(self, a: int, b: int, flip: int = 0) -> np.ndarray:
        """Expected detected signal [e-] (rows, cols) float64 at phase (a, b), flip bits (1: x, 2: y)."""
        return self._detected(self.field, a, b, flip)

    def _pick(self, arr: np.ndarray, a: int, b: int, flip: int, size: tuple[int, int], window: int = 1):
        if flip & 1:
            arr = arr[:, ::-1]
        if flip & 2:
            arr = arr[::-1, :]
        k = self.oversample
        h, w = size
        return arr[a:a + k * (h - 1) + window, b:b + k * (w - 1) + window]

    def _detected(self, fields: dict[str, np.ndarray], a: int, b: int, flip: int) -> np.ndarray:
        k = self.oversample
        h, w = self.frame_shape
        out = np.zeros((h, w))
        for c, f in fields.items():  # each target pixel detects its own colour's arrivals (as emulate._expected)
            arrive = self._pick(f, a, b, flip, (h, w))[::k, ::k]
            det = _detect(self.target, c, (h, w))
            out += arrive if det is None else np.where(det, arrive, 0.0)
        return np.maximum(out, 0.0)

    def mask(self, a: int, b: int, flip: int = 0) -> np.ndarray | None:
        """Car-area fraction per target pixel (float32) at phase (a, b) and flip."""
        if self.sub_total is None:
            return None
        k = self.oversample
        h, w = self.frame_shape
        tot = self._pick(self.sub_total.astype(np.float64), a, b, flip, (h, w), k)
        cy = self.sub_count_y[::-1] if flip & 2 else self.sub_count_y
        cx = self.sub_count_x[::-1] if flip & 1 else self.sub_count_x
        cy = cy[a:a + k * (h - 1) + k].astype(np.float64)
        cx = cx[b:b + k * (w - 1) + k].astype(np.float64)
        # box sums over K x K sub-cells starting at every K-th sub-cell
        s = np.add.reduceat(np.add.reduceat(tot, np.arange(0, k * h, k), axis=0), np.arange(0, k * w, k), axis=1)
        count = np.outer(np.add.reduceat(cy, np.arange(0, k * h, k)), np.add.reduceat(cx, np.arange(0, k * w, k)))
        frac = np.where(count > 0, s / np.maximum(count, 1), 0.0)
        return np.clip(frac, 0.0, 1.0).astype(np.float32)

    def draw(self, rng: int | np.random.Generator, a: int | None = None, b: int | None = None,
             flip: int | None = None) -> RawImage:
        """A fresh target raw: random phase and flip (unless given), photon-exact noise (Poisson + readout)."""
        rng = rng_from_seed(rng)
        k = self.oversample
        a = int(rng.integers(0, 2 * k)) if a is None else int(a)
        b = int(rng.integers(0, 2 * k)) if b is None else int(b)
        flip = int(rng.integers(0, 4)) if flip is None else int(flip)
        if not (0 <= a < 2 * k and 0 <= b < 2 * k and 0 <= flip < 4):
            raise MetrawError(f"phase ({a}, {b}) must lie in [0, {2 * k}) and flip in 0..3")
        mean = self.expected(a, b, flip)
        t = self.target
        haze = np.take(np.array([t.haze_for(c) for c in t.channels]), color_index(t.cfa_pattern, mean.shape))
        # scene and haze photoelectrons in one Poisson draw: a sum of independent Poisson variables is Poisson of
        # the summed means (one draw per pixel instead of two; Poisson sampling is most of a draw's time)
        counts = rng.poisson(mean + haze).astype(np.float64)
        profile = t.profile()
        if self.source_meta.get("approximate"):
            profile = profile.replace(approximate=True, approximate_reason="emulated from an approximate source")
        data = readout(counts, profile, rng)
        flags = np.zeros(mean.shape, np.uint8)
        sat = data >= profile.white_level_dn
        if profile.full_well_e is not None:
            sat |= counts >= profile.full_well_e
        if self.sat is not None:
            sat |= self._detected(self.sat, a, b, flip) > DEFAULT_ACCURACY.kernel_flux_loss * np.maximum(mean, 1e-300)
        flags[sat] |= FLAG_SATURATED
        ox, oy = self.phase_offset_m(a, b)
        params = {"target": t.to_dict(), "phase": [a, b], "oversample": k, "flip": flip,
                  "frame_offset_m": [ox, oy], "chain": "expected"}
        return RawImage(data=data, profile=profile, mask=self.mask(a, b, flip), flags=flags,
                        provenance=[{"function": "emulate_draw", "params": params}],
                        meta={**self.source_meta.get("meta", {}), "source_index": self.index})


def build_field(source: RawImage, target: TargetSystem, oversample: int = DEFAULT_OVERSAMPLE,
                accuracy: Accuracy | None = None, index: int = -1) -> PhaseField:
    """The ``PhaseField`` of ``source`` seen by ``target`` (axis-aligned frame and track, edge 'reflect')."""
    k = int(oversample)
    if k < 1:
        raise MetrawError(f"oversample must be >= 1, got {oversample}")
    if target.frame_rotation_rad != 0.0 or target.frame_offset_m != (0.0, 0.0) or target.frame_shape_px is not None:
        raise MetrawError("draws place the frame themselves: the target must have no frame offset, rotation or shape")
    if target.smear_m > 0 and abs(math.sin(2 * target.track_angle_rad)) > 1e-12:
        raise MetrawError("draws flip the scene about the frame axes: the track must run along a frame axis")
    acc = accuracy or DEFAULT_ACCURACY
    plan = plan_emulation(source.profile, source.shape, target, acc, "reflect")
    h0, w0 = plan.frame_shape
    h, w = h0 - 2, w0 - 2
    if h < 2 or w < 2:
        raise MetrawError(f"the target frame ({h0} x {w0} px) is too small for sampling-phase draws")
    ny, nx = k * (h + 1), k * (w + 1)
    gt = plan.target_gsd_m
    four = _Fourier(plan)
    hy, hx = plan.grid_h_m
    oy0, ox0 = plan.grid_origin
    Ny, Nx = plan.grid_shape
    g = plan.gridding
    cx, cy = plan.centre_m
    v = (np.arange(ny) - (ny - 1) / 2) * gt / k
    u = (np.arange(nx) - (nx - 1) / 2) * gt / k
    Ty = GaussianWindow((v + cy) / hy + oy0, Ny, True, *g)
    Tx = GaussianWindow((u + cx) / hx + ox0, Nx, True, *g)

    def lattice(cells: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {c: Tx.gather_cols(Ty.gather_rows(four.filtered(four.grid(plan.p[c] * e), c))).astype(np.float32)
                for c, e in cells.items()}

    cells = _cell_planes(source, plan)
    field = lattice(cells)
    sat_cells = _saturated_cells(source, plan)
    sat = lattice({c: np.where(sat_cells, e, 0.0) for c, e in cells.items()}) if sat_cells is not None else None
    sub_total = sub_cy = sub_cx = None
    if source.mask is not None:
        sub_total, sub_cy, sub_cx = _sub_cell_masks(source, plan, ny, nx, k)
    meta = {"approximate": bool(source.profile.approximate), "meta": dict(source.meta)}
    return PhaseField(target=target, oversample=k, frame_shape=(h, w), field=field,
                      sat=sat, sub_total=sub_total, sub_count_y=sub_cy, sub_count_x=sub_cx, source_meta=meta,
                      index=index)


def _sub_cell_masks(source: RawImage, plan, ny: int, nx: int, k: int):
    """Summed car fraction per GSD/K sub-cell (source cells by centre) and cells per sub-cell row/column."""
    hc, wc = plan.cells_shape
    m = _cell_mask(source, plan)
    gt, cell = plan.target_gsd_m, plan.cell_m
    sy, sx = ny + k - 1, nx + k - 1

    def assign(n_cells: int, centre: float, n_sub: int, n_lat: int) -> sp.csr_matrix:
        pos = (np.arange(n_cells) + 0.5) * cell - centre  # cell centres about the footprint centre
        e0 = -((n_lat - 1) / 2) * gt / k - gt / 2  # first sub-cell edge
        idx = np.floor((pos - e0) / (gt / k)).astype(np.int64)
        ok = (idx >= 0) & (idx < n_sub)
        return sp.csr_matrix((np.ones(ok.sum()), (idx[ok], np.flatnonzero(ok))), shape=(n_sub, n_cells))

    ay = assign(hc, plan.centre_m[1], sy, ny)
    ax = assign(wc, plan.centre_m[0], sx, nx)
    total = np.asarray(ay @ (ax @ m.T).T).astype(np.float32)
    return total, np.asarray(ay.sum(axis=1)).ravel().astype(np.int32), np.asarray(ax.sum(axis=1)).ravel().astype(np.int32)
