"""Bad inputs to `metraw ingest` / `metraw info`: one clear error line, exit status 2, nothing left behind."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from metraw.cli import main


def _png(path, rgb):
    import imagecodecs

    path.write_bytes(imagecodecs.png_encode(np.ascontiguousarray(rgb)))


def _raw_meta(**fields):
    """`--meta KEY=VALUE` arguments for a headerless raw (complete unless a field is overridden)."""
    base = dict(width=4, height=4, dtype="uint16", cfa_pattern="RGGB", black_level_dn=0, adc_bits=12)
    base.update(fields)
    return [a for k, v in base.items() for a in ("--meta", f"{k}={v}")]


def _ingest_fails(tmp_path, capsys, inputs, *extra):
    """Run `metraw ingest`, expect exit 2 with one error line and no output; return the message."""
    out = tmp_path / "out" / "store.zarr"
    rc = main(["ingest", *map(str, inputs), "--out", str(out), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("metraw ingest: error: "), err
    assert not out.exists()
    leftovers = list(out.parent.iterdir()) if out.parent.exists() else []
    assert leftovers == [], leftovers  # no temporary .partial directories either
    return lines[0]


def test_corrupt_png(tmp_path, capsys):
    bad = tmp_path / "a.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50)
    assert "corrupt or truncated image" in _ingest_fails(tmp_path, capsys, [bad])


def test_decoder_message_with_control_bytes_stays_one_line(tmp_path, capsys, monkeypatch):
    """A decoder whose message echoes damaged bytes (line breaks, control characters; seen from libpng on a
    corrupt PNG) still gives one printable error line."""
    import imagecodecs

    def broken(data):
        raise RuntimeError("bad chunk (p\x13H\n\x0e\x7f)")

    monkeypatch.setattr(imagecodecs, "png_decode", broken)
    bad = tmp_path / "a.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50)
    line = _ingest_fails(tmp_path, capsys, [bad])
    assert line.isprintable() and line.endswith("corrupt or truncated image (bad chunk (p H ))")


def test_corrupt_tiff(tmp_path, capsys):
    bad = tmp_path / "a.tif"
    bad.write_bytes(b"II*\x00" + b"\xff" * 64)
    assert "corrupt or truncated TIFF" in _ingest_fails(tmp_path, capsys, [bad])


def test_truncated_tiff(tmp_path, capsys):
    good = tmp_path / "full.tif"
    tifffile.imwrite(good, np.arange(200 * 300, dtype=np.uint16).reshape(200, 300), metadata=None)
    cut = tmp_path / "cut.tif"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    good.unlink()
    assert "truncated" in _ingest_fails(tmp_path, capsys, [cut])


def test_truncated_dng(tmp_path, capsys, real_data_dir):
    data = (real_data_dir / "canon_dng" / "colorchart.dng").read_bytes()
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[: len(data) // 2])
    assert "corrupt or truncated camera raw" in _ingest_fails(tmp_path, capsys, [cut])


def test_truncated_png(tmp_path, capsys):
    full = tmp_path / "full.png"
    _png(full, np.random.default_rng(0).integers(0, 256, (64, 64, 3)).astype(np.uint8))
    cut = tmp_path / "cut.png"
    cut.write_bytes(full.read_bytes()[:400])
    full.unlink()
    assert "corrupt or truncated image" in _ingest_fails(tmp_path, capsys, [cut])


def test_unsupported_format(tmp_path, capsys):
    bad = tmp_path / "notes.xyz"
    bad.write_text("this is not an image\n" * 20)
    assert "unsupported format" in _ingest_fails(tmp_path, capsys, [bad])


def test_nan_in_float_data(tmp_path, capsys):
    a = np.full((16, 16), 100.0, np.float32)
    a[3, 4] = np.nan
    bad = tmp_path / "nan.tif"
    tifffile.imwrite(bad, a, metadata=None)
    assert "1 NaN/inf values" in _ingest_fails(tmp_path, capsys, [bad])


def test_wrong_dtype_tiff(tmp_path, capsys):
    bad = tmp_path / "big.tif"
    tifffile.imwrite(bad, np.full((8, 8), 70000, np.uint32), metadata=None)
    assert "do not fit unsigned 16-bit DN" in _ingest_fails(tmp_path, capsys, [bad])


def test_wrong_dtype_headerless(tmp_path, capsys):
    bad = tmp_path / "c.raw"
    bad.write_bytes(np.zeros(16, np.complex64).tobytes())
    msg = _ingest_fails(tmp_path, capsys, [bad], *_raw_meta(dtype="complex64"))
    assert "is not a raw pixel type" in msg


def test_headerless_missing_metadata(tmp_path, capsys):
    bad = tmp_path / "a.raw"
    bad.write_bytes(np.zeros(64, np.uint16).tobytes())
    msg = _ingest_fails(tmp_path, capsys, [bad], "--meta", "dtype=uint16")
    assert "needs metadata: width, height, cfa_pattern, black_level_dn, adc_bits or white_level_dn missing" in msg


def test_headerless_size_mismatch(tmp_path, capsys):
    bad = tmp_path / "a.raw"
    bad.write_bytes(np.zeros(60, np.uint16).tobytes())
    msg = _ingest_fails(tmp_path, capsys, [bad], *_raw_meta(width=8, height=8))
    assert "file has 120 bytes but 8 x 8 uint16 pixels + 0 header bytes need 128 (truncated)" in msg


@pytest.mark.parametrize("line, match", [
    ("0 0.5 0.5 0.1", "need 'class cx cy w h', got 4 fields"),
    ("car 0.5 0.5 0.1 0.1", "non-numeric field"),
    ("0 1.5 0.5 0.1 0.1", "outside the normalised range"),
    ("9 0.5 0.5 0.1 0.1", "class ids [9] not in the 5 class names"),
])
def test_malformed_yolo(tmp_path, capsys, line, match):
    _png(tmp_path / "im.png", np.full((8, 8, 3), 90, np.uint8))
    (tmp_path / "aerial.names").write_text("car\ntruck\nbus\nminibus\ncyclist\n")
    (tmp_path / "im.txt").write_text("0 0.5 0.5 0.2 0.2\n" + line + "\n")
    assert match in _ingest_fails(tmp_path, capsys, [tmp_path], "--labels", "yolo")


def test_yolo_without_class_names(tmp_path, capsys):
    _png(tmp_path / "im.png", np.full((8, 8, 3), 90, np.uint8))
    (tmp_path / "im.txt").write_text("0 0.5 0.5 0.2 0.2\n")
    assert "YOLO labels need class names" in _ingest_fails(tmp_path, capsys, [tmp_path])


def test_mask_of_wrong_shape(tmp_path, capsys):
    _png(tmp_path / "im.png", np.full((8, 8, 3), 90, np.uint8))
    _png(tmp_path / "im_mask.png", np.zeros((8, 9), np.uint8))
    assert "mask shape (8, 9) differs" in _ingest_fails(tmp_path, capsys, [tmp_path / "im.png"], "--labels", "mask")


def test_failure_after_good_images_leaves_nothing(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    for i in range(3):
        _png(src / f"ok{i}.png", np.full((8, 8, 3), 40 * i, np.uint8))
    (src / "z_bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 30)
    assert "z_bad.png: corrupt or truncated image" in _ingest_fails(tmp_path, capsys, [src])


def test_existing_output_is_kept(tmp_path, capsys):
    _png(tmp_path / "im.png", np.full((8, 8, 3), 90, np.uint8))
    out = tmp_path / "store.zarr"
    out.mkdir()
    (out / "keep").write_text("x")
    rc = main(["ingest", str(tmp_path / "im.png"), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"metraw ingest: error: output {out} already exists (use --overwrite to replace it)"
    assert (out / "keep").read_text() == "x"


@pytest.mark.parametrize("text, match", [("source: {camera: {cfa_pattern: RGGB\n", "is not valid YAML"),
                                          ("source: {}\n", "no readable source.camera"),
                                          ("[1, 2]\n", "no readable source.camera")])
def test_camera_params_file_without_a_camera(tmp_path, capsys, text, match):
    """``--camera params.yaml`` that is not YAML, or has no source.camera: one line naming the file."""
    (tmp_path / "cam.yaml").write_text(text)
    tifffile.imwrite(tmp_path / "a.tif", np.zeros((8, 8), np.uint16))
    line = _ingest_fails(tmp_path, capsys, [tmp_path / "a.tif"], "--camera", str(tmp_path / "cam.yaml"))
    assert match in line and "cam.yaml" in line


def test_missing_input(tmp_path, capsys):
    assert "no such file or directory" in _ingest_fails(tmp_path, capsys, [tmp_path / "nope.dng"])


def test_info_on_corrupt_file(tmp_path, capsys):
    bad = tmp_path / "a.dng"
    bad.write_bytes(b"not a raw file at all" * 10)
    rc = main(["info", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("metraw info: error: ") and "unsupported format" in err
    assert len(err.splitlines()) == 1


def test_ingest_then_info_succeeds(tmp_path, capsys):
    (tmp_path / "aerial.names").write_text("car\ncyclist\n")
    _png(tmp_path / "im.png", np.full((10, 12, 3), 90, np.uint8))
    (tmp_path / "im.txt").write_text("0 0.5 0.5 0.5 0.4\n1 0.2 0.2 0.1 0.1\n")
    out = tmp_path / "s.zarr"
    assert main(["ingest", str(tmp_path), "--out", str(out), "--gsd-m", "0.13"]) == 0
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "images: 1" in text and "approximate_images: 1" in text and "car_boxes=1" in text
