"""Stored .mraw files of format version 3 still decode, bit for bit.

The blobs under tests/fixtures/codec were written by the version-3 encoder (metraw commit e5cee37,
before the throughput work of issue #18; the ``_8lanes`` and ``_16lanes`` files by those of 2026-11-28, 8 and 16 rANS
lanes) from the images
``fixture_images`` regenerates
deterministically; FIXTURES holds the SHA-256 of each blob and of its decoded pixels. An encoder
change may change the bytes it writes (these tests do not encode), but every decoder must read
these files to the same pixels. Files of a new format version get new names beside these; these
are never rewritten. ``python tests/test_codec_format.py --write`` writes missing files only.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

from metraw import codec
from metraw.codec import container, prepare
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

HERE = Path(__file__).resolve().parent / "fixtures" / "codec"

#: name -> (step, sha256 of the blob, sha256 of the decoded uint16 pixels, C order)
FIXTURES = {
    "v3_rggb_64x48_q1.mraw": (1.0, "aae6402926445770654ff285335bc6400fe66f1c0341887a7dafd43b53b97558",
                              "6624bfd6eeb2ce2dd687bb0523b5147edc45c4b8cf417142b1acfc493ae86433"),
    "v3_mono_300x440_q2.mraw": (2.0, "0b22940663ce97a9bc8e4a53d8141ad7c1d0fb161adc777df0990ce4f594fe7f",
                                "5e0abf6dab865bfe8a408925dcd2c6d51cf991320cc1aee07995ada3b5486fa6"),
    "v3_mono_300x440_q2_8lanes.mraw": (2.0, "638d98f12dfb027a2ea53007772b4c5b0fd1a35653a1682e889792bd02a385c0",
                                       "5e0abf6dab865bfe8a408925dcd2c6d51cf991320cc1aee07995ada3b5486fa6"),
    "v3_mono_300x440_q2_16lanes.mraw": (2.0, "03c778893bf3d9dd330a16a351d6d97d5a2d1caa3b676cca3e27cbeb37bc5a98",
                                        "5e0abf6dab865bfe8a408925dcd2c6d51cf991320cc1aee07995ada3b5486fa6"),
}


def fixture_images() -> dict[str, RawImage]:
    """The images behind the fixtures (deterministic: seeded sensor model, no randomness elsewhere)."""
    prof = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100.0, read_noise_e=3.0, white_level_dn=16000.0,
                              adc_bits=14, cfa_pattern="RGGB")
    yy, xx = np.mgrid[0:48, 0:64]
    small = RawImage(expose(50 + 20000 * (0.5 + 0.5 * np.sin(xx / 9.0) * np.cos(yy / 7.0)), prof, rng_from_seed(11)), prof)
    mono = prof.replace(cfa_pattern="mono")
    yy, xx = np.mgrid[0:300, 0:440]
    mean = 40 + 9000 * (0.5 + 0.5 * np.sin(xx / 31.0) * np.cos(yy / 23.0)) + 3000 * (np.hypot(yy - 150, xx - 220) < 20)
    data = expose(mean, mono, rng_from_seed(12))
    data[5, 7:40] = 16000            # saturated run: escapes
    data[290, 100:110] = 0           # below the transform's domain: escapes
    # the same mono image again from the encoders of 2026-11-28 (8, then 16 rANS lanes; format version 3 as before)
    return {"v3_rggb_64x48_q1.mraw": small, "v3_mono_300x440_q2.mraw": RawImage(data, mono),
            "v3_mono_300x440_q2_8lanes.mraw": RawImage(data, mono),
            "v3_mono_300x440_q2_16lanes.mraw": RawImage(data, mono)}


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


@pytest.mark.parametrize("loop", [f"{path}, {how}" for path in ("avx512", "avx2", "portable")
                                  for how in ("two vectors", "8-row halves")] + ["numba"])
@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_stored_version3_blob_decodes_bit_exact(name, loop, monkeypatch):
    from metraw.codec import native

    path, _, how = loop.partition(", ")
    if path != "numba" and path not in native.AVAILABLE:
        pytest.skip(f"the {path} codec path is not built or not run by this CPU")
    monkeypatch.setattr(native, "TWO_VECTORS", how == "two vectors")   # how a compiled path runs 16 lanes
    with native.path_in_use(path):
        _check_fixture(name)


def _check_fixture(name):
    step, blob_sha, pix_sha = FIXTURES[name]
    blob = (HERE / name).read_bytes()
    assert _sha(blob) == blob_sha, "the stored fixture changed: fixtures are never rewritten"
    assert blob[4] == 3 and codec.read_header(blob).step == step
    dec = codec.decode(blob)
    assert _sha(np.ascontiguousarray(dec.data, "<u2").tobytes()) == pix_sha
    img = fixture_images()[name]
    assert dec.profile == img.profile
    err = np.abs(dec.data.astype(np.float64) - img.data)
    assert np.all(err <= prepare.error_bound_dn(img.data, img.profile, step) + 1e-9)


def test_fixtures_cover_both_section_layouts():
    """One fixture codes its tile with a shared model (small tiles), the others per-plane models in
    4 (before 2026-11-28), 8 and 16 rANS lanes on 2 row tiles, with escapes."""
    from metraw.codec import predictive

    for name, lanes in (("v3_mono_300x440_q2.mraw", 4), ("v3_mono_300x440_q2_8lanes.mraw", 8),
                        ("v3_mono_300x440_q2_16lanes.mraw", 16)):
        hdr, secs = container.unpack((HERE / name).read_bytes())
        assert len(hdr.tiles) == 2 and len(secs[-1]) > 0
        assert all(predictive._HEAD.unpack_from(s, 0)[3:5] == (0, lanes) for s in secs[:-1])
    hdr, secs = container.unpack((HERE / "v3_rggb_64x48_q1.mraw").read_bytes())
    assert predictive._HEAD.unpack_from(secs[0], 0)[3:5] == (1, 1)


def _write() -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    for name, img in fixture_images().items():
        path = HERE / name
        if path.exists():
            print(f"{path} exists: left as it is")
        else:
            path.write_bytes(codec.encode(img, FIXTURES[name][0], seed=7, check_profile=False))
        blob = path.read_bytes()
        dec = codec.decode(blob)
        print(f'    "{name}": ({FIXTURES[name][0]}, "{_sha(blob)}",\n        "{_sha(np.ascontiguousarray(dec.data, "<u2").tobytes())}"),')


if __name__ == "__main__" and "--write" in sys.argv[1:]:
    _write()
