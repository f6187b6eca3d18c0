"""Issue #18: can the decoder's lanes run side by side in SIMD registers, compiled by numba?

The numba decoder's steady loop (``metraw.codec.decoder.decode_plane``) runs 4 lanes (rows 3 pixels apart) as scalar
code;
the record in docs/codec-speed.md leaves "lanes that SIMD can run side by side" as the route to a decoder that
does less per pixel. Every lane's pixel needs indexed loads (its neighbours at a lane's own buffer offset, the
context's coefficients, two rANS table entries, the next stream word), i.e. gather instructions once vectorised.

This script compiles the decoder's own per-pixel step (``decoder._pixel``, inlined) in a lane-major loop over
``--lanes`` independent lanes (state arrays indexed by lane: the shape a loop vectoriser needs), times it on
synthetic tables and buffer (the arithmetic does not depend on the values), and counts the vector and gather
instructions numba's LLVM emitted for it; then the same for the plainest indexed loop that stores,
c[j] = a[b[j]] * 3 + b[j], and for one that only reads, s += a[b[j]] (numba passes arrays without ``noalias``: a
store may alias any indexed load, the likely reason such loops stay scalar; a pure reduction has no store).

Outcome (2026-11-28): numba did not; hand-written AVX-512 in C does. ``metraw.codec._simd`` (``src/metraw/codec/
_simd.c``, an optional extension, loaded by ``metraw.codec.native``) runs the 8 lanes of a row group in one register,
the neighbours as register histories shifted across lanes instead of gathers from the buffer; the decoder became
~1.5x faster on one thread at the same values (docs/codec-speed.md).

Run: python benchmarks/codec_simd_lanes.py [--lanes 4,8,16]
"""

from __future__ import annotations

import argparse
import re
import time

import numba as nb
import numpy as np

from metraw.codec.decoder import PROB_SCALE, RANS_L, _pixel, context_table

TABLES = 32
ALPHA = 64
AMAX = 31
PIXELS = 2_000_000   # canon_dng's 2 MP


@nb.njit(nogil=True, boundscheck=False)
def lane_major(steps, pf, ws, b, w_, ww, uv, thr, ctab, coef, lut, fcum, words, xs, pos, esc, epos):
    """``steps`` pixels of every lane; lane j's pixel at flat index b[j] + step (within its own row)."""
    for i in range(steps):
        for j in range(xs.size):
            pv, xs[j], pos[j], epos[j] = _pixel(pf, b[j] + i, ws, w_[j], ww[j], uv[j], thr, ctab, coef, 0, 0, lut,
                                                fcum, ALPHA, AMAX, words, xs[j], pos[j], esc, epos[j])
            ww[j] = w_[j]
            w_[j] = pv & 0xFFFFFF       # keep the synthetic values bounded
            pos[j] = pos[j] + (1 << 16) if pos[j] < 16 else pos[j]
            epos[j] = 0 if epos[j] > 1000 else epos[j]


@nb.njit(nogil=True, boundscheck=False)
def indexed(a, b, c):
    for j in range(c.size):
        c[j] = a[b[j]] * 3 + b[j]


@nb.njit(nogil=True, boundscheck=False)
def indexed_sum(a, b):
    s = 0
    for j in range(b.size):
        s += a[b[j]]
    return s


def instructions(fn) -> dict[str, int]:
    asm = "\n".join(fn.inspect_asm().values())
    return {"gather": len(re.findall(r"gather", asm)), "zmm": asm.count("zmm"), "ymm": asm.count("ymm")}


def lanes_case(lanes: int, rounds: int = 5) -> tuple[float, dict[str, int]]:
    rng = np.random.default_rng(0)
    steps = PIXELS // lanes
    ws = steps + 8
    pf = rng.integers(0, 1 << 24, ws * (lanes + 3)).astype(np.int64)
    b = (np.arange(lanes, dtype=np.int64) + 2) * ws + 4
    w_ = rng.integers(0, 1 << 24, lanes).astype(np.int64)
    ww = w_.copy()
    uv = rng.integers(-(1 << 15), 1 << 15, lanes).astype(np.int64)
    thr = np.sort(rng.integers(1, 1 << 20, 7)).astype(np.int64) << 8
    ctab = context_table(thr)
    coef = rng.integers(-400, 400, 8 * 13).astype(np.int64)
    lut = rng.integers(0, ALPHA, TABLES * PROB_SCALE).astype(np.uint8)
    fcum = ((rng.integers(1, 64, TABLES * ALPHA).astype(np.uint32) << 16)
            | rng.integers(0, 2000, TABLES * ALPHA).astype(np.uint32))
    words = rng.integers(0, 1 << 16, 1 << 22).astype(np.uint16)
    esc = np.zeros(2048, np.int32)
    args = (pf, ws, b, w_, ww, uv, thr, ctab, coef, lut, fcum, words)

    def state():
        return (np.full(lanes, 3 * RANS_L, np.uint64), np.full(lanes, 1 << 21, np.int64), esc,
                np.zeros(lanes, np.int64))

    lane_major(10, *args, *state())
    times = []
    for _ in range(rounds):
        st = state()
        t = time.perf_counter()
        lane_major(steps, *args, *st)
        times.append(time.perf_counter() - t)
    return 1e9 * float(np.median(times)) / (steps * lanes), instructions(lane_major)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanes", default="4,8,16")
    args = ap.parse_args()
    for lanes in (int(v) for v in args.lanes.split(",")):
        ns, ins = lanes_case(lanes)
        print(f"{lanes:2d} lanes, lane-major loop of decoder._pixel: {ns:5.2f} ns/pixel (median of 5; 2 MP: "
              f"{ns * PIXELS / 1e6:5.1f} ms); instructions: {ins}")
    a = np.arange(1 << 16, dtype=np.int64)
    b = np.random.default_rng(0).integers(0, 1 << 16, 1 << 20).astype(np.int64)
    c = np.zeros(b.size, np.int64)
    indexed(a, b, c)
    indexed_sum(a, b)
    print(f"c[j] = a[b[j]] * 3 + b[j]: instructions {instructions(indexed)}")
    print(f"s += a[b[j]]: instructions {instructions(indexed_sum)}")
    print(f"LLVM's host CPU: {nb.core.codegen.ll.get_host_cpu_name()}")


if __name__ == "__main__":
    main()
