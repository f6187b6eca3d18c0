"""The compiled codec loops (metraw.codec.native: C, one extension with AVX-512, AVX2 and portable paths chosen at
run time) against the numba loops: same bytes and values, on every compiled path this host runs (``native.AVAILABLE``).

Both loops decode the same streams; the compiled one takes streams of 8 or 16 lanes. The cases cover the steady
part's edges (plane widths around the first steady column 3 (L - 1) + 1, heights that leave a short last group),
Bayer and mono, steps 0.5 / 1 / 2, 8-bit and 16-bit symbol tables, escapes, and corrupt streams. Skipped only where
the extension is not built.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from metraw import codec
from metraw.codec import native, predictive
from metraw.errors import MetrawError
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

@pytest.fixture(params=native.AVAILABLE or ("none",))
def compiled(request):
    """Each compiled path this host runs, in turn (the test runs once per path)."""
    if request.param == "none":
        pytest.skip("compiled codec loops not built")
    with native.path_in_use(request.param):
        yield request.param


needs_native = pytest.mark.usefixtures("compiled")

PROF = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100, read_noise_e=3, white_level_dn=16000, adc_bits=14)


def _decode_both(blob, monkeypatch):
    """(compiled, numba) decodes of ``blob``, and the symbol-table dtypes the compiled loop was given."""
    seen = []

    def spy(fn):
        def call(*args):
            seen.append(args[7].dtype)   # lut
            return fn(*args)
        return call

    with monkeypatch.context() as m:
        m.setattr(native, "decode_plane", spy(native.decode_plane))
        m.setattr(native, "decode_plane_dn", spy(native.decode_plane_dn))
        got = codec.decode(blob).data
    with monkeypatch.context() as m:
        m.setattr(native, "LIB", None)
        ref = codec.decode(blob).data
    return got, ref, seen


def _image(h, w, pattern, electrons, seed):
    prof = PROF.replace(cfa_pattern=pattern)
    yy, xx = np.mgrid[0:h, 0:w]
    mean = electrons * (0.6 + 0.4 * np.sin(xx / 9.0) * np.cos(yy / 7.0))
    return RawImage(expose(mean, prof, rng_from_seed(seed)), prof)


@needs_native
@pytest.mark.parametrize("lanes, two_vectors", [(8, True), (16, True), (16, False)])
@pytest.mark.parametrize("pattern", ["RGGB", "mono"])
def test_compiled_loop_decodes_what_the_numba_loop_decodes(lanes, two_vectors, pattern, monkeypatch):
    """16-lane groups both ways the compiled loop runs them: two vectors side by side, and two groups of 8 rows."""
    monkeypatch.setattr(predictive, "LANES", lanes)
    monkeypatch.setattr(native, "TWO_VECTORS", two_vectors)
    cell = 2 if pattern == "RGGB" else 1
    first_steady = 3 * (lanes - 1) + 1
    # plane widths: below, at and just past the steady part's first column; heights: full groups and a short one
    widths = [first_steady, first_steady + 1, first_steady + 2, first_steady + 3, 301]
    dtypes = []
    for k, wp in enumerate(widths):
        # >= 2^16 pixels in each of the frame's 2 row tiles: lanes, not a shared model; a short last row group
        hp = max(-(-(1 << 17) // wp), 8 * lanes) + 3
        img = _image(hp * cell, wp * cell, pattern, (40.0, 20000.0)[k % 2], seed=k)
        for step in (0.5, 1.0, 2.0):
            blob = codec.encode(img, step=step, check_profile=False)
            got, ref, seen = _decode_both(blob, monkeypatch)
            np.testing.assert_array_equal(got, ref)
            assert seen, f"width {wp}: the compiled loop did not run"   # not the numba loop twice
            dtypes += seen
    assert np.dtype(np.uint8) in dtypes   # 8-bit tables


def _lane_escapes(blob: bytes) -> int:
    """Escapes a section's lanes hold (header: per lane u32 state, varint words, varint escapes)."""
    from metraw.codec.container import get_varint

    mv = memoryview(blob)
    off, total = predictive._HEAD.size, 0
    for _ in range(blob[4]):
        _, off = get_varint(mv, off + 4)
        n, off = get_varint(mv, off)
        total += n
    return total


def _decode_planes_both(blob, us, monkeypatch):
    """(compiled, numba) ``predictive.decode_planes`` of ``blob``."""
    out = [predictive.decode_planes(blob, us)]
    with monkeypatch.context() as m:
        m.setattr(native, "LIB", None)
        out.append(predictive.decode_planes(blob, us))
    return out


@needs_native
def test_compiled_decoder_runs_in_a_row_groups_buffer(monkeypatch):
    """The compiled loop decodes each row group into the buffer's rows 2 .. and moves the group's last two rows up: a
    buffer of exactly a group's rows + 2 gives the symbols of a plane-size one (the numba loop's), a row fewer is
    refused, and the rows past a group's are never touched (a plane-size buffer's rows beyond stay as they were).
    Decoding to DN a row group at a time (``decode_planes_dn``: the dither made and the DN put out per group) gives
    the DN of the plane's symbols."""
    from metraw.codec import container, decoder, prepare

    calls = []
    original = native.decode_plane

    def spy(*args):
        calls.append([a.copy() if isinstance(a, np.ndarray) else a for a in args])
        return original(*args)

    # 2 row tiles of 2^17 pixels (lanes, not a shared model), planes of 203 rows: 12 groups of 16 and a short one
    img = _image(4 * 203, 2 * 161, "RGGB", 3000.0, seed=3)
    blob = codec.encode(img, 1.0, check_profile=False)
    header, sections = container.unpack(blob)
    (r0, r1), w = header.tiles[0], img.data.shape[1]
    keys, inv = prepare.dither_keys(0), prepare.inverse_args(img.profile, 1.0)
    grid = [(dy, dx) for dy in (0, 1) for dx in (0, 1)]
    dithers = [native.dither_fixed(*keys, (r0 + dy) * w + dx, (r1 - r0 - dy + 1) // 2, w // 2, 2 * w, 2)
               for dy, dx in grid]
    with monkeypatch.context() as m:
        m.setattr(native, "decode_plane", spy)
        syms = decoder.decode_planes(sections[0], dithers)
    p, u, sym = calls[0][:3]
    lanes = calls[0][11].size
    assert p.shape[0] == min(u.shape[0], lanes) + 2 < u.shape[0]   # the decoder allocates a group's buffer
    results = []
    for rows in (p.shape[0], u.shape[0] + 2):
        args = [a.copy() if isinstance(a, np.ndarray) else a for a in calls[0]]
        big = np.full((rows, p.shape[1]), 123456789, np.int64)
        big[:3] = p[:3]
        args[0] = big
        assert original(*args)
        results.append(args[2])
        if rows > p.shape[0]:
            assert np.all(big[p.shape[0]:] == 123456789)
    assert np.array_equal(results[0], results[1]) and np.array_equal(results[0], syms[0])
    args = [a.copy() if isinstance(a, np.ndarray) else a for a in calls[0]]
    args[0] = args[0][:-1]
    with pytest.raises(ValueError, match="row group"):
        original(*args)
    frame = np.full(img.data.shape, 7777, np.uint16)
    ref = frame.copy()
    for (dy, dx), s in zip(grid, syms):
        native.inverse_dn(s, keys, (r0 + dy) * w + dx, 2 * w, 2, *inv, ref[r0 + dy:r1:2, dx::2])
    decoder.decode_planes_dn(sections[0], [decoder.PlaneDN(keys, (r0 + dy) * w + dx, 2 * w, 2, inv,
                                                           frame[r0 + dy:r1:2, dx::2]) for dy, dx in grid])
    assert np.array_equal(frame, ref) and np.all(frame[r1:] == 7777)


@needs_native
@pytest.mark.parametrize("lanes", [8, 16])
@pytest.mark.parametrize("pattern", ["RGGB", "mono"])
def test_compiled_encoder_passes_write_the_numba_encoders_bytes(pattern, lanes, monkeypatch):
    """The encoder with the compiled residual and rANS passes and with numba's: the same stream, byte for byte
    (plane widths that leave a partial last vector of 8, heights that leave lanes of unequal length, faint and
    bright, with escapes and 16-bit tables; the rANS pass's lanes 8 or 16 at a time)."""
    monkeypatch.setattr(predictive, "LANES", lanes)
    rng = np.random.default_rng(2)
    cases = [_image(130, 2 * 77 + 2, pattern, 40.0, seed=1), _image(520, 526, pattern, 20000.0, seed=2)]
    spiky = expose(np.full((520, 520), 2000.0), PROF, rng_from_seed(1))
    spiky[rng.random(spiky.shape) < 0.01] = 15000
    cases.append(RawImage(spiky, PROF.replace(cfa_pattern=pattern)))
    for img, step in zip(cases, (1.0, 2.0, 0.5)):
        compiled = codec.encode(img, step=step, check_profile=False)
        with monkeypatch.context() as m:
            m.setattr(native, "LIB", None)
            assert codec.encode(img, step=step, check_profile=False) == compiled


@needs_native
def test_escape_index_is_the_escape_masks_flat_indices():
    """The compiled escape index gives ``np.flatnonzero(prepare.escape_mask)`` + offset: DN at and beside both bounds
    (a white level that is not an integer, a domain bound below 0 and one above), lengths that are not a multiple of
    the 256-DN blocks, no escapes, a few, and more than the first buffer holds."""
    from metraw.codec import prepare

    rng = np.random.default_rng(21)
    for white, black, n, share in [(16000.0, 100.0, 1, 0.5), (15999.5, 100.0, 1000, 0.01), (16000.0, 0.0, 70001, 0.0),
                                   (4095.0, 200.0, 70001, 0.003), (65535.0, 4000.0, 513, 0.2)]:
        prof = PROF.replace(white_level_dn=white, black_level_dn=black)
        low = prof.black_level_dn - prof.gain_dn_per_e * prepare.offset_e(prof)
        data = rng.integers(max(int(low) + 2, 0), int(white) - 1, n).astype(np.uint16)
        k = int(share * n)
        places = rng.choice(n, k, replace=False)
        edges = np.array([int(np.ceil(white)), int(np.ceil(white)) - 1, max(int(np.floor(low)), 0),
                          max(int(np.floor(low)) + 1, 0), 0, 65535], np.uint16)
        data[places] = rng.choice(edges, k)
        offset = int(rng.integers(0, 2**40))
        ref = np.flatnonzero(prepare.escape_mask(data, prof)) + offset
        got = prepare.escape_index(data, prof, offset)
        assert got.dtype == np.int64 and np.array_equal(got, ref), (white, n)
    assert k > 64 and ref.size > 64   # the last case overflows the first buffer


@needs_native
def test_compiled_dither_and_transform_give_numbas_values():
    """The dither (16 pixels a vector, 32-bit lanes = numba's index arithmetic mod 2^32, starts past 2^32 too) and
    the forward transform (contiguous rows and CFA-plane strides, row tails, the last row read element by element,
    values clamped below black and at white) against the numba kernels, exactly."""
    from metraw.codec import prepare

    for start, rows, cols, row_step, col_step in [(0, 3, 1, 1, 1), (7, 5, 17, 40, 2), (2**32 - 5, 4, 33, 70, 1),
                                                  (123456789, 9, 64, 128, 2)]:
        args = (0x12345678, 0x9ABCDEF0, start, rows, cols, row_step, col_step)
        np.testing.assert_array_equal(native.dither_grid(*args), prepare._dither_grid_kernel(*args))
    rng = np.random.default_rng(4)
    prof = PROF
    for shape in [(6, 37), (5, 64), (1, 3)]:
        tile = rng.integers(0, 16384, (2 * shape[0], 2 * shape[1])).astype(np.uint16)
        tile[0, :6] = [0, 1, 16000, 16383, 100, 99]   # below black, at and past white
        for plane in (tile, tile[::2, ::2], tile[1::2, 1::2], tile[1::2, ::2]):
            u = rng.uniform(-0.5, 0.5, plane.shape)
            for step in (0.5, 1.0, 2.0):
                k = prof.gain_dn_per_e
                args = (float(prof.black_level_dn), 1.0 / k, prepare.offset_e(prof),
                        (prof.white_level_dn - prof.black_level_dn) / k + prepare.offset_e(prof), 1.0 / step)
                np.testing.assert_array_equal(native.forward(plane, *args, u), prepare._forward_kernel(plane, *args, u))


@needs_native
def test_compiled_causal_buffer_is_numbas():
    """The encoder's padded causal buffer (rows above, left and right padding, s 2^16 - floor(u 2^16)) against
    numba's ``_front``, exactly: widths with a partial last vector, negative symbols, dither at -1/2 and just
    below 1/2."""
    rng = np.random.default_rng(6)
    for h, w in [(1, 1), (3, 9), (17, 64), (40, 77)]:
        s = rng.integers(-300, 70000, (h, w)).astype(np.int32)
        u = rng.uniform(-0.5, 0.5, (h, w))
        u.flat[0] = -0.5
        u.flat[-1] = np.nextafter(0.5, 0.0)
        c0 = int(predictive._mean_symbol(s))
        np.testing.assert_array_equal(native.front(s, u, c0), predictive._front(s, u, np.int64(c0) << 16))


@needs_native
def test_compiled_residual_pass_is_numbas_beyond_int32():
    """The residual pass against numba's where the buffer's values or the coefficients leave int32 (the AVX2 path
    multiplies int32 neighbours by one 32-bit multiply, other rows by the exact 64-bit sums): rows of large values
    between ordinary ones, coefficients or a bias beyond 2^31, partial last vectors."""
    from metraw.codec.decoder import predictor_table

    rng = np.random.default_rng(11)
    for h, w, big_coef in [(9, 13, False), (12, 37, False), (7, 20, True), (8, 21, "bias")]:
        s = rng.integers(-300, 3000, (h, w)).astype(np.int32)
        u = rng.uniform(-0.5, 0.5, (h, w))
        p = predictive._front(s, u, np.int64(int(predictive._mean_symbol(s))) << 16)
        p[5, 3:9] += np.int64(1) << 40           # rows 3-5 of the plane see them
        p[8, w // 2] = -(np.int64(1) << 31) - 1   # just below int32
        p[3, 2::2] = (1 << 31) - 7                # int32s whose differences are not (32-bit absolute differences)
        p[3, 3::2] = -(1 << 31) + 9
        thr = np.sort(rng.integers(0, 1 << 20, 3)).astype(np.int64)
        if w % 2:   # contexts that tell huge activities apart
            thr = np.array([1 << 20, (1 << 31) + 5, 1 << 33], np.int64)
        coef = rng.integers(-3000, 3000, (4, 11)).astype(np.int64)
        if big_coef is True:
            coef[2, 4] = (1 << 33) + 5
        bias = rng.integers(-1000, 1000, 4).astype(np.int64)
        if big_coef == "bias":
            bias[1:] = -(1 << 35) - 3   # the contexts these activities reach
        got = [np.zeros(h * w + 3, np.int32) for _ in range(2)]
        ref = [np.zeros(h * w + 3, np.int32) for _ in range(2)]
        mg = native.residuals(p, thr, predictor_table(coef, bias), 5, 1, *got, 3)
        mr = predictive._residuals(p, thr, coef.ravel(), bias, 5, 1, *ref, 3)
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])
        assert mg == mr


@needs_native
def test_compiled_plane_buffer_is_dither_forward_and_front(monkeypatch):
    """The encoder's one-pass plane buffer (dither, forward transform and causal buffer from the DN) against the three
    steps in numba (``_dither_grid_kernel``, ``_forward_kernel``, ``_front_c0``), exactly: CFA cells of 1 to 4 pixels
    (contiguous rows, the 32-bit load of 2-pixel cells, the scalar path), planes ending at the array's end (nothing
    read past it), widths with partial vectors, dither starts past 2^32, steps 0.5 / 1 / 2, DN below black and at or
    past white. And ``codec.encode`` writes the same bytes with it as without it."""
    from metraw.codec import prepare

    rng = np.random.default_rng(12)
    for trial in range(120):
        h, w = (int(v) for v in rng.integers(1, 40, 2))
        cell = int(rng.integers(1, 5))
        frame = rng.integers(0, 17000, (h * cell + int(rng.integers(0, 3)), w * cell + int(rng.integers(0, 3))))
        frame = frame.astype(np.uint16)
        frame.flat[:4] = [0, 99, 16000, 16999]
        dy, dx = (int(v) for v in rng.integers(0, cell, 2))
        plane = frame[dy::cell, dx::cell] if trial % 2 else frame[dy::cell, dx::cell][:h, :w]
        seed, start, step = int(rng.integers(0, 2**62)), int(rng.integers(0, 2**34)), float(rng.choice([0.5, 1, 2]))
        keys, args = prepare.dither_keys(seed), prepare.forward_args(PROF, step)
        u = prepare._dither_grid_kernel(*keys, start, *plane.shape, cell * frame.shape[1], cell)
        front, c0 = predictive._front_c0(prepare._forward_kernel(plane, *args, u), u)
        got, got_c0 = native.plane_buffer(plane, keys, start, cell * frame.shape[1], cell, args)
        np.testing.assert_array_equal(got, front)
        assert got_c0 == c0
    img = _image(300, 222, "RGGB", 400, 3)
    calls = []
    compiled = native.plane_buffer
    with monkeypatch.context() as m:
        m.setattr(native, "plane_buffer", lambda *a: calls.append(1) or compiled(*a))
        with_buffer = codec.encode(img, 1.0, 5)
    with monkeypatch.context() as m:   # the buffers from _tile_symbols, as without the compiled plane buffer
        m.setattr(codec, "_tile_buffers", lambda data, r0, r1, profile, step, seed: [
            predictive._causal_buffer(s, u) for _, u, s in codec._tile_symbols(data, r0, r1, profile, step, seed)])
        without = codec.encode(img, 1.0, 5)
    assert len(calls) == 8 and with_buffer == without   # 2 row tiles x 4 planes
    flipped = RawImage(img.data[::-1, ::-1], img.profile)   # negative strides: the buffers from _tile_symbols
    assert codec.encode(flipped, 1.0, 5) == codec.encode(RawImage(img.data[::-1, ::-1].copy(), img.profile), 1.0, 5)


@needs_native
def test_compiled_decoder_dither_and_inverse_are_numbas():
    """The decoder's fixed-point dither (``fixed_dither`` of ``_dither_grid_kernel``) and the inverse transform with
    the dither made on the way (``_inverse_dn_kernel``) against numba, exactly, into CFA planes of a frame with cells
    of 1 to 4 pixels (the merged 32-bit stores of 2-pixel cells, the scalar path): every pixel of the plane written,
    every other pixel of the frame left as it was; symbols far outside the DN range (clipped to 65535)."""
    from metraw.codec import decoder, prepare

    rng = np.random.default_rng(14)
    for trial in range(80):
        h, w = (int(v) for v in rng.integers(1, 45, 2))
        cell = int(rng.integers(1, 5))
        shape = (h * cell + int(rng.integers(0, 3)), w * cell + int(rng.integers(0, 3)))
        dy, dx = (int(v) for v in rng.integers(0, cell, 2))
        seed, start, step = int(rng.integers(0, 2**62)), int(rng.integers(0, 2**34)), float(rng.choice([0.5, 1, 2]))
        keys = prepare.dither_keys(seed)
        frame = np.full(shape, 7777, np.uint16)
        plane = frame[dy::cell, dx::cell]
        u = prepare._dither_grid_kernel(*keys, start, *plane.shape, cell * shape[1], cell)
        np.testing.assert_array_equal(native.dither_fixed(*keys, start, *plane.shape, cell * shape[1], cell),
                                      decoder.fixed_dither(u))
        sym = rng.integers(-50, 3000, plane.shape).astype(np.int32)
        sym.flat[:2] = [-100000, 100000]
        ref = np.empty(plane.shape, np.uint16)
        prepare._inverse_dn_kernel(sym, u, *prepare.inverse_args(PROF, step), ref)
        native.inverse_dn(sym, keys, start, cell * shape[1], cell, *prepare.inverse_args(PROF, step), plane)
        np.testing.assert_array_equal(plane, ref)
        others = np.ones(shape, bool)
        others[dy::cell, dx::cell] = False
        assert np.all(frame[others] == 7777)


@needs_native
def test_compiled_alphabet_indices_and_counts_are_numbas():
    """Alphabet indices (escape past +-amax) and per-table counts against numba's ``_index``: lengths with a partial
    last vector and odd lengths (the two sub-histograms), long runs of one bin, residuals at +-amax and beyond."""
    rng = np.random.default_rng(8)
    for n, amax, ntab in [(1, 1, 1), (17, 3, 2), (1001, 40, 32), (4096, 1023, 8)]:
        r = np.clip(rng.laplace(0, amax / 3, n), -2 * amax - 5, 2 * amax + 5).astype(np.int32)
        r[: n // 4] = amax if n > 8 else r[: n // 4]   # a run of one bin, at the alphabet's edge
        t = rng.integers(0, ntab, n).astype(np.int32)
        idx, counts = native.index(r, t, amax, ntab)
        ref_idx, ref_counts = predictive._index(r, t, amax, ntab)
        np.testing.assert_array_equal(idx, ref_idx)
        np.testing.assert_array_equal(counts, ref_counts)
        out = np.full(n, -12345, np.int32)   # into a given array, whatever it held
        idx_out, counts_out = native.index(r, t, amax, ntab, out)
        assert idx_out is out
        np.testing.assert_array_equal(out, ref_idx)
        np.testing.assert_array_equal(counts_out, ref_counts)
    for bad in (np.empty(n, np.int64), np.empty(n + 1, np.int32), np.empty(2 * n, np.int32)[::2]):
        with pytest.raises(ValueError, match="out must be"):
            native.index(r, t, amax, ntab, bad)


@needs_native
def test_compiled_loop_handles_escapes_and_16_bit_tables(monkeypatch):
    """Residuals beyond the alphabet (escapes, spread over the rows, so most fall in the steady part), rare large
    residuals (16-bit symbol tables) and random high contrast, as in real frames."""
    from metraw.codec import prepare

    rng = np.random.default_rng(0)
    shape = (300, 400)
    u = prepare.dither(3, 0, shape[0] * shape[1]).reshape(shape)
    s = np.rint(800 + rng.normal(0, 3, shape) + u).astype(np.int32)
    s[rng.integers(0, shape[0], 200), rng.integers(0, shape[1], 200)] += 5000
    blob = predictive.encode_planes([(s, u)])
    assert _lane_escapes(blob) >= 150
    got, ref = _decode_planes_both(blob, [u], monkeypatch)
    np.testing.assert_array_equal(got[0], s)
    np.testing.assert_array_equal(ref[0], s)

    spiky = expose(np.full((600, 600), 2000.0), PROF, rng_from_seed(1))
    spiky[rng.random(spiky.shape) < 0.01] = 15000
    contrast = rng.integers(100, 16000, (600, 600)).astype(np.uint16)
    dtypes = set()
    for data in (spiky, contrast):
        for step in (0.5, 2.0):
            blob = codec.encode(RawImage(data, PROF), step=step, check_profile=False)
            got, ref, seen = _decode_both(blob, monkeypatch)
            np.testing.assert_array_equal(got, ref)
            dtypes.update(seen)
    assert np.dtype(np.int16) in dtypes   # alphabets past 256 symbols: the 16-bit gather


@needs_native
def test_compiled_loops_are_exact_where_values_leave_int32(monkeypatch):
    """Symbols past 2^15 (buffer values s 2^16 past int32: the AVX2 path's 32-bit products give way to the exact
    64-bit sums, in the encoder's residual pass row by row and in the decoder's steady part from the step that meets
    one): a bright patch in the middle of ordinary rows, and a plane beyond int32 throughout; the same stream as
    numba's encoder and the planes back from both decoders."""
    from metraw.codec import prepare

    rng = np.random.default_rng(9)
    shape = (300, 400)
    u = prepare.dither(5, 0, shape[0] * shape[1]).reshape(shape)
    base = np.rint(30000 + rng.normal(0, 4, shape) + u).astype(np.int32)
    patch = base.copy()
    patch[120:140, 140:200] += 6000
    for s in (patch, base + 20000):
        blob = predictive.encode_planes([(s, u)])
        with monkeypatch.context() as m:
            m.setattr(native, "LIB", None)
            assert predictive.encode_planes([(s, u)]) == blob
        got, ref = _decode_planes_both(blob, [u], monkeypatch)
        np.testing.assert_array_equal(got[0], s)
        np.testing.assert_array_equal(ref[0], s)


@needs_native
def test_compiled_loop_rejects_corrupt_streams_like_the_numba_loop(monkeypatch):
    """Damaged coded words (a wrong stream with a right CRC, as from a buggy writer): both loops raise the same
    clear error, or decode the same values where the damage goes unseen."""
    from metraw.codec import prepare

    rng = np.random.default_rng(7)
    shape = (259, 257)
    u = prepare.dither(3, 0, shape[0] * shape[1]).reshape(shape)
    s = np.rint(200 + rng.normal(0, 2, shape) + u).astype(np.int32)
    s[rng.integers(0, shape[0], 6), rng.integers(0, shape[1], 6)] += 5000  # escaped residuals
    blob = predictive.encode_planes([(s, u)])
    assert blob[4] == predictive.LANES == 16   # header: nplanes, nact, phase shift, shared, lanes, ...
    errors = 0
    for trial in range(12):
        damaged = bytearray(blob)
        for i in rng.integers(len(blob) // 3, len(blob), 1 + trial % 4):
            damaged[i] ^= int(rng.integers(1, 256))
        outcomes = []   # compiled with a 16-lane group's two vectors side by side, as 8-row halves; numba
        for lib, two_vectors in ((native.LIB, True), (native.LIB, False), (None, False)):
            with monkeypatch.context() as m:
                m.setattr(native, "LIB", lib)
                m.setattr(native, "TWO_VECTORS", two_vectors)
                try:
                    outcomes.append(predictive.decode_planes(bytes(damaged), [u])[0])
                except MetrawError as exc:
                    outcomes.append(str(exc))
        if isinstance(outcomes[0], str):
            assert outcomes[0] == outcomes[1] == outcomes[2]
            errors += 1
        else:
            for other in outcomes[1:]:
                assert not isinstance(other, str)
                np.testing.assert_array_equal(outcomes[0], other)
    assert errors >= 6   # most damage is caught


def _native_in_child(variable: str, value: str, expression: str) -> tuple[str, str]:
    """(stdout, stderr) of a fresh Python with ``variable=value`` that imports ``metraw.codec.native`` and prints
    ``expression`` (warnings always shown)."""
    import subprocess
    import sys

    code = f"from metraw.codec import native; print({expression})"
    out = subprocess.run([sys.executable, "-W", "always", "-c", code], env=dict(os.environ, **{variable: value}),
                         capture_output=True, text=True, check=True)
    return out.stdout.strip(), out.stderr


def test_environment_chooses_the_path():
    """METRAW_NATIVE=0: the codec runs its numba loops (for comparisons and for a suspected fault); a path's name: that
    path; unset or auto: the best this host runs; a path the host lacks: a warning and the best."""
    def run(value):
        out, err = _native_in_child("METRAW_NATIVE", value, "native.PATH, native.LIB is None")
        return out.split(), err

    assert run("0")[0] == ["numba", "True"]
    best = native.auto_path(native.AVAILABLE)
    assert run("auto")[0][0] == best and run("")[0][0] == best
    for path in native.AVAILABLE:
        assert run(path)[0] == [path, "False"]
    for path in set(native.PATHS) - set(native.AVAILABLE):
        got, err = run(path)
        assert got[0] == best and "not a path this build" in err


def test_environment_chooses_the_16_lane_mode(monkeypatch):
    """METRAW_TWO_VECTORS=1 / 0: the compiled decoder runs a 16-lane group as two vectors side by side / as two 8-row
    groups (to time both on one host); unset or auto: the CPU's default (two vectors on AMD); anything else: one
    warning and the default. ``native.CPU_TWO_VECTORS``, the CPU's default, stays what it is whatever the variable
    says."""
    def run(value):
        out, err = _native_in_child("METRAW_TWO_VECTORS", value, "native.TWO_VECTORS, native.CPU_TWO_VECTORS")
        return out.split(), err

    monkeypatch.delenv("METRAW_TWO_VECTORS", raising=False)
    default = str(native.CPU_TWO_VECTORS)
    assert default == str(native._two_vectors(native.CPU_TWO_VECTORS)) == str(native._cpu_two_vectors(native._LIB))
    assert run("1")[0] == ["True", default] and run("0")[0] == ["False", default]
    assert run("")[0] == [default, default] and run("auto")[0] == [default, default]
    got, err = run("yes")
    assert got == [default, default] and "METRAW_TWO_VECTORS=yes" in err


def test_the_lane_modes_benchmark_names_the_faster_mode_against_the_cpus_default():
    """``--lane-modes``'s verdict: the median over the frames of two vectors / 8-row halves decode CPU; within 2 % of 1
    the same speed (the default stands), else the faster mode, and whether the CPU's default already is it."""
    bench = _codec_benchmark()
    same = bench.lane_modes_verdict("avx2", {"canon_dng": 0.99, "micasense": 1.01, "spacenet_pan": 0.97}, (30, 63),
                                    False)
    assert same.startswith("# 16-lane modes, path avx2, decode CPU two vectors / 8-row halves: canon_dng 0.990, ")
    assert "(median 0.990; two vectors took less CPU in 30 of 63 paired samples)" in same
    assert same.endswith("the same within 2%: the default (8-row halves) stands")
    two = bench.lane_modes_verdict("avx2", {"canon_dng": 0.90, "micasense": 0.95, "spacenet_pan": 1.0}, (50, 63), False)
    assert two.endswith("two vectors faster by 5.0%: not the default (8-row halves): METRAW_TWO_VECTORS=1 on this "
                        "CPU, and metraw_two_vector_steady to change")
    assert bench.lane_modes_verdict("avx2", {"canon_dng": 0.9}, (21, 21), True).endswith(
        "two vectors faster by 10.0%: the default already")
    halves = bench.lane_modes_verdict("avx512", {"canon_dng": 1.05, "micasense": 1.10}, (3, 42), True)
    assert "(median 1.075;" in halves
    assert "8-row halves faster by 7.5%: not the default (two vectors): METRAW_TWO_VECTORS=0" in halves
    assert bench.lane_modes_verdict("avx2", {}, (0, 0), False) == "# 16-lane modes, path avx2: no data"


def test_auto_selection_picks_only_paths_faster_than_numba():
    """Auto-selection runs the first of ``native.AUTO`` the host has, else numba: a compiled path that is slower than
    the numba loops on its CPU (the portable build anywhere) is never picked unless METRAW_NATIVE names it."""
    assert native.auto_path(("avx512", "avx2", "portable")) == "avx512"
    assert native.auto_path(()) == "numba"
    assert native.auto_path(("portable",)) == "numba"
    assert native.auto_path(("avx2", "portable")) == ("avx2" if "avx2" in native.AUTO else "numba")
    assert set(native.AUTO) <= set(native.PATHS)


def _codec_benchmark():
    """benchmarks/codec.py as a module."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("metraw_codec_benchmark",
                                                  Path(__file__).resolve().parents[1] / "benchmarks" / "codec.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_the_speed_benchmark_states_each_target_with_its_worst_case():
    """``--speed``'s summary line against issue #52's targets: the largest 1-thread CPU ratio (step 1, any frame),
    the smallest 2-thread wall ratio on canon_dng and micasense (steps 1 and 2; spacenet_pan's is not a target) and
    the largest bpp departure, each named, "short" where it misses."""
    bench = _codec_benchmark()
    rows = {("canon_dng", 1.0): (2.416, 3.12, 3.04, 0.55, 0.50), ("canon_dng", 2.0): (1.543, 2.95, 3.15, 0.56, 1.2),
            ("micasense", 1.0): (2.382, 3.62, 3.02, 0.45, 0.58), ("micasense", 2.0): (1.525, 3.90, 3.37, 0.40, 0.5),
            ("spacenet_pan", 1.0): (2.253, 2.40, 2.60, 0.64, 0.61), ("spacenet_pan", 2.0): (1.48, 1.0, 1.0, 2.0, 2.0)}
    line = bench.acceptance("avx2", rows)
    assert line.startswith("# issue #52's targets, path avx2: ")
    assert "step 1: ok (worst 0.64, spacenet_pan step 1 encode)" in line        # step 2's 1.2 and 2.0 not targets
    assert "steps 1 and 2: short (worst 2.95, canon_dng step 2 encode)" in line   # spacenet_pan's 1.0 not a target
    assert "issue's: ok (worst 0.04 %, spacenet_pan)" in line
    rows["micasense", 1.0] = (2.382 * 1.003, 3.1, 3.1, 1.01, 0.5)
    rows["canon_dng", 2.0] = (1.543, 3.0, 3.15, 0.56, 1.2)
    line = bench.acceptance("avx2", rows)
    assert "step 1: short (worst 1.01, micasense step 1 encode)" in line
    assert "steps 1 and 2: ok (worst 3.00, canon_dng step 2 encode)" in line
    assert "issue's: short (worst 0.30 %, micasense)" in line
    assert bench.acceptance("numba", {}).count("no data") == 3


@pytest.mark.skipif(sys.platform != "linux", reason="getrusage's page-fault count, Linux")
def test_the_speed_benchmark_counts_the_page_faults_of_the_calls_it_wraps():
    """``--speed``'s page-fault line: the minor faults of the wrapped calls only (64 fresh 4 KiB pages written: 64
    faults, and no more than a few besides), a mean per call."""
    import mmap

    bench = _codec_benchmark()
    count = bench.FaultCount()

    def touch_64_pages():
        m = mmap.mmap(-1, 64 * mmap.PAGESIZE)   # fresh anonymous pages, under a huge page's 2 MiB
        for k in range(64):
            m[k * mmap.PAGESIZE] = 1
        m.close()

    count.wrap(touch_64_pages)()
    np.zeros(1 << 20).sum()   # not wrapped: not counted
    count.wrap(lambda: None)()
    assert count.calls == 2 and 64 <= count.faults <= 80, count.faults
    assert count.line("avx2").startswith(f"# page faults, path avx2: {count.faults / 2:.0f} a metraw call, ")


def test_paths_give_the_same_bytes_and_values_on_the_benchmark_frames():
    """Every compiled path and numba: the same stream and decoded values on the benchmark's real frames (data/real,
    with the benchmark's fixed profiles, ``REAL_PROFILES`` of benchmarks/codec.py: every frame, whatever calibrate's
    fit does) at steps 1 and 2, and on a synthetic frame where those are absent."""
    from metraw.io import read_raw

    bench = _codec_benchmark()
    images = []
    for rel, fit in bench.REAL_PROFILES.items():
        if (bench.REAL / rel).exists():
            img = read_raw(bench.REAL / rel)
            images.append(RawImage(img.data, img.profile.replace(**fit)))
    images.append(_image(520, 700, "RGGB", 3000.0, seed=5))
    for img in images:
        for step in (1.0, 2.0):
            blobs, decoded = {}, {}
            for path in native.AVAILABLE + ("numba",):
                with native.path_in_use(path):
                    blobs[path] = codec.encode(img, step, 0, check_profile=False)
                    decoded[path] = codec.decode(blobs[path]).data
            ref = blobs["numba"]
            assert all(b == ref for b in blobs.values()), [p for p, b in blobs.items() if b != ref]
            for d in decoded.values():
                np.testing.assert_array_equal(d, decoded["numba"])


def test_the_compiled_loops_are_built_where_a_compiler_is():
    """An install on a machine with a C compiler (as CI's) builds and loads the extension, with the paths the CPU
    reports: a broken build configuration would otherwise only show as a slower codec."""
    import platform
    import shutil
    from pathlib import Path

    cpuinfo = Path("/proc/cpuinfo")
    flags = cpuinfo.read_text().split() if cpuinfo.exists() else []
    if not shutil.which("cc"):
        pytest.skip("no C compiler here: the numba loops are expected")
    assert native._LIB is not None, "metraw.codec._simd was not built or not loaded (pip install -e . builds it)"
    assert "portable" in native.AVAILABLE
    if platform.machine() == "x86_64":
        assert ("avx2" in native.AVAILABLE) == all(f in flags for f in ("avx2", "fma", "bmi2"))
        assert ("avx512" in native.AVAILABLE) == all(f in flags for f in ("avx512f", "avx512dq"))
    if os.environ.get("METRAW_NATIVE", "").strip() not in ("0", "numba"):
        assert native.LIB is not None


@pytest.mark.parametrize("compiler", ["gcc", "clang"])
def test_every_c_file_compiles_with_each_compiler_here(compiler, tmp_path):
    """The extension's C files compile with gcc and with clang (the compilers a user's pip may pick: clang on macOS
    and some Linux set-ups), with the flags pyproject gives, no warning or error; a compiler missing here is skipped.
    clang once refused an AVX-512 rounding mode held in a const variable (it takes only constant expressions), which
    would have left such a user with the numba loops."""
    import shutil
    import subprocess
    import tomllib
    from pathlib import Path

    if not shutil.which(compiler):
        pytest.skip(f"{compiler} is not installed here")
    repo = Path(__file__).resolve().parents[1]
    ext = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]["ext-modules"][0]
    for source in ext["sources"]:
        run = subprocess.run([compiler, *ext["extra-compile-args"], "-Wall", "-Werror", "-c", str(repo / source),
                              "-o", str(tmp_path / "out.o")], capture_output=True, text=True)
        assert run.returncode == 0, f"{compiler} {source}:\n{run.stderr[-2000:]}"


def test_a_library_of_another_interface_version_is_left_unused(monkeypatch):
    """A library built from an older ``_simd.c`` (its interface number differs, or it has none) is not called: one
    warning names the rebuild, and the codec keeps its numba loops."""
    import importlib.util
    import warnings

    if importlib.util.find_spec("metraw.codec._simd") is None:
        pytest.skip("the extension is not built here")
    monkeypatch.delenv("METRAW_NATIVE", raising=False)
    monkeypatch.setattr(native, "ABI", native.ABI + 1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lib, paths = native._open()
    assert lib is None and paths == ()
    assert len(caught) == 1 and "pip install -e ." in str(caught[0].message)


def test_a_library_lacking_a_function_is_left_unused(monkeypatch):
    """A library of the right interface number that lacks a function the code calls (a broken build) is not used: one
    warning, the numba loops, no failed import."""
    import warnings

    class Partial:   # the interface number and nothing else
        pass

    def abi():
        return native.ABI

    lib = Partial()
    lib.metraw_simd_abi = abi
    monkeypatch.delenv("METRAW_NATIVE", raising=False)
    monkeypatch.setattr(native.importlib.util, "find_spec",
                        lambda name: type("Spec", (), {"origin": native.__file__})())
    monkeypatch.setattr(native.ctypes, "CDLL", lambda path: lib)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert native._open() == (None, ())
    assert len(caught) == 1 and "lacks a function" in str(caught[0].message)


