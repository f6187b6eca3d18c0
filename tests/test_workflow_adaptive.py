"""The adaptive sweep's driver (workflow/scripts/adaptive.py, issue #70) on the smoke study (workflow/config/smoke.yaml,
its 9 points are the initial design, sim-to-real off): rounds run as Snakemake runs, each round's record, the spec's
adaptive block; the same command again runs zero jobs; a larger budget runs only the new round's point.

Its IoUs are those of a 2-epoch network (they only show that every rule runs): about 0.03-0.04, each with an sd of about
0.03 (2026-12-08), so the GP takes their spread for noise and its mean is flat. The required IoU is therefore set to the
median of the GP mean over the candidates after round 0: the doubt then spans every line and the rule rounds to run.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from workflow_workspace import REPO, file_digests, make_workspace, needs_tools, run

# not in the default run (pyproject.toml: -m 'not adaptive'): ~5 min of the 10 the suite may take on 2 cores;
# `python3 -m pytest -m adaptive tests/test_workflow_adaptive.py`
pytestmark = [pytest.mark.workflow, pytest.mark.adaptive, needs_tools]


def driver(root: Path, budget: int, required: float, screen: bool = False) -> tuple[str, dict]:
    (root / "adaptive.yaml").write_text(yaml.safe_dump({
        "target": {"adaptive": {"enabled": True, "budget": budget, "points_per_round": 1, "stop_width": 0.001,
                                "line_candidates": 11, "grid_candidates": 5, "screen": screen}},
        "spec": {"required_iou": required}}))
    proc = run(["python", str(REPO / "workflow" / "scripts" / "adaptive.py"), "--cores", "2", "--configfile",
                "smoke.yaml", "adaptive.yaml"], root)
    return proc.stderr, {p.name: json.loads(p.read_text()) for p in (root / "results" / "adaptive").glob("round_*.json")}


def test_rounds_cache_and_a_larger_budget(tmp_path):
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["sim_to_real"] = {"enabled": False}
    root = make_workspace(tmp_path / "ws", params)
    shutil.copy2(REPO / "workflow" / "config" / "smoke.yaml", root / "smoke.yaml")
    # round 0 only (budget = the initial design): the IoUs it measured set the required IoU of the sweep
    log, records = driver(root, 9, 0.01)
    assert list(records) == ["round_0.json"] and records["round_0.json"]["stop"]["stopped"]
    means = sorted(c["mean"] for c in records["round_0.json"]["candidates"])
    required = means[len(means) // 2]

    log, records = driver(root, 10, required)
    assert sorted(records) == ["round_0.json", "round_1.json"]
    assert "adaptive round 0: 9 points trained (0 jobs run)" in log  # the initial design was cached
    first = records["round_0.json"]
    assert len(first["chosen"]) == 1 and first["chosen"][0]["straddle"] > 0
    assert first["chosen"][0]["straddle"] == max(c["straddle"] for c in first["candidates"] if c["eligible"])
    new = first["chosen"][0]["name"]
    assert "adaptive round 1: 10 points trained (3 jobs run)" in log  # its emulate, train, evaluate
    assert records["round_1.json"]["stop"]["reason"] == "budget of 10 trained points spent"
    aggregate = json.loads((root / "results" / "aggregate.json").read_text())
    spec = yaml.safe_load((root / "results" / "spec.yaml").read_text())
    assert aggregate["adaptive"]["n_points"] == 10 and len(aggregate["points"]) == 10
    assert spec["context"]["adaptive"]["rounds"][1] == [new]
    assert (root / "results" / "figures" / "adaptive_iou_focal_length_m.png").is_file()
    before = file_digests(root / "results")

    # the same command again: every round replayed, zero jobs, the same bytes
    log, again = driver(root, 10, required)
    assert log.count("(0 jobs run)") == 2 and "the whole workflow ran 0 jobs, 0 in all" in log
    assert again == records and file_digests(root / "results") == before

    # one more point of budget: rounds 0 and 1 replayed with zero jobs, one new round with its point's chain
    log, more = driver(root, 11, required)
    assert sorted(more) == ["round_0.json", "round_1.json", "round_2.json"]
    assert log.count("(0 jobs run)") == 2 and "adaptive round 2: 11 points trained (3 jobs run)" in log
    assert {**more["round_0.json"], "budget": 10} == records["round_0.json"]  # the same round but for its budget
    added = more["round_1.json"]["chosen"][0]["name"]
    assert (root / "results" / "points" / added / "metrics.json").is_file()


def test_screening_scores_the_ends_without_training(tmp_path):
    """target.adaptive.screen: the nominal and mono are trained, the 7 other points of the smoke study are scored by
    the box model alone (emulate + screen, no train); a round's point gets its chain and its box-model score (a
    pair); the aggregate states the screening; the same command again runs zero jobs."""
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["sim_to_real"] = {"enabled": False}
    root = make_workspace(tmp_path / "ws", params)
    shutil.copy2(REPO / "workflow" / "config" / "smoke.yaml", root / "smoke.yaml")
    log, records = driver(root, 2, 0.01, screen=True)
    assert "adaptive round 0: 2 points trained, 7 more scored by the box model alone" in log
    points = root / "results" / "points"
    assert sorted(p.name for p in points.iterdir() if (p / "model").exists()) == ["cfa_pattern-mono", "nominal"]
    assert len(list(points.glob("*/screen.json"))) == 8  # the 7 screened and the nominal (its pair)
    means = sorted(c["mean"] for c in records["round_0.json"]["candidates"])
    required = means[len(means) // 2]

    log, records = driver(root, 3, required, screen=True)
    assert "adaptive round 1: 3 points trained, 7 more scored by the box model alone (4 jobs run)" in log
    new = records["round_0.json"]["chosen"][0]["name"]
    assert (points / new / "metrics.json").is_file() and (points / new / "screen.json").is_file()
    aggregate = json.loads((root / "results" / "aggregate.json").read_text())
    s = aggregate["screening"]
    assert s["n_pairs"] == 2 and {p["point"] for p in s["pairs"]} == {"nominal", new}
    assert len(s["rows"]) == 7 and len(aggregate["points"]) == 3
    for r in s["rows"]:
        assert abs(r["iou"] - (r["box_iou"] + s["offset"])) < 1e-12 and r["iou_sd"] > r["box_iou_sd"]
    spec = yaml.safe_load((root / "results" / "spec.yaml").read_text())
    assert spec["context"]["adaptive"]["screening"]["screened_points"] == [r["point"] for r in s["rows"]]
    before = file_digests(root / "results")
    log, again = driver(root, 3, required, screen=True)
    assert log.count("(0 jobs run)") == 2 and "the whole workflow ran 0 jobs, 0 in all" in log
    assert again == records and file_digests(root / "results") == before
