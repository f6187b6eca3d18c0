"""Segmentation data from a RawStore: VST'd packed CFA planes and car-fraction targets.

Input representation (one per image, computed once and cached in memory):

1. generalised Anscombe transform of the DN values with the image's own profile
   (``metraw.raw.vst.anscombe``): the noise of every pixel becomes ~N(0, 1) in these units, so the
   network sees unit-variance noise at every parameter point;
2. centring: subtract the image's median VST value (a constant: the noise stays unit variance;
   colour differences between planes are kept);
3. packing: the mosaic is shifted by at most one pixel so that its CFA cell reads R G / G B,
   then packed into 4 planes (canonical site order R, G, G, B; a mono mosaic's 2 x 2 cells alike: four pixels
   of one colour) at half resolution (``metraw.raw.cfa.pack_planes``, ``metraw.raw.cfa.PACKED_CELL_PX``).

Targets: the car area fraction of every mosaic pixel (the store's mask), packed exactly like the
image, so the network predicts one value per CFA site: the segmentation lives on the mosaic
grid, the finest grid the sensor samples. Training uses the fractions as soft targets; scoring
(``metraw.segment.evaluate``) measures IoU in ground area against them.

Augmentation acts on the mosaic *before* packing: one of the 8 dihedral transforms (flips,
rot90), then the one-pixel shift that restores the canonical R G / G B cell, so every plane
keeps its colour and the sub-pixel geometry of the CFA is respected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metraw.errors import MetrawError
from metraw.progress import progress_bar
from metraw.raw.cfa import PACKED_CELL_PX, PACKED_GEOMETRY, color_index, pack_planes
from metraw.raw.image import RawImage
from metraw.raw.sensor import rng_from_seed
from metraw.raw.vst import anscombe
from metraw.segment.condition import payload_condition


def split_indices(n_images: int, test_fraction: float, split_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed train/test split by image index: (sorted train indices, sorted test indices).

    The same (n_images, test_fraction, split_seed) gives the same split for every parameter
    point, so emulated stores (image i emulated from source image i) share it.
    """
    if not 0.0 < test_fraction < 1.0:
        raise MetrawError(f"test_fraction must be in (0, 1), got {test_fraction}")
    n_test = int(round(n_images * test_fraction))
    if n_images < 2 or n_test < 1 or n_test >= n_images:
        raise MetrawError(f"cannot split {n_images} images with test_fraction {test_fraction}: "
                          "need at least one training and one test image")
    perm = rng_from_seed(split_seed).permutation(n_images)
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


def source_indices(store) -> tuple[np.ndarray, int]:
    """(index in its source of each image of an emulated ``store``, images in that source).

    ``metraw emulate --images test`` records both (store attributes ``source_indices`` / ``source_images``): the
    store holds only its source's test split. A store without them (``--images all``, also with ``--limit``) holds
    images 0 .. n-1 of n, its own data set.
    """
    attrs = store.attrs
    if "source_indices" not in attrs:
        return np.arange(len(store)), len(store)
    indices = np.asarray(attrs["source_indices"], dtype=np.int64)
    n_source = int(attrs.get("source_images", len(store)))
    if len(indices) != len(store) or (len(indices) and not (0 <= indices.min() and indices.max() < n_source)):
        raise MetrawError(f"store {store.path}: its source_indices ({len(indices)}) do not match its "
                          f"{len(store)} images of a {n_source}-image source")
    return indices, n_source


def split_positions(store, test_fraction: float, split_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(source test indices, store positions of the test images) of an emulated ``store``: the split is its
    source's (``split_indices`` over the source's images), whatever subset of them the store holds; a store that
    lacks a test image of its source is refused in one line."""
    indices, n_source = source_indices(store)
    _, test_idx = split_indices(n_source, test_fraction, split_seed)
    is_test = np.isin(indices, test_idx)
    if int(is_test.sum()) != len(test_idx):
        missing = np.setdiff1d(test_idx, indices)
        raise MetrawError(f"store {store.path} lacks {len(missing)} of the {len(test_idx)} test images "
                          f"of its {n_source}-image source (e.g. source image {int(missing[0])}): emulate it with "
                          "the same training.split_seed and test_fraction")
    return test_idx, np.flatnonzero(is_test)


def vst_mosaic(image: RawImage) -> np.ndarray:
    """Generalised Anscombe of the image's DN with its own profile, minus its median (float32).

    Noise is ~unit variance per pixel for signals >~ 1 e-; the median subtraction is a constant.
    """
    return vst_mosaic_and_level(image)[0]


def vst_mosaic_and_level(image: RawImage) -> tuple[np.ndarray, float]:
    """``vst_mosaic`` and the median it subtracted (the image's VST level, ~2 sqrt(median e-))."""
    z = anscombe(image.data, image.profile)
    level = float(np.median(z))
    return (z - level).astype(np.float32), level


def tone_jitter(planes: np.ndarray, level: float, rng: np.random.Generator, gamma_range: float,
                gain_range: float) -> np.ndarray:
    """Domain randomisation of tone and colour on packed VST planes (S, h, w) centred on ``level``.

    The VST value is ~2 sqrt(e-), so a power law on it is one on the photoelectrons: z -> level (z / level)^g
    with g log-uniform in [1 / gamma_range, gamma_range] (the median stays put; darks are crushed or lifted
    as a processed photo's tone curve does), then each CFA plane is scaled by sqrt(c), c log-uniform in
    [1 / gain_range, gain_range] (a white balance error of c in electrons). The noise is no longer unit
    variance: an augmentation for robustness to processed real photos, not a metrological step (off by
    default; ``TrainConfig.tone_gamma_range`` / ``channel_gain_range``).
    """
    g = math.exp(rng.uniform(-math.log(gamma_range), math.log(gamma_range)))
    c = np.exp(rng.uniform(-math.log(gain_range), math.log(gain_range), planes.shape[0])).astype(np.float32)
    ref = max(level, 1.0)
    zabs = np.maximum(planes + np.float32(level), np.float32(0.5)) / np.float32(ref)
    out = np.float32(ref) * zabs ** np.float32(g) * np.sqrt(c)[:, None, None] - np.float32(level)
    return out.astype(np.float32, copy=False)


def _canonical_offset(ci: np.ndarray, mono: bool) -> tuple[int, int]:
    """(dy, dx) in {0, 1}^2 where the colour-index map ``ci`` has its R G / G B cell."""
    if mono:
        return 0, 0
    ci = np.tile(ci[:2, :2], (2, 2)) if ci.shape[0] < 3 or ci.shape[1] < 3 else ci
    for dy in (0, 1):
        for dx in (0, 1):
            if ci[dy, dx] == 0 and ci[dy + 1, dx + 1] == 2:
                return dy, dx
    raise MetrawError("internal error: no canonical CFA offset found")


#: The dihedral transforms (``dihedral``'s k) a prediction averages, by their count
#: (``metraw.segment.evaluate.averaged_probability``). Each set is a group, so its average is exactly equivariant
#: under it. 2 and 4 keep the image axes (the half turn; and the flips): motion smear stays along the track, as in
#: every training draw (the draws turn the scene before the emulation, not the emulated image); 8 adds the quarter
#: turns, which lay the smear across the track.
TRANSFORM_SETS = {1: (0,), 2: (0, 2), 4: (0, 2, 4, 6), 8: tuple(range(8))}
TRANSFORM_COUNTS = tuple(TRANSFORM_SETS)


def check_transforms(transforms) -> None:
    """A one-line error unless ``transforms`` is one of ``TRANSFORM_COUNTS``."""
    if isinstance(transforms, bool) or transforms not in TRANSFORM_COUNTS:
        raise MetrawError(f"transforms must be one of {', '.join(map(str, TRANSFORM_COUNTS))}, got {transforms!r}")


def dihedral(a: np.ndarray, k: int) -> np.ndarray:
    """One of the 8 dihedral transforms of the last two axes: k in 0..7 (rot90 k%4, then flip if k>=4)."""
    a = np.rot90(a, k % 4, axes=(-2, -1))
    return a[..., :, ::-1] if k >= 4 else a


def undo_dihedral(a: np.ndarray, k: int) -> np.ndarray:
    """Inverse of ``dihedral``: undo_dihedral(dihedral(a, k), k) == a."""
    a = a[..., :, ::-1] if k >= 4 else a
    return np.rot90(a, -(k % 4), axes=(-2, -1))


def canonical_window(pattern: str, shape: tuple[int, int], k: int = 0) -> tuple[int, int, int, int]:
    """(dy, dx, h, w): the mosaic window, rows dy..dy+h-1 and columns dx..dx+w-1 of the image of ``shape``
    transformed by ``dihedral`` k, that ``canonical_pack`` packs (whole R G / G B cells; h, w may be 0)."""
    step = PACKED_CELL_PX
    tshape = (shape[1], shape[0]) if k % 2 else (shape[0], shape[1])
    corner = (2 + shape[0] % 2, 2 + shape[1] % 2)  # the CFA is periodic: the parities fix the corners' colours
    dy, dx = _canonical_offset(dihedral(color_index(pattern, corner), k), pattern == "mono")
    return dy, dx, max(0, (tshape[0] - dy) // step * step), max(0, (tshape[1] - dx) // step * step)


def canonical_pack(z: np.ndarray, mask: np.ndarray | None, pattern: str, k: int = 0
                   ) -> tuple[np.ndarray, np.ndarray | None]:
    """Transform (``dihedral`` k), shift to the canonical R G / G B cell and pack.

    Returns planes (S, h, w) float32 and the car fraction of every site, packed the same way
    (S, h, w) float32 (or None). The result covers whole cells only (at most one mosaic
    row/column is dropped per side).
    """
    dy, dx, h, w = canonical_window(pattern, z.shape, k)
    z = dihedral(z, k)
    if h < 1 or w < 1:
        raise MetrawError(f"image of shape {z.shape} is too small to pack")
    packed = PACKED_GEOMETRY
    planes = pack_planes(np.ascontiguousarray(z[dy:dy + h, dx:dx + w]), packed)
    frac = None
    if mask is not None:
        m = dihedral(mask, k)[dy:dy + h, dx:dx + w]
        frac = pack_planes(np.ascontiguousarray(m, dtype=np.float32), packed)
    return planes.astype(np.float32, copy=False), frac


@dataclass
class PreparedImage:
    """Cached preprocessed image: centred VST mosaic (float32), car mask (float16), CFA pattern,
    ground sample distance of a mosaic pixel [m] (None when the profile lacks the geometry), and the
    payload's conditioning vector (``metraw.segment.condition.payload_condition``; None likewise)."""

    z: np.ndarray
    mask: np.ndarray
    pattern: str
    index: int
    gsd_m: float | None = None
    level: float = 0.0  # the median VST value subtracted from z
    condition: np.ndarray | None = None

    @property
    def packed_shape(self) -> tuple[int, int]:
        _, _, h, w = canonical_window(self.pattern, self.z.shape, 0)
        s = PACKED_CELL_PX
        return h // s, w // s

    def full(self) -> tuple[np.ndarray, np.ndarray]:
        """Whole image, untransformed: planes (S, h, w) and site car fractions (S, h, w)."""
        return canonical_pack(self.z, self.mask.astype(np.float32), self.pattern, 0)

    def crop(self, crop_px: int, rng: np.random.Generator, augment: bool = True, gamma_range: float = 1.0,
             gain_range: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """A random crop of ``crop_px`` packed pixels (or the whole image if smaller), augmented (dihedral;
        ``tone_jitter`` when a range exceeds 1)."""
        s = PACKED_CELL_PX
        side = crop_px * s + (s - 1)  # one spare row/column for the canonical shift
        H, W = self.z.shape
        ch, cw = min(side, H), min(side, W)
        y0 = int(rng.integers(0, H - ch + 1))
        x0 = int(rng.integers(0, W - cw + 1))
        k = int(rng.integers(0, 8)) if augment else 0
        z = self.z[y0:y0 + ch, x0:x0 + cw]
        m = self.mask[y0:y0 + ch, x0:x0 + cw]
        # the colour pattern of the crop is the store pattern shifted by (y0, x0)
        pattern = _shifted_pattern(self.pattern, y0, x0)
        planes, frac = canonical_pack(z, m.astype(np.float32), pattern, k)
        c = min(crop_px, planes.shape[-2], planes.shape[-1])
        planes, frac = planes[:, :c, :c], frac[:, :c, :c]
        if augment and (gamma_range > 1.0 or gain_range > 1.0):
            planes = tone_jitter(planes, self.level, rng, gamma_range, gain_range)
        return planes, frac


def _shifted_pattern(pattern: str, dy: int, dx: int) -> str:
    """The CFA pattern seen from pixel (dy, dx) of a mosaic with ``pattern``."""
    if pattern == "mono":
        return pattern
    cell = [[pattern[0], pattern[1]], [pattern[2], pattern[3]]]
    return "".join(cell[(dy + i) % 2][(dx + j) % 2] for i in (0, 1) for j in (0, 1))


def prepare(image: RawImage, index: int = -1) -> PreparedImage:
    """Preprocess one RawImage for the segmenter (needs a label mask)."""
    if image.mask is None:
        raise MetrawError(f"image {index} has no label mask; segmentation needs masks")
    z, level = vst_mosaic_and_level(image)
    return PreparedImage(z, image.mask.astype(np.float16), image.cfa_pattern, index, image.profile.gsd_m, level,
                         payload_condition(image.profile))


def prepare_store(store, indices, progress: bool | None = None) -> list[PreparedImage]:
    """Preprocess the images ``indices`` of a RawStore (read once, cached in memory)."""
    disable = None if progress is None else not progress
    return [prepare(store[int(i)], int(i)) for i in progress_bar(list(indices), desc="load", disable=disable)]


def batch_crops(images: list[PreparedImage], crop_px: int, rng: np.random.Generator, augment: bool = True,
                gamma_range: float = 1.0, gain_range: float = 1.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Stack one random crop per image, all cut to the smallest common packed side: (planes, site car fractions,
    the images' conditioning vectors (B, K), or None when one of them has none)."""
    xs, ys = zip(*(img.crop(crop_px, rng, augment, gamma_range, gain_range) for img in images))
    c = min(min(x.shape[-2:]) for x in xs)
    conds = [img.condition for img in images]
    cond = None if any(v is None for v in conds) else np.stack(conds)
    return np.stack([x[:, :c, :c] for x in xs]), np.stack([y[:, :c, :c] for y in ys]), cond
