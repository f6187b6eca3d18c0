"""A camera profile as docs/noise-model.md describes it: the page's example, written by hand from its field table
(no schema_version), loads as a user's profile and is what `metraw calibrate --profile` hands the raws recipe; a
frame the single-frame fit refuses names the two other calibrations."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from metraw import calibrate
from metraw.cli import main
from metraw.errors import MetrawError
from metraw.raw.profile import CalibrationProfile, load_profile
from metraw.raw.sensor import expose, rng_from_seed

DOC = Path(__file__).resolve().parents[1] / "docs" / "noise-model.md"


def _example() -> dict:
    blocks = re.findall(r"```json\n(.*?)```", DOC.read_text(), re.S)
    assert len(blocks) == 1, "docs/noise-model.md shows one example profile"
    return json.loads(blocks[0])


def test_the_docs_example_profile_loads_with_every_documented_field(tmp_path):
    example = _example()
    assert "schema_version" not in example  # written from the table: the current schema is meant
    table = re.findall(r"^\| (`.*?) \|", DOC.read_text().split("## The calibration profile")[1].split("##")[0], re.M)
    documented = {name for row in table for name in re.findall(r"`(\w+)`", row)} - {"RGGB", "BGGR", "GRBG", "GBRG",
                                                                                   "mono"}
    assert set(example) <= documented and documented - set(example) <= {"approximate", "approximate_reason",
                                                                        "schema_version"}
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(example))
    profile = load_profile(path)
    assert profile.gain_dn_per_e == 0.5 and profile.read_noise_e == 4.0 and profile.adc_bits == 12
    assert profile.gsd_m == pytest.approx(2.41e-6 * 250.0 / 1.026e-2)
    assert profile.uncertainty == {"gain_dn_per_e": 0.01, "read_noise_e": 0.3}
    assert CalibrationProfile.from_dict(profile.to_dict()) == profile  # and writes back with its schema_version
    out = tmp_path / "calibrated.json"
    assert main(["calibrate", "--profile", str(path), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["gain_dn_per_e"] == 0.5


def test_a_refused_single_frame_names_flats_and_darks_or_a_profile():
    from test_calibrate import BLACK, PROFILE

    h, w = 64, 96  # a small tile: too few smooth blocks
    frame = expose(300 + 3000 * np.mgrid[0:h, 0:w][1] / w, PROFILE, rng_from_seed(7))
    with pytest.raises(MetrawError) as refused:
        calibrate.from_image(frame, black_level_dn=BLACK, cfa_pattern="RGGB")
    message = str(refused.value)
    assert "single-frame fit" in message
    assert message.endswith("; calibrate from flats and darks instead (metraw calibrate --flats F.. --darks D..; "
                            "params.yaml source.raws.calibration.flats, darks) or give a camera profile "
                            "(--profile camera.json; calibration.profile; docs/noise-model.md)")
