"""The aggregation of a study (`metraw aggregate`): per-point results -> GP response surfaces, tolerances,
spec.yaml, figures.

The point list comes from params.yaml (`metraw.study.points.parameter_points`), never from a glob;
every point's metrics (and compression) file must exist. Outputs under ``--out``:
``spec.yaml``, ``aggregate.json``, ``figures/*.png`` and ``plots/*.csv`` (for ``dvc plots``).
With replicate models a point's IoU, precision, recall and object F1 (synthetic and real) are the means over
the replicates (``iou_measurement``, ``with_replicate_means``); box scores are the first model's.

Sim-to-real (``--real-metrics-pattern``, issue #16): each point's synthetic-trained model scored on the
real images emulated through the same point. aggregate.json then holds per point ``real_iou`` (+ sd),
``real_precision``, ``real_recall``, ``real_box_iou`` (box labels: predicted objects as boxes),
``real_labels``, ``sim_to_real_gap`` (synthetic test IoU - real IoU, with its sd) and ``sim_to_real_note``, plus a top-level ``sim_to_real`` summary (nominal gap, whether it
is within ``--gap-tolerance``; ``--source-real-metrics``: the drone-resolution reference); the IoU
figures draw the real points beside the synthetic ones. The GP, tolerances and spec.yaml are fitted
to the synthetic test IoU only: the real images are a check of transfer, not the basis of the spec.
"""


from __future__ import annotations

import csv
import io
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.spec import resolution
from metraw.spec.screening import DEFAULT_SCREEN, screened_rows

DEFAULT_METRICS = "{results}/{point}/metrics.json"
DEFAULT_COMPRESSION = "{results}/{point}/compression.json"

#: Figure file names (seed study numbering) per swept parameter.
IOU_FIGS = {"focal_length_m": "fig7c_iou_focal_length.png", "diameter_m": "fig7d_iou_diameter.png",
            "exposure_s": "fig7e_iou_exposure.png"}
#: Legend label of the real-image series in the IoU figures.
REAL_LABEL = "emulated real images (2 sd)"
RATIO_FIGS = {"focal_length_m": "fig8a_ratio_focal_length.png", "exposure_s": "fig8b_ratio_exposure.png",
              "diameter_m": "fig8c_ratio_diameter.png"}


@dataclass
class AggregateOptions:
    """What `aggregate` reads and writes (the options of `metraw aggregate`, same names and defaults)."""

    params: str = "params.yaml"
    results: str = "results"
    out: str = "results"
    metrics_pattern: str = DEFAULT_METRICS
    compression_pattern: str = DEFAULT_COMPRESSION
    stores_pattern: str = ""
    screen_pattern: str = DEFAULT_SCREEN
    real_metrics_pattern: str = ""
    source_real_metrics: str = ""
    source_metrics: str = ""
    gap_tolerance: float | None = None
    example_index: int = 0
    extrapolate: float = 0.0
    seed: int = 0


def _read_json(path: Path, what: str) -> dict[str, Any]:
    if not path.is_file():
        raise MetrawError(f"{what} {path} is missing (run its rule first; the point list comes from params.yaml)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise MetrawError(f"{what} {path} is not valid JSON: {exc}") from None


#: Scores of a metrics record that ``with_replicate_means`` averages over its replicate models.
REPLICATE_SCORES = ("precision", "recall", "object_f1")


def with_replicate_means(metrics: dict[str, Any]) -> dict[str, Any]:
    """``metrics`` with precision, recall and object F1 averaged over its replicate models (``metraw evaluate``
    of a model with replicates lists each model's scores), so they describe the same models as the IoU, which
    ``iou_measurement`` averages alike; a record without replicates is returned as it is."""
    reps = metrics.get("replicates") or []
    out = dict(metrics)
    for key in REPLICATE_SCORES:
        values = [r[key] for r in reps if r.get(key) is not None]
        if len(values) > 1:
            out[key] = float(np.mean(values))
    return out


def _read_measured(path: Path, what: str) -> tuple[dict[str, Any], tuple[float, float]]:
    """A metrics file with its scores averaged over replicates (``with_replicate_means``), and (IoU, variance of
    that IoU) (``iou_measurement``)."""
    return _measured(_read_json(path, what), str(path))


def _measured(metrics: dict[str, Any], where: str) -> tuple[dict[str, Any], tuple[float, float]]:
    """``_read_measured`` of metrics already read."""
    metrics = with_replicate_means(metrics)
    return metrics, iou_measurement(metrics, where)


def iou_measurement(metrics: dict[str, Any], where: str) -> tuple[float, float]:
    """Test-split IoU and the variance of that estimate.

    With replicate models (``metraw train`` with ``replicates`` > 1) the IoU is their mean and the variance
    adds the seeds' squared standard error (``iou_replicate_se``) to the test-image term below.

    The pooled IoU R = sum(TP_i) / sum(U_i) (U_i = TP_i + FP_i + FN_i per test image) is a ratio
    estimator; its variance over the draw of test images is, to first order (delta method),
    var(TP_i - R U_i) / (n mean(U)^2). One image gives no variance (0).
    """
    if metrics.get("iou") is None:
        raise MetrawError(f"{where}: metrics have no test-split 'iou'")
    recs = [r for r in metrics.get("per_image", []) if all(k in r for k in ("tp", "fp", "fn"))]
    iou = float(metrics["iou"])
    if len(recs) < 2:
        return iou, 0.0
    tp = np.array([r["tp"] for r in recs], dtype=np.float64)
    u = tp + np.array([r["fp"] + r["fn"] for r in recs], dtype=np.float64)
    if u.mean() <= 0:
        return iou, 0.0
    var = float(np.var(tp - iou * u, ddof=1) / (len(recs) * u.mean() ** 2))
    if metrics.get("iou_replicate_mean") is not None and metrics.get("iou_replicate_se") is not None:
        # replicate models (training seeds) scored on the same test images: their mean IoU, with the seed
        # error of that mean added to the test-image sampling error
        return float(metrics["iou_replicate_mean"]), var + float(metrics["iou_replicate_se"]) ** 2
    return iou, var


def load_point_results(params: dict[str, Any], results: str, metrics_pattern: str, compression_pattern: str,
                       real_pattern: str = "", gap_tolerance: float | None = None) -> list[dict[str, Any]]:
    """One record per point of params.yaml: parameters, IoU (+variance), compression (+variance) and, with
    ``real_pattern``, the real-image columns (``metraw.study.sim_to_real.real_columns``)."""
    from metraw.spec import unmeasured
    from metraw.study.points import CATEGORICAL, parameter_points, swept_parameters, target_params
    from metraw.study.sim_to_real import GAP_TOLERANCE, real_columns

    names = swept_parameters(params)
    if not names:
        raise MetrawError("params.yaml has no target.sweeps: nothing to fit")
    rows = []
    missing = []
    for point in parameter_points(params):
        mpath = Path(metrics_pattern.format(results=results, point=point))
        cpath = Path(compression_pattern.format(results=results, point=point)) if compression_pattern else None
        rpath = Path(real_pattern.format(results=results, point=point)) if real_pattern else None
        for path in (mpath, cpath, rpath):
            if path is not None and not path.is_file():
                missing.append(str(path))
        if missing:
            continue
        # degenerate models (issue #71): the point's verdict; a degenerate replicate of a measured point is dropped
        raw = _read_json(mpath, "metrics file")
        status = unmeasured.point_status(raw)
        metrics, (iou, iou_var) = _measured(unmeasured.drop_models(raw, status["dropped"]), str(mpath))
        tp = target_params(params, point)
        row = {"point": point, **{n: tp[n] if n in CATEGORICAL else float(tp[n]) for n in names}, "iou": iou, "iou_sd": math.sqrt(iou_var),
               "precision": metrics.get("precision"), "recall": metrics.get("recall"),
               "n_test_images": metrics.get("n_images"), "epochs": metrics.get("epochs"),
               "n_replicates": metrics.get("n_replicates", 1), "iou_replicate_sd": metrics.get("iou_replicate_sd"),
               "object_f1": metrics.get("object_f1"),
               "replicate_ious": [q["iou"] for q in metrics.get("replicates", []) if q.get("iou") is not None],
               "_network": metrics.get("network")}
        if cpath is not None:
            row.update(compression_columns(cpath))
        if rpath is not None:
            real, (real_iou, real_var) = _measured(unmeasured.drop_models(
                _read_json(rpath, "real-image metrics file"), status["dropped"]), str(rpath))
            row.update(real_columns(row, real, real_iou, iou_var, real_var,
                                    GAP_TOLERANCE if gap_tolerance is None else gap_tolerance))
        row.update(unmeasured.row_fields(status, len(status["models"])))
        rows.append(row)
    if missing:
        raise MetrawError(f"{len(missing)} per-point result file(s) missing, e.g. {missing[0]}")
    return rows


def box_model_scores(params: dict[str, Any], results: str, pattern: str = DEFAULT_SCREEN
                     ) -> dict[str, tuple[float, float]]:
    """Point -> (IoU, its variance) of the pretrained box model alone at every screen point of an adaptive sweep
    with ``target.adaptive.screen`` (`metraw.study.points.screen_points`; rule screen); {} without. One line when a
    score is missing."""
    from metraw.study.points import screen_points

    paths = {q: Path(pattern.format(results=results, point=q)) for q in screen_points(params)}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise MetrawError(f"{len(missing)} box-model score(s) missing, e.g. {missing[0]} (rule screen)")
    return {q: _read_measured(p, "box-model metrics file")[1] for q, p in paths.items()}


def compression_columns(path: Path) -> dict[str, Any]:
    """A point's compression record (rule compress) as its row's columns: ratio and its sd over the images, bits
    per pixel, each channel's ratio and sd, and the signal the codec saw."""
    comp = _read_json(path, "compression file")
    return {"ratio": float(comp["overall"]["ratio"]),
            "ratio_sd": _sd_of_mean([im["ratio"] for im in comp["images"]]),
            "bits_per_pixel": float(comp["overall"]["bits_per_pixel"]),
            **{f"ratio_{c}": v["ratio"] for c, v in comp["channels"].items()},
            **{f"ratio_{c}_sd": _sd_of_mean([im["channels"][c]["ratio"] for im in comp["images"]
                                             if c in im.get("channels", {})]) for c in comp["channels"]},
            "_signal": comp.get("signal_e")}


#: What the aggregate and the spec say of the network the points were trained with (its checkpoint's record,
#: ``metraw.segment.networks.network_record``): a specification belongs to its model.
NETWORK_KEYS = ("name", "kind", "arch", "encoder", "encoder_weights", "factory", "factory_sha256", "kwargs",
                "parameters", "conditioned")


def study_network(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The network every point's model is (``NETWORK_KEYS`` of the records their metrics carry), None when their
    metrics predate the record; one line when the points were trained with different networks."""
    found = {}
    for r in rows:
        rec = r.get("_network")
        if rec:
            found.setdefault(json.dumps({k: rec.get(k) for k in NETWORK_KEYS if k != "parameters"}, sort_keys=True),
                             (r["point"], {k: rec[k] for k in NETWORK_KEYS if rec.get(k) is not None}))
    if len(found) > 1:
        (p1, a), (p2, b) = list(found.values())[:2]
        raise MetrawError(f"the points were trained with different networks: {p1} with {a.get('name')}, "
                          f"{p2} with {b.get('name')} (rerun the trainings with one training.model)")
    return next(iter(found.values()))[1] if found else None


def _sd_of_mean(values: list[float]) -> float:
    """Standard error of the mean of per-image values (0 for fewer than two)."""
    v = np.asarray(values, dtype=np.float64)
    return float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else 0.0


def _sim_to_real(options, rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The top-level ``sim_to_real`` block (None without ``--real-metrics-pattern``)."""
    from metraw.study import sim_to_real
    from metraw.study.points import NOMINAL

    if not options.real_metrics_pattern:
        if options.source_real_metrics:
            raise MetrawError("--source-real-metrics needs --real-metrics-pattern (the per-point real metrics)")
        return None
    tolerance = sim_to_real.GAP_TOLERANCE if options.gap_tolerance is None else options.gap_tolerance
    source = None
    if options.source_real_metrics:
        real, real_measured = _read_measured(Path(options.source_real_metrics), "source real-image metrics file")
        synthetic, syn = None, (0.0, 0.0)
        if options.source_metrics:
            synthetic, syn = _read_measured(Path(options.source_metrics), "source metrics file")
        source = sim_to_real.source_record(synthetic, real, syn, real_measured, tolerance)
    return sim_to_real.summary(rows, NOMINAL, source, tolerance)


def _csv(rows: list[dict[str, Any]], cols: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: ("" if r.get(c) is None else r.get(c)) for c in cols})
    return buf.getvalue()


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path, overwrite=True) as tmp:
        tmp.write_text(text)


def aggregate(options: AggregateOptions) -> int:
    """The aggregate with BLAS on one thread: the GP fits' linear algebra sums in another order on more threads, and
    the spec's last digits then depended on the shell's thread settings (the workflow's job ran on 1; by hand on 2
    cores one bound differed in its 16th digit; pinned, the default run's spec.yaml and aggregate.json came out byte
    for byte the workflow's). Same inputs, same bytes, wherever it runs; the GPs are small. The params and the points'
    results are read and checked first: a bad input is refused before the GP's libraries load (~1 s)."""
    params, required, rows = _inputs(options)
    import scipy.linalg  # noqa: F401  the libraries whose thread pools to limit: loaded first, since
    import sklearn.gaussian_process  # noqa: F401  threadpoolctl limits only the ones loaded when it starts
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _aggregate(options, params, required, rows)


def _inputs(options: AggregateOptions) -> tuple[dict, float, list[dict]]:
    """The checked params, their required IoU and the points' result rows (MetrawError on a bad one)."""
    from metraw.study.points import load_params

    params = load_params(options.params)
    required = float(params.get("spec", {}).get("required_iou", math.nan))
    if not 0 < required < 1:
        raise MetrawError(f"{options.params}: spec.required_iou must lie in (0, 1), got {required}")
    rows = load_point_results(params, options.results, options.metrics_pattern, options.compression_pattern,
                              options.real_metrics_pattern, options.gap_tolerance)
    return params, required, rows


def _aggregate(options: AggregateOptions, params: dict, required: float, rows: list[dict]) -> int:
    from metraw.spec import figures, unmeasured
    from metraw.spec.builder import build_spec
    from metraw.spec.tolerance import BAND_SIGMA, ResponseGP, categorical_choice, joint_region, tolerance_interval
    from metraw.study.points import CATEGORICAL, NOMINAL, swept_parameters, target_params

    rows, skipped = unmeasured.split(rows)  # points whose every model is degenerate: out of every fit (issue #71)
    for r in skipped:
        print(unmeasured.line(r))
    unmeasured.require_measured(rows, skipped)
    real = _sim_to_real(options, rows)
    res = resolution.resolution(rows, options.metrics_pattern.format(results=options.results, point=NOMINAL))
    all_names = swept_parameters(params)
    names = [n for n in all_names if n not in CATEGORICAL]  # the GP's axes
    categorical = [n for n in all_names if n in CATEGORICAL]
    nominal = target_params(params, NOMINAL)
    at = {n: float(nominal[n]) for n in names}
    # the GP spans the numeric parameters at the nominal category; categories are compared by measurement
    gp_rows = [r for r in rows if all(r[c] == nominal[c] for c in categorical)]
    unmeasured.require_measured(rows, skipped, len(gp_rows))
    # an adaptive sweep's screening (#70): the points not trained, in the IoU GP as box model + offset and in the
    # ratio GP as measured
    screened, screening = screened_rows(params, box_model_scores(params, options.results, options.screen_pattern),
                                        gp_rows)
    iou_rows = gp_rows + screened
    if options.compression_pattern:  # the compression ratio needs no training: a screened point measures it fully
        for r in screened:
            r.update(compression_columns(Path(options.compression_pattern.format(results=options.results,
                                                                                 point=r["point"]))))
    X = np.array([[r[n] for n in names] for r in iou_rows])  # the IoU GP's and the ratio GP's points
    iou_gp = ResponseGP(names, X, [r["iou"] for r in iou_rows], [r["iou_sd"] ** 2 for r in iou_rows], seed=options.seed)
    iou_loo = iou_gp.leave_one_out()
    tols = {n: tolerance_interval(iou_gp, n, required, at, extrapolate=options.extrapolate) for n in names}
    joint = joint_region(iou_gp, required, tols, seed=options.seed)
    choices = {c: categorical_choice({r[c]: (r["iou"], r["iou_sd"]) for r in rows if _on_line(r, c, nominal, all_names)},
                                     nominal[c], required) for c in categorical
               if any(_on_line(r, c, nominal, all_names) for r in rows)}  # none: every value unmeasured (#71)
    has_ratio = bool(options.compression_pattern)
    ratio_gp = ratio_loo = None
    if has_ratio:
        ratio_gp = ResponseGP(names, X, [r["ratio"] for r in iou_rows], [r["ratio_sd"] ** 2 for r in iou_rows],
                              seed=options.seed)
        ratio_loo = ratio_gp.leave_one_out()
    grids = _grid_summaries(params, rows + screened, skipped, nominal, all_names, required, options.seed)
    nominal_row = next(r for r in rows + skipped if r["point"] == NOMINAL)
    prop_model = _property_model(options, rows + screened) if options.stores_pattern else None
    if prop_model is not None and "properties" not in nominal_row:  # an unmeasured nominal: its images' properties
        nominal_row["properties"] = _store_properties(options, nominal_row)
    unmeasured_list = [unmeasured.entry(r, all_names) for r in skipped]
    network = study_network(rows + skipped)
    adaptive = _adaptive_summary(params, iou_gp, tols, at, required, screening)  # None unless target.adaptive is on
    spec = build_spec(tols, nominal, required, nominal_row.get("_signal"), choices=choices,
                      context={"params_file": str(options.params), "loo_share_inside_2sigma": iou_loo["share_inside"],
                               **({"model": network} if network else {}), **resolution.spec_context(res),
                               **({"unmeasured_points": unmeasured_list} if skipped else {}),
                               **({"adaptive": adaptive} if adaptive else {})},
                      property_model=prop_model, model_at=nominal_row.get("properties"))

    for r, rec in zip(gp_rows, iou_loo["points"]):
        r["iou_loo_pred"], r["iou_loo_sd"], r["iou_loo_inside"] = rec["predicted"], rec["sd"], rec["inside"]
    examples = []
    if options.stores_pattern:
        from metraw.io.store import RawStore

        for r in rows:
            spath = Path(options.stores_pattern.format(point=r["point"], results=options.results))
            if not spath.exists():
                raise MetrawError(f"store {spath} of point {r['point']} is missing (needed for Fig. 6)")
            store = RawStore.open(spath)
            if not 0 <= options.example_index < len(store):
                raise MetrawError(f"--example-index {options.example_index} out of range for {spath} "
                                  f"({len(store)} images)")
            examples.append((r["point"], store[options.example_index]))

    # ---- everything computed: write outputs (each atomically)
    out = Path(options.out)
    figdir, plotdir = out / "figures", out / "plots"
    summary = {
        "required_iou": required, "band_sigma": BAND_SIGMA, "model": network, "parameters": all_names,
        "gp_parameters": names,
        "nominal": {**at, **{c: nominal[c] for c in categorical}},
        "points": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows],
        "iou_gp": {"kernel": iou_gp.kernel_description(), "white_sd": math.sqrt(iou_gp.white_variance),
                   "leave_one_out": iou_loo},
        "ratio_gp": None if ratio_gp is None else {
            "kernel": ratio_gp.kernel_description(), "white_sd": math.sqrt(ratio_gp.white_variance),
            "leave_one_out": ratio_loo},
        "tolerances": {n: {k: v for k, v in t.__dict__.items()} for n, t in tols.items()},
        "joint_region": joint,
        "categorical": choices,
        "grids": [g for _, g in grids],
        "property_model": None if prop_model is None else {
            "properties": prop_model.names, "kernel": prop_model.gp.kernel_description(),
            "white_sd": math.sqrt(prop_model.gp.white_variance), "leave_one_out": prop_model.gp.leave_one_out()},
    }
    summary["resolution"] = res  # the test split and the smallest IoU difference it resolves (spec/resolution.py)
    if real is not None:
        summary["sim_to_real"] = real
    if skipped:
        summary["unmeasured_points"] = unmeasured_list
    if adaptive:
        summary["adaptive"] = adaptive
    if screening:
        summary["screening"] = screening
    spec.save(out / "spec.yaml")
    _write_text(out / "aggregate.json", json.dumps(summary, indent=2, default=float) + "\n")
    pcols = ["point", *all_names, "iou", "iou_sd", "iou_loo_pred", "iou_loo_sd", "iou_loo_inside", "precision", "recall",
             "object_f1", "n_replicates", "iou_replicate_sd"]
    if real is not None:
        pcols += ["real_iou", "real_iou_sd", "real_precision", "real_recall", "real_box_iou", "sim_to_real_gap",
                  "sim_to_real_gap_sd"]
    if has_ratio:
        # per-channel columns of every point (a mono point has L, a Bayer point R, G, B): the union, not the first row's
        pcols += ["ratio", "ratio_sd", "bits_per_pixel"] + sorted({k for r in rows for k in r if k.startswith("ratio_")
                                                                   and k != "ratio_sd"})
    _write_text(plotdir / "points.csv", _csv(rows, pcols))
    for n in names:
        on_line = [r for r in rows if _on_line(r, n, nominal, all_names)]
        t = figures.line_table(iou_gp, n, at)
        _write_text(plotdir / f"iou_{n}.csv", _csv([dict(zip(t, v)) for v in zip(*t.values())], list(t)))
        figures.response_line(iou_gp, n, at, figdir / IOU_FIGS.get(n, f"iou_{n}.png"),
                              ylabel="IoU (test split)" if real is None else "IoU (synthetic test split; real: all)",
                              points=[(r[n], r["iou"], r["iou_sd"]) for r in on_line], required=required,
                              tolerance=tols[n], title=f"IoU vs {n} (others nominal)",
                              real_points=[(r[n], r["real_iou"], r["real_iou_sd"]) for r in on_line if "real_iou" in r],
                              real_label=REAL_LABEL,
                              replicate_points=[(r[n], y) for r in on_line for y in r.get("replicate_ious", [])],
                              unmeasured=[r[n] for r in skipped if _on_line(r, n, nominal, all_names)])
        if ratio_gp is not None:
            t = figures.line_table(ratio_gp, n, at)
            _write_text(plotdir / f"ratio_{n}.csv", _csv([dict(zip(t, v)) for v in zip(*t.values())], list(t)))
            figures.response_line(ratio_gp, n, at, figdir / RATIO_FIGS.get(n, f"ratio_{n}.png"),
                                  ylabel="compression ratio vs 16 bit",
                                  points=[(r[n], r["ratio"], r["ratio_sd"]) for r in on_line],
                                  title=f"compression ratio vs {n} (others nominal)")
            figures.channel_lines(n, _channel_series(on_line, n), figdir / f"fig8_ratio_channels_{n}.png",
                                  ylabel="compression ratio vs 16 bit", log_x=iou_gp.axes[names.index(n)].kind == "log",
                                  title=f"compression ratio per channel vs {n} (others nominal)")
    for c, choice in choices.items():
        figures.categorical_bars(c, {v: (r["iou"], r["iou_sd"]) for v, r in choice["values"].items()},
                                 figdir / f"iou_{c}.png", ylabel="IoU (test split)", required=required,
                                 title=f"IoU per {c} (others nominal)",
                                 unmeasured=[r[c] for r in skipped if _on_line(r, c, nominal, all_names)])
        if has_ratio:
            on_line = [r for r in rows if _on_line(r, c, nominal, all_names)]
            figures.categorical_bars(c, {r[c]: (r["ratio"], r["ratio_sd"]) for r in on_line},
                                     figdir / f"ratio_{c}.png", ylabel="compression ratio vs 16 bit",
                                     title=f"compression ratio per {c} (others nominal)")
            figures.categorical_channel_bars(c, {r[c]: _channel_ratios(r) for r in on_line},
                                             figdir / f"fig8_ratio_channels_{c}.png",
                                             ylabel="compression ratio vs 16 bit",
                                             title=f"compression ratio per channel per {c} (others nominal)")
    for model, g in grids:
        a, b = g["axes"]
        figures.grid_map(model, g, figdir / f"fig7b_iou_grid_{a}_{b}.png", required=required,
                         title=f"IoU over {a} x {b} (measured grid; fixed: {g['fixed'] or 'others nominal'})",
                         unmeasured=[(r[a], r[b]) for r in skipped if r["point"] in g.get("unmeasured_points", [])])
    if "focal_length_m" in names and "diameter_m" in names and not grids:
        figures.response_map(iou_gp, "focal_length_m", "diameter_m", at, figdir / "fig7b_iou_map.png",
                             label="IoU (GP mean)", required=required,
                             points=[(r["focal_length_m"], r["diameter_m"]) for r in rows],
                             title="IoU over focal length x diameter (exposure nominal)",
                             unmeasured=[(r["focal_length_m"], r["diameter_m"]) for r in skipped])
    if examples:
        figures.example_images(examples, figdir / "fig6_examples.png")
    if adaptive:
        from metraw.spec.adaptive import round_figures
        from metraw.study.points import point_rounds

        round_figures(iou_gp, iou_rows, point_rounds(params), at, required, figdir, [g["axes"] for _, g in grids])
    print(f"aggregate: {len(rows)} points; IoU LOO share inside 2 sigma {iou_loo['share_inside']:.2f} "
          f"(+- {iou_loo['share_inside_se']:.2f}, expected {iou_loo['expected_share']:.3f})"
          + ("" if ratio_loo is None else f"; ratio LOO {ratio_loo['share_inside']:.2f}")
          + (f"; {len(skipped)} more unmeasured (left out, listed above and in aggregate.json)" if skipped else ""))
    if real is not None and real["nominal"] is not None:
        nom = real["nominal"]
        print(f"  sim-to-real at nominal: synthetic IoU {nom['synthetic_iou']:.3f}, real IoU {nom['real_iou']:.3f}, "
              f"gap {nom['gap']:+.3f} (sd {nom['gap_sd']:.3f}): {'within' if nom['within_tolerance'] else 'outside'} "
              f"{real['tolerance']:g}; {real['points_within_tolerance']}/{real['n_points']} points within")
    for n, t in tols.items():
        if t.meets_requirement:
            print(f"  {n}: optimal {t.optimal:.4g}, min {t.min:.4g} ({t.min_limited_by}), "
                  f"max {t.max:.4g} ({t.max_limited_by})")
        else:
            print(f"  {n}: lower 2-sigma bound {t.lower_at_optimal:.3f} < required {required} even at the optimum")
    print(f"  joint region: share of the tolerance box meeting the requirement = {joint.get('share_of_box_ok')}")
    if prop_model is not None:
        loo = summary["property_model"]["leave_one_out"]
        print(f"  property model: IoU over {', '.join(prop_model.names)} from {len(prop_model.points)} points; "
              f"LOO share inside 2 sigma {loo['share_inside']:.2f}")
    for c, choice in choices.items():
        print(f"  {c}: allowed {choice['allowed'] or 'none'}; " + ", ".join(
            f"{v} IoU {r['iou']:.3f} +- {r['iou_sd']:.3f}" for v, r in choice["values"].items()))
    for _, g in grids:
        print(f"  grid {' x '.join(g['axes'])}: {len(g['points'])} measured points, "
              f"{sum(p['meets_requirement'] for p in g['points'])} meet {required:g}; GP region "
              f"{100 * g['share_of_grid_ok']:.0f} % of the grid box")
    info, *warnings = resolution.log_lines(res)
    print(info)
    for line in warnings:  # to the aggregate's log
        print(line, file=sys.stderr)
    print(f"wrote {out / 'spec.yaml'}, {out / 'aggregate.json'}, {figdir}/, {plotdir}/")
    return 0


def _adaptive_summary(params, iou_gp, tols, at, required, screening=None) -> dict[str, Any] | None:
    """The adaptive sweep's block of aggregate.json and spec.yaml's context (`metraw.spec.adaptive.summary`), or None
    for a study of listed points."""
    from metraw.study.points import adaptive_settings

    if not adaptive_settings(params)["enabled"]:
        return None
    from metraw.spec.adaptive import summary

    return summary(params, iou_gp, tols, at, required, screening)


def _property_model(options, rows: list[dict[str, Any]]):
    """Each point's image properties (medians over its store's images, ``row["properties"]``) and the IoU fit
    over them (`metraw.spec.property_model`), from every point: lines, grids and categorical points (and an adaptive
    sweep's screened points, `metraw.spec.screening`)."""
    from metraw.io.store import RawStore
    from metraw.raw.cfa import cfa_family
    from metraw.spec.property_model import PropertyModel, store_properties

    for r in rows:
        spath = Path(options.stores_pattern.format(point=r["point"], results=options.results))
        if not spath.exists():
            raise MetrawError(f"store {spath} of point {r['point']} is missing (needed for its image properties)")
        store = RawStore.open(spath)
        r["properties"] = store_properties(store)
        r["sensor"] = cfa_family(store[0].cfa_pattern)  # mono or bayer: points of two sensors are not comparable
    points = [{"point": r["point"], "iou": r["iou"], "iou_sd": r["iou_sd"], "sensor": r["sensor"], **r["properties"]}
              for r in rows]
    return PropertyModel.from_points(points, seed=options.seed)


def _store_properties(options, row: dict[str, Any]) -> dict[str, float]:
    """The image properties of one point's store (``_property_model`` reads every fitted point's alike)."""
    from metraw.io.store import RawStore
    from metraw.spec.property_model import store_properties

    spath = Path(options.stores_pattern.format(point=row["point"], results=options.results))
    if not spath.exists():
        raise MetrawError(f"store {spath} of point {row['point']} is missing (needed for its image properties)")
    return store_properties(RawStore.open(spath))


def _grid_summaries(params: dict[str, Any], rows: list[dict[str, Any]], skipped: list[dict[str, Any]],
                    nominal: dict[str, Any], names: list[str], required: float, seed: int) -> list:
    """``_grid_summary`` of every ``target.grids`` entry over the measured ``rows``. With unmeasured points
    (``skipped``, issue #71) a grid lists its own under ``unmeasured_points``, and a grid left with fewer than the 3
    measured points a 2-D GP needs is skipped with a printed line instead of failing the aggregate."""
    from metraw.study.points import adaptive_settings, grid_axes

    out = []
    for grid in params["target"].get("grids") or []:
        box = adaptive_settings(params)["enabled"]
        lost = [r["point"] for r in _grid_members(grid, skipped, nominal, names, box)]
        if lost and len(_grid_members(grid, rows, nominal, names, box)) < 3:
            print(f"  grid {' x '.join(grid_axes(grid)[0])}: skipped, "
                  f"{len(lost)} of its points unmeasured ({', '.join(lost)}) and fewer than 3 measured")
            continue
        model, summary = _grid_summary(params, grid, rows, nominal, names, required, seed)
        if lost:
            summary["unmeasured_points"] = lost
        out.append((model, summary))
    return out


def _on_line(row: dict[str, Any], name: str, nominal: dict[str, Any], names: list[str]) -> bool:
    """Whether ``row`` lies on the one-at-a-time line of ``name``: every other swept parameter nominal."""
    from metraw.study.points import same_value

    return all(same_value(row[m], nominal[m]) for m in names if m != name)


def _channel_ratios(row: dict[str, Any]) -> dict[str, tuple[float, float]]:
    """Per colour channel of one point: (compression ratio, its sd over images)."""
    return {key[len("ratio_"):]: (row[key], row[f"{key}_sd"]) for key in row
            if key.startswith("ratio_") and not key.endswith("_sd") and f"{key}_sd" in row}


def _channel_series(rows: list[dict[str, Any]], name: str) -> dict[str, list[tuple[float, float, float]]]:
    """Per colour channel: (parameter value, compression ratio, its sd over images) of ``rows``."""
    out: dict[str, list[tuple[float, float, float]]] = {}
    for r in rows:
        for c, (ratio, sd) in _channel_ratios(r).items():
            out.setdefault(c, []).append((r[name], ratio, sd))
    return out


def _grid_members(grid: dict[str, Any], rows: list[dict[str, Any]], nominal: dict[str, Any], names: list[str],
                  box: bool = False) -> list[dict[str, Any]]:
    """The rows on one ``target.grids`` entry (its two axes' values, the others at its fixed or the nominal values);
    ``box``: anywhere in the grid's box on its two axes (an adaptive sweep's cells, #70)."""
    from metraw.study.points import grid_axes, same_value

    axes, fixed = grid_axes(grid)
    if len(axes) != 2:
        raise MetrawError(f"target.grids entry {grid} must have exactly two list-valued axes for its IoU map")
    want = {m: fixed.get(m, nominal[m]) for m in names if m not in axes}

    def on_grid(r, a):  # a listed value of the axis; with box, anywhere between its ends
        if box:
            return min(grid[a]) <= r[a] <= max(grid[a])
        return any(same_value(r[a], v) for v in grid[a])

    return [r for r in rows if all(same_value(r[m], v) for m, v in want.items())
            and on_grid(r, axes[0]) and on_grid(r, axes[1])]


def _grid_summary(params: dict[str, Any], grid: dict[str, Any], rows: list[dict[str, Any]], nominal: dict[str, Any],
                  names: list[str], required: float, seed: int):
    """(2-D GP, summary) of one ``target.grids`` entry from its measured points (`metraw.spec.tolerance.grid_region`)."""
    from metraw.spec.tolerance import grid_region
    from metraw.study.points import adaptive_settings, grid_axes

    axes, fixed = grid_axes(grid)
    members = _grid_members(grid, rows, nominal, names, adaptive_settings(params)["enabled"])
    if len(members) < 3:
        raise MetrawError(f"grid {' x '.join(axes)} has {len(members)} measured points; a 2-D GP needs >= 3")
    X = np.array([[r[axes[0]], r[axes[1]]] for r in members])
    model, summary = grid_region(axes, X, np.array([r["iou"] for r in members]),
                                 np.array([r["iou_sd"] ** 2 for r in members]), required, seed=seed)
    summary["fixed"] = fixed
    for p, r in zip(summary["points"], members):
        p["point"] = r["point"]
        if r.get("screened"):  # the box model's IoU plus the offset (metraw.spec.screening)
            p["screened"] = True
    return model, summary
