"""Tests of the dihedral averaging of predictions (metraw.segment.evaluate.averaged_probability)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from metraw.errors import MetrawError
from metraw.segment.data import canonical_pack, canonical_window, dihedral, undo_dihedral
from metraw.segment.evaluate import _mosaic, averaged_probability, car_probability, predict_logits

PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")


class SiteWise(torch.nn.Module):
    """Logits that are a fixed function of each site's own value: equivariant under any transform of the
    mosaic that keeps colours, so averaging can only change the result through bookkeeping errors."""

    def forward(self, x):
        return 3.0 * x - 0.5


def random_conv(in_channels: int) -> torch.nn.Module:
    """A network with no symmetry at all: one 3 x 3 convolution with random weights."""
    torch.manual_seed(0)
    net = torch.nn.Conv2d(in_channels, in_channels, 3, padding=1)
    with torch.no_grad():
        net.weight.normal_()
    return net.eval()


@pytest.mark.parametrize("k", range(8))
def test_undo_dihedral_inverts_dihedral(k):
    a = np.arange(35.0).reshape(5, 7)
    assert np.array_equal(undo_dihedral(dihedral(a, k), k), a)


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("shape", [(16, 16), (17, 20), (20, 17), (19, 23)])
def test_canonical_window_is_the_packed_extent(pattern, shape):
    z = np.random.default_rng(1).normal(size=shape).astype(np.float32)
    for k in range(8):
        dy, dx, h, w = canonical_window(pattern, shape, k)
        planes, _ = canonical_pack(z, None, pattern, k)
        assert planes.shape == (4, h // 2, w // 2) and dy in (0, 1) and dx in (0, 1)
        assert np.array_equal(_mosaic(planes, pattern), dihedral(z, k)[dy:dy + h, dx:dx + w])


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("shape", [(16, 16), (17, 20), (19, 23)])
@pytest.mark.parametrize("transforms", [2, 4, 8])
def test_averaging_a_sitewise_network_changes_nothing(pattern, shape, transforms):
    """Every transform sees each pixel with its own colour: the average of a site-wise network equals one pass
    at every pixel, edges included (a check of the unpacking, turning back and repacking)."""
    z = np.random.default_rng(2).normal(size=shape).astype(np.float32)
    one = averaged_probability(SiteWise(), z, pattern, transforms=1)
    avg = averaged_probability(SiteWise(), z, pattern, transforms=transforms)
    assert avg.shape == one.shape and avg.dtype == np.float32
    np.testing.assert_allclose(avg, one, rtol=0, atol=2e-7)
    planes, _ = canonical_pack(z, None, pattern, 0)
    assert np.array_equal(one, car_probability(predict_logits(SiteWise(), planes)))


def _mono_mosaic(z: np.ndarray, net, transforms: int) -> np.ndarray:
    """The averaged probability of a mono mosaic ``z`` (even sides: packed whole) back on the mosaic grid."""
    from metraw.segment.predict import sites_to_mosaic

    assert z.shape[0] % 2 == 0 and z.shape[1] % 2 == 0
    return sites_to_mosaic(averaged_probability(net, z, "mono", transforms=transforms), "mono", z.shape)


@pytest.mark.parametrize("k", range(1, 8))
def test_eight_fold_average_turns_with_the_image(k):
    """The 8-fold average of a network with no symmetry is equivariant: turning or flipping the input turns or
    flips the prediction exactly; one pass is not."""
    net = random_conv(4)  # a mono mosaic packs in 4 planes of 2 x 2 pixels, as a Bayer one
    z = np.random.default_rng(3).normal(size=(20, 26)).astype(np.float32)
    avg = _mono_mosaic(z, net, 8)
    avg_k = _mono_mosaic(dihedral(z, k).copy(), net, 8)
    np.testing.assert_allclose(avg_k, dihedral(avg, k), rtol=0, atol=1e-6)
    one_k = _mono_mosaic(dihedral(z, k).copy(), net, 1)
    assert np.abs(one_k - dihedral(_mono_mosaic(z, net, 1), k)).max() > 1e-2


@pytest.mark.parametrize("transforms", [2, 4])
def test_axis_keeping_averages_turn_with_their_group_and_keep_the_smear_along_its_axis(transforms):
    """2 and 4 transforms average over the half turn (and the flips): exactly equivariant under those, and none of
    them lays a row (a smear along x) across the columns."""
    from metraw.segment.data import TRANSFORM_SETS

    ks = TRANSFORM_SETS[transforms]
    assert len(ks) == transforms and set(ks) <= {0, 2, 4, 6}
    row = np.zeros((9, 9), np.float32)
    row[4, 2:7] = 1.0  # a smear along x
    for k in ks:
        assert np.array_equal(dihedral(row, k), row)  # turned by a half or flipped, it stays one row
    net = random_conv(4)
    z = np.random.default_rng(4).normal(size=(20, 26)).astype(np.float32)
    avg = _mono_mosaic(z, net, transforms)
    for k in ks[1:]:
        avg_k = _mono_mosaic(dihedral(z, k).copy(), net, transforms)
        np.testing.assert_allclose(avg_k, dihedral(avg, k), rtol=0, atol=1e-6)
    avg_quarter = _mono_mosaic(dihedral(z, 1).copy(), net, transforms)
    assert np.abs(avg_quarter - dihedral(avg, 1)).max() > 1e-2  # not under a quarter turn


def test_transform_count_is_checked():
    from metraw.segment.train import TrainConfig

    z = np.zeros((8, 8), np.float32)
    for bad in (0, 3, 16, True):
        with pytest.raises(MetrawError, match="transforms must be one of 1, 2, 4, 8"):
            averaged_probability(SiteWise(), z, "RGGB", transforms=bad)
        with pytest.raises(MetrawError, match="transforms must be one of 1, 2, 4, 8"):
            TrainConfig.from_dict({"predict_transforms": bad})
    assert TrainConfig.from_dict({}).predict_transforms == 1
