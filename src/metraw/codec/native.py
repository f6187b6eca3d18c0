"""The codec's per-pixel loops compiled from C, where they are built and run: the decoder's sequential loop (lanes in
vector registers), the encoder's residual pass (8 pixels of a row at a time) and its rANS pass (8 or 16 lanes at a time),
its causal buffer (from the DN in one pass with the dither and the forward transform, or from the symbols), alphabet
indices, the dither and the forward transform; the decoder's fixed-point dither and its inverse transform (the dither
made on the way).

One extension, ``metraw.codec._simd``, holds every path, chosen at import by what the CPU reports (runtime dispatch,
as numpy and libjpeg-turbo do; ``PATHS`` best first):

- ``avx512``: AVX-512 F and DQ intrinsics (``_simd.c``, ``_simd_prepare.c``);
- ``avx2``: the kernels of ``_simd_vec.h`` (GCC / Clang vector extensions, 4 lanes of 64 bits a register, table
  lookups by element loads, not gather instructions) compiled for AVX2 with FMA and BMI2 (``_simd_avx2.c``, a target
  pragma: no special build flags);
- ``portable``: the same kernels compiled for the build's default target (``_simd_portable.c``: any CPU, ARM
  included);
- ``numba``: no library (not built: no C compiler), the codec's numba loops (``decoder.decode_plane``,
  ``predictive._residuals``, ``predictive._rans_encode``, ``predictive._front``, ``predictive._index``,
  ``prepare._dither_grid_kernel``, ``prepare._forward_kernel``, ``decoder.fixed_dither``,
  ``prepare._inverse_dn_kernel``).

``PATH`` names the path that runs: the first of ``AUTO`` (the paths measured faster than numba) in ``AVAILABLE`` (the
compiled paths this build has and this CPU runs), else numba; or the one ``METRAW_NATIVE`` asks for (``avx512``,
``avx2``, ``portable``, or ``0`` / ``numba``; unset, empty, ``1`` or ``auto``: that first one). ``use(path)`` switches in-process (tests, benchmarks). Every path runs the same arithmetic, so
the streams and decoded values are the same (tests compare them on every path the host has); only the speed differs.
The compiled decoder takes streams of ``LANE_COUNTS`` lanes (today's encoder writes 16); others take the numba loop.
C sources: ``_simd_driver.c`` (the scalar parts and the schedules every path shares), the files above, ``_simd.h``.

The C functions are called through ctypes (which releases the GIL, so tiles decode in parallel threads); they use no
Python API. Arrays are passed by address: the caller keeps them alive, C-contiguous and of the documented dtypes.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib.util
import os
import types
import warnings

import numpy as np

#: Lane counts the compiled steady loop runs (8 lanes = one vector of 8 int64, 16 = two: ``TWO_VECTORS``).
LANE_COUNTS = (8, 16)
#: Bytes the compiled loop may read past the end of the symbol table and of the word array (the AVX-512 path's 32-bit
#: gathers).
READ_PAST_END_BYTES = 4
#: The library's interface version (``metraw_simd_abi`` in ``_simd_driver.c``): raised with any change of its
#: functions.
ABI = 5
#: The compiled paths, best first, and their bits in ``metraw_simd_paths()`` (``_simd.h``).
PATHS = ("avx512", "avx2", "portable")
#: The compiled paths auto-selection may pick, best first: those measured faster than the numba loops (1-thread CPU,
#: encode and decode, ``benchmarks/codec.py --native``). avx2 since 2026-11-28 (forced on an AVX-512 Intel Xeon,
#: Emerald Rapids, 2 cores, load ~4.6; medians of 11 alternating rounds, ms, encode / decode): canon_dng 45.6 / 40.8
#: against numba's 52.8 / 54.1, micasense 22.3 / 26.7 against 30.9 / 34.7, spacenet_pan 8.1 / 7.2 against 9.0 / 9.2
#: (JPEG-LS 68.2 / 61.9, 42.5 / 39.6, 12.2 / 11.2). Not measured on a CPU without AVX-512; its decoder uses no
#: gather instruction (slow on AMD Zen 2-4 and on Intel cores under the GDS / Downfall microcode: ``_simd_vec.h``).
#: The portable build (2 lanes of 64 bits, SSE2 there) is not picked: 2.0-2.3x numba's time on the same host (encode
#: canon_dng 123 against 62 ms, decode 134 against 69).
AUTO = ("avx512", "avx2")
_PATH_BITS = {"portable": 1, "avx2": 2, "avx512": 4}
#: The functions every path exports as ``metraw_<name>_<path>``.
_NAMES = ("decode_plane", "decode_plane_dn", "residuals", "rans_encode", "dither_grid", "forward", "plane_buffer",
          "dither_fixed", "inverse_dn", "front", "index")


def _open() -> tuple[ctypes.CDLL | None, tuple[str, ...]]:
    """The extension's library and the compiled paths this CPU runs, or (None, ()) (not built, not loadable, built
    from another version of the C sources). A stale library (an editable install not rebuilt after a pull) gets one
    warning naming the fix; the codec then runs its numba loops."""
    spec = importlib.util.find_spec("metraw.codec._simd")
    if spec is None or not spec.origin or not os.path.isfile(spec.origin):
        return None, ()
    try:
        lib = ctypes.CDLL(spec.origin)
        lib.metraw_simd_abi.restype = ctypes.c_int
        abi = lib.metraw_simd_abi()
    except (OSError, AttributeError):
        abi = None
    if abi != ABI:
        warnings.warn(f"{spec.origin} was built from another version of metraw's C sources (interface {abi}, this "
                      f"code needs {ABI}): the codec runs its numba loops; rebuild it with pip install -e .",
                      stacklevel=2)
        return None, ()
    try:
        lib.metraw_simd_paths.restype = ctypes.c_int
        bits = lib.metraw_simd_paths()
        available = tuple(p for p in PATHS if bits & _PATH_BITS[p])
        for p in available:
            _declare(lib, p)
        lib.metraw_escape_index.restype = ctypes.c_int64
        lib.metraw_escape_index.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64,
                                            ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64]
    except AttributeError as exc:   # the interface number matches but a function is missing: a broken build
        warnings.warn(f"{spec.origin} lacks a function this code calls ({exc}): the codec runs its numba loops; "
                      f"rebuild it with pip install -e .", stacklevel=2)
        return None, ()
    return lib, available


def _declare(lib: ctypes.CDLL, path: str) -> types.SimpleNamespace:
    """The C functions of one path (``metraw_<name>_<path>``) with their signatures, by name."""
    p, i64, c_int, u64, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_uint64, ctypes.c_double
    sig = {
        "decode_plane": ([p, i64, i64, p, p, p, p, i64, i64, p, c_int, p, i64, i64, p, p, p, p, p, p, p, i64, c_int],
                         c_int),
        "decode_plane_dn": ([p, i64, i64, p, p, p, p, i64, i64, p, c_int, p, i64, i64, p, p, p, p, p, p, p, i64, c_int,
                             u64, u64, i64, i64, i64, f64, f64, f64, p, i64, i64], c_int),
        "residuals": ([p, i64, i64, p, i64, p, i64, i64, p, p], i64),
        "rans_encode": ([p, p, i64, i64, i64, p, p, p, p, p, p, p, i64, p, p, p], None),
        "dither_grid": ([u64, u64, i64, i64, i64, i64, i64, p], None),
        "forward": ([p, i64, i64, i64, i64, f64, f64, f64, f64, f64, p, p], None),
        "plane_buffer": ([p, i64, i64, i64, i64, u64, u64, i64, i64, i64, f64, f64, f64, f64, f64, p], i64),
        "dither_fixed": ([u64, u64, i64, i64, i64, i64, i64, p], None),
        "inverse_dn": ([p, i64, i64, u64, u64, i64, i64, i64, f64, f64, f64, p, i64, i64], None),
        "front": ([p, p, i64, i64, i64, p], None),
        "index": ([p, p, i64, i64, i64, p, p], None),
    }
    fns = {}
    for name in _NAMES:
        fn = getattr(lib, f"metraw_{name}_{path}")
        fn.argtypes, fn.restype = sig[name]
        fns[name] = fn
    return types.SimpleNamespace(**fns)


def auto_path(available: tuple[str, ...]) -> str:
    """The path auto-selection runs: the first of ``AUTO`` among ``available``, else numba (a compiled path that is
    not in ``AUTO`` runs only when METRAW_NATIVE asks for it)."""
    return next((p for p in AUTO if p in available), "numba")


def _requested(available: tuple[str, ...]) -> str:
    """The path METRAW_NATIVE asks for, or ``auto_path`` (also for a path this host lacks, with one warning)."""
    want = os.environ.get("METRAW_NATIVE", "").strip().lower()
    if want in ("0", "numba"):
        return "numba"
    best = auto_path(available)
    if want in ("", "1", "auto"):
        return best
    if want not in available:
        have = ", ".join(available) or "none"
        warnings.warn(f"METRAW_NATIVE={want}: not a path this build and CPU run (available: {have}; or 0 for numba): "
                      f"running {best}", stacklevel=2)
        return best
    return want


def use(path: str) -> None:
    """Run the codec's loops on ``path`` (one of ``AVAILABLE`` or ``"numba"``) from now on, in this process."""
    global LIB, PATH, _F
    if path == "numba":
        LIB, PATH, _F = None, "numba", None
        return
    if path not in AVAILABLE:
        raise ValueError(f"codec path {path!r} is not available here (available: {AVAILABLE + ('numba',)})")
    LIB, PATH, _F = _LIB, path, _declare(_LIB, path)


@contextlib.contextmanager
def path_in_use(path: str):
    """``use(path)`` for the duration of a ``with`` block, then the path before it."""
    before = PATH
    use(path)
    try:
        yield
    finally:
        use(before)


def _two_vectors(cpu_default: bool) -> bool:
    """The compiled decoder's way with a 16-lane group: METRAW_TWO_VECTORS=1 or 0 forces one (to time both on a
    host); unset or auto: ``cpu_default``, the CPU's (``_cpu_two_vectors``)."""
    want = os.environ.get("METRAW_TWO_VECTORS", "").strip().lower()
    if want in ("0", "1"):
        return want == "1"
    if want not in ("", "auto"):
        warnings.warn(f"METRAW_TWO_VECTORS={want}: not 0, 1 or auto: the CPU's default", stacklevel=2)
    return cpu_default


def _cpu_two_vectors(lib: ctypes.CDLL | None) -> bool:
    """The CPU's default 16-lane mode (``metraw_two_vector_steady``: two vectors on AMD CPUs), whatever
    METRAW_TWO_VECTORS says."""
    return bool(lib.metraw_two_vector_steady()) if lib is not None else False


_LIB, AVAILABLE = _open()
#: The library while a compiled path runs, else None (the codec's modules test ``LIB is not None``).
LIB: ctypes.CDLL | None = None
#: The path that runs: one of ``PATHS`` or "numba".
PATH = "numba"
_F: types.SimpleNamespace | None = None
use(_requested(AVAILABLE))

#: The CPU's own choice of ``TWO_VECTORS`` (what it is without METRAW_TWO_VECTORS).
CPU_TWO_VECTORS = _cpu_two_vectors(_LIB)
#: Whether the compiled decoder runs a 16-lane group's two vectors side by side (AMD CPUs: on a Zen 5 the overlap hid
#: the AVX-512 gathers' latency; on AVX2 not yet timed on AMD) or as two groups of 8 rows one after the other
#: (others); the same values either way. ``benchmarks/codec.py --lane-modes`` times the two against each other.
TWO_VECTORS = _two_vectors(CPU_TWO_VECTORS)


def cpu() -> str:
    """The CPU's model and its SIMD flags that matter here (from /proc/cpuinfo where there is one)."""
    import platform

    model, flags = platform.processor() or platform.machine(), []
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model in ("", platform.machine(), platform.processor()):
                    model = value.strip()
                elif key.strip() in ("flags", "Features") and not flags:
                    have = set(value.split())
                    flags = [x for x in ("sse4_2", "avx", "avx2", "fma", "bmi2", "avx512f", "avx512dq", "avx512bw",
                                         "avx512vl", "asimd", "sve") if x in have]
    except OSError:
        pass
    return f"{model} [{' '.join(flags)}]"


def _addr(a: np.ndarray, dtype) -> int:
    if a.dtype != dtype or not a.flags.c_contiguous:
        raise TypeError(f"native codec loop: expected a C-contiguous {np.dtype(dtype)} array, got {a.dtype}")
    return a.ctypes.data


def _eight_contexts(table: np.ndarray) -> np.ndarray:
    """A predictor table (``decoder.predictor_table``, nact x 13) padded with zeros to the 8 contexts the vector
    code permutes over."""
    out = np.zeros((8, 13), np.int64)
    out[:table.shape[0]] = table
    return out


def decode_plane(p, u, sym, thr7, coef13, tab0, pshift, lut, fcum, amax, words, xs, pos, pmin, esc, epos, eend) -> bool:
    """``decoder.decode_plane`` (same arguments but ``ctab``, same results) in the compiled loop; a compiled path must
    run and ``xs.size`` in ``LANE_COUNTS``. ``lut`` and ``words`` must be readable ``READ_PAST_END_BYTES`` past
    their ends (``decoder`` allocates them so); ``coef13`` holds 13 values per context (padded here to 8 contexts).
    ``p``: the padded buffer's first min(h, lanes) + 2 rows or more (w + 4 columns; ``decoder._init_front`` set), in
    which the loop decodes one row group after the other (its contents after the call: the last group's rows)."""
    h, w = u.shape
    if p.ndim != 2 or p.shape[1] != w + 4 or p.shape[0] < min(h, xs.size) + 2 or sym.shape != u.shape:
        raise ValueError("native decoder: the buffer needs w + 4 columns and a row group's rows + 2, the symbols the "
                         "dither's shape")
    coef = _eight_contexts(coef13.reshape(-1, 13))   # held here while the C function runs
    return bool(_F.decode_plane(*_decoder_args(p, h, w, u, sym, thr7, coef, tab0, pshift, lut, fcum, amax, words, xs,
                                               pos, pmin, esc, epos, eend)))


def _decoder_args(p, h, w, u, sym, thr7, coef, tab0, pshift, lut, fcum, amax, words, xs, pos, pmin, esc, epos,
                  eend) -> list:
    """The arguments decode_plane and decode_plane_dn share, as the C functions take them (addresses: the caller
    holds the arrays, ``coef`` from ``_eight_contexts`` included, until the call returns)."""
    lut16 = lut.dtype == np.int16
    return [_addr(p, np.int64), h, w, _addr(u, np.int32), _addr(sym, np.int32), _addr(thr7, np.int64),
            _addr(coef, np.int64), int(tab0), int(pshift), _addr(lut, np.int16 if lut16 else np.uint8), int(lut16),
            _addr(fcum, np.uint32), fcum.shape[1], int(amax), _addr(words, np.uint16), _addr(xs, np.uint64),
            _addr(pos, np.int64), _addr(pmin, np.int64), _addr(esc, np.int32), _addr(epos, np.int64),
            _addr(eend, np.int64), xs.size, int(TWO_VECTORS)]


def decode_plane_dn(p, u_rows, sym_rows, thr7, coef13, tab0, pshift, lut, fcum, amax, words, xs, pos, pmin, esc, epos,
                    eend, keys: tuple[int, int], start: int, row_step: int, col_step: int, inv: tuple, out) -> bool:
    """``decode_plane`` then ``inverse_dn`` into ``out`` (uint16, the plane's shape, positive strides: a CFA plane of the
    frame), the plane's fixed-point dither made on the way (``dither_fixed``'s, pixels start + i row_step + j col_step),
    a row group at a time: ``u_rows``, ``sym_rows`` int32 buffers of a group's rows (min(h, lanes) x w), so no array of
    the plane's size is made or read. The same DN as the three calls. ``inv``: ``prepare.inverse_args``."""
    h, w = out.shape
    rows = min(h, xs.size)
    rs, cs = (st // out.itemsize for st in out.strides)
    if (p.ndim != 2 or p.shape[1] != w + 4 or p.shape[0] < rows + 2 or u_rows.shape != (rows, w)
            or sym_rows.shape != (rows, w) or out.dtype != np.uint16 or rs <= 0 or cs <= 0):
        raise ValueError("native decoder: the buffer needs w + 4 columns and a row group's rows + 2, the dither and "
                         "symbol buffers a row group's rows, the output uint16 at positive strides")
    coef = _eight_contexts(coef13.reshape(-1, 13))   # held here while the C function runs
    return bool(_F.decode_plane_dn(*_decoder_args(p, h, w, u_rows, sym_rows, thr7, coef, tab0, pshift, lut, fcum,
                                                  amax, words, xs, pos, pmin, esc, epos, eend),
                                   keys[0], keys[1], int(start), int(row_step), int(col_step),
                                   *(float(v) for v in inv), out.ctypes.data, rs, cs))


def residuals(p, thr, table, tab0, pshift, r_out, t_out, off) -> int:
    """``predictive._residuals`` (the encoder's residual pass over one plane, same results), 8 pixels of a
    row at a time: ``p`` the plane's padded buffer, ``thr`` its nact - 1 thresholds, ``table`` its predictors
    (``decoder.predictor_table``); residuals and table indices go to ``r_out`` / ``t_out`` (int32) at ``off``. Returns
    max |r|."""
    h, w = p.shape[0] - 2, p.shape[1] - 4
    coef13 = _eight_contexts(table)
    if not (off >= 0 and off + h * w <= min(r_out.size, t_out.size) and thr.size == table.shape[0] - 1 <= 7):
        raise ValueError("native residuals: outputs too small or thresholds do not match the predictors")
    thr = np.ascontiguousarray(thr, np.int64)
    return int(_F.residuals(_addr(p, np.int64), h, w, _addr(thr, np.int64), thr.size, _addr(coef13, np.int64),
                                    int(tab0), int(pshift), _addr(r_out, np.int32) + 4 * off,
                                    _addr(t_out, np.int32) + 4 * off))


def rans_encode(idx, tab, freq, cum, rcp, rs, rl, lr, ls, out):
    """``predictive._rans_encode`` (the same states, word counts and words in ``out``) with 16 lanes at a time in
    the compiled path: ``idx``, ``tab`` int32 per symbol; ``freq``, ``cum`` int64 and ``rcp`` float64, tables x alphabet;
    ``rs``, ``rl``, ``lr``, ``ls`` the lanes' rows (``predictive._lane_rows``, int64); ``out`` uint16, one word per
    symbol and one more (the 32-bit scatter writes a word past a lane's next). Returns (states uint64, word counts
    int64), one per lane."""
    nl = lr.size - 1
    if not (1 <= nl <= 16 and out.size >= idx.size + 1 and tab.size == idx.size):
        raise ValueError("native rANS: 1-16 lanes and one output word per symbol, plus one, are needed")
    xs = np.empty(nl, np.uint64)
    nws = np.empty(nl, np.int64)
    _F.rans_encode(_addr(idx, np.int32), _addr(tab, np.int32), idx.size, freq.shape[0], freq.shape[1],
                           _addr(freq, np.int64), _addr(cum, np.int64), _addr(rcp, np.float64), _addr(rs, np.int64),
                           _addr(rl, np.int64), _addr(lr, np.int64), _addr(ls, np.int64), nl, _addr(out, np.uint16),
                           _addr(xs, np.uint64), _addr(nws, np.int64))
    return xs, nws


def dither_grid(k1: int, k2: int, start: int, rows: int, cols: int, row_step: int, col_step: int) -> np.ndarray:
    """``prepare._dither_grid_kernel`` (the same float64 values), 16 pixels at a time."""
    out = np.empty((rows, cols), np.float64)
    if out.size:
        _F.dither_grid(k1, k2, start, rows, cols, row_step, col_step, out.ctypes.data)
    return out


def dither_fixed(k1: int, k2: int, start: int, rows: int, cols: int, row_step: int, col_step: int) -> np.ndarray:
    """``decoder.fixed_dither`` of ``prepare._dither_grid_kernel``'s values (int32 floor(u 2^16)) without the float
    dither array: the decoder's dither of a plane."""
    out = np.empty((rows, cols), np.int32)
    if out.size:
        _F.dither_fixed(k1, k2, start, rows, cols, row_step, col_step, out.ctypes.data)
    return out


def inverse_dn(sym: np.ndarray, keys: tuple[int, int], start: int, row_step: int, col_step: int, half_step: float,
               k: float, offset: float, out: np.ndarray) -> None:
    """``prepare._inverse_dn_kernel`` (the same uint16 DN into ``out``) with the dither of ``prepare.dither_grid``
    (``keys`` from ``prepare.dither_keys``, pixels start + i row_step + j col_step) made on the way: ``sym`` int32
    (h, w) C-contiguous, ``out`` uint16 (h, w) at any positive strides (a CFA plane of the frame). At a column stride
    of 2 (2-pixel cells) the compiled paths store 32-bit words whose other halves (the pixels between, in the same row)
    they read and write back unchanged: no other thread may write those meanwhile (the decoder's tiles are rows)."""
    h, w = sym.shape
    rs, cs = (st // out.itemsize for st in out.strides)
    if out.dtype != np.uint16 or out.shape != sym.shape or rs <= 0 or cs <= 0:
        raise TypeError("native inverse: a uint16 output of the symbols' shape with positive strides is needed")
    if sym.size:
        _F.inverse_dn(_addr(sym, np.int32), h, w, keys[0], keys[1], int(start), int(row_step), int(col_step),
                              half_step, k, offset, out.ctypes.data, rs, cs)


def forward(data: np.ndarray, black: float, inv_k: float, c: float, xmax: float, inv_step: float,
            u: np.ndarray) -> np.ndarray:
    """``prepare._forward_kernel`` (the same int32 symbols): ``data`` uint16 (h, w), rows and columns at
    any positive stride (a CFA plane of a tile), ``u`` the float64 dither (h, w), C-contiguous."""
    h, w = data.shape
    rs, cs = (st // data.itemsize for st in data.strides)
    if data.dtype != np.uint16 or rs <= 0 or cs <= 0 or u.shape != data.shape:
        raise TypeError("native forward: uint16 data with positive strides and a dither of its shape are needed")
    out = np.empty((h, w), np.int32)
    if out.size:
        _F.forward(data.ctypes.data, h, w, rs, cs, black, inv_k, c, xmax, inv_step, _addr(u, np.float64),
                           out.ctypes.data)
    return out


def front(s: np.ndarray, u: np.ndarray, c0: int) -> np.ndarray:
    """``predictive._front`` (the same int64 buffer, (h + 2) x (w + 4)) of symbols ``s`` (int32) and dither ``u``
    (float64), both C-contiguous (h, w), with the rows above at ``c0`` 2^16."""
    h, w = s.shape
    if u.shape != s.shape:
        raise ValueError("native front: the dither must have the symbols' shape")
    p = np.empty((h + 2, w + 4), np.int64)
    _F.front(_addr(s, np.int32), _addr(u, np.float64), h, w, int(c0) << 16, p.ctypes.data)
    return p


def plane_buffer(data: np.ndarray, keys: tuple[int, int], start: int, row_step: int, col_step: int,
                 forward_args: tuple[float, float, float, float, float]) -> tuple[np.ndarray, int]:
    """The encoder's causal buffer of a CFA plane straight from its DN, in one pass: (front, c0) as
    ``predictive._front_c0`` gives them for the symbols ``prepare.forward(data, ..., u)`` and the dither
    ``u = prepare.dither_grid(seed, start, h, w, row_step, col_step)``, without making either array. ``data`` uint16
    (h, w) at any positive strides; ``keys`` the dither's (k1, k2) (``prepare.dither_keys``); ``forward_args``
    (black, 1 / K, c, xmax, 1 / q) (``prepare.forward_args``)."""
    h, w = data.shape
    rs, cs = (st // data.itemsize for st in data.strides)
    if data.dtype != np.uint16 or rs <= 0 or cs <= 0 or h * w == 0:
        raise TypeError("native plane buffer: non-empty uint16 data with positive strides are needed")
    p = np.empty((h + 2, w + 4), np.int64)
    total = _F.plane_buffer(data.ctypes.data, h, w, rs, cs, keys[0], keys[1], int(start), int(row_step),
                                    int(col_step), *forward_args, p.ctypes.data)
    c0 = int(np.rint(np.float64(total) / np.float64(h * w)))   # predictive._mean_symbol
    p[:2] = c0 << 16
    p[2, :2] = c0 << 16
    return p, c0


def escape_index(data: np.ndarray, white: int, low: int, offset: int) -> np.ndarray:
    """The flat indices (+ ``offset``, int64, in order) of the DN of ``data`` (uint16, C-contiguous) >= ``white`` or <=
    ``low`` (integers): ``np.flatnonzero`` of ``prepare.escape_mask`` in one pass that skips escape-free blocks."""
    if data.dtype != np.uint16 or not data.flags.c_contiguous:
        raise TypeError("native escape index: C-contiguous uint16 data are needed")
    out = np.empty(64, np.int64)
    n = _LIB.metraw_escape_index(data.ctypes.data, data.size, int(white), int(low), int(offset), out.ctypes.data, 64)
    if n > out.size:
        out = np.empty(n, np.int64)
        _LIB.metraw_escape_index(data.ctypes.data, data.size, int(white), int(low), int(offset), out.ctypes.data, n)
    return out[:n]


def index(r: np.ndarray, t: np.ndarray, amax: int, ntab: int,
          out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``predictive._index`` (the same alphabet indices, int32, and per-table counts, int64 ntab x (2 amax + 2)) of
    residuals ``r`` and table indices ``t`` (int32, C-contiguous, every t < ntab); the indices into ``out`` (int32,
    contiguous, r.size) where given."""
    if r.shape != t.shape or not 1 <= amax <= 2**30:
        raise ValueError("native index: residuals and table indices of one shape, 1 <= amax, are needed")
    if out is None:
        idx = np.empty(r.size, np.int32)
    elif out.dtype != np.int32 or out.size != r.size or not out.flags.c_contiguous:
        raise ValueError("native index: out must be a contiguous int32 array of the residuals' size")
    else:
        idx = out
    counts = np.zeros((ntab, 2 * amax + 2), np.int64)
    _F.index(_addr(r, np.int32), _addr(t, np.int32), r.size, int(amax), int(ntab), idx.ctypes.data,
                     counts.ctypes.data)
    return idx, counts
