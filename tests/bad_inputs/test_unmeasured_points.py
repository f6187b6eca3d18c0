"""`metraw aggregate` on a study whose segmenters all collapsed (issue #71): every point's models predict no car
pixel (or every pixel car) on the test split, so nothing was measured; or too few points are left for the IoU GP.
Refused like any bad input: exit 2, one line, nothing written."""

from __future__ import annotations

import json

import pytest

from . import _inputs as make
from ._check import refused


def _metrics(kind: str) -> dict:
    """A metrics record as `metraw evaluate` writes it for one model on 2 test images of 4 x 16 x 16 sites:
    ``kind`` "nothing" (no pixel called car), "everything" (every pixel) or "working"."""
    from metraw.segment.evaluate import point_degeneracy, summarise
    from metraw.segment.degenerate import degeneracy

    recs = []
    for true in (40.0, 60.0):
        tp, fp = {"nothing": (0.0, 0.0), "everything": (true, 1024 - true), "working": (0.6 * true, 10.0)}[kind]
        recs.append({"shape": [4, 16, 16], "tp": tp, "fp": fp, "fn": true - tp, "iou": tp / (fp + true)})
    out = {**summarise(recs), "per_image": recs, "epochs": 1, **degeneracy(recs)}
    return {**out, **point_degeneracy(out)}


def _study(root, kinds: dict[str, str], default: str) -> None:
    from metraw.study.points import parameter_points, load_params

    make.params(root / "params.yaml", ("target.sweeps", {"focal_length_m": [1.2], "diameter_m": [0.35, 0.5],
                                                         "exposure_s": [300.0e-6]}), ("target.grids", []))
    for point in parameter_points(load_params(root / "params.yaml")):
        (root / "results" / point).mkdir(parents=True)
        (root / "results" / point / "metrics.json").write_text(json.dumps(_metrics(kinds.get(point, default))))


@pytest.mark.parametrize("kind", ["nothing", "everything"])
def test_no_point_measured(tmp_path, kind):
    _study(tmp_path, {}, kind)
    line = refused(["aggregate", "--params", "params.yaml", "--results", "results", "--out", "out",
                    "--compression-pattern", ""], "no point was measured", tmp_path, inprocess=True)
    assert "5 of 5 points unmeasured" in line and "nominal" in line


def test_too_few_points_measured_for_the_gp(tmp_path):
    _study(tmp_path, {"nominal": "working", "diameter_m-0.5": "working"}, "nothing")
    refused(["aggregate", "--params", "params.yaml", "--results", "results", "--out", "out",
             "--compression-pattern", ""], "only 2 measured point(s) for the IoU GP", tmp_path, inprocess=True)
