"""The adaptive sweep (issue #70) without training: its points (metraw.study.points), the straddle rule and its stop
(metraw.spec.adaptive) on a noisy synthetic IoU curve with a known crossing, and the round record."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from metraw.errors import MetrawError
from metraw.spec import adaptive
from metraw.spec.tolerance import ResponseGP, tolerance_interval
from metraw.study.points import (adaptive_points, initial_design, listed_points, parameter_points, point_rounds,
                                 validate_params)

REPO = Path(__file__).resolve().parents[1]
REQUIRED = 0.15
#: The synthetic response: IoU(f) = 0.05 + 0.25 / (1 + exp((f - 1.5 m) / 0.12 m)), crossing 0.15 at
#: f = 1.5 + 0.12 ln 1.5 m; each measurement adds normal noise of NOISE_SD (its stated sd).
CROSSING_M = 1.5 + 0.12 * math.log(1.5)
NOISE_SD = 0.004


def iou_curve(f: float) -> float:
    return 0.05 + 0.25 / (1.0 + math.exp((f - 1.5) / 0.12))


def repo_params() -> dict:
    return yaml.safe_load((REPO / "params.yaml").read_text())


def line_params(stop_width: float = 0.05, budget: int = 30, per_round: int = 1) -> dict:
    """The repository's params with one numeric line, focal length over [0.8, 2.0] m (nominal 1.644 m)."""
    params = repo_params()
    params["target"]["sweeps"] = {"focal_length_m": [0.8, 2.0]}
    params["target"].pop("grids")
    params["target"]["adaptive"] = {"enabled": True, "budget": budget, "points_per_round": per_round,
                                    "stop_width": stop_width, "line_candidates": 81}
    params["spec"]["required_iou"] = REQUIRED
    return params


def measure(params: dict, seed: int) -> list[dict]:
    """A row per point of ``params``, as the aggregate reads them: the curve plus seeded noise (each point's own
    draw, the same whenever it is measured again)."""
    rows = []
    for name, overrides in parameter_points(params).items():
        f = float(overrides.get("focal_length_m", params["target"]["nominal"]["focal_length_m"]))
        noise = np.random.default_rng([seed, int(round(f * 1e6))]).normal(0.0, NOISE_SD)
        rows.append({"point": name, "focal_length_m": f, "iou": iou_curve(f) + noise, "iou_sd": NOISE_SD})
    return rows


def run_sweep(params: dict, seed: int) -> tuple[dict, list[dict]]:
    """The driver's loop without training: plan a round, add its choices, until the record says stop."""
    params = copy.deepcopy(params)
    records = []
    for r in range(100):
        record = adaptive.plan_round(params, measure(params, seed), r)
        records.append(record)
        if record["stop"]["stopped"]:
            return params, records
        params["target"]["adaptive"].setdefault("chosen", []).append([c["overrides"] for c in record["chosen"]])
    raise AssertionError("no stop in 100 rounds")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_straddle_finds_a_known_crossing_to_the_stop_width_with_fewer_points_than_a_grid(seed):
    """Stop width 0.05 of the range: a uniform grid of that resolution trains 21 points; the rule stops when the
    stretch of doubt is that narrow, with far fewer, and the true crossing lies in it."""
    width = 0.05
    params, records = run_sweep(line_params(width), seed)
    last = records[-1]
    n_grid = round(1 / width) + 1
    n_adaptive = last["n_trained"]
    assert last["stop"]["reason"].startswith("every stretch of doubt")
    assert 3 < n_adaptive <= 12 < n_grid  # 3: the initial design (0.8, nominal 1.644, 2.0 m)
    line = last["lines"]["focal_length_m"]
    (found,) = line["mean_crossings"]
    span = 2.0 - 0.8
    assert abs(found - CROSSING_M) <= width * span
    (doubt,) = line["stretches"]
    assert doubt["width"] <= width
    assert doubt["low"] - 0.01 * span <= CROSSING_M <= doubt["high"] + 0.01 * span
    # the chosen points gather around the crossing: every point after the initial design within 0.3 m of it
    chosen = [float(o["focal_length_m"]) for rnd in params["target"]["adaptive"]["chosen"] for o in rnd]
    assert chosen and all(abs(f - CROSSING_M) < 0.3 for f in chosen)


def test_uniform_grid_of_the_same_count_does_not_reach_the_stop_width():
    """The comparison's other side: a uniform grid with as many points as the rule used leaves a wider stretch of
    doubt (its spacing is coarser than the rule's points near the crossing)."""
    width = 0.05
    params, records = run_sweep(line_params(width), 0)
    n = records[-1]["n_trained"]
    values = np.linspace(0.8, 2.0, n)
    rng = np.random.default_rng(0)
    y = np.array([iou_curve(f) for f in values]) + rng.normal(0, NOISE_SD, n)
    model = ResponseGP(["focal_length_m"], values[:, None], y, np.full(n, NOISE_SD ** 2))
    grid_doubt = adaptive.line_doubt(model, "focal_length_m", {"focal_length_m": 1.644}, REQUIRED)
    assert grid_doubt["widest"] > records[-1]["lines"]["focal_length_m"]["widest"]


def test_a_round_is_reproducible_and_its_record_says_why():
    params = line_params(0.05, per_round=2)
    rows = measure(params, 0)
    a = adaptive.plan_round(params, rows, 0)
    b = adaptive.plan_round(params, rows, 0)
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert len(a["chosen"]) == 2 and not a["stop"]["stopped"]
    # the first pick is the candidate of largest straddle; the second's sd is conditioned on the first's
    best = max((c for c in a["candidates"] if c["eligible"]), key=lambda c: c["straddle"])
    assert a["chosen"][0]["name"] == best["name"]
    second = next(c for c in a["candidates"] if c["name"] == a["chosen"][1]["name"])
    assert a["chosen"][1]["latent_sd"] < second["latent_sd"]
    assert "largest straddle" in a["chosen"][0]["why"]
    assert {"kernel", "white_sd", "X", "iou", "iou_sd", "axes"} <= set(a["gp"])
    assert len(a["candidates"]) == 81 - 2  # the line's values less its trained ends (the nominal 1.644 is not one)
    for c in a["candidates"]:
        assert math.isclose(c["straddle"], 1.96 * c["latent_sd"] - abs(c["mean"] - REQUIRED), abs_tol=1e-12)


def test_budget_stops_the_sweep():
    params, records = run_sweep(line_params(0.01, budget=6, per_round=2), 0)
    assert [len(r["chosen"]) for r in records] == [2, 1, 0]
    assert records[-1]["n_trained"] == 6
    assert records[-1]["stop"]["reason"] == "budget of 6 trained points spent"


def test_latent_sd_is_the_predictive_sd_without_the_white_noise():
    rng = np.random.default_rng(0)
    X = rng.uniform([0.8, 0.1], [2.0, 0.5], (9, 2))
    y = 0.2 + 0.1 * np.sin(3 * X[:, 0]) + 0.2 * X[:, 1] + rng.normal(0, 0.01, 9)
    model = ResponseGP(["focal_length_m", "diameter_m"], X, y, np.full(9, 1e-4))
    C = rng.uniform([0.8, 0.1], [2.0, 0.5], (6, 2))
    assert np.allclose(model.latent_sd(C), np.sqrt(model.predict(C).sd ** 2 - model.white_variance), rtol=1e-6)
    # conditioning on a point lowers the sd there and changes nothing far away in the working space
    after = model.latent_sd(C, C[:1])
    assert after[0] < model.latent_sd(C)[0] and np.all(after <= model.latent_sd(C) + 1e-12)


def test_default_study_is_unchanged_and_its_adaptive_design():
    params = repo_params()
    assert params["target"]["adaptive"]["enabled"] is False
    validate_params(params)
    assert parameter_points(params) == listed_points(params)
    assert len(parameter_points(params)) == 20
    on = copy.deepcopy(params)
    on["target"]["adaptive"]["enabled"] = True
    design = initial_design(on)
    # nominal, both range ends of the 5 two-sided numeric lines, one end of atmospheric transmission (0.5; nominal
    # 0.8 is the other), the mono point, the 4 grid corners: each also a point of the listed study (shared cache)
    assert len(design) == 17 and set(design) <= set(listed_points(params))
    assert design["focal_length_m-0.8+diameter_m-0.5"] == {"focal_length_m": 0.8, "diameter_m": 0.5}
    on["target"]["adaptive"]["chosen"] = [[{"focal_length_m": 1.3}], [{"focal_length_m": 1.1, "diameter_m": 0.2}]]
    points = adaptive_points(on)
    assert list(points)[-2:] == ["focal_length_m-1.3", "focal_length_m-1.1"]  # diameter 0.2 m is the nominal
    assert point_rounds(on)["focal_length_m-1.1"] == 2 and point_rounds(on)["nominal"] == 0


def test_grid_cells_are_candidates_once():
    params = repo_params()
    params["target"]["adaptive"].update(enabled=True, grid_candidates=5, line_candidates=5)
    cands = adaptive.candidates(params, parameter_points(params))
    cells = [c for c in cands if c["kind"] == "grid"]
    keys = [frozenset(c["overrides"].items()) for c in cands]
    assert len(keys) == len(set(keys))
    # 25 cells less the 4 corners (trained) and the cells on the focal-length or diameter line (the nominal's
    # values are not on the 5-value mesh: none lies on a line)
    assert len(cells) == 25 - 4
    assert all(c["name"].startswith("focal_length_m-") and "+diameter_m-" in c["name"] for c in cells)


@pytest.mark.parametrize("change, message", [
    ({"budget": 10}, "less than the initial design's 17 points"),
    ({"chosen": [[{"focal_length_m": 3.0}]]}, "outside its range"),
    ({"chosen": [[{"cfa_pattern": 1.0}]]}, "not a numeric swept parameter"),
    ({"budget": 17, "chosen": [[{"focal_length_m": 1.3}]]}, "exceed the budget of 17"),
    ({"stop_width": 0}, "stop_width"),
])
def test_bad_adaptive_settings_are_one_line(change, message):
    params = repo_params()
    params["target"]["adaptive"].update(enabled=True, **change)
    with pytest.raises(MetrawError, match=message):
        validate_params(params)


def test_tolerance_ends_state_their_uncertainty():
    params, records = run_sweep(line_params(0.05), 0)
    model, names, at = adaptive.fit_iou(params, measure(params, 0))
    tol = tolerance_interval(model, "focal_length_m", REQUIRED, at)
    s = adaptive.summary(params, model, {"focal_length_m": tol}, at, REQUIRED)
    assert s["adaptive"] and s["all_lines_resolved"] and s["n_points"] == records[-1]["n_trained"]
    end = s["tolerance_ends"]["focal_length_m"]["max"]
    assert end["limited_by"] == "requirement"
    # the spec's end (lower band = required) is the edge of the stretch where the 2-sigma band holds the level (its
    # low edge: the IoU falls with f, the upper band crosses further out), and the mean's crossing lies inside it
    assert math.isclose(end["band"]["low"], end["value"], rel_tol=2e-3)
    assert end["band"]["low"] < records[-1]["lines"]["focal_length_m"]["mean_crossings"][0] < end["band"]["high"]
    assert end["doubt"]["width"] <= 0.05
    assert s["tolerance_ends"]["focal_length_m"]["min"]["limited_by"] == "sampled_range"


@pytest.mark.parametrize("adaptive_settings, word", [
    ({"enabled": False}, "target.adaptive.enabled is false"),
    ({"enabled": True, "budget": 5}, "less than the initial design's 17 points"),
    ({"enabled": True, "points_per_round": 0}, "points_per_round"),
])
def test_the_driver_refuses_bad_settings_in_one_line_and_writes_nothing(tmp_path, adaptive_settings, word):
    import subprocess
    import sys

    (tmp_path / "params.yaml").write_text((REPO / "params.yaml").read_text())
    (tmp_path / "my.yaml").write_text(yaml.safe_dump({"target": {"adaptive": adaptive_settings}}))
    before = sorted(p.name for p in tmp_path.rglob("*"))
    proc = subprocess.run([sys.executable, str(REPO / "workflow" / "scripts" / "adaptive.py"), "--cores", "1",
                           "--configfile", "my.yaml"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("metraw adaptive: error: ") and word in line
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


# ---------------------------------------------------------------------- screening by the box model
#: The synthetic box model: the curve less what fine-tuning adds (BOX_OFFSET), with its own seeded noise.
BOX_OFFSET = 0.012


def write_box_scores(params: dict, results: Path, seed: int) -> None:
    """``screen.json`` of every screen point as `metraw evaluate` writes it (IoU, its replicates and per-image
    counts omitted: the IoU's variance is then 0, so the rows' sd is the offset's alone)."""
    from metraw.spec.screening import DEFAULT_SCREEN
    from metraw.study.points import screen_points

    for name, overrides in screen_points(params).items():
        f = float(overrides.get("focal_length_m", params["target"]["nominal"]["focal_length_m"]))
        noise = np.random.default_rng([seed, 7, int(round(f * 1e6))]).normal(0.0, NOISE_SD)
        path = Path(DEFAULT_SCREEN.format(results=results, point=name))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"iou": iou_curve(f) - BOX_OFFSET + noise}))


def run_screened_sweep(params: dict, seed: int, results: Path) -> tuple[dict, list[dict]]:
    """`run_sweep` with the screening: every round the box model scores the screen points, the GP takes them."""
    from metraw.spec.aggregate import box_model_scores
    from metraw.spec.screening import screened_rows

    params = copy.deepcopy(params)
    records = []
    for r in range(100):
        rows = measure(params, seed)
        write_box_scores(params, results, seed)
        screened, record = screened_rows(params, box_model_scores(params, str(results)), rows)
        records.append(adaptive.plan_round(params, rows, r, screened=screened, screening=record))
        if records[-1]["stop"]["stopped"]:
            return params, records
        params["target"]["adaptive"].setdefault("chosen", []).append([c["overrides"] for c in records[-1]["chosen"]])
    raise AssertionError("no stop in 100 rounds")


def test_screening_trains_the_nominal_and_the_categories_and_scores_the_ends():
    from metraw.study.points import screen_points, target_params

    params = repo_params()
    params["target"]["adaptive"].update(enabled=True, screen=True, budget=10)
    validate_params(params)  # a budget of 10 holds the screened design
    assert list(initial_design(params)) == ["nominal", "cfa_pattern-mono"]
    screen = screen_points(params)
    # the nominal, the 11 range ends and the 4 grid corners: the unscreened design less the mono point
    unscreened = copy.deepcopy(params)
    unscreened["target"]["adaptive"]["screen"] = False
    assert set(screen) == set(initial_design(unscreened)) - {"cfa_pattern-mono"} and len(screen) == 16
    assert target_params(params, "diameter_m-0.5")["diameter_m"] == 0.5  # an untrained point resolves
    params["target"]["adaptive"]["chosen"] = [[{"focal_length_m": 1.3}]]
    assert "focal_length_m-1.3" in screen_points(params)  # a trained point is scored both ways (a pair)
    off = copy.deepcopy(params)
    off["target"]["adaptive"]["enabled"] = False
    assert screen_points(off) == {} and parameter_points(off) == listed_points(off)


def test_the_offset_and_its_spread():
    from metraw.spec.screening import offset

    pairs = [{"fine_tuned": a, "box": b} for a, b in [(0.21, 0.20), (0.30, 0.27), (0.10, 0.10)]]
    got = offset(pairs, 0.02)
    d = np.array([0.01, 0.03, 0.0])
    assert math.isclose(got["offset"], d.mean()) and math.isclose(got["offset_sd"], d.std(ddof=1))
    assert got["offset_sd_from"] == "pairs" and math.isclose(got["added_sd"], d.std(ddof=1) * math.sqrt(4 / 3))
    two = offset(pairs[:2], 0.02)  # fewer than 3 pairs: the stated prior sd
    assert two["offset_sd"] == 0.02 and two["offset_sd_from"] == "target.adaptive.screen_offset_sd"
    with pytest.raises(MetrawError, match="no trained point"):
        offset([], 0.02)


def test_screened_rows_are_the_untrained_points_shifted_by_the_offset(tmp_path):
    from metraw.spec.aggregate import box_model_scores
    from metraw.spec.screening import screened_rows

    params = line_params(0.05)
    params["target"]["adaptive"]["screen"] = True
    rows = measure(params, 0)
    assert [r["point"] for r in rows] == ["nominal"]
    write_box_scores(params, tmp_path, 0)
    screened, record = screened_rows(params, box_model_scores(params, str(tmp_path)), rows)
    assert [r["point"] for r in screened] == ["focal_length_m-0.8", "focal_length_m-2.0"]
    assert record["n_pairs"] == 1 and record["offset_sd"] == 0.02
    box_nominal = json.loads((tmp_path / "points" / "nominal" / "screen.json").read_text())["iou"]
    assert math.isclose(record["offset"], rows[0]["iou"] - box_nominal)
    for r in screened:
        assert r["screened"] and math.isclose(r["iou"], r["box_iou"] + record["offset"])
        assert math.isclose(r["iou_sd"], 0.02 * math.sqrt(2))  # the box IoU's variance is 0 here
    (tmp_path / "points" / "focal_length_m-2.0" / "screen.json").unlink()
    with pytest.raises(MetrawError, match="box-model score.*focal_length_m-2.0/screen.json"):
        box_model_scores(params, str(tmp_path))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_screening_finds_the_crossing_with_fewer_trained_points(seed, tmp_path):
    """The box model (the curve less a constant, its own noise) at the ends in place of their training: the rule
    reaches the stop width with fewer trained points than without the screening, the offset is recovered within
    its sampling error, and the crossing is found as well."""
    width = 0.05
    _, plain = run_sweep(line_params(width), seed)
    params = line_params(width)
    params["target"]["adaptive"]["screen"] = True
    params, records = run_screened_sweep(params, seed, tmp_path)
    last = records[-1]
    assert last["stop"]["reason"].startswith("every stretch of doubt")
    assert last["n_trained"] < plain[-1]["n_trained"]
    (found,) = last["lines"]["focal_length_m"]["mean_crossings"]
    assert abs(found - CROSSING_M) <= width * (2.0 - 0.8)
    s = last["screening"]
    # each difference = BOX_OFFSET + (noise of the trained point - noise of the box score): sd sqrt(2) NOISE_SD
    assert abs(s["offset"] - BOX_OFFSET) <= 3 * math.sqrt(2) * NOISE_SD / math.sqrt(s["n_pairs"])
