"""Compact U-Net for car segmentation on packed, variance-stabilised raw planes (plain torch).

Input: (B, S, h, w) packed CFA planes in VST units (unit noise variance, see
``metraw.segment.data``), S = 4 for Bayer (canonical R, G, G, B site order), 1 for mono.
Output: (B, S, h, w) logits of "car", one per CFA site, i.e. a prediction for every mosaic pixel.

``Segmenter`` (and ``ForeignSegmenter``, the same around a network of another kind: ``metraw.segment.networks``)
resamples the input to the network's working grid and the logits back, so the loss
and the IoU always live on the image's own mosaic grid:
- ``upsample`` > 1: bilinear upsampling of the input, logits average-pooled back (coarse
  satellite images get the same receptive field in pixels as a larger image);
- ``pool`` > 1: average pooling of the input (fine drone images: the same ground context for a
  fraction of the cost), logits upsampled bilinearly back.
Compare the choices in ``benchmarks/segment.py``.
"""

from __future__ import annotations

import torch
from torch import nn
import torch.nn.functional as F


def _norm(channels: int) -> nn.Module:
    # GroupNorm: independent of batch composition (padding, batch size), same in train and eval.
    return nn.GroupNorm(min(8, channels), channels)


class _Block(nn.Sequential):
    def __init__(self, cin: int, cout: int):
        super().__init__(
            nn.Conv2d(cin, cout, 3, padding=1, bias=False), _norm(cout), nn.ReLU(inplace=True),
            nn.Conv2d(cout, cout, 3, padding=1, bias=False), _norm(cout), nn.ReLU(inplace=True),
        )


class UNet(nn.Module):
    """U-Net with ``depth`` poolings and ``base_channels`` * 2**level channels per level.

    ``n_condition`` > 0: every block's output is scaled and shifted per channel by a linear map of a
    conditioning vector (FiLM: x (1 + gamma) + beta; ``metraw.segment.condition``), zero at initialisation.
    """

    def __init__(self, in_channels: int, base_channels: int = 16, depth: int = 3, out_channels: int = 1,
                 n_condition: int = 0):
        super().__init__()
        self.depth = depth
        self.n_condition = int(n_condition)
        chans = [base_channels * 2**i for i in range(depth + 1)]
        self.down = nn.ModuleList()
        cin = in_channels
        for c in chans[:-1]:
            self.down.append(_Block(cin, c))
            cin = c
        self.bottom = _Block(chans[-2], chans[-1])
        self.up = nn.ModuleList()
        self.dec = nn.ModuleList()
        for i in range(depth - 1, -1, -1):
            self.up.append(nn.ConvTranspose2d(chans[i + 1], chans[i], 2, stride=2))
            self.dec.append(_Block(2 * chans[i], chans[i]))
        self.head = nn.Conv2d(chans[0], out_channels, 1)
        self.film = nn.ModuleList()
        if self.n_condition:
            for c in chans[:-1] + [chans[-1]] + chans[-2::-1]:  # down blocks, bottom, decoder blocks
                layer = nn.Linear(self.n_condition, 2 * c)
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)
                self.film.append(layer)

    @property
    def multiple(self) -> int:
        """Input sides must be multiples of this (2**depth)."""
        return 2**self.depth

    def forward(self, x: torch.Tensor, condition: torch.Tensor | None = None) -> torch.Tensor:
        """Logits of ``x`` (B, C, h, w); ``condition`` (B, n_condition) when the network is conditioned."""
        film = iter(self.film)
        if self.n_condition:
            if condition is None or tuple(condition.shape) != (x.shape[0], self.n_condition):
                raise ValueError(f"this network is conditioned: it needs a condition of shape ({x.shape[0]}, "
                                 f"{self.n_condition}), got {None if condition is None else tuple(condition.shape)}")
            condition = condition.to(x.dtype)

        def modulate(h: torch.Tensor) -> torch.Tensor:
            if not self.n_condition:
                return h
            gamma, beta = next(film)(condition).chunk(2, dim=1)
            return h * (1 + gamma[:, :, None, None]) + beta[:, :, None, None]

        skips = []
        for block in self.down:
            x = modulate(block(x))
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = modulate(self.bottom(x))
        for up, dec in zip(self.up, self.dec):
            x = up(x)
            x = modulate(dec(torch.cat([x, skips.pop()], dim=1)))
        return self.head(x)


def _pad_to(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Pad the last two axes up to a multiple (reflect where possible, else replicate)."""
    ph, pw = (-x.shape[-2]) % multiple, (-x.shape[-1]) % multiple
    if not (ph or pw):
        return x
    mode = "reflect" if min(x.shape[-2:]) > max(ph, pw) else "replicate"
    return F.pad(x, (0, pw, 0, ph), mode=mode)


class _GridWrapper(nn.Module):
    """Resampling to a network's working grid and padding to its input multiple, around ``core``.

    ``forward(x, condition)`` accepts any (B, S, h, w) and returns logits (B, S, h, w) on the input grid;
    ``condition`` (B, n_condition) only for a conditioned network.
    """

    def __init__(self, upsample: int = 1, pool: int = 1):
        super().__init__()
        if upsample < 1 or pool < 1 or (upsample > 1 and pool > 1):
            raise ValueError("upsample and pool must be integers >= 1, at most one of them > 1")
        self.upsample = int(upsample)
        self.pool = int(pool)

    @property
    def core(self) -> nn.Module:
        """The network on the working grid."""
        raise NotImplementedError

    @property
    def multiple(self) -> int:
        """The network's input sides must be multiples of this (the wrapper pads)."""
        raise NotImplementedError

    @property
    def n_condition(self) -> int:
        """Length of the conditioning vector the network takes (0: none)."""
        return 0

    def forward(self, x: torch.Tensor, condition: torch.Tensor | None = None) -> torch.Tensor:
        h, w = x.shape[-2:]
        f, p = self.upsample, self.pool
        if f > 1:
            x = F.interpolate(x, scale_factor=f, mode="bilinear", align_corners=False)
        if p > 1:
            x = F.avg_pool2d(_pad_to(x, p), p)
        hn, wn = x.shape[-2:]
        x = _pad_to(x, self.multiple)
        y = (self.core(x, condition) if self.n_condition else self.core(x))[..., :hn, :wn]
        if f > 1:
            y = F.avg_pool2d(y, f)
        if p > 1:
            y = F.interpolate(y, scale_factor=p, mode="bilinear", align_corners=False)[..., :h, :w]
        return y


class Segmenter(_GridWrapper):
    """metraw's U-Net wrapped with resampling to its working grid and padding to a valid size
    (``_GridWrapper``); ``n_condition`` > 0: FiLM-conditioned on the payload."""

    def __init__(self, in_channels: int, base_channels: int = 16, depth: int = 3, upsample: int = 1,
                 pool: int = 1, n_condition: int = 0):
        super().__init__(upsample, pool)
        self.unet = UNet(in_channels, base_channels, depth, out_channels=in_channels, n_condition=n_condition)

    @property
    def core(self) -> nn.Module:
        return self.unet

    @property
    def multiple(self) -> int:
        return self.unet.multiple

    @property
    def n_condition(self) -> int:
        return self.unet.n_condition


class ForeignSegmenter(_GridWrapper):
    """Any network that keeps the contract of ``metraw.segment.networks`` (logits of the input's shape; input sides
    multiples of ``multiple``), wrapped like ``Segmenter``; it takes no conditioning."""

    def __init__(self, network: nn.Module, multiple: int, upsample: int = 1, pool: int = 1):
        super().__init__(upsample, pool)
        if int(multiple) < 1:
            raise ValueError(f"multiple must be >= 1, got {multiple}")
        self.net = network
        self._multiple = int(multiple)

    @property
    def core(self) -> nn.Module:
        return self.net

    @property
    def multiple(self) -> int:
        return self._multiple
