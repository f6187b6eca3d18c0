"""Gaussian-process response surfaces over the parameter space, bands, tolerances.

A ``ResponseGP`` fits a scikit-learn ``GaussianProcessRegressor`` to one scalar outcome
(test-split IoU, compression ratio) measured at the parameter points of the study.

Inputs: each parameter is mapped to a working axis (``log`` for scale parameters such as
aperture diameter and exposure time, ``linear`` otherwise) and normalised to [0, 1] over
the sampled range, so one prior length scale fits every axis.
Kernel: C * Matern(nu=5/2, one length scale per axis) + WhiteKernel. Per-point measurement
variances (e.g. var(per-image IoU) / n_images: the finite test set) enter as ``alpha``; the
white kernel learns what is left (run-to-run training variability, model misfit).
Targets are standardised (``normalize_y``).

Band: ``mean +- k * sd`` with sd the *predictive* standard deviation of a new measurement
at x, i.e. the latent GP variance plus the learned white-noise variance (not the per-point
``alpha`` of the existing test sets). This is the band a newly built and trained system at x
is expected to fall in; it is the band plotted, calibrated by leave-one-point-out, and used
for tolerances (conservative: the lower bound includes the run-to-run scatter).

Tolerance of a parameter: the connected interval around the optimum (argmax of the mean on
the 1-D line with all other parameters at nominal) on which ``mean - k sd >= required``,
found on a fine grid. The grid covers the sampled range, optionally extended by a fraction
``extrapolate`` of it on the working axis; an interval end that stops at the grid edge is
marked ``limited_by = "sampled_range"`` (or ``"extrapolation_edge"``) rather than ``"requirement"``,
and any end beyond the sampled range is flagged ``extrapolated``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.errors import MetrawError

#: Working-axis transform per known parameter (everything else: linear).
LOG_PARAMETERS = frozenset({"diameter_m", "exposure_s", "pixel_pitch_m", "haze_e", "path_radiance_w_m2_sr_m"})
#: Band half-width in standard deviations (the seed study shows 2 sigma).
BAND_SIGMA = 2.0


def axis_kind(name: str) -> str:
    return "log" if name in LOG_PARAMETERS else "linear"


@dataclass
class Axis:
    """Map one parameter to [0, 1] over its sampled range (log or linear working axis)."""

    name: str
    kind: str
    lo: float
    hi: float

    def _w(self, v):
        v = np.asarray(v, dtype=np.float64)
        if self.kind == "log":
            if np.any(v <= 0):
                raise MetrawError(f"parameter {self.name} must be > 0 on a log axis")
            return np.log(v)
        return v

    def _w_inv(self, w):
        return np.exp(w) if self.kind == "log" else np.asarray(w, dtype=np.float64)

    @property
    def span(self) -> float:
        s = float(self._w(self.hi) - self._w(self.lo))
        return s if s > 0 else 1.0

    def to_unit(self, v):
        return (self._w(v) - self._w(self.lo)) / self.span

    def from_unit(self, u):
        return self._w_inv(self._w(self.lo) + np.asarray(u, dtype=np.float64) * self.span)


@dataclass
class Prediction:
    """Mean, predictive sd and the k-sigma band of a response."""

    mean: np.ndarray
    sd: np.ndarray
    k: float = BAND_SIGMA

    @property
    def lower(self) -> np.ndarray:
        return self.mean - self.k * self.sd

    @property
    def upper(self) -> np.ndarray:
        return self.mean + self.k * self.sd


class ResponseGP:
    """GP regression of one outcome over named parameters (see module docstring).

    ``names``: parameter names (columns of ``X``); ``X``: (n, d) parameter values in SI units;
    ``y``: (n,) outcomes; ``y_var``: optional (n,) measurement variances (same unit as y squared).
    """

    def __init__(self, names: Sequence[str], X: np.ndarray, y: np.ndarray, y_var: np.ndarray | None = None,
                 axes: Sequence[Axis] | None = None, seed: int = 0, restarts: int = 2, nu: float = 2.5):
        self.names = list(names)
        self.X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        self.y = np.asarray(y, dtype=np.float64).ravel()
        n, d = self.X.shape
        if d != len(self.names):
            raise MetrawError(f"{d} parameter columns but {len(self.names)} names")
        if self.y.size != n or n < 3:
            raise MetrawError(f"a GP needs >= 3 points with one outcome each, got {n} points and {self.y.size} outcomes")
        if not (np.all(np.isfinite(self.X)) and np.all(np.isfinite(self.y))):
            raise MetrawError("GP inputs and outcomes must be finite")
        self.y_var = np.zeros(n) if y_var is None else np.asarray(y_var, dtype=np.float64).ravel()
        if self.y_var.size != n or np.any(self.y_var < 0) or not np.all(np.isfinite(self.y_var)):
            raise MetrawError("measurement variances must be finite, >= 0, one per point")
        self.axes = list(axes) if axes is not None else [
            Axis(nm, axis_kind(nm), float(self.X[:, j].min()), float(self.X[:, j].max()))
            for j, nm in enumerate(self.names)]
        self.seed = seed
        self.restarts = restarts
        self.nu = nu
        self._fit()

    # ------------------------------------------------------------------ fitting
    def unit(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        return np.column_stack([ax.to_unit(X[:, j]) for j, ax in enumerate(self.axes)])

    def _fit(self) -> None:
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        # A parameter never varied carries no information about its length scale: leave it out.
        self._active = np.ptp(self.unit(self.X), axis=0) > 0
        if not self._active.any():
            raise MetrawError("a GP needs at least one parameter that varies between the points")
        n_active = int(self._active.sum())
        matern = Matern(length_scale=np.full(n_active, 0.5), length_scale_bounds=(0.05, 50.0), nu=self.nu)
        kernel = (ConstantKernel(1.0, (1e-3, 1e2)) * matern
                  + WhiteKernel(noise_level=1e-2, noise_level_bounds=(1e-8, 1.0)))
        y_scale = float(np.std(self.y)) if np.std(self.y) > 0 else 1.0
        # alpha is in the units of the standardised target (normalize_y divides y by its sd).
        alpha = self.y_var / y_scale**2 + 1e-10
        self.gp = GaussianProcessRegressor(kernel=kernel, alpha=alpha, normalize_y=True,
                                           n_restarts_optimizer=self.restarts, random_state=self.seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.gp.fit(self._features(self.X), self.y)

    def _features(self, X: np.ndarray) -> np.ndarray:
        return self.unit(X)[:, self._active]

    @property
    def white_variance(self) -> float:
        """Learned white-noise variance in the outcome's unit squared."""
        k = self.gp.kernel_
        return float(k.k2.noise_level) * float(self.gp._y_train_std) ** 2

    def kernel_description(self) -> str:
        return str(self.gp.kernel_)

    # ------------------------------------------------------------------ prediction
    def predict(self, X: np.ndarray, k: float = BAND_SIGMA) -> Prediction:
        """Mean and predictive sd (latent + white noise) at parameter values X (n, d)."""
        mean, sd_total = self.gp.predict(self._features(X), return_std=True)
        # sklearn's predictive std includes the white kernel (it is part of k(x, x)); that is
        # the band of a new measurement intended here.
        return Prediction(np.asarray(mean), np.asarray(sd_total), k)

    def latent_sd(self, X: np.ndarray, added: np.ndarray | None = None) -> np.ndarray:
        """Posterior sd of the mean response (the latent GP, without the white noise a new measurement adds) at X
        (n, d), in the outcome's unit; ``added``: (m, d) points to condition on as well, as if measured with the
        mean of the fitted points' noise (the fitted kernel kept; their outcomes do not enter an sd). What training
        more points can reduce: the adaptive sweep's straddle rule (metraw.spec.adaptive)."""
        k = self.gp.kernel_
        latent, white = k.k1, float(k.k2.noise_level)
        F = self._features(self.X)
        noise = np.asarray(self.gp.alpha, dtype=np.float64) * np.ones(len(F)) + white
        if added is not None and len(added):
            F = np.vstack([F, self._features(added)])
            noise = np.concatenate([noise, np.full(len(added), float(np.mean(noise)))])
        C = self._features(X)
        K = latent(F) + np.diag(noise)
        Kc = latent(C, F)
        var = latent.diag(C) - np.einsum("ij,ji->i", Kc, np.linalg.solve(K, Kc.T))
        return np.sqrt(np.clip(var, 0.0, None)) * float(self.gp._y_train_std)

    def line(self, name: str, values: np.ndarray, at: Mapping[str, float], k: float = BAND_SIGMA) -> Prediction:
        """Prediction along one parameter with the others fixed at ``at`` (e.g. nominal)."""
        j = self.names.index(name)
        X = np.tile([float(at[n]) for n in self.names], (len(values), 1))
        X[:, j] = values
        return self.predict(X, k)

    # ------------------------------------------------------------------ calibration
    def leave_one_out(self, k: float = BAND_SIGMA) -> dict[str, Any]:
        """Refit without each point in turn; is the held-out value inside its k-sigma band?

        The held-out point's own measurement variance is added to the predictive variance
        (it is a noisy measurement of the response). Returns per-point records and the share
        inside, with its binomial standard error.
        """
        n = len(self.y)
        records = []
        for i in range(n):
            keep = np.arange(n) != i
            sub = ResponseGP(self.names, self.X[keep], self.y[keep], self.y_var[keep], axes=self.axes,
                             seed=self.seed, restarts=self.restarts, nu=self.nu)
            p = sub.predict(self.X[i:i + 1], k)
            sd = math.sqrt(float(p.sd[0]) ** 2 + float(self.y_var[i]))
            z = (float(self.y[i]) - float(p.mean[0])) / sd if sd > 0 else math.inf
            records.append({"index": i, "observed": float(self.y[i]), "predicted": float(p.mean[0]),
                            "sd": sd, "z": z, "inside": bool(abs(z) <= k)})
        share = sum(r["inside"] for r in records) / n
        return {"k": k, "n": n, "share_inside": share, "share_inside_se": math.sqrt(share * (1 - share) / n),
                "expected_share": math.erf(k / math.sqrt(2)), "points": records}


# ---------------------------------------------------------------------- tolerances
@dataclass
class Tolerance:
    """Tolerance interval of one parameter (others at nominal); SI values.

    ``optimal``: argmax of the GP mean on the line; ``min``/``max``: interval ends (None when
    the lower bound misses the requirement even at the optimum); ``*_limited_by``:
    "requirement", "sampled_range" or "extrapolation_edge"; ``*_extrapolated``: the end lies
    outside the sampled range.
    """

    name: str
    optimal: float
    mean_at_optimal: float
    lower_at_optimal: float
    min: float | None
    max: float | None
    min_limited_by: str | None
    max_limited_by: str | None
    min_extrapolated: bool
    max_extrapolated: bool
    sampled_min: float
    sampled_max: float
    meets_requirement: bool
    extra: dict[str, Any] = field(default_factory=dict)


def _grid(ax: Axis, n: int, extrapolate: float) -> np.ndarray:
    return ax.from_unit(np.linspace(-extrapolate, 1.0 + extrapolate, n))


def tolerance_interval(model: ResponseGP, name: str, required: float, at: Mapping[str, float],
                       n_grid: int = 801, extrapolate: float = 0.0, k: float = BAND_SIGMA) -> Tolerance:
    """Interval of ``name`` where the lower k-sigma bound >= ``required`` (see module docstring)."""
    ax = model.axes[model.names.index(name)]
    grid = _grid(ax, n_grid, extrapolate)
    p = model.line(name, grid, at, k)
    i_opt = int(np.argmax(p.mean))
    ok = p.lower >= required
    edge_kind = "extrapolation_edge" if extrapolate > 0 else "sampled_range"
    eps = 1e-9 * max(abs(ax.hi), abs(ax.lo), 1e-300)
    if not ok[i_opt]:
        return Tolerance(name, float(grid[i_opt]), float(p.mean[i_opt]), float(p.lower[i_opt]), None, None, None, None,
                         False, False, ax.lo, ax.hi, False)
    lo = i_opt
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    hi = i_opt
    while hi < n_grid - 1 and ok[hi + 1]:
        hi += 1
    vmin = _crossing(grid, p.lower, lo, lo - 1, required, ax) if lo > 0 else float(grid[0])
    vmax = _crossing(grid, p.lower, hi, hi + 1, required, ax) if hi < n_grid - 1 else float(grid[-1])
    return Tolerance(
        name, float(grid[i_opt]), float(p.mean[i_opt]), float(p.lower[i_opt]), vmin, vmax,
        "requirement" if lo > 0 else edge_kind, "requirement" if hi < n_grid - 1 else edge_kind,
        vmin < ax.lo - eps, vmax > ax.hi + eps, ax.lo, ax.hi, True)


def _crossing(grid: np.ndarray, lower: np.ndarray, i_in: int, i_out: int, required: float, ax: Axis) -> float:
    """Linear interpolation (on the working axis) of where the lower bound crosses ``required``."""
    u_in, u_out = ax.to_unit(grid[i_in]), ax.to_unit(grid[i_out])
    l_in, l_out = lower[i_in], lower[i_out]
    t = (l_in - required) / (l_in - l_out) if l_in != l_out else 0.0
    return float(ax.from_unit(u_in + t * (u_out - u_in)))


def joint_region(model: ResponseGP, required: float, tolerances: Mapping[str, Tolerance], n_per_axis: int = 21,
                 k: float = BAND_SIGMA, max_points: int = 200_000, seed: int = 0) -> dict[str, Any]:
    """The joint acceptable region on a grid over the box of the one-at-a-time intervals.

    Returns the share of the box (grid points, uniform on the working axes; a scrambled Sobol
    sample when the grid would exceed ``max_points``) where the lower
    bound meets ``required`` with *all* parameters varied together, the worst lower bound in
    the box and where it occurs. A share below 1 says the one-at-a-time box is not jointly
    safe: the spec's box must then be read as a set of independent limits only near nominal.
    """
    names = model.names
    bounds = []
    for j, nm in enumerate(names):
        t = tolerances.get(nm)
        if t is None or not t.meets_requirement:
            return {"share_of_box_ok": None, "reason": f"parameter {nm} has no tolerance interval"}
        ax = model.axes[j]
        bounds.append((ax, ax.to_unit(t.min), ax.to_unit(t.max)))
    if n_per_axis ** len(names) <= max_points:
        sampling = f"grid of {n_per_axis} per axis"
        mesh = np.meshgrid(*(np.linspace(lo, hi, n_per_axis) for _, lo, hi in bounds), indexing="ij")
        U = np.column_stack([m.ravel() for m in mesh])
    else:  # many parameters: a scrambled Sobol sample of the box (a full grid would be n^d points)
        from scipy.stats import qmc

        m = int(math.ceil(math.log2(max_points)))
        sampling = f"Sobol sample of 2^{m} points"
        lo = np.array([b[1] for b in bounds])
        hi = np.array([b[2] for b in bounds])
        U = lo + qmc.Sobol(len(names), scramble=True, seed=seed).random_base2(m) * (hi - lo)
    X = np.column_stack([ax.from_unit(U[:, j]) for j, (ax, _, _) in enumerate(bounds)])
    p = model.predict(X, k)
    ok = p.lower >= required
    worst = int(np.argmin(p.lower))
    return {"share_of_box_ok": float(ok.mean()), "n_grid": int(X.shape[0]), "sampling": sampling,
            "worst_lower": float(p.lower[worst]),
            "worst_at": {nm: float(X[worst, j]) for j, nm in enumerate(names)}}


# ---------------------------------------------------------------------- categorical parameters and grids
def categorical_choice(measured: Mapping[str, tuple[float, float]], nominal_value: str, required: float,
                       k: float = BAND_SIGMA) -> dict[str, Any]:
    """Allowed values of a categorical parameter from direct measurements (no GP across categories).

    ``measured``: value -> (IoU, sd) with every other parameter at nominal. A value is allowed when
    its measured lower bound ``IoU - k sd`` meets ``required``. The optimal value is the one of highest IoU
    (``highest``) when it exceeds the nominal value's by more than k sd of the difference, else the nominal (a tie
    within the errors does not move the choice). The sds add in quadrature: the values' test images are the same
    scenes, so their errors correlate positively and the true sd of the difference is smaller (the rule keeps the
    nominal a little more often than it must).
    """
    values = {v: {"iou": float(m), "iou_sd": float(sd), "lower": float(m - k * sd),
                  "meets_requirement": bool(m - k * sd >= required)} for v, (m, sd) in measured.items()}
    best = max(values, key=lambda v: values[v]["iou"])
    optimal = best
    if nominal_value in values and best != nominal_value:
        top, nom = values[best], values[nominal_value]
        if top["iou"] - nom["iou"] <= k * math.hypot(top["iou_sd"], nom["iou_sd"]):
            optimal = nominal_value
    return {"nominal": nominal_value, "optimal": optimal, "highest": best,
            "allowed": [v for v, r in values.items() if r["meets_requirement"]], "values": values, "k": k,
            "rule": f"allowed: measured IoU - {k:g} sd >= required (others nominal); optimal: the highest IoU if above "
                    f"the nominal's by more than {k:g} sd of the difference, else the nominal"}


def grid_region(names: Sequence[str], X: np.ndarray, y: np.ndarray, y_var: np.ndarray, required: float,
                n_mesh: int = 41, k: float = BAND_SIGMA, seed: int = 0) -> tuple[ResponseGP, dict[str, Any]]:
    """2-D GP over a cross grid's measured points and its tolerance region.

    Returns (model, summary): per measured point its lower bound and whether it meets ``required``;
    on an ``n_mesh`` x ``n_mesh`` mesh over the sampled box (working axes) the share where the GP's
    lower k-sigma band meets it, the region's bounding box and the mask (rows: second axis)."""
    if len(names) != 2:
        raise MetrawError(f"a grid region needs exactly two axes, got {list(names)}")
    model = ResponseGP(names, X, y, y_var, seed=seed)
    ua = np.linspace(0.0, 1.0, n_mesh)
    ax0, ax1 = model.axes
    va, vb = ax0.from_unit(ua), ax1.from_unit(ua)
    A, B = np.meshgrid(va, vb)
    p = model.predict(np.column_stack([A.ravel(), B.ravel()]), k)
    ok = (p.lower >= required).reshape(A.shape)
    box = None
    if ok.any():
        box = {names[0]: [float(A[ok].min()), float(A[ok].max())], names[1]: [float(B[ok].min()), float(B[ok].max())]}
    loo = model.leave_one_out(k) if len(y) >= 4 else None
    points = [{names[0]: float(X[i, 0]), names[1]: float(X[i, 1]), "iou": float(y[i]), "iou_sd": math.sqrt(y_var[i]),
               "lower_measured": float(y[i] - k * math.sqrt(y_var[i])),
               "meets_requirement": bool(y[i] - k * math.sqrt(y_var[i]) >= required)} for i in range(len(y))]
    return model, {"axes": list(names), "kernel": model.kernel_description(), "white_sd": math.sqrt(model.white_variance),
                   "points": points, "share_of_grid_ok": float(ok.mean()), "n_mesh": n_mesh,
                   "bounding_box_ok": box, "mesh": {names[0]: va.tolist(), names[1]: vb.tolist()},
                   "mask_ok": ok.astype(int).tolist(),
                   "leave_one_out_share_inside": None if loo is None else loo["share_inside"]}
