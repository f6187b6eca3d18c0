"""Sim-to-real benchmark outside the workflow: when it is on (params.yaml sim_to_real.enabled) and what
`metraw aggregate` reports from hand-made per-point metrics (real columns, gap, notes, summary, figures)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from metraw.errors import MetrawError
from metraw.study.sim_to_real import GAP_TOLERANCE, REASONS, gap_note, resolve_enabled

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- enabled: auto / true / false
@pytest.mark.parametrize("enabled, exists, expected", [
    ("auto", True, True), ("auto", False, False), (True, True, True), (False, True, False), (False, False, False)])
def test_resolve_enabled(tmp_path, enabled, exists, expected):
    if exists:
        (tmp_path / "real").mkdir()
    params = {"sim_to_real": {"enabled": enabled, "path": "real", "gsd_m": 0.135}}
    assert resolve_enabled(params, base=tmp_path) is expected


def test_resolve_enabled_true_without_the_folder_is_an_error(tmp_path):
    with pytest.raises(MetrawError, match=r"sim_to_real/enabled is true but the real image folder 'real' does not"):
        resolve_enabled({"sim_to_real": {"enabled": True, "path": "real", "gsd_m": 0.1}}, "params.yaml", tmp_path)


def test_no_section_is_off(tmp_path):
    assert resolve_enabled({}, base=tmp_path) is False


def test_repository_params_require_the_committed_kit_folder():
    # the real photos are part of the repository: the default run is the same on every machine (no silent "auto")
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    assert params["sim_to_real"]["enabled"] is True
    assert params["sim_to_real"]["path"] == "data/real/kit_ais"
    assert resolve_enabled(params, "params.yaml", REPO) is True
    assert len(list((REPO / "data" / "real" / "kit_ais").glob("*.png"))) == 15


# ----------------------------------------------------------------------------- aggregate's real columns
def _records(rng, n, iou):
    """Per-image (tp, fp, fn) as `metraw evaluate` writes them, pooled IoU about ``iou``."""
    u = rng.uniform(50, 150, n)
    tp = u * np.clip(iou + rng.normal(0, 0.05, n), 0.01, 1)
    fp = (u - tp) * 0.5
    return [{"tp": float(a), "fp": float(b), "fn": float(c - a - b)} for a, b, c in zip(tp, fp, u)]


def _metrics(path: Path, rng, iou: float, n: int, labels: str | None = None) -> dict:
    recs = _records(rng, n, iou)
    tp = sum(r["tp"] for r in recs)
    fp = sum(r["fp"] for r in recs)
    fn = sum(r["fn"] for r in recs)
    m = {"iou": tp / (tp + fp + fn), "precision": tp / (tp + fp), "recall": tp / (tp + fn), "per_image": recs,
         "n_images": n}
    if labels:
        m.update(labels=labels, split="all (foreign store)")
    if labels == "box-approximate":  # metraw evaluate scores the predicted objects' boxes too
        m.update(box_iou=min(1.0, m["iou"] + 0.05), box_precision=m["precision"])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(m))
    return m


@pytest.fixture
def hand_made(tmp_path):
    """params.yaml with 4 points and, per point, synthetic metrics and real metrics (box-approximate labels):
    the real IoU is the synthetic one minus 0.02 at the nominal point, minus 0.2 elsewhere."""
    from metraw.study.points import parameter_points

    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["target"]["sweeps"] = {"focal_length_m": [1.2], "diameter_m": [0.35], "exposure_s": [300.0e-6]}
    params["target"].pop("grids", None)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    rng = np.random.default_rng(0)
    made = {}
    for i, point in enumerate(parameter_points(params)):
        syn = _metrics(tmp_path / "results" / point / "metrics.json", rng, 0.6 - 0.05 * i, 6)
        drop = 0.02 if point == "nominal" else 0.2
        real = _metrics(tmp_path / "results" / point / "real_metrics.json", rng, syn["iou"] - drop, 5, "box-approximate")
        made[point] = (syn, real)
    src_syn = _metrics(tmp_path / "results" / "source" / "metrics.json", rng, 0.8, 4)
    src_real = _metrics(tmp_path / "results" / "source" / "real_metrics.json", rng, 0.5, 5, "box-approximate")
    return tmp_path, made, (src_syn, src_real)


def _aggregate(root: Path, *extra: str) -> int:
    from metraw.cli import main

    return main(["aggregate", "--params", str(root / "params.yaml"), "--results", str(root / "results"),
                 "--out", str(root / "out"), "--compression-pattern", "", *extra])


def test_aggregate_reports_real_columns_and_the_gap(hand_made, capsys):
    from metraw.spec.aggregate import iou_measurement

    root, made, (src_syn, src_real) = hand_made
    assert _aggregate(root, "--real-metrics-pattern", "{results}/{point}/real_metrics.json",
                      "--source-real-metrics", str(root / "results/source/real_metrics.json"),
                      "--source-metrics", str(root / "results/source/metrics.json")) == 0
    table = json.loads((root / "out" / "aggregate.json").read_text())
    for row in table["points"]:
        syn, real = made[row["point"]]
        assert row["iou"] == pytest.approx(syn["iou"])
        assert row["real_iou"] == pytest.approx(real["iou"])
        assert row["real_precision"] == pytest.approx(real["precision"])
        assert row["real_recall"] == pytest.approx(real["recall"])
        assert row["real_box_iou"] == pytest.approx(real["box_iou"])
        assert row["real_labels"] == "box-approximate" and row["real_n_images"] == 5
        assert row["sim_to_real_gap"] == pytest.approx(syn["iou"] - real["iou"])
        # the delta-method variances of two independent image sets add
        var = iou_measurement(syn, "s")[1] + iou_measurement(real, "r")[1]
        assert row["real_iou_sd"] == pytest.approx(math.sqrt(iou_measurement(real, "r")[1]))
        assert row["sim_to_real_gap_sd"] == pytest.approx(math.sqrt(var))
        within = abs(row["sim_to_real_gap"]) <= GAP_TOLERANCE
        assert row["sim_to_real_within_tolerance"] is within
        # a large gap comes with its reasons: box labels, approximate raws, scene realism
        assert ("box-approximate" in row["sim_to_real_note"]) is (not within)
        assert ("approximate: reconstructed from processed" in row["sim_to_real_note"]) is (not within)
    s = table["sim_to_real"]
    nominal = next(r for r in table["points"] if r["point"] == "nominal")
    assert s["nominal"]["gap"] == pytest.approx(nominal["sim_to_real_gap"])
    assert s["nominal"]["within_tolerance"] is (abs(nominal["sim_to_real_gap"]) <= 0.05)
    assert s["tolerance"] == GAP_TOLERANCE and s["labels"] == "box-approximate" and s["n_points"] == 4
    assert set(s["reasons"]) == set(REASONS)
    assert "synthetic test IoU only" in s["basis"]
    assert s["source"]["real_iou"] == pytest.approx(src_real["iou"])
    assert s["source"]["gap"] == pytest.approx(src_syn["iou"] - src_real["iou"])
    # the GP is fitted to the synthetic IoU only: the same spec as without the real metrics
    spec = (root / "out" / "spec.yaml").read_text()
    points_csv = (root / "out" / "plots" / "points.csv").read_text().splitlines()
    assert "real_iou" in points_csv[0] and "sim_to_real_gap" in points_csv[0]
    assert "sim-to-real at nominal" in capsys.readouterr().out
    assert _aggregate(root) == 0
    assert (root / "out" / "spec.yaml").read_text() == spec
    plain = json.loads((root / "out" / "aggregate.json").read_text())
    assert "sim_to_real" not in plain and "real_iou" not in plain["points"][0]
    assert plain["iou_gp"] == table["iou_gp"] and plain["tolerances"] == table["tolerances"]


def test_real_iou_of_replicate_models_is_their_mean_as_on_the_synthetic_side(hand_made):
    """With replicates the synthetic IoU is the replicates' mean; the real IoU and the gap must be measured alike
    (not the first replicate's IoU against the others' mean), for the points and for the source, and so must
    precision, recall and object F1."""
    from metraw.spec.aggregate import iou_measurement

    root, made, (src_syn, src_real) = hand_made
    shifted = {}
    for path, shift in [(root / "results/nominal/metrics.json", 0.01), (root / "results/nominal/real_metrics.json", -0.03),
                        (root / "results/source/metrics.json", 0.02), (root / "results/source/real_metrics.json", 0.04)]:
        m = json.loads(path.read_text())
        m.update(iou_replicate_mean=m["iou"] + shift, iou_replicate_se=0.004, n_replicates=3,
                 replicates=[{"seed": k, "iou": m["iou"] + shift, "precision": m["precision"] + d,
                              "recall": m["recall"] - d, "object_f1": 0.5 + d} for k, d in enumerate((0.0, 0.03, 0.09))])
        path.write_text(json.dumps(m))
        shifted[path.parent.name, path.name] = m
    assert _aggregate(root, "--real-metrics-pattern", "{results}/{point}/real_metrics.json",
                      "--source-real-metrics", str(root / "results/source/real_metrics.json"),
                      "--source-metrics", str(root / "results/source/metrics.json")) == 0
    table = json.loads((root / "out" / "aggregate.json").read_text())
    nominal = next(r for r in table["points"] if r["point"] == "nominal")
    syn, real = shifted["nominal", "metrics.json"], shifted["nominal", "real_metrics.json"]
    assert nominal["iou"] == pytest.approx(syn["iou"] + 0.01)
    assert nominal["real_iou"] == pytest.approx(real["iou"] - 0.03)
    assert nominal["real_iou_sd"] == pytest.approx(math.sqrt(iou_measurement(real, "r")[1]))
    assert nominal["real_iou_sd"] ** 2 == pytest.approx(iou_measurement({**real, "iou_replicate_mean": None}, "r")[1]
                                                        + 0.004 ** 2)
    assert nominal["sim_to_real_gap"] == pytest.approx(syn["iou"] - real["iou"] + 0.04)
    # precision, recall and object F1 describe the same models as the IoU: the replicates' means
    assert nominal["precision"] == pytest.approx(syn["precision"] + 0.04)
    assert nominal["recall"] == pytest.approx(syn["recall"] - 0.04)
    assert nominal["object_f1"] == pytest.approx(0.54)
    assert nominal["real_precision"] == pytest.approx(real["precision"] + 0.04)
    assert nominal["real_recall"] == pytest.approx(real["recall"] - 0.04)
    assert nominal["real_box_iou"] == pytest.approx(real["box_iou"])  # box scores: the first model's
    source = table["sim_to_real"]["source"]
    assert source["synthetic_iou"] == pytest.approx(src_syn["iou"] + 0.02)
    assert source["real_iou"] == pytest.approx(src_real["iou"] + 0.04)
    assert source["gap"] == pytest.approx(src_syn["iou"] - src_real["iou"] - 0.02)
    assert table["sim_to_real"]["nominal"]["real_iou"] == pytest.approx(nominal["real_iou"])


def test_iou_figures_draw_the_real_series(hand_made, monkeypatch):
    """The per-parameter IoU figures get a second series (the real points, their 2-sd bars) and a legend."""
    from metraw.spec import figures

    root, _, _ = hand_made
    drawn = {}
    original = figures.response_line

    def spy(model, name, at, path, **kw):
        drawn[Path(path).name] = kw
        return original(model, name, at, path, **kw)

    monkeypatch.setattr(figures, "response_line", spy)
    assert _aggregate(root, "--real-metrics-pattern", "{results}/{point}/real_metrics.json") == 0
    iou_figs = {k: v for k, v in drawn.items() if k.startswith("fig7")}
    assert set(iou_figs) == {"fig7c_iou_focal_length.png", "fig7d_iou_diameter.png", "fig7e_iou_exposure.png"}
    for kw in iou_figs.values():
        assert len(kw["real_points"]) == 2 and all(sd > 0 for _, _, sd in kw["real_points"])  # nominal + sweep value
        assert "real" in kw["real_label"]
    assert all((root / "out" / "figures" / name).stat().st_size > 0 for name in iou_figs)


def test_a_missing_real_metrics_file_is_one_clear_error(hand_made, capsys):
    root, _, _ = hand_made
    (root / "results" / "diameter_m-0.35" / "real_metrics.json").unlink()
    assert _aggregate(root, "--real-metrics-pattern", "{results}/{point}/real_metrics.json") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "diameter_m-0.35/real_metrics.json" in err[0]
    assert not (root / "out").exists()


def test_gap_note_within_and_outside():
    assert gap_note(0.01, 0.02, "box-approximate").endswith("within 0.05")
    note = gap_note(0.3, 0.05, "exact")
    assert "outside 0.05" in note and "YOLO" not in note and "scene realism" in note
    note = gap_note(0.07, 0.01, "box-approximate", precision=(0.30, 0.17), recall=(0.28, 0.23))
    assert "precision 0.300 -> 0.170, recall 0.280 -> 0.230" in note and "YOLO" in note
