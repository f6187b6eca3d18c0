"""Specification vector, runtime check (PASS / NORMALISE / REJECT) and normalisation."""

import math
from pathlib import Path

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed
from metraw.spec.builder import Limit, Specification, build_spec
from metraw.spec.check import check, apply_chain
from metraw.spec.property_model import WAVELENGTH_REF_M
from metraw.spec.tolerance import Tolerance

H = 600e3
PITCH = 2.4e-6
SPEED = 6900.0


def real_data_dir() -> Path:
    """The real files committed with the repository (data/real, see its README.md)."""
    return Path(__file__).resolve().parents[1] / "data" / "real"


def make_spec() -> Specification:
    props = {
        "gsd_m": Limit(0.9, 0.8, 1.0, "m", {"better": "lower"}),
        "diffraction_m": Limit(1.65, 1.4, 2.2, "m", {"better": "lower"}),
        "smear_m": Limit(1.2, 0.6, 2.0, "m", {"better": "lower"}),
        "signal_e": Limit(150.0, 60.0, 400.0, "e-", {"better": "higher"}),
    }
    params = {"focal_length_m": Limit(1.6, 1.44, 1.8, "m")}
    return Specification(0.6, params, props, {"cfa_pattern": "RGGB"})


def make_image(gsd=0.9, diameter=0.2, exposure=180e-6, level_e=150.0, size=256, seed=1,
               claimed_gain=None) -> RawImage:
    prof = CalibrationProfile(gain_dn_per_e=1.0, black_level_dn=64, read_noise_e=3.0, white_level_dn=4095,
                              adc_bits=12, cfa_pattern="RGGB", full_well_e=10000.0,
                              pixel_pitch_m=PITCH, focal_length_m=PITCH * H / gsd, aperture_diameter_m=diameter,
                              altitude_m=H, exposure_s=exposure, ground_speed_m_per_s=SPEED)
    yy, xx = np.mgrid[0:size, 0:size]
    mean = level_e * (0.3 + 1.4 * xx / size)  # smooth ramp: the single-frame noise fit needs a range
    img = RawImage(expose(mean, prof, rng_from_seed(seed)), prof)
    if claimed_gain is not None:
        img = RawImage(img.data, prof.replace(gain_dn_per_e=claimed_gain), None, None)
    return img


def test_spec_yaml_round_trip(tmp_path):
    spec = make_spec()
    spec.save(tmp_path / "spec.yaml")
    back = Specification.load(tmp_path / "spec.yaml")
    assert back.to_dict() == spec.to_dict()
    (tmp_path / "bad.yaml").write_text("spec_version: 99\n")
    with pytest.raises(MetrawError, match="spec_version"):
        Specification.load(tmp_path / "bad.yaml")
    with pytest.raises(MetrawError, match="not found"):
        Specification.load(tmp_path / "none.yaml")


NOMINAL = {"altitude_m": H, "pixel_pitch_m": PITCH, "focal_length_m": 1.644, "diameter_m": 0.2,
           "exposure_s": 180e-6, "ground_speed_m_per_s": SPEED, "obscuration_ratio": 0.3, "cfa_pattern": "RGGB"}


def _tol(name, opt, lo, hi):
    return Tolerance(name, opt, 0.7, 0.65, lo, hi, "requirement", "sampled_range", False, False, lo, hi, True)


def test_build_spec_maps_parameters_to_image_properties():
    nominal = dict(NOMINAL)
    tols = {"focal_length_m": _tol("focal_length_m", 1.644, 1.2, 2.0), "diameter_m": _tol("diameter_m", 0.35, 0.15, 0.5),
            "exposure_s": _tol("exposure_s", 180e-6, 100e-6, 300e-6)}
    spec = build_spec(tols, nominal, 0.6, {"median": 70.0, "p05": 40.0, "p95": 120.0})
    g = spec.properties["gsd_m"]
    assert (g.min, g.max, g.optimal) == pytest.approx((PITCH * H / 2.0, PITCH * H / 1.2, PITCH * H / 1.644))
    d = spec.properties["diffraction_m"]
    assert (d.min, d.max) == pytest.approx((WAVELENGTH_REF_M * H / 0.5, WAVELENGTH_REF_M * H / 0.15))
    assert spec.properties["smear_m"].max == pytest.approx(SPEED * 300e-6)
    s = spec.properties["signal_e"]
    # photon budget D^2 t / f^2: the optimum has (0.35/0.2)^2 more light than nominal
    assert s.optimal == pytest.approx(70.0 * (0.35 / 0.2) ** 2)
    assert s.min == pytest.approx(40.0 * min((1.644 / 2.0) ** 2, (0.15 / 0.2) ** 2, 100 / 180))
    assert s.max == pytest.approx(120.0 * max((1.644 / 1.2) ** 2, (0.5 / 0.2) ** 2, 300 / 180))
    assert spec.parameters["focal_length_m"].to_dict()["unit"] == "m"


def test_check_pass():
    d = check(make_image(), make_spec())
    assert d.verdict == "PASS", d.reasons
    assert d.noise["measured"] and d.noise["consistent"]
    assert d.properties["signal_e"]["value"] == pytest.approx(150.0, rel=0.05)


def test_check_rejects_worse_and_unknown():
    d = check(make_image(gsd=1.2), make_spec(), measure_noise=False)
    assert d.verdict == "REJECT" and any("gsd_m" in r and "worse" in r for r in d.reasons)
    d = check(make_image(level_e=20.0), make_spec(), measure_noise=False)
    assert d.verdict == "REJECT" and any("signal_e" in r for r in d.reasons)
    d = check(make_image(diameter=0.1), make_spec(), measure_noise=False)
    assert d.verdict == "REJECT" and any("diffraction_m" in r for r in d.reasons)
    img = make_image()
    img = RawImage(img.data, img.profile.replace(altitude_m=None))
    d = check(img, make_spec(), measure_noise=False)
    assert d.verdict == "REJECT" and any("cannot be determined" in r for r in d.reasons)


def test_check_flags_a_wrong_profile():
    # the pixels were made with K = 1 DN/e-; the profile claims 2 DN/e-
    d = check(make_image(claimed_gain=2.0), make_spec())
    assert d.verdict == "REJECT"
    assert d.noise["checks"]["gain_dn_per_e"]["contradicts"]
    assert d.noise["checks"]["gain_dn_per_e"]["measured"] == pytest.approx(1.0, rel=0.15)
    assert any("contradicts the pixels" in r and "gain_dn_per_e" in r for r in d.reasons)


def test_normalise_finer_sharper_brighter_image_reaches_spec():
    spec = make_spec()
    # GSD 0.45 m (2x finer), 0.3 m mirror (sharper); after 2x2 binning 600 e- per pixel > 400 (brighter)
    img = make_image(gsd=0.45, diameter=0.3, level_e=150.0, size=256)
    d = check(img, spec, measure_noise=False)
    assert d.verdict == "NORMALISE", d.reasons
    fns = [s["function"] for s in d.chain]
    assert fns[0] == "bin_same_colour" and d.chain[0]["params"]["factor"] == 2
    assert "redistribute" in fns and fns[-1] == "thin"
    out = apply_chain(img, d.chain, seed=3)
    assert out.profile.gsd_m == pytest.approx(0.9)
    assert [p["function"] for p in out.provenance] == fns
    # signal now at the optimum: 150 e- x 4 (binning) thinned to 150 e-
    again = check(out, spec, measure_noise=False)
    assert again.verdict == "PASS", again.reasons
    assert again.properties["signal_e"]["value"] == pytest.approx(150.0, rel=0.05)
    # determinism
    assert np.array_equal(apply_chain(img, d.chain, seed=3).data, out.data)


def test_normalise_blur_kernel_adds_the_planned_variance():
    # a point-like source spreads to the Gaussian the plan asks for (second moment, sampling error bounded)
    from metraw.spec.check import _gaussian_kernel

    k = _gaussian_kernel(2.0)
    r = np.arange(k.shape[0]) - k.shape[0] // 2
    assert k.sum() == pytest.approx(1.0)
    assert float((k.sum(axis=1) * r**2).sum()) == pytest.approx(4.0, rel=1e-3)


def test_check_cli_on_real_frames(tmp_path):
    real = real_data_dir()
    dng = real / "canon_dng" / "colorchart.dng"
    from metraw.cli import main

    make_spec().save(tmp_path / "spec.yaml")
    rc = main(["check", str(dng), "--spec", str(tmp_path / "spec.yaml"), "--json", str(tmp_path / "d.json")])
    assert rc == 0
    import json

    d = json.loads((tmp_path / "d.json").read_text())
    # a handheld camera frame has no altitude: its ground properties cannot be established
    assert d["verdict"] == "REJECT" and d["reasons"]
    # the verdict is a result (status 0), or with --exit-code a status a script can gate on
    assert main(["check", str(dng), "--spec", str(tmp_path / "spec.yaml"), "--no-noise", "--exit-code"]) == 1


def test_check_flags_a_deliberately_wrong_profile_on_a_real_frame(tmp_path):
    dng = real_data_dir() / "canon_dng" / "colorchart.dng"
    import json

    from metraw.cli import main
    from metraw.io import read_raw

    make_spec().save(tmp_path / "spec.yaml")
    wrong = read_raw(dng).profile.replace(gain_dn_per_e=0.5, read_noise_e=2.0,
                                          uncertainty={"gain_dn_per_e": 0.01, "read_noise_e": 0.1})
    (tmp_path / "wrong.json").write_text(wrong.to_json())
    rc = main(["check", str(dng), "--spec", str(tmp_path / "spec.yaml"), "--profile", str(tmp_path / "wrong.json"),
               "--json", str(tmp_path / "d.json")])
    assert rc == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["verdict"] == "REJECT"
    assert d["noise"]["checks"]["gain_dn_per_e"]["contradicts"]
    assert any("contradicts the pixels" in r for r in d["reasons"])


def test_subcell_blur_kernels_carry_the_planned_variance():
    # photons move by whole cells: below one cell a sampled kernel of the nominal width would add
    # too little variance (a box shorter than a cell none); the plan's variance must be exact
    from metraw.spec.check import _box_kernel, _gaussian_kernel

    for sigma in (0.2, 0.363, 0.8, 3.0):
        k = _gaussian_kernel(sigma)
        r = np.arange(k.shape[0]) - k.shape[0] // 2
        assert k.sum() == pytest.approx(1.0) and k.min() >= 0
        assert float((k.sum(axis=1) * r**2).sum()) == pytest.approx(sigma**2, rel=1e-6)
    for length in (0.3, 0.668, 1.0, 4.5):
        k = _box_kernel(length)[0]
        r = np.arange(k.size) - k.size // 2
        assert k.sum() == pytest.approx(1.0) and k.min() >= 0
        assert float((k * r**2).sum()) == pytest.approx(length**2 / 12, rel=1e-6)


def test_redistribute_adds_the_planned_blur_to_a_point_source():
    # a bright single-cell source through the planned sub-cell smear: the measured along-track
    # variance of the landing photons equals L^2/12 within k = 4 standard errors
    from metraw.spec.check import apply_chain

    prof = make_image().profile.replace(read_noise_e=0.0)
    n_e = 4000
    data = np.full((64, 64), 64, np.uint16)
    data[32, 32] = 64 + n_e  # R site (RGGB, even row and column); K = 1 DN/e-
    img = RawImage(data, prof)
    length = 0.668
    out = apply_chain(img, [{"function": "redistribute", "params": {"kernel": "box_along_track", "length_cells": length}}],
                      seed=5)
    plane = out.data[0::2, 0::2].astype(np.float64) - 64
    cols = plane.sum(axis=0)
    x = np.arange(cols.size) - 16
    n = cols.sum()
    var = float((cols * x**2).sum() / n)
    want = length**2 / 12
    # per photon the offset is -1/0/+1 with variance want: var of the sample mean of x^2 ~ want (1 - want) / n
    se = math.sqrt(want * (1 - want) / n)
    assert n == pytest.approx(n_e, abs=1)
    assert abs(var - want) < 4 * se
    assert plane.sum(axis=1)[16] == pytest.approx(n, abs=1)  # along-track only: rows untouched


def test_thinning_uses_the_light_ratio_of_the_geometry():
    # with the optimum system in the spec context, p = collected light ratio (per pixel, after
    # binning), not the scene-dependent ratio of medians: a 0.4 m mirror collects 4x the light
    from metraw.spec.check import light_ratio

    spec = make_spec()
    spec.context["optimum"] = {"diameter_m": 0.2, "exposure_s": 180e-6, "pixel_pitch_m": PITCH,
                               "focal_length_m": PITCH * H / 0.9, "obscuration_ratio": 0.0,
                               "optical_transmission": 1.0}
    img = make_image(diameter=0.4, level_e=600.0, size=128)
    assert light_ratio(img.profile, spec.context["optimum"]) == pytest.approx(0.25)
    d = check(img, spec, measure_noise=False)
    thin = [s for s in d.chain if s["function"] == "thin"]
    assert d.verdict == "NORMALISE" and thin[0]["params"]["p"] == pytest.approx(0.25)
    # finer GSD: 2x2 binning sums 4 pixels, the pixel collects 1/4: p = 1 after binning -> no thinning
    img = make_image(gsd=0.45, level_e=100.0, size=128)
    assert light_ratio(img.profile, spec.context["optimum"], 2) == pytest.approx(1.0)


def test_optimum_signal_above_the_sampled_range_is_clipped_and_thinning_targets_it():
    # optimal D and t at their sampled maxima: the optimum combines both (10.4x nominal light), a
    # corner the one-at-a-time lines never reach (max 6.25x): optimal = max, light_scale = 6.25 / 10.4
    nominal = dict(NOMINAL)
    tols = {"focal_length_m": _tol("focal_length_m", 1.644, 1.2, 2.0), "diameter_m": _tol("diameter_m", 0.5, 0.15, 0.5),
            "exposure_s": _tol("exposure_s", 300e-6, 100e-6, 300e-6)}
    spec = build_spec(tols, nominal, 0.6, {"median": 70.0, "p05": 40.0, "p95": 80.0})
    s = spec.properties["signal_e"]
    joint = 70.0 * (0.5 / 0.2) ** 2 * 300 / 180
    assert s.max == pytest.approx(80.0 * (0.5 / 0.2) ** 2) and s.max < joint
    assert s.optimal == pytest.approx(s.max) and s.min <= s.optimal <= s.max
    assert s.details["light_scale"] == pytest.approx(s.max / joint)
    # an image from the optimum system itself, brighter than the spec's max: thinned by light_scale
    # (before the fix the light ratio was 1 and the image was rejected as 'cannot be thinned')
    spec.properties = {"signal_e": s}
    spec.context["optimum"]["obscuration_ratio"] = 0.3
    img = make_image(diameter=0.5, exposure=300e-6, gsd=PITCH * H / 1.644, level_e=1.3 * s.max, size=128)
    img = RawImage(img.data, img.profile.replace(obscuration_ratio=0.3))
    d = check(img, spec, measure_noise=False)
    thin = [c for c in d.chain if c["function"] == "thin"]
    assert d.verdict == "NORMALISE", d.reasons
    assert thin[0]["params"]["p"] == pytest.approx(s.details["light_scale"], rel=1e-6)


def _store_with(tmp_path, images):
    from metraw.io.store import RawStore

    with RawStore.create(tmp_path / "s.zarr") as s:
        for im in images:
            s.append(im)
    return tmp_path / "s.zarr"


def test_check_and_normalise_cli_on_a_store_image(tmp_path, capsys):
    from metraw.cli import main
    from metraw.io import read_raw

    spec = make_spec()
    spec.save(tmp_path / "spec.yaml")
    fine = make_image(gsd=0.45, level_e=60.0, size=128)  # 240 e- after 2x2 binning: in spec, no thinning
    mask = np.zeros(fine.shape, np.float32)
    mask[40:60, 20:80] = 1.0
    fine = RawImage(fine.data, fine.profile, mask, None, [], {"long": "x" * 500})
    store = _store_with(tmp_path, [make_image(size=64), fine])
    sp = str(tmp_path / "spec.yaml")
    assert main(["check", f"{store}#1", "--spec", sp, "--no-noise", "--exit-code"]) == 0
    assert capsys.readouterr().out.startswith("NORMALISE")
    assert main(["check", str(store), "--index", "0", "--spec", sp, "--no-noise", "--exit-code"]) == 0
    assert capsys.readouterr().out.startswith("PASS")
    out = tmp_path / "n.tif"
    assert main(["normalise", f"{store}#1", str(out), "--spec", sp, "--no-noise", "--seed", "2"]) == 0
    back = read_raw(out)
    assert back.profile.gsd_m == pytest.approx(0.9) and back.shape == (64, 64)
    assert back.provenance[-1]["function"] == "bin_same_colour"
    # the label mask follows the geometry: car area is conserved by same-colour binning
    assert back.mask is not None and back.mask.sum() * 4 == pytest.approx(mask.sum(), rel=1e-6)
    assert main(["normalise", str(store), str(tmp_path / "n.zarr"), "--index", "1", "--spec", sp, "--no-noise"]) == 0
    # bad inputs: one clear line, exit 2, nothing written
    for argv, msg in ((["check", f"{store}#7", "--spec", sp], "out of range"),
                      (["check", str(store), "--spec", sp], "choose an image"),
                      (["check", f"{tmp_path}/none.zarr#1", "--spec", sp], "not a metraw store"),
                      (["check", f"{store}#x", "--spec", sp], "image index"),
                      (["normalise", f"{store}#1", str(tmp_path / "n.tif"), "--spec", sp, "--no-noise"], "exist")):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], err


def test_partial_profile_overrides_the_images_own(tmp_path):
    import json

    from metraw.cli import main

    make_spec().save(tmp_path / "spec.yaml")
    store = _store_with(tmp_path, [make_image(size=256)])
    (tmp_path / "p.json").write_text(json.dumps({"gain_dn_per_e": 2.0, "uncertainty": {"gain_dn_per_e": 0.01}}))
    rc = main(["check", f"{store}#0", "--spec", str(tmp_path / "spec.yaml"), "--profile", str(tmp_path / "p.json"),
               "--json", str(tmp_path / "d.json")])
    assert rc == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["verdict"] == "REJECT" and d["noise"]["checks"]["gain_dn_per_e"]["contradicts"]
    (tmp_path / "bad.json").write_text(json.dumps({"gain": 2.0}))
    assert main(["check", f"{store}#0", "--spec", str(tmp_path / "spec.yaml"), "--profile", str(tmp_path / "bad.json")]) == 2


def test_signal_uses_the_measured_gain_when_the_profile_marks_it_unknown():
    # pixels made with K = 2 DN/e-; the profile states the convention K = 1 marked unknown (inf)
    img = make_image(level_e=150.0, size=256)
    prof = img.profile.replace(gain_dn_per_e=2.0)
    data = expose(150.0 * (0.3 + 1.4 * np.mgrid[0:256, 0:256][1] / 256), prof, rng_from_seed(4))
    unknown = RawImage(data, prof.replace(gain_dn_per_e=1.0, uncertainty={"gain_dn_per_e": math.inf}))
    d = check(unknown, make_spec())
    assert "measured from the noise" in d.properties["signal_e"]["source"]
    assert d.properties["signal_e"]["value"] == pytest.approx(150.0, rel=0.1)
    d = check(unknown, make_spec(), measure_noise=False)
    assert d.verdict == "REJECT" and any("signal_e cannot be determined" in r and "gain is unknown" in r
                                         for r in d.reasons)


@pytest.mark.parametrize("rel", ["micasense/IMG_0000_1.tif", "spacenet_pan/pan1.tif", "kit_ais/MOS155.png"])
def test_check_cli_on_each_kind_of_real_frame(tmp_path, rel):
    # MicaSense raw TIFF, WorldView pan GeoTIFF, KIT AIS photo (see each folder's SOURCE.txt):
    # none states a satellite's geometry and the spec is RGGB: a REJECT naming what is missing
    path = real_data_dir() / rel
    import json

    from metraw.cli import main

    make_spec().save(tmp_path / "spec.yaml")
    assert main(["check", str(path), "--spec", str(tmp_path / "spec.yaml"), "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["verdict"] == "REJECT"
    assert any("gsd_m cannot be determined (the profile lacks" in r for r in d["reasons"])


def test_a_partial_wrong_gain_on_the_real_dng_contradicts_the_pixels(tmp_path):
    # the Canon DNG's gain is unknown in the file; its noise says K ~ 1.98 DN/e-; claiming 0.5 is flagged
    dng = real_data_dir() / "canon_dng" / "colorchart.dng"
    import json

    from metraw.cli import main

    make_spec().save(tmp_path / "spec.yaml")
    (tmp_path / "wrong.json").write_text('{"gain_dn_per_e": 0.5}')
    assert main(["check", str(dng), "--spec", str(tmp_path / "spec.yaml"), "--profile", str(tmp_path / "wrong.json"),
                 "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    g = d["noise"]["checks"]["gain_dn_per_e"]
    assert d["verdict"] == "REJECT" and g["contradicts"] and g["measured"] == pytest.approx(1.98, rel=0.05)
    assert any("contradicts the pixels: gain_dn_per_e" in r for r in d["reasons"])
