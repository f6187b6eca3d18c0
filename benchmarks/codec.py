"""Codec benchmark: metraw at steps 0.5/1/2 vs lossless and near-lossless peers on real frames.

Real data: data/real of the repository (canon_dng, micasense, spacenet_pan; see its README.md).
Profiles: fixed per frame (REAL_PROFILES: the single-frame fit's values before e6ab38f). Timings side by side in one
run (2 threads for metraw). Writes docs/figures/codec_rd.png.  Run: nice -n 5 python benchmarks/codec.py
Speed only (real frames, steps 1 and 2: 2-thread wall and 1-thread CPU ratios against JPEG-LS):
nice -n 5 python benchmarks/codec.py --speed   (all cases round-robin, medians of SPEED_REPS rounds;
then the 20 MP frame: absolute times and Mpix/s)
Compiled loops against numba (1-thread CPU, the real frames at step 1, same process, alternating rounds):
nice -n 5 python benchmarks/codec.py --native
Both time every codec path the host runs (native.AVAILABLE, then numba; --paths avx2,numba picks some; --reps N
rounds for --speed, --no-large skips its 20 MP frame) and print the CPU's model and flags and the path at import.
--as-avx2-host runs either as on a CPU without AVX-512 (``AVX2_HOST_ENV``: the codec's AVX2 loops, numba's code
generated for an x86-64-v3 CPU, numpy's and OpenBLAS's AVX-512 kernels off), so that an AVX-512 host measures what
an AVX2-only one would run; CharLS has no such dispatch. ``--help`` lists the options.

Where the time goes (issue #18; CPU ms on one core, THREADS = 1, step 1, medians of 7 calls per
stage, 2 shared cores under load 2-9 from other users: +-10 %). Before = commit e5cee37, after =
this version; the streams are byte-identical on these frames (only the code changed). Stages are
timed one by one (warm caches), so they need not add up to the totals.

    stage                                          canon_dng 2.0 MP RGGB    micasense 1.2 MP mono
                                                   before    after          before    after
    encode, total                                   56.8      37.9            24.8      18.0
      dither (counter hash)                          0.8       0.9             0.5       0.5
      transform + quantise (forward)                 1.2       2.0 (a)         0.7       0.8
      profile noise check (tile 0)                   0.8       0.8             0.2       0.2
      model: padded buffer                           3.3       0.7 (b)         0.8       0.6
      model: activity thresholds                     2.6       1.0             0.2       0.1
      model: least-squares normal equations + solve  5.2       4.9             0.6       0.6
      prediction + context (_residuals)             21.7      13.2            11.6       8.6
      entropy coding (tables, 4-lane rANS, escapes) 14.7       8.4             8.8       5.1
      rest (escape list, packing, cache effects)     6.5       6.0             1.6       1.5
    decode, total                                   45.9      35.2            24.7      20.2
      container unpack + CRC-32C                     0.1       0.1             0.1       0.1
      dither                                         0.8       0.9             0.5       0.5
      section set-up (tables, buffers) +            45.6      31.7            22.9      18.8
        per-pixel prediction, context, rANS         (set-up 1.8, per pixel 29.8)  (1.0, 17.8)
      inverse transform                              1.1       1.2 (a)         0.4       0.5
    (a) per CFA plane through a row buffer (the planes are now contiguous arrays; strided rows
        are gathered / stored); (b) contiguous planes vectorise.

The per-pixel loops dominate: the encoder's prediction pass and rANS (~60 %), the decoder's
sequential 4-lane loop (~85 %). Container, CRC and per-tile Python work are < 1 ms per frame.
The decoder is bound by each lane's dependency chain (neighbours -> activity context ->
12-tap prediction -> table index -> rANS lookup -> value), ~190 instructions per pixel.

``--speed`` before / after on the same machine, back to back (load 7-9 from other users, so the
2-thread runs got ~1 core: par 0.45-0.7), metraw CPU on 1 thread / JPEG-LS CPU, steps 1 and 2:
canon_dng 1.19-1.20 / 1.08-1.09 -> 0.84-0.88 / 0.90; micasense 0.81 / 1.54 -> 0.68-0.69 / 0.86-0.87;
spacenet_pan 1.04-1.05 / 1.54-1.55 -> 0.81-0.82 / 0.89-0.90 (encode / decode); 20 MP frame
1.35-1.50 / 1.16-1.24 -> 0.97-0.99 / 0.82-1.13 (7 rounds only: noisy).

What bounds the per-core speed (session of 2026-11-25; 1-thread CPU / JPEG-LS, medians of 25 interleaved
rounds, load ~2.5 from another user's training). The decoder's steady 4-lane loop compiles to 656
instructions per step of 4 pixels: 164 per pixel, 36 of them stack loads and stores (4 lanes' states and
~15 table and array pointers do not fit in 16 registers); the work itself is ~120 (10 neighbour and 13
coefficient loads, 12 64-bit multiplies, 5 absolute differences, context lookup, phase fold, 2 table loads
and the rANS update per pixel). Integer dither, one coefficient-and-bias array and the symbols read back
after the loop took decode from 0.91-0.93 to 0.85-0.89 of JPEG-LS (same bytes). Tried and measured, not
taken: an escape branch instead of the branch-free select (decode 1.26 of JPEG-LS: slower); two passes
of two lanes instead of four lanes at once, to keep the lane states in registers (1.00 vs 0.88: the four
dependency chains' overlap is worth more than the spills); the dither read from the buffer address the
pixel is written to (one pointer for all lanes: no change); fewer taps
(5 taps: +2.6 / +3.9 % bits on canon_dng at steps 1 / 2, +5.0 / +6.8 % on the synthetic frame; 8 taps: +0.9 / +1.4 %
and +3.4 / +4.9 %); an activity context from the rows above only, which would let a vectorised pass compute the
context and 10 of the 12 taps before the sequential loop (+1.0 to +3.3 % bits on the shared frames); a
sparser least-squares lattice in the encoder (the smallest odd stride with <= 16384 samples: +0.26 to
+0.90 % bits on canon_dng and spacenet_pan, for ~3 ms of canon_dng's 47); a gathered, per-tap vectorised prediction in the encoder (1.73 vs 1.41 ms a plane: slower).
Every format-preserving step left is worth a few per cent; the 3x on two cores asks ~1.5x per core, i.e.
a new stream version whose sequential loop does far less per pixel (a context that costs < 1 % bits yet
is known before the row, or lanes that SIMD can run side by side).

What such a version would cost in bits (2026-11-26; encoder changed in a scratch copy, bytes of
``codec.encode`` at steps 1 / 2; bits do not depend on load): one predictor for all activity contexts
(the contexts keep their tables; the sequential loop would need no per-context coefficients and the
encoder's prediction becomes a plain stencil): canon_dng +4.2 / +6.1 %, micasense +4.8 / +6.9 %,
spacenet_pan +1.5 / +2.3 %, synthetic +3.5 / +5.5 %. The predictor's context from the rows above only
(|N-NW| + |N-NE| + |N-NN| + |NW-NWW| + |NE-NEE|, 8 classes at its own quantiles) while the tables keep the
full activity, so a pass before the row could compute context and 10 of the 12 taps: +1.1 / +1.5 %,
+1.8 / +2.4 %, +0.3 / +0.3 %, +1.1 / +1.2 %. Both exceed issue #18's 1 % bound on the shared frames.
Tried and measured the same day, not taken: a format-preserving decoder whose lanes run blocks of 16 (or 32)
columns 18 (34) apart, so that before each block a vectorised pass computes every context's 10-tap sum over
the rows above (in float64: exact for buffer values below 2^34, checked per block, else the block went the
general way) and the sequential step keeps only the context, the W and WW taps and rANS. Decoded symbols
identical on every frame of ``frames()`` at steps 0.5 / 1 / 2, but 1-thread decode CPU / JPEG-LS went from
0.94-0.99 to 1.02-1.07 (blocks of 16; 32: 1.02-1.09; two alternating rounds each, load ~4 from a workflow run):
the pass alone cost 13 ms of canon_dng's ~47 (8 contexts x 10 taps x 2 MP), and the sequential part fell only
from ~43 to ~33 ms: the lanes' dependency chain (context -> table -> rANS -> value -> next context), not the
instruction count, bounds it.
Tried 2026-11-27, not taken: 8 lanes instead of 4 (the header carries the lane count; the encoder codes any count,
and a scratch decoder had an 8-lane steady loop, lane j 3 pixels behind lane j - 1). Bits +0.00 to +0.05 %; 1-thread
decode CPU, medians of three alternating rounds (load ~1): canon_dng 37.2 -> 36.3 ms, micasense 22.4 -> 22.6 ms,
spacenet_pan 7.3 -> 6.4 ms, each within its rounds' spread. Twice the independent chains (with the spills of twice
the lane registers) buy no clear gain: past 4 lanes the loop's own work bounds it, so a faster decoder must do less
per pixel.

Tried 2026-11-28, not taken: lanes side by side in SIMD registers, compiled by numba (``benchmarks/codec_simd_lanes.py``:
the decoder's own ``_pixel`` in a lane-major loop over per-lane state arrays, the shape a loop vectoriser needs). Each
lane's pixel needs indexed loads (neighbours at its own offset, its context's coefficients, two rANS table entries, the
next word), i.e. gathers, and stores (its value, its state). Numba's LLVM (22.1, this Emerald Rapids with AVX-512)
emits no gather and no zmm instruction for it at 4, 8 or 16 lanes (39.6 / 42.2 / 44.2 ns a pixel: scalar code with
the lane states in memory), nor for c[j] = a[b[j]] * 3 + b[j]; it does gather (256-bit) for s += a[b[j]], which
stores nothing. Numba passes arrays without ``noalias``: a store may alias any indexed load, the likely reason the
loop stays scalar. SIMD lanes would need hand-written intrinsics (a C extension: a compiler at install time), outside
this numba code base.

Done 2026-11-28: the loops in C with AVX-512 (``metraw.codec._simd``, an optional extension built by ``pip install``
where a C compiler is; ``metraw.codec.native`` loads it, the numba loops stay where it is absent or with
METRAW_NATIVE=0, and the tests hold both to the same bytes and values). (1) The decoder: 8 rANS lanes (the encoder
writes 8 since, +0.01-0.05 % bits; the header carries the count, old 4-lane files decode as before) side by side in
one 512-bit register; a lane's neighbours are register histories of itself and the two lanes above, shifted across
lanes (valignq), so the steady loop reads no pixel it wrote; 5 gathers (dither, symbol table, frequency table, word,
escape) and 1 scatter a step of 8 pixels; ~25 instructions a pixel against numba's ~164. (2) The encoder's residual
pass 8 pixels of a row at a time (coefficients by vpermq from 8-context registers). (3) The encoder's rANS pass 8
lanes at a time (reciprocal division with explicit rounding, -ffp-contract=off: numba's words). 16 lanes (two
registers) were not faster than 8 on canon_dng (per-plane decode 1.58-1.78x numba against 1.98-2.10x for 8, runs
back to back on a noisy host): the edges of each row group (3 (L - 1) columns on the scalar path) grow with L.
1-thread, same process, alternating, canon_dng step 1: decode
55.8 -> 36.8 ms, micasense 32.3 -> 21.6, spacenet_pan 9.8 -> 6.7 (numba 8-lane decode = numba 4-lane decode: the
numba loop runs 8-lane groups as two 4-row groups); encode 60.5 -> 50.9, 26.4 -> 22.7, 9.5 -> 8.8 (load ~1.7).
(4) The dither and the forward transform (d5fcb01), the encoder's causal buffer (1f6ab1a), its alphabet indices and
counts (2b57d2b). Plus, in numba, the least-squares sampling loop without a view per sample (1.35x on that loop,
same bytes). At 2b57d2b, 1-thread CPU with the compiled loops against without (METRAW_NATIVE off; same process,
alternating, 11 rounds, step 1): encode canon_dng 65.1 -> 48.0 ms (1.36x), micasense 30.4 -> 19.3 (1.58x),
spacenet_pan 10.1 -> 7.8 (1.30x); decode 59.3 -> 37.3 (1.59x), 34.7 -> 20.4 (1.70x), 9.7 -> 6.3 (1.54x).
``--speed`` at 2b57d2b (21 rounds, load 1.1-1.3; bpp as in issue #18's table), JPEG-LS / metraw 2-thread wall,
encode / decode, steps 1 and 2: canon_dng 2.64 / 3.27 and 2.66 / 3.46; micasense 3.78 / 3.62 and 3.77 / 3.57;
spacenet_pan 2.58 / 3.09 and 2.67 / 2.96; 1-thread CPU / JPEG-LS: 0.62 / 0.50, 0.64 / 0.51; 0.43 / 0.47, 0.44 / 0.47;
0.59 / 0.52, 0.61 / 0.53; par (CPU / wall on 2 threads) 1.74-1.86. 20 MP frame: 2-thread 257 / 199 ms (step 1) and
275 / 209 ms (step 2), 73-78 / 95-101 Mpix/s, x JPEG-LS 3.10 / 3.53 and 3.15 / 3.90. The runs before it, same
benchmark: at 1f6ab1a (load 1.1-1.9) canon_dng 2.80 / 3.29 and 2.79 / 3.37, micasense 3.70 / 3.87 and 3.51 / 3.65,
20 MP 3.09 / 3.37 and 2.92 / 3.30; at d5fcb01 canon_dng 2.69 / 3.17 and 2.56 / 3.43; at ec80929 (before (4))
2.47 / 3.25 and 2.40 / 3.18. JPEG-LS's own times moved by up to 20 % between these runs (canon_dng encode 66-84 ms):
the host's pace, not the code.
Left: canon_dng's encode at 2.56-2.80x (3x needs ~7-15 % less CPU). Its 1-thread encode (~41-48 ms): least squares
~9 (normal equations on 28 k samples a plane at stride 3 ~6, thresholds ~2), residual pass (C, bound by the two
512-bit ports: 12 vpmullq a vector) ~8, rANS (C, gather-bound) ~5.6, causal buffer (C, memory-bound) ~2, alphabet
indices and counts (C) ~3, transform and dither (C) ~3, the rest (escape mask, noise check, container) ~4.
Tried, not taken: a hand multi-quickselect for the thresholds (146 against np.partition's 235 us a plane: ~0.7 ms a
frame); 4 sub-histograms in numba's _index (no faster).

Done 2026-11-28 (afternoon session, on a 2-core AMD EPYC Zen 5 VM with AVX-512, where JPEG-LS runs ~1.8x faster than on
the Intel Emerald Rapids VM above: canon_dng 39 / 35 ms encode / decode). ``--speed`` at d4b0a04 (the state above) on
this machine: canon_dng 2.57 / 2.96 and 2.57 / 2.98, micasense 3.63 / 2.95 and 3.54 / 3.01, spacenet_pan 3.04 / 2.89
and 3.10 / 2.91 (steps 1 and 2, JPEG-LS / metraw 2-thread wall, encode / decode). perf on one core then: encode
rANS 20 %, residual pass 17 %, forward transform 12.5 % (memory-bound in the frame: 2.6 ms against 1.2 ms alone),
alphabet indices 6 %, causal buffer 5.5 %, dither 3 %, numba 26 % (least squares ~2.9 ms, thresholds 1.1, profile
check 0.55); decode: the steady loop 71 % (its samples on the instructions after the gathers), the edges' scalar path
9 %, numba 9 % (inverse transform, fixed-point dither), dither 3 %. Steps, each with the same bytes (sha256 of every
``frames()`` stream at steps 0.5 / 1 / 2, both loops) unless said:
(1) the encoder's plane buffer straight from the DN in one C pass per CFA plane (dither hash, forward transform,
causal buffer; no dither or symbol arrays in memory): encode 1-thread 24.1 -> 20.9 ms, 2-thread wall 14.3 -> 12.2;
(2) the decoder's fixed-point dither and its inverse transform in C (the dither made on the way): decode 2-thread
wall 11.2-11.6 -> 10.6 ms; (3) 16 rANS lanes (bits +0.01-0.15 % against 8) and the decoder's 16-lane groups as two
vectors side by side (their chains overlap, hiding the gathers' latency): decode 1-thread 19.6 -> 16.6 ms
(micasense 10.8 -> 8.9), only on AMD: on Intel, where two vectors measured 10-25 % slower (above), a 16-lane group runs
as two 8-row groups, the 8-lane speed (``native.TWO_VECTORS``; the same values, tested both ways); (4) the encoder's
rANS pass 16 lanes as two vectors, with one gather of each symbol's table entry and one of its packed frequency and
cumulative frequency (the reciprocal by an IEEE division): 5.5 -> 4.0 ms a frame; (5) the activity thresholds by a
histogram of activity >> 8: 1.1 -> 0.08 ms; (6) the profile check's mean absolute deviation by a histogram: 0.5 ->
0.03 ms. Tried, not taken: the least squares in C (sampling and Gram sums in a fixed order shared with numba; the same
bytes) took 3.2 ms against numba's 2.9 (the scalar sampling ~1.8 ms, bound by the samples' scattered reads and
context stores); narrowing stores in registers instead of vpmovqd to memory (no change); the tiles' escapes found in
their threads (no change). At dbc82d6 + (6), 1-thread CPU with the compiled loops against without (METRAW_NATIVE off;
same process, alternating, 11 rounds, step 1): encode canon_dng 23.0 -> 18.3 ms (1.26x), micasense 11.0 -> 7.8
(1.41x), spacenet_pan 4.0 -> 2.9 (1.38x); decode 27.7 -> 16.4 (1.69x), 16.0 -> 8.9 (1.79x), 4.8 -> 3.1 (1.56x).
``--speed`` (21 rounds, load 1.0-1.1): canon_dng 3.59 / 3.71 and 3.61 / 3.77; micasense 5.12 / 3.88 and 5.15 / 3.97;
spacenet_pan 4.03 / 3.43 and 4.04 / 3.46; 1-thread CPU / JPEG-LS 0.46 / 0.46, 0.45 / 0.46; 0.30 / 0.43, 0.30 / 0.43;
0.40 / 0.48, 0.39 / 0.48; bpp 2.416 / 1.543, 2.382 / 1.525, 2.254 / 1.480; 20 MP frame 104.9 / 86.6 ms (step 1),
190 / 231 Mpix/s, x JPEG-LS 4.01 / 4.08.
Then (7) a 16-lane group's edges as 8-lane ramps (A = lanes 0-7 alone in its steady part while B = lanes 8-15
starts, both vectors, B alone while A ends): the scalar path 17 % -> 10 % of decode, decode 1-thread against 8 lanes
1.16 -> 1.21x (canon_dng) and 1.23 -> 1.25x (micasense), the same values. After it, ``--native`` (load ~1): encode
canon_dng 22.7 -> 17.2 ms (1.32x), micasense 10.7 -> 7.1 (1.52x), spacenet_pan 3.9 -> 2.7 (1.43x); decode 27.2 -> 15.1
(1.80x), 15.6 -> 8.4 (1.85x), 4.7 -> 2.9 (1.63x). ``--speed`` (load 0.7-1.0): canon_dng 3.49 / 3.72 and 3.47 / 3.83,
micasense 4.89 / 3.89 and 5.01 / 3.99, spacenet_pan 3.99 / 3.53 and 3.96 / 3.57; 1-thread CPU / JPEG-LS 0.31-0.47;
20 MP frame 110.9 / 85.4 ms at step 1 (180 / 234 Mpix/s). The 20 MP frame's step-2 encode times vary between runs
(132-252 ms of CPU over three runs of 7 rounds, against 163-174 at step 1); alone, 1 thread, alternating steps in one
process: 158-162 ms at step 2 and 163-166 at step 1, so the spread is the benchmark's (its rounds interleave JPEG-LS's
20 MP calls), not the coder's.
The same code (534ba2b) on an Intel Xeon with AVX-512 (the H200 device machine's CPU, 16 cores, gcc 13, Python 3.12;
the extension built there with pyproject's flags; 2026-11-28; each command under ``taskset -c 0,1``, two cores, load
0.1-1.2): decoding a 16-lane group as two 8-row halves against two vectors side by side, 1 thread, 15 alternating
rounds: 0.906 / 0.915 / 0.863 of the two-vector time (canon_dng / micasense / spacenet_pan), so ``native.TWO_VECTORS``
stays off on Intel. ``--native``: encode 51.6 -> 31.3 ms (1.65x), 28.1 -> 15.0 (1.87x), 8.6 -> 5.9 (1.47x); decode
53.7 -> 28.0 (1.92x), 33.8 -> 17.1 (1.98x), 9.4 -> 5.7 (1.64x). ``--speed`` (JPEG-LS / metraw 2-thread wall, encode /
decode, steps 1 and 2): canon_dng 3.76 / 4.71 and 3.81 / 4.74, micasense 5.32 / 4.70 and 5.38 / 4.74, spacenet_pan 3.38
/ 3.58 and 3.19 / 3.58; 1-thread CPU / JPEG-LS 0.33-0.51 (JPEG-LS 88 / 80 ms on canon_dng there); bpp as on AMD; 20 MP
frame 207.6 / 172.1 ms at step 1 (4.17 / 4.32x JPEG-LS). So issue #18's bounds hold on both vendors.

A vectorised pass can only take taps whose coefficients do not depend on the activity context (which needs W).
``benchmarks/codec_predictors.py`` (2026-11-26; empirical H(r | context, phase) in float arithmetic, no side
information, steps 1 / 2) measured such predictors against today's: one shared predictor canon_dng +1.5 / +2.0 %,
micasense +5.5 / +8.3 %, spacenet_pan +1.7 / +2.7 %; a shared sum of the 10 taps above plus per-context W, WW, N
and bias +1.1 / +1.7, +2.5 / +3.9, +1.0 / +1.5 %; per-context N, NW, NE, NN, WW and bias plus a shared sum of the
6 farther taps +0.9 / +1.4, +1.2 / +1.6, +0.2 / +0.3 %. None stays within issue #18's 1 % on every frame.

``--speed`` on a quiet machine (2026-11-27 17:30, load 0.4-1.5; 21 rounds; the streams as above), metraw 1-thread CPU /
JPEG-LS CPU, encode / decode at steps 1 and 2: canon_dng 0.84 / 0.94 both; micasense 0.64 / 0.91 and 0.63 / 0.91;
spacenet_pan 0.78 / 0.91 and 0.77 / 0.90. 2-thread wall, JPEG-LS / metraw: 2.16 / 2.00, 2.19 / 2.02; 2.82 / 2.01,
2.81 / 2.04; 2.28 / 1.86, 2.34 / 1.94, with metraw's CPU / wall at 1.84-1.94 (the tiles run concurrently). 20 MP
frame (7 rounds): 2-thread 239 / 218 ms (step 1) and 237 / 195 ms (step 2), 83-84 / 92-102 Mpix/s; 1-thread CPU
0.94 / 1.06 and 0.95 / 0.88 of JPEG-LS. With two cores busy 1.9 of the time, 3x JPEG-LS on two threads needs a
1-thread CPU ratio <= ~0.63: encode is there on micasense only, decode is ~1.45x away on every frame.
Then ``codec.TILE_PIXELS`` 5 -> 2.5 MP (frames up to 5 MP keep their 2 tiles, so the rows above do not change): the
20 MP frame in 8 tiles instead of 4, 1-thread CPU / JPEG-LS (5 interleaved rounds, 1-thread calls only):
encode 0.89 -> 0.67 (step 1) and 0.87 -> 0.67 (step 2), decode 0.88 -> 0.89 and 0.87 -> 0.88, bpp 2.9367 -> 2.9450
and 2.0325 -> 2.0354; measured that way, decode is below JPEG-LS's at 4 tiles too (the 1.06 above: 7 rounds).

The AVX2 path (issue #52; forced on the Intel Emerald Rapids VM, 2026-11-28 evening): ``--native`` (load ~4.6) 1-thread
CPU ms encode / decode, avx2 against numba: canon_dng 45.6 / 40.8 against 52.8 / 54.1, micasense 22.3 / 26.7 against
30.9 / 34.7, spacenet_pan 8.1 / 7.2 against 9.0 / 9.2 (so native.AUTO picks avx2 without AVX-512). ``--speed --reps 11
--no-large`` (load 1.4 -> 5.7: a one-core job ran throughout, so par ~0.7 and the 2-thread walls are not an idle
machine's), cpu1 / JPEG-LS encode / decode at steps 1 and 2: avx2 canon_dng 0.73 / 0.69, 0.75 / 0.66; micasense
0.58 / 0.67, 0.46 / 0.57; spacenet_pan 0.67 / 0.60, 0.61 / 0.69 (numba 0.68-0.97, avx512 0.40-0.56); canon_dng's
step-1 encode there 57.7 ms against numba's 56.7 (a tie in that run; 45.6 against 52.8 in ``--native``).

The same VM quiet (2026-11-29, load ~1), ``--speed --reps 15 --no-large --paths avx2,avx512,portable,numba``, JPEG-LS /
metraw 2-thread wall, encode / decode at steps 1 and 2: avx2 canon_dng 2.78 / 2.85, 2.65 / 2.91; micasense 3.64 / 3.17,
3.58 / 3.13; spacenet_pan 2.49 / 2.57, 2.41 / 2.60 (cpu1 0.45-0.71; par 1.69-1.86: the two tiles of a 2 MP frame keep
~1.75 cores busy, not 2). A sampling profile (``perf record -e cpu-clock``, no hardware counters in the VM) of the avx2
decoder put the steady loop's time on its gathers; the escape's gather (one of five a step) is needed only where a
lane's symbol is the escape, rare, so it now runs only in those steps (the AVX-512 path too): ``--native`` medians of 4
alternating runs of the two builds, decode 1-thread CPU ms canon_dng 38.5 -> 32.8 (avx2), 28.8 -> 25.0 (avx512);
micasense 20.0 -> 19.6, 16.3 -> 14.4; spacenet_pan 6.8 -> 6.8, 5.6 -> 5.2. ``--speed --paths avx2 --reps 11`` after it
and after moving the escape mask into the tiles: canon_dng 2.75 / 3.01, 2.59 / 3.15; micasense 3.76 / 3.07, 3.79 /
3.23. The encoder's avx2 rANS pass spends its time at the gather of each symbol's table entry (16 lanes reading 16
places of an 8 MB array); its residual pass is arithmetic on 4 x 64-bit lanes, so canon_dng's encode (1-thread 53 ms
against 35 on avx512) stays under 3x JPEG-LS on two threads.

Session of 2026-11-29 (issue #52; the same Emerald Rapids VM, quiet, load ~1; the codec path forced). The avx2 rANS pass
now reads each block's table entries first, lane by lane in step order, by scalar loads (no gathers in the steps):
in-process A/B of the two builds (``ctypes``, 25 alternating rounds, canon_dng's tile), 3.86 -> 3.23-3.25 ms (0.82-0.85x),
the same streams; the portable build keeps its gathers (the block's reads first made it 1.36-1.53x slower).
``--speed --paths avx2,avx512,portable --reps 11 --no-large`` after it, JPEG-LS / metraw 2-thread wall, encode / decode
at steps 1 and 2: avx2 canon_dng 2.39 / 2.45, 2.77 / 2.91; micasense 3.01 / 2.58, 3.28 / 2.66; spacenet_pan 2.14 / 2.50,
2.23 / 2.46 (cpu1 0.51-0.66; par 1.62-1.86); avx512 canon_dng 3.53 / 3.56, 2.83 / 3.43; micasense 4.12 / 4.07, 4.22 /
3.66; portable 0.93-1.16 (cpu1 1.41-1.88). Two more runs right after (``--paths avx2,avx512``, 11 rounds each): avx2
canon_dng 2.79 / 3.11, 2.64 / 2.79 and 2.53 / 2.98, 2.96 / 2.77; micasense 3.53 / 2.96, 3.62 / 2.86 and 3.71 / 3.20,
3.48 / 3.01; avx512 canon_dng 3.11 / 4.07, 3.38 / 4.20 and 3.00 / 3.82, 3.17 / 3.82. How far one run moves: JPEG-LS's
own canon_dng encode, the same call in every row, took 67.7-81.7 ms across the rows of the first run, and one case's
per-round ratio (JPEG-LS / metraw, timed side by side) spread 2.0-3.4 over the 11 rounds (avx2 canon_dng encode): the
median's own error is ~+-0.15, and a single run's ratio is good to ~+-10 %. The median of the per-round ratios instead
of the ratio of the medians moved the avx2 rows by -0.10 to +0.48 (mostly up) and was no steadier from run to run:
not taken (the ratio of the medians stays the measure, comparable with the records above).
Then, the same bytes and values: the normal equations through unsigned indices (numba checks no index for wrap-around;
0.78 -> 0.69 ms a canon_dng plane); the profile check on the first tile's buffers in place and the HH band's range in
one pass (1.16 -> ~0.7 ms on that tile's thread); the frame's escape mask concatenated only for the bit account
(-0.29 ms of the ~1.4 ms that run on one core after the tiles: escape list 0.5, container 0.4 there). canon_dng
2-thread encode against the build before them, three alternating processes each: 21.8-28.6 ms against 21.9-26.3, no
difference this host resolves (JPEG-LS's own time in the same processes: 62.6-83.0 ms). Not taken: the alphabet
counts in four sub-histograms instead of two, 2.31 against 2.44 ms a frame (indices and counts, avx2, 30 alternating
rounds; avx512 2.73 against 2.87): 0.1 ms.
Where the time goes (1-thread, avx2, canon_dng, per tile of 1 MP; medians of 30 encodes): plane buffers 4 x 0.62 ms,
models 4 x 0.9-1.0 (numba: normal equations 0.8, of which gathering the samples 0.58), residual pass 4 x 1.55, alphabet
indices and counts 1.85, rANS 3.3 after the change above; ~2.3 ms after the last tile (escape masks and list, container)
on one core. Tried and not taken: (1) each tile's planes and its section as separate tasks that either thread takes
(a slower core takes fewer planes; the same bytes): canon_dng 2-thread encode 23.3-27.1 ms against 23.9-28.3 quiet, and
42.7-46.2 against 44.4-45.0 with a spinning process on one core, no gain; (2) the 64-bit arithmetic shift as two
shifts and a blend instead of a compare (no port-5 compare): residual pass 0.993x, encode and decode within the
in-process A/B's +-4 % (whichever build ran first in a round was ~4 % faster); (3) the normal equations context by
context (every sample's context first, then each context's samples: exactly the same sums) 0.98 ms against 0.79:
slower (eight sweeps of the plane instead of one). The residual pass is bound by its instruction count (~115 vector
instructions per 4 pixels, spread evenly in the sampling profile: 13 loads, 12 vpermd / vpmuldq / vpaddq taps, the
context's 7 compares), not by one unit.

Later on 2026-11-29 (issue #52; the same VM). What the host gives two threads: the same 1-thread call on both CPUs at
once (two processes, each pinned, 16 rounds alternating with the call alone) takes 0.97x (JPEG-LS decode), 0.98x
(JPEG-LS encode), 1.03x (metraw decode) and 1.10x (metraw encode) its time alone, and two JPEG-LS calls on two threads
of one process do x1.82-2.05 the work of one (``--speed`` now prints this, measured in its own rounds). metraw's par
(1.75-1.86) is at that capacity, so a 2-thread wall ratio of 3 needs a 1-thread CPU ratio of ~0.61-0.68 or less here.
The VM's speed drifts by up to 1.5x within minutes (one 1-thread canon_dng decode: 37-63 ms in consecutive processes;
JPEG-LS's decode 62-92 ms): hence in-process A/Bs with alternating order. metraw's time moves more than JPEG-LS's
with the host's mood (avx2 canon_dng 1-thread encode 38.0 ms in the day's first ``--speed`` run, 59.1 ms in this
session's first, +55 %, while JPEG-LS's went from 67.5 to 91.4 ms, +35 %): it moves far more memory per pixel. Taken, the same bytes and values: the avx2 inverse transform merges a 2-pixel-cell plane's 8 DN into
32-bit words (as the AVX-512 path does) instead of 8 word stores, canon_dng's 4 planes 4.86 -> 4.28 ms; the frame's
escape list is one more work item of the decoder's threads (canon_dng 2-thread decode 0.95-1.00x, median ~0.97, 8
runs); a row group's symbols are taken from the causal buffer right after the group (decode_plane replayed, 300
rounds: 0.994x). Then less memory: the decoder decodes a plane in a buffer of one row group's rows (+2 above, moved up
after each group) instead of the plane's (canon_dng 2 -> 0.2 MB a plane, micasense 4.8 -> 0.15 MB; decode_plane
replayed, 200 rounds: avx2 canon_dng 0.933-0.940x, micasense 0.956-0.967x; avx512 0.970-0.982x), and makes each
group's dither and puts out its DN right after it (no plane-size dither or symbol arrays; 2-thread decode against
the former, 30 rounds: avx2 canon_dng 0.934-0.939x, micasense 0.887-0.916x, spacenet_pan 0.945x; avx512
0.956-0.992x); the encoder makes, fits and passes over a tile's planes one after the other (one 2 MB causal buffer in
cache instead of four made first): 2-thread encode avx2 canon_dng 0.951-0.975x (1 thread 0.991x), single-plane tiles
unchanged; the tile's escapes as flat indices in one C pass that tests blocks of 256 DN whole (0.54 ms a canon_dng
tile for the mask and np.flatnonzero before): encode 0.982-0.991x. What stays on one core after the tiles: the escape
stream (``entropy.encode_streams``, 0.38 ms for canon_dng's 14 escapes, Python over small arrays) and the container
(0.27 ms). Tried, not taken: (1) the escape stream coded
likewise by the first free thread in the encoder: canon_dng 0.97-1.00x, micasense 1.02-1.03x (4 runs); (2) the dither
hashed in the avx2 steady loop instead of gathered from the dither plane: canon_dng decode 1.09x, micasense 1.00x
(with the dither pass still made; it is 0.9 ms a frame): ~13 vector instructions a vector step cost more than the
gather here; (3) one fused table by slot (symbol << 24 | (freq - 1) << 12 | slot - cum: one lookup instead of the
symbol's then its (freq, cum)) on every path: decode 0.987x / 1.026x (avx2 canon_dng / micasense), 1.009x (avx512
canon_dng): a plane's table grows from 128 to 512 KB and its build from 0.28 to 0.34 ms a tile; (4) the codec's two
threads pinned to the two CPUs: 0.98-1.02x. The avx2 decoder's steady loop runs ~230 instructions a vector step of 4
lanes (~57 a pixel; ~34 cycles a pixel at the VM's 2.3 GHz), its samples piling up after the symbol table's and the
(freq, cum) gathers (18 % and 14 %): what would cut it is a steady loop with the lanes' values in 32 bits (8 lanes a
register), a rewrite of the AVX2 kernel not begun.

Later still on 2026-11-29 (the next session; the same VM). The encoder's time per canon_dng tile on AVX2
(1 MP, 2 threads, the host slow): planes 4 x 0.82 ms, models 4 x 1.23, residuals 4 x 1.88, alphabet indices 2.1,
rANS 4.9. In the rANS pass, the lanes' walk over their rows took ~40 % (one entry load and store a symbol, ~2.3
cycles), and making the array of entries tab alpha + idx before it 13 %: the walk now reads tab and idx itself
(AVX-512: two gathers in place of one), with no array made first: the pass 0.86-0.93x (AVX2) and 0.68-0.73x
(AVX-512) on the three frames, replayed in one process against the former build; 1-thread canon_dng encode 0.93x
(AVX2) and 0.92x (AVX-512) in one such A/B, 0.98-0.99x in another (the VM's drift). The portable path keeps the array
(two element gathers: 1.33x slower). Tried, not taken: (1) the reciprocal 1 / freq loaded in the walk beside the
entry instead of divided in the step (AVX2): 1.03x, the division was not what bound the step; (2) the extension
built with -falign-loops=32: the rANS pass 0.98x, encode and decode within the noise; the code's layout moves the
rANS pass by up to 8 % between builds of the same source (the same walk loop at another address), so each A/B here
compares builds of one layout where it matters; (3) the least-squares Gram matrix in 2 x 2 register blocks instead
of one dot product a pair: its block 7.6 -> 5.4 us (0.1 ms a plane), but it changes the sums' order and so the
coefficients' last bits and the stream's bytes, for ~3 % of an encode: not taken.
"""

from __future__ import annotations

import argparse
import io
import math
import os
import sys
import threading
import time
import warnings
from pathlib import Path

import imagecodecs
import numpy as np

from metraw import codec
from metraw.codec import prepare
from metraw.codec.selfcheck import self_check
from metraw.io import read_raw
from metraw.raw.image import RawImage
from metraw.raw.profile import CalibrationProfile
from metraw.raw.sensor import expose, rng_from_seed

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
REAL_NAMES = ("canon_dng", "micasense", "spacenet_pan")


#: Each real frame's noise profile, fixed: the gain [DN/e-] and read noise [e-] that the single-frame fit
#: (metraw.calibrate.from_image) gave before e6ab38f (the fit of issue #51 item 3 returns other values and refuses
#: spacenet_pan), on top of the profile read_raw reads from the file (black and white level, CFA, camera); no frame
#: has unused low bits. The codec's bits depend on this profile: with it, canon_dng / micasense / spacenet_pan code
#: at 2.416 / 2.382 / 2.254 bpp at step 1, as in the tables above, whatever calibrate's fit does next.
REAL_PROFILES = {
    "canon_dng/colorchart.dng": {"gain_dn_per_e": 1.979204758086497, "read_noise_e": 5.889697818669081},
    "micasense/IMG_0000_1.tif": {"gain_dn_per_e": 1.2990650484412891, "read_noise_e": 6.298109637783334},
    "spacenet_pan/pan1.tif": {"gain_dn_per_e": 2.351707199275583, "read_noise_e": 0.0},
}


def frames():
    out = []
    for rel, fit in REAL_PROFILES.items():
        path = REAL / rel
        if not path.exists():
            continue
        img = read_raw(path)
        out.append((rel.split("/")[0], RawImage(img.data, img.profile.replace(**fit))))
    prof = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100, read_noise_e=3, white_level_dn=16000, adc_bits=14)
    yy, xx = np.mgrid[0:1024, 0:1536]
    mean = 50 + 20000 * (0.5 + 0.5 * np.sin(xx / 150.0) * np.cos(yy / 97.0))
    out.append(("synthetic", RawImage(expose(mean, prof, rng_from_seed(1)), prof)))
    # emulated-target sized RGGB images of 20-60 e- (the workflow's zarr blobs: no embedded profile)
    prof = prof.replace(cfa_pattern="RGGB")
    for n in (34, 68, 130):
        yy, xx = np.mgrid[0:n, 0:n]
        out.append((f"faint{n}x{n}", RawImage(expose(40 + 20 * np.sin(xx / 7.0) * np.cos(yy / 5.0), prof,
                                                      rng_from_seed(n)), prof)))
    return out


def side_by_side(fns, reps=9, cpu=False, samples=False, batch=1):
    """Median wall times [s] of several functions, run interleaved (same load for each); with
    ``cpu=True`` also the median process CPU times [s] (all threads): returns (walls, cpus).
    ``samples=True``: the lists of times instead of their medians. ``batch``: each sample is the
    mean over that many consecutive calls (throughput: a codec writing a stream of frames)."""
    ts = [[] for _ in fns]
    cs = [[] for _ in fns]
    for _ in range(reps):
        for t_list, c_list, fn in zip(ts, cs, fns):
            c = time.process_time()
            t = time.perf_counter()
            for _ in range(batch):
                fn()
            t_list.append((time.perf_counter() - t) / batch)
            c_list.append((time.process_time() - c) / batch)
    if samples:
        return (ts, cs) if cpu else ts
    walls = [float(np.median(t)) for t in ts]
    return (walls, [float(np.median(c)) for c in cs]) if cpu else walls


def speed_vs_jpegls(img, blob, jl, step, small):
    """metraw against lossless JPEG-LS (CharLS, single-threaded) on the same frame, interleaved:
    2-thread wall times and, with codec.THREADS = 1, single-thread CPU times (the cost per core,
    insensitive to other processes sharing the cores). Returns a dict of medians [s] and ratios."""
    d = img.data
    fns = [lambda: codec.encode(img, step, 0, embed_profile=not small),
           lambda: codec.decode(blob, profile=img.profile),
           lambda: imagecodecs.jpegls_encode(d), lambda: imagecodecs.jpegls_decode(jl)]
    threads = codec.THREADS
    try:
        (te, td, te_j, td_j), (ce2, cd2, _, _) = side_by_side(fns, cpu=True)
        codec.THREADS = 1
        _, (ce, cd, ce_j, cd_j) = side_by_side(fns, cpu=True)
    finally:
        codec.THREADS = threads
    return {"wall_enc": te, "wall_dec": td, "wall_enc_jls": te_j, "wall_dec_jls": td_j,
            "cpu1_enc": ce, "cpu1_dec": cd, "cpu1_enc_jls": ce_j, "cpu1_dec_jls": cd_j,
            # CPU time / wall time of the 2-thread runs: ~2 when the row tiles really run at once
            "par_enc": ce2 / te, "par_dec": cd2 / td}


def fpack(d, step):
    """fpack-style quantisation: astropy CompImageHDU, RICE_1, SUBTRACTIVE_DITHER_1 with
    quantize_level = 1 / step (fpack's step = its per-tile noise estimate / quantize_level).
    Returns the FITS file bytes (incl. two 2880-byte header blocks: see ``fpack_data_bytes``)."""
    from astropy.io import fits

    hdu = fits.CompImageHDU(data=d.astype(np.float32), compression_type="RICE_1", quantize_level=1.0 / step,
                            quantize_method=1, dither_seed=1)
    buf = io.BytesIO()
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(buf)
    return buf.getvalue()


def fpack_data_bytes(blob):
    """Bytes of the compressed image HDU's data (the FITS headers left out)."""
    from astropy.io import fits

    with fits.open(io.BytesIO(blob)) as f:
        return int(f[1].fileinfo()["datSpan"])


def fpack_decode(blob):
    from astropy.io import fits

    with fits.open(io.BytesIO(blob)) as f:
        out = np.asarray(f[1].data)
    return np.clip(np.rint(out), 0, 65535).astype(np.uint16)


def timed(fn, reps=5):
    """(result, median wall time [s]) over ``reps`` repetitions."""
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        r = fn()
        ts.append(time.perf_counter() - t)
    return r, float(np.median(ts))


def seed_bias(img, step, seeds=40):
    """Error averaged over ``seeds`` dither seeds: frame mean and per-decile means, each with its
    standard error (from the spread of per-seed means, so pixel correlations are accounted for)."""
    y = img.data
    ok = ~prepare.escape_mask(y, img.profile)
    sig = prepare.sigma_t_dn(y, img.profile)
    yv = y[ok].astype(np.float64)
    edges = np.unique(np.quantile(yv, np.linspace(0, 1, 11)))
    idx = np.clip(np.searchsorted(edges, yv, side="right") - 1, 0, edges.size - 2)
    cnt = np.maximum(np.bincount(idx, minlength=edges.size - 1), 1)
    frame, dec = [], []
    for s in range(seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = codec.decode(codec.encode(img, step, 1000 + s)).data
        with np.errstate(divide="ignore", invalid="ignore"):  # sigma_T = 0 only on escaped pixels
            e = ((d.astype(np.float64) - y) / sig)[ok]
        frame.append(e.mean())
        dec.append(np.bincount(idx, e, minlength=edges.size - 1) / cnt)
    frame, dec = np.array(frame), np.array(dec)
    se = lambda a: a.std(axis=0, ddof=1) / math.sqrt(seeds)  # noqa: E731
    worst = int(np.argmax(np.abs(dec.mean(0))))
    return frame.mean(), se(frame), dec.mean(0)[worst], se(dec)[worst], float(np.max(se(dec)))


def err_stats(img, dec_data, step_for_sigma=None):
    sig = prepare.sigma_t_dn(img.data, img.profile)
    with np.errstate(divide="ignore", invalid="ignore"):  # sigma_T = 0 only on escaped pixels
        e = (dec_data.astype(np.float64) - img.data) / sig
    ok = ~prepare.escape_mask(img.data, img.profile)
    ev = e[ok]
    c = np.corrcoef(e[:, :-2][ok[:, :-2] & ok[:, 2:]], e[:, 2:][ok[:, :-2] & ok[:, 2:]])[0, 1] if ev.std() > 0 else 0.0
    return ev.mean(), math.sqrt(np.mean(ev * ev)), c


SPEED_REPS = 21
#: Consecutive calls per sample (throughput, as when a store writes a stream of frames). On this VM an idle
#: core takes milliseconds to wake: the first 2-thread call after a pause runs its second tile late
#: (spacenet_pan encode: 6.7 ms as the first call after a 50 ms pause, 5.9 ms warm; JPEG-LS 8.4 / 8.2 ms).
SPEED_BATCH = 5


#: What ``--as-avx2-host`` sets before the benchmark starts again in a fresh process: the codec's AVX2 loops, numba's
#: code for a generic AVX2 + FMA + BMI2 CPU (its cache is kept per CPU name), numpy's dispatch and OpenBLAS's kernels
#: without AVX-512.
AVX2_HOST_ENV = {"METRAW_NATIVE": "avx2", "NUMBA_CPU_NAME": "x86-64-v3", "NUMBA_CPU_FEATURES": "",
                 "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR", "OPENBLAS_CORETYPE": "Haswell"}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="The module's docstring keeps the measurements and how they were made.")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--speed", action="store_true",
                      help="only the speed against JPEG-LS (real frames, steps 1 and 2; then the 20 MP frame)")
    mode.add_argument("--native", action="store_true",
                      help="the compiled loops against numba (1-thread CPU, real frames, step 1)")
    ap.add_argument("--paths", help="codec paths to time, comma-separated (default: every compiled path this host "
                                    "runs, then numba; with --as-avx2-host: avx2,portable,numba)")
    ap.add_argument("--reps", type=int, default=SPEED_REPS, help=f"rounds of --speed (default {SPEED_REPS})")
    ap.add_argument("--no-large", action="store_true", help="--speed without the 20 MP frame")
    ap.add_argument("--as-avx2-host", action="store_true",
                    help="run as on a CPU without AVX-512 (AVX2_HOST_ENV, in a fresh process)")
    args = ap.parse_args(argv)
    if args.reps < 1:
        ap.error("--reps must be >= 1")
    return args


#: The command line's options (``parse_args``; ``main`` sets them).
ARGS = parse_args([])


def _paths() -> list[str]:
    """The codec paths to time: ``--paths a,b`` or every compiled path this host runs, then numba."""
    from metraw.codec import native

    if ARGS.paths:
        return ARGS.paths.split(",")
    avail = [p for p in native.AVAILABLE if not (ARGS.as_avx2_host and p == "avx512")]
    return avail + ["numba"]


def _as_avx2_host() -> None:
    """Start this benchmark again with ``AVX2_HOST_ENV`` set (numba and numpy read theirs at import)."""
    if all(os.environ.get(k) == v for k, v in AVX2_HOST_ENV.items()):
        return
    print("# run as an AVX2-only host: " + " ".join(f"{k}={v!r}" for k, v in AVX2_HOST_ENV.items()), flush=True)
    os.execve(sys.executable, [sys.executable, *sys.argv], {**os.environ, **AVX2_HOST_ENV})


def _print_host() -> None:
    from metraw.codec import native

    print(f"# CPU: {native.cpu()}; codec path at import: {native.PATH} (METRAW_NATIVE="
          f"{os.environ.get('METRAW_NATIVE', '')!r}), available: {', '.join(native.AVAILABLE) or 'none'}; numba's "
          f"code for {os.environ.get('NUMBA_CPU_NAME') or 'this CPU'}; numpy's AVX-512 kernels "
          f"{'on' if _numpy_avx512() else 'off'}")


def _numpy_avx512() -> bool:
    """Whether numpy's runtime dispatch runs AVX-512 kernels (``NPY_DISABLE_CPU_FEATURES`` turns them off)."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # numpy < 2 or a layout without it: say what the CPU has
        return "avx512f" in open("/proc/cpuinfo").read() if os.path.exists("/proc/cpuinfo") else False
    return bool(__cpu_features__.get("X86_V4", __cpu_features__.get("AVX512_SKX", False)))


def two_at_once(fn) -> float:
    """Wall time [s] of two calls of ``fn`` at once, one on a helper thread (``fn`` must release the GIL, as CharLS
    does): against one call's, what two threads of independent work give on this host."""
    t = time.perf_counter()
    helper = threading.Thread(target=fn)
    helper.start()
    fn()
    helper.join()
    return time.perf_counter() - t


def speed_main() -> int:
    """``--speed``: only the speed comparison with lossless JPEG-LS on the real frames (steps 1, 2), for every codec
    path (``--paths``; default: each compiled path this host runs and numba).

    All (path, frame, step) cases run round-robin, ``SPEED_REPS`` rounds (``--reps``): each round times every case's
    metraw encode/decode on 2 threads, then on 1 thread, each next to CharLS. A spell in which the shared machine
    gives this process one core then hits every case alike instead of one row."""
    from metraw.codec import native

    reps, paths = ARGS.reps, _paths()
    _print_host()
    print(f"# load: {os.getloadavg()} at the start; medians of {reps} rounds, all cases "
          f"round-robin, each interleaved with JPEG-LS (CharLS); a sample = mean of {SPEED_BATCH} consecutive calls")
    print(f"{'path':8s} {'frame':12s} {'MP':>4s} {'q':>4s} {'bpp':>6s} {'enc ms':>7s} {'dec ms':>7s} {'jls e':>6s} "
          f"{'jls d':>6s} {'wall2 e':>7s} {'wall2 d':>7s} | {'cpu1 ms e':>9s} {'cpu1 ms d':>9s} {'jls e':>6s} "
          f"{'jls d':>6s} {'cpu1 e':>6s} {'cpu1 d':>6s} {'par e':>5s} {'par d':>5s} {'won e':>5s} {'won d':>5s} | "
          f"{'Mpx/s e2':>8s} {'Mpx/s d2':>8s} {'Mpx/s e1':>8s} {'Mpx/s d1':>8s}")
    cases = []
    for name, img in frames():
        if name not in REAL_NAMES:
            continue
        jl = imagecodecs.jpegls_encode(img.data)
        for step in (1.0, 2.0):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                blob = codec.encode(img, step, 0)
            cases.append((name, step, img, blob, jl))
    # per path and case: [2-thread walls, 2-thread cpus, 1-thread cpus], each 4 lists (enc, dec, jls enc, jls dec)
    samples = {p: [[[[] for _ in range(4)] for _ in range(3)] for _ in cases] for p in paths}
    capacity = [([], []) for _ in range(2)]   # JPEG-LS encode, decode: (one call's walls, two at once)
    threads, before = codec.THREADS, native.PATH
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for _ in range(reps):
                for path in paths:
                    native.use(path)
                    for (name, step, img, blob, jl), smp in zip(cases, samples[path]):
                        d = img.data
                        fns = [lambda: codec.encode(img, step, 0), lambda: codec.decode(blob, profile=img.profile),
                               lambda: imagecodecs.jpegls_encode(d), lambda: imagecodecs.jpegls_decode(jl)]
                        for nthreads, walls, cpus in ((threads, smp[0], smp[1]), (1, None, smp[2])):
                            codec.THREADS = nthreads
                            w, c = side_by_side(fns, reps=1, cpu=True, samples=True, batch=SPEED_BATCH)
                            for k in range(4):
                                if walls is not None:
                                    walls[k] += w[k]
                                cpus[k] += c[k]
                # the host's 2-thread capacity in the same rounds: a JPEG-LS call alone, then two at once
                d, jl = cases[0][2].data, cases[0][4]
                for (one, two), fn in zip(capacity, (lambda: imagecodecs.jpegls_encode(d),
                                                     lambda: imagecodecs.jpegls_decode(jl))):
                    t = time.perf_counter()
                    fn()
                    one.append(time.perf_counter() - t)
                    two.append(two_at_once(fn))
    finally:
        codec.THREADS = threads
        native.use(before)
    for path in paths:
        for (name, step, img, blob, jl), (walls, cpus2, cpus1) in zip(cases, samples[path]):
            te, td, te_j, td_j = (float(np.median(v)) for v in walls)
            ce2, cd2 = float(np.median(cpus2[0])), float(np.median(cpus2[1]))
            ce, cd, ce_j, cd_j = (float(np.median(v)) for v in cpus1)
            # share of rounds in which metraw (2 threads) beat JPEG-LS, encode and decode
            won_e = np.mean(np.array(walls[0]) < np.array(walls[2]))
            won_d = np.mean(np.array(walls[1]) < np.array(walls[3]))
            mp = img.data.size / 1e6
            print(f"{path:8s} {name:12s} {mp:4.1f} {step:4.1f} {8 * len(blob) / img.data.size:6.3f} {te * 1e3:7.1f} "
                  f"{td * 1e3:7.1f} {te_j * 1e3:6.1f} {td_j * 1e3:6.1f} {te_j / te:7.2f} {td_j / td:7.2f} | "
                  f"{ce * 1e3:9.1f} {cd * 1e3:9.1f} {ce_j * 1e3:6.1f} {cd_j * 1e3:6.1f} {ce / ce_j:6.2f} {cd / cd_j:6.2f} "
                  f"{ce2 / te:5.2f} {cd2 / td:5.2f} {won_e:5.2f} {won_d:5.2f} | {mp / te:8.1f} {mp / td:8.1f} "
                  f"{mp / ce:8.1f} {mp / cd:8.1f}")
    print("# wall2 = JPEG-LS wall / metraw wall, metraw on 2 threads (> 1: metraw faster); cpu1 = metraw CPU time "
          "on 1 thread / JPEG-LS CPU time; par = metraw CPU / wall on 2 threads (2: tiles fully concurrent); "
          "won = share of rounds in which metraw's 2-thread wall time beat JPEG-LS's; Mpx/s e2/d2 = megapixels per "
          "second of wall time on 2 threads, e1/d1 per second of CPU time on 1 thread")
    cap = [2 * float(np.median(one)) / float(np.median(two)) for one, two in capacity]
    print(f"# host: two JPEG-LS calls at once on 2 threads ({cases[0][0]}, the same rounds) do x{cap[0]:.2f} / "
          f"x{cap[1]:.2f} (encode / decode) the work of one in one call's time; at that capacity wall2 >= 3 needs "
          f"cpu1 <= {cap[0] / 3:.2f} / {cap[1] / 3:.2f} (before metraw's own 2-thread overheads)")
    print(f"# load: {os.getloadavg()} at the end")
    if not ARGS.no_large:
        print(f"# the 20 MP frame on the path at import, {native.PATH}")
        speed_large()
    return 0


#: Rounds of the 20 MP frame's timing (each call takes ~0.2-0.5 s: fewer rounds than the real frames).
LARGE_REPS = 7


def large_frame() -> RawImage:
    """A 20.0 MP RGGB frame (5472 x 3648, a 1"-sensor camera's size) from the sensor model: a smooth
    scene with edges and fine texture, 50 to 20000 e-, 14-bit. Deterministic (seeded)."""
    prof = CalibrationProfile(gain_dn_per_e=0.5, black_level_dn=100, read_noise_e=3, white_level_dn=16000,
                              adc_bits=14, cfa_pattern="RGGB")
    yy, xx = np.mgrid[0:3648, 0:5472].astype(np.float32)
    mean = (50 + 20000 * (0.5 + 0.5 * np.sin(xx / 150.0) * np.cos(yy / 97.0))
            * (1 + 0.3 * np.sign(np.sin(xx / 41.0 + yy / 53.0))) / 1.3
            + 300 * np.sin(xx / 2.7) * np.sin(yy / 3.1) ** 2)
    return RawImage(expose(np.maximum(mean, 0.0), prof, rng_from_seed(20)), prof)


def speed_large() -> None:
    """Absolute times and Mpix/s on the 20 MP frame (steps 1 and 2), interleaved with JPEG-LS: metraw on
    2 threads (wall) and on 1 thread (CPU), medians of ``LARGE_REPS`` rounds."""
    img = large_frame()
    d = img.data
    jl = imagecodecs.jpegls_encode(d)
    mp = d.size / 1e6
    print(f"\n# 20 MP frame ({d.shape[1]} x {d.shape[0]} RGGB, synthetic, sensor model): medians of {LARGE_REPS} "
          f"rounds, load {os.getloadavg()} at the start")
    print(f"{'step':>4s} {'bpp':>6s} {'jls bpp':>7s} | {'wall2 e ms':>10s} {'wall2 d ms':>10s} {'jls e ms':>8s} {'jls d ms':>8s} "
          f"{'x jls e':>7s} {'x jls d':>7s} | {'cpu1 e ms':>9s} {'cpu1 d ms':>9s} {'jls e':>6s} {'jls d':>6s} "
          f"{'cpu1 e':>6s} {'cpu1 d':>6s} | {'Mpx/s e2':>8s} {'Mpx/s d2':>8s} {'Mpx/s e1':>8s} {'Mpx/s d1':>8s}")
    threads = codec.THREADS
    try:
        for step in (1.0, 2.0):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                blob = codec.encode(img, step, 0)
                fns = [lambda: codec.encode(img, step, 0), lambda: codec.decode(blob),
                       lambda: imagecodecs.jpegls_encode(d), lambda: imagecodecs.jpegls_decode(jl)]
                walls = [[] for _ in fns]
                cpus = [[] for _ in fns]
                for _ in range(LARGE_REPS):
                    for nthreads, dest in ((threads, walls), (1, cpus)):
                        codec.THREADS = nthreads
                        w, c = side_by_side(fns, reps=1, cpu=True, samples=True)
                        for k in range(4):
                            dest[k] += (w if dest is walls else c)[k]
            te, td, te_j, td_j = (float(np.median(v)) for v in walls)
            ce, cd, ce_j, cd_j = (float(np.median(v)) for v in cpus)
            print(f"{step:4.1f} {8 * len(blob) / d.size:6.3f} {8 * len(jl) / d.size:7.3f} | {te * 1e3:10.1f} {td * 1e3:10.1f} "
                  f"{te_j * 1e3:8.1f} {td_j * 1e3:8.1f} {te_j / te:7.2f} {td_j / td:7.2f} | {ce * 1e3:9.1f} {cd * 1e3:9.1f} "
                  f"{ce_j * 1e3:6.1f} {cd_j * 1e3:6.1f} {ce / ce_j:6.2f} {cd / cd_j:6.2f} | {mp / te:8.1f} {mp / td:8.1f} "
                  f"{mp / ce:8.1f} {mp / cd:8.1f}")
    finally:
        codec.THREADS = threads
    print("# x jls = JPEG-LS wall / metraw wall (metraw on 2 threads); cpu1 = metraw CPU on 1 thread / JPEG-LS CPU")


def native_main(rounds: int = 11) -> int:
    """1-thread CPU of encode and decode on each codec path (``--paths``; default: each compiled path this host runs,
    and numba's loops), same process, alternating; medians of ``rounds`` (a sample: 3 calls; encode without the
    profile check), and JPEG-LS (CharLS) on the same frame for scale."""
    from metraw.codec import native

    _print_host()
    paths, before, threads = _paths(), native.PATH, codec.THREADS
    print(f"# load: {os.getloadavg()} at the start; two_vectors={native.TWO_VECTORS}; 1-thread CPU ms (x JPEG-LS)")
    codec.THREADS = 1
    try:
        for name, img in frames():
            if name not in REAL_NAMES:
                continue
            blob = codec.encode(img, 1.0, 0, check_profile=False)
            jl = imagecodecs.jpegls_encode(img.data)
            d = img.data
            ms = {}
            for _ in range(rounds):
                for key in paths + ["JPEG-LS"]:
                    if key != "JPEG-LS":
                        native.use(key)
                    enc = (lambda: imagecodecs.jpegls_encode(d)) if key == "JPEG-LS" else \
                        (lambda: codec.encode(img, 1.0, 0, check_profile=False))
                    dec = (lambda: imagecodecs.jpegls_decode(jl)) if key == "JPEG-LS" else (lambda: codec.decode(blob))
                    for what, fn in (("enc", enc), ("dec", dec)):
                        t = time.process_time()
                        for _ in range(3):
                            fn()
                        ms.setdefault((what, key), []).append((time.process_time() - t) / 3 * 1e3)
            m = {k: float(np.median(v)) for k, v in ms.items()}
            cells = "   ".join(f"{p} {m['enc', p]:6.1f} ({m['enc', p] / m['enc', 'JPEG-LS']:.2f}) / "
                               f"{m['dec', p]:6.1f} ({m['dec', p] / m['dec', 'JPEG-LS']:.2f})" for p in paths)
            print(f"{name:13s} encode / decode: {cells}   JPEG-LS {m['enc', 'JPEG-LS']:6.1f} / {m['dec', 'JPEG-LS']:6.1f}")
    finally:
        native.use(before)
        codec.THREADS = threads
    return 0


def main() -> int:
    global ARGS
    ARGS = parse_args()
    if ARGS.as_avx2_host:
        _as_avx2_host()
    if ARGS.speed:
        return speed_main()
    if ARGS.native:
        return native_main()
    print(f"# load: {os.getloadavg()} at the start (2 cores)")
    rows = []
    rd = {}
    accept = []
    for name, img in frames():
        d = img.data
        mb = d.nbytes / 1e6
        n = d.size

        def row(method, blob_len, te, td, bias, rms, corr):
            rows.append((name, method, 8 * blob_len / n, 16 * n / 8 / blob_len, mb / te, mb / td, bias, rms, corr))

        jl, te = timed(lambda: imagecodecs.jpegls_encode(d))
        _, td = timed(lambda: imagecodecs.jpegls_decode(jl))
        row("jpegls lossless", len(jl), te, td, 0, 0, 0)
        jls_te, jls_td = te, td
        z, te = timed(lambda: imagecodecs.zstd_encode(d.tobytes(), level=9))
        _, td = timed(lambda: imagecodecs.zstd_decode(z))
        row("zstd-9", len(z), te, td, 0, 0, 0)
        try:
            aec_kw = dict(bitspersample=16, flags=imagecodecs.AEC.FLAG.DATA_PREPROCESS)
            a, te = timed(lambda: imagecodecs.aec_encode(d, **aec_kw))
            ad, td = timed(lambda: imagecodecs.aec_decode(a, **aec_kw))
            # libaec pads the last block: keep the first d.size samples
            assert np.array_equal(np.frombuffer(ad, np.uint16)[:d.size].reshape(d.shape), d), "aec round trip differs"
            row("aec (ccsds-121)", len(a), te, td, 0, 0, 0)
        except Exception as exc:  # noqa: BLE001
            print(f"# aec failed on {name}: {exc}", file=sys.stderr)
        try:
            x, te = timed(lambda: imagecodecs.jpegxl_encode(d, lossless=True, effort=3), reps=1)
            _, td = timed(lambda: imagecodecs.jpegxl_decode(x), reps=1)
            row("jpegxl lossless e3", len(x), te, td, 0, 0, 0)
        except Exception as exc:  # noqa: BLE001
            print(f"# jpegxl failed on {name}: {exc}", file=sys.stderr)
        sig_med = float(np.median(prepare.sigma_t_dn(d, img.profile)))
        small = name.startswith("faint")
        for step in (0.5, 1.0, 2.0):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                blob = codec.encode(img, step, 0, embed_profile=not small)
                sp = speed_vs_jpegls(img, blob, jl, step, small)
                te, td = sp["wall_enc"], sp["wall_dec"]
            dec = codec.decode(blob, profile=img.profile)
            s = self_check(img, dec, step)
            row(f"metraw q={step}", len(blob), te, td, s["mean_error_sigma"], s["rms_error_sigma"], s["neighbour_corr"])
            rows[-1] = rows[-1] + (math.log2(math.sqrt(2 * math.pi * math.e) / step), s["worst_decile_mean_sigma"],
                                   s["bound_violations"], s["mean_error_se_sigma"])
            rd.setdefault(name, {}).setdefault("metraw", []).append((s["rms_error_sigma"], 8 * len(blob) / n))
            seeds = 100 if name == "spacenet_pan" else 40
            sb = seed_bias(img, step, seeds) if name in REAL_NAMES else (math.nan,) * 5
            accept.append((name, step, 8 * len(blob) / n, math.log2(math.sqrt(2 * math.pi * math.e) / step),
                           16 * n / 8 / len(blob), mb / te, mb / td, sp, sb,
                           s["rms_over_uniform"], s["rms_over_expected"], s["neighbour_corr"],
                           s["bound_violations"], s["issue_bound_violations"]))
            # JPEG-LS near-lossless with the same max error as metraw's median-sigma bound
            near = max(1, int(step * sig_med / 2))
            jn, te = timed(lambda: imagecodecs.jpegls_encode(d, level=near))
            dn, td = timed(lambda: imagecodecs.jpegls_decode(jn))
            b, r, c = err_stats(img, dn)
            row(f"jpegls near={near}", len(jn), te, td, b, r, c)
            try:
                fp, te = timed(lambda: fpack(d, step), reps=3)
                fd, td = timed(lambda: fpack_decode(fp), reps=3)
                b, r, c = err_stats(img, fd)
                row(f"fpack q={step} (rice)", len(fp), te, td, b, r, c)
                row(f"  fpack data only", fpack_data_bytes(fp), te, td, b, r, c)
                rd[name].setdefault("fpack", []).append((r, 8 * len(fp) / n))
            except Exception as exc:  # noqa: BLE001
                print(f"# fpack failed: {exc}", file=sys.stderr)
            rd[name].setdefault("jpegls-nl", []).append((r, 8 * len(jn) / n))
            try:
                lz, te = timed(lambda: imagecodecs.lerc_encode(d, level=float(near)))
                ld, td = timed(lambda: imagecodecs.lerc_decode(lz))
                b, r, c = err_stats(img, np.asarray(ld))
                row(f"lerc maxerr={near}", len(lz), te, td, b, r, c)
                rd[name].setdefault("lerc", []).append((r, 8 * len(lz) / n))
            except Exception as exc:  # noqa: BLE001
                print(f"# lerc failed: {exc}", file=sys.stderr)
    print(f"{'frame':12s} {'method':20s} {'bpp':>6s} {'ratio':>6s} {'encMB/s':>8s} {'decMB/s':>8s} "
          f"{'bias[s]':>9s} {'rms[s]':>7s} {'nbcorr':>7s} {'bound':>6s} {'worstdec':>9s} {'viol':>4s} {'biasSE':>8s}")
    for r in rows:
        extra = f" {r[9]:6.3f} {r[10]:9.2e} {int(r[11]):4d} {r[12]:8.1e}" if len(r) > 9 else ""
        print(f"{r[0]:12s} {r[1]:20s} {r[2]:6.3f} {r[3]:6.2f} {r[4]:8.1f} {r[5]:8.1f} {r[6]:9.2e} {r[7]:7.4f} {r[8]:7.4f}{extra}")
    print("\n# acceptance: bias averaged over dither seeds (100 for spacenet_pan, 40 for the other real frames; "
          "mean +- standard error); speed: medians of 9 repetitions interleaved with lossless JPEG-LS (CharLS, "
          "single-threaded). wall2 = JPEG-LS wall time / metraw wall time with 2 threads (> 1: metraw faster); "
          "cpu1 = metraw CPU time with 1 thread / JPEG-LS CPU time (cost per core; < 2 means 2 free cores "
          "beat JPEG-LS); par = metraw CPU time / wall time with 2 threads (2 = tiles fully concurrent)")
    print(f"# load: {os.getloadavg()} at the end (2 cores)")
    print(f"{'frame':12s} {'q':>4s} {'bpp':>6s} {'bound':>6s} {'excess':>6s} {'x16bit':>6s} {'encMB/s':>8s} {'decMB/s':>8s} "
          f"{'wall2 e':>7s} {'wall2 d':>7s} {'cpu1 e':>6s} {'cpu1 d':>6s} {'par e':>5s} {'par d':>5s} {'bias[s] +- se':>20s} {'worst decile +- se':>20s} {'rms/(q/v12)':>11s} "
          f"{'rms/exp':>7s} {'nbcorr':>7s} {'viol':>4s} {'viol(q/2+.5)':>12s}")
    for a in accept:
        sp, sb = a[7], a[8]
        print(f"{a[0]:12s} {a[1]:4.1f} {a[2]:6.3f} {a[3]:6.3f} {a[2] - a[3]:6.3f} {a[4]:6.2f} {a[5]:8.1f} {a[6]:8.1f} "
              f"{sp['wall_enc_jls'] / sp['wall_enc']:7.2f} {sp['wall_dec_jls'] / sp['wall_dec']:7.2f} "
              f"{sp['cpu1_enc'] / sp['cpu1_enc_jls']:6.2f} {sp['cpu1_dec'] / sp['cpu1_dec_jls']:6.2f} "
              f"{sp['par_enc']:5.2f} {sp['par_dec']:5.2f} {sb[0]:+9.1e} +- {sb[1]:7.1e} {sb[2]:+9.1e} +- {sb[3]:7.1e} {a[9]:11.4f} "
              f"{a[10]:7.4f} {a[11]:+7.4f} {int(a[12]):4d} {int(a[13]):12d}")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 4))
        for name, methods in rd.items():
            if name.startswith("faint"):
                continue
            for m, pts in methods.items():
                pts = sorted(pts)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-" if m == "metraw" else "x--", label=f"{name} {m}")
        q = np.linspace(0.4, 2.2, 50)
        ax.plot(q / math.sqrt(12), np.log2(math.sqrt(2 * math.pi * math.e) / q), "k:", label="log2(sqrt(2 pi e)/q)")
        ax.set_xlabel("rms added error [sigma]")
        ax.set_ylabel("bits/pixel")
        ax.legend(fontsize=5)
        out = Path(__file__).resolve().parents[1] / "docs" / "figures" / "codec_rd.png"
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.tight_layout()
        fig.savefig(out, dpi=120)
        print(f"# wrote {out}")
    except Exception as exc:  # noqa: BLE001
        print(f"# plot failed: {exc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
