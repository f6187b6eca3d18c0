"""Colour filter array (CFA) patterns.

A pattern is a 4-letter string read row-major over a 2 x 2 cell ("RGGB" means R at (0, 0),
G at (0, 1) and (1, 0), B at (1, 1)), or "mono" for a sensor without a CFA. Each colour plane
is its own signal: noise models, codecs and emulation work per plane.
"""

from __future__ import annotations

import numpy as np

from metraw.errors import MetrawError

BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
PATTERNS = BAYER_PATTERNS + ("mono",)


def cfa_family(pattern: str) -> str:
    """``bayer`` for any Bayer phase (a different phase is not a different sensor), else the pattern."""
    return "mono" if pattern == "mono" else "bayer"


def validate_pattern(pattern: str) -> str:
    if pattern not in PATTERNS:
        raise MetrawError(f"unsupported CFA pattern {pattern!r}; expected one of {', '.join(PATTERNS)}")
    return pattern


def channel_names(pattern: str) -> tuple[str, ...]:
    """Distinct colours of a pattern in R, G, B order, or ("L",) for mono."""
    validate_pattern(pattern)
    return ("L",) if pattern == "mono" else ("R", "G", "B")


def cell_size(pattern: str) -> int:
    """Side of the repeating CFA cell in pixels (2 for Bayer, 1 for mono)."""
    return 1 if validate_pattern(pattern) == "mono" else 2


#: Side [pixels] of the cell the segmenter packs every mosaic in (`pack_planes` with the 2 x 2 geometry of
#: ``PACKED_GEOMETRY``): a Bayer cell's four sites, or four neighbouring pixels of a mono sensor, become four
#: planes at half resolution, so a mono network costs what a Bayer one does on the same pixels.
PACKED_CELL_PX = 2
#: The site order of the packed 2 x 2 cell (R G / G B positions; for mono, four pixels of one colour).
PACKED_GEOMETRY = "RGGB"


def fill_factor(pattern: str, channel: str) -> float:
    """Fraction phi_c of pixels carrying colour ``channel`` (R, B: 1/4, G: 1/2, mono: 1)."""
    if pattern == "mono":
        return 1.0
    return pattern.count(channel) / 4.0


def color_index(pattern: str, shape: tuple[int, int]) -> np.ndarray:
    """Per-pixel index into ``channel_names(pattern)`` for an image of ``shape`` (uint8)."""
    names = channel_names(pattern)
    h, w = shape
    if pattern == "mono":
        return np.zeros(shape, dtype=np.uint8)
    cell = np.array([[names.index(pattern[0]), names.index(pattern[1])],
                     [names.index(pattern[2]), names.index(pattern[3])]], dtype=np.uint8)
    return np.tile(cell, ((h + 1) // 2, (w + 1) // 2))[:h, :w]


def plane_offsets(pattern: str) -> list[tuple[str, int, int]]:
    """The sub-lattices of a pattern: (colour, row offset, column offset), one per cell site."""
    if validate_pattern(pattern) == "mono":
        return [("L", 0, 0)]
    return [(pattern[0], 0, 0), (pattern[1], 0, 1), (pattern[2], 1, 0), (pattern[3], 1, 1)]


def split_planes(data: np.ndarray, pattern: str) -> list[np.ndarray]:
    """Views of each CFA sub-lattice (row-major site order, see ``plane_offsets``)."""
    step = cell_size(pattern)
    return [data[..., dy::step, dx::step] for _, dy, dx in plane_offsets(pattern)]


def pack_planes(data: np.ndarray, pattern: str) -> np.ndarray:
    """Stack the CFA sub-lattices as channels: (H, W) -> (S, ceil(H/2), ceil(W/2)), S = sites.

    Odd sizes are padded by edge replication so all planes share a shape; ``unpack_planes``
    with the original shape drops the padding.
    """
    step = cell_size(pattern)
    h, w = data.shape[-2:]
    ph, pw = (-h) % step, (-w) % step
    if ph or pw:
        data = np.pad(data, [(0, 0)] * (data.ndim - 2) + [(0, ph), (0, pw)], mode="edge")
    return np.stack(split_planes(data, pattern), axis=-3)


def unpack_planes(planes: np.ndarray, pattern: str, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of ``pack_planes``: interleave the site planes back into a mosaic of ``shape``."""
    step = cell_size(pattern)
    h, w = shape
    out = np.empty(planes.shape[:-3] + (planes.shape[-2] * step, planes.shape[-1] * step), dtype=planes.dtype)
    for i, (_, dy, dx) in enumerate(plane_offsets(pattern)):
        out[..., dy::step, dx::step] = planes[..., i, :, :]
    return out[..., :h, :w]
