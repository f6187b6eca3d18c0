"""Single-frame Poisson-Gaussian noise fit: ``from_image`` and ``combine_images`` (``metraw.calibrate``)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import stats

from metraw.calibrate.results import (FIT_FRACTION, CalibrationResult, ChannelCalibration, _build_profile,
                                     _frame_array, _native, _radiometry, _weighted_mean)
from metraw.errors import MetrawError
from metraw.raw.cfa import channel_names, plane_offsets, split_planes
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile

#: Side of a from_image block in 2 x 2 cells of one CFA plane (8 -> 16 x 16 plane pixels).
BLOCK_CELLS = 8
#: Fewest accepted blocks per channel for a single-frame fit.
MIN_BLOCKS = 40
#: Fewest blocks in one signal bin of a single-frame fit: MIN_PER_BIN for frames with few blocks
#: (so that there are >= 8 bins), up to BIN_BLOCKS for large frames; at least half of a bin's blocks
#: must pass the smoothness selection.
MIN_PER_BIN = 8
BIN_BLOCKS = 16
#: Fraction of the smoothest blocks of a signal bin from which the bin's noise scale is read
#: (``_smooth_blocks``).
SMOOTH_QUANTILE = 0.25
#: The frame is cut into TILES x TILES tiles for the spatial jackknife of a single-frame fit.
TILES = 4
#: Largest relative standard uncertainty of K that from_image still reports as a fit.
MAX_RELATIVE_GAIN_UNCERTAINTY = 0.5
#: What a refused single-frame fit leaves a user: the two other calibrations (README "Your own data").
WAYS_OUT = ("; calibrate from flats and darks instead (metraw calibrate --flats F.. --darks D..; params.yaml "
            "source.raws.calibration.flats, darks) or give a camera profile (--profile camera.json; "
            "calibration.profile; docs/noise-model.md)")


# ------------------------------------------------------------------------------ single frame
def _block_stats(plane: np.ndarray, white: float, cells: int) -> dict[str, np.ndarray]:
    """Per block of ``cells`` x ``cells`` 2 x 2 cells (n = cells^2 cells) of one CFA plane:

    ``mu`` the mean; ``v`` the mean square of the diagonal Haar detail HH (noise alone:
    sigma^2 chi2_n / n); ``s`` the smoothness statistic, the mean square of the horizontal and
    vertical details LH, HL about their block means (noise alone: sigma^2 chi2_{2n-2} / (2n-2));
    ``ok`` False for clipped blocks; ``row``, ``col`` the block centre as a fraction of the plane.
    For white Gaussian noise the four Haar sub-bands of a 2 x 2 cell are orthogonal projections,
    so ``s`` is independent of ``v``: choosing blocks by ``s`` leaves the distribution of their
    ``v`` untouched (no selection bias to correct). Texture, edges and curvature raise ``s`` (LH/HL
    pass lower spatial frequencies than HH and respond to edges of any orientation).
    """
    b = cells
    h, w = plane.shape
    nby, nbx = h // (2 * b), w // (2 * b)
    if nby == 0 or nbx == 0:
        empty = np.empty(0)
        return {"mu": empty, "v": empty, "s": empty, "ok": np.empty(0, bool), "row": empty, "col": empty}
    p = plane[: nby * 2 * b, : nbx * 2 * b]
    y00, y01, y10, y11 = p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]

    def blocks(a: np.ndarray) -> np.ndarray:
        return a.reshape(nby, b, nbx, b).transpose(0, 2, 1, 3)

    hh = blocks(0.5 * (y00 - y01 - y10 + y11))
    lh = blocks(0.5 * (y00 + y01 - y10 - y11))
    hl = blocks(0.5 * (y00 - y01 + y10 - y11))
    v = np.mean(hh ** 2, axis=(2, 3))
    s = (np.sum((lh - lh.mean(axis=(2, 3), keepdims=True)) ** 2, axis=(2, 3))
         + np.sum((hl - hl.mean(axis=(2, 3), keepdims=True)) ** 2, axis=(2, 3))) / _smooth_dof(b)
    mu = np.mean(blocks(0.25 * (y00 + y01 + y10 + y11)), axis=(2, 3))
    pb = p.reshape(nby, 2 * b, nbx, 2 * b)
    hi = pb.max(axis=(1, 3))
    lo = pb.min(axis=(1, 3))
    ok = (hi < white) & (lo > 0) & (mu + 6.0 * np.sqrt(v) < white) & (v > 0) & (s > 0)
    row, col = np.meshgrid((np.arange(nby) + 0.5) / nby, (np.arange(nbx) + 0.5) / nbx, indexing="ij")
    return {"mu": mu.ravel(), "v": v.ravel(), "s": s.ravel(), "ok": ok.ravel(), "row": row.ravel(),
            "col": col.ravel()}


def _smooth_dof(cells: int) -> int:
    """Degrees of freedom of the smoothness statistic ``s`` of ``_block_stats`` (LH and HL about their means)."""
    return max(2 * cells * cells - 2, 1)


def _smooth_blocks(s: np.ndarray, dof: int, texture_p: float, quantile: float = SMOOTH_QUANTILE) -> np.ndarray:
    """Indices of the blocks of one signal bin whose smoothness ``s`` is consistent with noise alone.

    The bin's noise scale is read off its smoothest ``quantile`` (that order statistic matched to
    the same quantile of chi2_dof / dof); blocks above the ``1 - texture_p`` quantile of that scaled
    distribution are textured. In a noise-only bin a fraction ~``texture_p`` is dropped; in a bin
    mixing materials the smoothest population is kept. Assumption: the smoothest quarter of a bin
    is nearly noise only; texture it still holds biases the bin upwards (``_fit_channel`` catches
    the curve shapes this produces, ``_fit_channel_jackknife`` measures what it does to K).
    """
    m = s.size
    k = max(int(round(quantile * m)), 1)
    ref = float(np.partition(s, k - 1)[k - 1])
    scale = ref * dof / stats.chi2.ppf(k / (m + 1.0), dof)
    return np.flatnonzero(s <= scale * stats.chi2.ppf(1.0 - texture_p, dof) / dof)


def _signal_bins(x: np.ndarray, per_bin: int, nbins: int = 48) -> list[np.ndarray]:
    """Index arrays of the signal bins: at most ``nbins`` (fewer for few blocks) equal steps of
    sqrt(x), i.e. about equal steps of noise level, each holding >= ``per_bin`` blocks. Sparse
    bins above the last full one (the bright tail: it carries the gain's lever arm, e.g. next to
    clipped highlights) are merged in order until they hold ``per_bin``; sparse bins below it are
    dropped (rare dark levels come from a few deep shadows, mostly along shadow edges, which would
    anchor the intercept). Measured on the embedded scenes: merging the dark tail as well lowers
    the share of honest fits (|z| <= 2) from ~95 % to ~84 %."""
    nb = int(np.clip(x.size // per_bin, 1, nbins))
    r = np.sqrt(np.maximum(x, 0.0))
    lo, hi = (float(r.min()), float(r.max())) if r.size else (0.0, 0.0)
    idx = np.minimum(((r - lo) / max(hi - lo, 1e-12) * nb).astype(int), nb - 1)
    bins = [np.flatnonzero(idx == i) for i in range(nb)]
    full = [i for i, b in enumerate(bins) if b.size >= per_bin]
    if not full:
        return []
    out = [bins[i] for i in range(full[0], full[-1] + 1) if bins[i].size >= per_bin]
    tail = np.empty(0, int)
    for b in bins[full[-1] + 1:]:
        tail = np.concatenate([tail, b])
        if tail.size >= per_bin:
            out.append(tail)
            tail = np.empty(0, int)
    return out


def _fit_ptc(x: np.ndarray, y: np.ndarray, sy: np.ndarray, quadratic: bool = True
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least squares y = a x + b (+ c x^2): parameters [a, b, c], covariance, chi2_red."""
    cols = [x, np.ones_like(x)] + ([x * x] if quadratic else [])
    design = np.stack(cols, axis=1)
    w = 1.0 / sy ** 2
    scale = np.sqrt(np.sum(design ** 2 * w[:, None], axis=0))  # column scaling for conditioning
    ds = design / scale
    normal = ds.T @ (ds * w[:, None])
    try:
        cov_s = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        cov_s = np.full(normal.shape, np.inf)
    beta_s = cov_s @ (ds.T @ (w * y))
    beta = beta_s / scale
    cov = cov_s / np.outer(scale, scale)
    dof = x.size - design.shape[1]
    chi2 = float(np.sum(w * (y - design @ beta) ** 2) / dof) if dof > 0 else float("nan")
    if dof > 0 and chi2 > 1:
        cov = cov * chi2
    if not quadratic:
        beta, cov2 = np.append(beta, 0.0), np.zeros((3, 3))
        cov2[:2, :2] = cov
        cov = cov2
    return beta, cov, chi2


def _admissible_fit(x: np.ndarray, y: np.ndarray, sy: np.ndarray) -> tuple[float, float, float] | None:
    """Weighted least squares of y = a x + b + c x^2 under the physical constraints b >= q^2/12
    (b = K^2 sigma_d^2 + q^2/12) and c >= 0 (PRNU^2, multiplicative texture): the best of the
    fits with c = 0, with b = 1/12, and with both (active sets; ``_fit_channel`` calls it when the
    free fit breaks a constraint). Returns (a, b, c), or None when no such fit is admissible."""
    best = None
    w = 1.0 / sy ** 2
    for fix_b, fix_c in ((False, True), (True, False), (True, True)):
        cols = [x] + ([] if fix_b else [np.ones_like(x)]) + ([] if fix_c else [x * x])
        design = np.stack(cols, axis=1)
        target = y - (1.0 / 12.0 if fix_b else 0.0)
        scale = np.sqrt(np.sum(design ** 2 * w[:, None], axis=0))
        ds = design / scale
        try:
            beta = np.linalg.solve(ds.T @ (ds * w[:, None]), ds.T @ (w * target)) / scale
        except np.linalg.LinAlgError:
            continue
        a = float(beta[0])
        b = 1.0 / 12.0 if fix_b else float(beta[1])
        c = 0.0 if fix_c else float(beta[-1])
        if b < 1.0 / 12.0 or c < 0.0:
            continue
        chi2 = float(np.sum(w * (target - design @ beta) ** 2))
        if best is None or chi2 < best[0]:
            best = (chi2, a, b, c)
    return None if best is None else best[1:]


def _read_noise_fit(a: float, b: float, cov: np.ndarray, black_u: float) -> tuple[float, float]:
    """sigma_d = sqrt(b - 1/12) / a from a single-frame fit, with first-order uncertainty from the
    full covariance of (a, b) (their errors are anti-correlated, which adds up in sigma_d) and the black
    level's uncertainty (b shifts by a * delta_black); one-sided when b <= 1/12 (as ``_read_noise``)."""
    var_a, var_b, cov_ab = float(cov[0, 0]), float(cov[1, 1]) + (a * black_u) ** 2, float(cov[0, 1])
    excess = b - 1.0 / 12.0
    if not (np.isfinite(var_a) and np.isfinite(var_b) and np.isfinite(cov_ab)):
        return (math.sqrt(max(excess, 0.0)) / a if a > 0 else float("nan")), float("inf")
    if excess <= 0:
        return 0.0, math.sqrt(math.sqrt(max(var_b, 0.0))) / a
    sd = math.sqrt(excess) / a
    da, db = -sd / a, 1.0 / (2.0 * a * math.sqrt(excess))
    return sd, math.sqrt(max(da * da * var_a + db * db * var_b + 2.0 * da * db * cov_ab, 0.0))


def _fit_channel(mu: np.ndarray, v: np.ndarray, s: np.ndarray, black: float, n_per_block: int, channel: str,
                 notes: list[str], black_u: float = 0.0, texture_p: float = 1e-3) -> ChannelCalibration:
    """Bin blocks by mean, keep the smooth ones (``_smooth_blocks``), fit the photon-transfer curve.

    Per bin the variance is the mean of the kept blocks' HH variances: unbiased for noise-only
    blocks (the selection looks at ``s`` alone), with n k y / sigma^2 ~ chi2_{n k} for k kept
    blocks, hence the standard uncertainty y sqrt(2 / (n k)). ``black_u`` (the black level's
    uncertainty) enters the intercept: b shifts by K * delta_black.

    Fit var = a x + b + c x^2 (x = mu - black), weighted, Birge-inflated (``_fit_ptc``). Physics
    demands b >= q^2/12 (b = K^2 sigma_d^2 + q^2/12) and c >= 0 (PRNU^2, multiplicative
    texture). Texture the frame cannot tell from noise (white at the plane scale, heavier on dark
    materials than on bright ones) bends the free fit exactly across those limits - intercept under
    q^2/12, negative curvature - and then inflates K. Such a fit is replaced by the constrained one
    (``_admissible_fit``) and the distance K moved is added in quadrature to its uncertainty (a
    noise-only frame moves by about its own sampling error; a textured one by its texture bias).
    Raises MetrawError when too few smooth levels remain or K is not constrained (relative
    uncertainty >= MAX_RELATIVE_GAIN_UNCERTAINTY).
    """
    nblk = mu.size
    if nblk < MIN_BLOCKS:
        raise MetrawError(f"channel {channel}: only {nblk} unclipped blocks "
                          f"(need >= {MIN_BLOCKS}); the frame is too small or too textured for a single-frame fit")
    per_bin = int(np.clip(nblk // 8, MIN_PER_BIN, BIN_BLOCKS))  # >= 8 bins where blocks are few
    dof_s = _smooth_dof(int(round(math.sqrt(n_per_block))))
    xs, ys, sys_, counts = [], [], [], []
    for sel in _signal_bins(mu - black, per_bin):
        keep = sel[_smooth_blocks(s[sel], dof_s, texture_p)]
        if keep.size < per_bin // 2:
            continue
        est = float(np.mean(v[keep]))
        xs.append(float(np.mean(mu[keep])) - black)
        ys.append(est)
        sys_.append(est * math.sqrt(2.0 / (keep.size * n_per_block)))
        counts.append(keep.size)
    x, y, sy = np.array(xs), np.array(ys), np.array(sys_)
    if x.size < 4:
        raise MetrawError(f"channel {channel}: smooth blocks cover too few signal levels for a single-frame fit "
                          f"(mean {mu.min():.1f}..{mu.max():.1f} DN); the frame is too flat, small or textured")
    # Outlier bins (texture-dominated): iterative rejection on robustly scaled residuals.
    keep = np.ones(x.size, bool)
    for _ in range(5):
        beta, _, _ = _fit_ptc(x[keep], y[keep], sy[keep], quadratic=keep.sum() >= 6)
        res = (y - (beta[0] * x + beta[1] + beta[2] * x * x)) / sy
        scale = max(1.0, 1.4826 * float(np.median(np.abs(res[keep]))))
        new_keep = np.abs(res) <= 4.0 * scale
        if np.array_equal(new_keep, keep) or new_keep.sum() < 4:
            break
        keep = new_keep
    if (~keep).sum():
        notes.append(f"channel {channel}: {(~keep).sum()} of {x.size} signal bins rejected as outliers (texture)")
    x, y, sy = x[keep], y[keep], sy[keep]
    counts = [k for k, ok in zip(counts, keep) if ok]
    # Photon-transfer peak inside the data (full well before the ADC clips): fit below 70 % of it.
    smooth = np.array([np.median(y[max(0, i - 2):i + 3]) for i in range(y.size)])
    peak = int(np.argmax(smooth))
    tail = y[peak + 1:]
    if tail.size >= 3 and np.median(tail) < smooth[peak] - 3 * sy[peak]:
        cut = x <= FIT_FRACTION * x[peak]
        notes.append(f"channel {channel}: variance peaks at {x[peak] + black:.1f} DN; fit below {FIT_FRACTION:.0%} of it")
        x, y, sy = x[cut], y[cut], sy[cut]
        counts = [k for k, ok in zip(counts, cut) if ok]
    if x.size < 4:
        raise MetrawError(f"channel {channel}: too few signal levels for a single-frame fit")
    beta, cov, chi2 = _fit_ptc(x, y, sy, quadratic=True)
    a, b, c = (float(t) for t in beta)
    ua = math.sqrt(cov[0, 0]) if np.isfinite(cov[0, 0]) else float("inf")
    uc = math.sqrt(cov[2, 2]) if np.isfinite(cov[2, 2]) else float("inf")
    span = (float(x.min()), float(x.max()))
    rn, rn_u = _read_noise_fit(a, b, cov, black_u)
    if b < 1.0 / 12.0 or c < 0.0:
        # Not physical: report the constrained fit, its uncertainty widened by the move it took.
        adm = _admissible_fit(x, y, sy)
        if adm is not None:
            a_free, rn_free = a, rn
            a, b, c = adm
            ua = math.hypot(ua, a - a_free)
            cov = cov.copy()
            cov[0, 0] = ua * ua
            rn, rn_u = _read_noise_fit(a, b, cov, black_u)
            rn_u = math.hypot(rn_u, rn - rn_free)
            notes.append(f"channel {channel}: free fit not physical (intercept below q^2/12 or negative curvature): "
                         f"constrained fit, K moved by {a - a_free:+.3g} DN/e- (in its uncertainty)")
    if not (a > 0 and ua < MAX_RELATIVE_GAIN_UNCERTAINTY * a):
        raise MetrawError(f"channel {channel}: the frame does not constrain the gain (K = {a:.3g} +- {ua:.2g} DN/e-, "
                          f"signal range {span[0]:.1f}..{span[1]:.1f} DN above black): too flat or too textured; it "
                          f"needs smooth regions over a wide range of brightness")
    if b - 1.0 / 12.0 <= 0:
        notes.append(f"channel {channel}: read noise not resolved above quantisation")
    prnu = math.sqrt(c) if c > 0 else 0.0
    prnu_u = uc / (2 * prnu) if prnu > 0 else math.sqrt(uc)
    return ChannelCalibration(channel, a, ua, rn, rn_u, black, black_u, int(sum(counts)), span, chi2,
                              prnu=prnu, prnu_u=prnu_u)


def _fit_channel_jackknife(mu: np.ndarray, v: np.ndarray, s: np.ndarray, tile: np.ndarray, black: float,
                           n_per_block: int, channel: str, notes: list[str], black_u: float = 0.0,
                           texture_p: float = 1e-3) -> ChannelCalibration:
    """``_fit_channel`` with a delete-one-tile jackknife over the TILES x TILES tiles of the frame.

    The fit's own uncertainty treats the bins' scatter as noise; texture makes K depend on which
    objects the frame happens to show. Refitting with each tile left out (g refits) gives the
    jackknife standard error sqrt((g-1)/g sum (K_i - mean K)^2) (and the same for read noise), which
    holds that dependence; the reported uncertainty is the larger of the two. A channel whose refits
    fail for more than half of the tiles is unstable and refused; so is one whose K is no longer
    constrained (MAX_RELATIVE_GAIN_UNCERTAINTY) with the jackknife error. Texture that biases every
    tile alike is not seen here: that is left to the physical constraints of ``_fit_channel``.
    """
    ch = _fit_channel(mu, v, s, black, n_per_block, channel, notes, black_u, texture_p)
    reps, fails = [], 0
    groups = np.unique(tile)
    for t in groups:
        m = tile != t
        try:
            r = _fit_channel(mu[m], v[m], s[m], black, n_per_block, channel, [], black_u, texture_p)
            reps.append((r.gain_dn_per_e, r.read_noise_e))
        except MetrawError:
            fails += 1
    if len(reps) < 2 or fails > groups.size // 2:
        raise MetrawError(f"channel {channel}: the fit is unstable: it fails for {fails} of {groups.size} refits "
                          f"that each leave one tile of the frame out; the frame is too small or too textured")
    arr = np.array(reps)
    g = len(reps)
    u_jk = np.sqrt((g - 1) / g * np.sum((arr - arr.mean(axis=0)) ** 2, axis=0))
    if u_jk[0] > ch.gain_dn_per_e_u or u_jk[1] > ch.read_noise_e_u:
        notes.append(f"channel {channel}: uncertainty from the tile jackknife ({g} refits)")
    ch.gain_dn_per_e_u = max(ch.gain_dn_per_e_u, float(u_jk[0]))
    ch.read_noise_e_u = max(ch.read_noise_e_u, float(u_jk[1]))
    if not ch.gain_dn_per_e_u < MAX_RELATIVE_GAIN_UNCERTAINTY * ch.gain_dn_per_e:
        raise MetrawError(f"channel {channel}: the frame does not constrain the gain (K = {ch.gain_dn_per_e:.3g} +- "
                          f"{ch.gain_dn_per_e_u:.2g} DN/e-, jackknife over {g} tiles): the fit depends on which "
                          f"parts of the frame it sees")
    return ch


def _refused_channel(channel: str, black: float, black_u: float) -> ChannelCalibration:
    """Placeholder of a channel the frame cannot calibrate: NaN values and infinite uncertainties, so it
    has weight 0 wherever channels or images are combined by inverse variance (``_weighted_mean``)."""
    nan, inf = float("nan"), float("inf")
    return ChannelCalibration(channel, nan, inf, nan, inf, black, black_u, 0, (nan, nan), nan)


def from_image(image: RawImage | np.ndarray, *, black_level_dn: float | None = None,
               cfa_pattern: str | None = None, white_level_dn: float | None = None, adc_bits: int | None = None,
               profile: CalibrationProfile | None = None, block_cells: int = BLOCK_CELLS,
               texture_p: float = 1e-3) -> CalibrationResult:
    """Single-frame Poisson-Gaussian noise fit (see the module docstring).

    ``image``: a ``RawImage`` (pattern, black and white from its profile) or a 2-D uint16
    array with ``black_level_dn`` and ``cfa_pattern`` given (in the array's stored units).
    ``block_cells``: block side in 2 x 2 cells of one CFA plane; ``texture_p``: probability
    that the smoothness test drops a noise-only block. A channel that cannot be fitted
    (unconstrained, not physical or unstable: ``_fit_channel``, ``_fit_channel_jackknife``) is
    kept as NaN +- inf in ``channels`` with the reason in ``notes``, and has no weight in the
    profile; raises ``MetrawError`` when no channel can be fitted (tiny, flat, clipped or
    textured frames).
    """
    if not 0 < texture_p < 1:
        raise MetrawError(f"texture_p must be in (0, 1), got {texture_p}")
    if block_cells < 2:
        raise MetrawError(f"block_cells must be >= 2, got {block_cells}")
    base = profile if profile is not None else (image.profile if isinstance(image, RawImage) else None)
    data = _frame_array(image)
    rad = _radiometry([data], base, cfa_pattern, black_level_dn, white_level_dn, adc_bits)
    if rad.black_dn is None:
        raise MetrawError("from_image needs the black level (black_level_dn): a single frame cannot separate it "
                          "from the read noise")
    black_u = 0.0
    if black_level_dn is None and base is not None:
        black_u = float(base.uncertainty.get("black_level_dn", 0.0)) / rad.scale
    native = _native(data, rad.shift)
    n = block_cells * block_cells
    keys = ("mu", "v", "s", "tile")
    per_channel: dict[str, dict[str, list[np.ndarray]]] = {}
    total = rejected_clip = 0
    for (colour, _, _), plane in zip(plane_offsets(rad.cfa_pattern), split_planes(native, rad.cfa_pattern)):
        st = _block_stats(plane, rad.white_dn, block_cells)
        st["tile"] = (np.floor(st["row"] * TILES) * TILES + np.floor(st["col"] * TILES)).astype(int)
        good = st["ok"]
        total += good.size
        rejected_clip += int((~good).sum())
        acc = per_channel.setdefault(colour, {k: [] for k in keys})
        for k in keys:
            acc[k].append(st[k][good])
    notes = []
    if rad.shift:
        notes.append(f"data have {rad.shift} unused low bits: profile in native DN (stored DN >> {rad.shift})")
    if total:
        notes.append(f"blocks: {total} in all, {rejected_clip} clipped or dark-clipped")
    channels, refused = {}, {}
    for colour in channel_names(rad.cfa_pattern):
        acc = per_channel.get(colour, {k: [] for k in keys})
        mu, v, s, tile = (np.concatenate(acc[k]) if acc[k] else np.empty(0) for k in keys)
        try:
            channels[colour] = _fit_channel_jackknife(mu, v, s, tile.astype(int), rad.black_dn, n, colour, notes,
                                                      black_u, texture_p)
        except MetrawError as exc:
            refused[colour] = str(exc)
            channels[colour] = _refused_channel(colour, rad.black_dn, black_u)
    if len(refused) == len(channels):
        raise MetrawError("; ".join(refused.values()) + WAYS_OUT)  # the frame refused: the two other calibrations
    notes += [f"channel {c} not fitted: {why}" for c, why in refused.items()]
    prof = _build_profile(base, rad, channels, None)
    return CalibrationResult(prof, "single_frame_poisson_gaussian", channels, rad.shift, notes)


# ------------------------------------------------------------------------------ several single frames


def combine_images(results: Sequence[CalibrationResult]) -> CalibrationResult:
    """Single-frame fits of several images of one camera -> one result: per channel and for the profile, the
    inverse-variance weighted mean of gain, read noise and black level, its uncertainty inflated by the Birge
    ratio when the images scatter more than their stated uncertainties (``_weighted_mean``). The first result's
    profile carries the geometry."""
    if not results:
        raise MetrawError("combine_images needs at least one single-frame result")
    if len(results) == 1:
        return results[0]
    channels = {}
    for c in results[0].channels:
        per = [r.channels[c] for r in results]
        k, k_u, chi2 = _weighted_mean([p.gain_dn_per_e for p in per], [p.gain_dn_per_e_u for p in per])
        rn, rn_u, _ = _weighted_mean([p.read_noise_e for p in per], [p.read_noise_e_u for p in per])
        bl, bl_u, _ = _weighted_mean([p.black_level_dn for p in per], [max(p.black_level_dn_u, 1e-12) for p in per])
        span = (min(p.signal_range_dn[0] for p in per), max(p.signal_range_dn[1] for p in per))
        channels[c] = ChannelCalibration(c, k, k_u, rn, rn_u, bl, bl_u, sum(p.n_points for p in per), span, chi2)
    names = list(channels)
    k, k_u, _ = _weighted_mean([channels[c].gain_dn_per_e for c in names], [channels[c].gain_dn_per_e_u for c in names])
    rn, rn_u, _ = _weighted_mean([channels[c].read_noise_e for c in names], [channels[c].read_noise_e_u for c in names])
    first = results[0].profile
    unc = {**first.uncertainty, "gain_dn_per_e": k_u, "read_noise_e": rn_u}
    profile = first.replace(gain_dn_per_e=k, read_noise_e=rn, uncertainty=unc)
    notes = [f"{len(results)} images fitted one by one, combined by inverse-variance weights (Birge-inflated)"]
    notes += sorted({n for r in results for n in r.notes if "unused low bits" in n})
    return CalibrationResult(profile, "single_frame_poisson_gaussian", channels, results[0].unused_low_bits, notes)
