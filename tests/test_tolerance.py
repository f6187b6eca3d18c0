"""GP response surfaces: calibrated bands, tolerance intervals, leave-one-out, aggregate inputs."""

import json
import math
import re

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.spec.tolerance import ResponseGP, joint_region, tolerance_interval


def test_gp_recovers_smooth_function_with_calibrated_bands():
    rng = np.random.default_rng(3)
    f = lambda x: 0.6 + 0.25 * np.sin(2.5 * x)  # noqa: E731
    sd = 0.03
    x = np.linspace(0.0, 2.0, 30)
    model = ResponseGP(["x_m"], x[:, None], f(x) + rng.normal(0, sd, x.size))
    # the learned white noise matches the true noise (sampling error of a variance from 30 points ~ 26 %)
    assert abs(math.sqrt(model.white_variance) / sd - 1) < 0.5
    xt = rng.uniform(0.0, 2.0, 400)
    p = model.predict(xt[:, None])
    y_new = f(xt) + rng.normal(0, sd, xt.size)
    inside = np.mean(np.abs(y_new - p.mean) <= 2 * p.sd)
    expected = math.erf(2 / math.sqrt(2))
    se = math.sqrt(expected * (1 - expected) / xt.size)
    assert expected - 3 * se <= inside <= 1.0
    # the mean tracks the function to within its latent uncertainty
    latent = np.sqrt(np.maximum(p.sd**2 - model.white_variance, 1e-12))
    assert np.mean(np.abs(p.mean - f(xt)) <= 3 * latent + 1e-3) > 0.95


def test_leave_one_out_share_and_binomial_error():
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 1.0, 12)
    y = 0.5 + 0.2 * x + rng.normal(0, 0.02, x.size)
    loo = ResponseGP(["x_m"], x[:, None], y, np.full(x.size, 0.02**2)).leave_one_out()
    assert loo["n"] == 12 and len(loo["points"]) == 12
    assert loo["share_inside"] == sum(r["inside"] for r in loo["points"]) / 12
    # a linear function with known noise: held-out points are inside at about the nominal 95 % rate
    assert loo["share_inside"] >= 0.954 - 3 * math.sqrt(0.954 * 0.046 / 12)


def test_tolerance_interval_matches_analytic():
    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 1.0, 21)
    f = lambda x: 0.8 - 0.6 * (x - 0.4) ** 2  # noqa: E731
    sd = 1e-3
    model = ResponseGP(["x_m"], x[:, None], f(x) + rng.normal(0, sd, x.size))
    required = 0.75
    t = tolerance_interval(model, "x_m", required, {"x_m": 0.5})
    band = 2 * model.predict(np.array([[0.4]])).sd[0]
    half = math.sqrt((0.8 - required - band) / 0.6)
    assert t.meets_requirement
    # the peak is flat: a mean error of ~1e-4 moves the argmax by sqrt(1e-4 / 0.6) ~ 0.013
    assert t.optimal == pytest.approx(0.4, abs=0.04)
    assert t.min == pytest.approx(0.4 - half, abs=0.01)
    assert t.max == pytest.approx(0.4 + half, abs=0.01)
    assert t.min_limited_by == t.max_limited_by == "requirement"
    assert not (t.min_extrapolated or t.max_extrapolated)


def test_tolerance_at_sampled_edge_is_flagged_and_extrapolation_marked():
    x = np.linspace(1.0, 2.0, 11)
    model = ResponseGP(["diameter_m"], x[:, None], 0.3 + 0.3 * (x - 1.0), np.full(11, 1e-6))
    t = tolerance_interval(model, "diameter_m", 0.45, {"diameter_m": 1.5})
    assert t.max == pytest.approx(2.0) and t.max_limited_by == "sampled_range" and not t.max_extrapolated
    assert t.min_limited_by == "requirement" and 1.45 < t.min < 1.6
    te = tolerance_interval(model, "diameter_m", 0.45, {"diameter_m": 1.5}, extrapolate=0.2)
    assert te.max > 2.0 and te.max_extrapolated and te.max_limited_by == "extrapolation_edge"
    unmet = tolerance_interval(model, "diameter_m", 0.9, {"diameter_m": 1.5})
    assert not unmet.meets_requirement and unmet.min is None


def test_joint_region_of_separable_function():
    # y = 1 - a^2 - b^2 on a one-at-a-time design: the box corners fail, the centre holds
    a = np.r_[0.0, -0.6, -0.3, 0.3, 0.6, 0, 0, 0, 0]
    b = np.r_[0.0, 0, 0, 0, 0, -0.6, -0.3, 0.3, 0.6]
    X = np.column_stack([a, b])
    model = ResponseGP(["a_m", "b_m"], X, 1 - a**2 - b**2, np.full(9, 1e-6))
    tols = {n: tolerance_interval(model, n, 0.8, {"a_m": 0.0, "b_m": 0.0}) for n in ("a_m", "b_m")}
    j = joint_region(model, 0.8, tols, n_per_axis=11)
    assert 0.3 < j["share_of_box_ok"] < 1.0
    assert j["worst_lower"] < 0.8


def test_gp_rejects_bad_input():
    with pytest.raises(MetrawError):
        ResponseGP(["x_m"], np.array([[0.0], [1.0]]), [0.1, 0.2])
    with pytest.raises(MetrawError):
        ResponseGP(["x_m"], np.array([[0.0], [1.0], [2.0]]), [0.1, np.nan, 0.3])


def _records(rng, n, iou):
    """Per-image (tp, fp, fn) as `metraw evaluate` writes them, pooled IoU about ``iou``."""
    u = rng.uniform(50, 150, n)
    tp = u * np.clip(iou + rng.normal(0, 0.1, n), 0, 1)
    fp = (u - tp) * 0.5
    return [{"tp": float(a), "fp": float(b), "fn": float(c - a - b)} for a, b, c in zip(tp, fp, u)]


def _write_point(root, point, iou=0.7):
    d = root / point
    d.mkdir(parents=True)
    recs = _records(np.random.default_rng(len(point)), 3, iou)
    pooled = sum(r["tp"] for r in recs) / sum(r["tp"] + r["fp"] + r["fn"] for r in recs)
    (d / "metrics.json").write_text(json.dumps({"iou": pooled, "per_image": recs, "n_images": 3}))


def test_aggregate_errors_clearly_when_a_point_is_missing(tmp_path):
    from metraw.spec.aggregate import load_point_results
    from metraw.study.points import load_params, parameter_points

    params = load_params("params.yaml")
    points = list(parameter_points(params))
    for p in points[:-1]:
        _write_point(tmp_path, p)
    with pytest.raises(MetrawError, match=re.escape(points[-1])):
        load_point_results(params, str(tmp_path), "{results}/{point}/metrics.json", "")
    _write_point(tmp_path, points[-1], 0.5)
    rows = load_point_results(params, str(tmp_path), "{results}/{point}/metrics.json", "")
    assert [r["point"] for r in rows] == points
    assert rows[-1]["n_test_images"] == 3 and rows[-1]["iou_sd"] > 0


def test_pooled_iou_variance_matches_resampling():
    """The delta-method variance of the pooled IoU agrees with the spread over resampled test sets."""
    from metraw.spec.aggregate import iou_measurement

    rng = np.random.default_rng(5)
    recs = _records(rng, 400, 0.6)
    tp = np.array([r["tp"] for r in recs])
    u = np.array([r["tp"] + r["fp"] + r["fn"] for r in recs])
    iou, var = iou_measurement({"iou": tp.sum() / u.sum(), "per_image": recs}, "test")
    boot = [tp[i].sum() / u[i].sum() for i in rng.integers(0, len(recs), (2000, len(recs)))]
    # the bootstrap variance from 2000 resamples has a relative SE of sqrt(2/2000) ~ 3 %
    assert np.var(boot, ddof=1) == pytest.approx(var, rel=0.15)
    assert iou_measurement({"iou": 0.5, "per_image": recs[:1]}, "test") == (0.5, 0.0)
