"""The adaptive sweep's rule (issue #70): train next where the IoU GP cannot yet tell which side of the required IoU
the response lies (docs/statistics.md, "An adaptive sweep").

Straddle (Bryan et al., NIPS 2005): s(x) = 1.96 sigma(x) - |mu(x) - t|, t = ``spec.required_iou``, mu the GP mean and
sigma the posterior sd of the mean response (the latent GP: what more training can reduce; the white noise a new
measurement adds cannot be trained away, and with it the rule would sample a flat crossing for ever). The GP is the
aggregate's (`metraw.spec.tolerance.ResponseGP` over the numeric parameters at the nominal categories, each point's
IoU variance, test images and replicate seeds, as ``alpha``). s > 0 where the 95 % interval of the mean still holds
t: a *stretch of doubt*. Candidates: ``line_candidates`` values along each numeric parameter's range (others
nominal, uniform on its working axis) and the ``grid_candidates`` x ``grid_candidates`` cells of each grid, values
rounded to 4 significant digits (point names stay short), trained points left out; categorical parameters are not
adapted. A round takes ``points_per_round`` candidates one after the other, each time the largest straddle with the
sd conditioned on the round's earlier choices (their outcomes unknown, the sd needs none), so a round does not pile
its points on one spot; candidates on a line whose stretches are all narrow enough are passed over.
Stop: every stretch of doubt of every line is at most ``stop_width`` of the line's range (working axis), or the
budget is spent, or no candidate has a positive straddle.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from metraw.errors import MetrawError
from metraw.spec.tolerance import BAND_SIGMA, Axis, ResponseGP, Tolerance, axis_kind

#: The straddle's multiple of sigma (Bryan et al. 2005: the 95 % interval of a normal).
STRADDLE_Z = 1.96
#: Points along a line where its stretches of doubt are measured (on the working axis).
LINE_RESOLUTION = 801


def straddle(mean: np.ndarray, sd: np.ndarray, level: float, z: float = STRADDLE_Z) -> np.ndarray:
    """``z sd - |mean - level|``: positive where the z-sigma interval of the mean holds ``level``."""
    return z * np.asarray(sd, dtype=np.float64) - np.abs(np.asarray(mean, dtype=np.float64) - level)


def _round4(value: float) -> float:
    return float(f"{float(value):.4g}")


def candidates(params: dict[str, Any], trained: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Every candidate point: values along each numeric line, cells of each two-axis grid, each once (a cell on a
    line is that line's), none already ``trained`` (name -> overrides). Records: name, overrides, kind (line |
    grid), where (the line's parameter or the grid's axes)."""
    from metraw.study.points import adaptive_settings, grid_axes, named_point, numeric_ranges

    settings = adaptive_settings(params)
    seen = {_key(o) for o in trained.values()}
    out = []

    def add(overrides, kind, where):
        name, overrides = named_point(params, overrides)
        if _key(overrides) not in seen:
            seen.add(_key(overrides))
            out.append({"name": name, "overrides": overrides, "kind": kind, "where": where})

    ranges = numeric_ranges(params)
    for name, (low, high) in ranges.items():
        ax = Axis(name, axis_kind(name), low, high)
        for v in ax.from_unit(np.linspace(0.0, 1.0, settings["line_candidates"])):
            add({name: _round4(v)}, "line", name)
    for grid in params["target"].get("grids") or []:
        axes, fixed = grid_axes(grid)
        if len(axes) != 2:
            continue
        (a, b), n = axes, settings["grid_candidates"]
        va, vb = (Axis(k, axis_kind(k), min(grid[k]), max(grid[k])).from_unit(np.linspace(0, 1, n)) for k in (a, b))
        for x in va:
            for y in vb:
                add({**{k: v for k, v in fixed.items()}, a: _round4(x), b: _round4(y)}, "grid", f"{a} x {b}")
    return out


def _key(overrides: Mapping[str, Any]) -> frozenset:
    return frozenset((k, v if isinstance(v, str) else float(v)) for k, v in overrides.items())


def design_matrix(names: Sequence[str], at: Mapping[str, float], overrides: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """(n, d) parameter values: ``at`` (the nominal) with each point's overrides of the GP's parameters."""
    return np.array([[float(o.get(n, at[n])) for n in names] for o in overrides], dtype=np.float64).reshape(-1, len(names))


# ---------------------------------------------------------------------- lines: stretches of doubt
def stretches(u: np.ndarray, x: np.ndarray, s: np.ndarray) -> list[dict[str, float]]:
    """The connected runs where ``s`` > 0 along a line (``u`` its working-axis unit coordinate, ``x`` its values):
    low and high value, width in ``u`` (the ends interpolated where s crosses 0)."""
    out = []
    pos = s > 0
    i = 0
    while i < len(s):
        if not pos[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(s) and pos[j + 1]:
            j += 1
        ulo = u[i] if i == 0 else u[i - 1] + (u[i] - u[i - 1]) * (0 - s[i - 1]) / (s[i] - s[i - 1])
        uhi = u[j] if j == len(s) - 1 else u[j] + (u[j + 1] - u[j]) * (0 - s[j]) / (s[j + 1] - s[j])
        out.append({"u_low": float(ulo), "u_high": float(uhi), "width": float(uhi - ulo),
                    "low": float(np.interp(ulo, u, x)), "high": float(np.interp(uhi, u, x)),
                    "at_range_edge": bool(i == 0 or j == len(s) - 1)})
        i = j + 1
    return out


def mean_crossings(u: np.ndarray, x: np.ndarray, mean: np.ndarray, level: float) -> list[float]:
    """Values where the GP mean crosses ``level`` along a line (linear interpolation on the working axis)."""
    d = mean - level
    out = []
    for i in np.flatnonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0):
        t = d[i] / (d[i] - d[i + 1])
        out.append(float(np.interp(u[i] + t * (u[i + 1] - u[i]), u, x)))
    return out


def line_doubt(model: ResponseGP, name: str, at: Mapping[str, float], level: float,
               n: int = LINE_RESOLUTION) -> dict[str, Any]:
    """Along ``name`` over the GP's sampled range (others at ``at``): the mean's crossings of ``level``, the stretches
    of doubt (straddle > 0) and the widest one's width (fraction of the range on the working axis)."""
    ax = model.axes[model.names.index(name)]
    u = np.linspace(0.0, 1.0, n)
    x = ax.from_unit(u)
    X = design_matrix(model.names, at, [{name: v} for v in x])
    mean = model.predict(X).mean
    s = straddle(mean, model.latent_sd(X), level)
    found = stretches(u, x, s)
    return {"stretches": found, "widest": max((f["width"] for f in found), default=0.0),
            "mean_crossings": mean_crossings(u, x, mean, level)}


# ---------------------------------------------------------------------- one round
def choose(model: ResponseGP, X: np.ndarray, level: float, n: int, eligible: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """Pick up to ``n`` rows of the candidates ``X`` one after the other by largest straddle, the latent sd
    conditioned on the earlier picks of the round. Returns (mean, latent sd, straddle) of every candidate before any
    pick, and the picks: index, straddle, latent sd at the time of the pick. Stops early when no eligible candidate
    has a positive straddle."""
    mean = model.predict(X).mean
    sd0 = model.latent_sd(X)
    s0 = straddle(mean, sd0, level)
    ok = np.ones(len(X), bool) if eligible is None else np.asarray(eligible, bool).copy()
    picks: list[dict[str, Any]] = []
    sd = sd0
    for _ in range(n):
        if picks:
            sd = model.latent_sd(X, X[[p["index"] for p in picks]])
        s = np.where(ok, straddle(mean, sd, level), -np.inf)
        i = int(np.argmax(s)) if len(s) else -1
        if i < 0 or not s[i] > 0:
            break
        picks.append({"index": i, "straddle": float(s[i]), "latent_sd": float(sd[i])})
        ok[i] = False
    return mean, sd0, s0, picks


def fit_iou(params: dict[str, Any], rows: Sequence[Mapping[str, Any]], seed: int = 0
            ) -> tuple[ResponseGP, list[str], dict[str, float]]:
    """The aggregate's IoU GP (`metraw.spec.aggregate`): the numeric parameters, the points at the nominal
    categories, each point's IoU variance as alpha. Returns (model, its parameter names, the nominal values)."""
    from metraw.study.points import CATEGORICAL, NOMINAL, swept_parameters, target_params

    all_names = swept_parameters(params)
    names = [n for n in all_names if n not in CATEGORICAL]
    nominal = target_params(params, NOMINAL)
    gp_rows = [r for r in rows if all(r[c] == nominal[c] for c in all_names if c in CATEGORICAL)]
    X = np.array([[r[n] for n in names] for r in gp_rows])
    model = ResponseGP(names, X, [r["iou"] for r in gp_rows], [r["iou_sd"] ** 2 for r in gp_rows], seed=seed)
    return model, names, {n: float(nominal[n]) for n in names}


def gp_state(model: ResponseGP) -> dict[str, Any]:
    """What a round record keeps of the GP: its data, axes, fitted kernel and white noise."""
    return {"parameters": model.names, "kernel": model.kernel_description(),
            "white_sd": math.sqrt(model.white_variance),
            "log_marginal_likelihood": float(model.gp.log_marginal_likelihood_value_),
            "axes": [{"name": a.name, "kind": a.kind, "low": a.lo, "high": a.hi} for a in model.axes],
            "X": model.X.tolist(), "iou": model.y.tolist(), "iou_sd": np.sqrt(model.y_var).tolist()}


def plan_round(params: dict[str, Any], rows: Sequence[Mapping[str, Any]], round_index: int, seed: int = 0,
               screened: Sequence[Mapping[str, Any]] = (), screening: Mapping[str, Any] | None = None
               ) -> dict[str, Any]:
    """Round ``round_index``'s record: the GP fitted to ``rows`` (every point trained so far) and ``screened`` (the
    box model's rows of the points not trained, `metraw.spec.screening`; ``screening`` its record), each line's
    stretches of doubt, every candidate's straddle, the points chosen for the next round and why, or why the sweep
    stops."""
    from metraw.study.points import adaptive_settings, parameter_points, point_rounds

    settings = adaptive_settings(params)
    level = float(params["spec"]["required_iou"])
    width = float(settings["stop_width"])
    model, names, at = fit_iou(params, [*rows, *screened], seed)
    trained = parameter_points(params)
    lines = {n: line_doubt(model, n, at, level) for n in names}
    for rec in lines.values():
        rec["resolved"] = rec["widest"] <= width
    cands = candidates(params, trained)
    X = design_matrix(names, at, [c["overrides"] for c in cands])
    eligible = np.array([not (c["kind"] == "line" and lines[c["where"]]["resolved"]) for c in cands], bool)
    left = int(settings["budget"]) - len(trained)
    unresolved = [n for n, rec in lines.items() if not rec["resolved"]]
    n_pick = min(int(settings["points_per_round"]), max(left, 0)) if unresolved else 0
    mean, sd, s, picks = choose(model, X, level, n_pick, eligible) if len(cands) else (
        np.zeros(0), np.zeros(0), np.zeros(0), [])
    chosen = []
    for i, p in enumerate(picks):
        c = cands[p["index"]]
        conditioned = f"; sd conditioned on this round's {i} earlier choice(s)" if i else ""
        chosen.append({"name": c["name"], "overrides": c["overrides"], "kind": c["kind"], "where": c["where"],
                       "straddle": p["straddle"], "mean": float(mean[p["index"]]), "latent_sd": p["latent_sd"],
                       "why": f"largest straddle {p['straddle']:.4g} among the {int(eligible.sum())} eligible candidates "
                              f"(1.96 x {p['latent_sd']:.4g} - |{mean[p['index']]:.4g} - {level:g}|{conditioned}); "
                              f"unresolved lines: {', '.join(unresolved)}"})
    if not unresolved:
        reason = f"every stretch of doubt of every line is at most {width:g} of its range"
    elif left <= 0:
        reason = f"budget of {settings['budget']} trained points spent"
    elif not chosen:
        reason = "no eligible candidate has a positive straddle"
    else:
        reason = None
    rounds = point_rounds(params)
    return {
        "round": round_index, "required_iou": level, "straddle_z": STRADDLE_Z, "stop_width": width,
        "budget": int(settings["budget"]), "points_per_round": int(settings["points_per_round"]),
        "n_trained": len(trained),
        "trained": [{"point": r["point"], "round": rounds.get(r["point"], 0), "iou": r["iou"], "iou_sd": r["iou_sd"]}
                    for r in rows],
        **({"screening": dict(screening)} if screening else {}),
        "gp": gp_state(model),
        "lines": lines,
        "candidates": [{**c, "mean": float(mean[i]), "latent_sd": float(sd[i]), "straddle": float(s[i]),
                        "eligible": bool(eligible[i])} for i, c in enumerate(cands)],
        "chosen": chosen,
        "stop": {"stopped": reason is not None, "reason": reason},
    }


# ---------------------------------------------------------------------- what the aggregate reports
def line_bands(model: ResponseGP, name: str, at: Mapping[str, float], level: float, k: float = BAND_SIGMA,
               n: int = LINE_RESOLUTION) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """Along ``name`` (others at ``at``): the stretches where the GP's k-sigma band (predictive sd) holds ``level``,
    and the stretches of doubt of the mean (straddle > 0); each with its ends and width (`stretches`)."""
    ax = model.axes[model.names.index(name)]
    u = np.linspace(0.0, 1.0, n)
    x = ax.from_unit(u)
    X = design_matrix(model.names, at, [{name: v} for v in x])
    p = model.predict(X, k)
    return (stretches(u, x, k * p.sd - np.abs(p.mean - level)),
            stretches(u, x, straddle(p.mean, model.latent_sd(X), level)))


def nearest_stretch(found: list[dict[str, float]], u: float) -> dict[str, float] | None:
    """The stretch of ``found`` nearest to the working-axis unit coordinate ``u`` (one holding it first): low, high,
    width; None when there is none."""
    if not found:
        return None
    best = min(found, key=lambda f: max(f["u_low"] - u, u - f["u_high"], 0.0))
    return {"low": best["low"], "high": best["high"], "width": best["width"]}


def tolerance_ends(model: ResponseGP, tolerances: Mapping[str, Tolerance], at: Mapping[str, float], level: float,
                   k: float = BAND_SIGMA, n: int = LINE_RESOLUTION) -> dict[str, Any]:
    """Each tolerance end's uncertainty: for an end set by the requirement, the stretch of its line where the GP's
    k-sigma band (predictive sd) holds ``level`` (the end is that stretch's edge: the spec's end moves within it as
    the mean does) and the stretch of doubt of the mean (straddle > 0) nearest to it, each with its width as a
    fraction of the range (working axis; `line_bands`). An end set by the sampled range has no uncertainty of this
    kind."""
    out = {}
    for name, t in tolerances.items():
        ax = model.axes[model.names.index(name)]
        band, doubt = line_bands(model, name, at, level, k, n)
        ends = {}
        for side in ("min", "max"):
            value, by = getattr(t, side), getattr(t, f"{side}_limited_by")
            rec: dict[str, Any] = {"value": value, "limited_by": by}
            if value is not None and by == "requirement":
                ue = float(ax.to_unit(value))
                rec["band"] = nearest_stretch(band, ue)
                rec["doubt"] = nearest_stretch(doubt, ue)
            ends[side] = rec
        out[name] = ends
    return out


def summary(params: dict[str, Any], model: ResponseGP, tolerances: Mapping[str, Tolerance], at: Mapping[str, float],
            level: float, screening: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``adaptive`` block of aggregate.json and spec.yaml's context: that the points came from an adaptive run,
    its settings, the points each round added, each line's widest stretch of doubt and each tolerance end's
    uncertainty (`tolerance_ends`); with screening, the points the box model alone measured and its offset
    (`metraw.spec.screening`)."""
    from metraw.study.points import adaptive_settings, point_rounds

    settings = adaptive_settings(params)
    rounds = point_rounds(params)
    by_round: dict[int, list[str]] = {}
    for name, r in rounds.items():
        by_round.setdefault(r, []).append(name)
    widest = {n: line_doubt(model, n, at, level)["widest"] for n in model.names}
    return {"adaptive": True, "rule": f"straddle {STRADDLE_Z} sigma - |mu - {level:g}| (Bryan et al. 2005)",
            "budget": int(settings["budget"]), "points_per_round": int(settings["points_per_round"]),
            "stop_width": float(settings["stop_width"]), "n_points": len(rounds),
            "rounds": [by_round[r] for r in sorted(by_round)],
            "widest_doubt": widest, "all_lines_resolved": all(w <= settings["stop_width"] for w in widest.values()),
            "tolerance_ends": tolerance_ends(model, tolerances, at, level),
            **({"screening": {"screened_points": [r["point"] for r in screening["rows"]],
                              "offset": screening["offset"], "offset_sd": screening["offset_sd"],
                              "n_pairs": screening["n_pairs"], "offset_sd_from": screening["offset_sd_from"]}}
               if screening else {})}


def round_figures(model: ResponseGP, rows: Sequence[Mapping[str, Any]], rounds: Mapping[str, int],
                  at: Mapping[str, float], level: float, figdir: str | Path,
                  grids: Sequence[Sequence[str]] = ()) -> list[Path]:
    """``adaptive_iou_{parameter}.png`` per line (GP mean, 2-sigma band, the stretches of doubt shaded, the trained
    points on the line coloured and numbered by round, screened rows (``screened``: the box model's, untrained) as
    open squares) and ``adaptive_grid_{a}_{b}.png`` per grid (the GP mean over the grid's plane, the contour mean =
    required, the trained points numbered by round, the screened ones as squares). Returns the paths."""
    from metraw.spec.figures import LABELS, _plt, _save, line_table

    plt = _plt()
    figdir = Path(figdir)

    def cmap(r):  # one colour per round (tab10's, round 0 in blue, then orange, green, red, ...)
        return f"C{r % 10}"
    written = []
    for name in model.names:
        others = [m for m in model.names if m != name]
        on = [r for r in rows if r["point"] in rounds and all(float(r[m]) == at[m] for m in others)]
        t = line_table(model, name, at)
        doubt = line_doubt(model, name, at, level)
        fig, ax = plt.subplots(figsize=(4.8, 3.4))
        ax.fill_between(t[name], t["lower"], t["upper"], color="0.6", alpha=0.3, lw=0, label="GP 2$\\sigma$ band")
        ax.plot(t[name], t["mean"], color="0.2", lw=1.5, label="GP mean")
        for i, st in enumerate(doubt["stretches"]):
            ax.axvspan(st["low"], st["high"], color="gold", alpha=0.35, lw=0,
                       label="straddle > 0 (doubt)" if i == 0 else None)
        ax.axhline(level, color="tab:red", ls="--", lw=1, label=f"required {level:g}")
        for r in on:
            c = cmap(rounds[r["point"]])
            ax.errorbar(float(r[name]), r["iou"], yerr=2 * r["iou_sd"], fmt="o", color=c, ms=4, capsize=2)
            ax.annotate(str(rounds[r["point"]]), (float(r[name]), r["iou"]), textcoords="offset points",
                        xytext=(4, 4), fontsize=7, color=c)
        for i, r in enumerate(r for r in rows if r.get("screened") and all(float(r[m]) == at[m] for m in others)):
            ax.errorbar(float(r[name]), r["iou"], yerr=2 * r["iou_sd"], fmt="s", mfc="none", color="0.35", ms=5,
                        capsize=2, label="box model + offset (screened, untrained)" if i == 0 else None)
        ax.plot([], [], "o", color="C0", ms=4, label="trained (colour, number: round)")
        if model.axes[model.names.index(name)].kind == "log":
            ax.set_xscale("log")
        ax.set_xlabel(LABELS.get(name, name))
        ax.set_ylabel("IoU (test split)")
        ax.set_title(f"adaptive sweep: IoU vs {name} (others nominal)", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="best")
        path = figdir / f"adaptive_iou_{name}.png"
        _save(fig, path)
        written.append(path)
    for a, b in grids:
        if a not in model.names or b not in model.names:
            raise MetrawError(f"grid axes {a}, {b} are not both parameters of the GP ({', '.join(model.names)})")
        ga, gb = (model.axes[model.names.index(k)].from_unit(np.linspace(0, 1, 60)) for k in (a, b))
        A, B = np.meshgrid(ga, gb)
        X = np.tile([at[m] for m in model.names], (A.size, 1))
        X[:, model.names.index(a)], X[:, model.names.index(b)] = A.ravel(), B.ravel()
        mean = model.predict(X).mean.reshape(A.shape)
        fig, ax = plt.subplots(figsize=(5.0, 3.9))
        im = ax.pcolormesh(A, B, mean, shading="auto", cmap="Greys")
        fig.colorbar(im, ax=ax, label="IoU (GP mean)")
        if mean.min() < level < mean.max():
            ax.contour(A, B, mean, levels=[level], colors="tab:red", linewidths=1.2)
        others = [m for m in model.names if m not in (a, b)]
        for r in rows:
            if r.get("screened") and all(float(r[m]) == at[m] for m in others):
                ax.plot(float(r[a]), float(r[b]), "s", mfc="none", color="tab:blue", ms=6)
            elif r["point"] in rounds and all(float(r[m]) == at[m] for m in others):
                c = cmap(rounds[r["point"]])
                ax.plot(float(r[a]), float(r[b]), "o", color=c, ms=5)
                ax.annotate(str(rounds[r["point"]]), (float(r[a]), float(r[b])), textcoords="offset points",
                            xytext=(4, 4), fontsize=7, color=c)
        for k, setter in ((a, ax.set_xscale), (b, ax.set_yscale)):
            if model.axes[model.names.index(k)].kind == "log":
                setter("log")
        ax.set_xlabel(LABELS.get(a, a))
        ax.set_ylabel(LABELS.get(b, b))
        ax.set_title(f"points by round, squares screened; red: mean = {level:g}", fontsize=8)
        path = figdir / f"adaptive_grid_{a}_{b}.png"
        _save(fig, path)
        written.append(path)
    return written
