"""Sampling-phase draws (metraw.emulate.draws): exactly the emulator's expected chain at that offset and flip,
with photon-exact noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from metraw.emulate.draws import build_field
from metraw.emulate.emulator import emulate, expected_electrons
from metraw.emulate.target import TargetSystem
from metraw.errors import MetrawError
from metraw.raw.image import RawImage

PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"


@pytest.fixture(scope="module")
def scene():
    from metraw.scenes import generate_one

    return generate_one(2, 0, 256)


@pytest.fixture(scope="module")
def target():
    # nominal payload with a long smear along x (so a wrong flip would show) and a GSD giving ~18 px
    t = TargetSystem.from_params(str(PARAMS))
    return dataclasses.replace(t, focal_length_m=0.9, ground_speed_m_per_s=6900.0 * 4)


def flipped(img: RawImage, flip: int) -> RawImage:
    """The scene mirrored about its centre (bit 1: x, bit 2: y), CFA pattern relabelled to match."""
    d, m = img.data, img.mask
    cell = [list(img.profile.cfa_pattern[:2]), list(img.profile.cfa_pattern[2:])]
    if flip & 1:
        d, m, cell = d[:, ::-1], m[:, ::-1], [r[::-1] for r in cell]
    if flip & 2:
        d, m, cell = d[::-1], m[::-1], cell[::-1]
    prof = img.profile.replace(cfa_pattern="".join(cell[0] + cell[1]))
    return RawImage(data=np.ascontiguousarray(d), profile=prof, mask=np.ascontiguousarray(m))


@pytest.mark.parametrize("a,b,flip", [(0, 0, 0), (1, 3, 0), (3, 2, 1), (2, 1, 2), (0, 3, 3)])
def test_draw_expectation_and_labels_equal_the_emulator_at_that_offset(scene, target, a, b, flip):
    field = build_field(scene, target)
    ox, oy = field.phase_offset_m(a, b)
    at = dataclasses.replace(target, frame_offset_m=(ox, oy), frame_shape_px=field.frame_shape)
    ref, _ = expected_electrons(flipped(scene, flip), at)
    got = field.expected(a, b, flip)
    assert got.shape == ref.shape
    assert np.abs(got - ref).max() <= 1e-6 * ref.max()  # float32 lattice; gridding itself is ~1e-5
    emu = emulate(flipped(scene, flip), at, "expected", 0)
    assert np.array_equal(field.mask(a, b, flip), emu.mask)


def test_phases_differ_and_span_one_cfa_period(scene, target):
    field = build_field(scene, target)
    k = field.oversample
    assert field.n_phases == (2 * k) ** 2 * 4
    offsets = [field.phase_offset_m(0, b)[0] for b in range(2 * k)]
    assert np.allclose(np.diff(offsets), target.gsd_m / k)
    assert offsets[-1] - offsets[0] + target.gsd_m / k == pytest.approx(2 * target.gsd_m)
    e = [field.expected(0, b) for b in range(2 * k)]
    assert all(not np.allclose(e[0], x) for x in e[1:])


def test_draw_noise_is_poisson_plus_read_noise(scene, target):
    """Over many draws at one phase and flip: per-pixel mean and variance of the electrons as the model says
    (mean within 4 standard errors; the variance within its sampling error)."""
    field = build_field(scene, target)
    n = 400
    prof = target.profile()
    e = np.stack([(field.draw(s, 1, 2, 0).data.astype(np.float64) - prof.black_level_dn) / prof.gain_dn_per_e
                  for s in range(n)])
    from metraw.raw.cfa import color_index

    haze = np.take([target.haze_for(c) for c in target.channels], color_index(target.cfa_pattern, e.shape[1:]))
    dark = prof.dark_current_e_per_s * (prof.exposure_s or 0.0)
    lam = field.expected(1, 2, 0) + haze + dark
    var_model = lam + prof.read_noise_e**2 + prof.gain_dn_per_e**-2 / 12
    z = (e.mean(0) - lam) / np.sqrt(var_model / n)
    assert abs(z.mean()) < 4 / np.sqrt(z.size)  # unbiased over the frame
    assert np.abs(z).max() < 6
    ratio = e.var(0, ddof=1) / var_model
    assert abs(ratio.mean() - 1) < 4 * np.sqrt(2 / (n - 1)) / np.sqrt(ratio.size)
    d = e - e.mean(0)  # neighbour correlation of the noise
    rho = (d[:, :, 1:] * d[:, :, :-1]).mean() / np.sqrt((d[:, :, 1:] ** 2).mean() * (d[:, :, :-1] ** 2).mean())
    assert abs(rho) < 4 / np.sqrt(d[:, :, 1:].size)


def test_draws_are_deterministic_and_vary_with_the_seed(scene, target):
    field = build_field(scene, target)
    a, b = field.draw(7), field.draw(7)
    assert np.array_equal(a.data, b.data) and np.array_equal(a.mask, b.mask)
    assert a.provenance[-1]["params"] == b.provenance[-1]["params"]
    assert not np.array_equal(a.data, field.draw(8).data)
    assert a.profile.gsd_m == pytest.approx(target.gsd_m)


def test_draws_refuse_frames_they_cannot_reproduce(scene, target):
    with pytest.raises(MetrawError, match="frame offset"):
        build_field(scene, dataclasses.replace(target, frame_offset_m=(1.0, 0.0)))
    with pytest.raises(MetrawError, match="along a frame axis"):
        build_field(scene, dataclasses.replace(target, track_angle_rad=0.3))
    with pytest.raises(MetrawError, match="phase"):
        build_field(scene, target).draw(0, a=4 * 2)
