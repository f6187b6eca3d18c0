"""Acceptance tests of metraw.emulate (issue 5): radiometry, noise model, chains, hard cases.

Tolerances are sampling errors: k standard errors of the estimated quantity.
"""

from __future__ import annotations

import json

import math

import numpy as np
import pytest
from scipy import stats

from metraw.emulate.emulator import emulate, expected_electrons, photon_electrons
from metraw.emulate.plan import plan_emulation, thinning_ratios
from metraw.emulate.target import TargetSystem, parse_point
from metraw.errors import MetrawError
from metraw.physics.accuracy import Accuracy
from metraw.raw.image import FLAG_SATURATED, RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

SOURCE = dict(camera="test drone", cfa_pattern="RGGB", pixel_pitch_m=2.41e-6, focal_length_m=10.26e-3,
              aperture_diameter_m=3.664e-3, altitude_m=250.0, exposure_s=1.0e-3, optical_transmission=0.9,
              gain_dn_per_e=0.25, black_level_dn=256, read_noise_e=3.0, full_well_e=15000.0, white_level_dn=4095,
              adc_bits=12, qe_per_channel={"R": 0.45, "G": 0.55, "B": 0.40})
NOMINAL = dict(altitude_m=600000.0, diameter_m=0.2, obscuration_ratio=0.3, focal_length_m=1.644, pixel_pitch_m=2.4e-6,
               cfa_pattern="RGGB", exposure_s=180e-6, ground_speed_m_per_s=6900.0, optical_transmission=0.8,
               qe_per_channel={"R": 0.45, "G": 0.55, "B": 0.40}, read_noise_e=3.0, gain_dn_per_e=1.0,
               black_level_dn=64, adc_bits=12, full_well_e=10000.0, atmospheric_transmission=0.8, haze_e=0.0)


def source_profile(**changes) -> CalibrationProfile:
    return CalibrationProfile(**{**SOURCE, **changes})


def flat_source(shape, mean_e, seed=0, **changes) -> RawImage:
    prof = source_profile(**changes)
    return RawImage(expose(np.full(shape, float(mean_e)), prof, rng_from_seed(seed)), prof)


def target(**changes) -> TargetSystem:
    return TargetSystem(**{**NOMINAL, **changes})


def gsd_ratio_target(ratio: float, **changes) -> TargetSystem:
    """A target whose GSD is ``ratio`` source GSDs (focal length chosen accordingly)."""
    gs = SOURCE["pixel_pitch_m"] * SOURCE["altitude_m"] / SOURCE["focal_length_m"]
    f = NOMINAL["pixel_pitch_m"] * NOMINAL["altitude_m"] / (ratio * gs)
    return target(focal_length_m=f, **changes)


def radiometric_e(tgt: TargetSystem, mean_source_e: float, channel: str) -> float:
    """Radiometric equation (DESIGN 3): target e- per pixel of ``channel`` for a flat source."""
    prof = source_profile()
    alpha, _ = thinning_ratios(prof, tgt)
    gs = prof.pixel_pitch_m * prof.altitude_m / prof.focal_length_m
    return alpha[channel] * mean_source_e * (tgt.gsd_m / gs) ** 2


def colour_planes(a, pattern="RGGB"):
    return {"R": a[..., 0::2, 0::2], "G1": a[..., 0::2, 1::2], "G2": a[..., 1::2, 0::2], "B": a[..., 1::2, 1::2]}


# --------------------------------------------------------------------------- flat field: mean, variance, correlation
@pytest.fixture(scope="module")
def flat_draws():
    """A flat 10 000 e- source emulated 30 times (GSD ratio 6, ~72 e- per G pixel, p < 1e-3)."""
    tgt = gsd_ratio_target(6.0, exposure_s=6.0e-4, ground_speed_m_per_s=0.0)
    src = flat_source((600, 900), 10000.0, seed=1)
    outs = [emulate(src, tgt, mode="auto", seed=s) for s in range(30)]
    return tgt, src, outs


def test_flat_mean_matches_radiometric_equation(flat_draws):
    tgt, src, outs = flat_draws
    assert outs[0].meta["emulation"]["chain"] == "expected"
    e = np.stack([o.electrons() for o in outs])
    src_e = src.electrons()
    for name, ch in (("R", "R"), ("G1", "G"), ("B", "B")):
        plane = colour_planes(e)[name]
        mean_src = colour_planes(src_e)[name].mean()
        want = radiometric_e(tgt, mean_src, ch)
        se = plane.std() / math.sqrt(plane.size)
        assert abs(plane.mean() - want) <= 0.005 * want, (ch, plane.mean(), want)
        assert abs(plane.mean() - want) <= 5 * se + 2e-3 * want, (ch, plane.mean(), want, se)


def test_flat_variance_is_poisson_plus_read_noise(flat_draws):
    tgt, _, outs = flat_draws
    e = np.stack([o.electrons() for o in outs])
    quant = 1.0 / (12 * tgt.gain_dn_per_e**2)
    for name in ("R", "G1", "G2", "B"):
        plane = colour_planes(e)[name]
        mean, var = plane.mean(), plane.var(ddof=1)
        want = mean + tgt.read_noise_e**2 + quant
        rel_se = math.sqrt(2.0 / plane.size) * 1.2  # variance estimate's relative SE (slight excess kurtosis)
        assert abs(var / want - 1) <= min(0.01, 4 * rel_se), (name, var, want)


def test_flat_neighbour_correlation(flat_draws):
    _, _, outs = flat_draws
    r_all = []
    for axis in (0, 1):
        num = den_a = den_b = 0.0
        for o in outs:
            e = o.electrons()
            planes = colour_planes(e)
            resid = np.empty_like(e)
            for name, (dy, dx) in zip(("R", "G1", "G2", "B"), ((0, 0), (0, 1), (1, 0), (1, 1))):
                resid[dy::2, dx::2] = planes[name] - planes[name].mean()
            a = resid[:-1] if axis == 0 else resid[:, :-1]
            b = resid[1:] if axis == 0 else resid[:, 1:]
            num += (a * b).sum()
            den_a += (a * a).sum()
            den_b += (b * b).sum()
        r_all.append(num / math.sqrt(den_a * den_b))
    assert max(abs(r) for r in r_all) <= 0.005, r_all


def test_low_signal_histogram_is_poisson_convolved_with_read_noise():
    tgt = gsd_ratio_target(6.0, exposure_s=6.0e-4 * 2.0 / 72.0, ground_speed_m_per_s=0.0)
    src = flat_source((600, 900), 10000.0, seed=2)
    outs = [emulate(src, tgt, seed=100 + s) for s in range(10)]
    dn = np.stack([colour_planes(o.data)["G1"] for o in outs]).ravel().astype(np.int64)
    mu = radiometric_e(tgt, colour_planes(src.electrons())["G1"].mean(), "G")
    assert 1.5 < mu < 2.5
    k = np.arange(0, 40)
    pk = stats.poisson.pmf(k, mu)
    lo, hi = dn.min(), dn.max()
    edges = np.arange(lo, hi + 2) - 0.5
    sigma = tgt.read_noise_e * tgt.gain_dn_per_e
    cdf = stats.norm.cdf((edges[None, :] - tgt.black_level_dn - tgt.gain_dn_per_e * k[:, None]) / sigma)
    expected_p = (pk[:, None] * np.diff(cdf, axis=1)).sum(axis=0)
    observed = np.bincount(dn - lo, minlength=hi - lo + 1)
    exp_counts = expected_p * dn.size
    # merge bins with < 5 expected counts into their neighbours
    obs_m, exp_m, acc_o, acc_e = [], [], 0.0, 0.0
    for o, e in zip(observed, exp_counts):
        acc_o += o
        acc_e += e
        if acc_e >= 5:
            obs_m.append(acc_o)
            exp_m.append(acc_e)
            acc_o = acc_e = 0.0
    obs_m[-1] += acc_o
    exp_m[-1] += acc_e
    exp_m = np.array(exp_m) * (sum(obs_m) / sum(exp_m))
    chi2 = ((np.array(obs_m) - exp_m) ** 2 / exp_m).sum()
    pval = stats.chi2.sf(chi2, len(obs_m) - 1)
    assert pval > 1e-3, (chi2, len(obs_m), pval)


# --------------------------------------------------------------------------- photon chain vs expected chain
def structured_source(shape=(240, 360), seed=3, **changes) -> RawImage:
    yy, xx = np.mgrid[0: shape[0], 0: shape[1]]
    scene = 1500 + 1200 * np.sin(xx / 15.0) * np.cos(yy / 23.0) + 2000 * ((xx // 40 + yy // 40) % 2)
    prof = source_profile(**changes)
    return RawImage(expose(scene, prof, rng_from_seed(seed)), prof)


@pytest.mark.parametrize("edge,rotation,speed,jitter", [("reflect", 0.0, 0.0, 0.0), ("zero", 0.0, 0.0, 0.0),
                                                         ("reflect", 0.4, 0.0, 0.0), ("reflect", 0.0, 6900.0, 1e-6)])
def test_mean_of_photon_draws_agrees_with_expected(edge, rotation, speed, jitter):
    src = structured_source()
    tgt = target(ground_speed_m_per_s=speed, jitter_rms_rad=jitter, frame_rotation_rad=rotation)
    want, plan = expected_electrons(src, tgt, edge=edge)
    if speed or jitter:  # the last case draws smear (1.2 m) and jitter (0.6 m rms) per photon
        assert plan.smear_m > 0 and plan.jitter_m > 0
    n = 200
    draws = np.stack([photon_electrons(src, tgt, edge=edge, seed=i)[0] for i in range(n)]).astype(np.float64)
    det = want > 0
    mean = draws.mean(axis=0)[det]
    se = draws.std(axis=0, ddof=1)[det] / math.sqrt(n)
    z = (mean - want[det]) / se
    # every pixel within 3 standard errors, Bonferroni-corrected for the number of pixels compared
    z_max = stats.norm.isf(0.001 / (2 * z.size))
    assert np.abs(z).max() <= max(3.0, z_max), (np.abs(z).max(), z.size)
    assert np.mean(np.abs(z) > 3) <= 0.0027 + 4 * math.sqrt(0.0027 / z.size)
    chi2 = float((z**2).sum())
    assert stats.chi2.sf(chi2, z.size) > 1e-4 and stats.chi2.cdf(chi2, z.size) > 1e-4, (chi2, z.size)
    assert abs(mean.sum() / want[det].sum() - 1) <= 4 * math.sqrt((se**2).sum()) / want[det].sum()


# --------------------------------------------------------------------------- geometry
def test_non_integer_gsd_ratio_and_mask_geometry():
    src = flat_source((600, 900), 6000.0, seed=4)
    mask = np.zeros(src.shape, np.float32)
    mask[100:260, 200:530] = 1.0
    src = RawImage(src.data, src.profile, mask=mask)
    tgt = gsd_ratio_target(7.3, ground_speed_m_per_s=0.0)
    want, plan = expected_electrons(src, tgt)
    assert abs(plan.target_gsd_m / plan.source_gsd_m - 7.3) < 1e-9
    src_g = colour_planes(src.electrons())["G1"].mean()
    g = colour_planes(want)["G1"]
    assert abs(g.mean() / radiometric_e(tgt, src_g, "G") - 1) < 1e-3
    out = emulate(src, tgt, seed=0)
    ratio = plan.target_gsd_m / plan.source_gsd_m
    # car area is preserved by the mask geometry (to the cell quantisation at the rectangle's border)
    area_src = mask.sum()
    area_tgt = out.mask.astype(np.float64).sum() * ratio**2
    assert abs(area_tgt / area_src - 1) < 0.03, (area_tgt, area_src)
    assert out.mask.max() == 1.0 and 0 < out.mask[out.mask > 0].min() < 1


def test_rotated_frame_keeps_radiometry_and_fits_footprint():
    src = flat_source((600, 900), 6000.0, seed=5)
    tgt = target(ground_speed_m_per_s=6900.0, frame_rotation_rad=0.5, track_angle_rad=0.2)
    want, plan = expected_electrons(src, tgt)
    assert plan.frame_shape[0] >= 1 and plan.frame_shape[1] >= 1
    src_g = colour_planes(src.electrons())["G1"].mean()
    assert abs(colour_planes(want)["G1"].mean() / radiometric_e(tgt, src_g, "G") - 1) < 2e-3
    assert any("motion smear" in m for m in plan.modelled)
    # a requested frame larger than the footprint is refused with numbers
    with pytest.raises(MetrawError, match="does not fit"):
        plan_emulation(src.profile, src.shape, tgt.replace(frame_shape_px=(100, 100)))


def test_psf_larger_than_frame_edge_policy():
    src = flat_source((200, 300), 6000.0, seed=6)
    tgt = target(ground_speed_m_per_s=0.0)
    with pytest.raises(MetrawError, match="margin of .* m inside each edge"):
        plan_emulation(src.profile, src.shape, tgt, edge="valid")
    # reflect (default): a flat scene stays exactly flat, even though the PSF wings exceed the frame
    want, _ = expected_electrons(src, tgt, edge="reflect")
    g = colour_planes(want)["G1"]
    assert g.std() / g.mean() < 5e-3
    # zero: light from outside is missing, the edges are darker than the centre
    dark, _ = expected_electrons(src, tgt, edge="zero")
    gz = colour_planes(dark)["G1"]
    assert gz[0, 0] < 0.9 * gz[gz.shape[0] // 2, gz.shape[1] // 2]


# --------------------------------------------------------------------------- hard cases
def test_target_needing_more_light_than_recorded_is_refused():
    with pytest.raises(MetrawError, match=r"times more light than the source recorded in band [RGB]"):
        thinning_ratios(source_profile(), target(diameter_m=50.0, exposure_s=0.5))


def test_zero_exposure_is_refused():
    with pytest.raises(MetrawError, match="exposure_s must be > 0"):
        thinning_ratios(source_profile(), target(exposure_s=0.0))
    with pytest.raises(MetrawError, match="source exposure_s must be > 0"):
        thinning_ratios(source_profile(exposure_s=0.0), target())


def test_saturated_source_pixels_flag_the_target_pixels_they_feed():
    src = flat_source((600, 900), 3000.0, seed=7)
    data = src.data.copy()
    data[290:310, 440:460] = src.profile.white_level_dn
    src = RawImage(data, src.profile)
    tgt = target(ground_speed_m_per_s=0.0)
    out = emulate(src, tgt, seed=0)
    sat = (out.flags & FLAG_SATURATED) != 0
    assert sat.any()
    plan = plan_emulation(src.profile, src.shape, tgt)
    ht, wt = plan.frame_shape
    assert sat[ht // 2, wt // 2]  # the pixel the saturated block falls on
    assert not sat[0, 0] and not sat[-1, -1]  # far away pixels are not affected
    entry = out.provenance[-1]["params"]
    assert entry["saturated_source_cells"] > 0 and entry["target_pixels_fed_by_saturated"] == int(sat.sum())


def test_scenes_that_differ_in_exposure_alone_share_the_plan_but_keep_their_own_thinning():
    from metraw.emulate import plan as emulate_module

    short = flat_source((600, 900), 800.0, seed=3, exposure_s=0.5e-3)
    long = RawImage(short.data, short.profile.replace(exposure_s=1.0e-3))
    tgt = target(ground_speed_m_per_s=0.0)
    emulate_module._PLAN_CACHE.clear()
    fresh = emulate(long, tgt, "expected", seed=1)
    plan_long = plan_emulation(long.profile, long.shape, tgt)
    emulate_module._PLAN_CACHE.clear()
    plan_short = plan_emulation(short.profile, short.shape, tgt)
    plan_after = plan_emulation(long.profile, long.shape, tgt)
    # one Fourier grid and transfer for both, each its own alpha and p (half the exposure: twice the ratios)
    assert plan_after.transfer is plan_short.transfer and len(emulate_module._PLAN_CACHE) == 1
    assert (plan_after.alpha, plan_after.p) == thinning_ratios(long.profile, tgt) == (plan_long.alpha, plan_long.p)
    assert all(plan_short.alpha[c] == pytest.approx(2 * plan_after.alpha[c], rel=1e-12) for c in plan_short.alpha)
    # and the emulation through the shared plan is the one through a plan of its own, bit for bit
    assert np.array_equal(emulate(long, tgt, "expected", seed=1).data, fresh.data)


def test_very_large_sums_use_float64():
    # 60 000 e- per pixel at gain 1/16 DN/e- and a 16-bit ADC: cell sums ~1e9 e- per target pixel footprint
    src = flat_source((800, 1200), 60000.0, seed=8, gain_dn_per_e=1 / 16, white_level_dn=65535, adc_bits=16,
                      full_well_e=1e6)
    tgt = gsd_ratio_target(40.0, ground_speed_m_per_s=0.0)
    want, plan = expected_electrons(src, tgt)
    src_g = colour_planes(src.electrons())["G1"].mean()
    assert abs(colour_planes(want)["G1"].mean() / radiometric_e(tgt, src_g, "G") - 1) < 1e-4
    # photon chain: integer counts of more than 2^31 photons in one cell would overflow int32
    from metraw.physics.rawfunc import stochastic_round, thin_counts

    n = stochastic_round(np.array([3.0e12, 7.5]), rng_from_seed(0))
    assert n.dtype == np.int64 and n[0] == 3_000_000_000_000
    k = thin_counts(n, 1e-3, rng_from_seed(1))
    assert abs(k[0] - 3e9) < 6 * math.sqrt(3e9)


# --------------------------------------------------------------------------- reporting and determinism
def test_result_profile_provenance_and_determinism():
    src = structured_source()
    tgt = target()
    a = emulate(src, tgt, seed=11)
    b = emulate(src, tgt, seed=11)
    c = emulate(src, tgt, seed=12)
    assert np.array_equal(a.data, b.data) and not np.array_equal(a.data, c.data)
    assert a.profile.gsd_m == pytest.approx(tgt.gsd_m)
    assert a.profile.cfa_pattern == "RGGB" and a.profile.black_level_dn == 64
    entry = a.provenance[-1]
    assert entry["function"] == "emulate"
    bounds = entry["params"]["error_bounds"]
    assert "poisson_shortcut_excess_variance_rel" in bounds and bounds["poisson_shortcut_excess_variance_rel"] < 1e-3
    assert any("motion smear" in m for m in entry["params"]["modelled"])
    assert entry["params"]["accuracy"] == Accuracy().to_dict()
    photon = emulate(src, tgt, mode="photon", seed=11)
    assert photon.meta["emulation"]["chain"] == "photon"
    assert np.array_equal(photon.data, emulate(src, tgt, mode="photon", seed=11).data)
    assert not np.array_equal(photon.data, emulate(src, tgt, mode="photon", seed=12).data)
    with pytest.raises(MetrawError, match="mode"):
        emulate(src, tgt, mode="fast")


def test_approximate_source_stays_approximate_after_emulation():
    """A raw rebuilt from a processed photo is flagged approximate; its emulated target raws keep the flag
    and say why (a synthetic or camera source gives an exact target profile)."""
    src = structured_source()
    assert not emulate(src, target(), seed=0).profile.approximate
    prof = src.profile.replace(approximate=True, approximate_reason="made from a processed 8-bit RGB image")
    out = emulate(RawImage(src.data, prof, mask=src.mask), target(), seed=0)
    assert out.profile.approximate and "processed 8-bit RGB" in out.profile.approximate_reason
    assert out.profile.gsd_m == pytest.approx(target().gsd_m)


def test_parse_point_and_from_params():
    pt = parse_point("focal_length_m=1.644,diameter_m=0.2,exposure_s=180e-6,cfa_pattern=mono,frame_offset_m=10:-5")
    assert pt["exposure_s"] == 180e-6 and pt["cfa_pattern"] == "mono" and pt["frame_offset_m"] == (10.0, -5.0)
    with pytest.raises(MetrawError, match="unknown target field"):
        parse_point("focal_length=1")
    params = {"target": {"nominal": dict(NOMINAL, haze_e=5.0)}}
    t = TargetSystem.from_params(params, {"diameter_m": 0.5})
    assert t.diameter_m == 0.5 and t.haze_e == 5.0


# --------------------------------------------------------------------------- command line
def test_cli_emulate_writes_store_atomically(tmp_path, capsys):
    import yaml

    from metraw.cli import main
    from metraw.io.store import RawStore

    params = tmp_path / "params.yaml"
    from pathlib import Path

    full = yaml.safe_load((Path(__file__).resolve().parents[1] / "params.yaml").read_text())
    full["target"]["nominal"] = dict(NOMINAL)
    # NOMINAL has no path radiance: keep only the sweeps of fields it has (a sweep of another is refused)
    full["target"]["sweeps"] = {k: v for k, v in full["target"]["sweeps"].items() if k in NOMINAL}
    full["training"]["pretrain"]["box"] = {k: v for k, v in full["training"]["pretrain"]["box"].items() if k in NOMINAL}
    full["target"]["emulation"] = {"mode": "auto", "seed": 0}
    params.write_text(yaml.safe_dump(full))
    src_path = tmp_path / "src.zarr"
    with RawStore.create(src_path) as store:
        store.append(structured_source(seed=20))
        store.append(structured_source(seed=21))
    out = tmp_path / "out.zarr"
    rc = main(["emulate", str(src_path), str(out), "--params", str(params), "--point",
               "focal_length_m=1.2,exposure_s=300e-6"])
    assert rc == 0 and "GSD ratio" in capsys.readouterr().out
    res = RawStore.open(out)
    assert len(res) == 2 and res[0].profile.exposure_s == 300e-6 and res[0].profile.focal_length_m == 1.2
    assert res[0].provenance[-1]["params"]["seed"] == [0, 0]
    # the bytes do not depend on the number of worker processes (default 2; image i uses seed (0, i))
    one = tmp_path / "one.zarr"
    assert main(["emulate", str(src_path), str(one), "--params", str(params), "--point",
                 "focal_length_m=1.2,exposure_s=300e-6", "--workers", "1"]) == 0
    assert "1 workers" in capsys.readouterr().out
    res1 = RawStore.open(one)
    for i in range(2):
        assert np.array_equal(res1[i].data, res[i].data) and res1[i].provenance == res[i].provenance
    assert not np.array_equal(res[0].data, res[1].data)
    bad = tmp_path / "bad.zarr"
    rc = main(["emulate", str(src_path), str(bad), "--params", str(params), "--point", "diameter_m=30,exposure_s=1"])
    assert rc == 2 and "times more light" in capsys.readouterr().err
    assert not bad.exists() and not any(p.name.startswith(".bad.zarr") for p in tmp_path.iterdir())
    # --at-point NAME: the parameter file's point, merged once in metraw.study.points; the same store as the full list of
    # its fields as overrides (what the workflow passed before), ints of the parameter file held as floats alike
    from metraw.study.points import target_params

    full["target"]["nominal"]["black_level_dn"] = 64  # an int in the file
    params.write_text(yaml.safe_dump(full))
    fields = target_params(full, "diameter_m-0.5")
    listed = ",".join(f"{k}={v}" for k, v in fields.items() if not isinstance(v, (dict, list)))
    by_name, by_list = tmp_path / "name.zarr", tmp_path / "list.zarr"
    assert main(["emulate", str(src_path), str(by_name), "--params", str(params), "--at-point", "diameter_m-0.5"]) == 0
    assert main(["emulate", str(src_path), str(by_list), "--params", str(params), "--point", listed]) == 0
    a, b = RawStore.open(by_name), RawStore.open(by_list)
    assert a[0].profile.aperture_diameter_m == 0.5
    for i in range(2):
        assert np.array_equal(a[i].data, b[i].data) and a[i].provenance == b[i].provenance
    assert json.dumps(a[0].provenance[-1]["params"]["target"]) == json.dumps(b[0].provenance[-1]["params"]["target"])
    capsys.readouterr()
    rc = main(["emulate", str(src_path), str(tmp_path / "both.zarr"), "--params", str(params), "--at-point", "nominal",
               "--point", "diameter_m=0.3"])
    assert rc == 2 and "not both" in capsys.readouterr().err
    rc = main(["emulate", str(src_path), str(tmp_path / "nope.zarr"), "--params", str(params), "--at-point", "nope"])
    assert rc == 2 and "unknown parameter point 'nope'" in capsys.readouterr().err


def test_expected_chain_matches_optics_kernel_for_a_point_source():
    """One bright source cell: the Fourier chain equals metraw.physics.optics.system_kernel (an independent
    implementation, validated against the Airy formula) averaged over the cell (uniform photon positions),
    to <= 5e-4 of the peak (band sampling 1e-4 in each, gridding 2e-7)."""
    from metraw.emulate.emulator import _cell_planes, _Fourier
    from metraw.physics import optics

    data = np.full((600, 900), 256, np.uint16)
    ci, cj = 151, 223
    data[2 * ci, 2 * cj + 1] = data[2 * ci + 1, 2 * cj] = 256 + 1000  # 4000 e- in each G site of one cell
    src = RawImage(data, source_profile())
    tgt = target(ground_speed_m_per_s=0.0)
    plan = plan_emulation(src.profile, src.shape, tgt, edge="zero")
    arrivals = _Fourier(plan).arrivals(_cell_planes(src, plan)["G"], "G")
    ht, wt = plan.frame_shape
    gt = plan.target_gsd_m
    u0 = ((cj + 0.5) * plan.cell_m - plan.centre_m[0]) / gt + wt / 2
    v0 = ((ci + 0.5) * plan.cell_m - plan.centre_m[1]) / gt + ht / 2
    n, c = 4, plan.cell_m / gt
    ref = np.zeros((ht, wt))
    for a in range(n):
        for b in range(n):
            off = (v0 + ((a + 0.5) / n - 0.5) * c - 0.5 - (ht - 1) / 2, u0 + ((b + 0.5) / n - 0.5) * c - 0.5 - (wt - 1) / 2)
            ref += optics.system_kernel(plan.bands["G"], tgt.diameter_m, gt / tgt.altitude_m, (ht, wt),
                                        tgt.obscuration_ratio, center_offset_px=off)
    ref *= 8000.0 / n**2
    assert np.abs(arrivals - ref).max() <= 5e-4 * ref.max()


# --------------------------------------------------------------------------- plan arrays: cached parts, exact shortcuts
def test_axis_aligned_sinc_shortcut_is_the_grid_form_bit_for_bit():
    """``_sinc_along`` takes the vector form only where the other axis's factor is exactly zero (signed zeros
    included): it then equals the full grid's sines element for element, and elsewhere it is the full form."""
    from metraw.emulate.plan import _sinc_along

    fy = np.fft.fftfreq(37, 0.31)[:, None]
    fx = np.fft.rfftfreq(40, 0.29)[None, :]
    for c, s in ((1.0, 0.0), (1.0, -0.0), (-0.0, 1.0), (0.0, -1.0), (math.cos(0.3), math.sin(0.3)),
                 (math.cos(math.pi / 2), 1.0)):
        for scale in (0.88, 1.24, 3.7):
            want = np.sinc(scale * (fx * c + fy * s))
            got = np.broadcast_to(_sinc_along(fx, fy, c, s, scale), want.shape)
            assert np.array_equal(got, want), (c, s, scale)


def test_plans_are_the_same_with_their_cached_arrays_and_without():
    """A plan made after others (its grid, OTF table and OTF on the grid taken from the caches) has the transfer
    functions of one made from empty caches, and the cached arrays cannot be written to."""
    from metraw.emulate import plan as E

    src = flat_source((400, 600), 5000.0)
    targets = [gsd_ratio_target(6.0), gsd_ratio_target(7.5), gsd_ratio_target(6.0, exposure_s=3e-4),
               gsd_ratio_target(6.0, diameter_m=0.35), gsd_ratio_target(6.0, frame_rotation_rad=0.4)]
    warm = [plan_emulation(src.profile, src.shape, t) for t in targets]
    for t, plan in zip(targets, warm):
        E._PLAN_CACHE.clear()
        for cached in (E._grid_arrays, E._grid_otf, E._poly_otf_table):
            cached.cache_clear()
        cold = plan_emulation(src.profile, src.shape, t)
        assert plan.transfer.keys() == cold.transfer.keys()
        assert all(np.array_equal(plan.transfer[c], cold.transfer[c]) for c in plan.transfer)
    with pytest.raises(ValueError):
        E._grid_arrays(64, 64, 0.5, 0.5, 0.7)[3][0, 0] = 1.0
