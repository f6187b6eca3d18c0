"""Scanline rasterisation of a ``Scene``'s shapes on the supersampled grid (render step 1).

Each sample (r, c) has its centre at x = c, y = r in sample units. A convex polygon covers the samples whose
centres satisfy every edge's half-plane test; a disc the samples within its radius. Shapes are painted in
the order given (``rasterise``: by increasing height, so a tree crown hides the car below it), each
overwriting the samples it covers.

The spans are computed and painted in compiled loops (numba), one call per scene: the arithmetic per row is
the former per-shape numpy code's, operation for operation (float64, no fused multiply-add), including the
polygon's orientation, a sum in numpy's pairwise order (``_numpy_sum``). So the painted grids are
bit-identical to it, which tests/test_scenes.py checks against a plain-numpy reference.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: Largest number of objects a scene may hold (object ids are stored as uint16).
MAX_OBJECTS = 65535


#: Longest vertex list whose orientation the compiled code sums (numpy's pairwise sum is one block up to here).
PAIRWISE_BLOCK = 128


@nb.njit(cache=True, nogil=True)
def _numpy_sum(a, n):
    """sum(a[:n]) for n <= ``PAIRWISE_BLOCK`` in the order of numpy's pairwise summation (``np.sum`` of a
    contiguous float64 array): sequential below 8 terms, else 8 interleaved partial sums."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    i = 8
    end = n - n % 8
    while i < end:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[i]
        i += 1
    return res


def _orientation(verts: np.ndarray) -> float:
    """+1 where twice the polygon's signed (shoelace) area is >= 0, else -1, summed by numpy (the compiled
    loop's ``_numpy_sum`` gives the same sum for short vertex lists)."""
    p, q = verts, np.roll(verts, -1, axis=0)
    return 1.0 if float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1])) >= 0 else -1.0


@nb.njit(cache=True, nogil=True)
def _fill_row(target, r, lo, hi, value):
    for c in range(lo, hi):
        target[r, c] = value


@nb.njit(cache=True, nogil=True)
def _paint_polygon(target, vx, vy, lo_v, hi_v, value, sign, cross):
    """Paint the convex polygon with vertices (vx, vy)[lo_v:hi_v] (sample units) with ``value``; ``sign`` is its
    ``_orientation`` or 0 (computed here: at most ``PAIRWISE_BLOCK`` vertices); ``cross`` is scratch of at
    least hi_v - lo_v entries."""
    n_rows, n_cols = target.shape
    k = hi_v - lo_v
    ymin, ymax = vy[lo_v], vy[lo_v]
    for i in range(lo_v, hi_v):
        ymin = min(ymin, vy[i])
        ymax = max(ymax, vy[i])
    y0 = max(0, int(np.ceil(ymin)))
    y1 = min(n_rows - 1, int(np.floor(ymax)))
    if y1 < y0:
        return
    if sign == 0:
        for i in range(k):
            j = (i + 1) % k
            cross[i] = vx[lo_v + i] * vy[lo_v + j] - vx[lo_v + j] * vy[lo_v + i]
        sign = 1.0 if _numpy_sum(cross, k) >= 0 else -1.0
    for r in range(y0, y1 + 1):
        row = float(r)
        xmin = -np.inf
        xmax = np.inf
        for i in range(k):
            j = (i + 1) % k
            px, py, qx, qy = vx[lo_v + i], vy[lo_v + i], vx[lo_v + j], vy[lo_v + j]
            # inside: sign * ((qx-px)(Y-py) - (qy-py)(X-px)) >= 0  ->  a X + b >= 0
            a = -sign * (qy - py)
            b = sign * ((qx - px) * (row - py) + (qy - py) * px)
            if a > 0:
                xmin = max(xmin, -b / a)
            elif a < 0:
                xmax = min(xmax, -b / a)
            elif not b >= 0:
                xmax = -np.inf
        lo = int(min(max(np.ceil(xmin), 0.0), float(n_cols)))  # np.ceil: inf stays a float (math.ceil: an int)
        hi = int(min(max(np.floor(xmax) + 1.0, 0.0), float(n_cols)))
        _fill_row(target, r, lo, hi, value)


@nb.njit(cache=True, nogil=True)
def _disc_rows(cy, rad, n_rows):
    """First and last row of a disc's samples (last < first when none)."""
    return max(0, int(np.ceil(cy - rad))), min(n_rows - 1, int(np.floor(cy + rad)))


@nb.njit(cache=True, nogil=True)
def _disc_span(cx, cy, rad, r, n_cols):
    """[lo, hi) columns of the disc's samples on row ``r``."""
    dy = float(r) - cy
    half = math.sqrt(max(rad * rad - dy * dy, 0.0))
    return (int(min(max(np.ceil(cx - half), 0.0), float(n_cols))),
            int(min(max(np.floor(cx + half) + 1.0, 0.0), float(n_cols))))


@nb.njit(cache=True, nogil=True)
def _paint_disc(target, cx, cy, rad, value):
    """Paint the disc of centre (cx, cy) and radius ``rad`` (sample units) with ``value``."""
    n_rows, n_cols = target.shape
    y0, y1 = _disc_rows(cy, rad, n_rows)
    for r in range(y0, y1 + 1):
        lo, hi = _disc_span(cx, cy, rad, r, n_cols)
        _fill_row(target, r, lo, hi, value)


@nb.njit(cache=True, nogil=True)
def _disc_spans(cx, cy, rad, n_rows, n_cols):
    y0, y1 = _disc_rows(cy, rad, n_rows)
    n = max(y1 - y0 + 1, 0)
    rows, lo, hi = np.arange(y0, y0 + n), np.empty(n, np.int64), np.empty(n, np.int64)
    for k in range(n):
        lo[k], hi[k] = _disc_span(cx, cy, rad, y0 + k, n_cols)
    return rows, lo, hi


@nb.njit(cache=True, nogil=True)
def _paint(target, is_disc, values, disc, vx, vy, vstart, sign):
    """Paint shapes 0, 1, ... in turn: shape i is the disc ``disc[i]`` (cx, cy, r) where ``is_disc[i]``, else the
    polygon with vertices vstart[i] .. vstart[i + 1] - 1 of (vx, vy) and orientation ``sign[i]`` (0: computed
    here); its value is ``values[i]``."""
    kmax = 1
    for i in range(values.size):
        kmax = max(kmax, vstart[i + 1] - vstart[i])
    cross = np.empty(kmax)
    for i in range(values.size):
        if is_disc[i]:
            _paint_disc(target, disc[i, 0], disc[i, 1], disc[i, 2], values[i])
        else:
            _paint_polygon(target, vx, vy, vstart[i], vstart[i + 1], values[i], sign[i], cross)


def paint(target: np.ndarray, shapes: list, values: np.ndarray) -> None:
    """Paint ``shapes`` in turn onto ``target`` (2-D, sample units): each is a polygon, a (k, 2) float64 array
    of (x, y) vertices, or a disc, a tuple (cx, cy, r); ``values`` holds one value per shape (target's dtype)."""
    n = len(shapes)
    is_disc = np.zeros(n, np.bool_)
    disc = np.zeros((n, 3))
    polys = []
    vstart = np.zeros(n + 1, np.int64)
    sign = np.zeros(n)
    for i, s in enumerate(shapes):
        if isinstance(s, tuple):
            is_disc[i] = True
            disc[i] = s
            vstart[i + 1] = vstart[i]
        else:
            polys.append(s)
            vstart[i + 1] = vstart[i] + len(s)
            if len(s) > PAIRWISE_BLOCK:
                sign[i] = _orientation(s)
    verts = np.concatenate(polys) if polys else np.zeros((0, 2))
    _paint(target, is_disc, np.asarray(values, target.dtype), disc, np.ascontiguousarray(verts[:, 0]),
           np.ascontiguousarray(verts[:, 1]), vstart, sign)


def disc_spans(cx: float, cy: float, r: float, n_rows: int, n_cols: int):
    """Row indices and [lo, hi) column spans (int64 arrays) of the sample centres in a disc (sample units), as
    ``paint`` covers them, or None when it covers no row."""
    rows, lo, hi = _disc_spans(float(cx), float(cy), float(r), int(n_rows), int(n_cols))
    return (rows, lo, hi) if rows.size else None


def rasterise(scene, size_px: int, gsd_m: float, supersample: int):
    """Object id and caster height per sample, and the tree-crown discs painted.

    Returns ``(obj, caster_h, crowns)``: two arrays of shape (size_px * supersample,) * 2 (uint16 object ids,
    float32 caster heights [m]) and a list of ``(object, cx, cy, r, spans)`` in sample units (``disc_spans``).
    """
    n = size_px * supersample
    d = gsd_m / supersample  # metres per sample
    heights = np.asarray(scene.height_m)
    if len(heights) > MAX_OBJECTS:
        raise ValueError("too many objects in one scene")
    order = sorted(range(len(scene.shapes)), key=lambda i: (heights[_shape_obj(scene.shapes[i])], i))
    shapes, values, crowns = [], [], []
    for i in order:
        shape = scene.shapes[i]
        if isinstance(shape[0], str):
            _, cx, cy, r, o = shape
            disc = (cx / d - 0.5, cy / d - 0.5, r / d)
            shapes.append(disc)
            if scene.crown[o]:
                spans = disc_spans(*disc, n, n)
                if spans is not None:
                    crowns.append((o, *disc, spans))
        else:
            verts, o = shape
            shapes.append(verts / d - 0.5)
        values.append(o)
    obj = np.zeros((n, n), np.uint16)
    paint(obj, shapes, np.asarray(values, np.uint16))
    casters = sorted(scene.casters, key=lambda c: c[1])
    caster_h = np.zeros((n, n), np.float32)
    paint(caster_h, [poly / d - 0.5 for poly, _ in casters], np.asarray([h for _, h in casters], np.float32))
    return obj, caster_h, crowns


def _shape_obj(shape) -> int:
    return shape[4] if isinstance(shape[0], str) else shape[1]
