"""The study's whole parameter space (issue 17): categorical CFA sweep, pixel pitch with its detector model,
haze sweeps, cross grids (2-D GP and tolerance region), compression per channel, spec and check of the new lines."""

from __future__ import annotations

import copy
import csv
import importlib.util
import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from metraw.errors import MetrawError
from metraw.spec.builder import Choice, Limit, Specification
from metraw.spec.check import apply_chain, check, stated_haze_e
from metraw.spec.tolerance import categorical_choice, grid_region
from metraw.study.points import (grid_point_name, load_params, parameter_points, swept_parameters, target_params,
                           validate_params)

REPO = Path(__file__).resolve().parents[1]


def base_params() -> dict:
    params = load_params(REPO / "params.yaml")
    params["target"]["sweeps"] = {"focal_length_m": [1.2], "diameter_m": [0.35], "exposure_s": [300.0e-6],
                                  "pixel_pitch_m": [4.8e-6], "cfa_pattern": ["mono"],
                                  "path_radiance_w_m2_sr_m": [6.0e+7], "atmospheric_transmission": [0.5]}
    params["target"]["grids"] = [{"focal_length_m": [1.2, 1.644, 2.0], "diameter_m": [0.2, 0.35]}]
    return params


# --------------------------------------------------------------------------- points
@pytest.mark.parametrize("configfile", sorted((REPO / "workflow" / "config").glob("*.yaml")), ids=lambda p: p.name)
def test_every_workflow_configfile_merged_over_params_is_valid(configfile):
    from snakemake.utils import update_config

    from metraw.study.points import validate_params
    from metraw.study.pretraining import pretrain_settings

    params = yaml.safe_load((REPO / "params.yaml").read_text())
    update_config(params, yaml.safe_load(configfile.read_text()))  # what --configfile does to the config
    validate_params(params, configfile)
    if configfile.name == "gpu.yaml":  # larger pretraining batches; the rest of the pretraining section stays
        settings = pretrain_settings(params)
        assert (settings["batch_size"], settings["epochs"], settings["extra_scenes"]) == (64, 160, 1920)
        assert settings["box"] and settings["finetune_epochs"] == 4 and settings["enabled"]


def test_points_cover_categorical_values_and_grids_without_repeats():
    params = base_params()
    validate_params(params)
    points = parameter_points(params)
    assert points["cfa_pattern-mono"] == {"cfa_pattern": "mono"}
    # grid points already on a line (1.2 x 0.2, 1.644 x 0.35, nominal) are those points, not repeated; a grid
    # point with one parameter off nominal is named as a line point
    grid = list(points)[8:]
    assert grid == ["focal_length_m-1.2+diameter_m-0.35", "focal_length_m-2.0", "focal_length_m-2.0+diameter_m-0.35"]
    assert points["focal_length_m-2.0"] == {"focal_length_m": 2.0}
    assert len(points) == 1 + 7 + 3
    assert grid_point_name({"focal_length_m": 0.8, "diameter_m": 0.1}) == "focal_length_m-0.8+diameter_m-0.1"
    assert swept_parameters(params) == ["focal_length_m", "diameter_m", "exposure_s", "pixel_pitch_m", "cfa_pattern",
                                        "path_radiance_w_m2_sr_m", "atmospheric_transmission"]


def test_cfa_sweep_holding_the_nominal_pattern_skips_it_like_a_numeric_sweep():
    params = base_params()
    params["target"]["sweeps"]["cfa_pattern"] = [params["target"]["nominal"]["cfa_pattern"], "mono"]
    params["target"]["sweeps"]["diameter_m"] = [params["target"]["nominal"]["diameter_m"], 0.35]
    points = parameter_points(params)
    assert "cfa_pattern-mono" in points and "diameter_m-0.35" in points
    assert not any(p.startswith("cfa_pattern-") and p != "cfa_pattern-mono" for p in points)
    assert sum(p.startswith("diameter_m-") for p in points) == 1
    # with a mono nominal one Bayer phase is a design point
    params["target"]["nominal"]["cfa_pattern"] = "mono"
    params["target"]["sweeps"]["cfa_pattern"] = ["mono", "GRBG"]
    assert parameter_points(params)["cfa_pattern-GRBG"] == {"cfa_pattern": "GRBG"}


def test_pixel_pitch_points_scale_the_full_well_with_the_pixel_area():
    params = base_params()
    nominal = params["target"]["nominal"]
    t = target_params(params, "pixel_pitch_m-4.8e-06")
    assert t["full_well_e"] == pytest.approx(nominal["full_well_e"] * 4.0)
    assert t["read_noise_e"] == nominal["read_noise_e"]
    assert target_params(params, "focal_length_m-1.2")["full_well_e"] == nominal["full_well_e"]
    params["target"]["pixel_scaling"] = {"full_well": "fixed"}
    assert target_params(params, "pixel_pitch_m-4.8e-06")["full_well_e"] == nominal["full_well_e"]


@pytest.mark.parametrize("change, message", [
    (lambda p: p["target"]["sweeps"].update(cfa_pattern=["GRBG"]), "Bayer phase"),
    (lambda p: p["target"]["sweeps"].update(cfa_pattern=["RGGB", "GRBG"]), "Bayer phase"),
    (lambda p: (p["target"]["nominal"].update(cfa_pattern="mono"), p["target"]["sweeps"].update(
        cfa_pattern=["RGGB", "BGGR"])), "two Bayer phases"),
    (lambda p: p["target"]["sweeps"].update(cfa_pattern=[3]), "is not of type 'string'"),
    (lambda p: p["target"]["sweeps"].update(focal_length_m=["long"]), "is not of type 'number'"),
    (lambda p: p["target"]["sweeps"].update(cfa_pattern=["Mono"]), "is not one of"),
    (lambda p: p["target"].update(grids=[{"focal_length_m": [1.0, 2.0], "diameter_m": 0.3}]), "two list-valued"),
    (lambda p: p["target"].update(grids=[{"focal_length_m": [1.0, 2.0], "mirror_m": [0.3, 0.4]}]), "mirror_m"),
    (lambda p: p["target"].update(grids=[{"focal_length_m": [0.0, 2.0], "diameter_m": [0.3, 0.4]}]),
     "grids/0/focal_length_m"),
    (lambda p: p["training"]["pretrain"]["box"].update(mirror_m=[0.1, 0.2]), "mirror_m.*numeric field"),
    (lambda p: p["training"]["pretrain"]["box"].update(cfa_pattern=[1, 2]), "cfa_pattern.*numeric field"),
    (lambda p: p["training"]["pretrain"]["box"].update(diameter_m=[0.5, 0.1]), "low < high"),
    (lambda p: p["training"]["pretrain"]["box"].update(diameter_m=[0.1]), "pretrain/box/diameter_m"),
    (lambda p: p["training"]["pretrain"]["box"].update(atmospheric_transmission=[0.5, 1.5]),
     "training/pretrain/box/atmospheric_transmission.*target/nominal/atmospheric_transmission"),
])
def test_bad_sweeps_and_grids_get_one_clear_error(change, message):
    params = base_params()
    change(params)
    with pytest.raises(MetrawError, match=message):
        validate_params(params)
        parameter_points(params)


def test_dvc_yaml_has_categorical_foreach_and_explicit_grid_stages():
    spec = importlib.util.spec_from_file_location("dvc_yaml", REPO / "workflow" / "scripts" / "dvc_yaml.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    params = base_params()
    params["sim_to_real"]["enabled"] = False
    stages = mod.build(params)["stages"]
    assert stages["emulate_cfa_pattern"]["foreach"] == "${target.sweeps.cfa_pattern}"
    grid = [k for k in stages if k.startswith("train_grid_")]
    assert len(grid) == 3 and stages["train_grid_1"]["outs"] == ["results/points/focal_length_m-2.0/model"]
    assert stages["train_grid_0"]["outs"] == ["results/points/focal_length_m-1.2+diameter_m-0.35/model"]
    assert "dvc_point=focal_length_m-1.2+diameter_m-0.35" in stages["train_grid_0"]["cmd"]
    deps = stages["aggregate"]["deps"]
    assert "results/points/focal_length_m-2.0+diameter_m-0.35/metrics.json" in deps
    assert "results/points/cfa_pattern-${target.sweeps.cfa_pattern[0]}/metrics.json" in deps
    plots = [next(iter(p)) for p in mod.build(params)["plots"]]
    assert not any("cfa_pattern" in p for p in plots) and "results/plots/iou_pixel_pitch_m.csv" in plots
    # every point fine-tunes the pretraining of its own CFA pattern: the nominal's Bayer one, the mono point a mono one
    pre, mono = "results/pretrained/RGGB/model", "results/pretrained/mono/model"
    assert pre in stages["train_nominal"]["deps"] and pre in stages["train_grid_0"]["deps"]
    assert pre in stages["train_focal_length_m"]["do"]["deps"]
    cfa_deps = stages["train_cfa_pattern"]["do"]["deps"]
    assert "results/pretrained/${item}/model" in cfa_deps and pre not in cfa_deps
    for pattern, model in (("RGGB", pre), ("mono", mono)):
        stage = stages[f"pretrain_{pattern}"]
        assert "target.sweeps" not in str(stage["params"]) and stage["outs"] == [model]
        assert stage["cmd"].endswith(f"--allowed-rules pretrain decode_store -- {model}")
    from metraw.study.pretraining import draws_extra_scenes, fine_tuned_points, pretrained_patterns

    assert set(fine_tuned_points(params)) == set(parameter_points(params))
    assert pretrained_patterns(params) == ["RGGB", "mono"]
    assert draws_extra_scenes(params) and "pretrain_scenes" in stages
    params["training"]["pretrain"]["enabled"] = False
    assert fine_tuned_points(params) == [] and pretrained_patterns(params) == [] and not draws_extra_scenes(params)
    stages = mod.build(params)["stages"]
    assert not [k for k in stages if k.startswith("pretrain")] and pre not in stages["train_nominal"]["deps"]
    assert not any("pretrained" in d for d in stages["train_cfa_pattern"]["do"]["deps"])


# --------------------------------------------------------------------------- categorical choice, 2-D grid GP
def test_categorical_choice_allows_values_whose_lower_bound_meets_the_requirement():
    c = categorical_choice({"RGGB": (0.30, 0.01), "mono": (0.26, 0.02)}, "RGGB", 0.25)
    assert c["optimal"] == "RGGB" and c["allowed"] == ["RGGB"]  # mono: 0.26 - 2 x 0.02 = 0.22 < 0.25
    c = categorical_choice({"RGGB": (0.30, 0.01), "mono": (0.33, 0.01)}, "RGGB", 0.25)
    # 0.03 above the nominal, 2 sd of the difference = 2 x 0.01 sqrt(2) = 0.0283: mono is better beyond the errors
    assert c["optimal"] == c["highest"] == "mono" and c["allowed"] == ["RGGB", "mono"]
    c = categorical_choice({"RGGB": (0.30, 0.01), "mono": (0.327, 0.01)}, "RGGB", 0.25)
    assert c["optimal"] == "RGGB" and c["highest"] == "mono"  # 0.027 < 0.0283: a tie keeps the nominal
    # the default run of 2026-11-28: mono 0.0004 above RGGB with sds 0.011 / 0.009
    c = categorical_choice({"RGGB": (0.2091, 0.0090), "mono": (0.2095, 0.0111)}, "RGGB", 0.15)
    assert c["optimal"] == "RGGB" and c["highest"] == "mono" and c["allowed"] == ["RGGB", "mono"]
    c = categorical_choice({"RGGB": (0.20, 0.01), "mono": (0.25, 0.01)}, "mono", 0.15)  # a mono nominal
    assert c["optimal"] == c["highest"] == "mono"


def test_grid_region_recovers_a_known_boundary():
    """IoU = 0.1 + D (D = diameter) over a 4 x 4 grid: the mean meets 0.35 at D = 0.25, the region starts there
    or a little above (its lower band is conservative), and spans every focal length."""
    f = np.array([0.8, 1.2, 1.6, 2.0])
    d = np.array([0.1, 0.2, 0.35, 0.5])
    F, D = np.meshgrid(f, d)
    X = np.column_stack([F.ravel(), D.ravel()])
    y = 0.1 + D.ravel()
    model, summary = grid_region(["focal_length_m", "diameter_m"], X, y, np.full(y.size, 1e-6), 0.35)
    mask = np.array(summary["mask_ok"], bool)
    dd = np.array(summary["mesh"]["diameter_m"])
    ok_rows = dd[mask.all(axis=1)]
    # conservative (the lower 2-sigma band), but not beyond the measured row at D = 0.35 (IoU 0.45)
    assert 0.24 <= ok_rows.min() <= 0.35 and not mask[dd < 0.24].any()
    mean = model.predict(np.array([[1.4, 0.25]])).mean[0]
    assert mean == pytest.approx(0.35, abs=0.02)
    assert summary["bounding_box_ok"]["focal_length_m"] == pytest.approx([0.8, 2.0])
    assert [p["meets_requirement"] for p in summary["points"]] == list(y - 2e-3 >= 0.35)
    assert summary["leave_one_out_share_inside"] is not None


# --------------------------------------------------------------------------- aggregate end to end
def _metrics(path: Path, iou: float, n: int = 6, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    recs = []
    for _ in range(n):
        u = int(rng.integers(80, 120))
        tp = int(round(iou * u))
        fp = (u - tp) // 2
        recs.append({"tp": tp, "fp": fp, "fn": u - tp - fp})
    pooled = sum(r["tp"] for r in recs) / sum(r["tp"] + r["fp"] + r["fn"] for r in recs)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"iou": pooled, "per_image": recs, "n_images": n, "precision": 0.5, "recall": 0.5}))


def _compression(path: Path, ratio: float, channels: tuple[str, ...]) -> None:
    images = [{"ratio": ratio * (1 + 0.01 * i), "channels": {c: {"ratio": ratio * (1 + 0.02 * j + 0.01 * i)}
                                                             for j, c in enumerate(channels)}} for i in range(4)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"overall": {"ratio": ratio, "bits_per_pixel": 16 / ratio}, "images": images,
                                "channels": {c: {"ratio": ratio * (1 + 0.02 * j)} for j, c in enumerate(channels)},
                                "signal_e": {"median": 35.0, "p05": 17.0, "p95": 60.0}}))


def test_aggregate_runs_its_linear_algebra_on_one_blas_thread():
    """`metraw aggregate` pins every BLAS it uses to one thread whatever the shell allows: with 2 the GP fits of the
    default run's metrics gave a spec bound that differed in its 16th digit (2026-11-28). threadpoolctl limits only
    the libraries loaded when it starts, so scipy's own OpenBLAS (loaded with scikit-learn's GP) must be loaded
    first. In a fresh process with 2 BLAS threads allowed: inside the command every BLAS pool runs 1 thread, and no
    BLAS the GP needs is loaded only after it."""
    import subprocess
    import sys

    code = """
import json
from threadpoolctl import threadpool_info
from metraw.spec import aggregate
blas = lambda: [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
seen = []
aggregate._inputs = lambda options: ({}, 0.5, [])
aggregate._aggregate = lambda options, params, required, rows: seen.append(blas()) or 0
assert aggregate.aggregate(None) == 0
import scipy.linalg, sklearn.gaussian_process
print(json.dumps({"inside": seen[0], "after": blas()}))
"""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2", "MKL_NUM_THREADS": "2"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(got["inside"]) == len(got["after"]) >= 1 and set(got["inside"]) == {1}, got
    assert max(got["after"]) == 2, got  # the limit ends with the command, and the shell's 2 threads were real


def test_aggregate_writes_categorical_grid_and_per_channel_results(tmp_path, capsys):
    from metraw.cli import main

    params = base_params()
    params["spec"]["required_iou"] = 0.2
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    for i, (point, over) in enumerate(parameter_points(params).items()):
        t = target_params(params, point)
        # IoU grows with D and with 1/GSD; mono is worse than Bayer here
        iou = 0.15 + 0.6 * t["diameter_m"] * (1.644 / t["focal_length_m"]) ** -0.5 * (2.4e-6 / t["pixel_pitch_m"]) ** 0.3
        iou -= 0.08 if t["cfa_pattern"] == "mono" else 0.0
        _metrics(tmp_path / "results" / point / "metrics.json", min(iou, 0.9), seed=i)
        _compression(tmp_path / "results" / point / "compression.json", 4.0 + 0.1 * i,
                     ("L",) if t["cfa_pattern"] == "mono" else ("R", "G", "B"))
    assert main(["aggregate", "--params", str(tmp_path / "params.yaml"), "--results", str(tmp_path / "results"),
                 "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "cfa_pattern: allowed" in out and "grid focal_length_m x diameter_m: 6 measured points" in out
    table = json.loads((tmp_path / "out" / "aggregate.json").read_text())
    assert table["parameters"] == swept_parameters(params)
    assert "cfa_pattern" not in table["gp_parameters"] and len(table["gp_parameters"]) == 6
    mono = next(r for r in table["points"] if r["point"] == "cfa_pattern-mono")
    assert table["categorical"]["cfa_pattern"]["values"]["mono"]["iou"] == pytest.approx(mono["iou"])
    grid = table["grids"][0]
    assert len(grid["points"]) == 6 and 0 <= grid["share_of_grid_ok"] <= 1
    assert {p["point"] for p in grid["points"]} >= {"nominal", "focal_length_m-2.0+diameter_m-0.35"}
    nominal = next(r for r in table["points"] if r["point"] == "nominal")
    assert nominal["ratio_G_sd"] > 0 and "iou_loo_pred" in nominal and "iou_loo_pred" not in mono
    spec = yaml.safe_load((tmp_path / "out" / "spec.yaml").read_text())
    assert set(spec["parameters"]) == set(swept_parameters(params))
    cfa = spec["parameters"]["cfa_pattern"]
    assert cfa["optimal"] == "RGGB" and cfa["allowed"] == ["RGGB"] and cfa["allowed_families"] == ["bayer"]
    assert cfa["measured"]["mono"]["iou"] == pytest.approx(mono["iou"])
    back = Specification.load(tmp_path / "out" / "spec.yaml")
    assert isinstance(back.parameters["cfa_pattern"], Choice)
    figs = {p.name for p in (tmp_path / "out" / "figures").iterdir()}
    assert {"fig7b_iou_grid_focal_length_m_diameter_m.png", "iou_cfa_pattern.png", "ratio_cfa_pattern.png",
            "fig8_ratio_channels_exposure_s.png", "fig8_ratio_channels_path_radiance_w_m2_sr_m.png",
            "fig8_ratio_channels_cfa_pattern.png"} <= figs
    # every point's per-channel ratios reach points.csv: the mono point's L as well as the Bayer points' R, G, B
    csv_rows = list(csv.DictReader(io.StringIO((tmp_path / "out" / "plots" / "points.csv").read_text())))
    by_point = {r["point"]: r for r in csv_rows}
    assert float(by_point["cfa_pattern-mono"]["ratio_L"]) == pytest.approx(mono["ratio_L"])
    assert float(by_point["cfa_pattern-mono"]["ratio_L_sd"]) > 0 and by_point["cfa_pattern-mono"]["ratio_G"] == ""
    assert float(by_point["nominal"]["ratio_G"]) == pytest.approx(nominal["ratio_G"]) and by_point["nominal"]["ratio_L"] == ""


def test_aggregate_writes_the_same_bytes_in_any_process(tmp_path):
    """Two `metraw aggregate` processes over the same points' results, with other string hash seeds (set orders) and
    2 BLAS threads allowed, write byte-identical outputs: table, spec, figures, plots (the workflow's killed-run test
    compares the chain's outputs, not the aggregate's)."""
    import subprocess
    import sys

    from workflow_workspace import file_digests

    params = base_params()
    params["target"]["sweeps"] = {"focal_length_m": [1.2], "diameter_m": [0.35], "exposure_s": [300.0e-6],
                                  "cfa_pattern": ["mono"]}
    params["target"].pop("grids")
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    for i, point in enumerate(parameter_points(params)):
        _metrics(tmp_path / "results" / point / "metrics.json", 0.2 + 0.05 * i, seed=i)
        _compression(tmp_path / "results" / point / "compression.json", 4.0 + 0.1 * i,
                     ("L",) if point == "cfa_pattern-mono" else ("R", "G", "B"))
    outs = []
    for hash_seed in ("1", "2"):
        out = tmp_path / f"out{hash_seed}"
        env = {**os.environ, "PYTHONHASHSEED": hash_seed, "OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
        subprocess.run([sys.executable, "-m", "metraw", "aggregate", "--params", str(tmp_path / "params.yaml"),
                        "--results", str(tmp_path / "results"), "--out", str(out)], env=env, check=True,
                       capture_output=True)
        outs.append(file_digests(out))
    assert {"aggregate.json", "spec.yaml"} <= set(outs[0]) and any(name.endswith(".png") for name in outs[0])
    assert outs[0] == outs[1], sorted(k for k in outs[0].keys() | outs[1].keys() if outs[0].get(k) != outs[1].get(k))


# --------------------------------------------------------------------------- check / normalise
def _spec(allowed=("RGGB",), haze=(20.0, 10.0, 30.0)) -> Specification:
    props = {"haze_e": Limit(*haze, "e-", {"better": "lower"})}
    params = {"cfa_pattern": Choice("RGGB", list(allowed), "", {"allowed_families": sorted(
        {"mono" if v == "mono" else "bayer" for v in allowed})})}
    return Specification(0.3, params, props, {"cfa_pattern": "RGGB"})


@pytest.fixture(scope="module")
def hazy_image():
    from test_emulate import flat_source, gsd_ratio_target

    from metraw.emulate.emulator import emulate

    tgt = gsd_ratio_target(6.0, exposure_s=6.0e-4, ground_speed_m_per_s=0.0, path_radiance_w_m2_sr_m=3e7)
    return tgt, emulate(flat_source((300, 450), 10000.0, seed=1), tgt, seed=3)


def test_check_judges_the_cfa_family_and_the_stated_haze(hazy_image):
    tgt, img = hazy_image
    haze = float(np.mean([tgt.haze_for(c) for c in tgt.channels]))
    assert stated_haze_e(img) == pytest.approx(haze)
    ok = check(img, _spec(haze=(haze, haze * 0.5, haze * 1.5)), measure_noise=False)
    assert ok.verdict == "PASS", ok.reasons
    # another Bayer phase is the same sensor; mono is another
    grbg = type(img)(img.data, img.profile.replace(cfa_pattern="GRBG"), img.mask, img.flags, list(img.provenance))
    assert check(grbg, _spec(haze=(haze, haze * 0.5, haze * 1.5)), measure_noise=False).verdict == "PASS"
    d = check(img, _spec(allowed=("mono",), haze=(haze, haze * 0.5, haze * 1.5)), measure_noise=False)
    assert d.verdict == "REJECT" and any("not among the spec's allowed mono" in r for r in d.reasons)
    d = check(img, _spec(allowed=(), haze=(haze, haze * 0.5, haze * 1.5)), measure_noise=False)
    assert d.verdict == "REJECT" and any("none meets the required IoU" in r for r in d.reasons)
    # more haze than the spec: cannot be removed
    d = check(img, _spec(haze=(haze / 3, haze / 4, haze / 2)), measure_noise=False)
    assert d.verdict == "REJECT" and any("cannot be removed without adding noise" in r for r in d.reasons)
    # less haze than the spec: add the missing path radiance as Poisson light
    d = check(img, _spec(haze=(2 * haze, 1.5 * haze, 3 * haze)), measure_noise=False)
    assert d.verdict == "NORMALISE" and d.chain[-1]["function"] == "add_poisson"
    assert d.chain[-1]["params"]["mean_e"] == pytest.approx(haze)
    out = apply_chain(img, d.chain, seed=5)
    added = out.electrons().mean() - img.electrons().mean()
    se = math.sqrt(2 * (img.electrons().var() + haze) / img.data.size)
    assert abs(added - haze) <= 4 * se
    assert stated_haze_e(out) == pytest.approx(2 * haze)
    assert check(out, _spec(haze=(2 * haze, 1.5 * haze, 3 * haze)), measure_noise=False).verdict == "PASS"
    # an image whose provenance says nothing about haze is not rejected for it
    bare = type(img)(img.data, img.profile, img.mask, img.flags, [])
    d = check(bare, _spec(haze=(haze, haze * 0.5, haze * 1.5)), measure_noise=False)
    assert d.verdict == "PASS" and any("haze_e not stated" in r for r in d.reasons)


def test_spec_refuses_a_malformed_categorical_line():
    d = _spec().to_dict()
    bad = copy.deepcopy(d)
    bad["parameters"]["cfa_pattern"]["allowed"] = "RGGB"
    with pytest.raises(MetrawError, match="allowed must be a list"):
        Specification.from_dict(bad)
    assert Specification.from_dict(d).to_dict() == d
