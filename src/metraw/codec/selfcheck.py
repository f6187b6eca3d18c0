"""Self-check of a decoded image against its original (docs/codec.md).

All statistics are in units of the codec's sigma, sigma_T = K sqrt(x + 3/8 + s^2) [DN]
(``prepare.sigma_t_dn``, evaluated at the original value), over non-escaped pixels.
"""

from __future__ import annotations

import math

import numpy as np

from metraw.codec import prepare
from metraw.raw.image import RawImage


def rounded_uniform_var_dn2(a: np.ndarray) -> np.ndarray:
    """E[rint(e)^2] [DN^2] for e uniform on (-a, a) [DN]: the variance of a subtractively dithered
    error after rounding an integer original to the integer DN grid."""
    a = np.asarray(a, dtype=np.float64)
    kmax = int(np.ceil(a.max() + 0.5)) if a.size else 0
    if kmax > 64:  # many DN per step: the continuous limit is exact to < 1e-6 relative
        return a * a / 3.0 + 1.0 / 12.0
    tot = np.zeros_like(a)
    for k in range(1, kmax + 1):
        tot += k * k * np.clip(a - (k - 0.5), 0.0, 1.0)
    return np.where(a > 0, tot / np.where(a > 0, a, 1.0), 0.0)


def self_check(original: RawImage, decoded: RawImage, step: float) -> dict[str, float]:
    """Error statistics: bound violations, bias (frame and worst decile), rms vs step/sqrt(12),
    neighbour correlation (horizontal and vertical, same CFA plane), escapes exact."""
    prof = original.profile
    y = original.data
    err = decoded.data.astype(np.float64) - y
    esc = prepare.escape_mask(y, prof)
    sig = prepare.sigma_t_dn(y, prof)
    ok = ~esc
    e = np.where(ok, err / np.where(ok, sig, 1.0), 0.0)
    bound = prepare.error_bound_dn(y, prof, step)
    n = int(ok.sum())
    out: dict[str, float] = {"pixels": float(y.size), "escaped": float(esc.sum()),
                             "escapes_exact": float(np.all(err[esc] == 0)),
                             "bound_violations": float(np.sum(np.abs(err) > bound + 1e-9))}
    # the bound step/2 sigma + 0.5 DN, without the curvature term K q^2 / 24
    loose = 0.5 * step * sig + 0.5
    out["issue_bound_violations"] = float(np.sum(ok & (np.abs(err) > loose + 1e-9)))
    if n == 0:
        return out
    ev = e[ok]
    out["mean_error_sigma"] = float(ev.mean())
    out["mean_error_se_sigma"] = float(ev.std() / math.sqrt(n))
    out["rms_error_sigma"] = float(math.sqrt(np.mean(ev * ev)))
    out["rms_over_uniform"] = out["rms_error_sigma"] / (step / math.sqrt(12.0))
    # expected rms including the final rounding to integer DN. The original y is an integer, so the
    # decoded error is rint(e) with e ~ U(-a, a), a = q sigma_T / 2 [DN] (curvature term neglected):
    # E rint(e)^2 = (1/a) sum_k k^2 |{t in [0, a): rint(t) = k}| (-> a^2/3 + 1/12 for a >> 1 DN,
    # 0 for a < 1/2: then every pixel decodes exactly).
    out["rms_over_expected"] = out["rms_error_sigma"] / math.sqrt(np.mean(rounded_uniform_var_dn2(0.5 * step * sig[ok])
                                                                          / sig[ok] ** 2))
    out["max_error_dn"] = float(np.abs(err[ok]).max())
    cell = 1 if prof.cfa_pattern == "mono" else 2
    corrs = []
    for a, b, m1, m2 in ((e[:, :-cell], e[:, cell:], ok[:, :-cell], ok[:, cell:]),
                         (e[:-cell], e[cell:], ok[:-cell], ok[cell:])):
        m = m1 & m2
        if m.sum() > 2:
            corrs.append(float(np.corrcoef(a[m], b[m])[0, 1]))
    out["neighbour_corr"] = max(corrs, key=abs) if corrs else 0.0
    # bias per intensity decile of the original value
    yv = y[ok].astype(np.float64)
    edges = np.unique(np.quantile(yv, np.linspace(0, 1, 11)))
    if edges.size > 2:
        idx = np.clip(np.searchsorted(edges, yv, side="right") - 1, 0, edges.size - 2)
        means = np.bincount(idx, ev) / np.maximum(np.bincount(idx), 1)
        cnt = np.bincount(idx)
        worst = int(np.argmax(np.abs(np.where(cnt > 0, means, 0))))
        out["worst_decile_mean_sigma"] = float(means[worst])
        out["worst_decile_count"] = float(cnt[worst])
    return out


def format_check(stats: dict[str, float]) -> str:
    return "\n".join(f"{k:26s} {v:.6g}" for k, v in stats.items())
